"""Simulate one log of the twin: physics, then the logger (noise, quantisation, defects).

:func:`simulate_run` returns a :class:`TwinRun` with what the logger wrote, the noise- and
defect-free truth, the node temperatures and the table of injected defects (the ground truth
every consumer can compare against).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from rafi import SENSORS
from rafi.twin.defects import apply_defects, defect_record, plan_defects
from rafi.twin.machines import NODES, Ambient, DefectRates, TwinParams, machine_params
from rafi.twin.physics import (
    ambient_series,
    displacement_truth,
    integrate,
    sensor_truth,
    thermal_displacement,
)
from rafi.twin.schedules import Step, sample_schedule, schedule_from_pairs
from rafi.twin.signals import ar1


@dataclass
class TwinRun:
    """Result of :func:`simulate_run`.

    Attributes
    ----------
    log : DataFrame
        What the logger wrote: canonical columns ``time``, ``speed_rpm``, ``T1``..``T16``,
        ``disp_um`` with noise, quantisation and the injected defects (rows may be
        missing, duplicated or swapped; cells may hold spikes, NaN or open-circuit values).
        ``RangeIndex``: the position ``row`` used in :attr:`defects`.
    truth : DataFrame
        Same columns on the regular grid, noise-free and defect-free (sensor lag and
        calibration offsets included, because they are properties of the sensor).
    nodes : DataFrame
        ``time``, ``t_s``, ``speed_rpm``, ``ambient`` and every node temperature (degC),
        ``cooler_on`` (bool), ``disp_thermal_um`` and ``disp_centrifugal_um``.
    defects : DataFrame
        One row per injected defect: ``kind`` (missing_row, restart_gap, duplicate_row,
        swapped_rows, spike, dropout, stuck_displacement), ``row`` (0-based position in
        ``log`` of the first affected row; for missing_row / restart_gap the first row
        after the hole), ``n_rows``, ``column``, ``time`` (true time of the first affected
        sample), ``value`` and ``detail``.  In the written file the line number of
        position ``row`` is ``row + header_line + 1``.
    """

    log: pd.DataFrame
    truth: pd.DataFrame
    nodes: pd.DataFrame
    defects: pd.DataFrame
    params: TwinParams
    seed: int
    schedule: list


def _canonical(times, speeds, temps, disp) -> pd.DataFrame:
    data = {"time": pd.DatetimeIndex(times).astype("datetime64[ns]"), "speed_rpm": speeds}
    for j, name in enumerate(SENSORS):
        data[name] = temps[:, j]
    data["disp_um"] = disp
    return pd.DataFrame(data)


def _defect_rates(defects: bool | DefectRates | None) -> DefectRates:
    """The logger's defect rates: ``True`` the defaults, ``False``/``None`` none, else as given."""
    if defects is True:
        return DefectRates()
    if not defects:
        return DefectRates.none()
    return defects


def _node_frame(
    times: pd.Series,
    dt: float,
    speeds: np.ndarray,
    ambient: np.ndarray,
    nodes: np.ndarray,
    *,
    cooler: np.ndarray,
    disp_thermal: np.ndarray,
    disp_all: np.ndarray,
) -> pd.DataFrame:
    """The physics behind a run, one row per sample (:attr:`TwinRun.nodes`).

    Parameters
    ----------
    times : pandas.Series
        Time of each sample.
    dt : float
        Sample period (s).
    speeds : numpy.ndarray
        True spindle speed (r/min).
    ambient : numpy.ndarray
        Room temperature (degC).
    nodes : numpy.ndarray
        Node temperatures (samples x nodes, degC).
    cooler : numpy.ndarray
        Whether the oil cooler was on.
    disp_thermal, disp_all : numpy.ndarray
        Thermal and total (thermal + centrifugal) displacement (um).

    Returns
    -------
    pandas.DataFrame
        ``time``, ``t_s``, ``speed_rpm``, ``ambient``, one column per node, ``cooler_on``,
        ``disp_thermal_um`` and ``disp_centrifugal_um``.
    """
    n = len(speeds)
    frame = pd.DataFrame({"time": times, "t_s": np.arange(n) * dt, "speed_rpm": speeds, "ambient": ambient})
    for j, name in enumerate(NODES):
        frame[name] = nodes[:, j]
    frame["cooler_on"] = cooler
    frame["disp_thermal_um"] = disp_thermal
    frame["disp_centrifugal_um"] = disp_all - disp_thermal
    return frame


