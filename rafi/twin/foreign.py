"""Foreign machines (``rafi simulate foreign``): random twins nobody here tuned on, with the truth
of where their test days leave the training range.

A foreign machine is the twin's thermal network (:mod:`rafi.twin.physics`) with every constant
drawn anew from a seed: heat capacities (the time constants), conductances, heat sources,
displacement gains, the centrifugal draw-in; 4 to 40 temperature sensors, each at its own place
(a mix of one or two nodes and the room air), with its own lag, offset and name; its own room
(level, daily swing, drift, wander); its own speeds. It is tested like the turning centre of
issue 46: one log a day (a cold start at 60 s a row), training days first, then test days, some
of which leave the training range (a hot or a cold room, a speed above the training speeds, a
run longer than any training run). :func:`foreign_machine` returns the logs, the config block
that reads them and the truth; :func:`envelope_fractions` states, per test day, the fraction of
its rows outside the training envelope, computed from the generated logs.

**Production** (``plan="production"``, ``rafi simulate foreign --plan production``; default
``varied``). The varied plan tests a machine the way a qualification does: runs at every
training speed and speed steps, each day different. A machine in production is logged otherwise,
like the turning centre of issue 46: a handful of sensors (:data:`PRODUCTION_SENSOR_COUNT`), the
same job every day (70-100 min at each training speed in an order of its own, each step 0.9-1.1 x
as long from day to day) in a shop that warms while it runs
(:data:`PRODUCTION_SHOP_WARMING_K_PER_H`, the same each day within 20 %), over weeks in which the
season moves the room (:data:`PRODUCTION_SEASON_K_PER_DAY`): 8-12 training days, then, 1-7 days
on (:data:`PRODUCTION_TEST_GAP_DAYS`), 4-6 test days of the same job that carry the season on,
so many of their rows lie beyond every training temperature. Every training day shows the
temperatures in one combination (the job's) and the test days leave it: the conditions under
which the turning centre's ridge on filtered rises ran away. Its kinds do not run away here
(``docs/decisions.md``, 2026-11-29, "foreign machines in production do not run away either").
:func:`production_days`; the machine and its sensors are drawn as for the varied plan, with
fewer sensors.

**Realism** (``realism=``, ``rafi simulate foreign --realism all``; default none). The twin's
physics is linear: every sensor and the displacement are linear responses of the same few drives
(the speed's heat, the room), so a fit on strongly collinear temperatures extrapolates honestly
on its test days. Real machines break that; the turning centre of issue 46 made a ridge on
filtered rises run away on test days whose temperatures lay outside the training range. Five
effects a real machine has and the twin has not, each drawn per machine by
:func:`foreign_realism` on a stream of its own (the machine, its days and every noise stay those
of the plain machine), each with its reason (``all``: the five):

* ``hidden_source``: a heat source nobody put a sensor on - a hydraulic unit or a neighbouring
  machine beside the column, a counterbalance or the sun on the head, a rotary union at the
  spindle's rear (:data:`HIDDEN_SOURCE_NODES`) - cycling on its own thermostat (period 20-120
  min), strong enough to raise its node 1-4 K; on the training days at about one level, on each
  test day lower or higher (another shift, another job). It moves the displacement and only the
  sensors near its node: a direction of the temperatures the training days did not show.
* ``convection``: still air takes heat away as ``dT ** 1.2-1.33`` (free convection), not
  linearly: a machine hotter than on any training day loses more than the linear law says, so
  the ratios between its temperatures shift where the fit extrapolates.
* ``fixed_chiller``: many oil coolers hold a fixed set point (here the training days' room
  plus the cooler's offset) instead of tracking the room: on a warmer or colder day the coolant
  sits elsewhere relative to the structure and the room than on any training day.
* ``sensor_mount``: from one test day on, 1-3 sensors were knocked off and re-glued (a magnet
  moved, a cable pulled): another lag (x 0.3-3) and another share of the room air.
* ``warm_start``: the training runs were cold starts (the machine stood overnight), but a test
  part is made when the machine is free: a test day (60 %) starts after only 1-10 h at rest, the
  heavy column and head still warm from the day before while the fast nodes have cooled, and the
  probe is zeroed on the warm machine. Its slow and fast temperatures then move in a
  combination no cold start shows.

``truth["realism"]`` records what was drawn and per day the mean and largest contribution (um);
:attr:`ForeignMachine.parts` holds the noise-free contributions row by row
(:func:`simulate_day_parts`). Without ``realism`` nothing of this is drawn: the logs are byte for
byte those of the plain machine.

Pure: everything follows from the seed; only :func:`write_foreign` writes files.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from rafi.twin.machines import AMBIENT, NODES, Ambient, SensorSpec, TwinParams, machine_params
from rafi.twin.physics import (
    ambient_series,
    displacement_truth,
    integrate,
    integrate_realistic,
    sensor_truth,
    system_matrices,
)
from rafi.twin.schedules import REST_BEFORE_START_S, Step, sample_schedule, with_rest
from rafi.twin.signals import ar1

#: Sample period of a foreign machine's logs (s): a plant logger's, like the turning centre's.
FOREIGN_SAMPLE_S = 60.0
#: Fewest and most temperature sensors of a foreign machine.
SENSOR_COUNT = (4, 40)
#: The base machines whose network a foreign machine spreads, with the speed range (r/min) its
#: heat laws were written for.
BASES = {"tapping-center-a": (3000.0, 18000.0), "machining-center-b": (1250.0, 6000.0)}
#: How a test day may leave the training range (:func:`plan_days`).
OUTSIDE_KINDS = ("hot_room", "cold_room", "over_speed", "long_run")
#: A test day inside the training range: speed steps between the training speeds, the usual room.
INSIDE_KIND = "steps"
#: Nodes a sensor can sit on (the shaft turns: nobody glues a sensor to it), with the odds.
PLACES = {
    "front_bearing": 1.0,
    "rear_bearing": 1.0,
    "stator": 0.6,
    "motor_base": 1.0,
    "housing": 1.2,
    "coolant": 0.8,
    "tank": 0.5,
    "head": 1.2,
    "column": 0.8,
}
#: How sensors are named, one style a machine ("{place}" names it after its node).
NAME_STYLES = ("T{i}", "TC{i:02d}", "Temp{i}", "ch{i:02d}", "sensor_{i}", "{place}_{i}")
#: How a machine's days are planned (``plan=``): :func:`plan_days` or :func:`production_days`.
PLANS = ("varied", "production")
#: A machine in production (``plan="production"``): its sensors (fewest, most), training and test
#: days (fewest, most), the job's steps beyond one at each training speed (fewest, most) and their
#: length (minutes; above ``runs.min_constant_s`` even at 0.9 x, so RAFI's per-speed fits have
#: runs), how fast its shop warms while it runs (K/h, per machine; each day within
#: :data:`PRODUCTION_DAY_SPREAD`) and how fast the season moves the room's level from one day to
#: the next (K/day, per machine; up or down).
PRODUCTION_SENSOR_COUNT = (4, 8)
PRODUCTION_TRAINING_DAYS = (8, 12)
PRODUCTION_TEST_DAYS = (4, 6)
PRODUCTION_JOB_EXTRA_STEPS = (0, 2)
PRODUCTION_STEP_MIN = (70.0, 100.0)
PRODUCTION_SHOP_WARMING_K_PER_H = (0.5, 2.0)
PRODUCTION_SEASON_K_PER_DAY = (0.15, 0.45)
PRODUCTION_DAY_SPREAD = 0.2
#: Days between the last training day and the first test day (fewest, most): the test part is
#: logged some weeks on, when the season has moved the room further.
PRODUCTION_TEST_GAP_DAYS = (1, 7)
#: A production test day's kind: the training days' job on a day of the season's trend.
PRODUCTION_KIND = "production"
#: Envelope margin (K): a temperature or rise more than this beyond the training range is outside
#: (about twice a sensor's noise, so a test day at the edge of the range is not outside by noise).
ENVELOPE_MARGIN_K = 0.1
#: A speed more than this (r/min) beyond the training speeds is outside (``speed_tolerance_rpm``).
ENVELOPE_SPEED_TOL_RPM = 50.0
#: The spindle stands below this (r/min): such rows have no speed to be outside (``idle_below_rpm``).
IDLE_BELOW_RPM = 100.0
#: Setup change (``setup_change=True``): from a day in the second half of the training days on,
#: the node with the largest displacement gain reaches the probe by this factor of its gain (a
#: fixture or the probe re-clamped: its growth now partly cancels, or reverses, what it did).
SETUP_CHANGE_FACTOR = (-1.0, 0.0)
#: Setup drift (``setup_drift=True``): its standard deviation per machine (um) and time constant (s).
SETUP_DRIFT_UM = (0.5, 3.0)
SETUP_DRIFT_TAU_S = 7200.0
#: What ``realism=`` can add to a machine, in the order drawn (the module's docstring says why each
#: happens on real machines and not in the linear twin).
REALISM_EFFECTS = ("hidden_source", "convection", "fixed_chiller", "sensor_mount", "warm_start")
#: The effects that change the nodes' temperatures (the others change what a sensor reads).
NODE_EFFECTS = ("hidden_source", "convection", "fixed_chiller")
#: Nodes an unobserved heat source may heat, and what it stands for there.
HIDDEN_SOURCE_NODES = {
    "column": "a hydraulic unit or a neighbouring machine beside the column",
    "head": "a hydraulic counterbalance or clamp in the head, or sun on the headstock",
    "motor_base": "a rotary union or tool-clamp cylinder at the spindle's rear",
}
#: The source's power at its training level: the steady rise (K) it alone would give its node at
#: rest (drawn per machine).
HIDDEN_SOURCE_RISE_K = (1.0, 4.0)
#: It cycles on and off (its own thermostat): period (min) and the share of it on, drawn per day.
HIDDEN_SOURCE_PERIOD_MIN = (20.0, 120.0)
HIDDEN_SOURCE_DUTY = (0.3, 0.8)
#: Its level (times the training level) on a training day, and on a test day either lower or
#: higher (half each): the neighbour works another shift, the hydraulics another job.
HIDDEN_SOURCE_TRAINING_LEVEL = (0.8, 1.2)
HIDDEN_SOURCE_TEST_LEVELS = ((0.2, 0.5), (1.6, 2.5))
#: Exponent of the still-air heat loss ``dT ** n`` (free convection: about 1.25), drawn per machine.
CONVECTION_EXPONENT = (1.2, 1.33)
#: Sensors reseated (knocked off, re-glued) from one test day on: how many (at most a fifth of
#: the sensors, at least one), their lag's factor and their new share of the room air.
MOUNT_SENSORS = (1, 3)
MOUNT_LAG_FACTOR = (0.3, 3.0)
MOUNT_AMBIENT_SHARE = (0.02, 0.5)
#: Bounds of a reseated sensor's lag (s).
MOUNT_LAG_S = (20.0, 1800.0)
#: A test day starts warm with this chance: the machine stood only a few hours (log-uniform
#: between these, h) since the previous day's end, at the new day's room temperature.
WARM_START_SHARE = 0.6
WARM_REST_H = (1.0, 10.0)
#: Decimals of the temperatures and the displacement in the written logs.
TEMP_DECIMALS = 2
DISP_DECIMALS = 3
#: A rise is measured from the median of the day's first seconds (the cold machine at rest).
REFERENCE_S = REST_BEFORE_START_S


@dataclass(frozen=True)
class Day:
    """One logged day: its file stem, role (``training`` or ``test``), kind, schedule (at rest
    first), room and start."""

    stem: str
    role: str
    kind: str
    schedule: tuple[Step, ...]
    ambient: Ambient
    start: pd.Timestamp


@dataclass(frozen=True)
class ForeignMachine:
    """What :func:`foreign_machine` returns: the machine's name, its ``machines.<name>`` block,
    its logs (file stem -> canonical frame: ``time``, ``speed_rpm``, the sensors, ``disp_um``),
    the truth (a JSON-able dict: constants, sensors, days, envelope, test runs) and, with
    ``realism``, the parts (file stem -> what the effects added, noise-free)."""

    name: str
    config: dict
    logs: dict[str, pd.DataFrame]
    truth: dict
    #: With ``realism``: per day the noise-free ground truth of what it added (:func:`simulate_day_parts`).
    parts: dict[str, pd.DataFrame] = field(default_factory=dict)


def _factor(rng: np.random.Generator, sigma: float) -> float:
    """A log-normal spread factor (clipped at 2 sigma)."""
    return float(np.exp(sigma * np.clip(rng.standard_normal(), -2.0, 2.0)))


def _law(rng: np.random.Generator, g: tuple, sigma: float) -> tuple:
    return (g[0] * _factor(rng, sigma), g[1] * _factor(rng, sigma), g[2])


def foreign_params(base: TwinParams, rng: np.random.Generator) -> TwinParams:
    """``base``'s network with every constant spread (much wider than a sibling's): capacities and
    conductances (the time constants), heat sources, coolant and cooler, displacement gains (a
    sign may flip, nodes without a gain may get one), the draw-in; noise levels and quanta drawn."""
    gains = {k: v * _factor(rng, 0.4) for k, v in base.disp_gain.items()}
    for node in ("head", "column"):
        if node in gains and rng.random() < 0.3:
            gains[node] = -gains[node]
    for node in ("front_bearing", "stator", "coolant"):
        if rng.random() < 0.25:
            gains[node] = float(rng.normal(0.0, 0.3))
    return replace(
        base,
        capacity={k: v * _factor(rng, 0.4) for k, v in base.capacity.items()},
        links={k: v * _factor(rng, 0.3) for k, v in base.links.items()},
        speed_links={k: _law(rng, v, 0.3) for k, v in base.speed_links.items()},
        to_ambient={k: _law(rng, v, 0.3) for k, v in base.to_ambient.items()},
        coolant_flow_w_per_k=base.coolant_flow_w_per_k * _factor(rng, 0.3),
        cooler_power_w=base.cooler_power_w * _factor(rng, 0.3),
        bearing_front_w=base.bearing_front_w * _factor(rng, 0.35),
        bearing_rear_w=base.bearing_rear_w * _factor(rng, 0.35),
        motor_magnetising_w=base.motor_magnetising_w * _factor(rng, 0.35),
        motor_iron_w=base.motor_iron_w * _factor(rng, 0.35),
        rotor_w=base.rotor_w * _factor(rng, 0.35),
        disp_gain=gains,
        centrifugal_um=base.centrifugal_um * _factor(rng, 0.4),
        temp_noise_c=float(rng.uniform(0.02, 0.06)),
        disp_noise_um=float(rng.uniform(0.1, 0.4)),
        disp_quantum_um=float(rng.choice([0.001, 0.01, 0.1])),
        probe_offset_um=float(rng.uniform(0.0, 5.0)),
    )


def foreign_sensors(n: int, rng: np.random.Generator) -> tuple[SensorSpec, ...]:
    """``n`` sensors at random places: a node (the first on one the displacement depends on),
    with a chance of a second, always a share of the room air; one may be a room sensor. Lags
    log-uniform 20-900 s, offsets about 0.2 K, named in one of :data:`NAME_STYLES`."""
    places, odds = list(PLACES), np.array(list(PLACES.values()))
    style = str(rng.choice(NAME_STYLES))
    room_sensor = n > 4 and rng.random() < 0.5
    out, seen = [], {}
    for i in range(1, n + 1):
        if room_sensor and i == n:
            place, mix, lag = AMBIENT, {AMBIENT: 1.0}, 120.0
        else:
            place = str(rng.choice(["housing", "motor_base", "head"])) if i == 1 else None
            place = place or str(rng.choice(places, p=odds / odds.sum()))
            mix = {place: float(rng.uniform(0.5, 0.95))}
            if rng.random() < 0.6:
                other = str(rng.choice([p for p in places if p != place]))
                mix[other] = float(rng.uniform(0.05, 0.4))
            mix[AMBIENT] = float(rng.uniform(0.02, 0.3))
            lag = float(np.exp(rng.uniform(np.log(20.0), np.log(900.0))))
        total = sum(mix.values())
        seen[place] = seen.get(place, 0) + 1  # "{place}_{i}" counts per place: housing_1, housing_2
        name = style.format(i=seen[place] if "{place}" in style else i, place=place.replace("_", ""))
        out.append(
            SensorSpec(
                name, place, tuple((k, v / total) for k, v in mix.items()), lag, float(rng.normal(0, 0.2))
            )
        )
    return tuple(out)


def _room(rng: np.random.Generator, room_c: float, shift_c: float = 0.0) -> Ambient:
    """A day's room: the machine's level (+ ``shift_c``), its own swing, drift and wander."""
    return Ambient(
        base_c=room_c + shift_c + float(rng.normal(0.0, 0.7)),
        daily_amplitude_c=float(rng.uniform(0.2, 1.2)),
        peak_hour=float(rng.uniform(13.0, 17.0)),
        drift_c_per_h=float(rng.normal(0.0, 0.15)),
        wander_c=float(rng.uniform(0.03, 0.15)),
    )


def _steps(rng: np.random.Generator, lo: float, top: float) -> list[Step]:
    """4-6 steps of 20-50 min at speeds between ``lo`` and ``top`` (one varying run)."""
    k = int(rng.integers(4, 7))
    return [
        Step(60.0 * float(rng.uniform(20, 50)), float(np.round(rng.uniform(lo, top), -1))) for _ in range(k)
    ]


def training_speeds(rng: np.random.Generator, base: str) -> tuple[list[float], float]:
    """2-4 evenly spaced training speeds from the base's lowest to 55-75 % of its highest
    (rounded to 10 r/min), and the slowest speed a day may run at."""
    lo, hi = BASES[base]
    top = hi * float(rng.uniform(0.55, 0.75))
    k = int(rng.integers(2, 5))
    return [float(np.round(v, -1)) for v in np.linspace(lo, top, k)], lo


def plan_days(rng: np.random.Generator, speeds: list[float], lo: float, room_c: float) -> list[Day]:
    """Training days, then test days, one a day from 2026-06-01 (each a cold start after
    :data:`REST_BEFORE_START_S` at rest).

    Training: a 2-4 h constant run at each training speed, then 1-2 days of speed steps between
    the training speeds. Test: 3-4 days, the first inside the range (:data:`INSIDE_KIND`), at
    least one of :data:`OUTSIDE_KINDS` (a room 2-5 K warmer or colder than usual with speed
    steps, 2-3 h at 1.2-1.4 x the top training speed, or the top speed for 1.8-2.5 x the longest
    training run), the others either.
    """
    top = max(speeds)
    plan: list[tuple[str, str, list[Step], float]] = []
    hours = [float(rng.uniform(2.0, 4.0)) for _ in speeds]
    plan += [("training", "constant", [Step(3600.0 * h, s)], 0.0) for s, h in zip(speeds, hours)]
    plan += [("training", INSIDE_KIND, _steps(rng, lo, top), 0.0) for _ in range(int(rng.integers(1, 3)))]
    n_test = int(rng.integers(3, 5))
    kinds = [INSIDE_KIND, str(rng.choice(OUTSIDE_KINDS))]
    kinds += [str(rng.choice((INSIDE_KIND, *OUTSIDE_KINDS))) for _ in range(n_test - 2)]
    for kind in kinds:
        if kind in ("hot_room", "cold_room"):
            shift = float(rng.uniform(2.0, 5.0)) * (1 if kind == "hot_room" else -1)
            plan.append(("test", kind, _steps(rng, lo, top), shift))
        elif kind == "over_speed":
            over = float(np.round(top * rng.uniform(1.2, 1.4), -1))
            plan.append(("test", kind, [Step(3600.0 * float(rng.uniform(2.0, 3.0)), over)], 0.0))
        elif kind == "long_run":
            long_h = max(hours) * float(rng.uniform(1.8, 2.5))
            plan.append(("test", kind, [Step(3600.0 * long_h, top)], 0.0))
        else:
            plan.append(("test", kind, _steps(rng, lo, top), 0.0))
    day0 = pd.Timestamp("2026-06-01")
    out = []
    for d, (role, kind, steps, shift) in enumerate(plan, start=1):
        start = day0 + pd.Timedelta(days=d - 1, hours=7, minutes=int(rng.integers(0, 60)))
        stem = f"day{d:02d}_{'train' if role == 'training' else 'test'}"
        out.append(Day(stem, role, kind, tuple(with_rest(steps)), _room(rng, room_c, shift), start))
    return out


def production_days(rng: np.random.Generator, speeds: list[float], lo: float, room_c: float) -> list[Day]:
    """The days of a machine in production (the module's docstring): the training days one a day
    from 2026-06-01, the test days one a day after a gap (each a cold start after
    :data:`REST_BEFORE_START_S` at rest).

    One job for every day: a step at each training speed and :data:`PRODUCTION_JOB_EXTRA_STEPS`
    more at one of them, in a random order, each of :data:`PRODUCTION_STEP_MIN` minutes (``lo``
    unused: the job runs the speeds it was qualified at); on each day every step 0.9-1.1 x as
    long. The room: the machine's level ``room_c`` moved by the season (a per-machine
    :data:`PRODUCTION_SEASON_K_PER_DAY`, warming or cooling, times the day's index) plus the day's
    own spread, warming while the job runs by the machine's :data:`PRODUCTION_SHOP_WARMING_K_PER_H`
    (within :data:`PRODUCTION_DAY_SPREAD` each day). :data:`PRODUCTION_TRAINING_DAYS` training
    days, then after :data:`PRODUCTION_TEST_GAP_DAYS` days :data:`PRODUCTION_TEST_DAYS` test days
    (:data:`PRODUCTION_KIND`; a file's day number is its day since the first).
    """
    extra = int(rng.integers(*PRODUCTION_JOB_EXTRA_STEPS, endpoint=True))
    order = rng.permutation([*speeds, *rng.choice(speeds, size=extra)])
    job = [Step(60.0 * float(rng.uniform(*PRODUCTION_STEP_MIN)), float(v)) for v in order]
    warming = float(rng.uniform(*PRODUCTION_SHOP_WARMING_K_PER_H))
    season = float(rng.uniform(*PRODUCTION_SEASON_K_PER_DAY)) * float(rng.choice([-1.0, 1.0]))
    n_train = int(rng.integers(*PRODUCTION_TRAINING_DAYS, endpoint=True))
    n_test = int(rng.integers(*PRODUCTION_TEST_DAYS, endpoint=True))
    gap = int(rng.integers(*PRODUCTION_TEST_GAP_DAYS, endpoint=True))
    day0 = pd.Timestamp("2026-06-01")
    spread = (1.0 - PRODUCTION_DAY_SPREAD, 1.0 + PRODUCTION_DAY_SPREAD)
    out = []
    for d in range(1, n_train + n_test + 1):
        role = "training" if d <= n_train else "test"
        on = d - 1 + (gap if role == "test" else 0)  # days since the first day
        steps = [Step(s.duration_s * float(rng.uniform(0.9, 1.1)), s.speed_rpm) for s in job]
        ambient = replace(
            _room(rng, room_c, season * on), drift_c_per_h=warming * float(rng.uniform(*spread))
        )
        start = day0 + pd.Timedelta(days=on, hours=7, minutes=int(rng.integers(0, 60)))
        stem = f"day{on + 1:02d}_{'train' if role == 'training' else 'test'}"
        kind = INSIDE_KIND if role == "training" else PRODUCTION_KIND
        out.append(Day(stem, role, kind, tuple(with_rest(steps)), ambient, start))
    return out


@dataclass(frozen=True)
class Realism:
    """What ``realism=`` drew for one machine (:func:`foreign_realism`): the effects and their
    constants; per day (file stem) the hidden source's level, period, duty and phase, the
    sensors as mounted that day (only the days after a reseat) and the hours the machine stood
    before a warm start (only the days that start warm)."""

    effects: tuple[str, ...]
    source_node: str = ""
    source_w: float = 0.0
    source_days: dict = field(default_factory=dict)
    convection_exponent: float | None = None
    cooler_set_c: float | None = None
    mount_from: str = ""
    mounted: tuple[SensorSpec, ...] = ()
    warm_rest_h: dict = field(default_factory=dict)

    def sensors_on(self, params: TwinParams, day: Day, days: list[Day]) -> tuple[SensorSpec, ...]:
        """The sensors as they read on ``day``: reseated ones from :attr:`mount_from` on."""
        stems = [d.stem for d in days]
        if self.mount_from and stems.index(day.stem) >= stems.index(self.mount_from):
            return self.mounted
        return params.sensors


def parse_realism(text: str | None) -> tuple[str, ...]:
    """``"all"``, ``"none"`` or a comma-separated subset of :data:`REALISM_EFFECTS` (in their
    order); an unknown name raises ``ValueError`` naming the known ones."""
    text = (text or "").strip()
    if text in ("", "none"):
        return ()
    if text == "all":
        return REALISM_EFFECTS
    names = {v.strip() for v in text.split(",") if v.strip()}
    unknown = sorted(names - set(REALISM_EFFECTS))
    if unknown:
        raise ValueError(
            f"unknown realism effect(s) {', '.join(unknown)}; expected 'all', 'none' or a comma-separated "
            f"subset of {', '.join(REALISM_EFFECTS)}"
        )
    return tuple(e for e in REALISM_EFFECTS if e in names)


def _steady_rise_k_per_w(params: TwinParams, node: str) -> float:
    """The steady rise (K) of ``node`` per W into it, the spindle at rest, room and cooler off."""
    A, _ = system_matrices(params, 0.0, 0.0)
    cap = np.array([params.capacity[nm] for nm in NODES])
    i = NODES.index(node)
    e = np.zeros(len(NODES))
    e[i] = 1.0 / cap[i]
    return float(np.linalg.solve(-A, e)[i])


def _reseat(spec: SensorSpec, rng: np.random.Generator) -> SensorSpec:
    """``spec`` knocked off and re-glued: its lag times :data:`MOUNT_LAG_FACTOR`, its share of the
    room air drawn anew (:data:`MOUNT_AMBIENT_SHARE`), the nodes keeping their proportions."""
    lag = float(np.clip(spec.lag_s * np.exp(rng.uniform(*np.log(MOUNT_LAG_FACTOR))), *MOUNT_LAG_S))
    air = float(rng.uniform(*MOUNT_AMBIENT_SHARE))
    nodes = {k: v for k, v in spec.mix if k != AMBIENT}
    total = sum(nodes.values())
    mix = tuple((k, (1.0 - air) * v / total) for k, v in nodes.items()) + ((AMBIENT, air),)
    return replace(spec, mix=mix, lag_s=lag)


def foreign_realism(seed: int, design: Design, effects: tuple[str, ...]) -> Realism:
    """The constants of ``effects`` (of :data:`REALISM_EFFECTS`) for the machine of ``seed``, from
    a stream of their own (the machine and its days are those without them).

    ``hidden_source``: a node of :data:`HIDDEN_SOURCE_NODES`, a power giving it a steady rise of
    :data:`HIDDEN_SOURCE_RISE_K` at rest; per day its level (:data:`HIDDEN_SOURCE_TRAINING_LEVEL`,
    test days :data:`HIDDEN_SOURCE_TEST_LEVELS`), period, duty and phase. ``convection``: the
    exponent (:data:`CONVECTION_EXPONENT`). ``fixed_chiller``: the set point, the training days'
    mean room plus the machine's cooler offset. ``sensor_mount``: the first test day on which
    :data:`MOUNT_SENSORS` sensors (not a room sensor) read reseated (:func:`_reseat`).
    ``warm_start``: each test day with the chance :data:`WARM_START_SHARE` starts after only
    :data:`WARM_REST_H` hours at rest. Drawn in this order, so an effect's constants do not depend
    on which effects follow it.
    """
    effects = tuple(e for e in REALISM_EFFECTS if e in effects)
    if not effects:
        return Realism(())
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 46, 2]))
    params, days = design.params, design.days
    out: dict = {"effects": effects}
    if "hidden_source" in effects:
        node = str(rng.choice(list(HIDDEN_SOURCE_NODES)))
        power = float(rng.uniform(*HIDDEN_SOURCE_RISE_K)) / _steady_rise_k_per_w(params, node)
        per_day = {}
        for d in days:
            if d.role == "training":
                level = float(rng.uniform(*HIDDEN_SOURCE_TRAINING_LEVEL))
            else:
                level = float(rng.uniform(*HIDDEN_SOURCE_TEST_LEVELS[int(rng.integers(0, 2))]))
            period = 60.0 * float(rng.uniform(*HIDDEN_SOURCE_PERIOD_MIN))
            per_day[d.stem] = {
                "level": level,
                "period_s": period,
                "duty": float(rng.uniform(*HIDDEN_SOURCE_DUTY)),
                "phase_s": float(rng.uniform(0.0, period)),
            }
        out.update(source_node=node, source_w=power, source_days=per_day)
    if "convection" in effects:
        out["convection_exponent"] = float(rng.uniform(*CONVECTION_EXPONENT))
    if "fixed_chiller" in effects:
        rooms = [d.ambient.base_c for d in days if d.role == "training"]
        out["cooler_set_c"] = float(np.mean(rooms)) + params.cooler_offset_c
    if "sensor_mount" in effects:
        tests = [d.stem for d in days if d.role == "test"]
        movable = [j for j, spec in enumerate(params.sensors) if spec.position != AMBIENT]
        k = int(rng.integers(*MOUNT_SENSORS, endpoint=True))
        k = max(1, min(k, len(params.sensors) // 5, len(movable)))
        chosen = set(int(j) for j in rng.choice(movable, size=k, replace=False))
        mounted = tuple(_reseat(spec, rng) if j in chosen else spec for j, spec in enumerate(params.sensors))
        out.update(mount_from=str(rng.choice(tests)), mounted=mounted)
    if "warm_start" in effects:
        warm = {}
        for d in days:
            if d.role == "test" and rng.random() < WARM_START_SHARE:
                warm[d.stem] = float(np.exp(rng.uniform(*np.log(WARM_REST_H))))
        out["warm_rest_h"] = warm
    return Realism(**out)


def hidden_source_w(realism: Realism, day: Day, n: int, dt: float) -> np.ndarray:
    """The hidden source's heat (W) into each node at each of ``n`` samples of ``day`` (n x
    nodes): on for ``duty`` of every ``period_s`` from ``phase_s``, at ``level`` times
    :attr:`Realism.source_w`; zeros without the effect."""
    out = np.zeros((n, len(NODES)))
    if "hidden_source" not in realism.effects:
        return out
    p = realism.source_days[day.stem]
    t = np.arange(n) * dt + p["phase_s"]
    on = np.mod(t, p["period_s"]) < p["duty"] * p["period_s"]
    out[:, NODES.index(realism.source_node)] = np.where(on, p["level"] * realism.source_w, 0.0)
    return out


def simulate_day_parts(
    params: TwinParams,
    day: Day,
    seed: int,
    dt: float = FOREIGN_SAMPLE_S,
    setup_drift_um: float = 0.0,
    *,
    realism: Realism | None = None,
    days: list[Day] | None = None,
    warm_from: np.ndarray | None = None,
) -> tuple[pd.DataFrame, pd.DataFrame | None, np.ndarray]:
    """One day's log: a cold start (every node at the room's temperature) through
    :func:`rafi.twin.physics.integrate`; sensors with white and slow noise, quantised; the
    displacement from the probe's zero with white and slow noise; the speed with 1 r/min jitter.
    Values as the file holds them (:data:`TEMP_DECIMALS`, :data:`DISP_DECIMALS`), so what is
    computed from the frame (the envelope) is what a reader of the file computes. With
    ``setup_drift_um`` the displacement also wanders by what no sensor sees (the probe's stand,
    the foundation): a slow AR(1) walk from 0 of that standard deviation and a time constant of
    :data:`SETUP_DRIFT_TAU_S`, from its own random stream (the rest of the day is unchanged).

    With ``realism`` (:func:`foreign_realism`; ``days``: the machine's days, for a reseat) the
    nodes come from :func:`rafi.twin.physics.integrate_realistic` when an effect of
    :data:`NODE_EFFECTS` is drawn (the hidden source's heat, the convection law, the fixed
    chiller; else from :func:`rafi.twin.physics.integrate`), and the sensors are those of the day;
    every noise is the same draw as without. A day of ``realism.warm_rest_h`` with ``warm_from``
    (the nodes at the previous day's end) starts warm: those nodes after that many hours at rest
    in the day's first room temperature (:func:`night`), the probe zeroed on the warm machine.

    Returns
    -------
    tuple
        The log (``time``, ``speed_rpm``, one column per sensor of ``params``, ``disp_um``) and,
        with ``realism``, its parts (noise-free, per row): ``time``, ``realism_um`` (the
        displacement minus the linear twin's: every effect's contribution), ``hidden_source_um``
        (the displacement minus that without the hidden source) and ``hidden_source:<sensor>``
        (each sensor's reading minus that without the hidden source, K); else ``None``; and the
        nodes' temperatures at the day's last sample (for the next day's warm start).
    """
    speeds = sample_schedule(day.schedule, dt)
    n = len(speeds)
    times = day.start + pd.to_timedelta(np.arange(n) * dt, unit="s")
    rng_amb, rng_noise = (np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(2))
    t_amb = ambient_series(day.ambient, times, rng_amb)
    x_ref = np.full(len(NODES), t_amb[0])
    parts = None
    if realism is None or not realism.effects:
        nodes, _ = integrate(params, speeds, t_amb, dt)
        specs = params
    else:
        specs = replace(params, sensors=realism.sensors_on(params, day, days or [day]))
        linear, _ = integrate(params, speeds, t_amb, dt)
        nodes = without = linear
        ref = x_ref
        kw = {"convection_exponent": realism.convection_exponent, "cooler_set_c": realism.cooler_set_c}
        if warm_from is not None and day.stem in realism.warm_rest_h:
            ref = night(params, warm_from, float(t_amb[0]), realism.warm_rest_h[day.stem], dt, **kw)
        if set(realism.effects) & set(NODE_EFFECTS) or ref is not x_ref:
            extra = hidden_source_w(realism, day, n, dt)
            nodes, _ = integrate_realistic(params, speeds, t_amb, dt, extra_w=extra, x0=ref, **kw)
            without, _ = integrate_realistic(params, speeds, t_amb, dt, x0=ref, **kw)
        full = displacement_truth(params, nodes, speeds, dt, ref)
        parts = pd.DataFrame(
            {
                "time": times,
                "realism_um": full - displacement_truth(params, linear, speeds, dt, x_ref),
                "hidden_source_um": full - displacement_truth(params, without, speeds, dt, ref),
            }
        )
        x_ref = ref  # the probe is zeroed on the machine as it starts
        seen = sensor_truth(specs, nodes, t_amb, dt) - sensor_truth(specs, without, t_amb, dt)
        for j, spec in enumerate(specs.sensors):
            parts[f"hidden_source:{spec.name}"] = seen[:, j]
    zero = float(rng_noise.uniform(-1, 1) * params.probe_offset_um)
    disp = displacement_truth(params, nodes, speeds, dt, x_ref) + zero
    temps = sensor_truth(specs, nodes, t_amb, dt)
    a = np.exp(-dt / 600.0)
    slow = ar1(rng_noise.normal(0.0, params.temp_noise_c, temps.shape), a, np.sqrt(1 - a * a))
    temps = temps + rng_noise.normal(0.0, params.temp_noise_c, temps.shape) + slow
    temps = np.round(np.round(temps / params.temp_quantum_c) * params.temp_quantum_c, TEMP_DECIMALS)
    drift = ar1(rng_noise.normal(0.0, params.disp_noise_um * 0.5, n), a, np.sqrt(1 - a * a))
    disp = disp + rng_noise.normal(0.0, params.disp_noise_um, n) + drift
    if setup_drift_um > 0:
        b = np.exp(-dt / SETUP_DRIFT_TAU_S)
        rng_setup = np.random.default_rng(np.random.SeedSequence([int(seed), 7]))
        disp = disp + ar1(rng_setup.normal(0.0, setup_drift_um * np.sqrt(1 - b * b), n), b)
    disp = np.round(np.round(disp / params.disp_quantum_um) * params.disp_quantum_um, DISP_DECIMALS)
    jitter = np.round(rng_noise.normal(0.0, params.speed_jitter_rpm, n))
    frame = pd.DataFrame({"time": times, "speed_rpm": np.where(speeds > 0, speeds + jitter, 0.0)})
    for j, spec in enumerate(params.sensors):
        frame[spec.name] = temps[:, j]
    frame["disp_um"] = disp
    return frame, parts, nodes[-1]


def night(
    params: TwinParams,
    nodes: np.ndarray,
    room_c: float,
    hours: float,
    dt: float = FOREIGN_SAMPLE_S,
    *,
    convection_exponent: float | None = None,
    cooler_set_c: float | None = None,
) -> np.ndarray:
    """The nodes' temperatures after ``hours`` at rest from ``nodes`` in a room at ``room_c``
    (the cooler's thermostat on, ``convection_exponent`` and ``cooler_set_c`` as
    :func:`rafi.twin.physics.integrate_realistic`)."""
    m = max(1, int(round(3600.0 * hours / dt)))
    kw = {"convection_exponent": convection_exponent, "cooler_set_c": cooler_set_c}
    out, _ = integrate_realistic(params, np.zeros(m + 1), np.full(m + 1, room_c), dt, x0=nodes, **kw)
    return out[-1]


def _rises(frame: pd.DataFrame, sensors: list[str], dt: float) -> np.ndarray:
    """Every sensor's rise from the median of the day's first :data:`REFERENCE_S` seconds."""
    values = frame[sensors].to_numpy(dtype=float)
    k = max(1, int(round(REFERENCE_S / dt)))
    return values - np.median(values[:k], axis=0)


def envelope(train: list[pd.DataFrame], sensors: list[str], speeds: list[float], dt: float) -> dict:
    """The training envelope: per sensor the lowest and highest temperature and rise over every
    row of the training days, and the training speeds' range."""
    temps = np.vstack([f[sensors].to_numpy(dtype=float) for f in train])
    rises = np.vstack([_rises(f, sensors, dt) for f in train])
    return {
        "margin_k": ENVELOPE_MARGIN_K,
        "speed_tolerance_rpm": ENVELOPE_SPEED_TOL_RPM,
        "temperature_c": {
            s: [float(temps[:, j].min()), float(temps[:, j].max())] for j, s in enumerate(sensors)
        },
        "rise_k": {s: [float(rises[:, j].min()), float(rises[:, j].max())] for j, s in enumerate(sensors)},
        "speed_rpm": [float(min(speeds)), float(max(speeds))],
    }


def _beyond(values: np.ndarray, bounds: dict, sensors: list[str], margin: float) -> np.ndarray:
    lo = np.array([bounds[s][0] for s in sensors]) - margin
    hi = np.array([bounds[s][1] for s in sensors]) + margin
    return ((values < lo) | (values > hi)).any(axis=1)


def envelope_fractions(frame: pd.DataFrame, env: dict, sensors: list[str], dt: float) -> dict:
    """The fraction of a day's rows outside the training envelope ``env`` (:func:`envelope`).

    A row is outside in temperature when any sensor reads more than ``margin_k`` below its
    training minimum or above its training maximum; in rise likewise with the rise from the
    day's first :data:`REFERENCE_S` seconds; in speed when the spindle turns (at least
    :data:`IDLE_BELOW_RPM`) more than ``speed_tolerance_rpm`` below the slowest or above the
    fastest training speed. ``any``: outside in at least one of the three.

    Returns
    -------
    dict
        ``rows``, ``outside_temperature``, ``outside_rise``, ``outside_speed``, ``outside_any``
        (fractions 0..1) and ``max_excess_k`` (the largest temperature excess beyond the range).
    """
    margin, tol = env["margin_k"], env["speed_tolerance_rpm"]
    temps = frame[sensors].to_numpy(dtype=float)
    t_out = _beyond(temps, env["temperature_c"], sensors, margin)
    r_out = _beyond(_rises(frame, sensors, dt), env["rise_k"], sensors, margin)
    speed = frame["speed_rpm"].to_numpy(dtype=float)
    lo, hi = env["speed_rpm"]
    s_out = (speed >= IDLE_BELOW_RPM) & ((speed < lo - tol) | (speed > hi + tol))
    lo_t = np.array([env["temperature_c"][s][0] for s in sensors])
    hi_t = np.array([env["temperature_c"][s][1] for s in sensors])
    excess = np.maximum(np.maximum(lo_t - temps, temps - hi_t), 0.0).max()
    return {
        "rows": int(len(frame)),
        "outside_temperature": float(t_out.mean()),
        "outside_rise": float(r_out.mean()),
        "outside_speed": float(s_out.mean()),
        "outside_any": float((t_out | r_out | s_out).mean()),
        "max_excess_k": float(excess),
    }


def foreign_config(sensors: list[str], speeds: list[float]) -> dict:
    """The ``machines.<name>`` block that reads a foreign machine: 60 s rows, its training
    speeds, its sensors (native CSV), roles by file name (``*_train*`` trains, ``*_test*``
    validates: the test days)."""
    return {
        "sample_period_s": FOREIGN_SAMPLE_S,
        "training_speeds_rpm": [int(s) for s in speeds],
        "input": {"sensors": list(sensors)},
        "runs": {
            "windows": [{"role": "training", "log": "*_train*"}, {"role": "validation", "log": "*_test*"}]
        },
    }


def _sensor_truth(spec: SensorSpec) -> dict:
    return {
        "name": spec.name,
        "place": spec.position,
        "mix": {k: round(v, 4) for k, v in spec.mix},
        "lag_s": round(spec.lag_s, 1),
        "offset_c": round(spec.offset_c, 3),
    }


@dataclass(frozen=True)
class Design:
    """What a seed draws before any simulation (:func:`foreign_design`): the base network's name,
    the machine's constants and sensors, its training speeds and its days."""

    base: str
    params: TwinParams
    speeds: list[float]
    days: list[Day]


def foreign_design(seed: int, plan: str = "varied") -> Design:
    """The design of the foreign machine of ``seed``, cheap (no day simulated): the base network,
    its spread constants (:func:`foreign_params`), 4-40 sensors (:func:`foreign_sensors`; with
    ``plan="production"`` :data:`PRODUCTION_SENSOR_COUNT`), the training speeds
    (:func:`training_speeds`), a room level of 18-26 degC and the days (:func:`plan_days`, or
    :func:`production_days`)."""
    if plan not in PLANS:
        raise ValueError(f"unknown plan {plan!r}; expected one of {', '.join(PLANS)}")
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 46]))
    base = str(rng.choice(list(BASES)))
    params = foreign_params(machine_params(base), rng)
    lo_n, hi_n = PRODUCTION_SENSOR_COUNT if plan == "production" else SENSOR_COUNT
    params = replace(
        params,
        machine=f"foreign-{int(seed)}",
        sensors=foreign_sensors(int(rng.integers(lo_n, hi_n, endpoint=True)), rng),
    )
    speeds, lo = training_speeds(rng, base)
    days = production_days if plan == "production" else plan_days
    return Design(base, params, speeds, days(rng, speeds, lo, float(rng.uniform(18.0, 26.0))))


def setup_change_of(seed: int, params: TwinParams, days: list[Day]) -> dict:
    """What ``setup_change=True`` changes on the machine of ``seed``, from a stream of its own:
    ``from_day`` (the stem of a training day in the second half of the training days, never the
    last), ``node`` (the largest |displacement gain|) and ``factor`` (:data:`SETUP_CHANGE_FACTOR`,
    the share of the node's gain that reaches the probe from that day on)."""
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 46, 3]))
    training = [d.stem for d in days if d.role == "training"]
    first = max(1, len(training) // 2)
    day = training[int(rng.integers(first, max(first + 1, len(training) - 1)))]
    node = max(params.disp_gain, key=lambda k: abs(params.disp_gain[k]))
    return {"from_day": day, "node": node, "factor": float(rng.uniform(*SETUP_CHANGE_FACTOR))}


def foreign_machine(
    seed: int,
    setup_drift: bool = False,
    realism: tuple[str, ...] | str = (),
    plan: str = "varied",
    setup_change: bool = False,
) -> ForeignMachine:
    """A foreign machine from ``seed``: its name ``foreign-<seed>``, config block, logs and truth.

    Parameters
    ----------
    seed : int
        Controls everything: the base network and its spread, the sensors, speeds, days, rooms
        and noise.
    setup_drift : bool
        The displacement also wanders by what no sensor sees (:func:`simulate_day_parts`), with a
        standard deviation drawn per machine from :data:`SETUP_DRIFT_UM` on a stream of its own:
        the same machine and days as without, plus the drift.
    realism : tuple of str or str
        Effects of :data:`REALISM_EFFECTS` (or a text for :func:`parse_realism`: ``"all"``) that
        real machines have and the linear twin has not (the module's docstring), drawn by
        :func:`foreign_realism` on a stream of their own: the same machine, days and noise as
        without, plus the effects. Default none: the logs are those of the plain machine.
    plan : str
        How its days are planned (:data:`PLANS`): ``varied`` (a qualification's runs and steps,
        :func:`plan_days`) or ``production`` (the same job every day through a season, with
        fewer sensors, :func:`production_days`): another machine from the same seed.
    setup_change : bool
        From a training day in the second half on, the displacement's largest node gain reaches the
        probe only by a factor in :data:`SETUP_CHANGE_FACTOR` (:func:`setup_change_of`): a change
        no sensor sees, so the training runs disagree (``rafi.family.unexplained``). The same
        machine, days, temperatures and noise as without; ``truth["setup_change"]`` says what.

    Returns
    -------
    ForeignMachine
        ``truth`` holds ``seed``, ``base``, the constants that matter (heat sources, capacities,
        displacement gains), ``sensors`` (place, mix, lag, offset), ``training_speeds_rpm``,
        ``days`` (stem, role, kind, hours, speeds, room level), ``envelope`` (:func:`envelope`)
        and ``test_runs`` (per test day: its stem and kind and :func:`envelope_fractions`);
        with ``realism`` also ``realism`` (:func:`realism_truth`), and ``parts`` holds per day
        the noise-free contributions (:func:`simulate_day_parts`).
    """
    design = foreign_design(seed, plan)
    base, params, speeds, days = design.base, design.params, design.speeds, design.days
    drift_um = 0.0
    if setup_drift:
        drift_um = float(np.random.default_rng([int(seed), 46, 1]).uniform(*SETUP_DRIFT_UM))
    effects = parse_realism(realism) if isinstance(realism, str) else tuple(realism)
    unknown = set(effects) - set(REALISM_EFFECTS)
    if unknown:
        raise ValueError(f"unknown realism effect(s) {sorted(unknown)}; known: {', '.join(REALISM_EFFECTS)}")
    real = foreign_realism(seed, design, effects) if effects else None
    change = setup_change_of(seed, params, days) if setup_change else None
    changed = params
    if change is not None:
        gains = {**params.disp_gain, change["node"]: params.disp_gain[change["node"]] * change["factor"]}
        changed = replace(params, disp_gain=gains)
    change_at = [d.stem for d in days].index(change["from_day"]) if change is not None else len(days)
    logs, parts, end = {}, {}, None
    for k, d in enumerate(days):
        seed_k = int(seed) * 1000 + k
        frame, part, end = simulate_day_parts(
            changed if k >= change_at else params,
            d,
            seed_k,
            setup_drift_um=drift_um,
            realism=real,
            days=days,
            warm_from=end,
        )
        logs[d.stem] = frame
        if part is not None:
            parts[d.stem] = part
    names = [s.name for s in params.sensors]
    env = envelope([logs[d.stem] for d in days if d.role == "training"], names, speeds, FOREIGN_SAMPLE_S)
    test_runs = [
        {"stem": d.stem, "kind": d.kind, **envelope_fractions(logs[d.stem], env, names, FOREIGN_SAMPLE_S)}
        for d in days
        if d.role == "test"
    ]
    truth = {
        "seed": int(seed),
        "machine": params.machine,
        **({"plan": plan} if plan != "varied" else {}),
        "base": base,
        "sample_period_s": FOREIGN_SAMPLE_S,
        "setup_drift_um": drift_um,
        "heat_w": {
            "bearing_front": params.bearing_front_w,
            "bearing_rear": params.bearing_rear_w,
            "motor_magnetising": params.motor_magnetising_w,
            "motor_iron": params.motor_iron_w,
            "rotor": params.rotor_w,
        },
        "capacity_j_per_k": dict(params.capacity),
        "disp_gain_um_per_k": dict(params.disp_gain),
        "sensors": [_sensor_truth(s) for s in params.sensors],
        "training_speeds_rpm": speeds,
        "days": [
            {
                "stem": d.stem,
                "role": d.role,
                "kind": d.kind,
                "hours": round(sum(s.duration_s for s in d.schedule) / 3600.0, 3),
                "speeds_rpm": [s.speed_rpm for s in d.schedule if s.speed_rpm > 0],
                "room_c": round(d.ambient.base_c, 3),
            }
            for d in days
        ],
        "envelope": env,
        "test_runs": test_runs,
    }
    if real is not None:
        truth["realism"] = realism_truth(real, params, days, parts)
    if change is not None:
        truth["setup_change"] = {**change, "factor": round(change["factor"], 4)}
    return ForeignMachine(params.machine, foreign_config(names, speeds), logs, truth, parts)


def realism_truth(real: Realism, params: TwinParams, days: list[Day], parts: dict[str, pd.DataFrame]) -> dict:
    """What ``realism`` drew, JSON-able: ``effects``; per effect its constants
    (``hidden_source``: node, what it stands for, power and per day level, period, duty;
    ``convection``: exponent; ``fixed_chiller``: set point; ``sensor_mount``: from which day,
    each reseated sensor's lag and room share before and after; ``warm_start``: the hours at rest
    before each warm day); ``days``: per day the mean and
    largest |contribution| (um) of every effect together and of the hidden source alone."""
    out: dict = {"effects": list(real.effects)}
    if "hidden_source" in real.effects:
        out["hidden_source"] = {
            "node": real.source_node,
            "stands_for": HIDDEN_SOURCE_NODES[real.source_node],
            "power_w": round(real.source_w, 3),
            "days": {
                stem: {
                    "level": round(p["level"], 4),
                    "period_min": round(p["period_s"] / 60.0, 2),
                    "duty": round(p["duty"], 4),
                }
                for stem, p in real.source_days.items()
            },
        }
    if "convection" in real.effects:
        out["convection"] = {"exponent": round(real.convection_exponent, 4)}
    if "fixed_chiller" in real.effects:
        out["fixed_chiller"] = {"set_c": round(real.cooler_set_c, 3)}
    if "sensor_mount" in real.effects:
        moved = [
            {
                "name": a.name,
                "lag_s": [round(a.lag_s, 1), round(b.lag_s, 1)],
                "ambient_share": [
                    round(dict(a.mix).get(AMBIENT, 0.0), 4),
                    round(dict(b.mix).get(AMBIENT, 0.0), 4),
                ],
            }
            for a, b in zip(params.sensors, real.mounted)
            if a != b
        ]
        out["sensor_mount"] = {"from_day": real.mount_from, "sensors": moved}
    if "warm_start" in real.effects:
        out["warm_start"] = {"rest_h": {stem: round(h, 3) for stem, h in real.warm_rest_h.items()}}
    out["days"] = {
        d.stem: {
            "realism_mae_um": round(float(parts[d.stem]["realism_um"].abs().mean()), 4),
            "realism_max_um": round(float(parts[d.stem]["realism_um"].abs().max()), 4),
            "hidden_source_mae_um": round(float(parts[d.stem]["hidden_source_um"].abs().mean()), 4),
        }
        for d in days
    }
    return out


def write_foreign(
    seed: int,
    out_dir: str | os.PathLike,
    setup_drift: bool = False,
    realism: tuple[str, ...] | str = (),
    plan: str = "varied",
    setup_change: bool = False,
) -> tuple[ForeignMachine, list[Path]]:
    """Write the foreign machine of ``seed`` as a project's data; returns the machine and the files
    written (logs first).

    Into a new folder: its logs as native CSVs in ``out_dir/raw/<name>/``, ``out_dir/config.yaml``
    (that machine only) and ``out_dir/truth.json``. Into a project that has a ``config.yaml``: the
    machine's block added under its ``machines:`` (:func:`rafi.ops.init_config.add_machine`: the
    rest of the file, comments included, as it was), the logs in the project's ``raw_dir`` and
    the truth in ``out_dir/truth-<name>.json``; the same machine again changes nothing. Beside
    ``Snakefile`` and ``workflow/`` (copied, or ``snakemake -s <Snakefile> -d out_dir``) the
    folder is a project. ``setup_drift``, ``realism``, ``plan``, ``setup_change``:
    :func:`foreign_machine` (the parts are not written; the truth says what was drawn).

    Raises
    ------
    rafi.errors.SettingsError
        The project's ``config.yaml`` cannot be read, or has a machine of that name with other
        settings (nothing is written).
    """

    from rafi.artefact import write_text_atomic
    from rafi.readers.native import format_raw_log

    machine = foreign_machine(
        seed, setup_drift=setup_drift, realism=realism, plan=plan, setup_change=setup_change
    )
    out = Path(out_dir)
    config_file = out / "config.yaml"
    config_text, raw_dir, truth_file = _project_for(machine, config_file)
    folder = out / raw_dir / machine.name
    folder.mkdir(parents=True, exist_ok=True)
    sensors = machine.config["input"]["sensors"]
    written = []
    for stem, frame in machine.logs.items():
        meta = {"machine": machine.name, "run_id": stem, "sample_period_s": f"{FOREIGN_SAMPLE_S:g}"}
        path = folder / f"{stem}.csv"
        decimals = {"disp_um": DISP_DECIMALS, **{s: TEMP_DECIMALS for s in sensors}}
        write_text_atomic(path, format_raw_log(frame, meta, decimals=decimals))
        written.append(path)
    if config_text is not None:
        write_text_atomic(config_file, config_text)
    write_text_atomic(out / truth_file, json.dumps(machine.truth, indent=1) + "\n")
    return machine, [*written, config_file, out / truth_file]


def _project_for(machine: ForeignMachine, config_file: Path) -> tuple[str | None, str, str]:
    """Where :func:`write_foreign` puts ``machine`` beside ``config_file``: ``(the config text to
    write, or None to leave the file as it is; the raw_dir; the truth's file name)``."""
    import yaml

    from rafi.errors import SettingsError
    from rafi.ops.init_config import add_machine
    from rafi.settings import run_settings

    block = {machine.name: machine.config}
    if not config_file.exists():
        config = {"raw_dir": "raw", "results_dir": "results", "reports_dir": "reports", "defaults": {}}
        return yaml.safe_dump({**config, "machines": block}, sort_keys=False), "raw", "truth.json"
    try:
        text = config_file.read_text(encoding="utf-8")
        config = yaml.safe_load(text) or {}
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise SettingsError(f"{config_file}: cannot read the config ({exc}); nothing written") from None
    raw_dir = str(run_settings(config)["raw_dir"])
    truth_file = f"truth-{machine.name}.json"
    present = (config.get("machines") or {}).get(machine.name)
    if present == json.loads(json.dumps(machine.config)):
        return None, raw_dir, truth_file
    if present is not None:
        raise SettingsError(
            f"{config_file}: machine {machine.name!r} is already under machines: with other settings; "
            "nothing written (remove its entry, or write into another --out)"
        )
    lines = yaml.safe_dump(block, sort_keys=False).splitlines()
    new_text, _ = add_machine(text, "".join(f"  {line}\n" for line in lines), machine.name)
    return new_text, raw_dir, truth_file
