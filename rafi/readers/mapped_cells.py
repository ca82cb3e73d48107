"""Cells of a mapped csv or xlsx file: the table as read, and cell values parsed as numbers or text.

:class:`Table` is the header and raw rows of one file with what is needed to word an error
(file, sheet, row, Excel cell); :func:`numeric` and :func:`text` turn one column of raw cells
into values. Used by :mod:`rafi.readers.mapped` and :mod:`rafi.readers.mapped_time`.
"""

from __future__ import annotations

import datetime as dt
import math
import re
from pathlib import Path

import numpy as np

from rafi.errors import RawFormatError
from rafi.readers.input_spec import norm_header


def excel_column(index0: int) -> str:
    """0-based column index -> Excel letters (0 -> A, 26 -> AA)."""
    letters = ""
    n = index0 + 1
    while n:
        n, rem = divmod(n - 1, 26)
        letters = chr(65 + rem) + letters
    return letters


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
