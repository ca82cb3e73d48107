"""Locally adaptive prediction intervals judged one level up: an outer leave-one-run-out over the
training runs' out-of-fold (OOF) residuals (issue 26, the study of a normalised score).

Usage (from the repository root; see benchmarks/README.md)::

    python benchmarks/bench_intervals.py --project /tmp/rd/ch1-windows ... --project /tmp/twins

Each ``--project`` is a Snakemake project that has run ``rule compare`` (``results/<machine>/``
with ``runs.csv``, ``runs.parquet``, ``rank/key_sensors.json``, ``comparison/best_model.json``
and the CV memo ``.cv_memo/<key>.oof.parquet``): the folders ``bench_realdata.py --keep DIR``
leaves, or a copy of this project after ``snakemake --cores 2`` (the twin machines). Every
machine under ``results/`` is judged.

**What is judged, on training runs only.** The offered model's OOF residuals (each training run
predicted by the fold model that never saw it) are the calibration set of the shipped interval
(:func:`rafi.family.intervals.calibrate`). One level up, each training run ``r`` is held out in
turn: a variant is calibrated on the OOF samples of the other runs (its own finite-sample
correction included, measured on those runs alone) and its coverage and width are measured on
``r``'s OOF samples. Validation and test rows are never read.

**Variants** (:data:`VARIANTS`): an interval ``predicted +- q * s(x)`` where ``q`` is the
run-weighted quantile of the score ``|residual| / s(x)``:

* normaliser ``s(x)``: ``const`` (1: the shipped absolute score); ``spread`` (the range of the
  family's predictions at the sample, + its calibration median: model disagreement; the
  controller would have to run every kind); ``spread3`` (the same over the three kinds with the
  lowest CV mean max |residual| in ``comparison/cv.csv``, the offered one among them: the poor
  kinds' disagreement is noise; the choice reads every training fold, the outer held-out run's
  too, a small leak in its favour); ``mahal`` (the Mahalanobis distance of the key
  sensors' rises and the speed from the training samples' mean, + its median); ``knn`` (the
  standardised distance to the nearest training sample, + its median); ``magnitude`` (``|predicted|``
  + its median);
* cells: ``cells`` (Mondrian settled / transient / outside, as shipped) or ``pooled``;
* correction: ``level`` (the shipped corrected level, up to 1 = the largest residual, measured
  on every cell pooled); ``cell_level`` (the same correction measured per cell on the cell's own
  samples, the pooled one for a cell that falls back); ``none``
  (the nominal level), ``scale`` (the nominal-level quantile times the smallest factor >= 1 at
  which the leave-one-run-out coverage of the calibration runs reaches the level).

A distance is computed for each OOF sample against the training samples of its fold (every
training run but its own), as the controller would against the final model's training data.

Output: a table per data set (mean over held-out runs of coverage, the lowest run's coverage,
the median half-width x 2 = width) and a summary table over data sets;
``benchmarks/results/intervals.json`` and ``intervals.md``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import platform
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / "benchmarks"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from _results import write_results  # noqa: E402

from rafi.family.forward_folds import is_forward  # noqa: E402
from rafi.family.interval_fit import whole_run_units  # noqa: E402
from rafi.family.interval_rule import CELLS, interval_cell  # noqa: E402
from rafi.family.intervals import _quantiles, corrected_level, unit_weights  # noqa: E402

LEVEL = 0.9
TRANSIENT_S = 1800.0
MIN_RUNS = 3
#: Every k-th training sample kept for the nearest-neighbour distance (what a controller stores).
KNN_THIN = 10
NORMALISERS = ("const", "spread", "spread3", "mahal", "knn", "magnitude")
#: The kinds whose predictions ``spread3`` spans: the lowest CV mean max |residual|.
SPREAD_KINDS = 3
CORRECTIONS = ("level", "cell_level", "none", "scale")
SCALE_GRID = np.round(np.arange(1.0, 20.0 + 1e-9, 0.01), 6)


# ----------------------------------------------------------------------------- the data


def newest_oof(results: Path) -> Path:
    """The newest OOF memo of a machine's results."""
    files = sorted((results / ".cv_memo").glob("*.oof.parquet"), key=lambda p: p.stat().st_mtime)
    if not files:
        raise FileNotFoundError(f"{results}/.cv_memo has no *.oof.parquet: run rule compare first")
    return files[-1]


