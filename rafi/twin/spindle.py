"""Physics-based digital twin of a motorised CNC spindle (the paper's rig and a second machine).

A lumped thermal network (10 nodes) is integrated exactly at the sample step with a
zero-order-hold exponential integrator (``expm`` of the augmented system, cached per
speed), so a 4 h run at 5 s takes a few milliseconds.  An on/off oil cooler with a
hysteresis thermostat tracks the room temperature; it makes the coolant temperatures
cycle like on a real machine.  Sixteen sensors read mixes of node temperatures through
their own first-order lag, calibration offset, noise and 0.01 degC quantisation.  The
axial displacement is the thermal expansion of shaft, cartridge, head and column plus the
centrifugal draw-in of the BT30 holder (~n^2, a jump when the speed changes) and noise.
Logger defects (missing rows, restart gaps, duplicates, spikes, sensor dropouts, swapped
rows) are injected at documented, seed-controlled rates and reported in a table.

Public API (see ``docs/twin.md``)::

    Step, TwinParams, Ambient, DefectRates, TwinRun, RunSpec
    machine_params(machine) -> TwinParams
    simulate_run(schedule, *, params=None, seed=0, start=..., ambient=None,
                 defects=True, noise=True, sample_period_s=5.0, ...) -> TwinRun
    constant_schedule(speed_rpm, duration_s), multi_condition_schedule(...)
    shipped_specs(machine) -> list[RunSpec]; write_shipped(out_dir, machines=...)
    write_day(out_dir, machine=..., seed=..., ...); plot_runs(paths, out_dir)

``import rafi.twin.spindle`` only needs NumPy, SciPy and pandas (matplotlib and openpyxl are
imported inside the functions that need them).
"""

from __future__ import annotations

import datetime as _dt
import io
import os
import re
import zipfile
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.linalg import expm
from scipy.signal import lfilter

from rafi import SENSORS

# --------------------------------------------------------------------------- nodes

#: Lumped nodes of the thermal network, in state-vector order.
NODES = (
    "shaft",
    "front_bearing",
    "rear_bearing",
    "stator",
    "motor_base",
    "housing",
    "coolant",
    "tank",
    "head",
    "column",
)
_N = len(NODES)
_I = {name: i for i, name in enumerate(NODES)}
#: Extra "node" name usable in sensor mixes: the room air.
AMBIENT = "ambient"

#: Speed normalisation (r/min) used in every speed law below.
N_REF = 10000.0


@dataclass(frozen=True)
class Step:
    """One step of a speed schedule: hold ``speed_rpm`` for ``duration_s`` seconds."""

    duration_s: float
    speed_rpm: float


@dataclass(frozen=True)
class Ambient:
    """Room temperature model (degC) at clock time.

    ``T(t) = base_c + daily_amplitude_c * cos(2 pi (hour - peak_hour) / 24)
    + drift_c_per_h * hours_since_start + wander`` where ``wander`` is a smooth seeded
    random signal (sum of sinusoids with periods of 40 min .. 6 h) of RMS ``wander_c``.
    """

    base_c: float = 22.0
    daily_amplitude_c: float = 0.6
    peak_hour: float = 15.0
    drift_c_per_h: float = 0.0
    wander_c: float = 0.08


@dataclass(frozen=True)
class DefectRates:
    """Logger-defect rates (all seed-controlled; ``DefectRates.none()`` disables them).

    Rates are per data row unless named otherwise.
    """

    missing_row: float = 0.002  # single rows lost
    restart_gap_prob: float = 0.5  # probability that a file has one logger restart gap
    restart_gap_s: tuple[float, float] = (20.0, 50.0)
    duplicate_row: float = 0.001  # rows written twice (identical copy right after)
    spike_per_1000_rows: float = 1.5  # single-sample spikes (one cell) per 1000 rows
    dropout_prob: float = 0.5  # probability of one sensor dropout per file
    dropout_s: tuple[float, float] = (60.0, 600.0)
    swap_per_1000_rows: float = 0.7  # two adjacent rows written in swapped order

    @staticmethod
    def none() -> DefectRates:
        return DefectRates(0.0, 0.0, (0.0, 0.0), 0.0, 0.0, 0.0, (0.0, 0.0), 0.0)

    @staticmethod
    def light() -> DefectRates:
        """The light defect level of the continuous machining-center-b log."""
        return DefectRates(
            missing_row=0.001,
            restart_gap_prob=0.0,
            duplicate_row=0.0,
            spike_per_1000_rows=0.4,
            dropout_prob=1.0,
            dropout_s=(120.0, 300.0),
            swap_per_1000_rows=0.0,
        )


@dataclass(frozen=True)
class SensorSpec:
    """One temperature sensor: a mix of node temperatures seen through a lag."""

    name: str
    position: str
    mix: tuple[tuple[str, float], ...]
    lag_s: float
    offset_c: float


@dataclass(frozen=True)
class TwinParams:
    """Every physical constant of one machine (SI units, W, J/K, W/K, um/K)."""

    machine: str
    #: heat capacities per node, J/K
    capacity: dict = field(default_factory=dict)
    #: fixed conductances between nodes, W/K: {(a, b): G}
    links: dict = field(default_factory=dict)
    #: conductances that grow with speed: {(a, b): (G0, G1, exponent)} -> G0 + G1 (n/N_REF)^exp
    speed_links: dict = field(default_factory=dict)
    #: conductances to room air: {node: (G0, G1, exponent)}
    to_ambient: dict = field(default_factory=dict)
    #: coolant mass flow times heat capacity, W/K (jacket <-> tank loop)
    coolant_flow_w_per_k: float = 0.0
    cooler_power_w: float = 0.0
    cooler_hysteresis_c: float = 0.8
    cooler_offset_c: float = -0.2
    #: heat sources
    bearing_front_w: float = 0.0  # at N_REF, scales (n/N_REF)^(5/3)
    bearing_rear_w: float = 0.0
    bearing_to_shaft: float = 0.5  # share of bearing friction entering the shaft (inner ring)
    motor_magnetising_w: float = 0.0  # stator copper loss of the magnetising current (< base speed)
    motor_base_speed_rpm: float = 8000.0
    motor_iron_w: float = 0.0  # at N_REF, scales (n/N_REF)^1.4
    rotor_w: float = 0.0  # rotor losses + windage at N_REF, scales (n/N_REF)^2
    #: displacement sensitivities, um per K of node rise (negative: moves away from table)
    disp_gain: dict = field(default_factory=dict)
    centrifugal_um: float = 0.0  # draw-in at N_REF (um, sign: negative = away), ~n^2
    centrifugal_lag_s: float = 8.0
    #: sensors
    sensors: tuple[SensorSpec, ...] = ()
    temp_noise_c: float = 0.05
    temp_quantum_c: float = 0.01
    disp_noise_um: float = 0.2
    disp_quantum_um: float = 0.001
    speed_jitter_rpm: float = 1.0
    probe_offset_um: float = 2.0  # |random| probe zero offset per run (uniform +-)


def _sensor_table(
    offsets: Sequence[float], lags: Sequence[float], mixes: Sequence[dict], positions: Sequence[str]
) -> tuple[SensorSpec, ...]:
    out = []
    for i, (off, lag, mix, pos) in enumerate(zip(offsets, lags, mixes, positions), start=1):
        total = sum(mix.values())
        out.append(
            SensorSpec(f"T{i}", pos, tuple((k, v / total) for k, v in mix.items()), float(lag), float(off))
        )
    return tuple(out)


