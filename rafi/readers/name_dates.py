"""The date in a log's file name and the time of day in its rows (``input.time.date_from_name``).

Some loggers write only the time of day in each row (``14:03:20``) and the date in the file name
(``spindle_2026-03-14.csv``, ``log_20260314.csv``, ``14.03.2026.csv``). ``date_from_name`` is the
date as the name writes it, in ``strftime`` codes (:data:`DATE_CODES`: ``%Y-%m-%d``, ``%Y%m%d``,
``%d.%m.%Y``), found anywhere in the name. Pure functions, standard library only (the mapping is
checked while the run is planned, without pandas):

* :func:`date_format_problem`: what is wrong with a configured format (or None);
* :func:`dates_in_name`: the dates a name holds in that form;
* :func:`time_of_day_seconds`: one cell as seconds since midnight;
* :func:`day_offsets`: the day of each row of a log over midnight (:data:`ROLLOVER_S`);
* :func:`name_date_format`: the format ``rafi init`` proposes for a folder's names.
"""

from __future__ import annotations

import datetime as dt
import re

from rafi.contract.input import DATE_FROM_NAME_ROLLOVER_S as ROLLOVER_S

#: The ``strftime`` codes of ``input.time.date_from_name`` and the text each matches (as
#: ``strptime`` reads them: a month and a day of one or two digits).
DATE_CODES = {
    "Y": r"\d{4}",
    "y": r"\d{2}",
    "m": r"1[0-2]|0[1-9]|[1-9]",
    "d": r"3[01]|[12]\d|0[1-9]|[1-9]",
    "b": r"[A-Za-z]{3}",
    "B": r"[A-Za-z]{3,9}",
}

#: A time of day as text: ``H:MM``, ``H:MM:SS``, ``H:MM:SS.fff`` on a 24-hour clock, or the same
#: with ``AM`` / ``PM`` after it on a 12-hour clock (``2:15:30 PM``, ``02:15 pm``, ``2:15:30PM``).
TIME_OF_DAY = re.compile(r"^(\d{1,2}):(\d{2})(?::(\d{2})(?:[.,](\d+))?)?(?:\s*([AaPp])\.?[Mm]\.?)?$")

_CODE = re.compile(r"%(.)")


def date_format_problem(fmt) -> str | None:
    """Why ``fmt`` cannot be ``input.time.date_from_name``, in words; None when it can.

    It must be text holding a day (``%d``), a month (``%m``, ``%b``, ``%B``) and a year
    (``%Y``, ``%y``), and no other code (``%%`` is a percent sign).
    """
    if not isinstance(fmt, str):
        return f"{fmt!r}: expected a date format such as '%Y-%m-%d' (quote it)"
    codes = _CODE.findall(fmt.replace("%%", ""))
    other = next((c for c in codes if c not in DATE_CODES), None)
    if other is not None:
        return f"'%{other}' is not a date code; the name's date in %Y, %y, %m, %b, %B and %d, e.g. '%Y%m%d'"
    if not ("d" in codes and {"m", "b", "B"} & set(codes) and {"Y", "y"} & set(codes)):
        return (
            f"{fmt!r}: expected a date format with a day, a month and a year, as the file names write "
            "it: '%Y-%m-%d' (spindle_2026-03-14.csv), '%Y%m%d' (log_20260314.csv), '%d.%m.%Y'"
        )
    return None


def _pattern(fmt: str) -> re.Pattern:
    """A regular expression of the texts ``fmt`` writes, not touching other digits."""
    out, k = [], 0
    while k < len(fmt):
        if fmt[k] == "%" and k + 1 < len(fmt):
            code = fmt[k + 1]
            out.append("%" if code == "%" else f"(?:{DATE_CODES[code]})")
            k += 2
        else:
            out.append(re.escape(fmt[k]))
            k += 1
    return re.compile(r"(?<!\d)" + "".join(out) + r"(?!\d)")


def dates_in_name(name: str, fmt: str) -> list[dt.date]:
    """The distinct dates ``name`` writes in the form ``fmt``, in the order found.

    Parameters
    ----------
    name : str
        A file name (``spindle_2026-03-14.csv``).
    fmt : str
        ``input.time.date_from_name`` (checked: :func:`date_format_problem`).

    Returns
    -------
    list of datetime.date
        Empty when none is found (a text of the form that is no date, ``2026-13-01``, is none).
    """
    found: list[dt.date] = []
    pattern = _pattern(fmt)
    for k in range(len(name)):
        m = pattern.match(name, k)
        if m is None:
            continue
        try:
            day = dt.datetime.strptime(m.group(0), fmt).date()
        except ValueError:
            continue
        if day not in found:
            found.append(day)
    return found


