"""Unit and metadata checks: deg F / K temperatures, rev/s speeds, speeds beyond training, mm / nm
displacement, metadata naming another machine or another sample period.

Each function takes the :class:`~rafi.readers.checks_base.Signals` of a frame and a
:class:`~rafi.readers.checks_base.Where`; it raises the check's error (certain) or returns its
warnings (suspicious). Thresholds are module constants, documented in docs/raw-format.md
("Checks").
"""

from __future__ import annotations

import numpy as np

from rafi import SENSORS
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

#: Coolest sensor's start level above this (in the file's numbers) -> deg F.
DEGF_ABOVE = 40.0
#: Coolest sensor's start level in this range -> kelvin.
KELVIN_RANGE = (240.0, 480.0)
#: A machine's coolest sensor at the start of a log, deg C (for the messages).
START_EXPECTED_C = (10.0, 35.0)

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

#: Metadata / configured sample period off from the data's median step by more than this factor.
PERIOD_FACTOR = 1.5


def temperature_unit(sig: Signals, where: Where) -> None:
    """Error if the temperatures are in deg F or K (from the coolest sensor's start level)."""
    mask = sig.start_mask()
    levels = {s: start_level(sig.values[s], mask) for s in SENSORS}
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
            f"{fmt(level)} (= {level - 273.15:.1f} deg C if K); a machine's coolest sensor is "
            f"{lo:g}-{hi:g} deg C at the start of a log. Set input.temperature_unit: K (mapped "
            "files) or write deg C",
            column=coolest,
        )
    if DEGF_ABOVE < level < KELVIN_RANGE[0]:
        raise where.check_error(
            "temperature_unit",
            f"temperatures look like deg F: the coolest sensor {where.label(coolest)} starts at "
            f"{fmt(level)} (= {(level - 32) / 1.8:.1f} deg C if deg F); a machine's coolest sensor "
            f"is {lo:g}-{hi:g} deg C at the start of a log, values above {DEGF_ABOVE:g} are not. "
            "The logger writes deg F: convert to deg C",
            column=coolest,
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


def speed_unit(sig: Signals, where: Where, training_speeds_rpm, tolerance_rpm: float) -> list[CheckWarning]:
    """rev/s instead of r/min: error if plateaus x 60 match training speeds while the raw values do
    not; a warning if the spindle turns but never exceeds :data:`REV_PER_S_MAX` and x 60 would
    fall in the trained range."""
    speeds = [float(s) for s in training_speeds_rpm or ()]
    if not speeds:
        return []
    s = sig.values["speed_rpm"]
    plateaus = _plateaus(s)
    if any(_near(v, speeds, tolerance_rpm) is not None for v, _ in plateaus):
        return []
    label = where.label("speed_rpm")
    matched = [(v, _near(60 * v, speeds, tolerance_rpm)) for v, _ in plateaus]
    matched = [(v, m) for v, m in matched if m is not None]
    if matched:
        listed = ", ".join(f"{fmt(v)} x 60 = {fmt(60 * v)}" for v, _ in matched[:4])
        raise where.check_error(
            "speed_unit",
            f"{label} holds {len(plateaus)} plateau(s) that match no training speed "
            f"({', '.join(fmt(x) for x in speeds)} r/min) but do x 60 ({listed} r/min): the logger "
            "writes rev/s; convert the speed to r/min",
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


def speed_range(sig: Signals, where: Where, training_speeds_rpm, tolerance_rpm: float) -> list[CheckWarning]:
    """Warning if the spindle runs far above the highest training speed (the model extrapolates)."""
    speeds = [float(s) for s in training_speeds_rpm or ()]
    if not speeds:
        return []
    s = sig.values["speed_rpm"]
    limit = SPEED_RANGE_FACTOR * max(speeds) + tolerance_rpm
    above = np.flatnonzero(np.nan_to_num(s, nan=0.0) > limit)
    duration = float(np.nanmax(sig.t) - np.nanmin(sig.t)) if sig.n else 0.0
    need_s = min(SPEED_RANGE_MIN_S, SPEED_RANGE_MIN_SHARE * duration)
    if above.size < 3 or above.size * sig.period_s < need_s:
        return []
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


def displacement_unit(
    sig: Signals, where: Where, *, mm_max_range_um: float, mm_min_temp_rise_k: float
) -> None:
    """Error if the displacement is in mm (hardly moves while the machine heats) or in nm (moves
    more than thermal growth can); ranges are 2nd-98th percentiles, so glitches do not hide it."""
    d = sig.values["disp_um"]
    spread = robust_range(d)
    label = where.label("disp_um")
    if spread > NM_ABOVE_UM:
        raise where.check_error(
            "displacement_unit",
            f"{label} varies by {fmt(spread)} um (2nd-98th percentile), more than thermal growth can "
            f"be ({NM_ABOVE_UM:g} um): values look like nanometres; convert to um",
            column="disp_um",
        )
    rise = max((robust_range(sig.values[s], 1.0, 99.0) for s in SENSORS), default=0.0)
    if spread <= mm_max_range_um and rise >= mm_min_temp_rise_k:
        raise where.check_error(
            "displacement_unit",
            f"{label} varies by only {spread:.3g} um (2nd-98th percentile) while temperatures change "
            f"by {rise:.1f} K: values look like millimetres; set displacement.unit: mm in "
            "the machine's input mapping (config.yaml)",
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
