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

import contextlib
import csv
import hashlib
import io
import os
import tempfile
from pathlib import Path
from typing import Iterator

import numpy as np
import pandas as pd

from . import REQUIRED_COLUMNS, SENSORS
from .errors import RawFormatError

NUMERIC_COLUMNS = ("speed_rpm", *SENSORS, "disp_um")

#: Metadata keys with a documented meaning; any other ``# key: value`` is kept as text.
KNOWN_METADATA = {"machine", "run_id", "sample_period_s", "notes"}


# --------------------------------------------------------------------------- hashing

def sha256_file(path: str | os.PathLike) -> str:
    """Return the hex SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


# --------------------------------------------------------------------------- atomic writes

@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    On any exception the temporary file is removed and ``path`` is untouched.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=target.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8, ``\\n`` line ends) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8", newline="\n")


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_csv_atomic(frame: pd.DataFrame, path: str | os.PathLike, **kwargs) -> None:
    """Write a table as CSV atomically (no index unless asked)."""
    kwargs.setdefault("index", False)
    kwargs.setdefault("lineterminator", "\n")
    with atomic_path(path) as tmp:
        frame.to_csv(tmp, **kwargs)


def write_parquet_atomic(frame: pd.DataFrame, path: str | os.PathLike) -> None:
    """Write a frame as Parquet atomically (index kept)."""
    with atomic_path(path) as tmp:
        frame.to_parquet(tmp, engine="pyarrow")


# --------------------------------------------------------------------------- native reader

def _decode(path: Path, raw: bytes) -> str:
    if not raw.strip():
        raise RawFormatError(path, "file is empty; expected optional '# key: value' lines, "
                                   "a header line and data rows")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise RawFormatError(
            path, f"byte 0x{raw[exc.start]:02x} is not valid UTF-8; the file must be UTF-8 encoded",
            line=line) from None


def _split_metadata(path: Path, lines: list[str]) -> tuple[dict[str, str], int]:
    """Return metadata and the index of the header line."""
    meta: dict[str, str] = {}
    notes: list[str] = []
    for i, line in enumerate(lines):
        stripped = line.strip()
        if not stripped:
            continue
        if not stripped.startswith("#"):
            meta_notes = "\n".join(notes)
            if meta_notes:
                meta["notes"] = (meta.get("notes", "") + "\n" + meta_notes).strip()
            return meta, i
        body = stripped.lstrip("#").strip()
        key, sep, value = body.partition(":")
        key = key.strip().lower().replace(" ", "_")
        if sep and key and " " not in key:
            meta[key] = value.strip()
        elif body:
            notes.append(body)
    raise RawFormatError(path, "no header line found after the metadata; expected a header "
                               f"with columns {', '.join(REQUIRED_COLUMNS)}", line=len(lines))


def parse_metadata(meta: dict[str, str], path: Path) -> dict:
    """Type the documented metadata keys (``sample_period_s`` as float)."""
    out: dict = dict(meta)
    if "sample_period_s" in out:
        try:
            out["sample_period_s"] = float(out["sample_period_s"])
        except ValueError:
            raise RawFormatError(path, f"metadata 'sample_period_s' is {meta['sample_period_s']!r}; "
                                       "expected a number of seconds") from None
        if not out["sample_period_s"] > 0:
            raise RawFormatError(path, "metadata 'sample_period_s' must be positive")
    return out


def _first_bad(values: pd.Series, parsed: pd.Series) -> int | None:
    """Index label of the first value that is non-empty but did not parse."""
    bad = parsed.isna() & values.fillna("").str.strip().ne("")
    if bad.any():
        return bad.idxmax()
    return None


def read_raw_log(path: str | os.PathLike) -> pd.DataFrame:
    """Read one native raw log (``docs/raw-format.md``) into the canonical frame.

    Parameters
    ----------
    path : str or os.PathLike
        CSV file under ``raw/<machine>/``.

    Returns
    -------
    pandas.DataFrame
        Canonical columns first (``time``, ``speed_rpm``, ``T1``..``T16``,
        ``disp_um``), then extra columns; index = 1-based line number in the file.
        ``attrs`` holds ``metadata`` (dict), ``source`` (path) and ``sha256``.
        Empty numeric fields become NaN (a logger dropout); cleaning decides what
        to do with them.

    Raises
    ------
    RawFormatError
        Naming file, line and column, on anything that does not follow the format.
    """
    path = Path(path)
    raw = path.read_bytes()
    text = _decode(path, raw)
    lines = text.splitlines()
    meta, header_idx = _split_metadata(path, lines)
    meta = parse_metadata(meta, path)
    header_line_no = header_idx + 1

    header = next(csv.reader([lines[header_idx]]))
    header = [h.strip() for h in header]
    if len(header) == 1:
        for delim in (";", "\t", "|"):
            if delim in header[0]:
                raise RawFormatError(path, f"header is separated by {delim!r}; expected commas "
                                           "(',') between columns", line=header_line_no)
    seen: set[str] = set()
    for name in header:
        if name in seen:
            raise RawFormatError(path, f"column {name!r} appears twice in the header",
                                 line=header_line_no, column=name)
        seen.add(name)
    missing = [c for c in REQUIRED_COLUMNS if c not in seen]
    if missing:
        raise RawFormatError(path, f"required column(s) missing from header: {', '.join(missing)}; "
                                   f"expected {', '.join(REQUIRED_COLUMNS)}",
                             line=header_line_no, column=missing[0])

    body_lines = lines[header_idx + 1:]
    rows: list[list[str]] = []
    line_numbers: list[int] = []
    for offset, line in enumerate(body_lines):
        if not line.strip():
            continue
        line_no = header_line_no + 1 + offset
        fields = next(csv.reader([line]))
        if len(fields) != len(header):
            if [f.strip() for f in fields] == header:
                raise RawFormatError(path, "the header line is repeated inside the data; expected "
                                           "one header only", line=line_no)
            hint = ""
            if len(fields) > len(header):
                hint = " (a decimal comma, or an unquoted comma in a value?)"
            elif offset == len(body_lines) - 1:
                hint = " (the last line looks truncated)"
            raise RawFormatError(path, f"found {len(fields)} fields, expected {len(header)} as in "
                                       f"the header{hint}", line=line_no)
        rows.append(fields)
        line_numbers.append(line_no)
    if not rows:
        raise RawFormatError(path, "header found but no data rows", line=header_line_no)

    strings = pd.DataFrame(rows, columns=header, index=pd.Index(line_numbers, name="line"), dtype=object)
    frame = pd.DataFrame(index=strings.index)

    time_str = strings["time"].astype(str).str.strip()
    if time_str.eq("").any():
        bad = time_str.eq("").idxmax()
        raise RawFormatError(path, "empty timestamp; expected an ISO-8601 time such as "
                                   "2026-03-01T08:00:00", line=int(bad), column="time")
    times = pd.to_datetime(time_str, format="ISO8601", errors="coerce", utc=True)
    bad = _first_bad(time_str, times)
    if bad is not None:
        if times.notna().any() and time_str.loc[bad] == "time":
            raise RawFormatError(path, "the header line is repeated inside the data; expected one "
                                       "header only", line=int(bad), column="time")
        raise RawFormatError(path, f"{time_str.loc[bad]!r} is not an ISO-8601 timestamp "
                                   "(e.g. 2026-03-01T08:00:00)", line=int(bad), column="time")
    frame["time"] = times.dt.tz_convert(None).astype("datetime64[ns]")

    for name in NUMERIC_COLUMNS:
        values = strings[name].astype(str).str.strip()
        parsed = pd.to_numeric(values.where(values.ne(""), None), errors="coerce")
        bad = _first_bad(values, parsed)
        if bad is not None:
            found = values.loc[bad]
            hint = " (decimal comma? use a point)" if "," in found else ""
            raise RawFormatError(path, f"{found!r} is not a number{hint}; expected a decimal "
                                       f"number in {name}", line=int(bad), column=name)
        frame[name] = parsed.astype("float64")

    for name in header:
        if name in frame.columns:
            continue
        values = strings[name].astype(str).str.strip()
        parsed = pd.to_numeric(values.where(values.ne(""), None), errors="coerce")
        if _first_bad(values, parsed) is None:
            frame[name] = parsed.astype("float64")
        else:
            frame[name] = values

    frame.attrs["metadata"] = meta
    frame.attrs["source"] = str(path)
    frame.attrs["sha256"] = hashlib.sha256(raw).hexdigest()
    return frame


# --------------------------------------------------------------------------- native writer

#: Decimal places used when writing each canonical column (the logger's resolution).
DEFAULT_DECIMALS = {"speed_rpm": 0, **{s: 2 for s in SENSORS}, "disp_um": 3}


def format_raw_log(frame: pd.DataFrame, metadata: dict | None = None,
                   decimals: dict[str, int] | None = None) -> str:
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
                strs = np.array([("0." + "0" * nd) if s == ("-0." + "0" * nd) else s for s in strs],
                                dtype=object)
            elif nd == 0:
                strs = np.array(["0" if s == "-0" else s for s in strs], dtype=object)
            rendered[name] = strs
        else:
            rendered[name] = col.astype(str).to_numpy(dtype=object)
    for i in range(len(frame)):
        out.write(",".join(rendered[name][i] for name in columns) + "\n")
    return out.getvalue()


def write_raw_log(frame: pd.DataFrame, path: str | os.PathLike, metadata: dict | None = None,
                  decimals: dict[str, int] | None = None) -> None:
    """Write a native raw log atomically (see :func:`format_raw_log`)."""
    write_text_atomic(path, format_raw_log(frame, metadata, decimals))
