"""The clock of a mapped log: parsed from its time column, or built from the row number.

``input.time.kind`` says where a mapped file's times come from (``docs/raw-format.md``):

* ``timestamp``: a column of dates and times (``time.format``, or ISO-8601), or a column of the
  time of day with the date in another (``time.date_column``: :func:`date_and_time`) or in the
  file name (``time.date_from_name``: :func:`name_dated_times`);
* ``elapsed_s``: a column of seconds (or ``h:mm:ss`` cells) counted from ``time.start``;
  ``elapsed_min`` and ``elapsed_h`` the same in minutes or hours (a duration cell is a duration);
* ``epoch_s``, ``epoch_ms``, ``excel_days``: a clock written as a number from a fixed origin
  (:data:`rafi.contract.input.EPOCH_CLOCKS`: Unix seconds or milliseconds, UTC; Excel's serial
  day numbers, the logger's own time): dates, ``time.start`` not read;
* ``none``: the file has no time column. Data row k (0-based, in file order, blank lines
  not counted) is at ``time.start + k * time.period_s``: a logger that writes one row per
  period and never misses one. The times are *assumed*, not measured, and the frame says so
  in ``attrs['metadata']['assumed']`` (see :func:`assumed_notes`).

Without ``time.start`` an ``elapsed_s`` or ``none`` log has no clock (:func:`has_clock`): its
times count from :data:`rafi.contract.input.NO_CLOCK_EPOCH` for the arithmetic, and the frame says
``attrs['metadata']['clock'] = False`` so that no later step shows them as dates.

The speed of a log without a speed column is a configured constant
(:func:`rafi.readers.input_spec.constant_speed`); its note is worded here too.
"""

from __future__ import annotations

import datetime as dt
import re

import numpy as np
import pandas as pd

from rafi.contract import ELAPSED_SECONDS, EPOCH_CLOCKS, NO_CLOCK_EPOCH
from rafi.errors import RawFormatError
from rafi.readers.mapped_table import Table, numeric
from rafi.readers.name_dates import (
    cell_text,
    dates_in_name,
    day_offsets,
    is_time_of_day,
    time_of_day_hint,
    time_of_day_seconds,
)
from rafi.readers.parsing import TIME_MAX, TIME_MIN

#: The unit of an elapsed time column, in words (its messages).
ELAPSED_WORDS = {
    "elapsed_s": "seconds",
    "elapsed_min": "minutes",
    "elapsed_h": "hours",
    "epoch_s": "seconds since 1970-01-01 (Unix time)",
    "epoch_ms": "milliseconds since 1970-01-01 (Unix time)",
    "excel_days": "days since 1899-12-30 (an Excel date number)",
}


def timestamps(table: Table, values: list, spec: dict, column: str, col_index: int) -> pd.Series:
    """The time column of a mapped file as naive timestamps (``input.time.kind`` timestamp or elapsed_s).

    Parameters
    ----------
    table : Table
        The file (words the error).
    values : list
        The cells of the time column, in row order.
    spec : dict
        The normalised ``input:`` mapping.
    column : str
        The header as written in the file.
    col_index : int
        0-based column index.

    Returns
    -------
    pandas.Series
        One timestamp per row (naive; UTC where the text carried an offset).

    Raises
    ------
    RawFormatError
        At the first cell that is empty, not a time, or outside 1678..2261.
    """
    if spec["time"]["kind"] in ELAPSED_SECONDS or spec["time"]["kind"] in EPOCH_CLOCKS:
        return _elapsed_times(table, values, spec, column, col_index)
    if spec["time"]["date_from_name"] is not None:
        times = name_dated_times(table, values, spec, column, col_index)
    else:
        times = _text_times(values, spec["time"]["format"])
    if times is None:
        times = _cell_times(table, values, spec["time"]["format"], column, col_index)
    zone = spec["time"]["timezone"]
    return times if zone is None else local_to_utc(table, values, times, zone, column, col_index)


#: A text time ending in a UTC offset (``Z``, ``+01:00``, ``-0500``).
_UTC_OFFSET = re.compile(r"(?:[zZ]|[+-]\d{2}:?\d{2})$")


