"""The prior's fitness: how far a re-qualification moved its prior, and where this machine's new
data stand against what the prior alone covers (``docs/models.md``, "Re-qualification from a
prior", "The prior's fitness").

:func:`fitness_block` is pure: the prior's artefact, its own qualification
(:func:`rafi.family.prior.prior_qualification`), where it comes from
(:func:`rafi.family.prior.prior_origin`), what the adaptation chose and the new training data's
speeds and temperature rises in, the ``fitness`` block of the adapted artefact's ``adaptation``
out (covered by the ``model_id``; the same inputs give the same bytes). Its ``warnings`` block
promotion until confirmed in ``checks.confirmed`` (:func:`fitness_warnings`, read by rule
``decide``):

* ``prior_adaptation``: the adaptation moved the prior beyond :data:`BOUNDS` (a gain, a time
  factor at an edge of its grid, or a prediction moved by more than half its size);
* ``prior_speeds``: a speed the prior was trained at that no new training run covers (within the
  machine's ``speed_tolerance_rpm``): there the model is the prior's alone, untested here. When the
  prior is itself a re-qualification that left some of those speeds to its own prior
  (:func:`inherited_speeds`), the warning says so: nothing since that older prior tested them.

Two more are found beside the fit, by the family's CV (:func:`rafi.family.compare.run_family`):
``prior_dynamics`` (:func:`dynamics_warning`) and ``prior_misfit`` (:func:`misfit_warning`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping

import numpy as np

__all__ = [
    "BOUNDS",
    "CHECKS",
    "fitness_block",
    "fitness_warnings",
    "dynamics_warning",
    "misfit_warning",
    "MISFIT_HALF_WIDTHS",
    "prior_half_width",
    "warning_remedy",
    "prior_speed_range",
    "prior_speeds_known",
    "prior_only_speeds",
    "inherited_speeds",
    "inherited_text",
    "prior_trained_speeds",
    "prior_rise_ranges",
]

#: The bounds of an adaptation that needs no confirmation (``docs/models.md``, "The prior's
#: fitness"). ``gain``: one gain between 2/3 and 3/2 (symmetric in ratio; a sibling's build spread
#: and a repair moved the twin's gains by 1.2-1.35, the foreign prior of issue 47 needed 1.76);
#: ``time_factor``: inside the grid of ``prior_time`` (0.5 and 2 are its edges: the true factor may
#: lie beyond); ``prediction_change``: the RMS of the prediction's move over the new training
#: samples, relative to the prior's own prediction there (a gain ``b`` moves it by ``|b - 1|``, so
#: 0.5 is the gain bound's upper side for every method, ``prior_ridge`` included).
BOUNDS = {"gain": (0.67, 1.5), "time_factor": (0.71, 1.41), "prediction_change": 0.5}
#: The check ids of the fitness warnings (``checks.confirmed``: ``{file: <prior id>, check: <id>}``).
CHECKS = ("prior_adaptation", "prior_speeds", "prior_dynamics", "prior_misfit")
#: ``prior_misfit``: the prior as it is scores, on the new training runs, more than this many of its
#: own pooled 90 % half widths (:func:`misfit_warning`). Set on 40 random designs of one sensor
#: layout as the value above every true sibling's (10.7), judged on 40 designs never run before: it
#: fired on 1 of 40 true siblings and on 13 of the 23 other designs declared siblings that the other
#: warnings left to ``prior_speeds`` alone (issue 47, ``docs/decisions.md`` 2026-11-30).
MISFIT_HALF_WIDTHS = 11.0


def _finite(values: Iterable) -> list[float]:
    out = []
    for v in values:
        try:
            f = float(v)
        except (TypeError, ValueError):
            continue
        if math.isfinite(f):
            out.append(f)
    return out


def prior_speed_range(prior: Mapping) -> list[float] | None:
    """The prior's speed range (r/min): its artefact's ``speed_range_rpm``, else its per-speed
    models' extremes (``rafi`` kinds), else (a CV-weighted ensemble of RAFI's kinds, which record
    speeds, not a range) its members' joined, else ``None``."""
    if prior.get("speed_range_rpm"):
        lo, hi = prior["speed_range_rpm"]
        return [float(lo), float(hi)]
    speeds = _finite(s.get("speed_rpm") for s in prior.get("speeds") or [])
    members = [m for m in (prior.get("members") or {}).values() if isinstance(m, Mapping)]
    speeds += [v for m in members for v in prior_speed_range(m) or []]
    return [min(speeds), max(speeds)] if speeds else None


