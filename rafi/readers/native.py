"""Reading and writing logs and tables: the I/O edge of the project.

The native raw-log format is documented in ``docs/raw-format.md``. Every reader
returns the *canonical frame*: columns ``time`` (datetime64[ns]), ``speed_rpm``,
``T1``..``T16`` (deg C) and ``disp_um`` (float64), then any extra columns of the
file, indexed by the 1-based line number of each row in the source file (so any
later message can point back at the file). Metadata goes to ``frame.attrs``.

Writers are atomic: they write a temporary file beside the target and rename it,
so an interrupted run never leaves a half-written file that looks complete.
"""

from __future__ import annotations

import hashlib
import io
import math
import os
from pathlib import Path

import numpy as np
import pandas as pd

from rafi.artefact import write_text_atomic
from rafi.contract.sensors import DEFAULT_SENSORS, canonical_columns, frame_sensors
from rafi.errors import RawFormatError, quote
from rafi.readers.discovery import FOREIGN_FORMAT_DOCS
from rafi.readers.name_dates import is_time_of_day, time_of_day_hint
from rafi.readers.parsing import (
    _INNER_SPACE,
    FIELD_MAX_CHARS,
    METADATA_MAX_CHARS,
    NUMERIC_COLUMNS,
    _decode,
    check_column_count,
    check_fields,
    field_count_error,
    field_too_long_error,
    marker_hint,
    out_of_range_time,
    parse_numbers,
    read_file_bytes,
    split_fields,
    split_lines,
    to_naive_ns,
    without_markers,
)

#: Metadata keys with a documented meaning; any other ``# key: value`` is kept as text.
KNOWN_METADATA = {"machine", "run_id", "sample_period_s", "notes"}


# --------------------------------------------------------------------------- hashing


# --------------------------------------------------------------------------- atomic writes


# --------------------------------------------------------------------------- native reader


def _split_metadata(path: Path, lines: list[str]) -> tuple[dict[str, str], int, dict[str, int]]:
    """Return metadata, the index of the header line and the line number of each key."""
    meta: dict[str, str] = {}
    where: dict[str, int] = {}
    notes: list[str] = []
    total = 0
    for i, line in enumerate(lines):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            total += len(stripped)
            if total > METADATA_MAX_CHARS:
                raise RawFormatError(
                    path,
                    f"the '#' metadata lines hold more than {METADATA_MAX_CHARS} characters up to "
                    "this line; metadata is a few short 'key: value' lines: move long notes "
                    "out of the log",
                    line=i + 1,
                    check="field_too_long",
                )
        if not stripped.startswith("#"):
            meta_notes = "\n".join(notes)
            if meta_notes:
                meta["notes"] = (meta.get("notes", "") + "\n" + meta_notes).strip()
            return meta, i, where
        body = stripped.lstrip("#").strip()
        key, sep, value = body.partition(":")
        key = key.strip().lower().replace(" ", "_")
        if len(body) > FIELD_MAX_CHARS:
            raise field_too_long_error(
                path, body, line=i + 1, what=f"metadata {quote(key, 20) if sep else 'line'}"
            )
        if sep and key and " " not in key:
            if key == "notes" and key in meta:  # multi-line notes (see format_raw_log)
                meta[key] = meta[key] + "\n" + value.strip()
            else:
                meta[key] = value.strip()
            where[key] = i + 1
        elif body:
            notes.append(body)
    raise RawFormatError(
        path,
        "no header line found after the metadata; expected a header "
        f"with columns {', '.join(canonical_columns(DEFAULT_SENSORS))} (or the machine's input.sensors)",
        line=len(lines),
    )


