"""Section "The model offered to the machine: <kind>": the comparison's champion in full.

Computed from this machine's results only: the champion of ``comparison/summary.csv`` (chosen by
whole-run CV on the training runs), its artefact ``comparison/best_model.json`` (the file the
registry judges and the compensator runs), ``comparison/cv.csv`` and ``per_run.csv``. The
section lists what the model reads, the equation and every coefficient exactly as the artefact
stores them (shortest round-trip decimal: the written table *is* the model), what CV chose and
the validation result of every validation run; the residual plots are files of rule
``report_figures`` (group ``comparison``, :func:`deployed_panels` says which runs, in which
order). Nothing is evaluated or drawn here.
"""

from __future__ import annotations

import importlib
import re

import numpy as np
import pandas as pd

from rafi.family.features import sensors_left_out
from rafi.family.forward_folds import MIN_TRAIN, horizon_of
from rafi.family.ridge import fit_rows_of
from rafi.family.time_blocks import SCHEME as TIME_BLOCKS
from rafi.family.time_blocks import hours
from rafi.report.comparison_section import cv_schemes, family_champion, forward_mask, selection_score
from rafi.report.deployed_terms import (
    rafi_equation,
    rafi_inputs,
    rafi_tables,
    ridge_equation,
    ridge_inputs,
    ridge_tables,
)
from rafi.report.ensemble_section import ensemble_context
from rafi.report.format import fmt_num, fmt_sig, fmt_speed, isnum, plain, run_speeds, short_id, truthy
from rafi.report.inputs import model_noise_floors, noise_floors
from rafi.report.intervals import (
    band_columns,
    band_label,
    coverage_fields,
    has_band,
    interval_block,
    interval_context,
)
from rafi.report.trained_range import adapted_speeds
from rafi.report.verdict import placement

UM = "\u00b5m"

#: Where each kind's class lives (its docstring is the kind's own description).
KIND_CLASSES = {
    "rafi": ("rafi.family.published", "PublishedRafi"),
    "rafi_linear": ("rafi.family.rafi_linear", "RafiLinear"),
    "ridge_global": ("rafi.family.ridge_global", "RidgeGlobal"),
    "dynamic": ("rafi.family.dynamic", "DynamicRidge"),
    "grey_box": ("rafi.family.grey_box", "GreyBox"),
    "temperature_ridge": ("rafi.family.temperature_ridge", "TemperatureRidge"),
}

#: What the section says an offered ensemble is (its class has no kind description of one kind).
ENSEMBLE_DESCRIPTION = (
    "The CV-weighted ensemble: the weighted mean of the predictions of the family's kinds, each "
    "weighted by its whole-run cross-validation score on the training runs (models: offer: ensemble)."
)

#: What the section says an ensemble adapted from a prior as a whole is.
ADAPTED_ENSEMBLE_DESCRIPTION = (
    "The ensemble prior adapted as a whole: the weighted mean of the predictions of the prior's "
    "members as this run moved them, with the prior's weights (from its own qualification)."
)

#: At most this many validation runs per residual figure (3 rows of 2 panels: one page).
RUNS_PER_FIGURE = 6


def kind_description(kind: str) -> str:
    """The first paragraph of the kind's class docstring, as plain text (``""`` if unknown)."""
    where = KIND_CLASSES.get(kind)
    if where is None:
        return ""
    doc = getattr(importlib.import_module(where[0]), where[1]).__doc__ or ""
    first = " ".join(doc.strip().split("\n\n")[0].split())
    first = re.sub(r"^Kind ``[^`]+``:\s*", "", first)
    first = re.sub(r":[a-z]+:`~?([^`]+)`", lambda m: m.group(1).rsplit(".", 1)[-1], first)
    text = first.replace("``", "")
    return text[:1].upper() + text[1:]


def deployed_figure_key(k: int) -> str:
    """Key of the ``k``-th (1-based) residual figure of the offered model (group ``comparison``)."""
    return f"deployed/residuals/{k}"


def offered_name(summary: pd.DataFrame | None):
    """Name of the model offered to the machine (the comparison's champion), or ``None``."""
    if summary is None or not len(summary):
        return None
    return family_champion(summary.assign(model=summary["model"].astype(str)))