def prior_trained_speeds(prior: Mapping, base: Mapping | None = None) -> list[float]:
    """The speeds (r/min) of the per-speed models the prior (or ``base``, the artefact re-fitted)
    records: RAFI's kinds; for a CV-weighted ensemble prior whose ``base`` has none, its own
    ``trained_speeds_rpm`` and its members' (they trained on the same runs); empty when no
    artefact records them."""
    from rafi.family.prior import ENSEMBLE_KIND

    base = prior if base is None else base
    speeds = _finite(s.get("speed_rpm") for s in base.get("speeds") or [])
    if not speeds and prior.get("kind") == ENSEMBLE_KIND:
        members = [m for m in (prior.get("members") or {}).values() if isinstance(m, Mapping)]
        speeds = _finite(s.get("speed_rpm") for m in members for s in m.get("speeds") or [])
        speeds += _finite(prior.get("trained_speeds_rpm") or [])
    return sorted(set(speeds))


def prior_rise_ranges(prior: Mapping) -> dict[str, list[float]]:
    """Sensor -> the range of temperature rise (K) the prior was trained on: ``regressor_ranges``
    (ridge kinds), else the union of its per-speed models' (``rafi`` kinds)."""
    out: dict[str, list[float]] = {}
    blocks = [prior.get("regressor_ranges") or {}]
    blocks += [s.get("regressor_ranges") or {} for s in prior.get("speeds") or []]
    for block in blocks:
        for sensor, pair in block.items():
            lo, hi = (float(v) for v in pair)
            old = out.get(str(sensor))
            out[str(sensor)] = [min(lo, old[0]), max(hi, old[1])] if old else [lo, hi]
    return out


def _outside(prior: list[float] | None, tested: list[float] | None) -> list[list[float]]:
    """The parts of the interval ``prior`` that ``tested`` does not reach."""
    if not prior:
        return []
    if not tested:
        return [list(prior)]
    out = []
    if prior[0] < tested[0]:
        out.append([prior[0], min(prior[1], tested[0])])
    if prior[1] > tested[1]:
        out.append([max(prior[0], tested[1]), prior[1]])
    return out


#: Relative moves closer than this are a tie (one gain moves every coefficient by the same share,
#: up to rounding, which differs between NumPy builds): the first coefficient in order is named.
TIE_RELATIVE = 1e-9


def _largest_change(change: list[dict]) -> dict | None:
    """The coefficient that moved most relative to its prior value (``|prior|`` above 0); of
    moves tied within :data:`TIE_RELATIVE`, the first."""
    best = None
    for c in change or []:
        a, b = float(c["prior"]), float(c["new"])
        if a == 0 or not (math.isfinite(a) and math.isfinite(b)):
            continue
        rel = (b - a) / abs(a)
        if best is None or abs(rel) > abs(best["relative"]) * (1.0 + TIE_RELATIVE):
            best = {"name": str(c["name"]), "prior": a, "new": b, "relative": rel}
    return best


def _prediction_change(before: np.ndarray, after: np.ndarray) -> float | None:
    before, after = np.asarray(before, dtype=float), np.asarray(after, dtype=float)
    ok = np.isfinite(before) & np.isfinite(after)
    size = float(np.sqrt(np.mean(before[ok] ** 2))) if ok.any() else 0.0
    if size <= 0:
        return None
    return float(np.sqrt(np.mean((after[ok] - before[ok]) ** 2))) / size


def prior_speeds_known(
    prior: Mapping, *, base: Mapping | None = None, qualification: Mapping | None = None
) -> list[float]:
    """The speeds (r/min, sorted) the prior is known to have been trained at: its (or ``base``'s)
    per-speed models' (:func:`prior_trained_speeds`), else its qualification's ``speeds_rpm``;
    empty when neither says."""
    base = prior if base is None else base
    speeds = prior_trained_speeds(prior, base) or _finite((qualification or {}).get("speeds_rpm") or [])
    return sorted(set(speeds))


def prior_only_speeds(
    prior: Mapping,
    tested_speeds_rpm: Iterable[float],
    *,
    tolerance_rpm: float,
    base: Mapping | None = None,
    qualification: Mapping | None = None,
) -> list[float]:
    """The prior's speeds (r/min) that no tested speed is within ``tolerance_rpm`` of: those of
    :func:`prior_speeds_known`, else the ends of its speed range. The fitness warning
    ``prior_speeds`` names them; ``rafi plan`` says beforehand which a programme leaves to the
    prior alone."""
    base = prior if base is None else base
    tested = _finite(tested_speeds_rpm)
    ends = prior_speeds_known(prior, base=base, qualification=qualification) or (
        prior_speed_range(base) or []
    )
    tol = float(tolerance_rpm)
    return sorted({s for s in ends if not any(abs(s - t) <= tol for t in tested)})


