"""Raw files an earlier run quarantined and that are still as they were (standard library only).

With ``on_bad_input: fail`` a clean job fails on a file it cannot use. A file quarantined by an
earlier ``quarantine`` run (``rafi nightly``) has up-to-date outputs, so no job would look at it
again; the workflow asks :func:`still_quarantined` while it plans and stops with the reasons.
"""

from __future__ import annotations

import csv
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
