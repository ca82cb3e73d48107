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
   ``backwards_tolerance_samples`` default of ``rafi.readers.checks.check_log``; both read
   ``rafi.settings.BACKWARDS_TOLERANCE_SAMPLES``.)
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
6. **Spikes** (``T1``..``T16``, ``disp_um``). A burst of 1 to ``MAX_SPIKE_SAMPLES`` (3)
   consecutive samples is a spike when every sample of it lies beyond *both* valid
   samples enclosing the burst in its segment, on the same side, by more than
   ``spike_threshold * sigma``; for one sample, its distance from the median of the
   two neighbours exceeds the threshold plus half their spread.
   ``sigma`` is the MAD-based standard deviation of the column's first
   differences (1.4826 * MAD), floored at the logger resolution (smallest
   non-zero step) and at 0.01 (K or um), so a quantised or frozen signal does
   not make every step a spike. A genuine step (e.g. the displacement jump at a
   speed change) moves away from one neighbour only and is never flagged; nor is an
   excursion longer than three samples (a change of state, not a glitch).
   Spikes are set to NaN and interpolated from their neighbours (``spike_replaced``, one
   row per burst, ``n_rows`` = its samples).
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

The input frame is never modified. Each step is a function of this module (after
:func:`clean_log`, in this order); :func:`clean_log` runs them.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from rafi.contract.sensors import DEFAULT_SENSORS, frame_sensors
from rafi.errors import RawFormatError
from rafi.settings import BACKWARDS_TOLERANCE_SAMPLES, backwards_cause

#: Columns of the audit table, in order (``docs/design.md``).
AUDIT_COLUMNS = ("file", "action", "column", "first_line", "last_line", "n_rows", "detail")

#: Columns checked for open-circuit values and spikes (value columns 1..16+1).
SENSOR_COLUMNS = (*DEFAULT_SENSORS, "disp_um")

#: Value columns ``1 .. SENSOR_END - 1`` are the sensors (column 0 is the speed) of the paper's
#: rig; :func:`sensor_end` gives it for any machine's value columns.
SENSOR_END = 1 + len(SENSOR_COLUMNS)

#: The value columns of the paper's rig: the speed, its sensors and the displacement.
DEFAULT_NAMES = ("speed_rpm", *SENSOR_COLUMNS)


def sensor_end(names: Sequence[str]) -> int:
    """One past the last measured channel among the value columns ``names`` (the speed, the
    temperature sensors, ``disp_um``, then the numeric extras): the index after ``disp_um``."""
    return list(names).index("disp_um") + 1


#: The longest burst of consecutive samples that counts as a spike (a logger or EMI glitch);
#: a longer excursion that returns is left alone: it may be a change of state.
MAX_SPIKE_SAMPLES = 3

#: Floor of the spike sigma in the column's unit (K for temperatures, um for displacement).
SPIKE_SIGMA_FLOOR = 0.01

#: Normal-consistency factor of the median absolute deviation.
MAD_TO_SIGMA = 1.4826

#: A snapped timestamp that moved by more than this fraction of the period is reported.
SNAP_REPORT_FRACTION = 0.01

#: The median sample interval may differ from ``sample_period_s`` by at most this fraction.
PERIOD_MISMATCH_FRACTION = 0.25


@dataclass(frozen=True)
class Samples:
    """The rows of a log before the grid: times (ns since the epoch), values, source lines."""

    times_ns: np.ndarray
    values: np.ndarray  # rows x value columns
    lines: np.ndarray

    def take(self, rows: np.ndarray) -> Samples:
        """The rows ``rows`` (indices or a boolean mask), as a new :class:`Samples`."""
        return Samples(self.times_ns[rows], self.values[rows], self.lines[rows])


