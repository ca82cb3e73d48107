"""The interval's level correction: unit by unit or run by run? Judged one level up on the
training runs' out-of-fold (OOF) residuals (issue 26).

Usage (from the repository root; see benchmarks/README.md)::

    python benchmarks/bench_interval_groups.py --project /tmp/rd/ch1-windows ... --project /tmp/twins

Each ``--project`` is a Snakemake project that has run ``rule compare`` (the folders
``bench_realdata.py --keep DIR`` leaves, or a copy of this project after ``snakemake --cores 2``).
Every machine under ``results/`` is judged.

**The question.** The shipped interval (:func:`rafi.family.intervals.calibrate`) finds its
finite-sample correction by leaving out one calibration *unit* at a time. On a continuous log a
training run is held out by the whole-run folds and by up to ``cv_forward_runs`` forward folds,
so it is up to three units: leaving out one of them keeps the run's other units in the quantile,
which then has "seen" the run it is asked to cover. ``by_run`` leaves out every unit of the run
(:func:`rafi.family.forward_folds.unit_run`).

**The judge, on training runs only.** Each training run ``r`` is held out in turn with all its
units: the offered model's interval is calibrated (the real :func:`calibrate`, the machine's
settings) on the OOF samples of the other runs, once per variant, and its coverage is measured on
``r``'s OOF samples (each of ``r``'s units weighing the same). Per data set: the mean coverage
over held-out runs, the lowest, the median width. Validation and test rows are never read. The
pipeline's calibration on every OOF sample (by unit or by run, as the artefact records) is
checked against the half-widths of ``comparison/best_model.json`` first.

Output: ``benchmarks/results/interval_groups.json`` and ``interval_groups.md``.
"""

from __future__ import annotations

import datetime as dt
import json
import platform
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / "benchmarks"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from _results import write_results  # noqa: E402
from bench_intervals import machines_of, newest_oof, projects_of  # noqa: E402

from rafi.family.forward_folds import is_forward, unit_run  # noqa: E402
from rafi.family.interval_fit import interval_options, whole_run_units  # noqa: E402
from rafi.family.intervals import _cell_of, calibrate  # noqa: E402
from rafi.settings import machine_settings  # noqa: E402

#: Variant name -> ``by_run`` of :func:`calibrate`.
VARIANTS = {"by_unit": False, "by_run": True}


def offered_oof(results: Path) -> tuple[pd.DataFrame, dict]:
    """The offered model's finite OOF samples its interval calibrated on (the forward units only
    when its calibration scheme names forward folds) and its artefact
    (``comparison/best_model.json``)."""
    best = json.loads((results / "comparison" / "best_model.json").read_text(encoding="utf-8"))
    oof = pd.read_parquet(newest_oof(results))
    if not any(map(is_forward, str(best["interval"]["calibration"]["scheme"]).split("+"))):
        oof = whole_run_units(oof)
    oof = oof.loc[oof["model"].astype(str) == str(best["kind"])]
    oof = oof.loc[np.isfinite(oof["residual_um"].to_numpy(dtype=float))].reset_index(drop=True)
    return oof, best


def coverage_of(block: dict, held: pd.DataFrame) -> tuple[float, np.ndarray]:
    """Mean over ``held``'s units of the fraction of samples inside ``block``'s interval, and the
    half-widths of its samples."""
    half = block["half_width_um"]
    h = np.array([half[c] for c in _cell_of(held, block["transient_s"])])
    inside = pd.Series(np.abs(held["residual_um"].to_numpy(dtype=float)) <= h)
    return float(inside.groupby(held["unit"].astype(str).to_numpy()).mean().mean()), h


def judge_machine(results: Path, options: dict) -> dict:
    """Outer leave-one-run-out of every variant on one machine (module docstring)."""
    oof, best = offered_oof(results)
    kw = {**options, "tolerance_rpm": float(best["interval"]["tolerance_rpm"])}
    scheme = str(best["interval"]["calibration"]["scheme"])
    stored_by_run = best["interval"]["calibration"].get("left_out") == "run"
    shipped = calibrate(oof, scheme=scheme, by_run=stored_by_run, **kw)["half_width_um"]
    stored = best["interval"]["half_width_um"]
    if not all(np.isclose(shipped[c], stored[c], rtol=1e-9, atol=1e-12) for c in stored):
        raise SystemExit(f"{results}: recalibration {shipped} != best_model.json's interval")
    runs = unit_run(oof["unit"])
    out = {"kind": str(best["kind"]), "units": int(oof["unit"].nunique()), "runs": int(len(set(runs)))}
    for name, by_run in VARIANTS.items():
        per_run, widths = {}, []
        for r in sorted(set(runs)):
            mine = runs == r
            block = calibrate(oof.loc[~mine], scheme=scheme, by_run=by_run, **kw)
            per_run[r], h = coverage_of(block, oof.loc[mine])
            widths.append(2 * h)
        cov = np.array(list(per_run.values()))
        out[name] = {
            "coverage": float(cov.mean()),
            "min_run_coverage": float(cov.min()),
            "median_width_um": float(np.median(np.concatenate(widths))),
            "per_run": per_run,
        }
    return out


def markdown(table: dict) -> list[str]:
    """Per data set and variant: mean coverage % (lowest run) / median width um; the criterion."""
    head = ["data set", "offered", "units / runs", *VARIANTS]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, t in table.items():
        cells = [
            f"{100 * t[v]['coverage']:.1f} % ({100 * t[v]['min_run_coverage']:.0f})"
            f" / {t[v]['median_width_um']:.2f}"
            for v in VARIANTS
        ]
        lines.append(f"| {name} | {t['kind']} | {t['units']} / {t['runs']} | " + " | ".join(cells) + " |")
    dev = {v: np.mean([abs(100 * t[v]["coverage"] - 90) for t in table.values()]) for v in VARIANTS}
    lines += ["", "Mean |coverage - 90| over data sets: " + ", ".join(f"{v} {d:.2f}" for v, d in dev.items())]
    return lines


def main(argv: list[str] | None = None) -> int:
    table: dict[str, dict] = {}
    for project in projects_of(argv, __doc__):
        config = yaml.safe_load((project / "config.yaml").read_text(encoding="utf-8"))
        for results in machines_of(project):
            options = interval_options(machine_settings(config, results.name)["models"])
            print(f"{results.name} ...", file=sys.stderr)
            table[results.name] = judge_machine(results, options)
    lines = markdown(table)
    print("\n".join(lines))
    meta = {"date": dt.date.today().isoformat(), "python": platform.python_version()}
    write_results("interval_groups", {"meta": meta, "data": table}, "\n".join(lines) + "\n", indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
