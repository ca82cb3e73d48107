"""The shortest test programme of a re-qualification (the function behind ``rafi plan``).

:func:`plan_programme` turns the machine's training speeds, a budget of machine hours, the
speed range in use and what the prior says of itself (:func:`prior_view`: the speeds it was
trained at, its interval's half widths, its slowest time constant) into a table of steps in the
format of ``rafi record --plan`` (docs/record.md, "The test plan"), each with the ``reason`` it
is there; :func:`plan_csv` writes the CSV that :func:`rafi.deploy.record_plan.read_plan` reads.
The rule is in the docstring of :func:`plan_programme`: a person can predict the plan from it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import pandas as pd

from rafi.deploy.record_plan import PLAN_COLUMNS, RUN_NAME
from rafi.errors import RafiUserError, SettingsError

__all__ = [
    "PLAN_TABLE_COLUMNS",
    "covering_budget_h",
    "heat_ups_s",
    "plan_csv",
    "plan_limits",
    "plan_programme",
    "plan_text",
    "prior_speeds_left",
    "prior_view",
    "spread_order",
]

#: Seconds at rest before the first heat-up (the reference window falls on the cold machine at
#: rest), at most ``runs.max_leading_rest_s`` less :data:`REST_MARGIN_S` (:func:`plan_limits`).
REST_S = 180.0
#: How far below ``runs.max_leading_rest_s`` the rest stays (a logger that starts a sample late,
#: the speed's smoothing): a longer rest would be cut as a run of its own.
REST_MARGIN_S = 60.0
#: A heat-up gets no more than this (the paper's 4 h training run: near the steady state).
MAX_RUN_S = 4 * 3600.0
#: Extra time is given in whole minutes.
QUANTUM_S = 60.0
#: A heat-up and a cool-down of this many of the prior's slowest time constants show a change of
#: that constant (``prior_time``'s factors 0.5-2 differ most over the first two).
TAU_SPAN = 2.0
#: The columns of the table :func:`plan_programme` returns: the record format's, then what a
#: person reads beside them (not written to the CSV).
PLAN_TABLE_COLUMNS = (*PLAN_COLUMNS, "step", "kind", "start_h")


def plan_limits(settings: Mapping) -> dict:
    """``min_run_s``, ``transient_s`` and ``rest_s`` of :func:`plan_programme` from a machine's
    resolved settings.

    A run of the programme lasts at least ``runs.min_run_s`` (a shorter run is excluded) and at
    least ``runs.min_constant_s``: a shorter heat-up is cut as a ``varying`` run, whose automatic
    role is ``validation_multi`` (``docs/raw-format.md``, "Segmentation"), so a recorded
    programme would not train without a hand-written window. ``transient_s`` is
    ``models.interval_transient_s``. ``rest_s``, the rest before the first heat-up, is
    :data:`REST_S` or less: below ``runs.max_leading_rest_s`` by :data:`REST_MARGIN_S` (or two
    samples, if longer), so the pipeline takes it as the first heat-up's rest before start and not
    as a run of its own; whole seconds.

    Raises
    ------
    SettingsError
        ``runs.max_leading_rest_s`` leaves no rest as long as ``reference.window_s`` (the
        reference window would not fall on the machine at rest).
    """
    runs = settings["runs"]
    max_rest = float(runs["max_leading_rest_s"])
    margin = max(REST_MARGIN_S, 2 * float(settings.get("sample_period_s") or 0.0))
    rest = math.floor(min(REST_S, max_rest - margin))
    window = max(float((settings.get("reference") or {}).get("window_s") or 0.0), 1.0)
    if rest < window:
        raise SettingsError(
            f"runs.max_leading_rest_s {max_rest:g} s leaves the plan no rest before the first heat-up as "
            f"long as reference.window_s ({window:g} s) and {margin:g} s under the limit; set "
            f"runs.max_leading_rest_s to at least {window + margin:g}"
        )
    return {
        "min_run_s": max(float(runs["min_run_s"]), float(runs["min_constant_s"])),
        "transient_s": float(settings["models"]["interval_transient_s"]),
        "rest_s": float(rest),
    }


def _selected_taus(artefact: Mapping) -> list[float]:
    """The filter time constants and draw-in lag of an artefact's ``selected`` (s, finite, > 0)."""
    selected = artefact.get("selected") or {}
    taus = [float(t) for t in list(selected.get("taus_s") or []) + list(selected.get("speed_taus_s") or [])]
    if selected.get("centrifugal_lag_s") is not None:
        taus.append(float(selected["centrifugal_lag_s"]))
    return [t for t in taus if math.isfinite(t) and t > 0]


