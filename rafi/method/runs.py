"""Cutting clean logs into runs, giving each a role and a reference state.

:func:`find_runs` works on each file and each ``segment`` of it separately (a run
never spans a gap). Within a segment:

0. The speed is smoothed by a centred rolling median of ``SPEED_SMOOTH_S``
   (60 s, at least 3 samples) for the cutting only (steps stay sharp; speed
   noise and single ramp samples go); run statistics use the logged speed.
1. **Idle** samples: ``speed_rpm < idle_below_rpm`` (or unknown speed).
2. **Pieces** of the non-idle stretches: a piece continues while the speed stays
   within ``speed_tolerance_rpm`` of the speed at its first sample; adjacent
   pieces whose medians differ by at most the tolerance are merged again (speed
   noise does not fragment a constant stretch).
3. A non-idle piece lasting at least ``min_constant_s`` is **constant**;
   consecutive shorter non-idle pieces form a varying stretch.
4. **Ramp samples**: a varying stretch of at most ``RAMP_MAX_SAMPLES`` samples
   next to a constant piece (the spindle ramping up or down between two log
   samples) is absorbed into that constant run (the following one when the
   stretch precedes a constant piece, else the preceding one).
5. Varying stretches separated only by an idle piece shorter than
   ``min_constant_s`` (a stop inside a multi-condition schedule) are merged,
   idle piece included, into one **varying** run. So one cold-start log with
   several short speed steps is ONE varying run.
6. **Rest before start**: an idle piece at the very start of a segment that is shorter
   than ``max_leading_rest_s`` (default 300 s) and followed by a non-idle run is absorbed
   into that run as its rest before start (a cold-start log: the logger is started with
   the machine at rest, then the spindle). A one-run file stays one run (``run_id`` = the
   stem), ``t_s`` of the run starts at the log (segment) start, and the reference window
   falls on the rest: the reference state is the machine at rest, which is also what
   a compensation on the controller is relative to; ``note`` calls it the cold machine at rest
   only where the temperatures show it (:func:`cold_starts`: a machine that rested only an
   hour or two after work is still warm). The kind (constant / varying) and the
   speed statistics (``speed_rpm``, ``speed_min_rpm``, ``speed_max_rpm``) ignore the rest;
   ``duration_s`` counts every sample of the run, rest included; ``note`` states the rest.
   A longer leading idle piece stays an idle run of its own.
7. Every other idle piece is an **idle** run.

Roles: ``excluded`` when shorter than ``min_run_s`` (reason in ``note``);
constant within ``speed_tolerance_rpm`` of a training speed -> ``training``;
other constant -> ``validation_single``; varying -> ``validation_multi``; idle ->
``validation_idle``, and ``training`` when it lies in the training schedule
(``idle_training = 'schedule'``, :func:`rafi.method.windows.schedule_cooldowns`).
``overrides`` (keyed by run_id, else file stem) set the role with ``role_source = 'config'``.

Durations count samples: ``duration_s = n_samples * period``; ``start_s`` and
``end_s`` are the ``t_s`` (seconds since the first sample of the file) of the
first and last sample of the run.

Reference state: ``dT_i = T_i - T_i,ref`` and ``dz_um = disp_um - disp_ref`` with
the reference = median (NaN ignored) over the first ``reference_window_s`` of the
run (``run_start``) or of the segment the run came from (``log_start``); at
least one sample is always used. A sensor without a valid value in the window
gets NaN rises for that run (stated in ``note``); NaN values left by cleaning stay
NaN in the rises, and later steps drop them.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd

from rafi.contract.sensors import (  # noqa: F401 (runs_frame_columns: this module's API)
    DEFAULT_SENSORS,
    common_sensors,
    frame_sensors,
    runs_frame_columns,
)
from rafi.method.windows import (
    IDLE_TRAINING,
    VALIDATION_BY_KIND,
    check_windows,
    cut_points,
    leak_check,
    resolve_windows,
    schedule_cooldowns,
    window_of,
)
from rafi.settings import MACHINE_DEFAULTS

#: Roles a run can have (``docs/design.md``).
ROLES = ("training", "validation_single", "validation_multi", "validation_idle", "excluded")

#: Columns of ``runs.csv``, in order.
RUNS_TABLE_COLUMNS = (
    "run_id",
    "file",
    "segment",
    "start_s",
    "end_s",
    "duration_s",
    "speed_rpm",
    "speed_min_rpm",
    "speed_max_rpm",
    "kind",
    "role",
    "role_source",
    "reference",
    "sha256",
    "note",
    "role_reason",
    "start_time",
    "end_time",
)


#: :func:`runs_frame_columns` of the paper's rig.
RUNS_FRAME_COLUMNS = runs_frame_columns()

#: File-name suffixes removed from the keys of ``clean_frames`` to get the stem.
LOG_SUFFIXES = (".csv", ".xlsx", ".xls", ".txt", ".parquet", ".tsv")

REFERENCE_RULES = ("run_start", "log_start")

#: Width (s) of the centred rolling median applied to the speed before cutting it into
#: pieces (at least 3 samples): removes speed noise and isolated ramp samples, keeps steps sharp.
SPEED_SMOOTH_S = 60.0

#: A varying stretch of at most this many samples next to a constant run is a ramp.
RAMP_MAX_SAMPLES = 3

#: What the note of a run with a rest before start calls its reference state: the machine at rest,
#: and a cold machine at rest only where the temperatures show it (:func:`cold_starts`).
AT_REST = "machine at rest"
COLD_AT_REST = "cold machine at rest"
#: A start from rest is cold when its reference temperatures lie as close to the machine's
#: at-rest pattern as its usual start does: their distance from it (K, root mean square over the
#: sensors) at most this many times the median distance of the machine's starts from rest, or
#: :data:`COLD_FLOOR_K` (:func:`cold_starts`).
COLD_DISTANCE_FACTOR = 2.0
#: The distance (K) below which a start from rest is always cold: sensors that read the same to the
#: logger's resolution every morning leave a median distance near 0.
COLD_FLOOR_K = 0.05
#: Fewest runs starting from rest that give the machine an at-rest pattern, and fewest sensors
#: with a reference value that give a run one.
MIN_COLD_RUNS = 3
MIN_COLD_SENSORS = 3


class RunSpan(NamedTuple):
    """One run of a log: rows ``start:end`` of the segment ``seg_start:seg_end`` (row indices of
    the log), its kind and the number of rest samples it absorbed at its start."""

    segment: int
    seg_start: int
    seg_end: int
    start: int
    end: int
    kind: str
    rest: int


def _stem(key: str) -> str:
    p = Path(str(key))
    return p.stem if p.suffix.lower() in LOG_SUFFIXES else p.name


def find_runs(
    clean_frames: dict,
    sha256: dict,
    *,
    training_speeds_rpm,
    speed_tolerance_rpm: float,
    idle_below_rpm: float,
    min_run_s: float,
    min_constant_s: float,
    overrides,
    reference_rule: str,
    reference_window_s: float,
    max_leading_rest_s: float = MACHINE_DEFAULTS["runs"]["max_leading_rest_s"],
    windows=MACHINE_DEFAULTS["runs"]["windows"],
    idle_training: bool | str = MACHINE_DEFAULTS["runs"]["idle_training"],
    allow_training_after_validation: bool = MACHINE_DEFAULTS["runs"]["allow_training_after_validation"],
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Find the runs of a machine's clean logs, classify them and compute the rises.

    Parameters
    ----------
    clean_frames : dict of str -> pandas.DataFrame
        File stem (a file name such as ``x.csv`` is accepted too; the stem is then
        the name without its suffix) -> clean frame of :func:`rafi.method.clean.clean_log`
        (``time``, ``t_s``, ``speed_rpm``, the machine's sensors, ``disp_um``,
        ``segment``). Files are processed in sorted key order; every frame has the same sensors.
    sha256 : dict of str -> str
        Same keys -> SHA-256 of the raw file (missing keys give an empty text).
    training_speeds_rpm : sequence of float
        Speeds the model is trained at.
    speed_tolerance_rpm : float
        Tolerance both for "constant" speed and for matching a training speed.
    idle_below_rpm : float
        Speeds below this are idle.
    min_run_s : float
        Runs shorter than this are ``excluded``.
    min_constant_s : float
        A constant-speed piece shorter than this is part of a varying run.
    overrides : dict of str -> str or None
        Run id or file stem -> role (one of ``ROLES``); run id wins over stem.
    reference_rule : {'run_start', 'log_start'}
        Where the reference state is taken.
    reference_window_s : float
        Length of the reference window, seconds.
    max_leading_rest_s : float
        An idle stretch at the start of a segment shorter than this (s) is the rest before
        the start of the following run and is absorbed into it (``0``: never).
    windows : sequence of mapping
        ``runs: windows:``, roles by time (:mod:`rafi.method.windows`); runs are cut where a
        window starts or ends. A run in a window gets the window's role (``role_source =
        'window'``); run-id overrides still win.
    idle_training : {False, 'schedule', True}
        Which idle runs (cool-downs) are ``training`` runs (the family's models learn the
        cool-down; RAFI as published ignores idle training runs). ``True``: every one in a
        training window, and every automatic one before validation data of its log (the leak
        guard). ``'schedule'``: every one in a training window, and the automatic ones in the
        training schedule (:func:`rafi.method.windows.schedule_cooldowns`). ``False``: none
        (idle runs in a training window are ``excluded``).
    allow_training_after_validation : bool
        Accept configured training data after validation data of the same log (the leak guard,
        :func:`rafi.method.windows.leak_check`, otherwise refuses it).

    Returns
    -------
    runs_table : pandas.DataFrame
        One row per run, columns ``RUNS_TABLE_COLUMNS`` (``docs/design.md`` plus
        ``note``). ``run_id`` is the stem when the file gives one run, else
        ``f"{stem}#{k}"`` with ``k = 1, 2, ...`` in time order.
    runs_frame : pandas.DataFrame
        All runs stacked (RangeIndex), columns :func:`runs_frame_columns` of the frames'
        sensors; ``t_s`` is
        seconds since the start of the run (for a run with an absorbed rest: since the
        start of the rest, i.e. of the log segment).

    Raises
    ------
    ValueError
        On an unknown ``reference_rule`` or an override with an unknown role.
    rafi.errors.SettingsError
        A bad or overlapping window, or configured training data after validation data of the
        same log (unless ``allow_training_after_validation``).
    """
    rules = run_rules(
        training_speeds_rpm=training_speeds_rpm,
        speed_tolerance_rpm=speed_tolerance_rpm,
        idle_below_rpm=idle_below_rpm,
        min_run_s=min_run_s,
        min_constant_s=min_constant_s,
        overrides=overrides,
        reference_rule=reference_rule,
        reference_window_s=reference_window_s,
        max_leading_rest_s=max_leading_rest_s,
        windows=windows,
        idle_training=idle_training,
        allow_training_after_validation=allow_training_after_validation,
    )
    sensors = common_sensors(clean_frames)
    rows: list[dict] = []
    samples: list[dict] = []
    rests: dict = {}
    for key in sorted(clean_frames):
        if len(clean_frames[key]) == 0:
            continue
        log_rows, log_samples, log_rests = log_runs(key, log_arrays(clean_frames[key]), sha256, rules)
        rows += log_rows
        samples += log_samples
        rests.update(log_rests)
    rows = _said_cold(rows, cold_starts(rests))
    return runs_table(rows), stack_runs(samples, sensors)


