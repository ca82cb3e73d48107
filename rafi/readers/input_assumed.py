"""What the ``input:`` mapping says in place of a missing time or speed column (standard library only).

Some loggers write no time column (one row per period) and some logs were recorded at one
spindle speed with no speed column. The mapping then gives what the file does not hold
(``docs/raw-format.md``, "Logs without a time or speed column"):

* ``time: {kind: none, period_s: 60, start: "2026-03-02T06:00:00"}``: data row k of a file is
  at ``start + k * period_s`` (``start`` optional: without it the log has no clock,
  :func:`rafi.readers.mapped_time.has_clock`);
* ``speed: {constant_rpm: 3000}`` for every file of the machine, and/or
  ``speed: {constant_rpm_by_file: {"<glob on the file name>": 3000}}`` per file (a matching
  glob wins over ``constant_rpm``); no speed column is read then.

:func:`check_no_time_column` and :func:`check_speed` are the parts of
:func:`rafi.readers.input_spec.normalise_input_spec` for these keys (they raise
:class:`rafi.errors.InputSpecError` naming the key); :func:`constant_speed` finds a file's speed.
The reader records what it assumed in ``attrs['metadata']['assumed']``
(:func:`rafi.readers.mapped_time.assumed_notes`).
"""

from __future__ import annotations

import fnmatch
import math

from rafi.errors import InputSpecError


def _error(key: str, message: str) -> InputSpecError:
    return InputSpecError(f"input.{key}: {message}")


def _positive(value, *, zero_ok: bool = False) -> bool:
    """True for a finite int/float above 0 (or at 0 with ``zero_ok``); bools are not numbers."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return False
    return value >= 0 if zero_ok else value > 0


def check_no_time_column(out: dict) -> None:
    """``time.kind: none``: the period is given, nothing asks for a time column (in place)."""
    tm = out["time"]
    if tm["kind"] != "none":
        if tm["period_s"] is not None:
            raise _error(
                "time.period_s",
                f"applies to time.kind: none only (kind is {tm['kind']}: the time column gives the times)",
            )
        return
    period = tm["period_s"]
    if period is None:
        raise _error(
            "time.period_s",
            "missing: time.kind: none needs the logger's period (row k of a file is at start + k * period_s)",
        )
    if not _positive(period):
        raise _error("time.period_s", f"{period!r}: expected a positive number of seconds")
    tm["period_s"] = float(period)
    if "time" in out["columns"]:
        raise _error(
            "columns.time", "time.kind: none reads no time column; remove columns.time or set time.kind"
        )
    if tm["format"] is not None:
        raise _error("time.format", "applies to time.kind: timestamp only (kind is none)")
    sp = out["sample_period_s"]
    if sp is not None and sp != tm["period_s"]:
        raise _error(
            "sample_period_s",
            f"{sp:g} s differs from time.period_s {tm['period_s']:g} s; give the period once (time.period_s)",
        )
    out["sample_period_s"] = tm["period_s"]


def check_speed(out: dict) -> None:
    """``speed:`` constants are non-negative numbers keyed by non-empty globs (in place)."""
    speed = out["speed"]
    rpm = speed["constant_rpm"]
    if rpm is not None:
        if not _positive(rpm, zero_ok=True):
            raise _error("speed.constant_rpm", f"{rpm!r}: expected a speed in r/min (a number >= 0)")
        speed["constant_rpm"] = float(rpm)
    by_file = speed["constant_rpm_by_file"]
    if by_file is None:
        by_file = {}
    if not isinstance(by_file, dict):
        raise _error(
            "speed.constant_rpm_by_file",
            f"expected a mapping of file-name globs to speeds (e.g. '*_3000rpm*': 3000), got {by_file!r}",
        )
    checked = {}
    for glob, value in by_file.items():
        if not isinstance(glob, str) or not glob.strip():
            raise _error("speed.constant_rpm_by_file", f"{glob!r}: expected a glob on the file name")
        if not _positive(value, zero_ok=True):
            raise _error(
                f"speed.constant_rpm_by_file.{glob}", f"{value!r}: expected a speed in r/min (a number >= 0)"
            )
        checked[glob] = float(value)
    speed["constant_rpm_by_file"] = checked
    if has_constant_speed(out) and "speed_rpm" in out["columns"]:
        raise _error(
            "speed",
            "conflicts with columns.speed_rpm: the speed comes either from a column or from "
            "speed.constant_rpm / speed.constant_rpm_by_file, not both",
        )


def has_constant_speed(spec: dict) -> bool:
    """True if a normalised mapping takes the speed from config (no speed column is read)."""
    speed = spec["speed"]
    return speed["constant_rpm"] is not None or bool(speed["constant_rpm_by_file"])


def constant_speed(file_name: str, spec: dict) -> tuple[float, str] | None:
    """The configured constant speed of one file, and where it comes from.

    Parameters
    ----------
    file_name : str
        The raw file's name (not its folder), matched case-sensitively against the globs of
        ``speed.constant_rpm_by_file``.
    spec : dict
        A normalised ``input:`` mapping.

    Returns
    -------
    tuple of (float, str) or None
        ``(speed_rpm, source)`` with ``source`` the config key that gave it
        (``input.speed.constant_rpm_by_file['<glob>']`` or ``input.speed.constant_rpm``);
        ``None`` when the mapping configures no constant speed for this file.

    Raises
    ------
    InputSpecError
        Two globs with different speeds match the file: which one applies is not decidable.
    """
    by_file = spec["speed"]["constant_rpm_by_file"]
    hits = [(glob, rpm) for glob, rpm in by_file.items() if fnmatch.fnmatchcase(file_name, glob)]
    if len({rpm for _, rpm in hits}) > 1:
        listed = ", ".join(f"{glob!r} ({rpm:g} r/min)" for glob, rpm in hits)
        raise _error(
            "speed.constant_rpm_by_file",
            f"file {file_name!r} matches {listed}; make the globs exclusive",
        )
    if hits:
        return hits[0][1], f"input.speed.constant_rpm_by_file[{hits[0][0]!r}]"
    if spec["speed"]["constant_rpm"] is not None:
        return spec["speed"]["constant_rpm"], "input.speed.constant_rpm"
    return None


def check_period(spec: dict, sample_period_s: float) -> None:
    """Refuse a log without a time column whose period is not the machine's sample period.

    The clean step lays every log on the grid of the machine's ``sample_period_s``; rows that
    are ``time.period_s`` apart would not fit it.

    Parameters
    ----------
    spec : dict
        A normalised ``input:`` mapping.
    sample_period_s : float
        The machine's ``sample_period_s`` setting.

    Raises
    ------
    InputSpecError
        ``time.kind`` is ``none`` and ``time.period_s`` differs from ``sample_period_s``.
    """
    period = spec["time"]["period_s"]
    if spec["time"]["kind"] == "none" and period is not None and float(period) != float(sample_period_s):
        raise _error(
            "time.period_s",
            f"{period:g} s differs from the machine's sample_period_s {float(sample_period_s):g} s; "
            f"set sample_period_s: {period:g} for this machine",
        )


def log_speed(log_name: str | None, file_name: str, spec: dict) -> tuple[float, str] | None:
    """:func:`constant_speed` of a log that is not a whole file (a sheet of a workbook,
    docs/raw-format.md): a glob matching the log's name wins, then one matching the file
    name, then ``speed.constant_rpm``."""
    found = constant_speed(log_name, spec) if log_name is not None and log_name != file_name else None
    if found is None or found[1] == "input.speed.constant_rpm":
        found = constant_speed(file_name, spec) or found
    return found
