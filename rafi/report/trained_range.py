"""A model's validation samples outside what it was trained on: one computation for the report.

Three passages state them: the verdict's statement of what a residual can and cannot show (for
the model offered to the machine, :func:`rafi.report.verdict.residual_statement`), the
validation section's multi-condition runs and the comparison's explanation of why RAFI as
published fails (both for RAFI as published, :mod:`rafi.report.model_sections`,
:mod:`rafi.report.comparison_section`). Each reads the counts of its model's rows (``per_run.csv``
or ``validation/summary.csv``: ``n_samples``, ``n_outside_temp_range``,
``n_outside_speed_range``, which the model's own evaluation flagged) and the trained speeds of its
artefact here, so a speed is inside or outside the same range in every passage: the range the
model's flag used (``speed_range_rpm``; RAFI as published records its training speeds, per
speed, and blends between them), not the speeds the training runs happened to cover.
"""

from __future__ import annotations

import pandas as pd

from rafi.report.format import fmt_speed_range, isnum

__all__ = ["trained_speed_span", "trained_speeds_text", "outside_counts", "range_facts"]


def trained_speed_span(artefact) -> tuple[float, float] | None:
    """The speeds an artefact was trained on, as its outside-speed flag reads them.

    Parameters
    ----------
    artefact : dict or None
        A model's artefact (``model.json``, ``comparison/best_model.json``).

    Returns
    -------
    tuple of float or None
        ``speed_range_rpm`` (every kind of the family, a CV-weighted ensemble: the union of its
        members'), else the lowest and highest of its per-speed records (``speeds``: RAFI as
        published); ``None`` where the artefact records neither.
    """
    if not isinstance(artefact, dict):
        return None
    span = artefact.get("speed_range_rpm")
    if isinstance(span, (list, tuple)) and len(span) == 2 and all(isnum(v) for v in span):
        return float(min(span)), float(max(span))
    speeds = [float(s["speed_rpm"]) for s in artefact.get("speeds") or [] if isnum(s.get("speed_rpm"))]
    return (min(speeds), max(speeds)) if speeds else None


def trained_speeds_text(artefact) -> str:
    """:func:`trained_speed_span` as the report writes it (``1 250–5 000 r/min``; one speed
    once, ``3 000 r/min``); ``""`` where the artefact records none."""
    span = trained_speed_span(artefact)
    return fmt_speed_range(*span) if span else ""


def _total(rows: pd.DataFrame, column: str) -> int | None:
    if column not in rows:
        return None
    return int(pd.to_numeric(rows[column], errors="coerce").fillna(0).sum())


def outside_counts(rows: pd.DataFrame | None) -> dict | None:
    """The samples of ``rows`` (one model's validation runs) outside its trained ranges.

    Parameters
    ----------
    rows : DataFrame or None
        One model's rows of ``per_run.csv`` or ``validation/summary.csv`` (one row per
        validation run, or one row per model in ``comparison/summary.csv``).

    Returns
    -------
    dict or None
        ``n_samples``, ``n_temp`` (outside the trained temperature range), ``n_speed`` (outside
        the trained speeds; ``None`` without the column), summed over the rows, and ``temp_pct``
        / ``speed_pct`` (% of ``n_samples``; ``None`` without samples); ``None`` without rows
        or without ``n_samples`` and ``n_outside_temp_range``.
    """
    if rows is None or not len(rows) or not {"n_samples", "n_outside_temp_range"} <= set(rows.columns):
        return None
    n, temp, speed = (
        _total(rows, "n_samples"),
        _total(rows, "n_outside_temp_range"),
        _total(rows, "n_outside_speed_range"),
    )
    return {
        "n_samples": n,
        "n_temp": temp,
        "n_speed": speed,
        "temp_pct": 100.0 * temp / n if n else None,
        "speed_pct": 100.0 * speed / n if n and speed is not None else None,
    }


def range_facts(rows: pd.DataFrame | None, artefact) -> dict | None:
    """:func:`outside_counts` of a model's rows with ``speeds`` (:func:`trained_speeds_text` of
    its artefact, ``""`` unknown); ``None`` without counts."""
    counts = outside_counts(rows)
    return None if counts is None else {**counts, "speeds": trained_speeds_text(artefact)}
