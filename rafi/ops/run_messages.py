"""What a workflow run says at its end about the jobs that failed on bad input (standard library only).

A job that fails on bad input ends its log with one line (``workflow/scripts/_glue.py``)::

    RAFI <step> (<wildcards>) failed: <file>, line <n>: <what was expected> (<likely cause>)

Snakemake prints a failed job's block and log in the middle of its output; the Snakefile's
``onerror`` (``say_failures`` in ``workflow/rules/common.smk``) repeats these lines at the very
end, so the message is the last thing the user reads.
"""

from __future__ import annotations

import os
from pathlib import Path

#: How a bad-input failure line starts and what it holds.
PREFIX = "RAFI "
MARKER = " failed: "


def failure_line(step: str, wildcards: str, message: str) -> str:
    """The line a job that failed ends its log with: ``RAFI <step> (<wildcards>) failed: <message>``."""
    return f"{PREFIX}{step} ({wildcards}){MARKER}{message}"


def is_failure_line(line: str) -> bool:
    """True for a job log's closing line of a failure on bad input."""
    return line.startswith(PREFIX) and MARKER in line


def last_failure_line(log_file: str | os.PathLike) -> str | None:
    """The failure line a job log ends with, or None (the job did not fail on bad input)."""
    try:
        with open(log_file, encoding="utf-8", errors="replace") as fh:
            lines = [line.rstrip("\n") for line in fh if line.strip()]
    except OSError:
        return None
    return lines[-1] if lines and is_failure_line(lines[-1]) else None


def failure_lines(logs_dir: str | os.PathLike, since: float) -> list[str]:
    """The failure lines of every job log under ``logs_dir`` written at or after ``since``
    (``time.time()`` when the run started), in path order; earlier runs' logs are left out."""
    found = []
    for path in sorted(Path(logs_dir).rglob("*.log")):
        try:
            if path.stat().st_mtime < since:
                continue
        except OSError:
            continue
        line = last_failure_line(path)
        if line is not None:
            found.append(line)
    return found
