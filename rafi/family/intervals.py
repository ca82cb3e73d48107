"""Calibrating the prediction interval of a model on its whole-run CV residuals (``docs/models.md``,
"Prediction intervals").

The per-sample rule (cells, change clock) is :mod:`rafi.family.interval_rule`; this module finds
the half-width of each cell and evaluates the interval over a frame.

Method: **run-weighted Mondrian split-conformal** on the out-of-fold (OOF) residuals of the
whole-run cross-validation (:func:`rafi.family.crossval.cross_validate` with ``oof=``). Samples of
one run are strongly autocorrelated, so the exchangeable units are the held-out runs (time blocks
for time-blocked folds), not the samples: every OOF sample of a unit gets the weight
``1 / (that unit's samples in the cell)``, so each unit counts equally, and a cell's half-width is
the weighted quantile of ``|residual|`` at a corrected level (:func:`corrected_level`).

A cell with fewer than ``min_runs`` units falls back: ``settled`` / ``transient`` to the pooled
half-width (every OOF sample, units weighted equally), ``outside`` to the largest of the pooled and
the two in-range cells. ``outside`` is never narrower than an in-range cell (extrapolation is no
safer than interpolation).

``decorrelation_s`` (:func:`decorrelation_s`): the smallest lag at which the autocorrelation of the
OOF exceedance indicators, pooled over units, falls below :data:`DECORRELATION_ACF`, times the
sample spacing (with too few exceedances, of the residuals themselves).
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from rafi.family.forward_folds import unit_run
from rafi.family.interval_rule import (
    CELLS,
    COMPONENT_EXCESS,
    EXCESS_SLOPE,
    INTERVAL_SCHEMA,
    interval_cell,
    since_change,
    widening,
)
from rafi.family.whole_log import layout, unsort
from rafi.method.validate import coverage_and_width  # noqa: F401 - re-exported: defined beside validate_runs

__all__ = [
    "METHOD",
    "OOF_COLUMNS",
    "DECORRELATION_ACF",
    "clock_settings",
    "tolerance_of",
    "oof_samples",
    "since_change_of_frame",
    "weighted_quantile",
    "unit_weights",
    "corrected_level",
    "decorrelation_s",
    "calibrate",
    "interval_of",
    "set_interval",
    "interval_columns",
    "coverage_and_width",
]

METHOD = "split_conformal_by_run"
#: The OOF samples a calibration reads (:func:`rafi.family.crossval.cross_validate` ``oof=``).
OOF_COLUMNS = ["model", "unit", "run_id", "t_s", "residual_um", "since_change_s", "outside", "excess"]
#: Pooled autocorrelation of the exceedance indicators below which they count as independent.
DECORRELATION_ACF = 0.1
#: Grid step of the corrected level (:func:`corrected_level`).
LEVEL_STEP = 0.001


# --------------------------------------------------------------------------- change clock on a frame


def clock_settings(artefact: dict) -> dict:
    """What the change clock of a model reads from its artefact: the reference ``rule`` and
    ``window_s`` (the reference windows reset the clock) and ``restart_gap_s`` (the filter restart
    gap of the family's filtered kinds; infinite for RAFI, as the streaming compensator does)."""
    from rafi.settings import MACHINE_DEFAULTS

    ref = {**MACHINE_DEFAULTS["reference"], **(artefact.get("reference") or {})}
    hyper = artefact.get("hyperparameters") or {}
    return {
        "rule": str(ref["rule"]),
        "window_s": float(ref["window_s"]),
        "restart_gap_s": float(hyper.get("filter_restart_gap_s", math.inf)),
    }


def tolerance_of(artefact: dict) -> float:
    """The speed move (r/min) that resets a model's change clock: its ``speed_tolerance_rpm``."""
    from rafi.settings import MACHINE_DEFAULTS

    for block in ("hyperparameters", "fuzzy"):
        value = (artefact.get(block) or {}).get("speed_tolerance_rpm")
        if value is not None:
            return float(value)
    return float(MACHINE_DEFAULTS["speed_tolerance_rpm"])


def since_change_of_frame(
    frame: pd.DataFrame, *, rule: str, window_s: float, restart_gap_s: float, tolerance_rpm: float
) -> np.ndarray:
    """Seconds since the change clock's last reset, per row of ``frame`` (its row order).

    The clock (:func:`rafi.family.interval_rule.since_change`) runs over the rows in the order of
    :func:`rafi.family.whole_log.layout` (by log and ``log_t_s``; per run and ``t_s`` without whole
    logs); it is reset at the layout's ``restart`` rows (a log's first sample, a gap longer than
    ``restart_gap_s``; per run: each run's first sample) and at the first row of each reference
    group (the start of a reference window).
    """
    n = len(frame)
    if n == 0:
        return np.zeros(0)
    lay = layout(frame, rule=rule, window_s=window_s, restart_gap_s=restart_gap_s)
    first_of_group = np.zeros(n, dtype=bool)
    first_of_group[np.unique(lay.ref_group, return_index=True)[1]] = True
    speed = frame["speed_rpm"].to_numpy(dtype=float, na_value=np.nan)[lay.order]
    since = since_change(lay.t, speed, lay.restart | first_of_group, tolerance_rpm=tolerance_rpm)
    return unsort(since, lay)


def oof_samples(folds: list[pd.DataFrame], frame: pd.DataFrame, artefact: dict, name: str) -> pd.DataFrame:
    """The OOF samples (:data:`OOF_COLUMNS`) of one model's cross-validation.

    ``folds`` holds per fold the held-out samples: ``pos`` (position in ``frame``), ``unit``,
    ``residual_um`` and ``outside``; ``frame`` is what the folds predicted from (whole logs), and
    ``artefact`` a fold model's artefact (its change clock settings, :func:`clock_settings`, and
    :func:`tolerance_of`). The change clock runs over ``frame`` once: a log's clock depends on the
    log alone, so it is the clock of any fold that predicts the log.
    """
    if not folds:
        return pd.DataFrame(
            {c: pd.Series(dtype=object if c in ("model", "unit", "run_id") else float) for c in OOF_COLUMNS}
        )
    parts = pd.concat(folds, ignore_index=True)
    pos = parts["pos"].to_numpy(dtype=np.int64)
    since = since_change_of_frame(frame, tolerance_rpm=tolerance_of(artefact), **clock_settings(artefact))
    out = pd.DataFrame(
        {
            "model": name,
            "unit": parts["unit"].astype(str).to_numpy(),
            "run_id": frame["run_id"].astype(str).to_numpy()[pos],
            "t_s": frame["t_s"].to_numpy(dtype=float, na_value=np.nan)[pos],
            "residual_um": parts["residual_um"].to_numpy(dtype=float),
            "since_change_s": since[pos],
            "outside": parts["outside"].to_numpy(dtype=bool),
            "excess": parts["excess"].to_numpy(dtype=float) if "excess" in parts else np.zeros(len(parts)),
        }
    )
    return out[OOF_COLUMNS]


# --------------------------------------------------------------------------- run-weighted quantiles


def unit_weights(units: np.ndarray) -> np.ndarray:
    """Per sample, ``1 / (samples of its unit)``: every unit weighs 1 in total."""
    codes, counts = np.unique(np.asarray(units).astype(str), return_inverse=True, return_counts=True)[1:]
    return 1.0 / counts[codes]


def weighted_quantile(values: np.ndarray, weights: np.ndarray, level: float) -> float:
    """The smallest value whose cumulative weight share reaches ``level`` (``inverted_cdf``:
    with equal weights this is ``numpy.quantile(values, level, method="inverted_cdf")``)."""
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        return math.nan
    order = np.argsort(v, kind="stable")
    share = np.cumsum(np.asarray(weights, dtype=float)[order])
    share /= share[-1]
    k = int(np.searchsorted(share, min(float(level), 1.0) - 1e-12, side="left"))
    return float(v[order][min(k, v.size - 1)])


def _quantiles(values: np.ndarray, weights: np.ndarray, levels: np.ndarray) -> np.ndarray:
    order = np.argsort(values, kind="stable")
    share = np.cumsum(weights[order])
    share /= share[-1]
    k = np.searchsorted(share, np.minimum(levels, 1.0) - 1e-12, side="left")
    return values[order][np.minimum(k, values.size - 1)]


def corrected_level(
    abs_residual: np.ndarray, units: np.ndarray, level: float, groups: np.ndarray | None = None
) -> float:
    """The quantile level used for the half-widths: the smallest ``lam >= level`` (a grid of
    :data:`LEVEL_STEP`) at which the leave-one-unit-out coverage reaches ``level``.

    For each unit ``u``, ``h(lam)`` is the unit-weighted quantile of the *other* units' residuals;
    the coverage is the mean over units of the fraction of ``u``'s samples within ``h(lam)``. This
    is the finite-sample correction measured on the calibration units themselves: a quantile of
    ``n`` units covers a new unit less often than ``lam`` (it is estimated on them), and this finds
    the level that covers a unit it has not seen ``level`` of the time. It never narrows (``lam >=
    level``). With fewer than two units there is nothing to leave out: ``lam = 1`` (the largest
    residual).

    ``groups`` (per sample, e.g. :func:`rafi.family.forward_folds.unit_run`): a unit is left out
    together with every unit of its group, so a run held out by several folds never calibrates
    against its own other units. With fewer than two groups: ``lam = 1``.
    """
    a = np.asarray(abs_residual, dtype=float)
    u = np.asarray(units).astype(str)
    g = u if groups is None else np.asarray(groups).astype(str)
    names = np.unique(u)
    if len(names) < 2 or len(np.unique(g)) < 2:
        return 1.0
    grid = np.round(np.arange(float(level), 1.0 + LEVEL_STEP / 2, LEVEL_STEP), 9)
    grid[-1] = min(grid[-1], 1.0)
    cover = np.zeros(len(grid))
    for name in names:
        mine = u == name
        kept = g != g[mine][0]
        h = _quantiles(a[kept], unit_weights(u[kept]), grid)
        own = np.sort(a[mine])
        cover += np.searchsorted(own, h, side="right") / own.size
    cover /= len(names)
    ok = np.flatnonzero(cover >= float(level) - 1e-12)
    return float(grid[ok[0]]) if ok.size else 1.0


# --------------------------------------------------------------------------- decorrelation


#: Fewer exceedances than this say nothing of their correlation: :func:`decorrelation_s` then
#: reads the residuals' own autocorrelation instead.
MIN_EXCEEDANCES = 10


def decorrelation_s(oof: pd.DataFrame, exceeds: np.ndarray, residuals: np.ndarray | None = None) -> float:
    """Seconds at which the exceedances of the OOF samples are about independent.

    ``exceeds`` marks the OOF samples outside their interval. Within each unit (samples in ``t_s``
    order) the lag-``L`` autocorrelation of the indicator, pooled over units (sums of products
    over every unit, over the pooled variance), is computed for ``L = 1, 2, ...``; the first lag
    below :data:`DECORRELATION_ACF`, times the median sample spacing, is returned; when it never
    falls below the limit within the longest unit, that unit's duration. With fewer than
    :data:`MIN_EXCEEDANCES` exceedances (or nothing but) the indicator says nothing: the same is
    done on ``residuals`` (the OOF residuals; an exceedance is a large residual, and a residual's
    autocorrelation lasts at least as long as that of its large values: the conservative side for
    a test that thins to one sample per ``decorrelation_s``). Without those, one sample spacing.
    """
    if not len(oof):
        return math.nan
    order = np.lexsort((oof["t_s"].to_numpy(dtype=float), pd.factorize(oof["unit"].astype(str))[0]))
    unit = oof["unit"].astype(str).to_numpy()[order]
    t = oof["t_s"].to_numpy(dtype=float)[order]
    same = unit[1:] == unit[:-1]
    dt = np.diff(t)[same]
    spacing = float(np.median(dt[dt > 0])) if (dt > 0).any() else 1.0
    x = np.asarray(exceeds, dtype=bool)
    if MIN_EXCEEDANCES <= x.sum() <= len(x) - MIN_EXCEEDANCES:
        series = x.astype(float)[order]
    elif residuals is not None:
        series = np.asarray(residuals, dtype=float)[order]
    else:
        return spacing
    lag = _first_lag_below(series, unit)
    return spacing if lag is None else lag * spacing


def _first_lag_below(x: np.ndarray, unit: np.ndarray) -> int | None:
    """The first lag at which the pooled within-unit autocorrelation of ``x`` falls below
    :data:`DECORRELATION_ACF` (the longest unit's length if never; None: no variance)."""
    x = x - x.mean()
    var = float(np.sum(x * x))
    if var <= 0:
        return None
    longest = int(pd.Series(unit).value_counts().max())
    for lag in range(1, longest):
        pair = unit[lag:] == unit[:-lag]
        if float(np.sum(x[lag:][pair] * x[:-lag][pair])) / var < DECORRELATION_ACF:
            return lag
    return longest


# --------------------------------------------------------------------------- calibration


def _cell_of(oof: pd.DataFrame, transient_s: float) -> np.ndarray:
    since = oof["since_change_s"].to_numpy(dtype=float)
    outside = oof["outside"].to_numpy(dtype=bool)
    return np.array(
        [interval_cell(since_change_s=s, outside=o, transient_s=transient_s) for s, o in zip(since, outside)],
        dtype=object,
    )


def calibrate(
    oof: pd.DataFrame,
    *,
    level: float,
    transient_s: float,
    tolerance_rpm: float,
    min_runs: int,
    scheme: str,
    by_run: bool = True,
) -> dict | None:
    """The artefact's ``interval`` block from one model's OOF samples (:data:`OOF_COLUMNS`).

    Parameters
    ----------
    oof : pandas.DataFrame
        The model's held-out samples of the whole-run CV (finite residuals only are used).
    level : float
        Nominal coverage (``models: interval_level``).
    transient_s : float
        ``models: interval_transient_s``.
    tolerance_rpm : float
        The speed move that resets the change clock (the machine's ``speed_tolerance_rpm``).
    min_runs : int
        ``models: interval_min_runs``: a cell with fewer units falls back (module docstring).
    scheme : str
        The CV scheme the OOF samples come from (recorded).
    by_run : bool
        Measure the level correction leaving out every unit of the held-out unit's run
        (:func:`corrected_level` with ``groups`` :func:`~rafi.family.forward_folds.unit_run`: a run
        held out by the whole-run and the forward folds is several units). False: unit by unit,
        the correction before 2026-11-26 (``benchmarks/bench_interval_groups.py`` compares them).
        Recorded as ``calibration.left_out: run`` (``time block`` under time-blocked folds).

    Returns
    -------
    dict or None
        The block (schema :data:`rafi.family.interval_rule.INTERVAL_SCHEMA`); ``None`` without any
        finite OOF residual (no fold): the model then has no interval.
    """
    res = oof["residual_um"].to_numpy(dtype=float)
    ok = np.isfinite(res)
    if not ok.any():
        return None
    data = oof.loc[ok]
    excess = data["excess"].to_numpy(dtype=float) if "excess" in data else np.zeros(len(data))
    a = np.abs(res[ok]) / widening({"excess_slope": EXCESS_SLOPE}, excess)  # a normalised score
    units = data["unit"].astype(str).to_numpy()
    cells = _cell_of(data, transient_s)
    lam = corrected_level(a, units, level, groups=unit_run(units) if by_run else None)
    pooled = weighted_quantile(a, unit_weights(units), lam)
    half, stats, fell_back = {}, {}, []
    for cell in CELLS:
        mine = cells == cell
        n_units = len(np.unique(units[mine]))
        stats[cell] = {"n_runs": int(n_units), "n_samples": int(mine.sum())}
        if n_units >= max(int(min_runs), 1):
            half[cell] = weighted_quantile(a[mine], unit_weights(units[mine]), lam)
        else:
            fell_back.append(cell)
            half[cell] = pooled
    if "outside" in fell_back:
        half["outside"] = max(pooled, half["settled"], half["transient"])
    half["outside"] = max(half["outside"], half["settled"], half["transient"])
    h = np.array([half[c] for c in cells])
    block = {
        "schema": INTERVAL_SCHEMA,
        "method": METHOD,
        "level": float(level),
        "transient_s": float(transient_s),
        "tolerance_rpm": float(tolerance_rpm),
        "half_width_um": {c: float(half[c]) for c in CELLS},
        "excess_slope": EXCESS_SLOPE,
        COMPONENT_EXCESS: True,
        "decorrelation_s": float(decorrelation_s(data, a > h, res[ok])),
        "calibration": {
            "scheme": str(scheme),
            "units": "time blocks" if scheme == "time_blocks" else "runs",
            "n_runs": int(len(np.unique(units))),
            "n_samples": int(len(a)),
            "corrected_level": float(lam),
            "pooled_half_width_um": float(pooled),
            "min_runs": int(min_runs),
            "cells": stats,
            "fallback": fell_back,
        },
    }
    if by_run:  # a time block is its own group: the block is what is left out
        block["calibration"]["left_out"] = "time block" if scheme == "time_blocks" else "run"
    return block


# --------------------------------------------------------------------------- models and frames


def interval_of(model) -> dict | None:
    """The ``interval`` block of a fitted model or an artefact dict (``None``: no interval)."""
    if isinstance(model, dict):
        block = model.get("interval")
    else:
        inner = getattr(model, "model_", None)
        block = getattr(inner if inner is not None else model, "interval_", None)
    return block if isinstance(block, dict) and block.get("schema") == INTERVAL_SCHEMA else None


def set_interval(model, block: dict | None):
    """Give a fitted model (a family model or a ``RafiModel``) its ``interval`` block; its
    artefact (``to_dict``) then carries it and its ``model_id`` covers it. Returns ``model``."""
    inner = getattr(model, "model_", None)  # PublishedRafi / RafiLinear wrap a RafiModel
    (inner if inner is not None else model).interval_ = block
    return model


def interval_columns(
    model,
    frame: pd.DataFrame,
    predicted_um: np.ndarray,
    outside: np.ndarray,
    excess: np.ndarray | None = None,
) -> pd.DataFrame:
    """``lower_um``, ``upper_um``, ``interval_cell`` per row of ``frame`` (its order and index).

    ``model`` is a fitted model or an artefact dict; without an interval block the bounds are NaN
    and the cell is empty. ``excess`` (``range_excess`` of ``predict_detail``) widens the interval
    beyond the trained range. A NaN prediction gives NaN bounds (its cell is still named). With
    ``functools.partial(interval_columns, model)`` it is the ``bounds`` of
    :func:`rafi.method.validate.validate_runs`.
    """
    n = len(frame)
    block = interval_of(model)
    if block is None or n == 0:
        return pd.DataFrame(
            {"lower_um": np.full(n, np.nan), "upper_um": np.full(n, np.nan), "interval_cell": [""] * n},
            index=frame.index,
        )
    artefact = model if isinstance(model, dict) else model.to_dict()
    since = since_change_of_frame(
        frame, tolerance_rpm=float(block["tolerance_rpm"]), **clock_settings(artefact)
    )
    transient = float(block["transient_s"])
    outside = np.asarray(outside, dtype=bool)
    cells = [
        interval_cell(since_change_s=s, outside=o, transient_s=transient) for s, o in zip(since, outside)
    ]
    h = np.array([float(block["half_width_um"][c]) for c in cells])
    if excess is not None:  # beyond the trained range the interval widens (interval_rule.widening)
        h = h * widening(block, excess)
    pred = np.asarray(predicted_um, dtype=float)
    return pd.DataFrame(
        {"lower_um": pred - h, "upper_um": pred + h, "interval_cell": cells}, index=frame.index
    )
