"""A new day of logs for a machine (``rafi simulate day``): new file names, never overwritten."""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd

from rafi.twin.machines import Ambient, DefectRates, machine_params
from rafi.twin.recipes import VARYING_B, RunSpec, machining_center_b_spec
from rafi.twin.schedules import (
    REST_BEFORE_START_S,
    constant_schedule,
    multi_condition_schedule,
    schedule_from_pairs,
    with_rest,
)
from rafi.twin.writers import render_run, render_xlsx

# --------------------------------------------------------------------------- a new day

#: Default training speeds of ``rafi simulate day`` per machine.
TRAINING_SPEEDS = {
    "tapping-center-a": (3000, 6000, 9000, 12000, 15000, 18000),
    "machining-center-b": (1250, 2500, 3750, 5000),
}


def _runs_a(speeds, validation_speeds, multi, hours) -> list[tuple[str, list, str]]:
    """``(file stem, schedule, description)`` of each tapping-center-a log of a day."""
    rest = f"{REST_BEFORE_START_S:g} s at rest"
    run_hours = hours or 4.0
    runs = [
        (
            f"train_{int(sp):05d}rpm",
            with_rest(constant_schedule(sp, run_hours * 3600.0)),
            f"training run, {run_hours:g} h at {int(sp)} r/min, cold start after {rest}",
        )
        for sp in speeds
    ]
    runs += [
        (
            f"valid_{int(sp):05d}rpm",
            with_rest(constant_schedule(sp, 3 * 3600.0)),
            f"validation run, 3 h at {int(sp)} r/min, cold start after {rest}",
        )
        for sp in validation_speeds
    ]
    if multi:
        runs.append(
            (
                "multi_condition",
                with_rest(multi_condition_schedule()),
                f"multi-condition run, {rest}, then 4.5 h",
            )
        )
    return runs


def plan_runs(plan) -> list[tuple[str, list, str]]:
    """``(file stem, schedule, description)`` of each recording of a test plan (``rafi plan``,
    ``rafi record --plan``: :class:`rafi.deploy.record_plan.Plan`), for tapping-center-a.

    Consecutive steps with the same ``run`` are one recording; a step without a run is not
    recorded. Each recording starts cold (an unrecorded step between two recordings stands for a
    cool-down long enough to reach the room's temperature, ``docs/twin.md``). A recording whose
    first step is at rest (0 r/min: the rest ``rafi plan`` writes, within
    ``runs.max_leading_rest_s``) is logged as the plan says, as ``rafi record --plan`` logs it;
    one that starts at a speed gets ``REST_BEFORE_START_S`` at rest first, as the shipped logs
    do (never both: a rest of the plan's and the twin's together could exceed
    ``runs.max_leading_rest_s`` and be cut as a run of its own).
    """
    runs: list[tuple[str, list, str]] = []
    last = None
    for step in plan.steps:
        if step.run is None:
            last = None
            continue
        if step.run != last:
            runs.append((step.run, [], f"plan {Path(plan.path).name}, recording {step.run}"))
            last = step.run
        runs[-1][1].append((float(step.duration_s), float(step.speed_rpm)))
    return [
        (stem, with_rest(schedule_from_pairs(steps), 0.0 if steps[0][1] == 0 else REST_BEFORE_START_S), desc)
        for stem, steps, desc in runs
    ]


def _plan_steps_b(plan) -> list[tuple[float, float, str]]:
    """``(hours, r/min, remark)`` of every step of a plan (machining-center-b logs continuously)."""
    return [
        (s.duration_s / 3600.0, s.speed_rpm, f"Plan {s.run or 'Pause'} {s.speed_rpm:g} 1/min")
        for s in plan.steps
    ]


def _steps_b(speeds, validation_speeds, multi, hours) -> list[tuple[float, float, str]]:
    """``(hours, r/min, remark)`` steps of the continuous machining-center-b log of a day."""
    steps = []
    for sp in speeds:
        steps += [(hours or 4.0, sp, f"Warmlauf {sp} 1/min"), (3.0, 0, "Stillstand")]
    for sp in validation_speeds:
        steps += [(3.0, sp, f"Validierung {sp} 1/min"), (2.0, 0, "Stillstand")]
    if multi:
        steps += list(VARYING_B)
    return steps


