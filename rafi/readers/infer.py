"""What each column of an unknown log holds, from its header and its content (``rafi init``).

Pure functions on the cells of one table (a csv file or an xlsx sheet, as
:mod:`rafi.readers.infer_files` reads it): :func:`guess_columns` gives every column a likely
role (``time``, ``speed``, ``temperature``, ``displacement``, ``other``, ``text``, ``empty``), a
unit, a confidence and the reason in words; :func:`sensor_names` turns the temperature headers
into sensor names. Where the content leaves a unit or a role open (a temperature in deg F or a
warm deg C, a displacement in mm or um, a counter or a clock) the guess carries a ``check``
sentence: ``rafi init`` says it in the terminal and writes the key commented out with ``# CHECK:``.

The rules, in words (``docs/init.md``):

* **time**: timestamps (date cells, or text that parses as date and time), or numbers that rise
  at every row in regular steps (elapsed seconds; or a clock number, :data:`CLOCK_NUMBERS`, when
  the first one is a date of 2000-2099 in Unix seconds, Unix milliseconds or Excel's day
  numbers), or a time of day (``08:00:00``, time cells) beside a **date** column (dates, all at
  midnight, no time in the text);
* **speed**: non-negative, up to 100 000, mostly held at a few levels with jumps between them
  (a spindle speed in r/min); a column at one level is a speed only if its header says so;
* **temperature**: smooth (no jumps), 0-120 (deg C), 250-400 (K); a start between
  :data:`FAHRENHEIT_START` would be a room in deg F or a warm machine in deg C: said, not guessed;
* **displacement**: smooth, starting near 0 or going negative; um or mm by its range and
  resolution; its sign cannot be known from the data (the probe's convention): always said.

A header that names a role (``Temperatur``, ``°C``, ``rpm``, ``µm``, ``時間``) raises the
confidence when the content agrees; when it disagrees the content wins and the guess is marked.
"""

from __future__ import annotations

import datetime as dt
import re
from collections import Counter
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from rafi.readers.mapped_table import excel_column
from rafi.readers.name_dates import is_time_of_day
from rafi.readers.parsing import without_markers

#: Roles a column can get.
ROLES = ("time", "date", "speed", "temperature", "displacement", "other", "text", "empty")

#: Highest plausible spindle speed, r/min.
SPEED_MAX_RPM = 100_000.0

#: Temperature ranges by unit (all values inside): deg C and K.
CELSIUS_RANGE = (-20.0, 120.0)
KELVIN_RANGE = (250.0, 400.0)

#: A start level in this band (deg F of a room, 45-100 F = 7-38 C) is also a warm machine in
#: deg C: the unit is said to be unsure.
FAHRENHEIT_START = (45.0, 100.0)

#: Share of cells that must parse for a column to be numbers (or times).
PARSE_SHARE = 0.95

#: A clock number's kind in words (``rafi init``'s reason).
CLOCK_WORDS = {
    "epoch_s": "a date in Unix seconds",
    "epoch_ms": "a date in Unix milliseconds",
    "excel_days": "a date as Excel's day number",
}

#: A clock written as a number (``input.time.kind``): the first value's range (a date of
#: 2000-2099) and the largest step (an hour), per kind.
CLOCK_NUMBERS = {
    "epoch_s": ((946_684_800.0, 4_102_444_800.0), 3600.0),
    "epoch_ms": ((946_684_800_000.0, 4_102_444_800_000.0), 3_600_000.0),
    "excel_days": ((36_526.0, 73_051.0), 1.0 / 24.0),
}

