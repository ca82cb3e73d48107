"""Selection rules judged one level up: an outer whole-run CV over the training runs.

Usage (from the repository root; see benchmarks/README.md)::

    python benchmarks/bench_selection_rules.py --project /tmp/rd/ch3-windows --project /tmp/twins

Each ``--project`` is a Snakemake project that has run (``config.yaml`` and
``results/<machine>/`` with ``runs.csv``, ``runs.parquet``, ``rank/key_sensors.json`` and
``comparison/cv.csv``): the folders ``bench_realdata.py --keep DIR`` leaves, or a copy of this
project after ``snakemake --cores 2`` (the twin machines). Every machine under ``results/`` is
judged (``--machines`` to pick some).

**Why one level up.** The champion is chosen by the whole-run CV of the training runs
(``comparison/cv.csv``); whether a *rule* that chooses from those CV scores is good is itself a
question of generalisation, and the honest judge is the same CV one level up, on the training
runs only (validation and test rows are never read here):

* outer folds: each training run ``r`` is held out in turn (leave one run out);
* on the other training runs the rule sees an **inner** whole-run CV of every enabled kind
  (:func:`rafi.family.crossval.cross_validate` on the runs table with ``r`` out of the training
  role; each kind still chooses its own hyperparameters by its own CV inside every fit) and
  picks a kind;
* the picked kind is scored on ``r`` by the model of that kind fitted on all the other training
  runs: exactly the row of ``comparison/cv.csv`` that holds ``r`` out (the pipeline's own
  numbers; its scheme must be ``leave_one_run_out``).

The outer score of a rule is the mean over the outer folds of the max |residual| of its pick
(the loss the gates judge, the same as the current selection score), with the pooled RMSE
beside it; ``oracle`` is the best kind per outer fold (a floor no rule can beat) and
``paired`` the mean and standard error of the per-fold difference to the current rule.

The rules (:data:`RULES`), every one a function of training-run CV rows alone:

* ``mean_max`` (the rule before the forward folds, :func:`rafi.family.selection.choose_champion` on
  whole-run rows): the lowest mean over the held-out runs of the max |residual|;
* ``mean_max_forward`` (the current rule: the same function on the whole-run and the forward
  rows, :data:`FORWARD`): the lowest mean of the whole-run and the forward scores where the inner
  training runs give forward folds (in a continuous log, at least 5 of them), else ``mean_max``;
* ``mean_plus_se``: the lowest mean + one standard error of the fold scores (sample standard
  deviation over sqrt(folds)): an upper confidence bound on the CV loss, so a kind that is
  good on most folds and very bad on one loses to a kind that is steady;
* ``one_se_simplest``: the one-standard-error rule, towards the simpler kind
  (:data:`rafi.family.selection.SIMPLICITY`) among those whose mean is within one standard
  error of the best mean;
* ``ridge_floor`` (issue 46): the plain ridge ``temperature_ridge`` unless a kind beats it by
  more than one standard error of the paired fold difference (:func:`rule_ridge_floor`; the
  current rule without the plain ridge among the kinds);
* ``without_<KIND>`` (with ``--without KIND``): the current rule on the same inner CV rows
  without that kind, so its paired difference to ``mean_max_forward`` says whether the kind
  earns its place in the family (without minus with);
* ``speed_folds``: ``mean_max`` on other inner folds, one per training speed with the
  cool-downs that follow its runs (:func:`speed_with_cooldown_folds`): folds that look like a
  validation at an unseen speed followed by its cool-down;
* ``cv_weighted_ensemble`` (not a choice of one kind): the product's ensemble, the weighted mean
  of its members' predictions (every kind but RAFI's two, and the plain ridge), weights
  proportional to 1 / (inner CV mean max |residual|)^2 (:func:`ensemble_weights`); scored on
  the held-out run from refits of every kind on the outer-training runs
  (:func:`held_out_predictions`, checked against ``comparison/cv.csv``);
* ``stacked`` (the super learner, not a choice of one kind): weights ``w >= 0``, ``sum w = 1``
  minimising the squared error of the weighted inner out-of-fold predictions (:mod:`_stacking`:
  the inner whole-run and forward folds of :data:`STACK_SCHEMES`, each scheme weighing the same
  and each held-out unit the same within it; a kind with no finite OOF prediction on a held-out
  unit gets 0, a sample where an entering kind is NaN is left out of the fit),
  the OOF samples coming from the same inner fits as the rules' CV rows (``cross_validate``
  with ``oof=``, as the pipeline's ``rule compare``); scored like the ensemble;
* ``average_within_se`` (issue 46, not a choice of one kind): the plain mean of the predictions
  of the kinds whose inner CV mean is within one standard error of the best
  (:func:`within_se_weights`); scored like the ensemble;
* ``cv_weighted_median`` (2026-11-29, issue 46): ``cv_weighted_ensemble``'s weights, the weighted
  median of the predictions (:func:`blend_median`) instead of their mean: robust to a member
  that runs away; scored like the ensemble.

The scores of every rule on the machine's full training CV (what it would offer now) are
printed beside (for ``stacked``: its weights on the full training CV, whose rows the bench
recomputes and checks against ``comparison/cv.csv``). Paired differences are given to
``mean_max`` and to the current rule ``mean_max_forward``. Output: a table per machine,
``benchmarks/results/selection_rules.json`` and ``selection_rules.md``. It reads the data and
settings of each project and refits the family about 10 times per training run; minutes per
machine.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import functools
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / "benchmarks"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from _results import write_results  # noqa: E402
from _stacking import stacked_weights  # noqa: E402

from rafi.contract import RESULT_FILES  # noqa: E402
from rafi.family import crossval  # noqa: E402
from rafi.family.compare import make_model  # noqa: E402
from rafi.family.ensemble import cv_weights, ensemble_members  # noqa: E402
from rafi.family.feature_memo import sharing_features  # noqa: E402
from rafi.family.forward_folds import configured_scheme, is_forward  # noqa: E402
from rafi.family.interval_fit import stacked_oof  # noqa: E402
from rafi.family.plain_ridge import PLAIN_RIDGE  # noqa: E402
from rafi.family.selection import SIMPLICITY, choose_champion  # noqa: E402
from rafi.family.whole_log import rows_of_logs  # noqa: E402
from rafi.settings import MACHINE_DEFAULTS, machine_settings  # noqa: E402

#: The role of the outer held-out run in the tables the inner CV sees: not training, not scored.
OUTER = "outer_held_out"
SPEED_SCHEME = "speed_with_cooldown"
ENSEMBLE = "cv_weighted_ensemble"
STACKED = "stacked"
AVERAGE = "average_within_se"
#: The CV-weighted ensemble's weights with the weighted median of the members instead of their mean.
MEDIAN = "cv_weighted_median"
#: The rules that are not a choice of one kind (scored from refits of every kind).
BLENDS = (ENSEMBLE, STACKED, AVERAGE, MEDIAN)


# ----------------------------------------------------------------------------- inner folds


def speed_with_cooldown_folds(runs_table: pd.DataFrame, tolerance_rpm: float = 50.0):
    """One fold per training speed: its runs and every idle training run that directly follows
    one of them in time (the cool-down after it). An idle run with no run before it is a fold
    of its own. Yields ``(train_ids, test_ids)`` like :func:`rafi.family.crossval.leave_one_speed_out`."""
    t = runs_table.loc[runs_table["role"].astype(str) == "training"].sort_values("start_s", kind="stable")
    groups: list[tuple[float | None, list[str]]] = []
    current = None
    for rid, speed, kind in zip(t["run_id"].astype(str), t["speed_rpm"].astype(float), t["kind"].astype(str)):
        if kind == "idle" or not speed > 0:
            if current is None:
                groups.append((None, [rid]))
            else:
                current[1].append(rid)
            continue
        current = next((g for g in groups if g[0] is not None and abs(g[0] - speed) <= tolerance_rpm), None)
        if current is None:
            current = (speed, [rid])
            groups.append(current)
        else:
            current[1].append(rid)
    ids = list(t["run_id"].astype(str))
    for _, test in groups:
        train = [r for r in ids if r not in test]
        if train:
            crossval.assert_disjoint(train, test)
            yield train, list(test)


@contextlib.contextmanager
def extra_scheme(name: str, splitter):
    """``name`` known to :func:`rafi.family.crossval.split_runs` while the block runs (the
    experiment's own folds; the pipeline's schemes are untouched afterwards)."""
    crossval.SCHEMES[name] = splitter
    try:
        yield
    finally:
        crossval.SCHEMES.pop(name, None)


# ----------------------------------------------------------------------------- the rules


def fold_stats(cv: pd.DataFrame) -> pd.DataFrame:
    """Per model: folds, mean and standard error of the max |residual| over held-out runs
    (infinite when a fold has no finite score), pooled RMSE; sorted by name."""
    rows = []
    for name, g in cv.groupby(cv["model"].astype(str)):
        mx = pd.to_numeric(g["max_abs_after_um"], errors="coerce").to_numpy(dtype=float)
        rmse = pd.to_numeric(g["rmse_um"], errors="coerce").to_numpy(dtype=float)
        ok = len(mx) > 1 and np.isfinite(mx).all()
        rows.append(
            {
                "model": name,
                "folds": len(mx),
                "mean": float(mx.mean()) if ok else np.inf,
                "se": float(mx.std(ddof=1) / np.sqrt(len(mx))) if ok else np.inf,
                "rmse": float(np.sqrt(np.mean(rmse**2))) if ok else np.inf,
            }
        )
    t = pd.DataFrame(rows)
    return t.assign(cx=t["model"].map(SIMPLICITY).fillna(len(SIMPLICITY)))


def _lowest(t: pd.DataFrame, score: pd.Series) -> str | None:
    t = t.assign(_s=np.round(score / 1e-3)).sort_values(["_s", "cx", "model"], kind="stable")
    return None if not np.isfinite(t["_s"].iloc[0]) else str(t["model"].iloc[0])


def rule_mean_max(cv: pd.DataFrame) -> str | None:
    """The current rule."""
    return choose_champion(cv)


def rule_mean_plus_se(cv: pd.DataFrame) -> str | None:
    """Lowest mean + one standard error of the fold max |residual|."""
    t = fold_stats(cv)
    return _lowest(t, t["mean"] + t["se"])


def rule_one_se_simplest(cv: pd.DataFrame) -> str | None:
    """The simplest kind whose mean is within one standard error of the lowest mean."""
    t = fold_stats(cv)
    best = t.loc[t["mean"].idxmin()]
    if not np.isfinite(best["mean"]):
        return None
    near = t.loc[t["mean"] <= best["mean"] + best["se"] + 1e-9]
    return str(near.sort_values(["cx", "mean", "model"], kind="stable")["model"].iloc[0])


def rule_ridge_floor(cv: pd.DataFrame) -> str | None:
    """The plain ridge (:data:`PLAIN_RIDGE`) unless a kind beats it by more than one standard
    error: a kind whose mean over the held-out runs of the paired difference (its max |residual|
    minus the plain ridge's, run by run) is below minus the standard error of that difference
    beats it; among those, the current rule's pick. Without the plain ridge among the rows (or
    with a held-out run it cannot predict): the current rule."""
    t = cv.assign(model=cv["model"].astype(str), test_runs=cv["test_runs"].astype(str))
    table = t.pivot_table(index="test_runs", columns="model", values="max_abs_after_um", aggfunc="first")
    if PLAIN_RIDGE not in table or len(table) < 2 or not np.isfinite(table[PLAIN_RIDGE]).all():
        return choose_champion(cv)
    beats = []
    for kind in table.columns:
        diff = (table[kind] - table[PLAIN_RIDGE]).to_numpy(dtype=float)
        if kind != PLAIN_RIDGE and np.isfinite(diff).all():
            if diff.mean() < -diff.std(ddof=1) / np.sqrt(len(diff)):
                beats.append(kind)
    return choose_champion(cv.loc[t["model"].isin(beats)]) if beats else PLAIN_RIDGE


def within_se_weights(cv: pd.DataFrame) -> dict[str, float]:
    """``average_within_se``: equal weights on the kinds whose mean fold max |residual| is within
    one standard error (the best kind's) of the lowest mean (the set ``one_se_simplest`` picks
    its simplest kind from)."""
    t = fold_stats(cv)
    t = t.loc[np.isfinite(t["mean"])]
    if t.empty:
        return {}
    best = t.loc[t["mean"].idxmin()]
    near = sorted(t.loc[t["mean"] <= best["mean"] + best["se"] + 1e-9, "model"])
    return {k: 1.0 / len(near) for k in near}


def rule_without(kind: str):
    """The current rule on CV rows without ``kind``: whether a kind earns its place in the family
    (``--without``; the paired difference to ``mean_max_forward`` is without minus with)."""

    def rule(cv: pd.DataFrame) -> str | None:
        return choose_champion(cv.loc[cv["model"].astype(str) != kind])

    return rule


def ensemble_weights(cv: pd.DataFrame) -> dict[str, float]:
    """The product's ensemble weights on whole-run CV rows: :func:`rafi.family.ensemble.cv_weights`
    (proportional to 1 / (mean fold max |residual|)^2) over the members
    :func:`rafi.family.ensemble.ensemble_members` takes from the kinds of ``cv`` (RAFI's kinds
    are scored, not blended). Where fewer than two members have a finite score the product
    offers one kind: the member with the finite score alone (empty when none has one)."""
    members = ensemble_members(sorted(set(cv["model"].astype(str))), floor=PLAIN_RIDGE)
    whole = cv if "scheme" in cv.columns else cv.assign(scheme="leave_one_run_out")
    weights = cv_weights(whole, members)
    if weights:
        return weights
    t = fold_stats(cv)
    t = t.loc[np.isfinite(t["mean"]) & (t["mean"] > 0) & t["model"].isin(members)]
    return {str(t["model"].iloc[0]): 1.0} if len(t) else {}


#: The forward scheme of the current rule (from the default ``models: cv_forward_runs``).
FORWARD = configured_scheme(MACHINE_DEFAULTS["models"])

#: The inner schemes the stacked ensemble fits its weights on (each weighs the same).
STACK_SCHEMES = ("leave_one_run_out", FORWARD)

#: Rule name -> (inner scheme or schemes, rule function).
RULES = {
    "mean_max": ("leave_one_run_out", rule_mean_max),
    "mean_max_forward": (("leave_one_run_out", FORWARD), rule_mean_max),
    "mean_plus_se": ("leave_one_run_out", rule_mean_plus_se),
    "one_se_simplest": ("leave_one_run_out", rule_one_se_simplest),
    "ridge_floor": ("leave_one_run_out", rule_ridge_floor),
    "speed_folds": (SPEED_SCHEME, rule_mean_max),
}


# ----------------------------------------------------------------------------- one machine


def schemes_of(scheme) -> tuple:
    """The inner schemes a rule reads: one name or a tuple of names (:data:`RULES`)."""
    return tuple(scheme) if isinstance(scheme, tuple) else (scheme,)


def rows_of(cvs: dict, scheme) -> pd.DataFrame:
    """A rule's CV rows: those of its scheme, or of each of its schemes stacked."""
    return pd.concat([cvs[s] for s in schemes_of(scheme)], ignore_index=True)


