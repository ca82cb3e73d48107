"""Cleaning one canonical log: a regular time grid, every change recorded.

:func:`clean_log` turns the canonical frame of a reader (``rafi.readers``) into the
*clean frame* of ``docs/design.md`` and an *audit table* with one row per action,
whose ``first_line`` / ``last_line`` point at lines of the SOURCE file (the index
of the canonical frame). The steps, in this order:

1. **Time order.** A row at most ``BACKWARDS_TOLERANCE_SAMPLES`` (3) sample
   periods earlier than the latest time before it is a local swap: rows are
   sorted (stable) by time and each backwards step is recorded (``reordered``).
   A larger backwards jump is a clock reset and raises
   :class:`~rafi.errors.RawFormatError` (file, line, column ``time``): sorting
   would silently interleave two stretches of the log. (Same limit as the
   ``backwards_tolerance_samples`` default of ``rafi.readers.checks.check_log``.)
2. **Duplicates.** Rows with the same timestamp as an earlier row are dropped,
   the first one is kept (``duplicate_dropped``; the detail says whether the
   values were identical or which columns differed).
3. **Open circuit.** Values equal to one of ``open_circuit_values`` in
   ``T1``..``T16`` and ``disp_um`` become NaN (``open_circuit_removed``, one row
   per sensor and run of consecutive lines); step 7 then treats them as dropouts.
4. **Grid.** Times are snapped to the nearest point of the grid
   ``first time + k * sample_period_s`` (``time_snapped`` when any row moved by
   more than 1 % of the period); rows that land on an occupied grid point are
   dropped as duplicates. ``t_s`` = seconds since the first sample.
5. **Gaps.** Missing grid points are inserted when the time between the two
   samples around the gap is at most ``max_interpolate_gap_s``
   (``gap_interpolated``); a longer gap starts a new ``segment`` and is never
   bridged (``gap_split``).
6. **Spikes** (``T1``..``T16``, ``disp_um``). A sample is a single-sample spike
   when it lies beyond *both* neighbouring valid samples of its segment, on the
   same side, by more than ``spike_threshold * sigma``; i.e. its distance from
   the median of the two neighbours exceeds the threshold plus half their spread.
   ``sigma`` is the MAD-based standard deviation of the column's first
   differences (1.4826 * MAD), floored at the logger resolution (smallest
   non-zero step) and at 0.01 (K or um), so a quantised or frozen signal does
   not make every step a spike. A genuine step (e.g. the displacement jump at a
   speed change) moves away from one neighbour only and is never flagged.
   Spikes are set to NaN and interpolated from their neighbours (``spike_replaced``).
7. **Dropouts.** Runs of NaN in a numeric column whose valid neighbours (same
   segment) are at most ``max_interpolate_gap_s`` apart are interpolated
   linearly (``dropout_interpolated``). Longer runs, and runs at the start or end
   of a segment, are LEFT NaN (``dropout_left_nan``): the clean frame may hold
   NaN in a sensor column and every later step must drop those samples or that
   sensor (``rafi.method.runs`` keeps them as NaN rises).
8. **Speed** is piecewise constant and never blended: missing values (dropouts
   and inserted gap rows) take the previous value of the segment (the next one at
   the start of a segment) (``speed_filled`` for dropouts).
9. **Extra columns.** Numeric extras are kept and gap-filled / interpolated like
   the sensors (no open-circuit or spike test); text extras are dropped from the
   clean frame (``column_dropped``; they stay in the raw file).

The input frame is never modified.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd

from rafi import SENSORS
from rafi.errors import RawFormatError
from rafi.settings import BACKWARDS_TOLERANCE_SAMPLES

#: Columns of the audit table, in order (``docs/design.md``).
AUDIT_COLUMNS = ("file", "action", "column", "first_line", "last_line", "n_rows", "detail")


#: Columns checked for open-circuit values and single-sample spikes.
SENSOR_COLUMNS = (*SENSORS, "disp_um")

#: Floor of the spike sigma in the column's unit (K for temperatures, um for displacement).
SPIKE_SIGMA_FLOOR = 0.01

#: Normal-consistency factor of the median absolute deviation.
MAD_TO_SIGMA = 1.4826

#: A snapped timestamp that moved by more than this fraction of the period is reported.
SNAP_REPORT_FRACTION = 0.01

#: The median sample interval may differ from ``sample_period_s`` by at most this fraction.
PERIOD_MISMATCH_FRACTION = 0.25


# --------------------------------------------------------------------------- helpers


class _Audit:
    """Collects audit rows as plain lists (fast, no per-row DataFrame)."""

    def __init__(self, file: str):
        self.file = file
        self.rows: list[tuple] = []

    def add(self, action: str, column: str, first_line, last_line, n_rows, detail: str) -> None:
        self.rows.append((self.file, action, column, int(first_line), int(last_line), int(n_rows), detail))

    def frame(self) -> pd.DataFrame:
        """Audit rows ordered by source line (stable: step order within a line)."""
        return _audit_frame(sorted(self.rows, key=lambda r: r[3]))


def _audit_frame(rows: list[tuple]) -> pd.DataFrame:
    cols = list(zip(*rows)) if rows else [[] for _ in AUDIT_COLUMNS]
    data = {}
    for name, values in zip(AUDIT_COLUMNS, cols):
        if name in ("first_line", "last_line", "n_rows"):
            data[name] = np.asarray(values, dtype="int64")
        else:
            data[name] = pd.array(list(values), dtype="str")
    return pd.DataFrame(data, columns=list(AUDIT_COLUMNS))


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (inclusive) indices of the runs of True in a 1-D boolean array."""
    m = np.concatenate(([False], np.asarray(mask, bool), [False]))
    d = np.diff(m.astype(np.int8))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1) - 1


