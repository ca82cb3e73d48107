"""The plain ridge in every qualification: ``temperature_ridge`` fitted and scored as the floor.

Every comparison (:func:`rafi.family.compare.run_family`) fits and scores the plain ridge, kind
``temperature_ridge`` (:mod:`rafi.family.temperature_ridge`), whatever ``models: enabled`` says:
the same fit, the same whole-run (and forward) CV, the same validation as the kinds beside it. It
is a **candidate** (the selection may offer it) only when ``models: enabled`` names it; otherwise
it is the reference alone: scored, listed, never ranked or offered (``docs/models.md``, "The
plain ridge as the floor").

This module says, from a comparison's summary, by how much every model beats the plain ridge on
the training runs (the selection score, :func:`rafi.family.selection.selection_table`) and on the
validation runs (the worst max |residual|), and why the offered model is offered where it does
not beat the plain ridge on the training runs (:data:`REASONS`). NumPy and pandas only; the
report words it (:mod:`rafi.report.plain_ridge`), ``comparison/summary.csv`` keeps it
(:data:`FLOOR_COLUMNS`) for benchmarks.

Under the current rule (the lowest selection score among the candidates) a candidate plain ridge
with a finite score is never beaten by more than a tie: the offered model's score is at most the
plain ridge's (equal within :data:`rafi.family.selection.TIE_UM`, the tie-breakers then decide).
So the offered model trails the plain ridge on the training runs only when the plain ridge is not
enabled (``not_enabled``), on a tie (``tie``) or without a CV score (``no_cv``);
``tests/test_plain_ridge.py`` checks that no other case occurs. Under ``models: offer: ensemble``
the CV-weighted ensemble (:mod:`rafi.family.ensemble`, the plain ridge one of its members) is
offered whatever its own score: its reason is ``ensemble`` whether its score is lower than the
plain ridge's or not (the margins say which; ``beats`` is the reason of a model the lowest score
chose). An ensemble prior adapted as a whole (``prior_shared_gain``, ``prior_shared_ridge``:
:mod:`rafi.family.adapted`) is offered by the re-qualification's rule
(:func:`rafi.family.selection.choose_champion`), not by that setting, and its members are the
prior's, not the plain ridge scored here: the reason is ``adapted_ensemble``, ahead or behind.

The selection score is the mean of the whole-run and the forward CV means where forward folds
ran; a margin on it can come from one of the two alone (a plain ridge that holds out whole runs
well and predicts the next runs badly), so :func:`floor_facts` gives the margins on each.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import pandas as pd

from rafi.family.ensemble import ENSEMBLE
from rafi.family.selection import SHARED_GAIN, SHARED_RIDGE, SIMPLICITY, TIE_UM

__all__ = [
    "PLAIN_RIDGE",
    "FLOOR_COLUMNS",
    "REASONS",
    "SCORE_PARTS",
    "with_plain_ridge",
    "floor_columns",
    "versus_plain_ridge",
    "floor_facts",
]

#: The kind fitted and scored in every comparison as the floor.
PLAIN_RIDGE = "temperature_ridge"

#: Columns :func:`floor_columns` adds to ``comparison/summary.csv``.
FLOOR_COLUMNS = [
    "candidate",
    "plain_ridge_cv_margin_um",
    "plain_ridge_cv_margin_pct",
    "plain_ridge_validation_margin_um",
    "plain_ridge_validation_margin_pct",
    "versus_plain_ridge",
]

#: The values of ``versus_plain_ridge`` on the offered model's row (empty on the others).
REASONS = {
    "beats": (
        "its selection score is lower than the plain ridge's by more than a tie, and the rule offers "
        "the lowest score (never on an ensemble: its rule is its reason)"
    ),
    "is_plain_ridge": "the offered model is the plain ridge",
    "not_enabled": "the plain ridge is not among the enabled kinds: scored as the reference only",
    "tie": "equal selection scores within TIE_UM: the tie-breakers chose",
    "no_cv": "no CV score: the default rule offered the model",
    "ensemble": (
        "the CV-weighted ensemble, offered under models.offer: ensemble whatever its own score, ahead "
        "of the plain ridge or behind it (the plain ridge among its members)"
    ),
    "adapted_ensemble": (
        "the ensemble prior adapted as a whole (prior_shared_gain, prior_shared_ridge), offered by the "
        "re-qualification's rule, not by models.offer, ahead of the plain ridge or behind it (its "
        "members are the prior's, as the run moved them)"
    ),
    "other": "offered with a higher selection score than a candidate plain ridge (not the current rule)",
}


def with_plain_ridge(factories: dict, factory: Callable) -> dict:
    """``factories`` (kind -> a function building the unfitted model) with the plain ridge's
    ``factory`` last when ``factories`` does not hold it already (then unchanged)."""
    return factories if PLAIN_RIDGE in factories else {**factories, PLAIN_RIDGE: factory}


def _num(value) -> float:
    """``value`` as a float; NaN for a missing or non-numeric one."""
    try:
        return float(value) if value is not None and not isinstance(value, (bool, np.bool_)) else np.nan
    except (TypeError, ValueError):
        return np.nan


def _margin(reference: float, value: float) -> tuple[float, float]:
    """``reference - value`` (um) and that in percent of ``reference``; NaN unless both finite
    (and the percentage unless ``reference`` > 0)."""
    if not (np.isfinite(reference) and np.isfinite(value)):
        return np.nan, np.nan
    d = reference - value
    return d, 100.0 * d / reference if reference > 0 else np.nan


def _row(summary: pd.DataFrame, name: str) -> dict | None:
    rows = summary[summary["model"].astype(str) == name]
    return rows.iloc[0].to_dict() if len(rows) else None


def _score(row: dict) -> float:
    """A summary row's selection score (``cv_mean_max_abs_um`` in a table without it)."""
    return _num(row.get("selection_score_um", row.get("cv_mean_max_abs_um")))


