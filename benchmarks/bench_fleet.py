"""Fleet benchmark: cold runs and a fleet night for 1, 10, 50 twin machines, and a per-job profile.

Usage (from the repository root; see benchmarks/README.md)::

    python benchmarks/bench_fleet.py                          # N = 1 10 50, target all, 2 cores
    python benchmarks/bench_fleet.py --sizes 1 10             # smaller fleets only
    python benchmarks/bench_fleet.py --target tables --no-night
    python benchmarks/bench_fleet.py --sizes 1 --keep /tmp/fb # keep the projects to inspect

Per fleet size N, in a fresh temporary project (Snakefile, workflow/, profiles/, config.yaml
with ``nightly_settle_s: 0``, its own raw/):

1. raw/fleet-000 ... fleet-<N-1>: each a shipped-size machine from the digital twin,
   ``rafi.twin.day.write_day`` as ``rafi simulate day --machine tapping-center-a --seed S
   --validation-speeds 4500,8000,10500,13500,16500 --multi`` (12 native CSVs like
   tapping-center-a's: 6 training, 5 validation, 1 multi-condition), seed ``--seed0 + i``, so
   every machine has its own noise, defects, room and dates (not copies). The ``# machine:``
   header line names the machine's folder. Machine i is the same file set for every N.
2. ``snakemake -n --cores C <target>`` (planning only, timed), then the cold run
   ``snakemake --cores C <target>`` under ``/usr/bin/time -v``: wall time, the peak RSS of the
   largest single process (time -v) and of the whole process tree (sum of the RSS of every
   descendant, sampled from /proc every 0.2 s).
3. A fleet night (target all or nightly): one new log on every machine (``rafi simulate day
   --speeds 3000 --ambient-shift 2``, one training log, like bench_nightly.py), then
   ``rafi nightly --cores C`` (settle 0), timed the same way.

A size whose predicted time (linear fit of the sizes measured so far) exceeds ``--budget-s``
is not run but extrapolated, and the report says so.

The profile (from the largest measured fleet): job count per rule (Snakemake's job stats),
the rule's ``benchmark:`` seconds per job, and each job's start-up: a no-op ``script:`` job
timed in a throw-away workflow (Python start, Snakemake's preamble, the benchmark wrapper)
plus the import time of the rule script's imports (``_glue`` and the ``import`` statements of
the script, function bodies included), so ``work = s per job - start-up``.

Results: ``benchmarks/results/fleet.json`` and ``fleet.md``.
"""

from __future__ import annotations

import argparse
import ast
import datetime as dt
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / "benchmarks"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from _results import write_results  # noqa: E402

TIME_V = Path("/usr/bin/time")
TWIN_MACHINE = "tapping-center-a"
VALIDATION_SPEEDS = (4500, 8000, 10500, 13500, 16500)
PAGE = os.sysconf("SC_PAGE_SIZE")
ACCEPTED_NIGHT_EXITS = (0, 2, 3, 4)  # all good, candidate failed, recalibration due, input rejected


# --------------------------------------------------------------------------- fleets from the twin


def machine_name(i: int) -> str:
    return f"fleet-{i:03d}"


def _rename_machine(paths, name: str) -> None:
    """Point the ``# machine:`` metadata line of each native CSV at the folder's machine."""
    for p in paths:
        text = Path(p).read_text(encoding="utf-8")
        Path(p).write_text(
            re.sub(r"^# machine: .*$", f"# machine: {name}", text, count=1, flags=re.M), encoding="utf-8"
        )


def _generate(args: tuple[str, int, int, dict]) -> list[str]:
    """Write one day of twin logs for machine ``name`` into ``out/<name>/``; return the file names."""
    from rafi.twin.day import write_day

    out, i, seed, kwargs = args
    name = machine_name(i)
    tmp = Path(out) / f".gen-{name}-{seed}"
    paths = write_day(tmp, machine=TWIN_MACHINE, seed=seed, **kwargs)
    _rename_machine(paths, name)
    dest = Path(out) / name
    dest.mkdir(parents=True, exist_ok=True)
    for p in paths:
        os.replace(p, dest / p.name)
    shutil.rmtree(tmp)
    return [p.name for p in paths]


def generate_fleet(cache: Path, n: int, seed0: int, workers: int) -> None:
    """Machines ``fleet-000 .. fleet-<n-1>`` under ``cache`` (the ones already there are kept)."""
    todo = [i for i in range(n) if not (cache / machine_name(i)).is_dir()]
    kwargs = {"validation_speeds": VALIDATION_SPEEDS, "multi": True}
    jobs = [(str(cache), i, seed0 + i, kwargs) for i in todo]
    if not jobs:
        return
    with ProcessPoolExecutor(max_workers=max(1, workers)) as pool:
        for files in pool.map(_generate, jobs):
            assert len(files) == 12, files


