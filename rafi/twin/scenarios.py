"""Re-qualification scenarios with a known truth: an old machine, a changed new one (docs/twin.md).

Each :class:`Scenario` pairs the OLD machine (the shipped twin of a machine, qualified with the
full test plan) with a NEW machine that differs in one stated way:

* ``sibling`` - the same series: every physical constant (heat capacities, conductances, heat
  sources, displacement sensitivities, centrifugal draw-in, sensor lags) times a seeded factor
  ``exp(0.04 z)``, ``z`` standard normal clipped to +-2 (a build spread of about 4 %, at most 8 %);
  the sensor positions (mixes) and the noise stay;
* ``reworn`` - a re-worn spindle: bearing friction +30 % (the physics' ``wear``) and the
  shaft-bearing contact conductances x1.25 (a higher preload after the bearings were set again);
* ``season`` - summer: the room 6 K warmer with a daily swing of 1.5 K instead of 0.6 K, and the
  coolant held 1 K further below the room (oil-cooler set point room - 1.2 K instead of - 0.2 K);
* ``replaced_sensor`` - one key sensor (T8, rear bearing) replaced: +0.4 K offset, gain 1.04,
  time constant x1.3.

The runs are simulated CLEAN straight into a runs table and frame (no logger defects, so no
clean/segmentation step; the approach of ``benchmarks/bench_models.py`` ``twin_preview``), with
the logger's noise and each run's rises against the median of its first 60 s, as rule ``runs``
makes them. Every run set also carries the noise-free displacement rise (the truth), so a
benchmark can state the noise floor: the worst residual a perfect model would still show.
"""

from __future__ import annotations

import hashlib
import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from rafi import SENSORS
from rafi.twin.machines import Ambient, SensorSpec, TwinParams, machine_params
from rafi.twin.recipes import RUNS_B, VARYING_B, shipped_specs
from rafi.twin.schedules import Step, constant_schedule, sample_schedule, with_rest
from rafi.twin.simulate import simulate_run

__all__ = [
    "SCENARIOS",
    "KEY_SENSORS",
    "RunSet",
    "Scenario",
    "TwinMachine",
    "combine",
    "make_scenario",
    "scaled_constants",
    "noise_floor",
]

#: The scenarios, in the order the benchmark shows them.
SCENARIOS = ("sibling", "reworn", "season", "replaced_sensor")
#: Key sensors of each machine in the scenarios (tapping-center-a: the paper's).
KEY_SENSORS = {"tapping-center-a": ("T6", "T8", "T9"), "machining-center-b": ("T6", "T8", "T9")}
#: Build spread of a sibling: log-normal sigma of every constant, clipped at 2 sigma.
SIBLING_SPREAD = 0.04
#: The sensor a ``replaced_sensor`` scenario replaces, and how the new one differs.
REPLACED = {"sensor": "T8", "offset_c": 0.4, "gain": 1.04, "lag_factor": 1.3}
#: Re-worn spindle: bearing friction (physics ``wear``) and the shaft-bearing conductance factor.
REWORN = {"wear": 0.30, "preload_conductance_factor": 1.25}
#: Season: room shift, daily swing and the coolant set point below the room.
SEASON = {"room_shift_c": 6.0, "daily_amplitude_c": 1.5, "cooler_offset_c": -1.2}
#: Reference window of every run (rule ``runs``: median of the first 60 s).
REFERENCE_S = 60.0
#: The seed side of a repeated full plan's draws (:meth:`Scenario.new_full_training`): above the
#: sides of the old runs (0), the validation runs (1), the full plan (2) and a plan's programme (3).
REPEAT_SIDE = 100
RISES = [f"d{s}" for s in SENSORS]