def _day_command(
    machine, seed, date_s, *, ambient_shift, sensor_drift, wear, sibling, name, plan, speeds,
    validation_speeds, multi, hours, defects, stuck_displacement,
) -> str:  # fmt: skip
    """The ``rafi simulate day`` command line that regenerates a day (written into each log)."""
    parts = [f"rafi simulate day --machine {machine} --seed {seed} --date {date_s}"]
    if ambient_shift:
        parts.append(f"--ambient-shift {ambient_shift:g}")
    parts += [f"--sensor-drift {k}:{v:g}" for k, v in sorted((sensor_drift or {}).items())]
    if wear:
        parts.append(f"--wear {wear:g}")
    if sibling is not None:
        parts.append(f"--sibling {int(sibling)}")
    if name:
        parts.append(f"--name {name}")
    if plan is not None:
        parts.append(f"--plan {Path(plan.path).name}")
    if speeds:
        parts.append("--speeds " + ",".join(str(int(s)) for s in speeds))
    if validation_speeds:
        parts.append("--validation-speeds " + ",".join(str(int(s)) for s in validation_speeds))
    flags = [
        (multi, "--multi"),
        (hours, f"--hours {hours or 0:g}"),
        (not defects, "--no-defects"),
        (stuck_displacement, "--stuck-displacement"),
    ]
    parts += [flag for on, flag in flags if on]
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
    plan=None,
    sibling: int | None = None,
    name: str | None = None,
) -> list[Path]:
    """Write a new day of logs for ``machine`` under ``out_dir/<machine>/``.

    File names carry the date and the seed (``<date>_s<seed>_train_03000rpm.csv`` ...;
    machining-center-b: ``thermal_log_<date>_s<seed>.xlsx``) and existing files are never
    overwritten (``FileExistsError``). With ``plan`` (a :class:`rafi.deploy.record_plan.Plan`)
    the plan's recordings are the training runs (:func:`plan_runs`) instead of ``speeds``. With
    ``sibling`` (a seed) the logs are those of another machine of the same series: every physical
    constant spread by its build factor (:func:`rafi.twin.scenarios.sibling_params`). ``name``
    is the machine's name in the project (its folder, and the header of tapping-center-a's logs:
    a sibling is another machine of the same twin); default ``machine``.
    Constant-speed runs are cold starts on consecutive days starting at ``date``; every
    tapping-center-a log (training, validation, multi-condition) starts with
    ``REST_BEFORE_START_S`` (180 s) at rest before the spindle starts, like the shipped logs.
    """
    from rafi.artefact import write_bytes_atomic, write_text_atomic

    machine_params(machine)  # an unknown machine raises ValueError
    speeds = list(TRAINING_SPEEDS[machine] if speeds is None and plan is None else speeds or [])
    validation_speeds = list(validation_speeds or [])
    day0 = (
        pd.Timestamp(date) if date else pd.Timestamp("2026-04-01") + pd.Timedelta(days=int(seed))
    ).normalize()
    date_s = day0.strftime("%Y-%m-%d")
    command = _day_command(
        machine, seed, date_s, ambient_shift=ambient_shift, sensor_drift=sensor_drift, wear=wear,
        sibling=sibling, name=name, plan=plan, speeds=speeds, validation_speeds=validation_speeds,
        multi=multi, hours=hours, defects=defects, stuck_displacement=stuck_displacement,
    )  # fmt: skip
    overrides = dict(sensor_drift=sensor_drift, wear=wear, stuck_displacement=stuck_displacement)
    if sibling is not None:
        from rafi.twin.scenarios import sibling_params

        overrides["params"] = sibling_params(machine_params(machine), int(sibling))
    folder = Path(out_dir) / (name or machine)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 99]))
    rates = DefectRates() if defects else DefectRates.none()
    if machine == "machining-center-b":
        steps = (_plan_steps_b(plan) if plan is not None else []) + _steps_b(
            speeds, validation_speeds, multi, hours
        )
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
        write_bytes_atomic(target, render_xlsx(spec, remarks=tuple(steps), command=command, **overrides))
        return [target]
    runs = (plan_runs(plan) if plan is not None else []) + _runs_a(speeds, validation_speeds, multi, hours)
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
        spec = RunSpec(
            machine, file, Path(file).stem, tuple(sched), start, int(seed) * 1000 + k, amb, desc, rates
        )
        text, _ = render_run(spec, command, name=name, **overrides)
        write_text_atomic(target, text)
        written.append(target)
    return written
