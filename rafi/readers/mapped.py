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
``attrs['metadata']['assumed']``. The file's header and rows are read, and its cells
parsed, by :mod:`rafi.readers.mapped_table`.

Every problem with a file raises :class:`rafi.errors.RawFormatError` naming the
file, the sheet (xlsx), the line/row and the column as written in the file. A
mapping that is itself wrong raises :class:`rafi.errors.InputSpecError`.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np
import pandas as pd

from rafi.errors import RawFormatError
from rafi.readers.input_assumed import has_constant_speed, log_speed
from rafi.readers.input_layouts import is_sheet_pattern
from rafi.readers.input_spec import (
    _spec_error,
    normalise_input_spec,
)
from rafi.readers.mapped_columns import canonical_values as _canonical_values
from rafi.readers.mapped_columns import (
    check_footer,
    closest_headers,  # noqa: F401 (this module's API)
    column_label,
    sanitise_name,
)
from rafi.readers.mapped_columns import column_positions as _column_positions
from rafi.readers.mapped_columns import frame_times as _frame_times
from rafi.readers.mapped_join import join_partner
from rafi.readers.mapped_table import (
    Table,
    excel_column,
    numeric,
    read_table,
    text,
)
from rafi.readers.mapped_time import assumed_notes, has_clock
from rafi.readers.parsing import (
    numeric_columns,
    read_file_bytes,
    to_naive_ns,
)


def _file_speed(path: Path, spec: dict, name: str | None = None) -> tuple[float, str] | None:
    """The log's configured constant speed and its key; None when the speed is read from a column.

    ``name`` is the log's name (a sheet-log's id, docs/raw-format.md), matched first; then the
    file name."""
    if not has_constant_speed(spec):
        return None
    found = log_speed(name, path.name, spec)
    if found is None:
        globs = ", ".join(repr(g) for g in spec["speed"]["constant_rpm_by_file"])
        raise RawFormatError(
            path,
            f"no speed for this file: the mapping reads no speed column and no glob of "
            f"input.speed.constant_rpm_by_file ({globs}) matches the "
            + (f"log name {name!r} or the " if name and name != path.name else "")
            + f"file name {path.name!r}; "
            "add a glob that matches it, or set input.speed.constant_rpm for the machine",
        )
    return found


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
        The normalised ``input:`` mapping (``decimal``, ``missing_values``).

    Notes
    -----
    A column is numbers if every cell is one (or empty, or a marker of
    ``input.missing_values``), else text. A column without a header is
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
            markers = spec["missing_values"]
            frame[new] = numeric(table, values, spec["decimal"], name, j, "a number", missing=markers)
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
    meta["columns"] = {canon: column_label(table, j) for canon, j in positions.items()}
    if spec["sample_period_s"] is not None:
        meta["sample_period_s"] = spec["sample_period_s"]
    assumed = assumed_notes(spec, speed=speed)
    if assumed:
        meta["assumed"] = assumed
    if not has_clock(spec):
        meta["clock"] = False  # elapsed times from NO_CLOCK_EPOCH: no date (rafi.method.runs)
    return meta


def read_mapped(
    path: str | os.PathLike,
    input_spec: dict,
    *,
    sheet: str | None = None,
    partner: str | os.PathLike | None = None,
    name: str | None = None,
) -> pd.DataFrame:
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
        file with no configured constant speed when the mapping reads no speed column, and a
        missing partner file or one whose rows do not agree (``input.join``).
    InputSpecError
        If the mapping is invalid (two speed globs with different speeds match the file
        included), or ``input.sheet`` is a pattern and no ``sheet`` is given.

    Notes
    -----
    ``sheet`` is the sheet to read when ``input.sheet`` is a pattern (each matching sheet is a
    log of its own, :mod:`rafi.readers.log_sources`); ``partner`` the partner file of an
    ``input.join`` (:mod:`rafi.readers.mapped_join`: its ``join.columns`` replace this file's);
    ``name`` the log's name, matched by ``speed.constant_rpm_by_file`` before the file name.
    """
    path = Path(path)
    spec = normalise_input_spec(input_spec)
    if spec["format"] not in ("csv", "xlsx"):
        raise _spec_error("format", f"read_mapped reads csv or xlsx, not {spec['format']!r}")
    if sheet is not None:
        spec["sheet"] = sheet
    elif is_sheet_pattern(spec["sheet"]):
        raise _spec_error("sheet", f"{spec['sheet']!r} is a pattern: give the sheet of the log to read")
    if spec["join"] is not None and partner is None:
        raise _spec_error("join", "the mapping joins a partner file: give the partner of the log to read")
    raw = read_file_bytes(path)
    speed = _file_speed(path, spec, name)
    table = read_table(path, raw, spec)
    positions = _column_positions(table, spec)
    if not table.rows:
        raise RawFormatError(path, "header found but no data rows", line=table.header_row, sheet=table.sheet)
    check_footer(table, positions, spec)

    cols = list(zip(*table.rows))
    index = pd.Index(table.row_numbers, name="line", dtype="int64")
    frame = pd.DataFrame(index=index)
    frame["time"] = to_naive_ns(_frame_times(table, cols, positions, spec)).to_numpy()
    joined, join_meta = {}, None
    if spec["join"] is not None:
        joined, join_meta = join_partner(table, frame["time"].to_numpy(), spec, Path(partner))
    for canon in numeric_columns(spec["sensors"]):
        if canon in joined:
            frame[canon] = joined[canon]
        elif canon == "speed_rpm" and speed is not None:
            frame[canon] = np.full(len(index), speed[0], dtype="float64")
        else:
            j = positions[canon]
            frame[canon] = _canonical_values(table, list(cols[j]), canon, j, spec)
    if spec["keep_extra"]:
        _add_extra_columns(frame, table, cols, positions, spec)

    frame.attrs["metadata"] = _mapped_metadata(spec, table, positions, speed)
    if join_meta is not None:
        frame.attrs["metadata"]["join"] = join_meta
    frame.attrs["source"] = str(path)
    frame.attrs["sha256"] = hashlib.sha256(raw).hexdigest()
    return frame
