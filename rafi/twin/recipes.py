"""The shipped-data recipe: one :class:`RunSpec` per shipped log, its seed, schedule and room.

Every shipped seed derives from :data:`SHIPPED_SEED`; :func:`shipped_specs` lists the logs of a
machine and :func:`simulate_spec` simulates one. The writers are in :mod:`rafi.twin.writers`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from rafi.twin.machines import Ambient, DefectRates
from rafi.twin.schedules import (
    MULTI_CONDITION_A,
    REST_BEFORE_START_S,
    Step,
    constant_schedule,
    multi_condition_schedule,
    with_rest,
)
from rafi.twin.simulate import TwinRun, simulate_run

#: Seed from which every shipped run's seed is derived (documented in docs/twin.md).
SHIPPED_SEED = 2023
#: The command that regenerates the shipped data (written into every shipped file).
SHIPPED_COMMAND = "rafi simulate shipped --out raw"


@dataclass(frozen=True)
class RunSpec:
    """One shipped log: file name, schedule, clock start, seed and room model."""

    machine: str
    file: str
    run_id: str
    schedule: tuple
    start: str | pd.Timestamp
    seed: int
    ambient: Ambient
    description: str
    defects: DefectRates = DefectRates()


def simulate_spec(spec: RunSpec, **overrides) -> TwinRun:
    """Simulate the log of ``spec``; ``overrides`` go to :func:`rafi.twin.simulate.simulate_run`."""
    kwargs = dict(
        machine=spec.machine, seed=spec.seed, start=spec.start, ambient=spec.ambient, defects=spec.defects
    )
    return simulate_run(spec.schedule, **{**kwargs, **overrides})


def _spec_a(i, file, desc, schedule, *, start, base_c, drift):
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
                    start=start,
                    base_c=base,
                    drift=drift,
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
                    start=start,
                    base_c=base,
                    drift=drift,
                )
            )
        specs.append(
            _spec_a(
                20,
                "multi_condition.csv",
                f"multi-condition validation run, {rest:g} s at rest, then 4.5 h of speed steps "
                + ", ".join(f"{n} r/min {m} min" for m, n in MULTI_CONDITION_A),
                with_rest(multi_condition_schedule()),
                start="2026-03-17T08:00:00",
                base_c=22.3,
                drift=0.02,
            )
        )
        return specs
    if machine == "machining-center-b":
        return [machining_center_b_spec()]
    raise ValueError(f"unknown machine {machine!r}")


#: machining-center-b: training 1250/2500/3750/5000 r/min and validation 3500 r/min, each from the
#: end of an idle cool-down (``(hours, r/min, remark)`` steps; 0 h to 33 h of the log).
RUNS_B = (
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
)
#: machining-center-b: 4 h of short varying-speed steps, below the lowest trained speed too (33 h to 37 h).
VARYING_B = (
    (25 / 60, 800, "Wechsellast"),
    (35 / 60, 4200, ""),
    (30 / 60, 1800, ""),
    (20 / 60, 600, ""),
    (40 / 60, 3000, ""),
    (30 / 60, 4800, ""),
    (25 / 60, 1000, ""),
    (35 / 60, 2200, "Ende Wechsellast"),
)
#: machining-center-b: the end of the log like real logs end (37 h to 48 h): a cool-down, then steps of
#: 1-2 h whose speed only decreases, one of them 1 h at a training speed (2500 r/min: exactly
#: ``runs.min_constant_s`` long, so it segments as a constant run that lies after the validation runs),
#: then a final cool-down.
STEPS_B = (
    (3.0, 0, "Stillstand"),
    (2.0, 4500, "Stufe 4500 1/min"),
    (1.0, 2500, "Stufe 2500 1/min"),
    (1.0, 1500, "Stufe 1500 1/min"),
    (1.0, 500, "Stufe 500 1/min"),
    (3.0, 0, "Stillstand, Messende"),
)
#: machining-center-b continuous log (48 h): :data:`RUNS_B`, :data:`VARYING_B`, :data:`STEPS_B`.
SCHEDULE_B = RUNS_B + VARYING_B + STEPS_B
B_FILE = "thermal_log_2026-10-14.xlsx"
B_START = "2026-10-14T06:00:00"


def machining_center_b_spec(
    seed: int = SHIPPED_SEED * 100 + 50,
    start: str = B_START,
    file: str = B_FILE,
    ambient: Ambient | None = None,
    schedule=SCHEDULE_B,
) -> RunSpec:
    """The machining-center-b log: one continuous log of ``(hours, r/min, remark)`` steps."""
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
        "continuous 48 h log, training 1250/2500/3750/5000 r/min, validation 3500 r/min, "
        "idle cool-downs, 4 h of varying speed, a cool-down, decreasing 1-2 h steps "
        "4500/2500/1500/500 r/min and a final cool-down",
        DefectRates.light(),
    )