#: Paper Table 2 positions.
POSITIONS = (
    "spindle coolant exit point, right side",
    "spindle coolant exit point, right side",
    "spindle coolant exit point, right side",
    "right spindle coolant outlet",
    "spindle coolant outlet",
    "spindle motor base",
    "right spindle coolant outlet",
    "rear spindle bearing",
    "rear spindle bearing",
    "spindle front, behind tool magazine",
    "spindle coolant inlet",
    "spindle coolant inlet, left side",
    "under the spindle head, near the Z rail",
    "spindle coolant inlet, left side",
    "spindle coolant inlet, left side",
    "spindle motor base",
)

#: Sensor mixes (weights, normalised to 1) per Table 2 position.
MIXES_A = (
    {"coolant": 0.72, "housing": 0.12, "head": 0.04, AMBIENT: 0.12},  # T1 exit right
    {"coolant": 0.76, "housing": 0.10, "head": 0.04, AMBIENT: 0.10},  # T2
    {"coolant": 0.66, "housing": 0.11, "tank": 0.10, AMBIENT: 0.13},  # T3
    {"coolant": 0.78, "motor_base": 0.08, AMBIENT: 0.14},  # T4 right outlet
    {"coolant": 0.88, "motor_base": 0.04, AMBIENT: 0.08},  # T5 outlet
    {"motor_base": 0.62, "stator": 0.15, "rear_bearing": 0.10, "head": 0.08, AMBIENT: 0.05},  # T6
    {"coolant": 0.74, "housing": 0.10, AMBIENT: 0.16},  # T7 right outlet
    {"rear_bearing": 0.55, "motor_base": 0.30, "head": 0.10, AMBIENT: 0.05},  # T8 rear bearing
    {"rear_bearing": 0.45, "motor_base": 0.35, "head": 0.14, AMBIENT: 0.06},  # T9 rear bearing
    {"housing": 0.30, "front_bearing": 0.08, "head": 0.22, AMBIENT: 0.40},  # T10 front, magazine
    {"tank": 0.86, "head": 0.04, AMBIENT: 0.10},  # T11 inlet
    {"tank": 0.70, "housing": 0.12, AMBIENT: 0.18},  # T12 inlet left
    {"head": 0.50, "column": 0.30, AMBIENT: 0.20},  # T13 under head, Z rail
    {"tank": 0.66, "housing": 0.14, "head": 0.05, AMBIENT: 0.15},  # T14 inlet left
    {"tank": 0.74, "housing": 0.08, AMBIENT: 0.18},  # T15 inlet left
    {"motor_base": 0.46, "head": 0.34, "column": 0.05, AMBIENT: 0.15},  # T16 motor base (far)
)
LAGS_A = (40, 45, 50, 35, 30, 120, 40, 90, 110, 150, 30, 45, 240, 50, 45, 180)
OFFSETS_A = (
    0.12,
    -0.08,
    0.21,
    -0.15,
    0.05,
    0.18,
    -0.22,
    0.09,
    -0.11,
    0.25,
    -0.04,
    0.14,
    -0.19,
    0.07,
    -0.06,
    0.16,
)


def tapping_center_a() -> TwinParams:
    """Parameters of the paper's rig: PMC tapping center, BT30 built-in spindle."""
    return TwinParams(
        machine="tapping-center-a",
        capacity={
            "shaft": 3200.0,
            "front_bearing": 900.0,
            "rear_bearing": 700.0,
            "stator": 4000.0,
            "motor_base": 9000.0,
            "housing": 8000.0,
            "coolant": 1200.0,
            "tank": 60000.0,
            "head": 104000.0,
            "column": 600000.0,
        },
        links={
            ("shaft", "front_bearing"): 6.0,
            ("shaft", "rear_bearing"): 4.0,
            ("front_bearing", "housing"): 10.0,
            ("rear_bearing", "motor_base"): 5.0,
            ("stator", "coolant"): 22.0,
            ("stator", "motor_base"): 6.0,
            ("motor_base", "coolant"): 4.0,
            ("housing", "coolant"): 8.0,
            ("motor_base", "housing"): 4.0,
            ("housing", "head"): 6.0,
            ("motor_base", "head"): 5.0,
            ("head", "column"): 10.0,
        },
        speed_links={("shaft", "stator"): (1.5, 4.0, 0.8)},
        to_ambient={
            "shaft": (0.5, 2.07, 0.8),
            "housing": (1.0, 1.0, 0.8),
            "motor_base": (1.0, 0.0, 1.0),
            "head": (14.0, 0.0, 1.0),
            "column": (60.0, 0.0, 1.0),
            "tank": (6.0, 0.0, 1.0),
        },
        coolant_flow_w_per_k=250.0,
        cooler_power_w=900.0,
        cooler_hysteresis_c=1.0,
        cooler_offset_c=-0.2,
        bearing_front_w=45.0,
        bearing_rear_w=22.5,
        bearing_to_shaft=0.55,
        motor_magnetising_w=345.0,
        motor_base_speed_rpm=10500.0,
        motor_iron_w=134.0,
        rotor_w=30.0,
        disp_gain={"shaft": 0.9, "housing": 0.47, "motor_base": 0.39, "head": 1.19, "column": -0.5},
        centrifugal_um=-0.6,
        centrifugal_lag_s=8.0,
        sensors=_sensor_table(OFFSETS_A, LAGS_A, MIXES_A, POSITIONS),
    )


_MACHINES = {"tapping-center-a": tapping_center_a}


def machine_params(machine: str) -> TwinParams:
    """Twin parameters of a shipped machine by id."""
    try:
        return _MACHINES[machine]()
    except KeyError:
        raise ValueError(f"unknown machine {machine!r}; known: {', '.join(_MACHINES)}") from None


# --------------------------------------------------------------------------- physics


def heat_sources(params: TwinParams, speed_rpm: float, wear: float = 0.0) -> np.ndarray:
    """Heat input per node (W) at a constant speed; ``wear`` raises bearing friction."""
    n = abs(float(speed_rpm))
    q = np.zeros(_N)
    if n <= 0:
        return q
    r = n / N_REF
    fb = params.bearing_front_w * r ** (5.0 / 3.0) * (1.0 + wear)
    rb = params.bearing_rear_w * r ** (5.0 / 3.0) * (1.0 + wear)
    s = params.bearing_to_shaft
    q[_I["front_bearing"]] += fb * (1 - s)
    q[_I["rear_bearing"]] += rb * (1 - s)
    q[_I["shaft"]] += (fb + rb) * s
    field_weak = min(1.0, params.motor_base_speed_rpm / n) ** 2
    # above base speed the flux is weakened (~1/n): magnetising copper loss ~ 1/n^2,
    # iron loss ~ f^1.4 B^2
    q[_I["stator"]] += (params.motor_magnetising_w + params.motor_iron_w * r**1.4) * field_weak
    q[_I["shaft"]] += params.rotor_w * r**2
    return q


def _system(params: TwinParams, speed_rpm: float, wear: float) -> tuple[np.ndarray, np.ndarray]:
    """Continuous system x' = A x + B u, u = [T_ambient, 1, cooler_on]."""
    n = abs(float(speed_rpm))
    r = n / N_REF
    G = np.zeros((_N, _N))

    def add(a, b, g):
        i, j = _I[a], _I[b]
        G[i, j] += g
        G[j, i] += g

    for (a, b), g in params.links.items():
        add(a, b, g)
    for (a, b), (g0, g1, e) in params.speed_links.items():
        add(a, b, g0 + g1 * r**e)
    add("coolant", "tank", params.coolant_flow_w_per_k)  # well-mixed jacket, loop to the tank
    ga = np.zeros(_N)
    for node, (g0, g1, e) in params.to_ambient.items():
        ga[_I[node]] += g0 + g1 * r**e
    cap = np.array([params.capacity[nm] for nm in NODES])
    A = (G - np.diag(G.sum(axis=1) + ga)) / cap[:, None]
    B = np.zeros((_N, 3))
    B[:, 0] = ga / cap
    B[:, 1] = heat_sources(params, n, wear) / cap
    B[_I["tank"], 2] = -params.cooler_power_w / cap[_I["tank"]]
    return A, B