@dataclass(frozen=True)
class Grid:
    """The log on its regular time grid: one row per grid point from the first sample on.

    ``index`` is the grid point (time = ``origin_ns + index * period``), ``segment`` the
    segment, ``line`` the source line (-1 for an inserted row), ``present`` whether the file
    had a row there; ``values`` is column-contiguous (rows x value columns, NaN = missing).
    """

    index: np.ndarray
    segment: np.ndarray
    line: np.ndarray
    present: np.ndarray
    values: np.ndarray
    origin_ns: int


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
    period, max_gap, threshold = check_arguments(sample_period_s, max_interpolate_gap_s, spike_threshold)
    check_frame(frame, file)
    lines = source_lines(frame)
    numeric_extras, text_extras = split_extras(frame)
    names = ("speed_rpm", *frame_sensors(frame), "disp_um", *numeric_extras)
    rows = column_rows(frame, lines, text_extras)
    samples = Samples(timestamps_ns(frame, lines, file), value_array(frame, names), lines)

    samples, done = sort_by_time(samples, period, frame.attrs.get("source") or file, _sheet_of(frame))
    rows += done
    samples, done = drop_duplicate_times(samples, names)
    rows += done
    samples, done = remove_open_circuit(samples, open_circuit_values, names)
    rows += done
    samples, grid_index, done = snap_to_grid(samples, period, file, names)
    rows += done
    grid, done = bridge_gaps(samples, grid_index, period, max_gap)
    rows += done
    grid, spike, done = replace_spikes(grid, period, max_gap, threshold, names)
    rows += done
    grid, done = interpolate_dropouts(grid, spike, period, max_gap, names)
    rows += done
    grid, done = fill_speed(grid)
    rows += done
    return grid_frame(grid, period, names, frame.attrs), audit_frame(file, rows)


# --------------------------------------------------------------------------- input and output


def check_arguments(
    sample_period_s: float, max_interpolate_gap_s: float, spike_threshold: float
) -> tuple[float, float, float]:
    """The three numeric settings as floats; ValueError unless period and threshold are positive
    and the gap non-negative."""
    period, max_gap, threshold = float(sample_period_s), float(max_interpolate_gap_s), float(spike_threshold)
    if not period > 0 or not max_gap >= 0 or not threshold > 0:
        raise ValueError(
            "sample_period_s and spike_threshold must be positive and max_interpolate_gap_s non-negative"
        )
    return period, max_gap, threshold


def check_frame(frame: pd.DataFrame, file: str) -> None:
    """RawFormatError unless ``frame`` has the canonical columns and at least one row."""
    missing = [c for c in ("time", "speed_rpm", "disp_um") if c not in frame.columns]
    if not missing and not frame_sensors(frame):
        missing = ["a temperature sensor between speed_rpm and disp_um"]
    if missing:
        raise RawFormatError(
            file,
            f"column(s) {', '.join(missing)} missing; expected the canonical frame of rafi.readers",
            column=missing[0],
        )
    if len(frame) == 0:
        raise RawFormatError(file, "no data rows")


def source_lines(frame: pd.DataFrame) -> np.ndarray:
    """The source line of each row: the integer index, else 1, 2, ..."""
    if pd.api.types.is_integer_dtype(frame.index):
        return np.asarray(frame.index, dtype="int64")
    return np.arange(1, len(frame) + 1, dtype="int64")


def split_extras(frame: pd.DataFrame) -> tuple[list[str], list[str]]:
    """The extra columns (not canonical), numeric (bool included) and text, in frame order."""
    numeric, text = [], []
    canonical = ("time", "speed_rpm", *frame_sensors(frame), "disp_um")
    for c in frame.columns:
        if c in canonical:
            continue
        col = frame[c]
        if pd.api.types.is_numeric_dtype(col) or pd.api.types.is_bool_dtype(col):
            numeric.append(c)
        else:
            text.append(c)
    return numeric, text


def column_rows(frame: pd.DataFrame, lines: np.ndarray, text_extras: Sequence[str]) -> list[tuple]:
    """Audit rows of whole columns: ``assumed`` (the reader took the column from the config:
    ``attrs['metadata']['assumed']``), then ``column_dropped`` for every text extra."""
    rows = []
    meta = frame.attrs.get("metadata")
    for column, detail in ((meta.get("assumed") if isinstance(meta, dict) else None) or {}).items():
        rows.append(audit_row("assumed", str(column), lines[0], lines[-1], len(frame), str(detail)))
    for c in text_extras:
        detail = "text column not kept in the clean frame (it stays in the raw file)"
        rows.append(audit_row("column_dropped", str(c), lines[0], lines[-1], 0, detail))
    return rows


