"""Mapped readers: bring a machine's own CSV or xlsx layout into the canonical frame.

A machine's ``input:`` mapping in ``config.yaml`` (documented in
``docs/raw-format.md``, "Bringing your own layout") says where its columns are,
what they are called, which units and sign they use. :func:`read_mapped` reads one
file with such a mapping and returns the same canonical frame as
:func:`rafi.io.read_raw_log`: ``time``, ``speed_rpm``, ``T1``..``T16``, ``disp_um``
then the remaining columns under sanitised names, indexed by the 1-based line (CSV)
or row (xlsx, as Excel shows it) of each record.

Every problem with a file raises :class:`rafi.errors.RawFormatError` naming the
file, the sheet (xlsx), the line/row and the column as written in the file. A
mapping that is itself wrong raises :class:`rafi.errors.InputSpecError`.
"""

from __future__ import annotations

import codecs
import copy
import datetime as dt
import difflib
import hashlib
import math
import os
import re
import unicodedata
from pathlib import Path

import numpy as np
import pandas as pd

from . import REQUIRED_COLUMNS, SENSORS
from .errors import InputSpecError, RawFormatError
from .io import (NUMERIC_COLUMNS, TIME_MAX, TIME_MIN, _split_fields, decode_bytes,
                 split_lines, to_naive_ns)

FORMATS = ("native", "csv", "xlsx")

#: Defaults of the ``input:`` mapping (``pattern`` defaults by format).
INPUT_DEFAULTS: dict = {
    "format": "native",
    "pattern": None,
    "sheet": 0,
    "delimiter": ",",
    "decimal": ".",
    "encoding": "utf-8",
    "header_row": 1,
    "skip_rows": 0,
    "columns": {},
    "time": {"kind": "timestamp", "start": "2000-01-01T00:00:00", "format": None},
    "sample_period_s": None,
    "displacement": {"column": None, "unit": "um", "sign": 1},
    "temperature_unit": "C",
    "keep_extra": True,
}

DEFAULT_PATTERN = {"native": "*.csv", "csv": "*.csv", "xlsx": "*.xlsx"}

#: Keys meaningful for the native format (everything else is for csv/xlsx).
NATIVE_KEYS = {"format", "pattern", "sample_period_s"}

_CANONICAL_RE = "^(time|speed_rpm|T([1-9]|1[0-6])|disp_um)$"

#: JSON schema (draft 7) of one ``input:`` mapping; the workflow's config schema embeds it.
#: It carries no ``default`` keywords on purpose: a validator that fills defaults in would
#: add csv/xlsx keys to native mappings. Defaults live in :data:`INPUT_DEFAULTS`.
INPUT_SCHEMA: dict = {
    "type": "object",
    "additionalProperties": False,
    "properties": {
        "format": {"enum": list(FORMATS)},
        "pattern": {"oneOf": [
            {"type": "string", "minLength": 1},
            {"type": "array", "items": {"type": "string", "minLength": 1}, "minItems": 1}]},
        "sheet": {"type": ["string", "integer"], "minLength": 1, "minimum": 0},
        "delimiter": {"anyOf": [{"type": "string", "minLength": 1, "maxLength": 1},
                                {"enum": ["tab", "\\t"]}]},
        "decimal": {"enum": [".", ","]},
        "encoding": {"type": "string", "minLength": 1},
        "header_row": {"type": "integer", "minimum": 1},
        "skip_rows": {"type": "integer", "minimum": 0},
        "columns": {
            "type": "object",
            "propertyNames": {"pattern": _CANONICAL_RE},
            "additionalProperties": {"type": "string", "minLength": 1},
        },
        "time": {
            "type": "object",
            "additionalProperties": False,
            "properties": {
                "kind": {"enum": ["timestamp", "elapsed_s"]},
                "start": {"type": "string", "minLength": 1},
                "format": {"type": ["string", "null"]},
            },
        },
        "sample_period_s": {"type": "number", "exclusiveMinimum": 0},
        "displacement": {
            "type": "object",
            "additionalProperties": False,
            "properties": {
                "column": {"type": "string", "minLength": 1},
                "unit": {"enum": ["um", "mm"]},
                "sign": {"enum": [1, -1]},
            },
        },
        "temperature_unit": {"enum": ["C", "K"]},
        "keep_extra": {"type": "boolean"},
    },
}


