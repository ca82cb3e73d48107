"""The logs of a machine's raw files: a file, a sheet, a file and its partner (standard library only).

Discovery (:func:`rafi.readers.input_spec.discover_logs`, while Snakemake plans) finds the raw
files matching ``input.pattern``; :func:`expand_logs` turns them into logs
(docs/raw-format.md):

* one log per file, named by :func:`rafi.readers.input_spec.log_id` of its stem (the default);
* with a sheet pattern (``input.sheet: "*"``, ``"Tag *"``), one log per matching sheet of
  each workbook, named after the sheet (:func:`sheet_log_name`; prefixed by the file's stem
  where two files have a sheet of that name). The sheet names are read from
  ``xl/workbook.xml`` (:func:`xlsx_sheet_names`), without openpyxl;
* with ``input.join``, the files whose name holds ``join.replace[0]`` are logs, each with its
  partner (the name with ``replace[1]`` in its place); the partners are not logs themselves;
* a file ``rafi record`` wrote (:mod:`rafi.readers.recordings`) is one log, read as a native
  file whatever the mapping says (no sheet, no partner).

A log is a :data:`LogSource` dict: ``path`` (the raw file), ``sheet`` (None: the mapping's
sheet), ``partner`` (None: no join) and ``recording`` (True: a recording, read with
:func:`rafi.readers.recordings.recording_spec`). Its content stamp (:func:`log_stamp`) combines the
file's, the sheet's name and the partner's: the clean step's ``raw_stamps`` param and the
``sha256`` of its audit row.
"""

from __future__ import annotations

import fnmatch
import hashlib
import re
import zipfile
from pathlib import Path
from xml.etree import ElementTree

from rafi.errors import InputSpecError, RawFormatError, bound_message, short_path
from rafi.readers.discovery import NAME_MAX_BYTES, safe_name_problem
from rafi.readers.input_layouts import is_sheet_pattern

#: A log of a machine: ``{"path": str, "sheet": str | None, "partner": str | None,
#: "recording": bool}``.
LogSource = dict

#: Characters a sheet-log's name never holds: path separators, characters Windows refuses in
#: file names, ``.`` (so the name has no suffix), ``%``, ``{``, ``}`` (Snakemake wildcards) and
#: ``#`` (runs are ``<log>#<k>``).
_UNSAFE = re.compile(r'[/\\:*?"<>|.%{}#\x00-\x1f\x7f]')
#: A sheet-log's name is cut to this many bytes (and gets a hash) beyond it.
SHEET_NAME_MAX_BYTES = 100
_MAIN_NS = "{http://schemas.openxmlformats.org/spreadsheetml/2006/main}"


def _percent(char: str) -> str:
    return "".join(f"%{b:02X}" for b in char.encode("utf-8", "surrogateescape"))


def log_id(stem: str) -> str:
    """The name of a raw file's outputs (``clean/<log id>.parquet``): its stem, with ``%``,
    ``{``, ``}`` and control characters percent-encoded.

    Snakemake reads ``{name}`` in any path as a wildcard and has no escape for it, so a raw
    file called ``log_{date}.csv`` gets the outputs ``clean/log_%7Bdate%7D.*``; a line break
    becomes ``%0A``. Every other character (spaces, unicode) is kept as it is. A stem whose
    encoding is longer than ``NAME_MAX_BYTES`` (150) bytes, or ends in a run Snakemake refuses
    as a wildcard value (a substring repeated 20 or more times, ``log_000...0``), is cut to
    100 bytes and gets ``%~`` and 12 hex digits of the SHA-256 of the stem: ``%~`` never occurs
    in a plain id, so two stems never share an id.
    """
    text = "".join(_percent(c) if c in "%{}" or ord(c) < 32 or ord(c) == 127 else c for c in stem)
    if len(text.encode("utf-8", "surrogateescape")) <= NAME_MAX_BYTES and safe_name_problem(text) is None:
        return text
    digest = hashlib.sha256(stem.encode("utf-8", "surrogateescape")).hexdigest()[:12]
    head = text.encode("utf-8", "surrogateescape")[:100].decode("utf-8", "ignore")
    head = re.sub(r"%[0-9A-F]?$", "", head)  # do not cut an escape in two
    return f"{head}%~{digest}"


