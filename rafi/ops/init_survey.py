"""What ``rafi init`` found in a machine's logs: one :class:`Survey` from the files as read.

:func:`survey` is pure: it takes the tables :func:`rafi.readers.infer_files.read_unknown` read,
gives each column its role (:mod:`rafi.readers.infer`), each log its shape
(:mod:`rafi.ops.init_layout`), and collects what the config block needs and what the user
must decide (``checks``: one sentence each, the key first). :mod:`rafi.ops.init_config` writes
the block, :mod:`rafi.ops.init_cli` prints the findings.
"""

from __future__ import annotations

import datetime as dt
import re
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path
from zoneinfo import ZoneInfo

import numpy as np
import pandas as pd

from rafi.contract import ELAPSED_SECONDS, EPOCH_CLOCKS
from rafi.ops.init_layout import (
    STEP_MIN_S,
    LogShape,
    elapsed_seconds,
    log_kind,
    propose_min_constant,
    propose_training,
    sample_period,
    speed_steps,
)
from rafi.ops.init_pairs import pair_parts, sheet_glob
from rafi.readers.checks_base import robust_range
from rafi.readers.checks_channels import SIGN_MIN_HEAT_RPM, sign_evidence, speed_heat
from rafi.readers.infer import (
    MARKERS_MAX,
    ColumnGuess,
    guess_columns,
    missing_markers,
    sensor_names,
    to_numbers,
    to_times,
)
from rafi.readers.infer_files import RawTable
from rafi.readers.mapped_time import date_and_time
from rafi.readers.name_dates import dates_in_name, day_offsets, name_date_format, time_of_day_seconds
from rafi.settings import DAYLIGHT_SAVING_SHIFT_S, DAYLIGHT_SAVING_SLACK_S

#: Share of regular time steps below which the sample period is not taken as given.
REGULAR_SHARE = 0.9


@dataclass
class Survey:
    """Everything ``rafi init`` found (see the module docstring).

    Attributes
    ----------
    machine : str
    tables : list of RawTable
        The files, in the order given.
    guesses : list of ColumnGuess
        The columns of the first file.
    sensors : dict
        Sensor name -> header of each temperature column, in column order.
    time, speed : ColumnGuess or None
    date : ColumnGuess or None
        The date column of a time of day (``input.time.date_column``), else None.
    probes : list of ColumnGuess
        The displacement candidates, the one to model first.
    time_format : str or None
        ``input.time.format`` for text timestamps that are not ISO 8601.
    period_s : float or None
        The sample period (None: no time column, or irregular).
    regular_share : float
    shapes : list of LogShape
    kind, kind_why : str
        ``continuous`` or ``runs``, and why.
    training : dict
        :func:`rafi.ops.init_layout.propose_training`.
    min_constant : tuple or None
        :func:`rafi.ops.init_layout.propose_min_constant`.
    sign : int or None
        The sign that makes the probe positive while the spindle heats (None: no evidence).
    sign_why : str
    probe_signs : list of (int or None, str)
        ``sign`` and ``sign_why`` of every probe, in the order of ``probes`` (the first is
        ``sign``'s): several probes of one machine may move in different directions.
    speed_by_file : dict
        Without a speed column: glob -> r/min read from the file names (``*_3000rpm*``).
    checks : list of str
        What the user must decide, one sentence each, starting with the key.
    notes : list of str
        Other findings (files with another header, other sheets).
    sheet_glob : str or None
        ``input.sheet`` as a pattern when several sheets of a workbook share one layout (each a
        log); None for one sheet, or when no pattern matches exactly those sheets (then a check).
    partner : RawTable or None
        The first partner file when the files come in pairs (``join``), else None.
    partner_guesses : list of ColumnGuess
        The partner's columns.
    join : tuple of str or None
        ``input.join.replace``: the texts that tell a log's file from its partner's.
    join_by : str
        ``time`` when both files have a time column, else ``row``.
    logs : list of RawTable
        The tables surveyed as logs (of the first log's layout; partners not among them).
    given_period_s : float or None
        The sample period the user gave (``--period-s``): the clock of a log without a time
        column, row k at k times it.
    clock_back : tuple or None
        ``(log name, data row, seconds)`` of the first step back of about an hour of a clock
        (a daylight-saving change of a local clock: ``input.time.timezone``), else None.
    clock_back_zone : str or None
        A time zone whose daylight-saving change falls on the date of that step back
        (:func:`zone_falling_back_on`), the one proposed for ``input.time.timezone``.
    date_from_name : str or None
        ``input.time.date_from_name``: the date format every log's file name holds
        (:func:`rafi.readers.name_dates.name_date_format`) when the clock is a time of day
        without a date column, else None.
    date_from_name_check : str or None
        Why that format needs a look (the names read day first and month first), else None.
    missing_values : collections.Counter
        ``input.missing_values``: the texts of cells without a value found in the numeric
        columns of the logs and partners (:func:`rafi.readers.infer.missing_markers`) and how
        many cells hold each.
    """

    machine: str
    tables: list
    guesses: list
    sensors: dict
    time: ColumnGuess | None
    date: ColumnGuess | None
    speed: ColumnGuess | None
    probes: list
    time_format: str | None = None
    period_s: float | None = None
    regular_share: float = 0.0
    shapes: list = field(default_factory=list)
    kind: str = "runs"
    kind_why: str = ""
    training: dict = field(default_factory=dict)
    min_constant: tuple | None = None
    sign: int | None = None
    sign_why: str = ""
    probe_signs: list = field(default_factory=list)
    speed_by_file: dict = field(default_factory=dict)
    checks: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    sheet_glob: str | None = None
    partner: RawTable | None = None
    partner_guesses: list = field(default_factory=list)
    join: tuple | None = None
    join_by: str = "time"
    logs: list = field(default_factory=list)
    given_period_s: float | None = None
    missing_values: Counter = field(default_factory=Counter)
    clock_back: tuple | None = None
    clock_back_zone: str | None = None
    date_from_name: str | None = None
    date_from_name_check: str | None = None

    @property
    def first(self) -> RawTable:
        """The first log surveyed (its columns are :attr:`guesses`)."""
        return self.logs[0] if self.logs else self.tables[0]

    @property
    def format(self) -> str:
        return self.first.format

    @property
    def temperatures(self) -> list[ColumnGuess]:
        return [g for g in self.guesses if g.role == "temperature"]


