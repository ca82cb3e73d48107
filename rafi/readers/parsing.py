"""Text-level parsing shared by the readers: reading, decoding, lines, fields, numbers, times.

Input is bounded (``docs/raw-format.md``, "Limits"): a line of a text file is at most
:data:`LINE_MAX_BYTES` bytes (check ``line_too_long``), a field, cell or metadata value at most
:data:`FIELD_MAX_CHARS` characters and a native file's metadata at most
:data:`METADATA_MAX_CHARS` characters in all (check ``field_too_long``). A sample of 16
temperatures, a speed and a displacement takes about 150 bytes; the limits leave room for
hundreds of extra columns and long notes, and keep what a bad file can put into a message, a
Parquet file's metadata or a report small. A file holds at most :data:`FILE_MAX_BYTES` bytes
(check ``file_too_large``) and a header at most :data:`COLUMNS_MAX` columns (check
``too_many_columns``). A file that cannot be read at all (permissions, an I/O error, not a
regular file: a FIFO, a socket, a device, a directory) raises check ``unreadable``; a FIFO is
never waited on.
"""

from __future__ import annotations

import csv
import errno
import json
import os
import re
import stat
from pathlib import Path

import numpy as np
import pandas as pd

from rafi.contract.sensors import DEFAULT_SENSORS
from rafi.errors import QUOTE_MAX_CHARS, RawFormatError, quote

#: A temperature unit other than deg C (``input.temperature_unit``, the unit checks) -> its
#: conversion to deg C.
TO_DEG_C = {"K": lambda v: v - 273.15, "F": lambda v: (v - 32.0) / 1.8}


def numeric_columns(sensors=DEFAULT_SENSORS) -> tuple[str, ...]:
    """The numeric canonical columns of a machine with ``sensors``: speed, sensors, displacement."""
    return ("speed_rpm", *sensors, "disp_um")


#: :func:`numeric_columns` of the paper's rig.
NUMERIC_COLUMNS = numeric_columns()

#: Longest line of a raw text file, in bytes (check ``line_too_long``): 64 KiB.
LINE_MAX_BYTES = 64 * 1024

#: Longest field: a value between delimiters, an xlsx cell, a ``# key: value`` value, a
#: header (check ``field_too_long``): 4 KiB characters.
FIELD_MAX_CHARS = 4 * 1024

#: Most characters the ``#`` metadata lines of a native file hold together (check
#: ``field_too_long``): 64 KiB. The metadata travels in every clean Parquet file's schema.
METADATA_MAX_CHARS = 64 * 1024

#: Largest raw file, in bytes (check ``file_too_large``): 256 MiB. Reading a native file takes
#: about 16 times its size in memory (a 90 MB file peaks at 1.5 GB); an xlsx workbook's sheets
#: may inflate to at most this many bytes too (``rafi.readers.mapped_table.check_zip_sizes``).
FILE_MAX_BYTES = 256 * 1024 * 1024

#: Most columns of a header (check ``too_many_columns``): 1024. A log has 19 required
#: columns and a few extra ones; 10,000 empty extra columns cost 1.5 GB and 11 s to read.
COLUMNS_MAX = 1024

#: Bytes scanned at a time for line breaks (bounds the scan's temporary arrays).
_SCAN_CHUNK = 1 << 20

_ERRNO_WORDS = {
    errno.EACCES: "permission denied",
    errno.EPERM: "permission denied",
    errno.EIO: "I/O error",
    errno.EISDIR: "it is a directory, not a file",
    errno.ENOENT: "no such file (moved or deleted after the run was planned?)",
}


def unreadable_error(path, exc: OSError) -> RawFormatError:
    """The ``unreadable`` error for a file the operating system refused to read."""
    what = _ERRNO_WORDS.get(exc.errno, exc.strerror or type(exc).__name__)
    code = f" ({errno.errorcode[exc.errno]})" if exc.errno in errno.errorcode else ""
    return RawFormatError(
        path,
        f"cannot read the file: {what}{code}; check the file's permissions or the disk",
        check="unreadable",
    )


