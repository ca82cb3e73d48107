"""Ground-truth generators for the clean / runs / equilibrium tests.

In the style of ``ruptures.datasets`` (``pw_constant(n, dim, n_bkps, ...) ->
(signal, bkps)``): every generator returns the data AND the truth it was built
from, so a test can compare what the code finds with what was put in.

* :func:`thermal_response` - noise-free first-order temperatures and displacement
  for any speed profile (independent of the twin's physics, ``rafi.twin.physics``).
* :func:`canonical_log` - a regular, defect-free canonical frame (as
  ``rafi.readers.native.read_raw_log`` returns it) and its noise-free truth.
* :func:`inject_defects` - duplicates, swaps, spikes, dropouts, open-circuit
  values and gaps injected into a canonical log at random, non-interacting
  places; returns the defective frame and a defect table with the SOURCE lines
  the audit must report (:mod:`rafi.twin.synthetic_defects`, imported here).
* :func:`schedule_log` - a clean frame (``rafi.method.clean`` output format) following a
  speed schedule, with the true piece boundaries.
* :func:`first_order_run` - ``dz = rise (1 - exp(-t / tau))`` plus noise.

Everything is deterministic given ``seed``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rafi import SENSORS
from rafi.twin.schedules import Step, sample_schedule, speed_at
from rafi.twin.signals import first_order, step_response
from rafi.twin.synthetic_defects import OPEN_CIRCUIT, inject_defects  # noqa: F401 (part of this module's API)

START = pd.Timestamp("2026-03-02T08:00:00")
AMBIENT_C = 22.0
#: Rise of each sensor at 18000 r/min (K) and its time-constant factor.
GAIN = np.array([1.5, 1.4, 1.6, 2.0, 1.2, 9.0, 2.2, 7.5, 8.0, 5.0, 0.8, 1.1, 0.9, 3.0, 1.0, 8.5])
LAG = np.array([1.6, 1.7, 1.5, 1.4, 1.3, 1.0, 1.5, 1.05, 0.95, 1.2, 2.0, 1.8, 1.9, 1.3, 1.8, 1.1])
#: Thermal displacement plateau at 18000 r/min (um) and centrifugal growth coefficient (um/rpm^2).
DISP_GAIN_UM = 28.0
CENTRIFUGAL_UM_PER_RPM2 = 1.5e-8

H = 3600.0
#: A continuous log's schedule: 4 constant runs and idles (one too short), then a varying tail
#: with a short stop inside it (speed r/min, duration s).
CONTINUOUS_SCHEDULE = [
    (3000, 4 * H),
    (0, H),
    (6000, 4 * H),
    (0, 600),
    (4500, 3 * H),
    (0, 2700),
    (9000, 2 * H),
    (0, H),
    (3000, 1200),
    (9000, 1200),
    (0, 300),
    (12000, 1200),
    (6000, 1200),
]
#: ``rafi.method.clean.clean_log`` keyword arguments that fit these logs (5 s samples).
CLEAN_KWARGS = dict(
    file="log.csv",
    sample_period_s=5.0,
    max_interpolate_gap_s=60.0,
    spike_threshold=8.0,
    open_circuit_values=[-999.0, 999.9, 850.0],
)
#: ``rafi.method.runs.find_runs`` keyword arguments that fit these logs.
FIND_RUNS_KWARGS = dict(
    training_speeds_rpm=[3000, 6000, 9000, 12000, 15000, 18000],
    speed_tolerance_rpm=50,
    idle_below_rpm=100,
    min_run_s=1800,
    min_constant_s=3600,
    overrides={},
    reference_rule="run_start",
    reference_window_s=60,
    max_leading_rest_s=300,
)


def thermal_response(
    speed_rpm, period_s: float = 5.0, *, tau_s: float = 2400.0
) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free temperature rises (n x 16, K) and displacement (n, um) for a speed profile.

    Each sensor follows a first-order lag (time constant ``tau_s * LAG``) towards
    ``GAIN * (speed / 18000) ** 0.9``; the displacement lags towards
    ``DISP_GAIN_UM * (speed / 18000) ** 0.8`` with ``tau_s`` and jumps by the
    centrifugal term ``CENTRIFUGAL_UM_PER_RPM2 * speed**2`` at speed changes.
    """
    s = np.asarray(speed_rpm, dtype=float)
    frac = np.clip(s, 0, None) / 18000.0
    u_t = (frac**0.9)[:, None] * GAIN[None, :]
    rises = np.column_stack([first_order(u_t[:, i], period_s, tau_s * LAG[i]) for i in range(16)])
    z = first_order(DISP_GAIN_UM * frac**0.8, period_s, tau_s) + CENTRIFUGAL_UM_PER_RPM2 * s**2
    return rises, z


