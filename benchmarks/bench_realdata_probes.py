"""FL_THERMAL as one machine with five probes, configured from ``rafi init``'s proposal as written.

Usage (from the repository root; see benchmarks/README.md)::

    python benchmarks/bench_realdata_probes.py                 # one project, one snakemake run
    python benchmarks/bench_realdata_probes.py --keep /tmp/fl  # keep the project

A temporary project holds a copy of ``Snakefile``, ``workflow/`` and ``rafi/``, the workbook under
``raw/fl-thermal/`` and the config block ``rafi init --machine fl-thermal`` proposes for it, taken
as written (no edit: its chronological split, ``reference: log_start``, ``runs.min_constant_s``
and ``input.probes`` ch1..ch5). One ``snakemake --cores N`` run builds every probe's model, its
registry and report, and the machine's report of the five probes. Each probe is scored as
``bench_realdata.py`` scores its one-channel machine (:func:`bench_realdata.project_scores`: the
test MAE over the published split's test rows, read once to report). Output: a table ``probe |
offered (kind) | test MAE | every kind``, the wall time of the run, and
``benchmarks/results/realdata_probes.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _results import write_results  # noqa: E402
from bench_realdata import default_data, project_scores, read_workbook  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MACHINE = "fl-thermal"


def write_project(proj: Path, data: Path) -> dict:
    """The project in ``proj`` with ``rafi init``'s proposal as its config; returns the block."""
    proj.mkdir(parents=True, exist_ok=True)
    shutil.copy2(ROOT / "Snakefile", proj / "Snakefile")
    for name in ("workflow", "rafi"):
        shutil.copytree(ROOT / name, proj / name, ignore=shutil.ignore_patterns("__pycache__"))
    raw = proj / "raw" / MACHINE
    raw.mkdir(parents=True)
    shutil.copy2(data, raw / "data.xlsx")
    env = {"PYTHONPATH": str(proj)}
    done = subprocess.run(
        [sys.executable, "-m", "rafi.cli", "init", "--machine", MACHINE, str(raw / "data.xlsx")],
        capture_output=True, text=True, cwd=proj, env={**os.environ, **env}, check=True,
    )  # fmt: skip
    block = yaml.safe_load(done.stdout)
    (proj / "config.yaml").write_text(
        yaml.safe_dump(block, allow_unicode=True, sort_keys=False), encoding="utf-8"
    )
    return block["machines"][MACHINE]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=None, help="FL_THERMAL data.xlsx")
    parser.add_argument("--cores", type=int, default=2, help="passed to snakemake --cores")
    parser.add_argument("--keep", type=Path, default=None, help="keep the project in this folder")
    args = parser.parse_args(argv)
    data = args.data or default_data()
    if not data.is_file():
        parser.error(f"no workbook at {data} (--data PATH: FL_THERMAL's data/data.xlsx)")
    proj = args.keep or Path(tempfile.mkdtemp(prefix="rafi-realdata-probes-"))
    if args.keep is not None:
        shutil.rmtree(proj, ignore_errors=True)
    try:
        entry = write_project(proj, data)
        probes = list(entry["input"]["probes"])
        start = time.perf_counter()
        done = subprocess.run(
            [sys.executable, "-m", "snakemake", "--cores", str(args.cores)],
            capture_output=True, text=True, cwd=proj, env={**os.environ, "PYTHONPATH": str(proj)},
        )  # fmt: skip
        wall = time.perf_counter() - start
        if done.returncode != 0:
            print(done.stderr[-3000:], file=sys.stderr)
            return 1
        frame = read_workbook(data)
        rows = []
        for probe in probes:
            channel = entry["input"]["probes"][probe]["column"].split("(")[0]
            unit = f"{MACHINE}@{probe}"
            score = project_scores(proj, unit, frame, channel)
            summary = pd.read_csv(proj / "results" / unit / "comparison" / "summary.csv")
            offered = str(summary[summary["champion"].astype(bool)]["model"].iloc[0])
            rows.append({"probe": probe, "offered": offered, "mae": score["mae"]})
        lines = ["| probe | offered (kind) | test MAE, um | every kind |", "|---|---|---|---|"]
        for r in rows:
            every = ", ".join(f"{k} {v:.2f}" for k, v in r["mae"].items())
            lines.append(f"| {r['probe']} | `{r['offered']}` | {r['mae'][r['offered']]:.2f} | {every} |")
        text = "\n".join(
            [f"FL_THERMAL, one machine with {len(probes)} probes, rafi init's proposal as written; "
             f"one `snakemake --cores {args.cores}` run, {wall:.0f} s wall", "", *lines]
        )  # fmt: skip
        print(text)
        report = {"date": dt.date.today().isoformat(), "wall_s": round(wall, 1), "rows": rows, "entry": entry}
        write_results("realdata_probes", report, text, ensure_ascii=False)
        return 0
    finally:
        if args.keep is None:
            shutil.rmtree(proj, ignore_errors=True)


if __name__ == "__main__":
    raise SystemExit(main())
