"""The ``input:`` mapping of a machine and the discovery of its raw files (standard library only).

Snakemake evaluates ``workflow/rules/common.smk`` on every invocation (``rafi nightly``
included) before it runs any job; what that needs of the readers lives here, so planning does
not import NumPy or pandas: :data:`INPUT_DEFAULTS` (the mapping's defaults, by format),
:data:`INPUT_SCHEMA` (both from :mod:`rafi.contract`), :func:`normalise_input_spec` (raises
:class:`rafi.errors.InputSpecError`), :func:`find_logs` (the raw files of a machine folder),
:func:`discover_logs` (every machine's logs - a file, a sheet of a workbook, a file with its
partner: :mod:`rafi.readers.log_sources` -, leaving out links out of ``raw_dir`` and files still
being written: :mod:`rafi.readers.discovery`), :func:`discover_machines` (their raw files) and
:func:`log_id` (the name of a raw file's outputs). The layouts beyond one header row, one sheet
and one file are checked by :mod:`rafi.readers.input_layouts`.
"""

from __future__ import annotations

import codecs
import copy
import datetime as dt
import math
import os
import re
import unicodedata
from collections.abc import Iterable
from pathlib import Path

from rafi.contract import (  # noqa: F401 (INPUT_SCHEMA, TIME_KINDS: part of this module's API)
    DEFAULT_PATTERN,
    DEFAULT_SENSORS,
    EPOCH_CLOCKS,
    FORMATS,
    INPUT_DEFAULTS,
    INPUT_SCHEMA,
    MAX_SENSORS,
    NATIVE_KEYS,
    NON_SENSOR_COLUMNS,
    PROBE_KEYS,
    PROBE_NAME_RE,
    PROBE_SEPARATOR,
    RESERVED_NAMES,
    SENSOR_NAME_RE,
    TEMPERATURE_UNITS,
    TIME_KINDS,
)
from rafi.contract.input import MISSING_VALUE_MAX_CHARS
from rafi.errors import InputSpecError, bound_message, short_path
from rafi.readers.discovery import (
    SKIP_PREFIX,
    is_inside,
    link_warning,
    no_match_reason,
    not_a_file,
    not_a_file_warning,
    safe_name_problem,
    settling_files,
    settling_warning,
    split_outside,
)
from rafi.readers.input_assumed import check_no_time_column, check_speed, has_constant_speed, log_speed
from rafi.readers.input_channels import (  # noqa: F401 (probe_spec, sensor_name_problem: this module's API)
    _spec_error,
    check_probes,
    check_sensors,
    first_duplicate,
    probe_spec,
    sensor_name_problem,
)
from rafi.readers.input_layouts import (
    check_column_refs,
    check_header_row,
    check_join,
    check_sheet,
    partner_columns,
    partner_layout,
    ref_key,
)
from rafi.readers.log_sources import expand_logs, log_id, log_name  # noqa: F401 (log_id: this module's API)
from rafi.readers.name_dates import date_format_problem
from rafi.readers.recordings import find_recordings

# --------------------------------------------------------------------------- the input: mapping


def normalise_input_spec(spec: dict | None) -> dict:
    """Validate an ``input:`` mapping and fill in the defaults.

    The steps, in order (each raises on the first problem it finds): the mapping's keys
    (:func:`merge_input_defaults`), the format and the file pattern (:func:`check_format`), how
    the text is read (:func:`check_text_layout`), the columns and the displacement channel
    (:func:`check_columns`), the clock (:func:`check_time`), and a log without a time or speed
    column (:mod:`rafi.readers.input_assumed`).

    Parameters
    ----------
    spec : dict or None
        The mapping as written in ``config.yaml`` (``None`` = native format).

    Returns
    -------
    dict
        A new dict with every key of :data:`INPUT_DEFAULTS` (nested ``time``, ``speed`` and
        ``displacement`` complete, ``pattern`` set from the format, ``sensors`` the list of the
        machine's temperature sensors: :func:`check_sensors`).

    Raises
    ------
    InputSpecError
        Naming the key (``input.displacement.unit``) and what is accepted.
    """
    spec = {} if spec is None else spec
    out = merge_input_defaults(spec)
    check_format(out, spec)
    check_join(out)
    check_text_layout(out)
    check_sensors(out)
    check_columns(out)
    check_probes(out)
    check_time(out)
    check_no_time_column(out)
    check_speed(out)
    if out["temperature_unit"] not in TEMPERATURE_UNITS:
        raise _spec_error(
            "temperature_unit", f"{out['temperature_unit']!r}: expected {', '.join(TEMPERATURE_UNITS)}"
        )
    if not isinstance(out["keep_extra"], bool):
        raise _spec_error("keep_extra", f"{out['keep_extra']!r}: expected true or false")
    return out