def machine_inputs(project: Path, machine: str) -> dict:
    """Settings, runs table and frame, key sensors and the pipeline's CV rows of one machine."""
    config = yaml.safe_load((project / "config.yaml").read_text(encoding="utf-8"))
    s = machine_settings(config, machine)
    res = project / "results" / machine
    keys = json.loads((res / RESULT_FILES["key_sensors_json"]).read_text(encoding="utf-8"))["sensors"]
    settings = {
        "key_sensors": list(keys),
        "terms": s["fit"]["terms"],
        "reference": s["reference"],
        "machine": machine,
        "options": s["models"],
        "hac_maxlags": s["fit"]["hac_maxlags"],
        "speed_tolerance_rpm": s["speed_tolerance_rpm"],
    }
    cv = pd.read_csv(res / RESULT_FILES["comparison_cv"])
    # every enabled kind and the plain ridge, a candidate of every rule (as on the foreign machines,
    # whose configs enable every kind): ``ridge_floor`` needs it, and the rules are compared alike
    kinds = list(dict.fromkeys([*s["models"]["enabled"], PLAIN_RIDGE]))
    return {
        "factories": {k: functools.partial(make_model, k, **settings) for k in kinds},
        "table": pd.read_csv(res / RESULT_FILES["runs_csv"]),
        "frame": pd.read_parquet(res / RESULT_FILES["runs_parquet"]),
        "cv": cv.loc[cv["model"].astype(str).isin(kinds)].reset_index(drop=True),
    }