def _axis_first(probes: list[ColumnGuess]) -> list[ColumnGuess]:
    """Probes whose header names the Z axis (the spindle's) first, then the rest in column order."""
    z = re.compile(r"(^|[^a-z])z\s*\d*([^a-z]|$)", re.I)
    return sorted(probes, key=lambda g: (not z.search(g.header), g.index))


def elapsed_kind(unit: str | None) -> str:
    """``input.time.kind`` of an elapsed time column in ``unit`` (``min``, ``h``; else seconds)."""
    kind = f"elapsed_{unit}"
    return kind if kind in ELAPSED_SECONDS else "elapsed_s"


#: The keys of a table's layout (:attr:`RawTable.layout`) that one ``input`` block holds for
#: every file: two files that differ in one are read by two blocks.
SHARED_LAYOUT_KEYS = ("delimiter", "decimal", "encoding", "header_row", "skip_rows")


def layout_key(table: RawTable) -> tuple:
    """What two tables of one layout share: the format, the reading keys of one ``input`` block
    (:data:`SHARED_LAYOUT_KEYS`: the delimiter, the decimal mark, the header's row, ...) and the
    header names, in any order for a csv or a workbook with a header row of distinct names (the
    pipeline's reader finds each mapped column by its header, wherever it stands); in order
    otherwise (a native log, columns by letter, a header twice)."""
    names = tuple(table.header)
    if table.format != "native" and not table.headerless and len(set(names)) == len(names):
        names = tuple(sorted(names))
    reading = tuple(str(table.layout.get(key)) for key in SHARED_LAYOUT_KEYS)
    return table.format, reading, names


def column_cells(table: RawTable, guess: ColumnGuess) -> list:
    """The cells of ``guess``'s column in ``table``: at its position when the header there is
    the same, else under its header (a file of the same layout with its columns in another order)."""
    j = guess.index
    if not (j < len(table.header) and table.header[j] == guess.header):
        j = table.header.index(guess.header)
    return table.columns[j]


