"""Features of the family's models: temperature rises, causal first-order filters, the
reference speed and whether the training runs identify a speed term (``docs/models.md``).

Evaluated with NumPy only: nothing here is fitted.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

from rafi.contract.sensors import run_sensors

SPEED_SCALE_RPM = 1000.0  # speed features are in krpm and krpm^2
SPEED_POWER_SCALE_RPM = 10000.0  # speed-power features use (n / 10000 r/min)^p
#: A term relative to the reference speed needs this many training runs that show a speed change.
MIN_IDENTIFYING_RUNS = 2


def rise_column(sensor: str) -> str:
    """Name of the rise column of ``sensor`` in a runs frame (``T6`` -> ``dT6``)."""
    return f"d{sensor}"


def times(frame: pd.DataFrame) -> np.ndarray:
    """``t_s`` of every row (s), or the row number where the frame has no time column."""
    return (
        frame["t_s"].to_numpy(dtype=float) if "t_s" in frame.columns else np.arange(len(frame), dtype=float)
    )


#: A sensor whose rise is missing on at most this share of the training rows stays an input of
#: the family's ridge models (the rows that miss it are left out of the fit); more, and the sensor
#: is left out. A dropout of minutes should not cost a sensor its place in the model.
MAX_MISSING_FRACTION = 0.05


def usable_sensors(
    runs_frame: pd.DataFrame,
    sensors: Sequence[str] | None = None,
    max_missing_fraction: float = MAX_MISSING_FRACTION,
) -> list[str]:
    """Sensors (of ``sensors``; every sensor of ``runs_frame`` when ``None``) whose rise column
    exists, is missing (NaN) on at most ``max_missing_fraction`` of
    the rows of ``runs_frame`` and is not constant over its finite values."""
    sensors = run_sensors(runs_frame) if sensors is None else sensors
    left_out = sensors_left_out(runs_frame, sensors, max_missing_fraction)
    return [s for s in sensors if rise_column(s) in runs_frame.columns and s not in left_out]


def sensors_left_out(
    runs_frame: pd.DataFrame,
    sensors: Sequence[str] | None = None,
    max_missing_fraction: float = MAX_MISSING_FRACTION,
) -> dict[str, str]:
    """Sensor -> why it is not usable (:func:`usable_sensors`), for the sensors of ``sensors``
    whose rise column is in ``runs_frame`` (a sensor the machine does not have is not listed).

    Returns
    -------
    dict
        ``"no value"``, ``"missing on 7.2 % of the rows"`` or ``"constant"``.
    """
    out = {}
    for s in run_sensors(runs_frame) if sensors is None else sensors:
        col = rise_column(s)
        if col not in runs_frame.columns:
            continue
        v = runs_frame[col].to_numpy(dtype=float)
        finite = np.isfinite(v)
        if not finite.any():
            out[s] = "no value"
        elif 1.0 - finite.mean() > max_missing_fraction:
            out[s] = f"missing on {100.0 * (1.0 - finite.mean()):.1f} % of the rows"
        elif np.ptp(v[finite]) <= 1e-9:
            out[s] = "constant"
    return out


def complete_rows(runs_frame: pd.DataFrame, sensors: Sequence[str]) -> np.ndarray:
    """Mask of the rows where the rise of every one of ``sensors`` is finite."""
    cols = [rise_column(s) for s in sensors]
    return np.isfinite(runs_frame[cols].to_numpy(dtype=float)).all(axis=1)


def lowpass_runs(
    values: np.ndarray,
    t_s: np.ndarray,
    run_codes: np.ndarray,
    taus_s: Sequence[float],
    initial: str = "settled",
) -> np.ndarray:
    """Causal first-order low-pass of every column of ``values`` for every ``tau``.

    ``y[k] = y[k-1] + (1 - exp(-(t[k] - t[k-1]) / tau)) * (x[k] - y[k-1])``, evaluated sample
    by sample inside each run (rows must be sorted by run then time). Initial condition: the
    filter starts *settled* on the run's first sample, ``y[0] = x[0]``; for a run referenced
    at its own start (``run_start``) that first rise is ~0, i.e. the filter starts from the
    reference state. ``tau = 0`` passes the input through. Returns
    ``(n, n_columns * len(taus))`` ordered tau-major. A NaN input holds the filter state.
    ``initial="zero"``: the state before the run's first sample is 0 (a cold start from rest:
    the first sample is then ``g0 * x[0]`` with ``g0`` the gain of one nominal sample step).
    """
    if initial not in ("settled", "zero"):
        raise ValueError(f"initial={initial!r}: use settled or zero")
    x = np.asarray(values, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    n, p = x.shape
    taus = np.asarray(list(taus_s), dtype=float)
    if len(taus) and (taus <= 0).all():
        return np.tile(x, (1, len(taus)))
    if (taus <= 0).any():  # pass-through columns need no loop
        parts = [x if tau <= 0 else lowpass_runs(x, t_s, run_codes, [tau], initial) for tau in taus]
        return np.column_stack(parts)
    out = np.empty((n, p * len(taus)))
    xx = np.tile(x, (1, len(taus)))
    tau_col = np.repeat(taus, p)
    dt = np.diff(np.asarray(t_s, dtype=float), prepend=np.nan)
    new_run = np.ones(n, dtype=bool)
    new_run[1:] = run_codes[1:] != run_codes[:-1]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        gain = np.where(
            tau_col[None, :] > 0, -np.expm1(-np.clip(dt, 0, None)[:, None] / tau_col[None, :]), 1.0
        )
    tt = np.asarray(t_s, dtype=float)
    step = float(np.median(np.diff(tt))) if n > 1 and np.isfinite(np.diff(tt)).any() else 1.0
    gain0 = -np.expm1(-max(step, 0.0) / tau_col)
    starts = np.flatnonzero(new_run)
    ends = np.append(starts[1:], n)
    for a, b in zip(starts, ends):
        seg = xx[a:b]
        dts = dt[a + 1 : b]
        if np.isfinite(seg).all() and (dts.size == 0 or np.allclose(dts, dts[0], rtol=1e-9, atol=0)):
            # regular grid, no gaps: the recursion is a first-order IIR filter per column
            out[a:b] = _lowpass_regular(seg, gain[a + 1] if b - a > 1 else gain0, gain0, initial)
            continue
        y = np.zeros(p * len(taus))
        for k in range(a, b):
            xk = xx[k]
            if k == a:
                y = np.where(np.isfinite(xk), gain0 * xk if initial == "zero" else xk, 0.0)
            else:
                y = np.where(np.isfinite(xk), y + gain[k] * (xk - y), y)
            out[k] = y
    return out


def _lowpass_regular(x: np.ndarray, gain: np.ndarray, gain0: np.ndarray, initial: str) -> np.ndarray:
    """:func:`lowpass_runs` on one run sampled on a regular grid with no missing value:
    ``y[k] = (1 - g) y[k-1] + g x[k]`` per column (same numbers as the sample loop, to
    rounding), computed by :func:`first_order_recursion`."""
    g = np.asarray(gain, dtype=float)
    y0 = np.asarray(gain0, dtype=float) * x[0] if initial == "zero" else x[0].astype(float)
    out = np.empty_like(x, dtype=float)
    out[0] = y0
    if len(x) > 1:
        out[1:] = first_order_recursion(x[1:], 1.0 - g, g, y0)
    return out


#: Largest growth of the scaling factor ``a**-k`` inside one block of :func:`first_order_recursion`.
_MAX_LOG_SCALE = 600.0


def first_order_recursion(x: np.ndarray, a: np.ndarray, b: np.ndarray, y0: np.ndarray) -> np.ndarray:
    """``y[k] = a y[k-1] + b x[k]`` down the rows of ``x``, per column, with ``y[-1] = y0``.

    Vectorised without a sample loop (and without importing scipy.signal, whose import alone
    costs about a second per job): inside a block of rows,
    ``y[k] = a^k (y0 + sum_{j<=k} b a^-j x[j])``, a cumulative sum. Blocks are short enough
    that ``a^-k`` stays below ``exp(600)``; the rounding error is then of the order of
    ``eps * max|x| * b / (1 - a)``, as for the recursion itself.
    """
    x = np.asarray(x, dtype=float)
    a = np.broadcast_to(np.asarray(a, dtype=float), x.shape[1:]).copy()
    b = np.broadcast_to(np.asarray(b, dtype=float), x.shape[1:])
    y_prev = np.broadcast_to(np.asarray(y0, dtype=float), x.shape[1:]).copy()
    out = np.empty_like(x)
    through = a <= 1e-300  # no memory: y = b x
    a[through] = 0.5  # any value: those columns are overwritten below
    log_a = np.log(a)
    block = max(1, int(_MAX_LOG_SCALE / max(float(np.max(-log_a)), 1e-300)))
    for start in range(0, len(x), block):
        seg = x[start : start + block]
        k = np.arange(1, len(seg) + 1, dtype=float).reshape((-1,) + (1,) * (x.ndim - 1))
        scale = np.exp(-k * log_a)  # a^-k
        y = (y_prev + np.cumsum(seg * (b * scale), axis=0)) / scale
        out[start : start + len(seg)] = y
        y_prev = y[-1]
    if through.any():
        out[:, through] = x[:, through] * b[through]
    return out


def run_order(frame: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Positions that sort ``frame`` by (run, t_s) and the run code per sorted row."""
    if "run_id" in frame.columns:
        runs = pd.factorize(frame["run_id"].astype(str))[0]
    else:
        runs = np.zeros(len(frame), dtype=int)
    t = times(frame)
    order = np.lexsort((t, runs))
    return order, runs[order]