# --------------------------------------------------------------------------- the mapping

def _spec_error(key: str, message: str) -> InputSpecError:
    return InputSpecError(f"input.{key}: {message}")


def normalise_input_spec(spec: dict | None) -> dict:
    """Validate an ``input:`` mapping and fill in the defaults.

    Parameters
    ----------
    spec : dict or None
        The mapping as written in ``config.yaml`` (``None`` = native format).

    Returns
    -------
    dict
        A new dict with every key of :data:`INPUT_DEFAULTS` (nested ``time`` and
        ``displacement`` complete, ``pattern`` set from the format).

    Raises
    ------
    InputSpecError
        Naming the key (``input.displacement.unit``) and what is accepted.
    """
    if spec is None:
        spec = {}
    if not isinstance(spec, dict):
        raise InputSpecError(f"input: expected a mapping, got {type(spec).__name__}")
    unknown = sorted(set(spec) - set(INPUT_DEFAULTS))
    if unknown:
        raise _spec_error(unknown[0], f"unknown key; accepted keys: {', '.join(INPUT_DEFAULTS)}")
    out = copy.deepcopy(INPUT_DEFAULTS)
    for key, value in spec.items():
        if key in ("time", "displacement"):
            if value is None:
                continue
            if not isinstance(value, dict):
                raise _spec_error(key, f"expected a mapping, got {value!r}")
            extra = sorted(set(value) - set(INPUT_DEFAULTS[key]))
            if extra:
                raise _spec_error(f"{key}.{extra[0]}", "unknown key; accepted keys: "
                                  + ", ".join(INPUT_DEFAULTS[key]))
            out[key].update(value)
        elif key == "columns":
            out[key] = dict(value or {})
        else:
            out[key] = value

    fmt = out["format"]
    if fmt not in FORMATS:
        raise _spec_error("format", f"{fmt!r} is not one of {', '.join(FORMATS)}")
    if fmt == "native":
        extra = sorted(k for k in spec if k not in NATIVE_KEYS
                       and not _is_default(k, spec[k]))
        if extra:
            raise _spec_error(extra[0], "applies to format csv or xlsx only; a native file is "
                                        "read as documented in docs/raw-format.md")
    if out["pattern"] is None:
        out["pattern"] = DEFAULT_PATTERN[fmt]
    pats = out["pattern"] if isinstance(out["pattern"], (list, tuple)) else [out["pattern"]]
    if not pats or not all(isinstance(x, str) and x.strip() for x in pats):
        raise _spec_error("pattern", f"{out['pattern']!r}: expected a glob such as '*.xlsx' "
                                     "or a list of globs")
    out["pattern"] = out["pattern"] if isinstance(out["pattern"], str) else list(pats)

    sheet = out["sheet"]
    if isinstance(sheet, bool) or not isinstance(sheet, (str, int)) or \
            (isinstance(sheet, int) and sheet < 0) or (isinstance(sheet, str) and not sheet):
        raise _spec_error("sheet", f"{sheet!r}: expected a sheet name or a 0-based index")
    delim = out["delimiter"]
    if delim in ("tab", "\\t"):
        delim = out["delimiter"] = "\t"
    if not isinstance(delim, str) or len(delim) != 1 or delim in "\r\n\"":
        raise _spec_error("delimiter", f"{delim!r}: expected one character such as ',' ';' or tab")
    if out["decimal"] not in (".", ","):
        raise _spec_error("decimal", f"{out['decimal']!r}: expected '.' or ','")
    if out["decimal"] == delim:
        raise _spec_error("decimal", f"the decimal mark {delim!r} is also the delimiter; "
                                     "set delimiter: ';' for decimal commas")
    try:
        codecs.lookup(str(out["encoding"]))
    except LookupError:
        raise _spec_error("encoding", f"unknown encoding {out['encoding']!r} "
                                      "(e.g. utf-8, latin-1, cp1252)") from None
    for key, low in (("header_row", 1), ("skip_rows", 0)):
        v = out[key]
        if isinstance(v, bool) or not isinstance(v, int) or v < low:
            raise _spec_error(key, f"{v!r}: expected an integer >= {low}")

    columns = out["columns"]
    for canon, theirs in columns.items():
        if not re.match(_CANONICAL_RE, str(canon)):
            raise _spec_error(f"columns.{canon}", "not a canonical column; map "
                              + ", ".join(REQUIRED_COLUMNS) + " to your headers")
        if not isinstance(theirs, str) or not theirs.strip():
            raise _spec_error(f"columns.{canon}", f"{theirs!r}: expected your header text")
    disp = out["displacement"]
    if disp["column"] is not None:
        if not isinstance(disp["column"], str) or not disp["column"].strip():
            raise _spec_error("displacement.column", f"{disp['column']!r}: expected a header text")
        if "disp_um" in columns and _norm(columns["disp_um"]) != _norm(disp["column"]):
            raise _spec_error("displacement.column", "conflicts with columns.disp_um; give the "
                                                     "target channel in one place only")
    if disp["unit"] not in ("um", "mm"):
        raise _spec_error("displacement.unit", f"{disp['unit']!r}: expected um or mm")
    if isinstance(disp["sign"], bool) or disp["sign"] not in (1, -1):
        raise _spec_error("displacement.sign", f"{disp['sign']!r}: expected 1 or -1")
    resolved = resolve_columns(out)
    dup = _first_duplicate([_norm(v) for v in resolved.values()])
    if dup is not None:
        names = [k for k, v in resolved.items() if _norm(v) == dup]
        raise _spec_error("columns", f"header {dup!r} is mapped to {' and '.join(names)}; "
                                     "each header can feed one canonical column")

    tm = out["time"]
    if tm["kind"] not in ("timestamp", "elapsed_s"):
        raise _spec_error("time.kind", f"{tm['kind']!r}: expected timestamp or elapsed_s")
    try:
        start = pd.Timestamp(str(tm["start"]))
    except (ValueError, TypeError):
        raise _spec_error("time.start", f"{tm['start']!r} is not an ISO-8601 timestamp") from None
    if start.tzinfo is not None:
        start = start.tz_convert(None)
    if not (TIME_MIN <= start <= TIME_MAX):
        raise _spec_error("time.start", f"{tm['start']!r} is outside 1678..2261")
    tm["start"] = str(tm["start"])
    if tm["format"] is not None and (not isinstance(tm["format"], str) or "%" not in tm["format"]):
        raise _spec_error("time.format", f"{tm['format']!r}: expected a strptime format such as "
                                         "'%d.%m.%Y %H:%M:%S'")
    sp = out["sample_period_s"]
    if sp is not None:
        if isinstance(sp, bool) or not isinstance(sp, (int, float)) or not (math.isfinite(sp) and sp > 0):
            raise _spec_error("sample_period_s", f"{sp!r}: expected a positive number of seconds")
        out["sample_period_s"] = float(sp)
    if out["temperature_unit"] not in ("C", "K"):
        raise _spec_error("temperature_unit", f"{out['temperature_unit']!r}: expected C or K")
    if not isinstance(out["keep_extra"], bool):
        raise _spec_error("keep_extra", f"{out['keep_extra']!r}: expected true or false")
    return out


