"""Speed schedules: the twin's steps and the piecewise-constant profiles of the synthetic logs.

Two spellings of a schedule are in use and both are served here: steps of
``(duration_s, speed_rpm)`` (:class:`Step`, the twin and :func:`rafi.twin.synthetic_logs.schedule_log`)
sampled by :func:`sample_schedule`, and ``(start_s, speed_rpm)`` change points evaluated at
arbitrary times by :func:`speed_at` (:func:`rafi.twin.synthetic_logs.canonical_log`,
:func:`rafi.twin.synthetic_runs.make_synthetic_runs`).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Step:
    """One step of a speed schedule: hold ``speed_rpm`` for ``duration_s`` seconds."""

    duration_s: float
    speed_rpm: float


def sample_schedule(schedule: Sequence[Step], dt: float) -> np.ndarray:
    """Speed of every sample: each step held for ``round(duration_s / dt)`` samples.

    Parameters
    ----------
    schedule : sequence of Step
        Steps in time order; steps shorter than half a sample are dropped.
    dt : float
        Sample period, s.

    Returns
    -------
    numpy.ndarray
        Speed per sample, r/min.
    """
    speeds = []
    for st in schedule:
        k = int(round(st.duration_s / dt))
        if k <= 0:
            continue
        speeds.extend([float(st.speed_rpm)] * k)
    if not speeds:
        raise ValueError("the schedule is empty")
    return np.asarray(speeds)


def constant_schedule(speed_rpm: float, duration_s: float) -> list[Step]:
    """A single constant-speed step."""
    return [Step(float(duration_s), float(speed_rpm))]


def schedule_from_pairs(pairs: Iterable[Step | tuple[float, float]]) -> list[Step]:
    """Build a schedule from ``(duration_s, speed_rpm)`` pairs (steps are kept as they are)."""
    return [p if isinstance(p, Step) else Step(float(p[0]), float(p[1])) for p in pairs]


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


#: Rest (spindle at 0 r/min) logged before the spindle starts in every cold-start log of
#: tapping-center-a (shipped and ``day`` mode): the logger is started with the machine cold
#: and at rest, then the spindle is started. The reference window (first 60 s) falls on it.
REST_BEFORE_START_S = 180.0


def with_rest(schedule: Sequence[Step], rest_s: float = REST_BEFORE_START_S) -> list[Step]:
    """``schedule`` preceded by ``rest_s`` seconds at 0 r/min (cold machine at rest)."""
    steps = list(schedule)
    return ([Step(float(rest_s), 0.0)] if rest_s > 0 else []) + steps


def speed_at(t_s: np.ndarray, changes: Sequence[tuple[float, float]]) -> np.ndarray:
    """Piecewise-constant speed at times ``t_s`` from ``(start_s, speed_rpm)`` change points.

    Parameters
    ----------
    t_s : numpy.ndarray
        Times, s; none before the first change point.
    changes : sequence of (start_s, speed_rpm)
        ``speed_rpm`` holds from ``start_s`` on; start times ascending.

    Returns
    -------
    numpy.ndarray
        Speed at each time, r/min (float).
    """
    times = np.array([a for a, _ in changes], float)
    speeds = np.array([b for _, b in changes], float)
    return speeds[np.searchsorted(times, t_s, side="right") - 1]
