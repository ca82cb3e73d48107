"""Time `rafi nightly` on a trimmed copy of the shipped data.

    python benchmarks/bench_nightly.py [--keep DIR] [--all-files] [--no-report] [--full-check]
                                         [--synthetic]

Sets up a project copy in a temporary directory (Snakefile, workflow/, config.yaml and a
subset of raw/tapping-center-a), runs a first night (full pipeline, timed for information),
then times:

* a night with nothing new        (target < 5 s)
* a night with one new log        (target < 20 s; the log comes from `rafi simulate day`,
                                   else a renamed copy of a validation log), and how long
                                   the process stays alive after its last line (idle at exit)

and prints the figures. Exit status 0 when both targets are met, 1 otherwise.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MACHINE = "tapping-center-a"
TARGET_NEW_S = 20.0
TARGET_NOTHING_S = 5.0


def setup(dest: Path, all_files: bool) -> Path:
    proj = dest / "proj"
    proj.mkdir(parents=True)
    shutil.copytree(ROOT / "workflow", proj / "workflow")
    shutil.copy(ROOT / "config.yaml", proj / "config.yaml")
    # the night reads a log the moment it is written: the benchmark times the pipeline, not the
    # settle time that makes a real night wait for a log still being written (nightly_settle_s)
    with open(proj / "config.yaml", "a", encoding="utf-8") as fh:
        fh.write("\nnightly_settle_s: 0\n")
    snakefile = (ROOT / "Snakefile").read_text()
    if "registry.smk" not in snakefile and '"*.smk"' not in snakefile:
        snakefile += '\n\ninclude: "workflow/rules/registry.smk"\n'
    (proj / "Snakefile").write_text(snakefile)
    raw = proj / "raw" / MACHINE
    raw.mkdir(parents=True)
    if SYNTH:
        synthetic_logs(raw, SYNTHETIC)
        return proj
    files = sorted((ROOT / "raw" / MACHINE).glob("*.csv"))
    keep = (
        files
        if all_files
        else [
            f
            for f in files
            if re.search(r"(train|trn).*(3000|9000|15000)|valid.*(4500|13500)|multi", f.name, re.I)
        ]
        or files
    )
    for f in keep:
        shutil.copy2(f, raw / f.name)
    return proj


EXTRA: list[str] = []
SYNTH = False


def synthetic_logs(raw: Path, names_days, seed0: int = 0) -> None:
    """Write defect-free synthetic logs (rafi/twin/synthetic_logs.py) instead of the shipped data."""
    sys.path.insert(0, str(ROOT / "tests"))
    import pandas as pd

    from rafi.readers.native import write_raw_log
    from rafi.twin.synthetic_logs import canonical_log

    for i, (name, speed, n, day) in enumerate(names_days):
        log, _ = canonical_log(
            n,
            steps=((0.0, speed),),
            seed=seed0 + i,
            extras=False,
            start=pd.Timestamp("2026-03-02T08:00:00") + pd.Timedelta(days=day),
        )
        write_raw_log(log, raw / f"{name}.csv", metadata={"machine": MACHINE})


SYNTHETIC = [
    ("train-3000", 3000, 2880, 0),
    ("train-9000", 9000, 2880, 1),
    ("train-15000", 15000, 2880, 2),
    ("valid-4500", 4500, 1440, 3),
    ("valid-13500", 13500, 1440, 4),
]


def nightly(proj: Path) -> tuple[float, int, str, float]:
    """``(seconds, exit code, output, idle seconds at exit)``.

    The idle time is from the last line `rafi nightly` prints (its summary) to the end of the
    process: Snakemake's scheduler timer, when a job rate limit is set, kept the interpreter
    alive for up to a second there (rafi.ops.snakemake_api sets none).
    """
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "rafi.cli", "nightly", "--directory", str(proj), "--cores", "2", *EXTRA],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines, last = [], t0
    for line in proc.stdout:
        lines.append(line)
        last = time.perf_counter()
    code = proc.wait()
    end = time.perf_counter()
    return end - t0, code, "".join(lines), end - last


def add_one_log(proj: Path) -> str:
    if SYNTH:
        synthetic_logs(proj / "raw" / MACHINE, [("day2-valid-10500", 10500, 1440, 9)], seed0=50)
        return "synthetic validation log"
    before = set((proj / "raw" / MACHINE).glob("*.csv"))
    sim = subprocess.run(
        [
            sys.executable,
            "-m",
            "rafi.cli",
            "simulate",
            "day",
            "--machine",
            MACHINE,
            "--out",
            str(proj / "raw"),
            "--seed",
            "11",
            "--ambient-shift",
            "2",
        ],
        capture_output=True,
        text=True,
        cwd=proj,
    )
    new = set((proj / "raw" / MACHINE).glob("*.csv")) - before
    if sim.returncode == 0 and new:
        # keep exactly one new log so the figure means "one new log"
        for extra in sorted(new)[1:]:
            extra.unlink()
        return f"rafi simulate day -> {sorted(new)[0].name}"
    src = next(p for p in sorted(before) if re.search("valid", p.name, re.I))
    dst = src.with_name(src.stem + "-bench-copy.csv")
    shutil.copy2(src, dst)
    return f"copy of {src.name}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--keep", help="build the project copy in this directory and keep it")
    ap.add_argument("--all-files", action="store_true", help="use every shipped log, not a subset")
    ap.add_argument("--no-report", action="store_true", help="time the nights without the report")
    ap.add_argument(
        "--full-check", action="store_true", help="no fingerprint fast path: always ask Snakemake (dry run)"
    )
    ap.add_argument(
        "--synthetic",
        action="store_true",
        help="use synthetic logs (rafi/twin/synthetic_logs.py) instead of the shipped data",
    )
    args = ap.parse_args(argv)
    global SYNTH
    SYNTH = args.synthetic
    EXTRA[:] = (["--no-report"] if args.no_report else []) + (["--full-check"] if args.full_check else [])
    if not SYNTH and not any((ROOT / "raw" / MACHINE).glob("*.csv")):
        print(f"no shipped data in raw/{MACHINE}: run `rafi simulate shipped --out raw` first")
        return 2
    tmp = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="rafi-bench-"))
    try:
        proj = setup(tmp, args.all_files)
        n_files = len(list((proj / "raw" / MACHINE).glob("*.csv")))
        t_first, rc, out, _ = nightly(proj)
        print(f"first night ({n_files} logs, full pipeline): {t_first:6.1f} s  exit {rc}")
        if rc not in (0, 2, 3, 4):
            print(out)
            return 1
        t_none, rc_none, out_none, _ = nightly(proj)
        ok_none = t_none < TARGET_NOTHING_S and "nothing new" in out_none
        print(
            f"nothing new:                          {t_none:6.1f} s  exit {rc_none}  "
            f"(target < {TARGET_NOTHING_S:.0f} s: {'ok' if ok_none else 'MISSED'})"
        )
        what = add_one_log(proj)
        t_new, rc_new, out_new, idle = nightly(proj)
        jobs = re.findall(r"done (\w+)", out_new)
        ok_new = t_new < TARGET_NEW_S
        print(
            f"one new log ({what}): {t_new:6.1f} s  exit {rc_new}  {len(jobs)} jobs "
            f"[{', '.join(jobs)}]  (target < {TARGET_NEW_S:.0f} s: {'ok' if ok_new else 'MISSED'})"
        )
        print(f"idle at exit (last line printed -> process gone): {idle:.2f} s")
        return 0 if ok_none and ok_new else 1
    finally:
        if not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
