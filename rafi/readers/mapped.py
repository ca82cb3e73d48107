"""Mapped readers: bring a machine's own CSV or xlsx layout into the canonical frame.

A machine's ``input:`` mapping in ``config.yaml`` (documented in
``docs/raw-format.md``, "Bringing your own layout") says where its columns are,
what they are called, which units and sign they use. :func:`read_mapped` reads one
file with such a mapping and returns the same canonical frame as
:func:`rafi.readers.native.read_raw_log`: ``time``, ``speed_rpm``, ``T1``..``T16``, ``disp_um``
then the remaining columns under sanitised names, indexed by the 1-based line (CSV)
or row (xlsx, as Excel shows it) of each record.

A file without a time column (``time.kind: none``) gets the times ``time.start + k *
time.period_s`` (:mod:`rafi.readers.mapped_time`); a file without a speed column its
configured constant speed (:mod:`rafi.readers.input_assumed`); both are recorded in
``attrs['metadata']['assumed']``. The file's header and rows are read by
:mod:`rafi.readers.mapped_tables`, its cells parsed by :mod:`rafi.readers.mapped_cells`.

Every problem with a file raises :class:`rafi.errors.RawFormatError` naming the
file, the sheet (xlsx), the line/row and the column as written in the file. A
mapping that is itself wrong raises :class:`rafi.errors.InputSpecError`.
"""

from __future__ import annotations

import difflib
import hashlib
import os
import re
import unicodedata
from pathlib import Path

import numpy as np
import pandas as pd

from rafi import SENSORS
from rafi.errors import RawFormatError
from rafi.readers.input_assumed import constant_speed, has_constant_speed
from rafi.readers.input_spec import (
    _spec_error,
    norm_header,
    normalise_input_spec,
    resolve_columns,
)
from rafi.readers.mapped_cells import (
    Table,
    excel_column,
    numeric,
    text,
)
from rafi.readers.mapped_tables import read_table
from rafi.readers.mapped_time import assumed_notes, has_clock, row_times, row_times_error, timestamps
from rafi.readers.parsing import (
    NUMERIC_COLUMNS,
    read_file_bytes,
    to_naive_ns,
)

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


# --------------------------------------------------------------------------- main entry


def _file_speed(path: Path, spec: dict) -> tuple[float, str] | None:
    """The file's configured constant speed and its key; None when the speed is read from a column."""
    if not has_constant_speed(spec):
        return None
    found = constant_speed(path.name, spec)
    if found is None:
        globs = ", ".join(repr(g) for g in spec["speed"]["constant_rpm_by_file"])
        raise RawFormatError(
            path,
            f"no speed for this file: the mapping reads no speed column and no glob of "
            f"input.speed.constant_rpm_by_file ({globs}) matches the file name {path.name!r}; "
            "add a glob that matches it, or set input.speed.constant_rpm for the machine",
        )
    return found


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
    where = (
        "input.displacement.column"
        if (canon == "disp_um" and spec["displacement"]["column"])
        else f"input.columns.{canon}"
    )
    return RawFormatError(
        table.path,
        f"header {theirs!r} ({where}) not found in the header row; {hint}",
        line=table.header_row,
        column=theirs,
        sheet=table.sheet,
    )


def _column_positions(table: Table, spec: dict) -> dict[str, int]:
    """Where each canonical column the mapping reads is in the file.

    Parameters
    ----------
    table : Table
        The file.
    spec : dict
        The normalised ``input:`` mapping.

    Returns
    -------
    dict
        Canonical column -> 0-based column index, for every column the mapping reads
        from the file (:func:`rafi.readers.input_spec.resolve_columns`).

    Raises
    ------
    RawFormatError
        When a mapped header is not in the file, or is there more than once.
    """
    positions: dict[str, int] = {}
    for canon, theirs in resolve_columns(spec).items():
        key = norm_header(theirs)
        hits = [j for j, h in enumerate(table.header) if h == key]
        if not hits:
            raise _header_not_found(table, spec, canon, theirs)
        if len(hits) > 1:
            raise RawFormatError(
                table.path,
                f"header {theirs!r} appears {len(hits)} times "
                f"(columns {', '.join(excel_column(j) for j in hits)}); "
                f"cannot tell which one is {canon}",
                line=table.header_row,
                column=theirs,
                sheet=table.sheet,
            )
        positions[canon] = hits[0]
    return positions