def parse_metadata(meta: dict[str, str], path: Path, lines: dict[str, int] | None = None) -> dict:
    """Type the documented metadata keys (``sample_period_s`` as a positive float)."""
    out: dict = dict(meta)
    line = (lines or {}).get("sample_period_s")
    if "sample_period_s" in out:
        try:
            out["sample_period_s"] = float(out["sample_period_s"])
        except ValueError:
            raise RawFormatError(
                path,
                f"metadata 'sample_period_s' is {quote(meta['sample_period_s'])}; "
                "expected a number of seconds such as 5",
                line=line,
            ) from None
        if not (math.isfinite(out["sample_period_s"]) and out["sample_period_s"] > 0):
            raise RawFormatError(
                path,
                f"metadata 'sample_period_s' is {quote(meta['sample_period_s'])}; "
                "expected a positive number of seconds",
                line=line,
            )
    return out


def _check_header(
    path: Path,
    header: list[str],
    line_no: int,
    required: tuple[str, ...] = canonical_columns(DEFAULT_SENSORS),
) -> None:
    """Refuse a header that cannot be the native one: wrong delimiter, a name twice, a column missing.

    Parameters
    ----------
    path : Path
        The file (names the error).
    header : list of str
        The header's fields, stripped.
    line_no : int
        1-based line of the header.
    required : tuple of str
        The canonical columns of the machine (:func:`rafi.contract.sensors.canonical_columns`).

    Raises
    ------
    RawFormatError
        At the first problem, in the order: field limits, column count, a delimiter other
        than ``,``, a duplicate name, missing required columns.
    """
    check_fields(path, header, line_no)
    check_column_count(path, header, line_no)
    if len(header) == 1:
        for delim in (";", "\t", "|"):
            if delim in header[0]:
                raise RawFormatError(
                    path,
                    f"header is separated by {delim!r}; expected commas (',') between columns",
                    line=line_no,
                )
    seen: set[str] = set()
    for name in header:
        if name in seen:
            raise RawFormatError(
                path, f"column {quote(name)} appears twice in the header", line=line_no, column=name
            )
        seen.add(name)
    missing = [c for c in required if c not in seen]
    if len(missing) * 2 > len(required):
        shown = ", ".join(quote(name) for name in header[:4]) + (", ..." if len(header) > 4 else "")
        raise RawFormatError(
            path,
            f"the header ({shown}) is not the native layout's (time, speed_rpm, the sensors, "
            f"disp_um: {len(missing)} of {len(required)} missing); a log written by another "
            f"logger needs the machine's input block in config.yaml: `rafi init --machine NAME "
            f"{path.parent}/` proposes it ({FOREIGN_FORMAT_DOCS})",
            line=line_no,
            column=missing[0],
        )
    if missing:
        raise RawFormatError(
            path,
            f"required column(s) missing from header: {', '.join(missing)}; "
            f"expected {', '.join(required)} (the sensors are the machine's input.sensors)",
            line=line_no,
            column=missing[0],
        )


def _split_rows(
    path: Path, body_lines: list[str], header: list[str], header_line_no: int
) -> tuple[list[list[str]], list[int]]:
    """The data lines after the header as fields, with the 1-based line number of each row.

    Parameters
    ----------
    path : Path
        The file (names the error).
    body_lines : list of str
        The lines after the header.
    header : list of str
        The header's fields (their number is the number every row must have).
    header_line_no : int
        1-based line of the header.

    Returns
    -------
    rows : list of list of str
        One list of fields per non-blank line (stripped where the file has whitespace).
    line_numbers : list of int
        The line of each row.

    Raises
    ------
    RawFormatError
        On an oversized field, the header repeated inside the data, a row with another
        number of fields, or no data row at all.
    """
    # Whitespace around values is allowed; skip the per-field strip when there is none.
    needs_strip = _INNER_SPACE.search("".join(body_lines)) is not None
    rows: list[list[str]] = []
    line_numbers: list[int] = []
    n_fields = len(header)
    first = header[0]
    for offset, line in enumerate(body_lines):
        if not line or (needs_strip and not line.strip()):
            continue
        line_no = header_line_no + 1 + offset
        fields = line.split(",") if '"' not in line else split_fields(path, line, line_no)
        if needs_strip:
            fields = [f.strip() for f in fields]
        if len(line) > FIELD_MAX_CHARS:
            check_fields(path, fields, line_no, header, raw_line=line)
        if fields[0] == first and fields == header:
            raise RawFormatError(
                path, "the header line is repeated inside the data; expected one header only", line=line_no
            )
        if len(fields) != n_fields:
            raise field_count_error(
                path,
                line,
                line_no,
                len(fields),
                n_fields,
                last=offset == len(body_lines) - 1,
                too_many_hint="a decimal comma, or an unquoted comma in a value?",
            )
        rows.append(fields)
        line_numbers.append(line_no)
    if not rows:
        raise RawFormatError(path, "header found but no data rows", line=header_line_no)
    return rows, line_numbers