def local_to_utc(
    table: Table, values: list, times: pd.Series, zone: str, column: str, col_index: int
) -> pd.Series:
    """Naive local times of the time zone ``zone`` (``input.time.timezone``) as naive UTC.

    A clock that goes back an hour in the autumn writes one hour twice: the order of the rows
    tells which is which (``ambiguous="infer"``); a time the spring change skips is moved
    forward. So the times rise where the clock went back, and no false gap opens where it
    went forward.

    Parameters
    ----------
    table : Table
        The file (words the error).
    values : list
        The cells of the time column, in row order.
    times : pandas.Series
        The cells as naive times.
    zone : str
        An IANA time zone name.
    column : str
        The header as written in the file.
    col_index : int
        0-based column index.

    Raises
    ------
    RawFormatError
        A cell carries a UTC offset (it says its zone itself), or the repeated hour of a
        fall-back cannot be told apart by the order of the rows.
    """
    for k, v in enumerate(values):
        if isinstance(v, str) and _UTC_OFFSET.search(v.strip()):
            raise table.error(
                f"{v.strip()!r} carries a UTC offset, while input.time.timezone is {zone!r}: the offset "
                "says the zone already; leave input.time.timezone out",
                row=table.row_numbers[k],
                column=column,
                col_index=col_index,
            )
    try:
        local = pd.DatetimeIndex(times).tz_localize(zone, ambiguous="infer", nonexistent="shift_forward")
    except (ValueError, TypeError) as exc:  # pytz's AmbiguousTimeError is a ValueError
        found = re.search(r"(\d{4}-\d{2}-\d{2} \d{2}:\d{2}:\d{2})", str(exc))
        at = pd.Timestamp(found.group(1)) if found else None
        hits = np.flatnonzero(pd.DatetimeIndex(times) == at) if at is not None else []
        k = int(hits[0]) if len(hits) else 0
        raise table.error(
            f"{values[k]!r} lies in the hour repeated when the clock of {zone} went back, and the order "
            "of the rows does not tell which of the two it is (no row repeats it, or the rows are not "
            "in time order); split the file there, or leave input.time.timezone out",
            row=table.row_numbers[k],
            column=column,
            col_index=col_index,
        ) from None
    return pd.Series(local.tz_convert("UTC").tz_localize(None), index=times.index)


def date_and_time(dates: list, times: list) -> list:
    """The cells of a date column and a time-of-day column as one cell per row
    (``input.time.date_column``): a workbook's date and time cells combined into a
    ``datetime``, anything else as the text ``"<date> <time>"`` (a date cell written as its ISO
    date, a time cell as ``HH:MM:SS``), ready for :func:`timestamps` and ``time.format``. A row
    whose date or time is empty stays empty.

    Parameters
    ----------
    dates, times : list
        The cells of the two columns, in row order.
    """
    out = []
    for d, t in zip(dates, times):
        if d is None or t is None or str(d).strip() == "" or str(t).strip() == "":
            out.append(None)
            continue
        if isinstance(d, dt.datetime):
            d = d.date()
        if isinstance(t, dt.datetime):
            t = t.time()
        if isinstance(d, dt.date) and isinstance(t, dt.time):
            out.append(dt.datetime.combine(d, t))
            continue
        day = d.isoformat() if isinstance(d, dt.date) else str(d).strip()
        clock = t.isoformat() if isinstance(t, dt.time) else str(t).strip()
        out.append(f"{day} {clock}")
    return out