def _discrete(params: TwinParams, speed_rpm: float, dt: float, wear: float):
    A, B = _system(params, speed_rpm, wear)
    M = np.zeros((_N + 3, _N + 3))
    M[:_N, :_N] = A
    M[:_N, _N:] = B
    E = expm(M * dt)
    return E[:_N, :_N], E[:_N, _N:]


def ambient_series(ambient: Ambient, times: pd.DatetimeIndex, rng: np.random.Generator) -> np.ndarray:
    """Room temperature at the given clock times (seeded wander)."""
    t0 = times[0]
    hours = np.asarray((times - t0) / pd.Timedelta(hours=1), dtype=float)
    clock = (t0.hour + t0.minute / 60 + t0.second / 3600) + hours
    temp = ambient.base_c + ambient.daily_amplitude_c * np.cos(2 * np.pi * (clock - ambient.peak_hour) / 24)
    temp = temp + ambient.drift_c_per_h * hours
    periods = rng.uniform(0.7, 6.0, size=6)
    phases = rng.uniform(0, 2 * np.pi, size=6)
    amps = rng.normal(0, 1, size=6)
    wander = sum(a * np.sin(2 * np.pi * hours / p + ph) for a, p, ph in zip(amps, periods, phases))
    rms = np.sqrt(np.sum(amps**2) / 2) or 1.0
    return temp + ambient.wander_c * wander / rms


def _schedule_speeds(schedule: Sequence[Step], dt: float) -> np.ndarray:
    speeds = []
    for st in schedule:
        k = int(round(st.duration_s / dt))
        if k <= 0:
            continue
        speeds.extend([float(st.speed_rpm)] * k)
    if not speeds:
        raise ValueError("the schedule is empty")
    return np.asarray(speeds)