#: Sub-mappings of ``input:`` whose keys merge one by one over their defaults.
NESTED_KEYS = ("time", "speed", "displacement")


def merge_input_defaults(spec) -> dict:
    """A copy of :data:`INPUT_DEFAULTS` with ``spec``'s values; unknown keys are refused.

    ``time``, ``speed`` and ``displacement`` merge key by key (``None`` keeps the defaults);
    ``columns`` replaces. Values are not checked here.
    """
    if not isinstance(spec, dict):
        raise InputSpecError(f"input: expected a mapping, got {type(spec).__name__}")
    unknown = sorted(set(spec) - set(INPUT_DEFAULTS))
    if unknown:
        raise _spec_error(unknown[0], f"unknown key; accepted keys: {', '.join(INPUT_DEFAULTS)}")
    out = copy.deepcopy(INPUT_DEFAULTS)
    for key, value in spec.items():
        if key in NESTED_KEYS:
            if value is None:
                continue
            if not isinstance(value, dict):
                raise _spec_error(key, f"expected a mapping, got {value!r}")
            extra = sorted(set(value) - set(INPUT_DEFAULTS[key]))
            if extra:
                raise _spec_error(
                    f"{key}.{extra[0]}", "unknown key; accepted keys: " + ", ".join(INPUT_DEFAULTS[key])
                )
            out[key].update(value)
        elif key == "columns":
            if value is not None and not isinstance(value, dict):
                raise _spec_error(key, f"expected a mapping of canonical names to headers, got {value!r}")
            out[key] = dict(value or {})
        else:
            out[key] = value
    return out


def check_format(out: dict, spec: dict) -> None:
    """``format`` is known, a native mapping sets only native keys, and ``pattern`` is a glob or a
    list of globs (set from the format when not given). ``out`` is changed in place."""
    fmt = out["format"]
    if fmt not in FORMATS:
        raise _spec_error("format", f"{fmt!r} is not one of {', '.join(FORMATS)}")
    if fmt == "native":
        extra = sorted(k for k in spec if k not in NATIVE_KEYS and not _is_default(k, spec[k]))
        if extra:
            raise _spec_error(
                extra[0],
                "applies to format csv or xlsx only; a native file is "
                "read as documented in docs/raw-format.md",
            )
    if out["pattern"] is None:
        out["pattern"] = DEFAULT_PATTERN[fmt]
    pats = out["pattern"] if isinstance(out["pattern"], (list, tuple)) else [out["pattern"]]
    if not pats or not all(isinstance(x, str) and x.strip() for x in pats):
        raise _spec_error(
            "pattern", f"{out['pattern']!r}: expected a glob such as '*.xlsx' or a list of globs"
        )
    out["pattern"] = out["pattern"] if isinstance(out["pattern"], str) else list(pats)


def check_text_layout(out: dict) -> None:
    """``sheet``, ``delimiter`` (``tab`` becomes a tab), ``decimal``, ``encoding``, ``header_row``,
    ``skip_rows``, ``footer_rows`` and ``missing_values``: how the file's text is read. ``out`` is
    changed in place."""
    check_sheet(out)
    delim = out["delimiter"]
    if delim in ("tab", "\\t"):
        delim = out["delimiter"] = "\t"
    if not isinstance(delim, str) or len(delim) != 1 or delim in '\r\n"':
        raise _spec_error("delimiter", f"{delim!r}: expected one character such as ',' ';' or tab")
    if out["decimal"] not in (".", ","):
        raise _spec_error("decimal", f"{out['decimal']!r}: expected '.' or ','")
    if out["decimal"] == delim:
        raise _spec_error(
            "decimal",
            f"the decimal mark {delim!r} is also the delimiter; set delimiter: ';' for decimal commas",
        )
    try:
        codecs.lookup(str(out["encoding"]))
    except LookupError:
        raise _spec_error(
            "encoding", f"unknown encoding {out['encoding']!r} (e.g. utf-8, latin-1, cp1252)"
        ) from None
    check_header_row(out)
    for key in ("skip_rows", "footer_rows"):
        v = out[key]
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise _spec_error(key, f"{v!r}: expected an integer >= 0")
    out["missing_values"] = check_missing_values(out["missing_values"])