_HINTS = {
    "time": re.compile(
        r"(^|[^a-z])(time|zeit|datum|date|timestamp|zeitstempel|elapsed|sec|seconds|uhrzeit)([^a-z]|$)"
        r"|時間|时间|[\[(]\s*s\s*[\])]",
        re.I,
    ),
    "speed": re.compile(
        r"rpm|1/min|r/min|u/min|min-1|min\^-1|drehzahl|speed|spindle|spindel|轉速|转速|^n\s*[\[(]", re.I
    ),
    "temperature": re.compile(
        r"°\s*[cf]|deg\s*[cf]|[\[(]\s*[ck]\s*[\])]|temp(?!el)|^t\s*_?\d+|^tc\s*_?\d*|pt\s*100|溫度|温度|fühler",
        re.I,
    ),
    "displacement": re.compile(
        r"[µμ]m\b|(?<![a-z])um\b|[\[(]\s*mm\s*[\])]|verlagerung|displacement|disp|deform|dehnung|elongation|probe|"
        r"sonde|位移|變位|变位|^ch\s*_?\d+|^[xyz]\s*_?\d*\s*([\[(]|$)|^d[xyz]\b",
        re.I,
    ),
}

_UNIT_HINTS = (
    ("degF", re.compile(r"°\s*f|deg\s*f|fahrenheit|[\[(]\s*f\s*[\])]", re.I)),
    ("K", re.compile(r"kelvin|[\[(]\s*k\s*[\])]", re.I)),
    ("degC", re.compile(r"°\s*c|deg\s*c|celsius|[\[(]\s*c\s*[\])]", re.I)),
    ("mm", re.compile(r"[\[(]\s*mm\s*[\])]|\bmm\b", re.I)),
    ("um", re.compile(r"[µμ]m|\bum\b|[\[(]\s*um\s*[\])]|micron", re.I)),
    ("min", re.compile(r"[\[(]\s*min\s*[\])]", re.I)),
    ("h", re.compile(r"[\[(]\s*h\s*[\])]", re.I)),
)

_COUNTER = re.compile(r"^(nr|no|index|idx|zeile|row|#|lfd|sample|n)\.?$", re.I)


@dataclass(frozen=True)
class ColumnGuess:
    """What one column probably holds.

    Attributes
    ----------
    index : int
        0-based position in the table.
    header : str
        The header as read (stripped).
    role : str
        One of :data:`ROLES`.
    unit : str or None
        ``timestamp`` or ``s`` (time), ``rpm``, ``degC``/``K``/``degF`` (temperature),
        ``um``/``mm`` (displacement); None when it does not apply or is unknown.
    confidence : str
        ``high`` (header and content agree), ``medium`` (content alone), ``low`` (they
        disagree, or the content fits a second reading).
    why : str
        The evidence in words.
    check : str or None
        What the user must decide (the unit, the sign, the role), or None.
    """

    index: int
    header: str
    role: str
    unit: str | None
    confidence: str
    why: str
    check: str | None = None

    @property
    def letter(self) -> str:
        """The column's Excel letter (A, B, ..., AA)."""
        return excel_column(self.index)


def header_hints(header: str) -> set[str]:
    """The roles a header names (``'Temperatur 3 [°C]'`` -> ``{'temperature'}``)."""
    return {role for role, rx in _HINTS.items() if rx.search(header or "")}


def header_unit(header: str) -> str | None:
    """The unit a header names, if any (``degC``, ``degF``, ``K``, ``mm``, ``um``, ``min``, ``h``)."""
    for unit, rx in _UNIT_HINTS:
        if rx.search(header or ""):
            return unit
    return None


# --------------------------------------------------------------------------- cells


def to_numbers(cells, decimal: str = ".") -> np.ndarray:
    """Cells (numbers, text, None) -> float64; NaN for an empty cell or one that is not a number."""
    out = np.full(len(cells), np.nan)
    for k, v in enumerate(cells):
        if v is None or isinstance(v, bool):
            continue
        if isinstance(v, (int, float, np.integer, np.floating)):
            out[k] = float(v)
            continue
        if isinstance(v, (dt.datetime, dt.date, dt.time, dt.timedelta)):
            continue
        s = str(v).strip().replace("\u00a0", "").replace(" ", "")
        if decimal == ",":
            s = s.replace(".", "").replace(",", ".") if "," in s else s
        try:
            out[k] = float(s)
        except ValueError:
            pass
    out[~np.isfinite(out)] = np.nan
    return out