def integrate(
    params: TwinParams,
    speeds: np.ndarray,
    t_amb: np.ndarray,
    dt: float,
    *,
    wear: float = 0.0,
    x0: np.ndarray | None = None,
    cooler_on0: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Integrate the network: node temperatures (n x nodes) at each sample and cooler state.

    Sample ``k`` is the state at the sample instant; the speed and room temperature of
    sample ``k`` are held over the interval to sample ``k + 1`` (zero-order hold, exact).
    The cooler thermostat is evaluated at each sample (on above set + h/2, off below
    set - h/2, set = room + offset).
    """
    n = len(speeds)
    x = np.full(_N, t_amb[0]) if x0 is None else np.array(x0, dtype=float)
    cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
    out = np.empty((n, _N))
    cooler = np.zeros(n, dtype=bool)
    on = bool(cooler_on0)
    half = params.cooler_hysteresis_c / 2
    it = _I["tank"]
    for k in range(n):
        out[k] = x
        sp = float(speeds[k])
        if sp not in cache:
            cache[sp] = _discrete(params, sp, dt, wear)
        Phi, Gam = cache[sp]
        sp_set = t_amb[k] + params.cooler_offset_c
        if x[it] > sp_set + half:
            on = True
        elif x[it] < sp_set - half:
            on = False
        cooler[k] = on
        x = Phi @ x + Gam @ np.array([t_amb[k], 1.0, 1.0 if on else 0.0])
    return out, cooler


def _lag(signal: np.ndarray, lag_s: float, dt: float) -> np.ndarray:
    """First-order lag sampled at dt, starting in steady state."""
    if lag_s <= 0:
        return signal.copy()
    a = np.exp(-dt / lag_s)
    y, _ = lfilter([1 - a], [1, -a], signal, zi=[a * signal[0]])
    return y


def displacement_truth(
    params: TwinParams, nodes: np.ndarray, speeds: np.ndarray, dt: float, x_ref: np.ndarray
) -> np.ndarray:
    """Noise-free axial displacement (um): thermal expansion + centrifugal draw-in."""
    z = np.zeros(len(nodes))
    for node, gain in params.disp_gain.items():
        z += gain * (nodes[:, _I[node]] - x_ref[_I[node]])
    cf = params.centrifugal_um * (np.abs(speeds) / N_REF) ** 2
    # the draw-in follows the speed within seconds: a visible jump at each speed change
    a = np.exp(-dt / params.centrifugal_lag_s)
    prev = np.concatenate([[cf[0]], cf[:-1]])
    z += prev + (cf - prev) * (1 - a)
    return z


def sensor_truth(
    params: TwinParams, nodes: np.ndarray, t_amb: np.ndarray, dt: float, drift: dict | None = None
) -> np.ndarray:
    """Noise-free sensor readings (n x 16): node mix, own lag, calibration offset (+ drift)."""
    drift = drift or {}
    out = np.empty((len(nodes), len(params.sensors)))
    for j, s in enumerate(params.sensors):
        mixed = np.zeros(len(nodes))
        for name, w in s.mix:
            mixed += w * (t_amb if name == AMBIENT else nodes[:, _I[name]])
        out[:, j] = _lag(mixed, s.lag_s, dt) + s.offset_c + drift.get(s.name, 0.0)
    return out


# --------------------------------------------------------------------------- schedules


def constant_schedule(speed_rpm: float, duration_s: float) -> list[Step]:
    """A single constant-speed step."""
    return [Step(float(duration_s), float(speed_rpm))]


def schedule_from_pairs(pairs: Iterable[tuple[float, float]]) -> list[Step]:
    """Build a schedule from ``(duration_s, speed_rpm)`` pairs."""
    return [Step(float(d), float(n)) for d, n in pairs]


#: The 4.5 h multi-condition schedule of tapping-center-a (paper Figure 13 style):
#: (minutes, r/min) across trained and untrained speeds.
MULTI_CONDITION_A = (
    (30, 3000),
    (35, 9000),
    (30, 4500),
    (40, 18000),
    (35, 6000),
    (35, 15000),
    (30, 10500),
    (35, 13500),
)


def multi_condition_schedule(steps_min: Sequence[tuple[float, float]] = MULTI_CONDITION_A) -> list[Step]:
    """A varying-speed schedule from ``(minutes, r/min)`` steps."""
    return [Step(60.0 * m, float(n)) for m, n in steps_min]


def schedule_duration_s(schedule: Sequence[Step]) -> float:
    return float(sum(st.duration_s for st in schedule))


#: Rest (spindle at 0 r/min) logged before the spindle starts in every cold-start log of
#: tapping-center-a (shipped and ``day`` mode): the logger is started with the machine cold
#: and at rest, then the spindle is started. The reference window (first 60 s) falls on it.
REST_BEFORE_START_S = 180.0


def with_rest(schedule: Sequence[Step], rest_s: float = REST_BEFORE_START_S) -> list[Step]:
    """``schedule`` preceded by ``rest_s`` seconds at 0 r/min (cold machine at rest)."""
    steps = list(schedule)
    return ([Step(float(rest_s), 0.0)] if rest_s > 0 else []) + steps


# --------------------------------------------------------------------------- the run


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


DEFECT_COLUMNS = ("kind", "row", "n_rows", "column", "time", "value", "detail")
OPEN_CIRCUIT_VALUES = (-999.0, 850.0)


def _canonical(times, speeds, temps, disp) -> pd.DataFrame:
    data = {"time": pd.DatetimeIndex(times).astype("datetime64[ns]"), "speed_rpm": speeds}
    for j, name in enumerate(SENSORS):
        data[name] = temps[:, j]
    data["disp_um"] = disp
    return pd.DataFrame(data)


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
    if defects is True:
        rates = DefectRates()
    elif not defects:
        rates = DefectRates.none()
    else:
        rates = defects
    steps = [st if isinstance(st, Step) else Step(float(st[0]), float(st[1])) for st in schedule]
    dt = float(sample_period_s)
    speeds = _schedule_speeds(steps, dt)
    n = len(speeds)
    start_ts = pd.Timestamp(start)
    times = start_ts + pd.to_timedelta(np.arange(n) * dt, unit="s")
    ss = np.random.SeedSequence(int(seed))
    rng_amb, rng_noise, rng_def, rng_probe = (np.random.default_rng(s) for s in ss.spawn(4))

    t_amb = ambient_series(ambient, times, rng_amb)
    nodes, cooler = integrate(params, speeds, t_amb, dt, wear=wear, x0=initial_nodes)
    x_ref = np.full(_N, t_amb[0]) if initial_nodes is None else np.asarray(initial_nodes, float)
    z_th = np.zeros(n)
    for node, gain in params.disp_gain.items():
        z_th += gain * (nodes[:, _I[node]] - x_ref[_I[node]])
    z_all = displacement_truth(params, nodes, speeds, dt, x_ref)
    zero = (
        float(probe_zero_um)
        if probe_zero_um is not None
        else float(rng_probe.uniform(-1, 1) * params.probe_offset_um)
    )
    disp_true = z_all + zero
    temps_true = sensor_truth(params, nodes, t_amb, dt, sensor_drift)

    truth = _canonical(times, speeds, temps_true, disp_true)
    node_frame = pd.DataFrame(
        {"time": truth["time"], "t_s": np.arange(n) * dt, "speed_rpm": speeds, "ambient": t_amb}
    )
    for j, name in enumerate(NODES):
        node_frame[name] = nodes[:, j]
    node_frame["cooler_on"] = cooler
    node_frame["disp_thermal_um"] = z_th
    node_frame["disp_centrifugal_um"] = z_all - z_th

    # ---- the logger: noise and quantisation (per true sample, so duplicates are copies)
    if noise:
        temps = temps_true + rng_noise.normal(0.0, params.temp_noise_c, temps_true.shape)
        white = rng_noise.normal(0.0, params.disp_noise_um * 0.85, n)
        a = np.exp(-dt / 60.0)
        slow = lfilter([np.sqrt(1 - a * a)], [1, -a], rng_noise.normal(0.0, params.disp_noise_um * 0.5, n))
        disp = disp_true + white + slow
        # sensor noise: white + a slow part (air drafts at the magnet/clay mounting)
        a2 = np.exp(-dt / 180.0)
        drafts = lfilter(
            [np.sqrt(1 - a2 * a2)],
            [1, -a2],
            rng_noise.normal(0.0, params.temp_noise_c * 0.8, temps_true.shape),
            axis=0,
        )
        temps = temps + drafts
        temps = np.round(temps / params.temp_quantum_c) * params.temp_quantum_c
        disp = np.round(disp / params.disp_quantum_um) * params.disp_quantum_um
        jitter = np.round(rng_noise.normal(0.0, params.speed_jitter_rpm, n))
        speed_log = np.where(speeds > 0, speeds + jitter, 0.0)
    else:
        temps, disp, speed_log = temps_true.copy(), disp_true.copy(), speeds.copy()

    records: list[dict] = []
    if stuck_displacement:
        k0 = int(0.25 * n)
        disp[k0:] = disp[k0]
        records.append(
            dict(
                kind="stuck_displacement",
                src=k0,
                n_rows=n - k0,
                column="disp_um",
                value=float(disp[k0]),
                detail="displacement frozen at its last value",
            )
        )
    order, records, cells = _inject_defects(rates, n, dt, rng_def, records)
    log = _canonical(times[order], speed_log[order], temps[order], disp[order])
    defect_table = _finish_defects(records, cells, log, order, times)
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


def _inject_defects(rates: DefectRates, n: int, dt: float, rng: np.random.Generator, records: list[dict]):
    """Row-order defects -> (order of source rows, records, cell defects)."""
    keep = np.ones(n, dtype=bool)
    protect = 3  # first/last rows untouched
    if rates.restart_gap_prob > 0 and rng.random() < rates.restart_gap_prob:
        lo, hi = rates.restart_gap_s
        length = max(int(round(rng.uniform(lo, hi) / dt)), 1)
        p = int(rng.integers(int(0.1 * n), int(0.9 * n) - length))
        keep[p : p + length] = False
        records.append(
            dict(
                kind="restart_gap",
                src=p,
                n_rows=length,
                column="",
                value=np.nan,
                detail=f"logger restart: {length * dt:.0f} s without rows",
            )
        )
    if rates.missing_row > 0:
        cand = rng.random(n) < rates.missing_row
        cand[:protect] = cand[-protect:] = False
        for p in np.flatnonzero(cand & keep):
            if not keep[p - 1] or not keep[p + 1]:
                continue
            keep[p] = False
            records.append(
                dict(
                    kind="missing_row",
                    src=int(p),
                    n_rows=1,
                    column="",
                    value=np.nan,
                    detail="sample not written",
                )
            )
    src = np.flatnonzero(keep)
    dup = rng.random(len(src)) < rates.duplicate_row if rates.duplicate_row > 0 else np.zeros(len(src), bool)
    dup[:protect] = dup[-protect:] = False
    order_l: list[int] = []
    kind_l: list[str] = []
    for i, s in enumerate(src):
        order_l.append(int(s))
        kind_l.append("")
        if dup[i]:
            order_l.append(int(s))
            kind_l.append("dup")
            kind_l[-2] = "dup0"
            records.append(
                dict(
                    kind="duplicate_row",
                    src=int(s),
                    n_rows=1,
                    column="",
                    value=np.nan,
                    detail="row written twice",
                )
            )
    order = np.asarray(order_l)
    kinds = np.asarray(kind_l, dtype=object)
    # swaps of two adjacent, consecutive, plain rows
    n_swap = rng.poisson(rates.swap_per_1000_rows * n / 1000.0) if rates.swap_per_1000_rows > 0 else 0
    for _ in range(n_swap):
        for _try in range(20):
            p = int(rng.integers(protect, len(order) - protect - 1))
            if (kinds[p - 1 : p + 3] == "").all() and order[p + 1] == order[p] + 1:
                order[p], order[p + 1] = order[p + 1], order[p]
                kinds[p] = kinds[p + 1] = "swap"
                records.append(
                    dict(
                        kind="swapped_rows",
                        src=int(order[p]),
                        n_rows=2,
                        column="",
                        value=np.nan,
                        detail="two adjacent rows written in swapped order",
                    )
                )
                break
    cells: list[dict] = []
    n_spike = rng.poisson(rates.spike_per_1000_rows * n / 1000.0) if rates.spike_per_1000_rows > 0 else 0
    for _ in range(n_spike):
        for _try in range(20):
            p = int(rng.integers(protect, len(order) - protect))
            if kinds[p] == "":
                break
        kinds[p] = "spike"
        if rng.random() < 0.2:
            col = "disp_um"
            delta = float(rng.choice([-1, 1]) * rng.uniform(8.0, 30.0))
        else:
            col = SENSORS[int(rng.integers(0, 16))]
            delta = float(rng.choice([-1, 1]) * rng.uniform(3.0, 15.0))
        cells.append(dict(kind="spike", pos=p, n_rows=1, column=col, delta=delta))
    if rates.dropout_prob > 0 and rng.random() < rates.dropout_prob:
        lo, hi = rates.dropout_s
        length = max(int(round(rng.uniform(lo, hi) / dt)), 1)
        p = int(rng.integers(int(0.05 * len(order)), int(0.95 * len(order)) - length))
        col = SENSORS[int(rng.integers(0, 16))]
        style = ["", -999.0, 850.0][int(rng.integers(0, 3))]
        cells.append(dict(kind="dropout", pos=p, n_rows=length, column=col, style=style))
    return order, records, cells


def _finish_defects(records, cells, log: pd.DataFrame, order: np.ndarray, times) -> pd.DataFrame:
    rows = []
    first_pos = {}
    for pos, s in enumerate(order):
        first_pos.setdefault(int(s), pos)
    for rec in records:
        s = rec["src"]
        if rec["kind"] in ("missing_row", "restart_gap"):
            after = np.searchsorted(np.sort(order), s + rec["n_rows"])
            nxt = np.sort(order)[min(after, len(order) - 1)]
            pos = first_pos[int(nxt)]
        elif rec["kind"] == "duplicate_row":
            pos = first_pos[s] + 1
        elif rec["kind"] == "swapped_rows":
            pos = first_pos[s]
        else:
            pos = first_pos.get(s, 0)
        rows.append(
            dict(
                kind=rec["kind"],
                row=int(pos),
                n_rows=int(rec["n_rows"]),
                column=rec["column"],
                time=times[s],
                value=rec["value"],
                detail=rec["detail"],
            )
        )
    for c in cells:
        p, col = c["pos"], c["column"]
        j = log.columns.get_loc(col)
        if c["kind"] == "spike":
            old = float(log.iat[p, j])
            log.iat[p, j] = round(old + c["delta"], 3 if col == "disp_um" else 2)
            rows.append(
                dict(
                    kind="spike",
                    row=p,
                    n_rows=1,
                    column=col,
                    time=log["time"].iat[p],
                    value=float(log.iat[p, j]),
                    detail=f"single-sample spike {c['delta']:+.2f}",
                )
            )
        else:
            length = min(c["n_rows"], len(log) - p)
            style = c["style"]
            log.iloc[p : p + length, j] = np.nan if style == "" else float(style)
            what = "empty fields" if style == "" else f"open-circuit value {style}"
            rows.append(
                dict(
                    kind="dropout",
                    row=p,
                    n_rows=length,
                    column=col,
                    time=log["time"].iat[p],
                    value=np.nan if style == "" else float(style),
                    detail=f"sensor dropout, {what}",
                )
            )
    table = pd.DataFrame(rows, columns=list(DEFECT_COLUMNS))
    if len(table):
        table = table.sort_values(["row", "kind"], kind="stable").reset_index(drop=True)
    table["row"] = table["row"].astype("int64")
    table["n_rows"] = table["n_rows"].astype("int64")
    return table


# --------------------------------------------------------------------------- shipped data

#: Seed from which every shipped run's seed is derived (documented in docs/twin.md).
SHIPPED_SEED = 2023
SHIPPED_COMMAND = "rafi simulate shipped --out raw"


@dataclass(frozen=True)
class RunSpec:
    """One shipped log: file name, schedule, clock start, seed and room model."""

    machine: str
    file: str
    run_id: str
    schedule: tuple
    start: str
    seed: int
    ambient: Ambient
    description: str
    defects: DefectRates = DefectRates()


def _spec_a(i, file, desc, schedule, start, base_c, drift):
    return RunSpec(
        "tapping-center-a",
        file,
        Path(file).stem,
        tuple(schedule),
        start,
        SHIPPED_SEED * 100 + i,
        Ambient(base_c=base_c, drift_c_per_h=drift),
        desc,
    )


def shipped_specs(machine: str = "tapping-center-a") -> list[RunSpec]:
    """The runs of the shipped data set of one machine."""
    if machine == "tapping-center-a":
        h = 3600.0
        rest = REST_BEFORE_START_S
        specs = []
        train = [
            (3000, "2026-03-02T08:00:00", 21.6, 0.02),
            (6000, "2026-03-03T08:10:00", 21.9, -0.03),
            (9000, "2026-03-04T07:55:00", 22.3, 0.01),
            (12000, "2026-03-05T08:05:00", 22.0, 0.04),
            (15000, "2026-03-06T08:00:00", 21.7, -0.02),
            (18000, "2026-03-09T08:15:00", 22.2, 0.0),
        ]
        for i, (sp, start, base, drift) in enumerate(train):
            specs.append(
                _spec_a(
                    i,
                    f"train_{sp:05d}rpm.csv",
                    f"training run, 4 h at {sp} r/min, cold start after {rest:g} s at rest",
                    with_rest(constant_schedule(sp, 4 * h)),
                    start,
                    base,
                    drift,
                )
            )
        valid = [
            (4500, 4.0, "2026-03-10T08:00:00", 22.4, 0.03),
            (8000, 3.0, "2026-03-11T09:00:00", 22.1, 0.0),
            (10500, 2.5, "2026-03-12T08:30:00", 21.8, -0.02),
            (13500, 4.0, "2026-03-13T08:00:00", 22.5, 0.02),
            (16500, 2.0, "2026-03-16T10:00:00", 22.0, 0.05),
        ]
        for i, (sp, hours, start, base, drift) in enumerate(valid, start=10):
            specs.append(
                _spec_a(
                    i,
                    f"valid_{sp:05d}rpm.csv",
                    f"validation run, {hours:g} h at {sp} r/min, cold start after {rest:g} s at rest",
                    with_rest(constant_schedule(sp, hours * h)),
                    start,
                    base,
                    drift,
                )
            )
        specs.append(
            _spec_a(
                20,
                "multi_condition.csv",
                f"multi-condition validation run, {rest:g} s at rest, then 4.5 h of speed steps "
                + ", ".join(f"{n} r/min {m} min" for m, n in MULTI_CONDITION_A),
                with_rest(multi_condition_schedule()),
                "2026-03-17T08:00:00",
                22.3,
                0.02,
            )
        )
        return specs
    if machine == "machining-center-b":
        return [machining_center_b_spec()]
    raise ValueError(f"unknown machine {machine!r}")


def noise_floor(
    machine: str = "tapping-center-a",
    roles: Sequence[str] = ("valid", "multi"),
    reference_window_s: float = 60.0,
) -> pd.DataFrame:
    """Max |residual| a *perfect* model would leave on each shipped run: the logger's noise.

    Each run of :func:`shipped_specs` is simulated again with the same seed and no logger
    defects (noise and defects use independent random streams, so the noise is the shipped
    one); the displacement noise is the log minus the noise-free truth, referenced like
    ``dz`` (minus its median over the first ``reference_window_s``). Only runs whose file
    name starts with one of ``roles`` are included.

    Returns
    -------
    DataFrame
        ``run_id``, ``n_samples``, ``noise_std_um`` and ``floor_max_abs_um`` per run.
    """
    rows = []
    for spec in shipped_specs(machine):
        if not spec.file.startswith(tuple(roles)):
            continue
        run = simulate_run(
            spec.schedule,
            machine=spec.machine,
            seed=spec.seed,
            start=spec.start,
            ambient=spec.ambient,
            defects=False,
        )
        noise = run.log["disp_um"].to_numpy() - run.truth["disp_um"].to_numpy()
        t = run.nodes["t_s"].to_numpy()
        noise = noise - np.median(noise[t <= t[0] + reference_window_s])
        rows.append(
            {
                "run_id": spec.run_id,
                "n_samples": int(len(noise)),
                "noise_std_um": float(np.std(noise)),
                "floor_max_abs_um": float(np.max(np.abs(noise))),
            }
        )
    return pd.DataFrame(rows, columns=["run_id", "n_samples", "noise_std_um", "floor_max_abs_um"])


def _notes(spec: RunSpec, command: str) -> str:
    return (
        f"generated by the RAFI spindle digital twin (rafi.twin), seed {spec.seed}; "
        f"{spec.description}; regenerate with: {command}"
    )


def render_run(spec: RunSpec, command: str = SHIPPED_COMMAND, **overrides) -> tuple[str, TwinRun]:
    """Simulate a spec and render it as native raw-log text."""
    from rafi.readers.native import format_raw_log

    run = simulate_run(
        spec.schedule,
        machine=spec.machine,
        seed=spec.seed,
        start=spec.start,
        ambient=spec.ambient,
        defects=spec.defects,
        **overrides,
    )
    meta = {
        "machine": spec.machine,
        "run_id": spec.run_id,
        "sample_period_s": "5",
        "notes": _notes(spec, command),
    }
    return format_raw_log(run.log, meta), run


def write_shipped(
    out_dir: str | os.PathLike = "raw", machines: Sequence[str] = ("tapping-center-a", "machining-center-b")
) -> list[Path]:
    """Write the shipped data set under ``out_dir/<machine>/``; return the files written."""
    from rafi.artefact import write_text_atomic

    written = []
    for machine in machines:
        folder = Path(out_dir) / machine
        for spec in shipped_specs(machine):
            target = folder / spec.file
            if spec.file.endswith(".xlsx"):
                write_bytes_deterministic(target, render_xlsx(spec))
            else:
                text, _ = render_run(spec)
                write_text_atomic(target, text)
            written.append(target)
    return written


# --------------------------------------------------------------------------- machining-center-b


def machining_center_b() -> TwinParams:
    """A second, smaller machine: BT40 motor spindle up to 6000 r/min, other constants."""
    a = tapping_center_a()
    mixes = list(MIXES_A)
    mixes[5] = {"motor_base": 0.55, "stator": 0.10, "head": 0.25, AMBIENT: 0.10}
    mixes[8] = {"rear_bearing": 0.35, "motor_base": 0.30, "head": 0.20, AMBIENT: 0.15}
    lags = (50, 50, 60, 40, 35, 150, 45, 100, 140, 160, 35, 50, 300, 55, 50, 200)
    offsets = (
        -0.10,
        0.14,
        0.05,
        0.22,
        -0.18,
        -0.07,
        0.11,
        0.19,
        -0.24,
        0.03,
        0.16,
        -0.12,
        0.08,
        -0.21,
        0.13,
        -0.05,
    )
    return replace(
        a,
        machine="machining-center-b",
        capacity={
            "shaft": 2600.0,
            "front_bearing": 800.0,
            "rear_bearing": 600.0,
            "stator": 3200.0,
            "motor_base": 7000.0,
            "housing": 6500.0,
            "coolant": 1000.0,
            "tank": 45000.0,
            "head": 55000.0,
            "column": 400000.0,
        },
        speed_links={("shaft", "stator"): (1.2, 6.0, 0.8)},
        to_ambient={
            "shaft": (0.5, 3.0, 0.8),
            "housing": (1.0, 1.5, 0.8),
            "motor_base": (1.0, 0.0, 1.0),
            "head": (12.0, 0.0, 1.0),
            "column": (45.0, 0.0, 1.0),
            "tank": (5.0, 0.0, 1.0),
        },
        coolant_flow_w_per_k=200.0,
        cooler_power_w=700.0,
        cooler_hysteresis_c=1.0,
        cooler_offset_c=0.0,
        bearing_front_w=300.0,
        bearing_rear_w=150.0,
        bearing_to_shaft=0.55,
        motor_magnetising_w=120.0,
        motor_base_speed_rpm=3000.0,
        motor_iron_w=260.0,
        rotor_w=60.0,
        disp_gain={"shaft": 0.8, "housing": 0.45, "motor_base": 0.35, "head": 1.0, "column": -0.7},
        centrifugal_um=-2.5,
        probe_offset_um=0.0,
        sensors=_sensor_table(offsets, lags, mixes, POSITIONS),
        temp_noise_c=0.05,
        disp_noise_um=0.25,
    )


_MACHINES["machining-center-b"] = machining_center_b

#: machining-center-b continuous log: (hours, r/min, remark) - training 1250/2500/3750/5000,
#: validation 3500, idle cool-downs, then a varying tail that goes below the lowest trained speed.
SCHEDULE_B = (
    (4.0, 1250, "Warmlauf 1250 1/min"),
    (3.0, 0, "Stillstand"),
    (4.0, 2500, "Warmlauf 2500 1/min"),
    (3.0, 0, "Stillstand"),
    (4.0, 3750, "Warmlauf 3750 1/min"),
    (3.0, 0, "Stillstand"),
    (4.0, 5000, "Warmlauf 5000 1/min"),
    (3.0, 0, "Stillstand"),
    (3.0, 3500, "Validierung 3500 1/min"),
    (2.0, 0, "Stillstand"),
    (25 / 60, 800, "Wechsellast"),
    (35 / 60, 4200, ""),
    (30 / 60, 1800, ""),
    (20 / 60, 600, ""),
    (40 / 60, 3000, ""),
    (30 / 60, 4800, ""),
    (25 / 60, 1000, ""),
    (35 / 60, 2200, "Ende Wechsellast"),
)
B_FILE = "thermal_log_2026-10-14.xlsx"
B_START = "2026-10-14T06:00:00"
B_SAMPLE_S = 15.0
B_SHEET = "Messdaten"
B_COLUMNS = (
    "Zeit [s]",
    "Drehzahl [1/min]",
    *(f"Temperatur {i} [°C]" for i in range(1, 17)),
    "Verlagerung X1 [µm]",
    "Verlagerung Y1 [µm]",
    "Verlagerung Z1 [µm]",
    "Verlagerung Z2 [µm]",
    "Bemerkung",
)


def machining_center_b_spec(
    seed: int = SHIPPED_SEED * 100 + 50,
    start: str = B_START,
    file: str = B_FILE,
    ambient: Ambient | None = None,
    schedule=SCHEDULE_B,
) -> RunSpec:
    sched = tuple(Step(h * 3600.0, float(n)) for h, n, _ in schedule)
    return RunSpec(
        "machining-center-b",
        file,
        Path(file).stem,
        sched,
        start,
        seed,
        ambient
        or Ambient(base_c=19.5, daily_amplitude_c=1.2, peak_hour=16.0, drift_c_per_h=0.0, wander_c=0.15),
        "continuous log, training 1250/2500/3750/5000 r/min, validation 3500 r/min, "
        "idle cool-downs and a varying-speed tail",
        DefectRates.light(),
    )


def simulate_b(spec: RunSpec, remarks=SCHEDULE_B, **overrides) -> tuple[pd.DataFrame, TwinRun]:
    """Simulate the machining-center-b log and map it to its foreign (German) layout."""
    run = simulate_run(
        spec.schedule,
        machine=spec.machine,
        seed=spec.seed,
        start=spec.start,
        ambient=spec.ambient,
        defects=spec.defects,
        sample_period_s=B_SAMPLE_S,
        **overrides,
    )
    log = run.log
    t0 = pd.Timestamp(spec.start)
    rng = np.random.default_rng(np.random.SeedSequence([int(spec.seed), 7]))
    n = len(log)
    elapsed = ((log["time"] - t0) / pd.Timedelta(seconds=1)).round().astype("int64")
    out = pd.DataFrame({B_COLUMNS[0]: elapsed.to_numpy(), B_COLUMNS[1]: log["speed_rpm"].to_numpy()})
    for i, s in enumerate(SENSORS):
        out[B_COLUMNS[2 + i]] = log[s].to_numpy()
    disp = log["disp_um"].to_numpy()
    hours = elapsed.to_numpy() / 3600.0
    # radial drifts: small, slow, partly thermal
    dz_rel = disp - np.nanmedian(disp[:4])
    x1 = 0.12 * dz_rel + 0.4 * np.sin(2 * np.pi * hours / 9.0) + rng.normal(0, 0.15, n)
    y1 = -0.08 * dz_rel + 0.3 * np.cos(2 * np.pi * hours / 13.0) + rng.normal(0, 0.15, n)
    z2 = -disp + 3.2 + 0.03 * dz_rel + rng.normal(0, 0.35, n)
    out[B_COLUMNS[18]] = np.round(x1, 3)
    out[B_COLUMNS[19]] = np.round(y1, 3)
    out[B_COLUMNS[20]] = np.round(-disp, 3) + 0.0  # Z1: sign reversed axial probe
    out[B_COLUMNS[21]] = np.round(z2, 3)
    remark = np.full(n, "", dtype=object)
    step_starts = np.cumsum([0.0] + [h * 3600.0 for h, _, _ in remarks[:-1]])
    for s0, (_, _, text) in zip(step_starts, remarks):
        if text:
            k = int(np.searchsorted(elapsed.to_numpy(), s0))
            if k < n:
                remark[k] = text
    for _, d in run.defects.iterrows():
        if d["kind"] == "dropout":
            sensor = int(str(d["column"])[1:])
            remark[int(d["row"])] = (
                remark[int(d["row"])] + "; " if remark[int(d["row"])] else ""
            ) + f"Fühler {sensor} Wackelkontakt"
    out[B_COLUMNS[22]] = remark
    return out, run


_FIXED_ZIP_TIME = (2026, 10, 16, 7, 30, 0)
_FIXED_DOC_TIME = _dt.datetime(2026, 10, 16, 7, 30, 0)


def render_xlsx(spec: RunSpec, remarks=SCHEDULE_B, command: str = SHIPPED_COMMAND, **overrides) -> bytes:
    """The machining-center-b workbook as bytes (deterministic: fixed document and zip times)."""
    import openpyxl

    frame, run = simulate_b(spec, remarks=remarks, **overrides)
    wb = openpyxl.Workbook()
    info = wb.active
    info.title = "Info"
    rows = [
        ("Maschine", "BAZ-B (machining-center-b)"),
        ("Messbeginn", spec.start.replace("T", " ")),
        ("Abtastrate", f"{B_SAMPLE_S:g} s"),
        ("Messmittel", "16 x PT100 Anlegefühler, 4 Wirbelstromsensoren"),
        ("Hinweis", "Z1 = axiale Verlagerung, Vorzeichen: positiv = weg vom Tisch"),
        ("Erzeugt", f"RAFI Digital Twin (rafi.twin), seed {spec.seed}; {command}"),
    ]
    for r in rows:
        info.append(list(r))
    ws = wb.create_sheet(B_SHEET)
    ws.append(list(B_COLUMNS))
    values = frame.to_numpy(dtype=object)
    for row in values:
        cells = []
        for j, v in enumerate(row):
            if j == len(row) - 1:
                cells.append(v if v else None)
            elif j == 0:
                cells.append(int(v))
            else:
                fv = float(v)
                cells.append(None if np.isnan(fv) else (int(fv) if j == 1 else fv))
        ws.append(cells)
    wb.properties.creator = "rafi.twin"
    wb.properties.created = _FIXED_DOC_TIME
    buf = io.BytesIO()
    wb.save(buf)
    return normalise_zip(buf.getvalue())


def normalise_zip(data: bytes) -> bytes:
    """Rewrite an xlsx zip with fixed entry times and a fixed ``dcterms:modified``."""
    src = zipfile.ZipFile(io.BytesIO(data))
    out = io.BytesIO()
    stamp = _FIXED_DOC_TIME.strftime("%Y-%m-%dT%H:%M:%SZ")
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            body = src.read(info.filename)
            if info.filename == "docProps/core.xml":
                body = re.sub(
                    rb"(<dcterms:modified[^>]*>)[^<]*(</dcterms:modified>)",
                    rb"\g<1>" + stamp.encode() + rb"\g<2>",
                    body,
                )
            zi = zipfile.ZipInfo(info.filename, date_time=_FIXED_ZIP_TIME)
            zi.compress_type = zipfile.ZIP_DEFLATED
            zi.external_attr = 0o600 << 16
            dst.writestr(zi, body)
    return out.getvalue()


def write_bytes_deterministic(path: str | os.PathLike, data: bytes) -> None:
    from rafi.artefact import write_bytes_atomic

    write_bytes_atomic(path, data)


def read_b_layout(path: str | os.PathLike) -> pd.DataFrame:
    """Read the machining-center-b workbook's data sheet as a plain frame (for tests)."""
    import openpyxl

    wb = openpyxl.load_workbook(path, read_only=True, data_only=True)
    ws = wb[B_SHEET]
    rows = list(ws.iter_rows(values_only=True))
    wb.close()
    return pd.DataFrame(rows[1:], columns=list(rows[0]))


# --------------------------------------------------------------------------- a new day

TRAINING_SPEEDS = {
    "tapping-center-a": (3000, 6000, 9000, 12000, 15000, 18000),
    "machining-center-b": (1250, 2500, 3750, 5000),
}


def _day_command(
    machine,
    seed,
    date,
    ambient_shift,
    sensor_drift,
    wear,
    speeds,
    validation_speeds,
    multi,
    hours,
    defects,
    stuck,
) -> str:
    parts = [f"rafi simulate day --machine {machine} --seed {seed} --date {date}"]
    if ambient_shift:
        parts.append(f"--ambient-shift {ambient_shift:g}")
    for k, v in sorted((sensor_drift or {}).items()):
        parts.append(f"--sensor-drift {k}:{v:g}")
    if wear:
        parts.append(f"--wear {wear:g}")
    parts.append("--speeds " + ",".join(str(int(s)) for s in speeds))
    if validation_speeds:
        parts.append("--validation-speeds " + ",".join(str(int(s)) for s in validation_speeds))
    if multi:
        parts.append("--multi")
    if hours:
        parts.append(f"--hours {hours:g}")
    if not defects:
        parts.append("--no-defects")
    if stuck:
        parts.append("--stuck-displacement")
    return " ".join(parts)


def write_day(
    out_dir: str | os.PathLike = "raw",
    *,
    machine: str = "tapping-center-a",
    seed: int = 1,
    date: str | None = None,
    ambient_shift: float = 0.0,
    sensor_drift: dict | None = None,
    wear: float = 0.0,
    speeds: Sequence[int] | None = None,
    validation_speeds: Sequence[int] = (),
    multi: bool = False,
    hours: float | None = None,
    defects: bool = True,
    stuck_displacement: bool = False,
) -> list[Path]:
    """Write a new day of logs for ``machine`` under ``out_dir/<machine>/``.

    File names carry the date and the seed (``<date>_s<seed>_train_03000rpm.csv`` ...;
    machining-center-b: ``thermal_log_<date>_s<seed>.xlsx``) and existing files are never
    overwritten (``FileExistsError``).  Constant-speed runs are cold starts on
    consecutive days starting at ``date``; every tapping-center-a log (training, validation,
    multi-condition) starts with ``REST_BEFORE_START_S`` (180 s) at rest before the spindle
    starts, like the shipped logs.
    """
    from rafi.artefact import write_text_atomic
    from rafi.readers.native import format_raw_log

    if machine not in _MACHINES:
        raise ValueError(f"unknown machine {machine!r}; known: {', '.join(_MACHINES)}")
    speeds = list(TRAINING_SPEEDS[machine] if speeds is None else speeds)
    validation_speeds = list(validation_speeds or [])
    day0 = (
        pd.Timestamp(date) if date else pd.Timestamp("2026-04-01") + pd.Timedelta(days=int(seed))
    ).normalize()
    date_s = day0.strftime("%Y-%m-%d")
    command = _day_command(
        machine,
        seed,
        date_s,
        ambient_shift,
        sensor_drift,
        wear,
        speeds,
        validation_speeds,
        multi,
        hours,
        defects,
        stuck_displacement,
    )
    folder = Path(out_dir) / machine
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 99]))
    rates = DefectRates() if defects else DefectRates.none()
    if machine == "machining-center-b":
        steps = []
        for sp in speeds:
            steps += [(hours or 4.0, sp, f"Warmlauf {sp} 1/min"), (3.0, 0, "Stillstand")]
        for sp in validation_speeds:
            steps += [(3.0, sp, f"Validierung {sp} 1/min"), (2.0, 0, "Stillstand")]
        if multi:
            steps += list(SCHEDULE_B[10:])
        if not steps:
            raise ValueError("nothing to simulate: give --speeds, --validation-speeds or --multi")
        file = f"thermal_log_{date_s}_s{seed}.xlsx"
        target = folder / file
        if target.exists():
            raise FileExistsError(f"{target} exists; choose another --seed or --date")
        base = machining_center_b_spec()
        spec = machining_center_b_spec(
            seed=int(seed),
            start=f"{date_s}T06:00:00",
            file=file,
            ambient=replace(
                base.ambient, base_c=base.ambient.base_c + ambient_shift + float(rng.normal(0, 0.3))
            ),
            schedule=tuple(steps),
        )
        spec = replace(spec, defects=DefectRates.light() if defects else DefectRates.none())
        data = render_xlsx(
            spec,
            remarks=tuple(steps),
            command=command,
            sensor_drift=sensor_drift,
            wear=wear,
            stuck_displacement=stuck_displacement,
        )
        write_bytes_deterministic(target, data)
        return [target]
    runs = []
    run_hours = hours or 4.0
    for sp in speeds:
        runs.append(
            (
                f"train_{int(sp):05d}rpm",
                with_rest(constant_schedule(sp, run_hours * 3600.0)),
                f"training run, {run_hours:g} h at {int(sp)} r/min, cold start after "
                f"{REST_BEFORE_START_S:g} s at rest",
            )
        )
    for sp in validation_speeds:
        runs.append(
            (
                f"valid_{int(sp):05d}rpm",
                with_rest(constant_schedule(sp, 3 * 3600.0)),
                f"validation run, 3 h at {int(sp)} r/min, cold start after {REST_BEFORE_START_S:g} s at rest",
            )
        )
    if multi:
        runs.append(
            (
                "multi_condition",
                with_rest(multi_condition_schedule()),
                f"multi-condition run, {REST_BEFORE_START_S:g} s at rest, then 4.5 h",
            )
        )
    if not runs:
        raise ValueError("nothing to simulate: give --speeds, --validation-speeds or --multi")
    plan = []
    for k, (stem, sched, desc) in enumerate(runs):
        day = day0 + pd.Timedelta(days=k)
        file = f"{day:%Y-%m-%d}_s{seed}_{stem}.csv"
        target = folder / file
        if target.exists():
            raise FileExistsError(f"{target} exists; choose another --seed or --date")
        plan.append((k, day, file, target, sched, desc))
    written = []
    for k, day, file, target, sched, desc in plan:
        start = day + pd.Timedelta(hours=8, minutes=int(rng.integers(0, 30)))
        amb = Ambient(
            base_c=22.0 + ambient_shift + float(rng.normal(0, 0.3)), drift_c_per_h=float(rng.normal(0, 0.03))
        )
        run_seed = int(seed) * 1000 + k
        run = simulate_run(
            sched,
            machine=machine,
            seed=run_seed,
            start=start,
            ambient=amb,
            defects=rates,
            sensor_drift=sensor_drift,
            wear=wear,
            stuck_displacement=stuck_displacement,
        )
        meta = {
            "machine": machine,
            "run_id": Path(file).stem,
            "sample_period_s": "5",
            "notes": f"generated by the RAFI spindle digital twin (rafi.twin), seed {run_seed}; "
            f"{desc}; regenerate with: {command}",
        }
        write_text_atomic(target, format_raw_log(run.log, meta))
        written.append(target)
    return written