def versus_plain_ridge(champion: dict, ridge: dict) -> str:
    """Why the offered model is offered beside the plain ridge: a key of :data:`REASONS`.

    Parameters
    ----------
    champion, ridge : dict
        The offered model's and the plain ridge's rows of the summary (``model``,
        ``selection_score_um``, ``cv_max_abs_um``, ``candidate``).
    """
    name = str(champion["model"])
    if name == str(ridge["model"]):
        return "is_plain_ridge"
    mine, floor = _score(champion), _score(ridge)
    if not np.isfinite(mine):
        return "no_cv"
    # an ensemble is offered by its rule whatever its score, ahead of the plain ridge or behind it:
    # the rule is the reason (the margins say whether it beats it)
    if name in (SHARED_GAIN, SHARED_RIDGE):  # offered by the re-qualification's rule, not by models.offer
        return "adapted_ensemble"
    if str(champion.get("kind") or name) == ENSEMBLE:  # offered by models.offer, not by its score
        return "ensemble"
    if not np.isfinite(floor) or np.round(mine / TIE_UM) < np.round(floor / TIE_UM):
        return "beats"  # also a plain ridge that cannot predict some held-out run
    if not bool(ridge.get("candidate", True)):
        return "not_enabled"
    # a candidate plain ridge with a finite, lower score is offered instead: never reached by
    # rafi.family.selection.choose_champion (tests/test_plain_ridge.py)
    return "tie" if np.round(mine / TIE_UM) == np.round(floor / TIE_UM) else "other"


def floor_columns(summary: pd.DataFrame, candidates: Sequence[str], champion: str | None) -> pd.DataFrame:
    """``summary`` with :data:`FLOOR_COLUMNS`.

    Parameters
    ----------
    summary : pandas.DataFrame
        One row per model: ``model``, ``selection_score_um``, ``cv_max_abs_um`` and
        ``max_abs_after_um`` (the worst max |residual| over the validation runs).
    candidates : sequence of str
        The models the selection may offer.
    champion : str or None
        The offered model.

    Returns
    -------
    pandas.DataFrame
        ``candidate`` (bool), ``plain_ridge_cv_margin_um`` (the plain ridge's selection score
        minus the model's: positive where the model beats it on the training runs) and
        ``plain_ridge_cv_margin_pct`` (that in % of the plain ridge's), the same for the worst
        validation max |residual| (``plain_ridge_validation_margin_um``, ``_pct``), NaN where a
        number is missing or infinite; ``versus_plain_ridge`` (:func:`versus_plain_ridge`) on the
        offered model's row, ``""`` elsewhere. Without a plain ridge row the margins are NaN.
    """
    out = summary.assign(candidate=summary["model"].astype(str).isin([str(c) for c in candidates]))
    ridge = _row(out, PLAIN_RIDGE)
    cv, val = [], []
    for r in out.to_dict("records"):
        cv.append(_margin(_score(ridge), _score(r)) if ridge else (np.nan, np.nan))
        after = _num(r.get("max_abs_after_um"))
        val.append(_margin(_num(ridge.get("max_abs_after_um")), after) if ridge else (np.nan, np.nan))
    out["plain_ridge_cv_margin_um"] = [m for m, _ in cv]
    out["plain_ridge_cv_margin_pct"] = [p for _, p in cv]
    out["plain_ridge_validation_margin_um"] = [m for m, _ in val]
    out["plain_ridge_validation_margin_pct"] = [p for _, p in val]
    mine = _row(out, str(champion)) if champion is not None else None
    why = versus_plain_ridge(mine, ridge) if mine and ridge else ""
    out["versus_plain_ridge"] = np.where(out["model"].astype(str) == str(champion), why, "")
    return out