def _observe(
    rises: np.ndarray, z: np.ndarray, rng: np.random.Generator, noise_temp: float, noise_disp: float
):
    """True temperatures, and temperatures and displacement with Gaussian noise (in this order of draws)."""
    temps = AMBIENT_C + rises
    return temps, temps + rng.normal(0, noise_temp, temps.shape), z + rng.normal(0, noise_disp, len(z))


def _set_readings(frame: pd.DataFrame, temps: np.ndarray, disp: np.ndarray) -> None:
    """Columns ``T1``..``T16`` and ``disp_um`` of ``frame`` (in place)."""
    for i, name in enumerate(SENSORS):
        frame[name] = temps[:, i]
    frame["disp_um"] = disp


def canonical_log(
    n_samples: int = 3000,
    *,
    period_s: float = 5.0,
    steps=((0.0, 6000.0), (7500.0, 9000.0)),
    noise_temp: float = 0.02,
    noise_disp: float = 0.1,
    seed: int = 0,
    start: pd.Timestamp = START,
    first_line: int = 2,
    extras: bool = True,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """A regular, defect-free canonical frame and its noise-free truth.

    Parameters
    ----------
    n_samples : int
        Rows.
    period_s : float
        Sample period.
    steps : sequence of (t_s, speed_rpm)
        Piecewise-constant speed: ``speed_rpm`` from ``t_s`` on (first at 0).
    noise_temp, noise_disp : float
        Gaussian noise (K, um) added to the temperatures / displacement.
    seed : int
        Random seed.
    start : pandas.Timestamp
        Time of the first sample.
    first_line : int
        Source line of the first data row (2 = header on line 1, no metadata).
    extras : bool
        Add a numeric extra ``ambient_c`` and a text extra ``operator``.

    Returns
    -------
    log : pandas.DataFrame
        Canonical frame (index ``line``): ``time``, ``speed_rpm``, ``T1``..``T16``,
        ``disp_um`` (+ extras); what a perfect logger would have written.
    truth : pandas.DataFrame
        Same index and numeric columns without noise, plus ``t_s``.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(n_samples) * period_s
    speed = speed_at(t, steps)
    rises, z = thermal_response(speed, period_s)
    index = pd.Index(np.arange(first_line, first_line + n_samples), name="line")
    time = start + pd.to_timedelta(t, unit="s")
    truth = pd.DataFrame({"time": time, "t_s": t, "speed_rpm": speed}, index=index)
    log = pd.DataFrame({"time": time, "speed_rpm": speed}, index=index)
    temps, noisy, disp = _observe(rises, z, rng, noise_temp, noise_disp)
    _set_readings(truth, temps, z)
    _set_readings(log, noisy, disp)
    if extras:
        amb = AMBIENT_C + 0.5 * np.sin(2 * np.pi * t / 86400.0)
        truth["ambient_c"] = amb
        log["ambient_c"] = amb
        log["operator"] = pd.array(np.where(np.arange(n_samples) % 2, "ab", "cd"), dtype="str")
    log["time"] = log["time"].astype("datetime64[ns]")
    truth["time"] = truth["time"].astype("datetime64[ns]")
    return log, truth


def schedule_log(
    schedule,
    *,
    period_s: float = 5.0,
    seed: int = 0,
    ramp_samples: int = 0,
    speed_noise_rpm: float = 0.0,
    noise_temp: float = 0.02,
    noise_disp: float = 0.1,
    start: pd.Timestamp = START,
    segment: int = 0,
    t0_s: float = 0.0,
    tau_s: float = 2400.0,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """A clean frame (``rafi.method.clean`` format) that follows a speed schedule.

    Parameters
    ----------
    schedule : sequence of (speed_rpm, duration_s)
        Pieces in time order; durations are whole multiples of ``period_s``.
    period_s : float
        Sample period.
    seed : int
        Random seed of the noise.
    ramp_samples : int
        Samples at the start of each piece (after the first) whose speed ramps
        linearly from the previous speed (as a controller log shows a spindle
        ramping); they belong to the new piece in the truth.
    speed_noise_rpm : float
        Uniform speed noise (+-) added to non-idle samples.
    noise_temp, noise_disp : float
        Gaussian noise of temperatures (K) and displacement (um).
    start : pandas.Timestamp
        Time at ``t_s == t0_s``.
    segment : int
        Value of the ``segment`` column.
    t0_s : float
        ``t_s`` of the first sample.
    tau_s : float
        Thermal time constant.

    Returns
    -------
    frame : pandas.DataFrame
        ``time``, ``t_s``, ``speed_rpm``, ``T1``..``T16``, ``disp_um``, ``segment``.
    pieces : pandas.DataFrame
        Truth: ``speed_rpm``, ``start_s``, ``end_s`` (t_s of the last sample),
        ``duration_s`` (samples x period), ``first_row``, ``last_row``.
    """
    rng = np.random.default_rng(seed)
    counts = [int(round(d / period_s)) for _, d in schedule]
    speed = sample_schedule([Step(d, s) for s, d in schedule], period_s)
    bounds = np.concatenate(([0], np.cumsum(counts)))
    for k in range(1, len(schedule)):
        a, b = float(schedule[k - 1][0]), float(schedule[k][0])
        for r in range(min(ramp_samples, counts[k] - 1)):
            speed[bounds[k] + r] = a + (b - a) * (r + 1) / (ramp_samples + 1)
    if speed_noise_rpm:
        moving = speed > 0
        speed[moving] += rng.uniform(-speed_noise_rpm, speed_noise_rpm, moving.sum())
    n = len(speed)
    t = t0_s + np.arange(n) * period_s
    rises, z = thermal_response(speed, period_s, tau_s=tau_s)
    frame = pd.DataFrame(
        {
            "time": (start + pd.to_timedelta(t - t0_s, unit="s")).astype("datetime64[ns]"),
            "t_s": t,
            "speed_rpm": speed,
        }
    )
    _, temps, disp = _observe(rises, z, rng, noise_temp, noise_disp)
    _set_readings(frame, temps, disp)
    frame["segment"] = np.int64(segment)
    pieces = pd.DataFrame(
        {
            "speed_rpm": [float(s) for s, _ in schedule],
            "start_s": t[bounds[:-1]],
            "end_s": t[bounds[1:] - 1],
            "duration_s": np.asarray(counts, float) * period_s,
            "first_row": bounds[:-1],
            "last_row": bounds[1:] - 1,
        }
    )
    return frame, pieces


def first_order_run(
    *,
    tau_s: float = 2000.0,
    rise_um: float = 20.0,
    duration_s: float = 14400.0,
    period_s: float = 5.0,
    noise_um: float = 0.1,
    offset_um: float = 0.0,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """``dz = offset + rise (1 - exp(-t / tau)) + noise`` on a regular grid.

    The true time to enter a band of ``f * rise`` around the asymptote is
    ``tau * ln(1 / f)``.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(int(round(duration_s / period_s))) * period_s
    dz = offset_um + step_response(t, rise_um, tau_s) + rng.normal(0, noise_um, len(t))
    return t, dz