@dataclass(frozen=True)
class RunRules:
    """The settings of :func:`find_runs`, checked and as the steps use them (see its parameters)."""

    training_speeds_rpm: np.ndarray  # sorted
    speed_tolerance_rpm: float
    idle_below_rpm: float
    min_run_s: float
    min_constant_s: float
    overrides: dict
    reference_rule: str
    reference_window_s: float
    max_leading_rest_s: float
    windows: list
    idle_training: bool | str
    allow_training_after_validation: bool


def run_rules(
    *,
    training_speeds_rpm,
    speed_tolerance_rpm,
    idle_below_rpm,
    min_run_s,
    min_constant_s,
    overrides,
    reference_rule,
    reference_window_s,
    max_leading_rest_s,
    windows,
    idle_training,
    allow_training_after_validation,
) -> RunRules:
    """The :class:`RunRules` of :func:`find_runs`' keyword arguments.

    Raises
    ------
    ValueError
        An unknown ``reference_rule`` or ``idle_training``, or an override with an unknown role.
    rafi.errors.SettingsError
        A bad window (:func:`rafi.method.windows.check_windows`).
    """
    if not any(idle_training is v if isinstance(v, bool) else idle_training == v for v in IDLE_TRAINING):
        raise ValueError(f"idle_training is {idle_training!r}; expected false, 'schedule' or true")
    if reference_rule not in REFERENCE_RULES:
        raise ValueError(
            f"reference_rule is {reference_rule!r}; expected one of {', '.join(REFERENCE_RULES)}"
        )
    overrides = dict(overrides or {})
    for key, role in overrides.items():
        if role not in ROLES:
            raise ValueError(f"override {key!r}: role {role!r} is not one of {', '.join(ROLES)}")
    return RunRules(
        training_speeds_rpm=np.asarray(sorted(float(s) for s in (training_speeds_rpm or [])), dtype=float),
        speed_tolerance_rpm=float(speed_tolerance_rpm),
        idle_below_rpm=float(idle_below_rpm),
        min_run_s=float(min_run_s),
        min_constant_s=float(min_constant_s),
        overrides=overrides,
        reference_rule=reference_rule,
        reference_window_s=float(reference_window_s),
        max_leading_rest_s=float(max_leading_rest_s),
        windows=check_windows(windows),
        idle_training=idle_training,
        allow_training_after_validation=allow_training_after_validation,
    )