def _time_and_speed(
    table: RawTable, guesses: list, survey: Survey
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Seconds since the first row and the speed of one table (None where the column is missing)."""
    t = s = None
    if survey.time is not None:
        cells = column_cells(table, survey.time)
        if survey.time.unit == "timeofday" and survey.date is None:
            times = name_dated(cells, table.path.name, survey.date_from_name)
            t = None if times is None else elapsed_seconds(times)
        elif survey.time.unit in ("timestamp", "timeofday"):
            if survey.time.unit == "timeofday":
                cells = date_and_time(list(column_cells(table, survey.date)), list(cells))
            times, fmt, _ = to_times(cells)
            survey.time_format = fmt
            t = None if times is None else elapsed_seconds(times)
        else:
            unit = survey.time.unit
            per = EPOCH_CLOCKS[unit][1] if unit in EPOCH_CLOCKS else ELAPSED_SECONDS[elapsed_kind(unit)]
            t = elapsed_seconds(to_numbers(cells, table.layout.get("decimal", "."))) * per
    elif survey.given_period_s is not None:  # no time column: row k at k periods (--period-s)
        t = np.arange(table.n_rows, dtype=float) * survey.given_period_s
    if survey.speed is not None:
        s = to_numbers(column_cells(table, survey.speed), table.layout.get("decimal", "."))
    return t, s


def probe_sign(t_s: np.ndarray, speed: np.ndarray, disp: np.ndarray) -> tuple[int | None, str]:
    """The sign that makes ``disp`` positive while the spindle heats, and why (None: no clear
    evidence), by the pipeline's own check (:func:`rafi.readers.checks_channels.sign_evidence` of
    :func:`~rafi.readers.checks_channels.speed_heat`), so that ``rafi init`` and the report's
    probe sign agree on a log."""
    ok = np.isfinite(t_s) & np.isfinite(speed) & np.isfinite(disp)
    if ok.sum() < 10:
        return None, "too few rows to tell"
    period = float(np.median(np.diff(t_s[ok])))
    if not period > 0:
        return None, "the time column does not advance from row to row"
    heat = speed_heat(speed[ok], period)
    if robust_range(heat) < SIGN_MIN_HEAT_RPM or np.std(disp[ok]) == 0:
        return None, "the speed or the probe does not change"
    sign, r = sign_evidence(heat, disp[ok])
    if r is None:
        return None, "the probe does not change enough to tell"
    if sign == 0:
        return None, f"no clear direction while the spindle heats (r = {r:+.2f})"
    return sign, f"it {'rises' if sign > 0 else 'falls'} while the spindle heats (r = {r:+.2f})"


def _speeds_from_names(names: list[str]) -> dict[str, float]:
    """``{'*_3000rpm*': 3000, ...}`` from file names that carry a speed, else ``{}``."""
    out = {}
    for name in names:
        m = re.search(r"(\d+)\s*(rpm|upm|u_min|1_min)", name, re.I)
        if not m:
            return {}
        out[f"*{m.group(0)}*"] = float(m.group(1))
    return out


def _probe_cells(survey: Survey, table: RawTable, k: int = 0) -> np.ndarray | None:
    """Probe ``k``'s values beside ``table``'s rows: its own column, or its partner file's
    (row by row, when the two have as many rows; else None)."""
    if survey.join is None:
        return to_numbers(column_cells(table, survey.probes[k]), table.layout.get("decimal", "."))
    name = table.path.name.replace(*survey.join)
    partner = next((t for t in survey.tables if t.path.name == name), None)
    if partner is None or partner.n_rows != table.n_rows:
        return None
    return to_numbers(column_cells(partner, survey.probes[k]), partner.layout.get("decimal", "."))


#: A unit at the end of a probe's word (``Z_um``, ``Y_mm``, ``X_`` of ``X_µm``): not part of its name.
_UNIT_SUFFIX = re.compile(r"(?<=[A-Za-z0-9])_+(um|mm|microns?|mu)?_*$", re.I)


def probe_names(headers: list[str]) -> list[str]:
    """A probe name for every displacement header: its first word that the other headers do not
    share (``ch1(um)`` -> ``ch1``, ``Verlagerung Z1 [µm]`` -> ``Z1``), without a unit at its end
    (``Z_um`` -> ``Z``, ``Y_mm`` -> ``Y``) unless that makes two names one, where that is a
    valid, unique name, else ``P<k>``."""
    from rafi.contract import PROBE_NAME_RE

    tokens = [re.findall(r"[A-Za-z][A-Za-z0-9_]*", h) for h in headers]
    shared = set.intersection(*(set(t) for t in tokens)) if len(tokens) > 1 else set()
    words = [next((w for w in t if w not in shared), "") for t in tokens]
    bare = [_UNIT_SUFFIX.sub("", w) for w in words]
    if len(set(bare)) == len(bare):
        words = bare
    words = [w[:16] for w in words]
    return [
        w if re.match(PROBE_NAME_RE, w) and words.count(w) == 1 else f"P{k + 1}" for k, w in enumerate(words)
    ]


def _read_probe_signs(survey: Survey, table: RawTable, t: np.ndarray, speed: np.ndarray) -> None:
    """Each probe's direction while the spindle heats (:func:`probe_sign`) from ``table``, for the
    probes no earlier table has told; ``survey.sign`` is the first probe's."""
    if len(survey.probe_signs) != len(survey.probes):
        survey.probe_signs = [(None, "")] * len(survey.probes)
    for k, (sign, _) in enumerate(survey.probe_signs):
        if sign is None:
            d = _probe_cells(survey, table, k)
            if d is not None:
                survey.probe_signs[k] = probe_sign(t, speed, d)
    if survey.probe_signs:
        survey.sign, survey.sign_why = survey.probe_signs[0]