def inner_cv(
    factories: dict, table: pd.DataFrame, frame: pd.DataFrame, scheme: str, oof: list | None = None
) -> pd.DataFrame:
    """Whole-run CV rows of every kind on the training runs of ``table`` under ``scheme``; with
    ``oof`` (a list), every kind's out-of-fold samples are appended to it (the same fits,
    :func:`rafi.family.crossval.cross_validate`, as the pipeline's ``rule compare`` does)."""
    with extra_scheme(SPEED_SCHEME, speed_with_cooldown_folds):
        parts = [
            crossval.cross_validate(f, table, frame, scheme, name=k, oof=oof) for k, f in factories.items()
        ]
    return pd.concat(parts, ignore_index=True)


def inner_fold(factories: dict, table: pd.DataFrame, frame: pd.DataFrame, schemes) -> tuple[dict, dict]:
    """The CV rows of every kind under each of ``schemes`` on the training runs of ``table``, and
    the OOF samples (:data:`rafi.family.intervals.OOF_COLUMNS`) of the schemes the stacked
    ensemble fits on (:data:`STACK_SCHEMES`)."""
    rows, oofs = {}, {}
    for sc in schemes:
        parts = [] if sc in STACK_SCHEMES else None
        rows[sc] = inner_cv(factories, table, frame, sc, oof=parts)
        if parts is not None:
            oofs[sc] = stacked_oof(parts)
    return rows, oofs