@dataclass(frozen=True)
class LogArrays:
    """One clean log as arrays (rows in time order): seconds since its first sample, segment,
    speed, temperatures (rows x ``sensors``), displacement, clock (``NaT`` without one), the
    sample period and the sensors' names."""

    t_s: np.ndarray
    segment: np.ndarray
    speed: np.ndarray
    temps: np.ndarray
    disp: np.ndarray
    times: np.ndarray
    period: float
    sensors: tuple[str, ...] = DEFAULT_SENSORS


def log_arrays(frame: pd.DataFrame) -> LogArrays:
    """The :class:`LogArrays` of a clean frame (``t_s`` from ``time`` and one segment where the
    frame has no such column); no clock (``NaT``) where the reader marked the log as having none
    (``attrs['metadata']['clock']`` False: elapsed seconds without ``input.time.start``)."""
    n_rows = len(frame)
    if "t_s" in frame:
        t_s = frame["t_s"].to_numpy(dtype=float)
    else:
        time = pd.to_datetime(frame["time"])
        t_s = (time - time.iloc[0]).dt.total_seconds().to_numpy()
    seg = frame["segment"].to_numpy(dtype="int64") if "segment" in frame else np.zeros(n_rows, "int64")
    sensors = frame_sensors(frame)
    temps = np.column_stack([frame[s].to_numpy(dtype=float, na_value=np.nan) for s in sensors])
    meta = frame.attrs.get("metadata")
    clock = "time" in frame and not (isinstance(meta, dict) and meta.get("clock") is False)
    times = (
        frame["time"].to_numpy(dtype="datetime64[ns]")
        if clock
        else np.full(n_rows, np.datetime64("NaT"), dtype="datetime64[ns]")
    )
    return LogArrays(
        t_s=t_s,
        segment=seg,
        speed=frame["speed_rpm"].to_numpy(dtype=float, na_value=np.nan),
        temps=temps,
        disp=frame["disp_um"].to_numpy(dtype=float, na_value=np.nan),
        times=times,
        period=sample_period(t_s, seg),
        sensors=sensors,
    )