def _trained_speeds(artefact: Mapping) -> list[float]:
    """The speeds of an artefact's per-speed records (RAFI's kinds) and its ``trained_speeds_rpm``
    (an ensemble's own record); none for the other kinds."""
    records = [float(s["speed_rpm"]) for s in artefact.get("speeds") or [] if "speed_rpm" in s]
    return records + [float(v) for v in artefact.get("trained_speeds_rpm") or []]


def _speed_range(artefact: Mapping) -> tuple[float, float] | None:
    """An artefact's ``speed_range_rpm``, else the extremes of its per-speed records, else None."""
    if artefact.get("speed_range_rpm"):
        lo, hi = (float(v) for v in artefact["speed_range_rpm"])
        return lo, hi
    speeds = _trained_speeds(artefact)
    return (min(speeds), max(speeds)) if speeds else None


def prior_view(prior: Mapping | None, *, tolerance_rpm: float = 0.0) -> dict | None:
    """What :func:`plan_programme` reads of a prior's artefact (None: no prior).

    A CV-weighted ensemble (``kind: ensemble``, :mod:`rafi.family.ensemble`) is read whole: its
    trained speeds are its own record and its members' per-speed records, its speed range the union of
    its own and its members' ranges, its interval its own (calibrated on the blend, not a
    member's); its time constants are those of the member the adaptation re-fits, the heaviest
    (:func:`rafi.family.prior.prior_base`: ``prior_time`` scales that member's filters; an
    ensemble has none of its own).

    Parameters
    ----------
    prior : mapping or None
        The prior's artefact (``model.json`` content of any kind of the family).
    tolerance_rpm : float
        ``speed_tolerance_rpm``: a speed this close to a trained one counts as trained.

    Returns
    -------
    dict or None
        ``label`` (``prior <id> (<kind> of <machine>)``), ``trained_speeds_rpm`` (RAFI's
        per-speed records, an ensemble's: its members'; None for the other kinds, which record a
        range only), ``speed_range_rpm`` (``(low, high)`` or None), ``half_width_um`` (the
        interval's ``settled`` / ``transient`` / ``outside`` half widths, empty without an
        interval), ``slowest_tau_s`` (the longest filter time constant or draw-in lag of
        ``selected``; None for kinds without), ``tau_member`` (an ensemble's member that
        ``slowest_tau_s`` is of, else None), ``members`` (an ensemble's member count, else None)
        and ``tolerance_rpm``.

    Raises
    ------
    PriorIncompatible
        An ensemble without its members' artefacts.
    """
    if not prior:
        return None
    from rafi.family.prior import ENSEMBLE_KIND, ensemble_member, prior_base

    parts = [prior]
    member = None
    if prior.get("kind") == ENSEMBLE_KIND:
        member = ensemble_member(prior)  # refused (one line) without the members' artefacts
        parts += [m for m in (prior.get("members") or {}).values() if isinstance(m, dict)]
    speeds = sorted({s for part in parts for s in _trained_speeds(part)})
    ranges = [r for r in (_speed_range(part) for part in parts) if r is not None]
    speed_range = (min(r[0] for r in ranges), max(r[1] for r in ranges)) if ranges else None
    taus = _selected_taus(prior_base(prior))
    half = ((prior.get("interval") or {}).get("half_width_um")) or {}
    who = f"prior {str(prior.get('model_id', ''))[:12]} ({prior.get('kind', '?')}"
    who += f" of {prior.get('machine')})" if prior.get("machine") else ")"
    return {
        "label": who,
        "trained_speeds_rpm": speeds or None,
        "speed_range_rpm": speed_range,
        "half_width_um": {str(k): float(v) for k, v in half.items() if v is not None},
        "slowest_tau_s": max(taus) if taus else None,
        "tau_member": member["name"] if member and taus else None,
        "members": member["n_members"] if member else None,
        "tolerance_rpm": float(tolerance_rpm),
    }