def _is_default(key: str, value) -> bool:
    """True if ``value`` says nothing beyond the default (a filled-in default is harmless)."""
    default = INPUT_DEFAULTS[key]
    if value is None or value == default:
        return True
    if isinstance(default, dict) and isinstance(value, dict):
        return {**default, **value} == default
    return False


def resolve_columns(spec: dict) -> dict[str, str]:
    """Canonical name -> the header text to look for (identity where not mapped)."""
    cols = {name: spec["columns"].get(name, name) for name in REQUIRED_COLUMNS}
    if spec["displacement"]["column"] is not None:
        cols["disp_um"] = spec["displacement"]["column"]
    return cols


# --------------------------------------------------------------------------- helpers

def _norm(text) -> str:
    """Header comparison key: NFC-normalised, stripped text."""
    if text is None:
        return ""
    return unicodedata.normalize("NFC", str(text)).strip()


def _first_duplicate(items):
    seen = set()
    for item in items:
        if item in seen:
            return item
        seen.add(item)
    return None


def sanitise_name(header: str) -> str:
    """A header as a snake_case ASCII column name: ``'Verlagerung X1 [µm]'`` -> ``'verlagerung_x1_um'``."""
    text = _norm(header).replace("µ", "u").replace("μ", "u").replace("°", "")
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
        return exact + max(difflib.SequenceMatcher(None, wanted, h).ratio(),
                           difflib.SequenceMatcher(None, sw, sh).ratio())

    ranked = sorted(available, key=score, reverse=True)
    return [h for h in ranked[:n] if score(h) >= 0.4]