def log_runs(key, log: LogArrays, sha256: dict, rules: RunRules) -> tuple[list[dict], list[dict], dict]:
    """The runs of one log (``key``: its key in ``clean_frames``): their rows of the runs table
    (after the leak guard), their samples (:func:`run_samples`) and, per run with a rest before
    start, its reference temperatures by sensor (for :func:`cold_starts`).

    The log is cut into runs (:func:`split_log`), then at its window
    boundaries; each run gets its role (:func:`assign_role`) and reference state
    (:func:`reference_state`).
    """
    name, stem = str(key), _stem(key)
    log_windows = resolve_windows(rules.windows, name, log.t_s, log.times)
    spans = split_log(
        log.speed,
        log.segment,
        log.period,
        tol=rules.speed_tolerance_rpm,
        idle_below=rules.idle_below_rpm,
        min_constant_s=rules.min_constant_s,
        max_leading_rest_s=rules.max_leading_rest_s,
    )
    spans = cut_at(spans, cut_points(log_windows, log.t_s))
    rows, samples, rests = [], [], {}
    for k, span in enumerate(spans, start=1):
        run_id = stem if len(spans) == 1 else f"{stem}#{k}"
        speed_rpm, speed_min, speed_max = speed_statistics(log.speed[span.start + span.rest : span.end])
        duration = (span.end - span.start) * log.period
        window = window_of(log_windows, float(log.t_s[span.start]))
        role, source, reason = assign_role(
            span.kind, speed_rpm, duration, window, (run_id, stem, name), rules
        )
        reference = reference_state(log, span, rules)
        notes = []
        if span.rest:
            notes.append(
                f"rest before start: {span.rest * log.period:g} s at rest absorbed (reference "
                f"state = {AT_REST})"
            )
            rests[run_id] = pd.Series(reference.temps, index=list(log.sensors))
        if reference.missing:
            notes.append(f"no valid reference value for {', '.join(reference.missing)}: rises are NaN")
        rows.append(
            {
                "run_id": run_id,
                "file": name,
                "segment": span.segment,
                "start_s": float(log.t_s[span.start]),
                "end_s": float(log.t_s[span.end - 1]),
                "duration_s": float(duration),
                "speed_rpm": speed_rpm,
                "speed_min_rpm": speed_min,
                "speed_max_rpm": speed_max,
                "kind": span.kind,
                "role": role,
                "role_source": source,
                "reference": reference.text,
                "sha256": str(sha256.get(key, sha256.get(stem, ""))),
                "note": "; ".join(notes),
                "role_reason": reason,
                "start_time": _iso(log.times[span.start]),
                "end_time": _iso(log.times[span.end - 1]),
            }
        )
        samples.append(run_samples(log, span, reference, run_id=run_id, key=name))
    return _guard_log(rows, rules), samples, rests