def add_night_logs(raw: Path, machines: list[str], seed0: int, workers: int) -> None:
    """One new training log (3000 r/min, room 2 K warmer) on every machine, its own seed each."""
    kwargs = {"speeds": (3000,), "ambient_shift": 2.0}
    jobs = [(str(raw), int(m.split("-")[1]), seed0 + int(m.split("-")[1]), kwargs) for m in machines]
    with ProcessPoolExecutor(max_workers=max(1, workers)) as pool:
        for files in pool.map(_generate, jobs):
            assert len(files) == 1, files


def make_project(dest: Path, cache: Path, n: int) -> Path:
    """A runnable project in ``dest`` with machines 0..n-1 of ``cache`` as its raw/."""
    dest.mkdir(parents=True)
    shutil.copy2(ROOT / "Snakefile", dest / "Snakefile")
    ignore = shutil.ignore_patterns("__pycache__")
    shutil.copytree(ROOT / "workflow", dest / "workflow", ignore=ignore)
    if (ROOT / "profiles").is_dir():
        shutil.copytree(ROOT / "profiles", dest / "profiles", ignore=ignore)
    shutil.copy2(ROOT / "config.yaml", dest / "config.yaml")
    # time the pipeline, not the wait for a log that may still be written (bench_nightly.py)
    with open(dest / "config.yaml", "a", encoding="utf-8") as fh:
        fh.write("\nnightly_settle_s: 0\n")
    for i in range(n):
        shutil.copytree(cache / machine_name(i), dest / "raw" / machine_name(i))
    return dest


# --------------------------------------------------------------------------- timing and memory


class TreeRss:
    """Peak of the summed RSS of a process and all its descendants, sampled from /proc."""

    def __init__(self, pid: int, interval: float = 0.2):
        self.pid, self.interval, self.peak, self.samples = pid, interval, 0, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()

    @staticmethod
    def _table() -> dict[int, tuple[int, int]]:
        """pid -> (ppid, rss bytes) of every process visible in /proc."""
        out = {}
        for entry in os.scandir("/proc"):
            if not entry.name.isdigit():
                continue
            try:
                with open(f"/proc/{entry.name}/stat", "rb") as fh:
                    stat = fh.read()
                with open(f"/proc/{entry.name}/statm", "rb") as fh:
                    rss = int(fh.read().split()[1]) * PAGE
            except (OSError, IndexError, ValueError):
                continue
            fields = stat[stat.rfind(b")") + 2 :].split()
            out[int(entry.name)] = (int(fields[1]), rss)
        return out

    def sample(self) -> int:
        table = self._table()
        children: dict[int, list[int]] = {}
        for pid, (ppid, _) in table.items():
            children.setdefault(ppid, []).append(pid)
        total, stack = 0, [self.pid]
        while stack:
            pid = stack.pop()
            if pid in table:
                total += table[pid][1]
            stack += children.get(pid, [])
        return total

    def _run(self):
        while not self._stop.is_set():
            self.peak = max(self.peak, self.sample())
            self.samples += 1
            self._stop.wait(self.interval)