def excel_column(index0: int) -> str:
    """0-based column index -> Excel letters (0 -> A, 26 -> AA)."""
    letters = ""
    n = index0 + 1
    while n:
        n, rem = divmod(n - 1, 26)
        letters = chr(65 + rem) + letters
    return letters


class _Table:
    """Header + raw rows of one file, with what is needed to word an error."""

    def __init__(self, path: Path, header: list, rows: list[list], row_numbers: list[int],
                 header_row: int, sheet: str | None):
        self.path = path
        self.header = [_norm(h) for h in header]
        self.rows = rows
        self.row_numbers = row_numbers
        self.header_row = header_row
        self.sheet = sheet

    def error(self, message: str, *, row: int | None = None, column: str | None = None,
              col_index: int | None = None) -> RawFormatError:
        if self.sheet is not None and row is not None and col_index is not None:
            message = f"{message} (cell {excel_column(col_index)}{row})"
        return RawFormatError(self.path, message, line=row, column=column, sheet=self.sheet)


# --------------------------------------------------------------------------- file readers

def _read_csv_table(path: Path, raw: bytes, spec: dict) -> _Table:
    text = decode_bytes(path, raw, spec["encoding"],
                        hint="set input.encoding to the file's encoding (e.g. latin-1, cp1252)")
    lines = split_lines(text)
    hr = spec["header_row"]
    if hr > len(lines) or not lines[hr - 1].strip():
        raise RawFormatError(path, f"no header at line {hr} (input.header_row); the file has "
                                   f"{len(lines)} line(s)", line=min(hr, max(len(lines), 1)))
    delim = spec["delimiter"]
    header = [h.strip() for h in _split_fields(path, lines[hr - 1], hr, delim)]
    if len(header) == 1:
        for other in (";", ",", "\t", "|"):
            if other != delim and other in header[0]:
                raise RawFormatError(path, f"header is separated by {other!r}, not by the "
                                           f"configured delimiter {delim!r}; set input.delimiter",
                                     line=hr)
    rows, numbers = [], []
    first_data = hr + spec["skip_rows"]          # 0-based index of the first data line
    for i in range(first_data, len(lines)):
        line = lines[i]
        if not line.strip():
            continue
        line_no = i + 1
        fields = _split_fields(path, line, line_no, delim)
        if len(fields) > len(header) and not any(f.strip() for f in fields[len(header):]):
            fields = fields[: len(header)]
        if len(fields) != len(header):
            if [_norm(f) for f in fields] == [_norm(h) for h in header]:
                raise RawFormatError(path, "the header line is repeated inside the data; "
                                           "expected one header only", line=line_no)
            hint = ""
            if '"' in line:
                hint = " (an unclosed or stray quote '\"' merges fields?)"
            elif len(fields) > len(header):
                hint = (" (a decimal comma with delimiter ','? set input.delimiter and "
                        "input.decimal)" if delim == "," else " (a delimiter inside a value?)")
            elif i == len(lines) - 1:
                hint = " (the last line looks truncated)"
            raise RawFormatError(path, f"found {len(fields)} fields, expected {len(header)} as "
                                       f"in the header{hint}", line=line_no)
        rows.append(fields)
        numbers.append(line_no)
    return _Table(path, header, rows, numbers, hr, None)


