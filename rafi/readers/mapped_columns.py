"""The columns of a mapped csv or xlsx file: where each canonical column is, and its values.

:func:`column_positions` finds each column the ``input:`` mapping reads (by header text, column
letter or position; docs/raw-format.md), :func:`frame_times` the time of each row and
:func:`canonical_values` one numeric column in the canonical unit and sign. Used by
:mod:`rafi.readers.mapped` (a file) and :mod:`rafi.readers.mapped_join` (its partner file).
"""

from __future__ import annotations

import difflib
import re
import unicodedata

import numpy as np
import pandas as pd

from rafi.errors import RawFormatError
from rafi.readers.input_layouts import column_index
from rafi.readers.input_spec import DATE_COLUMN, norm_header, resolve_columns
from rafi.readers.mapped_table import Table, excel_column, numeric
from rafi.readers.mapped_time import date_and_time, is_time_cell, row_times, row_times_error, timestamps
from rafi.readers.parsing import TO_DEG_C

# --------------------------------------------------------------------------- the mapping


def sanitise_name(header: str) -> str:
    """A header as a snake_case ASCII column name: ``'Verlagerung X1 [µm]'`` -> ``'verlagerung_x1_um'``."""
    text = norm_header(header).replace("µ", "u").replace("μ", "u").replace("°", "")
    text = text.replace("ß", "ss").replace("%", "pct")
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    text = re.sub(r"[^0-9a-zA-Z]+", "_", text).strip("_").lower()
    if not text:
        return "column"
    if text[0].isdigit():
        text = "c_" + text
    return text


def _simple(text: str) -> str:
    return re.sub(r"[\W_]+", "", sanitise_name(text)).casefold()


def closest_headers(wanted: str, available: list[str], n: int = 3) -> list[str]:
    """The ``n`` available headers most like ``wanted`` (difflib ratio, units/case/punctuation
    differences forgiven first): ``'Temperatur 3 [°C]'`` finds ``'Temperatur 3 [C]'``."""
    sw = _simple(wanted)

    def score(h: str) -> float:
        sh = _simple(h)
        exact = 1.0 if sh == sw and sw else 0.0
        return exact + max(
            difflib.SequenceMatcher(None, wanted, h).ratio(), difflib.SequenceMatcher(None, sw, sh).ratio()
        )

    ranked = sorted(available, key=score, reverse=True)
    return [h for h in ranked[:n] if score(h) >= 0.4]


def _header_not_found(table: Table, spec: dict, canon: str, theirs: str) -> RawFormatError:
    """The error for a mapped header missing from the file, with the closest headers it has.

    Parameters
    ----------
    table : Table
        The file.
    spec : dict
        The normalised ``input:`` mapping (says which key named the header).
    canon : str
        The canonical column sought.
    theirs : str
        The header the mapping gives for it.

    Returns
    -------
    RawFormatError
        Naming the header, the mapping key and the closest (else the first eight) headers.
    """
    candidates = [h for h in table.header if h]
    close = closest_headers(norm_header(theirs), candidates)
    if close:
        hint = "closest: " + ", ".join(repr(c) for c in close)
    else:
        hint = (
            "available: "
            + ", ".join(repr(c) for c in candidates[:8])
            + (", ..." if len(candidates) > 8 else "")
        )
    where = _mapping_key(spec, canon)
    return RawFormatError(
        table.path,
        f"header {theirs!r} ({where}) not found in the header row; {hint}",
        line=table.header_row,
        column=theirs,
        sheet=table.sheet,
    )


def _mapping_key(spec: dict, canon: str) -> str:
    """The config key that names canonical column ``canon``'s column."""
    if canon == "disp_um" and spec["displacement"]["column"]:
        return "input.displacement.column"
    if canon == DATE_COLUMN:
        return "input.time.date_column"
    return f"input.columns.{canon}"


def _where(table: Table) -> str:
    return f"sheet {table.sheet!r}" if table.sheet is not None else "the file"


def looks_like_data(table: Table) -> str | None:
    """If the header row's cells are mostly numbers: a sentence saying so (else None).

    A file without a header row read with ``header_row: 1`` has its first data row as header:
    its "headers" are numbers, and a mapped header is then missing or found several times."""
    cells = [h for h in table.header if h]
    numbers = []
    for h in cells:
        try:
            float(h.replace(",", "."))
        except ValueError:
            continue
        numbers.append(h)
    if len(cells) < 2 or len(numbers) < 0.8 * len(cells):
        return None
    shown = ", ".join(repr(h) for h in numbers[:3])
    return (
        f"row {table.header_row} (input.header_row) looks like data, not a header: {len(numbers)} of "
        f"its {len(cells)} cells are numbers ({shown}, ...); for a file without a header row set "
        "input.header_row: none and give input.columns as column letters ('A', 'B', ...) or "
        "1-based positions"
    )