def _fmt(x: float) -> str:
    return f"{x:.6g}"


def _fill_index(valid: np.ndarray, seg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the previous / next valid row of the same segment for each row (-1: none)."""
    n = len(valid)
    idx = np.arange(n)
    prev = np.maximum.accumulate(np.where(valid, idx, -1))
    nxt = np.minimum.accumulate(np.where(valid, idx, n)[::-1])[::-1]
    prev = np.where((prev >= 0) & (seg[np.clip(prev, 0, n - 1)] == seg), prev, -1)
    nxt = np.where((nxt < n) & (seg[np.clip(nxt, 0, n - 1)] == seg), nxt, -1)
    return prev, nxt


# --------------------------------------------------------------------------- clean_log


def clean_log(
    frame: pd.DataFrame,
    *,
    file,
    sample_period_s: float,
    max_interpolate_gap_s: float,
    spike_threshold: float,
    open_circuit_values: Iterable[float],
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Clean one canonical log onto a regular time grid and record every change.

    Parameters
    ----------
    frame : pandas.DataFrame
        Canonical frame (``rafi.readers.native.read_raw_log`` / ``read_log``): columns
        ``time``, ``speed_rpm``, ``T1``..``T16``, ``disp_um`` and extras; index =
        1-based line number in the source file. Not modified.
    file : str or os.PathLike
        Name of the source file, used in the audit table and in error messages.
    sample_period_s : float
        Logger sample period (grid spacing), seconds.
    max_interpolate_gap_s : float
        Longest time between two valid samples that may be bridged by linear
        interpolation (missing rows and sensor dropouts alike).
    spike_threshold : float
        Spike threshold in units of the robust sigma of the first differences.
    open_circuit_values : iterable of float
        Values a sensor reports when its circuit is open (become NaN).

    Returns
    -------
    clean_frame : pandas.DataFrame
        RangeIndex; columns ``time``, ``t_s``, ``speed_rpm``, ``T1``..``T16``,
        ``disp_um``, ``segment`` (int64), then the numeric extra columns. Sensor
        values may be NaN where a dropout was too long to interpolate. ``attrs``
        are copied from the input.
    audit_actions : pandas.DataFrame
        Columns ``file``, ``action``, ``column``, ``first_line``, ``last_line``,
        ``n_rows``, ``detail``; lines are lines of the source file. Actions:
        ``reordered``, ``duplicate_dropped``, ``open_circuit_removed``,
        ``time_snapped``, ``gap_interpolated``, ``gap_split``, ``spike_replaced``,
        ``dropout_interpolated``, ``dropout_left_nan``, ``speed_filled``,
        ``column_dropped``, ``assumed`` (a column the reader took from the config, not the
        file: ``attrs['metadata']['assumed']``, e.g. no time column).

    Raises
    ------
    RawFormatError
        On a clock reset (time goes backwards by more than
        ``BACKWARDS_TOLERANCE_SAMPLES`` sample periods), a missing timestamp, no rows, or a median
        sample interval far from ``sample_period_s``.
    ValueError
        On non-positive ``sample_period_s`` / ``max_interpolate_gap_s`` /
        ``spike_threshold``.

    Notes
    -----
    The steps and rules are listed in the module docstring.
    """
    file = str(file)
    period = float(sample_period_s)
    max_gap = float(max_interpolate_gap_s)
    if not period > 0 or not max_gap >= 0 or not float(spike_threshold) > 0:
        raise ValueError(
            "sample_period_s and spike_threshold must be positive and max_interpolate_gap_s non-negative"
        )
    missing = [c for c in ("time", "speed_rpm", *SENSOR_COLUMNS) if c not in frame.columns]
    if missing:
        raise RawFormatError(
            file,
            f"column(s) {', '.join(missing)} missing; expected the canonical frame of rafi.readers",
            column=missing[0],
        )
    if len(frame) == 0:
        raise RawFormatError(file, "no data rows")
    audit = _Audit(file)
    eps = 1e-9 * max(1.0, max_gap)

    # ---------------------------------------------------------------- columns
    lines = (
        np.asarray(frame.index, dtype="int64")
        if pd.api.types.is_integer_dtype(frame.index)
        else np.arange(1, len(frame) + 1, dtype="int64")
    )
    extras = [c for c in frame.columns if c not in ("time", "speed_rpm", *SENSOR_COLUMNS)]
    num_extras, text_extras = [], []
    for c in extras:
        col = frame[c]
        if pd.api.types.is_numeric_dtype(col) or pd.api.types.is_bool_dtype(col):
            num_extras.append(c)
        else:
            text_extras.append(c)
    meta = frame.attrs.get("metadata")
    for column, detail in ((meta.get("assumed") if isinstance(meta, dict) else None) or {}).items():
        audit.add("assumed", str(column), lines[0], lines[-1], len(frame), str(detail))  # from config
    for c in text_extras:
        audit.add(
            "column_dropped",
            str(c),
            lines[0],
            lines[-1],
            0,
            "text column not kept in the clean frame (it stays in the raw file)",
        )
    value_cols = ["speed_rpm", *SENSOR_COLUMNS, *num_extras]
    n_sensor = len(SENSOR_COLUMNS)  # value columns 1 .. n_sensor are sensors

    times = pd.to_datetime(frame["time"])
    tns = times.to_numpy(dtype="datetime64[ns]").view("int64")
    nat = tns == np.iinfo(np.int64).min
    if nat.any():
        i = int(np.argmax(nat))
        raise RawFormatError(
            file, "missing timestamp; expected an ISO-8601 time", line=int(lines[i]), column="time"
        )
    values = np.column_stack(
        [frame[c].to_numpy(dtype="float64", na_value=np.nan) for c in value_cols]
    )  # a copy: the input is never touched

    # ---------------------------------------------------------------- 1. time order
    if len(tns) > 1:
        runmax = np.maximum.accumulate(tns)
        back_ns = runmax[:-1] - tns[1:]  # > 0: row i+1 is earlier than before
        reset = back_ns > BACKWARDS_TOLERANCE_SAMPLES * period * 1e9 + 0.5
        if reset.any():
            i = int(np.argmax(reset)) + 1
            raise RawFormatError(
                file,
                f"timestamps go backwards by {_fmt(back_ns[i - 1] / 1e9)} s at line "
                f"{lines[i]}; expected increasing times (a clock reset? split the file or "
                "fix the clock)",
                line=int(lines[i]),
                column="time",
            )
        steps = np.flatnonzero(tns[1:] < tns[:-1]) + 1
        for i in steps:
            audit.add(
                "reordered",
                "time",
                lines[i - 1],
                lines[i],
                1,
                f"line {lines[i]} is {_fmt((tns[i - 1] - tns[i]) / 1e9)} s earlier than "
                f"line {lines[i - 1]}; rows sorted by time",
            )
        if len(steps):
            order = np.argsort(tns, kind="stable")
            tns, values, lines = tns[order], values[order], lines[order]

    # ---------------------------------------------------------------- 2. duplicates
    def drop_repeats(dup: np.ndarray, why: str) -> None:
        nonlocal tns, values, lines
        if not dup.any():
            return
        n = len(tns)
        keep_idx = np.maximum.accumulate(np.where(~dup, np.arange(n), 0))
        for i in np.flatnonzero(dup):
            k = keep_idx[i]
            a, b = values[i], values[k]
            differ = [value_cols[j] for j in np.flatnonzero(~((a == b) | (np.isnan(a) & np.isnan(b))))]
            if differ:
                detail = f"{why} line {lines[k]} but differs in {', '.join(differ)}; kept line {lines[k]}"
            else:
                detail = f"{why} line {lines[k]} with identical values; kept line {lines[k]}"
            audit.add("duplicate_dropped", "time", lines[i], lines[i], 1, detail)
        keep = ~dup
        tns, values, lines = tns[keep], values[keep], lines[keep]

    if len(tns) > 1:
        drop_repeats(np.concatenate(([False], tns[1:] == tns[:-1])), "same timestamp as")

    # ---------------------------------------------------------------- 3. open circuit
    oc = [float(v) for v in (open_circuit_values or [])]
    if oc:
        sens = values[:, 1 : 1 + n_sensor]
        is_oc = np.zeros(sens.shape, bool)
        for v in oc:
            is_oc |= np.abs(sens - v) <= 1e-9 * max(1.0, abs(v))
        for j in np.flatnonzero(is_oc.any(axis=0)):
            starts, ends = _runs(is_oc[:, j])
            for s, e in zip(starts, ends):
                audit.add(
                    "open_circuit_removed",
                    SENSOR_COLUMNS[j],
                    lines[s],
                    lines[e],
                    e - s + 1,
                    f"open-circuit value {_fmt(sens[s, j])} -> NaN (then treated as a dropout)",
                )
        sens[is_oc] = np.nan
        values[:, 1 : 1 + n_sensor] = sens

    # ---------------------------------------------------------------- 4. grid
    period_ns = int(round(period * 1e9))
    t0 = int(tns[0])
    rel = tns - t0
    if len(rel) > 2:
        med = float(np.median(np.diff(rel))) / 1e9
        if abs(med - period) > PERIOD_MISMATCH_FRACTION * period:
            raise RawFormatError(
                file,
                f"the median time between samples is {_fmt(med)} s; expected "
                f"the sample period {_fmt(period)} s (metadata "
                "'sample_period_s' or config)",
                column="time",
            )
    k = np.rint(rel / period_ns).astype("int64")
    shift = np.abs(rel - k * period_ns)
    moved = shift > SNAP_REPORT_FRACTION * period_ns
    if moved.any():
        idx = np.flatnonzero(moved)
        audit.add(
            "time_snapped",
            "time",
            lines[idx[0]],
            lines[idx[-1]],
            len(idx),
            f"{len(idx)} timestamps moved to the {_fmt(period)} s grid "
            f"(largest shift {_fmt(shift.max() / 1e9)} s)",
        )
    if len(k) > 1:
        collide = np.concatenate(([False], k[1:] == k[:-1]))
        if collide.any():
            kk = k
            drop_repeats(collide, f"snaps to the same {_fmt(period)} s grid point as")
            k = kk[~collide]

    # ---------------------------------------------------------------- 5. gaps and segments
    dk = np.diff(k)
    gap_at = np.flatnonzero(dk > 1)  # gap between row g and g + 1
    span = dk[gap_at] * period
    long_gap = span > max_gap + eps
    seg_start = np.concatenate(([0], gap_at[long_gap] + 1))
    seg_end = np.concatenate((gap_at[long_gap], [len(k) - 1]))
    for g, sp, lg in zip(gap_at, span, long_gap):
        n_miss = int(dk[g] - 1)
        if lg:
            audit.add(
                "gap_split",
                "time",
                lines[g],
                lines[g + 1],
                n_miss,
                f"{_fmt(sp)} s between samples (> max_interpolate_gap_s = {_fmt(max_gap)} s): "
                f"not bridged; a new segment starts at line {lines[g + 1]}",
            )
        else:
            audit.add(
                "gap_interpolated",
                "time",
                lines[g],
                lines[g + 1],
                n_miss,
                f"{n_miss} missing row(s) ({_fmt(sp)} s between samples) inserted; values "
                "interpolated linearly, speed carried forward",
            )
    grid_k = np.concatenate([np.arange(k[s], k[e] + 1) for s, e in zip(seg_start, seg_end)])
    seg = np.concatenate(
        [np.full(k[e] - k[s] + 1, i, dtype="int64") for i, (s, e) in enumerate(zip(seg_start, seg_end))]
    )
    pos = np.searchsorted(grid_k, k)
    n = len(grid_k)
    grid = np.full((n, values.shape[1]), np.nan, order="F")  # column-contiguous
    grid[pos] = values
    present = np.zeros(n, bool)
    present[pos] = True
    gline = np.full(n, -1, dtype="int64")
    gline[pos] = lines

    # ---------------------------------------------------------------- 6. spikes
    spike = np.zeros((n, values.shape[1]), bool, order="F")
    thr = float(spike_threshold)
    for j in range(1, 1 + n_sensor):
        col = grid[:, j]
        vi = np.flatnonzero(~np.isnan(col))
        if len(vi) < 3:
            continue
        v = col[vi]
        same = seg[vi[1:]] == seg[vi[:-1]]
        d = np.diff(v)[same]
        if len(d) == 0:
            continue
        sigma = MAD_TO_SIGMA * float(np.median(np.abs(d - np.median(d))))
        nz = np.abs(d)[np.abs(d) > 1e-9]
        resolution = float(nz.min()) if len(nz) else 0.0
        limit = thr * max(sigma, resolution, SPIKE_SIGMA_FLOOR)
        dl = v[1:-1] - v[:-2]
        dr = v[1:-1] - v[2:]
        ok = same[:-1] & same[1:] & ((grid_k[vi[2:]] - grid_k[vi[:-2]]) * period <= max_gap + eps)
        hit = ok & (np.sign(dl) == np.sign(dr)) & (np.minimum(np.abs(dl), np.abs(dr)) > limit)
        for h in np.flatnonzero(hit):
            r = vi[h + 1]
            spike[r, j] = True
            audit.add(
                "spike_replaced",
                value_cols[j],
                gline[r],
                gline[r],
                1,
                f"{_fmt(v[h + 1])} vs neighbours {_fmt(v[h])} and {_fmt(v[h + 2])} "
                f"(threshold {_fmt(limit)} = {_fmt(thr)} x robust sigma); interpolated",
            )
    grid[spike] = np.nan

    # ---------------------------------------------------------------- 7. interpolation
    for j in range(1, grid.shape[1]):
        col = grid[:, j]
        nanpos = np.flatnonzero(np.isnan(col))
        if len(nanpos) == 0:
            continue
        prev, nxt = _fill_index(~np.isnan(col), seg)
        p, q = prev[nanpos], nxt[nanpos]
        both = (p >= 0) & (q >= 0)
        pc, qc = np.where(both, p, nanpos), np.where(both, q, nanpos)
        kp, kq = grid_k[pc], grid_k[qc]
        span = (kq - kp) * period
        fill = both & (span <= max_gap + eps)
        w = (grid_k[nanpos] - kp) / np.where(kq > kp, kq - kp, 1)
        est = col[pc] + w * (col[qc] - col[pc])
        col[nanpos[fill]] = est[fill]  # grid is Fortran-ordered: col is a view
        # audit: NaN runs holding dropout cells (present rows, not spikes, not inserted rows)
        run_start = np.flatnonzero(np.concatenate(([True], np.diff(nanpos) > 1)))
        dcell = present[nanpos] & ~spike[nanpos, j]
        n_drop = np.add.reduceat(dcell.astype(np.int64), run_start)
        run_end = np.concatenate((run_start[1:], [len(nanpos)])) - 1
        name = value_cols[j]
        for r0, r1, nd in zip(run_start, run_end, n_drop):
            if nd == 0:
                continue
            cells = nanpos[r0 : r1 + 1][dcell[r0 : r1 + 1]]
            first, last = gline[cells[0]], gline[cells[-1]]
            if fill[r0]:
                audit.add(
                    "dropout_interpolated",
                    name,
                    first,
                    last,
                    nd,
                    f"{nd} missing value(s) ({_fmt(span[r0])} s between valid samples) interpolated linearly",
                )
            else:
                where = (
                    "at the start or end of a segment"
                    if not both[r0]
                    else f"{_fmt(span[r0])} s between valid samples "
                    f"(> max_interpolate_gap_s = {_fmt(max_gap)} s)"
                )
                audit.add(
                    "dropout_left_nan",
                    name,
                    first,
                    last,
                    nd,
                    f"{nd} missing value(s) {where}: left NaN; later steps drop these "
                    "samples for this sensor",
                )

    # ---------------------------------------------------------------- 8. speed
    speed = grid[:, 0]
    sval = ~np.isnan(speed)
    if not sval.all():
        sprev, snxt = _fill_index(sval, seg)
        src = np.where(sprev >= 0, sprev, snxt)
        need = ~sval & (src >= 0)
        speed_filled = speed.copy()
        speed_filled[need] = speed[src[need]]
        dropped = ~sval & present
        starts, ends = _runs(dropped)
        for s, e in zip(starts, ends):
            cells = np.flatnonzero(dropped[s : e + 1]) + s
            audit.add(
                "speed_filled",
                "speed_rpm",
                gline[cells[0]],
                gline[cells[-1]],
                len(cells),
                f"{len(cells)} missing speed value(s) set to the "
                f"{'previous' if sprev[s] >= 0 else 'next'} value (speed is piecewise "
                "constant, never interpolated)",
            )
        grid[:, 0] = speed_filled

    # ---------------------------------------------------------------- output
    t_s = grid_k * period
    out = {
        "time": (np.int64(t0) + grid_k * np.int64(period_ns)).view("datetime64[ns]"),
        "t_s": t_s.astype("float64"),
        "speed_rpm": grid[:, 0],
    }
    for j, name in enumerate(value_cols[1 : 1 + n_sensor], start=1):
        out[name] = grid[:, j]
    out["segment"] = seg
    for j, name in enumerate(num_extras, start=1 + n_sensor):
        out[name] = grid[:, j]
    clean = pd.DataFrame(out)
    clean.attrs = {key: (dict(val) if isinstance(val, dict) else val) for key, val in frame.attrs.items()}
    return clean, audit.frame()


# --------------------------------------------------------------------------- summary