def timestamps_ns(frame: pd.DataFrame, lines: np.ndarray, file: str) -> np.ndarray:
    """The ``time`` column as int64 nanoseconds; RawFormatError at the first missing one."""
    times = pd.to_datetime(frame["time"]).to_numpy(dtype="datetime64[ns]").view("int64")
    missing = times == np.iinfo(np.int64).min  # NaT
    if missing.any():
        i = int(np.argmax(missing))
        raise RawFormatError(
            file, "missing timestamp; expected an ISO-8601 time", line=int(lines[i]), column="time"
        )
    return times


def value_array(frame: pd.DataFrame, names: Sequence[str]) -> np.ndarray:
    """The columns ``names`` as a new float array (rows x columns; missing = NaN)."""
    return np.column_stack([frame[c].to_numpy(dtype="float64", na_value=np.nan) for c in names])


def grid_frame(grid: Grid, period_s: float, names: Sequence[str], attrs: dict) -> pd.DataFrame:
    """The clean frame of a cleaned grid: ``time``, ``t_s``, the speed and sensors, ``segment``,
    then the numeric extras; ``attrs`` copied (one level deep)."""
    period_ns = int(round(period_s * 1e9))
    out = {
        "time": (np.int64(grid.origin_ns) + grid.index * np.int64(period_ns)).view("datetime64[ns]"),
        "t_s": (grid.index * period_s).astype("float64"),
    }
    end = sensor_end(names)
    for j, name in enumerate(names[:end]):
        out[name] = grid.values[:, j]
    out["segment"] = grid.segment
    for j, name in enumerate(names[end:], start=end):
        out[name] = grid.values[:, j]
    clean = pd.DataFrame(out)
    clean.attrs = {key: (dict(val) if isinstance(val, dict) else val) for key, val in attrs.items()}
    return clean


def audit_frame(file: str, rows: list[tuple]) -> pd.DataFrame:
    """The audit table of ``file`` from audit rows (:func:`audit_row`),
    ordered by source line (stable: step order within a line)."""
    rows = [(file, *row) for row in sorted(rows, key=lambda r: r[2])]
    cols = list(zip(*rows)) if rows else [[] for _ in AUDIT_COLUMNS]
    data = {}
    for name, values in zip(AUDIT_COLUMNS, cols):
        if name in ("first_line", "last_line", "n_rows"):
            data[name] = np.asarray(values, dtype="int64")
        else:
            data[name] = pd.array(list(values), dtype="str")
    return pd.DataFrame(data, columns=list(AUDIT_COLUMNS))


# --------------------------------------------------------------------------- the steps
#
# Every step takes what the step before it returned and returns new values (the arrays it is
# given are never modified) and the audit rows of what it did: tuples ``(action, column,
# first_line, last_line, n_rows, detail)`` (:func:`audit_row`; ``clean_log`` adds the file name).
# Before the grid the log is a :class:`Samples` (rows in file order, then sorted); from the grid
# on it is a :class:`Grid` (one row per grid point, inserted rows included). The value columns
# of both are ``speed_rpm``, the sensors :data:`SENSOR_COLUMNS`, then the numeric extras, in
# that order; ``names`` are their names.


def audit_row(action: str, column: str, first_line, last_line, n_rows, detail: str) -> tuple:
    """One audit row (without the file): ``(action, column, first_line, last_line, n_rows, detail)``."""
    return (action, column, int(first_line), int(last_line), int(n_rows), detail)


def fmt(x: float) -> str:
    """A number for an audit detail or a message: 6 significant digits."""
    return f"{x:.6g}"


def true_runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end (inclusive) indices of the runs of True in a 1-D boolean array."""
    padded = np.concatenate(([False], np.asarray(mask, bool), [False]))
    step = np.diff(padded.astype(np.int8))
    return np.flatnonzero(step == 1), np.flatnonzero(step == -1) - 1


def neighbours_in_segment(valid: np.ndarray, segment: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index of the previous / next valid row (a row counts itself) of the same segment; -1: none."""
    n = len(valid)
    idx = np.arange(n)
    prev = np.maximum.accumulate(np.where(valid, idx, -1))
    nxt = np.minimum.accumulate(np.where(valid, idx, n)[::-1])[::-1]
    prev = np.where((prev >= 0) & (segment[np.clip(prev, 0, n - 1)] == segment), prev, -1)
    nxt = np.where((nxt < n) & (segment[np.clip(nxt, 0, n - 1)] == segment), nxt, -1)
    return prev, nxt


