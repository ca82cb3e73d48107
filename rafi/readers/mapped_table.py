"""The table of a mapped csv or xlsx file: its rows as the machine's ``input:`` mapping lays them
out, and its cells parsed as numbers or text.

:func:`read_table` reads the header row (``input.header_row``) and the data rows after
``input.skip_rows`` into a :class:`Table` (cells as in the file, not yet parsed, with what is
needed to word an error: file, sheet, row, Excel cell), refusing a layout that does not follow
the mapping: a wrong delimiter, a row with another number of fields, the header repeated in the
data, a missing sheet, a cell past the last header. :func:`numeric` and :func:`text` turn one
column of raw cells into values; :func:`check_formulas` refuses formula cells whose value the
workbook does not hold (check ``formula_without_value``); :func:`check_zip_sizes` refuses a
workbook that would inflate past ``rafi.readers.parsing.FILE_MAX_BYTES`` (check
``file_too_large``). :mod:`rafi.readers.mapped` turns the table into the canonical frame.
"""

from __future__ import annotations

import datetime as dt
import difflib
import io
import math
import re
import zipfile
from collections.abc import Collection
from pathlib import Path

import numpy as np

from rafi.errors import RawFormatError, quote
from rafi.readers.input_layouts import column_label as excel_column  # noqa: F401 (this module's API)
from rafi.readers.input_spec import norm_header
from rafi.readers.parsing import (
    FIELD_MAX_CHARS,
    FILE_MAX_BYTES,
    check_column_count,
    check_fields,
    decode_bytes,
    field_count_error,
    marker_hint,
    split_fields,
    split_lines,
    unreadable_error,
    without_markers,
)


class Table:
    """Header + raw rows of one file, with what is needed to word an error."""

    def __init__(
        self,
        path: Path,
        header: list,
        rows: list[list],
        row_numbers: list[int],
        header_row: int,
        sheet: str | None,
    ):
        self.path = path
        self.header = [norm_header(h) for h in header]
        self.rows = rows
        self.row_numbers = row_numbers
        self.header_row = header_row
        self.sheet = sheet
        self.footer: list[list] = []
        self.footer_numbers: list[int] = []

    def drop_footer(self, n: int) -> None:
        """Set the last ``n`` data rows aside as summary rows (``input.footer_rows``): they are no
        longer :attr:`rows`, but :attr:`footer` (and their numbers :attr:`footer_numbers`).

        Raises
        ------
        RawFormatError
            The table has no more than ``n`` data rows.
        """
        if n <= 0 or not self.rows:  # no data row at all: the reader says so
            return
        if len(self.rows) <= n:
            raise RawFormatError(
                self.path,
                f"input.footer_rows: {n} summary row(s) to drop at the end, but the "
                f"{'sheet' if self.sheet is not None else 'file'} has only {len(self.rows)} data rows",
                line=self.row_numbers[-1] if self.row_numbers else self.header_row,
                sheet=self.sheet,
            )
        self.footer, self.footer_numbers = self.rows[-n:], self.row_numbers[-n:]
        self.rows, self.row_numbers = self.rows[:-n], self.row_numbers[:-n]

    def error(
        self, message: str, *, row: int | None = None, column: str | None = None, col_index: int | None = None
    ) -> RawFormatError:
        """A RawFormatError at ``row`` / ``column`` (with the Excel cell for xlsx)."""
        if self.sheet is not None and row is not None and col_index is not None:
            message = f"{message} (cell {excel_column(col_index)}{row})"
        return RawFormatError(self.path, message, line=row, column=column, sheet=self.sheet)


# --------------------------------------------------------------------------- the rows


