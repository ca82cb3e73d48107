"""Roles by time: training / validation / excluded windows of a log, and the leak guard.

A window (``runs: windows:`` in ``config.yaml``, ``docs/raw-format.md``) gives a role to every
sample of a log whose time falls in ``[start, end)``::

    - role: training          # training | validation | excluded
      start: 0                # optional: from the first sample of the log
      end: 0.6                # optional: to the last sample of the log (inclusive)
      unit: fraction          # elapsed_s (seconds since the log's first sample) | fraction of the
                              # log's span | time (ISO-8601 timestamps on the log's clock)
      log: "*"                # optional glob on the file name: the logs it applies to

:func:`resolve_windows` turns the windows of one log into intervals on the log's clock (seconds
since its first sample); :func:`cut_points` says where runs must be cut so that no run spans a
boundary; :func:`window_of` finds the window of a run. :func:`leak_check` is the leak guard:
data that comes after (or during) validation data of the same log never trains a model unless
the configuration says so explicitly. :func:`schedule_cooldowns` gives the automatic cool-downs
of the training schedule (``runs.idle_training: schedule``) their training role.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from rafi.errors import SettingsError

WINDOW_ROLES = ("training", "validation", "excluded")
#: ``runs.idle_training``: no cool-down trains / the cool-downs of the training schedule / every one
#: before validation data.
IDLE_TRAINING = (False, "schedule", True)
WINDOW_UNITS = ("elapsed_s", "fraction", "time")
#: The validation role of a run of each kind.
VALIDATION_BY_KIND = {
    "constant": "validation_single",
    "varying": "validation_multi",
    "idle": "validation_idle",
}


@dataclass(frozen=True)
class Window:
    """One window of one log on the log's clock: samples with ``start_s <= t < end_s``."""

    role: str
    start_s: float
    end_s: float
    text: str  # the window as configured, for people


def describe_window(spec: Mapping) -> str:
    unit = spec.get("unit", "elapsed_s")
    start, end = spec.get("start"), spec.get("end")
    if unit == "fraction":
        a = "start" if start is None else f"{100 * float(start):g} %"
        b = "end" if end is None else f"{100 * float(end):g} %"
        span = f"{a}-{b} of the log"
    elif unit == "elapsed_s":
        a = "start" if start is None else f"{float(start) / 3600:g} h"
        b = "end" if end is None else f"{float(end) / 3600:g} h"
        span = f"{a}-{b} of the log"
    else:
        span = f"{start or 'start'} to {end or 'end'}"
    return f"{spec['role']} window {span}"


def check_windows(windows: Sequence[Mapping] | None) -> list[dict]:
    """The windows as given, checked; raise :class:`SettingsError` naming the bad entry."""
    out = []
    for k, spec in enumerate(windows or []):
        where = f"runs.windows[{k}]"
        if not isinstance(spec, Mapping):
            raise SettingsError(f"{where}: expected a mapping with role, start, end, unit; got {spec!r}")
        unknown = sorted(set(spec) - {"role", "start", "end", "unit", "log"})
        if unknown:
            raise SettingsError(
                f"{where}: unknown key(s) {', '.join(unknown)} (known: role, start, end, unit, log)"
            )
        if spec.get("role") not in WINDOW_ROLES:
            raise SettingsError(
                f"{where}: role {spec.get('role')!r}; expected one of {', '.join(WINDOW_ROLES)}"
            )
        unit = spec.get("unit", "elapsed_s")
        if unit not in WINDOW_UNITS:
            raise SettingsError(f"{where}: unit {unit!r}; expected one of {', '.join(WINDOW_UNITS)}")
        for key in ("start", "end"):
            value = spec.get(key)
            if value is None:
                continue
            if unit == "time":
                try:
                    pd.Timestamp(str(value))
                except ValueError:
                    raise SettingsError(f"{where}: {key} {value!r} is not an ISO-8601 time") from None
            elif not isinstance(value, (int, float)) or isinstance(value, bool):
                raise SettingsError(f"{where}: {key} {value!r} is not a number ({unit})")
            elif unit == "fraction" and not 0 <= float(value) <= 1:
                raise SettingsError(f"{where}: {key} {value!r} is not a fraction between 0 and 1")
        out.append(dict(spec, unit=unit))
    return out