def bridgeable(span_s, max_gap_s: float):
    """Whether two valid samples ``span_s`` seconds apart may be bridged by interpolation
    (``span_s <= max_gap_s``, with a float slack of 1e-9 relative)."""
    return span_s <= max_gap_s + 1e-9 * max(1.0, max_gap_s)


# --------------------------------------------------------------------------- before the grid


def sort_by_time(
    samples: Samples, period_s: float, file: str, sheet: str | None = None
) -> tuple[Samples, list[tuple]]:
    """Step 1: sort the rows by time (stable); each local backwards step is ``reordered``.

    ``file`` (the raw file's path) and ``sheet`` (of a workbook) name the error.

    Raises
    ------
    RawFormatError
        A step back of more than ``BACKWARDS_TOLERANCE_SAMPLES`` periods (a clock reset, or a
        daylight-saving change of a local clock: the message says which is likelier).
    """
    times, lines = samples.times_ns, samples.lines
    if len(times) <= 1:
        return samples, []
    back_ns = np.maximum.accumulate(times)[:-1] - times[1:]  # > 0: row i+1 is earlier than before
    reset = back_ns > BACKWARDS_TOLERANCE_SAMPLES * period_s * 1e9 + 0.5
    if reset.any():
        i = int(np.argmax(reset)) + 1
        back_s = back_ns[i - 1] / 1e9
        raise RawFormatError(
            file,
            f"timestamps go backwards by {fmt(back_s)} s at {'row' if sheet else 'line'} "
            f"{lines[i]}; expected increasing times ({backwards_cause(back_s)})",
            line=int(lines[i]),
            column="time",
            sheet=sheet,
        )
    steps = np.flatnonzero(times[1:] < times[:-1]) + 1
    rows = [
        audit_row(
            "reordered",
            "time",
            lines[i - 1],
            lines[i],
            1,
            f"line {lines[i]} is {fmt((times[i - 1] - times[i]) / 1e9)} s earlier than "
            f"line {lines[i - 1]}; rows sorted by time",
        )
        for i in steps
    ]
    if not len(steps):
        return samples, rows
    return samples.take(np.argsort(times, kind="stable")), rows


def _sheet_of(frame: pd.DataFrame) -> str | None:
    """The workbook sheet a frame was read from (``attrs['metadata']['sheet']``), else None."""
    meta = frame.attrs.get("metadata")
    sheet = meta.get("sheet") if isinstance(meta, dict) else None
    return sheet if isinstance(sheet, str) else None


def drop_repeated_rows(
    samples: Samples, repeated: np.ndarray, why: str, names: Sequence[str]
) -> tuple[Samples, list[tuple]]:
    """Drop the rows marked ``repeated``; the row each repeats is the last unmarked row before it.

    One ``duplicate_dropped`` row per dropped row; its detail starts with ``why`` (e.g. "same
    timestamp as") and says whether the values were identical or which columns differed.
    """
    if not repeated.any():
        return samples, []
    values, lines = samples.values, samples.lines
    kept_of = np.maximum.accumulate(np.where(~repeated, np.arange(len(repeated)), 0))
    rows = []
    for i in np.flatnonzero(repeated):
        k = kept_of[i]
        a, b = values[i], values[k]
        differ = [names[j] for j in np.flatnonzero(~((a == b) | (np.isnan(a) & np.isnan(b))))]
        if differ:
            detail = f"{why} line {lines[k]} but differs in {', '.join(differ)}; kept line {lines[k]}"
        else:
            detail = f"{why} line {lines[k]} with identical values; kept line {lines[k]}"
        rows.append(audit_row("duplicate_dropped", "time", lines[i], lines[i], 1, detail))
    return samples.take(~repeated), rows


def drop_duplicate_times(samples: Samples, names: Sequence[str]) -> tuple[Samples, list[tuple]]:
    """Step 2: a row with the timestamp of the row before it (rows sorted) is dropped."""
    times = samples.times_ns
    if len(times) <= 1:
        return samples, []
    return drop_repeated_rows(
        samples, np.concatenate(([False], times[1:] == times[:-1])), "same timestamp as", names
    )