def _parse_times(path: Path, time_str: list[str], line_numbers: list[int]) -> np.ndarray:
    """The ``time`` column as naive ``datetime64[ns]`` (UTC where the text carried an offset).

    Parameters
    ----------
    path : Path
        The file (names the error).
    time_str : list of str
        The ``time`` fields, in row order.
    line_numbers : list of int
        The line of each row.

    Returns
    -------
    numpy.ndarray
        One timestamp per row.

    Raises
    ------
    RawFormatError
        At the first empty field, text that is not ISO-8601 (the header repeated inside the
        data is named as such) or a time outside the years 1678..2261.
    """
    if "" in time_str:
        bad = line_numbers[time_str.index("")]
        raise RawFormatError(
            path,
            "empty timestamp; expected an ISO-8601 time such as 2026-03-01T08:00:00",
            line=bad,
            column="time",
        )
    times = pd.Series(
        pd.to_datetime(pd.Series(time_str, dtype=object), format="ISO8601", errors="coerce", utc=True)
    )
    if times.isna().any():
        k = int(np.argmax(times.isna().to_numpy()))
        if times.notna().any() and time_str[k] == "time":
            raise RawFormatError(
                path,
                "the header line is repeated inside the data; expected one header only",
                line=line_numbers[k],
                column="time",
            )
        if is_time_of_day(time_str[k]):
            hint = time_of_day_hint(time_str[k], path.name, str(path.parent), native=True)
            raise RawFormatError(path, hint, line=line_numbers[k], column="time")
        raise RawFormatError(
            path,
            f"{quote(time_str[k])} is not an ISO-8601 timestamp (e.g. 2026-03-01T08:00:00)",
            line=line_numbers[k],
            column="time",
        )
    k = out_of_range_time(times)
    if k is not None:
        raise RawFormatError(
            path,
            f"timestamp {quote(time_str[k])} is outside the supported years 1678..2261",
            line=line_numbers[k],
            column="time",
        )
    return to_naive_ns(times).to_numpy()


def _parse_values(
    path: Path,
    header: list[str],
    columns: dict[str, list[str]],
    line_numbers: list[int],
    numeric: tuple[str, ...] = NUMERIC_COLUMNS,
    missing: tuple[str, ...] = (),
) -> dict[str, object]:
    """The numeric canonical columns, then the extra columns (numbers where every field is one, else text).

    Parameters
    ----------
    path : Path
        The file (names the error).
    header : list of str
        Column names in file order.
    columns : dict
        Column name -> its fields, in row order.
    line_numbers : list of int
        The line of each row.
    numeric : tuple of str
        The numeric canonical columns (:func:`rafi.readers.parsing.numeric_columns`).
    missing : tuple of str
        ``input.missing_values``: fields that are missing values in every numeric column
        (:func:`rafi.readers.parsing.without_markers`, as the mapped readers read them).

    Returns
    -------
    dict
        Column name -> values: ``float64`` arrays for ``speed_rpm``, the sensors and
        ``disp_um`` (empty fields and markers NaN), then every other column except ``time`` in
        file order (numbers where every field is one, a marker or empty, else text).

    Raises
    ------
    RawFormatError
        At the first field of a canonical column that is not a number.
    """
    data: dict[str, object] = {}
    for name in numeric:
        parsed, bad = parse_numbers(without_markers(columns[name], missing, ""))
        if bad is not None:
            found = columns[name][bad]
            hint = " (decimal comma? use a point)" if "," in found else ""
            raise RawFormatError(
                path,
                f"{quote(found)} is not a number{hint}; expected a decimal number in {name}"
                f"{marker_hint(found, hint)}",
                line=line_numbers[bad],
                column=name,
            )
        data[name] = parsed
    for name in header:
        if name in data or name == "time":
            continue
        parsed, bad = parse_numbers(without_markers(columns[name], missing, ""))
        data[name] = parsed if bad is None else pd.array(columns[name], dtype="str")
    return data