def cold_starts(
    rest_temps: dict,
    factor: float = COLD_DISTANCE_FACTOR,
    floor_k: float = COLD_FLOOR_K,
    min_runs: int = MIN_COLD_RUNS,
    min_sensors: int = MIN_COLD_SENSORS,
) -> set:
    """The runs starting from rest whose reference temperatures show a cold machine.

    A machine that stood long enough is at the room's temperature throughout: every sensor reads
    the room plus its own fixed offset (where it sits, its mounting), the same pattern on every
    such morning whatever the room's level that day. A machine that rested only an hour or two
    after work is still warm in its heavy parts and cooler in its fast ones: its sensors leave
    that pattern. So each run's reference temperatures are taken less their mean over the run's
    sensors (the room's level out); the machine's at-rest pattern is the median of that over its
    runs from rest; a run's distance from it is the root mean square over its sensors; and a run
    is cold when that distance is at most ``factor`` times the median distance of those runs (the
    scatter a cold start shows: noise, the logger's resolution), or at most ``floor_k``. The
    absolute level says nothing here: rooms differ by kelvins from day to day, a warm start by
    tenths between the sensors. On the generated foreign machines a start 1-3 h after the day
    before lies 2-18 times the median distance away, a cold start at most 1.5 times; after 4 h
    and more a start is cold by this rule, and by the temperatures too.

    The pattern is that of the machine's usual start: most starts from rest must be cold (a
    qualification's days start after a night). Without ``min_runs`` runs from rest there is no
    pattern, and a run with fewer than ``min_sensors`` reference values has none of its own:
    nothing is shown cold, and the note says the machine at rest.

    Parameters
    ----------
    rest_temps : dict
        Run id -> its reference temperatures (``pandas.Series`` by sensor; NaN: no value), of the
        runs with a rest before start.
    factor, floor_k : float
        How far (times the median distance, or K) a cold start may lie from the pattern.
    min_runs, min_sensors : int
        See above.

    Returns
    -------
    set of str
        The run ids shown cold.
    """
    if len(rest_temps) < min_runs:
        return set()
    table = pd.DataFrame(rest_temps).T.astype(float)
    pattern = table.sub(table.mean(axis=1), axis=0)
    off = pattern.sub(pattern.median(axis=0), axis=1)
    distance = np.sqrt((off**2).mean(axis=1, skipna=True))
    limit = max(factor * float(distance.median()), floor_k)
    cold = (table.notna().sum(axis=1) >= min_sensors) & (distance <= limit)
    return {str(run_id) for run_id in table.index[cold.to_numpy()]}


def _said_cold(rows: list[dict], cold: set) -> list[dict]:
    """``rows`` with the reference state of the runs in ``cold`` said as the cold machine at rest."""
    rest, said = f"(reference state = {AT_REST})", f"(reference state = {COLD_AT_REST})"
    return [
        {**row, "note": str(row["note"]).replace(rest, said)} if row["run_id"] in cold else row
        for row in rows
    ]


def speed_statistics(speed: np.ndarray) -> tuple[float, float, float]:
    """Median, minimum and maximum of a run's speed, NaN ignored (all NaN without a valid one)."""
    if not np.isfinite(speed).any():
        return float("nan"), float("nan"), float("nan")
    return float(np.nanmedian(speed)), float(np.nanmin(speed)), float(np.nanmax(speed))


def assign_role(kind: str, speed_rpm: float, duration_s: float, window, names, rules: RunRules):
    """The role cascade of one run: ``(role, role_source, role_reason)``.

    In order, each later rule winning: the automatic role (:func:`_auto_role`); an idle
    cool-down trains with ``idle_training`` true (with ``'schedule'`` it is decided later, by
    :func:`rafi.method.windows.schedule_cooldowns`); a window holding the run (``window``, or None)
    sets the role (:func:`_window_role`); an override for the first of ``names`` (run id, file
    stem, file name) found in ``rules.overrides`` sets it last (``role_source = 'config'``).
    """
    role, reason = _auto_role(kind, speed_rpm, duration_s, rules)
    if role == "validation_idle" and rules.idle_training is True:
        role, reason = "training", reason + "; idle cool-down used for training (runs.idle_training)"
    source = "auto"
    if window is not None:
        what = f"constant at {speed_rpm:.0f} r/min" if kind == "constant" else kind
        role, source, reason = _window_role(
            window, what, kind, duration_s, rules.min_run_s, rules.idle_training
        )
    for name in names:
        if name in rules.overrides:
            reason = f"run-id override {name!r} in runs.overrides (otherwise: {role}, {reason})"
            return rules.overrides[name], "config", reason
    return role, source, reason


