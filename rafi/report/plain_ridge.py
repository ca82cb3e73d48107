"""The report's passage on the plain ridge: by how much the offered model beats it, and why.

Computed from ``comparison/summary.csv`` alone (:func:`rafi.family.plain_ridge.floor_facts`):
the offered model's margin over the plain ridge (kind ``temperature_ridge``, scored in every
comparison) on the training runs (its selection score) and on the validation runs (the worst max
|residual|), and, where it does not beat the plain ridge on the training runs, the selection
rule's reason for offering it anyway. A clause whose number is missing is left out; without any
number, the sentence is.
"""

from __future__ import annotations

import pandas as pd

from rafi.family.plain_ridge import PLAIN_RIDGE, floor_facts
from rafi.family.selection import SHARED_GAIN, SHARED_RIDGE, TIE_UM
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
    """``("beats", "by 0.42 µm (18 %) in the training-run CV")``: ``trails`` for a negative
    margin, ``("equals", where)`` for one that rounds to 0.00 µm, the percentage only with a
    finite ``pct``; ``None`` without a finite ``um``."""
    if not isnum(um):
        return None
    size = fmt_num(abs(float(um)), 2, UM)
    if size == fmt_num(0.0, 2, UM):
        return "equals", where
    share = f" ({fmt_num(abs(float(pct)), 0)} %)" if isnum(pct) else ""
    return ("beats" if float(um) > 0 else "trails"), f"by {size}{share} {where}"


def floor_sentence(facts: dict | None) -> str:
    """``The offered model (<model>) beats the plain ridge by X µm (Y %) in the training-run CV
    and by Z µm on the validation runs.``, from :func:`rafi.family.plain_ridge.floor_facts`.

    Each clause only with its number (the validation one without a percentage, the CV one with
    it when the plain ridge's score is positive); ``trails`` where the offered model is behind;
    ``""`` without facts or without any number. When the offered model is the plain ridge
    itself, that is the sentence.
    """
    if not facts:
        return ""
    if facts["reason"] == "is_plain_ridge":
        return f"The offered model is the plain ridge ({PLAIN_RIDGE}) itself, chosen among the enabled kinds."
    cv = _clause(facts["cv_um"], facts["cv_pct"], "in the training-run CV")
    val = _clause(facts["validation_um"], None, "on the validation runs")
    parts = [f"{cv[0]} the plain ridge {cv[1]}"] if cv else []
    if val and not cv:
        parts.append(f"{val[0]} the plain ridge {val[1]}")
    elif val:
        parts.append(val[1] if val[0] == cv[0] != "equals" else f"{val[0]} it {val[1]}")
    return f"The offered model ({facts['model']}) {' and '.join(parts)}." if parts else ""


def floor_reason(facts: dict | None) -> str:
    """Why the offered model is offered where it does not beat the plain ridge on the training
    runs (the selection rule's reason, from ``facts["reason"]``); ``""`` where it beats it, is
    the plain ridge, or without facts."""
    if not facts:
        return ""
    reason, name = facts["reason"], facts["model"]
    lead = f"{name} is offered although it does not beat the plain ridge in the training-run CV"
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
        return (
            f"{lead}: models: offer is ensemble on this machine, which offers the CV-weighted blend of "
            "every kind whatever its own CV score (the rule judged one level up, across real logs and "
            "foreign machines, not on this machine's folds); the plain ridge is one of its members."
        )
    if reason == "adapted_ensemble":
        rule = ADAPTED_RULES.get(name, "chooses among the candidates that start from the prior")
        return (
            f"{lead}: it is the ensemble prior adapted as a whole, offered by the re-qualification's "
            f"rule, which {rule} (Model comparison, selection rule), not by models: offer; the plain "
            "ridge scored here is not one of its members (they are the prior's, as this run moved them)."
        )
    if reason == "other":
        return f"{lead}, although the plain ridge is enabled and scores lower: not the rule stated above."
    return ""


def section_plain_ridge(summary: pd.DataFrame | None) -> dict | None:
    """The passage's context: ``sentence`` (:func:`floor_sentence`), ``reason``
    (:func:`floor_reason`), ``reference_only`` (the plain ridge is not enabled here: scored,
    never offered) and ``name`` (``temperature_ridge``); ``None`` without an offered model or a
    plain ridge row in ``comparison/summary.csv``."""
    facts = floor_facts(summary) if summary is not None else None
    if facts is None:
        return None
    return {
        "sentence": floor_sentence(facts),
        "reason": floor_reason(facts),
        "reference_only": not facts["candidate"],
        "name": PLAIN_RIDGE,
    }
