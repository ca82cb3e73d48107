"""Reading a log of unknown layout for ``rafi init``: its format, sheets, delimiter, header row.

:func:`read_unknown` opens one file (a native log, a delimited text with any delimiter and
decimal mark, an xlsx workbook) and returns a :class:`RawTable`: the layout it found (what
``input:`` keys would say it), every sheet of a workbook with what it holds, and the header and
cells of the data table. Nothing is assumed about the columns here; :mod:`rafi.readers.infer`
says what they hold. The csv text is split by the project's own reader
(:func:`rafi.readers.mapped_table.read_csv_table`) with the layout found, so a file that
``rafi init`` reads is one the pipeline reads with the proposed mapping.
"""

from __future__ import annotations

import codecs
import csv
import datetime as dt
import io
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from rafi.errors import RawFormatError, quote
from rafi.readers.input_spec import norm_header
from rafi.readers.mapped_table import excel_column, read_csv_table
from rafi.readers.name_dates import is_time_of_day
from rafi.readers.parsing import read_file_bytes, split_lines

#: Delimiters tried on a text file, in order of preference on a tie.
DELIMITERS = (",", ";", "\t", "|")

#: Encodings tried on a text file, in order.
ENCODINGS = ("utf-8", "cp1252")

#: Lines (rows) looked at to find the header.
HEAD_LINES = 40

#: Rows of numbers in a row, from the top, that make a file one without a header row.
HEADERLESS_DATA_ROWS = 5


@dataclass(frozen=True)
class SheetInfo:
    """One sheet of a workbook: its name, data rows, columns, kind (``data``, ``info``, ``empty``)
    and header (data sheets)."""

    name: str
    rows: int
    columns: int
    kind: str
    header: tuple = ()


@dataclass
class RawTable:
    """A file of unknown layout as read: the layout found, the sheets, the data table.

    Attributes
    ----------
    path : Path
        The file.
    format : str
        ``native``, ``csv`` or ``xlsx``.
    layout : dict
        The ``input:`` keys that say how it is read: ``delimiter``, ``decimal``, ``encoding``
        (csv), ``sheet`` (xlsx), ``header_row``, ``skip_rows``.
    header : list of str
        The headers (stripped, NFC).
    columns : list of list
        The cells of each column, in row order.
    sheets : list of SheetInfo
        Every sheet of a workbook (empty for a text file).
    meta : dict
        A native file's ``# key: value`` lines.
    start_hint : tuple of (str, str) or None
        A start time found beside the data (ISO text, where it was found).
    notes : list of str
        What the reading noticed (other data sheets, a units row).
    labels : list of str
        Per column, the text of the label rows after the header (units), else empty.
    sheet_group : tuple of str
        A workbook's data sheets sharing this sheet's header, this one included (workbook
        order); empty for a text file.
    """

    path: Path
    format: str
    layout: dict
    header: list
    columns: list
    sheets: list = field(default_factory=list)
    meta: dict = field(default_factory=dict)
    start_hint: tuple | None = None
    notes: list = field(default_factory=list)
    labels: list = field(default_factory=list)
    sheet_group: tuple = ()

    @property
    def n_rows(self) -> int:
        """Data rows."""
        return len(self.columns[0]) if self.columns else 0

    @property
    def headerless(self) -> bool:
        """No header row: the columns are named by their letters."""
        return self.layout.get("header_row", 1) is None

    @property
    def name(self) -> str:
        """The log's name: the sheet's, for one of several sheets of a workbook; else the file's."""
        return self.layout["sheet"] if len(self.sheet_group) > 1 else self.path.name


def _is_number(text) -> bool:
    if isinstance(text, (int, float)) and not isinstance(text, bool):
        return True
    if isinstance(text, (dt.datetime, dt.date, dt.time, dt.timedelta)):
        return True
    s = str(text).strip().replace(",", ".") if text is not None else ""
    if re.match(r"^\d{1,4}[-./]\d{1,2}[-./]\d{1,4}", s):
        return True
    try:
        float(s)
    except ValueError:
        return False
    return True