class Reference(NamedTuple):
    """The reference state of a run: temperatures (per sensor of the log), displacement, the rule in
    words, and the columns without a valid reference value (their rises are NaN)."""

    temps: np.ndarray
    disp_um: float
    text: str
    missing: list


def reference_state(log: LogArrays, span: RunSpan, rules: RunRules) -> Reference:
    """The median (NaN ignored) of the first ``reference_window_s`` of the run (``run_start``) or
    of its segment (``log_start``); at least one sample."""
    window = rules.reference_window_s
    if rules.reference_rule == "run_start":
        r0, r_end = span.start, span.end
        text = f"median of the first {window:g} s of the run (run_start)"
    else:
        r0, r_end = span.seg_start, span.seg_end
        text = f"median of the first {window:g} s of segment {span.segment} of the log (log_start)"
    t_s = log.t_s
    r1 = r0 + max(1, int(np.searchsorted(t_s[r0:r_end], t_s[r0] + window - 1e-9, side="left")))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN window -> NaN
        temps = np.nanmedian(log.temps[r0:r1], axis=0)
        disp = float(np.nanmedian(log.disp[r0:r1]))
    missing = [s for s, value in zip(log.sensors, temps) if np.isnan(value)]
    if np.isnan(disp):
        missing.append("disp_um")
    return Reference(temps, disp, text, missing)


def run_samples(log: LogArrays, span: RunSpan, reference: Reference, *, run_id: str, key: str) -> dict:
    """The samples of one run: ``run_id``, ``log`` and the row count, and the run's slice of
    every other column of ``runs.parquet`` (rises relative to ``reference``)."""
    a, b = span.start, span.end
    columns = {
        "t_s": log.t_s[a:b] - log.t_s[a],
        "time": log.times[a:b],
        "speed_rpm": log.speed[a:b],
    }
    for i, s in enumerate(log.sensors):
        columns[s] = log.temps[a:b, i]
        columns[f"d{s}"] = log.temps[a:b, i] - reference.temps[i]
    columns["disp_um"] = log.disp[a:b]
    columns["dz_um"] = log.disp[a:b] - reference.disp_um
    columns["log_t_s"] = log.t_s[a:b]
    columns["segment"] = log.segment[a:b]
    return {"run_id": run_id, "log": key, "n": b - a, "columns": columns}


def runs_table(rows: list[dict]) -> pd.DataFrame:
    """``runs.csv``: the rows of every run, columns ``RUNS_TABLE_COLUMNS`` with their dtypes."""
    table = pd.DataFrame(rows, columns=list(RUNS_TABLE_COLUMNS))
    return table.astype(
        {
            "segment": "int64",
            "start_s": "float64",
            "end_s": "float64",
            "duration_s": "float64",
            "speed_rpm": "float64",
            "speed_min_rpm": "float64",
            "speed_max_rpm": "float64",
        }
    )


def stack_runs(samples: list[dict], sensors=DEFAULT_SENSORS) -> pd.DataFrame:
    """``runs.parquet``: the samples of every run (:func:`run_samples`) stacked, columns
    :func:`runs_frame_columns` of ``sensors`` (``run_id`` text, ``segment`` int64; typed when
    empty)."""
    columns = runs_frame_columns(sensors)
    counts = [run["n"] for run in samples]
    data = {
        "run_id": pd.Categorical.from_codes(
            np.repeat(np.arange(len(samples)), counts), categories=[run["run_id"] for run in samples]
        ).astype("str")
        if samples
        else pd.array([], dtype="str"),
        "log": np.repeat(np.array([run["log"] for run in samples], dtype=object), counts)
        if samples
        else np.array([], dtype=object),
    }
    for c in columns:
        if c in data:
            continue
        if samples:
            data[c] = np.concatenate([run["columns"][c] for run in samples])
        else:
            data[c] = np.array([], dtype="datetime64[ns]" if c == "time" else float)
    frame = pd.DataFrame(data, columns=list(columns))
    frame["segment"] = frame["segment"].astype("int64")
    return frame


def _iso(value) -> str:
    return "" if pd.isna(value) else pd.Timestamp(value).isoformat()