def check_missing_values(markers) -> list[str]:
    """``input.missing_values``: the texts a logger writes in a cell without a value (``---``,
    ``#N/A``, ``NaN``), each read as missing in every numeric column.

    Parameters
    ----------
    markers : list of str or None
        As written in the config (``None``: none).

    Returns
    -------
    list of str
        The markers, stripped (cells are compared stripped), in the order given.

    Raises
    ------
    InputSpecError
        Not a list; a marker that is not text (YAML reads ``null``, ``yes`` or ``1.5`` as no
        text: quote it), empty, longer than :data:`rafi.contract.input.MISSING_VALUE_MAX_CHARS`
        characters, a number (a number a sensor writes for no value is
        ``clean.open_circuit_values``), or given twice.
    """
    if markers is None:
        return []
    if not isinstance(markers, (list, tuple)):
        raise _spec_error(
            "missing_values", f'{markers!r}: expected a list of texts, e.g. ["---", "#N/A", "NaN"]'
        )
    out: list[str] = []
    for k, marker in enumerate(markers):
        key = f"missing_values[{k}]"
        if not isinstance(marker, str):
            raise _spec_error(
                key, f'{marker!r} is not a text; quote the marker as the file writes it ("#N/A", "null")'
            )
        text = marker.strip()
        if not text or len(text) > MISSING_VALUE_MAX_CHARS:
            raise _spec_error(
                key, f"{marker!r}: expected the text of a cell, 1 to {MISSING_VALUE_MAX_CHARS} characters"
            )
        if _is_finite_number(text):
            raise _spec_error(
                key,
                f"{marker!r} is a number; a number a sensor reports when it has no reading is "
                "clean.open_circuit_values",
            )
        if text in out:
            raise _spec_error(key, f"{marker!r} is listed twice")
        out.append(text)
    return out


def _is_finite_number(text: str) -> bool:
    """True if ``text`` reads as a finite number with a decimal point or comma (``-9999``, ``1,5``)."""
    try:
        return math.isfinite(float(text.replace(",", ".")))
    except ValueError:
        return False


def check_columns(out: dict) -> None:
    """``columns`` maps the machine's columns (time, speed_rpm, its sensors, disp_um) to header
    texts (or, :mod:`rafi.readers.input_layouts`, column letters and positions), ``displacement``
    names one channel in one place with a known unit and sign, and no column feeds two columns."""
    columns = out["columns"]
    known = (*NON_SENSOR_COLUMNS, *out["sensors"])
    for canon in columns:
        if canon not in known:
            raise _spec_error(
                f"columns.{canon}",
                f"not a column of this machine; map {', '.join(NON_SENSOR_COLUMNS)} and the sensors "
                f"of input.sensors ({', '.join(out['sensors'])}) to your headers",
            )
    if out["join"] is not None:
        for canon in out["join"]["columns"]:
            if canon not in known:
                raise _spec_error("join.columns", f"{canon!r} is not a column of this machine")
    resolved = resolve_columns(out)
    check_column_refs(out, list(resolved))
    header = out["header_row"] is not None
    disp = out["displacement"]
    if disp["column"] is not None and "disp_um" in columns:
        if ref_key(columns["disp_um"], header) != ref_key(disp["column"], header):
            raise _spec_error(
                "displacement.column",
                "conflicts with columns.disp_um; give the target channel in one place only",
            )
    if disp["unit"] not in ("um", "mm"):
        raise _spec_error("displacement.unit", f"{disp['unit']!r}: expected um or mm")
    if isinstance(disp["sign"], bool) or disp["sign"] not in (1, -1):
        raise _spec_error("displacement.sign", f"{disp['sign']!r}: expected 1 or -1")
    keys = {canon: ref_key(value, header) for canon, value in resolved.items()}
    dup = first_duplicate(list(keys.values()))
    if dup is not None:
        names = [k for k, v in keys.items() if v == dup]
        raise _spec_error(
            "columns",
            f"{dup} is mapped to {' and '.join(names)}; each column can feed one canonical column",
        )