def deployed_panels(summary, per_run, residuals, noise: dict | None = None) -> list[list[dict]]:
    """The residual panels of the offered model, grouped into figures of at most
    :data:`RUNS_PER_FIGURE`: per validation run (``per_run.csv`` order, idle cool-downs
    included) ``run_id``, ``role``, ``before`` / ``after`` (max |dz|, max |residual|, um),
    ``noise_floor`` (um or NaN: the run's, ``noise`` of :func:`rafi.report.inputs.noise_floors`;
    without it ``per_run.csv``'s) and ``frame`` (``t_s``, ``measured_um``, ``residual_um``; with
    ``lower_um``, ``upper_um``, ``predicted_um`` where the results hold the interval)."""
    name = offered_name(summary)
    if name is None or per_run is None or residuals is None or not len(residuals):
        return []
    pr = per_run[per_run["model"].astype(str) == name]
    res = residuals[residuals["model"].astype(str) == name]
    panels = []
    for r in pr.to_dict("records"):
        rid = str(r["run_id"])
        f = res[res["run_id"].astype(str) == rid].sort_values("t_s")
        if not len(f):
            continue
        floor = r.get("noise_floor_um") if noise is None else noise.get(rid)
        panels.append(
            {
                "run_id": rid,
                "role": str(r.get("role", "")),
                "before": float(r.get("max_abs_before_um", np.nan)),
                "after": float(r.get("max_abs_after_um", np.nan)),
                "noise_floor": float(floor) if isnum(floor) else np.nan,
                "frame": f[["t_s", "measured_um", "residual_um", *band_columns(f)]].reset_index(drop=True),
            }
        )
    return [panels[i : i + RUNS_PER_FIGURE] for i in range(0, len(panels), RUNS_PER_FIGURE)]


def _of_model(table, name):
    """The rows of model ``name`` in a comparison table (``None`` without the table)."""
    if table is None or "model" not in table:
        return None
    return table[table["model"].astype(str) == name]


# ---------------------------------------------------------------------------- CV
def _hyper_text(art: dict) -> list[tuple[str, str]]:
    """``(hyperparameter, value chosen, from)`` of the artefact's ``selected``."""
    sel = art.get("selected") or {}
    grids = sel.get("grids") or {}
    out = []

    def grid(name):
        g = grids.get(name)
        return ", ".join(fmt_num(v, 0) for v in g) if g else ""

    if "alpha" in sel:
        g = grids.get("alpha") or []
        span = f"{len(g)} values {fmt_sig(min(g), 2)} \u2026 {fmt_sig(max(g), 2)}" if g else ""
        out.append(("ridge penalty alpha", fmt_sig(sel["alpha"], 3), span))
    kind = art.get("kind")
    if kind == "dynamic":
        out.append(
            (
                "rise filter constants (s)",
                ", ".join(fmt_num(t, 0) for t in sel.get("taus_s", [])),
                grid("dynamic_taus_s"),
            )
        )
    if kind == "temperature_ridge":
        taus = ", ".join(fmt_num(t, 0) for t in sel.get("taus_s", []))
        out.append(("rise filter constants (s)", taus, "fixed, every one at once (no speed input)"))
    if kind == "grey_box":
        search = (art.get("hyperparameters") or {}).get("filter_search", "")
        out.append(
            (
                "rise filter constants (s)",
                ", ".join(fmt_num(t, 0) for t in sel.get("taus_s", [])),
                grid("grey_box_taus_s") + (" (all at once: filter_search all)" if search == "all" else ""),
            )
        )
        st = sel.get("speed_taus_s") or []
        out.append(
            (
                "heat-input filter constants (s)",
                ", ".join(fmt_num(t, 0) for t in st) if st else "none (the heat-input block left out)",
                grid("grey_box_speed_taus_s") + (" (the block in or out)" if search == "all" else ""),
            )
        )
        if sel.get("instantaneous_n2"):
            out.append(
                (
                    "draw-in lag (s)",
                    fmt_num(sel.get("centrifugal_lag_s"), 0),
                    grid("grey_box_centrifugal_lags_s"),
                )
            )
        else:
            out.append(
                (
                    "draw-in n\u00b2 term",
                    "not used (not identified: fewer than 2 training runs step from their reference speed)",
                    "",
                )
            )
    if kind in ("ridge_global", "dynamic"):
        out.append(("speed-dependent gains dT\u00b7n", "used" if sel.get("speed_gain") else "not used", ""))
        out.append(
            (
                "speed terms n \u2212 n\u2080, n\u00b2 \u2212 n\u2080\u00b2",
                "used" if sel.get("speed_terms") else "not used (not identified)",
                "",
            )
        )
    return out


