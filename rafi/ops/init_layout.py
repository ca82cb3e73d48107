"""The shape of unknown logs for ``rafi init``: sample period, speed steps, one log or many runs.

Pure functions on arrays (the time and speed columns :mod:`rafi.readers.infer` found):
:func:`elapsed_seconds` (a time column as seconds since the first row), :func:`sample_period`
(the median step and how regular the steps are), :func:`speed_steps` (the pipeline's own
cutting, :func:`rafi.method.runs.segment_runs`, with short pieces kept as steps),
:func:`log_kind` (one continuous log with cool-downs, or separate runs each starting cold) and
the proposals that follow from them: :func:`propose_training` (training speeds and, for a
continuous log, a chronological split) and :func:`propose_min_constant` (``runs.min_constant_s``
when short steps would otherwise become constant runs of their own).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import pandas as pd

from rafi.method.runs import segment_runs
from rafi.settings import MACHINE_DEFAULTS

#: A step is "main" (a candidate training or validation run) when it lasts at least this share
#: of the longest step of the logs.
MAIN_STEP_SHARE = 0.6

#: An idle stretch inside a log at least this long is a cool-down (s).
COOLDOWN_MIN_S = 1800.0

#: Steps shorter than this are kept as part of a varying stretch when listing steps (s).
STEP_MIN_S = 300.0

#: ``runs.min_constant_s`` proposals are rounded to this (s).
ROUND_S = 900.0


@dataclass(frozen=True)
class SpeedStep:
    """One stretch of a log: ``kind`` idle / constant / varying, its level (median r/min; the
    range for a varying stretch), the ``t_s`` of its first sample, its ``end_s`` (first sample
    after it, or one period after its last) and its duration (s)."""

    kind: str
    level_rpm: float
    low_rpm: float
    high_rpm: float
    start_s: float
    end_s: float

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


@dataclass(frozen=True)
class LogShape:
    """What one log looks like: name, rows, period (None without a clock), steps."""

    name: str
    rows: int
    period_s: float | None
    regular_share: float
    steps: tuple

    @property
    def duration_s(self) -> float:
        return self.steps[-1].end_s - self.steps[0].start_s if self.steps else 0.0

    @property
    def starts_cold(self) -> bool:
        """The log starts at rest (an idle first step), or with its only run."""
        return bool(self.steps) and (self.steps[0].kind == "idle" or len(self.main_steps()) <= 1)

    def main_steps(self, longest: float | None = None) -> list[SpeedStep]:
        """The constant steps lasting at least :data:`MAIN_STEP_SHARE` of ``longest`` (default:
        of this log's longest constant step)."""
        const = [s for s in self.steps if s.kind == "constant"]
        if not const:
            return []
        top = longest if longest is not None else max(s.duration_s for s in const)
        return [s for s in const if s.duration_s >= MAIN_STEP_SHARE * top - 1e-9]

    def cooldowns(self) -> list[SpeedStep]:
        """Idle stretches of at least :data:`COOLDOWN_MIN_S` between two non-idle steps."""
        inner = self.steps[1:-1]
        return [s for s in inner if s.kind == "idle" and s.duration_s >= COOLDOWN_MIN_S]


def elapsed_seconds(values: np.ndarray) -> np.ndarray:
    """Seconds since the first row of a time column (timestamps or elapsed seconds)."""
    if np.issubdtype(np.asarray(values).dtype, np.datetime64):
        t = pd.to_datetime(values)
        return np.asarray((t - t[0]) / pd.Timedelta(seconds=1), dtype=float)
    v = np.asarray(values, dtype=float)
    return v - v[np.isfinite(v)][0]


def sample_period(t_s: np.ndarray) -> tuple[float | None, float]:
    """``(median time step, share of steps within 1 % of it)``; ``(None, 0)`` with under two rows."""
    d = np.diff(t_s[np.isfinite(t_s)])
    d = d[d > 0]
    if len(d) == 0:
        return None, 0.0
    step = float(np.median(d))
    return step, float(np.mean(np.abs(d - step) <= 0.01 * step + 1e-9))


def speed_steps(
    t_s: np.ndarray,
    speed: np.ndarray,
    period_s: float,
    *,
    tol: float = MACHINE_DEFAULTS["speed_tolerance_rpm"],
    idle_below: float = MACHINE_DEFAULTS["runs"]["idle_below_rpm"],
) -> list[SpeedStep]:
    """The steps of one log, cut as the pipeline cuts runs with ``min_constant_s`` =
    :data:`STEP_MIN_S` (so every step of 5 min or more is its own ``constant`` step).

    Parameters
    ----------
    t_s : numpy.ndarray
        Seconds since the first row (increasing).
    speed : numpy.ndarray
        r/min per row.
    period_s : float
        The sample period.
    tol, idle_below : float
        ``speed_tolerance_rpm`` and ``runs.idle_below_rpm``.

    Returns
    -------
    list of SpeedStep
        In time order.
    """
    out = []
    for a, b, kind, _ in segment_runs(
        speed, period_s, tol=tol, idle_below=idle_below, min_constant_s=STEP_MIN_S
    ):
        v = speed[a:b]
        v = v[np.isfinite(v)]
        level = float(np.median(v)) if len(v) else 0.0
        end = t_s[b] if b < len(t_s) else t_s[b - 1] + period_s
        low, high = (float(v.min()), float(v.max())) if len(v) else (0.0, 0.0)
        out.append(SpeedStep(kind, level, low, high, float(t_s[a]), float(end)))
    return out


def log_kind(shapes: list[LogShape]) -> tuple[str, str]:
    """``('continuous', why)`` when a log holds several main steps with cool-downs between them,
    else ``('runs', why)`` (separate runs, each file starting cold)."""
    for s in shapes:
        main, cool = s.main_steps(), s.cooldowns()
        if len(main) >= 2 and cool:
            return "continuous", (
                f"{s.name}: {len(main)} long speed steps with {len(cool)} idle cool-down(s) between them "
                f"in {s.duration_s / 3600:.1f} h"
            )
    cold = sum(s.starts_cold for s in shapes)
    return "runs", f"{len(shapes)} file(s), {cold} starting at rest or holding one run"


def _level(x: float) -> float:
    """A speed level rounded as a set point (to 10 r/min; 50 above 10 000)."""
    q = 50.0 if x >= 10_000 else 10.0
    return float(round(x / q) * q)


def propose_training(shapes: list[LogShape], kind: str) -> dict:
    """Training speeds to propose, and for a continuous log a chronological split.

    A continuous log: its main steps in time order train until the first one whose speed lies
    between the speeds before it (an in-between speed: validation from there on); the split
    falls at the end of the last training step. Separate runs: the speeds of files whose
    name says ``train``, when some do; else every main speed (the user must choose).

    Returns
    -------
    dict
        ``speeds`` (sorted r/min), ``why``, and for a continuous log ``split_s`` (seconds from
        the log's start) and ``log`` (its name).
    """
    if kind == "continuous":
        log = max(shapes, key=lambda s: len(s.main_steps()))
        train: list[SpeedStep] = []
        for step in log.main_steps():
            levels = [s.level_rpm for s in train]
            if len(levels) >= 2 and min(levels) < step.level_rpm < max(levels):
                break
            train.append(step)
        speeds = sorted({_level(s.level_rpm) for s in train})
        rest = [_level(s.level_rpm) for s in log.main_steps()[len(train) :]]
        why = f"the long steps before the first in-between speed ({', '.join(f'{x:g}' for x in rest)})"
        return {"speeds": speeds, "why": why, "split_s": train[-1].end_s, "log": log.name}
    named = [s for s in shapes if re.search(r"train", s.name, re.I)]
    pool = named or shapes
    longest = max((st.duration_s for s in pool for st in s.steps if st.kind == "constant"), default=0.0)
    speeds = sorted({_level(st.level_rpm) for s in pool for st in s.main_steps(longest)})
    why = (
        f"the speeds of the {len(named)} file(s) named 'train'"
        if named
        else "every long constant speed: decide which train and which validate"
    )
    return {"speeds": speeds, "why": why}


def propose_min_constant(shapes: list[LogShape], default_s: float | None = None) -> tuple[float, str] | None:
    """``runs.min_constant_s`` to propose when steps shorter than the main steps would still be
    constant runs of their own (at least ``default_s``, the default 3600 s): halfway between the
    longest such step and the shortest main step, rounded to :data:`ROUND_S`; then those steps
    form one varying run. None when there is no such step."""
    default_s = MACHINE_DEFAULTS["runs"]["min_constant_s"] if default_s is None else default_s
    const = [st for s in shapes for st in s.steps if st.kind == "constant"]
    if not const:
        return None
    longest = max(st.duration_s for st in const)
    main = [st for st in const if st.duration_s >= MAIN_STEP_SHARE * longest - 1e-9]
    short = [st for st in const if st.duration_s < MAIN_STEP_SHARE * longest - 1e-9]
    short = [st for st in short if st.duration_s >= default_s - 1e-9]
    if not short:
        return None
    hi, lo = max(st.duration_s for st in short), min(st.duration_s for st in main)
    value = float(np.ceil((hi + lo) / 2 / ROUND_S) * ROUND_S)
    value = min(max(value, hi + ROUND_S), lo) if lo > hi + ROUND_S else (hi + lo) / 2
    why = (
        f"the {len(short)} step(s) of {min(st.duration_s for st in short) / 3600:.1f}-{hi / 3600:.1f} h form "
        f"one varying run; the steps of {lo / 3600:.1f} h and more stay constant runs"
    )
    return value, why
