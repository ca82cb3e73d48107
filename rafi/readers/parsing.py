"""Text-level parsing shared by the readers: decoding, lines, fields, numbers, times."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np
import pandas as pd

from rafi import SENSORS
from rafi.errors import RawFormatError

NUMERIC_COLUMNS = ("speed_rpm", *SENSORS, "disp_um")


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

    Rejects empty files, UTF-16/32 files and NUL bytes (a binary or corrupted file).
    """
    if not raw.strip():
        raise RawFormatError(
            path, "file is empty; expected optional '# key: value' lines, a header line and data rows"
        )
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
        raise RawFormatError(path, "file is UTF-16 encoded; save it as UTF-8 text (CSV UTF-8)", line=1)
    nul = raw.find(b"\x00")
    if nul >= 0:
        line = raw[:nul].count(b"\n") + 1
        raise RawFormatError(
            path,
            "NUL byte (0x00) in the text: the file looks binary or corrupted; expected plain text",
            line=line,
        )
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