def _guesses(table: RawTable, markers=(), *, dated: bool = False) -> list[ColumnGuess]:
    """Every column's guess (``markers``: missing-value texts, read as empty cells; ``dated``: the
    file names carry the date, a time of day is the clock); a table without a header row is
    guessed by content alone and its columns are named by letter."""
    decimal = table.layout.get("decimal", ".")
    if not table.headerless:
        return guess_columns(table.header, table.columns, decimal, table.labels, markers, dated=dated)
    guesses = guess_columns([""] * len(table.header), table.columns, decimal, markers=markers, dated=dated)
    return [replace(g, header=g.letter) for g in guesses]


def _markers(tables: list[RawTable]) -> Counter:
    """The missing-value markers of ``tables`` together (:func:`rafi.readers.infer.missing_markers`)."""
    found: Counter = Counter()
    for t in tables:
        found.update(missing_markers(t.columns, t.layout.get("decimal", ".")))
    return found if len(found) <= MARKERS_MAX else Counter()


def _pairs(tables: list[RawTable]) -> tuple[list[RawTable], list[RawTable], tuple | None]:
    """``(logs, partners, replace)``: the files of the layout with temperatures and those of the
    layout with the displacement when they come in pairs by name, else ``(tables, [], None)``."""
    groups: dict = {}
    for t in tables:
        groups.setdefault(layout_key(t), []).append(t)
    if len(groups) != 2:
        return tables, [], None
    roles = {key: {g.role for g in _guesses(group[0])} for key, group in groups.items()}
    mains = [k for k, r in roles.items() if "temperature" in r and "displacement" not in r]
    partners = [k for k, r in roles.items() if "displacement" in r and "temperature" not in r]
    if len(mains) != 1 or len(partners) != 1:
        return tables, [], None
    logs, others = groups[mains[0]], groups[partners[0]]
    parts = pair_parts([t.path.name for t in logs], [t.path.name for t in others])
    return (logs, others, parts) if parts else (tables, [], None)


def _hour_back(name: str, t_s: np.ndarray) -> tuple | None:
    """``(name, data row, seconds)`` of the first step back of a clock by about an hour (a
    daylight-saving change), else None; the row is 1-based among the data rows."""
    steps = np.diff(t_s)
    near = np.abs(-steps - DAYLIGHT_SAVING_SHIFT_S) <= DAYLIGHT_SAVING_SLACK_S
    if not near.any():
        return None
    k = int(np.argmax(near)) + 1
    return name, k + 1, float(-steps[k - 1])


#: Time zones whose daylight-saving changes fall on different days (the European Union's, the
#: United States', Australia's): the one whose clocks go back on the date of a log's step back is
#: proposed for ``input.time.timezone`` (a CHECK: zones of one region share the day).
FALL_BACK_ZONES = ("Europe/Berlin", "America/New_York", "Australia/Sydney")