def dz_lookup(frame: pd.DataFrame) -> pd.Series:
    """The measured displacement indexed by ``(run_id, t_s)`` (the key of an OOF sample)."""
    index = pd.MultiIndex.from_arrays([frame["run_id"].astype(str), frame["t_s"].astype(float)])
    if index.has_duplicates:
        raise SystemExit("runs.parquet has two samples at one (run_id, t_s)")
    return pd.Series(frame["dz_um"].to_numpy(dtype=float), index=index)


def stacked_rule(oofs: dict, kinds, dz_at: pd.Series) -> dict:
    """:func:`_stacking.stacked_weights` on inner OOF samples; a stop when no kind is usable."""
    weights = stacked_weights(oofs, list(kinds), dz_at)
    if not weights:
        raise SystemExit("stacked: no kind has a finite out-of-fold prediction on every sample")
    return weights


def positive(weights: dict) -> dict:
    """The kinds with a weight above 0 (a kind left out may predict NaN: 0 * NaN is NaN)."""
    return {k: w for k, w in weights.items() if w > 0}


def weights_text(weights: dict) -> str:
    """``kind weight`` pairs of the weights of at least 0.005."""
    return " ".join(f"{k} {w:.2f}" for k, w in weights.items() if w >= 0.005)


def held_out_predictions(factories: dict, table: pd.DataFrame, frame: pd.DataFrame, held: str):
    """``(dz, {kind: prediction})`` on the samples of training run ``held``, every kind fitted on
    the other training runs as in :func:`rafi.family.crossval.cross_validate`."""
    universe = frame.loc[rows_of_logs(frame, crossval.training_runs(table, frame)[0]["run_id"])]
    fold_table = crossval.hold_out(table, [held])
    needed = universe.loc[rows_of_logs(universe, {held})]
    mine = (needed["run_id"].astype(str) == held).to_numpy()
    preds = {}
    with sharing_features(universe):
        for kind, factory in factories.items():
            model = factory().fit(fold_table, universe)
            preds[kind] = np.asarray(model.predict(needed), dtype=float)[mine]
    return needed["dz_um"].to_numpy(dtype=float)[mine], preds