def applies_to(spec: Mapping, log_name: str) -> bool:
    """Does the window ``spec`` (:func:`check_windows`) apply to the log ``log_name`` (its ``log``
    glob on the file name; every log without one)?"""
    return fnmatch.fnmatch(log_name, str(spec.get("log", "*")))


def window_interval(
    spec: Mapping, k: int, log_name: str, span: float, times: np.ndarray | None
) -> tuple[float, float]:
    """Where the ``k``-th window ``spec`` (:func:`check_windows`) lies on the clock of the log
    ``log_name`` (``span``: seconds from its first to its last sample; ``times``: its clock per
    sample, ``NaT`` or None without one): ``(start_s, end_s)``, seconds since the log's first
    sample (``inf`` for an open end).

    Raises
    ------
    SettingsError
        A ``time`` window on a log without a clock.
    """
    start, end, unit = spec.get("start"), spec.get("end"), spec["unit"]
    if unit == "fraction":
        a = 0.0 if start is None else float(start) * span
        b = np.inf if end is None or float(end) >= 1 else float(end) * span
    elif unit == "elapsed_s":
        a = 0.0 if start is None else float(start)
        b = np.inf if end is None else float(end)
    else:
        if times is None or not len(times) or pd.isna(times[0]):
            raise SettingsError(
                f"runs.windows[{k}]: unit 'time' but log {log_name} has no clock (no time column "
                "or start time): give the window in elapsed_s or fraction"
            )
        t0 = pd.Timestamp(times[0])
        a = 0.0 if start is None else (pd.Timestamp(str(start)) - t0).total_seconds()
        b = np.inf if end is None else (pd.Timestamp(str(end)) - t0).total_seconds()
    return float(a), float(b)


def resolve_windows(
    windows: Sequence[Mapping] | None, log_name: str, t_s: np.ndarray, times: np.ndarray | None
) -> list[Window]:
    """The windows that apply to one log, on its clock.

    Parameters
    ----------
    windows : sequence of mapping
        ``runs: windows:`` (:func:`check_windows`).
    log_name : str
        The log's file name (matched against each window's ``log`` glob).
    t_s : numpy.ndarray
        Seconds since the log's first sample, per sample (increasing).
    times : numpy.ndarray of datetime64 or None
        The log's clock per sample (``NaT`` or None where the log has none).

    Returns
    -------
    list of Window
        In time order.

    Raises
    ------
    SettingsError
        A ``time`` window on a log without a clock, or two windows of the log that overlap.
    """
    out = []
    span = float(t_s[-1] - t_s[0]) if len(t_s) else 0.0
    for k, spec in enumerate(check_windows(windows)):
        if not applies_to(spec, log_name):
            continue
        a, b = window_interval(spec, k, log_name, span, times)
        if b <= a:
            raise SettingsError(f"runs.windows[{k}] ({describe_window(spec)}): end is not after start")
        out.append(Window(spec["role"], float(a), float(b), describe_window(spec)))
    out.sort(key=lambda w: w.start_s)
    for w1, w2 in zip(out, out[1:]):
        if w2.start_s < w1.end_s:
            raise SettingsError(
                f"runs.windows: '{w1.text}' and '{w2.text}' overlap in log {log_name}; "
                "a sample can have one role only"
            )
    return out


def cut_points(windows: Sequence[Window], t_s: np.ndarray) -> np.ndarray:
    """Sample indices where a window starts or ends (a run is cut there)."""
    edges = [e for w in windows for e in (w.start_s, w.end_s) if np.isfinite(e)]
    idx = np.searchsorted(t_s, np.asarray(edges, dtype=float) - 1e-9, side="left")
    return np.unique(idx[(idx > 0) & (idx < len(t_s))])


def window_of(windows: Sequence[Window], t_first: float) -> Window | None:
    """The window holding a run that starts at ``t_first`` (runs never span a boundary)."""
    for w in windows:
        if w.start_s - 1e-9 <= t_first < w.end_s:
            return w
    return None


def _validation_data(table: pd.DataFrame) -> pd.Series:
    """The runs of one log that count as validation data for the leak guard (see :func:`leak_check`)."""
    role, source = table["role"].astype(str), table["role_source"].astype(str)
    return role.str.startswith("validation") & (
        (source != "auto") | role.isin(["validation_single", "validation_multi"])
    )


