"""Checks of a machine's runs against its configuration: what matches nothing, what is likely wrong.

After :func:`rafi.method.runs.find_runs` (the runs step of the method, ``workflow/scripts/method.py``),
:func:`check_runs` holds the runs table and the logs against the ``runs:``, ``reference:``,
``training_speeds_rpm`` and ``input.speed`` settings:

* an entry that matches nothing stops the run with :class:`rafi.errors.SettingsError` naming its
  key: a ``runs.windows[i].log`` glob matching no log of the machine, a window lying outside every
  log it applies to, a ``runs.overrides`` key naming no run, log or file, an
  ``input.speed.constant_rpm_by_file`` glob matching no file;
* no training run at all (no run at a training speed, no training window): one line naming
  ``training_speeds_rpm``, the configured speeds and the speeds the logs hold (with run counts);
* warnings (lines for the method's log and the end-of-run lines, :mod:`rafi.ops.run_messages`):
  a configured training speed with no training run; several runs in one continuous log segment
  with ``reference.rule: run_start`` (each run then starts from its own, usually warm, state).

Pure functions on the runs table and plain values; the errors list every problem found, one per
``; ``-separated item, on one line.
"""

from __future__ import annotations

import fnmatch
import math
from collections.abc import Iterable, Mapping, Sequence

import numpy as np
import pandas as pd

from rafi.errors import SettingsError
from rafi.method.rank import speed_training_runs
from rafi.method.windows import applies_to, check_windows, describe_window, window_interval
from rafi.settings import MACHINE_DEFAULTS

#: How many names a message lists before ``... (N more)``.
LISTED = 8
#: Where the docs explain the reference state of runs inside a continuous log.
CONTINUOUS_LOG_DOCS = "docs/raw-format.md#worked-example-a-continuous-log-with-a-chronological-split"


def listed(names: Iterable[str], limit: int = LISTED) -> str:
    """``a, b, c`` (the first ``limit`` names, then ``... (N more)``); ``none`` for no name."""
    names = [str(n) for n in names]
    if not names:
        return "none"
    more = f", ... ({len(names) - limit} more)" if len(names) > limit else ""
    return ", ".join(names[:limit]) + more


def _rpm(value: float) -> str:
    return f"{value:.0f}"


def speed_groups(speeds: Sequence[float], tolerance_rpm: float) -> list[tuple[float, int]]:
    """The distinct speeds of ``speeds`` (NaN left out): sorted speeds within ``tolerance_rpm``
    of the first of a group form one group; ``(median speed, count)`` per group, ascending."""
    values = sorted(float(s) for s in speeds if s is not None and not math.isnan(float(s)))
    groups: list[list[float]] = []
    for v in values:
        if groups and v - groups[-1][0] <= tolerance_rpm + 1e-9:
            groups[-1].append(v)
        else:
            groups.append([v])
    return [(float(np.median(g)), len(g)) for g in groups]


def speeds_found(table: pd.DataFrame, tolerance_rpm: float) -> str:
    """The speeds of a machine's runs, compactly: each constant speed with its run count (and how
    many of them are excluded), then the varying and idle runs: ``"constant-speed runs at 1500
    (2), 3000 (1, 1 excluded) r/min; 1 varying, 2 idle"``."""
    kind = table["kind"].astype(str) if "kind" in table else pd.Series("", index=table.index)
    constant = table[kind == "constant"]
    parts = []
    for speed, count in speed_groups(constant["speed_rpm"].tolist(), tolerance_rpm):
        near = constant[(constant["speed_rpm"] - speed).abs() <= tolerance_rpm + 1e-9]
        excluded = int((near["role"].astype(str) == "excluded").sum())
        parts.append(f"{_rpm(speed)} ({count}{f', {excluded} excluded' if excluded else ''})")
    text = f"constant-speed runs at {listed(parts, 10)} r/min" if parts else "no constant-speed run"
    counts = (("varying", int((kind == "varying").sum())), ("idle", int((kind == "idle").sum())))
    others = [f"{n} {what}" for what, n in counts if n]
    return text + (f"; {', '.join(others)}" if others else "")