@dataclass(frozen=True)
class TwinMachine:
    """One simulated machine: its constants, its bearing wear and how its room differs."""

    params: TwinParams
    wear: float = 0.0
    room_shift_c: float = 0.0
    daily_amplitude_c: float | None = None

    def room(self, ambient: Ambient) -> Ambient:
        """The room of a run of this machine (a recipe's room, shifted by the season)."""
        amp = ambient.daily_amplitude_c if self.daily_amplitude_c is None else self.daily_amplitude_c
        return replace(ambient, base_c=ambient.base_c + self.room_shift_c, daily_amplitude_c=amp)


@dataclass
class RunSet:
    """Runs ready for :func:`rafi.family.compare.run_family`, and their truth.

    Attributes
    ----------
    table : DataFrame
        One row per run: ``run_id``, ``role`` (training, validation_single, validation_multi),
        ``speed_rpm`` (the held speed; 0 for a cool-down), ``kind``, ``duration_s``, ``file`` and
        ``sha256`` (of the run's data, so a prior's data hashes can be checked against it).
    frame : DataFrame
        ``run_id``, ``t_s``, ``speed_rpm``, ``dT1``..``dT16`` and ``dz_um`` (measured rises).
    truth : DataFrame
        ``run_id``, ``t_s`` and ``dz_true_um``: the noise-free displacement rise, row for row
        with ``frame``.
    """

    table: pd.DataFrame
    frame: pd.DataFrame
    truth: pd.DataFrame


def combine(*sets: RunSet) -> RunSet:
    """One run set of several (run ids must differ)."""
    table = pd.concat([s.table for s in sets], ignore_index=True)
    if table["run_id"].duplicated().any():
        raise ValueError(f"run ids repeat: {sorted(table.loc[table['run_id'].duplicated(), 'run_id'])}")
    return RunSet(
        table,
        pd.concat([s.frame for s in sets], ignore_index=True),
        pd.concat([s.truth for s in sets], ignore_index=True),
    )


def noise_floor(runs: RunSet, roles: Sequence[str] = ("validation_single", "validation_multi")) -> float:
    """max |measured - true displacement rise| (um) over the runs of ``roles``: a perfect model's
    worst residual."""
    ids = set(runs.table.loc[runs.table["role"].isin(roles), "run_id"])
    keep = runs.frame["run_id"].isin(ids).to_numpy()
    return float(
        np.max(np.abs(runs.frame["dz_um"].to_numpy()[keep] - runs.truth["dz_true_um"].to_numpy()[keep]))
    )


def noise_mae(runs: RunSet, roles: Sequence[str] = ("validation_single", "validation_multi")) -> float:
    """mean |measured - true displacement rise| (um) over the runs of ``roles``: a perfect model's
    MAE (what :func:`noise_floor` is to the worst residual)."""
    ids = set(runs.table.loc[runs.table["role"].isin(roles), "run_id"])
    keep = runs.frame["run_id"].isin(ids).to_numpy()
    return float(
        np.mean(np.abs(runs.frame["dz_um"].to_numpy()[keep] - runs.truth["dz_true_um"].to_numpy()[keep]))
    )


def _factor(rng: np.random.Generator) -> float:
    return float(np.exp(SIBLING_SPREAD * np.clip(rng.standard_normal(), -2.0, 2.0)))


def sibling_params(params: TwinParams, seed: int) -> TwinParams:
    """``params`` of a machine of the same series: every constant times a seeded build factor.

    Spread (:data:`SIBLING_SPREAD`): capacities, fixed and speed-dependent conductances (both
    terms; the exponents stay), room conductances, coolant flow, cooler power, every heat source,
    every displacement sensitivity, the centrifugal draw-in and every sensor's lag. Kept: sensor
    mixes and offsets, noise, quanta, the thermostat.
    """
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 27]))
    return replace(
        params,
        **scaled_constants(params, lambda: _factor(rng)),
        sensors=tuple(replace(s, lag_s=s.lag_s * _factor(rng)) for s in params.sensors),
    )