def remove_open_circuit(
    samples: Samples, open_circuit_values: Iterable[float], names: Sequence[str] = DEFAULT_NAMES
) -> tuple[Samples, list[tuple]]:
    """Step 3: sensor values equal (1e-9 relative) to an open-circuit value become NaN.

    One ``open_circuit_removed`` row per sensor and run of consecutive rows.
    """
    codes = [float(v) for v in (open_circuit_values or [])]
    if not codes:
        return samples, []
    values = samples.values.copy()
    channels = names[1 : sensor_end(names)]
    sensors = values[:, 1 : sensor_end(names)]  # a view: setting it sets ``values``
    is_open = np.zeros(sensors.shape, bool)
    for code in codes:
        is_open |= np.abs(sensors - code) <= 1e-9 * max(1.0, abs(code))
    rows = []
    for j in np.flatnonzero(is_open.any(axis=0)):
        for s, e in zip(*true_runs(is_open[:, j])):
            rows.append(
                audit_row(
                    "open_circuit_removed",
                    channels[j],
                    samples.lines[s],
                    samples.lines[e],
                    e - s + 1,
                    f"open-circuit value {fmt(sensors[s, j])} -> NaN (then treated as a dropout)",
                )
            )
    sensors[is_open] = np.nan
    return Samples(samples.times_ns, values, samples.lines), rows


def snap_to_grid(
    samples: Samples, period_s: float, file: str, names: Sequence[str]
) -> tuple[Samples, np.ndarray, list[tuple]]:
    """Step 4: the grid point of every row (``times_ns[0] + k * period``); rows that land on an
    occupied point are dropped as duplicates.

    Returns the remaining rows, their grid index ``k`` (increasing) and the audit rows
    (``time_snapped`` when a row moved by more than ``SNAP_REPORT_FRACTION`` of the period,
    then ``duplicate_dropped``).

    Raises
    ------
    RawFormatError
        The median time between samples is further than ``PERIOD_MISMATCH_FRACTION`` from
        ``period_s``.
    """
    period_ns = int(round(period_s * 1e9))
    lines = samples.lines
    rel = samples.times_ns - int(samples.times_ns[0])
    if len(rel) > 2:
        median_s = float(np.median(np.diff(rel))) / 1e9
        if abs(median_s - period_s) > PERIOD_MISMATCH_FRACTION * period_s:
            raise RawFormatError(
                file,
                f"the median time between samples is {fmt(median_s)} s; expected "
                f"the sample period {fmt(period_s)} s (metadata "
                "'sample_period_s' or config)",
                column="time",
            )
    k = np.rint(rel / period_ns).astype("int64")
    shift = np.abs(rel - k * period_ns)
    moved = np.flatnonzero(shift > SNAP_REPORT_FRACTION * period_ns)
    rows = []
    if len(moved):
        rows.append(
            audit_row(
                "time_snapped",
                "time",
                lines[moved[0]],
                lines[moved[-1]],
                len(moved),
                f"{len(moved)} timestamps moved to the {fmt(period_s)} s grid "
                f"(largest shift {fmt(shift.max() / 1e9)} s)",
            )
        )
    if len(k) > 1:
        collide = np.concatenate(([False], k[1:] == k[:-1]))
        if collide.any():
            samples, dropped = drop_repeated_rows(
                samples, collide, f"snaps to the same {fmt(period_s)} s grid point as", names
            )
            rows += dropped
            k = k[~collide]
    return samples, k, rows