def training_speed_problems(
    table: pd.DataFrame,
    training_speeds_rpm: Sequence[float],
    tolerance_rpm: float,
    machine: str,
    *,
    prior: object = None,
) -> list[str]:
    """Warnings for the configured training speeds without a training run; raises if no run trains.

    Where the machine may re-qualify from a prior (``models.prior`` other than ``none``: ``rafi
    plan``'s short programme tests some speeds and leaves the rest to the prior) the warning adds
    that case and the prior's ``prior_speeds`` confirmation; the rule cannot tell whether a prior
    is in use tonight (``auto`` takes the champion when there is one), so it says both.

    Raises
    ------
    SettingsError
        No constant-speed run has the role ``training`` (the runs RAFI as published learns from,
        :func:`rafi.method.rank.speed_training_runs`): names ``training_speeds_rpm``, the
        configured speeds and the speeds the logs hold (:func:`speeds_found`).
    """
    configured = [float(s) for s in training_speeds_rpm or []]
    speeds = ", ".join(_rpm(s) for s in configured) or "none"
    training = speed_training_runs(table).dropna(subset=["speed_rpm"])
    if training.empty:
        raise SettingsError(
            f"training_speeds_rpm: no training run on machine {machine}: no run at {speeds} r/min "
            f"(+- {tolerance_rpm:g}, speed_tolerance_rpm) and no training window (runs.windows). "
            f"The logs hold {speeds_found(table, tolerance_rpm)}. Set training_speeds_rpm to the "
            "speeds the machine was trained at, or give training windows"
        )
    trained = training["speed_rpm"].astype(float).to_numpy()
    missing = [s for s in configured if not (np.abs(trained - s) <= tolerance_rpm + 1e-9).any()]
    if not missing:
        return []
    groups = speed_groups(trained, tolerance_rpm)
    at = ", ".join(f"{_rpm(s)} ({n})" for s, n in groups)
    if prior not in (None, "none"):
        advice_prior = (
            "; in a re-qualification from a prior (models.prior) these speeds are left to the prior, "
            "and the promotion waits for the prior_speeds confirmation (docs/models.md)"
        )
    else:
        advice_prior = ""
    if configured == [float(s) for s in MACHINE_DEFAULTS["training_speeds_rpm"]]:
        where = f"the default {speeds} r/min, the paper rig's: this machine sets none"
        own = ", ".join(_rpm(s) for s, _ in groups)
        advice = f"; if these are this machine's speeds, set training_speeds_rpm: [{own}]"
    else:
        where, advice = f"configured {speeds} r/min", ""
    return [
        f"training_speeds_rpm: no training run at {', '.join(_rpm(s) for s in missing)} r/min "
        f"({where}); the training runs are at {at} r/min (run counts in brackets); "
        f"the model is fitted at those speeds only{advice}{advice_prior}"
    ]


def continuous_log_warnings(table: pd.DataFrame, reference_rule: str) -> list[str]:
    """One warning per log segment that holds several runs (not ``excluded``) while the reference
    rule is ``run_start``: each run is then relative to its own start, inside a continuous log
    usually a warm machine, not the cold one; ``reference: {rule: log_start}`` is the cure."""
    if reference_rule != "run_start" or table.empty:
        return []
    kept = table[table["role"].astype(str) != "excluded"]
    out = []
    for (file, segment), runs in kept.groupby(["file", "segment"], sort=True):
        if len(runs) < 2:
            continue
        segment_text = f" (segment {segment})" if int(segment) else ""
        out.append(
            f"log {file}{segment_text} holds {len(runs)} runs of one continuous recording and "
            "reference.rule is run_start: each run's rises and "
            "displacement start from its own first samples, a warm machine for every run but the "
            "first. For runs inside one continuous log set `reference: {rule: log_start}` "
            f"({CONTINUOUS_LOG_DOCS}); a recording of `rafi plan`'s programme is read per run by "
            "design, leave it (docs/record.md)"
        )
    return out


def window_problems(windows, logs: Mapping[str, tuple[float, np.ndarray | None]], machine: str, all_logs=()):
    """The ``runs.windows`` entries that match nothing, one message each: a ``log`` glob that
    matches no log of the machine (``all_logs``: every file of the machine, quarantined ones
    included; ``logs`` if empty), and a window that lies outside every log it applies to.

    ``logs``: the usable logs, file name -> (span in s from first to last sample, clock per
    sample or None).
    """
    names = sorted(set(all_logs) | set(logs))
    problems = []
    for k, spec in enumerate(check_windows(windows)):
        key = f"runs.windows[{k}]"
        if "log" in spec and not any(applies_to(spec, name) for name in names):
            problems.append(
                f"{key}.log: {spec['log']!r} matches no log of machine {machine} (logs: {listed(names)})"
            )
            continue
        spans = {name: logs[name] for name in sorted(logs) if applies_to(spec, name)}
        inside, where = False, []
        for name, (span, times) in spans.items():
            a, b = window_interval(spec, k, name, span, times)
            inside |= a <= span + 1e-9 and b > 0
            where.append(f"{name}: 0-{span / 3600:.3g} h")
        if spans and not inside:
            problems.append(
                f"{key} ({describe_window(spec)}): lies outside every log it applies to "
                f"({listed(where, 4)}; start and end are {spec['unit']})"
            )
    return problems