def read_raw_log(path: str | os.PathLike, sensors=DEFAULT_SENSORS, missing_values=()) -> pd.DataFrame:
    """Read one native raw log (``docs/raw-format.md``) into the canonical frame.

    Parameters
    ----------
    path : str or os.PathLike
        CSV file under ``raw/<machine>/``.
    sensors : sequence of str
        The machine's temperature sensors (``input.sensors``; the paper rig's ``T1`` .. ``T16``
        by default): columns the header must have.
    missing_values : sequence of str
        ``input.missing_values``: the texts the logger writes for no value (``---``, ``NaN``),
        missing in every numeric column as in a mapped log (none by default).

    Returns
    -------
    pandas.DataFrame
        Canonical columns first (``time``, ``speed_rpm``, the sensors, ``disp_um``), then
        extra columns; index = 1-based line number in the file.
        ``attrs`` holds ``metadata`` (dict), ``source`` (path) and ``sha256``.
        Empty numeric fields and ``missing_values`` markers become NaN (a logger dropout);
        cleaning decides what to do with them.

    Raises
    ------
    RawFormatError
        Naming file, line and column, on anything that does not follow the format.
        No other exception escapes for any file content (property-tested).
    """
    path = Path(path)
    raw = read_file_bytes(path)
    text = _decode(path, raw)
    lines = split_lines(text)
    meta, header_idx, meta_lines = _split_metadata(path, lines)
    meta = parse_metadata(meta, path, meta_lines)
    header_line_no = header_idx + 1

    header = [h.strip() for h in split_fields(path, lines[header_idx], header_line_no)]
    required = canonical_columns(sensors)
    _check_header(path, header, header_line_no, required)
    rows, line_numbers = _split_rows(path, lines[header_idx + 1 :], header, header_line_no)

    index = pd.Index(line_numbers, name="line", dtype="int64")
    columns = {name: list(col) for name, col in zip(header, zip(*rows))}
    data: dict[str, object] = {"time": _parse_times(path, columns["time"], line_numbers)}
    data.update(_parse_values(path, header, columns, line_numbers, required[1:], tuple(missing_values)))

    frame = pd.DataFrame(data, index=index)
    frame.attrs["metadata"] = meta
    frame.attrs["source"] = str(path)
    frame.attrs["sha256"] = hashlib.sha256(raw).hexdigest()
    return frame


# --------------------------------------------------------------------------- dispatch


