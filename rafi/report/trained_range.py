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

A sample counts outside the trained speeds only when its speed lies more than the machine's
``speed_tolerance_rpm`` beyond them (:func:`beyond_trained_speeds`: the rule of RAFI's own flag,
:func:`rafi.method.fuzzy.triangular_weights`, which the streaming compensator applies too; the
report runs no model code, so it is written out here and held equal by a test): a
measured speed jitters by a few r/min around its set point, and the ridge kinds' flag
(``outside_speed_range`` of ``residuals.parquet``) takes any sample above the highest training run's
nominal speed, 18 001 r/min beside a training run at 18 000 r/min that itself ran at 17 997-18 003.
Where the residual samples are at hand (``comparison/residuals.parquet``), the counts are recounted
from them by that rule (:func:`speed_counts`): a flagged sample beyond the model's trained speeds
by more than the tolerance; the trained speeds are its artefact's when the report holds it
(``best_model.json``, ``model.json``), else those of this machine's constant training runs
(:func:`machine_training_span`), which every model of the comparison was fitted on.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rafi.method.rank import speed_training_runs
from rafi.report.format import NBSP, fmt_num, fmt_speed_range, isnum
from rafi.settings import MACHINE_DEFAULTS

__all__ = [
    "trained_speed_span",
    "trained_speeds_text",
    "outside_counts",
    "range_facts",
    "beyond_trained_speeds",
    "machine_training_span",
    "model_speed_span",
    "speed_counts",
    "model_speed_counts",
    "with_speed_counts",
    "stored_speed_counts",
    "speed_list",
    "adapted_speeds",
]


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


def range_facts(rows: pd.DataFrame | None, artefact, counts: pd.Series | None = None) -> dict | None:
    """:func:`outside_counts` of a model's rows with ``speeds`` (:func:`trained_speeds_text` of
    its artefact, ``""`` unknown); ``None`` without counts. ``counts``: the model's samples
    outside its trained speeds per run, recounted by the tolerance (:func:`speed_counts`), in
    place of the rows' own ``n_outside_speed_range`` (:func:`with_speed_counts`)."""
    counts = outside_counts(with_speed_counts(rows, counts))
    return None if counts is None else {**counts, "speeds": trained_speeds_text(artefact)}


def beyond_trained_speeds(speed_rpm, span, tolerance_rpm: float) -> np.ndarray:
    """Where a speed lies more than ``tolerance_rpm`` below or above the trained speeds ``span``.

    The rule of RAFI's own ``outside_speed_range`` flag and of the streaming compensator's
    (:func:`rafi.method.fuzzy.triangular_weights`, ``tolerance_rpm`` the machine's
    ``speed_tolerance_rpm``), applied to any model's trained range. Written out here, not
    imported: the report job runs no model code (``tests/test_report.py``);
    ``tests/test_report_trained_range.py`` holds it equal to ``triangular_weights``' flag.

    Parameters
    ----------
    speed_rpm : array_like
        Sample speeds (r/min); NaN is never beyond.
    span : tuple of float
        The lowest and highest trained speed (:func:`trained_speed_span`).
    tolerance_rpm : float
        The machine's ``speed_tolerance_rpm``.

    Returns
    -------
    numpy.ndarray of bool

    Examples
    --------
    >>> beyond_trained_speeds([18004.0, 18051.0, 0.0], (0.0, 18000.0), 50.0).tolist()
    [False, True, False]
    """
    lo, hi = float(min(span)), float(max(span))
    s = np.atleast_1d(np.asarray(speed_rpm, dtype=float))
    tol = float(tolerance_rpm)
    with np.errstate(invalid="ignore"):
        return np.isfinite(s) & ((s < lo - tol) | (s > hi + tol))


def machine_training_span(runs: pd.DataFrame | None) -> tuple[float, float] | None:
    """The lowest and highest speed of this machine's constant training runs (``runs.csv``,
    :func:`rafi.method.rank.speed_training_runs`): speeds every model of the comparison was
    trained at (RAFI as published at exactly these; the ridge kinds at these and the idle and
    varying training runs'; an adaptation also at its prior's); ``None`` without them."""
    if runs is None or not {"role", "speed_rpm"} <= set(runs.columns):
        return None
    speeds = pd.to_numeric(speed_training_runs(runs)["speed_rpm"], errors="coerce").dropna()
    return (float(speeds.min()), float(speeds.max())) if len(speeds) else None