def time_of_day_seconds(cell, time_format: str | None = None) -> float | None:
    """A time-of-day cell as seconds since midnight; None when it is not one.

    Parameters
    ----------
    cell : object
        A workbook's time cell (``datetime.time``), or text: ``H:MM[:SS[.fff]]`` (24-hour, or
        12-hour with ``AM`` / ``PM`` after it: :data:`TIME_OF_DAY`), or as ``time_format``
        writes it when given.
    time_format : str or None
        ``input.time.format``: a ``strptime`` format of the time of day.
    """
    if isinstance(cell, dt.time):
        return cell.hour * 3600 + cell.minute * 60 + cell.second + cell.microsecond / 1e6
    if not isinstance(cell, str):
        return None
    text = cell.strip()
    if time_format:
        try:
            t = dt.datetime.strptime(text, time_format)
        except ValueError:
            return None
        return t.hour * 3600 + t.minute * 60 + t.second + t.microsecond / 1e6
    m = TIME_OF_DAY.match(text)
    if m is None:
        return None
    h, mi, s = int(m.group(1)), int(m.group(2)), int(m.group(3) or 0)
    if m.group(5):  # a 12-hour clock: 12 AM is midnight, 12 PM noon
        if not 1 <= h <= 12:
            return None
        h = h % 12 + (12 if m.group(5) in "Pp" else 0)
    if h > 23 or mi > 59 or s > 59:
        return None
    return h * 3600 + mi * 60 + s + (float("0." + m.group(4)) if m.group(4) else 0.0)


def is_time_of_day(cell) -> bool:
    """``cell`` is a time of day and nothing more: a time cell, or text ``H:MM[:SS[.fff]]`` (with
    ``AM`` / ``PM`` on a 12-hour clock) that :func:`time_of_day_seconds` reads."""
    return isinstance(cell, dt.time) or (isinstance(cell, str) and time_of_day_seconds(cell) is not None)


def day_offsets(seconds: list[float]) -> list[int]:
    """The day of each row of a log that writes the time of day, counted from its first row's.

    A time of day more than :data:`ROLLOVER_S` (12 h) before the row above is on the next day: the
    log ran over midnight (``23:59:30`` then ``00:00:00``). A smaller step back stays on the same
    day, so the times go back and the checks call it a clock reset.
    """
    out, day = [], 0
    for k, sec in enumerate(seconds):
        if k and sec < seconds[k - 1] - ROLLOVER_S:
            day += 1
        out.append(day)
    return out


#: The date formats ``rafi init`` tries on file names, in order: the ISO forms, then day first
#: before month first.
NAME_DATE_FORMATS = (
    "%Y-%m-%d",
    "%Y%m%d",
    "%Y_%m_%d",
    "%Y.%m.%d",
    "%d.%m.%Y",
    "%m.%d.%Y",
    "%d-%m-%Y",
    "%m-%d-%Y",
    "%d_%m_%Y",
    "%m_%d_%Y",
)


def _swapped(fmt: str) -> str:
    return fmt.replace("%d", "%@").replace("%m", "%d").replace("%@", "%m")


def name_date_format(names: list[str]) -> tuple[str | None, str | None]:
    """The ``input.time.date_from_name`` that finds one date in every name, and a check.

    Parameters
    ----------
    names : list of str
        The logs' file names.

    Returns
    -------
    tuple
        ``(format, check)``: the first of :data:`NAME_DATE_FORMATS` that finds exactly one date
        in each name (None: none does); ``check`` is a sentence when the same names read day
        first and month first too (``03.04.2026``), else None.
    """
    if not names:
        return None, None
    fits = [f for f in NAME_DATE_FORMATS if all(len(dates_in_name(n, f)) == 1 for n in names)]
    if not fits:
        return None, None
    fmt, check = fits[0], None
    other = _swapped(fmt)
    example = next((n for n in names if dates_in_name(n, fmt) != dates_in_name(n, other)), None)
    if other in fits and example is not None:
        check = (
            f"the file names' dates read day first or month first ({example}): {fmt!r} reads it as "
            f"{dates_in_name(example, fmt)[0]:%d %B %Y}; {other!r} if the month comes first"
        )
    return fmt, check


def cell_text(cell) -> str:
    """A cell as an error shows it: a time cell as ``HH:MM:SS``, text stripped."""
    return cell.isoformat() if isinstance(cell, dt.time) else str(cell).strip()


def time_of_day_hint(cell, name: str, folder: str, *, native: bool = False) -> str:
    """The error's words for a time of day met where a date and time was expected.

    Parameters
    ----------
    cell : object
        The cell (:func:`is_time_of_day`).
    name, folder : str
        The file's name and its folder (``rafi init``'s argument).
    native : bool
        The file was read as the native layout (its time must be a date and time).

    Returns
    -------
    str
        ``'14:03:20' is a time of day without a date; ...`` naming ``input.time.date_from_name``
        (with the format of the date the name holds, if one does), ``input.time.date_column`` and
        ``rafi init``.
    """
    fmt, _ = name_date_format([name])
    if fmt is not None:
        key = f"input.time.date_from_name: {fmt!r} (the date in the file name, {dates_in_name(name, fmt)[0]})"
    else:
        key = (
            "input.time.date_from_name (the date in the file name, e.g. '%Y-%m-%d' for "
            "spindle_2026-03-14.csv)"
        )
    init = f"`rafi init --machine NAME {folder}/` proposes it"
    if native:
        return (
            f"{cell_text(cell)!r} is a time of day without a date; the native layout's time is a date "
            f"and time (ISO-8601): a logger that writes the date apart needs the machine's input block "
            f"with format csv and {key}; {init}"
        )
    return (
        f"{cell_text(cell)!r} is a time of day without a date; set {key}, or input.time.date_column "
        f"(the date in a column of its own); {init}"
    )
