"""The twin's machines: node list, every physical constant, sensors, room and logger defect rates.

Two machines are modelled: ``tapping-center-a`` (the paper's rig, PMC tapping center, BT30
built-in spindle) and ``machining-center-b`` (a smaller BT40 motor spindle). The numbers are
documented in ``docs/twin.md``; the physics that uses them is in :mod:`rafi.twin.physics`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

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
#: Position of each node in the state vector.
NODE_INDEX = {name: i for i, name in enumerate(NODES)}
#: Extra "node" name usable in sensor mixes: the room air.
AMBIENT = "ambient"

#: Speed normalisation (r/min) used in every speed law below.
N_REF = 10000.0


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
#: Calibration offsets (degC).
OFFSETS_A = (
    (0.12, -0.08, 0.21, -0.15, 0.05, 0.18, -0.22, 0.09)  # T1..T8
    + (-0.11, 0.25, -0.04, 0.14, -0.19, 0.07, -0.06, 0.16)  # T9..T16
)


def _per_node(*values: float) -> dict:
    """``{node: value}`` in the order of :data:`NODES`."""
    return dict(zip(NODES, values, strict=True))


def tapping_center_a() -> TwinParams:
    """Parameters of the paper's rig: PMC tapping center, BT30 built-in spindle."""
    return TwinParams(
        machine="tapping-center-a",
        capacity=_per_node(3200.0, 900.0, 700.0, 4000.0, 9000.0, 8000.0, 1200.0, 60000.0, 104000.0, 600000.0),
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


def machining_center_b() -> TwinParams:
    """A second, smaller machine: BT40 motor spindle up to 6000 r/min, other constants."""
    a = tapping_center_a()
    mixes = list(MIXES_A)
    mixes[5] = {"motor_base": 0.55, "stator": 0.10, "head": 0.25, AMBIENT: 0.10}
    mixes[8] = {"rear_bearing": 0.35, "motor_base": 0.30, "head": 0.20, AMBIENT: 0.15}
    lags = (50, 50, 60, 40, 35, 150, 45, 100, 140, 160, 35, 50, 300, 55, 50, 200)
    offsets = (
        (-0.10, 0.14, 0.05, 0.22, -0.18, -0.07, 0.11, 0.19)  # T1..T8
        + (-0.24, 0.03, 0.16, -0.12, 0.08, -0.21, 0.13, -0.05)  # T9..T16
    )
    return replace(
        a,
        machine="machining-center-b",
        capacity=_per_node(2600.0, 800.0, 600.0, 3200.0, 7000.0, 6500.0, 1000.0, 45000.0, 55000.0, 400000.0),
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
        cooler_offset_c=0.0,
        bearing_front_w=300.0,
        bearing_rear_w=150.0,
        motor_magnetising_w=120.0,
        motor_base_speed_rpm=3000.0,
        motor_iron_w=260.0,
        rotor_w=60.0,
        disp_gain={"shaft": 0.8, "housing": 0.45, "motor_base": 0.35, "head": 1.0, "column": -0.7},
        centrifugal_um=-2.5,
        probe_offset_um=0.0,
        sensors=_sensor_table(offsets, lags, mixes, POSITIONS),
        disp_noise_um=0.25,
    )


#: Parameter factory of each machine id.
MACHINES = {"tapping-center-a": tapping_center_a, "machining-center-b": machining_center_b}


def machine_params(machine: str) -> TwinParams:
    """Twin parameters of a shipped machine by id."""
    try:
        return MACHINES[machine]()
    except KeyError:
        raise ValueError(f"unknown machine {machine!r}; known: {', '.join(MACHINES)}") from None