def _nothing_chosen(text) -> str:
    """``summary.csv``'s ``selected`` of a model without hyperparameters, without its lead words:
    ``nothing to choose (one OLS per training speed, fuzzy blend)`` -> ``one OLS per ...``."""
    if not isinstance(text, str):
        return ""
    m = re.fullmatch(r"\s*nothing to choose\s*\((.*)\)\s*", text)
    return m.group(1) if m else text


#: ``cv.csv`` columns of a fold as the section lists them.
_FOLD_FIELDS = ("max_abs_before_um", "max_abs_after_um", "rmse_um")
#: ``summary.csv`` columns of a candidate the model beat.
_SCORE_FIELDS = (
    "selection_score_um",
    "cv_mean_max_abs_um",
    "cv_forward_mean_max_abs_um",
    "cv_max_abs_um",
    "selection_rank",
)


def _folds_of(cv: pd.DataFrame | None, name: str) -> tuple[list[dict], list[dict]]:
    """Model ``name``'s rows of ``cv.csv``: the whole-run folds and, apart, the forward folds
    (with the fold and how many training runs before it the fold was trained on)."""
    if cv is None or not len(cv) or "model" not in cv:
        return [], []
    mine = cv[cv["model"].astype(str) == name]
    forward = forward_mask(mine)
    whole = [
        {**_fields(r, _FOLD_FIELDS), "test_runs": r.get("test_runs", "")}
        for r in mine[~forward].to_dict("records")
    ]
    ahead = [
        {**_fields(r, (*_FOLD_FIELDS, "fold", "n_train_runs")), "test_runs": r.get("test_runs", "")}
        for r in mine[forward].to_dict("records")
    ]
    return whole, ahead


def _cv_context(art: dict, summary: pd.DataFrame, cv: pd.DataFrame | None, name: str) -> dict:
    """What CV chose: the model's own (inner) choice, the outer score that made it the
    champion (the selection score; with forward folds the mean of the whole-run and the forward
    score, both shown), the candidates it beat (by that score), and its folds (whole-run, and
    the forward folds apart)."""
    hyper = art.get("hyperparameters") or {}
    inner = art.get("cv") or []
    scores = [float(r["score_um"]) for r in inner if isnum(r.get("score_um"))]
    s = summary.assign(model=summary["model"].astype(str))
    s = s.assign(_score=pd.to_numeric(s.apply(selection_score, axis=1), errors="coerce"))
    me = s[s["model"] == name].iloc[0]
    if "candidate" in s:  # the plain ridge scored as the reference only was no candidate
        s = s[s["candidate"].map(truthy) | (s["model"] == name)]
    others = [
        {**_fields(r | {"selection_score_um": r["_score"]}, _SCORE_FIELDS), "model": r["model"]}
        | {"rafi": str(r.get("kind")) == "rafi"}
        for r in s.sort_values("_score", na_position="last", kind="stable").to_dict("records")
        if r["model"] != name
    ]
    folds, forward_folds = _folds_of(cv, name)
    whole_scheme, forward_scheme = cv_schemes(cv)
    scheme = whole_scheme.replace("_", "-")
    metric = str(hyper.get("cv_metric", ""))
    blocks = (art.get("selected") or {}).get("cv_folds")
    unit = "blocks" if blocks else "runs"
    return {
        "hyper": [dict(zip(("chosen", "value", "grid"), r)) for r in _hyper_text(art)] or None,
        "inner_metric": {
            "rmse": f"the pooled RMSE of the held-out {unit}",
            "max_abs": f"the mean over held-out {unit} of the max |residual|",
        }.get(metric, metric),
        # time-blocked folds (rafi.family.time_blocks): how, for people; None for whole runs
        "time_blocks": (
            f"{blocks['blocks']} blocks of the training time, {hours(blocks['gap_s'])} guard gaps, "
            f"filters up to {blocks['max_filter_s']:g} s"
        )
        if blocks
        else None,
        # what a fold of the outer CV (comparison/cv.csv) holds out: a time block or a run
        "held_unit": "block" if scheme == TIME_BLOCKS.replace("_", "-") else "run",
        "inner_scheme": str(hyper.get("cv", "")).replace("_", "-"),
        "inner_n": len(inner),
        "selected": _nothing_chosen(me.get("selected")),
        "inner_best": fmt_num(min(scores), 3, UM) if scores else "",
        "edges": list((art.get("selected") or {}).get("grid_edges") or []),
        "score": fmt_num(me["_score"], 2, UM),
        "whole_score": fmt_num(me.get("cv_mean_max_abs_um"), 2, UM),
        # the forward folds (rafi.family.forward_folds): runs each holds out, 0 without them
        "horizon": horizon_of(forward_scheme) if forward_scheme and forward_folds else 0,
        "forward_score": fmt_num(me.get("cv_forward_mean_max_abs_um"), 2, UM),
        "min_train": MIN_TRAIN,
        "worst": fmt_num(me.get("cv_max_abs_um"), 2, UM),
        "n_models": len(s),
        "scheme": scheme,
        "beaten": others or None,
        "folds": folds or None,
        "forward_folds": forward_folds or None,
        "n_forward_folds": len({r["fold"] for r in forward_folds}),
    }


