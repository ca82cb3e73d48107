"""Channel checks: channels present in too few rows, a constant sensor, a stuck logger, a
displacement and a temperature swapped, and the sign of the probe.

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
    is_flat,
    present,
    robust_range,
    start_level,
    whole_log_warning,
)

#: A channel with values in fewer than this share of the rows is sparse.
SPARSE_BELOW = 0.5
#: Channels without which a log cannot be used (sparse -> error); temperatures only warn.
REQUIRED = ("speed_rpm", "disp_um")

#: A sensor that moves less than this (K, 1st-99th percentile) is constant ...
FLAT_K = 0.01
#: ... while another sensor changes by at least this (K): constant_channel.
OTHERS_CHANGE_K = 1.0
#: The displacement changes by at least this (um, 2nd-98th percentile), or the speed by more than
#: the speed tolerance, while every temperature is constant: stuck_logger.
ACTIVE_DISP_UM = 1.0

#: Every sensor repeating its value for this long (s) while the displacement changes by
#: :data:`FROZEN_DISP_UM` (um, 2nd-98th percentile of that stretch) is a frozen logger too.
FROZEN_MIN_S = 1200.0
FROZEN_DISP_UM = 2.0

#: A sensor whose start level is this far (K) from the other sensors' median start level is out of
#: the temperatures' band; with the displacement inside it the two are swapped (error).
SWAP_OUTLIER_K = 5.0
#: Alone (no displacement inside the band), an outlier this far is only a warning.
LONE_OUTLIER_K = 10.0
#: A sensor that starts that far *above* the others and ends with at most this share of its
#: excess over their median (and not below them) is a hot part cooling down (a file that starts
#: during a cool-down), not a foreign quantity.
COOLING_SHARE = 0.5
#: Margin (K) around the other sensors' start levels / overall range that is "inside the band".
BAND_MARGIN_K = 2.0
#: Two channels whose values agree within this in this share of the rows are the same channel.
SAME_WITHIN = 0.01
SAME_SHARE = 0.95

#: disp_um a straight-line function of one sensor (r^2 at least this, the sensor changing by
#: :data:`OTHERS_CHANGE_K` or more): a temperature scaled or shifted into the displacement column.
AFFINE_MIN_R2 = 0.9995
#: A sensor must change by this much (K, 1st-99th percentile) for a copy of it to count.
COPY_MIN_CHANGE_K = 0.5
#: The spindle at rest (within the speed tolerance of 0) in this share of the rows while a sensor
#: rises this far (K) above its start level: a spindle at rest does not heat the machine.
IDLE_SHARE = 0.98
IDLE_HEATING_K = 5.0

#: Probe sign: the heating signal is the spindle's heat input, the speed through a first-order
#: low-pass of this time constant (s) from rest at the file's first row ...
SIGN_HEAT_TAU_S = 1800.0
#: ... when that changes by at least this much (r/min); otherwise the hottest sensor's excess over
#: the row median of the temperatures, when that changes by :data:`SIGN_MIN_TEMP_K` or more. Both
#: leave out the room, which moves every sensor and the structure together and can turn the
#: displacement either way.
SIGN_MIN_HEAT_RPM = 100.0
SIGN_MIN_TEMP_K = 1.0
#: ... the displacement must change by this much (um, 2nd-98th percentile) ...
SIGN_MIN_DISP_UM = 1.0
#: ... and |correlation| between them must be at least this.
SIGN_MIN_CORR = 0.7


def sparse_channel(sig: Signals, where: Where) -> list[CheckWarning]:
    """Error if ``speed_rpm`` or ``disp_um`` has values in under half of the rows; a warning for a
    temperature (open-circuit readings count as missing)."""
    warnings = []
    for name in (*REQUIRED, *sig.sensors):
        v = sig.values[name]
        share = float((~np.isnan(v)).mean()) if v.size else 0.0
        if share >= SPARSE_BELOW:
            continue
        text = (
            f"{where.label(name)} has a value in only {int((~np.isnan(v)).sum())} of {v.size} rows "
            f"({100 * share:.0f} %, less than {100 * SPARSE_BELOW:.0f} %)"
        )
        if name in REQUIRED:
            raise where.check_error(
                "sparse_channel",
                f"{text}: too few to model or validate; a loose cable, a wrong column mapped, or a "
                "logger that writes this channel only now and then",
                column=name,
            )
        warnings.append(
            whole_log_warning(
                "sparse_channel",
                name,
                f"{text}: an intermittent sensor; its gaps are interpolated or left empty",
                sig,
            )
        )
    return warnings


def _frozen_stretch(sig: Signals, sensors: list[str]) -> tuple[int, int]:
    """Start and length of the longest stretch of rows in which no sensor's value changes (a
    missing value counts as unchanged)."""
    temps = np.column_stack([sig.values[s] for s in sensors])
    same = np.all((temps[1:] == temps[:-1]) | np.isnan(temps[1:]) | np.isnan(temps[:-1]), axis=1)
    best, start, run_start, length = 0, 0, 0, 0
    for k, flag in enumerate(same):
        if flag:
            if length == 0:
                run_start = k
            length += 1
            if length > best:
                best, start = length, run_start
        else:
            length = 0
    return start, best + 1 if best else 0


def stuck_logger_and_constant(sig: Signals, where: Where, tolerance_rpm: float) -> list[CheckWarning]:
    """Error if every temperature is constant while the displacement or the speed changes (the
    logger repeats stale values), over the whole log or for :data:`FROZEN_MIN_S` in a row; a
    warning for one constant sensor while others change."""
    with_values = [s for s in sig.sensors if present(sig.values[s]).size]
    flat = [s for s in with_values if is_flat(sig.values[s], FLAT_K)]
    if with_values and len(flat) == len(with_values):
        d_change = robust_range(sig.values["disp_um"])
        s_change = robust_range(sig.values["speed_rpm"], 1.0, 99.0)
        if d_change >= ACTIVE_DISP_UM or s_change > tolerance_rpm:
            moving = (
                f"disp_um changes by {fmt(d_change)} um"
                if d_change >= ACTIVE_DISP_UM
                else f"the speed changes by {fmt(s_change)} r/min"
            )
            raise where.check_error(
                "stuck_logger",
                f"all {len(flat)} temperatures are constant (each within {FLAT_K:g} K over {sig.n} "
                f"rows) while {moving}: the logger repeats stale temperature values (a stuck "
                "logger or a frozen interface)",
                column=flat[0],
            )
        return []
    if len(with_values) >= 2:
        first, length = _frozen_stretch(sig, with_values)
        if length * sig.period_s >= FROZEN_MIN_S:
            stretch = slice(first, first + length)
            d_change = robust_range(sig.values["disp_um"][stretch])
            if d_change >= FROZEN_DISP_UM:
                raise where.check_error(
                    "stuck_logger",
                    f"all {len(with_values)} temperatures repeat the same values for {length} rows "
                    f"({length * sig.period_s / 60:.0f} min, lines {sig.lines[first]}-"
                    f"{sig.lines[first + length - 1]}) while disp_um changes by {fmt(d_change)} um: "
                    "the logger repeats stale temperature values (a stuck logger or a frozen interface)",
                    line=sig.lines[first],
                    column=with_values[0],
                )
    warnings = []
    for name in flat:
        others = max((robust_range(sig.values[s], 1.0, 99.0) for s in with_values if s != name), default=0.0)
        if others < OTHERS_CHANGE_K:
            continue
        v = present(sig.values[name])
        warnings.append(
            whole_log_warning(
                "constant_channel",
                name,
                f"{where.label(name)} stays at {fmt(float(np.median(v)))} deg C (within {FLAT_K:g} K in "
                f"98 % of {v.size} values) while other sensors change by up to {others:.1f} K: a stuck "
                "or disconnected sensor, or a constant written by the logger",
                sig,
            )
        )
    return warnings


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    both = ~np.isnan(a) & ~np.isnan(b)
    if both.sum() < 10:
        return False
    return float((np.abs(a[both] - b[both]) <= SAME_WITHIN).mean()) >= SAME_SHARE


def _affine_copy(sig: Signals, where: Where) -> list[CheckWarning]:
    """Warning if ``disp_um`` is a straight-line function of one sensor (r^2 at least
    :data:`AFFINE_MIN_R2`): a real probe lags the temperatures and has its own noise."""
    d = sig.values["disp_um"]
    for s in sig.sensors:
        v = sig.values[s]
        both = ~np.isnan(d) & ~np.isnan(v)
        if both.sum() < 10 or robust_range(v[both], 1.0, 99.0) < OTHERS_CHANGE_K or np.std(d[both]) == 0:
            continue
        r = float(np.corrcoef(v[both], d[both])[0, 1])
        if not np.isfinite(r) or r * r < AFFINE_MIN_R2:
            continue
        slope, offset = np.polyfit(v[both], d[both], 1)
        return [
            whole_log_warning(
                "swapped_channels",
                "disp_um",
                f"{where.label('disp_um')} is a straight-line function of {where.label(s)} "
                f"(disp_um = {slope:.4g} x {s} {'+' if offset >= 0 else '-'} {abs(offset):.4g}, r^2 = "
                f"{r * r:.5f} over {int(both.sum())} rows): a real probe lags the temperatures; a "
                "temperature channel scaled or shifted into the displacement column?",
                sig,
            )
        ]
    return []


def copied_channel(sig: Signals, where: Where) -> list[CheckWarning]:
    """Sensors holding the same values as another sensor (within :data:`SAME_WITHIN` in
    :data:`SAME_SHARE` of the rows) while they change by :data:`COPY_MIN_CHANGE_K`: error if every
    sensor is a copy of one, else a warning per copied sensor."""
    names = [s for s in sig.sensors if robust_range(sig.values[s], 1.0, 99.0) >= COPY_MIN_CHANGE_K]
    copies: dict[str, str] = {}
    for i, a in enumerate(names):
        if a in copies:
            continue
        for b in names[i + 1 :]:
            if b not in copies and _same(sig.values[a], sig.values[b]):
                copies[b] = a
    if not copies:
        return []
    with_values = [s for s in sig.sensors if present(sig.values[s]).size]
    originals = set(copies.values())
    if len(originals) == 1 and len(copies) + 1 == len(with_values):
        first = next(iter(originals))
        raise where.check_error(
            "copied_channel",
            f"all {len(with_values)} temperatures hold the same values as {where.label(first)} (within "
            f"{SAME_WITHIN:g} in {100 * SAME_SHARE:.0f} % of the rows): one channel written into every "
            "sensor column; check the logger's channel list or the input mapping",
            column=first,
        )
    return [
        whole_log_warning(
            "copied_channel",
            copy,
            f"{where.label(copy)} holds the same values as {where.label(original)} (within {SAME_WITHIN:g} "
            f"in {100 * SAME_SHARE:.0f} % of the rows) while both change by "
            f"{robust_range(sig.values[original], 1.0, 99.0):.1f} K: two sensors never agree that "
            "closely; one channel written twice (logger channel list or mapping)",
            sig,
        )
        for copy, original in copies.items()
    ]


def idle_speed(sig: Signals, where: Where, tolerance_rpm: float) -> list[CheckWarning]:
    """Warning if ``speed_rpm`` says the spindle is at rest in :data:`IDLE_SHARE` of the rows while
    a sensor rises :data:`IDLE_HEATING_K` above its start level: a stuck or wrong speed channel."""
    v = present(sig.values["speed_rpm"])
    if v.size == 0 or float((np.abs(v) <= tolerance_rpm).mean()) < IDLE_SHARE:
        return []
    mask = sig.start_mask()
    rises = {}
    for s in sig.sensors:
        x = present(sig.values[s])
        if x.size:
            rises[s] = float(np.percentile(x, 99)) - start_level(sig.values[s], mask)
    rises = {s: r for s, r in rises.items() if np.isfinite(r)}
    if not rises:
        return []
    hottest = max(rises, key=rises.get)
    if rises[hottest] < IDLE_HEATING_K:
        return []
    return [
        whole_log_warning(
            "constant_channel",
            "speed_rpm",
            f"{where.label('speed_rpm')} says the spindle is at rest in "
            f"{100 * float((np.abs(v) <= tolerance_rpm).mean()):.0f} % of the rows (within "
            f"{tolerance_rpm:g} r/min of 0) while {where.label(hottest)} rises {rises[hottest]:.1f} K "
            f"above its start level: a spindle at rest does not heat the machine; a stuck, "
            "disconnected or wrong speed channel?",
            sig,
        )
    ]


def swapped_channels(sig: Signals, where: Where) -> list[CheckWarning]:
    """A displacement that behaves like a temperature and a temperature that behaves like a
    displacement.

    Evidence: the start level (median over the first minutes) of each sensor against the other
    sensors'; whether the displacement starts inside the temperatures' band and stays within their
    overall range; and whether a channel holds the same values as another. Errors: both sides
    (a sensor out of the band and the displacement inside it: swapped), or a copy. Warnings: one
    side only.
    """
    mask = sig.start_mask()
    d = sig.values["disp_um"]
    d_label = where.label("disp_um")
    for s in sig.sensors:
        if _same(d, sig.values[s]):
            raise where.check_error(
                "swapped_channels",
                f"{d_label} holds the same values as {where.label(s)} (within {SAME_WITHIN:g} in "
                f"{100 * SAME_SHARE:.0f} % of the rows): the displacement is mapped to a temperature "
                "channel",
                column="disp_um",
            )
    affine = _affine_copy(sig, where)
    if affine:
        return affine
    levels = {s: start_level(sig.values[s], mask) for s in sig.sensors}
    levels = {s: v for s, v in levels.items() if np.isfinite(v)}
    if len(levels) < 3:
        return []
    d_start = start_level(d, mask)
    if not np.isfinite(d_start):
        return []

    def others(name):
        return [v for s, v in levels.items() if s != name]

    deviation = {s: abs(v - float(np.median(others(s)))) for s, v in levels.items()}
    outlier = max(deviation, key=deviation.get)
    rest = others(outlier) if deviation[outlier] > SWAP_OUTLIER_K else list(levels.values())
    if deviation[outlier] > SWAP_OUTLIER_K and _cools_towards_the_others(sig, outlier, levels):
        deviation[outlier] = 0.0  # out of the band, but a temperature: no swap, no warning
    band = (min(rest) - BAND_MARGIN_K, max(rest) + BAND_MARGIN_K)
    envelope_sensors = [s for s in levels if deviation[s] <= SWAP_OUTLIER_K] or list(levels)
    t_lo = min(np.nanpercentile(sig.values[s], 1) for s in envelope_sensors)
    t_hi = max(np.nanpercentile(sig.values[s], 99) for s in envelope_sensors)
    d_ok = present(d)
    d_lo, d_hi = np.percentile(d_ok, [2, 98])
    d_inside = band[0] <= d_start <= band[1] and d_lo >= t_lo - BAND_MARGIN_K and d_hi <= t_hi + BAND_MARGIN_K
    band_text = f"{fmt(min(rest))}..{fmt(max(rest))} deg C"
    if deviation[outlier] > SWAP_OUTLIER_K and d_inside:
        raise where.check_error(
            "swapped_channels",
            f"{where.label(outlier)} and {d_label} look swapped: {outlier} starts at "
            f"{fmt(levels[outlier])} while the other sensors start at {band_text}, and disp_um "
            f"starts at {fmt(d_start)} um, inside that band, and stays within the temperatures' "
            f"{fmt(t_lo)}..{fmt(t_hi)}; swap the columns back (header or input mapping)",
            column=outlier,
        )
    if d_inside:
        return [
            whole_log_warning(
                "swapped_channels",
                "disp_um",
                f"{d_label} behaves like a temperature: it starts at {fmt(d_start)} um, inside the "
                f"sensors' start levels {band_text}, and stays within their range "
                f"{fmt(t_lo)}..{fmt(t_hi)}: a temperature channel mapped as the displacement?",
                sig,
            )
        ]
    if deviation[outlier] > LONE_OUTLIER_K:
        return [
            whole_log_warning(
                "swapped_channels",
                outlier,
                f"{where.label(outlier)} starts at {fmt(levels[outlier])} deg C while the other sensors "
                f"start at {band_text} ({deviation[outlier]:.1f} K from their median): a displacement "
                "or another quantity in a temperature column, or a sensor of another machine part?",
                sig,
            )
        ]
    return []


def _cools_towards_the_others(sig: Signals, sensor: str, start_levels: dict[str, float]) -> bool:
    """``sensor`` starts above the other sensors' median and ends with at most
    :data:`COOLING_SHARE` of that excess, not below them by more than :data:`BAND_MARGIN_K` (levels
    over the first and the last minutes): a displacement falling from 40 um to 0 ends far below."""
    last_minutes = sig.end_mask()
    end = {s: start_level(sig.values[s], last_minutes) for s in start_levels}
    rest_start = [v for s, v in start_levels.items() if s != sensor]
    rest_end = [v for s, v in end.items() if s != sensor and np.isfinite(v)]
    if not rest_end or not np.isfinite(end[sensor]):
        return False
    excess_start = start_levels[sensor] - float(np.median(rest_start))
    excess_end = end[sensor] - float(np.median(rest_end))
    return excess_start > 0 and -BAND_MARGIN_K <= excess_end <= COOLING_SHARE * excess_start


def probe_sign(sig: Signals) -> int:
    """Sign of the displacement's change while the spindle heats the machine: +1, -1, or 0
    without clear evidence.

    The heating signal is :func:`heat_signal`; the evidence is clear when it and the displacement
    both change enough (:data:`SIGN_MIN_DISP_UM`) and their correlation reaches
    :data:`SIGN_MIN_CORR` in size.
    """
    heat = heat_signal(sig)
    return 0 if heat is None else sign_evidence(heat, sig.values["disp_um"])[0]


def sign_evidence(heat: np.ndarray, disp: np.ndarray) -> tuple[int, float | None]:
    """The displacement's direction while ``heat`` rises: ``(+1, -1 or 0, their correlation)``.

    0 without clear evidence: fewer than 10 samples where both are finite, a displacement that
    changes by less than :data:`SIGN_MIN_DISP_UM`, or a correlation under :data:`SIGN_MIN_CORR` in
    size (the correlation is None where it cannot be computed). ``rafi init`` says the same
    (:func:`rafi.ops.init_survey.probe_sign`).
    """
    heat, disp = np.asarray(heat, dtype=float), np.asarray(disp, dtype=float)
    both = np.isfinite(heat) & np.isfinite(disp)
    if both.sum() < 10:
        return 0, None
    heat, disp = heat[both], disp[both]
    if robust_range(disp) < SIGN_MIN_DISP_UM or np.std(heat) == 0 or np.std(disp) == 0:
        return 0, None
    r = float(np.corrcoef(heat, disp)[0, 1])
    if not np.isfinite(r):
        return 0, None
    return (0 if abs(r) < SIGN_MIN_CORR else (1 if r > 0 else -1)), r


def speed_heat(speed: np.ndarray, period_s: float) -> np.ndarray:
    """The spindle's heat input as the sign check reads it: the speed through a first-order
    low-pass of :data:`SIGN_HEAT_TAU_S` from rest before the first sample, a missing speed holding
    the last value."""
    from_rest = pd.Series(np.r_[0.0, np.asarray(speed, dtype=float)]).ffill().fillna(0.0)
    gain = 1.0 - np.exp(-period_s / SIGN_HEAT_TAU_S)
    return from_rest.ewm(alpha=gain, adjust=False).mean().to_numpy()[1:]


def heat_signal(sig: Signals) -> np.ndarray | None:
    """What rises while the spindle heats the machine, or ``None`` when nothing does clearly.

    The speed through a first-order low-pass (:data:`SIGN_HEAT_TAU_S`, from rest at the first row,
    a missing speed holding the last value) when that changes by :data:`SIGN_MIN_HEAT_RPM`;
    otherwise the hottest sensor's excess over the row median of the temperatures when that
    changes by :data:`SIGN_MIN_TEMP_K`. Neither follows the room: a room that cools while the
    spindle runs lowers every temperature and may move the displacement either way.
    """
    speed = sig.values["speed_rpm"]
    if np.isfinite(speed).any():
        heat = speed_heat(speed, sig.period_s)
        if robust_range(heat) >= SIGN_MIN_HEAT_RPM:
            return heat
    temps = np.column_stack([sig.values[s] for s in sig.sensors])
    has = np.sum(~np.isnan(temps), axis=1) >= 2
    if not has.any():
        return None
    excess = np.full(sig.n, np.nan)
    excess[has] = np.nanmax(temps[has], axis=1) - np.nanmedian(temps[has], axis=1)
    if robust_range(excess[has]) < SIGN_MIN_TEMP_K:
        return None
    return excess