def _untrained(speed: float, view: Mapping | None) -> bool:
    """True when the prior never trained at ``speed``: no trained speed within the tolerance, or,
    for a kind that records a range only, outside that range widened by the tolerance."""
    if not view:
        return False
    tol = float(view.get("tolerance_rpm") or 0.0)
    trained = view.get("trained_speeds_rpm")
    if trained:
        return not any(abs(speed - t) <= tol + 1e-9 for t in trained)
    if view.get("speed_range_rpm"):
        lo, hi = view["speed_range_rpm"]
        return not lo - tol - 1e-9 <= speed <= hi + tol + 1e-9
    return False


def _trained_text(view: Mapping) -> str:
    who = f"its {view['members']} members " if view.get("members") else ""
    trained = view.get("trained_speeds_rpm")
    if trained:
        return who + "trained at " + ", ".join(f"{s:g}" for s in trained) + " r/min"
    lo, hi = view["speed_range_rpm"]
    return who + f"trained over {lo:g}-{hi:g} r/min"


def _interval_text(view: Mapping) -> str:
    """Whose interval a reason quotes: the prior's, an ensemble's own (not a member's)."""
    return "the ensemble's own interval" if view.get("members") else "its interval"


def _tau_text(view: Mapping) -> str:
    """The prior's slowest time constant as a reason names it (an ensemble's: of which member)."""
    tau = f"{float(view['slowest_tau_s']):g} s"
    if view.get("tau_member"):
        tau += f", of its heaviest member {view['tau_member']}: the one the adaptation re-fits"
    return f"the prior's slowest time constant ({tau})"


def spread_order(speeds: Sequence[float], taken: Sequence[float] = ()) -> list[float]:
    """The speeds in the order the plan takes them: highest, lowest, then the widest gaps.

    After the highest and the lowest, the next speed is the one farthest from every speed
    already taken (the middle of the widest gap left); a tie goes to the lower speed. With
    ``taken`` (speeds an earlier group took) every speed is chosen that way from the start.

    Parameters
    ----------
    speeds : sequence of float
        Candidate speeds, r/min (duplicates are taken once).
    taken : sequence of float
        Speeds already in the plan.

    Returns
    -------
    list of float
    """
    left = sorted(set(float(s) for s in speeds))
    if not left:
        return []
    order: list[float] = []
    have = [float(t) for t in taken]
    if not have:
        order.append(left.pop())
        if left:
            order.append(left.pop(0))
    while left:
        best = max(left, key=lambda s: (min(abs(s - t) for t in [*have, *order]), -s))
        order.append(best)
        left.remove(best)
    return order