# ---------------------------------------------------------------------------- section
def _fields(row: dict, keys) -> dict:
    """``keys`` of a frame's row as plain values, ``None`` for a missing one."""
    return {k: plain(row.get(k)) for k in keys}


def _validation_rows(
    per_run: pd.DataFrame | None, name: str, runs: pd.DataFrame | None = None, noise: dict | None = None
) -> list[dict] | None:
    """``per_run.csv``'s rows of model ``name`` (``passed`` as a bool), ``None`` without it; each
    with its ``speed`` as every section prints it (:func:`rafi.report.format.fmt_run_speed` of its
    row of ``runs``, ``runs.csv``: a varying run's range, not the median speed of ``per_run.csv``;
    that median only for a run ``runs.csv`` does not hold) and the run's ``noise_floor_um``
    (``noise``: :func:`rafi.report.inputs.noise_floors`; without it ``per_run.csv``'s)."""
    if per_run is None or not len(per_run):
        return None
    keys = ("speed_rpm", "max_abs_before_um", "max_abs_after_um", "noise_floor_um", "rmse_after_um")
    speeds = run_speeds(runs)
    return [
        {**_fields(r, keys), "run_id": r["run_id"], "role": str(r.get("role", ""))}
        | ({} if noise is None else {"noise_floor_um": noise.get(str(r["run_id"]))})
        | {"speed": speeds.get(str(r["run_id"])) or fmt_speed(r.get("speed_rpm"))}
        | {"passed": truthy(r.get("passed", False))}
        | coverage_fields(r)
        for r in per_run[per_run["model"].astype(str) == name].to_dict("records")
    ]


def unpredicted_rows(per_run: pd.DataFrame | None, name: str) -> list[dict]:
    """The validation runs on which model ``name`` gave no value for some measured samples
    (``per_run.csv``'s ``n_unpredicted`` > 0): ``run_id``, ``n`` (those samples), ``n_scored``
    (the samples its figures are over) and ``inputs`` (what had no value there, may be ``""``)."""
    if per_run is None or not len(per_run) or "n_unpredicted" not in per_run.columns:
        return []
    rows = per_run[(per_run["model"].astype(str) == name) & (per_run["n_unpredicted"].fillna(0) > 0)]
    return [
        {
            "run_id": str(r["run_id"]),
            "n": int(r["n_unpredicted"]),
            "n_scored": int(r["n_samples"]),
            "inputs": "" if pd.isna(r.get("unpredicted_inputs")) else str(r.get("unpredicted_inputs")),
        }
        for r in rows.to_dict("records")
    ]


def sensors_left_out_text(art: dict, runs_table, runs_frame) -> str:
    """The sensors of the data a ridge artefact does not read, each with the reason
    (:func:`rafi.family.features.sensors_left_out` on the rows its fit used), e.g.
    ``"T5: missing on 7.2 % of the rows; T12: constant"``; ``""`` when every sensor is read, the
    sensors were named in the settings or chosen on a prior's data (an adapted prior), or the
    samples are not at hand."""
    named = (art.get("hyperparameters") or {}).get("sensors") or art.get("adaptation")
    if runs_table is None or runs_frame is None or named:
        return ""
    try:
        _, frame, rows = fit_rows_of(runs_table, runs_frame)
    except (KeyError, ValueError):  # no training run in these tables: nothing to say
        return ""
    used = set(art.get("key_sensors") or [])
    reasons = sensors_left_out(frame.loc[rows])
    return "; ".join(f"{s}: {why}" for s, why in reasons.items() if s not in used)