def inherited_speeds(prior: Mapping, speeds_rpm: Iterable[float], *, tolerance_rpm: float) -> dict | None:
    """Of ``speeds_rpm`` (the speeds a re-qualification leaves to ``prior`` alone), those the prior
    itself left to its own prior: the prior is a re-qualification too and its fitness block's
    ``speeds_prior_only_rpm`` holds them (within ``tolerance_rpm``). Its tested speeds never
    reached them, so the model there is older than the prior.

    Returns
    -------
    dict or None
        ``speeds_rpm`` (sorted), ``from`` (the older prior's ``model_id`` and ``machine``, as the
        prior's fitness block names it) and ``via`` (the prior's own machine); None when the prior
        is no re-qualification or left none of them to its prior.
    """
    fitness = (prior.get("adaptation") or {}).get("fitness") or {}
    older = _finite(fitness.get("speeds_prior_only_rpm") or [])
    tol = float(tolerance_rpm)
    speeds = sorted({float(s) for s in _finite(speeds_rpm) if any(abs(s - o) <= tol for o in older)})
    if not speeds:
        return None
    origin = fitness.get("prior") or {}
    return {
        "speeds_rpm": speeds,
        "from": {"model_id": str(origin.get("model_id") or ""), "machine": origin.get("machine")},
        "via": prior.get("machine"),
    }


def fitness_block(
    prior: Mapping,
    *,
    base: Mapping | None = None,
    qualification: Mapping | None,
    origin: str | None,
    method: str,
    gain: float | None,
    time_factor: float | None,
    alpha: float | None,
    coefficient_change: list[dict],
    prior_prediction: np.ndarray,
    new_prediction: np.ndarray,
    tested_speeds_rpm: Iterable[float],
    tested_rises: Mapping[str, list[float]],
    speed_tolerance_rpm: float,
) -> dict:
    """The ``fitness`` block of an adapted artefact (module docstring).

    Parameters
    ----------
    prior : mapping
        The prior's artefact.
    base : mapping, optional
        The artefact re-fitted when it is not ``prior`` itself: a CV-weighted ensemble prior's
        heaviest member (:func:`rafi.family.prior.prior_base`). Its speed and rise ranges are what
        the prior covers; the block's ``prior`` then also names it (``member``).
    qualification : mapping or None
        :func:`rafi.family.prior.prior_qualification` (``None``: not known, e.g. a prior given
        in-process). The prior's speeds are its (or ``base``'s) per-speed models', else the
        qualification's ``speeds_rpm``, else the ends of its speed range.
    origin : str or None
        ``this machine``, ``declared sibling`` (:func:`rafi.family.prior.prior_origin`) or
        ``None`` (not checked: a prior given in-process).
    method, gain, time_factor, alpha, coefficient_change
        What the adaptation chose (:class:`rafi.family.adapted.AdaptedPrior`).
    prior_prediction, new_prediction : array
        The prior's and the adapted model's prediction (um) on the new training samples.
    tested_speeds_rpm : iterable of float
        The speeds of the new training runs.
    tested_rises : mapping
        Sensor -> ``[lo, hi]`` of the temperature rise (K) on the new training samples.
    speed_tolerance_rpm : float
        A prior speed within this of a tested one is covered (``speed_tolerance_rpm``).

    Returns
    -------
    dict
        ``origin``, ``prior`` (its qualification: ``model_id``, ``machine``, ``kind``,
        ``max_residual_um``, ``n_runs``; not the time of its promotion, a fact of its registry that
        would make the adapted model's id differ between installations:
        :func:`rafi.family.prior.prior_promoted`), ``method``, ``gain``, ``time_factor``,
        ``alpha``, ``largest_coefficient_change`` (``name``, ``prior``, ``new``, ``relative``),
        ``prediction_change``, ``speeds_tested_rpm``, ``speed_range_tested_rpm``,
        ``speeds_prior_rpm`` (``None``: only its range is known), ``speed_range_prior_rpm``,
        ``speeds_prior_only_rpm``, ``temperature`` (per sensor: ``tested``, ``prior``,
        ``prior_only`` ranges), ``bounds`` (:data:`BOUNDS`) and ``warnings``
        (:func:`fitness_warnings`); and ``speeds_inherited`` (:func:`inherited_speeds`) only when
        the prior left some of its prior-only speeds to its own prior.
    """
    qual = dict(qualification or {})
    base = prior if base is None else base
    tested = sorted(set(_finite(tested_speeds_rpm)))
    prior_range = prior_speed_range(base)
    prior_speeds = prior_speeds_known(prior, base=base, qualification=qual) or None
    prior_only = prior_only_speeds(
        prior, tested, tolerance_rpm=speed_tolerance_rpm, base=base, qualification=qual
    )
    ranges = prior_rise_ranges(base)
    temperature = []
    for sensor in sorted(set(ranges) | set(tested_rises)):
        here = [float(v) for v in tested_rises[sensor]] if sensor in tested_rises else None
        there = ranges.get(sensor)
        temperature.append(
            {"sensor": sensor, "tested": here, "prior": there, "prior_only": _outside(there, here)}
        )
    block = {
        "origin": origin,
        "prior": {
            "model_id": str(prior.get("model_id") or ""),
            "machine": prior.get("machine"),
            "kind": prior.get("kind"),
            "max_residual_um": qual.get("max_residual_um"),
            "n_runs": qual.get("n_runs"),
        },
        "method": method,
        "gain": gain,
        "time_factor": time_factor,
        "alpha": alpha,
        "largest_coefficient_change": _largest_change(coefficient_change),
        "prediction_change": _prediction_change(prior_prediction, new_prediction),
        "speeds_tested_rpm": tested,
        "speed_range_tested_rpm": [tested[0], tested[-1]] if tested else None,
        "speeds_prior_rpm": prior_speeds,
        "speed_range_prior_rpm": prior_range,
        "speeds_prior_only_rpm": prior_only,
        "temperature": temperature,
        "bounds": {k: list(v) if isinstance(v, tuple) else v for k, v in BOUNDS.items()},
    }
    inherited = inherited_speeds(prior, prior_only, tolerance_rpm=speed_tolerance_rpm)
    if inherited is not None:  # only then: every other adapted artefact keeps its bytes and its id
        block["speeds_inherited"] = inherited
    if base is not prior:  # the member of an ensemble prior that was re-fitted
        block["prior"]["member"] = {"kind": base.get("kind"), "model_id": str(base.get("model_id") or "")}
    block["warnings"] = fitness_warnings(block)
    return block