def model_speed_span(res: dict, model_id) -> tuple[float, float] | None:
    """The trained speeds of the model with id ``model_id``: its artefact's
    (:func:`trained_speed_span` of ``best_model`` or ``model`` carrying that id), else this
    machine's constant training runs' (:func:`machine_training_span` of ``runs_csv``)."""
    for artefact in (res.get("best_model"), res.get("model")):
        if isinstance(artefact, dict) and model_id and str(artefact.get("model_id", "")) == str(model_id):
            span = trained_speed_span(artefact)
            if span is not None:
                return span
    return machine_training_span(res.get("runs_csv"))


def speed_counts(samples: pd.DataFrame | None, span, tolerance_rpm) -> pd.Series | None:
    """Per validation run, one model's samples outside its trained speeds by more than the tolerance.

    Parameters
    ----------
    samples : DataFrame or None
        The model's rows of ``comparison/residuals.parquet`` (or ``validation/residuals.parquet``):
        ``run_id``, ``speed_rpm``, ``residual_um``, ``outside_speed_range``.
    span : tuple of float or None
        Its trained speeds (:func:`model_speed_span`).
    tolerance_rpm : float or None
        The machine's ``speed_tolerance_rpm``.

    Returns
    -------
    pandas.Series or None
        ``run_id`` -> the samples with a residual (those ``n_outside_speed_range`` counts) that
        the model flagged outside its trained speeds and whose speed lies more than
        ``tolerance_rpm`` beyond ``span`` (:func:`beyond_trained_speeds`); ``None`` without the
        samples, their columns, a span or a tolerance (the stored counts then stand).
    """
    need = {"run_id", "speed_rpm", "residual_um", "outside_speed_range"}
    if samples is None or not need <= set(samples.columns) or span is None or not isnum(tolerance_rpm):
        return None
    ok = np.isfinite(pd.to_numeric(samples["residual_um"], errors="coerce").to_numpy(dtype=float))
    flagged = samples["outside_speed_range"].fillna(False).to_numpy(dtype=bool)
    speed = pd.to_numeric(samples["speed_rpm"], errors="coerce").to_numpy(dtype=float)
    out = ok & flagged & beyond_trained_speeds(speed, span, float(tolerance_rpm))
    return pd.Series(out.astype(int), index=samples.index).groupby(samples["run_id"].astype(str)).sum()


def model_speed_counts(res: dict, tolerance_rpm) -> dict[str, pd.Series]:
    """Model name -> :func:`speed_counts` of its samples in ``comparison/residuals.parquet``
    (``comparison_residuals``), its trained speeds by its id in ``comparison/summary.csv``
    (:func:`model_speed_span`); without the samples, for RAFI as published, its samples in
    ``validation/residuals.parquet`` (``residuals``) under the name ``rafi`` and ``model.json``'s
    speeds. Empty where nothing can be recounted (the stored counts then stand)."""
    out: dict[str, pd.Series] = {}
    samples, summary = res.get("comparison_residuals"), res.get("comparison")
    if samples is not None and "model" in samples and summary is not None and "model_id" in summary:
        ids = dict(zip(summary["model"].astype(str), summary["model_id"].astype(str)))
        for name, rows in samples.groupby(samples["model"].astype(str), sort=False):
            counts = speed_counts(rows, model_speed_span(res, ids.get(name)), tolerance_rpm)
            if counts is not None:
                out[name] = counts
        return out
    model = res.get("model")
    if isinstance(model, dict):
        counts = speed_counts(res.get("residuals"), trained_speed_span(model), tolerance_rpm)
        if counts is not None:
            out["rafi"] = counts
    return out


def with_speed_counts(rows: pd.DataFrame | None, counts: pd.Series | None) -> pd.DataFrame | None:
    """``rows`` (one model's rows of ``per_run.csv``, ``validation/summary.csv`` or its row of
    ``comparison/summary.csv``) with ``n_outside_speed_range`` from ``counts``
    (:func:`speed_counts`): per run where a row names a run the samples hold, the total over
    every run for a row of the whole model (no ``run_id``, or ``all``); unchanged without
    ``counts``."""
    if rows is None or counts is None or "n_outside_speed_range" not in rows:
        return rows
    out = rows.copy()
    if "run_id" in out:
        ids = out["run_id"].astype(str)
        whole = ids == "all"
        here = ids.isin(counts.index)
        out.loc[here, "n_outside_speed_range"] = ids[here].map(counts).astype(int)
        out.loc[whole, "n_outside_speed_range"] = int(counts.sum())
    else:
        out["n_outside_speed_range"] = int(counts.sum())
    return out