def _elapsed_times(table: Table, values: list, spec: dict, column: str, col_index: int) -> pd.Series:
    """A column of seconds (minutes, hours: ``time.kind``; or ``h:mm:ss`` cells) from
    ``time.start``, as naive timestamps.

    Parameters
    ----------
    table : Table
        The file (words the error).
    values : list
        The cells of the time column, in row order: numbers, text, or the
        ``datetime.time`` / ``datetime.timedelta`` of a duration cell.
    spec : dict
        The normalised ``input:`` mapping, ``time.kind`` ``elapsed_s``.
    column : str
        The header as written in the file.
    col_index : int
        0-based column index.

    Returns
    -------
    pandas.Series
        ``time.start`` (made naive UTC) plus each cell's seconds, rounded to the nanosecond.

    Raises
    ------
    RawFormatError
        At the first cell that is not a number, is empty, or lands outside 1678..2261.
    """
    tm = spec["time"]
    per = EPOCH_CLOCKS[tm["kind"]][1] if tm["kind"] in EPOCH_CLOCKS else ELAPSED_SECONDS[tm["kind"]]
    word = ELAPSED_WORDS[tm["kind"]]
    secs = []
    for v in values:
        if isinstance(v, dt.timedelta):
            v = v.total_seconds() / per
        elif isinstance(v, dt.time):
            v = (v.hour * 3600 + v.minute * 60 + v.second + v.microsecond / 1e6) / per
        secs.append(v)
    expected = word if tm["kind"] in EPOCH_CLOCKS else f"elapsed {word}"
    try:
        sec = numeric(table, secs, spec["decimal"], column, col_index, expected) * per
    except RawFormatError as exc:
        what = f"a number of {expected}"
        summary = footer_error(table, values, _is_elapsed_cell, column, col_index, exc, what=what)
        raise summary or exc from None
    if tm["kind"] == "excel_days":
        sec = np.round(sec, 3)  # Excel keeps milliseconds; its day fractions are not exact in binary
    empty = np.isnan(sec)
    if empty.any():
        k = int(np.argmax(empty))
        raise table.error(
            f"empty time; expected {expected}",
            row=table.row_numbers[k],
            column=column,
            col_index=col_index,
        )
    start = _start(spec)
    lo = (TIME_MIN - start).total_seconds()
    hi = (TIME_MAX - start).total_seconds()
    bad = (sec < lo) | (sec > hi)
    if bad.any():
        k = int(np.argmax(bad))
        where = (
            f"{values[k]!r} {word}"
            if tm["kind"] in EPOCH_CLOCKS
            else f"{values[k]!r} {word} from {_start_text(tm)}"
        )
        raise table.error(
            f"{where} is outside the supported years 1678..2261",
            row=table.row_numbers[k],
            column=column,
            col_index=col_index,
        )
    return pd.Series(start + pd.to_timedelta(np.round(sec * 1e9).astype("int64"), unit="ns"))


def _text_times(values: list, time_format: str | None) -> pd.Series | None:
    """All-text timestamps parsed at once (the fast path for CSV); None when any cell needs a closer look.

    Parameters
    ----------
    values : list
        The cells of the time column, in row order.
    time_format : str or None
        ``input.time.format`` (a ``strftime`` format); None for ISO-8601.

    Returns
    -------
    pandas.Series or None
        Naive timestamps (UTC where the text carried an offset) when every cell is
        non-empty text that parses to a time in 1678..2261; else None, and
        :func:`_cell_times` finds and words the first bad cell.
    """
    if not (values and all(isinstance(v, str) and v.strip() for v in values)):
        return None
    strings = pd.Series([v.strip() for v in values], dtype=object)
    try:
        if time_format:
            parsed = pd.to_datetime(strings, format=time_format, errors="coerce", utc=True)
        else:
            parsed = pd.to_datetime(strings, format="ISO8601", errors="coerce", utc=True)
        naive = parsed.dt.tz_convert(None)
        if naive.notna().all() and ((naive >= TIME_MIN) & (naive <= TIME_MAX)).all():
            return naive
    except (ValueError, TypeError, OverflowError):
        pass
    return None


def _cell_time(value: object, time_format: str | None) -> pd.Timestamp | None:
    """One date-and-time cell as a naive timestamp; None when it is not one (or is empty).

    Parameters
    ----------
    value : object
        The cell: a ``datetime.datetime`` / ``datetime.date`` (xlsx), or text.
    time_format : str or None
        ``input.time.format`` (a ``strptime`` format); None for ISO-8601.

    Returns
    -------
    pandas.Timestamp or None
        Naive (converted to UTC where the text carried an offset); None for anything
        that does not parse.
    """
    if isinstance(value, (dt.datetime, dt.date)):
        return pd.Timestamp(value)
    if not (isinstance(value, str) and value.strip()):
        return None
    text = value.strip()
    try:
        if time_format:
            ts = pd.Timestamp(dt.datetime.strptime(text, time_format))
        else:
            ts = pd.to_datetime(text, format="ISO8601")
    except (ValueError, TypeError, OverflowError):
        return None
    if ts is pd.NaT:
        return None
    if ts.tzinfo is not None:
        ts = ts.tz_convert("UTC").tz_localize(None)
    return ts


