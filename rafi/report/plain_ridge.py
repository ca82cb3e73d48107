"""The report's passage on the plain ridge: by how much the offered model beats it, and why.

Computed from ``comparison/summary.csv`` alone (:func:`rafi.family.plain_ridge.floor_facts`):
the offered model's margin over the plain ridge (kind ``temperature_ridge``, scored in every
comparison) on the training runs, each margin naming its score (the whole-run CV, the forward CV
and the selection score, their mean, where forward folds ran), and on the validation runs (the
worst max |residual|); and the selection rule's reason for offering it where that reason is not
a lower score (it does not beat the plain ridge, or it is an ensemble, which its rule offers
whatever its score). A clause whose number is missing is left out; without any
number, the sentence is.
"""

from __future__ import annotations

import pandas as pd

from rafi.family.plain_ridge import PLAIN_RIDGE, floor_facts
from rafi.family.selection import SHARED_GAIN, SHARED_RIDGE, TIE_UM
from rafi.family.time_blocks import SCHEME as TIME_BLOCKS
from rafi.report.format import fmt_num, isnum

__all__ = ["UM", "floor_sentence", "floor_reason", "section_plain_ridge"]

UM = "\u00b5m"

#: What the re-qualification's rule does with each adaptation of an ensemble prior as a whole
#: (:func:`rafi.family.selection.choose_champion`), for the reason ``adapted_ensemble``.
ADAPTED_RULES = {
    SHARED_RIDGE: (
        "offers the moved members whenever the cross-validation could score them, whatever the scores"
    ),
    SHARED_GAIN: (
        "offers the shared gain unless another candidate's score is lower than its by more than one "
        "standard error of the paired per-fold differences"
    ),
}


def _clause(um, pct, where: str) -> tuple[str, str] | None:
    """``("beats", "by 0.42 µm (18 %) in the whole-run CV (...)")``: ``trails`` for a negative
    margin, ``("equals", where)`` for one that rounds to 0.00 µm, the percentage only with a
    finite ``pct``; ``None`` without a finite ``um``."""
    if not isnum(um):
        return None
    size = fmt_num(abs(float(um)), 2, UM)
    if size == fmt_num(0.0, 2, UM):
        return "equals", where
    share = f" ({fmt_num(abs(float(pct)), 0)} %)" if isnum(pct) else ""
    return ("beats" if float(um) > 0 else "trails"), f"by {size}{share} {where}"


def _against(part: dict, what: str = "") -> str:
    """``(mean held-out max |residual| 2.97 µm against 3.50 µm)``: the offered model's value
    first, the plain ridge's second."""
    return f"({what}{fmt_num(part['mine'], 2, UM)} against {fmt_num(part['ridge'], 2, UM)})"


def _margin_clauses(facts: dict, whole: str) -> tuple[list, tuple | None]:
    """The training-run CV clauses of :func:`floor_sentence`, each naming its score, and the
    validation clause (``None`` without its number)."""
    sc = facts.get("scores") or {}
    get = lambda k: sc.get(k) or {"um": None, "pct": None, "mine": None, "ridge": None}  # noqa: E731
    sel, wh, fw, val = get("selection"), get("whole"), get("forward"), get("validation")
    mean = "mean held-out max |residual| "
    if not sc:  # facts without the parts: the selection score's margin, named as such
        cv = [_clause(facts["cv_um"], facts["cv_pct"], "in the selection score")]
    elif isnum(fw["um"]) and isnum(wh["um"]):  # forward folds ran: both parts, then their mean
        cv = [
            _clause(wh["um"], wh["pct"], f"in the {whole} {_against(wh, mean)}"),
            _clause(fw["um"], fw["pct"], f"in the forward CV {_against(fw)}"),
            _clause(sel["um"], sel["pct"], f"in the selection score, their mean {_against(sel)}"),
        ]
    elif isnum(wh["mine"]):  # no forward folds: the whole-run mean is the selection score
        cv = [_clause(sel["um"], sel["pct"], f"in the {whole}, the selection score {_against(sel, mean)}")]
    else:
        cv = [_clause(sel["um"], sel["pct"], f"in the selection score {_against(sel)}")]
    if not sc:
        v = _clause(facts["validation_um"], None, "on the validation runs")
    else:
        v = _clause(val["um"], None, f"on the validation runs {_against(val, 'worst max |residual| ')}")
    return [c for c in cv if c], v