def stored_speed_counts(summary: pd.DataFrame | None, counts: dict) -> list[dict]:
    """The stored counts the recount replaced where they differ: the models whose
    ``n_outside_speed_range`` in ``comparison/summary.csv`` (the sum of their rows of
    ``per_run.csv``: each model's own ``outside_speed_range`` flag) is not their recounted total
    (``counts``: :func:`model_speed_counts`), grouped by that stored total.

    The ridge kinds' flag takes any sample beyond their training speeds, without the tolerance;
    it is not only a count (it widens the prediction interval: ``interval_cell`` ``outside``), so
    the models keep it and the report states the recount and the stored figure beside each other.

    Returns
    -------
    list of dict
        ``count`` (the stored total) and ``models`` (names, in the summary's order), one per stored
        total, in order of first appearance; ``[]`` when every recounted model agrees.
    """
    if summary is None or not counts or not {"model", "n_outside_speed_range"} <= set(summary.columns):
        return []
    groups: dict[int, list[str]] = {}
    for name, stored in zip(
        summary["model"].astype(str), pd.to_numeric(summary["n_outside_speed_range"], errors="coerce")
    ):
        if name in counts and isnum(stored) and int(stored) != int(counts[name].sum()):
            groups.setdefault(int(stored), []).append(name)
    return [{"count": count, "models": names} for count, names in groups.items()]


def speed_list(values) -> str:
    """Speeds one by one, as the report writes a list: ``3 000 and 18 000 r/min``, ``6 000, 9 000,
    12 000 and 15 000 r/min``; ``""`` for none. A list, never a range: the speeds between were
    not run."""
    words = [fmt_num(float(v), 0) for v in values or [] if isnum(v)]
    if not words:
        return ""
    joined = words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]
    return f"{joined}{NBSP}r/min"


def adapted_speeds(
    artefact, rest_below_rpm: float = MACHINE_DEFAULTS["runs"]["idle_below_rpm"]
) -> dict | None:
    """The speeds of a model adapted from a prior, each said as what it is.

    From the ``adaptation.fitness`` block (:func:`rafi.family.prior_fitness.fitness_block`; its
    stored keys are read, not changed): the speeds this machine's new training runs tested
    (``speeds_tested_rpm``), a rest among them said as the machine at rest - an idle training run,
    a cool-down - not as a speed tested between the others, and the prior's speeds no new run
    tested (``speeds_prior_only_rpm``).

    Parameters
    ----------
    artefact : dict or None
        The model's artefact (``comparison/best_model.json``).
    rest_below_rpm : float
        Below this a tested speed is the machine at rest (``runs.idle_below_rpm``).

    Returns
    -------
    dict or None
        ``tested`` (the running speeds tested here, :func:`speed_list`), ``rest`` (the new
        training runs include the machine at rest), ``tested_text`` (both in words: ``3 000 and
        18 000 r/min and the machine at rest (0 r/min, a cool-down)``), ``prior_only``
        (:func:`speed_list`; ``""`` none), ``prior`` (the prior's speeds, a list; ``""``
        unknown), ``prior_range`` (the prior's range, ``3 000–18 000 r/min``; ``""`` unknown) and
        ``span`` (the running speeds the model was trained at, here and by the prior, as a range);
        ``None`` for a model not adapted from a prior.
    """
    adaptation = artefact.get("adaptation") if isinstance(artefact, dict) else None
    fit = adaptation.get("fitness") if isinstance(adaptation, dict) else None
    if not isinstance(fit, dict) or fit.get("speeds_tested_rpm") is None:
        return None
    tested = [float(v) for v in fit.get("speeds_tested_rpm") or [] if isnum(v)]
    running = [v for v in tested if abs(v) >= float(rest_below_rpm)]
    rest = [v for v in tested if abs(v) < float(rest_below_rpm)]
    words = [speed_list(running)] if running else []
    if rest:
        words.append(f"the machine at rest ({speed_list(rest[:1])}, a cool-down)")
    prior_range = [float(v) for v in fit.get("speed_range_prior_rpm") or [] if isnum(v)]
    known = running + prior_range + [float(v) for v in fit.get("speeds_prior_rpm") or [] if isnum(v)]
    return {
        "tested": speed_list(running),
        "rest": bool(rest),
        "tested_text": " and ".join(words) or "none",
        "prior_only": speed_list(fit.get("speeds_prior_only_rpm")),
        "prior": speed_list(fit.get("speeds_prior_rpm")),
        "prior_range": fmt_speed_range(*prior_range) if len(prior_range) == 2 else "",
        "span": fmt_speed_range(min(known), max(known)) if known else "",
    }