def _candidates(speeds_rpm, speed_range) -> list[float]:
    speeds = [float(s) for s in speeds_rpm if math.isfinite(float(s)) and float(s) > 0]
    if not speeds:
        raise RafiUserError("plan: no training speed above 0 r/min; expected the machine's training speeds")
    if speed_range is None:
        return sorted(set(speeds))
    lo, hi = (float(v) for v in speed_range)
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo <= hi):
        raise RafiUserError(f"plan: speed range {lo:g}..{hi:g} r/min; expected 0 <= low <= high")
    inside = sorted({s for s in speeds if lo <= s <= hi})
    if not inside:
        raise RafiUserError(
            f"plan: none of the training speeds ({', '.join(f'{s:g}' for s in sorted(set(speeds)))}"
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


def _view_uncertainty(speeds: list[float], view: Mapping | None) -> dict | None:
    """``speed -> half width (um)`` of the prior's interval cell at each speed: ``outside`` where
    it never trained, ``settled`` where it did (None: no prior, or no interval)."""
    half = (view or {}).get("half_width_um") or {}
    if "outside" not in half or "settled" not in half:
        return None
    return {s: half["outside"] if _untrained(s, view) else half["settled"] for s in speeds}


def _heat_reason(i: int, speed: float, speeds: list[float], view: Mapping | None) -> str:
    """Why heat-up ``i`` (0-based) runs at ``speed``."""
    if view and _untrained(speed, view):
        half = (view.get("half_width_um") or {}).get("outside")
        cell = f"; {_interval_text(view)} there is the outside cell"
        width = f"{cell}, +/-{half:.3g} um" if half is not None else ""
        return f"a speed the prior never trained at ({_trained_text(view)}){width}"
    where = (
        "the highest speed: the largest heat input, the best-conditioned single run"
        + (" for a gain on the prior" if view else "")
        if speed == max(speeds)
        else "the lowest speed: with the highest, the range in use is spanned"
        if speed == min(speeds)
        else "the middle of the widest gap left between the speeds taken"
    )
    if view and (view.get("trained_speeds_rpm") or view.get("speed_range_rpm")):
        half = (view.get("half_width_um") or {}).get("settled")
        width = f", {_interval_text(view).removeprefix('its ')} +/-{half:.3g} um" if half is not None else ""
        return f"{where} (trained by the prior{width})"
    return where


def _extras(left, k, n_cool, run_s, speeds, *, uncertainty, view) -> tuple[list[float], list[float]]:
    """The time each heat-up and cool-down gets beyond ``run_s`` (:func:`plan_programme`, step 3)."""
    heat_extra, cool_extra = [0.0] * k, [0.0] * n_cool
    tau = (view or {}).get("slowest_tau_s")
    if tau:  # the prior's slowest time constant: a heat-up and a cool-down long enough to see it
        want = math.floor((min(TAU_SPAN * float(tau), MAX_RUN_S) - run_s) / QUANTUM_S + 1e-9) * QUANTUM_S
        for extra in (heat_extra, cool_extra):
            if extra:
                extra[0] = max(0.0, min(want, math.floor(left / QUANTUM_S + 1e-9) * QUANTUM_S))
                left -= extra[0]
    weights = _weights(speeds, uncertainty if uncertainty is not None else _view_uncertainty(speeds, view))
    shared = _share(left, weights, [MAX_RUN_S - run_s - e for e in heat_extra])
    heat_extra = [a + b for a, b in zip(heat_extra, shared)]
    left -= sum(shared)
    shared = _share(left, [1.0] * n_cool, [MAX_RUN_S - run_s - e for e in cool_extra])
    return heat_extra, [a + b for a, b in zip(cool_extra, shared)]


def _rows(speeds, heat_extra, cool_extra, run_s, rest_s, view) -> list[tuple]:
    """``(speed_rpm, duration_s, note, reason, kind)`` of every step."""
    k, n_cool, tau = len(speeds), len(cool_extra), (view or {}).get("slowest_tau_s")
    rows = [
        (
            0.0,
            rest_s,
            "rest before start (cold machine at rest: the reference)",
            f"the reference: the cold machine at rest, {rest_s:g} s (the first heat-up's rest before start)",
            "rest",
        )
    ]
    for i, speed in enumerate(speeds):
        heat = run_s + heat_extra[i]
        reason = _heat_reason(i, speed, speeds, view)
        if tau and i == 0 and heat_extra[0] > 0:
            reason += f"; long enough to see {_tau_text(view)} change"
        rows.append(
            (speed, heat, f"heat-up {i + 1} of {k}: {speed:g} r/min, {heat / 60:g} min", reason, "heat-up")
        )
        if i < n_cool:
            cool = run_s + cool_extra[i]
            why = "spindle stopped: the machine cooling, a run of its own between the heat-ups (a CV fold)"
            if i == k - 1:
                why = "spindle stopped: the final cool-down (a CV fold)"
            if tau and i == 0 and cool_extra[0] > 0:
                why += f"; long enough to see {_tau_text(view)} as it cools"
            rows.append(
                (0.0, cool, f"cool-down {i + 1}: spindle stopped, {cool / 60:g} min", why, "cool-down")
            )
    return rows


def plan_programme(
    *,
    speeds_rpm: Sequence[float],
    budget_h: float,
    speed_range: tuple[float, float] | None = None,
    min_run_s: float = 1800.0,
    transient_s: float = 1800.0,
    rest_s: float = REST_S,
    uncertainty: Mapping[float, float] | None = None,
    prior: Mapping | None = None,
    name: str = "requal",
) -> pd.DataFrame:
    """The test programme of a re-qualification that fits in ``budget_h`` hours of machine time.

    ONE recording (``run`` = ``name`` on every step): the pipeline cuts it into runs and the
    family's filters carry the machine's state from one run to the next (docs/models.md,
    "Whole-log dynamics"). Every run lasts ``run_s = max(min_run_s, transient_s)`` or more
    (shorter runs are excluded; the first ``transient_s`` of a run is where a prior is least
    sure). ``prior`` is :func:`prior_view` of the prior; without one, steps 1 and 3 reduce to
    spreading the speeds and sharing the time equally. The rule:

    1. **Speeds**: the training speeds ``speeds_rpm`` inside ``speed_range`` (none: all). First
       those the prior **never trained at** (no trained speed within ``tolerance_rpm``; for a
       kind that records only a range, outside it; a CV-weighted ensemble's trained speeds are
       its members', :func:`prior_view`), in the order of :func:`spread_order`
       (highest, lowest, then the middle of the widest gap left), then the trained ones,
       farthest from those taken first. The highest comes first among equals: its heat-up moves
       the spindle most (the best-conditioned run for a gain); the lowest second spans the range.
    2. **How many**: ``k`` heat-ups, the most (one per speed at most) with
       ``rest_s + k run_s + (k - 1) run_s <= budget``: ``rest_s`` at rest first (the reference;
       :func:`plan_limits` keeps it under ``runs.max_leading_rest_s``), then the heat-ups, each
       but the last followed by a cool-down (0 r/min) of ``run_s``; a final cool-down when
       ``run_s`` is left over and ``k >= 2``. Heat-ups and cool-downs are the whole-run CV's folds.
    3. **How long**: with a prior whose slowest time constant is ``tau`` (``slowest_tau_s``), the
       time left goes first to the first heat-up, then to the cool-down after it, each up to
       ``TAU_SPAN`` (2) ``tau`` (whole minutes, not beyond): long enough to see a repair move the
       time constants. The rest
       goes to the heat-ups in proportion to ``uncertainty`` (speed -> how unsure; none: the
       prior's interval half width, ``outside`` at an untrained speed, ``settled`` at a trained
       one; a speed not named counts as the worst named; no interval: equal shares), none beyond
       ``MAX_RUN_S`` (4 h), in whole minutes; what they cannot take goes to the cool-downs in
       equal shares, whole minutes, up to 4 h each; the rest is not used.
    4. **Order**: the heat-ups run in the order of step 1 (large speed jumps; a programme stopped
       early holds where the prior is least sure and the most spread speeds).

    Every step carries its ``reason`` (the rule that put it there, in words).

    Parameters
    ----------
    speeds_rpm : sequence of float
        The machine's training speeds, r/min.
    budget_h : float
        Machine time available, h (the plan's total, rest and cool-downs included).
    speed_range : (float, float), optional
        The range of speeds in use, r/min (inclusive).
    min_run_s : float
        ``runs.min_run_s``: a shorter run is excluded by the pipeline.
    transient_s : float
        ``models.interval_transient_s``: the transient cell of the intervals.
    rest_s : float
        The rest before the first heat-up, s (:func:`plan_limits`).
    uncertainty : mapping, optional
        Speed (r/min) -> how unsure the prior is there (any positive scale); overrides the
        prior's interval.
    prior : mapping, optional
        :func:`prior_view` of the prior (None: no prior).
    name : str
        The recording's name (starts its file name).

    Returns
    -------
    pandas.DataFrame
        One row per step, columns :data:`PLAN_TABLE_COLUMNS`: ``speed_rpm``, ``duration_s``,
        ``run`` (``name``), ``note``, ``reason``, then ``step`` (1, 2, ...), ``kind`` (``rest``,
        ``heat-up``, ``cool-down``), ``start_h``. ``attrs``: ``budget_h``, ``total_h``,
        ``speeds_rpm`` (taken, in order), ``untrained_rpm`` (those the prior never trained at).

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
    rest_s = float(rest_s)
    run_s = max(float(min_run_s), float(transient_s))
    candidates = _candidates(speeds_rpm, speed_range)
    untrained = [s for s in candidates if _untrained(s, prior)]
    first = spread_order(untrained)
    order = first + spread_order([s for s in candidates if s not in untrained], taken=first)
    k = 0
    while k < len(order) and heat_ups_s(k + 1, run_s=run_s, rest_s=rest_s) <= budget_s + 1e-9:
        k += 1
    if k == 0:
        raise RafiUserError(
            f"plan: a budget of {float(budget_h):g} h is shorter than the rest and one heat-up "
            f"({rest_s:g} s + {run_s:g} s); give at least {(rest_s + run_s) / 3600:.2f} h"
        )
    speeds = order[:k]
    n_cool = k - 1
    left = budget_s - rest_s - k * run_s - n_cool * run_s
    if k > 1 and left >= run_s - 1e-9:
        n_cool, left = k, left - run_s
    heat_extra, cool_extra = _extras(left, k, n_cool, run_s, speeds, uncertainty=uncertainty, view=prior)
    rows = _rows(speeds, heat_extra, cool_extra, run_s, rest_s, prior)
    plan = pd.DataFrame(rows, columns=["speed_rpm", "duration_s", "note", "reason", "kind"])
    plan.insert(2, "run", str(name))
    plan.insert(5, "step", range(1, len(plan) + 1))
    plan["start_h"] = (plan["duration_s"].cumsum() - plan["duration_s"]) / 3600.0
    plan = plan[list(PLAN_TABLE_COLUMNS)]
    plan.attrs.update(
        budget_h=float(budget_h),
        total_h=float(plan["duration_s"].sum()) / 3600.0,
        speeds_rpm=speeds,
        untrained_rpm=[s for s in speeds if s in untrained],
        run_s=run_s,
        rest_s=rest_s,
    )
    return plan


def heat_ups_s(k: int, *, run_s: float, rest_s: float) -> float:
    """Seconds a programme of ``k`` heat-ups needs (step 2 of :func:`plan_programme`): the rest,
    the heat-ups and a cool-down between each two, every run ``run_s`` long."""
    return rest_s + k * run_s + (k - 1) * run_s


def prior_speeds_left(plan: pd.DataFrame, prior: Mapping | None, *, tolerance_rpm: float) -> list[float]:
    """The speeds (r/min) the prior was trained at that ``plan`` does not test: there the
    re-qualified model is the prior's alone, and the night's fitness warning ``prior_speeds``
    blocks its promotion until confirmed (:func:`rafi.family.prior_fitness.prior_only_speeds`, the
    same rule on the prior's artefact ``prior``, read whole). Empty without a prior."""
    from rafi.family.prior_fitness import prior_only_speeds

    if not prior:
        return []
    return prior_only_speeds(prior, plan["speed_rpm"].astype(float).tolist(), tolerance_rpm=tolerance_rpm)


def covering_budget_h(
    artefact: Mapping | None, *, tolerance_rpm: float, max_h: float = 48.0, **programme
) -> float | None:
    """The smallest budget (h, rounded up to 0.01 h) whose :func:`plan_programme` (``programme``:
    its keyword arguments but ``budget_h``, ``prior`` the view of ``artefact``) leaves no speed of
    the prior's artefact ``artefact`` untested (:func:`prior_speeds_left`), or None when no
    programme of at most ``max_h`` does (the prior's speeds are not among the machine's training
    speeds in the range, or need more time). Only the budgets of whole programmes are tried
    (:func:`heat_ups_s` for ``k`` = 1, 2, ...: between them the plan does not take another speed)."""
    longest = plan_programme(budget_h=max_h, **programme)
    if prior_speeds_left(longest, artefact, tolerance_rpm=tolerance_rpm):
        return None
    timing = {"run_s": longest.attrs["run_s"], "rest_s": longest.attrs["rest_s"]}
    for k in range(1, len(longest.attrs["speeds_rpm"]) + 1):
        budget_h = math.ceil(heat_ups_s(k, **timing) / 36.0) / 100.0
        plan = plan_programme(budget_h=budget_h, **programme)
        if not prior_speeds_left(plan, artefact, tolerance_rpm=tolerance_rpm):
            return budget_h
    return None


def plan_text(plan: pd.DataFrame) -> str:
    """The programme as the command prints it: one line per step, its reason at the end."""
    lines = [f"{'step':>4}  {'start':>7}  {'kind':<9}  {'r/min':>6}  {'min':>5}  reason"]
    for row in plan.itertuples(index=False):
        lines.append(
            f"{row.step:>4}  {row.start_h:>5.2f} h  {row.kind:<9}  {row.speed_rpm:>6g}  "
            f"{row.duration_s / 60:>5g}  {row.reason}"
        )
    return "\n".join(lines)


def plan_csv(plan: pd.DataFrame) -> str:
    """The CSV text of a plan in the format of ``rafi record --plan`` (its columns only).

    Parameters
    ----------
    plan : pandas.DataFrame
        The output of :func:`plan_programme`.

    Returns
    -------
    str
        A ``#`` comment line (budget, total, speeds), the header
        ``speed_rpm,duration_s,run,note,reason`` and one line per step.
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