#: Text time formats tried in order (``None``: ISO 8601, read by pandas without a format); the
#: 12-hour clocks (``10/31/2026 08:00:00 PM``) of US loggers last.
TIME_FORMATS = (
    None,
    "%d.%m.%Y %H:%M:%S",
    "%d.%m.%Y %H:%M",
    "%d/%m/%Y %H:%M:%S",
    "%m/%d/%Y %H:%M:%S",
    "%m/%d/%Y %I:%M:%S %p",
    "%m/%d/%Y %I:%M %p",
    "%d/%m/%Y %I:%M:%S %p",
    "%Y-%m-%d %I:%M:%S %p",
)


def _day_month_swapped(formats: set) -> bool:
    """Two of ``formats`` differ only by the order of day and month (both read every cell)."""
    swapped = {f.replace("%d", "%@").replace("%m", "%d").replace("%@", "%m") for f in formats if f}
    return bool(swapped & formats)


def _is_time_of_day(filled: list) -> bool:
    """Every cell a time of day: a workbook's time cell, or text ``H:MM[:SS[.f]]``
    (:func:`rafi.readers.name_dates.is_time_of_day`)."""
    return all(is_time_of_day(v) for v in filled)


def _has_clock_text(filled: list) -> bool:
    """Some text cell carries a time of day (``08:00``): a timestamp, though at midnight."""
    return any(isinstance(v, str) and ":" in v for v in filled)


#: A UTC offset at the end of a timestamp's text (``Z``, ``+01:00``, ``-0500``).
UTC_OFFSET = re.compile(r"\d(Z|[+-]\d{2}:?\d{2})$")


def has_utc_offset(cells) -> bool:
    """Some text cell ends with a UTC offset (``2026-03-02T06:00:00+01:00``, ``...Z``)."""
    return any(isinstance(v, str) and UTC_OFFSET.search(v.strip()) for v in cells)


def _naive_utc(parsed: pd.Series) -> pd.Series:
    """Timestamps parsed with ``utc=True`` as naive UTC, as the pipeline's reader keeps them
    (:func:`rafi.readers.mapped_time.timestamps`: an offset is converted to UTC)."""
    return parsed.dt.tz_convert(None) if isinstance(parsed.dtype, pd.DatetimeTZDtype) else parsed


def to_times(cells) -> tuple[np.ndarray | None, str | None, str | None]:
    """Cells as timestamps: ``(datetime64 array, time.format or None, check or None)``; ``(None, None,
    None)`` when the cells are not times. Date cells of a workbook are times as they are;
    text is tried against :data:`TIME_FORMATS` (two formats that both read every cell, day
    first and month first, give a ``check`` sentence). Times with a UTC offset (``Z``,
    ``+01:00``) are converted to UTC and made naive, as the pipeline's reader does: the array is
    always ``datetime64[ns]``."""
    filled = [v for v in cells if v is not None and str(v).strip() != ""]
    if not filled:
        return None, None, None
    if all(isinstance(v, (dt.date, pd.Timestamp)) for v in filled):  # a datetime is a date too
        parsed = pd.to_datetime(pd.Series(list(cells)), errors="coerce", utc=True)
        return _naive_utc(parsed).to_numpy(), None, None
    if not all(isinstance(v, str) for v in filled):
        return None, None, None
    texts = pd.Series([str(v).strip() if v is not None else None for v in cells])
    if not texts.dropna().str.contains(r"\d{1,4}[-./]\d{1,2}[-./]\d{1,4}").all():
        return None, None, None
    hits = []
    for fmt in TIME_FORMATS:
        try:
            parsed = pd.to_datetime(texts, format=fmt if fmt else "ISO8601", errors="coerce", utc=True)
        except (ValueError, TypeError, OverflowError):
            continue
        parsed = _naive_utc(parsed)
        if parsed.notna().sum() >= PARSE_SHARE * len(filled):
            hits.append((fmt, parsed))
    if not hits:
        return None, None, None
    fmt, parsed = hits[0]
    check = None
    if len(hits) > 1 and _day_month_swapped({h[0] for h in hits}):
        check = "day/month or month/day? both read every cell; set time.format"
    return parsed.to_numpy(), fmt, check


