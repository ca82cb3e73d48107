"""Machine-level checks across a machine's raw files (standard library only).

The per-file checks (:mod:`rafi.readers.checks`) see one file at a time. The checkpoint
``input_status`` sees all files of a machine and adds (:func:`apply_machine_checks`):

* ``duplicate_content``: a file byte-identical (same SHA-256) to another usable file of the
  machine; the later one by name is rejected (it would be trained or validated on twice).
* ``probe_sign``: a file whose displacement moves the other way than expected while the
  spindle heats the machine. ``checks.probe_sign: positive`` / ``negative``: a file with the opposite
  clear sign is rejected (error). ``auto``: expected is the sign of most of the machine's *other*
  files with a clear sign (positive, the documented convention, without any); a file that
  disagrees gets a warning.

It also gathers every per-file warning from the clean audits, and marks each one ``confirmed``
when an entry of ``checks.confirmed`` matches it (glob on the file name, exact check id).
"""

from __future__ import annotations

import csv
import fnmatch
import os
from collections.abc import Iterable, Mapping
from pathlib import Path

#: ``checks.probe_sign`` -> the expected sign (``auto``: from the other files).
CONFIGURED_SIGNS = {"positive": 1, "negative": -1}
#: Audit action of a warning row (``clean/<stem>.audit.csv``).
WARNING_ACTION = "warning"


def _int(value, default: int = 0) -> int:
    try:
        return int(float(value))
    except (TypeError, ValueError):
        return default


def read_rows(path: str | os.PathLike) -> list[dict]:
    """The rows of a CSV table as dicts (``[]`` if it cannot be read)."""
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            return list(csv.DictReader(fh))
    except (OSError, UnicodeDecodeError, csv.Error):
        return []


def audit_warnings(rows: Iterable[Mapping]) -> list[dict]:
    """The warning rows of a clean audit as ``{"file", "check", "column", "message", "first_line",
    "last_line"}`` (the detail ``"<check id>: <message>"`` split at its first colon)."""
    found = []
    for row in rows:
        if (row.get("action") or "").strip() != WARNING_ACTION:
            continue
        detail = row.get("detail") or ""
        check, _, message = detail.partition(": ")
        found.append(
            {
                "file": row.get("file") or "",
                "check": check.strip(),
                "column": row.get("column") or "",
                "message": message.strip() or detail,
                "first_line": row.get("first_line") or "",
                "last_line": row.get("last_line") or "",
            }
        )
    return found


def is_confirmed(file: str, check: str, confirmed: Iterable[Mapping]) -> bool:
    """True if an entry ``{file: <name or glob>, check: <id>}`` of ``checks.confirmed`` matches
    (``fnmatch``, case-sensitive, on the file name without folder; the check id exactly)."""
    name = Path(file).name
    return any(
        str(c.get("check")) == check and fnmatch.fnmatchcase(name, str(c.get("file", "")))
        for c in confirmed or ()
    )


def _expected_sign(setting: str, others: list[int]) -> int:
    if setting in CONFIGURED_SIGNS:
        return CONFIGURED_SIGNS[setting]
    pos, neg = sum(1 for s in others if s > 0), sum(1 for s in others if s < 0)
    return -1 if neg > pos else 1


def _sign_word(sign: int) -> str:
    return "rises" if sign > 0 else "falls"


def duplicate_rejections(
    usable: Iterable[str],
    sha: Mapping[str, str],
    *,
    links: Iterable[str] = (),
    keep: Mapping[str, str] | None = None,
) -> list[tuple[str, str, str]]:
    """The usable files that are byte-identical copies of another usable file.

    Of the files sharing a SHA-256, one stays: never a symbolic link while a regular file is
    there (removing the link loses nothing), else the file ``keep`` names for that content
    (:func:`rafi.ops.duplicates.copies_to_keep`: the one the champion was trained on, else
    the oldest), else the first by name. A file without a hash is nobody's copy.

    Returns
    -------
    list of tuple
        ``(file, "duplicate_content", why)`` per copy, in the order the files were ranked.
    """
    linked = set(links)
    keep = keep or {}

    def rank(file: str) -> tuple:
        return (file in linked, file != keep.get(sha[file]), file)

    first_of: dict[str, str] = {}
    found = []
    for file in sorted(usable, key=rank):
        digest = sha[file]
        if not digest:
            continue
        if digest not in first_of:
            first_of[digest] = file
            continue
        what = "remove the link" if file in linked else "delete the copy"
        found.append(
            (
                file,
                "duplicate_content",
                f"byte-identical to {first_of[digest]} (sha256 {digest[:12]}): the same data would be "
                f"used twice; {what}",
            )
        )
    return found