def load_machine(results: Path) -> pd.DataFrame:
    """The offered model's OOF samples with the difficulty estimates' inputs.

    Columns: ``unit``, ``residual``, ``cell``, ``pred``, ``spread`` (max - min of the family's
    predictions), ``x_*`` (key sensors' rises and the speed), finite residuals only.
    """
    best = json.loads((results / "comparison" / "best_model.json").read_text())
    kind = str(best["kind"])
    oof = pd.read_parquet(newest_oof(results))
    oof = whole_run_units(oof)  # forward folds apart
    runs = pd.read_parquet(results / "runs.parquet")
    sensors = json.loads((results / "rank" / "key_sensors.json").read_text())["sensors"]
    wide = oof.pivot_table(index=["run_id", "t_s"], columns="model", values="residual_um", dropna=False)
    spread = (wide.max(axis=1) - wide.min(axis=1)).rename("spread")
    cv = pd.read_csv(results / "comparison" / "cv.csv")
    cv = cv.loc[~cv["scheme"].map(is_forward).to_numpy(dtype=bool)]
    best_kinds = list(cv.groupby("model")["max_abs_after_um"].mean().nsmallest(SPREAD_KINDS).index)
    top = wide[[k for k in best_kinds if k in wide.columns]]
    spread = pd.concat([spread, (top.max(axis=1) - top.min(axis=1)).rename("spread3")], axis=1)
    mine = oof.loc[oof["model"].astype(str) == kind].copy()
    feats = runs[["run_id", "t_s", "dz_um", "speed_rpm"] + [f"dT{s[1:]}" for s in sensors]]
    mine = mine.merge(feats, on=["run_id", "t_s"], how="left").merge(
        spread.reset_index(), on=["run_id", "t_s"], how="left"
    )
    mine = mine.loc[np.isfinite(mine["residual_um"].to_numpy(float))].reset_index(drop=True)
    cells = [
        interval_cell(since_change_s=s, outside=bool(o), transient_s=TRANSIENT_S)
        for s, o in zip(mine["since_change_s"], mine["outside"])
    ]
    out = pd.DataFrame(
        {
            "unit": mine["unit"].astype(str).to_numpy(),
            "residual": mine["residual_um"].to_numpy(float),
            "cell": np.array(cells, dtype=object),
            "pred": mine["dz_um"].to_numpy(float) - mine["residual_um"].to_numpy(float),
            "spread": mine["spread"].to_numpy(float),
            "spread3": mine["spread3"].to_numpy(float),
        }
    )
    for s in sensors:
        out[f"x_dT{s[1:]}"] = mine[f"dT{s[1:]}"].to_numpy(float)
    out["x_speed"] = mine["speed_rpm"].to_numpy(float)
    out.attrs["kind"] = kind
    return out


def distances(data: pd.DataFrame) -> pd.DataFrame:
    """``mahal`` and ``knn`` per sample, each against the samples of the other units (its fold's
    training data; the OOF samples of the training runs are every training sample)."""
    cols = [c for c in data.columns if c.startswith("x_")]
    x = data[cols].to_numpy(float)
    x = np.where(np.isfinite(x), x, np.nanmean(x, axis=0))
    units = data["unit"].to_numpy()
    mahal = np.empty(len(data))
    knn = np.empty(len(data))
    for u in np.unique(units):
        mine = units == u
        train = x[~mine]
        mean = train.mean(axis=0)
        sd = train.std(axis=0)
        sd[sd <= 0] = 1.0
        z_train = (train - mean) / sd
        z = (x[mine] - mean) / sd
        cov = np.cov(z_train, rowvar=False) + 1e-3 * np.eye(len(cols))
        inv = np.linalg.inv(cov)
        mahal[mine] = np.sqrt(np.einsum("ij,jk,ik->i", z, inv, z))
        ref = z_train[::KNN_THIN]
        d2 = ((z[:, None, :] - ref[None, :, :]) ** 2).sum(axis=2)
        knn[mine] = np.sqrt(d2.min(axis=1))
    return data.assign(mahal=mahal, knn=knn)


def difficulty(data: pd.DataFrame, normaliser: str) -> np.ndarray:
    """The raw difficulty estimate ``g(x)`` (``s = g + median g`` is formed in calibration)."""
    if normaliser == "const":
        return np.zeros(len(data))
    if normaliser == "magnitude":
        return np.abs(data["pred"].to_numpy(float))
    g = data[normaliser].to_numpy(float)
    return np.where(np.isfinite(g), g, np.nanmedian(g))


# ----------------------------------------------------------------------------- a variant


def _scale_factor(score: np.ndarray, units: np.ndarray, level: float) -> float:
    """The smallest factor >= 1 on the nominal quantile at which the leave-one-unit-out
    coverage of the calibration units reaches ``level`` (:data:`SCALE_GRID`; its end if never)."""
    names = np.unique(units)
    if len(names) < 2:
        return float(SCALE_GRID[-1])
    cover = np.zeros(len(SCALE_GRID))
    for name in names:
        mine = units == name
        q = _quantiles(score[~mine], unit_weights(units[~mine]), np.array([level]))[0]
        own = np.sort(score[mine])
        cover += np.searchsorted(own, q * SCALE_GRID, side="right") / own.size
    cover /= len(names)
    ok = np.flatnonzero(cover >= level - 1e-12)
    return float(SCALE_GRID[ok[0]] if ok.size else SCALE_GRID[-1])


