"""Layouts of the ``input:`` mapping beyond one header row, one sheet and one file (standard library only).

Three parts of :func:`rafi.readers.input_spec.normalise_input_spec` (docs/raw-format.md):

* a file without a header row (``header_row: none``): the columns are given by letter (``"A"``,
  ``"AB"``) or 1-based position; :func:`column_index` reads either, :func:`check_header_row`
  and :func:`check_column_refs` check the mapping;
* every sheet of a workbook as its own log (``sheet: "*"``, ``sheet: "Tag *"``):
  :func:`is_sheet_pattern`, :func:`check_sheet`;
* temperatures and displacement in two files (``join:``): :func:`check_join` and
  :func:`partner_spec` (the mapping the partner file is read with).

Each raises :class:`rafi.errors.InputSpecError` naming the key.
"""

from __future__ import annotations

import copy
import math
import re
import unicodedata

from rafi.contract import JOIN_BY, JOIN_DEFAULTS, JOIN_LAYOUT_KEYS, NO_HEADER
from rafi.errors import InputSpecError

#: Excel's last column is XFD (16384).
MAX_COLUMNS = 16384
_LETTERS = re.compile(r"^[A-Za-z]{1,3}$")
_SHEET_PATTERN = re.compile(r"[*?\[\]]")


def _error(key: str, message: str) -> InputSpecError:
    return InputSpecError(f"input.{key}: {message}")


# --------------------------------------------------------------------------- column letters


def letters_index(text: str) -> int | None:
    """0-based index of an Excel column letter (``"A"`` -> 0, ``"ab"`` -> 27); None if ``text``
    is not one (or lies past XFD)."""
    text = str(text).strip()
    if not _LETTERS.match(text):
        return None
    n = 0
    for ch in text.upper():
        n = n * 26 + (ord(ch) - 64)
    return n - 1 if n <= MAX_COLUMNS else None


def column_index(value, *, header: bool) -> int | None:
    """The 0-based column a value of ``input.columns`` names by position, or None for a header.

    Parameters
    ----------
    value : str or int
        A value of ``input.columns``: a 1-based position (an integer), a column letter, or a
        header text.
    header : bool
        Whether the file has a header row. With one, a string is always a header text (even
        ``"A"``) and only an integer is a position; without one, a string must be a letter.

    Returns
    -------
    int or None
        The column's 0-based index; None if ``value`` is a header text (or not a valid letter
        without a header row: :func:`check_column_refs` refuses that).
    """
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return value - 1 if 1 <= value <= MAX_COLUMNS else None
    if header:
        return None
    return letters_index(value)


def column_label(index0: int) -> str:
    """0-based column index -> Excel letters (0 -> A, 26 -> AA)."""
    letters = ""
    n = index0 + 1
    while n:
        n, rem = divmod(n - 1, 26)
        letters = chr(65 + rem) + letters
    return letters


def check_header_row(out: dict) -> None:
    """``header_row``: an integer >= 1, or ``none`` / YAML null (stored as None). In place."""
    value = out["header_row"]
    if value is None or (isinstance(value, str) and value.strip().lower() in (NO_HEADER, "null", "~")):
        out["header_row"] = None
        return
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise _error(
            "header_row",
            f"{value!r}: expected the 1-based line of the header, or none for a file without one",
        )


def check_column_refs(out: dict, required: list[str]) -> None:
    """The values of ``columns`` (and ``displacement.column``) fit ``header_row``.

    With a header row a value is a header text or a 1-based position (an integer); without
    one, a column letter or a position, and every column the mapping reads (``required``,
    from :func:`rafi.readers.input_spec.resolve_columns`) must be mapped. No column may feed
    two canonical names.
    """
    header = out["header_row"] is not None
    columns = out["columns"]
    for canon, value in columns.items():
        _check_ref(f"columns.{canon}", value, header)
    disp = out["displacement"]["column"]
    if disp is not None:
        _check_ref("displacement.column", disp, header)
    if header:
        return
    for canon in required:
        if canon not in columns and not (canon == "disp_um" and disp is not None):
            raise _error(
                f"columns.{canon}",
                "missing: with header_row: none every column read is given by letter or position "
                f"(e.g. columns: {{{canon}: 'C'}})",
            )


def _check_ref(key: str, value, header: bool) -> None:
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise _error(key, f"{value!r}: expected a header text, a column letter or a 1-based position")
    if isinstance(value, int):
        if not 1 <= value <= MAX_COLUMNS:
            raise _error(key, f"{value!r}: a column position is 1-based, at most {MAX_COLUMNS}")
        return
    if not value.strip():
        raise _error(key, f"{value!r}: expected your header text")
    if not header and letters_index(value) is None:
        raise _error(
            key,
            f"{value!r} is not a column letter; with header_row: none give a column letter "
            "('A', 'AB') or a 1-based position (3)",
        )


def ref_key(value, header: bool) -> str:
    """What two mapped values share when they name the same column (duplicate check)."""
    index = column_index(value, header=header)
    if index is not None:
        return f"column {column_label(index)}"
    return f"header {unicodedata.normalize('NFC', str(value)).strip()!r}"


# --------------------------------------------------------------------------- sheets


def is_sheet_pattern(sheet) -> bool:
    """True if ``input.sheet`` is a glob (holds ``*``, ``?``, ``[`` or ``]``): every matching
    sheet of a workbook is then a log of its own."""
    return isinstance(sheet, str) and bool(_SHEET_PATTERN.search(sheet))