def partner_input_spec(spec: dict) -> tuple[dict, list[str]]:
    """The normalised mapping the partner file of a ``join`` is read with, and the canonical
    columns read from it (:func:`rafi.readers.input_layouts.partner_layout`).

    Raises
    ------
    InputSpecError
        Naming the ``input.join.input`` key that is wrong for the partner.
    """
    wanted = partner_columns(spec)
    raw = partner_layout(spec)
    out = merge_input_defaults(raw)
    try:
        check_format(out, raw)
        check_sheet(out)
        check_text_layout(out)
        check_time(out)
        check_no_time_column(out)
        if out["displacement"]["unit"] not in ("um", "mm"):
            raise _spec_error("displacement.unit", f"{out['displacement']['unit']!r}: expected um or mm")
        if isinstance(out["displacement"]["sign"], bool) or out["displacement"]["sign"] not in (1, -1):
            raise _spec_error("displacement.sign", f"{out['displacement']['sign']!r}: expected 1 or -1")
        check_column_refs(out, wanted)
    except InputSpecError as exc:
        raise InputSpecError(str(exc).replace("input.", "input.join.input.", 1)) from None
    out["join"] = None
    out["sensors"], out["probes"] = list(spec["sensors"]), {}
    return out, wanted


def check_time(out: dict) -> None:
    """``time.kind``, ``time.start`` (ISO 8601 within pandas' range, or None: no clock),
    ``time.date_column``, ``time.date_from_name``, ``time.timezone``, ``time.format`` (a strptime
    format) and ``sample_period_s`` (a positive number, made a float). ``out`` is changed in place."""
    tm = out["time"]
    if tm["kind"] not in TIME_KINDS:
        raise _spec_error("time.kind", f"{tm['kind']!r}: expected {', '.join(TIME_KINDS)}")
    if tm["start"] is not None and not _plain_start_ok(str(tm["start"])):
        import pandas as pd

        from rafi.readers.parsing import TIME_MAX, TIME_MIN

        try:
            start = pd.Timestamp(str(tm["start"]))
        except (ValueError, TypeError):
            raise _spec_error("time.start", f"{tm['start']!r} is not an ISO-8601 timestamp") from None
        if start.tzinfo is not None:
            start = start.tz_convert(None)
        if not (TIME_MIN <= start <= TIME_MAX):
            raise _spec_error("time.start", f"{tm['start']!r} is outside 1678..2261")
    if tm["start"] is not None and tm["kind"] in EPOCH_CLOCKS:
        raise _spec_error(
            "time.start",
            f"{tm['start']!r} with kind {tm['kind']}: the clock numbers carry their own date "
            f"(from {EPOCH_CLOCKS[tm['kind']][0][:10]}); leave time.start out",
        )
    tm["start"] = None if tm["start"] is None else str(tm["start"])
    if tm["date_column"] is not None and (tm["kind"] != "timestamp" or not str(tm["date_column"]).strip()):
        raise _spec_error(
            "time.date_column",
            f"{tm['date_column']!r}: a date column goes with time.kind timestamp (the time column then "
            "holds the time of day)",
        )
    check_date_from_name(tm)
    check_timezone(tm)
    if tm["format"] is not None and (not isinstance(tm["format"], str) or "%" not in tm["format"]):
        raise _spec_error(
            "time.format", f"{tm['format']!r}: expected a strptime format such as '%d.%m.%Y %H:%M:%S'"
        )
    sp = out["sample_period_s"]
    if sp is not None:
        if isinstance(sp, bool) or not isinstance(sp, (int, float)) or not (math.isfinite(sp) and sp > 0):
            raise _spec_error("sample_period_s", f"{sp!r}: expected a positive number of seconds")
        out["sample_period_s"] = float(sp)