def read_table(path: Path, raw: bytes, spec: dict) -> Table:
    """The header and data rows of a csv or xlsx file, as ``spec['format']`` says.

    Parameters
    ----------
    path : Path
        The raw file (names the errors).
    raw : bytes
        Its content (read once).
    spec : dict
        The normalised ``input:`` mapping, ``format`` ``csv`` or ``xlsx``.

    Returns
    -------
    Table
        Header, rows and their line (csv) or row (xlsx) numbers; the last ``input.footer_rows``
        rows set aside as :attr:`Table.footer`.

    Raises
    ------
    RawFormatError
        On anything in the file's layout that does not follow the mapping (an empty
        workbook file included), or no more data rows than ``input.footer_rows``.
    """
    if spec["format"] == "csv":
        table = read_csv_table(path, raw, spec)
    elif not raw:
        raise RawFormatError(path, "file is empty; expected an .xlsx workbook")
    else:
        table = read_xlsx_table(path, raw, spec)
    table.drop_footer(spec.get("footer_rows", 0))
    return table


def read_csv_table(path: Path, raw: bytes, spec: dict) -> Table:
    """The header and data rows of a delimited text file (``input.encoding``, ``delimiter``, ``header_row``).

    Blank lines are skipped; empty fields past the header's last column are dropped. Raises
    :class:`rafi.errors.RawFormatError` on a missing header, a header split by another
    delimiter than ``input.delimiter``, the header repeated in the data, or a row with
    another number of fields.
    """
    text = decode_bytes(
        path, raw, spec["encoding"], hint="set input.encoding to the file's encoding (e.g. latin-1, cp1252)"
    )
    lines = split_lines(text)
    hr = spec["header_row"]
    delim = spec["delimiter"]
    if hr is None:  # no header row: as many (unnamed) columns as the first data line has fields
        first_data = spec["skip_rows"]  # 0-based index of the first data line
        first = next((i for i in range(first_data, len(lines)) if lines[i].strip()), None)
        if first is None:
            raise RawFormatError(
                path, f"no data line after the {first_data} skipped line(s) (input.skip_rows)", line=1
            )
        fields = split_fields(path, lines[first], first + 1, delim)
        check_column_count(path, fields, first + 1)
        _check_delimiter(path, fields, delim, first + 1, "the first data line")
        header = [""] * len(fields)
    else:
        if hr > len(lines) or not lines[hr - 1].strip():
            raise RawFormatError(
                path,
                f"no header at line {hr} (input.header_row); the file has {len(lines)} line(s)",
                line=min(hr, max(len(lines), 1)),
            )
        header = [h.strip() for h in split_fields(path, lines[hr - 1], hr, delim)]
        check_fields(path, header, hr)
        check_column_count(path, header, hr)
        _check_delimiter(path, header, delim, hr, "header")
        first_data = hr + spec["skip_rows"]  # 0-based index of the first data line
    rows, numbers = [], []
    for i in range(first_data, len(lines)):
        line = lines[i]
        if not line.strip():
            continue
        line_no = i + 1
        fields = split_fields(path, line, line_no, delim)
        if len(line) > FIELD_MAX_CHARS:
            check_fields(path, fields, line_no, header, raw_line=line)
        if len(fields) > len(header) and not any(f.strip() for f in fields[len(header) :]):
            fields = fields[: len(header)]
        if len(fields) != len(header):
            if hr is not None and [norm_header(f) for f in fields] == [norm_header(h) for h in header]:
                raise RawFormatError(
                    path,
                    "the header line is repeated inside the data; expected one header only",
                    line=line_no,
                )
            raise field_count_error(
                path,
                line,
                line_no,
                len(fields),
                len(header),
                last=i == len(lines) - 1,
                too_many_hint=too_many_fields_hint(len(fields), len(header), delim, hr),
            )
        rows.append(fields)
        numbers.append(line_no)
    return Table(path, header, rows, numbers, hr, None)


def too_many_fields_hint(found: int, expected: int, delimiter: str, header_row: int | None) -> str:
    """The likely cause of a data line with ``found`` fields under a header of ``expected``:
    a decimal comma split by the delimiter ``,`` only when the counts allow it (each value split
    in two at most: no more than twice the header's fields); far more fields than that, a line
    above the table (a preamble) taken for the header; else a delimiter inside a value."""
    if delimiter == "," and found <= 2 * expected:
        return "a decimal comma with delimiter ','? set input.delimiter and input.decimal"
    if header_row is not None and found > 2 * expected:
        return (
            f"line {header_row} (input.header_row) looks like a line above the table, "
            "not its header: set input.header_row to the line of the column names"
        )
    return "a delimiter inside a value?"