def _tie_breaker(champion: dict, ridge: dict) -> str:
    """Which tie-breaker of :func:`rafi.family.selection.selection_table` put ``champion`` before
    the plain ridge: ``worst`` (lower worst held-out run), ``simpler`` (:data:`SIMPLICITY`) or
    ``name``."""
    mine, floor = _num(champion.get("cv_max_abs_um")), _num(ridge.get("cv_max_abs_um"))
    if np.isfinite(mine) and np.isfinite(floor) and np.round(mine / TIE_UM) != np.round(floor / TIE_UM):
        return "worst"
    n = len(SIMPLICITY)
    if SIMPLICITY.get(str(champion["model"]), n) != SIMPLICITY.get(str(ridge["model"]), n):
        return "simpler"
    return "name"


def floor_facts(summary: pd.DataFrame) -> dict | None:
    """The offered model beside the plain ridge, from ``comparison/summary.csv``.

    Returns
    -------
    dict or None
        ``None`` without an offered model (``champion``) or a plain ridge row; else ``model``,
        ``kind`` (the offered model's), ``cv_um`` / ``cv_pct`` / ``validation_um`` /
        ``validation_pct`` (its margins over the plain ridge, NaN where missing: computed from
        the scores as :func:`floor_columns` computes them), ``reason``
        (:data:`REASONS`), ``candidate`` (the plain ridge may be offered), ``enabled`` (the
        candidates), ``tie_breaker`` (:func:`_tie_breaker` on a tie, else ``""``),
        ``worst_um`` / ``ridge_worst_um`` (their worst held-out runs) and ``scores``: for each
        score of :data:`SCORE_PARTS` (``selection``, ``whole``, ``forward``, ``validation``), both
        values and the margin (:func:`_scores`; ``cv_um`` / ``validation_um`` are those of
        ``selection`` / ``validation``).
    """
    if summary is None or not len(summary) or "champion" not in summary:
        return None
    s = summary.assign(model=summary["model"].astype(str))
    chosen = s[s["champion"].astype(str).str.lower().isin(["true", "1"])]
    if not len(chosen) or not (s["model"] == PLAIN_RIDGE).any():
        return None
    name = str(chosen["model"].iloc[0])
    if "candidate" not in s:  # a summary written before the floor columns: every model a candidate
        s["candidate"] = True
    s["candidate"] = s["candidate"].astype(str).str.lower().isin(["true", "1"])
    filled = floor_columns(
        s.drop(columns=[c for c in FLOOR_COLUMNS if c != "candidate"], errors="ignore"),
        list(s.loc[s["candidate"], "model"]),
        name,
    )
    me, ridge = _row(filled, name), _row(filled, PLAIN_RIDGE)
    reason = str(me["versus_plain_ridge"])
    return {
        "model": name,
        "kind": str(me.get("kind", name)),
        "cv_um": me["plain_ridge_cv_margin_um"],
        "cv_pct": me["plain_ridge_cv_margin_pct"],
        "validation_um": me["plain_ridge_validation_margin_um"],
        "validation_pct": me["plain_ridge_validation_margin_pct"],
        "reason": reason,
        "candidate": bool(ridge["candidate"]),
        "enabled": [str(m) for m in filled.loc[filled["candidate"], "model"]],
        "tie_breaker": _tie_breaker(me, ridge) if reason == "tie" else "",
        "worst_um": _num(me.get("cv_max_abs_um")),
        "ridge_worst_um": _num(ridge.get("cv_max_abs_um")),
        "scores": {part: _scores(me, ridge, column) for part, column in SCORE_PARTS.items()},
    }


#: The scores a margin over the plain ridge is on: the selection score (the mean of the other
#: two where forward folds ran, else the whole-run mean), the whole-run CV mean max |residual|,
#: the forward CV's, and the worst max |residual| over the validation runs.
SCORE_PARTS = {
    "selection": "selection_score_um",
    "whole": "cv_mean_max_abs_um",
    "forward": "cv_forward_mean_max_abs_um",
    "validation": "max_abs_after_um",
}


def _scores(me: dict, ridge: dict, column: str) -> dict:
    """The offered model's and the plain ridge's ``column`` and the margin on it: ``mine``,
    ``ridge``, ``um`` (the plain ridge's minus the model's) and ``pct`` (of the plain ridge's);
    NaN where a number is missing or infinite (:func:`_margin`)."""
    mine = _score(me) if column == "selection_score_um" else _num(me.get(column))
    floor = _score(ridge) if column == "selection_score_um" else _num(ridge.get(column))
    um, pct = _margin(floor, mine)
    return {"mine": mine, "ridge": floor, "um": um, "pct": pct}