def check_date_from_name(tm: dict) -> None:
    """``time.date_from_name``: the date of each file in its name, in ``strftime`` codes
    (:func:`rafi.readers.name_dates.date_format_problem`), the time column holding the time of day;
    or None. It goes with ``time.kind`` timestamp and without ``time.date_column``."""
    fmt = tm["date_from_name"]
    if fmt is None:
        return
    if tm["kind"] != "timestamp":
        raise _spec_error(
            "time.date_from_name",
            f"applies to time.kind timestamp only (kind is {tm['kind']}; the time column then holds "
            "the time of day)",
        )
    if tm["date_column"] is not None:
        raise _spec_error(
            "time.date_from_name",
            f"the date is in a column (time.date_column {tm['date_column']!r}) or in the file name: "
            "give one of the two",
        )
    problem = date_format_problem(fmt)
    if problem is not None:
        raise _spec_error("time.date_from_name", problem)


def check_timezone(tm: dict) -> None:
    """``time.timezone``: an IANA time zone name (``Europe/Berlin``) whose local times a timestamp
    column holds (read into UTC, so a daylight-saving change repeats no time and leaves no gap),
    or None (the times as written)."""
    zone = tm["timezone"]
    if zone is None:
        return
    if tm["kind"] != "timestamp":
        raise _spec_error(
            "time.timezone",
            f"applies to time.kind timestamp only (kind is {tm['kind']}: counted times, not a clock's)",
        )
    import zoneinfo

    try:
        if not isinstance(zone, str) or not zone.strip():
            raise ValueError(zone)
        zoneinfo.ZoneInfo(zone.strip())
    except (zoneinfo.ZoneInfoNotFoundError, ValueError, TypeError):
        raise _spec_error(
            "time.timezone",
            f"{zone!r} is not a time zone name; expected an IANA name such as Europe/Berlin, America/Chicago",
        ) from None
    tm["timezone"] = zone.strip()


def _is_default(key: str, value) -> bool:
    """True if ``value`` says nothing beyond the default (a filled-in default is harmless)."""
    default = INPUT_DEFAULTS[key]
    if value is None or value == default:
        return True
    if isinstance(default, dict) and isinstance(value, dict):
        return {**default, **value} == default
    return False


#: The canonical name of ``input.time.date_column`` among the mapped columns (never a frame column).
DATE_COLUMN = "time_date"


def resolve_columns(spec: dict) -> dict[str, str]:
    """Canonical name -> the header text to look for (identity where not mapped).

    ``time`` is left out when ``time.kind`` is ``none`` (:data:`DATE_COLUMN` is added with
    ``time.date_column``), ``speed_rpm`` when the speed is a
    configured constant and the columns of ``join.columns``: those columns are not read from
    the file.
    """
    names = ("time", "speed_rpm", *spec["sensors"], "disp_um")
    cols = {name: spec["columns"].get(name, name) for name in names}
    if spec["time"]["kind"] == "none":
        del cols["time"]
    elif spec["time"]["date_column"] is not None:
        cols[DATE_COLUMN] = spec["time"]["date_column"]
    if has_constant_speed(spec):
        del cols["speed_rpm"]
    if spec["displacement"]["column"] is not None:
        cols["disp_um"] = spec["displacement"]["column"]
    for canon in (spec.get("join") or {}).get("columns", ()):
        cols.pop(canon, None)  # read from the partner file
    return cols


def norm_header(text) -> str:
    """Header comparison key: NFC-normalised, stripped text."""
    if text is None:
        return ""
    return unicodedata.normalize("NFC", str(text)).strip()


#: ``YYYY-MM-DD``, optionally with ``[T ]HH:MM[:SS]``: the ``time.start`` values checked
#: without pandas (everything else goes through ``pd.Timestamp``, as the reader parses it).
_PLAIN_START = re.compile(r"^\d{4}-\d{2}-\d{2}(?:[T ]\d{2}:\d{2}(?::\d{2})?)?$")
_START_MIN, _START_MAX = (
    dt.datetime(1678, 1, 1),
    dt.datetime(2261, 12, 31),
)  # rafi.readers.parsing.TIME_MIN/MAX


