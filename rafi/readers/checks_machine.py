"""Machine-level checks across a machine's raw files (standard library only).

The per-file checks (:mod:`rafi.readers.checks`) see one file at a time. The checkpoint
``input_status`` sees all files of a machine and adds (:func:`apply_machine_checks`):

* ``duplicate_content``: a file byte-identical (same SHA-256) to another usable file of the
  machine; the later one by name is rejected (it would be trained or validated on twice).
* ``probe_sign``: a file whose displacement moves the other way than expected while the
  temperatures rise. ``checks.probe_sign: positive`` / ``negative``: a file with the opposite
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


def apply_machine_checks(
    status: dict,
    summaries: Iterable[Mapping],
    warnings: Iterable[Mapping] = (),
    *,
    probe_sign: str = "auto",
    confirmed: Iterable[Mapping] = (),
    links: Iterable[str] = (),
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
    extra_warnings: list[dict] = []

    def reject(file: str, check: str, why: str) -> None:
        usable.remove(file)
        rejected.append(
            {"file": file, "sha256": sha[file], "check": check, "reason": f"{file}: {check}: {why}"}
        )

    # -- duplicate content: the later file by name goes (a link before any regular file)
    linked = set(links)
    first_of: dict[str, str] = {}
    for file in sorted(usable, key=lambda f: (f in linked, f)):
        digest = sha[file]
        if not digest:
            continue
        if digest in first_of:
            reject(
                file,
                "duplicate_content",
                f"byte-identical to {first_of[digest]} (sha256 {digest[:12]}): the same data would be "
                + ("used twice; remove the link" if file in linked else "used twice; delete the copy"),
            )
        else:
            first_of[digest] = file

    # -- probe sign
    signs = {f: _int(rows.get(f, {}).get("probe_sign")) for f in usable}
    for file in sorted(usable):
        sign = signs[file]
        if sign == 0:
            continue
        others = [s for f, s in signs.items() if f != file and s != 0 and f in usable]
        expected = _expected_sign(probe_sign, others)
        if sign == expected:
            continue
        evidence = f"the displacement {_sign_word(sign)} while the temperatures rise (probe sign {sign:+d})"
        if probe_sign in CONFIGURED_SIGNS:
            reject(
                file,
                "probe_sign",
                f"{evidence} but checks.probe_sign is {probe_sign}: the probe's sign is reversed in this "
                "file; fix the file, or set input.displacement.sign (config.yaml)",
            )
            continue
        basis = (
            f"{sum(1 for s in others if s == expected)} of the machine's other {len(others)} file(s) "
            f"with a clear sign say {expected:+d}"
            if others
            else "no other file says otherwise and the convention is positive (growth towards the table)"
        )
        extra_warnings.append(
            {
                "file": file,
                "check": "probe_sign",
                "column": "disp_um",
                "message": f"{evidence}; {basis}: a reversed probe? (checks.probe_sign: auto)",
            }
        )

    listed = []
    for w in [*warnings, *extra_warnings]:
        file = str(w.get("file") or "")
        if file not in usable:
            continue
        listed.append(
            {
                "file": file,
                "sha256": sha.get(file, ""),
                "check": str(w.get("check") or ""),
                "column": str(w.get("column") or ""),
                "message": str(w.get("message") or ""),
                "confirmed": is_confirmed(file, str(w.get("check") or ""), confirmed),
            }
        )
    out = dict(status)
    out.update(
        status="usable" if usable else "skipped",
        usable=usable,
        rejected=rejected,
        warnings=listed,
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