def sorted_inputs(frame: pd.DataFrame, sensors: Sequence[str]):
    """What a ridge-family feature matrix is built from, rows sorted by (run, t_s).

    Returns ``order`` (positions that sort ``frame``), the run code, the rises of ``sensors``,
    ``t_s`` and the speed (r/min) per sorted row.
    """
    order, codes = run_order(frame)
    rises = frame[[rise_column(s) for s in sensors]].to_numpy(dtype=float)[order]
    rpm = frame["speed_rpm"].to_numpy(dtype=float)[order]
    return order, codes, rises, times(frame)[order], rpm


def reference_speed(frame: pd.DataFrame, rule: str, window_s: float) -> np.ndarray:
    """Speed of each row's reference state (r/min), the origin of the speed features.

    ``run_start``: median speed over the first ``window_s`` of the row's run (the same window
    the rises were referenced to); ``zero``: 0 r/min (a log that starts with the spindle at rest).
    """
    if rule not in ("run_start", "zero"):
        raise ValueError(f"speed reference rule {rule!r}: use run_start, zero or auto")
    n = len(frame)
    if rule == "zero" or n == 0:
        return np.zeros(n)
    codes = pd.factorize(frame["run_id"])[0] if "run_id" in frame.columns else np.zeros(n, dtype=int)
    t = times(frame)
    speed = frame["speed_rpm"].to_numpy(dtype=float)
    out = np.empty(n)
    for c in np.unique(codes):
        rows = np.flatnonzero(codes == c)
        tr = t[rows]
        out[rows] = np.median(speed[rows[tr <= tr.min() + window_s]])
    return out