def _cell_times(
    table: Table, values: list, time_format: str | None, column: str, col_index: int
) -> pd.Series:
    """Date-and-time cells parsed one by one, the error naming the first bad cell.

    Parameters
    ----------
    table : Table
        The file (words the error).
    values : list
        The cells of the time column, in row order.
    time_format : str or None
        ``input.time.format``; None for ISO-8601.
    column : str
        The header as written in the file.
    col_index : int
        0-based column index.

    Returns
    -------
    pandas.Series
        One naive timestamp per row.

    Raises
    ------
    RawFormatError
        At the first cell that is empty, not a timestamp, or outside 1678..2261.
    """
    parsed = []
    for k, v in enumerate(values):
        where = {"row": table.row_numbers[k], "column": column, "col_index": col_index}
        if v is None or (isinstance(v, str) and not v.strip()):
            raise table.error("empty timestamp; expected a date and time", **where)
        ts = _cell_time(v, time_format)
        if ts is None and is_time_of_day(v):
            hint = time_of_day_hint(v, table.path.name, str(table.path.parent))
            raise table.error(hint, **where)
        if ts is None:
            expect = (
                f"a time in the format {time_format!r}"
                if time_format
                else "an ISO-8601 time such as 2026-10-14T08:00:00 (or set input.time.format)"
            )
            exc = table.error(f"{v!r} is not a timestamp; expected {expect}", **where)
            is_time = lambda cell: _cell_time(cell, time_format) is not None  # noqa: E731
            raise footer_error(table, values, is_time, column, col_index, exc) or exc
        if not (TIME_MIN <= ts <= TIME_MAX):
            raise table.error(f"timestamp {v!r} is outside the supported years 1678..2261", **where)
        parsed.append(ts)
    return pd.Series(pd.DatetimeIndex(parsed))


def file_date(table: Table, fmt: str) -> dt.date:
    """The date the file name of ``table`` writes in the form ``fmt`` (``input.time.date_from_name``).

    Raises
    ------
    RawFormatError
        Naming the file: the name holds no date of that form, or two.
    """
    name = table.path.name
    found = dates_in_name(name, fmt)
    example = dt.date(2026, 3, 14).strftime(fmt)
    if not found:
        raise RawFormatError(
            table.path,
            f"no date in the form {fmt!r} (input.time.date_from_name) in the file name {name!r}; expected "
            f"the date as e.g. {example!r} for 14 March 2026 (the log's date: its rows hold the time of "
            "day); a file of another logger, or names that write the date another way?",
        )
    if len(found) > 1:
        shown = ", ".join(str(d) for d in found)
        raise RawFormatError(
            table.path,
            f"two dates in the form {fmt!r} (input.time.date_from_name) in the file name {name!r} "
            f"({shown}): which is the log's cannot be told; put the text beside it into the format, "
            f"e.g. 'log_{fmt}'",
        )
    return found[0]