def floor_sentence(facts: dict | None, whole: str = "whole-run CV") -> str:
    """``The offered model (<model>) beats the plain ridge by X µm (Y %) in the whole-run CV (...),
    by ... in the forward CV (...) and by ... in the selection score, their mean (...), and by Z
    µm on the validation runs (...).``, from :func:`rafi.family.plain_ridge.floor_facts`.

    Every margin names the score it is on, with both values: the whole-run CV mean max |residual|
    (``whole``: how the section names those folds; the score the ensemble's weights use), the
    forward CV's and the selection score (their mean) where forward folds ran, else the whole-run
    mean as the selection score; then the worst max |residual| on the validation runs (no
    percentage). Each clause only with its number; ``trails`` where the offered model is behind,
    ``equals`` where the margin rounds to 0.00 µm; ``""`` without facts or without any number.
    When the offered model is the plain ridge itself, that is the sentence.
    """
    if not facts:
        return ""
    if facts["reason"] == "is_plain_ridge":
        return f"The offered model is the plain ridge ({PLAIN_RIDGE}) itself, chosen among the enabled kinds."
    cv, val = _margin_clauses(facts, whole)
    parts, verb = [], None
    for v, text in cv + ([val] if val else []):
        if verb is None:
            parts.append(f"{v} the plain ridge {text}")
        elif v == verb and v != "equals":
            parts.append(text)
        else:
            parts.append(f"{v} it {text}")
        verb = v
    if not parts:
        return ""
    n_cv = len(cv)
    if not n_cv:
        return f"The offered model ({facts['model']}) {parts[-1]}."
    head = parts[:n_cv]
    text = head[0] if n_cv == 1 else ", ".join(head[:-1]) + " and " + head[-1]
    if val:
        text += (", and " if n_cv > 1 else " and ") + parts[-1]
    return f"The offered model ({facts['model']}) {text}."


def floor_reason(facts: dict | None, whole: str = "whole-run CV") -> str:
    """Why the offered model is offered beside the plain ridge where the reason is not that it
    scores lower (the selection rule's reason, from ``facts["reason"]``): a model the rule offers
    although it does not beat the plain ridge on the selection score, and an ensemble, which its
    rule offers whatever its score (``ensemble``, ``adapted_ensemble``: said also where it beats
    it, so a margin is never read as the reason); ``""`` for a model the lowest score chose
    (``beats``), the plain ridge itself, or without facts. ``whole``: how the section names the
    whole-run folds (the ensemble's weights use them only)."""
    if not facts:
        return ""
    reason, name = facts["reason"], facts["model"]
    ahead = isnum(facts.get("cv_um")) and float(facts["cv_um"]) > 0
    lead = f"{name} is offered although it does not beat the plain ridge on the selection score"
    if reason == "not_enabled":
        return (
            f"{lead}: the plain ridge is not among the kinds enabled for this machine "
            f"(models: enabled: {', '.join(facts['enabled'])}), so it is scored as the reference only, "
            "and the rule offers the enabled kind with the lowest selection score."
        )
    if reason == "tie":
        nm = f"{TIE_UM * 1000:g} nm"
        then = {
            "worst": (
                f"the lower worst held-out run ({name} {fmt_num(facts['worst_um'], 2, UM)}, the plain "
                f"ridge {fmt_num(facts['ridge_worst_um'], 2, UM)})"
            ),
            "simpler": f"the simpler kind ({name} before {PLAIN_RIDGE})",
            "name": "the first name in alphabetical order",
        }[facts["tie_breaker"]]
        return (
            f"{lead}: their selection scores are equal within {nm} (a tie), and the rule then takes {then}."
        )
    if reason == "no_cv":
        return (
            f"No cross-validation fold scored the models, so the default rule offered {name}, without "
            "a comparison with the plain ridge on the training runs."
        )
    if reason == "ensemble":
        rule = (
            "offers the CV-weighted blend of every kind whatever its own CV score (the rule judged "
            "one level up, across real logs and foreign machines, not on this machine's folds); its "
            f"weights come from the {whole} only, and the plain ridge is one of its members."
        )
        if ahead:
            return (
                f"{name} is offered by models: offer: ensemble, not because it beats the plain ridge: "
                f"that setting {rule}"
            )
        return f"{lead}: models: offer is ensemble on this machine, which {rule}"
    if reason == "adapted_ensemble":
        rule = ADAPTED_RULES.get(name, "chooses among the candidates that start from the prior")
        members = (
            "the plain ridge scored here is not one of its members (they are the prior's, as this run "
            "moved them)."
        )
        if ahead:
            return (
                f"{name} is the ensemble prior adapted as a whole, offered by the re-qualification's rule, "
                f"which {rule} (Model comparison, selection rule), not because it beats the plain ridge and "
                f"not by models: offer; {members}"
            )
        return (
            f"{lead}: it is the ensemble prior adapted as a whole, offered by the re-qualification's "
            f"rule, which {rule} (Model comparison, selection rule), not by models: offer; {members}"
        )
    if reason == "other":
        return f"{lead}, although the plain ridge is enabled and scores lower: not the rule stated above."
    return ""


def section_plain_ridge(summary: pd.DataFrame | None, scheme: str = "") -> dict | None:
    """The passage's context: ``sentence`` (:func:`floor_sentence`), ``reason``
    (:func:`floor_reason`), ``reference_only`` (the plain ridge is not enabled here: scored,
    never offered) and ``name`` (``temperature_ridge``); ``None`` without an offered model or a
    plain ridge row in ``comparison/summary.csv``. ``scheme``: the whole-run scheme of
    ``comparison/cv.csv`` (``time_blocks``: the folds are named time-blocked CV)."""
    facts = floor_facts(summary) if summary is not None else None
    if facts is None:
        return None
    whole = "time-blocked CV" if str(scheme) == TIME_BLOCKS else "whole-run CV"
    return {
        "sentence": floor_sentence(facts, whole),
        "reason": floor_reason(facts, whole),
        "reference_only": not facts["candidate"],
        "name": PLAIN_RIDGE,
    }
