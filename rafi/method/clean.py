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

The input frame is never modified. Each step is a function of
:mod:`rafi.method.clean_steps`; :func:`clean_log` runs them in this order.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
import pandas as pd

from rafi.contract.sensors import frame_sensors
from rafi.errors import RawFormatError
from rafi.method.clean_steps import (  # noqa: F401 (the step constants: part of this module's API)
    MAD_TO_SIGMA,
    PERIOD_MISMATCH_FRACTION,
    SENSOR_COLUMNS,
    SNAP_REPORT_FRACTION,
    SPIKE_SIGMA_FLOOR,
    Grid,
    Samples,
    audit_row,
    bridge_gaps,
    drop_duplicate_times,
    fill_speed,
    interpolate_dropouts,
    remove_open_circuit,
    replace_spikes,
    sensor_end,
    snap_to_grid,
    sort_by_time,
)
from rafi.settings import BACKWARDS_TOLERANCE_SAMPLES  # noqa: F401 (named in the docstrings)

#: Columns of the audit table, in order (``docs/design.md``).
AUDIT_COLUMNS = ("file", "action", "column", "first_line", "last_line", "n_rows", "detail")


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

    samples, done = sort_by_time(samples, period, file)
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
    """The audit table of ``file`` from audit rows (:func:`rafi.method.clean_steps.audit_row`),
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