def dynamics_warning(model: str, score_um: float, reference: str, reference_um: float) -> dict:
    """The fitness warning ``prior_dynamics`` (one line): a model fitted from scratch on the new
    data, ``model``, scored clearly lower in the whole-run CV than the prior adapted by one gain,
    ``reference`` (:func:`rafi.family.selection.scratch_ahead`), so the prior may not describe this
    machine's dynamics. Found beside the fit, by the family's CV (:func:`rafi.family.compare.run_family`)."""
    return {
        "check": "prior_dynamics",
        "message": (
            f"{model}, fitted from scratch on the new data, scored clearly lower in the cross-validation "
            f"than the prior with one gain ({reference}): {score_um:.3g} against {reference_um:.3g} um, by "
            "more than one standard error of the paired per-fold differences; the prior may not describe "
            "this machine's dynamics"
        ),
    }


def misfit_warning(score_um: float, prior: Mapping) -> dict | None:
    """The fitness warning ``prior_misfit`` (one line), or None: the prior as it is lies, on the new
    training runs, more than :data:`MISFIT_HALF_WIDTHS` of its own pooled 90 % half widths off
    (``score_um``: the whole-run CV's score of the candidate ``prior``, the mean over held-out runs of
    the max |residual|; the half width: ``prior``'s ``interval.calibration.pooled_half_width_um``).
    The prior does not describe this machine as it is: another design declared a sibling, or a
    large change (a repair). None when the prior has no calibrated interval or the score is not
    finite. Found beside the fit, by the family's CV (:func:`rafi.family.compare.run_family`)."""
    half = prior_half_width(prior)
    score = _finite([score_um])
    if half is None or not score or score[0] <= MISFIT_HALF_WIDTHS * half:
        return None
    from rafi.family.prior import ensemble_member

    who, whose = "the prior as it is", "its own"
    member = ensemble_member(dict(prior))  # the candidate ``prior`` is its heaviest member as it is
    if member is not None:
        who, whose = f"the ensemble prior's heaviest member ({member['kind']}) as it is", "the ensemble's"
    return {
        "check": "prior_misfit",
        "message": (
            f"{who} lies {score[0]:.3g} um off on the new training runs (the cross-validation's "
            f"mean worst residual per run), {score[0] / half:.1f} times {whose} 90 % half width "
            f"({half:.3g} um; more than {MISFIT_HALF_WIDTHS:g}): the prior does not describe this machine "
            "as it is (another design, or a large change)"
        ),
    }