#: Most rows at the end of a table taken as summary rows (``Mean``, ``Max``, ...).
FOOTER_MAX_ROWS = 10

_CLOCK_TEXT = re.compile(r"^\d{1,2}:\d{2}")


def footer_rows(columns: list) -> int:
    """How many rows at the end of a table are summary rows (``Mean``, ``Max``, ``Average``): its
    last rows whose first column holds text that is neither a number nor a date nor a time of
    day, below cells that all are (``input.footer_rows``). 0 when there are none, more than
    :data:`FOOTER_MAX_ROWS`, or as many as half the rows."""
    if not columns or not columns[0]:
        return 0
    first = columns[0]
    n = 0
    for v in reversed(first):
        if not (isinstance(v, str) and v.strip()) or _is_number(v) or _CLOCK_TEXT.match(v.strip()):
            break
        n += 1
    if not n or n > FOOTER_MAX_ROWS or 2 * n >= len(first):
        return 0
    body = _filled(first[:-n])
    timeish = [c for c in body if _is_number(c) or (isinstance(c, str) and _CLOCK_TEXT.match(c.strip()))]
    return n if body and len(timeish) == len(body) else 0


def _without_footer(columns: list, layout: dict, notes: list) -> list:
    """``columns`` without their summary rows (:func:`footer_rows`); when there are some,
    ``layout['footer_rows']`` and a note say how many, and which (both changed in place)."""
    n = footer_rows(columns)
    if not n:
        return columns
    layout["footer_rows"] = n
    texts = ", ".join(repr(str(v).strip()) for v in columns[0][-n:])
    notes.append(f"the last {n} row(s) are a summary ({texts}), not samples: left out (input.footer_rows)")
    return [list(c[:-n]) for c in columns]


def _filled(cells) -> list:
    return [c for c in cells if c is not None and str(c).strip() != ""]


def _label_row(cells, least: int = 2) -> bool:
    """Mostly text (a header or a units row): at least ``least`` filled cells, no more than a
    fifth numbers."""
    filled = _filled(cells)
    if len(filled) < least:
        return False
    return sum(_is_number(c) for c in filled) <= len(filled) // 5


def _data_row(cells, least: int = 2) -> bool:
    filled = _filled(cells)
    return len(filled) >= least and sum(_is_number(c) for c in filled) >= 0.6 * len(filled)


def _least_filled(rows: list) -> int:
    """Filled cells a header or data row needs: 2, or 1 when no row of the head holds more than
    one (a one-column table: a displacement file of its own, the partner of a temperature file)."""
    return 1 if max((len(_filled(r)) for r in rows[:HEAD_LINES]), default=0) == 1 else 2


def _width(cells) -> int:
    """Cells up to the last filled one (a row's width, empty cells at its end not counted)."""
    return max((j + 1 for j, c in enumerate(cells) if c is not None and str(c).strip() != ""), default=0)


#: A header row names at least this share of the columns of the data rows below it (a
#: ``key,value`` line of a preamble above a table of 19 columns names 2: not its header).
HEADER_MIN_WIDTH_SHARE = 0.5


def header_position(rows: list) -> tuple[int, int] | None:
    """``(header index, label rows after it)`` of the first text row followed by data, or None.

    A header and its label rows (units) name about as many columns as the data rows below
    them hold (at least :data:`HEADER_MIN_WIDTH_SHARE` of the widest of them): the text lines
    of a ``key,value`` preamble are not the header of the table under them.
    """
    least = _least_filled(rows)
    for k, cells in enumerate(rows[:HEAD_LINES]):
        if not _label_row(cells, least):
            continue
        skip = 0
        while k + 1 + skip < len(rows) and skip < 3 and _label_row(rows[k + 1 + skip], least):
            skip += 1
        nxt = [r for r in rows[k + 1 + skip : k + 6 + skip] if any(c not in (None, "") for c in r)]
        if not (nxt and all(_data_row(r, least) for r in nxt)):
            continue
        data_width = max(_width(r) for r in nxt)
        if _width(cells) < HEADER_MIN_WIDTH_SHARE * data_width:
            continue  # a preamble line: the header is one of the label rows after it
        return k, skip
    return None


