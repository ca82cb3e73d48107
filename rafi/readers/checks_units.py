"""Unit and metadata checks: deg F / K temperatures, rev/s speeds, speeds beyond training, mm / nm
displacement, metadata naming another machine or another sample period.

Each function takes the :class:`~rafi.readers.checks_base.Signals` of a frame and a
:class:`~rafi.readers.checks_base.Where`; it raises the check's error (certain) or returns its
warnings (suspicious). Thresholds are module constants, documented in docs/raw-format.md
("Checks").
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rafi.readers.checks_base import (
    CheckWarning,
    Signals,
    Where,
    fmt,
    present,
    robust_range,
    start_level,
    whole_log_warning,
)
from rafi.readers.checks_jumps import displacement_jumps
from rafi.readers.parsing import TO_DEG_C

#: Coolest sensor's start level above this (in the file's numbers) -> deg F.
DEGF_ABOVE = 40.0
#: Coolest sensor's start level in this range -> kelvin.
KELVIN_RANGE = (240.0, 480.0)
#: A machine's coolest sensor at the start of a log, deg C (for the messages).
START_EXPECTED_C = (10.0, 35.0)
#: Margin (K) around the deg C sensors' start levels that a converted sensor must land in.
CONVERTED_BAND_K = 3.0
#: A sensor whose level (median of 5 rows) steps by at least this (K) from one row to the next ...
STEP_K = 5.0
#: ... and lands within this (K) of the deg F (or deg C) value of its level before: unit switch.
STEP_MATCH_K = 3.0
#: Rows each side of a step whose median is the level before / after it.
STEP_ROWS = 5

#: Speed units that are not r/min: factor to r/min and name (check speed_unit).
SPEED_UNITS = ((60.0, "rev/s"), (60.0 / (2.0 * np.pi), "rad/s"))
#: A spindle whose 99th-percentile running speed is below this share of the lowest training speed
#: runs far below what the model was trained for (check speed_range; 1 / SPEED_RANGE_FACTOR).
SPEED_LOW_FACTOR = 0.8

#: Fewest rows (and share of the rows) at one speed value for it to count as a plateau.
PLATEAU_MIN_ROWS = 10
PLATEAU_MIN_SHARE = 0.02
#: A spindle whose 99th-percentile speed stays at or below this "runs" suspiciously slowly.
REV_PER_S_MAX = 500.0
#: Share of rows the spindle must turn in for the slow-speed warning.
RUNNING_MIN_SHARE = 0.10
#: A speed above this factor x the highest training speed (+ tolerance) is far outside training.
SPEED_RANGE_FACTOR = 1.25
#: Time above that limit that makes a run (s), or this share of the log if it is shorter.
SPEED_RANGE_MIN_S = 300.0
SPEED_RANGE_MIN_SHARE = 0.10

#: Robust displacement range (2nd-98th percentile) above this -> nanometres (um).
NM_ABOVE_UM = 2000.0
#: Rows of the running median the displacement is smoothed with before its range is taken (so
#: that scattered glitch samples, even a few percent of the rows, do not widen it).
GLITCH_MEDIAN_ROWS = 7
#: The displacement's level stepping by this much (um) to 1/1000 of its level before (or back):
#: the logger switched between um and mm part way.
MM_STEP_UM = 2.0
#: Plausible thermal growth per kelvin of the hottest sensor's change (um/K): outside -> warning
#: (inches, mils, a wrong scale factor).
GROWTH_PER_K_UM = (0.2, 15.0)

#: Metadata / configured sample period off from the data's median step by more than this factor.
PERIOD_FACTOR = 1.5


def temperature_unit(sig: Signals, where: Where) -> None:
    """Error if the temperatures are in deg F or K: all of them (from the coolest sensor's start
    level), some of them (their start levels, converted, land among the others'), or from part
    way through the log on (a sensor's level steps to the deg F value of its level before)."""
    mask = sig.start_mask()
    levels = {s: start_level(sig.values[s], mask) for s in sig.sensors}
    levels = {s: v for s, v in levels.items() if np.isfinite(v)}
    if not levels:
        return
    coolest = min(levels, key=levels.get)
    level = levels[coolest]
    lo, hi = START_EXPECTED_C
    if KELVIN_RANGE[0] <= level <= KELVIN_RANGE[1]:
        raise where.check_error(
            "temperature_unit",
            f"temperatures look like kelvin: the coolest sensor {where.label(coolest)} starts at "
            f"{fmt(level)} (= {TO_DEG_C['K'](level):.1f} deg C if K); a machine's coolest sensor is "
            f"{lo:g}-{hi:g} deg C at the start of a log. Set input.temperature_unit: K (mapped "
            "files) or write deg C",
            column=coolest,
        )
    if DEGF_ABOVE < level < KELVIN_RANGE[0]:
        raise where.check_error(
            "temperature_unit",
            f"temperatures look like deg F: the coolest sensor {where.label(coolest)} starts at "
            f"{fmt(level)} (= {TO_DEG_C['F'](level):.1f} deg C if deg F); a machine's coolest sensor "
            f"is {lo:g}-{hi:g} deg C at the start of a log, values above {DEGF_ABOVE:g} are not. "
            "The logger writes deg F: set input.temperature_unit: F (mapped files) or write deg C",
            column=coolest,
        )
    _some_sensors(levels, where)
    _part_way(sig, where)


def _some_sensors(levels: dict, where: Where) -> None:
    """Error if the sensors that start above :data:`DEGF_ABOVE` would, in deg F or K, start among
    the others (within :data:`CONVERTED_BAND_K`)."""
    cool = [v for v in levels.values() if v <= DEGF_ABOVE]
    if not cool:
        return
    band = (min(cool) - CONVERTED_BAND_K, max(cool) + CONVERTED_BAND_K)
    for unit, convert in (("deg F", TO_DEG_C["F"]), ("kelvin", TO_DEG_C["K"])):
        hits = [s for s, v in levels.items() if v > DEGF_ABOVE and band[0] <= convert(v) <= band[1]]
        if not hits:
            continue
        s = hits[0]
        names = ", ".join(hits[:8]) + (", ..." if len(hits) > 8 else "")
        raise where.check_error(
            "temperature_unit",
            f"{len(hits)} sensor(s) look like {unit} ({names}): {where.label(s)} starts at "
            f"{fmt(levels[s])} (= {convert(levels[s]):.1f} deg C if {unit}) while the other "
            f"{len(cool)} sensor(s) start at {fmt(min(cool))}..{fmt(max(cool))} deg C; those "
            f"channels are logged in {unit}: convert them to deg C",
            column=s,
        )


def level_steps(values: np.ndarray, min_step: float):
    """Where a channel's level steps by ``min_step`` or more from one row to the next: yields
    ``(k, before, after)`` with ``k`` the row index of the step and the medians of up to
    :data:`STEP_ROWS` rows before and after it (single spikes do not count)."""
    v = pd.Series(values)
    if v.notna().sum() < 2 * STEP_ROWS:
        return
    before = v.rolling(STEP_ROWS, min_periods=3).median().to_numpy()[:-1]
    after = v[::-1].rolling(STEP_ROWS, min_periods=3).median().to_numpy()[::-1][1:]
    big = np.nan_to_num(np.abs(after - before), nan=0.0) >= min_step
    k = 0
    while k < big.size:
        if not big[k]:
            k += 1
            continue
        end = k
        while end + 1 < big.size and big[end + 1]:
            end += 1
        mid = (k + end) // 2  # the middle of the rows whose windows straddle the step
        yield mid + 1, float(before[mid]), float(after[mid])
        k = end + 1


def _part_way(sig: Signals, where: Where) -> None:
    """Error if a sensor's level steps (by :data:`STEP_K` or more) to the deg F value of its level
    before the step, or back: the logger switched unit part way through the log."""
    for s in sig.sensors:
        for k, b, a in level_steps(sig.values[s], STEP_K):
            to_f = abs(a - (b * 1.8 + 32.0)) <= STEP_MATCH_K
            from_f = abs(b - (a * 1.8 + 32.0)) <= STEP_MATCH_K
            if not (to_f or from_f):
                continue
            line = int(sig.lines[k])
            what = "from this line on" if to_f else "before this line"
            raise where.check_error(
                "temperature_unit",
                f"{where.label(s)} steps from {fmt(b)} to {fmt(a)} at line {line}, the deg F value "
                f"of {fmt(b if to_f else a)} deg C: the logger writes deg F {what}; convert those "
                "rows to deg C",
                line=line,
                column=s,
            )


def _plateaus(speed: np.ndarray) -> list[tuple[float, int]]:
    """Speeds held over many rows: (value, rows), non-zero values only, most rows first."""
    v = present(speed)
    v = np.round(v[v > 0], 1)
    if v.size == 0:
        return []
    values, counts = np.unique(v, return_counts=True)
    need = max(PLATEAU_MIN_ROWS, PLATEAU_MIN_SHARE * speed.size)
    keep = counts >= need
    order = np.argsort(-counts[keep])
    return [(float(values[keep][k]), int(counts[keep][k])) for k in order]


def _near(value: float, speeds, tol: float) -> float | None:
    for s in speeds:
        if abs(value - float(s)) <= tol:
            return float(s)
    return None


def _part_way_speed(plateaus, where: Where, speeds: list[float], tolerance_rpm: float) -> None:
    """Error if the log holds plateaus in the trained range and one far below it (under
    :data:`SPEED_LOW_FACTOR` x the lowest training speed) that is, x 60, a training speed or
    another plateau of the log, or, x 9.549, a training speed: part of the log is in rev/s or
    rad/s."""
    slow_below = SPEED_LOW_FACTOR * min(speeds)
    fast = [v for v, _ in plateaus if v >= slow_below]
    if not fast:
        return  # no part in r/min: the whole-log rule below speaks
    for v, rows in plateaus:
        if v >= slow_below:
            continue
        for factor, unit in SPEED_UNITS:
            targets = [*speeds, *fast] if unit == "rev/s" else speeds
            match = _near(factor * v, targets, tolerance_rpm)
            if match is None:
                continue
            what = "a training speed" if match in speeds else "another speed of this log"
            raise where.check_error(
                "speed_unit",
                f"{where.label('speed_rpm')} holds {fmt(v)} r/min for {rows} rows, and {fmt(v)} x "
                f"{factor:.4g} = {fmt(factor * v)} r/min is {what} "
                f"({fmt(match)} r/min): part of the log is written in {unit}; convert it to r/min",
                column="speed_rpm",
            )


def speed_unit(sig: Signals, where: Where, training_speeds_rpm, tolerance_rpm: float) -> list[CheckWarning]:
    """rev/s instead of r/min: error if plateaus x 60 match training speeds while the raw values do
    not; a warning if the spindle turns but never exceeds :data:`REV_PER_S_MAX` and x 60 would
    fall in the trained range."""
    speeds = [float(s) for s in training_speeds_rpm or ()]
    if not speeds:
        return []
    s = sig.values["speed_rpm"]
    plateaus = _plateaus(s)
    label = where.label("speed_rpm")
    _part_way_speed(plateaus, where, speeds, tolerance_rpm)
    if any(_near(v, speeds, tolerance_rpm) is not None for v, _ in plateaus):
        return []
    for factor, unit in SPEED_UNITS:
        matched = [(v, _near(factor * v, speeds, tolerance_rpm)) for v, _ in plateaus]
        matched = [(v, m) for v, m in matched if m is not None]
        if not matched:
            continue
        listed = ", ".join(f"{fmt(v)} x {factor:.4g} = {fmt(factor * v)}" for v, _ in matched[:4])
        raise where.check_error(
            "speed_unit",
            f"{label} holds {len(plateaus)} plateau(s) that match no training speed "
            f"({', '.join(fmt(x) for x in speeds)} r/min) but do x {factor:.4g} ({listed} r/min): the "
            f"logger writes {unit}; convert the speed to r/min",
            column="speed_rpm",
        )
    v = present(s)
    if v.size == 0:
        return []
    running = float((v > 0).mean())
    top = float(np.percentile(v, 99))
    lo, hi = min(speeds) - tolerance_rpm, SPEED_RANGE_FACTOR * max(speeds) + tolerance_rpm
    if running >= RUNNING_MIN_SHARE and 0 < top <= REV_PER_S_MAX and lo <= 60 * top <= hi:
        return [
            whole_log_warning(
                "speed_unit",
                "speed_rpm",
                f"{label} never exceeds {fmt(top)} r/min (99th percentile) although the spindle turns "
                f"in {100 * running:.0f} % of the rows; x 60 = {fmt(60 * top)} r/min would lie in the "
                f"trained range ({fmt(min(speeds))}-{fmt(max(speeds))} r/min): rev/s instead of r/min?",
                sig,
            )
        ]
    return []


def speed_range(
    sig: Signals, where: Where, training_speeds_rpm, tolerance_rpm: float, *, check_low: bool = True
) -> list[CheckWarning]:
    """Warning if the spindle runs far above the highest training speed, or (``check_low``) only
    far below the lowest one: the model extrapolates, or the speed is in another unit."""
    speeds = [float(s) for s in training_speeds_rpm or ()]
    if not speeds:
        return []
    s = sig.values["speed_rpm"]
    limit = SPEED_RANGE_FACTOR * max(speeds) + tolerance_rpm
    above = np.flatnonzero(np.nan_to_num(s, nan=0.0) > limit)
    duration = float(np.nanmax(sig.t) - np.nanmin(sig.t)) if sig.n else 0.0
    need_s = min(SPEED_RANGE_MIN_S, SPEED_RANGE_MIN_SHARE * duration)
    if above.size < 3 or above.size * sig.period_s < need_s:
        return _far_below(sig, where, speeds, tolerance_rpm) if check_low else []
    top = float(np.nanmax(s[above]))
    return [
        CheckWarning(
            "speed_range",
            "speed_rpm",
            f"{where.label('speed_rpm')} reaches {fmt(top)} r/min for {above.size * sig.period_s / 60:.0f} "
            f"min ({above.size} rows above {fmt(limit)} r/min), far above the highest training speed "
            f"{fmt(max(speeds))} r/min: the model would extrapolate; a wrong speed channel or unit, "
            "or a run outside what the machine was trained for",
            int(sig.lines[above[0]]),
            int(sig.lines[above[-1]]),
        )
    ]


def _far_below(sig: Signals, where: Where, speeds: list[float], tolerance_rpm: float) -> list[CheckWarning]:
    """Warning if the spindle turns in :data:`RUNNING_MIN_SHARE` of the rows but its 99th-percentile
    running speed stays below :data:`SPEED_LOW_FACTOR` x the lowest training speed."""
    v = present(sig.values["speed_rpm"])
    running = v[v > tolerance_rpm]
    if v.size == 0 or running.size < RUNNING_MIN_SHARE * v.size:
        return []
    top = float(np.percentile(running, 99))
    limit = SPEED_LOW_FACTOR * min(speeds)
    if top >= limit:
        return []
    hints = ", ".join(f"x {f:.4g} = {fmt(f * top)} r/min if {u}" for f, u in SPEED_UNITS)
    return [
        whole_log_warning(
            "speed_range",
            "speed_rpm",
            f"{where.label('speed_rpm')} never exceeds {fmt(top)} r/min (99th percentile of the "
            f"{100 * running.size / v.size:.0f} % of rows the spindle turns in), below "
            f"{SPEED_LOW_FACTOR:g} x the lowest training speed {fmt(min(speeds))} r/min: the model "
            f"would extrapolate, or the speed is in another unit ({hints})",
            sig,
        )
    ]


def smoothed(values: np.ndarray) -> np.ndarray:
    """Running median over :data:`GLITCH_MEDIAN_ROWS` rows (missing values left out): a glitch
    sample, or several percent of them scattered over the log, disappears."""
    return (
        pd.Series(values)
        .rolling(GLITCH_MEDIAN_ROWS, center=True, min_periods=1)
        .median()
        .to_numpy(dtype=float)
    )


def _temperature_change(sig: Signals, rows=slice(None)) -> tuple[float, str]:
    """The largest change of a sensor (1st-99th percentile, K) over ``rows``, and that sensor."""
    changes = {s: robust_range(sig.values[s][rows], 1.0, 99.0) for s in sig.sensors}
    name = max(changes, key=changes.get)
    return changes[name], name


def displacement_unit(
    sig: Signals, where: Where, *, mm_max_range_um: float, mm_min_temp_rise_k: float
) -> list[CheckWarning]:
    """Error if the displacement is in mm (hardly moves while the machine heats, or steps to a
    thousandth of its level part way) or in nm (moves more than thermal growth can); a warning if it moves
    implausibly much or little per kelvin (inches, mils, a scale factor). Ranges are 2nd-98th
    percentiles of the running median, so glitches do not hide a unit."""
    d = smoothed(sig.values["disp_um"])
    spread = robust_range(d)
    label = where.label("disp_um")
    if spread > NM_ABOVE_UM:
        raise where.check_error(
            "displacement_unit",
            f"{label} varies by {fmt(spread)} um (2nd-98th percentile), more than thermal growth can "
            f"be ({NM_ABOVE_UM:g} um): values look like nanometres; convert to um",
            column="disp_um",
        )
    rise, hottest = _temperature_change(sig)
    if spread <= mm_max_range_um and rise >= mm_min_temp_rise_k:
        raise where.check_error(
            "displacement_unit",
            f"{label} varies by only {spread:.3g} um (2nd-98th percentile) while temperatures change "
            f"by {rise:.1f} K: values look like millimetres; set displacement.unit: mm in "
            "the machine's input mapping (config.yaml)",
            column="disp_um",
        )
    _mm_step(sig, where)
    jumps = displacement_jumps(sig, where, spread)
    if rise < mm_min_temp_rise_k or spread <= 0:
        return jumps
    per_k = spread / rise
    lo, hi = GROWTH_PER_K_UM
    if lo <= per_k <= hi:
        return jumps
    cause = (
        "a scale factor too large (inches x 25.4, or um written as nm / 10?)"
        if per_k > hi
        else "a scale factor too small (mils, 0.0254, or a fraction of a um?)"
    )
    return [
        whole_log_warning(
            "displacement_unit",
            "disp_um",
            f"{label} changes by {fmt(spread)} um (2nd-98th percentile) while {where.label(hottest)} "
            f"changes by {rise:.1f} K: {per_k:.3g} um/K, outside the {lo:g}..{hi:g} um/K thermal growth "
            f"can give; {cause} Check displacement.unit and the logger's scaling",
            sig,
        ),
        *jumps,
    ]


def _mm_step(sig: Signals, where: Where) -> None:
    """Error if the displacement's level steps (by :data:`MM_STEP_UM` or more) to a thousandth of
    its level before, or to a thousand times it: um and mm mixed in one log."""
    for k, b, a in level_steps(sig.values["disp_um"], MM_STEP_UM):
        small, large = (a, b) if abs(a) < abs(b) else (b, a)
        if abs(small * 1000.0 - large) > max(1.0, 0.05 * abs(large)):
            continue
        line = int(sig.lines[k])
        which = "from this line on" if abs(a) < abs(b) else "before this line"
        raise where.check_error(
            "displacement_unit",
            f"{where.label('disp_um')} steps from {fmt(b)} to {fmt(a)} um at line {line}, a factor "
            f"1000: the values are in millimetres {which}; convert them to um",
            line=line,
            column="disp_um",
        )


def metadata_period(sig: Signals, where: Where, meta_period, configured_period) -> list[CheckWarning]:
    """Check the sample period against the data's median time step.

    Error if the file's metadata period is off by more than :data:`PERIOD_FACTOR` either way, or
    if the rows are more than that factor further apart than the configured period (cleaning
    would invent the rows in between). Rows closer than the configured period / the factor only
    warn: cleaning keeps one row per grid point.
    """
    steps = np.diff(sig.t)
    steps = steps[steps > 0]
    if steps.size < 3:
        return []
    step = float(np.median(steps))
    for source, period, both_ways in (
        ("the file's metadata sample_period_s", meta_period, True),
        ("the machine's sample_period_s (config.yaml)", configured_period, False),
    ):
        if period is None or float(period) <= 0:
            continue
        period = float(period)
        if step / period > PERIOD_FACTOR or (both_ways and period / step > PERIOD_FACTOR):
            ratio = max(period / step, step / period)
            raise where.check_error(
                "metadata_period",
                f"{source} is {fmt(period)} s but the rows are {fmt(step)} s apart (median step), "
                f"a factor {ratio:.2g}: a wrong period, or a file of another logger; correct the "
                "metadata or the setting",
                column="time",
            )
    if configured_period is not None and float(configured_period) / step > PERIOD_FACTOR:
        return [
            whole_log_warning(
                "metadata_period",
                "time",
                f"the rows are {fmt(step)} s apart (median step) but the machine's sample_period_s "
                f"is {fmt(float(configured_period))} s: cleaning keeps one row per "
                f"{fmt(float(configured_period))} s; set sample_period_s if the logger's period changed",
                sig,
            )
        ]
    return []


#: A log that starts before this was written by a logger whose clock was never set.
CLOCK_EARLIEST = "2000-01-01T00:00:00"


def clock_unset(time: pd.Series, where: Where, lines: np.ndarray) -> list[CheckWarning]:
    """Warning if the log starts before :data:`CLOCK_EARLIEST` (1970 or 1900: a clock that was
    never set); the bound is fixed, not "now", so the result never depends on the day it runs."""
    first = pd.Timestamp(time.min())
    if pd.isna(first) or first >= pd.Timestamp(CLOCK_EARLIEST):
        return []
    return [
        CheckWarning(
            "clock_unset",
            "time",
            f"{where.label('time')} starts at {first.isoformat()}, before {CLOCK_EARLIEST[:10]}: the "
            "logger's clock was never set (flat battery, no time server); windows by time "
            "(runs.windows unit time) and the order of this machine's logs cannot rely on it. "
            "Set the logger's clock, or map an elapsed-seconds column (input.time.kind elapsed_s)",
            int(lines[0]),
            int(lines[-1]),
        )
    ]


def metadata_machine(meta: dict, machine: str | None) -> list[CheckWarning]:
    """Warning if the metadata names another machine than the folder the file lies in."""
    named = meta.get("machine") if isinstance(meta, dict) else None
    if not machine or named is None or not str(named).strip():
        return []
    if str(named).strip().casefold() == str(machine).strip().casefold():
        return []
    return [
        CheckWarning(
            "metadata_machine",
            "",
            f"the file's metadata says machine {str(named)[:80]!r} but it lies in the folder of machine "
            f"{machine!r}: a log of another machine copied here?",
        )
    ]