def name_dated_times(table: Table, values: list, spec: dict, column: str, col_index: int) -> pd.Series:
    """A time-of-day column on the date of the file's name (``input.time.date_from_name``).

    Row k is at the name's date, plus as many days as the log passed midnight before it
    (:func:`rafi.readers.name_dates.day_offsets`: a time of day more than 12 h before the row
    above), plus its time of day. A smaller step back is kept (the checks call it a clock reset).

    Parameters
    ----------
    table : Table
        The file (its name gives the date; words the error).
    values : list
        The cells of the time column, in row order: ``H:MM[:SS[.fff]]`` text (or as
        ``time.format`` writes a time of day), or a workbook's time cells.
    spec : dict
        The normalised ``input:`` mapping.
    column : str
        The header as written in the file.
    col_index : int
        0-based column index.

    Returns
    -------
    pandas.Series
        Naive timestamps (the logger's own clock; :func:`timestamps` applies ``time.timezone``).

    Raises
    ------
    RawFormatError
        The name holds no date (or two: :func:`file_date`), at the first cell that is empty or
        not a time of day, or a date outside 1678..2261.
    """
    tm = spec["time"]
    day = file_date(table, tm["date_from_name"])
    secs = []
    for k, v in enumerate(values):
        sec = time_of_day_seconds(v, tm["format"])
        if sec is None:
            where = {"row": table.row_numbers[k], "column": column, "col_index": col_index}
            if v is None or (isinstance(v, str) and not v.strip()):
                raise table.error("empty time; expected a time of day such as 14:03:20", **where)
            expect = (
                f"a time of day in the format {tm['format']!r}"
                if tm["format"]
                else "a time of day such as 14:03:20 or 2:03:20 PM (H:MM[:SS]; or set input.time.format)"
            )
            exc = table.error(f"{cell_text(v)!r} is not a time of day; expected {expect}", **where)
            is_time = lambda cell: time_of_day_seconds(cell, tm["format"]) is not None  # noqa: E731
            raise footer_error(table, values, is_time, column, col_index, exc, what="a time of day") or exc
        secs.append(sec)
    offsets = np.asarray(day_offsets(secs), dtype="float64") * 86400.0 + np.asarray(secs, dtype="float64")
    start = pd.Timestamp(day)
    if not (TIME_MIN <= start and start + pd.Timedelta(seconds=float(offsets.max())) <= TIME_MAX):
        raise RawFormatError(
            table.path,
            f"the date {day} of the file name (input.time.date_from_name {tm['date_from_name']!r}) is "
            "outside the supported years 1678..2261",
        )
    return pd.Series(start + pd.to_timedelta(np.round(offsets * 1e9).astype("int64"), unit="ns"))


#: Most rows at the end of a file that the reader calls summary rows (``input.footer_rows``).
FOOTER_MAX_ROWS = 10


def _is_elapsed_cell(value) -> bool:
    """An elapsed-time cell: a number, a duration or time cell, or text that reads as a number."""
    if isinstance(value, (int, float, dt.timedelta, dt.time)) and not isinstance(value, bool):
        return True
    try:
        float(str(value).strip().replace(",", "."))
    except ValueError:
        return False
    return True


def trailing_text(values: list, is_time) -> int:
    """How many of the last ``values`` are text that ``is_time`` does not read as a time (the
    time cells of summary rows: ``Mean``, ``Max``), at most :data:`FOOTER_MAX_ROWS`; 0 when more
    are, or when they are half the rows or more."""
    n = 0
    for v in reversed(values):
        if not (isinstance(v, str) and v.strip()) or is_time(v):
            break
        n += 1
        if n > FOOTER_MAX_ROWS:
            return 0
    return n if 2 * n < len(values) else 0


def footer_error(
    table: Table, values: list, is_time, column: str, col_index: int, exc, *, what: str = "a timestamp"
) -> RawFormatError | None:
    """The error for summary rows at the end of a file (``Mean``, ``Max`` in the time column) when
    ``exc``, the error at the first cell that is not a time, is at the first of them; else None
    (a bad time elsewhere keeps its own error).

    Parameters
    ----------
    table : Table
        The file (words the error).
    values : list
        The cells of the time column, in row order.
    is_time : callable
        ``cell -> bool``: the cell reads as a time of this column.
    column : str
        The header as written in the file.
    col_index : int
        0-based column index.
    exc : RawFormatError
        The error at the first bad cell.
    what : str
        What a time cell of the column is, in words.
    """
    n = trailing_text(values, is_time)
    if not n or exc.line != table.row_numbers[len(values) - n]:
        return None
    texts = ", ".join(repr(str(v).strip()) for v in values[-n:])
    return table.error(
        f"{values[-n].strip()!r} is not {what}: the last {n} rows hold text in the time column "
        f"({texts}), not times; a summary row? set input.footer_rows: {n} (the rows to drop at the "
        "end of each file)",
        row=exc.line,
        column=column,
        col_index=col_index,
    )


def is_time_cell(value, spec: dict) -> bool:
    """Whether ``value``, the time cell of a row (the date and the time joined with
    ``time.date_column``), reads as a time of the mapped log's clock (``input.time``)."""
    if value is None or (isinstance(value, str) and not value.strip()):
        return False
    if spec["time"]["kind"] in ELAPSED_SECONDS:
        return _is_elapsed_cell(value)
    if spec["time"]["date_from_name"] is not None:
        return time_of_day_seconds(value, spec["time"]["format"]) is not None
    return _cell_time(value, spec["time"]["format"]) is not None