def headerless_start(rows: list) -> int | None:
    """Index of the first of :data:`HEADERLESS_DATA_ROWS` rows of numbers in a row (the data of a
    file without a header row, after a preamble of at most :data:`HEAD_LINES` rows), or None."""
    least = _least_filled(rows)
    for k in range(min(HEAD_LINES, len(rows))):
        nxt = rows[k : k + HEADERLESS_DATA_ROWS]
        if len(nxt) == min(HEADERLESS_DATA_ROWS, len(rows)) and all(_data_row(r, least) for r in nxt):
            return k
    return None


def letter_header(n: int) -> list[str]:
    """Column names of a table without a header row: its Excel letters (A, B, ..., AA)."""
    return [excel_column(j) for j in range(n)]


# --------------------------------------------------------------------------- text files


def split_quoted(line: str, delimiter: str) -> list[str]:
    """The stripped fields of one text line, split as the pipeline's reader splits it (the csv
    module: a field in double quotes may hold the delimiter, and its quotes are not part of it)."""
    try:
        fields = next(csv.reader([line], delimiter=delimiter, strict=False), [])
    except csv.Error:  # a line the reader refuses too: split plainly, the reader says why later
        fields = line.split(delimiter)
    return [f.strip() for f in fields]


def sniff_text(lines: list[str]) -> dict:
    """The delimiter, decimal mark and header line of text ``lines`` (comment lines ``#`` skipped).

    Returns
    -------
    dict
        ``delimiter``, ``decimal``, ``header_row`` (1-based), ``skip_rows`` (label lines after
        the header, e.g. units); ``header_row`` None when no header was found, and then
        ``headerless`` True when the lines are numbers from the top (after ``skip_rows`` lines).
    """
    body = [(i, ln) for i, ln in enumerate(lines[: HEAD_LINES * 5]) if ln.strip() and not ln.startswith("#")]
    best, score = ",", -1
    for delim in DELIMITERS:
        counts = [len(split_quoted(ln, delim)) - 1 for _, ln in body[:HEAD_LINES]]
        if not counts or max(counts) == 0:
            continue
        common = max(set(counts), key=counts.count)
        s = counts.count(common) * 1000 + common
        if common > 0 and s > score:
            best, score = delim, s
    rows = [split_quoted(ln, best) for _, ln in body]
    fields = [f for r in rows[1:HEAD_LINES] for f in r]
    commas = sum(bool(re.match(r"^[+-]?\d+,\d+$", f)) for f in fields)
    points = sum(bool(re.match(r"^[+-]?\d+\.\d+$", f)) for f in fields)
    decimal = "," if best != "," and commas > points else "."
    found = header_position(rows)
    header_row = body[found[0]][0] + 1 if found else None
    start = headerless_start(rows) if found is None else None
    return {
        "delimiter": best,
        "decimal": decimal,
        "header_row": header_row,
        "skip_rows": found[1] if found else (body[start][0] if start is not None else 0),
        "headerless": start is not None,
    }


def _labels(rows: list[list], n: int) -> list[str]:
    """Per column, the label rows' cells joined by a space (units such as ``°C``)."""
    return [
        " ".join(str(r[j]).strip() for r in rows if j < len(r) and r[j] is not None).strip() for j in range(n)
    ]


def _metadata(lines: list[str]) -> dict:
    meta = {}
    for ln in lines:
        if not ln.startswith("#"):
            break
        key, _, value = ln[1:].partition(":")
        meta[key.strip()] = value.strip()
    return meta