def _check_delimiter(path: Path, fields: list[str], delim: str, line_no: int, what: str) -> None:
    """A line read as one field but holding another delimiter: ``input.delimiter`` is wrong."""
    if len(fields) != 1:
        return
    for other in (";", ",", "\t", "|"):
        if other != delim and other in fields[0]:
            raise RawFormatError(
                path,
                f"{what} is separated by {other!r}, not by the configured delimiter {delim!r}; "
                "set input.delimiter",
                line=line_no,
            )


def read_xlsx_table(path: Path, raw: bytes, spec: dict) -> Table:
    """The sheet of the workbook whose bytes are ``raw`` (read once: the file is not opened again).

    The sheet is ``input.sheet`` (0-based number or name); rows before ``input.header_row``
    and the ``input.skip_rows`` after it are skipped, blank rows too. Raises
    :class:`rafi.errors.RawFormatError` on a file that is not a workbook, a missing sheet, a
    row past Excel's last, a value in a column without a header, or no header.
    """
    wb = _open_workbook(path, raw)
    try:
        name = _sheet_name(path, list(wb.sheetnames), spec["sheet"])
        ws = wb[name]
        # the sheet's own <dimension> may be stale or forged: rows past it would be dropped
        # silently, and a forged A1:XFD1048576 pads every row to 16384 cells
        ws.reset_dimensions()
        hr = spec["header_row"]
        try:
            header, header_cells, rows, numbers = _sheet_rows(path, ws, name, hr, spec["skip_rows"])
        except RawFormatError:
            raise
        except OSError as exc:
            raise unreadable_error(path, exc) from None
        except Exception as exc:  # malformed sheet XML
            raise RawFormatError(
                path, f"cannot read the sheet ({type(exc).__name__}: {quote(exc)})", sheet=name
            ) from None
        if hr is None:
            header = _pad_rows(path, name, rows, spec["skip_rows"])
        elif not header:
            raise RawFormatError(
                path,
                f"no header in row {hr} (input.header_row); the sheet is empty there",
                line=hr,
                sheet=name,
            )
        table = Table(path, header, rows, numbers, hr, name)
        check_formulas(table, header_cells[: len(header)], raw)
        return table
    finally:
        wb.close()


def _open_workbook(path: Path, raw: bytes):
    """The workbook of the bytes ``raw`` (read-only, cached values), or the error that says it
    is none."""
    try:
        import openpyxl
    except ImportError as exc:  # pragma: no cover - openpyxl is a dependency
        raise RawFormatError(path, f"reading xlsx needs openpyxl ({exc})") from None
    check_zip_sizes(path, raw)
    try:
        return openpyxl.load_workbook(io.BytesIO(raw), read_only=True, data_only=True)
    except OSError as exc:
        raise unreadable_error(path, exc) from None
    except Exception as exc:  # zip, XML, openpyxl's own errors: all mean "not a workbook"
        raise RawFormatError(
            path,
            f"not a readable .xlsx workbook ({type(exc).__name__}: {quote(exc)}); "
            "save it as Excel Workbook (.xlsx)",
        ) from None


def _sheet_name(path: Path, names: list[str], sheet: int | str) -> str:
    """The name of the sheet ``input.sheet`` (0-based number, or name as :func:`norm_header`
    compares them) among ``names``."""
    available = ", ".join(repr(n) for n in names)
    if isinstance(sheet, int):
        if sheet >= len(names):
            raise RawFormatError(
                path, f"no sheet number {sheet} (0-based, input.sheet); the workbook has: {available}"
            )
        return names[sheet]
    match = [n for n in names if norm_header(n) == norm_header(sheet)]
    if not match:
        close = difflib.get_close_matches(sheet, names, n=3, cutoff=0.5)
        hint = f"; closest: {', '.join(map(repr, close))}" if close else ""
        raise RawFormatError(path, f"no sheet {sheet!r} (input.sheet); the workbook has: {available}{hint}")
    return match[0]