def _speed_span(speeds) -> str:
    """The trained speed range ``[lo, hi]`` as the section writes it (``3 000 … 18 000 r/min``);
    one speed once (``3 000 r/min``); an en dash for none."""
    if not speeds:
        return "\u2013"
    lo, hi = fmt_num(speeds[0], 0), fmt_num(speeds[1], 0)
    return f"{lo} r/min" if lo == hi else f"{lo} \u2026 {hi} r/min"


def _adapted_span(art: dict) -> str | None:
    """An adapted prior's speeds, each said as what it is (:func:`rafi.report.trained_range.adapted_speeds`):
    those the new training runs tested, a list (a rest among them: the machine at rest, a
    cool-down), and those the prior alone covers, with the prior's range; ``None`` for any other
    model."""
    sp = adapted_speeds(art)
    if sp is None:
        return None
    text = f"tested here {sp['tested_text']}"
    if sp["prior_only"]:
        text += f"; covered by the prior alone {sp['prior_only']}"
    if sp["prior_range"]:
        text += (
            f" (the prior's range {sp['prior_range']})"
            if sp["prior_only"]
            else f"; the prior's range {sp['prior_range']}"
        )
    return text


def section_deployed(res: dict, figs, champion_after=None) -> dict | None:
    """The section's context, or ``None`` without a comparison champion and its artefact.

    Parameters
    ----------
    res : dict
        Loaded inputs: ``comparison``, ``comparison_per_run``, ``comparison_cv``,
        ``best_model`` (``comparison/best_model.json``), ``model`` (RAFI's ``model.json``,
        used if the champion is RAFI as published and ``best_model`` is absent).
    figs : rafi.report.embed.FigureFiles
        The figure files (group ``comparison``: :func:`deployed_figure_key`).
    champion_after : str, optional
        The model id on the machine after this run (``registry/decision.json``); where the model
        stands after the decision (``res["decision"]``): :func:`rafi.report.verdict.placement`.
    """
    summary = res.get("comparison")
    name = offered_name(summary)
    if name is None:
        return None
    row = summary[summary["model"].astype(str) == name].iloc[0]
    mid = str(row.get("model_id", ""))
    art = next(
        (
            c
            for c in (res.get("best_model"), res.get("model"))
            if isinstance(c, dict) and str(c.get("model_id", "")) == mid
        ),
        None,
    )
    if art is None:
        return None
    kind = str(art.get("kind", row.get("kind", "")))
    rafi_like = kind in ("rafi", "rafi_linear")
    ensemble = ensemble_context(art, summary, *cv_schemes(res.get("comparison_cv")))
    if ensemble is not None:
        parts = _ensemble_parts(art, ensemble)
    else:
        parts = _rafi_parts(art) if rafi_like else _ridge_parts(art, res)
    blocks, terms, equation, inputs = parts["blocks"], parts["terms"], parts["equation"], parts["inputs"]
    train_runs = parts["train_runs"]
    noise = noise_floors(res)
    validation = _validation_rows(res.get("comparison_per_run"), name, res.get("runs_csv"), noise)
    figures = _figures(figs)
    placed = placement(res.get("decision"), mid, champion_after)
    return {
        "name": name,
        "kind": kind,
        "model_id": mid,
        "short_id": short_id(mid),
        "description": (
            kind_description(kind)
            if ensemble is None
            else ADAPTED_ENSEMBLE_DESCRIPTION
            if ensemble["adapted"]
            else ENSEMBLE_DESCRIPTION
        ),
        "inputs_text": str(art.get("inputs", "")) or parts.get("inputs_text", ""),
        "ensemble": ensemble,
        "inputs": [{"input": a, "how": b} for a, b in inputs],
        "train_runs": ", ".join(train_runs),
        "n_train": len(train_runs),
        "speeds": _adapted_span(art) or _speed_span(parts["speeds"]),
        "rises": parts["rises"],
        "n_terms": len(terms),
        "equation": equation,
        "blocks": blocks,
        "terms": terms,
        "rmse": fmt_num(art.get("rmse_um"), 3, UM) if not rafi_like else "",
        "n_fit": fmt_num(parts["n_fit"], 0),
        "cv": _cv_context(art, summary, res.get("comparison_cv"), name),
        "passed": truthy(row.get("passed", False)),
        "worst": fmt_num(row.get("max_abs_after_um"), 2, UM),
        "worst_noise": fmt_num(model_noise_floors(res).get(name), 2, UM),
        "validation": validation,
        "unpredicted": unpredicted_rows(res.get("comparison_per_run"), name),
        "n_runs": len(validation or []),
        "figures": figures,
        **placed,
        "champion_after": short_id(champion_after) if champion_after else "",
        "rafi_like": rafi_like,
        "interval": interval_context(art),
        "band_label": band_label((interval_block(art) or {}).get("level")),
        "band": has_band(_of_model(res.get("comparison_residuals"), name)),
        "coverage": any(r["coverage_pct"] is not None for r in validation or []),
        "coverage_all": coverage_fields(row),
    }