def blend_median(predictions: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The weighted median of each row over its finite entries (the ``cv_weighted_median`` blend).

    Parameters
    ----------
    predictions : ndarray, shape (n, k)
        One column per member.
    weights : ndarray, shape (k,)
        Non-negative weights.

    Returns
    -------
    ndarray, shape (n,)
        Per row, with the finite ``p_k`` sorted and ``c`` the cumulative share of their weights:
        the first ``p`` whose ``c`` exceeds 1/2, the mean of it and the next where ``c`` is 1/2
        exactly (the ordinary median with equal weights); NaN where none is finite.
    """
    p = np.asarray(predictions, dtype=float)
    w = np.broadcast_to(np.asarray(weights, dtype=float), p.shape)
    have = np.isfinite(p)
    order = np.argsort(np.where(have, p, np.inf), axis=1, kind="stable")
    ps = np.take_along_axis(p, order, axis=1)
    ws = np.take_along_axis(np.where(have, w, 0.0), order, axis=1)
    total = ws.sum(axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        share = np.cumsum(ws, axis=1) / total
    tol = 1e-12
    first = np.argmax(share >= 0.5 - tol, axis=1)  # the first member reaching one half
    rows = np.arange(p.shape[0])
    at = ps[rows, first]
    above = np.where((share > 0.5 + tol) & np.isfinite(ps), ps, np.inf).min(axis=1)  # the next value
    exact = np.abs(share[rows, first] - 0.5) <= tol
    out = np.where(exact & np.isfinite(above), 0.5 * (at + above), at)
    return np.where(total[:, 0] > 0, out, np.nan)


def ensemble_score(dz: np.ndarray, preds: dict, weights: dict, median: bool = False) -> dict:
    """Max |residual| and RMSE of the weighted mean (``median``: the weighted median,
    :func:`blend_median`) of the predictions on one held-out run."""
    if median:
        kinds = [k for k, w in weights.items() if w > 0]
        matrix = np.column_stack([preds[k] for k in kinds])
        pred = blend_median(matrix, np.array([weights[k] for k in kinds]))
    else:
        pred = sum(w * preds[k] for k, w in weights.items())
    r = dz - pred
    ok = np.isfinite(r)
    return {"max": float(np.max(np.abs(r[ok]))), "rmse": float(np.sqrt(np.mean(r[ok] ** 2)))}


def check_rows(machine: str, ours: pd.DataFrame, pipeline: pd.DataFrame) -> None:
    """Stop unless the bench's CV rows on the full training runs are the pipeline's
    (``comparison/cv.csv``): the OOF samples the stacked weights are offered from are then
    those of the pipeline's own fits."""
    key = ["model", "fold", "test_runs"]
    a = ours.assign(test_runs=ours["test_runs"].astype(str)).set_index(key)["max_abs_after_um"]
    b = pipeline.assign(test_runs=pipeline["test_runs"].astype(str)).set_index(key)["max_abs_after_um"]
    same = a.index.sort_values().equals(b.index.sort_values()) and np.allclose(
        a.sort_index().to_numpy(dtype=float), b.sort_index().to_numpy(dtype=float), rtol=1e-6, atol=1e-6
    )
    if not same:
        raise SystemExit(f"{machine}: the full training CV differs from comparison/cv.csv")


def judge_machine(project: Path, machine: str, log=print) -> dict:
    """The outer CV of every rule on one machine (module docstring)."""
    inputs = machine_inputs(project, machine)
    table, frame, full_cv = inputs["table"], inputs["frame"], inputs["cv"]
    forward_rows = full_cv["scheme"].map(is_forward).to_numpy(dtype=bool)
    pipeline_forward = full_cv.loc[full_cv["scheme"].astype(str) == FORWARD]
    full_cv = full_cv.loc[~forward_rows]  # the outer scores: whole-run rows
    if set(full_cv["scheme"].astype(str)) != {"leave_one_run_out"}:
        raise SystemExit(f"{machine}: comparison/cv.csv is not leave_one_run_out; cannot score outer folds")
    outer_score = full_cv.set_index([full_cv["model"].astype(str), full_cv["test_runs"].astype(str)])
    schemes = sorted({s for scheme, _ in RULES.values() for s in schemes_of(scheme)})
    folds, t0, dz_at = [], time.perf_counter(), dz_lookup(frame)
    for _, (held,) in crossval.leave_one_run_out(table):
        inner_table = crossval.hold_out(table, [held], OUTER)
        inner, oofs = inner_fold(inputs["factories"], inner_table, frame, schemes)
        picks = {rule: fn(rows_of(inner, sc)) for rule, (sc, fn) in RULES.items()}
        scores = {
            m: {
                "max": float(outer_score.loc[(m, held), "max_abs_after_um"]),
                "rmse": float(outer_score.loc[(m, held), "rmse_um"]),
            }
            for m in inputs["factories"]
        }
        dz, preds = held_out_predictions(inputs["factories"], table, frame, held)
        for m in scores:  # the same fits as the pipeline's CV row of this run
            check = ensemble_score(dz, preds, {m: 1.0})["max"]
            if not np.isclose(check, scores[m]["max"], rtol=1e-6, atol=1e-6):
                raise SystemExit(f"{machine} {m} {held}: refit {check} um != cv.csv {scores[m]['max']} um")
        weights = ensemble_weights(inner["leave_one_run_out"])
        scores[ENSEMBLE] = ensemble_score(dz, preds, weights)
        scores[MEDIAN] = ensemble_score(dz, preds, weights, median=True)
        stacked = stacked_rule(oofs, inputs["factories"], dz_at)
        scores[STACKED] = ensemble_score(dz, preds, positive(stacked))
        scores[AVERAGE] = ensemble_score(dz, preds, within_se_weights(inner["leave_one_run_out"]))
        picks.update({b: b for b in BLENDS})
        fold = {"held_out": held, "picks": picks, "scores": scores, "weights": weights}
        folds.append({**fold, "stacked_weights": stacked})
        log(f"  {machine} outer fold {held}: " + ", ".join(f"{r} {p}" for r, p in picks.items()))
    full, full_oofs = inner_fold(inputs["factories"], table, frame, schemes)
    for sc, rows in {"leave_one_run_out": full_cv, FORWARD: pipeline_forward}.items():
        check_rows(machine, full[sc], rows)
        full[sc] = rows
    offered = {rule: fn(rows_of(full, sc)) for rule, (sc, fn) in RULES.items()}
    blends = {ENSEMBLE: ensemble_weights(full_cv), AVERAGE: within_se_weights(full_cv)}
    blends[MEDIAN] = blends[ENSEMBLE]
    blends[STACKED] = stacked_rule(full_oofs, inputs["factories"], dz_at)
    offered.update({rule: weights_text(w) for rule, w in blends.items()})
    return {
        "machine": machine,
        "project": str(project),
        "seconds": round(time.perf_counter() - t0, 1),
        "folds": folds,
        "offered_now": offered,
        "offered_weights": blends,  # the blends' weights on the full training CV
        "full_stats": fold_stats(full_cv).drop(columns="cx").to_dict(orient="records"),
    }


def paired(diff: np.ndarray, prefix: str) -> dict:
    """``<prefix>_diff_um`` and ``<prefix>_se_um``: the mean of the per-fold differences and its
    standard error (sample standard deviation over sqrt(folds); NaN with one fold)."""
    se = float(diff.std(ddof=1) / np.sqrt(len(diff))) if len(diff) > 1 else np.nan
    return {f"{prefix}_diff_um": float(diff.mean()), f"{prefix}_se_um": se}


def summarise(result: dict) -> list[dict]:
    """Per rule: the outer mean max |residual| of its picks, pooled RMSE, the paired differences
    to ``mean_max`` and to the current rule ``mean_max_forward`` (mean and standard error over
    outer folds), the picks; plus the oracle."""
    folds = result["folds"]
    base = np.array([f["scores"][f["picks"]["mean_max"]]["max"] for f in folds])
    current = np.array([f["scores"][f["picks"]["mean_max_forward"]]["max"] for f in folds])
    rows = []
    for rule in [*RULES, *BLENDS, "oracle"]:
        if rule == "oracle":
            kinds = [m for m in folds[0]["scores"] if m not in BLENDS]
            picks = [min(kinds, key=lambda m, f=f: f["scores"][m]["max"]) for f in folds]
        else:  # a rule that cannot choose in a fold (no speed folds on one speed): the current rule's
            picks = [f["picks"][rule] or f["picks"]["mean_max_forward"] for f in folds]
        mx = np.array([f["scores"][p]["max"] for f, p in zip(folds, picks)])
        rmse = np.array([f["scores"][p]["rmse"] for f, p in zip(folds, picks)])
        rows.append(
            {
                "machine": result["machine"],
                "rule": rule,
                "outer_mean_max_um": float(mx.mean()),
                "outer_worst_max_um": float(mx.max()),
                "outer_rmse_um": float(np.sqrt(np.mean(rmse**2))),
                **paired(mx - base, "paired"),
                **paired(mx - current, "vs_current"),
                "picks": " ".join(p or "-" for p in picks),
                "offered_now": result["offered_now"].get(rule, ""),
            }
        )
    return rows


def markdown(report: dict) -> str:
    """The report as markdown: one table over machines and rules."""
    head = [
        "machine",
        "rule",
        "outer mean max",
        "outer worst",
        "outer RMSE",
        "vs mean_max (SE)",
        "vs mean_max_forward (SE)",
        "picks per outer fold",
        "offers now",
    ]
    lines = [
        f"# Selection rules by outer whole-run CV ({report['date']})",
        "",
        f"Command: `{report['command']}`; host {report['host']}, {report['cpus']} CPUs.",
        "Training runs only; um. Outer folds: leave one training run out; a rule picks from the inner CV",
        "of the other training runs; its pick is scored on the held-out run (max |residual|).",
        "",
        f"| {' | '.join(head)} |",
        "|" + "---|" * len(head),
    ]
    for r in report["rows"]:
        cells = [
            r["machine"],
            r["rule"],
            f"{r['outer_mean_max_um']:.2f}",
            f"{r['outer_worst_max_um']:.2f}",
            f"{r['outer_rmse_um']:.2f}",
            f"{r['paired_diff_um']:+.2f} ({r['paired_se_um']:.2f})",
            f"{r['vs_current_diff_um']:+.2f} ({r['vs_current_se_um']:.2f})",
            r["picks"],
            r["offered_now"] or "-",
        ]
        lines.append(f"| {' | '.join(cells)} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--project",
        type=Path,
        action="append",
        required=True,
        help="a project that has run (config.yaml, results/<machine>/); repeat",
    )
    parser.add_argument("--machines", default="", help="comma-separated machine names (default: all)")
    parser.add_argument("--out", default="selection_rules", help="file stem under benchmarks/results/")
    parser.add_argument(
        "--without",
        default="",
        help="a kind: add rule without_<KIND>, the current rule on the same CV rows without that kind",
    )
    args = parser.parse_args(argv)
    if args.without:
        RULES[f"without_{args.without}"] = (RULES["mean_max_forward"][0], rule_without(args.without))
    wanted = {m.strip() for m in args.machines.split(",") if m.strip()}
    rows, results = [], []
    for project in args.project:
        for res in sorted((project / "results").iterdir()):
            if not (res / RESULT_FILES["comparison_cv"]).is_file() or (wanted and res.name not in wanted):
                continue
            print(f"{res.name} ({project})", flush=True)
            result = judge_machine(project, res.name, log=lambda m: print(m, flush=True))
            results.append(result)
            for row in summarise(result):
                rows.append(row)
                print(
                    f"  {row['rule']:16s} outer mean max {row['outer_mean_max_um']:7.2f} um, "
                    f"vs mean_max {row['paired_diff_um']:+.2f} ({row['paired_se_um']:.2f}), "
                    f"vs mean_max_forward {row['vs_current_diff_um']:+.2f} ({row['vs_current_se_um']:.2f}); "
                    f"offers now {row['offered_now'] or '-'}",
                    flush=True,
                )
    report = {
        "date": dt.date.today().isoformat(),
        "command": " ".join(
            ["python benchmarks/bench_selection_rules.py", *(sys.argv[1:] if argv is None else argv)]
        ),
        "host": platform.node(),
        "cpus": os.cpu_count(),
        "rows": rows,
        "machines": results,
    }
    text = markdown(report)
    print("\n" + text)
    write_results(args.out, report, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