def bridge_gaps(
    samples: Samples, k: np.ndarray, period_s: float, max_gap_s: float
) -> tuple[Grid, list[tuple]]:
    """Step 5: the rows on the full grid; a gap up to ``max_gap_s`` gets inserted NaN rows
    (``gap_interpolated``), a longer one starts a new segment (``gap_split``)."""
    lines = samples.lines
    step = np.diff(k)
    gap_at = np.flatnonzero(step > 1)  # gap between row g and g + 1
    span = step[gap_at] * period_s
    long_gap = ~bridgeable(span, max_gap_s)
    seg_start = np.concatenate(([0], gap_at[long_gap] + 1))
    seg_end = np.concatenate((gap_at[long_gap], [len(k) - 1]))
    rows = []
    for g, gap_s, is_long in zip(gap_at, span, long_gap):
        n_missing = int(step[g] - 1)
        if is_long:
            detail = (
                f"{fmt(gap_s)} s between samples (> max_interpolate_gap_s = {fmt(max_gap_s)} s): "
                f"not bridged; a new segment starts at line {lines[g + 1]}"
            )
        else:
            detail = (
                f"{n_missing} missing row(s) ({fmt(gap_s)} s between samples) inserted; values "
                "interpolated linearly, speed carried forward"
            )
        action = "gap_split" if is_long else "gap_interpolated"
        rows.append(audit_row(action, "time", lines[g], lines[g + 1], n_missing, detail))
    index = np.concatenate([np.arange(k[s], k[e] + 1) for s, e in zip(seg_start, seg_end)])
    segment = np.concatenate(
        [np.full(k[e] - k[s] + 1, i, dtype="int64") for i, (s, e) in enumerate(zip(seg_start, seg_end))]
    )
    pos = np.searchsorted(index, k)
    n = len(index)
    values = np.full((n, samples.values.shape[1]), np.nan, order="F")  # column-contiguous
    values[pos] = samples.values
    present = np.zeros(n, bool)
    present[pos] = True
    line = np.full(n, -1, dtype="int64")
    line[pos] = lines
    return Grid(index, segment, line, present, values, int(samples.times_ns[0])), rows


# --------------------------------------------------------------------------- on the grid


def spike_limit(diffs: np.ndarray, threshold: float) -> float:
    """The spike limit of a column: ``threshold`` x its robust sigma.

    ``diffs`` are the column's first differences inside segments; sigma is
    ``MAD_TO_SIGMA`` x their median absolute deviation, floored at the logger resolution
    (the smallest non-zero step) and at ``SPIKE_SIGMA_FLOOR``, so a quantised or frozen signal
    does not make every step a spike.
    """
    sigma = MAD_TO_SIGMA * float(np.median(np.abs(diffs - np.median(diffs))))
    steps = np.abs(diffs)[np.abs(diffs) > 1e-9]
    resolution = float(steps.min()) if len(steps) else 0.0
    return threshold * max(sigma, resolution, SPIKE_SIGMA_FLOOR)