def _read_xlsx_table(path: Path, spec: dict) -> _Table:
    try:
        import openpyxl
    except ImportError as exc:   # pragma: no cover - openpyxl is a dependency
        raise RawFormatError(path, f"reading xlsx needs openpyxl ({exc})") from None
    try:
        wb = openpyxl.load_workbook(path, read_only=True, data_only=True)
    except Exception as exc:   # zip, XML, openpyxl's own errors: all mean "not a workbook"
        raise RawFormatError(path, f"not a readable .xlsx workbook ({type(exc).__name__}: "
                                   f"{exc}); save it as Excel Workbook (.xlsx)") from None
    try:
        names = list(wb.sheetnames)
        sheet = spec["sheet"]
        available = ", ".join(repr(n) for n in names)
        if isinstance(sheet, int):
            if sheet >= len(names):
                raise RawFormatError(path, f"no sheet number {sheet} (0-based, input.sheet); the "
                                           f"workbook has: {available}")
            name = names[sheet]
        else:
            match = [n for n in names if _norm(n) == _norm(sheet)]
            if not match:
                close = difflib.get_close_matches(sheet, names, n=3, cutoff=0.5)
                hint = f"; closest: {', '.join(map(repr, close))}" if close else ""
                raise RawFormatError(path, f"no sheet {sheet!r} (input.sheet); the workbook has: "
                                           f"{available}{hint}")
            name = match[0]
        ws = wb[name]
        hr = spec["header_row"]
        header = None
        rows, numbers = [], []
        try:
            for row_no, values in enumerate(ws.iter_rows(values_only=True), start=1):
                if row_no < hr:
                    continue
                values = list(values)
                if row_no == hr:
                    while values and (values[-1] is None or str(values[-1]).strip() == ""):
                        values.pop()
                    header = ["" if v is None else str(v) for v in values]
                    continue
                if row_no <= hr + spec["skip_rows"]:
                    continue
                if all(v is None or (isinstance(v, str) and not v.strip()) for v in values):
                    continue
                if len(values) > len(header):
                    for j in range(len(header), len(values)):
                        if values[j] is not None and str(values[j]).strip():
                            raise RawFormatError(
                                path, f"cell {excel_column(j)}{row_no} holds {values[j]!r} but "
                                      "its column has no header", line=row_no,
                                column=excel_column(j), sheet=name)
                    values = values[: len(header)]
                elif len(values) < len(header):
                    values = values + [None] * (len(header) - len(values))
                rows.append(values)
                numbers.append(row_no)
        except RawFormatError:
            raise
        except Exception as exc:   # malformed sheet XML
            raise RawFormatError(path, f"cannot read the sheet ({type(exc).__name__}: {exc})",
                                 sheet=name) from None
        if not header:
            raise RawFormatError(path, f"no header in row {hr} (input.header_row); the sheet is "
                                       "empty there", line=hr, sheet=name)
        return _Table(path, header, rows, numbers, hr, name)
    finally:
        wb.close()


# --------------------------------------------------------------------------- value parsing

_THOUSANDS_POINT = re.compile(r"^[+-]?\d{1,3}(\.\d{3})+(,\d*)?$")


def _numeric(table: _Table, values: list, decimal: str, column: str, col_index: int,
             what: str) -> np.ndarray:
    """Raw cells -> float64 (NaN for empty); RawFormatError at the first bad cell."""
    out = np.full(len(values), np.nan)
    for k, v in enumerate(values):
        if v is None:
            continue
        if isinstance(v, bool) or isinstance(v, (dt.datetime, dt.date, dt.time, dt.timedelta)):
            raise table.error(f"{v!s} is not a number; expected {what}",
                              row=table.row_numbers[k], column=column, col_index=col_index)
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
                    t = "!"     # a point in a decimal-comma file: refuse rather than guess
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
                raise table.error(f"{s!r} is not a number{hint}; expected {what}",
                                  row=table.row_numbers[k], column=column,
                                  col_index=col_index) from None
        if not math.isfinite(x):
            raise table.error(f"{v!r} is not a finite number; expected {what}",
                              row=table.row_numbers[k], column=column, col_index=col_index)
        out[k] = x
    return out


