"""Filtered features over whole logs (``docs/models.md``, "Whole-log dynamics").

A runs frame of :func:`rafi.method.runs.find_runs` holds whole logs: every sample of a file is
in exactly one run, and ``log`` / ``log_t_s`` / ``segment`` say where. The family's
first-order filters then run **causally over each log** in ``log_t_s`` order, carrying their
state through cool-downs and short gaps; they restart (settled on the first finite sample) only
at the start of a log or after a gap longer than ``models: filter_restart_gap_s``. Because the
rises are relative to each run's reference, the *absolute* input is filtered (``T_i``, speed
powers) and the filtered value is referenced to the run's reference window (the window the
rises use): a feature is 0 at the run's reference state and carries the lag state of a run
that does not start cold.

A frame without ``log`` / ``log_t_s`` (old frames, synthetic tests) is filtered per run, as
before (:func:`rafi.family.features.lowpass_runs`, settled on the run's first sample).

Evaluated with NumPy only: nothing here is fitted.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from rafi.family.features import SPEED_POWER_SCALE_RPM, lowpass_runs, reference_median, rise_column, times

#: Largest exponent of the scaling factor inside one block of :func:`lowpass_log`.
_MAX_EXPONENT = 600.0
#: Decay exponent that marks a restart of the filter state (state weight ``exp(-1e9) = 0``).
_RESTART = 1e9


def has_whole_logs(frame: pd.DataFrame) -> bool:
    """True if ``frame`` says where each sample sits in its log (``log`` and ``log_t_s``)."""
    return {"log", "log_t_s"} <= set(frame.columns)


@dataclass(frozen=True)
class Layout:
    """How the rows of a frame are filtered: sort order, clock, restarts, reference windows.

    Attributes
    ----------
    order : ndarray
        Positions that sort the frame (by log then ``log_t_s``; per-run mode: by run then ``t_s``).
    t : ndarray
        Time (s) of every sorted row: ``log_t_s`` (whole logs) or ``t_s`` (per run).
    whole_logs : bool
        True: one filter per log; False: one per run (the filter settles on each run's first sample).
    restart : ndarray of bool
        Sorted rows where the filter restarts (log start, gap longer than the restart limit;
        per run: each run's first row).
    codes : ndarray
        Run code of every sorted row.
    ref_group : ndarray
        Reference group of every sorted row (the run under ``run_start``, the log segment
        under ``log_start``).
    ref_rows : list of ndarray
        Per reference group, the sorted rows of its reference window.
    """

    order: np.ndarray
    t: np.ndarray
    whole_logs: bool
    restart: np.ndarray
    codes: np.ndarray
    ref_group: np.ndarray
    ref_rows: list


def _window_rows(t: np.ndarray, rows: np.ndarray, window_s: float) -> np.ndarray:
    """The rows of ``rows`` (time order) within ``window_s`` of the first: the rule of
    :func:`rafi.method.runs.find_runs` (``t < t0 + window``, at least one sample)."""
    tr = t[rows]
    m = max(1, int(np.searchsorted(tr, tr[0] + float(window_s) - 1e-9, side="left")))
    return rows[:m]


def layout(frame: pd.DataFrame, *, rule: str, window_s: float, restart_gap_s: float) -> Layout:
    """The :class:`Layout` of ``frame``.

    Whole logs (``log``, ``log_t_s`` present): rows sorted by log (order of first appearance)
    and ``log_t_s``; the filter restarts at a log's first sample and after a gap longer than
    ``restart_gap_s``; the reference window of a row is the first ``window_s`` of its run
    (``rule == "run_start"``) or of its log segment (``log_start``; ``segment`` 0 where the
    frame has no such column). Otherwise rows are sorted by run and ``t_s`` and every run restarts.
    """
    n = len(frame)
    runs = (
        pd.factorize(frame["run_id"].astype(str))[0] if "run_id" in frame.columns else np.zeros(n, dtype=int)
    )
    if not has_whole_logs(frame):
        t_run = times(frame)
        order = np.lexsort((t_run, runs))
        codes = runs[order]
        restart = np.r_[True, codes[1:] != codes[:-1]] if n else np.zeros(0, dtype=bool)
        return Layout(order, t_run[order], False, restart, codes, codes, [])
    logs = pd.factorize(frame["log"].astype(str))[0]
    t_log = frame["log_t_s"].to_numpy(dtype=float)
    order = np.lexsort((t_log, logs))
    t = t_log[order]
    lg = logs[order]
    codes = runs[order]
    new_log = np.r_[True, lg[1:] != lg[:-1]] if n else np.zeros(0, dtype=bool)
    gap = np.r_[0.0, np.diff(t)] if n else np.zeros(0)
    restart = new_log | (gap > float(restart_gap_s))
    if rule == "run_start":
        key = codes
    else:
        has_seg = "segment" in frame.columns
        seg = frame["segment"].to_numpy(dtype="int64")[order] if has_seg else np.zeros(n, dtype="int64")
        key = pd.factorize(pd.Series(lg).astype(str) + "/" + pd.Series(seg).astype(str))[0]
    groups, first, ref_group = np.unique(key, return_index=True, return_inverse=True)
    ref_rows = []
    for g in range(len(groups)):
        rows = np.flatnonzero(ref_group == g)
        ref_rows.append(_window_rows(t, rows, window_s))
    return Layout(order, t, True, restart, codes, ref_group.reshape(-1), ref_rows)


def lowpass_log(
    values: np.ndarray, t_s: np.ndarray, restart: np.ndarray, taus_s: Sequence[float]
) -> np.ndarray:
    """Causal first-order low-pass of every column of ``values`` (rows in time order).

    ``y[k] = y[k-1] + (1 - exp(-(t[k] - t[k-1]) / tau)) * (x[k] - y[k-1])`` (exact for a
    zero-order-hold input, any spacing). At a row where ``restart`` is true the filter starts
    settled on the first finite sample (rows before it: NaN). A NaN input holds the state.
    ``tau = 0`` passes the input through. Returns ``(n, n_columns * len(taus))``, tau-major.

    Vectorised: ``y[k] = sum_j w_j x_j exp(-(c_k - c_j))`` with ``c`` the cumulative decay
    exponent ``sum dt / tau``, evaluated in blocks whose exponent stays below 600 (the rounding
    error is that of the recursion, about ``eps * max|x| * tau / dt``).
    """
    x = np.asarray(values, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    n, p = x.shape
    taus = [float(v) for v in taus_s]
    out = np.empty((n, p * len(taus)))
    if n == 0:
        return out
    t = np.asarray(t_s, dtype=float)
    restart = np.asarray(restart, dtype=bool).copy()
    restart[0] = True
    finite = np.isfinite(x)
    x0 = np.where(finite, x, 0.0)
    dt = np.clip(np.r_[0.0, np.diff(t)], 0.0, None)
    piece = np.cumsum(restart) - 1
    count = np.cumsum(finite, axis=0)
    before = (count - finite)[np.flatnonzero(restart)][piece]  # finite samples before the piece
    seen = count - before > 0  # a finite sample so far in this piece (column-wise)
    first = finite & (count - finite - before == 0)  # the piece's first finite sample
    for i, tau in enumerate(taus):
        cols = slice(i * p, (i + 1) * p)
        if tau <= 0:
            out[:, cols] = x
            continue
        inc = np.where(finite, (dt / tau)[:, None], 0.0)
        inc[first] = _RESTART
        w = np.where(finite, -np.expm1(-inc), 0.0)
        out[:, cols] = np.where(seen, _decay_sum(x0 * w, inc), np.nan)
    return out


def _decay_sum(u: np.ndarray, inc: np.ndarray) -> np.ndarray:
    """``y[k] = exp(-inc[k]) y[k-1] + u[k]`` down the rows, per column, ``y[-1] = 0``.

    Evaluated in blocks (:func:`_decay_blocks`) whose summed exponent stays below
    :data:`_MAX_EXPONENT`: a block's first row by one explicit step, the rest relative to it.
    """
    y = np.empty_like(u)
    prev = np.zeros(u.shape[1])
    for s, e in _decay_blocks(inc):
        y[s] = np.exp(-inc[s]) * prev + u[s]
        if e > s + 1:
            d = np.cumsum(inc[s + 1 : e], axis=0)  # in [0, 600]: no restart inside a block
            y[s + 1 : e] = np.exp(-d) * (y[s] + np.cumsum(u[s + 1 : e] * np.exp(d), axis=0))
        prev = y[e - 1]
    return y


def _decay_blocks(inc: np.ndarray) -> list[tuple[int, int]]:
    """The row blocks ``[start, end)`` of :func:`_decay_sum`.

    A restart (a row whose largest exponent reaches ``2 * _MAX_EXPONENT``: a filter's first
    sample, where the old state weighs exactly 0) always starts a block, and the exponent is
    summed from there: the blocks of a log, and so its filtered values to the last bit, are
    those of the log alone, whichever logs come before it in the frame (the cross-validation
    folds share a log's features, :mod:`rafi.family.feature_memo`).
    """
    n = len(inc)
    step = np.minimum(inc.max(axis=1), 2 * _MAX_EXPONENT) if n else np.zeros(0)
    starts = np.union1d([0], np.flatnonzero(step >= 2 * _MAX_EXPONENT)) if n else np.zeros(0, int)
    blocks = []
    for a, b in zip(starts, np.append(starts[1:], n)):
        summed = np.cumsum(step[a:b])
        s = a
        while s < b:
            e = max(s + 1, a + int(np.searchsorted(summed, summed[s - a] + _MAX_EXPONENT, side="right")))
            blocks.append((int(s), int(e)))
            s = e
    return blocks


def reference_values(filtered: np.ndarray, lay: Layout) -> np.ndarray:
    """Per sorted row, the median (NaN ignored) of ``filtered`` over its reference window."""
    ref = np.full((len(lay.ref_rows), filtered.shape[1]), np.nan)
    for g, rows in enumerate(lay.ref_rows):
        w = filtered[rows]
        ok = np.isfinite(w).any(axis=0)
        if ok.any():
            ref[g, ok] = np.nanmedian(w[:, ok], axis=0)
    return ref[lay.ref_group]


def filtered_rises(
    frame: pd.DataFrame, lay: Layout, sensors: Sequence[str], taus: Sequence[float]
) -> np.ndarray:
    """``L_tau`` of the rises of ``sensors`` for every ``tau`` (sorted rows, tau-major).

    Whole logs: ``L_tau(T_i)`` over the log minus its median over the row's reference window
    (``tau = 0``: the rise ``dT_i`` itself). Per run: :func:`lowpass_runs` of ``dT_i``.
    """
    rises = frame[[rise_column(s) for s in sensors]].to_numpy(dtype=float)[lay.order]
    if not lay.whole_logs:
        return lowpass_runs(rises, lay.t, lay.codes, taus)
    slow = [tau for tau in taus if tau > 0]
    if slow:
        absolute = frame[list(sensors)].to_numpy(dtype=float)[lay.order]
        f = lowpass_log(absolute, lay.t, lay.restart, slow)
        f = f - reference_values(f, lay)
    p, parts, k = len(sensors), [], 0
    for tau in taus:
        if tau > 0:
            parts.append(f[:, k * p : (k + 1) * p])
            k += 1
        else:
            parts.append(rises)
    return np.column_stack(parts) if parts else np.empty((len(rises), 0))


def filtered_inputs(
    values: np.ndarray, lay: Layout, taus: Sequence[float], *, initial: str, referenced: bool, window_s: float
) -> np.ndarray:
    """``L_tau`` of absolute inputs ``values`` (sorted rows), e.g. the speed powers.

    Whole logs: filtered over the log (settled at a restart) minus the median over the row's
    reference window. Per run: :func:`lowpass_runs` with ``initial``, minus the median over
    the run's first ``window_s`` if ``referenced``.
    """
    if lay.whole_logs:
        f = lowpass_log(values, lay.t, lay.restart, taus)
        return f - reference_values(f, lay)
    f = lowpass_runs(values, lay.t, lay.codes, taus, initial=initial)
    if referenced:
        f = f - reference_median(f, lay.t, lay.codes, window_s)
    return f


def heat_input(
    rpm: np.ndarray,
    lay: Layout,
    taus: Sequence[float],
    powers: Sequence[float],
    *,
    running_rpm: float,
    cold_start: bool,
    window_s: float,
) -> np.ndarray:
    """The heat-input features ``L_tau((|n| / 10^4 r/min)^p)`` (sorted rows; one block of
    ``len(powers)`` columns per ``tau``), ``p = 0`` meaning running (1, ``|n| > running_rpm``) or
    at rest (0). Filtered by :func:`filtered_inputs`: per-run frames from zero and referenced
    under a cold start (``reference.rule: run_start``), else settled on the first sample."""
    r = np.abs(rpm) / SPEED_POWER_SCALE_RPM
    pw = np.column_stack([(np.abs(rpm) > running_rpm).astype(float) if p == 0 else r**p for p in powers])
    return filtered_inputs(
        pw, lay, taus, initial="zero" if cold_start else "settled", referenced=cold_start, window_s=window_s
    )


def unsort(sorted_values: np.ndarray, lay: Layout) -> np.ndarray:
    """Rows of ``sorted_values`` back in the frame's row order (``sorted_values`` itself when
    the frame was in that order already, as a runs frame is)."""
    if np.array_equal(lay.order, np.arange(len(lay.order))):
        return sorted_values
    out = np.empty_like(sorted_values)
    out[lay.order] = sorted_values
    return out


def rows_of_logs(frame: pd.DataFrame, run_ids) -> np.ndarray:
    """Boolean mask of the rows of ``frame`` a model needs to evaluate the runs ``run_ids``:
    the whole logs that contain them (whole-log frames) or just their rows."""
    ids = set(map(str, run_ids))
    in_runs = frame["run_id"].astype(str).isin(ids).to_numpy()
    if not has_whole_logs(frame):
        return in_runs
    log = frame["log"].astype(str)
    # unique() rather than set(): iterating a column of Arrow strings costs ~1 us per row
    return log.isin(log[in_runs].unique()).to_numpy()
