"""Temperatures and displacement in two files: the partner file's columns joined to a log's rows.

A machine whose logger writes the temperatures to one file and the probe to another
(``temps_0312.csv`` and ``disp_0312.csv``) sets ``input.join`` (docs/raw-format.md,
"Temperatures and displacement in two files"): the partner of each raw file is the file of the
same folder named with ``join.replace[0]`` replaced by ``join.replace[1]``; the canonical
``join.columns`` are read from it (with the machine's layout keys, overridden by
``join.input``) and matched to the log's rows by time (each row takes the partner row nearest
its time within half a sample period) or by row (equal numbers of rows).

:func:`join_partner` is called by :func:`rafi.readers.mapped.read_mapped`; every disagreement
raises :class:`rafi.errors.RawFormatError` naming both files.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from rafi.errors import RawFormatError
from rafi.readers.input_layouts import is_sheet_pattern
from rafi.readers.input_spec import partner_input_spec
from rafi.readers.mapped_columns import canonical_values, column_positions, frame_times
from rafi.readers.mapped_table import Table, read_table
from rafi.readers.parsing import read_file_bytes, to_naive_ns


def _fmt(t) -> str:
    return str(pd.Timestamp(t))


def sample_period_ns(times: np.ndarray, spec: dict) -> float:
    """The log's sample period in ns: ``sample_period_s`` if the mapping gives it, else the
    median step of its times (NaN with fewer than two distinct times)."""
    if spec["sample_period_s"] is not None:
        return float(spec["sample_period_s"]) * 1e9
    steps = np.diff(np.sort(times.astype("int64")))
    steps = steps[steps > 0]
    return float(np.median(steps)) if len(steps) else float("nan")


def match_by_time(main_ns: np.ndarray, partner_ns: np.ndarray, tolerance_ns: float) -> np.ndarray:
    """For each main time, the index of the partner row nearest it within ``tolerance_ns`` (-1: none).

    Parameters
    ----------
    main_ns, partner_ns : numpy.ndarray of int64
        Times in ns (the partner's in any order).
    tolerance_ns : float
        Half a sample period: a partner row farther away than this is not the row's partner.

    Returns
    -------
    numpy.ndarray of int64
        Partner row per main row, -1 where none is close enough (ties: the earlier row).
    """
    order = np.argsort(partner_ns, kind="stable")
    sorted_ns = partner_ns[order]
    right = np.searchsorted(sorted_ns, main_ns, side="left")
    best = np.full(len(main_ns), -1, dtype="int64")
    best_gap = np.full(len(main_ns), np.inf)
    for cand in (right - 1, right):
        ok = (cand >= 0) & (cand < len(sorted_ns))
        gap = np.full(len(main_ns), np.inf)
        gap[ok] = np.abs(sorted_ns[cand[ok]].astype("float64") - main_ns[ok].astype("float64"))
        better = gap < best_gap
        best[better] = cand[better]
        best_gap[better] = gap[better]
    matched = best_gap <= tolerance_ns
    out = np.full(len(main_ns), -1, dtype="int64")
    out[matched] = order[best[matched]]
    return out


def _read_partner(table: Table, spec: dict, partner: Path) -> tuple[Table, dict, dict, list]:
    """The partner's table, its normalised mapping, the positions of its columns and its cells."""
    join = spec["join"]
    if not partner.is_file():
        raise RawFormatError(
            table.path,
            f"no partner file {partner.name!r} in {partner.parent} (input.join.replace "
            f"{join['replace'][0]!r} -> {join['replace'][1]!r} in the file name); the partner holds "
            f"{', '.join(join['columns'])}: copy it next to the file, or fix input.join.replace",
            sheet=table.sheet,
        )
    pspec, wanted = partner_input_spec(spec)
    if is_sheet_pattern(pspec["sheet"]):  # a sheet-log: the partner's sheet of the same name
        pspec["sheet"] = table.sheet
    ptable = read_table(partner, read_file_bytes(partner), pspec)
    columns = {c: pspec["columns"].get(c, c) for c in wanted}
    if "disp_um" in columns and pspec["displacement"]["column"] is not None:
        columns["disp_um"] = pspec["displacement"]["column"]
    positions = column_positions(ptable, pspec, columns)
    if not ptable.rows:
        raise RawFormatError(partner, "no data rows (partner file of input.join)", sheet=ptable.sheet)
    return ptable, pspec, positions, list(zip(*ptable.rows))


def join_partner(
    table: Table, main_times: np.ndarray, spec: dict, partner: Path
) -> tuple[dict[str, np.ndarray], dict]:
    """The ``join.columns`` of a log from its partner file, one value per row of ``table``.

    Parameters
    ----------
    table : Table
        The log's file as read.
    main_times : numpy.ndarray of datetime64[ns]
        The time of each of its rows.
    spec : dict
        The log's normalised ``input:`` mapping (``join`` set).
    partner : Path
        The partner file.

    Returns
    -------
    values : dict
        Canonical column -> float64 values per row of ``table`` (NaN where a row has no partner row).
    meta : dict
        ``attrs['metadata']['join']``: ``partner`` (file name), ``by``, ``columns``,
        ``unmatched_rows`` (rows without a partner row).

    Raises
    ------
    RawFormatError
        No partner file (naming the expected name); ``by: row`` and another number of rows;
        ``by: time`` and more than ``join.max_unmatched`` of either file's rows without a
        partner (naming both files and their time spans).
    """
    join = spec["join"]
    ptable, pspec, positions, pcols = _read_partner(table, spec, partner)
    n, m = len(table.rows), len(ptable.rows)
    if join["by"] == "row":
        if n != m:
            raise RawFormatError(
                table.path,
                f"{n} data rows, but its partner file {partner.name} has {m} (input.join.by: row "
                "needs the same number of rows in both files; by: time matches rows by their time)",
                sheet=table.sheet,
            )
        rows = np.arange(n)
    else:
        ptimes = to_naive_ns(frame_times(ptable, pcols, positions, pspec)).to_numpy()
        main_ns, p_ns = main_times.astype("int64"), ptimes.astype("int64")
        half = sample_period_ns(main_times, spec) / 2
        rows = match_by_time(main_ns, p_ns, half) if np.isfinite(half) else np.full(n, -1)
        lo, hi = main_ns.min() - half, main_ns.max() + half
        outside = int(np.count_nonzero((p_ns < lo) | (p_ns > hi)))
        unmatched = int(np.count_nonzero(rows < 0))
        share = max(unmatched / n, outside / m)
        if share > join["max_unmatched"]:
            raise RawFormatError(
                table.path,
                f"its times do not agree with its partner file {partner.name} (input.join.by: time): "
                f"{unmatched} of {n} rows have no partner row within {half / 1e9:g} s (half the sample "
                f"period) and {outside} of the partner's {m} rows lie outside this file's times; "
                f"this file runs {_fmt(main_times.min())} .. {_fmt(main_times.max())}, the partner "
                f"{_fmt(ptimes.min())} .. {_fmt(ptimes.max())}; at most "
                f"{join['max_unmatched']:.1%} is allowed (input.join.max_unmatched)",
                sheet=table.sheet,
            )
    values = {}
    for canon in join["columns"]:
        j = positions[canon]
        column = canonical_values(ptable, list(pcols[j]), canon, j, pspec)
        out = np.full(n, np.nan)
        ok = rows >= 0
        out[ok] = column[rows[ok]]
        values[canon] = out
    meta = {
        "partner": partner.name,
        "by": join["by"],
        "columns": list(join["columns"]),
        "unmatched_rows": int(np.count_nonzero(rows < 0)),
    }
    if ptable.sheet is not None:
        meta["partner_sheet"] = ptable.sheet
    return values, meta