def find_spikes(
    column: np.ndarray, grid: Grid, period_s: float, max_gap_s: float, threshold: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """The spikes of one column of the grid: single samples and short bursts.

    A burst of 1 to :data:`MAX_SPIKE_SAMPLES` consecutive valid samples of a segment is a
    spike when every sample of it lies beyond *both* valid samples enclosing the burst, on the
    same side, by more than :func:`spike_limit`, and the two enclosing samples are close
    enough to be bridged (:func:`bridgeable`). Shorter bursts are tested first; bursts that
    overlap or touch merge into one (a glitch of two samples followed by a smaller third).
    A step moves away from one enclosing sample only, and a plateau longer than
    :data:`MAX_SPIKE_SAMPLES` is a change of state, so neither is flagged.

    Returns
    -------
    spikes, before, after : numpy.ndarray of int
        Grid rows of the spike samples and, for each, of the valid samples enclosing its burst.
    limit : float
        The column's spike limit (NaN when the column has too few valid samples).
    """
    none = np.array([], dtype="int64")
    valid = np.flatnonzero(~np.isnan(column))
    if len(valid) < 3:
        return none, none, none, float("nan")
    v = column[valid]
    segment = grid.segment[valid]
    same = segment[1:] == segment[:-1]
    diffs = np.diff(v)[same]
    if len(diffs) == 0:
        return none, none, none, float("nan")
    limit = spike_limit(diffs, threshold)
    marked = np.zeros(len(v), bool)
    for length in range(1, MAX_SPIKE_SAMPLES + 1):
        first = np.arange(len(v) - length - 1)  # position of the sample before the burst
        if len(first) == 0:
            break
        last = first + length + 1  # position of the sample after it
        burst = np.lib.stride_tricks.sliding_window_view(v, length)[1 : len(v) - length]
        from_before = burst - v[first, None]
        from_after = burst - v[last, None]
        side = np.sign(from_before[:, :1])
        one_side = (np.sign(from_before) == side).all(axis=1) & (np.sign(from_after) == side).all(axis=1)
        far = np.minimum(np.abs(from_before), np.abs(from_after)).min(axis=1) > limit
        span_s = (grid.index[valid[last]] - grid.index[valid[first]]) * period_s
        enclosed = (segment[first] == segment[last]) & bridgeable(span_s, max_gap_s)
        hit = np.flatnonzero(one_side & far & enclosed)
        for offset in range(1, length + 1):
            marked[hit + offset] = True
    starts, ends = true_runs(marked)
    count = ends - starts + 1
    positions = np.flatnonzero(marked)
    before = np.repeat(starts - 1, count)
    after = np.repeat(ends + 1, count)
    return valid[positions], valid[before], valid[after], limit


def replace_spikes(
    grid: Grid, period_s: float, max_gap_s: float, threshold: float, names: Sequence[str]
) -> tuple[Grid, np.ndarray, list[tuple]]:
    """Step 6: spikes of the sensors, single samples and short bursts (:func:`find_spikes`),
    become NaN (step 7 interpolates them); one ``spike_replaced`` row per spike.

    Returns the grid, the spike mask (grid rows x value columns) and the audit rows.
    """
    values = grid.values
    spike = np.zeros(values.shape, bool, order="F")
    rows = []
    for j in range(1, sensor_end(names)):
        column = values[:, j]
        spikes, before, after, limit = find_spikes(column, grid, period_s, max_gap_s, threshold)
        spike[spikes, j] = True
        for group in (
            np.split(np.arange(len(spikes)), np.flatnonzero(np.diff(before)) + 1) if len(spikes) else []
        ):
            r, b, a = spikes[group], before[group[0]], after[group[0]]
            shown = (
                fmt(column[r[0]])
                if len(r) == 1
                else f"{len(r)} samples " + ", ".join(fmt(x) for x in column[r])
            )
            rows.append(
                audit_row(
                    "spike_replaced",
                    names[j],
                    grid.line[r[0]],
                    grid.line[r[-1]],
                    len(r),
                    f"{shown} vs neighbours {fmt(column[b])} and {fmt(column[a])} "
                    f"(threshold {fmt(limit)} = {fmt(threshold)} x robust sigma); interpolated",
                )
            )
    values = values.copy(order="F")
    values[spike] = np.nan
    return replace(grid, values=values), spike, rows


@dataclass(frozen=True)
class MissingValues:
    """The missing values of one grid column and how they were treated by
    :func:`interpolate_column` (one entry per missing value, in grid order)."""

    rows: np.ndarray  # grid rows of the NaN values
    enclosed: np.ndarray  # a valid value before and after it in the segment
    span_s: np.ndarray  # time between those two valid values (0 when not enclosed)
    filled: np.ndarray  # enclosed and bridgeable: interpolated


def interpolate_column(
    column: np.ndarray, grid: Grid, period_s: float, max_gap_s: float
) -> tuple[np.ndarray, MissingValues]:
    """A grid column with every NaN interpolated linearly (on the grid index) between the valid
    values around it, where both are in its segment and :func:`bridgeable`; other NaN stay.

    Returns the new column and its :class:`MissingValues` (as they were before filling).
    """
    missing = np.flatnonzero(np.isnan(column))
    if len(missing) == 0:
        none = np.array([], dtype=bool)
        return column.copy(), MissingValues(missing, none, np.array([], dtype=float), none)
    prev, nxt = neighbours_in_segment(~np.isnan(column), grid.segment)
    p, q = prev[missing], nxt[missing]
    enclosed = (p >= 0) & (q >= 0)
    before, after = np.where(enclosed, p, missing), np.where(enclosed, q, missing)
    k_before, k_after = grid.index[before], grid.index[after]
    span_s = (k_after - k_before) * period_s
    filled = enclosed & bridgeable(span_s, max_gap_s)
    weight = (grid.index[missing] - k_before) / np.where(k_after > k_before, k_after - k_before, 1)
    estimate = column[before] + weight * (column[after] - column[before])
    out = column.copy()
    out[missing[filled]] = estimate[filled]
    return out, MissingValues(missing, enclosed, span_s, filled)


def dropout_rows(
    name: str, missing: MissingValues, dropped: np.ndarray, line: np.ndarray, max_gap_s: float
) -> list[tuple]:
    """The audit rows of one column's stretches of missing values that hold dropouts.

    ``dropped`` marks, per missing value, a dropout: a value the file's row lacked (not an
    inserted row, not a spike). A stretch of consecutive missing values is reported once,
    ``dropout_interpolated`` or ``dropout_left_nan``, with the lines and count of its dropouts.
    """
    rows = []
    if len(missing.rows) == 0:
        return rows
    run_start = np.flatnonzero(np.concatenate(([True], np.diff(missing.rows) > 1)))
    run_end = np.concatenate((run_start[1:], [len(missing.rows)])) - 1
    n_dropped = np.add.reduceat(dropped.astype(np.int64), run_start)
    for r0, r1, n in zip(run_start, run_end, n_dropped):
        if n == 0:
            continue
        cells = missing.rows[r0 : r1 + 1][dropped[r0 : r1 + 1]]
        first, last = line[cells[0]], line[cells[-1]]
        span = fmt(missing.span_s[r0])
        if missing.filled[r0]:
            detail = f"{n} missing value(s) ({span} s between valid samples) interpolated linearly"
            rows.append(audit_row("dropout_interpolated", name, first, last, n, detail))
            continue
        where = (
            f"{span} s between valid samples (> max_interpolate_gap_s = {fmt(max_gap_s)} s)"
            if missing.enclosed[r0]
            else "at the start or end of a segment"
        )
        detail = (
            f"{n} missing value(s) {where}: left NaN; a sample that needs this value is not fitted or "
            "scored, and the family's ridge models leave the sensor out if any training sample of it "
            "is missing (docs/models.md)"
        )
        rows.append(audit_row("dropout_left_nan", name, first, last, n, detail))
    return rows


def interpolate_dropouts(
    grid: Grid, spike: np.ndarray, period_s: float, max_gap_s: float, names: Sequence[str]
) -> tuple[Grid, list[tuple]]:
    """Step 7: every value column but the speed through :func:`interpolate_column`; audit rows of
    the dropouts (:func:`dropout_rows`; gaps and spikes have their own rows)."""
    values = grid.values.copy(order="F")
    rows = []
    for j in range(1, values.shape[1]):
        values[:, j], missing = interpolate_column(values[:, j], grid, period_s, max_gap_s)
        dropped = grid.present[missing.rows] & ~spike[missing.rows, j]
        rows += dropout_rows(names[j], missing, dropped, grid.line, max_gap_s)
    return replace(grid, values=values), rows


def carry_speed(speed: np.ndarray, segment: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Missing speeds set to the previous valid speed of the segment, else the next one.

    Returns the filled speed and, per row, whether a previous valid speed exists.
    """
    prev, nxt = neighbours_in_segment(~np.isnan(speed), segment)
    source = np.where(prev >= 0, prev, nxt)
    fill = np.isnan(speed) & (source >= 0)
    out = speed.copy()
    out[fill] = speed[source[fill]]
    return out, prev >= 0


def fill_speed(grid: Grid) -> tuple[Grid, list[tuple]]:
    """Step 8: the speed is piecewise constant and never blended (:func:`carry_speed`); one
    ``speed_filled`` row per stretch of the file's rows without a speed."""
    speed = grid.values[:, 0]
    if not np.isnan(speed).any():
        return grid, []
    filled, has_previous = carry_speed(speed, grid.segment)
    rows = []
    for s, e in zip(*true_runs(np.isnan(speed) & grid.present)):
        n = e - s + 1
        rows.append(
            audit_row(
                "speed_filled",
                "speed_rpm",
                grid.line[s],
                grid.line[e],
                n,
                f"{n} missing speed value(s) set to the "
                f"{'previous' if has_previous[s] else 'next'} value (speed is piecewise "
                "constant, never interpolated)",
            )
        )
    values = grid.values.copy(order="F")
    values[:, 0] = filled
    return replace(grid, values=values), rows
