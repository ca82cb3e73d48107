"""The whole interval pipeline judged one level up, with refits (issue 26).

Usage (from the repository root; see benchmarks/README.md)::

    python benchmarks/bench_interval_refit.py --project /tmp/rd/ch1-windows ... --project /tmp/twins

Each ``--project`` is a Snakemake project that has run (as for ``bench_selection_rules.py``: the
folders ``bench_realdata.py --keep DIR`` leaves, or a copy of this project after ``snakemake
--cores 2``). Every machine under ``results/`` is judged (``--machines`` to pick some).

**Why refits.** ``bench_interval_groups.py`` scores a calibration on the held-out run's own
out-of-fold (OOF) residuals: models fitted on the *other calibration folds'* runs, as bad as the
residuals it calibrates on. The offered interval is put around the *final* model, fitted on every
training run; when more runs make a better model (a learning curve that has not flattened), an
interval calibrated on fold models is too wide for it, and that judge cannot see it. Here the
whole pipeline runs one level down:

* outer folds: each training run ``r`` is held out in turn;
* on the other training runs, every enabled kind's inner whole-run and forward CV (the same fits
  as the pipeline's ``rule compare``, :func:`bench_selection_rules.inner_fold`) gives the inner CV
  rows, from which the current rule picks a kind, and that kind's inner OOF samples, from which
  each variant calibrates an interval (:func:`rafi.family.intervals.calibrate`, the machine's
  settings);
* the interval is put around the kind's model fitted on *all* the other training runs, on ``r``:
  its residuals there are the OOF samples of ``r`` in the full whole-run CV (the pipeline's own
  fits, checked against ``comparison/cv.csv``), with their cells (change clock, out of range).

Validation and test rows are never read. The coverage of a data set is the mean over its outer
folds of the fraction of ``r``'s samples inside the interval, for the picked kind (what the
pipeline would offer) and, as a larger sample of the calibration alone, for every kind.

The variants (:data:`VARIANTS`):

* ``every_unit`` (shipped until 2026-11-26, ``models: interval_forward_units: true``): every
  inner OOF unit (whole-run and forward), the correction leaving out a run with all its units;
* ``whole_run`` (the default since 2026-11-26): the whole-run units only (forward units are
  fitted on fewer runs; :func:`rafi.family.interval_fit.whole_run_units`);
* ``learning_curve``: every unit, each unit's residuals scaled to what a model fitted on all the
  calibration's training runs would show (:func:`learning_curve_factors`).

Output: ``benchmarks/results/interval_refit.json`` and ``interval_refit.md``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import platform
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / "benchmarks"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from _results import write_results  # noqa: E402
from bench_interval_groups import coverage_of  # noqa: E402
from bench_selection_rules import (  # noqa: E402
    OUTER,
    RULES,
    STACK_SCHEMES,
    check_rows,
    inner_fold,
    machine_inputs,
    rows_of,
)

from rafi.family import crossval  # noqa: E402
from rafi.family.forward_folds import fold_unit, is_forward  # noqa: E402
from rafi.family.interval_fit import interval_options, whole_run_units  # noqa: E402
from rafi.family.intervals import calibrate  # noqa: E402
from rafi.settings import machine_settings  # noqa: E402

#: The rule the pipeline chooses by (``bench_selection_rules.RULES``).
CURRENT_RULE = "mean_max_forward"
VARIANTS = ("every_unit", "whole_run", "learning_curve")
WHOLE = "leave_one_run_out"


def unit_train_runs(rows: dict) -> dict[str, int]:
    """OOF unit name -> the number of training runs of the fold that held it out, from the CV rows
    of each scheme (a forward unit is ``f<fold>:<run>``, :func:`rafi.family.forward_folds.fold_unit`)."""
    out = {}
    for scheme, cv in rows.items():
        for fold, run, m in zip(cv["fold"], cv["test_runs"].astype(str), cv["n_train_runs"]):
            out[fold_unit(fold, run) if is_forward(scheme) else run] = int(m)
    return out


def learning_curve_factors(oof: pd.DataFrame, train_runs: dict, n_final: int) -> np.ndarray:
    """Per OOF sample, the factor that scales its unit's residuals to a model fitted on
    ``n_final`` runs.

    The unit's mean squared residual is modelled as ``a + b / m`` (``m``: the training runs of the
    fold that held the unit out): ``a`` what no more data removes, ``b / m`` the estimation error
    (the classic prediction variance of a least-squares fit). ``a`` and ``b`` by least squares over
    the units (each weighing the same), ``a`` at least 0; the factor is
    ``sqrt((a + b / n_final) / (a + b / m))``. With one distinct ``m`` or ``b <= 0``: 1 (no
    learning curve is seen, nothing is scaled).
    """
    units = oof["unit"].astype(str).to_numpy()
    res = oof["residual_um"].to_numpy(dtype=float)
    names, code = np.unique(units, return_inverse=True)
    m = np.array([train_runs[u] for u in names], dtype=float)
    ms = np.bincount(code, weights=res**2) / np.bincount(code)
    if len(np.unique(m)) < 2:
        return np.ones(len(res))
    b, a = np.polyfit(1.0 / m, ms, 1)
    if b <= 0:
        return np.ones(len(res))
    if a < 0:
        a, b = 0.0, float(np.sum(ms / m) / np.sum(1.0 / m**2))
    factor = np.sqrt((a + b / n_final) / (a + b / m))
    return factor[code]


def variant_oof(variant: str, oof: pd.DataFrame, train_runs: dict, n_final: int) -> pd.DataFrame:
    """The OOF samples a variant calibrates on (module docstring)."""
    if variant == "whole_run":
        return whole_run_units(oof)
    if variant == "learning_curve":
        scaled = oof["residual_um"].to_numpy(dtype=float) * learning_curve_factors(oof, train_runs, n_final)
        return oof.assign(residual_um=scaled)
    return oof


def coverage(block: dict | None, held: pd.DataFrame) -> tuple[float, float]:
    """Fraction of ``held``'s samples (one held-out run's OOF samples) inside ``block``'s interval
    and the median width (NaN, NaN without a block)."""
    if block is None or not len(held):
        return np.nan, np.nan
    share, h = coverage_of(block, held)  # held is one run: the mean over its units is its share
    return share, float(np.median(2 * h))


def judge_machine(project: Path, machine: str, log=print) -> dict:
    """Every variant's coverage one level up on one machine (module docstring)."""
    config = yaml.safe_load((project / "config.yaml").read_text(encoding="utf-8"))
    settings = machine_settings(config, machine)
    options = interval_options(settings["models"])
    tolerance = float(settings["speed_tolerance_rpm"])
    inputs = machine_inputs(project, machine)
    table, frame, kinds = inputs["table"], inputs["frame"], list(inputs["factories"])
    t0 = time.perf_counter()
    full, full_oofs = inner_fold(inputs["factories"], table, frame, STACK_SCHEMES)
    pipeline_cv = inputs["cv"]
    for scheme in STACK_SCHEMES:
        rows = pipeline_cv.loc[pipeline_cv["scheme"].astype(str) == scheme]
        if len(rows) or len(full[scheme]):
            check_rows(machine, full[scheme], rows)
    outer = full_oofs[WHOLE]
    outer = outer.loc[np.isfinite(outer["residual_um"].to_numpy(dtype=float))]
    scheme_rule, rule = RULES[CURRENT_RULE]
    folds = []
    for _, (held,) in crossval.leave_one_run_out(table):
        inner_table = crossval.hold_out(table, [held], OUTER)
        rows, oofs = inner_fold(inputs["factories"], inner_table, frame, STACK_SCHEMES)
        pick = rule(rows_of(rows, scheme_rule))
        train_runs = unit_train_runs(rows)
        n_final = len(crossval.training_runs(inner_table, frame)[0])
        inner = pd.concat([o for o in oofs.values() if len(o)], ignore_index=True)
        inner = inner.loc[np.isfinite(inner["residual_um"].to_numpy(dtype=float))]
        fold = {"held_out": held, "pick": pick, "n_inner_runs": n_final, "kinds": {}}
        for kind in kinds:
            mine = inner.loc[inner["model"].astype(str) == kind]
            held_res = outer.loc[(outer["model"].astype(str) == kind) & (outer["unit"].astype(str) == held)]
            out = {}
            for v in VARIANTS:
                data = variant_oof(v, mine, train_runs, n_final)
                block = (
                    calibrate(data, tolerance_rpm=tolerance, scheme="inner", **options) if len(data) else None
                )
                out[v] = dict(zip(("coverage", "width_um"), coverage(block, held_res)))
            fold["kinds"][kind] = out
        folds.append(fold)
        picked = fold["kinds"].get(pick, {})
        log(
            f"  {machine} outer {held}: pick {pick}; "
            + ", ".join(f"{v} {100 * picked.get(v, {}).get('coverage', np.nan):.1f} %" for v in VARIANTS)
        )
    return {"machine": machine, "seconds": round(time.perf_counter() - t0, 1), "folds": folds}