def _plain_start_ok(text: str) -> bool:
    """True if ``text`` is a plain ISO date/time that ``pd.Timestamp`` reads as the same
    valid time inside ``rafi.readers.parsing.TIME_MIN..TIME_MAX`` (no pandas import needed). False
    means: not sure, let pandas decide (and word the error)."""
    if not _PLAIN_START.match(text):
        return False
    try:
        value = dt.datetime.fromisoformat(text)
    except ValueError:
        return False
    return _START_MIN <= value <= _START_MAX


# --------------------------------------------------------------------------- raw files


def find_logs(
    machine_dir: str | os.PathLike, input_spec: dict | None = None, raw_dir: str | os.PathLike | None = None
) -> list[Path]:
    """Raw files of one machine folder matching the spec's ``pattern`` (glob or list), sorted.

    Hidden files (``.name``) and office lock files (``~$name.xlsx``) are skipped, and so is a
    symbolic link whose target lies outside ``raw_dir`` (default: the machine folder's parent)
    and a name that is not a regular file (a folder, a FIFO, a socket, a dangling link;
    :func:`scan_logs` also says which).
    """
    return scan_logs(machine_dir, input_spec, raw_dir)[0]


def scan_logs(
    machine_dir: str | os.PathLike, input_spec: dict | None = None, raw_dir: str | os.PathLike | None = None
) -> tuple[list[Path], list[str]]:
    """:func:`find_logs` and a warning line for each file it refused (``link_outside_raw``,
    ``not_a_file``)."""
    spec = normalise_input_spec(input_spec)
    folder = Path(machine_dir)
    root = Path(raw_dir) if raw_dir is not None else folder.absolute().parent
    patterns = [spec["pattern"]] if isinstance(spec["pattern"], str) else spec["pattern"]
    found = {p for pattern in patterns for p in folder.glob(pattern)}
    names = sorted(p for p in found if not p.name.startswith((".", "~$")))
    inside, refused = split_outside(names, root)
    files = []
    for path in inside:
        what = not_a_file(path)
        if what is None:
            files.append(path)
        else:
            refused.append(not_a_file_warning(path, what))
    return files, refused


# --------------------------------------------------------------------------- nightly and gates


def has_braces(path: str | os.PathLike) -> bool:
    """True if ``path`` holds ``{`` or ``}`` (Snakemake cannot name it as an input)."""
    text = str(path)
    return "{" in text or "}" in text


def discover_machines(
    raw_dir: str | os.PathLike,
    input_spec_of,
    configured: Iterable[str] = (),
    *,
    settle_s: float = 0,
    now: float | None = None,
) -> tuple[dict[str, dict[str, str]], list[str]]:
    """The machines under ``raw_dir`` and their raw files, as the workflow plans them:
    :func:`discover_logs` with each log's raw file only (``machine -> {log id: raw path}``)."""
    found, warnings = discover_logs(raw_dir, input_spec_of, configured, settle_s=settle_s, now=now)
    return {m: {key: src["path"] for key, src in logs.items()} for m, logs in found.items()}, warnings