_KINDS = (
    (stat.S_ISDIR, "a directory"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
)


def file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, in words (``"a regular file"``, ``"a FIFO (named pipe)"``)."""
    for test, words in _KINDS:
        if test(mode):
            return words
    return "a regular file" if stat.S_ISREG(mode) else "not a regular file"


def not_regular_error(path, mode: int) -> RawFormatError:
    """The ``unreadable`` error for a path that is not a regular file (a FIFO, a socket, ...)."""
    return RawFormatError(
        path,
        f"cannot read the file: it is {file_kind(mode)}, not a regular file; a raw log is a file "
        "the logger wrote: remove it from the machine folder or rename it so the pattern misses it",
        check="unreadable",
    )


def too_large_error(path, size: int, limit: int | None = None, what: str = "file") -> RawFormatError:
    """The ``file_too_large`` error: ``size`` bytes, more than ``limit`` (default :data:`FILE_MAX_BYTES`)."""
    limit = FILE_MAX_BYTES if limit is None else limit
    return RawFormatError(
        path,
        f"{what} of {size} bytes, larger than the limit of {limit} bytes ({limit >> 20} MiB); a log "
        "of a few days holds some megabytes: split the recording into several files, or the file "
        "is corrupted",
        check="file_too_large",
    )


def open_regular(path: str | os.PathLike):
    """Open ``path`` for reading in binary mode, only if it is a regular file of at most
    :data:`FILE_MAX_BYTES` bytes.

    The file is opened without blocking (a FIFO with no writer would otherwise wait for ever)
    and checked with ``fstat`` on the open descriptor (no race between a check and the open).

    Raises
    ------
    RawFormatError
        Check ``unreadable`` (cannot be opened, or not a regular file) or ``file_too_large``.
    """
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        try:  # a socket cannot be opened at all (ENXIO): say what it is
            mode = os.stat(path).st_mode
        except OSError:
            mode = stat.S_IFREG
        if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
            raise not_regular_error(path, mode) from None
        raise unreadable_error(path, exc) from None
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise unreadable_error(path, IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR)))
        if not stat.S_ISREG(st.st_mode):
            raise not_regular_error(path, st.st_mode)
        if st.st_size > FILE_MAX_BYTES:
            raise too_large_error(path, st.st_size)
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_file_bytes(path: str | os.PathLike) -> bytes:
    """The bytes of a raw file (:func:`open_regular`); :class:`RawFormatError` (check ``unreadable``)
    if it cannot be read, ``file_too_large`` if it holds more than :data:`FILE_MAX_BYTES` bytes
    (also when it grew past the limit while being read)."""
    with open_regular(path) as fh:
        try:
            data = fh.read(FILE_MAX_BYTES + 1)
        except OSError as exc:
            raise unreadable_error(path, exc) from None
    if len(data) > FILE_MAX_BYTES:
        raise too_large_error(path, len(data))
    return data


def check_column_count(path, header: list, line_no: int, sheet: str | None = None) -> None:
    """Raise ``too_many_columns`` if ``header`` has more than :data:`COLUMNS_MAX` names."""
    if len(header) <= COLUMNS_MAX:
        return
    raise RawFormatError(
        path,
        f"header of {len(header)} columns, more than the limit of {COLUMNS_MAX}; a log has the 19 "
        "required columns and a few more: the wrong header row, a transposed table, or a "
        "corrupted file",
        line=line_no,
        sheet=sheet,
        check="too_many_columns",
    )


def first_long_line(raw: bytes, limit: int = LINE_MAX_BYTES) -> tuple[int, int, int] | None:
    """The first line of ``raw`` longer than ``limit`` bytes: ``(line number, start, length)``.

    Lines end at ``\\n``, ``\\r\\n`` or ``\\r`` (numbered as :func:`split_lines` does). The bytes
    are scanned in chunks of 1 MiB without copying them or decoding them, and the scan stops
    at the first long line: a 50 MB line costs no more than its bytes.
    """
    if len(raw) <= limit:
        return None
    arr = np.frombuffer(raw, dtype=np.uint8)
    last_break = -1  # offset of the last line break seen
    start = None
    for lo in range(0, len(arr), _SCAN_CHUNK):
        chunk = arr[lo : lo + _SCAN_CHUNK]
        breaks = np.flatnonzero((chunk == 10) | (chunk == 13)) + lo
        if len(breaks):
            edges = np.concatenate(([last_break], breaks))
            over = np.flatnonzero(np.diff(edges) - 1 > limit)
            if len(over):
                start = int(edges[over[0]]) + 1
                break
            last_break = int(breaks[-1])
        if lo + len(chunk) - last_break - 1 > limit:
            start = last_break + 1
            break
    if start is None:
        return None
    ends = [k for k in (raw.find(b"\n", start), raw.find(b"\r", start)) if k >= 0]
    length = (min(ends) if ends else len(raw)) - start
    line_no = raw.count(b"\n", 0, start) + raw.count(b"\r", 0, start) - raw.count(b"\r\n", 0, start) + 1
    return line_no, start, length


def check_line_lengths(path, raw: bytes) -> None:
    """Raise ``line_too_long`` for the first line of ``raw`` longer than :data:`LINE_MAX_BYTES`."""
    found = first_long_line(raw)
    if found is None:
        return
    line_no, start, length = found
    head = raw[start : start + 4 * QUOTE_MAX_CHARS].decode("utf-8", errors="replace")[:QUOTE_MAX_CHARS]
    raise RawFormatError(
        path,
        f"line of {length} bytes, longer than the limit of {LINE_MAX_BYTES} bytes "
        f"(it starts {quote(head)}...); a line holds one sample: a huge notes or text value, "
        "or the line breaks were lost (a binary or corrupted file)",
        line=line_no,
        check="line_too_long",
    )


def first_long_field(fields, limit: int = FIELD_MAX_CHARS) -> int | None:
    """Position of the first text field longer than ``limit`` characters (``None``: none)."""
    for k, field in enumerate(fields):
        if isinstance(field, str) and len(field) > limit:
            return k
    return None


def field_too_long_error(
    path,
    field: str,
    *,
    line: int | None,
    column: str | None = None,
    sheet: str | None = None,
    what: str = "field",
    raw_line: str | None = None,
) -> RawFormatError:
    """The ``field_too_long`` error for ``field`` (longer than :data:`FIELD_MAX_CHARS`); a quote
    in ``raw_line`` (the line as written) or the field adds the likely cause, an unclosed quote."""
    quoted = '"' in field or (raw_line is not None and '"' in raw_line)
    hint = " or an unclosed quote '\"' that swallowed the rest of the line" if quoted else ""
    return RawFormatError(
        path,
        f"{what} of {len(field)} characters, longer than the limit of {FIELD_MAX_CHARS} "
        f"({quote(field)}); a value of a log is a number or a short text: a huge notes or text "
        f"value{hint}",
        line=line,
        column=column,
        sheet=sheet,
        check="field_too_long",
    )


def check_fields(
    path,
    fields: list,
    line_no: int,
    header: list | None = None,
    sheet: str | None = None,
    raw_line: str | None = None,
) -> None:
    """Raise ``field_too_long`` for the first field of a line (or row) longer than the limit."""
    k = first_long_field(fields)
    if k is None:
        return
    column = header[k] if header is not None and k < len(header) else None
    raise field_too_long_error(path, fields[k], line=line_no, column=column, sheet=sheet, raw_line=raw_line)


_LINE_BREAK = re.compile(r"\r\n|\r|\n")


def split_lines(text: str) -> list[str]:
    """Split text into lines the way an editor numbers them (``\\n``, ``\\r\\n``, ``\\r``).

    Unlike :meth:`str.splitlines` this does not break on form feeds, ``\\x1c``,
    ``\\u2028`` and friends, so line numbers in messages match what a user sees.
    """
    lines = _LINE_BREAK.split(text)
    if lines and lines[-1] == "":
        lines.pop()
    return lines


def decode_bytes(
    path: Path, raw: bytes, encoding: str = "utf-8", *, hint: str = "the file must be UTF-8 encoded"
) -> str:
    """Decode raw bytes, raising :class:`RawFormatError` with the line of the first bad byte.

    Rejects empty files, UTF-16/32 files, NUL bytes (a binary or corrupted file) and lines
    longer than :data:`LINE_MAX_BYTES` (``line_too_long``, checked before decoding).
    """
    if not raw or raw.isspace():  # (raw.strip() would copy a 50 MB file)
        raise RawFormatError(
            path, "file is empty; expected optional '# key: value' lines, a header line and data rows"
        )
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
        raise RawFormatError(path, "file is UTF-16 encoded; save it as UTF-8 text (CSV UTF-8)", line=1)
    nul = raw.find(b"\x00")
    if nul >= 0:
        line = raw.count(b"\n", 0, nul) + 1
        raise RawFormatError(
            path,
            "NUL byte (0x00) in the text: the file looks binary or corrupted; expected plain text",
            line=line,
        )
    check_line_lengths(path, raw)
    enc = "utf-8-sig" if encoding.lower().replace("_", "-") in ("utf-8", "utf8") else encoding
    try:
        return raw.decode(enc)
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise RawFormatError(
            path,
            f"byte 0x{raw[exc.start]:02x} is not valid {'UTF-8' if enc == 'utf-8-sig' else encoding}; {hint}",
            line=line,
        ) from None


def _decode(path: Path, raw: bytes) -> str:
    return decode_bytes(path, raw)


_INNER_SPACE = re.compile(r"[^\S\r\n]")


_PLAIN_NUMBER_CHARS = re.compile(r"[^0-9.eE+\-]")


def without_markers(cells: list, markers, empty=None) -> list:
    """``cells`` with every text cell that is one of ``markers`` as ``empty`` (a missing value).

    The one reading of ``input.missing_values`` (``docs/raw-format.md``, "Missing-value
    markers"), for the native and the mapped readers and ``rafi init``: a text cell, stripped,
    equal to a marker (case counts) is missing; numbers, dates and other texts are kept.

    Parameters
    ----------
    cells : list
        The cells of one column (text, numbers, None).
    markers : collection of str
        The markers, stripped (:func:`rafi.readers.input_spec.check_missing_values`).
    empty : object
        What a marker's cell becomes: None (a mapped cell), ``""`` (a native field).

    Returns
    -------
    list
        ``cells`` itself when there are no markers, else a new list.
    """
    if not markers:
        return cells
    marks = frozenset(markers)
    return [empty if isinstance(c, str) and c.strip() in marks else c for c in cells]


def marker_hint(cell: str, other_hint: str = "") -> str:
    """`` (a missing-value marker? ...)`` for a text cell without a digit (``---``, ``#N/A``,
    ``NaN``, ``ERR``) where no other cause was named; else empty."""
    if other_hint or not cell or any(c.isdigit() for c in cell):
        return ""
    listed = json.dumps(cell, ensure_ascii=False)
    return f" (a missing-value marker? list it in input.missing_values: [{listed}])"


def parse_numbers(values: list[str]) -> tuple[np.ndarray, int | None]:
    """Stripped strings -> float64 (``""`` = NaN) and the position of the first bad value.

    A value is bad when it is not empty and does not parse as a finite number
    (``nan``, ``inf`` and text are bad).
    """
    if _PLAIN_NUMBER_CHARS.search("".join(values)) is None:
        # fast path: only digits, signs, points and exponents -> float() semantics are plain
        try:
            parsed = np.array([v if v else "nan" for v in values], dtype=float)
        except ValueError:
            pass
        else:
            bad = ~np.isfinite(parsed) & np.array([bool(v) for v in values])
            return parsed, (int(np.argmax(bad)) if bad.any() else None)
    arr = np.array(values, dtype=object)
    empty = arr == ""
    work = arr.copy()
    work[empty] = np.nan
    parsed = np.asarray(pd.to_numeric(work, errors="coerce"), dtype=float)
    bad = ~np.isfinite(parsed) & ~empty
    if bad.any():
        return parsed, int(np.argmax(bad))
    return parsed, None


def split_fields(path: Path, line: str, line_no: int, delimiter: str = ",") -> list[str]:
    try:
        return next(csv.reader([line], delimiter=delimiter, strict=False))
    except (csv.Error, StopIteration) as exc:
        raise RawFormatError(
            path, f"cannot split the line into fields ({exc}); check quotes and delimiters", line=line_no
        ) from None


#: Earliest and latest timestamps the canonical frame can hold (datetime64[ns]).
TIME_MIN = pd.Timestamp("1678-01-01")


TIME_MAX = pd.Timestamp("2261-12-31")


def to_naive_ns(times: pd.Series) -> pd.Series:
    """UTC-aware or naive datetimes -> naive ``datetime64[ns]`` (caller checked the range)."""
    if isinstance(times.dtype, pd.DatetimeTZDtype):
        times = times.dt.tz_convert(None)
    return times.astype("datetime64[ns]")


def out_of_range_time(times: pd.Series) -> int | None:
    """Position of the first timestamp outside what datetime64[ns] can hold."""
    naive = times.dt.tz_convert(None) if isinstance(times.dtype, pd.DatetimeTZDtype) else times
    bad = (naive.notna() & ((naive < TIME_MIN) | (naive > TIME_MAX))).to_numpy()
    if bad.any():
        return int(np.argmax(bad))
    return None


def field_count_error(
    path, line: str, line_no: int, found: int, expected: int, *, last: bool, too_many_hint: str
) -> RawFormatError:
    """The error for a data line with ``found`` fields where the header has ``expected``, with
    a hint at the likely cause: a stray quote, ``too_many_hint`` for extra fields, or a
    truncated ``last`` line."""
    hint = ""
    if '"' in line:
        hint = " (an unclosed or stray quote '\"' merges fields?)"
    elif found > expected:
        hint = f" ({too_many_hint})"
    elif last:
        hint = " (the last line looks truncated)"
    return RawFormatError(
        path, f"found {found} fields, expected {expected} as in the header{hint}", line=line_no
    )