def xlsx_sheet_names(path: str | Path) -> list[str]:
    """The sheet names of an xlsx workbook, in the workbook's order (``xl/workbook.xml``).

    Raises
    ------
    RawFormatError
        The file is not a readable workbook.
    """
    try:
        with zipfile.ZipFile(path) as zf:
            info = zf.getinfo("xl/workbook.xml")
            if info.file_size > 16 << 20:
                raise RawFormatError(path, "xl/workbook.xml is larger than 16 MiB: a corrupted workbook")
            root = ElementTree.fromstring(zf.read(info))
    except RawFormatError:
        raise
    except (OSError, KeyError, zipfile.BadZipFile, ElementTree.ParseError, RuntimeError, ValueError) as exc:
        raise RawFormatError(
            path, f"cannot read its sheet names ({type(exc).__name__}); save it as Excel Workbook (.xlsx)"
        ) from None
    sheets = root.find(f"{_MAIN_NS}sheets")
    if sheets is None:  # a workbook written without the default namespace
        sheets = next((e for e in root.iter() if e.tag.rsplit("}", 1)[-1] == "sheets"), None)
    if sheets is None:
        return []
    return [str(e.get("name", "")) for e in sheets if e.tag.rsplit("}", 1)[-1] == "sheet"]


def sheet_matches(pattern: str, name: str) -> bool:
    """True if sheet ``name`` matches the glob ``pattern`` (case-insensitive, as Excel compares
    sheet names; a name equal to the pattern matches too)."""
    return name == pattern or fnmatch.fnmatchcase(name.casefold(), pattern.casefold())


def sheet_log_name(sheet: str, stem: str | None = None) -> str:
    """The name (and log id) of a sheet-log: the sheet's name, ``stem_`` before it if given,
    with every character of ``_UNSAFE`` as ``_`` and the ends stripped; beyond
    :data:`SHEET_NAME_MAX_BYTES` bytes cut and ended by ``_`` and 8 hex digits of its SHA-256.

    ``'Tag 01'`` -> ``'Tag 01'``; ``'3.5 h'`` -> ``'3_5 h'``; ``('Tag 01', 'week.2')`` ->
    ``'week_2_Tag 01'``. The name never holds a ``.``, so ``Path(name).stem == name``."""
    text = sheet if stem is None else f"{stem}_{sheet}"
    safe = _UNSAFE.sub("_", text).strip() or "sheet"
    digest = hashlib.sha256(text.encode("utf-8", "surrogateescape")).hexdigest()
    if len(safe.encode("utf-8")) > SHEET_NAME_MAX_BYTES:
        safe = safe.encode("utf-8")[: SHEET_NAME_MAX_BYTES - 9].decode("utf-8", "ignore") + "_" + digest[:8]
    if safe_name_problem(safe) is not None:
        safe = f"sheet_{digest[:12]}"
    return safe


def log_stamp(file_stamp: str, sheet: str | None = None, partner_stamp: str | None = None) -> str:
    """The content stamp of a log from its file's (``sha256:<hex>`` or ``unreadable:...``).

    A whole file: the file's stamp. A sheet or a joined file: ``sha256:`` and the SHA-256 of the
    file's stamp, the sheet's name and the partner's stamp, so two sheets of one workbook are
    not copies of each other and a changed partner changes the log. An unreadable file keeps
    its own stamp."""
    if (sheet is None and partner_stamp is None) or not file_stamp.startswith("sha256:"):
        return file_stamp
    text = "\n".join(("rafi-log", file_stamp, sheet or "", partner_stamp or ""))
    return "sha256:" + hashlib.sha256(text.encode("utf-8", "surrogateescape")).hexdigest()


def log_name(key: str, source: LogSource) -> str:
    """The name a log goes by in the audit, the runs and the model (its ``file``): the raw
    file's name, or for a sheet-log its id ``key`` (which has no suffix)."""
    return Path(source["path"]).name if source.get("sheet") is None else key


def partner_of(path: str | Path, spec: dict) -> Path | None:
    """The partner file of ``path`` (``input.join``), or None if its name does not hold
    ``join.replace[0]`` (or the mapping joins nothing)."""
    join = spec.get("join")
    path = Path(path)
    if join is None or join["replace"][0] not in path.name:
        return None
    old, new = join["replace"]
    return path.with_name(path.name.replace(old, new))


def _split_partners(paths: list[Path], spec: dict) -> tuple[list[Path], list[str]]:
    """The files that are logs (their name holds ``join.replace[0]``) and a warning line per
    file matching the pattern that is neither a log nor a partner."""
    old, new = spec["join"]["replace"]
    mains = [p for p in paths if old in p.name]
    warnings = [
        bound_message(
            f"ignoring {short_path(p)}: its name holds neither {old!r} (a log, input.join.replace) "
            f"nor {new!r} (a partner file)"
        )
        for p in paths
        if old not in p.name and (not new or new not in p.name)
    ]
    return mains, warnings


