"""The shortest test programme of a re-qualification (the function behind ``rafi plan``).

:func:`plan_programme` turns the speeds a prior was trained at, a budget of machine hours, the
speed range in use and (optionally) where the prior is least sure into a table of steps in the
format of ``rafi record --plan`` (docs/record.md, "The test plan"); :func:`plan_csv` writes the
CSV that :func:`rafi.deploy.record_plan.read_plan` reads. The rule is in the docstring of
:func:`plan_programme`: a person can predict the plan from it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import pandas as pd

from rafi.deploy.record_plan import PLAN_COLUMNS, RUN_NAME
from rafi.errors import RafiUserError

__all__ = ["PLAN_TABLE_COLUMNS", "plan_csv", "plan_limits", "plan_programme", "spread_order"]

#: Seconds at rest before the first heat-up (the reference window falls on the cold machine at rest).
REST_S = 180.0
#: A heat-up gets no more than this (the paper's 4 h training run: near the steady state).
MAX_RUN_S = 4 * 3600.0
#: Extra time is given in whole minutes.
QUANTUM_S = 60.0
#: The columns of the table :func:`plan_programme` returns: the record format's, then what a
#: person reads beside them (not written to the CSV).
PLAN_TABLE_COLUMNS = (*PLAN_COLUMNS, "step", "kind", "start_h")


def plan_limits(settings: Mapping) -> dict:
    """``min_run_s`` and ``transient_s`` of :func:`plan_programme` from a machine's settings.

    A run of the programme lasts at least ``runs.min_run_s`` (a shorter run is excluded) and at
    least ``runs.min_constant_s``: a shorter heat-up is cut as a ``varying`` run, whose automatic
    role is ``validation_multi`` (``docs/raw-format.md``, "Segmentation"), so a recorded
    programme would not train without a hand-written window. ``transient_s`` is
    ``models.interval_transient_s``.
    """
    runs = settings["runs"]
    return {
        "min_run_s": max(float(runs["min_run_s"]), float(runs["min_constant_s"])),
        "transient_s": float(settings["models"]["interval_transient_s"]),
    }


def spread_order(speeds: Sequence[float]) -> list[float]:
    """The speeds in the order the plan takes them: highest, lowest, then the widest gaps.

    After the highest and the lowest, the next speed is the one farthest from every speed
    already taken (the middle of the widest gap left); a tie goes to the lower speed.

    Parameters
    ----------
    speeds : sequence of float
        Candidate speeds, r/min (duplicates are taken once).

    Returns
    -------
    list of float
    """
    left = sorted(set(float(s) for s in speeds))
    if not left:
        return []
    order = [left.pop()]
    if left:
        order.append(left.pop(0))
    while left:
        best = max(left, key=lambda s: (min(abs(s - t) for t in order), -s))
        order.append(best)
        left.remove(best)
    return order


def _candidates(speeds_rpm, speed_range) -> list[float]:
    speeds = [float(s) for s in speeds_rpm if math.isfinite(float(s)) and float(s) > 0]
    if not speeds:
        raise RafiUserError("plan: no training speed above 0 r/min; expected the prior's training speeds")
    if speed_range is None:
        return sorted(set(speeds))
    lo, hi = (float(v) for v in speed_range)
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo <= hi):
        raise RafiUserError(f"plan: speed range {lo:g}..{hi:g} r/min; expected 0 <= low <= high")
    inside = sorted({s for s in speeds if lo <= s <= hi})
    if not inside:
        raise RafiUserError(
            f"plan: none of the prior's training speeds ({', '.join(f'{s:g}' for s in sorted(set(speeds)))}"
            f" r/min) lies in the speed range {lo:g}..{hi:g} r/min; widen the range"
        )
    return inside


def _share(extra_s: float, weights: list[float], room: list[float]) -> list[float]:
    """``extra_s`` shared in proportion to ``weights``, none beyond its ``room`` (water filling)."""
    out = [0.0] * len(weights)
    active = [i for i in range(len(weights)) if room[i] > 0]
    left = extra_s
    while active and left > 1e-9:
        total = sum(weights[i] for i in active)
        shares = {i: left * (weights[i] / total if total > 0 else 1 / len(active)) for i in active}
        full = [i for i in active if out[i] + shares[i] >= room[i]]
        if not full:
            for i in active:
                out[i] += shares[i]
            break
        for i in full:
            left -= room[i] - out[i]
            out[i] = room[i]
        active = [i for i in active if i not in full]
    return [math.floor(v / QUANTUM_S + 1e-9) * QUANTUM_S for v in out]


def _weights(speeds: list[float], uncertainty: Mapping | None) -> list[float]:
    """How sure the prior is not, per speed (1 each without ``uncertainty``)."""
    if not uncertainty:
        return [1.0] * len(speeds)
    given = {float(k): max(float(v), 0.0) for k, v in uncertainty.items() if math.isfinite(float(v))}
    worst = max(given.values(), default=1.0)
    return [given.get(s, worst) for s in speeds]


def plan_programme(
    *,
    speeds_rpm: Sequence[float],
    budget_h: float,
    speed_range: tuple[float, float] | None = None,
    min_run_s: float = 1800.0,
    transient_s: float = 1800.0,
    uncertainty: Mapping[float, float] | None = None,
    name: str = "requal",
) -> pd.DataFrame:
    """The test programme of a re-qualification that fits in ``budget_h`` hours of machine time.

    The programme is ONE recording (``run`` = ``name`` on every step): the pipeline cuts it
    into runs (heat-ups and cool-downs) and, because they are one log, the family's filters
    carry the machine's state from one run to the next (docs/models.md, "Whole-log dynamics"):
    a heat-up that starts warm after a short cool-down is modelled as such. The rule, step by
    step (every run lasts ``run_s = max(min_run_s, transient_s)`` or more: shorter runs are
    excluded by the pipeline, and the first ``transient_s`` of a run, the interval's transient
    cell, is where a prior is least sure):

    1. **Speeds**: the prior's training speeds ``speeds_rpm`` inside ``speed_range`` (the range
       in use; none: all), taken in the order of :func:`spread_order`: highest, lowest, then
       the middle of the widest gap left. The highest comes first because its heat-up moves
       the spindle most (the best-conditioned single run for a gain on the prior), the lowest
       second so two speeds already span the range.
    2. **How many**: ``k`` heat-ups, the most (at most one per speed) with
       ``REST_S + k run_s + (k - 1) run_s <= budget``: ``REST_S`` (180 s) at rest first (the
       reference window falls on the cold machine at rest), then the heat-ups, each but the
       last followed by a cool-down (speed 0) of ``run_s``. A final cool-down is added when
       ``run_s`` is left over and ``k >= 2`` (with one heat-up, a fold that holds it out would
       have no run at a speed to learn from). Heat-ups and cool-downs are the whole-run CV's
       folds (``k = 2`` already gives 3 runs); with ``runs.idle_training: true`` (or a training
       window over the recording) the cool-downs train.
    3. **How long**: the time left over goes to the heat-ups in proportion to ``uncertainty``
       (speed -> the prior's interval half width or CV error there; a speed it does not name
       counts as the worst it names; none: equal shares), no heat-up beyond ``MAX_RUN_S`` (4 h);
       extra time is given in whole minutes. What the heat-ups cannot take (beyond their 4 h,
       and what rounding down to minutes leaves) goes to the cool-downs in equal shares, whole
       minutes, up to 4 h each; the rest (under a minute per run, or beyond 4 h) is not used.
    4. **Order**: the heat-ups run in the order of step 1, so the speed jumps are large (the
       dynamics are excited) and a programme stopped early still holds the most spread speeds.

    Parameters
    ----------
    speeds_rpm : sequence of float
        The prior's training speeds, r/min.
    budget_h : float
        Machine time available, h (the plan's total, rest and cool-downs included).
    speed_range : (float, float), optional
        The range of speeds in use, r/min (inclusive).
    min_run_s : float
        ``runs.min_run_s``: a shorter run is excluded by the pipeline.
    transient_s : float
        ``models.interval_transient_s``: the transient cell of the intervals.
    uncertainty : mapping, optional
        Speed (r/min) -> how unsure the prior is there (any positive scale).
    name : str
        The recording's name (starts its file name).

    Returns
    -------
    pandas.DataFrame
        One row per step, columns :data:`PLAN_TABLE_COLUMNS`: ``speed_rpm``, ``duration_s``,
        ``run`` (``name``), ``note``, then ``step`` (1, 2, ...), ``kind`` (``rest``,
        ``heat-up``, ``cool-down``) and ``start_h`` (from the plan's start). ``attrs`` holds
        ``budget_h``, ``total_h`` and ``speeds_rpm`` (the speeds taken, in order).
        :func:`plan_csv` writes the record format's columns.

    Raises
    ------
    RafiUserError
        (exit status 64) No training speed in the range, a bad range or name, or a budget
        shorter than the rest and one heat-up.
    """
    if not RUN_NAME.match(str(name)):
        raise RafiUserError(
            f"plan: the name {name!r} cannot start a file name; use letters, digits, '.', '_', '-'"
        )
    budget_s = float(budget_h) * 3600.0
    run_s = max(float(min_run_s), float(transient_s))
    order = spread_order(_candidates(speeds_rpm, speed_range))
    k = 0
    while k < len(order) and REST_S + (k + 1) * run_s + k * run_s <= budget_s + 1e-9:
        k += 1
    if k == 0:
        raise RafiUserError(
            f"plan: a budget of {float(budget_h):g} h is shorter than the rest and one heat-up "
            f"({REST_S:g} s + {run_s:g} s); give at least {(REST_S + run_s) / 3600:.2f} h"
        )
    speeds = order[:k]
    n_cool = k - 1
    left = budget_s - REST_S - k * run_s - n_cool * run_s
    if k > 1 and left >= run_s - 1e-9:
        n_cool, left = k, left - run_s
    heat_extra = _share(left, _weights(speeds, uncertainty), [MAX_RUN_S - run_s] * k)
    left -= sum(heat_extra)
    cool_extra = _share(left, [1.0] * n_cool, [MAX_RUN_S - run_s] * n_cool)
    rows = [(0.0, REST_S, "rest before start (cold machine at rest: the reference)", "rest")]
    for i, speed in enumerate(speeds):
        heat = run_s + heat_extra[i]
        rows.append((speed, heat, f"heat-up {i + 1} of {k}: {speed:g} r/min, {heat / 60:g} min", "heat-up"))
        if i < n_cool:
            cool = run_s + cool_extra[i]
            rows.append((0.0, cool, f"cool-down {i + 1}: spindle stopped, {cool / 60:g} min", "cool-down"))
    plan = pd.DataFrame(rows, columns=["speed_rpm", "duration_s", "note", "kind"])
    plan.insert(2, "run", str(name))
    plan.insert(4, "step", range(1, len(plan) + 1))
    plan["start_h"] = (plan["duration_s"].cumsum() - plan["duration_s"]) / 3600.0
    plan = plan[list(PLAN_TABLE_COLUMNS)]
    plan.attrs.update(
        budget_h=float(budget_h), total_h=float(plan["duration_s"].sum()) / 3600.0, speeds_rpm=speeds
    )
    return plan


def plan_csv(plan: pd.DataFrame) -> str:
    """The CSV text of a plan in the format of ``rafi record --plan`` (its four columns only).

    Parameters
    ----------
    plan : pandas.DataFrame
        The output of :func:`plan_programme`.

    Returns
    -------
    str
        A ``#`` comment line (budget, total, speeds), the header ``speed_rpm,duration_s,run,note``
        and one line per step.
    """
    speeds = ", ".join(f"{s:g}" for s in plan.attrs.get("speeds_rpm", []))
    head = (
        f"# rafi plan: {plan.attrs.get('total_h', plan['duration_s'].sum() / 3600):.2f} h of "
        f"{plan.attrs.get('budget_h', float('nan')):g} h budget; heat-ups at {speeds} r/min\n"
    )
    body = plan[list(PLAN_COLUMNS)].assign(
        speed_rpm=plan["speed_rpm"].map(lambda v: f"{v:g}"),
        duration_s=plan["duration_s"].map(lambda v: f"{v:g}"),
    )
    return head + body.to_csv(index=False, lineterminator="\n")