def discover_logs(
    raw_dir: str | os.PathLike,
    input_spec_of,
    configured: Iterable[str] = (),
    *,
    settle_s: float = 0,
    now: float | None = None,
) -> tuple[dict[str, dict[str, dict]], list[str]]:
    """The machines under ``raw_dir`` and their logs, as the workflow plans them.

    Parameters
    ----------
    raw_dir : str or os.PathLike
        The folder of the machine folders.
    input_spec_of : callable
        ``machine -> input: mapping`` (the machine's resolved settings).
    configured : iterable of str
        Machines named under ``machines:`` in the config (a name with no folder is warned about).
    settle_s : float
        Run setting ``settle_s``: a file modified less than this many seconds before ``now``
        waits for the next run (``rafi.readers.discovery.settling_files``); 0: none waits.
    now : float, optional
        Time of the decision (``time.time()`` by default).

    Returns
    -------
    machines : dict
        ``machine -> {log id: log source}``, machines sorted; a log source is
        ``{"path", "sheet", "partner", "recording"}`` (:func:`rafi.readers.log_sources.expand_logs`:
        a file, a sheet of a workbook, a file joined with its partner, a file ``rafi record``
        wrote - :mod:`rafi.readers.recordings` -, found whatever ``input.pattern``). A folder
        with no usable file, a hidden folder and a folder whose name holds a brace are left
        out, and so are links whose target lies outside ``raw_dir`` (a linked machine folder
        included) and files still settling.
    warnings : list of str
        What was left out, and why; a refused link's line starts ``link_outside_raw:``, a
        settling file's ``settling:`` (``docs/raw-format.md``).

    Raises
    ------
    rafi.errors.InputSpecError
        A machine's ``input:`` mapping is invalid, two globs of its
        ``speed.constant_rpm_by_file`` with different speeds match one log, or its sheet
        pattern matches no sheet of any workbook (names the machine).
    rafi.errors.RawFormatError
        Two logs of a machine share an id (two raw files a stem), so their outputs would collide.
    """
    root = Path(raw_dir)
    found: dict[str, dict[str, dict]] = {}
    warnings: list[str] = []
    if not root.is_dir():
        return found, [f"raw_dir {str(root)!r} does not exist; no machines to process"]
    folders = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith("."))
    for folder in folders:
        refusal = _folder_refusal(folder, root)
        if refusal is not None:
            warnings.append(refusal)
            continue
        logs, more = _machine_logs(folder, input_spec_of(folder.name), root, settle_s, now)
        warnings += more
        if logs:
            found[folder.name] = logs
    names = {p.name for p in folders}
    for machine in sorted(m for m in set(configured) - names if PROBE_SEPARATOR not in str(m)):
        warnings.append(f"config has settings for machine {machine!r} but {root / machine} does not exist")
    return found, warnings


def _folder_refusal(folder: Path, root: Path) -> str | None:
    """Why the machine folder ``folder`` is skipped (its name, or a link leaving ``root``), or None."""
    machine = folder.name
    if has_braces(machine):
        return f"skipping machine folder {folder}: a machine name cannot hold {{ or }}"
    if PROBE_SEPARATOR in machine:
        return (
            f"skipping machine folder {folder}: a machine name cannot hold {PROBE_SEPARATOR!r} "
            "(it names a probe of a machine: <machine>@<probe>); rename the folder"
        )
    problem = safe_name_problem(machine)
    if problem is not None:
        return bound_message(f"skipping machine folder {short_path(folder)}: {problem}; rename the folder")
    if not is_inside(folder, root):
        return link_warning(folder, root)
    return None


def _machine_logs(
    folder: Path, spec: dict, root: Path, settle_s: float, now: float | None
) -> tuple[dict[str, dict], list[str]]:
    """The logs of one machine folder (see :func:`discover_logs`) and the warnings about it: the
    files refused or settling, and the line that skips the machine when it has no log."""
    machine = folder.name
    try:
        paths, refused = scan_logs(folder, spec, root)
        normalised = normalise_input_spec(spec)
        recorded, more = find_recordings(folder, normalised, root)
        refused = list(dict.fromkeys(refused + more))  # a name of both: one line
        paths = sorted(set(paths) | set(recorded))
        waiting = settling_files(paths, settle_s, now)
        left_out = {path for path, _ in waiting}
        use = [p for p in paths if p not in left_out]
        logs, notes = expand_logs(
            [p for p in use if p not in recorded], normalised, [p for p in use if p in recorded]
        )
        if has_constant_speed(normalised):
            for key, src in logs.items():  # two speed globs with different speeds: stop while planning
                if not src["recording"]:  # a recording has its own speed column
                    log_speed(log_name(key, src), Path(src["path"]).name, normalised)
    except InputSpecError as exc:
        raise InputSpecError(f"machine {machine!r}: {exc}") from None
    warnings = [*refused, *(settling_warning(path, age, settle_s) for path, age in waiting), *notes]
    if not logs:
        pattern = normalised["pattern"]
        why = no_match_reason(folder, pattern, machine)
        if refused or waiting:
            why = f"no usable file ({len(refused)} refused link(s), {len(waiting)} settling)"
        elif paths:
            why = f"no log in the {len(paths)} file(s) matching input.pattern {pattern!r}"
        warnings.append(f"{SKIP_PREFIX}{folder}: {why}")
    return logs, warnings