def _auto_role(kind: str, speed: float, duration: float, rules: RunRules) -> tuple[str, str]:
    """The automatic role of a run and why, in words."""
    train, tol, min_run_s = rules.training_speeds_rpm, rules.speed_tolerance_rpm, rules.min_run_s
    if duration < min_run_s - 1e-9:
        return "excluded", f"shorter than runs.min_run_s ({duration:g} s < {min_run_s:g} s)"
    if kind == "constant":
        if len(train) and np.min(np.abs(train - speed)) <= tol + 1e-9:
            return "training", f"constant at {speed:.0f} r/min, a training speed"
        return "validation_single", f"constant at {speed:.0f} r/min, not a training speed"
    if kind == "varying":
        return "validation_multi", "varying speed (steps shorter than runs.min_constant_s)"
    return "validation_idle", f"idle (spindle below {rules.idle_below_rpm:g} r/min): a cool-down"


def _window_role(win, what, kind, duration, min_run_s, idle_training) -> tuple[str, str, str]:
    """Role, source and reason of a run of ``kind`` (``what``: the kind for people) inside the
    window ``win``."""
    if win.role == "excluded":
        return "excluded", "window", f"in the {win.text}"
    if duration < min_run_s - 1e-9:
        return (
            "excluded",
            "window",
            f"in the {win.text} but shorter than runs.min_run_s ({duration:g} s < {min_run_s:g} s)",
        )
    if win.role == "validation":
        return VALIDATION_BY_KIND[kind], "window", f"in the {win.text} ({what})"
    if kind == "idle" and idle_training is False:
        return "excluded", "window", f"idle, in the {win.text}, and runs.idle_training is false"
    return "training", "window", f"in the {win.text} ({what})"


def _guard_log(rows: list[dict], rules: RunRules) -> list[dict]:
    """The runs of one log after the leak guard (:func:`rafi.method.windows.leak_check`), then with
    the cool-downs of the training schedule as training runs (``idle_training = 'schedule'``)."""
    if not rows:
        return rows
    table = leak_check(pd.DataFrame(rows), allow=rules.allow_training_after_validation)
    if rules.idle_training == "schedule":
        table = schedule_cooldowns(table)
    return table.to_dict("records")


# --------------------------------------------------------------------------- cutting by speed
#
# :func:`split_log` cuts every segment of a log with :func:`segment_runs` (smoothed speed ->
# idle samples -> pieces of near-constant speed (:func:`speed_pieces`) -> constant and varying
# stretches, ramps absorbed, stops inside a schedule merged, a short rest at the start absorbed:
# steps 0-7 of the module docstring); :func:`cut_at` cuts the runs again at the boundaries of
# time windows. Runs are :class:`RunSpan`: row indices of the log, never crossing a segment.


def sample_period(t_s: np.ndarray, seg: np.ndarray) -> float:
    """The median time step inside segments (1 s without one)."""
    if len(t_s) < 2:
        return 1.0
    d = np.diff(t_s)[seg[1:] == seg[:-1]]
    d = d[d > 0]
    return float(np.median(d)) if len(d) else 1.0


def speed_pieces(speed: np.ndarray, idle: np.ndarray, tol: float) -> list[list]:
    """Pieces ``[start, end_exclusive, is_idle]`` of one segment, in time order.

    Idle stretches (``idle``) are one piece each; a non-idle piece continues while the speed
    stays within ``tol`` of the speed at its first sample, and adjacent non-idle pieces whose
    medians differ by at most ``tol`` are merged again (speed noise around one set point).
    """
    n = len(speed)
    pieces: list[list] = []
    change = np.flatnonzero(np.diff(idle.astype(np.int8))) + 1
    bounds = np.concatenate(([0], change, [n]))
    for a, b in zip(bounds[:-1], bounds[1:]):
        if idle[a]:
            pieces.append([a, b, True])
            continue
        i = a
        while i < b:
            anchor = speed[i]
            j, w = i + 1, 64
            end = b
            while j < b:
                stop = min(b, j + w)
                out = np.abs(speed[j:stop] - anchor) > tol
                if out.any():
                    end = j + int(np.argmax(out))
                    break
                j, w = stop, w * 2
            pieces.append([i, end, False])
            i = end
    # merge adjacent non-idle pieces whose medians agree (speed noise around one set point)
    merged: list[list] = []
    for p in pieces:
        if merged and not p[2] and not merged[-1][2] and merged[-1][1] == p[0]:
            q = merged[-1]
            if abs(np.median(speed[q[0] : q[1]]) - np.median(speed[p[0] : p[1]])) <= tol:
                q[1] = p[1]
                continue
        merged.append(list(p))
    return merged