def speed_change_evidence(
    frame: pd.DataFrame, n0: np.ndarray, tolerance_rpm: float, window_s: float
) -> list[str]:
    """Training runs that show a speed change relative to their reference speed ``n0``.

    A run counts when it has at least ``window_s`` (the reference window; at least one
    samples) of samples within ``tolerance_rpm`` of its reference speed **and** at least as
    long more than ``tolerance_rpm`` away from it: a step such as the spindle start after a
    rest. Only such a step separates an instantaneous speed term (the centrifugal draw-in,
    ``n^2 - n0^2``) from the reference and from the slow thermal terms. A run referenced while
    already spinning shows only speed jitter (never > tolerance); a run without any sample at
    its reference speed (e.g. ``n0 = 0`` for a log segment that starts spinning) shows no
    step either.
    """
    n = frame["speed_rpm"].to_numpy(dtype=float)
    if not len(n):
        return []
    runs = frame["run_id"].astype(str).to_numpy() if "run_id" in frame.columns else np.full(len(n), "run")
    t = times(frame)
    away = np.abs(n - np.asarray(n0, dtype=float)) > float(tolerance_rpm)
    at = np.abs(n - np.asarray(n0, dtype=float)) <= float(tolerance_rpm)
    out = []
    for r in pd.unique(runs):
        i = np.flatnonzero(runs == r)
        dt = np.diff(np.sort(t[i]))
        period = float(np.median(dt[dt > 0])) if (dt > 0).any() else 1.0
        need = max(1, int(math.ceil(float(window_s) / period - 1e-9)))
        if at[i].sum() >= need and away[i].sum() >= need:
            out.append(str(r))
    return out


def reference_median(
    values: np.ndarray, t_s: np.ndarray, run_codes: np.ndarray, window_s: float
) -> np.ndarray:
    """Per row, the median of ``values`` over the first ``window_s`` of the row's run (sorted rows)."""
    out = np.empty_like(values)
    starts = np.flatnonzero(np.r_[True, run_codes[1:] != run_codes[:-1]])
    ends = np.r_[starts[1:], len(run_codes)]
    for a, b in zip(starts, ends):
        w = a + np.flatnonzero(t_s[a:b] <= t_s[a] + window_s)
        out[a:b] = np.median(values[w], axis=0) if len(w) else 0.0
    return out