#: Most distinct texts of a table's numeric columns read as missing-value markers; more are text.
MARKERS_MAX = 8

#: Least share of numbers among the filled cells of a column whose other cells may be markers.
MARKER_COLUMN_NUMBERS = 0.5


def missing_markers(columns: list, decimal: str = ".") -> Counter:
    """The texts a logger writes for a cell without a value (``---``, ``#N/A``, ``NaN``, ``ERR``,
    ``n/a``): text cells without a digit in columns otherwise of numbers.

    Parameters
    ----------
    columns : list of sequence
        The cells of each column of a table.
    decimal : str
        The decimal mark of text cells.

    Returns
    -------
    collections.Counter
        Marker (stripped) -> how many cells hold it. Empty when none is found, or when more than
        :data:`MARKERS_MAX` distinct texts are (the columns hold text, not markers). A column
        whose numbers are fewer than :data:`MARKER_COLUMN_NUMBERS` of its cells, or whose other
        texts carry a digit (dates, ``12a``), gives none.
    """
    found: Counter = Counter()
    for cells in columns:
        filled = [c for c in cells if c is not None and str(c).strip() != ""]
        if not filled:
            continue
        numbers = to_numbers(filled, decimal)
        texts = [str(c).strip() for c, x in zip(filled, numbers) if np.isnan(x) and isinstance(c, str)]
        if not texts or len(filled) - len(texts) < MARKER_COLUMN_NUMBERS * len(filled):
            continue
        if any(ch.isdigit() for t in texts for ch in t):
            continue
        found.update(texts)
    return found if len(found) <= MARKERS_MAX else Counter()


# --------------------------------------------------------------------------- content features


def _steps(values: np.ndarray) -> np.ndarray:
    v = values[np.isfinite(values)]
    return np.diff(v)


