"""The report's re-qualification section: what qualified a model that started from a prior.

Shown when ``comparison/summary.csv`` holds the adaptation candidates (``prior``,
``prior_gain``, ``prior_time``, ``prior_ridge``: :mod:`rafi.family.adapted`, ``docs/models.md``,
"Re-qualification from a prior"). Everything is read from this machine's results:

* the new data: the training runs of ``runs.csv`` (hours, speeds, cool-downs);
* the prior and how far each coefficient moved: the ``adaptation`` block of the offered model
  (``comparison/best_model.json``) - ``parent``, ``parent_machine``, ``method``, ``gain``,
  ``time_factor``, ``alpha`` and ``coefficient_change`` (``name``, ``prior``, ``new`` per coefficient);
* the prior's fitness: the block's ``fitness`` (:mod:`rafi.family.prior_fitness`) - where the
  prior comes from (this machine or a declared sibling), its own qualification, how far the
  prediction moved, the speeds and temperature rises tested here against those only the prior
  covers, and the warnings that block promotion until confirmed (:func:`fitness_context`);
* the comparison: every model's row of ``comparison/summary.csv`` - the prior unchanged, the
  adapted prior and the from-scratch family on the same data, each with its selection score on
  the new training runs (what chose: the whole-run CV score, or with forward-in-time folds the
  mean of the whole-run and the forward score, both shown) and its worst residual on the
  validation runs.

Without the candidates (no prior was offered) the section is left out; an offered model from
scratch still gets the section when a prior was a candidate (the prior lost, and the section says
by how much).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pandas as pd

from rafi.contract import REGISTRY_DIR
from rafi.family.confirmation import confirmation_entry
from rafi.family.prior import prior_promoted
from rafi.family.prior_fitness import inherited_text, warning_remedy
from rafi.family.selection import SHARED_GAIN, SHARED_RIDGE
from rafi.family.since_change import natural_order
from rafi.report.comparison_section import selection_score
from rafi.report.ensemble_section import adapted_from
from rafi.report.format import fmt_num, fmt_sig, fmt_speed, fmt_speed_range, isnum, short_id
from rafi.report.trained_range import adapted_speeds
from rafi.settings import truthy

#: The adaptation candidates, in the order the section lists them, and what each is.
CANDIDATES = {
    "prior": "the prior as it is (nothing re-fitted)",
    "prior_gain": "the prior with one gain on every coefficient, fitted on the new data",
    "prior_time": "the prior with its filter time constants scaled by one factor (by CV) and one gain",
    "prior_ridge": "the prior's coefficients moved by a ridge penalised towards them (strength by CV)",
    "prior_shared_gain": "the ensemble prior as a whole, its blend times one gain fitted on the new data",
    "prior_shared_ridge": "the ensemble prior as a whole times one gain, every member then moved toward the "
    "new data by a ridge at one fixed penalty",
}
#: The candidates that adapt the whole of a CV-weighted ensemble prior; beside them the others adapt
#: its heaviest member only (:mod:`rafi.family.adapted`), and the section says so.
ENSEMBLE_CANDIDATES = ("prior_shared_gain", "prior_shared_ridge")
#: What the member candidates are with an ensemble prior (``{kind}``: the heaviest member's kind).
MEMBER_CANDIDATES = {
    "prior": "the ensemble prior's heaviest member ({kind}) as it is (nothing re-fitted)",
    "prior_gain": "the ensemble prior's heaviest member ({kind}) with one gain on every coefficient",
    "prior_time": "the ensemble prior's heaviest member ({kind}) with its filter time constants scaled "
    "by one factor (by CV) and one gain",
    "prior_ridge": "the ensemble prior's heaviest member ({kind}), its coefficients moved by a ridge "
    "penalised towards them (strength by CV)",
}
#: How many of the largest coefficient moves the section tabulates.
MOVES_SHOWN = 12
#: How many of each moved member's largest coefficient moves the section tabulates (an ensemble
#: prior adapted as a whole, :func:`member_moves`).
MEMBER_MOVES_SHOWN = 3
#: The shared methods of an ensemble prior adapted as a whole (:mod:`rafi.family.adapted`).
SHARED_METHODS = ("shared_gain", "shared_ridge")


def _model_rows(summary: pd.DataFrame) -> list[dict]:
    """One row per model: group, what it is (``what``; ``member``: with an ensemble prior, a
    candidate that adapts its heaviest member only), CV scores (``cv_um`` the selection score that
    chose, ``cv_whole_um`` and ``cv_forward_um`` its parts), worst validation residual, coverage,
    offered."""
    rows = []
    ensemble_prior = summary["model"].astype(str).isin(ENSEMBLE_CANDIDATES).any()
    for r in summary.to_dict("records"):
        name = str(r["model"])
        group = "prior" if name == "prior" else ("adapted prior" if name in CANDIDATES else "from scratch")
        member = ensemble_prior and name in MEMBER_CANDIDATES
        what = CANDIDATES.get(name, f"kind {r.get('kind', name)}, fitted on the new data only")
        rows.append(
            {
                "model": name,
                "kind": str(r.get("kind", name)),
                "group": group,
                "what": MEMBER_CANDIDATES[name].format(kind=r.get("kind", "?")) if member else what,
                "member": member,
                "cv_um": selection_score(r),
                "cv_whole_um": r.get("cv_mean_max_abs_um"),
                "cv_forward_um": r.get("cv_forward_mean_max_abs_um"),
                "worst_um": r.get("max_abs_after_um"),
                "coverage_pct": 100 * float(r["coverage"]) if isnum(r.get("coverage")) else None,
                "offered": truthy(r.get("champion")),
                "candidate": truthy(r.get("candidate", True)),  # false: the plain ridge as reference only
            }
        )
    order = {"prior": 0, "adapted prior": 1, "from scratch": 2}
    return sorted(rows, key=lambda x: (order[x["group"]], x["model"]))


def _best_by_cv(rows: list[dict], group: str) -> dict | None:
    """The row of ``group`` the selection would take there: the lowest CV score, or without any
    CV score (no fold) the default rule's model (:func:`rafi.family.selection.default_champion`);
    candidates only (not the plain ridge scored as the reference, :mod:`rafi.family.plain_ridge`)."""
    from rafi.family.selection import default_champion

    mine = [r for r in rows if r["group"] == group and r["candidate"]]
    scored = [r for r in mine if isnum(r["cv_um"])]
    if scored:
        return min(scored, key=lambda r: float(r["cv_um"]))
    if not mine:
        return None
    name = default_champion([r["model"] for r in mine])
    return next(r for r in mine if r["model"] == name)


def new_data(runs: pd.DataFrame | None) -> dict | None:
    """Hours and speeds of the new training data (``runs.csv`` rows of role ``training``)."""
    if runs is None or "role" not in runs:
        return None
    tr = runs[runs["role"].astype(str) == "training"]
    if not len(tr):
        return None
    dur = pd.to_numeric(tr["duration_s"], errors="coerce").fillna(0.0)
    speed = pd.to_numeric(tr["speed_rpm"], errors="coerce").fillna(0.0)
    idle = tr["kind"].astype(str).eq("idle") if "kind" in tr else speed.le(0)
    per_speed = (
        pd.DataFrame({"speed": speed[~idle].round(), "h": dur[~idle] / 3600.0}).groupby("speed")["h"].sum()
    )
    return {
        "runs": int(len(tr)),
        "hours": float(dur.sum() / 3600.0),
        "idle_hours": float(dur[idle].sum() / 3600.0),
        "n_idle": int(idle.sum()),
        "speeds": [{"speed": fmt_speed(s), "hours": fmt_num(h, 1)} for s, h in per_speed.items()],
    }


def coefficient_moves(change, shown: int = MOVES_SHOWN) -> dict | None:
    """The largest coefficient moves of an adaptation, and their spread over all coefficients.

    ``change`` is the adaptation block's ``coefficient_change``: a list of ``{name, prior, new}``.
    The move of one coefficient is ``new - prior``, relative to ``|prior|`` where that is not zero;
    each row's ``ratio`` is ``new / prior`` (:func:`coefficient_ratio`: what the table shows, a
    negative ratio a flipped sign), ``None`` for a prior of 0.
    """
    if not isinstance(change, list) or not change:
        return None
    frame = pd.DataFrame(change)
    if not {"name", "prior", "new"} <= set(frame.columns):
        return None
    prior = pd.to_numeric(frame["prior"], errors="coerce").to_numpy(float)
    new = pd.to_numeric(frame["new"], errors="coerce").to_numpy(float)
    move = new - prior
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(np.abs(prior) > 0, move / np.abs(prior), np.nan)
    order = np.argsort(-np.abs(np.nan_to_num(move)), kind="stable")[:shown]
    rows = [
        {
            "name": str(frame["name"].iloc[i]),
            "prior": prior[i],
            "new": new[i],
            "move": move[i],
            "relative": rel[i],
            "ratio": coefficient_ratio(prior[i], new[i]),
        }
        for i in order
    ]
    finite = rel[np.isfinite(rel)]
    return {
        "n": int(len(frame)),
        "n_moved": int(np.sum(np.abs(move) > 0)),
        "median_relative": float(np.median(np.abs(finite))) if finite.size else None,
        "max_relative": float(np.max(np.abs(finite))) if finite.size else None,
        "rows": rows,
    }


def coefficient_ratio(prior, new) -> float | None:
    """``new / prior`` of one coefficient: how many times its prior value it is now (negative:
    its sign flipped); ``None`` where ``prior`` is 0 or either is not a finite number."""
    if not (isnum(prior) and isnum(new)) or float(prior) == 0:
        return None
    return float(new) / float(prior)


def ratio_words(prior, new) -> str:
    """How one coefficient moved, as a factor of its prior value: ``10.6 times its prior value``,
    ``\u22120.500 times its prior value: its sign flipped``, ``from 0 to 0.2500`` (a prior of 0).

    A relative move ``(new - prior) / |prior|`` reads as a shrink for a negative coefficient that
    grew (``-0.053`` to ``-0.562`` is ``-959 %``); the factor says it grew 10.6-fold with its sign.
    """
    ratio = coefficient_ratio(prior, new)
    if ratio is None:
        return f"from {fmt_sig(prior, 4)} to {fmt_sig(new, 4)}" if isnum(prior) and isnum(new) else ""
    flipped = ": its sign flipped" if ratio < 0 else ""
    return f"{fmt_sig(ratio, 3)} times its prior value{flipped}"


def largest_change_words(largest) -> str:
    """The coefficient that moved most relative to its prior value (the fitness block's
    ``largest_coefficient_change``: ``name``, ``prior``, ``new``) as the report and ``rafi status``
    say it: ``ridge_global: dT11@0s, −0.05303 → −0.2968: 5.60 times its prior value``
    (:func:`ratio_words`, never a relative change); ``""`` without one."""
    if not isinstance(largest, dict) or not largest.get("name"):
        return ""
    prior, new = largest.get("prior"), largest.get("new")
    return f"{largest['name']}, {fmt_sig(prior, 4)} \u2192 {fmt_sig(new, 4)}: {ratio_words(prior, new)}"


def _member_change(art: dict) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """``prior``, ``new`` and names of a member's ``adaptation.coefficient_change`` (empty
    without one)."""
    change = ((art or {}).get("adaptation") or {}).get("coefficient_change")
    rows = [c for c in change or [] if isinstance(c, dict) and {"name", "prior", "new"} <= set(c)]
    prior = np.array([c["prior"] if isnum(c["prior"]) else np.nan for c in rows], dtype=float)
    new = np.array([c["new"] if isnum(c["new"]) else np.nan for c in rows], dtype=float)
    return prior, new, [str(c["name"]) for c in rows]


def member_moves(best: dict | None, shown: int = MEMBER_MOVES_SHOWN) -> dict | None:
    """How far each member of an ensemble prior adapted as a whole moved (``prior_shared_gain``,
    ``prior_shared_ridge``: :class:`rafi.family.adapted.SharedAdaptedEnsemble`), from each member's
    own ``adaptation.coefficient_change`` in the artefact (``comparison/best_model.json``
    ``members``); ``None`` for any other model.

    ``shared_gain`` multiplies every member's coefficients by the shared gain; ``shared_ridge``
    then moves each ridge member's coefficients toward the new data by a ridge at the fixed
    penalty (a member that is not a ridge kind keeps the gain alone), so a coefficient's
    ``new / prior`` is the gain only where the ridge left it.

    Parameters
    ----------
    best : dict or None
        The offered artefact.
    shown : int
        How many of each moved member's largest moves to list.

    Returns
    -------
    dict or None
        ``method``, ``gain``, ``alpha`` (the ensemble's block), ``n`` (coefficients of every
        member), ``n_members``, ``ratio_lo`` / ``ratio_hi`` (``new / prior`` over every member's
        coefficients with a prior value other than 0; ``None`` without one), ``n_flipped`` (signs
        flipped), ``members`` (heaviest first: ``name``, ``kind``, ``weight``, ``moved``
        (``ridge``: the gain, then the ridge; ``gain``: the gain alone), ``n``, ``ratio_lo``,
        ``ratio_hi``, ``n_flipped``) and ``rows``: per member moved by the ridge its ``shown``
        largest moves by ``|new - prior| / |prior|`` (a coefficient moved from 0 first):
        ``member``, ``name``, ``prior``, ``new``, ``ratio``.
    """
    block = (best or {}).get("adaptation") if isinstance(best, dict) else None
    if not isinstance(block, dict) or block.get("method") not in SHARED_METHODS:
        return None
    weights = {str(k): float(v) for k, v in (best.get("weights") or {}).items() if isnum(v)}
    arts = best.get("members") if isinstance(best.get("members"), dict) else {}
    members, rows, every = [], [], []
    for name in sorted(weights, key=lambda n: -weights[n]):
        art = arts.get(name) or {}
        prior, new, names = _member_change(art)
        known = np.isfinite(prior) & np.isfinite(new) & (prior != 0)
        ratio = np.full(len(prior), np.nan)
        ratio[known] = new[known] / prior[known]
        every += list(ratio[known])
        moved = "ridge" if (art.get("adaptation") or {}).get("method") == "ridge" else "gain"
        members.append(
            {
                "name": name,
                "kind": str(art.get("kind") or name),
                "weight": weights[name],
                "moved": moved,
                "n": len(names),
                "ratio_lo": float(ratio[known].min()) if known.any() else None,
                "ratio_hi": float(ratio[known].max()) if known.any() else None,
                "n_flipped": int(np.sum(ratio[known] < 0)),
            }
        )
        if moved != "ridge" or not names:
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.where(known, np.abs(new - prior) / np.abs(prior), 0.0)
        rel = np.where((prior == 0) & np.isfinite(new) & (new != 0), np.inf, np.nan_to_num(rel))
        for i in np.argsort(-rel, kind="stable")[:shown]:
            rows.append(
                {
                    "member": name,
                    "name": names[i],
                    "prior": float(prior[i]),
                    "new": float(new[i]),
                    "ratio": None if np.isnan(ratio[i]) else float(ratio[i]),
                }
            )
    every = np.asarray(every, dtype=float)
    return {
        "method": block.get("method"),
        "gain": block.get("gain"),
        "alpha": block.get("alpha"),
        "n": sum(m["n"] for m in members),
        "n_members": len(members),
        "ratio_lo": float(every.min()) if every.size else None,
        "ratio_hi": float(every.max()) if every.size else None,
        "n_flipped": int(np.sum(every < 0)),
        "members": members,
        "rows": rows,
    }


def _speeds(values) -> str:
    """Speeds as ``3 000, 9 000 r/min`` (``none`` without one)."""
    values = list(values or [])
    return ", ".join(fmt_num(v, 0) for v in values) + "\u00a0r/min" if values else "none"


def _range(pair, digits: int = 1) -> str:
    return f"{fmt_num(pair[0], digits)} … {fmt_num(pair[1], digits)}" if pair else "–"


def _outside_ranges(parts, digits: int = 1) -> str:
    """The parts of the prior's rise range the new data do not reach (``prior_only``), ``; ``
    between them; a part whose ends read the same at ``digits`` (narrower than the table shows)
    is left out, and ``none`` is said without one."""
    shown = [_range(p, digits) for p in parts or [] if fmt_num(p[0], digits) != fmt_num(p[1], digits)]
    return "; ".join(shown) or "none"


def _entry_text(entry: dict, check: str) -> str:
    """A ``checks.confirmed`` entry in YAML flow style, as the settings hold it."""
    return f"{{file: {entry.get('file')}, check: {check}}}"


def confirmed_fitness(decision: dict | None, confirmed=()) -> dict | None:
    """The prior fitness warnings a person confirmed, as ``decision.json`` lists them
    (``prior_fitness.confirmed``), and the ``checks.confirmed`` entries that lifted them; ``None``
    where it lists none.

    Parameters
    ----------
    decision : dict or None
        ``registry/decision.json``.
    confirmed : sequence of dict
        The machine's ``checks.confirmed``: the entry that matches a warning (its prior's id, its
        first 12 characters or a glob, and the check: :func:`rafi.readers.checks_machine.is_confirmed`)
        is named as the settings hold it; where none matches (settings changed since), the entry
        ``{file: <first 12 characters of the prior's id>, check: <check>}`` that confirms it.

    Returns
    -------
    dict or None
        ``checks`` (in the decision's order), ``entries`` (the entry of each), ``by_check``
        (check -> entry), ``prior`` (short id), ``machine`` (the prior's), ``promoted`` (the
        decision put tonight's candidate on the machine: it rested on these confirmations) and
        ``words`` (``the prior fitness checks prior_speeds, prior_misfit of prior 6fca63e8ad59
        (tapping-center-a), confirmed in checks.confirmed: [...]``).
    """
    from rafi.readers.checks_machine import is_confirmed

    dec = decision if isinstance(decision, dict) else {}
    block = dec.get("prior_fitness") if isinstance(dec.get("prior_fitness"), dict) else {}
    found = [w for w in block.get("confirmed") or [] if isinstance(w, dict) and w.get("check")]
    if not found:
        return None
    entries, items = [], []
    for w in found:
        prior, check = str(w.get("prior") or ""), str(w.get("check"))
        match = next(
            (
                c
                for c in confirmed or ()
                if isinstance(c, dict)
                and (is_confirmed(prior, check, [c]) or is_confirmed(prior[:12], check, [c]))
            ),
            None,
        )
        entries.append(_entry_text(match, check) if match else f"{{file: {prior[:12]}, check: {check}}}")
        items.append((check, prior[:12], w.get("machine")))
    priors = list(dict.fromkeys((p, m) for _, p, m in items))
    checks = [c for c, _, _ in items]
    plural = "s" if len(items) > 1 else ""
    if len(priors) == 1:
        pid, machine = priors[0]
        what = f"the prior fitness check{plural} {', '.join(checks)} of prior {pid} ({machine})"
    else:
        what = f"the prior fitness check{plural} " + ", ".join(f"{c} of prior {p} ({m})" for c, p, m in items)
    after = dec.get("champion_id_after")
    return {
        "checks": checks,
        "entries": entries,
        "by_check": dict(zip(checks, entries)),
        "prior": priors[0][0],
        "machine": priors[0][1],
        "promoted": dec.get("decision") == "promoted" and bool(after) and after == dec.get("candidate_id"),
        "words": f"{what}, confirmed in checks.confirmed: [{', '.join(entries)}]",
    }


def fitness_context(
    block: dict | None,
    machine: str | None = None,
    results_dir: str | os.PathLike | None = None,
    *,
    decision: dict | None = None,
    model_id: str | None = None,
    confirmed=(),
) -> dict | None:
    """The prior's fitness (the adaptation block's ``fitness``) as the section shows it, or
    ``None`` without one: ``origin``, ``prior`` (its own qualification: ``id``, ``machine``,
    ``kind``, ``promoted``, ``max_residual_um``, ``n_runs``; ``promoted`` is read from its
    machine's registry under ``results_dir``, :func:`rafi.family.prior.prior_promoted`: a fact of
    the registry, not of the artefact, which carries it only from an earlier version),
    ``prediction_change`` and ``largest`` (:func:`rafi.family.prior_fitness.fitness_block`),
    ``speeds_tested``, ``speeds_prior``, ``speeds_prior_only``, ``inherited`` (the clause for the
    speeds the prior had only from its own prior, :func:`rafi.family.prior_fitness.inherited_text`)
    and the two ranges (text),
    ``temperature`` (rows: ``sensor``, ``tested``, ``prior``, ``prior_only``, text in K; the
    sensors in natural order, T2 before T10; a part of ``prior_only`` narrower than the table shows
    left out, :func:`_outside_ranges`),
    ``bounds`` and ``warnings`` (``check``, ``message``, ``confirm``: the ``checks.confirmed``
    entry that confirms it, ``instead``: what to do instead for ``machine``,
    :func:`rafi.family.prior_fitness.warning_remedy`; ``confirmed_by``: the entry that confirmed
    it where ``decision`` is the decision on ``model_id`` and lists it in
    ``prior_fitness.confirmed``, :func:`confirmed_fitness` with ``confirmed``, the machine's
    ``checks.confirmed``; else None), ``all_confirmed`` (every warning so confirmed),
    ``promoted_on_confirmation`` (that decision put the model on the machine: it rested on them)
    and ``largest_words`` (the largest relative coefficient change as a factor,
    :func:`ratio_words`)."""
    fit = (block or {}).get("fitness")
    if not isinstance(fit, dict):
        return None
    own = dict(fit.get("prior") or {})
    full_id = own.get("model_id") or (block or {}).get("parent") or ""
    pid = short_id(full_id)
    if results_dir is not None:
        prior_machine = (block or {}).get("parent_machine") or own.get("machine")
        own["promoted"] = prior_promoted(results_dir, prior_machine, full_id) or own.get("promoted")
    dec = decision if isinstance(decision, dict) else {}
    mine = bool(model_id) and str(dec.get("candidate_id") or "") == str(model_id)
    conf = confirmed_fitness(dec, confirmed) if mine else None
    by_check = (conf or {}).get("by_check") or {}
    warnings = [
        {
            **w,
            "confirm": confirmation_entry(pid, w.get("check")),
            "instead": warning_remedy(str(w.get("check")), machine),
            "confirmed_by": by_check.get(str(w.get("check"))),
        }
        for w in fit.get("warnings") or []
    ]
    largest_words = largest_change_words(fit.get("largest_coefficient_change"))
    return {
        "origin": fit.get("origin"),
        "prior": {**own, "id": pid},
        "prediction_change": fit.get("prediction_change"),
        "largest": fit.get("largest_coefficient_change"),
        # the speeds tested here, a list with a rest said as the machine at rest (rafi.report.trained_range)
        "speeds_tested": (adapted_speeds({"adaptation": {"fitness": fit}}) or {}).get("tested_text")
        or "none",
        "speeds_prior": _speeds(fit.get("speeds_prior_rpm")) if fit.get("speeds_prior_rpm") else None,
        "speeds_prior_only": _speeds(fit.get("speeds_prior_only_rpm")),
        "inherited": inherited_text(fit.get("speeds_inherited"), _speeds),
        "range_tested": fmt_speed_range(*(fit.get("speed_range_tested_rpm") or [None, None])),
        "range_prior": fmt_speed_range(*(fit.get("speed_range_prior_rpm") or [None, None])),
        "temperature": [
            {
                "sensor": t.get("sensor"),
                "tested": _range(t.get("tested")),
                "prior": _range(t.get("prior")),
                "prior_only": _outside_ranges(t.get("prior_only")),
            }
            # the block lists the sensors as text (T1, T10, T11, T2): the table in natural order
            for t in sorted(fit.get("temperature") or [], key=lambda t: natural_order(str(t.get("sensor"))))
        ],
        "bounds": fit.get("bounds") or {},
        "warnings": warnings,
        "all_confirmed": bool(warnings) and all(w["confirmed_by"] for w in warnings),
        "promoted_on_confirmation": bool(
            conf and conf["promoted"] and any(w["confirmed_by"] for w in warnings)
        ),
        "largest_words": largest_words,
    }


def registry_artefact(
    results_dir: str | os.PathLike | None, machine: str | None, model_id: str | None
) -> dict | None:
    """The artefact of ``model_id`` in ``machine``'s registry under ``results_dir``
    (``<results_dir>/<machine>/registry/models/<id>.json``), or None where it is not readable."""
    if results_dir is None or not machine or not model_id or "/" in f"{machine}{model_id}":
        return None
    path = Path(results_dir) / str(machine) / REGISTRY_DIR / "models" / f"{model_id}.json"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


def ensemble_prior(block: dict | None, results_dir: str | os.PathLike | None = None) -> dict | None:
    """The member of a CV-weighted ensemble prior that the adaptation re-fitted (the adaptation
    block's ``member``: ``name``, ``kind``, ``model_id`` short, ``weight``, ``n_members``), or
    ``None`` for any other prior.

    Also how that ensemble became its machine's champion, from its own artefact in that machine's
    registry under ``results_dir`` (:func:`registry_artefact`): ``offered_by`` ``adaptation`` (an
    ensemble prior adapted as a whole, offered by that re-qualification's rule; ``adapted``:
    :func:`rafi.report.ensemble_section.adapted_from` of it), ``setting`` (an ensemble of its
    machine's own kinds: ``models: offer: ensemble``) or None (its artefact is not readable here).
    """
    member = (block or {}).get("member")
    if not isinstance(member, dict) or not member.get("name"):
        return None
    prior = registry_artefact(results_dir, (block or {}).get("parent_machine"), (block or {}).get("parent"))
    adapted = adapted_from(prior) if prior is not None else None
    offered_by = None if prior is None else ("adaptation" if adapted else "setting")
    return {
        **member,
        "model_id": short_id(str(member.get("model_id") or "")),
        "offered_by": offered_by,
        "adapted": adapted,
    }


def _scored_by_cv(best: dict, key: str, cv: bool) -> bool:
    """Whether the adapted model's ``key`` (``alpha`` or ``factor``) was chosen by a CV that
    scored it: its artefact's ``cv`` table (one row a value tried, ``score_um`` None without a
    fold), else, for an artefact without one, whether the family's CV had a fold (``cv``)."""
    rows = [r for r in best.get("cv") or [] if isinstance(r, dict) and key in r]
    if rows:
        return any(isnum(r.get("score_um")) for r in rows)
    return cv


def how_chosen(best: dict, block: dict | None, cv: bool) -> dict:
    """How the offered adaptation's ridge penalty and time factor were set, in words (the
    section's "How far the prior moved"): ``alpha`` and ``time_factor`` (None where the block has
    none). ``shared_ridge``'s penalty is fixed for every machine
    (:data:`rafi.family.adapted.SHARED_RIDGE_ALPHA`), not chosen; ``prior_ridge``'s penalty and
    ``prior_time``'s factor are chosen by whole-run CV on the training runs, or, without a fold,
    are the prior's side (the largest penalty, the factor 1)."""
    block = block or {}
    words: dict = {"alpha": None, "time_factor": None}
    if block.get("alpha") is not None:
        if block.get("method") == "shared_ridge":
            words["alpha"] = "fixed for every machine, not chosen by CV"
        elif _scored_by_cv(best, "alpha", cv):
            words["alpha"] = "chosen by CV"
        else:
            words["alpha"] = "no CV fold: the largest of models.prior_ridge_alphas, the prior's side"
    if block.get("time_factor") is not None:
        if _scored_by_cv(best, "factor", cv):
            words["time_factor"] = "chosen by CV"
        else:
            words["time_factor"] = "no CV fold: the prior's own time constants"
    return words


def section_requalification(
    res: dict, results_dir: str | os.PathLike | None = None, confirmed=()
) -> dict | None:
    """The context of the re-qualification section, or ``None`` when no prior was a candidate.

    Parameters
    ----------
    res : dict
        The loaded results (:func:`rafi.report.inputs.load_results`); ``decision``
        (``registry/decision.json``) says which fitness warnings a person confirmed and the
        figure of the champion before this run.
    results_dir : str or path, optional
        The folder holding every machine's ``registry``: the prior's promotion time is read from
        its machine's (None: not shown unless the artefact carries it).
    confirmed : sequence of dict
        The machine's ``checks.confirmed`` (the entries that lifted the fitness warnings,
        :func:`confirmed_fitness`).

    Returns
    -------
    dict or None
        ``rows`` (every model: ``group`` prior / adapted prior / from scratch, ``cv_um``,
        ``cv_whole_um``, ``cv_forward_um``, ``worst_um``, ``coverage``, ``offered``), ``forward``
        (forward folds scored the models too), ``offered`` (its row), ``prior_row``,
        ``scratch`` (the from-scratch model CV ranks first), ``new_data`` (:func:`new_data`),
        ``adaptation`` (the offered model's block or ``None``: the prior lost), ``parent``
        (short id), ``moves`` (:func:`coefficient_moves`) and ``sentence`` (the comparison in
        one sentence, every number from the rows), ``fitness`` (:func:`fitness_context`),
        ``member`` (:func:`ensemble_prior`: the member of an ensemble prior that was re-fitted),
        ``chosen`` (:func:`how_chosen`: how the ridge penalty and the time factor were set),
        ``member_moves`` (:func:`member_moves`: an ensemble prior adapted as a whole, member by
        member), ``rule`` (:func:`rule_sentence`: the rule that offered the model) and
        ``on_machine`` (the ensemble prior as it is, when it is the champion before this run:
        ``id``, ``worst_um`` of ``decision.json`` ``champion_summary``; else None).
    """
    summ = res.get("comparison")
    if summ is None or "model" not in summ or not summ["model"].astype(str).isin(list(CANDIDATES)).any():
        return None
    rows = _model_rows(summ)
    offered = next((r for r in rows if r["offered"]), None)
    best = res.get("best_model") if isinstance(res.get("best_model"), dict) else {}
    block = best.get("adaptation") if isinstance(best.get("adaptation"), dict) else None
    prior_row = next((r for r in rows if r["model"] == "prior"), None)
    scratch = _best_by_cv(rows, "from scratch")
    cv = any(isnum(r["cv_um"]) for r in rows)
    forward = any(isnum(r["cv_forward_um"]) for r in rows)
    dec = res.get("decision") if isinstance(res.get("decision"), dict) else {}
    on_machine = None
    parent = str((block or {}).get("parent") or "")
    champ = dec.get("champion_summary") if isinstance(dec.get("champion_summary"), dict) else {}
    if parent and parent == str(dec.get("champion_id_before") or "") and isnum(champ.get("max_residual_um")):
        on_machine = {"id": short_id(parent), "worst_um": float(champ["max_residual_um"])}
    return {
        "rows": rows,
        "offered": offered,
        "prior_row": prior_row,
        "scratch": scratch,
        "new_data": new_data(res.get("runs_csv")),
        "adaptation": block,
        "parent": short_id(block.get("parent", "")) if block else "",
        "parent_machine": (block or {}).get("parent_machine") or "",
        "moves": coefficient_moves((block or {}).get("coefficient_change")),
        "fitness": fitness_context(
            block,
            best.get("machine"),
            results_dir,
            decision=dec,
            model_id=best.get("model_id"),
            confirmed=confirmed,
        ),
        # a CV-weighted ensemble prior: the member re-fitted (rafi.family.prior.prior_base)
        "member": ensemble_prior(block, results_dir),
        "sentence": comparison_sentence(offered, prior_row, scratch, on_machine),
        "on_machine": on_machine,
        "cv": cv,
        "chosen": how_chosen(best, block, cv),
        "forward": forward,
        "rule": rule_sentence(rows, cv, forward),
        "member_moves": member_moves(best),
    }


#: What the section says the cross-validation scored (every rule).
_SCORED = (
    "the prior as it is, the prior adapted to the new data and the from-scratch family fitted on the "
    "same data"
)


def rule_sentence(rows: list[dict], cv: bool, forward: bool = False) -> str:
    """The rule that offered the model, in one sentence, with the scores it applied to.

    With an ensemble prior the re-qualification's rule, not the lowest score, offers the model
    (:func:`rafi.family.selection.choose_champion`): ``prior_shared_ridge`` whenever the CV could
    score it, whatever the scores; without it, ``prior_shared_gain`` unless another candidate's
    score is lower by more than one standard error of the paired per-fold differences. Else the
    whole-run CV (and forward folds) chose; without a fold the default rule.

    Parameters
    ----------
    rows : list of dict
        :func:`_model_rows` (``model``, ``cv_um``: the selection score, ``offered``, ``candidate``).
    cv : bool
        A CV scored the models.
    forward : bool
        Forward-in-time folds scored them too (the score is the mean of both).

    Returns
    -------
    str
        Plain text, every score from ``rows``.
    """
    folds = "Whole-run cross-validation" + (" and forward-in-time folds" if forward else "")
    if not cv:
        return (
            "The new training runs give no whole-run cross-validation fold, so the default rule chose: the "
            "prior with one gain, the fewest parameters a single run can estimate, beside the prior as it is "
            "and the from-scratch family fitted on the same data"
        )
    offered = next((r for r in rows if r.get("offered")), None)
    names = {str(r["model"]) for r in rows}
    score = "selection score" if forward else "CV mean max |residual|"
    scored = [r for r in rows if r.get("candidate", True) and isnum(r.get("cv_um"))]
    lowest = min(scored, key=lambda r: float(r["cv_um"])) if scored else None

    def um(r):
        return f"{fmt_num(r['cv_um'], 2)} \u00b5m"

    if offered is not None and offered["model"] == SHARED_RIDGE and isnum(offered.get("cv_um")):
        low = (
            f", the lowest {lowest['model']} {um(lowest)}"
            if lowest is not None
            and lowest is not offered
            and float(lowest["cv_um"]) < float(offered["cv_um"])
            else ", the lowest"
        )
        return (
            "With an ensemble prior the re-qualification's rule offers the prior adapted as a whole with "
            f"every member moved toward the new data ({SHARED_RIDGE}) whenever the cross-validation could "
            "score it, whatever the scores (with a few training runs they cannot tell a move of the members "
            "from noise). "
            f"{folds} on the new training runs scored {_SCORED} all the same, by {score}: {SHARED_RIDGE} "
            f"{um(offered)}{low}"
        )
    if SHARED_GAIN in names and offered is not None:
        gain = next(r for r in rows if r["model"] == SHARED_GAIN)
        if offered is gain:
            outcome = f"no candidate beat it so, and {SHARED_GAIN} ({um(gain)}) is offered"
        else:
            outcome = (
                f"{offered['model']} ({um(offered)}) beat it so ({SHARED_GAIN} {um(gain)}) and is offered"
            )
        return (
            f"{folds} on the new training runs scored {_SCORED}; with an ensemble prior the "
            "re-qualification's rule offers the prior adapted as a whole with one shared gain "
            f"({SHARED_GAIN}) unless another candidate's score is lower than its by more than one standard "
            f"error of the paired per-fold differences: {outcome}"
        )
    return f"{folds} on the new training runs chose between {_SCORED}"


def comparison_sentence(
    offered: dict | None, prior_row: dict | None, scratch: dict | None, on_machine: dict | None = None
) -> str:
    """The offered model's worst validation residual beside the prior unchanged and the best
    from-scratch fit on the same data (chosen among the from-scratch kinds by the same CV).

    With an ensemble prior the candidate ``prior`` is its heaviest member alone, not the ensemble:
    the sentence says so, and where the ensemble prior is the model on the machine before this run
    (``on_machine``: ``id``, ``worst_um`` from ``decision.json`` ``champion_summary``, the same
    validation runs) it gives that figure too, each named as what it is.
    """
    if offered is None or not isnum(offered["worst_um"]):
        return ""
    parts = [f"The offered model ({offered['model']}) is within {fmt_num(offered['worst_um'], 2)} \u00b5m"]
    parts[0] += " on every validation run"
    beside = []
    member = prior_row is not None and prior_row.get("member")
    whole = member and isinstance(on_machine, dict) and isnum(on_machine.get("worst_um"))
    if whole:
        beside.append(
            f"the ensemble prior as it is ({on_machine['id']}, on the machine before this run) "
            f"{fmt_num(on_machine['worst_um'], 2)} \u00b5m"
        )
    if prior_row is not None and prior_row is not offered and isnum(prior_row["worst_um"]):
        if member:
            who = "its" if whole else "the ensemble prior's"
            who += f" heaviest member alone ({prior_row['kind']}, the candidate prior)"
        else:
            who = "the prior"
        beside.append(f"{who} unchanged {fmt_num(prior_row['worst_um'], 2)} \u00b5m")
    if scratch is not None and scratch is not offered and isnum(scratch["worst_um"]):
        beside.append(
            f"the from-scratch fit the selection takes on the same data ({scratch['model']}) "
            f"{fmt_num(scratch['worst_um'], 2)} \u00b5m"
        )
    if beside:
        parts.append(
            "; beside it, " + (", ".join(beside[:-1]) + " and " if len(beside) > 1 else "") + beside[-1]
        )
    return "".join(parts) + "."