def _timestamps(table: _Table, values: list, spec: dict, column: str, col_index: int) -> pd.Series:
    tm = spec["time"]
    if tm["kind"] == "elapsed_s":
        secs = []
        for k, v in enumerate(values):
            if isinstance(v, dt.timedelta):
                v = v.total_seconds()
            elif isinstance(v, dt.time):
                v = v.hour * 3600 + v.minute * 60 + v.second + v.microsecond / 1e6
            secs.append(v)
        sec = _numeric(table, secs, spec["decimal"], column, col_index, "elapsed seconds")
        empty = np.isnan(sec)
        if empty.any():
            k = int(np.argmax(empty))
            raise table.error("empty time; expected elapsed seconds", row=table.row_numbers[k],
                              column=column, col_index=col_index)
        start = pd.Timestamp(tm["start"])
        if start.tzinfo is not None:
            start = start.tz_convert(None)
        lo = (TIME_MIN - start).total_seconds()
        hi = (TIME_MAX - start).total_seconds()
        bad = (sec < lo) | (sec > hi)
        if bad.any():
            k = int(np.argmax(bad))
            raise table.error(f"{values[k]!r} seconds from {tm['start']} is outside the supported "
                              "years 1678..2261", row=table.row_numbers[k], column=column,
                              col_index=col_index)
        return pd.Series(start + pd.to_timedelta(np.round(sec * 1e9).astype("int64"), unit="ns"))

    if values and all(isinstance(v, str) and v.strip() for v in values):
        # vectorised path for text timestamps (CSV); errors fall through to the cell loop
        strings = pd.Series([v.strip() for v in values], dtype=object)
        try:
            if tm["format"]:
                parsed = pd.to_datetime(strings, format=tm["format"], errors="coerce", utc=True)
            else:
                parsed = pd.to_datetime(strings, format="ISO8601", errors="coerce", utc=True)
            naive = parsed.dt.tz_convert(None)
            if naive.notna().all() and ((naive >= TIME_MIN) & (naive <= TIME_MAX)).all():
                return naive
        except (ValueError, TypeError, OverflowError):
            pass

    parsed = []
    for k, v in enumerate(values):
        ts = None
        if isinstance(v, dt.datetime):
            ts = pd.Timestamp(v)
        elif isinstance(v, dt.date):
            ts = pd.Timestamp(v)
        elif isinstance(v, str) and v.strip():
            s = v.strip()
            try:
                if tm["format"]:
                    ts = pd.Timestamp(dt.datetime.strptime(s, tm["format"]))
                else:
                    ts = pd.to_datetime(s, format="ISO8601")
            except (ValueError, TypeError, OverflowError):
                ts = None
            if ts is not None and ts is not pd.NaT and ts.tzinfo is not None:
                ts = ts.tz_convert("UTC").tz_localize(None)
        elif v is None or (isinstance(v, str) and not v.strip()):
            raise table.error("empty timestamp; expected a date and time",
                              row=table.row_numbers[k], column=column, col_index=col_index)
        if ts is None or ts is pd.NaT:
            expect = (f"a time in the format {tm['format']!r}" if tm["format"] else
                      "an ISO-8601 time such as 2026-10-14T08:00:00 (or set input.time.format)")
            raise table.error(f"{v!r} is not a timestamp; expected {expect}",
                              row=table.row_numbers[k], column=column, col_index=col_index)
        if not (TIME_MIN <= ts <= TIME_MAX):
            raise table.error(f"timestamp {v!r} is outside the supported years 1678..2261",
                              row=table.row_numbers[k], column=column, col_index=col_index)
        parsed.append(ts)
    return pd.Series(pd.DatetimeIndex(parsed))


def _text(values: list) -> list[str]:
    out = []
    for v in values:
        if v is None:
            out.append("")
        elif isinstance(v, float) and v.is_integer():
            out.append(str(int(v)) if abs(v) < 1e15 else str(v))
        else:
            out.append(str(v).strip())
    return out