def timed(cmd: list[str], cwd: Path) -> dict:
    """Run ``cmd`` under ``/usr/bin/time -v`` (if present): wall s, peak RSS (largest process and tree)."""
    use_time = TIME_V.exists()
    full = [str(TIME_V), "-v", *cmd] if use_time else cmd
    load_before = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.Popen(full, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    with TreeRss(proc.pid) as tree:
        stdout, stderr = proc.communicate()
    wall = time.perf_counter() - t0
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", stderr) if use_time else None
    # core-seconds of the whole tree (Snakemake and every job it waited for): on a machine other
    # work shares, wall time grows with the load, core-seconds much less
    cpu = [re.search(rf"{kind} time \(seconds\): ([\d.]+)", stderr) for kind in ("User", "System")]
    return {
        "wall_s": round(wall, 2),
        "cpu_s": round(sum(float(c.group(1)) for c in cpu), 1) if use_time and all(cpu) else None,
        "load_1min": [round(load_before, 2), round(os.getloadavg()[0], 2)],
        "exit": proc.returncode,
        "peak_process_mb": round(int(m.group(1)) / 1024, 1) if m else None,
        "peak_tree_mb": round(tree.peak / 2**20, 1),
        "stdout": stdout,
        "stderr": stderr,
    }


def job_counts(text: str) -> dict[str, int]:
    """Rule -> jobs started, from the ``rule <name>:`` / ``localrule <name>:`` lines of Snakemake's log.

    (The ``Job stats`` table printed at the start misses the jobs added after a checkpoint.)
    """
    out: dict[str, int] = {}
    for m in re.finditer(r"^(?:local)?(?:rule|checkpoint) (\w+):", text, re.M):
        out[m.group(1)] = out.get(m.group(1), 0) + 1
    return out


def rule_of_tsv(bench_dir: Path, tsv: Path) -> str:
    rel = tsv.relative_to(bench_dir).parts
    if len(rel) > 1:
        return rel[0]  # clean/<stem>.tsv
    return "report_figures" if tsv.stem.startswith("report_figures_") else tsv.stem


def rule_seconds(results: Path, since: float = 0.0) -> dict[str, list[float]]:
    """Rule -> the ``s`` of every benchmark TSV written after ``since`` (epoch seconds)."""
    per_rule: dict[str, list[float]] = {}
    for bench_dir in sorted(results.glob("*/benchmarks")):
        for tsv in sorted(bench_dir.rglob("*.tsv")):
            if tsv.stat().st_mtime < since:
                continue
            lines = tsv.read_text().splitlines()
            if len(lines) < 2:
                continue
            row = dict(zip(lines[0].split("\t"), lines[1].split("\t")))
            try:
                per_rule.setdefault(rule_of_tsv(bench_dir, tsv), []).append(float(row["s"]))
            except (KeyError, ValueError):
                continue
    return per_rule


# --------------------------------------------------------------------------- one fleet size


def snakemake_cmd(cores: int, target: str, *extra: str) -> list[str]:
    return [sys.executable, "-m", "snakemake", "--cores", str(cores), *extra, target]


def run_size(n: int, cache: Path, workdir: Path, args) -> dict:
    proj = make_project(workdir / f"fleet-{n}", cache, n)
    files = sum(1 for p in (proj / "raw").rglob("*.csv"))
    raw_mb = sum(p.stat().st_size for p in (proj / "raw").rglob("*.csv")) / 2**20
    print(f"N={n}: {files} raw files, {raw_mb:.0f} MB in {proj}", flush=True)

    plan = timed(snakemake_cmd(args.cores, args.target, "-n"), proj)
    if plan["exit"] != 0:
        sys.stderr.write(plan["stderr"][-3000:])
        raise SystemExit(f"N={n}: snakemake -n failed (exit {plan['exit']}); project at {proj}")
    cold = timed(snakemake_cmd(args.cores, args.target), proj)
    if cold["exit"] != 0:
        sys.stderr.write(cold["stderr"][-5000:])
        raise SystemExit(f"N={n}: snakemake failed (exit {cold['exit']}); project kept at {proj}")
    jobs = job_counts(cold["stderr"])
    (proj / "bench-cold.log").write_text(cold["stderr"])
    seconds = rule_seconds(proj / "results")
    result = {
        "machines": n,
        "files": files,
        "raw_mb": round(raw_mb, 1),
        "plan_s": plan["wall_s"],
        "cold": {k: v for k, v in cold.items() if k not in ("stdout", "stderr")},
        "cold_jobs": jobs,
        "cold_job_seconds": {r: round(sum(v), 2) for r, v in seconds.items()},
        "cold_job_s_mean": {r: round(sum(v) / len(v), 3) for r, v in seconds.items()},
        "cold_sum_job_s": round(sum(sum(v) for v in seconds.values()), 1),
        "project": str(proj),
    }
    print(
        f"  plan {plan['wall_s']} s; cold {cold['wall_s']} s, {cold['cpu_s']} core-s, load "
        f"{cold['load_1min']} ({sum(jobs.values())} jobs), "
        f"peak {cold['peak_tree_mb']} MB tree / {cold['peak_process_mb']} MB one process",
        flush=True,
    )
    if args.night and args.target in ("all", "nightly"):
        machines = sorted(p.name for p in (proj / "raw").iterdir() if p.is_dir())
        add_night_logs(proj / "raw", machines, args.night_seed0, args.cores)
        started = time.time()
        night = timed(
            [
                sys.executable,
                "-m",
                "rafi.cli",
                "nightly",
                "--directory",
                str(proj),
                "--cores",
                str(args.cores),
            ],
            proj,
        )
        if night["exit"] not in ACCEPTED_NIGHT_EXITS:
            sys.stderr.write(night["stdout"][-3000:] + night["stderr"][-3000:])
            raise SystemExit(f"N={n}: rafi nightly exit {night['exit']}; project kept at {proj}")
        (proj / "bench-night.log").write_text(night["stdout"] + night["stderr"])
        m = re.search(r"(\d+) job\(s\) in", night["stdout"])
        done: dict[str, int] = {}
        for rule in re.findall(r"done (\w+)", night["stdout"]):
            done[rule] = done.get(rule, 0) + 1
        night_seconds = rule_seconds(proj / "results", since=started)
        result["night"] = {k: v for k, v in night.items() if k not in ("stdout", "stderr")}
        result["night"]["jobs"] = int(m.group(1)) if m else None
        result["night_job_seconds"] = {r: round(sum(v), 2) for r, v in night_seconds.items()}
        result["night_jobs"] = done
        print(
            f"  night {night['wall_s']} s, {night['cpu_s']} core-s, load {night['load_1min']} "
            f"(exit {night['exit']}, {result['night']['jobs']} jobs), "
            f"peak {night['peak_tree_mb']} MB tree",
            flush=True,
        )
    return result


# --------------------------------------------------------------------------- start-up profile


NOOP_SNAKEFILE = """
rule all:
    input: expand("out/{i}.txt", i=range(JOBS))

rule noop:
    output: "out/{i}.txt"
    benchmark: "bench/{i}.tsv"
    script: "noop.py"
"""


def noop_job_seconds(workdir: Path, jobs: int = 8) -> dict:
    """Benchmark ``s`` and the wall time per job of ``jobs`` no-op ``script:`` jobs on one core."""
    d = workdir / "noop"
    d.mkdir()
    (d / "Snakefile").write_text(f"JOBS = {jobs}\n" + NOOP_SNAKEFILE)
    (d / "noop.py").write_text('open(snakemake.output[0], "w").close()  # noqa: F821\n')
    t0 = time.perf_counter()
    proc = subprocess.run(snakemake_cmd(1, "all"), cwd=d, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"no-op workflow failed:\n{proc.stderr[-2000:]}")
    s = [float(p.read_text().splitlines()[1].split("\t")[0]) for p in sorted((d / "bench").glob("*.tsv"))]
    plan = timed(snakemake_cmd(1, "all", "-n", "--forceall"), d)["wall_s"]
    return {
        "jobs": jobs,
        "benchmark_s_per_job": round(sum(s) / len(s), 3),
        "wall_s": round(wall, 2),
        "wall_s_per_job_after_planning": round((wall - plan) / jobs, 3),
    }


def script_imports(script: Path) -> list[str]:
    """The import statements a workflow script runs, as source lines (also those in its function
    bodies: a script of a rule that runs several steps imports each step's modules in its
    function, and runs every function)."""
    tree = ast.parse(script.read_text())
    out: list[str] = []

    def visit(nodes):
        for node in nodes:
            if isinstance(node, ast.Import | ast.ImportFrom) and not (
                isinstance(node, ast.ImportFrom) and node.module == "__future__"
            ):
                out.append(ast.unparse(node))
            else:
                for field in ("body", "orelse", "finalbody", "handlers"):
                    visit(getattr(node, field, []) or [])

    visit(tree.body)
    return out


def rule_scripts(rules_dir: Path) -> dict[str, Path]:
    """Rule -> its ``script:`` file, from the .smk files."""
    out = {}
    for smk in sorted(rules_dir.glob("*.smk")):
        rule = None
        lines = smk.read_text().splitlines()
        for k, line in enumerate(lines):
            m = re.match(r"^(?:rule|checkpoint) (\w+):", line)
            if m:
                rule = m.group(1)
            elif rule and line.strip() == "script:" and k + 1 < len(lines):
                out[rule] = (smk.parent / lines[k + 1].strip().strip("\"'")).resolve()
    return out


PREAMBLE = "import pickle; from snakemake.logging import logger; from snakemake.iocontainers import Snakemake"


def best_of(code: str, cwd: Path, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], cwd=cwd, check=True, capture_output=True)
        times.append(time.perf_counter() - t0)
    return min(times)