# --------------------------------------------------------------------------- plots


def quick_clean(frame: pd.DataFrame, sample_period_s: float = 5.0) -> pd.DataFrame:
    """Minimal cleaning for plots and calibration checks (not the pipeline's cleaning).

    Sort by time, drop duplicate times, set open-circuit values to NaN, replace isolated
    spikes (deviation from a 5-sample rolling median > 1 K or > 3 um) by NaN, and
    interpolate on the regular grid.  Adds ``t_s`` (seconds since the first sample).
    """
    f = frame.sort_values("time", kind="stable").drop_duplicates("time").reset_index(drop=True)
    cols = [*SENSORS, "disp_um"]
    vals = f[cols].astype(float)
    vals = vals.mask(vals.isin(OPEN_CIRCUIT_VALUES))
    med = vals.rolling(5, center=True, min_periods=1).median()
    limit = pd.Series({**{s: 1.0 for s in SENSORS}, "disp_um": 3.0})
    vals = vals.mask((vals - med).abs() > limit, axis=1)
    f[cols] = vals
    grid = pd.date_range(f["time"].iloc[0], f["time"].iloc[-1], freq=pd.Timedelta(seconds=sample_period_s))
    f = f.set_index("time")
    f = f.reindex(f.index.union(grid)).sort_index()
    f[["speed_rpm", *cols]] = f[["speed_rpm", *cols]].interpolate(method="time", limit_direction="both")
    f = f.loc[grid].reset_index(names="time")
    f["t_s"] = (f["time"] - f["time"].iloc[0]) / pd.Timedelta(seconds=1)
    return f


