"""What cross-validation chose for a fitted model of the family, in words for people: the
``selected`` column of ``comparison/summary.csv`` (:func:`describe_selection`) and the compare
job's log (:func:`fitted_text`)."""

from __future__ import annotations

from rafi.family.ensemble import ENSEMBLE
from rafi.family.grey_box import GreyBox
from rafi.family.time_blocks import hours

__all__ = ["describe_selection", "fitted_text", "ensemble_text"]


def _seconds(values) -> str:
    return "/".join(f"{float(v):g}" for v in values) + " s"


def ensemble_text(weights: dict) -> str:
    """An ensemble's members by weight, heaviest first: ``temperature_ridge 0.324, dynamic 0.239``
    (three decimals; the order of ``weights`` among equals)."""
    ordered = sorted(weights.items(), key=lambda kv: -float(kv[1]))
    return ", ".join(f"{name} {float(w):.3f}" for name, w in ordered)


def describe_selection(model) -> str:
    """What cross-validation chose for a fitted model of the family, in one line for people."""
    if hasattr(model, "describe"):  # an adapted prior (rafi.family.adapted), an adapted ensemble too
        return model.describe()
    if getattr(model, "kind", None) == ENSEMBLE:  # rafi.family.ensemble: weights, not hyperparameters
        edged = sorted({e.split(":", 1)[0] for e in getattr(model, "grid_edges_", []) or []})
        edge = f"; member(s) at a grid edge: {', '.join(edged)}" if edged else ""
        return (
            f"CV weights of its {len(model.weights_)} members (1/s^2, s its whole-run CV mean max "
            f"|residual|): {ensemble_text(model.weights_)}; each member as CV chose it{edge}"
        )
    if not hasattr(model, "alpha_"):
        return "nothing to choose (one OLS per training speed, fuzzy blend)"
    parts = [
        f"alpha {model.alpha_:g}",
        "rises " + ", ".join("as is" if t <= 0 else f"filtered {t:g} s" for t in model.taus_),
    ]
    if isinstance(model, GreyBox):
        parts.append(
            f"heat-input filters {_seconds(model.speed_taus_)}"
            if model.speed_taus_
            else "no heat-input filters"
        )
        if model.instantaneous_:
            lag = model.centrifugal_lag_s_
            parts.append("draw-in n\u00b2 term" + (f" with a {lag:g} s lag" if lag > 0 else ""))
        else:
            parts.append("no draw-in term (not identified)")
    else:
        parts.append("speed gain dT\u00b7n" if model.speed_gain_ else "no speed gain")
        parts.append("speed terms" if model.speed_terms_ else "no speed terms (not identified)")
        if getattr(model, "speed_taus_", None):  # dynamic's heat-input history
            parts.append(f"heat-input filters {_seconds(model.speed_taus_)}")
    blocks = getattr(model, "time_blocks_", None)
    if blocks:
        parts.append(
            f"chosen on {blocks['blocks']} time blocks with {hours(blocks['gap_s'])} guard gaps "
            f"(filters up to {blocks['max_filter_s']:g} s)"
        )
    edges = list(getattr(model, "grid_edges_", []) or [])
    if edges:
        parts.append("AT A GRID EDGE (the best value may lie outside the grid): " + "; ".join(edges))
    return "; ".join(parts)


def fitted_text(model) -> str:
    """What CV chose, for the job's log."""
    if hasattr(model, "describe"):  # an adapted prior, an adapted ensemble too
        return " " + model.describe()
    if getattr(model, "kind", None) == ENSEMBLE:
        return f" weights {ensemble_text(model.weights_)}"
    text = f" alpha={model.alpha_:g} taus_s={model.taus_}" if hasattr(model, "alpha_") else ""
    if isinstance(model, GreyBox):
        text += (
            f" speed_taus_s={model.speed_taus_} instantaneous_n2={model.instantaneous_}"
            f" centrifugal_lag_s={model.centrifugal_lag_s_:g}"
        )
    return text
