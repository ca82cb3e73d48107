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
from rafi.report.comparison_section import selection_score
from rafi.report.ensemble_section import adapted_from
from rafi.report.format import fmt_num, fmt_speed, fmt_speed_range, isnum, short_id
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
    The move of one coefficient is ``new - prior``, relative to ``|prior|`` where that is not zero.
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


def _speeds(values) -> str:
    """Speeds as ``3 000, 9 000 r/min`` (``none`` without one)."""
    values = list(values or [])
    return ", ".join(fmt_num(v, 0) for v in values) + "\u00a0r/min" if values else "none"


def _range(pair, digits: int = 1) -> str:
    return f"{fmt_num(pair[0], digits)} … {fmt_num(pair[1], digits)}" if pair else "–"


def fitness_context(
    block: dict | None, machine: str | None = None, results_dir: str | os.PathLike | None = None
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
    ``temperature`` (rows: ``sensor``, ``tested``, ``prior``, ``prior_only``, text in K),
    ``bounds`` and ``warnings`` (``check``, ``message``, ``confirm``: the ``checks.confirmed``
    entry that confirms it, ``instead``: what to do instead for ``machine``,
    :func:`rafi.family.prior_fitness.warning_remedy`)."""
    fit = (block or {}).get("fitness")
    if not isinstance(fit, dict):
        return None
    own = dict(fit.get("prior") or {})
    full_id = own.get("model_id") or (block or {}).get("parent") or ""
    pid = short_id(full_id)
    if results_dir is not None:
        prior_machine = (block or {}).get("parent_machine") or own.get("machine")
        own["promoted"] = prior_promoted(results_dir, prior_machine, full_id) or own.get("promoted")
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
                "prior_only": "; ".join(_range(r) for r in t.get("prior_only") or []) or "none",
            }
            for t in fit.get("temperature") or []
        ],
        "bounds": fit.get("bounds") or {},
        "warnings": [
            {
                **w,
                "confirm": confirmation_entry(pid, w.get("check")),
                "instead": warning_remedy(str(w.get("check")), machine),
            }
            for w in fit.get("warnings") or []
        ],
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


def section_requalification(res: dict, results_dir: str | os.PathLike | None = None) -> dict | None:
    """The context of the re-qualification section, or ``None`` when no prior was a candidate.

    Parameters
    ----------
    res : dict
        The loaded results (:func:`rafi.report.inputs.load_results`).
    results_dir : str or path, optional
        The folder holding every machine's ``registry``: the prior's promotion time is read from
        its machine's (None: not shown unless the artefact carries it).

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
        ``chosen`` (:func:`how_chosen`: how the ridge penalty and the time factor were set).
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
        "fitness": fitness_context(block, best.get("machine"), results_dir),
        # a CV-weighted ensemble prior: the member re-fitted (rafi.family.prior.prior_base)
        "member": ensemble_prior(block, results_dir),
        "sentence": comparison_sentence(offered, prior_row, scratch),
        "cv": cv,
        "chosen": how_chosen(best, block, cv),
        "forward": any(isnum(r["cv_forward_um"]) for r in rows),
    }


def comparison_sentence(offered: dict | None, prior_row: dict | None, scratch: dict | None) -> str:
    """The offered model's worst validation residual beside the prior unchanged and the best
    from-scratch fit on the same data (chosen among the from-scratch kinds by the same CV)."""
    if offered is None or not isnum(offered["worst_um"]):
        return ""
    parts = [f"The offered model ({offered['model']}) is within {fmt_num(offered['worst_um'], 2)} \u00b5m"]
    parts[0] += " on every validation run"
    beside = []
    if prior_row is not None and prior_row is not offered and isnum(prior_row["worst_um"]):
        who = (
            f"the ensemble prior's heaviest member ({prior_row['kind']})"
            if prior_row.get("member")
            else "the prior"
        )
        beside.append(f"{who} unchanged {fmt_num(prior_row['worst_um'], 2)} \u00b5m")
    if scratch is not None and scratch is not offered and isnum(scratch["worst_um"]):
        beside.append(
            f"the from-scratch fit the selection takes on the same data ({scratch['model']}) "
            f"{fmt_num(scratch['worst_um'], 2)} \u00b5m"
        )
    if beside:
        parts.append("; beside it, " + " and ".join(beside))
    return "".join(parts) + "."