def _start_level(values: np.ndarray) -> float:
    v = values[np.isfinite(values)]
    return float(np.median(v[: max(3, len(v) // 100)]))


def _is_clock(values: np.ndarray) -> tuple[bool, float]:
    """(every row later than the one before in regular steps, the median step)."""
    d = _steps(values)
    if len(d) < 2 or np.isnan(values).any() or not (d > 0).all():
        return False, 0.0
    step = float(np.median(d))
    regular = np.mean(np.abs(d - step) <= 0.01 * step + 1e-9)
    return bool(regular >= 0.9), step


def clock_number_kind(values: np.ndarray, step: float) -> str | None:
    """The kind of a clock written as a number (:data:`CLOCK_NUMBERS`) whose first value and
    step fit it, else None (elapsed time)."""
    first = float(values[np.isfinite(values)][0])
    for kind, ((lo, hi), max_step) in CLOCK_NUMBERS.items():
        if lo <= first < hi and 0 < step <= max_step:
            return kind
    return None


def _is_speed(values: np.ndarray) -> tuple[bool, str]:
    """Held at levels with jumps between them, non-negative, in the r/min range."""
    v = values[np.isfinite(values)]
    top = float(np.max(np.abs(v)))
    if v.min() < 0 or top > SPEED_MAX_RPM or top < 100:
        return False, ""
    d = np.abs(np.diff(v))
    held = np.mean(d <= 0.005 * top)
    jumps = int(np.sum(d > 0.05 * top))
    levels = np.unique(np.round(v / max(top * 0.01, 1.0)))
    if held >= 0.97 and 1 <= jumps <= max(3, len(v) // 20):
        return True, f"held at levels (e.g. {_levels_text(v)}) with {jumps} jump(s), 0-{top:g}"
    if held >= 0.999 and len(levels) <= 2 and jumps == 0:
        return False, f"one level, {top:g}"
    return False, ""


def _levels_text(v: np.ndarray, n: int = 4) -> str:
    """The ``n`` most frequent levels, rounded to about 1 % of the largest value."""
    top = float(np.max(np.abs(v)))
    q = 10.0 ** np.floor(np.log10(max(top * 0.01, 1.0)))
    vals, counts = np.unique(np.round(v / q) * q, return_counts=True)
    best = vals[np.argsort(-counts)][:n]
    return ", ".join(f"{x:g}" for x in sorted(best))


def _smooth(values: np.ndarray) -> bool:
    """Slow against its noise: the lag-1 autocorrelation (after a 5-row running median, which
    removes single spikes) is at least :data:`SMOOTH_MIN_AUTOCORR` (a drifting probe with noise
    passes, a column that jumps from row to row does not)."""
    v = values[np.isfinite(values)]
    v = pd.Series(v).rolling(5, center=True, min_periods=1).median().to_numpy()  # single spikes go
    if len(v) < 10 or np.std(v) == 0:
        return False
    d = v - v.mean()
    return bool(np.sum(d[:-1] * d[1:]) / np.sum(d * d) >= SMOOTH_MIN_AUTOCORR)


#: Lag-1 autocorrelation of a slow channel (a temperature, a probe) at least.
SMOOTH_MIN_AUTOCORR = 0.8


def _resolution(values: np.ndarray) -> float:
    """The smallest step between two distinct values (the logger's resolution)."""
    u = np.unique(values[np.isfinite(values)])
    if len(u) < 2:
        return 0.0
    return float(np.min(np.diff(u)))


# --------------------------------------------------------------------------- one column


def _temperature(header: str, v: np.ndarray, hints: set) -> tuple[str, str, str | None] | None:
    """(unit, why, check) of a temperature column, or None when the levels are not a temperature."""
    lo, hi, start = float(np.nanmin(v)), float(np.nanmax(v)), _start_level(v)
    named = header_unit(header)
    span = f"{lo:.1f}-{hi:.1f}"
    if named == "degF":
        return "degF", f"header says deg F, {span}", None
    if KELVIN_RANGE[0] <= lo and hi <= KELVIN_RANGE[1]:
        return "K", f"{span}: Kelvin", None
    if not (CELSIUS_RANGE[0] <= lo and hi <= CELSIUS_RANGE[1]):
        return None
    said = " (header says deg C)" if named == "degC" else ""
    if named != "degC" and FAHRENHEIT_START[0] <= start <= FAHRENHEIT_START[1]:
        return "degC", f"{span}, starts at {start:.1f}", _F_CHECK
    return "degC", f"{span}, starts at {start:.1f}{said}", None


_F_CHECK = "deg C or deg F? a start above 45 is a room in deg F or a warm machine in deg C"


def _displacement(header: str, v: np.ndarray) -> tuple[str | None, str, str | None]:
    """(unit, why, check) of a displacement column: um or mm by range and resolution."""
    top = float(np.nanpercentile(np.abs(v), 99))
    res = _resolution(v)
    named = header_unit(header)
    rng = f"{np.nanmin(v):.4g}..{np.nanmax(v):.4g}"
    if named in ("um", "mm"):
        return named, f"{rng}, header says {named}", None
    if top >= 2.0:
        return "um", f"{rng}: tens of um (mm would be metres of growth)", None
    if top < 0.5 and 0 < res <= 0.001:
        return "mm", f"{rng}, resolution {res:g}: mm (um would be below the noise of a probe)", None
    return None, f"{rng}, resolution {res:g}", "um or mm? the range fits both"


def guess_column(index: int, header: str, cells, decimal: str = ".", label: str = "") -> ColumnGuess:
    """The likely role of one column from its header and cells (see the module docstring).

    Parameters
    ----------
    index : int
        0-based position of the column.
    header : str
        Its header (stripped).
    cells : sequence
        Its cells in row order (numbers, text, dates, None).
    decimal : str
        The decimal mark of text cells.
    label : str
        The column's label rows after the header (its unit, ``°C``), read with the header.

    Returns
    -------
    ColumnGuess
    """
    named = f"{header} [{label}]" if label else header
    hints = header_hints(named)

    def guess(role, unit, why, check=None, agree=None):
        same = {role, "time"} if role == "date" else {role}  # a "Date" header names the clock too
        agree = bool(same & hints) if agree is None else agree
        conf = "low" if check else ("high" if agree else "medium")
        other = hints - same
        if other and role not in hints and not check:
            conf = "low"
            check = f"the header suggests {', '.join(sorted(other))}; the content says {role}"
        return ColumnGuess(index, header, role, unit, conf, why, check)

    filled = [c for c in cells if c is not None and str(c).strip() != ""]
    if not filled:
        return ColumnGuess(index, header, "empty", None, "high", "no values")
    if _is_time_of_day(filled):
        return guess("time", "timeofday", "a time of day (the date in another column?)")
    times, fmt, tcheck = to_times(cells)
    if times is not None:
        stamps = pd.to_datetime(pd.Series(times)).dropna()
        if len(stamps) and (stamps == stamps.dt.normalize()).all() and not _has_clock_text(filled):
            return guess(
                "date", "date", "a date without the time of day" + (f" ({fmt})" if fmt else ""), tcheck
            )
        why = "date and time" + (f" ({fmt})" if fmt else "")
        if has_utc_offset(filled):
            why += ", with a UTC offset: read as UTC"
        return guess("time", "timestamp", why, tcheck)
    v = to_numbers(cells, decimal)
    n_num = int(np.isfinite(v).sum())
    if n_num < PARSE_SHARE * len(filled):
        return ColumnGuess(
            index, header, "text", None, "high", f"{len(filled) - n_num} cells are not numbers"
        )
    return _numeric_guess(named, v, hints, guess)


def _numeric_guess(header: str, v: np.ndarray, hints: set, guess) -> ColumnGuess:
    """The guess of a column of numbers (``guess`` builds the :class:`ColumnGuess`)."""
    if np.nanmax(v) == np.nanmin(v):
        if "speed" in hints and np.nanmin(v) >= 0:
            return guess("speed", "rpm", f"one level, {np.nanmin(v):g}, header names a speed")
        return guess("other", None, f"constant {np.nanmin(v):g}", agree=True)
    clock, step = _is_clock(v)
    if clock and ("time" in hints or not hints):  # a header naming another role is not a clock
        unit = header_unit(header)
        if unit in ("min", "h"):
            return guess("time", unit, f"rises by {step:g} {unit} every row: elapsed {unit}")
        kind = clock_number_kind(v, step)
        if kind is not None:
            return guess(
                "time",
                kind,
                f"from {v[np.isfinite(v)][0]:.12g}, by {step:.6g} every row: {CLOCK_WORDS[kind]}",
            )
        if _COUNTER.match(header.strip()):
            return guess("other", None, f"rises by {step:g} every row: a row counter", agree=True)
        if step == 1 and "time" not in hints:
            why = "rises by 1 every row"
            return guess("time", "s", why, "elapsed seconds at 1 s, or a row counter?")
        return guess("time", "s", f"rises by {step:g} every row: elapsed seconds")
    is_speed, why = _is_speed(v)
    if is_speed:
        return guess("speed", "rpm", why)
    if not _smooth(v):
        if "displacement" in hints:
            unit, why, _ = _displacement(header, v)
            return guess("displacement", unit, f"noisy, {why}", "a noisy channel: is it a probe?")
        return guess("other", None, "jumps from row to row: not a temperature or a probe", agree=True)
    start = _start_level(v)
    near_zero = abs(start) <= 0.1 * float(np.nanmax(np.abs(v))) + 0.05
    temp = _temperature(header, v, hints)
    if temp is not None and not ("displacement" in hints and "temperature" not in hints):
        if not near_zero or "temperature" in hints:
            unit, why, check = temp
            return guess("temperature", unit, "smooth, " + why, check)
    if near_zero or np.nanmin(v) < CELSIUS_RANGE[0] or "displacement" in hints or np.nanmin(v) < 0:
        unit, why, check = _displacement(header, v)
        why = ("smooth, starts near 0, " if near_zero else "smooth, ") + why
        return guess("displacement", unit, why, check)
    return guess("other", None, f"smooth, {np.nanmin(v):.4g}..{np.nanmax(v):.4g}: no role fits", agree=True)


# --------------------------------------------------------------------------- a whole table


def guess_columns(
    header: list[str],
    columns: list,
    decimal: str = ".",
    labels: list[str] | None = None,
    markers=(),
    *,
    dated: bool = False,
) -> list[ColumnGuess]:
    """Every column's guess, with one time and one speed column at most.

    Parameters
    ----------
    header : list of str
        The headers, in column order.
    columns : list of sequence
        The cells of each column, in the same order.
    decimal : str
        The decimal mark of text cells.
    labels : list of str, optional
        Each column's label rows after the header (units).
    markers : collection of str
        Missing-value markers (:func:`missing_markers`): such cells are read as empty.
    dated : bool
        The file names carry the date (``input.time.date_from_name``): a time of day is the
        clock without a date column.

    Returns
    -------
    list of ColumnGuess
        In column order. Of several time (speed) candidates the one with the highest
        confidence (then the first) keeps the role; the others become ``other``, saying so.
    """
    labels = labels or [""] * len(header)
    guesses = [
        guess_column(j, h, without_markers(list(c), markers), decimal, lab)
        for j, (h, c, lab) in enumerate(zip(header, columns, labels))
    ]
    if not any(g.role == "date" for g in guesses):  # a time of day needs its date
        guesses = [
            (
                replace(g, why="a time of day; the date in the file names")
                if dated
                else ColumnGuess(
                    g.index, g.header, "other", None, "low", "a time of day without a date column", None
                )
            )
            if g.role == "time" and g.unit == "timeofday"
            else g
            for g in guesses
        ]
    rank = {"high": 0, "medium": 1, "low": 2}
    for role in ("time", "speed"):
        found = [g for g in guesses if g.role == role]
        if len(found) < 2:
            continue
        keep = min(found, key=lambda g: (rank[g.confidence], g.index))
        for g in found:
            if g is not keep:
                guesses[g.index] = ColumnGuess(
                    g.index, g.header, "other", g.unit, "low", f"{g.why}; a second {role} column", None
                )
    return guesses


#: Names a sensor may not take (the canonical and derived columns; docs: the sensor contract).
RESERVED_NAMES = frozenset(
    {"time", "speed_rpm", "disp_um", "t_s", "dz_um", "log", "log_t_s", "segment", "run_id"}
)
SENSOR_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]{0,31}$")
#: Most sensors per machine.
MAX_SENSORS = 64

_UNIT_TAIL = re.compile(r"\s*[\[(][^\])]*[\])]\s*$")


def _slug(header: str) -> str:
    from rafi.readers.mapped import sanitise_name

    text = _UNIT_TAIL.sub("", header) or header
    slug = sanitise_name(text)
    slug = slug if slug != "column" else ""
    if slug.startswith("c_"):
        slug = "T" + slug[2:]
    return slug[:32].strip("_")


def sensor_names(headers: list[str]) -> list[str]:
    """A sensor name per temperature header: ``T<n>`` when every header carries its own
    number n (1..64; ``'Temperatur 3 [°C]'`` -> ``T3``, ``'t12(°C)'`` -> ``T12``), else a slug of
    the header (``'Lager vorne [°C]'`` -> ``lager_vorne``) when every slug is a valid and distinct
    sensor name, else ``T1``, ``T2``, ... in column order.
    """
    numbers = []
    for h in headers:
        found = re.findall(r"\d+", _UNIT_TAIL.sub("", h))
        numbers.append(int(found[-1]) if found else None)
    if all(n is not None and 1 <= n <= MAX_SENSORS for n in numbers) and len(set(numbers)) == len(numbers):
        return [f"T{n}" for n in numbers]
    slugs = [_slug(h) for h in headers]
    ok = all(SENSOR_NAME.match(s) and s not in RESERVED_NAMES for s in slugs)
    derived = any(s.startswith("d") and s[1:] in slugs for s in slugs)
    if ok and not derived and len(set(slugs)) == len(slugs):
        return slugs
    return [f"T{k}" for k in range(1, len(headers) + 1)]