def _sheet_rows(path: Path, ws, name: str, hr: int | None, skip_rows: int) -> tuple:
    """``(header, header_cells, rows, numbers)`` of the sheet ``ws``: the header row ``hr``
    (None: no header row, and ``header`` None) as text and as cells, then the data rows after
    ``skip_rows`` (blank ones dropped, each as wide as the header) and their row numbers."""
    header = None
    header_cells: list = []
    rows, numbers = [], []
    for row_no, values in enumerate(ws.iter_rows(values_only=True), start=1):
        if row_no > XLSX_MAX_ROWS:
            raise RawFormatError(
                path,
                f"a row numbered beyond {XLSX_MAX_ROWS}, the last row of an Excel sheet: "
                "a corrupted or crafted workbook; open and save it in Excel or LibreOffice",
                line=row_no,
                sheet=name,
            )
        if hr is None:  # no header row: every row after skip_rows is data
            if row_no > skip_rows:
                _keep_row(path, name, list(values), row_no, rows, numbers)
        elif row_no == hr:
            header_cells = list(values)
            header = _header_text(path, list(values), row_no, name)
        elif row_no > hr + skip_rows and not _blank(values):
            rows.append(_fit_row(path, list(values), header, row_no, name))
            numbers.append(row_no)
    return header, header_cells, rows, numbers


def _blank(values) -> bool:
    return all(v is None or (isinstance(v, str) and not v.strip()) for v in values)


def _header_text(path: Path, values: list, row_no: int, sheet: str) -> list[str]:
    """The header row's cells as text, trailing empty cells dropped."""
    while values and (values[-1] is None or str(values[-1]).strip() == ""):
        values.pop()
    header = ["" if v is None else str(v) for v in values]
    check_fields(path, header, row_no, sheet=sheet)
    check_column_count(path, header, row_no, sheet=sheet)
    return header


def _fit_row(path: Path, values: list, header: list[str], row_no: int, sheet: str) -> list:
    """A data row as wide as the header: padded with empty cells, or cut where only empty cells
    lie past the last header (a value there is refused)."""
    check_fields(path, values, row_no, header, sheet=sheet)
    for j in range(len(header), len(values)):
        if values[j] is not None and str(values[j]).strip():
            raise RawFormatError(
                path,
                f"cell {excel_column(j)}{row_no} holds {quote(values[j])} but its column has no header",
                line=row_no,
                column=excel_column(j),
                sheet=sheet,
            )
    return values[: len(header)] + [None] * (len(header) - len(values))


def _keep_row(path: Path, sheet: str, values: list, row_no: int, rows: list, numbers: list) -> None:
    """A data row of a sheet without a header row: kept (trailing empty cells dropped) unless blank."""
    while values and (values[-1] is None or (isinstance(values[-1], str) and not values[-1].strip())):
        values.pop()
    if not values:
        return
    check_fields(path, values, row_no, None, sheet=sheet)
    check_column_count(path, values, row_no, sheet=sheet)
    rows.append(values)
    numbers.append(row_no)


def _pad_rows(path: Path, sheet: str, rows: list[list], skip_rows: int) -> list[str]:
    """The unnamed header of a sheet without a header row (as wide as its widest row); the
    shorter rows are padded with empty cells in place."""
    if not rows:
        raise RawFormatError(
            path, f"no data row after the {skip_rows} skipped row(s) (input.skip_rows)", line=1, sheet=sheet
        )
    width = max(len(r) for r in rows)
    header = [""] * width
    for r in rows:
        r.extend([None] * (width - len(r)))
    return header


# --------------------------------------------------------------------------- formulas

#: A formula element of sheet XML (``<f>``, ``<f t="shared" .../>``, ``<x:f>``).
_FORMULA_TAG = re.compile(rb"<(?:[A-Za-z_][\w.-]*:)?f[\s>/]")