# --------------------------------------------------------------------------- main entry

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
        canonical -> header used, ``sample_period_s`` if the spec gives it),
        ``source``, ``sha256``.

    Raises
    ------
    RawFormatError
        Naming file, sheet (xlsx), line/row and the column as written in the file.
    InputSpecError
        If the mapping is invalid.
    """
    path = Path(path)
    spec = normalise_input_spec(input_spec)
    if spec["format"] not in ("csv", "xlsx"):
        raise _spec_error("format", f"read_mapped reads csv or xlsx, not {spec['format']!r}")
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise RawFormatError(path, f"cannot read the file ({exc.strerror or exc})") from None
    if spec["format"] == "csv":
        table = _read_csv_table(path, raw, spec)
    else:
        if not raw:
            raise RawFormatError(path, "file is empty; expected an .xlsx workbook")
        table = _read_xlsx_table(path, spec)

    header = table.header
    wanted = resolve_columns(spec)
    where_row = table.header_row
    positions: dict[str, int] = {}
    for canon, theirs in wanted.items():
        key = _norm(theirs)
        hits = [j for j, h in enumerate(header) if h == key]
        if not hits:
            candidates = [h for h in header if h]
            close = closest_headers(key, candidates)
            if close:
                hint = "closest: " + ", ".join(repr(c) for c in close)
            else:
                hint = "available: " + ", ".join(repr(c) for c in candidates[:8]) + \
                       (", ..." if len(candidates) > 8 else "")
            where = "input.displacement.column" if (canon == "disp_um" and
                                                    spec["displacement"]["column"]) else \
                f"input.columns.{canon}"
            raise RawFormatError(path, f"header {theirs!r} ({where}) not found in the header "
                                       f"row; {hint}", line=where_row, column=theirs,
                                 sheet=table.sheet)
        if len(hits) > 1:
            raise RawFormatError(path, f"header {theirs!r} appears {len(hits)} times "
                                       f"(columns {', '.join(excel_column(j) for j in hits)}); "
                                       f"cannot tell which one is {canon}", line=where_row,
                                 column=theirs, sheet=table.sheet)
        positions[canon] = hits[0]
    if not table.rows:
        raise RawFormatError(path, "header found but no data rows", line=where_row,
                             sheet=table.sheet)

    cols = list(zip(*table.rows))
    index = pd.Index(table.row_numbers, name="line", dtype="int64")
    frame = pd.DataFrame(index=index)
    j = positions["time"]
    times = _timestamps(table, list(cols[j]), spec, header[j], j)
    frame["time"] = to_naive_ns(times).to_numpy()
    for canon in NUMERIC_COLUMNS:
        j = positions[canon]
        unit = {"speed_rpm": "r/min", "disp_um": spec["displacement"]["unit"]}.get(
            canon, "deg " + spec["temperature_unit"])
        values = _numeric(table, list(cols[j]), spec["decimal"], header[j], j,
                          f"a number ({unit}) for {canon}")
        if canon == "disp_um":
            values = values * (1000.0 if spec["displacement"]["unit"] == "mm" else 1.0)
            values = values * spec["displacement"]["sign"] + 0.0   # no -0.0
        elif canon in SENSORS and spec["temperature_unit"] == "K":
            values = values - 273.15
        frame[canon] = values.astype("float64")

    if spec["keep_extra"]:
        used = set(positions.values())
        taken = set(frame.columns) | {"line"}
        for j, name in enumerate(header):
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
                frame[new] = _numeric(table, values, spec["decimal"], name, j, "a number")
            except RawFormatError:
                frame[new] = pd.Series(_text(values), index=index, dtype="str")

    meta: dict = {"format": spec["format"]}
    if table.sheet is not None:
        meta["sheet"] = table.sheet
    meta["columns"] = {canon: header[j] for canon, j in positions.items()}
    if spec["sample_period_s"] is not None:
        meta["sample_period_s"] = spec["sample_period_s"]
    frame.attrs["metadata"] = meta
    frame.attrs["source"] = str(path)
    frame.attrs["sha256"] = hashlib.sha256(raw).hexdigest()
    return frame
