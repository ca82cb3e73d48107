"""Files that come in pairs by name, and a workbook's sheets of one layout (``rafi init``).

Pure functions on file and sheet names: :func:`pair_parts` finds the two texts that tell a
run's temperature file from its displacement file (``temps_0312.csv`` / ``disp_0312.csv`` ->
``("temps", "disp")``, the ``input.join.replace`` of docs/raw-format.md); :func:`sheet_glob`
the ``input.sheet`` pattern that matches a workbook's log sheets and none of its others.
"""

from __future__ import annotations

import os

from rafi.readers.log_sources import sheet_matches


def _difference(a: str, b: str) -> tuple[str, str]:
    """The parts of ``a`` and ``b`` between their common start and their common end."""
    head = len(os.path.commonprefix([a, b]))
    tail = len(os.path.commonprefix([a[head:][::-1], b[head:][::-1]]))
    return a[head : len(a) - tail], b[head : len(b) - tail]


def pair_parts(mains: list[str], partners: list[str]) -> tuple[str, str] | None:
    """``(x, y)`` such that every name of ``mains`` with ``x`` replaced by ``y`` is a name of
    ``partners`` and every partner is reached so, and the names share more than their suffix;
    None when no such texts exist.

    Parameters
    ----------
    mains, partners : list of str
        File names (with their suffix) of the logs and of their partner files.

    Returns
    -------
    tuple of str or None
        The texts as ``input.join.replace`` takes them (both non-empty, ``y`` not in a main name).
    """
    if not mains or len(mains) != len(partners):
        return None
    for partner in partners:
        x, y = _difference(mains[0], partner)
        x, y = _word(mains[0], partner, x, y)
        if not x or not y or any(y in m for m in mains):
            continue
        if not any(c.isalnum() for m in mains for c in os.path.splitext(m)[0].replace(x, "")):
            continue  # nothing of the names shared but the suffix: not a pair by name
        if sorted(m.replace(x, y) for m in mains) == sorted(partners):
            return x, y
    return None


def _word(a: str, b: str, x: str, y: str) -> tuple[str, str]:
    """``x`` and ``y`` grown to whole words (letters and digits) of ``a`` and ``b``: the common
    letters of ``temps``/``temperature`` belong to the texts, not to the shared part."""
    i = a.find(x) if x else -1
    j = b.find(y) if y else -1
    if i < 0 or j < 0:
        return x, y
    while i > 0 and j > 0 and a[i - 1].isalnum() and a[i - 1] == b[j - 1]:
        i, j, x, y = i - 1, j - 1, a[i - 1] + x, b[j - 1] + y
    ea, eb = i + len(x), j + len(y)
    while ea < len(a) and eb < len(b) and a[ea].isalnum() and a[ea] == b[eb]:
        x, y, ea, eb = x + a[ea], y + b[eb], ea + 1, eb + 1
    return x, y


def main_pattern(x: str, mains: list[str], suffix: str) -> str:
    """``input.pattern`` matching the main files: ``temps_*.csv`` when they start with ``x``,
    else ``*temps*.csv``."""
    return f"{x}*{suffix}" if all(m.startswith(x) for m in mains) else f"*{x}*{suffix}"


def sheet_glob(logs: list[str], sheets: list[str]) -> str | None:
    """The ``input.sheet`` pattern matching exactly the sheets ``logs`` of a workbook whose
    sheets are ``sheets``: ``"*"`` when every sheet is a log, else their common start and
    ``*`` (``"Tag *"``); None when neither matches exactly (the user names them)."""
    if sorted(logs) == sorted(sheets):
        return "*"
    head = os.path.commonprefix(logs)
    if not head:
        return None
    glob = head + "*"
    if sorted(s for s in sheets if sheet_matches(glob, s)) == sorted(logs):
        return glob
    return None