def zone_falling_back_on(day: dt.date) -> str | None:
    """The first zone of :data:`FALL_BACK_ZONES` whose clocks go back (a daylight-saving change
    to a smaller UTC offset) on ``day``, else None."""
    for name in FALL_BACK_ZONES:
        zone = ZoneInfo(name)
        start = dt.datetime.combine(day, dt.time(0, 0), zone).utcoffset()
        end = dt.datetime.combine(day, dt.time(23, 59), zone).utcoffset()
        if end < start:
            return name
    return None


def _clock_back_day(table: RawTable, survey: Survey, row: int) -> dt.date | None:
    """The date of data row ``row`` (1-based) of a table whose clock is a timestamp, else None."""
    cells = table.columns[survey.time.index]
    if survey.time.unit == "timeofday" and survey.date is None:
        times = name_dated(cells, table.path.name, survey.date_from_name)
    else:
        if survey.time.unit == "timeofday":
            cells = date_and_time(list(table.columns[survey.date.index]), list(cells))
        times, _, _ = to_times(cells)
    if times is None or not 0 < row <= len(times) or pd.isna(times[row - 1]):
        return None
    return pd.Timestamp(times[row - 1]).date()


def name_dated(cells, name: str, fmt: str | None) -> np.ndarray | None:
    """Time-of-day cells on the date ``name`` writes in the form ``fmt``, as the pipeline's reader
    dates them (:func:`rafi.readers.mapped_time.name_dated_times`: a day later at each midnight
    passed); ``datetime64[ns]``, NaT where a cell is no time of day. None without one date in the
    name."""
    found = dates_in_name(name, fmt) if fmt else []
    if len(found) != 1:
        return None
    secs = [time_of_day_seconds(c) for c in cells]
    kept = [x for x in secs if x is not None]
    days = iter(day_offsets(kept))
    start = np.datetime64(found[0], "ns")
    out = np.full(len(secs), np.datetime64("NaT"), dtype="datetime64[ns]")
    for k, x in enumerate(secs):
        if x is not None:
            out[k] = start + np.timedelta64(int(round((next(days) * 86400 + x) * 1e9)), "ns")
    return out


def _log_shapes(survey: Survey, tables: list[RawTable]) -> None:
    """Period, steps and the probe's sign of every table (``survey`` is filled in)."""
    periods, shares = [], []
    for table in tables:
        t, s = _time_and_speed(table, survey.guesses, survey)
        if t is None:
            survey.shapes.append(LogShape(table.name, table.n_rows, None, 0.0, ()))
            continue
        clock_text = survey.time is not None and survey.time.unit in ("timestamp", "timeofday")
        back = _hour_back(table.name, t) if clock_text else None
        if back is not None:  # read as the reader reads it with input.time.timezone: an hour later
            if survey.clock_back is None:
                survey.clock_back = back
                day = _clock_back_day(table, survey, back[1])
                survey.clock_back_zone = zone_falling_back_on(day) if day is not None else None
            t = np.concatenate([t[: back[1] - 1], t[back[1] - 1 :] + DAYLIGHT_SAVING_SHIFT_S])
        period, share = sample_period(t)
        if period is not None and survey.time is not None and survey.time.unit in ("min", "h", "excel_days"):
            period = float(f"{period:.3g}")  # a clock in minutes, hours or days is rounded: 60.0012 s is 60
        if period is not None:  # a clock that stands still has no period
            periods.append(period)
            shares.append(share)
        steps = tuple(speed_steps(t, s, period)) if s is not None and period else ()
        survey.shapes.append(LogShape(table.name, table.n_rows, period, share, steps))
        if s is not None:
            _read_probe_signs(survey, table, t, s)
    if periods:
        survey.period_s = float(np.median(periods))
        survey.regular_share = float(min(shares))