def fit_variant(cal: pd.DataFrame, g: np.ndarray, *, cells: bool, correction: str) -> dict:
    """Calibrate one variant on ``cal`` (its difficulty ``g``): the offset, the cells' score
    quantiles ``q`` (h = q * (g + offset))."""
    units = cal["unit"].to_numpy()
    offset = float(np.median(g)) if np.any(g > 0) else 1.0
    offset = offset if offset > 0 else 1.0
    score = np.abs(cal["residual"].to_numpy(float)) / (g + offset)
    factor, lam = 1.0, LEVEL
    if correction in ("level", "cell_level"):
        lam = corrected_level(score, units, LEVEL)
    elif correction == "scale":
        factor = _scale_factor(score, units, LEVEL)
    pooled = _quantiles(score, unit_weights(units), np.array([lam]))[0]
    q = {c: pooled for c in CELLS}
    if cells:
        cell = cal["cell"].to_numpy()
        for c in CELLS:
            mine = cell == c
            if len(np.unique(units[mine])) >= MIN_RUNS:
                lam_c = (
                    corrected_level(score[mine], units[mine], LEVEL) if correction == "cell_level" else lam
                )
                q[c] = _quantiles(score[mine], unit_weights(units[mine]), np.array([lam_c]))[0]
        q["outside"] = max(q["outside"], q["settled"], q["transient"])
    return {"offset": offset, "q": {c: q[c] * factor for c in CELLS}, "lam": lam, "factor": factor}


def half_widths(fit: dict, data: pd.DataFrame, g: np.ndarray) -> np.ndarray:
    """``h`` per sample of ``data`` under a calibrated variant."""
    q = np.array([fit["q"][c] for c in data["cell"]])
    return q * (g + fit["offset"])


def outer_cv(data: pd.DataFrame, normaliser: str, *, cells: bool, correction: str) -> dict:
    """Hold out each unit in turn; calibrate on the others; coverage and widths on it."""
    g = difficulty(data, normaliser)
    units = data["unit"].to_numpy()
    per_run, widths, levels = [], [], []
    for u in np.unique(units):
        mine = units == u
        fit = fit_variant(data.loc[~mine], g[~mine], cells=cells, correction=correction)
        h = half_widths(fit, data.loc[mine], g[mine])
        r = np.abs(data.loc[mine, "residual"].to_numpy(float))
        per_run.append(float(np.mean(r <= h)))
        widths.append(2 * h)
        levels.append(fit["lam"] if correction != "scale" else fit["factor"])
    w = np.concatenate(widths)
    return {
        "coverage": float(np.mean(per_run)),
        "min_run_coverage": float(np.min(per_run)),
        "median_width_um": float(np.median(w)),
        "at_level_1": int(sum(lvl >= 1.0 for lvl in levels)) if correction != "scale" else 0,
        "per_run": per_run,
    }


VARIANTS = [(n, cells, corr) for n in NORMALISERS for cells in (True, False) for corr in CORRECTIONS]


def variant_name(normaliser: str, cells: bool, correction: str) -> str:
    return f"{normaliser}/{'cells' if cells else 'pooled'}/{correction}"


# ----------------------------------------------------------------------------- main


def machines_of(project: Path) -> list[Path]:
    return sorted(
        p for p in (project / "results").iterdir() if (p / "comparison" / "best_model.json").is_file()
    )


def projects_of(argv: list[str] | None, doc: str) -> list[Path]:
    """The ``--project`` folders of a study's command line (its module docstring's first paragraph
    as the description)."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    parser.add_argument("--project", type=Path, action="append", required=True)
    return parser.parse_args(argv).project


def main(argv: list[str] | None = None) -> int:
    table: dict[str, dict] = {}
    for project in projects_of(argv, __doc__):
        for results in machines_of(project):
            data = distances(load_machine(results))
            name = results.name
            print(f"{name}: offered {data.attrs['kind']}, {data['unit'].nunique()} runs", file=sys.stderr)
            table[name] = {"kind": data.attrs["kind"]}
            for n, cells, corr in VARIANTS:
                table[name][variant_name(n, cells, corr)] = outer_cv(data, n, cells=cells, correction=corr)
    lines = summary_lines(table)
    print("\n".join(lines))
    meta = {"date": dt.date.today().isoformat(), "python": platform.python_version(), "level": LEVEL}
    write_results("intervals", {"meta": meta, "data": table}, "\n".join(lines) + "\n", indent=1)
    return 0


def summary_lines(table: dict) -> list[str]:
    """One row per variant: per data set ``coverage % / median width um``, and the criterion."""
    sets = list(table)
    head = ["variant"] + sets + ["mean |cov - 90|", "lowest set cov", "mean median width"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for n, cells, corr in VARIANTS:
        v = variant_name(n, cells, corr)
        cov = [table[s][v]["coverage"] for s in sets]
        wid = [table[s][v]["median_width_um"] for s in sets]
        cellsx = [f"{100 * c:.1f} / {w:.2f}" for c, w in zip(cov, wid)]
        dev = np.mean([abs(100 * c - 100 * LEVEL) for c in cov])
        lines.append(
            "| "
            + " | ".join([v] + cellsx + [f"{dev:.1f}", f"{100 * min(cov):.1f}", f"{np.mean(wid):.2f}"])
            + " |"
        )
    return lines


if __name__ == "__main__":
    raise SystemExit(main())