def import_profile(scripts_dir: Path, scripts: dict[str, Path], repeat: int) -> dict:
    """Seconds of: a bare Python; + Snakemake's script preamble; + each rule script's imports."""
    path = f"import sys; sys.path.insert(0, {str(scripts_dir)!r}); "
    python = best_of("pass", scripts_dir, repeat)
    preamble = best_of(PREAMBLE, scripts_dir, repeat)
    per_rule = {}
    for rule, script in sorted(scripts.items()):
        code = path + PREAMBLE + "; " + "; ".join(script_imports(script))
        per_rule[rule] = round(best_of(code, scripts_dir, repeat), 3)
    return {"python_s": round(python, 3), "preamble_s": round(preamble, 3), "rule_imports_s": per_rule}


def importtime_top(scripts_dir: Path, script: Path, top: int = 10) -> list[tuple[str, float]]:
    """Packages by import time of ``script``'s imports: the ``self`` us of ``python -X importtime``
    summed over each top-level package's modules (s), largest first."""
    code = f"import sys; sys.path.insert(0, {str(scripts_dir)!r}); " + "; ".join(script_imports(script))
    proc = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", PREAMBLE + "; " + code],
        cwd=scripts_dir,
        capture_output=True,
        text=True,
    )
    per_pkg: dict[str, float] = {}
    for line in proc.stderr.splitlines():
        m = re.match(r"import time:\s+(\d+) \|\s+\d+ \| *(\S+)", line)
        if m:
            pkg = m.group(2).split(".")[0]
            per_pkg[pkg] = per_pkg.get(pkg, 0.0) + int(m.group(1)) / 1e6
    return sorted(((k, round(v, 3)) for k, v in per_pkg.items()), key=lambda kv: -kv[1])[:top]


def profile(size: dict, noop: dict, imports: dict) -> list[dict]:
    """Per rule, per machine: jobs, s per job, start-up per job, work per job (largest fleet)."""
    n = size["machines"]
    rows = []
    for rule, count in sorted(size["cold_jobs"].items()):
        if rule in ("all", "tables", "nightly"):  # targets, no job
            continue
        imp = imports["rule_imports_s"].get(rule)
        startup = noop["benchmark_s_per_job"] + (imp - imports["preamble_s"] if imp is not None else 0.0)
        mean = size["cold_job_s_mean"].get(rule)
        rows.append(
            {
                "rule": rule,
                "jobs_per_machine": round(count / n, 2),
                "s_per_job": mean,
                "startup_s_per_job": round(startup, 3),
                "work_s_per_job": round(mean - startup, 3) if mean is not None else None,
                "s_per_machine": round(mean * count / n, 2) if mean is not None else None,
                "startup_s_per_machine": round(startup * count / n, 2),
            }
        )
    return sorted(rows, key=lambda r: -(r["s_per_machine"] or r["startup_s_per_machine"]))