def column_positions(table: Table, spec: dict, columns: dict | None = None) -> dict[str, int]:
    """Where each canonical column the mapping reads is in the file.

    Parameters
    ----------
    table : Table
        The file.
    spec : dict
        The normalised ``input:`` mapping.
    columns : dict, optional
        Canonical column -> header text, letter or position to find (default: every column the
        mapping reads, :func:`rafi.readers.input_spec.resolve_columns`).

    Returns
    -------
    dict
        Canonical column -> 0-based column index.

    Raises
    ------
    RawFormatError
        When a mapped header is not in the file, or is there more than once (a header row of
        numbers: says it looks like data), or a letter or position lies beyond the last column.
    """
    positions: dict[str, int] = {}
    header = table.header_row is not None
    for canon, theirs in (resolve_columns(spec) if columns is None else columns).items():
        index = column_index(theirs, header=header)
        if index is not None:
            if index >= len(table.header):
                raise RawFormatError(
                    table.path,
                    f"{_mapping_key(spec, canon)}: column {excel_column(index)!r} (position {index + 1}) "
                    f"is beyond the {len(table.header)} columns of {_where(table)}",
                    column=excel_column(index),
                    sheet=table.sheet,
                )
            positions[canon] = index
            continue
        key = norm_header(theirs)
        hits = [j for j, h in enumerate(table.header) if h == key]
        if len(hits) != 1 and looks_like_data(table):
            raise RawFormatError(table.path, looks_like_data(table), line=table.header_row, sheet=table.sheet)
        if not hits:
            raise _header_not_found(table, spec, canon, theirs)
        if len(hits) > 1:
            raise RawFormatError(
                table.path,
                f"header {theirs!r} appears {len(hits)} times "
                f"(columns {', '.join(excel_column(j) for j in hits)}); "
                f"cannot tell which one is {canon} ({_mapping_key(spec, canon)})",
                line=table.header_row,
                column=theirs,
                sheet=table.sheet,
            )
        positions[canon] = hits[0]
    return positions


def column_label(table: Table, j: int) -> str:
    """Column ``j`` of ``table`` as errors name it: its header, else its letter."""
    return table.header[j] or excel_column(j)


def frame_times(table: Table, cols: list[tuple], positions: dict[str, int], spec: dict) -> pd.Series:
    """The time of each data row: from the time column, or row k at ``time.start + k * time.period_s``.

    Parameters
    ----------
    table : Table
        The file.
    cols : list of tuple
        The cells of each column, in row order.
    positions : dict
        Canonical column -> 0-based column index.
    spec : dict
        The normalised ``input:`` mapping.

    Returns
    -------
    pandas.Series
        Naive timestamps, one per row.

    Raises
    ------
    RawFormatError
        At the first cell that is not a time, or when the rows of a file without a time
        column would end after 2261.
    """
    if spec["time"]["kind"] == "none":
        problem = row_times_error(len(table.rows), spec)
        if problem:
            raise RawFormatError(table.path, problem, line=table.row_numbers[-1], sheet=table.sheet)
        return row_times(len(table.rows), spec)
    j = positions["time"]
    if DATE_COLUMN in positions:  # a date column and a time-of-day column
        d = positions[DATE_COLUMN]
        cells = date_and_time(list(cols[d]), list(cols[j]))
        return timestamps(table, cells, spec, f"{column_label(table, d)} + {column_label(table, j)}", j)
    return timestamps(table, list(cols[j]), spec, column_label(table, j), j)


def check_footer(table: Table, positions: dict[str, int], spec: dict) -> None:
    """The rows ``input.footer_rows`` set aside (:attr:`Table.footer`) are summary rows, not
    samples: a row whose time cell reads as a time is refused (a file without summary rows, or
    with fewer; the key is the same for every file of the machine). Nothing to check without a
    time column.

    Raises
    ------
    RawFormatError
        Naming the row, its time and the key.
    """
    if not table.footer or "time" not in positions:
        return
    j = positions["time"]
    for cells, row in zip(table.footer, table.footer_numbers):
        cell = cells[j]
        if DATE_COLUMN in positions:
            cell = date_and_time([cells[positions[DATE_COLUMN]]], [cell])[0]
        if is_time_cell(cell, spec):
            n = spec["footer_rows"]
            raise table.error(
                f"{str(cell).strip()!r} is a sample (a time), not a summary row; input.footer_rows: {n} "
                f"drops the last {n} rows of every file: does this file end without them, or with fewer?",
                row=row,
                column=column_label(table, j),
                col_index=j,
            )


def canonical_values(table: Table, column: list, canon: str, col_index: int, spec: dict) -> np.ndarray:
    """One numeric canonical column in the canonical unit and sign (um, deg C, r/min).

    Parameters
    ----------
    table : Table
        The file.
    column : list
        The column's cells, in row order.
    canon : str
        The canonical column (``speed_rpm``, ``T1``..``T16`` or ``disp_um``).
    col_index : int
        0-based index of the column in the file.
    spec : dict
        The normalised ``input:`` mapping (``decimal``, ``missing_values``, ``displacement.unit``
        and ``sign``, ``temperature_unit``).

    Returns
    -------
    numpy.ndarray
        ``float64``; empty cells and ``input.missing_values`` markers NaN; a displacement in mm
        times 1000 and by its sign (never -0.0), a temperature in K or deg F in deg C
        (:data:`rafi.readers.parsing.TO_DEG_C`).

    Raises
    ------
    RawFormatError
        At the first cell that is not a number.
    """
    unit = {"speed_rpm": "r/min", "disp_um": spec["displacement"]["unit"]}.get(
        canon, "deg " + spec["temperature_unit"]
    )
    label = column_label(table, col_index)
    what = f"a number ({unit}) for {canon}"
    values = numeric(table, column, spec["decimal"], label, col_index, what, missing=spec["missing_values"])
    if canon == "disp_um":
        values = values * (1000.0 if spec["displacement"]["unit"] == "mm" else 1.0)
        values = values * spec["displacement"]["sign"] + 0.0  # no -0.0
    elif canon in spec["sensors"] and spec["temperature_unit"] in TO_DEG_C:
        values = TO_DEG_C[spec["temperature_unit"]](values)
    return values.astype("float64")