def plot_runs(
    paths: Sequence[str | os.PathLike],
    out_dir: str | os.PathLike = "docs/img",
    sensors: Sequence[str] = ("T6", "T8", "T9", "T16", "T5", "T11", "T13"),
) -> list[Path]:
    """Figure 9 style plots: temperatures (top) and displacement (bottom) against time.

    One image ``twin-<stem>.png`` per log and ``twin-overview.png`` (all displacements).
    Logs get :func:`quick_clean` (open-circuit values and spikes masked) before plotting.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from rafi.readers.native import read_raw_log

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    runs = []
    for path in paths:
        raw = read_raw_log(path)
        f = quick_clean(raw, float(raw.attrs["metadata"].get("sample_period_s", 5.0)))
        runs.append((Path(path).stem, f))
        hours = f["t_s"] / 3600.0
        fig, (ax1, ax2) = plt.subplots(
            2, 1, figsize=(9, 6.5), sharex=True, gridspec_kw={"height_ratios": [3, 2]}
        )
        for s in sensors:
            style = "-" if s in ("T6", "T8", "T9", "T16") else "--"
            ax1.plot(hours, f[s], style, lw=0.8, label=s)
        ax1.set_ylabel("temperature (°C)")
        ax1.legend(ncol=4, fontsize=8, loc="lower right")
        ax1.grid(alpha=0.3)
        dz = f["disp_um"] - f["disp_um"][f["t_s"] <= 60].median()
        ax2.plot(hours, dz, lw=0.7, color="k")
        ax2.set_ylabel("axial displacement dz (µm)")
        ax2.set_xlabel("time since start (h)")
        ax2.grid(alpha=0.3)
        sp = f["speed_rpm"].median()
        fig.suptitle(
            f"{raw.attrs['metadata'].get('machine', '')} {Path(path).name} (median speed {sp:.0f} r/min)"
        )
        fig.tight_layout()
        target = out / f"twin-{Path(path).stem}.png"
        fig.savefig(target, dpi=90)
        plt.close(fig)
        written.append(target)
    fig, ax = plt.subplots(figsize=(9, 4.5))
    for stem, f in runs:
        dz = f["disp_um"] - f["disp_um"][f["t_s"] <= 60].median()
        ax.plot(f["t_s"] / 3600.0, dz, lw=0.7, label=stem)
    ax.set_xlabel("time since start (h)")
    ax.set_ylabel("dz (µm)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("displacement rise per run")
    fig.tight_layout()
    target = out / "twin-overview.png"
    fig.savefig(target, dpi=90)
    plt.close(fig)
    written.append(target)
    return written