def _frame_times(table: Table, cols: list[tuple], positions: dict[str, int], spec: dict) -> pd.Series:
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
    return timestamps(table, list(cols[j]), spec, table.header[j], j)


def _canonical_values(table: Table, column: list, canon: str, col_index: int, spec: dict) -> np.ndarray:
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
        The normalised ``input:`` mapping (``decimal``, ``displacement.unit`` and
        ``sign``, ``temperature_unit``).

    Returns
    -------
    numpy.ndarray
        ``float64``; empty cells NaN; a displacement in mm times 1000 and by its sign
        (never -0.0), a temperature in K minus 273.15.

    Raises
    ------
    RawFormatError
        At the first cell that is not a number.
    """
    unit = {"speed_rpm": "r/min", "disp_um": spec["displacement"]["unit"]}.get(
        canon, "deg " + spec["temperature_unit"]
    )
    values = numeric(
        table, column, spec["decimal"], table.header[col_index], col_index, f"a number ({unit}) for {canon}"
    )
    if canon == "disp_um":
        values = values * (1000.0 if spec["displacement"]["unit"] == "mm" else 1.0)
        values = values * spec["displacement"]["sign"] + 0.0  # no -0.0
    elif canon in SENSORS and spec["temperature_unit"] == "K":
        values = values - 273.15
    return values.astype("float64")


def _add_extra_columns(
    frame: pd.DataFrame, table: Table, cols: list[tuple], positions: dict[str, int], spec: dict
) -> None:
    """Append the file's other columns to ``frame`` (in place) under sanitised, unique names.

    Parameters
    ----------
    frame : pandas.DataFrame
        The canonical frame so far.
    table : Table
        The file.
    cols : list of tuple
        The cells of each column, in row order.
    positions : dict
        Canonical column -> 0-based column index (these columns are not repeated).
    spec : dict
        The normalised ``input:`` mapping (``decimal``).

    Notes
    -----
    A column is numbers if every cell is one, else text. A column without a header is
    named after its letter (``column_x``) and left out when it is empty too; a name
    already taken gets ``_2``, ``_3``, ...
    """
    used = set(positions.values())
    taken = set(frame.columns) | {"line"}
    for j, name in enumerate(table.header):
        if j in used:
            continue
        values = list(cols[j])
        if not name and all(v is None or str(v).strip() == "" for v in values):
            continue
        base = sanitise_name(name) if name else f"column_{excel_column(j).lower()}"
        new, n = base, 2
        while new in taken:
            new, n = f"{base}_{n}", n + 1
        taken.add(new)
        try:
            frame[new] = numeric(table, values, spec["decimal"], name, j, "a number")
        except RawFormatError:
            frame[new] = pd.Series(text(values), index=frame.index, dtype="str")


def _mapped_metadata(
    spec: dict, table: Table, positions: dict[str, int], speed: tuple[float, str] | None
) -> dict:
    """``attrs['metadata']`` of a mapped frame: format, sheet, headers used, period, what was assumed.

    Parameters
    ----------
    spec : dict
        The normalised ``input:`` mapping.
    table : Table
        The file.
    positions : dict
        Canonical column -> 0-based column index.
    speed : tuple of (float, str) or None
        The file's constant speed and its key; None when the speed was read.

    Returns
    -------
    dict
        ``format``, ``sheet`` (xlsx), ``columns`` (canonical -> header used),
        ``sample_period_s`` (when the mapping gives it), ``assumed`` (when not empty) and
        ``clock`` ``False`` when the times are not dates (:func:`has_clock`).
    """
    meta: dict = {"format": spec["format"]}
    if table.sheet is not None:
        meta["sheet"] = table.sheet
    meta["columns"] = {canon: table.header[j] for canon, j in positions.items()}
    if spec["sample_period_s"] is not None:
        meta["sample_period_s"] = spec["sample_period_s"]
    assumed = assumed_notes(spec, speed=speed)
    if assumed:
        meta["assumed"] = assumed
    if not has_clock(spec):
        meta["clock"] = False  # elapsed times from NO_CLOCK_EPOCH: no date (rafi.method.runs)
    return meta


def read_mapped(path: str | os.PathLike, input_spec: dict) -> pd.DataFrame:
    """Read a csv or xlsx log with a machine's ``input:`` mapping into the canonical frame.

    Parameters
    ----------
    path : str or os.PathLike
        The raw file.
    input_spec : dict
        The ``input:`` mapping (normalised here with :func:`normalise_input_spec`);
        ``format`` must be ``csv`` or ``xlsx``.

    Returns
    -------
    pandas.DataFrame
        Canonical frame: ``time``, ``speed_rpm``, ``T1``..``T16`` (deg C),
        ``disp_um`` (um, sign and unit applied), then the other columns of the file
        under sanitised names (``'Verlagerung X1 [µm]'`` -> ``verlagerung_x1_um``,
        values as in the file). Index ``line`` = 1-based line (csv) or row (xlsx).
        ``attrs``: ``metadata`` (``format``, ``sheet`` for xlsx, ``columns`` =
        canonical -> header used, ``sample_period_s`` if the spec gives it,
        ``assumed`` = canonical column -> sentence for ``time`` / ``speed_rpm`` when they
        come from the config rather than the file, see
        :func:`rafi.readers.mapped_time.assumed_notes`), ``source``, ``sha256``.
        Without a time column (``time.kind: none``) data row k is at ``time.start + k *
        time.period_s``; without a speed column every row has the file's constant speed
        (:func:`rafi.readers.input_spec.constant_speed`).

    Raises
    ------
    RawFormatError
        Naming file, sheet (xlsx), line/row and the column as written in the file; also a
        file with no configured constant speed when the mapping reads no speed column.
    InputSpecError
        If the mapping is invalid (two speed globs with different speeds match the file
        included).
    """
    path = Path(path)
    spec = normalise_input_spec(input_spec)
    if spec["format"] not in ("csv", "xlsx"):
        raise _spec_error("format", f"read_mapped reads csv or xlsx, not {spec['format']!r}")
    raw = read_file_bytes(path)
    speed = _file_speed(path, spec)
    table = read_table(path, raw, spec)
    positions = _column_positions(table, spec)
    if not table.rows:
        raise RawFormatError(path, "header found but no data rows", line=table.header_row, sheet=table.sheet)

    cols = list(zip(*table.rows))
    index = pd.Index(table.row_numbers, name="line", dtype="int64")
    frame = pd.DataFrame(index=index)
    frame["time"] = to_naive_ns(_frame_times(table, cols, positions, spec)).to_numpy()
    for canon in NUMERIC_COLUMNS:
        if canon == "speed_rpm" and speed is not None:
            frame[canon] = np.full(len(index), speed[0], dtype="float64")
        else:
            j = positions[canon]
            frame[canon] = _canonical_values(table, list(cols[j]), canon, j, spec)
    if spec["keep_extra"]:
        _add_extra_columns(frame, table, cols, positions, spec)

    frame.attrs["metadata"] = _mapped_metadata(spec, table, positions, speed)
    frame.attrs["source"] = str(path)
    frame.attrs["sha256"] = hashlib.sha256(raw).hexdigest()
    return frame