def scaled_constants(params: TwinParams, factor) -> dict:
    """Every physical constant of ``params`` but the sensors' (capacities, fixed and
    speed-dependent conductances - both terms, the exponents stay -, room conductances, coolant
    flow, cooler power, every heat source, every displacement sensitivity, the centrifugal
    draw-in), each times its own ``factor()``, drawn in that order: the keyword arguments of
    :func:`dataclasses.replace` (:func:`sibling_params`,
    :func:`rafi.twin.requalify_scenarios.random_design`)."""

    def law(g):
        return (g[0] * factor(), g[1] * factor(), g[2])

    return {
        "capacity": {k: v * factor() for k, v in params.capacity.items()},
        "links": {k: v * factor() for k, v in params.links.items()},
        "speed_links": {k: law(v) for k, v in params.speed_links.items()},
        "to_ambient": {k: law(v) for k, v in params.to_ambient.items()},
        "coolant_flow_w_per_k": params.coolant_flow_w_per_k * factor(),
        "cooler_power_w": params.cooler_power_w * factor(),
        "bearing_front_w": params.bearing_front_w * factor(),
        "bearing_rear_w": params.bearing_rear_w * factor(),
        "motor_magnetising_w": params.motor_magnetising_w * factor(),
        "motor_iron_w": params.motor_iron_w * factor(),
        "rotor_w": params.rotor_w * factor(),
        "disp_gain": {k: v * factor() for k, v in params.disp_gain.items()},
        "centrifugal_um": params.centrifugal_um * factor(),
    }


def replaced_sensor(spec: SensorSpec, offset_c: float, gain: float, lag_factor: float) -> SensorSpec:
    """A new sensor at the place of ``spec``: reads ``gain`` x the temperature (the mix weights
    scaled), ``offset_c`` more, through a lag ``lag_factor`` times as long."""
    mix = tuple((node, w * gain) for node, w in spec.mix)
    return replace(spec, mix=mix, offset_c=spec.offset_c + offset_c, lag_s=spec.lag_s * lag_factor)


def new_machine(name: str, params: TwinParams, seed: int = 0) -> TwinMachine:
    """The NEW machine of scenario ``name`` made from the OLD machine's ``params``."""
    if name == "sibling":
        return TwinMachine(sibling_params(params, seed))
    if name == "reworn":
        f = REWORN["preload_conductance_factor"]
        links = {
            k: v * f if k in {("shaft", "front_bearing"), ("shaft", "rear_bearing")} else v
            for k, v in params.links.items()
        }
        return TwinMachine(replace(params, links=links), wear=REWORN["wear"])
    if name == "season":
        return TwinMachine(
            replace(params, cooler_offset_c=SEASON["cooler_offset_c"]),
            room_shift_c=SEASON["room_shift_c"],
            daily_amplitude_c=SEASON["daily_amplitude_c"],
        )
    if name == "replaced_sensor":
        r = REPLACED
        sensors = tuple(
            replaced_sensor(s, r["offset_c"], r["gain"], r["lag_factor"]) if s.name == r["sensor"] else s
            for s in params.sensors
        )
        return TwinMachine(replace(params, sensors=sensors))
    raise ValueError(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}")


@dataclass(frozen=True)
class QualificationRun:
    """One cold-start run of a machine's full test plan."""

    run_id: str
    role: str
    speed_rpm: float
    schedule: tuple
    start: str
    ambient: Ambient
    seed: int