def survey(machine: str, tables: list[RawTable], *, period_s: float | None = None) -> Survey:
    """What the logs of ``machine`` hold (see the module docstring).

    Parameters
    ----------
    machine : str
        The machine's name (its folder under ``raw/``).
    tables : list of RawTable
        Its files as read, at least one.
    period_s : float, optional
        The seconds between two rows the user gave (``--period-s``): a log without a time
        column has this clock, and its speed steps are read as with a time column.

    Returns
    -------
    Survey
    """
    logs, partners, parts = _pairs(tables)
    first = logs[0]
    markers = _markers([t for t in logs if t.header == first.header and t.format == first.format] + partners)
    name_format, name_check = name_date_format(
        [t.path.name for t in logs if layout_key(t) == layout_key(first)]
    )
    guesses = _guesses(first, markers, dated=name_format is not None)
    temps = [g for g in guesses if g.role == "temperature"]
    names = sensor_names([g.header for g in temps]) if not first.headerless else []
    names = names or [f"T{k}" for k in range(1, len(temps) + 1)]
    partner_guesses = _guesses(partners[0], markers) if partners else []
    out = Survey(
        machine=machine,
        tables=tables,
        guesses=guesses,
        sensors=dict(zip(names, (g.header for g in temps))),
        time=next((g for g in guesses if g.role == "time"), None),
        date=next((g for g in guesses if g.role == "date"), None),
        speed=next((g for g in guesses if g.role == "speed"), None),
        probes=_axis_first([g for g in partner_guesses or guesses if g.role == "displacement"]),
        partner=partners[0] if partners else None,
        partner_guesses=partner_guesses,
        join=parts,
        given_period_s=period_s,
        missing_values=markers,
    )
    if out.time is not None and out.time.unit == "timeofday" and out.date is None:
        out.date_from_name, out.date_from_name_check = name_format, name_check
        example = first.path.name
        out.notes.append(
            f"the date of each log from its file name ({example}: {dates_in_name(example, name_format)[0]}), "
            f"the time of day from {out.time.header!r}: input.time.date_from_name {name_format!r}"
        )
    if parts:
        out.notes.append(
            f"{len(logs)} pair(s) of files by name: {parts[0]!r} holds the temperatures, {parts[1]!r} "
            f"the displacement ({logs[0].path.name} + {logs[0].path.name.replace(*parts)}): joined"
        )
        has_time = any(g.role == "time" for g in partner_guesses)
        out.join_by = "time" if out.time is not None and has_time else "row"
    for table in logs[1:] if parts else tables[1:]:
        if layout_key(table) != layout_key(first):
            out.notes.append(f"{table.path.name}: another layout than {first.path.name}; it is not surveyed")
    same = [t for t in logs if layout_key(t) == layout_key(first)]
    reordered = [t.path.name for t in same if t.header != first.header]
    if reordered:
        names = ", ".join(reordered[:3]) + (", ..." if len(reordered) > 3 else "")
        out.notes.append(
            f"{len(reordered)} file(s) hold the columns of {first.path.name} in another order ({names}): "
            "surveyed too (the block names each column by its header)"
        )
    out.logs = same
    if len(first.sheet_group) > 1:
        out.sheet_glob = sheet_glob(list(first.sheet_group), [x.name for x in first.sheets])
    out.notes += list(dict.fromkeys(n for t in same for n in t.notes))  # once, not once a file
    if markers:
        out.notes.append(f"missing values: {markers_text(markers)}: read as missing (input.missing_values)")
    _log_shapes(out, same)
    if any(s.steps for s in out.shapes):
        out.kind, out.kind_why = log_kind(out.shapes)
        out.training = propose_training([s for s in out.shapes if s.steps], out.kind)
        if out.kind == "continuous":  # separate runs: each file's step is its run, whatever its length
            out.min_constant = propose_min_constant([s for s in out.shapes if s.steps])
    else:
        out.kind_why = f"{len(out.shapes)} log(s) {_without_steps(out)}: each log one run"
    if out.sign is None and not out.sign_why:
        without = (
            "with the probe's rows not beside the speed's (a partner file of another length)"
            if any(s.steps for s in out.shapes)
            else _without_steps(out)
        )
        out.sign_why = f"{without} its direction while the spindle heats cannot be read"
    if out.speed is None:
        out.speed_by_file = _speeds_from_names([t.path.name for t in same])
    out.checks = _checks(out)
    return out


def _without_steps(s: Survey) -> str:
    """Why no speed step was read, in words: what the logs are without (a speed column, a clock),
    or that the speed never holds a level long enough."""
    clock = s.time is not None or s.given_period_s is not None
    if s.speed is None and not clock:
        return "without a speed column or a clock"
    if s.speed is None:
        return "without a speed column"
    if not clock:
        return "without a clock (no time column; --period-s gives one)"
    if s.period_s is None:
        return "with a clock that does not advance"
    return f"without a speed held for {STEP_MIN_S / 60:g} min or more"