#: Rows of an Excel sheet (1,048,576): a row numbered beyond it is a corrupted workbook.
XLSX_MAX_ROWS = 1 << 20


def check_zip_sizes(path, raw: bytes, limit: int = FILE_MAX_BYTES) -> None:
    """Raise ``file_too_large`` if the parts of the xlsx workbook ``raw`` inflate to more than
    ``limit`` bytes together (a "zip bomb": a small file whose sheet XML inflates to gigabytes).

    The sizes are those the zip's directory declares; Python's ``zipfile`` (used by openpyxl)
    never inflates a part beyond its declared size (it raises instead), so the check bounds
    what the reader inflates. A file that is not a zip is left to the reader (it says so).
    """
    try:
        with zipfile.ZipFile(io.BytesIO(raw)) as zf:
            infos = zf.infolist()
    except (zipfile.BadZipFile, OSError, RuntimeError, ValueError, EOFError, NotImplementedError):
        return
    total = sum(max(int(info.file_size), 0) for info in infos)
    if total > limit:
        biggest = max(infos, key=lambda info: info.file_size)
        raise RawFormatError(
            path,
            f"the workbook inflates to {total} bytes ({quote(biggest.filename)}: "
            f"{biggest.file_size} bytes) from {len(raw)} bytes on disk, more than the limit of "
            f"{limit} bytes ({limit >> 20} MiB); a log of a few days inflates to some megabytes: "
            "a corrupted or crafted workbook (a zip bomb), or split the recording into several files",
            check="file_too_large",
        )


def has_formulas(source: Path | bytes) -> bool:
    """True if any worksheet of the xlsx file (path or bytes) holds a formula (a streamed scan
    of its XML: about 0.05 s for the shipped 1.2 MB workbook, far less than reading it)."""
    if isinstance(source, (bytes, bytearray)):
        source = io.BytesIO(source)
    try:
        with zipfile.ZipFile(source) as zf:
            for name in zf.namelist():
                if not (name.startswith("xl/worksheets/") and name.endswith(".xml")):
                    continue
                tail = b""
                with zf.open(name) as fh:
                    for block in iter(lambda: fh.read(1 << 20), b""):
                        if _FORMULA_TAG.search(tail + block):
                            return True
                        tail = block[-32:]
    except (OSError, zipfile.BadZipFile, RuntimeError, ValueError, EOFError):
        return True  # cannot tell cheaply: let the exact check decide
    return False


def _is_formula(value) -> bool:
    if isinstance(value, str):
        return value.startswith("=")
    return type(value).__name__ in ("ArrayFormula", "DataTableFormula")


def check_formulas(table: Table, header_row: list, raw: bytes | None = None) -> None:
    """Raise ``formula_without_value`` if an empty cell of ``table`` is a formula.

    openpyxl reads the value a spreadsheet program saved with each formula; a workbook written
    by a program that does not compute formulas (a script, some exporters) has none, and its
    formula cells would read as empty, i.e. as logger dropouts. The exact check (the workbook
    opened a second time, formulas as text) runs only when the table has empty cells and the
    workbook has formulas at all.

    Parameters
    ----------
    table : Table
        The sheet as read with cached values (``data_only``).
    header_row : list
        The header row's cells as read (before the trailing empty ones were dropped).
    raw : bytes, optional
        The workbook's bytes (default: read ``table.path`` again).
    """
    empty = {
        row_no: [j for j, v in enumerate(values) if v is None]
        for row_no, values in zip(table.row_numbers, table.rows)
        if any(v is None for v in values)
    }
    header_gaps = [j for j, v in enumerate(header_row) if v is None]
    if header_gaps:
        empty[table.header_row] = header_gaps
    source = table.path if raw is None else raw
    if not empty or not has_formulas(source):
        return
    import openpyxl

    wb = openpyxl.load_workbook(
        io.BytesIO(raw) if raw is not None else table.path, read_only=True, data_only=False
    )
    try:
        found = []
        last = max(empty)
        ws = wb[table.sheet]
        ws.reset_dimensions()
        for row_no, values in enumerate(ws.iter_rows(values_only=True), start=1):
            if row_no > last:
                break
            for j in empty.get(row_no, ()):
                if j < len(values) and _is_formula(values[j]):
                    found.append((row_no, j, values[j]))
    finally:
        wb.close()
    if not found:
        return
    row_no, j, formula = found[0]
    text_ = formula if isinstance(formula, str) else getattr(formula, "text", str(formula))
    column = table.header[j] if j < len(table.header) and table.header[j] else excel_column(j)
    raise RawFormatError(
        table.path,
        f"cell {excel_column(j)}{row_no} holds the formula {quote(text_)} but no value saved with it "
        f"({len(found)} such cell(s) in the sheet); the workbook was written by a program that "
        "does not compute formulas, and its cells would read as dropouts: open and save it in "
        "Excel or LibreOffice so the values are saved, or export the sheet as CSV",
        line=row_no,
        column=column,
        sheet=table.sheet,
        check="formula_without_value",
    )