def check_sheet(out: dict) -> None:
    """``sheet``: a name, a 0-based index, or (xlsx) a glob on the sheet names."""
    sheet = out["sheet"]
    if (
        isinstance(sheet, bool)
        or not isinstance(sheet, (str, int))
        or (isinstance(sheet, int) and sheet < 0)
        or (isinstance(sheet, str) and not sheet)
    ):
        raise _error("sheet", f"{sheet!r}: expected a sheet name, a 0-based index or a glob such as '*'")
    if is_sheet_pattern(sheet) and out["format"] != "xlsx":
        raise _error("sheet", f"{sheet!r}: a sheet pattern applies to format xlsx only")


# --------------------------------------------------------------------------- join


def check_join(out: dict) -> None:
    """``join``: None, or a mapping completed from :data:`rafi.contract.input.JOIN_DEFAULTS`.

    ``replace`` is two texts (the first found in the names of the machine's files), ``by`` one
    of :data:`rafi.contract.input.JOIN_BY`, ``columns`` canonical names other than ``time``
    (from the partner file), ``max_unmatched`` a fraction and ``input`` the partner's own
    layout keys. In place.
    """
    join = out.get("join")
    if join is None:
        return
    if out["format"] not in ("csv", "xlsx"):
        raise _error("join", "applies to format csv or xlsx")
    if not isinstance(join, dict):
        raise _error("join", f"expected a mapping with replace, by, columns, got {join!r}")
    unknown = sorted(set(join) - set(JOIN_DEFAULTS))
    if unknown:
        raise _error(f"join.{unknown[0]}", "unknown key; accepted keys: " + ", ".join(JOIN_DEFAULTS))
    merged = copy.deepcopy(JOIN_DEFAULTS)
    merged.update({k: v for k, v in join.items() if v is not None})
    rep = merged["replace"]
    if (
        not isinstance(rep, (list, tuple))
        or len(rep) != 2
        or not all(isinstance(x, str) for x in rep)
        or not rep[0]
        or rep[0] == rep[1]
    ):
        raise _error(
            "join.replace",
            f"{rep!r}: expected two different texts [in the file name, in the partner's name], "
            "e.g. ['temps', 'disp']",
        )
    merged["replace"] = [rep[0], rep[1]]
    if merged["by"] not in JOIN_BY:
        raise _error("join.by", f"{merged['by']!r}: expected time or row")
    cols = merged["columns"]
    if isinstance(cols, str):
        cols = [cols]
    if not isinstance(cols, (list, tuple)) or not cols or not all(isinstance(c, str) for c in cols):
        raise _error("join.columns", f"{cols!r}: expected a list of canonical names such as [disp_um]")
    for c in cols:
        if c == "time":
            raise _error("join.columns", "time is read from both files; list the columns the partner adds")
    if len(set(cols)) != len(cols):
        raise _error("join.columns", f"{cols!r}: a column is listed twice")
    merged["columns"] = list(cols)
    share = merged["max_unmatched"]
    numeric = not isinstance(share, bool) and isinstance(share, (int, float))
    if not numeric or not (math.isfinite(share) and 0 <= share <= 1):
        raise _error("join.max_unmatched", f"{share!r}: expected a fraction between 0 and 1")
    merged["max_unmatched"] = float(share)
    layout = merged["input"]
    if not isinstance(layout, dict):
        raise _error("join.input", f"expected a mapping of layout keys for the partner file, got {layout!r}")
    extra = sorted(set(layout) - set(JOIN_LAYOUT_KEYS))
    if extra:
        raise _error(f"join.input.{extra[0]}", "not a layout key; accepted: " + ", ".join(JOIN_LAYOUT_KEYS))
    merged["input"] = dict(layout)
    out["join"] = merged


def partner_columns(spec: dict) -> list[str]:
    """The canonical columns read from the partner file: ``join.columns``, and ``time`` when the
    rows are matched by time."""
    join = spec["join"]
    return list(join["columns"]) + (["time"] if join["by"] == "time" else [])


def partner_layout(spec: dict) -> dict:
    """The ``input:`` mapping (not yet checked) the partner file of ``spec``'s ``join`` is read
    with: the machine's layout keys, overridden by ``join.input``; without ``join``, ``pattern``
    or speed (the partner gives ``join.columns`` and, by time, its clock; by row, no clock)."""
    join = spec["join"]
    base = {key: copy.deepcopy(spec[key]) for key in JOIN_LAYOUT_KEYS if key in spec}
    if "columns" not in join["input"]:
        keep = set(partner_columns(spec))
        base["columns"] = {k: v for k, v in spec["columns"].items() if k in keep}
    for key, value in join["input"].items():
        if key in ("time", "displacement") and isinstance(value, dict):
            base[key] = {**base.get(key, {}), **value}
        else:
            base[key] = copy.deepcopy(value)
    if join["by"] == "row":
        base["time"] = {**base.get("time", {}), "kind": "none", "period_s": 1.0, "format": None}
        base["columns"] = {k: v for k, v in base.get("columns", {}).items() if k != "time"}
    elif base.get("time", {}).get("kind") == "none":
        raise _error("join.by", "time needs a time column in both files; use by: row for files without one")
    if "disp_um" not in join["columns"]:
        base["displacement"] = {**base.get("displacement", {}), "column": None}
    return base