def summarise(result: dict) -> dict:
    """Per variant: mean coverage and median width over the outer folds, of the pick and of every
    kind (kinds without an interval in a fold are left out of that fold)."""
    out = {}
    for v in VARIANTS:
        pick = [f["kinds"][f["pick"]][v] for f in result["folds"] if f["pick"] in f["kinds"]]
        every = [k[v] for f in result["folds"] for k in f["kinds"].values()]
        cov = [p["coverage"] for p in pick if np.isfinite(p["coverage"])]
        out[v] = {
            "pick_coverage": float(np.mean(cov)) if cov else np.nan,
            "pick_min_coverage": float(np.min(cov)) if cov else np.nan,
            "pick_width_um": float(np.nanmedian([p["width_um"] for p in pick])) if pick else np.nan,
            "all_kinds_coverage": float(np.nanmean([k["coverage"] for k in every])) if every else np.nan,
        }
    return out


def markdown(table: dict) -> str:
    """Per data set and variant: the pick's mean coverage % (lowest fold) / median width um, and
    every kind's mean coverage; the mean |coverage - 90| over data sets."""
    head = ["data set", *(f"{v} pick" for v in VARIANTS), *(f"{v} all kinds" for v in VARIANTS)]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for name, s in table.items():
        picks = [
            f"{100 * s[v]['pick_coverage']:.1f} % ({100 * s[v]['pick_min_coverage']:.0f}) / "
            f"{s[v]['pick_width_um']:.2f}"
            for v in VARIANTS
        ]
        every = [f"{100 * s[v]['all_kinds_coverage']:.1f} %" for v in VARIANTS]
        lines.append(f"| {name} | " + " | ".join(picks + every) + " |")
    for what in ("pick_coverage", "all_kinds_coverage"):
        dev = {v: np.mean([abs(100 * s[v][what] - 90) for s in table.values()]) for v in VARIANTS}
        lines.append("")
        said = ", ".join(f"{v} {d:.2f}" for v, d in dev.items())
        lines.append(f"Mean |{what} - 90| over data sets: {said}")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--project", type=Path, action="append", required=True)
    parser.add_argument("--machines", default="", help="comma-separated machine names (default: all)")
    args = parser.parse_args(argv)
    wanted = {m.strip() for m in args.machines.split(",") if m.strip()}
    table, results = {}, []
    for project in args.project:
        for res in sorted((project / "results").iterdir()):
            if not (res / "comparison" / "cv.csv").is_file() or (wanted and res.name not in wanted):
                continue
            print(f"{res.name} ({project})", flush=True)
            result = judge_machine(project, res.name, log=lambda m: print(m, flush=True))
            results.append(result)
            table[res.name] = summarise(result)
    text = markdown(table)
    print("\n" + text)
    meta = {"date": dt.date.today().isoformat(), "python": platform.python_version(), "host": platform.node()}
    write_results("interval_refit", {"meta": meta, "summary": table, "machines": results}, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