# --------------------------------------------------------------------------- value parsing

_THOUSANDS_POINT = re.compile(r"^[+-]?\d{1,3}(\.\d{3})+(,\d*)?$")


def numeric(
    table: Table,
    values: list,
    decimal: str,
    column: str,
    col_index: int,
    what: str,
    *,
    missing: Collection[str] = (),
) -> np.ndarray:
    """Raw cells -> float64 (NaN for empty); RawFormatError at the first bad cell.

    Parameters
    ----------
    table : Table
        The file (words the error).
    values : list
        The cells of one column, in row order.
    decimal : str
        ``.`` or ``,`` (``input.decimal``).
    column : str
        The header as written in the file.
    col_index : int
        0-based column index (the Excel letter in xlsx errors).
    what : str
        What was expected, for the error message.
    missing : collection of str
        ``input.missing_values``: text cells (compared stripped) that are missing values.

    Returns
    -------
    numpy.ndarray
        float64, NaN where a cell is empty or a missing-value marker.
    """
    out = np.full(len(values), np.nan)
    values = without_markers(values, missing)
    for k, v in enumerate(values):
        if v is None:
            continue
        if isinstance(v, bool) or isinstance(v, (dt.datetime, dt.date, dt.time, dt.timedelta)):
            raise table.error(
                f"{v!s} is not a number; expected {what}",
                row=table.row_numbers[k],
                column=column,
                col_index=col_index,
            )
        if isinstance(v, (int, float, np.integer, np.floating)):
            x = float(v)
        else:
            s = str(v).strip()
            s = s.replace("\u00a0", "").replace(" ", "")
            if not s:
                continue
            t = s
            if decimal == ",":
                if "." in t and _THOUSANDS_POINT.match(t):
                    t = t.replace(".", "")
                elif "." in t:
                    t = "!"  # a point in a decimal-comma file: refuse rather than guess
                t = t.replace(",", ".")
            elif "," in t:
                t = "!"
            try:
                x = float(t)
            except ValueError:
                hint = ""
                if decimal == "." and "," in s:
                    hint = " (decimal comma? set input.decimal: ',')"
                elif decimal == "," and "." in s:
                    hint = " (decimal point in a file with input.decimal: ',')"
                raise table.error(
                    f"{s!r} is not a number{hint}; expected {what}{marker_hint(s, hint)}",
                    row=table.row_numbers[k],
                    column=column,
                    col_index=col_index,
                ) from None
        if not math.isfinite(x):
            raise table.error(
                f"{v!r} is not a finite number; expected {what}{marker_hint(str(v).strip())}",
                row=table.row_numbers[k],
                column=column,
                col_index=col_index,
            )
        out[k] = x
    return out


def text(values: list) -> list[str]:
    """Raw cells -> stripped text (empty for a missing cell, ``3.0`` -> ``"3"``)."""
    out = []
    for v in values:
        if v is None:
            out.append("")
        elif isinstance(v, float) and v.is_integer():
            out.append(str(int(v)) if abs(v) < 1e15 else str(v))
        else:
            out.append(str(v).strip())
    return out