def _native_header(header: list[str]) -> bool:
    """True for the project's own layout: ``time``, ``speed_rpm``, sensor names, ``disp_um``."""
    from rafi.readers.input_spec import sensor_name_problem

    if header[:2] != ["time", "speed_rpm"] or "disp_um" not in header[3:]:
        return False
    sensors = header[2 : header.index("disp_um")]
    return all(sensor_name_problem(name) is None for name in sensors)


def _times_of_day(cells: list) -> bool:
    """Every filled cell a time of day (``14:03:20``): the native layout's header over a clock
    without its date, which the native reader cannot read (``input.time.date_from_name``)."""
    filled = [c for c in cells if c is not None and str(c).strip()]
    return bool(filled) and all(is_time_of_day(c) for c in filled)


def _read_text(path: Path, raw: bytes) -> RawTable:
    # a byte-order mark of UTF-16 (Excel's "Unicode text" export, some Windows loggers) decides;
    # else UTF-8, then cp1252, which decodes any byte
    encodings = ("utf-16",) if raw.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)) else ENCODINGS
    for enc in encodings:
        try:
            text = raw.decode("utf-8-sig" if enc == "utf-8" else enc)
            break
        except UnicodeDecodeError:
            continue
    lines = split_lines(text)
    found = sniff_text(lines)
    if found["header_row"] is None and not found["headerless"]:
        raise RawFormatError(path, "no header line followed by rows of numbers in the first lines")
    spec = {
        "format": "csv",
        "encoding": enc,
        "delimiter": found["delimiter"],
        "decimal": found["decimal"],
        "header_row": found["header_row"],
        "skip_rows": found["skip_rows"],
    }
    table = read_csv_table(path, raw, spec)
    meta = _metadata(lines)
    if found["headerless"]:
        header = letter_header(len(table.header))
        labels = [""] * len(header)
        notes = ["no header row: the columns are named by their letters (A, B, ...)"]
    else:
        header = list(table.header)
        below = [ln for ln in lines[spec["header_row"] :] if ln.strip()][: spec["skip_rows"]]
        labels = _labels([split_quoted(ln, spec["delimiter"]) for ln in below], len(header))
        notes = [f"{spec['skip_rows']} label row(s) after the header skipped"] if spec["skip_rows"] else []
    columns = [list(c) for c in zip(*table.rows)] if table.rows else [[] for _ in header]
    native = _native_header(header) and found["delimiter"] == "," and not _times_of_day(columns[0])
    layout = {k: spec[k] for k in ("delimiter", "decimal", "encoding", "header_row", "skip_rows")}
    return RawTable(
        path,
        "native" if native else "csv",
        layout,
        header,
        columns if native else _without_footer(columns, layout, notes),
        meta=meta,
        notes=notes,
        labels=labels,
    )


# --------------------------------------------------------------------------- workbooks


def _sheet_rows(ws) -> list[list]:
    ws.reset_dimensions()
    return [list(r) for r in ws.iter_rows(values_only=True)]


def _start_in(name: str, rows: list[list]) -> tuple[str, str] | None:
    """A date-and-time cell of an info sheet (ISO text, where), or None."""
    for r, cells in enumerate(rows[:HEAD_LINES], start=1):
        for c, v in enumerate(cells):
            when = None
            if isinstance(v, dt.datetime):
                when = v
            elif isinstance(v, str) and re.match(r"^\s*\d{4}-\d{2}-\d{2}[ T]\d{2}:\d{2}(:\d{2})?\s*$", v):
                when = dt.datetime.fromisoformat(v.strip().replace(" ", "T"))
            if when is not None:
                label = next((str(x) for x in cells[:c] if isinstance(x, str) and x.strip()), "")
                beside = f", next to {quote(label)}" if label else ""
                return when.isoformat(
                    timespec="seconds"
                ), f"sheet {quote(name)} cell {excel_column(c)}{r}{beside}"
    return None