def leak_check(table: pd.DataFrame, *, allow: bool) -> pd.DataFrame:
    """The leak guard on the runs of one log (rows of the runs table, in time order).

    Validation data that must never be followed by training data: every run whose role is
    validation and that was configured (a validation window or a run-id override), and every
    automatic ``validation_single`` / ``validation_multi`` run. An automatic idle cool-down
    (``validation_idle``) between training runs belongs to the training schedule (each
    training run starts from the cool-down before it) and does not count.

    * A training run that was configured (window, override) and ends after such a validation
      run starts is refused with :class:`SettingsError`, unless ``allow``; then its ``note``
      says so.
    * An automatic training run after such a validation run becomes ``validation_single``
      (``role_source = 'leak_guard'``), so automatic roles never leak.

    Returns the table with roles, sources, reasons and notes updated.
    """
    out = table.copy()
    if out.empty:
        return out
    role = out["role"].astype(str)
    guard = _validation_data(out)
    if not guard.any():
        return out
    first = out.loc[guard].sort_values("start_s").iloc[0]
    after = (role == "training") & (out["end_s"] > float(first["start_s"]))
    what = f"validation run {first['run_id']} (from {float(first['start_s']) / 3600:.2f} h of the log)"
    for i in out.index[after]:
        run = out.loc[i]
        if run["role_source"] == "auto":
            demoted = VALIDATION_BY_KIND.get(str(run.get("kind", "")), "validation_single")
            out.loc[i, ["role", "role_source"]] = [demoted, "leak_guard"]
            out.loc[i, "role_reason"] = (
                f"would be training ({run['role_reason']}) but lies after {what} of the same log: "
                "data after validation data never trains (leak guard)"
            )
        elif allow:
            note = (
                f"trains although it lies after or during {what} of the same log "
                "(allowed by runs.allow_training_after_validation)"
            )
            out.loc[i, "note"] = "; ".join(x for x in (str(run["note"] or ""), note) if x)
        else:
            raise SettingsError(
                f"log {run['file']}: training run {run['run_id']} ({float(run['start_s']) / 3600:.2f}-"
                f"{float(run['end_s']) / 3600:.2f} h, {run['role_reason']}) lies after or overlaps {what}: "
                "a model trained on it has seen the future of the validation data. Move the training "
                "window before the validation window, or set runs.allow_training_after_validation: true "
                "to accept it (the report then says so)"
            )
    return out


def schedule_cooldowns(table: pd.DataFrame) -> pd.DataFrame:
    """The automatic cool-downs of the training schedule of one log as training runs.

    Runs of one log (rows of the runs table, after :func:`leak_check`). An automatic idle run
    (``validation_idle``, ``role_source = 'auto'``) trains when the next run after it that is
    neither such a cool-down nor ``excluded`` is a training run, and it starts before the first
    validation data of the log (as :func:`leak_check` counts it). So the cool-downs between
    training runs, and a long rest before the first one, train: each training run starts from
    the cool-down before it, and the cool-downs carry the slow thermal modes. A cool-down after
    the last training run (before a validation run, or at the end of the log) stays
    ``validation_idle``: no training run starts from it, and how the machine cools after the
    last training run is for the validation to judge.

    Returns the table with the roles and reasons of the promoted cool-downs updated.
    """
    out = table.copy()
    if out.empty:
        return out
    out = out.sort_values("start_s", kind="stable")
    role = out["role"].astype(str)
    cooldown = (role == "validation_idle") & (out["role_source"].astype(str) == "auto")
    validation = _validation_data(out)
    first_validation = float(out.loc[validation, "start_s"].min()) if validation.any() else np.inf
    following = None  # the next run (in time) that is neither a cool-down nor excluded
    for i in reversed(out.index):
        if cooldown[i]:
            starts_before = float(out.loc[i, "start_s"]) < first_validation
            if following is not None and following["role"] == "training" and starts_before:
                out.loc[i, "role"] = "training"
                out.loc[i, "role_reason"] = (
                    f"{out.loc[i, 'role_reason']}; in the training schedule: training run "
                    f"{following['run_id']} starts from it, before any validation data of the log "
                    "(runs.idle_training: schedule)"
                )
            else:
                out.loc[i, "role_reason"] = (
                    f"{out.loc[i, 'role_reason']}; not in the training schedule: no training run "
                    "follows it before validation data of the log (runs.idle_training: schedule)"
                )
        elif role[i] != "excluded":
            following = out.loc[i]
    return out.loc[table.index]
