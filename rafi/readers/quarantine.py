"""Quarantined raw files: per file and per machine (standard library only: used while planning).

With ``on_bad_input: fail`` a clean job fails on a file it cannot use. A file quarantined by an
earlier ``quarantine`` run (``rafi nightly``) has up-to-date outputs, so no job would look at it
again; the workflow asks :func:`still_quarantined` while it plans and stops with the reasons.

With ``on_bad_input: quarantine`` a machine none of whose files is usable is skipped:
:func:`machine_input_status` (the workflow's ``input_status`` checkpoint), :func:`input_check`
(the run-level ``results/input_check.json``) and :func:`rejection_lines` (what the run says at
its end) describe what was rejected.
"""

from __future__ import annotations

import csv
import json
import os
from collections.abc import Iterable
from pathlib import Path


def still_quarantined(pairs: Iterable[tuple[str | os.PathLike, str | os.PathLike]]) -> list[str]:
    """Reasons of the quarantined files whose summary is newer than the raw file.

    Parameters
    ----------
    pairs : iterable of (raw path, summary path)
        Each raw file with its ``clean/<log id>.summary.csv`` (which may not exist yet).

    Returns
    -------
    list of str
        The ``reason`` of every summary with status ``quarantined`` that is at least as new as
        its raw file (an edited raw file will be cleaned again, so it is not listed).
    """
    reasons = []
    for raw, summary in pairs:
        summary = Path(summary)
        try:
            if summary.stat().st_mtime < Path(raw).stat().st_mtime:
                continue
            with open(summary, encoding="utf-8", newline="") as fh:
                rows = list(csv.DictReader(fh))
        except (OSError, csv.Error, UnicodeDecodeError):
            continue
        reasons += [
            row.get("reason") or row.get("file", "?") for row in rows if row.get("status") == "quarantined"
        ]
    return reasons


# --------------------------------------------------------------------------- machine level
#
# With ``on_bad_input: quarantine`` a machine whose raw files are all quarantined has nothing to
# fit: it is *skipped* (its other outputs are not built; the run carries on with the other
# machines). The workflow learns this from a checkpoint per machine (``input_status``, after the
# clean jobs) that writes :func:`machine_input_status` to ``results/<machine>/input_status.json``;
# the final targets of the machine depend on it (docs/operations.md, "A skipped machine").

#: ``status`` of a machine with at least one usable raw file.
USABLE = "usable"
#: ``status`` of a machine whose raw files were all quarantined.
SKIPPED = "skipped"


def _summary_rows(path: str | os.PathLike) -> list[dict]:
    with open(path, encoding="utf-8", newline="") as fh:
        return list(csv.DictReader(fh))


def machine_input_status(machine: str, summaries: Iterable[str | os.PathLike]) -> dict:
    """Which raw files of ``machine`` are usable, which were rejected and why.

    Parameters
    ----------
    machine : str
        The machine (folder under ``raw_dir``).
    summaries : iterable of path
        The machine's per-file ``clean/<log id>.summary.csv`` (one row each, as the clean step
        writes them; a summary of several rows counts every row).

    Returns
    -------
    dict
        ``machine``; ``status`` (:data:`USABLE` if at least one file has status ``ok``, else
        :data:`SKIPPED`); ``n_files``; ``usable`` (file names); ``rejected`` (one
        ``{"file", "sha256", "reason"}`` per file that is not ``ok``), files in the order given.
    """
    usable, rejected = [], []
    for path in summaries:
        for row in _summary_rows(path):
            name = row.get("file") or Path(path).name
            if (row.get("status") or "").strip() == "ok":
                usable.append(name)
            else:
                reason = (row.get("reason") or "").strip() or "no reason recorded"
                rejected.append({"file": name, "sha256": row.get("sha256") or "", "reason": reason})
    return {
        "machine": machine,
        "status": USABLE if usable else SKIPPED,
        "n_files": len(usable) + len(rejected),
        "usable": usable,
        "rejected": rejected,
    }


def read_input_status(path: str | os.PathLike) -> dict:
    """A machine's ``input_status.json`` (as :func:`machine_input_status` returns it).

    Raises
    ------
    OSError
        The file cannot be read.
    ValueError
        It is not a machine input status (bad JSON, or ``status`` is neither usable nor skipped).
    """
    with open(path, encoding="utf-8") as fh:
        status = json.load(fh)
    if not isinstance(status, dict) or status.get("status") not in (USABLE, SKIPPED):
        raise ValueError(f"{path}: not a machine input status (status must be {USABLE!r} or {SKIPPED!r})")
    return status


def is_skipped(status: dict) -> bool:
    """True if the machine of ``status`` has no usable raw file."""
    return status.get("status") == SKIPPED


def input_check(statuses: Iterable[dict]) -> dict:
    """The run-level summary of rejected input (``results/input_check.json``).

    Parameters
    ----------
    statuses : iterable of dict
        :func:`machine_input_status` of every machine of the run.

    Returns
    -------
    dict
        ``input_rejected`` (any file quarantined or machine skipped), ``skipped_machines``,
        ``rejected_files`` (``{"machine", "file", "reason"}``), ``machines`` (machine ->
        ``{"status", "n_files", "n_rejected"}``).
    """
    statuses = sorted(statuses, key=lambda s: s["machine"])
    rejected = [{"machine": s["machine"], **f} for s in statuses for f in s.get("rejected", [])]
    skipped = [s["machine"] for s in statuses if is_skipped(s)]
    return {
        "input_rejected": bool(rejected or skipped),
        "skipped_machines": skipped,
        "rejected_files": [{k: f[k] for k in ("machine", "file", "reason")} for f in rejected],
        "machines": {
            s["machine"]: {
                "status": s["status"],
                "n_files": s.get("n_files", 0),
                "n_rejected": len(s.get("rejected", [])),
            }
            for s in statuses
        },
    }


def rejection_lines(statuses: Iterable[dict]) -> list[str]:
    """One line per machine with rejected input, for people (empty if nothing was rejected).

    A skipped machine: ``"<m>: SKIPPED - no usable raw file (<n> rejected): <file>: <reason>; ..."``;
    a machine that carried on without some files: ``"<m>: <k> of <n> raw file(s) quarantined: ..."``.
    """
    lines = []
    for s in sorted(statuses, key=lambda s: s["machine"]):
        rejected = s.get("rejected") or []
        listed = "; ".join(f"{f['file']}: {f['reason']}" for f in rejected)
        if is_skipped(s):
            lines.append(f"{s['machine']}: SKIPPED - no usable raw file ({len(rejected)} rejected): {listed}")
        elif rejected:
            lines.append(
                f"{s['machine']}: {len(rejected)} of {s.get('n_files', len(rejected))} raw file(s) "
                f"quarantined, carried on without them: {listed}"
            )
    return lines


def present_statuses(paths: Iterable[str | os.PathLike]) -> list[dict]:
    """:func:`read_input_status` of every path that exists and can be read (others left out)."""
    found = []
    for path in paths:
        try:
            found.append(read_input_status(path))
        except (OSError, ValueError):
            continue
    return found