def _logged_readings(
    params: TwinParams,
    temps_true: np.ndarray,
    disp_true: np.ndarray,
    speeds: np.ndarray,
    dt: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What the logger reads of the true values: noise, then quantisation.

    Parameters
    ----------
    params : TwinParams
        Noise levels and quanta of the sensors.
    temps_true : numpy.ndarray
        True sensor temperatures (samples x 16, degC).
    disp_true : numpy.ndarray
        True displacement (um).
    speeds : numpy.ndarray
        True spindle speed (r/min).
    dt : float
        Sample period (s).
    rng : numpy.random.Generator
        The noise stream (drawn in a fixed order: temperature noise, white and slow
        displacement noise, temperature drafts, speed jitter).

    Returns
    -------
    temps, disp, speed : numpy.ndarray
        Temperatures and displacement with white noise plus a slow AR(1) part, rounded to
        the sensors' quanta; speed with whole-r/min jitter while the spindle turns (0 at rest).
    """
    n = len(speeds)
    temps = temps_true + rng.normal(0.0, params.temp_noise_c, temps_true.shape)
    white = rng.normal(0.0, params.disp_noise_um * 0.85, n)
    a = np.exp(-dt / 60.0)
    slow = ar1(rng.normal(0.0, params.disp_noise_um * 0.5, n), a, np.sqrt(1 - a * a))
    disp = disp_true + white + slow
    # sensor noise: white + a slow part (air drafts at the magnet/clay mounting)
    a2 = np.exp(-dt / 180.0)
    drafts = ar1(rng.normal(0.0, params.temp_noise_c * 0.8, temps_true.shape), a2, np.sqrt(1 - a2 * a2))
    temps = temps + drafts
    temps = np.round(temps / params.temp_quantum_c) * params.temp_quantum_c
    disp = np.round(disp / params.disp_quantum_um) * params.disp_quantum_um
    jitter = np.round(rng.normal(0.0, params.speed_jitter_rpm, n))
    speed_log = np.where(speeds > 0, speeds + jitter, 0.0)
    return temps, disp, speed_log


def _freeze_displacement(disp: np.ndarray) -> dict:
    """Freeze ``disp`` (in place) at its value at 25 % of the run; return the defect's record."""
    n = len(disp)
    k0 = int(0.25 * n)
    disp[k0:] = disp[k0]
    return defect_record(
        "stuck_displacement",
        k0,
        n - k0,
        "displacement frozen at its last value",
        column="disp_um",
        value=float(disp[k0]),
    )


def simulate_run(
    schedule: Sequence[Step] | Sequence[tuple[float, float]],
    *,
    params: TwinParams | None = None,
    machine: str = "tapping-center-a",
    seed: int = 0,
    start: str | pd.Timestamp = "2026-03-02T08:00:00",
    ambient: Ambient | None = None,
    defects: bool | DefectRates | None = True,
    noise: bool = True,
    sample_period_s: float = 5.0,
    sensor_drift: dict | None = None,
    wear: float = 0.0,
    stuck_displacement: bool = False,
    probe_zero_um: float | None = None,
    initial_nodes: np.ndarray | None = None,
) -> TwinRun:
    """Simulate one log of the twin.

    Parameters
    ----------
    schedule : list of Step or (duration_s, speed_rpm) pairs
        Speed steps; durations are rounded to whole samples.  The machine starts cold
        (every node at room temperature) unless ``initial_nodes`` is given.
    params : TwinParams, optional
        Physical constants; default ``machine_params(machine)``.
    seed : int
        Controls everything random (room wander, noise, probe zero, defects).  Noise and
        defects use independent streams, so ``defects=False`` keeps the same noise.
    start : timestamp
        Clock time of the first sample (sets the daily room-temperature phase).
    ambient : Ambient, optional
        Room model; default ``Ambient()``.
    defects : bool or DefectRates
        ``True`` = ``DefectRates()``; ``False``/``None`` = clean log.
    noise : bool
        ``False``: no noise, no quantisation (the log then equals the truth unless
        defects are injected).
    sample_period_s : float
        Logger period (also the integration step).
    sensor_drift : dict, optional
        Extra calibration drift per sensor, e.g. ``{"T8": 0.4}`` (degC).
    wear : float
        Relative increase of bearing friction (0.1 = +10 %).
    stuck_displacement : bool
        Deliberately broken log: from 25 % of the run on the displacement channel repeats
        its last value (a frozen probe).
    probe_zero_um : float, optional
        Probe reading at the cold state; default random in +-``params.probe_offset_um``.
    """
    params = params or machine_params(machine)
    ambient = ambient or Ambient()
    rates = _defect_rates(defects)
    steps = schedule_from_pairs(schedule)
    dt = float(sample_period_s)
    speeds = sample_schedule(steps, dt)
    n = len(speeds)
    times = pd.Timestamp(start) + pd.to_timedelta(np.arange(n) * dt, unit="s")
    ss = np.random.SeedSequence(int(seed))
    rng_amb, rng_noise, rng_def, rng_probe = (np.random.default_rng(s) for s in ss.spawn(4))

    t_amb = ambient_series(ambient, times, rng_amb)
    nodes, cooler = integrate(params, speeds, t_amb, dt, wear=wear, x0=initial_nodes)
    x_ref = np.full(len(NODES), t_amb[0]) if initial_nodes is None else np.asarray(initial_nodes, float)
    z_th = thermal_displacement(params, nodes, x_ref)
    z_all = displacement_truth(params, nodes, speeds, dt, x_ref)
    zero = (
        float(probe_zero_um)
        if probe_zero_um is not None
        else float(rng_probe.uniform(-1, 1) * params.probe_offset_um)
    )
    disp_true = z_all + zero
    temps_true = sensor_truth(params, nodes, t_amb, dt, sensor_drift)
    truth = _canonical(times, speeds, temps_true, disp_true)
    node_frame = _node_frame(
        truth["time"], dt, speeds, t_amb, nodes, cooler=cooler, disp_thermal=z_th, disp_all=z_all
    )

    # the logger: noise and quantisation (per true sample, so duplicates are copies)
    if noise:
        temps, disp, speed_log = _logged_readings(params, temps_true, disp_true, speeds, dt, rng_noise)
    else:
        temps, disp, speed_log = temps_true.copy(), disp_true.copy(), speeds.copy()
    records: list[dict] = [_freeze_displacement(disp)] if stuck_displacement else []
    order, records, cells = plan_defects(rates, n, dt, rng_def, records)
    log = _canonical(times[order], speed_log[order], temps[order], disp[order])
    defect_table = apply_defects(records, cells, log, order, times)
    log.attrs.clear()
    return TwinRun(
        log=log,
        truth=truth,
        nodes=node_frame,
        defects=defect_table,
        params=params,
        seed=int(seed),
        schedule=steps,
    )