def _rafi_parts(art: dict) -> dict:
    """What the section shows of RAFI's artefact (one model per training speed): its tables,
    equation, inputs, speed span, rises seen in training, training runs and rows."""
    blocks, terms = rafi_tables(art)
    speeds = art.get("speeds") or []
    span = art.get("speed_range_rpm")
    if span is None and speeds:
        sp = [float(s["speed_rpm"]) for s in speeds]
        span = [min(sp), max(sp)]
    rng = {}
    for s in speeds:
        for k, (lo, hi) in (s.get("regressor_ranges") or {}).items():
            a, b = rng.get(k, (np.inf, -np.inf))
            rng[k] = (min(a, lo), max(b, hi))
    return {
        "blocks": blocks,
        "terms": terms,
        "equation": rafi_equation(art),
        "inputs": rafi_inputs(art),
        "speeds": span,
        "rises": ", ".join(f"{k} {fmt_num(v[0], 1)} \u2026 {fmt_num(v[1], 1)}" for k, v in rng.items()),
        "train_runs": [str(r) for s in speeds for r in s.get("train_runs") or []],
        "n_fit": sum(int(s.get("n") or 0) for s in speeds),
    }


def _ensemble_parts(art: dict, ensemble: dict) -> dict:
    """What the section shows of an ensemble's artefact (:mod:`rafi.family.ensemble`): no
    coefficients of its own (each member's are its own), the blend as its equation, the union of
    the members' sensors and speeds."""
    sensors = ", ".join(str(s) for s in art.get("key_sensors") or [])
    return {
        "blocks": [],
        "terms": [],
        "equation": [ensemble["equation"]],
        "inputs": [("temperature sensors (any member's)", sensors), ("members", str(ensemble["n"]))],
        "inputs_text": f"temperature sensors {sensors} and the spindle speed, each member its own",
        "speeds": art.get("speed_range_rpm"),
        "rises": "as each member was trained",
        "train_runs": [str(r) for r in art.get("train_runs") or []],
        "n_fit": None,
    }


def _ridge_parts(art: dict, res: dict) -> dict:
    """What the section shows of a ridge-like artefact (one model for every speed): as
    :func:`_rafi_parts`, and the sensors its training rows left out."""
    blocks, terms = ridge_tables(art)
    inputs = ridge_inputs(art)
    left_out = sensors_left_out_text(art, res.get("runs_csv"), res.get("runs_parquet"))
    if left_out:
        inputs.insert(1, ("sensors left out (training rows)", left_out))
    return {
        "blocks": blocks,
        "terms": terms,
        "equation": ridge_equation(art),
        "inputs": inputs,
        "speeds": art.get("speed_range_rpm"),
        "rises": "in the last column of the temperature terms",
        "train_runs": [str(r) for r in art.get("train_runs") or []],
        "n_fit": art.get("n"),
    }


def _figures(figs) -> list:
    """The section's figure files, numbered from 1 (:func:`deployed_figure_key`) until one is missing."""
    figures = []
    while (f := figs.get("comparison", deployed_figure_key(len(figures) + 1))) is not None:
        figures.append(f)
    return figures