def warning_remedy(check: str, machine: str | None) -> str:
    """What to do instead of confirming a fitness warning ``check``: record runs at the speeds the
    new data lack (``prior_speeds``), or, where the prior does not describe the machine or had to
    move beyond its bounds (``prior_misfit``, ``prior_dynamics``, ``prior_adaptation``), qualify it
    without the prior."""
    m = str(machine).split("@")[0] if machine else "<machine>"  # a probe unit's machine folder
    if check == "prior_speeds":
        return (
            f"record runs at those speeds (rafi plan --machine {m} names the --hours whose programme "
            "tests them all)"
        )
    return (
        f"qualify the machine without this prior (config.yaml: machines: {m}: models: {{prior: none}}; "
        f"the programme of a first qualification: rafi plan --machine {m} --prior none --hours <budget>)"
    )


def prior_half_width(prior: Mapping) -> float | None:
    """The prior's own pooled 90 % half width (um, ``interval.calibration.pooled_half_width_um``:
    its calibration over the held-out runs of its qualification), or None without a positive one."""
    calibration = (prior.get("interval") or {}).get("calibration") or {}
    half = _finite([calibration.get("pooled_half_width_um")])
    return half[0] if half and half[0] > 0 else None


def fitness_warnings(block: Mapping) -> list[dict]:
    """The fitness warnings of a ``fitness`` block: ``[{check, message}]`` (:data:`CHECKS`), one
    line each, none when the adaptation is inside :data:`BOUNDS` and the new data cover every
    speed of the prior."""
    out = []
    moved = []
    gain, factor, change = block.get("gain"), block.get("time_factor"), block.get("prediction_change")
    lo, hi = BOUNDS["gain"]
    if gain is not None and not lo <= float(gain) <= hi:
        moved.append(f"gain {float(gain):.3g} outside [{lo:g}, {hi:g}]")
    lo, hi = BOUNDS["time_factor"]
    if factor is not None and not lo <= float(factor) <= hi:
        moved.append(f"time factor {float(factor):g} outside [{lo:g}, {hi:g}]")
    if change is not None and float(change) > BOUNDS["prediction_change"]:
        moved.append(
            f"prediction moved by {100 * float(change):.0f} % of its size "
            f"(more than {100 * BOUNDS['prediction_change']:g} %)"
        )
    if moved:
        out.append(
            {
                "check": "prior_adaptation",
                "message": "the adaptation moved the prior beyond its bounds: " + "; ".join(moved),
            }
        )
    only = block.get("speeds_prior_only_rpm") or []
    if only:
        tested = block.get("speeds_tested_rpm") or []
        out.append(
            {
                "check": "prior_speeds",
                "message": (
                    f"the prior's speed(s) {', '.join(f'{s:g}' for s in only)} r/min have no new training "
                    f"run (tested here: {', '.join(f'{s:g}' for s in tested) or 'none'} r/min); there the "
                    "model is the prior's alone" + inherited_text(block.get("speeds_inherited"))
                ),
            }
        )
    return out


def inherited_text(inherited: Mapping | None, speeds_text=None) -> str:
    """The clause the ``prior_speeds`` warning, the report and ``rafi status`` add for the speeds
    the prior itself had only from its own prior (:func:`inherited_speeds`); empty without.
    ``speeds_text`` formats the list of speeds with their unit (default ``12000, 18000 r/min``)."""
    if not inherited:
        return ""
    values = [float(s) for s in inherited.get("speeds_rpm") or []]
    speeds = speeds_text(values) if speeds_text else ", ".join(f"{s:g}" for s in values) + " r/min"
    origin = inherited.get("from") or {}
    who = str(origin.get("model_id") or "")[:12] or "?"
    whose = f" of {origin['machine']}" if origin.get("machine") else ""
    # not "never tested on <via>": a repair's chain is one machine, whose older prior was tested there
    return f"; {speeds} the prior had only from its own prior ({who}{whose}): no run at them since that model"