def probe_sign_findings(
    signs: Mapping[str, int], probe_sign: str
) -> tuple[list[tuple[str, str, str]], list[dict]]:
    """Files whose displacement moves against the expected sign while the spindle heats the machine.

    Parameters
    ----------
    signs : mapping
        ``file -> probe sign`` (+1 / -1 / 0 = no evidence) of the usable files.
    probe_sign : str
        ``checks.probe_sign``: with ``positive`` / ``negative`` a file of the opposite clear
        sign is rejected; with ``auto`` the expected sign is that of most of the *other* files
        with a clear sign (positive without any) and a file that disagrees gets a warning.

    Returns
    -------
    tuple
        ``(rejections, warnings)``: ``(file, "probe_sign", why)`` and ``{"file", "check",
        "column", "message"}``, in file name order.
    """
    rejections, warnings = [], []
    for file in sorted(signs):
        sign = signs[file]
        if sign == 0:
            continue
        others = [s for f, s in signs.items() if f != file and s != 0]
        expected = _expected_sign(probe_sign, others)
        if sign == expected:
            continue
        evidence = (
            f"the displacement {_sign_word(sign)} while the spindle heats the machine (probe sign {sign:+d})"
        )
        if probe_sign in CONFIGURED_SIGNS:
            rejections.append(
                (
                    file,
                    "probe_sign",
                    f"{evidence} but checks.probe_sign is {probe_sign}: the probe's sign is reversed in "
                    "this file; fix the file, or set input.displacement.sign (config.yaml)",
                )
            )
            continue
        basis = (
            f"{sum(1 for s in others if s == expected)} of the machine's other {len(others)} file(s) "
            f"with a clear sign say {expected:+d}"
            if others
            else "no other file says otherwise and the convention is positive (growth towards the table)"
        )
        warnings.append(
            {
                "file": file,
                "check": "probe_sign",
                "column": "disp_um",
                "message": f"{evidence}; {basis}: a reversed probe? (checks.probe_sign: auto)",
            }
        )
    return rejections, warnings


def listed_warnings(
    warnings: Iterable[Mapping], usable: Iterable[str], sha: Mapping[str, str], confirmed: Iterable[Mapping]
) -> list[dict]:
    """The warnings on usable files, in the given order, as ``input_status.json`` lists them:
    ``{"file", "sha256", "check", "column", "message", "confirmed"}`` (:func:`is_confirmed`)."""
    usable = set(usable)
    listed = []
    for w in warnings:
        file = str(w.get("file") or "")
        if file not in usable:
            continue
        check = str(w.get("check") or "")
        listed.append(
            {
                "file": file,
                "sha256": sha.get(file, ""),
                "check": check,
                "column": str(w.get("column") or ""),
                "message": str(w.get("message") or ""),
                "confirmed": is_confirmed(file, check, confirmed),
            }
        )
    return listed


def apply_machine_checks(
    status: dict,
    summaries: Iterable[Mapping],
    warnings: Iterable[Mapping] = (),
    *,
    probe_sign: str = "auto",
    confirmed: Iterable[Mapping] = (),
    links: Iterable[str] = (),
    keep: Mapping[str, str] | None = None,
) -> dict:
    """Add the machine-level checks and the per-file warnings to a machine input status.

    Parameters
    ----------
    status : dict
        :func:`rafi.readers.quarantine.machine_input_status` of the machine (not modified).
    summaries : iterable of mapping
        The rows of the machine's ``clean/<stem>.summary.csv`` (``file``, ``sha256``, ``status``,
        ``probe_sign``).
    warnings : iterable of mapping
        :func:`audit_warnings` of every file's clean audit.
    probe_sign : str
        ``checks.probe_sign``: ``auto``, ``positive`` or ``negative``.
    confirmed : iterable of mapping
        ``checks.confirmed``.
    links : iterable of str
        Files that are symbolic links (inside ``raw/``): of byte-identical files the link is the
        copy that goes, whatever the names.
    keep : mapping, optional
        ``sha256 -> file``: of byte-identical files, the one that stays
        (:func:`duplicate_rejections`).

    Returns
    -------
    dict
        A copy of ``status`` where files rejected here moved from ``usable`` to ``rejected``
        (``{"file", "sha256", "check", "reason"}``) and ``status`` is recomputed; plus
        ``warnings`` (``{"file", "sha256", "check", "column", "message", "confirmed"}``, per-file
        ones of usable files first, in file order, then the machine-level ones) and ``probe_sign``
        (``{"setting", "files": {file: sign}}``).
    """
    if probe_sign not in ("auto", *CONFIGURED_SIGNS):
        raise ValueError(f"checks.probe_sign must be auto, positive or negative, not {probe_sign!r}")
    rows = {str(r.get("file")): r for r in summaries}
    usable = list(status.get("usable", []))
    sha = {f: str(rows.get(f, {}).get("sha256") or "") for f in usable}
    rejected = [dict(r) for r in status.get("rejected", [])]

    def reject(found: list[tuple[str, str, str]]) -> None:
        for file, check, why in found:
            usable.remove(file)
            rejected.append(
                {"file": file, "sha256": sha[file], "check": check, "reason": f"{file}: {check}: {why}"}
            )

    reject(duplicate_rejections(usable, sha, links=links, keep=keep))
    signs = {f: _int(rows.get(f, {}).get("probe_sign")) for f in usable}
    sign_rejections, sign_warnings = probe_sign_findings(signs, probe_sign)
    reject(sign_rejections)
    out = dict(status)
    out.update(
        status="usable" if usable else "skipped",
        usable=usable,
        rejected=rejected,
        warnings=listed_warnings([*warnings, *sign_warnings], usable, sha, confirmed),
        probe_sign={"setting": probe_sign, "files": {f: signs[f] for f in usable}},
    )
    return out


def warning_lines(status: Mapping) -> list[str]:
    """One line per warning of a machine input status, for the log: ``<file>: <check>: <message>``
    (``[confirmed]`` appended to a confirmed one)."""
    return [
        f"{w['file']}: {w['check']}: {w['message']}" + (" [confirmed]" if w.get("confirmed") else "")
        for w in status.get("warnings", [])
    ]
