"""Plausibility checks on a freshly read log, before cleaning (docs/raw-format.md, "Checks").

:func:`check_file` looks for mistakes that would otherwise pass silently through the pipeline
and spoil a model. What is *certain* raises :class:`rafi.errors.RawFormatError` naming the file,
the line (or sheet and row) and the column and saying what to do (the file is quarantined, or
the run stops); what is only *suspicious* comes back as a
:class:`~rafi.readers.checks_base.CheckWarning` (the file is used, the warning recorded in its
audit and shown). It also returns the file's probe sign (the sign of the displacement's change
while the spindle heats the machine), which the machine-level checks compare across files
(:mod:`rafi.readers.checks_machine`). :func:`check_log` is the same without the report.

Problems the cleaning step repairs (local swaps of adjacent rows, duplicates, single spikes,
short dropouts, documented open-circuit values) are left alone.

Checks of this module (thresholds are keyword arguments, defaults in brackets); the others are
in :mod:`rafi.readers.checks_units` and :mod:`rafi.readers.checks_channels`:

* a canonical column (``speed_rpm``, ``T1``..``T16``, ``disp_um``) without a single value
  (empty, or only open-circuit values).
* time going back by more than ``backwards_tolerance_samples`` (3) sample periods from one row
  to the next -> clock reset. A step back of up to 3 periods is left for cleaning.
* run shorter than ``min_run_s`` (0 = no check) from first to last timestamp.
* displacement constant: standard deviation below ``stuck_std_um`` (1e-3 um) or more than
  ``stuck_fraction`` (95 %) of the values identical, with at least ``min_samples`` (10) values.
* displacement stuck: the same value in consecutive rows for ``stuck_max_s`` (600 s) or longer
  while some temperature changes by ``stuck_min_temp_change_k`` (1 K) or more in that stretch.
* speed below 0 or above ``max_speed_rpm`` (100000 r/min).
* temperature outside ``temp_range_c`` (-40..200 deg C), except the documented open-circuit
  values (``clean.open_circuit_values``).
* displacement range (2nd-98th percentile) at most ``mm_max_range_um`` (0.2) while some
  temperature changes by at least ``mm_min_temp_rise_k`` (3 K) -> millimetres.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from rafi.contract.sensors import frame_sensors
from rafi.readers import checks_channels as channels
from rafi.readers import checks_units as units
from rafi.readers.checks_base import CheckWarning, Signals, Where
from rafi.settings import BACKWARDS_TOLERANCE_SAMPLES, backwards_cause

#: Every check id of the per-file checks (docs/raw-format.md, "Checks").
FILE_CHECKS = (
    "temperature_unit",
    "speed_unit",
    "speed_range",
    "displacement_unit",
    "displacement_step",
    "swapped_channels",
    "constant_channel",
    "stuck_logger",
    "copied_channel",
    "sparse_channel",
    "metadata_machine",
    "metadata_period",
    "clock_unset",
)


@dataclass
class CheckReport:
    """What :func:`check_file` found in a file that passed (no error).

    Attributes
    ----------
    warnings : list of CheckWarning
        Suspicious findings, in the order the checks ran.
    probe_sign : int
        +1 / -1: the displacement rises / falls while the spindle heats the machine; 0: no clear evidence.
    """

    warnings: list[CheckWarning] = field(default_factory=list)
    probe_sign: int = 0


def _longest_repeat(values: np.ndarray) -> tuple[int, int]:
    """Start and length of the longest stretch of identical consecutive non-NaN values."""
    if values.size == 0:
        return 0, 0
    same = np.concatenate(([False], (values[1:] == values[:-1])))
    starts = np.flatnonzero(~same)
    lengths = np.diff(np.append(starts, values.size))
    k = int(np.argmax(lengths))
    return int(starts[k]), int(lengths[k])


def _open_circuit_mask(values: np.ndarray, open_circuit_values) -> np.ndarray:
    mask = np.zeros(values.shape, dtype=bool)
    for v in open_circuit_values or ():
        mask |= np.isclose(values, float(v), rtol=0.0, atol=1e-6)
    return mask


def _values(frame: pd.DataFrame, where: Where, open_circuit_values) -> dict[str, np.ndarray]:
    """The value columns (speed, the machine's sensors, displacement: each must carry a value) as
    floats in that order, with open-circuit readings as NaN; error on an empty column."""
    n = len(frame)
    sensors = frame_sensors(frame)
    values: dict[str, np.ndarray] = {}
    for name in ("speed_rpm", *sensors, "disp_um"):
        v = frame[name].to_numpy(dtype=float, na_value=np.nan)
        oc = _open_circuit_mask(v, open_circuit_values) if name in sensors else np.zeros(n, bool)
        v = np.where(oc, np.nan, v)
        values[name] = v
        if np.isnan(v).all():
            extra = " or open-circuit" if oc.any() else ""
            raise where.error(
                f"{where.label(name)} has no value in any of the {n} rows (all "
                f"empty{extra}): sensor not connected or wrong column mapped",
                column=name,
                check="no_value",
            )
    return values


def _check_time(frame, where, t, lines, *, sample_period_s, backwards_tolerance_samples, min_run_s) -> None:
    steps = np.diff(t)
    limit = backwards_tolerance_samples * sample_period_s
    back = np.flatnonzero(steps < -limit)
    if back.size:
        k = int(back[0]) + 1
        prev, cur = frame["time"].iloc[k - 1], frame["time"].iloc[k]
        raise where.error(
            f"time goes back from {prev:%Y-%m-%dT%H:%M:%S} to {cur:%Y-%m-%dT%H:%M:%S} "
            f"({-steps[k - 1]:.0f} s, more than {backwards_tolerance_samples:g} samples of "
            f"{sample_period_s:g} s): {backwards_cause(-steps[k - 1])}",
            line=lines[k],
            column="time",
            check="clock_reset",
        )
    duration = float(np.nanmax(t) - np.nanmin(t)) if t.size else 0.0
    if min_run_s and duration < min_run_s:
        raise where.error(
            f"log covers only {duration:.0f} s, shorter than the minimum run of "
            f"{min_run_s:g} s (runs.min_run_s)",
            line=lines[-1],
            column="time",
            check="too_short",
        )


def _check_ranges(values, where, lines, max_speed_rpm, temp_range_c, open_circuit_values) -> None:
    s = values["speed_rpm"]
    bad = np.flatnonzero((s < 0) | (s > max_speed_rpm))
    if bad.size:
        k = int(bad[0])
        raise where.error(
            f"{where.prefix('speed_rpm')}speed {s[k]:g} r/min is {'negative' if s[k] < 0 else 'absurd'}; "
            f"expected 0..{max_speed_rpm:g} r/min",
            line=lines[k],
            column="speed_rpm",
            check="speed_value",
        )
    lo, hi = temp_range_c
    first_bad = None
    for name in values:
        if name in ("speed_rpm", "disp_um"):
            continue
        v = values[name]
        idx = np.flatnonzero((v < lo) | (v > hi))
        if idx.size and (first_bad is None or idx[0] < first_bad[0]):
            first_bad = (int(idx[0]), name)
    if first_bad is not None:
        k, name = first_bad
        oc = ", ".join(f"{x:g}" for x in open_circuit_values or ()) or "none configured"
        raise where.error(
            f"{where.prefix(name)}temperature {values[name][k]:g} deg C is outside {lo:g}..{hi:g} deg C "
            f"and not a documented open-circuit value ({oc}; "
            "clean.open_circuit_values)",
            line=lines[k],
            column=name,
            check="temperature_range",
        )


def _check_stuck_probe(values, where, lines, sample_period_s, th: dict) -> None:
    d = values["disp_um"]
    d_ok = d[~np.isnan(d)]
    std = float(np.std(d_ok))
    uniq, counts = np.unique(d_ok, return_counts=True)
    top = float(counts.max()) / d_ok.size
    if std < th["stuck_std_um"] or top > th["stuck_fraction"]:
        raise where.error(
            f"{where.label('disp_um')} is constant (std {std:.2g} um, "
            f"{100 * top:.0f} % of the values equal {uniq[counts.argmax()]:g}): stuck or "
            "disconnected probe, or the wrong channel is mapped",
            column="disp_um",
            check="displacement_constant",
        )
    first, length = _longest_repeat(d)
    if th["stuck_max_s"] > 0 and length * sample_period_s >= th["stuck_max_s"]:
        stretch = slice(first, first + length)
        change = max(
            (
                float(np.nanmax(values[s][stretch]) - np.nanmin(values[s][stretch]))
                for s in values
                if s not in ("speed_rpm", "disp_um") and np.isfinite(values[s][stretch]).any()
            ),
            default=0.0,
        )
        if change >= th["stuck_min_temp_change_k"]:
            raise where.error(
                f"{where.label('disp_um')} is stuck at {d[first]:g} um for {length} rows "
                f"({length * sample_period_s / 60:.0f} min, lines {lines[first]}-"
                f"{lines[first + length - 1]}) while temperatures change by {change:.1f} K: "
                "a live probe would move; check the probe and its cable",
                line=lines[first],
                column="disp_um",
                check="displacement_stuck",
            )


def check_file(
    frame: pd.DataFrame,
    path: str | os.PathLike | None = None,
    *,
    min_run_s: float = 0.0,
    sample_period_s: float | None = None,
    open_circuit_values=(),
    training_speeds_rpm=None,
    speed_tolerance_rpm: float = 50.0,
    machine: str | None = None,
    backwards_tolerance_samples: float = BACKWARDS_TOLERANCE_SAMPLES,
    max_speed_rpm: float = 100_000.0,
    temp_range_c: tuple[float, float] = (-40.0, 200.0),
    stuck_std_um: float = 1e-3,
    stuck_fraction: float = 0.95,
    stuck_max_s: float = 600.0,
    stuck_min_temp_change_k: float = 1.0,
    mm_max_range_um: float = 0.2,
    mm_min_temp_rise_k: float = 3.0,
    min_samples: int = 10,
) -> CheckReport:
    """Raise :class:`RawFormatError` on an implausible log; return its warnings and probe sign.

    Parameters
    ----------
    frame : pandas.DataFrame
        Canonical frame from :func:`rafi.readers.logs.read_log` (index = source line/row).
    path : str or os.PathLike, optional
        File named in messages (default ``frame.attrs['source']``).
    min_run_s : float
        Shortest acceptable log (first to last timestamp), seconds; 0 disables.
    sample_period_s : float, optional
        The machine's configured sample period (``sample_period_s``); default
        ``attrs['metadata']['sample_period_s']``, else the median positive time step. When given,
        it is also compared with the data (check ``metadata_period``).
    open_circuit_values : iterable of float
        Documented open-circuit readings (``clean.open_circuit_values``): allowed
        outside the temperature range and counted as missing.
    training_speeds_rpm : sequence of float, optional
        The machine's training speeds: checks ``speed_unit`` and ``speed_range`` need them
        (skipped without).
    speed_tolerance_rpm : float
        The machine's ``speed_tolerance_rpm``.
    machine : str, optional
        The machine (folder) the file belongs to (check ``metadata_machine``).
    backwards_tolerance_samples, max_speed_rpm, temp_range_c, stuck_std_um,
    stuck_fraction, stuck_max_s, stuck_min_temp_change_k, mm_max_range_um, mm_min_temp_rise_k, min_samples
        Thresholds, see the module docstring.

    Returns
    -------
    CheckReport
        The warnings (suspicious, not certain) and the file's probe sign.

    Raises
    ------
    RawFormatError
        A certain problem; the message starts with the location, then (for the checks with an
        id) ``"<check id>: "``, the evidence and the likely cause.
    """
    where = Where(frame, path)
    lines = frame.index.to_numpy()
    n = len(frame)
    if n == 0:
        raise where.error("no data rows")
    meta = frame.attrs.get("metadata") or {}
    meta = meta if isinstance(meta, dict) else {}
    values = _values(frame, where, open_circuit_values)
    t = frame["time"].to_numpy(dtype="datetime64[ns]").astype("int64") / 1e9
    steps = np.diff(t)
    period = sample_period_s if sample_period_s is not None else meta.get("sample_period_s")
    if period is None:
        pos = steps[steps > 0]
        period = float(np.median(pos)) if pos.size else 1.0
    period = float(period)
    sig = Signals(t=t - t[0], values=values, lines=lines, period_s=period)

    report = CheckReport()
    report.warnings += channels.sparse_channel(sig, where)
    report.warnings += units.metadata_period(sig, where, meta.get("sample_period_s"), sample_period_s)
    _check_time(
        frame,
        where,
        t,
        lines,
        sample_period_s=period,
        backwards_tolerance_samples=backwards_tolerance_samples,
        min_run_s=min_run_s,
    )
    units.temperature_unit(sig, where)
    _check_ranges(values, where, lines, max_speed_rpm, temp_range_c, open_circuit_values)
    if np.sum(~np.isnan(values["disp_um"])) >= min_samples:
        thresholds = {
            "stuck_std_um": stuck_std_um,
            "stuck_fraction": stuck_fraction,
            "stuck_max_s": stuck_max_s,
            "stuck_min_temp_change_k": stuck_min_temp_change_k,
        }
        _check_stuck_probe(values, where, lines, period, thresholds)
        report.warnings += units.displacement_unit(
            sig, where, mm_max_range_um=mm_max_range_um, mm_min_temp_rise_k=mm_min_temp_rise_k
        )
    report.warnings += channels.stuck_logger_and_constant(sig, where, speed_tolerance_rpm)
    report.warnings += channels.copied_channel(sig, where)
    report.warnings += channels.swapped_channels(sig, where)
    report.warnings += channels.idle_speed(sig, where, speed_tolerance_rpm)
    speed_unit = units.speed_unit(sig, where, training_speeds_rpm, speed_tolerance_rpm)
    report.warnings += speed_unit
    report.warnings += units.speed_range(
        sig, where, training_speeds_rpm, speed_tolerance_rpm, check_low=not speed_unit
    )
    report.warnings += units.metadata_machine(meta, machine)
    if meta.get("clock") is not False:  # a log without a clock has none to be unset
        report.warnings += units.clock_unset(frame["time"], where, lines)
    report.probe_sign = channels.probe_sign(sig)
    return report


def check_log(frame: pd.DataFrame, path: str | os.PathLike | None = None, **kwargs) -> pd.DataFrame:
    """:func:`check_file` for callers that want only the errors: returns ``frame`` itself (not
    copied), so calls can be chained; warnings are dropped (the clean step records them)."""
    check_file(frame, path, **kwargs)
    return frame