def override_problems(
    overrides: Mapping | None, table: pd.DataFrame, machine: str, other_files=()
) -> list[str]:
    """The ``runs.overrides`` keys that name no run, log stem or file name of the machine (a key
    naming a file in ``other_files``, e.g. a quarantined one, or one of its runs, is accepted)."""
    names = set(table["run_id"].astype(str)) | set(table["file"].astype(str))
    names |= {_stem(f) for f in table["file"].astype(str)}
    others = {_stem(f) for f in other_files} | {str(f) for f in other_files}
    problems = []
    for key in overrides or {}:
        key = str(key)
        if key in names or key in others or key.split("#", 1)[0] in others:
            continue
        problems.append(
            f"runs.overrides: {key!r} names no run, log or file of machine {machine} "
            f"(runs: {listed(table['run_id'].astype(str))})"
        )
    return problems


def _stem(name: str) -> str:
    return name.rsplit(".", 1)[0] if "." in name else name


def speed_glob_problems(by_file: Mapping | None, files: Iterable[str], machine: str) -> list[str]:
    """The ``input.speed.constant_rpm_by_file`` globs that match no file name of the machine."""
    files = sorted(str(f) for f in files)
    return [
        f"input.speed.constant_rpm_by_file: {glob!r} matches no file of machine {machine} "
        f"(files: {listed(files)})"
        for glob in by_file or {}
        if not any(fnmatch.fnmatchcase(f, str(glob)) for f in files)
    ]


def check_runs(
    table: pd.DataFrame,
    logs: Mapping[str, tuple[float, np.ndarray | None]],
    *,
    machine: str,
    runs: Mapping,
    reference_rule: str,
    training_speeds_rpm: Sequence[float],
    speed_tolerance_rpm: float,
    all_files: Iterable[str] = (),
    speed_by_file: Mapping | None = None,
    prior: object = None,
) -> list[str]:
    """Every check of this module on one machine's runs; returns the warnings.

    Parameters
    ----------
    table : pandas.DataFrame
        ``runs.csv`` (:func:`rafi.method.runs.find_runs`).
    logs : mapping
        The usable logs: file name -> (span in s from first to last sample, clock per sample or None).
    machine : str
        Its name, for the messages.
    runs : mapping
        The machine's ``runs:`` settings (``windows``, ``overrides``).
    reference_rule : str
        ``reference.rule``.
    training_speeds_rpm, speed_tolerance_rpm
        The machine's settings.
    all_files : iterable of str
        Every raw file name of the machine, quarantined ones included.
    speed_by_file : mapping, optional
        ``input.speed.constant_rpm_by_file``.
    prior : optional
        ``models.prior`` (None or ``none``: never a prior): :func:`training_speed_problems`.

    Raises
    ------
    SettingsError
        An entry that matches nothing (every one, on one line), or no training run.
    """
    all_files = sorted(set(all_files) | set(logs))
    others = sorted(set(all_files) - set(logs))
    problems = window_problems(runs.get("windows"), logs, machine, all_files)
    problems += override_problems(runs.get("overrides"), table, machine, others)
    problems += speed_glob_problems(speed_by_file, all_files, machine)
    if problems:
        raise SettingsError("; ".join(problems))
    warnings = training_speed_problems(table, training_speeds_rpm, speed_tolerance_rpm, machine, prior=prior)
    return warnings + continuous_log_warnings(table, reference_rule)


def log_spans(frames: Mapping[str, pd.DataFrame]) -> dict[str, tuple[float, np.ndarray | None]]:
    """File name -> (span in s from first to last sample, clock per sample or None) of clean frames
    (columns ``t_s`` or ``time``), as :func:`check_runs` takes them."""
    out = {}
    for name, frame in frames.items():
        if len(frame) == 0:
            continue
        if "t_s" in frame:
            t_s = frame["t_s"].to_numpy(dtype=float)
        else:
            t = pd.to_datetime(frame["time"])
            t_s = (t - t.iloc[0]).dt.total_seconds().to_numpy()
        times = frame["time"].to_numpy(dtype="datetime64[ns]") if "time" in frame else None
        out[str(name)] = (float(t_s[-1] - t_s[0]), times)
    return out
