"""What a workflow run says at its end about the jobs that failed on bad input, and the warnings
a job wants the user to read (standard library only).

A job that fails on bad input ends its log with one line (``workflow/scripts/_glue.py``)::

    RAFI <step> (<wildcards>) failed: <file>, line <n>: <what was expected> (<likely cause>)

Snakemake prints a failed job's block and log in the middle of its output; the Snakefile's
``onerror`` (``say_failures`` in ``workflow/rules/common.smk``) repeats these lines at the very
end, so the message is the last thing the user reads.

A warning the user must read (not only the job's log) is a line of its own in the log::

    RAFI <step> (<wildcards>) warning: <what is suspicious> (<what to do>)

The end-of-run lines (:mod:`rafi.ops.outcome`) repeat the warnings of each machine's logs under
its line, whether or not the job ran in this run: the log is that of the outputs in place.
"""

from __future__ import annotations

import os
from pathlib import Path

#: How a bad-input failure line starts and what it holds.
PREFIX = "RAFI "
MARKER = " failed: "
WARNING_MARKER = " warning: "
#: The line a job's log ends with when its step finished (``workflow/scripts/_glue.py``).
DONE_MARKER = "] done in "


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


def warning_line(step: str, wildcards: str, message: str) -> str:
    """A warning line of a job log: ``RAFI <step> (<wildcards>) warning: <message>``."""
    return f"{PREFIX}{step} ({wildcards}){WARNING_MARKER}{message}"


def is_warning_line(line: str) -> bool:
    """True for a warning line of a job log (:func:`warning_line`)."""
    return line.startswith(PREFIX) and WARNING_MARKER in line


def log_warnings(log_file: str | os.PathLike) -> list[str]:
    """The warning lines of a job log, in order, as ``(<step>): <message>`` (without ``RAFI`` and
    the wildcards); none if the log cannot be read."""
    try:
        with open(log_file, encoding="utf-8", errors="replace") as fh:
            lines = [line.rstrip("\n") for line in fh if is_warning_line(line)]
    except OSError:
        return []
    found = []
    for line in lines:
        head, message = line[len(PREFIX) :].split(WARNING_MARKER, 1)
        found.append(f"({head.split(' (', 1)[0]}): {message}")
    return found


def step_failed(log_file: str | os.PathLike) -> tuple[bool, str | None]:
    """Did the job whose log this is fail? ``(failed, failure line)``: a log that ends with a
    failure line (bad input) failed with it; a log without its ``[<step>] done in`` line (a
    traceback) failed with no line; an empty log (the step never began) or one that cannot be
    read says nothing (``False``)."""
    try:
        with open(log_file, encoding="utf-8", errors="replace") as fh:
            lines = [line.rstrip("\n") for line in fh if line.strip()]
    except OSError:
        return False, None
    if not lines:  # the step never began (a step after a failed one of the same job)
        return False, None
    if is_failure_line(lines[-1]):
        return True, lines[-1]
    return not any(DONE_MARKER in line for line in lines), None