def _sheet_logs(paths: list[Path], spec: dict) -> tuple[list[tuple[Path, str | None]], list[str]]:
    """``(file, sheet)`` per matching sheet of each workbook, and a warning per workbook where
    ``input.sheet`` matches no sheet.

    Raises
    ------
    InputSpecError
        The pattern matches no sheet of any workbook (naming ``input.sheet`` and the sheets).
    """
    pattern = spec["sheet"]
    found: list[tuple[Path, str | None]] = []
    warnings, seen = [], []
    for path in paths:
        try:
            names = xlsx_sheet_names(path)
        except RawFormatError:
            found.append((path, None))  # the reader says what is wrong with it
            continue
        hits = [n for n in names if sheet_matches(pattern, n)]
        seen.append(f"{path.name} has {', '.join(map(repr, names)) or 'no sheet'}")
        if not hits:
            warnings.append(
                bound_message(
                    f"{short_path(path)}: input.sheet {pattern!r} matches none of its sheets "
                    f"({', '.join(map(repr, names))}); the file is not read"
                )
            )
        found += [(path, n) for n in hits]
    if paths and not found:
        raise InputSpecError(
            bound_message(f"input.sheet: {pattern!r} matches no sheet of any workbook ({'; '.join(seen)})")
        )
    return found, warnings


def _sheet_ids(pairs: list[tuple[Path, str | None]]) -> dict[tuple[Path, str | None], str]:
    """The log name of each ``(file, sheet)``: the sheet's, prefixed by the file's stem where
    two files have a sheet of that name (deterministic: it depends on the names only).

    Raises
    ------
    RawFormatError
        Two sheets of one workbook whose names are the same once made safe (``a.b``, ``a_b``).
    """
    plain = {pair: sheet_log_name(pair[1]) for pair in pairs if pair[1] is not None}
    files_of: dict[str, set[Path]] = {}
    for (path, _), name in plain.items():
        files_of.setdefault(name.casefold(), set()).add(path)
    out: dict[tuple[Path, str | None], str] = {}
    for pair in pairs:
        path, sheet = pair
        if sheet is None:
            out[pair] = log_id(path.stem)
            continue
        name = plain[pair]
        out[pair] = sheet_log_name(sheet, path.stem) if len(files_of[name.casefold()]) > 1 else name
    by_file: dict[tuple[Path, str], tuple[Path, str | None]] = {}
    for pair, name in out.items():
        key = (pair[0], name.casefold())
        if key in by_file:
            raise RawFormatError(
                pair[0],
                f"its sheets {by_file[key][1]!r} and {pair[1]!r} would both be the log {name!r} "
                "(input.sheet is a pattern; a log is named after its sheet): rename one of them",
            )
        by_file[key] = pair
    return out


def expand_logs(
    paths: list[Path], spec: dict, recordings: list[Path] = ()
) -> tuple[dict[str, LogSource], list[str]]:
    """The logs of a machine's raw files (module docstring), by log id.

    Parameters
    ----------
    paths : list of Path
        The raw files matching ``input.pattern`` (sorted), recordings left out.
    spec : dict
        The machine's normalised ``input:`` mapping.
    recordings : list of Path
        The files ``rafi record`` wrote (:func:`rafi.readers.recordings.find_recordings`):
        one log each, after the others.

    Returns
    -------
    logs : dict
        Log id -> :data:`LogSource`, in the order of ``paths`` (and of the sheets).
    warnings : list of str
        Files not read (neither log nor partner; no matching sheet) and missing partners.

    Raises
    ------
    InputSpecError
        A sheet pattern matching no sheet of any workbook.
    RawFormatError
        Two logs with one id (two files with one stem; two sheets with one safe name).
    """
    warnings: list[str] = []
    if spec.get("join") is not None:
        paths, warnings = _split_partners(paths, spec)
    pairs: list[tuple[Path, str | None]] = [(p, None) for p in paths]
    if spec.get("format") == "xlsx" and is_sheet_pattern(spec.get("sheet")):
        pairs, more = _sheet_logs(paths, spec)
        warnings += more
    recorded = {Path(p) for p in recordings}
    pairs += [(Path(p), None) for p in recordings]
    ids = _sheet_ids(pairs)
    logs: dict[str, LogSource] = {}
    for pair in pairs:
        path, sheet = pair
        key = ids[pair]
        if key in logs:
            what = f"same stem {path.stem!r}" if sheet is None else f"same log name {key!r}"
            raise RawFormatError(
                path,
                f"{what} as {logs[key]['path']}; their outputs "
                "(results/<machine>/clean/<stem>.*) would collide - rename one of them",
            )
        if path in recorded:
            logs[key] = {"path": str(path), "sheet": None, "partner": None, "recording": True}
            continue
        partner = partner_of(path, spec)
        if partner is not None and not partner.exists():
            warnings.append(
                bound_message(
                    f"{short_path(path)}: no partner file {partner.name!r} (input.join.replace); "
                    "the log will be quarantined until it is there"
                )
            )
        logs[key] = {
            "path": str(path),
            "sheet": sheet,
            "partner": None if partner is None else str(partner),
            "recording": False,
        }
    return logs, warnings