def clock_back_text(found: tuple) -> str:
    """``the clock of a.csv goes back by 3540 s at data row 1081: a daylight-saving change?``"""
    name, row, back_s = found
    return f"the clock of {name} goes back by {back_s:g} s at data row {row}: a daylight-saving change?"


def footer_counts(s: Survey) -> list[int]:
    """The numbers of summary rows the logs end in (``input.footer_rows``), sorted, each once."""
    return sorted({t.layout.get("footer_rows", 0) for t in s.logs or s.tables})


def _checks(s: Survey) -> list[str]:
    """What the user must decide, one sentence each (key first)."""
    out = [f"column {g.letter} {g.header!r}: {g.check}" for g in s.guesses if g.check]
    if s.join:
        out += [
            f"column {g.letter} of {s.partner.path.name}: {g.check}" for g in s.partner_guesses if g.check
        ]
    if s.first.headerless:
        out.append(
            "input.columns: no header row; each column's role is from its content alone: check the letters"
        )
    group = s.first.sheet_group
    if len(group) > 1 and s.sheet_glob is None:
        out.append(
            f"input.sheet: {len(group)} sheets share one layout but no pattern matches only them; "
            "give a pattern (each matching sheet is a log) or read one sheet"
        )
    if len(footer_counts(s)) > 1:
        out.append(
            "input.footer_rows: the logs end in different numbers of summary rows "
            f"({', '.join(map(str, footer_counts(s)))}); the key drops as many at the end of every file"
        )
    if s.training.get("speeds"):
        out.append("training_speeds_rpm: decide which speeds train; the others validate")
    if s.format == "native":
        return out
    if s.date_from_name_check:
        out.append(f"input.time.date_from_name: {s.date_from_name_check}")
    if s.clock_back is not None:
        out.append(
            f"input.time.timezone: {clock_back_text(s.clock_back)} give the logger's time zone "
            "(an IANA name, e.g. Europe/Berlin); the steps are read as if it were given"
        )
    if s.time is None and s.given_period_s is None:
        out.append("input.time.period_s: no time column; give the seconds between two rows (--period-s)")
    elif s.period_s is None or s.regular_share < REGULAR_SHARE:
        out.append(
            f"sample_period_s: the time steps are irregular ({s.regular_share:.0%} regular); give the period"
        )
    if (
        s.time is not None
        and s.time.unit not in ("timestamp", "timeofday", *EPOCH_CLOCKS)
        and not s.first.start_hint
    ):
        out.append("input.time.start: elapsed seconds with no start date found; give when second 0 was")
    if s.speed is None and not s.speed_by_file:
        out.append("input.speed: no speed column; give constant_rpm or constant_rpm_by_file")
    if not s.probes:
        out.append("input.displacement.column: no displacement column found")
    else:
        out.append(f"input.displacement.sign: the probe's convention is not in the data; {s.sign_why}")
        if len(s.probes) > 1:
            out.append(
                f"input.probes: {len(s.probes)} displacement columns, each a probe; remove any that is "
                "not a displacement, and give a probe its own unit or sign where it differs"
            )
            out += _probe_sign_checks(s)
    return out


def _probe_sign_checks(s: Survey) -> list[str]:
    """The probes whose direction while the spindle heats is not the first probe's (or cannot be
    read), in one sentence; none when every probe moves as the first."""
    names = probe_names([g.header for g in s.probes])
    apart = [
        f"{name} {why}"
        for name, (sign, why) in zip(names[1:], s.probe_signs[1:], strict=False)
        if why and sign != s.sign
    ]
    if not apart:
        return []
    return [
        f"input.probes: unlike {names[0]} ({s.sign_why}): " + "; ".join(apart) + "; a probe that moves "
        "the other way takes its own sign (input.probes.<name>.sign)"
    ]


def markers_text(markers) -> str:
    """``'---' in 9 cells, 'NaN' in 3`` (most first)."""
    counts = markers.most_common()
    return ", ".join(
        f"{text!r} in {n} cell{'s' if n != 1 else ''}" if k == 0 else f"{text!r} in {n}"
        for k, (text, n) in enumerate(counts)
    )


def short_name(path: str | Path) -> str:
    return Path(path).name