def contract_violations(frame: pd.DataFrame) -> list[str]:
    """Ways ``frame`` breaks the canonical-frame contract (empty list = it holds).

    Checks column order and dtypes, the ``line`` index (unique, increasing, >= 1),
    finite-or-NaN numbers, no NaT in ``time`` and the ``attrs`` keys.
    """
    problems: list[str] = []
    cols = list(frame.columns)
    try:
        required = canonical_columns(frame_sensors(cols))
    except ValueError:
        required = canonical_columns(DEFAULT_SENSORS)
    if cols[: len(required)] != list(required):
        problems.append(f"canonical columns not first/in order: {cols[: len(required)]}")
        return problems
    numeric = required[1:]
    if len(set(cols)) != len(cols):
        problems.append("duplicate column names")
    if str(frame["time"].dtype) != "datetime64[ns]":
        problems.append(f"time dtype is {frame['time'].dtype}")
    elif frame["time"].isna().any():
        problems.append("NaT in time")
    for name in numeric:
        if str(frame[name].dtype) != "float64":
            problems.append(f"{name} dtype is {frame[name].dtype}")
        elif np.isinf(frame[name].to_numpy()).any():
            problems.append(f"infinite value in {name}")
    idx = frame.index
    if idx.name != "line":
        problems.append(f"index name is {idx.name!r}")
    if len(idx) == 0:
        problems.append("no rows")
    elif not (
        pd.api.types.is_integer_dtype(idx.dtype)
        and idx.is_unique
        and idx.is_monotonic_increasing
        and idx.min() >= 1
    ):
        problems.append("index is not unique increasing 1-based line numbers")
    for key in ("metadata", "source", "sha256"):
        if key not in frame.attrs:
            problems.append(f"attrs lacks {key!r}")
    if not isinstance(frame.attrs.get("metadata"), dict):
        problems.append("attrs['metadata'] is not a dict")
    return problems


# --------------------------------------------------------------------------- native writer

#: Decimal places used when writing each canonical column (the logger's resolution).
DEFAULT_DECIMALS = {"speed_rpm": 0, **{s: 2 for s in DEFAULT_SENSORS}, "disp_um": 3}


def format_raw_log(
    frame: pd.DataFrame, metadata: dict | None = None, decimals: dict[str, int] | None = None
) -> str:
    """Render a canonical frame as native raw-log text (deterministic).

    ``frame`` may hold NaN (written as an empty field) and rows in any order
    (written as given). ``time`` is written as ISO-8601 with whole seconds unless
    sub-second parts are present.
    """
    decimals = {**DEFAULT_DECIMALS, **(decimals or {})}
    out = io.StringIO()
    for key, value in (metadata or {}).items():
        for part in str(value).splitlines() or [""]:
            out.write(f"# {key}: {part}\n")
    columns = list(frame.columns)
    out.write(",".join(columns) + "\n")
    rendered: dict[str, np.ndarray] = {}
    for name in columns:
        col = frame[name]
        if name == "time":
            ts = pd.to_datetime(col)
            has_frac = bool((ts.dt.microsecond != 0).any())
            fmt = "%Y-%m-%dT%H:%M:%S.%f" if has_frac else "%Y-%m-%dT%H:%M:%S"
            rendered[name] = ts.dt.strftime(fmt).fillna("").to_numpy(dtype=object)
        elif pd.api.types.is_numeric_dtype(col):
            nd = decimals.get(name, 4)
            vals = col.to_numpy(dtype=float)
            strs = np.array([("" if np.isnan(v) else f"{v:.{nd}f}") for v in vals], dtype=object)
            if nd > 0:
                strs = np.array(
                    [("0." + "0" * nd) if s == ("-0." + "0" * nd) else s for s in strs], dtype=object
                )
            elif nd == 0:
                strs = np.array(["0" if s == "-0" else s for s in strs], dtype=object)
            rendered[name] = strs
        else:
            rendered[name] = col.astype(str).to_numpy(dtype=object)
    for i in range(len(frame)):
        out.write(",".join(rendered[name][i] for name in columns) + "\n")
    return out.getvalue()


def write_raw_log(
    frame: pd.DataFrame,
    path: str | os.PathLike,
    metadata: dict | None = None,
    decimals: dict[str, int] | None = None,
) -> None:
    """Write a native raw log atomically (see :func:`format_raw_log`)."""
    write_text_atomic(path, format_raw_log(frame, metadata, decimals))
