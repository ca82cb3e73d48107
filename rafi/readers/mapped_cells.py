"""Cells of a mapped csv or xlsx file: the table as read, and cell values parsed as numbers or text.

:class:`Table` is the header and raw rows of one file with what is needed to word an error
(file, sheet, row, Excel cell); :func:`numeric` and :func:`text` turn one column of raw cells
into values; :func:`check_formulas` refuses formula cells whose value the workbook does not
hold (check ``formula_without_value``); :func:`check_zip_sizes` refuses a workbook that would
inflate past ``rafi.readers.parsing.FILE_MAX_BYTES`` (check ``file_too_large``). Used by
:mod:`rafi.readers.mapped` and :mod:`rafi.readers.mapped_time`.
"""

from __future__ import annotations

import datetime as dt
import io
import math
import re
import zipfile
from pathlib import Path

import numpy as np

from rafi.errors import RawFormatError, quote
from rafi.readers.input_layouts import column_label as excel_column  # noqa: F401 (this module's API)
from rafi.readers.input_spec import norm_header
from rafi.readers.parsing import FILE_MAX_BYTES


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

    def error(
        self, message: str, *, row: int | None = None, column: str | None = None, col_index: int | None = None
    ) -> RawFormatError:
        """A RawFormatError at ``row`` / ``column`` (with the Excel cell for xlsx)."""
        if self.sheet is not None and row is not None and col_index is not None:
            message = f"{message} (cell {excel_column(col_index)}{row})"
        return RawFormatError(self.path, message, line=row, column=column, sheet=self.sheet)


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


def numeric(table: Table, values: list, decimal: str, column: str, col_index: int, what: str) -> np.ndarray:
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

    Returns
    -------
    numpy.ndarray
        float64, NaN where a cell is empty.
    """
    out = np.full(len(values), np.nan)
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
            s = str(v).strip().replace("\u00a0", "").replace(" ", "")
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
                    f"{s!r} is not a number{hint}; expected {what}",
                    row=table.row_numbers[k],
                    column=column,
                    col_index=col_index,
                ) from None
        if not math.isfinite(x):
            raise table.error(
                f"{v!r} is not a finite number; expected {what}",
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
