"""The test plan of ``rafi record --plan``: a CSV of speed steps (docs/record.md, "The test plan").

One step per line: ``speed_rpm`` (the speed command, r/min, 0 or more) held for ``duration_s``
seconds (above 0). An optional ``run`` column names the recording a step belongs to:
consecutive steps with the same name go into one file, a step with an empty ``run`` is not
recorded (a cool-down between two cold starts); without the column the whole plan is one
recording. Optional ``note`` and ``reason`` columns are free text for the reader of the plan
(``rafi plan`` writes why each step is there in ``reason``). Lines starting
with ``#`` and blank lines are ignored. Every mistake is one line naming the file, the line and
the column (:func:`read_plan`). Standard library only.
"""

from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass
from pathlib import Path

from rafi.errors import RafiUserError, quote, short_path

__all__ = ["PLAN_COLUMNS", "Plan", "PlanStep", "RUN_NAME", "read_plan"]

#: The columns a plan may have (``speed_rpm`` and ``duration_s`` are required).
PLAN_COLUMNS = ("speed_rpm", "duration_s", "run", "note", "reason")
#: What a recording's name may be: it starts the file name (``<run>_<start>.csv``).
RUN_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,79}$")
#: A plan longer than this is refused (a mistyped unit: hours written as seconds x 3600 twice).
MAX_PLAN_S = 60 * 86400.0
#: The most steps a plan may have.
MAX_STEPS = 10000


@dataclass(frozen=True)
class PlanStep:
    """One step: command ``speed_rpm`` for ``duration_s``; ``run`` the recording (None: not recorded)."""

    speed_rpm: float
    duration_s: float
    run: str | None
    line: int


@dataclass(frozen=True)
class Plan:
    """The steps of a plan file, in order, and where each starts."""

    path: str
    steps: tuple[PlanStep, ...]

    @property
    def total_s(self) -> float:
        """The plan's length, s."""
        return math.fsum(s.duration_s for s in self.steps)

    def starts(self) -> list[float]:
        """The time (s from the plan's start) each step begins."""
        out, t = [], 0.0
        for step in self.steps:
            out.append(t)
            t += step.duration_s
        return out

    def step_at(self, elapsed_s: float) -> int | None:
        """Index of the step in force ``elapsed_s`` after the start (None: the plan is over)."""
        t = 0.0
        for i, step in enumerate(self.steps):
            t += step.duration_s
            if elapsed_s < t:
                return i
        return None


def _error(path, message: str, line: int | None = None, column: str | None = None) -> RafiUserError:
    where = f"plan {short_path(path)}"
    if line is not None:
        where += f", line {line}"
    if column is not None:
        where += f", column {quote(column, 40)}"
    return RafiUserError(f"{where}: {message}")


def _number(path, text: str, line: int, column: str, *, positive: bool) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    bound = "above 0" if positive else "0 or more"
    what = "a duration in seconds" if column == "duration_s" else "a speed in r/min"
    if not math.isfinite(value) or value < 0 or (positive and value == 0):
        hint = " (decimal comma? use a point)" if "," in text else ""
        raise _error(path, f"{quote(text)} is not {what} {bound}{hint}", line, column)
    return value


def _header(path, fields: list[str], line: int) -> list[str]:
    names = [f.strip().lstrip("\ufeff").strip() for f in fields]
    for name in names:
        if name not in PLAN_COLUMNS:
            raise _error(
                path, f"unknown column; the columns are {', '.join(PLAN_COLUMNS)}", line, name or "(empty)"
            )
        if names.count(name) > 1:
            raise _error(path, "the column appears twice in the header", line, name)
    for name in ("speed_rpm", "duration_s"):
        if name not in names:
            raise _error(
                path,
                f"the header has no column {name!r}; expected e.g. 'speed_rpm,duration_s,run'",
                line,
            )
    return names


def read_plan(path, *, default_run: str = "rec", max_speed_rpm: float | None = None) -> Plan:
    """Read and check a plan file.

    Parameters
    ----------
    path : path
        The CSV file (UTF-8; a byte-order mark is accepted).
    default_run : str
        The recording's name when the plan has no ``run`` column.
    max_speed_rpm : float, optional
        A step faster than this is refused (none: no limit).

    Returns
    -------
    Plan

    Raises
    ------
    RafiUserError
        (exit status 64) The file cannot be read, or a line breaks the format: one line naming
        the file, the line and the column, what was found and what was expected.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise _error(path, "no such file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise _error(path, f"cannot be read as UTF-8 text ({type(exc).__name__}: {exc})") from None
    header: list[str] | None = None
    steps: list[PlanStep] = []
    for number, raw in enumerate(text.splitlines(), start=1):
        if not raw.strip() or raw.lstrip("\ufeff").lstrip().startswith("#"):
            continue
        try:
            fields = next(csv.reader([raw]))
        except csv.Error as exc:
            raise _error(path, f"not a CSV line ({exc})", number) from None
        if header is None:
            header = _header(path, fields, number)
            continue
        if len(fields) != len(header):
            raise _error(
                path, f"found {len(fields)} fields, expected {len(header)} ({','.join(header)})", number
            )
        row = {name: value.strip() for name, value in zip(header, fields)}
        speed = _number(path, row["speed_rpm"], number, "speed_rpm", positive=False)
        if max_speed_rpm is not None and speed > max_speed_rpm:
            raise _error(
                path, f"{speed:g} r/min is above the limit of {max_speed_rpm:g}", number, "speed_rpm"
            )
        duration = _number(path, row["duration_s"], number, "duration_s", positive=True)
        run: str | None = default_run
        if "run" in row:
            run = row["run"] or None
            if run is not None and not RUN_NAME.match(run):
                raise _error(
                    path,
                    f"{quote(run)} cannot start a file name; use letters, digits, '.', '_' and '-' "
                    "(at most 80, starting with a letter or digit), or leave it empty for a step "
                    "that is not recorded",
                    number,
                    "run",
                )
        steps.append(PlanStep(speed, duration, run, number))
        if len(steps) > MAX_STEPS:
            raise _error(path, f"more than {MAX_STEPS} steps", number)
    if header is None or not steps:
        raise _error(
            path,
            "no steps; expected a header 'speed_rpm,duration_s[,run][,note][,reason]' and one line per step",
        )
    plan = Plan(str(path), tuple(steps))
    if plan.total_s > MAX_PLAN_S:
        raise _error(path, f"the steps last {plan.total_s / 86400:.1f} days, more than 60: a unit mistake?")
    if all(s.run is None for s in steps):
        raise _error(path, "no step is recorded (every 'run' is empty)")
    return plan
