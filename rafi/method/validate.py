"""Validation by whole run and qualification against acceptance gates.

Every run whose ``role`` starts with ``"validation"`` (``validation_single``,
``validation_multi``, ``validation_idle``) is predicted as a whole (runs are never
split into random samples: 5 s samples are autocorrelated, so sample-wise splits
leak). Per run, over the samples where both ``dz_um`` and the prediction exist:

* ``max_abs_before_um`` = ``max |dz|`` (no compensation),
* ``max_abs_after_um``  = ``max |dz - predicted|`` (with compensation; the paper's
  Table 4 "residual"),
* ``improvement_pct`` = ``100 * (before - after) / before`` (paper definition; NaN
  if ``before`` is 0),
* ``rmse_before_um`` / ``rmse_after_um``, ``n_samples``, ``n_outside_temp_range``,
  ``n_outside_speed_range``, ``worse_than_uncompensated`` (``after > before``),
* ``n_outside_envelope``: samples whose prediction was held at the model's training envelope's
  edge (an input it reads, or the prediction, beyond the training range widened by its margin:
  :mod:`rafi.family.envelope`); 0 for a model whose ``predict_detail`` has no
  ``outside_envelope`` (``rafi``, ``rafi_linear``),
* ``n_unpredicted``: samples with a measured ``dz`` where the model gives no value (an input it
  reads is missing there: a sensor's dropout, a missing speed), left out of every figure above;
  ``unpredicted_inputs``: the inputs with no value on those samples (``"T11"``, ``"T8, speed"``;
  ``""`` when there are none), so a figure over fewer samples than the run has says why;
* ``paper_residual_um``: paper Table 4 for ``validation_single`` runs whose speed is
  within 50 r/min of a Table 4 speed, else NaN;
* ``noise_sigma_um`` / ``noise_floor_um``: the white-noise sigma of the run's ``dz`` and the
  expected max |noise| over its measured samples, estimated from the measurement alone
  (:func:`run_noise_floor`: the same for every model, whatever samples it compensated): a
  ``max_abs_after_um`` near ``noise_floor_um`` is at the noise;
* ``coverage`` / ``interval_width_um``: the fraction (0..1) of the run's samples with a finite
  measurement and interval that lie inside the model's prediction interval, and the median width
  of that interval (:mod:`rafi.family.intervals`; NaN for a model without an interval).

The residuals carry ``outside_envelope`` per sample (False where the model's detail has no such
column) and the interval per sample: ``lower_um`` / ``upper_um`` (bounds for the measured
displacement change, the convention of ``predicted_um``) and ``interval_cell`` (``settled``,
``transient`` or ``outside``; empty without an interval).

The model predicts the **whole** runs frame once (every log in time order, training and
excluded runs included: a model that filters its inputs sees the whole log before each
run) and each validation run is a slice of that prediction.

Qualification (:func:`qualify`)
-------------------------------
Gates ``{max_residual_um, min_improvement_pct, never_worse_than_uncompensated}``,
one verdict row per criterion and validation run:

* ``max_residual_um``: ``max_abs_after_um <= limit``;
* ``min_improvement_pct``: ``improvement_pct >= limit``;
* ``never_worse_than_uncompensated`` (if the gate is true): ``max_abs_after_um <=
  max_abs_before_um``; the row's ``limit`` is the run's ``max_abs_before_um``;
* ``min_coverage`` (off when None): ``coverage >= limit`` (a model without an interval has
  a NaN coverage and fails it).

Every gate applies to every validation run, idle cool-downs (``validation_idle``)
included: a compensated machine that cools down is as much in production as one that
warms up, and a residual above the limit on a cool-down is a failure like any other
(issue 12; before, idle runs were held only to the never-worse gate). A missing (NaN)
measurement fails its criterion.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rafi.contract.sensors import run_sensors
from rafi.method import paper
from rafi.method.noise import noise_floor
from rafi.method.paper import paper_value
from rafi.settings import GATE_KEYS

__all__ = [
    "PAPER_RESIDUAL_UM",
    "SUMMARY_COLUMNS",
    "RESIDUAL_COLUMNS",
    "VERDICT_COLUMNS",
    "validate_runs",
    "run_noise_floor",
    "coverage_and_width",
    "input_sensors",
    "inputs_without_value",
    "qualify",
    "overall_passed",
]

PAPER_RESIDUAL_UM = paper.RESIDUAL_UM
"""Maximum residual after compensation (um) per single-speed validation run, paper Table 4."""

SUMMARY_COLUMNS = [
    "run_id",
    "role",
    "speed_rpm",
    "duration_s",
    "max_abs_before_um",
    "max_abs_after_um",
    "improvement_pct",
    "rmse_before_um",
    "rmse_after_um",
    "n_samples",
    "n_outside_temp_range",
    "n_outside_speed_range",
    "n_outside_envelope",
    "n_unpredicted",
    "unpredicted_inputs",
    "worse_than_uncompensated",
    "paper_residual_um",
    "noise_sigma_um",
    "noise_floor_um",
    "coverage",
    "interval_width_um",
]
RESIDUAL_COLUMNS = [
    "run_id",
    "t_s",
    "speed_rpm",
    "measured_um",
    "predicted_um",
    "residual_um",
    "outside_temp_range",
    "outside_speed_range",
    "outside_envelope",
    "lower_um",
    "upper_um",
    "interval_cell",
]
VERDICT_COLUMNS = ["criterion", "limit", "measured", "passed", "run_id"]


def input_sensors(model) -> list[str] | None:
    """The temperature sensors ``model`` reads (RAFI's key sensors, a ridge model's ``sensors_``),
    or ``None`` when it does not say."""
    for name in ("key_sensors", "sensors_"):
        sensors = getattr(model, name, None)
        if sensors is not None:
            return [str(s) for s in sensors]
    return None


def inputs_without_value(sub: pd.DataFrame, missing: np.ndarray, sensors: list[str] | None) -> str:
    """The inputs with no value on the rows ``missing`` of the run frame ``sub``: each sensor of
    ``sensors`` (every sensor of ``sub`` when ``None``: :func:`rafi.contract.sensors.run_sensors`) whose
    rise is NaN on at
    least one of them, then ``speed`` if the speed is; joined by ``", "``."""
    if not missing.any():
        return ""
    names = [
        s
        for s in (run_sensors(sub) if sensors is None else sensors)
        if f"d{s}" in sub.columns
        and np.isnan(sub[f"d{s}"].to_numpy(dtype=float, na_value=np.nan)[missing]).any()
    ]
    if np.isnan(sub["speed_rpm"].to_numpy(dtype=float, na_value=np.nan)[missing]).any():
        names.append("speed")
    return ", ".join(names)


def _envelope_flags(detail: pd.DataFrame) -> np.ndarray:
    """``detail``'s ``outside_envelope`` as booleans (NaN: False); all False without the column
    (a model without a training envelope)."""
    if "outside_envelope" not in detail.columns:
        return np.zeros(len(detail), dtype=bool)
    return detail["outside_envelope"].fillna(False).to_numpy(dtype=bool)


def run_noise_floor(measured) -> tuple[float, float]:
    """``(noise_sigma_um, noise_floor_um)`` of a validation run, from its measured dz alone.

    The floor is the max |residual| a perfect model would typically leave on the run: a perfect
    model compensates every sample with a measurement, so the expected max |noise| is taken over
    all the run's measured samples (:func:`rafi.method.noise.noise_floor`), not over the samples a
    given model compensated. A model that gives no compensation on some samples (a dropout of a
    sensor it reads) is scored on fewer samples, but the run, and so its floor, is the same for
    every model: one figure per run in ``validation/summary.csv``, ``comparison/per_run.csv``
    and every place of the report (the model's max over fewer samples is compared against a
    floor at most a few hundredths of a um higher: the expected max grows with the log of the
    count).
    """
    return noise_floor(measured)


def _run_summary(run_id, role, speed, duration, *, detail, measured, t_s, bounds, sub, sensors) -> dict:
    pred = detail["predicted_um"].to_numpy(dtype=float)
    resid = measured - pred
    ok = np.isfinite(measured) & np.isfinite(pred)
    unpredicted = np.isfinite(measured) & ~np.isfinite(pred)
    n = int(ok.sum())
    if n:
        before = float(np.max(np.abs(measured[ok])))
        after = float(np.max(np.abs(resid[ok])))
        rmse_b = float(np.sqrt(np.mean(measured[ok] ** 2)))
        rmse_a = float(np.sqrt(np.mean(resid[ok] ** 2)))
    else:
        before = after = rmse_b = rmse_a = float("nan")
    improvement = 100.0 * (before - after) / before if n and before > 0 else float("nan")
    if duration is None or pd.isna(duration):
        finite_t = t_s[np.isfinite(t_s)]
        duration = float(finite_t.max() - finite_t.min()) if finite_t.size else float("nan")
    paper = (
        paper_value(speed, PAPER_RESIDUAL_UM)
        if role == "validation_single" and pd.notna(speed)
        else float("nan")
    )
    sigma, floor = run_noise_floor(measured)
    return {
        "run_id": run_id,
        "role": role,
        "speed_rpm": speed,
        "duration_s": float(duration),
        "max_abs_before_um": before,
        "max_abs_after_um": after,
        "improvement_pct": improvement,
        "rmse_before_um": rmse_b,
        "rmse_after_um": rmse_a,
        "n_samples": n,
        "n_outside_temp_range": int(detail["outside_temp_range"].to_numpy()[ok].sum()),
        "n_outside_speed_range": int(detail["outside_speed_range"].to_numpy()[ok].sum()),
        "n_outside_envelope": int(_envelope_flags(detail)[ok].sum()),
        "n_unpredicted": int(unpredicted.sum()),
        "unpredicted_inputs": inputs_without_value(sub, unpredicted, sensors),
        "worse_than_uncompensated": bool(n and after > before),
        "paper_residual_um": paper,
        "noise_sigma_um": sigma,
        "noise_floor_um": floor,
        **dict(
            zip(
                ("coverage", "interval_width_um"),
                coverage_and_width(measured, bounds["lower_um"], bounds["upper_um"]),
            )
        ),
    }


def time_ordered(runs_frame: pd.DataFrame) -> pd.DataFrame:
    """``runs_frame`` with every log in time order (positional index 0..n-1).

    With ``log`` and ``log_t_s`` (the runs frame of ``rafi.method.runs``): logs in order of
    first appearance, samples by the log's clock, so the runs of a log follow each other as
    recorded. Without them: runs in order of first appearance, samples by ``t_s``. Stable
    on ties.
    """
    if {"log", "log_t_s"} <= set(runs_frame.columns):
        group, clock = runs_frame["log"].astype(str), runs_frame["log_t_s"]
    else:
        group, clock = runs_frame["run_id"].astype(str), runs_frame["t_s"]
    codes = pd.factorize(group)[0]
    order = np.lexsort((clock.to_numpy(dtype=float, na_value=np.nan), codes))
    return runs_frame.iloc[order].reset_index(drop=True)


def coverage_and_width(measured, lower, upper) -> tuple[float, float]:
    """``coverage`` (fraction in [0, 1] of the samples with a finite measurement and interval that
    lie inside it, bounds included) and ``interval_width_um`` (median of ``upper - lower`` over
    those samples); NaN, NaN without such a sample."""
    m, lo, hi = (np.asarray(v, dtype=float) for v in (measured, lower, upper))
    ok = np.isfinite(m) & np.isfinite(lo) & np.isfinite(hi)
    if not ok.any():
        return float("nan"), float("nan")
    inside = (m[ok] >= lo[ok]) & (m[ok] <= hi[ok])
    return float(inside.mean()), float(np.median(hi[ok] - lo[ok]))


def _no_interval(frame: pd.DataFrame, predicted_um, outside, excess=None) -> pd.DataFrame:
    n = len(frame)
    return pd.DataFrame(
        {"lower_um": np.full(n, np.nan), "upper_um": np.full(n, np.nan), "interval_cell": [""] * n}
    )


def validate_runs(
    model, runs_table: pd.DataFrame, runs_frame: pd.DataFrame, *, bounds=None
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Compensate every validation run with ``model`` and measure the improvement.

    The model predicts the whole ``runs_frame`` once, in time order (:func:`time_ordered`),
    so a model that filters its inputs over a log sees the log's earlier samples (training
    and excluded runs included) before each validation run; each run is a slice of that
    prediction. A row-wise model gives the same numbers as predicting run by run.

    Parameters
    ----------
    model : rafi.method.model.RafiModel
        Anything with ``predict_detail(frame)`` returning ``predicted_um``,
        ``outside_temp_range`` and ``outside_speed_range`` (same rows as ``frame``).
    runs_table : pandas.DataFrame
        ``run_id``, ``role``, ``speed_rpm`` and (optional) ``duration_s``.
    runs_frame : pandas.DataFrame
        Stacked samples with ``run_id``, ``t_s``, ``speed_rpm``, the rises and ``dz_um``.
    bounds : callable, optional
        ``bounds(frame, predicted_um, outside, excess=)`` -> ``lower_um``, ``upper_um``,
        ``interval_cell`` per row of the time-ordered frame (``excess``: the detail's
        ``range_excess``, None for a model without it): the model's prediction interval
        (``functools.partial(rafi.family.intervals.interval_columns, model)``). Without it the
        bounds, ``coverage`` and ``interval_width_um`` are NaN.

    Returns
    -------
    summary : pandas.DataFrame
        One row per validation run, columns :data:`SUMMARY_COLUMNS`.
    residuals : pandas.DataFrame
        One row per sample of the validation runs, columns :data:`RESIDUAL_COLUMNS`.
    """
    for col in ("run_id", "role"):
        if col not in runs_table.columns:
            raise ValueError(f"runs_table lacks column {col!r}")
    for col in ("run_id", "t_s", "speed_rpm", "dz_um"):
        if col not in runs_frame.columns:
            raise ValueError(f"runs_frame lacks column {col!r}")
    roles = runs_table["role"].astype(str)
    val = runs_table.loc[roles.str.startswith("validation")]
    rows, parts = [], []
    sensors = input_sensors(model)
    if len(val):
        frame = time_ordered(runs_frame)
        whole = model.predict_detail(frame).reset_index(drop=True)
        outside = whole["outside_temp_range"].to_numpy(dtype=bool) | whole["outside_speed_range"].to_numpy(
            dtype=bool
        )
        predicted = whole["predicted_um"].to_numpy(dtype=float)
        excess = whole["range_excess"].to_numpy(dtype=float) if "range_excess" in whole.columns else None
        intervals = (bounds or _no_interval)(frame, predicted, outside, excess=excess)
        intervals = intervals.reset_index(drop=True)
        frame_ids = frame["run_id"].astype(str).to_numpy()
    for _, run in val.iterrows():
        run_id = str(run["run_id"])
        rows_of_run = np.flatnonzero(frame_ids == run_id)
        sub = frame.iloc[rows_of_run]
        detail = whole.iloc[rows_of_run]
        bounds = intervals.iloc[rows_of_run]
        measured = sub["dz_um"].to_numpy(dtype=float, na_value=np.nan)
        t_s = sub["t_s"].to_numpy(dtype=float, na_value=np.nan)
        speed = run.get("speed_rpm", np.nan)
        if pd.isna(speed) and len(sub):
            speed = np.nanmedian(sub["speed_rpm"].to_numpy(dtype=float, na_value=np.nan))
        speed = float(speed)
        rows.append(
            _run_summary(
                run_id,
                str(run["role"]),
                speed,
                run.get("duration_s"),
                detail=detail,
                measured=measured,
                t_s=t_s,
                bounds=bounds,
                sub=sub,
                sensors=sensors,
            )
        )
        pred = detail["predicted_um"].to_numpy(dtype=float)
        parts.append(
            pd.DataFrame(
                {
                    "run_id": run_id,
                    "t_s": t_s,
                    "speed_rpm": sub["speed_rpm"].to_numpy(dtype=float, na_value=np.nan),
                    "measured_um": measured,
                    "predicted_um": pred,
                    "residual_um": measured - pred,
                    "outside_temp_range": detail["outside_temp_range"].to_numpy(dtype=bool),
                    "outside_speed_range": detail["outside_speed_range"].to_numpy(dtype=bool),
                    "outside_envelope": _envelope_flags(detail),
                    "lower_um": bounds["lower_um"].to_numpy(dtype=float),
                    "upper_um": bounds["upper_um"].to_numpy(dtype=float),
                    "interval_cell": bounds["interval_cell"].to_numpy(dtype=object),
                }
            )
        )
    summary = pd.DataFrame(rows, columns=SUMMARY_COLUMNS)
    residuals = (
        pd.concat(parts, ignore_index=True)
        if parts
        else pd.DataFrame(
            {c: pd.Series(dtype=object if c == "interval_cell" else float) for c in RESIDUAL_COLUMNS}
        )
    )
    residuals = residuals[RESIDUAL_COLUMNS]
    summary = summary.astype(
        {
            "n_samples": "int64",
            "n_outside_temp_range": "int64",
            "n_outside_speed_range": "int64",
            "n_outside_envelope": "int64",
            "n_unpredicted": "int64",
            "unpredicted_inputs": "object",
            "worse_than_uncompensated": "bool",
        }
    )
    return summary, residuals