def has_clock(spec: dict) -> bool:
    """Whether a mapped log's times are dates: a timestamp column, or ``time.start`` given.

    Parameters
    ----------
    spec : dict
        The normalised ``input:`` mapping.

    Returns
    -------
    bool
        False for elapsed seconds or no time column without ``time.start``: the times are counted
        from :data:`rafi.contract.input.NO_CLOCK_EPOCH` and mean nothing as dates.
    """
    tm = spec["time"]
    return tm["kind"] == "timestamp" or tm["kind"] in EPOCH_CLOCKS or tm["start"] is not None


def _start(spec: dict) -> pd.Timestamp:
    """``time.start`` as a naive timestamp; :data:`NO_CLOCK_EPOCH` when it is not set; a clock
    number's own origin (:data:`rafi.contract.input.EPOCH_CLOCKS`)."""
    if spec["time"]["kind"] in EPOCH_CLOCKS:
        return pd.Timestamp(EPOCH_CLOCKS[spec["time"]["kind"]][0])
    given = spec["time"]["start"]
    start = pd.Timestamp(NO_CLOCK_EPOCH if given is None else given)
    return start.tz_convert(None) if start.tzinfo is not None else start


def _start_text(tm: dict) -> str:
    return "the log's first sample (input.time.start not set)" if tm["start"] is None else str(tm["start"])


def row_times(n_rows: int, spec: dict) -> pd.Series:
    """Times of a file without a time column: row k at ``time.start + k * time.period_s``.

    Parameters
    ----------
    n_rows : int
        Data rows of the file.
    spec : dict
        The normalised ``input:`` mapping, ``time.kind`` ``none``.

    Returns
    -------
    pandas.Series
        ``datetime64[ns]``, one per row, ``period_s`` apart (each offset rounded to the
        nanosecond from the start, so no error accumulates over a long log).
    """
    period_ns = float(spec["time"]["period_s"]) * 1e9
    offsets = np.round(np.arange(n_rows, dtype="float64") * period_ns).astype("int64")
    return pd.Series(_start(spec) + pd.to_timedelta(offsets, unit="ns"))


def row_times_error(n_rows: int, spec: dict) -> str | None:
    """Why :func:`row_times` cannot date ``n_rows`` rows (the last one after 2261), else None."""
    tm = spec["time"]
    span_s = (n_rows - 1) * float(tm["period_s"])
    if span_s > (TIME_MAX - _start(spec)).total_seconds():
        return (
            f"{n_rows} rows of {tm['period_s']:g} s from {_start_text(tm)} (input.time.start, "
            "input.time.period_s) end after the supported year 2261"
        )
    return None


def assumed_notes(spec: dict, *, speed: tuple[float, str] | None) -> dict[str, str]:
    """What a reader took from the config instead of the file, for ``attrs['metadata']['assumed']``.

    Parameters
    ----------
    spec : dict
        The normalised ``input:`` mapping.
    speed : tuple of (float, str) or None
        The file's constant speed and the key that gave it
        (:func:`rafi.readers.input_spec.constant_speed`); None when the speed was read.

    Returns
    -------
    dict
        Canonical column -> a sentence for people (empty when everything was read from the
        file): ``time`` when ``time.kind`` is ``none``, ``speed_rpm`` when the speed is a
        configured constant.
    """
    notes: dict[str, str] = {}
    tm = spec["time"]
    if tm["kind"] == "none":
        start = "the log's start" if tm["start"] is None else tm["start"]
        undated = ""
        if tm["start"] is None:
            undated = "; no date (input.time.start not set): times are hours since the log's start"
        notes["time"] = (
            f"no time column: row k of the file is taken to be at {start} + k x {tm['period_s']:g} s "
            f"(input.time.kind none, input.time.period_s); a missing row cannot be seen{undated}"
        )
    if speed is not None:
        rpm, source = speed
        notes["speed_rpm"] = f"no speed column: {rpm:g} r/min for every row, from {source}"
    return notes
