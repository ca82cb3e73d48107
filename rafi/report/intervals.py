"""The prediction interval as the report shows it: bands, coverage, the verdict's sentence.

Everything here is read from this machine's results, never computed anew (issue 26, the design
in :mod:`rafi.family.interval_rule`):

* ``residuals.parquet`` (validation and comparison): ``lower_um``, ``upper_um`` - the interval
  for the measured displacement change, in the convention of ``predicted_um``;
* ``validation/summary.csv``, ``comparison/per_run.csv`` and ``comparison/summary.csv``:
  ``coverage`` (fraction of a run's samples with a finite measurement and interval that lie
  inside it) and ``interval_width_um`` (median of ``upper - lower``);
* every model artefact: the block ``interval`` (``level``, ``transient_s``, ``tolerance_rpm``,
  ``half_width_um`` per cell, ``decorrelation_s``, ``calibration``, ``method``).

Older results have none of these: then there is no band, no coverage column and no sentence -
never a number made up in their place.

**The residual band.** The residual is ``measured - predicted``; the measured value lies in
``[lower, upper]`` exactly when the residual lies in ``[lower - predicted, upper - predicted]``
(:func:`residual_band`): that band is drawn around zero on every residual plot, so a residual
outside it is a sample outside the interval.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pandas as pd

from rafi.family.forward_folds import horizon_of, is_forward
from rafi.family.interval_rule import CELLS, COMPONENT_EXCESS
from rafi.report.format import isnum

#: The columns of an interval in ``residuals.parquet``.
BAND_COLUMNS = ("lower_um", "upper_um")
#: What a cell means, as the report says it.
CELL_TEXT = {
    "settled": "inside the trained temperature and speed ranges, settled since the last change",
    "transient": "inside the trained ranges, less than the transient time after a reset of the change clock",
    "outside": "outside the trained temperature or speed range",
}


def interval_block(doc) -> dict | None:
    """The ``interval`` block of a model artefact, or ``None`` (no artefact, an artefact written
    before intervals existed, or a block without a level or half-widths)."""
    block = doc.get("interval") if isinstance(doc, dict) else None
    if not isinstance(block, dict) or not isnum(block.get("level")):
        return None
    if not isinstance(block.get("half_width_um"), dict):
        return None
    return block


def shared_level(*docs) -> float | None:
    """The level of the artefacts' interval blocks when every block present states the same one
    (``None`` without a block or when they differ: then no figure names a level)."""
    levels = {float(b["level"]) for b in map(interval_block, docs) if b is not None}
    return levels.pop() if len(levels) == 1 else None


def replayed_level(summary: pd.DataFrame, *docs) -> float | None:
    """The interval level of the replayed model: that of the artefact among ``docs``
    (``model.json``, ``best_model.json``) whose ``model_id`` is the replay summary's (``None``
    when none is, or it has no ``interval`` block)."""
    ids = set(summary["model_id"].astype(str)) if "model_id" in summary else set()
    mine = [d for d in docs if isinstance(d, dict) and str(d.get("model_id")) in ids]
    return shared_level(*mine) if mine else None


def band_label(level: float | None) -> str:
    """The legend entry of a band: ``90 % interval`` (``prediction interval`` without a level)."""
    return f"{100 * level:g}\u00a0% interval" if isnum(level) else "prediction interval"


def times_in(level) -> str | None:
    """``level`` as "k times in n" (``0.9`` -> ``9 times in 10``, ``0.95`` -> ``19 times in 20``)."""
    if not isnum(level) or not 0 < float(level) < 1:
        return None
    f = Fraction(float(level)).limit_denominator(100)
    return f"{f.numerator} times in {f.denominator}"


def has_band(frame) -> bool:
    """``frame`` has the interval columns with at least one finite bound."""
    if frame is None or not all(c in frame for c in BAND_COLUMNS):
        return False
    lo = pd.to_numeric(frame["lower_um"], errors="coerce").to_numpy(float)
    hi = pd.to_numeric(frame["upper_um"], errors="coerce").to_numpy(float)
    return bool(np.any(np.isfinite(lo) & np.isfinite(hi)))


def residual_band(frame) -> tuple[np.ndarray, np.ndarray]:
    """The interval on the residual's scale: ``(lower - predicted, upper - predicted)``; the
    residual ``measured - predicted`` lies in it exactly when the measurement lies in
    ``[lower, upper]``."""
    pred = frame["predicted_um"].to_numpy(float)
    return frame["lower_um"].to_numpy(float) - pred, frame["upper_um"].to_numpy(float) - pred


def band_columns(frame) -> list[str]:
    """The columns a figure needs to draw the band of ``frame`` (empty without one)."""
    return [*BAND_COLUMNS, "predicted_um"] if has_band(frame) and "predicted_um" in frame else []


def coverage_fields(row) -> dict:
    """``coverage_pct`` (coverage in %) and ``interval_width_um`` of a table row (``None`` where
    the results have no such column or no value)."""
    cov = row.get("coverage") if hasattr(row, "get") else None
    width = row.get("interval_width_um") if hasattr(row, "get") else None
    return {
        "coverage_pct": 100.0 * float(cov) if isnum(cov) else None,
        "interval_width_um": float(width) if isnum(width) else None,
    }


def has_coverage(table) -> bool:
    """``table`` (a frame) has a ``coverage`` column with a value."""
    if table is None or "coverage" not in table:
        return False
    return bool(pd.to_numeric(table["coverage"], errors="coerce").notna().any())


def coverage_short(run_pct: float, all_pct: float | None, level_pct: float) -> str | None:
    """Which measured coverage falls short of the interval's level: ``"both"`` (the run's and
    the pooled one over every validation run), ``"run"``, ``"all"`` or ``None`` (neither: the
    level is held where it was measured). A pooled coverage not measured (``None``) never falls
    short. Strict: 89.9 % against a 90 % level is short."""
    run = run_pct < level_pct
    pooled = all_pct is not None and all_pct < level_pct
    return "both" if run and pooled else "run" if run else "all" if pooled else None


def pooled_coverage(summary: pd.DataFrame | None, model_id=None, name=None) -> float | None:
    """The coverage of a model over every validation sample, as ``comparison/summary.csv``
    stores it (``coverage``, 0..1), for the row of ``model_id`` (else of the model ``name``);
    ``None`` without the table, the row or a value."""
    if summary is None or "coverage" not in summary:
        return None
    column, value = ("model_id", model_id) if model_id else ("model", name)
    if not value or column not in summary:
        return None
    hit = summary[summary[column].astype(str) == str(value)]
    cov = pd.to_numeric(hit["coverage"], errors="coerce").dropna()
    return float(cov.iloc[0]) if len(cov) else None


def worst_run_interval(rows: pd.DataFrame | None, level, run_id=None, coverage_all=None) -> dict | None:
    """The interval at the worst run, for the verdict's sentence.

    Parameters
    ----------
    rows : DataFrame
        One model's rows per validation run (``validation/summary.csv`` or that model's rows of
        ``comparison/per_run.csv``): ``run_id``, ``max_abs_after_um``, ``coverage``,
        ``interval_width_um``.
    level : float
        The level of the model's artefact (its ``interval`` block).
    run_id : str, optional
        The worst run as the verdict names it; else the run with the largest max |residual|.
    coverage_all : float, optional
        The model's coverage over every validation sample (0..1, :func:`pooled_coverage`).

    Returns
    -------
    dict or None
        ``run_id``, ``half_width_um`` (half the median width), ``width_um``, ``coverage_pct``,
        ``coverage_all_pct`` (``None`` without ``coverage_all``), ``short``
        (:func:`coverage_short`: the sentence claims "right to +/-X, 9 times in 10" only when it
        is ``None``, else it says the measured coverage falls short of the level),
        ``level_pct``, ``times`` (:func:`times_in`) and ``uncompensated_um``: the run's largest
        uncompensated displacement change (``max_abs_before_um``) when the half-width is wider
        than it (an interval that no longer tells a compensation from none: the model is far
        from what it was trained on there), else None; ``None`` without a level, a coverage
        column or a finite value at that run.
    """
    times = times_in(level)
    if times is None or not has_coverage(rows) or "interval_width_um" not in rows:
        return None
    ids = rows["run_id"].astype(str)
    if run_id is None:
        after = pd.to_numeric(rows["max_abs_after_um"], errors="coerce")
        if not after.notna().any():
            return None
        run_id = ids[after.idxmax()]
    hit = rows[ids == str(run_id)]
    if not len(hit):
        return None
    f = coverage_fields(hit.iloc[0])
    if f["coverage_pct"] is None or f["interval_width_um"] is None:
        return None
    half = f["interval_width_um"] / 2.0
    before = hit.iloc[0].get("max_abs_before_um")
    wider = isnum(before) and half > float(before)
    all_pct = 100.0 * float(coverage_all) if isnum(coverage_all) else None
    return {
        "run_id": str(run_id),
        "half_width_um": half,
        "width_um": f["interval_width_um"],
        "coverage_pct": f["coverage_pct"],
        "coverage_all_pct": all_pct,
        "short": coverage_short(f["coverage_pct"], all_pct, 100.0 * float(level)),
        "level_pct": 100.0 * float(level),
        "times": times,
        "uncompensated_um": float(before) if wider else None,
    }


def _calibration_rows(cal: dict, half: dict) -> list[dict]:
    """Per cell: its half-width, what it means, the runs and samples it was calibrated on and
    whether it fell back to the pooled value (fields the calibration does not state: ``None``).

    The cells that took the pooled value are the list ``calibration.fallback``, as
    :func:`rafi.family.intervals.calibrate` has written it since the interval exists (no other key
    was ever written); a calibration without the key does not say (``None``: an en dash)."""
    per_cell = cal.get("cells") if isinstance(cal.get("cells"), dict) else {}
    fallback = cal.get("fallback")
    said = isinstance(fallback, (list, tuple))
    rows = []
    for cell in [c for c in CELLS if c in half] + [c for c in half if c not in CELLS]:
        info = per_cell.get(cell) if isinstance(per_cell.get(cell), dict) else {}
        fell = (cell in fallback) if said else None
        rows.append(
            {
                "cell": cell,
                "meaning": CELL_TEXT.get(cell, ""),
                "half_width_um": half[cell] if isnum(half[cell]) else None,
                "n_runs": info.get("n_runs"),
                "n_samples": info.get("n_samples"),
                "fallback": bool(fell) if fell is not None else None,
            }
        )
    return rows


def calibration_folds(scheme) -> tuple[str, int]:
    """The folds a calibration record's ``scheme`` names, in words, and the forward horizon.

    ``leave_one_run_out`` -> ``("leave-one-run-out", 0)``; the schemes joined by ``+`` where the
    forward folds calibrated too (an artefact made under the retired
    ``models.interval_forward_units``, or before 2026-11-26, still in a registry):
    ``leave_one_run_out+forward_2`` -> ``("leave-one-run-out and forward folds, 2 runs ahead", 2)``.
    """
    parts = [p for p in str(scheme or "").split("+") if p]
    whole = [p.replace("_", "-") for p in parts if not is_forward(p)]
    ahead = [horizon_of(p) for p in parts if is_forward(p)]
    words = " and ".join(whole)
    for h in ahead:
        said = f"forward folds, {'the next run' if h == 1 else f'{h} runs ahead'}"
        words = f"{words} and {said}" if words else said
    return words, (ahead[0] if ahead else 0)


def interval_context(doc) -> dict | None:
    """How the artefact's interval is computed and what it assumes, for the deployed section
    and the choices list (``None`` without an ``interval`` block).

    Returns
    -------
    dict
        ``method``, ``level_pct``, ``times``, ``transient_s``, ``tolerance_rpm``,
        ``decorrelation_s``, ``cells`` (:func:`_calibration_rows`), ``scheme`` (the CV folds of
        the calibration residuals, in words: :func:`calibration_folds`), ``forward`` (the forward
        folds' horizon in runs, 0 without them: a run held out by several forward folds is one
        calibration unit per fold), ``n_runs``, ``n_samples`` (over all cells), ``fallbacks``
        (cells that took the pooled value), ``split`` (the method is split-conformal by run) and
        ``by_run`` (the level correction left out every unit of a run together,
        ``calibration.left_out: run``), ``excess_slope`` (how fast h grows beyond the trained
        range, per training span; None for a block without it), ``components`` (the growth also
        reads the prediction's reach beyond the trained combinations of its features,
        ``component_excess``), ``other`` (the calibration's other plain entries,
        ``(key, text)``) and ``near_largest`` (the corrected level when it is
        :data:`NEAR_LARGEST_LEVEL` or more, else None: :func:`_near_largest`) and ``borrowed_from``
        (the model whose calibration the interval takes, ``calibration.borrowed_from``; None: its own).
    """
    block = interval_block(doc)
    if block is None:
        return None
    cal = block.get("calibration") if isinstance(block.get("calibration"), dict) else {}
    cells = _calibration_rows(cal, block["half_width_um"])
    method = str(block.get("method", ""))
    folds, forward = calibration_folds(cal.get("scheme", cal.get("cv", "")))
    return {
        "method": method,
        "split": method == "split_conformal_by_run",
        "level_pct": 100.0 * float(block["level"]),
        "times": times_in(block["level"]),
        "transient_s": block.get("transient_s") if isnum(block.get("transient_s")) else None,
        "tolerance_rpm": block.get("tolerance_rpm") if isnum(block.get("tolerance_rpm")) else None,
        "decorrelation_s": block.get("decorrelation_s") if isnum(block.get("decorrelation_s")) else None,
        "cells": cells,
        "scheme": folds,
        "forward": forward,
        "n_runs": cal.get("n_runs") if isnum(cal.get("n_runs")) else None,
        "n_samples": cal.get("n_samples") if isnum(cal.get("n_samples")) else None,
        "fallbacks": [c["cell"] for c in cells if c["fallback"]],
        "by_run": cal.get("left_out") == "run",
        "excess_slope": block.get("excess_slope") if isnum(block.get("excess_slope")) else None,
        "components": bool(block.get(COMPONENT_EXCESS, False)),
        "other": _other_calibration(cal),
        "near_largest": _near_largest(cal, float(block["level"])),
        "borrowed_from": str(cal["borrowed_from"]) if cal.get("borrowed_from") else None,
    }


#: A corrected level at or above this takes each cell's half-width near its largest held-out residual.
NEAR_LARGEST_LEVEL = 0.99


def _near_largest(cal: dict, level: float) -> float | None:
    """The corrected level when the level correction raised it to :data:`NEAR_LARGEST_LEVEL` or
    more (few calibration units: the half-widths sit near the largest held-out residuals), else
    None."""
    corrected = cal.get("corrected_level")
    if not isnum(corrected) or float(corrected) < max(NEAR_LARGEST_LEVEL, level + 1e-9):
        return None
    return float(corrected)


#: Keys of the calibration record the deployed section words itself.
_CALIBRATION_WORDED = (
    "cells",
    "fallback",
    "scheme",
    "cv",
    "n_runs",
    "n_samples",
    "left_out",
    "borrowed_from",
)


def _other_calibration(cal: dict) -> list[tuple[str, str]]:
    """The calibration record's other plain entries as ``(key, text)`` (nothing hidden)."""
    out = []
    for key, value in cal.items():
        if key in _CALIBRATION_WORDED or isinstance(value, dict):
            continue
        if isinstance(value, (list, tuple)):
            value = ", ".join(str(v) for v in value) or "none"
        elif isinstance(value, float):
            value = f"{value:.4g}"
        out.append((str(key).replace("_", " "), str(value)))
    return out