def segment_runs(
    speed: np.ndarray,
    period: float,
    *,
    tol: float,
    idle_below: float,
    min_constant_s: float,
    max_leading_rest_s: float = 0.0,
) -> list[tuple[int, int, str, int]]:
    """Runs ``(start, end_exclusive, kind, rest_samples)`` of one segment, in time order.

    ``rest_samples`` > 0 for a run that absorbed the segment's leading rest (its first
    ``rest_samples`` samples are the rest, idle).
    """
    win = max(3, 2 * int(round(SPEED_SMOOTH_S / 2 / period)) + 1)
    smooth = pd.Series(speed).rolling(win, center=True, min_periods=1).median().to_numpy()
    idle = ~(smooth >= idle_below)  # NaN speed counts as idle
    pieces = speed_pieces(smooth, idle, tol)
    min_const_n = min_constant_s / period
    groups: list[list] = []  # [start, end_exclusive, kind]
    for a, b, is_idle in pieces:
        kind = "idle" if is_idle else ("constant" if (b - a) >= min_const_n - 1e-9 else "varying")
        if kind == "varying" and groups and groups[-1][2] == "varying" and groups[-1][1] == a:
            groups[-1][1] = b  # consecutive short pieces: one stretch
        else:
            groups.append([a, b, kind])
    # ramps: a tiny varying stretch next to a constant run is absorbed by it
    kept: list[list] = []
    for k, g in enumerate(groups):
        if g[2] == "varying" and g[1] - g[0] <= RAMP_MAX_SAMPLES:
            nxt = groups[k + 1] if k + 1 < len(groups) else None
            if nxt is not None and nxt[2] == "constant" and nxt[0] == g[1]:
                nxt[0] = g[0]
                continue
            if kept and kept[-1][2] == "constant" and kept[-1][1] == g[0]:
                kept[-1][1] = g[1]
                continue
        kept.append(g)
    # a short idle stretch between two varying stretches is a stop inside the schedule
    out: list[list] = []
    for g in kept:
        if out and g[2] == "varying" and out[-1][2] == "varying":
            out[-1][1] = g[1]
            continue
        if (
            len(out) >= 2
            and g[2] == "varying"
            and out[-1][2] == "idle"
            and out[-2][2] == "varying"
            and (out[-1][1] - out[-1][0]) < min_const_n
        ):
            out.pop()
            out[-1][1] = g[1]
            continue
        out.append(g)
    rest = [0] * len(out)
    # a short rest at the segment start belongs to the following run (cold start from rest)
    if (
        len(out) >= 2
        and out[0][2] == "idle"
        and out[1][2] != "idle"
        and out[0][0] == 0
        and (out[0][1] - out[0][0]) * period < float(max_leading_rest_s) - 1e-9
    ):
        n_rest = out[0][1] - out[0][0]
        out[1][0] = out[0][0]
        out.pop(0)
        rest = [n_rest] + [0] * (len(out) - 1)
    return [(int(a), int(b), kind, int(r)) for (a, b, kind), r in zip(out, rest)]


def split_log(
    speed: np.ndarray,
    segment: np.ndarray,
    period: float,
    *,
    tol: float,
    idle_below: float,
    min_constant_s: float,
    max_leading_rest_s: float,
) -> list[RunSpan]:
    """The runs of every segment of a log (:func:`segment_runs` on each), in time order.

    ``speed`` and ``segment`` are the log's speed and segment per sample; ``period`` its
    sample period. Returns row indices of the log.
    """
    spans = []
    change = np.flatnonzero(segment[1:] != segment[:-1]) + 1
    for s0, s1 in zip(np.concatenate(([0], change)), np.concatenate((change, [len(segment)]))):
        for a, b, kind, rest in segment_runs(
            speed[s0:s1],
            period,
            tol=tol,
            idle_below=idle_below,
            min_constant_s=min_constant_s,
            max_leading_rest_s=max_leading_rest_s,
        ):
            spans.append(
                RunSpan(int(segment[s0]), int(s0), int(s1), int(s0 + a), int(s0 + b), kind, int(rest))
            )
    return spans


def cut_at(found: list[RunSpan], cuts: np.ndarray) -> list[RunSpan]:
    """``found`` runs split at the sample indices ``cuts`` (window boundaries)."""
    out = []
    for segment, s0, s1, a, b, kind, rest in found:
        inner = [int(c) for c in cuts if a < c < b]
        for x, y in zip([a, *inner], [*inner, b]):
            out.append(RunSpan(segment, s0, s1, x, y, kind, min(rest, y - x) if x == a else 0))
    return out