# --------------------------------------------------------------------------- fit and report


def linear_fit(xs: list[float], ys: list[float]) -> dict | None:
    """Least squares ``y = a + b x``; residuals; None with fewer than two distinct x."""
    if len(set(xs)) < 2:
        return None
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    b = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)
    a = my - b * mx
    return {
        "intercept_s": round(a, 2),
        "slope_s_per_machine": round(b, 2),
        "residuals_s": [round(y - (a + b * x), 2) for x, y in zip(xs, ys)],
    }


def predict(fit: dict | None, n: int) -> float | None:
    return None if fit is None else fit["intercept_s"] + fit["slope_s_per_machine"] * n


def markdown(report: dict) -> str:
    t = report["targets"]
    lines = [
        f"# Fleet benchmark ({report['date']})",
        "",
        f"Host: {report['host']}, {report['cpus']} CPUs, Python {report['python']}, "
        f"Snakemake {report['snakemake']}. Target `{report['target']}`, `--cores {report['cores']}`.",
        "",
        f"Command: `{report['command']}`",
        "",
        "| N | files | plan s | cold s | s per machine | cold core-s | load (1 min) | peak MB (tree) "
        "| peak MB (1 process) | night s | night core-s | night jobs | night peak MB |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in report["sizes"]:
        if s.get("extrapolated"):
            night = f"~{s['night_s']:.0f} (fit)" if s.get("night_s") is not None else "-"
            lines.append(
                f"| {s['machines']} | {s['files']} | - | ~{s['cold_s']:.0f} (fit) | - | - | - | - | - "
                f"| {night} | - | - | - |"
            )
            continue
        c, nt = s["cold"], s.get("night", {})
        lines.append(
            f"| {s['machines']} | {s['files']} | {s['plan_s']} | {c['wall_s']} | "
            f"{c['wall_s'] / s['machines']:.1f} | {c.get('cpu_s', '-')} | "
            f"{'-'.join(str(x) for x in c.get('load_1min', []))} | {c['peak_tree_mb']} | "
            f"{c['peak_process_mb']} | {nt.get('wall_s', '-')} | {nt.get('cpu_s', '-')} | "
            f"{nt.get('jobs', '-')} | {nt.get('peak_tree_mb', '-')} |"
        )
    for key, label in (("cold_fit", "cold run"), ("night_fit", "fleet night")):
        f = report.get(key)
        if f:
            lines.append("")
            lines.append(
                f"Linear fit, {label}: {f['intercept_s']} s + {f['slope_s_per_machine']} s per machine "
                f"(residuals {f['residuals_s']} s)."
            )
    lines += [
        "",
        f"Targets (issue 16): <= {t['s_per_machine']} s per additional machine, 50 cold < "
        f"{t['cold_50_s']} s, fleet night of 50 <= {t['night_50_s']} s.",
    ]
    prof = report.get("profile")
    if prof:
        imp = report["imports"]
        outside = report["noop"]["wall_s_per_job_after_planning"] - report["noop"]["benchmark_s_per_job"]
        lines += [
            "",
            f"## Where a machine's time goes (cold run, N = {report['profile_n']})",
            "",
            f"Start-up of a job: a no-op `script:` job {report['noop']['benchmark_s_per_job']} s "
            f"(benchmark s; bare Python {imp['python_s']} s, + Snakemake's preamble imports "
            f"{imp['preamble_s']} s); plus the rule script's own imports (below). "
            f"Snakemake's own wall per no-op job, outside the job: {outside:.2f} s.",
            "",
            "| rule | jobs per machine | s per job | start-up s per job | work s per job "
            "| s per machine | start-up s per machine |",
            "|---|---|---|---|---|---|---|",
        ]
        for r in prof:
            lines.append(
                f"| {r['rule']} | {r['jobs_per_machine']} | {r['s_per_job']} | {r['startup_s_per_job']} | "
                f"{r['work_s_per_job']} | {r['s_per_machine']} | {r['startup_s_per_machine']} |"
            )
        tot = sum(r["s_per_machine"] or 0 for r in prof)
        st = sum(r["startup_s_per_machine"] for r in prof)
        lines += [
            "",
            f"Sum per machine: {tot:.1f} s of job time, of which {st:.1f} s start-up "
            f"({100 * st / tot:.0f} %); on {report['cores']} cores at best "
            f"{tot / report['cores']:.1f} s of wall per machine.",
            "",
            f"Import time of `{report['importtime_script']}`'s imports by package (s, the self time "
            "of `python -X importtime` summed per package): "
            + ", ".join(f"{k} {v}" for k, v in report["importtime_top"]),
        ]
    nights = [s for s in report["sizes"] if s.get("night_jobs")]
    if nights:
        s = max(nights, key=lambda s: s["machines"])
        n = s["machines"]
        lines += [
            "",
            f"## Fleet night, N = {n}: jobs and job seconds per rule (per machine)",
            "",
            "| rule | jobs per machine | job s per machine |",
            "|---|---|---|",
        ]
        for rule, count in sorted(
            s["night_jobs"].items(), key=lambda kv: -s["night_job_seconds"].get(kv[0], 0)
        ):
            sec = s["night_job_seconds"].get(rule)
            lines.append(f"| {rule} | {count / n:.2f} | {'-' if sec is None else round(sec / n, 2)} |")
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- side by side with a commit


def code_tree(ref: str, workdir: Path) -> Path:
    """The workflow and package at ``ref``: the working tree for ``working``, else ``git archive``."""
    if ref == "working":
        return ROOT
    dest = workdir / f"code-{ref}"
    if not dest.is_dir():
        dest.mkdir(parents=True)
        archive = subprocess.run(["git", "archive", ref], cwd=ROOT, capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest


def shipped_project(dest: Path, code: Path, copies: int) -> Path:
    """The shipped raw/ (of the working tree, so every version reads the same data) plus ``copies``
    renamed copies of tapping-center-a, with ``code``'s Snakefile, workflow/, profiles/ and config."""
    dest.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__")
    shutil.copy2(code / "Snakefile", dest / "Snakefile")
    shutil.copytree(code / "workflow", dest / "workflow", ignore=ignore)
    if (code / "profiles").is_dir():
        shutil.copytree(code / "profiles", dest / "profiles", ignore=ignore)
    shutil.copy2(code / "config.yaml", dest / "config.yaml")
    shutil.copytree(ROOT / "raw", dest / "raw")
    for k in range(1, copies + 1):
        name = f"{TWIN_MACHINE}-copy{k}"
        shutil.copytree(ROOT / "raw" / TWIN_MACHINE, dest / "raw" / name)
        _rename_machine(sorted((dest / "raw" / name).glob("*.csv")), name)
    return dest


def marginal_side_by_side(refs: list[str], copies: int, repeats: int, workdir: Path, cores: int) -> dict:
    """Cold ``snakemake --cores`` of the shipped data and of the shipped data + ``copies`` copies of
    tapping-center-a, for every code version in ``refs``, interleaved (version after version, so
    the machine's load falls on all of them alike); the marginal cost of one more 12-file machine
    is (copies run - shipped run) / copies."""
    runs: list[dict] = []
    for rep in range(repeats):
        for ref in refs:
            code = code_tree(ref, workdir)
            env_path = "" if ref == "working" else str(code)
            for n_copies in (0, copies):
                proj = shipped_project(workdir / f"side-{ref}-{n_copies}-{rep}", code, n_copies)
                cmd = ["env", f"PYTHONPATH={env_path}", *snakemake_cmd(cores, "all")]
                result = timed(cmd, proj)
                if result["exit"] != 0:
                    sys.stderr.write(result["stderr"][-4000:])
                    raise SystemExit(f"{ref} with {n_copies} copies failed; project kept at {proj}")
                runs.append(
                    {"ref": ref, "copies": n_copies, "rep": rep}
                    | {k: v for k, v in result.items() if k not in ("stdout", "stderr")}
                )
                print(
                    f"  {ref:>10} +{n_copies} copies (rep {rep}): {result['wall_s']} s, "
                    f"{result['cpu_s']} core-s, load {result['load_1min']}",
                    flush=True,
                )
                shutil.rmtree(proj, ignore_errors=True)
    per_ref = {}
    for ref in refs:
        walls, cpus = [], []
        for rep in range(repeats):
            base = next(r for r in runs if r["ref"] == ref and r["rep"] == rep and r["copies"] == 0)
            more = next(r for r in runs if r["ref"] == ref and r["rep"] == rep and r["copies"] == copies)
            walls.append((more["wall_s"] - base["wall_s"]) / copies)
            cpus.append((more["cpu_s"] - base["cpu_s"]) / copies)
        per_ref[ref] = {"marginal_wall_s": sorted(walls), "marginal_core_s": sorted(cpus)}
    return {"copies": copies, "repeats": repeats, "runs": runs, "marginal": per_ref}


def big_night(n: int, new: int, cache: Path, workdir: Path, args) -> dict:
    """A fleet of ``n`` twin machines run cold, then a night where ``new`` of them have a new log
    and the others nothing new, timed (``rafi nightly --cores``)."""
    generate_fleet(cache, n, args.seed0, args.cores)
    proj = make_project(workdir / f"night-{n}", cache, n)
    cold = timed(snakemake_cmd(args.cores, "all"), proj)
    if cold["exit"] != 0:
        sys.stderr.write(cold["stderr"][-4000:])
        raise SystemExit(f"cold run of {n} machines failed; project kept at {proj}")
    print(f"  cold, {n} machines: {cold['wall_s']} s, {cold['cpu_s']} core-s, load {cold['load_1min']}")
    machines = sorted(p.name for p in (proj / "raw").iterdir() if p.is_dir())
    add_night_logs(proj / "raw", machines[:new], args.night_seed0, args.cores)
    cmd = [sys.executable, "-m", "rafi.cli", "nightly", "--directory", str(proj), "--cores", str(args.cores)]
    night = timed(cmd, proj)
    (proj / "bench-night.log").write_text(night["stdout"] + night["stderr"])
    if night["exit"] not in ACCEPTED_NIGHT_EXITS:
        sys.stderr.write(night["stdout"][-3000:] + night["stderr"][-3000:])
        raise SystemExit(f"rafi nightly exit {night['exit']}; project kept at {proj}")
    m = re.search(r"(\d+) job\(s\) in", night["stdout"])
    print(f"  night, {new} of {n} with a new log: {night['wall_s']} s, {night['cpu_s']} core-s")
    strip = ("stdout", "stderr")
    return {
        "machines": n,
        "with_new_log": new,
        "cold": {k: v for k, v in cold.items() if k not in strip},
        "night": {k: v for k, v in night.items() if k not in strip}
        | {"jobs": int(m.group(1)) if m else None},
        "project": str(proj) if args.keep else None,
    }


def side_markdown(report: dict) -> str:
    """The side-by-side table and the big night, as Markdown."""
    lines = [f"`{report['command']}` ({report['date']}, {report['cpus']} CPUs)", ""]
    side = report.get("side_by_side")
    if side:
        lines += [
            f"Marginal cost of one more 12-file machine, cold (shipped + {side['copies']} copies of "
            f"tapping-center-a minus shipped, / {side['copies']}), {side['repeats']} interleaved repeat(s):",
            "",
            "| code | wall s per machine (each repeat) | core-s per machine (each repeat) |",
            "|---|---|---|",
        ]
        for ref, m in side["marginal"].items():
            walls = ", ".join(f"{v:.1f}" for v in m["marginal_wall_s"])
            cpus = ", ".join(f"{v:.1f}" for v in m["marginal_core_s"])
            lines.append(f"| {ref} | {walls} | {cpus} |")
        refs = list(side["marginal"])
        if len(refs) == 2:
            new, old = (side["marginal"][r] for r in refs)
            med = lambda v: sorted(v)[len(v) // 2]  # noqa: E731
            lines += [
                "",
                f"Ratio {refs[0]} / {refs[1]} (medians): wall "
                f"{med(new['marginal_wall_s']) / med(old['marginal_wall_s']):.2f}, core-s "
                f"{med(new['marginal_core_s']) / med(old['marginal_core_s']):.2f}",
            ]
    night = report.get("big_night")
    if night:
        lines += [
            "",
            f"Fleet of {night['machines']}: cold {night['cold']['wall_s']} s ({night['cold']['cpu_s']} "
            f"core-s); night with {night['with_new_log']} new logs and "
            f"{night['machines'] - night['with_new_log']} machines with nothing new: "
            f"**{night['night']['wall_s']} s** ({night['night']['cpu_s']} core-s, {night['night']['jobs']} "
            f"jobs, exit {night['night']['exit']}, load {night['night']['load_1min']})",
        ]
    return "\n".join(lines) + "\n"


def main_side(args, argv) -> int:
    """``--side-by-side`` and ``--big-night``: the two measurements of issue 23."""
    workdir = args.keep or Path(tempfile.mkdtemp(prefix="rafi-bench-fleet-"))
    workdir.mkdir(parents=True, exist_ok=True)
    report = {
        "date": dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "cpus": os.cpu_count(),
        "command": " ".join(["python benchmarks/bench_fleet.py", *(sys.argv[1:] if argv is None else argv)]),
    }
    try:
        if args.side_by_side:
            # one commit: the working tree beside it; two or more: those, first against the rest
            refs = ["working", *args.side_by_side] if len(args.side_by_side) == 1 else args.side_by_side
            report["side_by_side"] = marginal_side_by_side(
                refs, args.copies, args.repeats, workdir, args.cores
            )
        if args.big_night:
            n, new = args.big_night
            cache = workdir / "twin-machines"
            cache.mkdir(exist_ok=True)
            report["big_night"] = big_night(n, new, cache, workdir, args)
    finally:
        if not args.keep:
            shutil.rmtree(workdir, ignore_errors=True)
    out = args.out.with_name(args.out.name + "-issue23")
    text = side_markdown(report)
    write_results(out.stem, report, text, out_dir=out.parent, final_newline=True)
    print(text)
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 10, 50], help="fleet sizes N")
    ap.add_argument("--target", default="all", choices=["all", "tables", "nightly"])
    ap.add_argument("--cores", type=int, default=2)
    ap.add_argument("--no-night", dest="night", action="store_false", help="skip the fleet night")
    ap.add_argument("--seed0", type=int, default=1000, help="seed of fleet-000 (machine i: seed0 + i)")
    ap.add_argument("--night-seed0", type=int, default=5000, help="seed of fleet-000's night log")
    ap.add_argument(
        "--budget-s",
        type=float,
        default=900.0,
        help="skip (and extrapolate) a size whose predicted cold + night time exceeds this",
    )
    ap.add_argument("--repeat", type=int, default=3, help="repeats of each import timing (best of)")
    ap.add_argument("--keep", type=Path, help="build the projects in this directory and keep them")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "fleet")
    ap.add_argument(
        "--side-by-side",
        nargs="+",
        metavar="COMMIT",
        help="marginal cost of one more machine, cold: the working tree beside one commit, or the "
        "first of several commits beside the others ('working' names the working tree)",
    )
    ap.add_argument("--copies", type=int, default=6, help="--side-by-side: copies of tapping-center-a")
    ap.add_argument("--repeats", type=int, default=1, help="--side-by-side: interleaved repeats")
    ap.add_argument(
        "--big-night",
        nargs=2,
        type=int,
        metavar=("N", "NEW"),
        help="N twin machines cold, then a night where NEW of them have a new log",
    )
    args = ap.parse_args(argv)
    if args.side_by_side or args.big_night:
        return main_side(args, argv)

    workdir = args.keep or Path(tempfile.mkdtemp(prefix="rafi-bench-fleet-"))
    workdir.mkdir(parents=True, exist_ok=True)
    cache = workdir / "twin-machines"
    cache.mkdir(exist_ok=True)
    sizes, measured = [], []
    try:
        for n in sorted(set(args.sizes)):
            cold_fit = linear_fit([s["machines"] for s in measured], [s["cold"]["wall_s"] for s in measured])
            night_fit = linear_fit(
                [s["machines"] for s in measured if "night" in s],
                [s["night"]["wall_s"] for s in measured if "night" in s],
            )
            guess = (predict(cold_fit, n) or 0.0) + (predict(night_fit, n) or 0.0)
            if cold_fit and guess > args.budget_s:
                print(
                    f"N={n}: predicted {guess:.0f} s > --budget-s {args.budget_s:.0f}: extrapolated",
                    flush=True,
                )
                sizes.append(
                    {
                        "machines": n,
                        "files": 12 * n,
                        "extrapolated": True,
                        "cold_s": round(predict(cold_fit, n), 1),
                        "night_s": round(predict(night_fit, n), 1) if night_fit else None,
                    }
                )
                continue
            t0 = time.perf_counter()
            generate_fleet(cache, n, args.seed0, args.cores)
            print(f"N={n}: twin machines ready ({time.perf_counter() - t0:.0f} s, not timed)", flush=True)
            result = run_size(n, cache, workdir, args)
            if not args.keep:
                shutil.rmtree(result["project"], ignore_errors=True)
                result["project"] = None
            measured.append(result)
            sizes.append(result)

        print("profiling job start-up ...", flush=True)
        scripts = rule_scripts(ROOT / "workflow" / "rules")
        scripts_dir = ROOT / "workflow" / "scripts"
        noop = noop_job_seconds(workdir)
        imports = import_profile(scripts_dir, scripts, args.repeat)
        biggest = max(measured, key=lambda s: s["machines"]) if measured else None
        top_rule = max(biggest["cold_jobs"], key=biggest["cold_jobs"].get) if biggest else "clean"
        top_script = scripts.get(top_rule, scripts_dir / "clean.py")
        import snakemake

        ys = [s["cold"]["wall_s"] for s in measured]
        ns = [s["machines"] for s in measured]
        report = {
            "date": dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
            "host": platform.node(),
            "cpus": os.cpu_count(),
            "python": platform.python_version(),
            "snakemake": snakemake.__version__,
            "target": args.target,
            "cores": args.cores,
            "command": " ".join(
                ["python benchmarks/bench_fleet.py", *(sys.argv[1:] if argv is None else argv)]
            ),
            "twin": (
                f"rafi simulate day --machine {TWIN_MACHINE} --seed <{args.seed0}+i> --validation-speeds "
                + ",".join(map(str, VALIDATION_SPEEDS))
                + " --multi (12 logs), folder fleet-<i>; night: --speeds 3000 --ambient-shift 2 "
                f"--seed <{args.night_seed0}+i>"
            ),
            "targets": {"s_per_machine": 4.0, "cold_50_s": 240.0, "night_50_s": 120.0},
            "sizes": sizes,
            "cold_fit": linear_fit(ns, ys),
            "night_fit": linear_fit(
                [s["machines"] for s in measured if "night" in s],
                [s["night"]["wall_s"] for s in measured if "night" in s],
            ),
            "noop": noop,
            "imports": imports,
            "importtime_script": str(top_script.relative_to(ROOT)),
            "importtime_top": importtime_top(scripts_dir, top_script),
            "profile_n": biggest["machines"] if biggest else None,
            "profile": profile(biggest, noop, imports) if biggest else [],
        }
    finally:
        if not args.keep:
            shutil.rmtree(workdir, ignore_errors=True)
    text = markdown(report)
    paths = write_results(args.out.stem, report, text, out_dir=args.out.parent, final_newline=True)
    print(text)
    print(f"wrote {paths[0]} and {paths[1]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