def qualify(summary: pd.DataFrame, gates: dict) -> pd.DataFrame:
    """Verdict per acceptance criterion and validation run.

    Parameters
    ----------
    summary : pandas.DataFrame
        From :func:`validate_runs`.
    gates : dict
        ``max_residual_um`` (float or None to skip), ``min_improvement_pct`` (float
        or None to skip), ``never_worse_than_uncompensated`` (bool), ``min_coverage`` (float
        in [0, 1] or None to skip; a summary without ``coverage`` fails it).

    Returns
    -------
    pandas.DataFrame
        Columns ``criterion``, ``limit``, ``measured``, ``passed``, ``run_id``: every gate
        for every validation run, idle cool-downs included (see the module docstring).
    """
    unknown = set(gates) - set(GATE_KEYS)
    if unknown:
        raise ValueError(f"unknown qualification gate(s): {sorted(unknown)}")
    max_res = gates.get("max_residual_um")
    min_imp = gates.get("min_improvement_pct")
    never_worse = bool(gates.get("never_worse_than_uncompensated", False))
    min_cov = gates.get("min_coverage")
    rows = []
    for _, run in summary.iterrows():
        after = float(run["max_abs_after_um"])
        before = float(run["max_abs_before_um"])
        if max_res is not None:
            rows.append(
                {
                    "criterion": "max_residual_um",
                    "limit": float(max_res),
                    "measured": after,
                    "passed": bool(after <= max_res),
                    "run_id": run["run_id"],
                }
            )
        if min_imp is not None:
            imp = float(run["improvement_pct"])
            rows.append(
                {
                    "criterion": "min_improvement_pct",
                    "limit": float(min_imp),
                    "measured": imp,
                    "passed": bool(imp >= min_imp),
                    "run_id": run["run_id"],
                }
            )
        if never_worse:
            rows.append(
                {
                    "criterion": "never_worse_than_uncompensated",
                    "limit": before,
                    "measured": after,
                    "passed": bool(after <= before),
                    "run_id": run["run_id"],
                }
            )
        if min_cov is not None:
            cov = float(run.get("coverage", np.nan))
            rows.append(
                {
                    "criterion": "min_coverage",
                    "limit": float(min_cov),
                    "measured": cov,
                    "passed": bool(cov >= min_cov),
                    "run_id": run["run_id"],
                }
            )
    verdict = pd.DataFrame(rows, columns=VERDICT_COLUMNS)
    verdict["passed"] = verdict["passed"].astype(bool)
    verdict["limit"] = verdict["limit"].astype(float)
    verdict["measured"] = verdict["measured"].astype(float)
    return verdict


def overall_passed(verdict: pd.DataFrame) -> bool:
    """True if there is at least one verdict row and every criterion passed.

    An empty verdict (no validation runs, or no gates) is *not* a pass: nothing
    was qualified.
    """
    return bool(len(verdict) > 0 and verdict["passed"].astype(bool).all())