def qualification(machine: str) -> list[QualificationRun]:
    """The full test plan of ``machine`` as cold-start runs (180 s at rest, then the spindle).

    tapping-center-a: the shipped runs (six 4 h training runs 3000..18000 r/min, five single-speed
    validation runs, the 4.5 h multi-condition run) with their rooms and seeds. machining-center-b:
    its shipped schedule's runs as cold starts (4 h training at 1250/2500/3750/5000 r/min, 3 h
    validation at 3500 r/min, the 4 h varying-speed run), one a day.
    """
    if machine == "tapping-center-a":
        out = []
        for s in shipped_specs(machine):
            role = {"train": "training", "valid": "validation_single"}.get(s.run_id.split("_")[0])
            speed = max(st.speed_rpm for st in s.schedule)
            if role is None:
                role, speed = "validation_multi", float(np.median([st.speed_rpm for st in s.schedule[1:]]))
            out.append(
                QualificationRun(s.run_id, role, float(speed), s.schedule, str(s.start), s.ambient, s.seed)
            )
        return out
    if machine == "machining-center-b":
        room = Ambient(base_c=19.5, daily_amplitude_c=1.2, peak_hour=16.0, wander_c=0.15)
        out, day = [], 0
        for hours, speed, _ in RUNS_B:
            if speed > 0:
                role = "validation_single" if speed == 3500 else "training"
                name = f"{'valid' if role != 'training' else 'train'}_{speed:05d}rpm"
                sched = tuple(with_rest(constant_schedule(speed, hours * 3600.0)))
                out.append(
                    QualificationRun(
                        name, role, float(speed), sched, f"2026-10-{14 + day}T06:00:00", room, 5000 + day
                    )
                )
                day += 1
        varying = tuple(with_rest([Step(h * 3600.0, float(n)) for h, n, _ in VARYING_B]))
        out.append(
            QualificationRun(
                "varying",
                "validation_multi",
                2500.0,
                varying,
                f"2026-10-{14 + day}T06:00:00",
                room,
                5000 + day,
            )
        )
        return out
    raise ValueError(f"unknown machine {machine!r}")


def _seed(*parts: int) -> int:
    return int(np.random.SeedSequence([int(p) for p in parts]).generate_state(1)[0])


