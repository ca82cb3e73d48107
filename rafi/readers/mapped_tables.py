"""The rows of a mapped csv or xlsx file, as its machine's ``input:`` mapping lays them out.

:func:`read_table` reads the header row (``input.header_row``) and the data rows after
``input.skip_rows`` into a :class:`rafi.readers.mapped_cells.Table` (cells as in the file, not
yet parsed), refusing a layout that does not follow the mapping: a wrong delimiter, a row with
another number of fields, the header repeated in the data, a missing sheet, a cell past the
last header. :mod:`rafi.readers.mapped` turns the table into the canonical frame.
"""

from __future__ import annotations

import difflib
import io
from pathlib import Path

from rafi.errors import RawFormatError, quote
from rafi.readers.input_spec import norm_header
from rafi.readers.mapped_cells import (
    XLSX_MAX_ROWS,
    Table,
    check_formulas,
    check_zip_sizes,
    excel_column,
)
from rafi.readers.parsing import (
    FIELD_MAX_CHARS,
    check_column_count,
    check_fields,
    decode_bytes,
    field_count_error,
    split_fields,
    split_lines,
    unreadable_error,
)


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
        Header, rows and their line (csv) or row (xlsx) numbers.

    Raises
    ------
    RawFormatError
        On anything in the file's layout that does not follow the mapping (an empty
        workbook file included).
    """
    if spec["format"] == "csv":
        return read_csv_table(path, raw, spec)
    if not raw:
        raise RawFormatError(path, "file is empty; expected an .xlsx workbook")
    return read_xlsx_table(path, raw, spec)


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
                too_many_hint=(
                    "a decimal comma with delimiter ','? set input.delimiter and input.decimal"
                    if delim == ","
                    else "a delimiter inside a value?"
                ),
            )
        rows.append(fields)
        numbers.append(line_no)
    return Table(path, header, rows, numbers, hr, None)


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
    try:
        import openpyxl
    except ImportError as exc:  # pragma: no cover - openpyxl is a dependency
        raise RawFormatError(path, f"reading xlsx needs openpyxl ({exc})") from None
    check_zip_sizes(path, raw)
    try:
        wb = openpyxl.load_workbook(io.BytesIO(raw), read_only=True, data_only=True)
    except OSError as exc:
        raise unreadable_error(path, exc) from None
    except Exception as exc:  # zip, XML, openpyxl's own errors: all mean "not a workbook"
        raise RawFormatError(
            path,
            f"not a readable .xlsx workbook ({type(exc).__name__}: {quote(exc)}); "
            "save it as Excel Workbook (.xlsx)",
        ) from None
    try:
        names = list(wb.sheetnames)
        sheet = spec["sheet"]
        available = ", ".join(repr(n) for n in names)
        if isinstance(sheet, int):
            if sheet >= len(names):
                raise RawFormatError(
                    path, f"no sheet number {sheet} (0-based, input.sheet); the workbook has: {available}"
                )
            name = names[sheet]
        else:
            match = [n for n in names if norm_header(n) == norm_header(sheet)]
            if not match:
                close = difflib.get_close_matches(sheet, names, n=3, cutoff=0.5)
                hint = f"; closest: {', '.join(map(repr, close))}" if close else ""
                raise RawFormatError(
                    path, f"no sheet {sheet!r} (input.sheet); the workbook has: {available}{hint}"
                )
            name = match[0]
        ws = wb[name]
        # the sheet's own <dimension> may be stale or forged: rows past it would be dropped
        # silently, and a forged A1:XFD1048576 pads every row to 16384 cells
        ws.reset_dimensions()
        hr = spec["header_row"]
        header = None
        header_cells: list = []
        rows, numbers = [], []
        try:
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
                    if row_no > spec["skip_rows"]:
                        _keep_row(path, name, list(values), row_no, rows, numbers)
                    continue
                if row_no < hr:
                    continue
                values = list(values)
                if row_no == hr:
                    header_cells = list(values)
                    while values and (values[-1] is None or str(values[-1]).strip() == ""):
                        values.pop()
                    header = ["" if v is None else str(v) for v in values]
                    check_fields(path, header, row_no, sheet=name)
                    check_column_count(path, header, row_no, sheet=name)
                    continue
                if row_no <= hr + spec["skip_rows"]:
                    continue
                if all(v is None or (isinstance(v, str) and not v.strip()) for v in values):
                    continue
                check_fields(path, values, row_no, header, sheet=name)
                if len(values) > len(header):
                    for j in range(len(header), len(values)):
                        if values[j] is not None and str(values[j]).strip():
                            raise RawFormatError(
                                path,
                                f"cell {excel_column(j)}{row_no} holds {quote(values[j])} but "
                                "its column has no header",
                                line=row_no,
                                column=excel_column(j),
                                sheet=name,
                            )
                    values = values[: len(header)]
                elif len(values) < len(header):
                    values = values + [None] * (len(header) - len(values))
                rows.append(values)
                numbers.append(row_no)
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
