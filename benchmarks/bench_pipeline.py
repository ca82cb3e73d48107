"""Wall time and peak memory of the whole pipeline (raw -> tables), shipped and 10x data.

Usage (from the repository root; see benchmarks/README.md)::

    python benchmarks/bench_pipeline.py                 # shipped + 10x, 2 cores
    python benchmarks/bench_pipeline.py --cases shipped --cores 2
    python benchmarks/bench_pipeline.py --scale 10 --target all   # include the report

Each case runs in a fresh temporary copy (Snakefile, workflow/, config.yaml, raw/):
``snakemake --cores N <target>`` under ``/usr/bin/time -v`` when available (peak RSS of
the largest single process: Snakemake itself or one job script), else with
``resource.getrusage(RUSAGE_CHILDREN)``. The per-rule ``benchmark:`` TSVs of the run are
summed per rule. Results go to ``benchmarks/results/pipeline.json`` and ``.md``.

The 10x data set: every raw file is replicated ``scale - 1`` times with its timestamps
shifted by whole weeks and a new ``run_id`` (text rewrite of the native CSV, so logger
defects are kept as they are); files in other formats (xlsx) are copied unchanged under
a new name. The pipeline's work grows linearly with the number of files.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / "benchmarks"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from _results import write_results  # noqa: E402

TIME_V = Path("/usr/bin/time")


def prepare(workdir: Path, raw_src: Path) -> None:
    """A runnable copy of the workflow in ``workdir`` reading raw data from ``raw_src``."""
    shutil.copy2(ROOT / "Snakefile", workdir / "Snakefile")
    shutil.copytree(ROOT / "workflow", workdir / "workflow", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy2(ROOT / "config.yaml", workdir / "config.yaml")
    shutil.copytree(raw_src, workdir / "raw")


def _shift_csv(text: str, shift: dt.timedelta, suffix: str) -> str:
    """Shift every data-row timestamp of a native CSV; append ``suffix`` to ``run_id``."""
    out, header_seen = [], False
    for line in text.splitlines(keepends=True):
        if not header_seen:
            if line.startswith("#"):
                m = re.match(r"^(#\s*run_id\s*:\s*)(.*?)(\s*)$", line)
                out.append(f"{m.group(1)}{m.group(2)}{suffix}\n" if m else line)
                continue
            header_seen = bool(line.strip())
            out.append(line)
            continue
        stamp, sep, rest = line.partition(",")
        try:
            new = dt.datetime.fromisoformat(stamp.strip()) + shift
            stamp = new.isoformat()
        except ValueError:
            pass  # leave a defect as it is
        out.append(stamp + sep + rest)
    return "".join(out)


def replicate(raw_src: Path, raw_dst: Path, scale: int) -> int:
    """Write ``scale`` copies of every raw file of ``raw_src`` to ``raw_dst``; return file count."""
    n = 0
    for machine in sorted(p for p in raw_src.iterdir() if p.is_dir()):
        dst = raw_dst / machine.name
        dst.mkdir(parents=True, exist_ok=True)
        for path in sorted(p for p in machine.iterdir() if p.is_file() and not p.name.startswith(".")):
            shutil.copy2(path, dst / path.name)
            n += 1
            text = path.read_text(encoding="utf-8-sig") if path.suffix == ".csv" else None
            for k in range(1, scale):
                name = f"{path.stem}_x{k:02d}{path.suffix}"
                if text is None:
                    shutil.copy2(path, dst / name)
                else:
                    (dst / name).write_text(
                        _shift_csv(text, dt.timedelta(weeks=k), f"_x{k:02d}"), encoding="utf-8"
                    )
                n += 1
    return n


def _parse_time_v(stderr: str) -> dict:
    out = {}
    m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", stderr)
    if m:
        out["peak_rss_mb"] = int(m.group(1)) / 1024
    m = re.search(r"Percent of CPU this job got: (\d+)%", stderr)
    if m:
        out["cpu_pct"] = int(m.group(1))
    return out


def rule_benchmarks(results: Path) -> dict:
    """Sum of wall seconds and max of peak RSS per rule from the ``benchmark:`` TSVs."""
    per_rule: dict[str, dict] = {}
    for tsv in sorted(results.glob("*/benchmarks/**/*.tsv")):
        rel = tsv.relative_to(results).parts
        rule = rel[2] if len(rel) > 3 else tsv.stem  # clean/<stem>.tsv -> clean
        lines = tsv.read_text().splitlines()
        if len(lines) < 2:
            continue
        row = dict(zip(lines[0].split("\t"), lines[1].split("\t")))
        entry = per_rule.setdefault(rule, {"jobs": 0, "wall_s": 0.0, "max_rss_mb": 0.0})
        entry["jobs"] += 1
        entry["wall_s"] += float(row.get("s", "nan"))
        try:
            entry["max_rss_mb"] = max(entry["max_rss_mb"], float(row.get("max_rss", "nan")))
        except ValueError:
            pass
    for entry in per_rule.values():
        entry["wall_s"] = round(entry["wall_s"], 2)
    return per_rule


def run_case(name: str, raw_src: Path, *, scale: int, cores: int, target: str, keep: bool) -> dict:
    workdir = Path(tempfile.mkdtemp(prefix=f"rafi-bench-{name}-"))
    try:
        if scale > 1:
            prepare_dir = workdir / "_raw"
            n_files = replicate(raw_src, prepare_dir, scale)
            prepare(workdir, prepare_dir)
            shutil.rmtree(prepare_dir)
        else:
            prepare(workdir, raw_src)
            n_files = sum(
                1 for p in (workdir / "raw").rglob("*") if p.is_file() and not p.name.startswith(".")
            )
        raw_mb = sum(p.stat().st_size for p in (workdir / "raw").rglob("*") if p.is_file()) / 2**20
        cmd = [sys.executable, "-m", "snakemake", "--cores", str(cores), target]
        use_time = TIME_V.exists()
        full = [str(TIME_V), "-v", *cmd] if use_time else cmd
        before = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
        t0 = time.perf_counter()
        proc = subprocess.run(full, cwd=workdir, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            sys.stderr.write(proc.stderr[-5000:])
            raise SystemExit(f"{name}: snakemake failed (exit {proc.returncode}); workdir kept at {workdir}")
        measured = _parse_time_v(proc.stderr) if use_time else {}
        if "peak_rss_mb" not in measured:
            after = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
            measured["peak_rss_mb"] = max(after, before) / 1024  # Linux: kB
        return {
            "case": name,
            "scale": scale,
            "files": n_files,
            "raw_mb": round(raw_mb, 1),
            "cores": cores,
            "target": target,
            "command": "snakemake " + " ".join(cmd[3:]),
            "wall_s": round(wall, 2),
            "peak_rss_mb": round(measured["peak_rss_mb"], 1),
            "cpu_pct": measured.get("cpu_pct"),
            "rules": rule_benchmarks(workdir / "results"),
            "workdir": str(workdir) if keep else None,
        }
    finally:
        if not keep:
            shutil.rmtree(workdir, ignore_errors=True)


def markdown(report: dict) -> str:
    lines = [
        f"# Pipeline benchmark ({report['date']})",
        "",
        f"Host: {report['host']}, {report['cpus']} CPUs, Python {report['python']}.",
        "",
        "| case | files | raw MB | command | wall s | peak RSS MB | CPU % |",
        "|---|---|---|---|---|---|---|",
    ]
    for c in report["cases"]:
        lines.append(
            f"| {c['case']} | {c['files']} | {c['raw_mb']} | `{c['command']}` | "
            f"{c['wall_s']} | {c['peak_rss_mb']} | {c['cpu_pct']} |"
        )
    for c in report["cases"]:
        lines += [
            "",
            f"## {c['case']}: per rule (sum of job wall time, max job RSS)",
            "",
            "| rule | jobs | wall s | max RSS MB |",
            "|---|---|---|---|",
        ]
        for rule, e in sorted(c["rules"].items(), key=lambda kv: -kv[1]["wall_s"]):
            lines.append(f"| {rule} | {e['jobs']} | {e['wall_s']} | {e['max_rss_mb']} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--raw", type=Path, default=ROOT / "raw", help="shipped raw data")
    parser.add_argument("--cases", nargs="+", default=["shipped", "scaled"], choices=["shipped", "scaled"])
    parser.add_argument("--scale", type=int, default=10, help="size factor of the scaled case")
    parser.add_argument("--cores", type=int, default=2)
    parser.add_argument(
        "--target", default="tables", help="snakemake target: tables (raw -> tables) or all (+ reports)"
    )
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "pipeline")
    parser.add_argument("--keep", action="store_true", help="keep the temporary work dirs")
    args = parser.parse_args(argv)
    if not any(p.is_dir() for p in args.raw.iterdir()):
        raise SystemExit(f"no machine folders under {args.raw}; generate the shipped data first")

    cases = []
    for case in args.cases:
        scale = 1 if case == "shipped" else args.scale
        print(f"running {case} (x{scale}) ...", flush=True)
        result = run_case(case, args.raw, scale=scale, cores=args.cores, target=args.target, keep=args.keep)
        print(
            f"  {result['files']} files, {result['raw_mb']} MB: {result['wall_s']} s, "
            f"peak RSS {result['peak_rss_mb']} MB",
            flush=True,
        )
        cases.append(result)
    report = {
        "date": dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "host": platform.node(),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "cases": cases,
    }
    paths = write_results(
        args.out.stem, report, markdown(report), out_dir=args.out.parent, final_newline=True
    )
    print(f"wrote {paths[0]} and {paths[1]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