def _sheet_table(name: str, rows: list[list]) -> tuple | None:
    """``(header row or None, skip, header, data rows, labels)`` of a sheet holding data: under
    a header row, or rows of numbers from the top (no header row: the columns by letter)."""
    found = header_position(rows)
    if found is not None:
        k, skip = found
        header = [norm_header("" if v is None else v) for v in rows[k]]
        while header and not header[-1]:
            header.pop()
        first, row, labels = k + 1 + skip, k + 1, _labels(rows[k + 1 : k + 1 + skip], len(header))
    else:
        start = headerless_start(rows)
        if start is None:
            return None
        width = max(len(r) for r in rows[start : start + HEAD_LINES])
        header, first, row, skip, labels = letter_header(width), start, None, start, [""] * width
    data = [r[: len(header)] + [None] * (len(header) - len(r)) for r in rows[first:]]
    data = [r for r in data if any(c is not None and str(c).strip() != "" for c in r)]
    while header and row is None and all(r[-1] is None for r in data):  # empty columns at the right
        header.pop()
        data = [r[:-1] for r in data]
    return row, skip, header, data, labels


def _read_workbook(path: Path, raw: bytes) -> list[RawTable]:
    """The largest data sheet of a workbook, then every other data sheet with its header."""
    import openpyxl

    from rafi.readers.mapped_table import check_zip_sizes

    check_zip_sizes(path, raw)
    try:
        wb = openpyxl.load_workbook(io.BytesIO(raw), read_only=True, data_only=True)
    except Exception as exc:  # zip, XML, openpyxl's own errors: all mean "not a workbook"
        raise RawFormatError(path, f"not a readable .xlsx workbook ({type(exc).__name__})") from None
    try:
        read = {name: _sheet_rows(wb[name]) for name in wb.sheetnames}
    finally:
        wb.close()
    sheets, tables, start = [], {}, None
    for name, rows in read.items():
        found = _sheet_table(name, rows)
        if found is None:
            kind = "empty" if not any(any(c is not None for c in r) for r in rows) else "info"
            sheets.append(SheetInfo(name, len(rows), max((len(r) for r in rows), default=0), kind))
            start = start or (_start_in(name, rows) if kind == "info" else None)
            continue
        tables[name] = found
        sheets.append(SheetInfo(name, len(found[3]), len(found[2]), "data", tuple(found[2])))
    if not tables:
        raise RawFormatError(path, "no sheet holds rows of numbers (under a header row or from the top)")
    first = max(tables, key=lambda n: len(tables[n][3]))
    group = [n for n in tables if n == first or tables[n][2] == tables[first][2]]
    twins = [n for n in group if n != first]
    notes = [f"{len(twins)} other sheet(s) with the same header: {', '.join(twins)}"] if twins else []
    if tables[first][0] is None:
        notes.append("no header row: the columns are named by their letters (A, B, ...)")
    out = []
    for name in [first, *twins]:
        header_row, skip, header, data, labels = tables[name]
        layout = {"sheet": name, "header_row": header_row, "skip_rows": skip}
        own = list(notes) if name == first else []
        columns = _without_footer(
            [list(c) for c in zip(*data)] if data else [[] for _ in header], layout, own
        )
        out.append(
            RawTable(
                path,
                "xlsx",
                layout,
                header,
                columns,
                sheets=sheets,
                start_hint=start,
                notes=own,
                labels=labels,
                sheet_group=tuple(group),
            )
        )
    return out


def read_unknown_logs(path: str | os.PathLike) -> list[RawTable]:
    """Every log of one file of unknown layout: the file, or every data sheet of a workbook that
    shares its largest sheet's header (the largest first, then the others in workbook order).

    Raises
    ------
    RawFormatError
        As :func:`read_unknown`.
    """
    path = Path(path)
    raw = read_file_bytes(path)
    if raw[:2] == b"PK":
        return _read_workbook(path, raw)
    return [_read_text(path, raw)]


def read_unknown(path: str | os.PathLike) -> RawTable:
    """Read one log of unknown layout (native, csv or xlsx; see the module docstring).

    Raises
    ------
    RawFormatError
        The file cannot be read, or holds no header followed by rows of numbers.
    """
    return read_unknown_logs(path)[0]