def _rise(values: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """``values`` against the median of their first :data:`REFERENCE_S` (at least one sample)."""
    ref = t_s <= t_s[0] + REFERENCE_S
    return values - np.median(values[ref], axis=0)


def simulate_runs(
    machine: TwinMachine,
    steps: Sequence[Step],
    runs: Sequence[tuple[str, str, float, int, int]],
    *,
    log_name: str,
    seed: int,
    start: str,
    ambient: Ambient,
    dt: float,
    reference: str = "run_start",
) -> RunSet:
    """Simulate ``steps`` on ``machine`` from cold as ONE log ``log_name``, cut into ``runs``.

    The frame is what rule ``runs`` makes of a log: the absolute readings (``T1``..``T16``,
    ``disp_um``), the rises against each run's first 60 s, ``t_s`` from the run's start and
    ``log`` / ``log_t_s`` / ``segment`` (0), so the family's filters carry the machine's state
    from one run of the log to the next (docs/models.md, "Whole-log dynamics").

    Parameters
    ----------
    machine : TwinMachine
    steps : sequence of Step
        The whole log's programme.
    runs : sequence of (run_id, role, speed_rpm, first_sample, n_samples)
        The runs of the log (samples outside every run are simulated but not kept).
    log_name : str
        The log's name (its file stem).
    seed, start, ambient, dt
        As :func:`rafi.twin.simulate.simulate_run` (no logger defects; the room shifted by
        :meth:`TwinMachine.room`).
    reference : {"run_start", "log_start"}
        The rises and ``dz_um`` against each run's first 60 s (``reference.rule: run_start``) or
        against the log's (``log_start``).
    """
    sim = simulate_run(
        steps,
        params=machine.params,
        seed=seed,
        start=start,
        ambient=machine.room(ambient),
        defects=False,
        sample_period_s=dt,
        wear=machine.wear,
    )
    log, truth = sim.log, sim.truth
    temps, disp = log[list(SENSORS)].to_numpy(), log["disp_um"].to_numpy()
    true_disp = truth["disp_um"].to_numpy()
    if reference not in ("run_start", "log_start"):
        raise ValueError(f"reference {reference!r}: expected run_start or log_start")
    log_t = np.arange(len(log)) * dt
    rows, frames, truths = [], [], []
    for run_id, role, speed, first, n in runs:
        part = slice(first, first + n)
        t_s = np.arange(n) * dt

        def rise(values, part=part, t_s=t_s):
            if reference == "run_start":
                return _rise(values[part], t_s)
            return _rise(values, log_t)[part]

        frame = pd.DataFrame({"run_id": run_id, "t_s": t_s, "speed_rpm": log["speed_rpm"].to_numpy()[part]})
        for j, name in enumerate(SENSORS):
            frame[name] = temps[part, j]
        frame["disp_um"] = disp[part]
        rises = rise(temps)
        for j, name in enumerate(RISES):
            frame[name] = rises[:, j]
        frame["dz_um"] = rise(disp)
        frame["log"], frame["log_t_s"], frame["segment"] = log_name, (first + np.arange(n)) * dt, 0
        true = rise(true_disp)
        digest = hashlib.sha256(frame[["t_s", "speed_rpm", *RISES, "dz_um"]].to_numpy().tobytes()).hexdigest()
        kind = "idle" if speed == 0 else ("varying" if role == "validation_multi" else "constant")
        rows.append(
            {"run_id": run_id, "role": role, "speed_rpm": float(speed), "kind": kind, "duration_s": n * dt}
            | {
                "log": log_name,
                "segment": 0,
                "start_s": first * dt,
                "file": f"{log_name}.csv",
                "sha256": digest,
            }
        )
        frames.append(frame)
        truths.append(pd.DataFrame({"run_id": run_id, "t_s": t_s, "dz_true_um": true}))
    return RunSet(
        pd.DataFrame(rows), pd.concat(frames, ignore_index=True), pd.concat(truths, ignore_index=True)
    )


def plan_pieces(
    plan: pd.DataFrame, dt: float, max_leading_rest_s: float | None = None
) -> list[tuple[str, list[tuple[str, float, int, int]]]]:
    """The logs and runs the pipeline cuts from ``plan`` (the :func:`rafi.method.runs.find_runs` rules
    for a clean log of held speeds).

    Each recording (consecutive steps of one ``run``) is a log; in it, consecutive steps at one
    speed form a run, and a first idle piece shorter than ``max_leading_rest_s``
    (``runs.max_leading_rest_s``; None: its default) is the rest before the next run's start.
    Steps are rounded to whole samples.

    Returns
    -------
    list of (log name, [(run suffix, speed_rpm, first_sample, n_samples), ...])
        Sample positions count from the plan's start.
    """
    if max_leading_rest_s is None:
        from rafi.settings import MACHINE_DEFAULTS

        max_leading_rest_s = float(MACHINE_DEFAULTS["runs"]["max_leading_rest_s"])
    names = [str(r) if isinstance(r, str) else "" for r in plan["run"]]
    counts = [int(round(float(d) / dt)) for d in plan["duration_s"]]
    speeds = [float(v) for v in plan["speed_rpm"]]
    out, first = [], 0
    for name, group in itertools.groupby(range(len(names)), key=names.__getitem__):
        idx = list(group)
        pieces, rest = [], 0
        for speed, same in itertools.groupby(idx, key=speeds.__getitem__):
            n = sum(counts[i] for i in same)
            if speed == 0 and not pieces and rest == 0 and n * dt < max_leading_rest_s:
                rest = n
            else:
                pieces.append((speed, first - rest, n + rest))
                rest = 0
            first += n
        if name:
            runs = [(f"{j + 1:02d}", sp, a, n) for j, (sp, a, n) in enumerate(pieces) if n > 0]
            out.append((name, runs))
    return out


def _one_run(machine: TwinMachine, q: QualificationRun, seed: int, dt: float, prefix: str) -> RunSet:
    n = len(sample_schedule(q.schedule, dt))
    return simulate_runs(
        machine,
        q.schedule,
        [(prefix + q.run_id, q.role, q.speed_rpm, 0, n)],
        log_name=prefix + q.run_id,
        seed=seed,
        start=q.start,
        ambient=q.ambient,
        dt=dt,
    )


@dataclass(frozen=True)
class Scenario:
    """An old machine qualified in full, a new one changed in one stated way (:data:`SCENARIOS`).

    Every run is seeded from ``seed``: the old machine's runs are the same in every scenario of
    a machine (so one old fit serves them all), the new machine's runs use other seeds.
    """

    name: str
    machine: str
    old: TwinMachine
    new: TwinMachine
    seed: int = 0
    sample_period_s: float = 20.0
    key_sensors: tuple = field(default=())

    def _runs(self, which: TwinMachine, side: int, roles: Sequence[str], prefix: str) -> RunSet:
        dt = self.sample_period_s
        return combine(
            *(
                _one_run(which, q, _seed(self.seed, side, q.seed), dt, prefix)
                for q in qualification(self.machine)
                if q.role in roles
            )
        )

    def old_runs(self) -> RunSet:
        """The old machine's full qualification: its training and validation runs (``old-`` ids)."""
        return self._runs(self.old, 0, ("training", "validation_single", "validation_multi"), "old-")

    def new_validation(self) -> RunSet:
        """The new machine's validation runs (the full plan's, ``new-`` ids)."""
        return self._runs(self.new, 1, ("validation_single", "validation_multi"), "new-")

    def new_full_training(self, draw: int = 0) -> RunSet:
        """The new machine's training runs of the full test plan (``new-`` ids). ``draw`` > 0: the
        same plan run again on the same machine, every run seeded afresh (its noise), as a second
        qualification would be: how far two full plans from scratch lie apart."""
        if draw < 0:
            raise ValueError(f"draw must be 0 or more, got {draw}")
        return self._runs(self.new, 2 if draw == 0 else REPEAT_SIDE + draw, ("training",), "new-")

    def new_runs(self) -> RunSet:
        """The new machine's full qualification: :meth:`new_full_training` + :meth:`new_validation`."""
        return combine(self.new_full_training(), self.new_validation())

    def plan_runs(
        self, plan: pd.DataFrame, start: str = "2026-06-01T07:00:00", reference: str = "run_start"
    ) -> RunSet:
        """The new machine following ``plan`` (:func:`rafi.ops.plan.plan_programme`) from cold, in one
        go: every run the pipeline would cut from its recordings (:func:`plan_pieces`) is a training
        run ``new-<recording>-<nn>`` (speed 0: a cool-down), each recording one log, its runs
        referenced as ``reference`` says (:func:`simulate_runs`)."""
        dt = self.sample_period_s
        steps = [Step(float(d), float(s)) for d, s in zip(plan["duration_s"], plan["speed_rpm"])]
        digest = hashlib.sha256(plan[["speed_rpm", "duration_s"]].to_numpy(float).tobytes()).digest()
        seed = _seed(self.seed, 3, int.from_bytes(digest[:4], "big"))
        sets = []
        for name, pieces in plan_pieces(plan, dt):
            runs = [(f"new-{name}-{suffix}", "training", sp, a, n) for suffix, sp, a, n in pieces]
            sets.append(
                simulate_runs(
                    self.new,
                    steps,
                    runs,
                    log_name=f"new-{name}",
                    seed=seed,
                    start=start,
                    ambient=Ambient(),
                    dt=dt,
                    reference=reference,
                )
            )
        return combine(*sets)


def make_scenario(
    name: str, machine: str = "tapping-center-a", *, seed: int = 0, sample_period_s: float = 20.0
) -> Scenario:
    """Scenario ``name`` (:data:`SCENARIOS`) of ``machine`` (the shipped twin is the OLD machine)."""
    params = machine_params(machine)
    return Scenario(
        name,
        machine,
        TwinMachine(params),
        new_machine(name, params, seed),
        seed,
        float(sample_period_s),
        KEY_SENSORS[machine],
    )
