"""The family's comparison step (``rule compare``): build a model of any kind from the
settings, read any artefact, choose the model offered to the machine on the training runs,
then validate every model once (``docs/models.md``).

:func:`choose_champion` chooses the champion (the model offered to the machine) from the
outer folds of the nested whole-run cross-validation on the **training runs only**
(:func:`rafi.family.crossval.cross_validate`): the lowest mean over held-out runs of the max
|residual| (:data:`SELECTION_RULE`). :func:`compare_models` then validates the fitted models
on the validation runs with :func:`rafi.method.validate.validate_runs` (the pipeline's own
definitions of residual and improvement) and the acceptance gates of
:func:`rafi.method.validate.qualify`; the validation results never change the choice: a
champion that fails a gate is reported as failing, with no second pick. :func:`run_family`
does all of it for the enabled kinds.
"""

from __future__ import annotations

import functools
import json
import os
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from rafi.artefact import json_text, write_text_atomic
from rafi.family.adapted import adaptation_factories
from rafi.family.crossval import (  # noqa: F401 - cv_data re-exported (it lived here)
    cross_validate,
    cv_data,
    cv_schemes,
    scheme_of,
    training_runs,
)
from rafi.family.cv_memo import cv_memo_key, read_cv, read_oof, write_cv, write_oof
from rafi.family.describe import describe_selection, fitted_text
from rafi.family.dynamic import DynamicRidge
from rafi.family.ensemble import (
    ENSEMBLE,
    WeightedEnsemble,
    cv_weights,
    ensemble_cv_rows,
    ensemble_members,
    ensemble_oof,
)
from rafi.family.feature_memo import sharing_features
from rafi.family.forward_folds import configured_scheme as forward_scheme
from rafi.family.forward_folds import is_forward
from rafi.family.grey_box import GreyBox
from rafi.family.interval_fit import borrow_interval, calibrate_family, calibration_units, stacked_oof
from rafi.family.intervals import coverage_and_width, interval_columns
from rafi.family.plain_ridge import PLAIN_RIDGE, floor_columns, with_plain_ridge
from rafi.family.prior_fitness import dynamics_warning, misfit_warning
from rafi.family.published import PublishedRafi
from rafi.family.rafi_linear import RafiLinear
from rafi.family.ridge_global import RidgeGlobal
from rafi.family.selection import (  # noqa: F401 - re-exported: the selection rule lives there
    SELECTION_COLUMNS,
    SELECTION_RULE,
    SHARED_GAIN,
    SHARED_RIDGE,
    choose_champion,
    default_champion,
    scratch_ahead,
    selection_table,
)
from rafi.family.since_change import change_of, change_table, set_aside_before
from rafi.family.temperature_ridge import TemperatureRidge
from rafi.family.whole_log import rows_of_logs
from rafi.method.rank import trained_speeds
from rafi.method.validate import qualify, validate_runs
from rafi.settings import MACHINE_DEFAULTS

KINDS = {
    "rafi": PublishedRafi,
    "rafi_linear": RafiLinear,
    "ridge_global": RidgeGlobal,
    "dynamic": DynamicRidge,
    "grey_box": GreyBox,
    "temperature_ridge": TemperatureRidge,
}


def make_model(
    kind: str,
    *,
    key_sensors: Sequence[str],
    terms: Sequence[str],
    reference: dict,
    machine: str | None,
    options: dict,
    hac_maxlags: int = MACHINE_DEFAULTS["fit"]["hac_maxlags"],
    speed_tolerance_rpm: float = MACHINE_DEFAULTS["speed_tolerance_rpm"],
):
    """An unfitted model of ``kind`` built from a machine's settings.

    Parameters
    ----------
    kind : str
        One of :data:`KINDS`.
    key_sensors : sequence of str
        RAFI's key sensors (kinds ``rafi``, ``rafi_linear``).
    terms : sequence of str
        ``fit: terms`` (kind ``rafi``).
    reference : dict
        The machine's ``reference:`` settings.
    machine : str or None
        Machine name recorded in the artefact.
    options : dict
        The machine's complete ``models:`` settings (:data:`rafi.settings.MACHINE_DEFAULTS`
        with the machine's changes); every key this kind reads must be present.
    hac_maxlags : int
        ``fit: hac_maxlags`` (kinds ``rafi``, ``rafi_linear``).
    speed_tolerance_rpm : float
        The machine's ``speed_tolerance_rpm`` (every kind).
    """
    o = options
    common = {"reference": reference, "machine": machine, "speed_tolerance_rpm": speed_tolerance_rpm}
    ridge = {"alphas": o["ridge_alphas"], "cv": o["cv"], "speed_reference": o["speed_reference"], **common}
    ridge["filter_restart_gap_s"] = o["filter_restart_gap_s"]
    ridge["component_envelope"] = o["component_envelope"]
    if kind == "rafi":
        return PublishedRafi(key_sensors=key_sensors, terms=terms, hac_maxlags=hac_maxlags, **common)
    if kind == "rafi_linear":
        return RafiLinear(key_sensors=key_sensors, hac_maxlags=hac_maxlags, **common)
    if kind == "ridge_global":
        return RidgeGlobal(cv_metric=o["cv_metric"], speed_gain=o["speed_gain"], **ridge)
    if kind == "dynamic":
        return DynamicRidge(
            taus_s=o["dynamic_taus_s"],
            max_taus=o["dynamic_max_taus"],
            heat_input=o["dynamic_heat_input"],
            speed_taus_s=o["grey_box_speed_taus_s"],
            speed_powers=o["grey_box_speed_powers"],
            cv_metric=o["cv_metric"],
            speed_gain=o["speed_gain"],
            **ridge,
        )
    if kind == "temperature_ridge":
        return TemperatureRidge(
            taus_s=o["temperature_ridge_taus_s"],
            cv_metric=o["cv_metric"],
            **{k: v for k, v in ridge.items() if k != "speed_reference"},
        )
    if kind == "grey_box":
        return GreyBox(
            taus_s=o["grey_box_taus_s"],
            speed_taus_s=o["grey_box_speed_taus_s"],
            speed_powers=o["grey_box_speed_powers"],
            centrifugal_lags_s=o["grey_box_centrifugal_lags_s"],
            cv_metric=o["grey_box_cv_metric"],
            **ridge,
        )
    raise ValueError(f"unknown model kind {kind!r}; known: {sorted(KINDS)}")


def load_any(source):
    """A fitted model from an artefact dict or a path to ``model.json``, by its ``kind``.

    Kind ``rafi`` is read by :meth:`rafi.method.model.RafiModel.from_dict` (the published method's
    own evaluator); the other kinds by their class (:data:`KINDS`).
    """
    if isinstance(source, (str, os.PathLike)):
        source = json.loads(Path(source).read_text(encoding="utf-8"))
    kind = source.get("kind")
    if kind == "rafi":
        from rafi.method.model import RafiModel

        return RafiModel.from_dict(source)
    if kind in KINDS:
        return KINDS[kind].from_dict(source)
    if kind == ENSEMBLE:
        return WeightedEnsemble.from_dict(source, load=load_any)
    raise ValueError(f"unknown model kind {kind!r}; known: {sorted([*KINDS, ENSEMBLE])}")


def save_any(model, path) -> None:
    """Write ``model.to_dict()`` atomically as pretty JSON."""
    write_text_atomic(path, json_text(model.to_dict()))


COMPARISON_COLUMNS = [
    "model",
    "kind",
    "scope",
    "run_id",
    "role",
    "speed_rpm",
    "n_samples",
    "max_abs_before_um",
    "max_abs_after_um",
    "improvement_pct",
    "rmse_before_um",
    "rmse_after_um",
    "n_outside_temp_range",
    "n_outside_speed_range",
    "n_outside_envelope",
    "n_unpredicted",
    "unpredicted_inputs",
    "worse_than_uncompensated",
    "passed",
    "verdict",
    "champion",
    "model_id",
    "noise_sigma_um",
    "noise_floor_um",
    "coverage",
    "interval_width_um",
]


#: The columns of ``comparison/verdict.csv``: the rows of :func:`rafi.method.validate.qualify`
#: (criterion x validation run) of every model, named by the model and its id.
VERDICT_COLUMNS = ["model", "model_id", "run_id", "criterion", "limit", "measured", "passed"]


def _model_kind(model) -> str:
    return str(getattr(model, "kind", None) or model.to_dict().get("kind", type(model).__name__))


def _model_id(model) -> str:
    """The artefact id of a fitted model (``""`` when it cannot say)."""
    try:
        return model.to_dict().get("model_id", "")
    except Exception:  # noqa: BLE001 - an unfitted or foreign object: id unknown
        return ""


def named_verdict(verdict: pd.DataFrame, name: str, model_id: str) -> pd.DataFrame:
    """One model's verdict rows as ``comparison/verdict.csv`` stores them.

    Parameters
    ----------
    verdict : pandas.DataFrame
        :func:`rafi.method.validate.qualify` of the model's validation summary.
    name, model_id : str
        The model's name in the family and its artefact id.

    Returns
    -------
    pandas.DataFrame
        :data:`VERDICT_COLUMNS`, in ``verdict``'s row order.
    """
    return verdict.assign(model=name, model_id=model_id)[VERDICT_COLUMNS].reset_index(drop=True)


def stacked_verdicts(parts: list) -> pd.DataFrame:
    """The verdict rows of every model, in the order of ``parts`` (:func:`named_verdict` frames);
    the empty table with :data:`VERDICT_COLUMNS` when no model has a gate."""
    parts = [p for p in parts if len(p)]
    if not parts:
        return pd.DataFrame(columns=VERDICT_COLUMNS)
    return pd.concat(parts, ignore_index=True)


def compare_models(
    models: dict,
    runs_table: pd.DataFrame,
    runs_frame: pd.DataFrame,
    gates: dict,
    *,
    champion: str | None = None,
    return_residuals: bool = False,
    return_verdict: bool = False,
):
    """Validate every fitted model on the validation runs and qualify it against ``gates``.

    The champion is chosen before, on the training runs (:func:`choose_champion`); this
    function only marks it: nothing here depends on which model is the champion.

    Parameters
    ----------
    models : dict[str, fitted model]
        Name -> anything with ``predict_detail`` (family models or a ``RafiModel``).
    gates : dict
        The config ``qualification:`` section (see :func:`rafi.method.validate.qualify`).
    champion : str, optional
        Name of the model chosen on the training runs (``champion`` is true on its rows).

    Returns
    -------
    summary : pandas.DataFrame
        Columns :data:`COMPARISON_COLUMNS`: one ``scope == "run"`` row per model and
        validation run, and one ``scope == "model"`` row per model with the worst case over
        every validation run, idle cool-downs included (``max_abs_after_um`` = worst max
        residual, ``improvement_pct`` = minimum over the runs, ``rmse_after_um`` = worst,
        counts summed, ``unpredicted_inputs`` the runs' inputs without a value, each once,
        ``passed`` = every gate of every run passed, ``verdict`` pass/fail,
        ``noise_sigma_um`` / ``noise_floor_um`` of the run with the worst residual,
        ``coverage`` / ``interval_width_um`` pooled over every validation sample).
    residuals : pandas.DataFrame (only with ``return_residuals=True``)
        :func:`rafi.method.validate.validate_runs` residuals with a ``model`` column.
    verdict : pandas.DataFrame (only with ``return_verdict=True``, after ``residuals``)
        Every model's :func:`rafi.method.validate.qualify` rows (:data:`VERDICT_COLUMNS`), in
        the order of ``models``.
    """
    parts, res_parts, verdict_parts = [], [], []
    for name, model in models.items():
        summary, residuals = validate_runs(
            model, runs_table, runs_frame, bounds=functools.partial(interval_columns, model)
        )
        verdict = qualify(summary, gates)
        passed_run = verdict.groupby(verdict["run_id"].astype(str))["passed"].all()
        s = summary.copy()
        s["passed"] = s["run_id"].astype(str).map(passed_run).fillna(False).astype(bool)
        s["model"], s["kind"], s["scope"] = name, _model_kind(model), "run"
        model_id = _model_id(model)
        s["model_id"] = model_id
        s["verdict"] = np.where(s["passed"], "pass", "fail")
        parts.append(s)
        verdict_parts.append(named_verdict(verdict, name, model_id))
        if return_residuals:
            res_parts.append(residuals.assign(model=name))
        overall = bool(len(verdict) and verdict["passed"].all())
        worst = s["max_abs_after_um"].astype(float).idxmax() if s["max_abs_after_um"].notna().any() else None
        parts.append(
            pd.DataFrame(
                [
                    {
                        "model": name,
                        "kind": s["kind"].iloc[0] if len(s) else _model_kind(model),
                        "scope": "model",
                        "run_id": "all",
                        "role": "all",
                        "speed_rpm": np.nan,
                        "n_samples": int(s["n_samples"].sum()),
                        "max_abs_before_um": float(s["max_abs_before_um"].max()) if len(s) else np.nan,
                        "max_abs_after_um": float(s["max_abs_after_um"].max()) if len(s) else np.nan,
                        "improvement_pct": float(s["improvement_pct"].min()) if len(s) else np.nan,
                        "rmse_before_um": float(s["rmse_before_um"].max()) if len(s) else np.nan,
                        "rmse_after_um": float(s["rmse_after_um"].max()) if len(s) else np.nan,
                        "n_outside_temp_range": int(s["n_outside_temp_range"].sum()),
                        "n_outside_speed_range": int(s["n_outside_speed_range"].sum()),
                        "n_outside_envelope": int(s["n_outside_envelope"].sum()),
                        "n_unpredicted": int(s["n_unpredicted"].sum()),
                        "unpredicted_inputs": _joined_inputs(s["unpredicted_inputs"]),
                        "worse_than_uncompensated": bool(s["worse_than_uncompensated"].any()),
                        "passed": overall,
                        "verdict": "pass" if overall else "fail",
                        "model_id": s["model_id"].iloc[0] if len(s) else "",
                        "noise_sigma_um": np.nan if worst is None else float(s.loc[worst, "noise_sigma_um"]),
                        "noise_floor_um": np.nan if worst is None else float(s.loc[worst, "noise_floor_um"]),
                        **_pooled_coverage(residuals),
                    }
                ]
            )
        )
    out = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=COMPARISON_COLUMNS)
    out["champion"] = out["model"].astype(str) == str(champion) if champion is not None else False
    out = out[COMPARISON_COLUMNS]
    extras = []
    if return_residuals:
        extras.append(pd.concat(res_parts, ignore_index=True) if res_parts else pd.DataFrame())
    if return_verdict:
        extras.append(stacked_verdicts(verdict_parts))
    return (out, *extras) if extras else out


def cv_unpredicted(cv: pd.DataFrame) -> pd.DataFrame:
    """Per model, the measured samples of its held-out training runs (whole-run CV; forward
    folds hold the same runs out again) it gave no value on: ``cv_unpredicted`` (their count)
    and ``cv_unpredicted_inputs`` (the inputs without a value, each once)."""
    columns = ["model", "cv_unpredicted", "cv_unpredicted_inputs"]
    if cv is None or not len(cv):
        return pd.DataFrame(columns=columns)
    whole = cv.loc[~cv["scheme"].map(is_forward).astype(bool)]
    rows = [
        {
            "model": name,
            "cv_unpredicted": int(g["n_unpredicted"].sum()),
            "cv_unpredicted_inputs": _joined_inputs(g["unpredicted_inputs"]),
        }
        for name, g in whole.groupby(whole["model"].astype(str), sort=False)
    ]
    return pd.DataFrame(rows, columns=columns)


def _joined_inputs(per_run: pd.Series) -> str:
    """The inputs of every run's ``unpredicted_inputs`` (``"T8, T11"``), each once, in order."""
    names = [n for text in per_run.fillna("").astype(str) for n in text.split(", ") if n]
    return ", ".join(dict.fromkeys(names))


def _pooled_coverage(residuals: pd.DataFrame) -> dict:
    """``coverage`` and ``interval_width_um`` over every validation sample of one model."""
    cov, width = coverage_and_width(residuals["measured_um"], residuals["lower_um"], residuals["upper_um"])
    return {"coverage": cov, "interval_width_um": width}


def fit_and_cross_validate(
    factories: dict,
    runs_table: pd.DataFrame,
    runs_frame: pd.DataFrame,
    *,
    scheme: str,
    forward: str | None = None,
    rafi_model=None,
    known_cv: pd.DataFrame | None = None,
    oof: list | None = None,
    log=print,
) -> tuple[dict, pd.DataFrame]:
    """Fit every kind of ``factories`` on the training runs and cross-validate it by whole run
    (and on forward folds).

    Parameters
    ----------
    factories : dict
        Kind -> a function building the unfitted model (:func:`make_model`), in order.
    scheme : str
        The CV scheme (``models: cv``).
    forward : str, optional
        A forward scheme (:func:`rafi.family.forward_folds.scheme_name`): every kind is also
        cross-validated on its folds when the training runs give one (rows with that ``scheme``).
    rafi_model : RafiModel, optional
        The pipeline's ``model.json``: the ``rafi`` entry, not refitted.
    known_cv : pandas.DataFrame, optional
        The CV rows of these data, settings and code, read from the memo
        (:mod:`rafi.family.cv_memo`): no CV is computed.
    oof : list, optional
        Receives every kind's out-of-fold samples (``cross_validate(oof=)``) when CV runs.

    Returns
    -------
    models : dict
        Kind -> fitted model.
    cv : pandas.DataFrame
        :func:`rafi.family.crossval.cross_validate` rows of every kind (``known_cv`` if given).
    """
    models, cv_parts = {}, []
    schemes = cv_schemes(runs_table, scheme, forward)
    universe = runs_frame.loc[rows_of_logs(runs_frame, training_runs(runs_table, runs_frame)[0]["run_id"])]
    for kind, factory in factories.items():
        with sharing_features(universe):  # the fit and every CV fold share the logs' features
            t0 = time.perf_counter()
            if kind == "rafi" and rafi_model is not None:
                models[kind] = rafi_model
            else:
                models[kind] = factory().fit(runs_table, runs_frame)
            log(f"{kind}: fitted in {time.perf_counter() - t0:.2f} s{fitted_text(models[kind])}")
            if known_cv is not None:
                continue
            for sch in schemes:
                t0 = time.perf_counter()
                cv = cross_validate(factory, runs_table, runs_frame, sch, name=kind, oof=oof)
                cv_parts.append(cv)
                worst = f"{cv['max_abs_after_um'].max():.2f} um" if len(cv) else "no fold"
                log(
                    f"{kind}: {scheme_of(runs_table, sch)} CV in {time.perf_counter() - t0:.1f} s,"
                    f" max |residual| {worst}"
                )
    if known_cv is not None:
        return models, known_cv
    return models, pd.concat(cv_parts, ignore_index=True) if cv_parts else pd.DataFrame()


def _cross_validated(
    factories, runs_table, runs_frame, settings, *, rafi_model, cv_memo_dir, code_version, log
):
    """The fitted models, CV rows and OOF samples of :func:`run_family`, from the memo
    (:mod:`rafi.family.cv_memo`) when it holds this CV (its rows and its OOF samples), else
    computed (and stored). Returns ``models, cv, oof, memo, fit_table``."""
    options = settings["options"]
    key = (
        cv_memo_key(runs_table, runs_frame, settings, code_version) if cv_memo_dir and code_version else None
    )
    known = read_cv(cv_memo_dir, key) if key else None
    known_oof = read_oof(cv_memo_dir, key) if known is not None else None
    known = known if known_oof is not None else None  # an entry without its OOF samples: recompute
    if known is not None:
        log(f"cross-validation rows from the memo ({key[:12]}: training runs, settings and code unchanged)")
    fit_table, fit_frame = cv_data(runs_table, runs_frame, options, log=log)
    oof_parts: list = []
    models, cv = fit_and_cross_validate(
        factories,
        fit_table,
        fit_frame,
        scheme=options["cv"],
        forward=forward_scheme(options),
        rafi_model=rafi_model,
        known_cv=known,
        oof=oof_parts,
        log=log,
    )
    oof = known_oof if known is not None else stacked_oof(oof_parts)
    memo = "read" if known is not None else None
    if key and known is None and len(cv):
        write_oof(cv_memo_dir, key, oof)
        write_cv(cv_memo_dir, key, cv)
        memo = "written"
    return models, cv, oof, memo, fit_table


def with_ensemble(
    models: dict, cv: pd.DataFrame, oof: pd.DataFrame, members, *, machine, trained_speeds_rpm=None, log=print
):
    """``models``, ``cv`` and ``oof`` with the CV-weighted ensemble of ``members``
    (:mod:`rafi.family.ensemble`; ``trained_speeds_rpm`` recorded in it): its model, its CV rows
    and its OOF samples, blended from the members' own. Unchanged when fewer than two members have
    a finite CV score."""
    weights = cv_weights(cv, [m for m in dict.fromkeys(members) if m in models])
    if not weights:
        return models, cv, oof
    blended = ensemble_oof(oof, weights)
    log(f"{ENSEMBLE}: " + ", ".join(f"{k} {w:.3f}" for k, w in weights.items()))
    ensemble = WeightedEnsemble.from_fitted(
        models, weights, machine=machine, trained_speeds_rpm=trained_speeds_rpm
    )
    models = {**models, ENSEMBLE: ensemble}
    cv = pd.concat([cv, ensemble_cv_rows(cv, blended)], ignore_index=True)
    return models, cv, pd.concat([oof, blended], ignore_index=True)


def offered_first(selection: pd.DataFrame, offered: str) -> pd.DataFrame:
    """``selection`` with the ``offered`` model's row first and the ranks renumbered in that order
    (a model offered by a rule other than the lowest score is rank 1 all the same)."""
    mine = selection["model"].astype(str) == offered
    out = pd.concat([selection.loc[mine], selection.loc[~mine]], ignore_index=True)
    ranked = out["selection_rank"].notna().to_numpy()
    rank = pd.array([pd.NA] * len(out), dtype="Int64")
    rank[ranked] = np.arange(1, int(ranked.sum()) + 1)
    out["selection_rank"] = rank
    return out


def prior_misfit_warning(models: dict, selection: pd.DataFrame) -> dict | None:
    """The fitness warning ``prior_misfit`` (:func:`rafi.family.prior_fitness.misfit_warning`) from
    the CV score of the candidate ``prior`` (the prior as it is) in ``selection``, or None without
    that candidate."""
    rows = selection.loc[selection["model"] == "prior", "selection_score_um"] if len(selection) else []
    if "prior" not in models or not len(rows):
        return None
    return misfit_warning(float(rows.iloc[0]), models["prior"].prior)


def _choose(cv: pd.DataFrame, candidates: list, offered: list, ensemble: bool, log) -> tuple:
    """``(champion, selection table, basis)`` of :func:`run_family`: :func:`choose_champion` among
    ``candidates`` (the CV-weighted ensemble when ``ensemble``; :func:`default_champion` without
    a fold, basis ``default``), the offered model first in the table of ``offered``."""
    selection = selection_table(cv, offered)
    champion = choose_champion(cv, candidates)
    basis = "cv"
    if champion is not None and not selection.empty and champion != str(selection["model"].iloc[0]):
        lowest = selection["model"].iloc[0]
        log(f"{champion} offered by the selection rule with a prior; the lowest score: {lowest}")
        selection = offered_first(selection, champion)
    if ensemble:
        champion, selection = ENSEMBLE, offered_first(selection, ENSEMBLE)
    if champion is None:
        champion, basis = default_champion(candidates), "default"
        log(f"no cross-validation fold: {champion} offered by the default rule")
    return champion, selection, basis


def run_family(
    runs_table: pd.DataFrame,
    runs_frame: pd.DataFrame,
    *,
    key_sensors: Sequence[str],
    terms: Sequence[str],
    reference: dict,
    machine: str | None,
    options: dict,
    gates: dict,
    hac_maxlags: int = MACHINE_DEFAULTS["fit"]["hac_maxlags"],
    speed_tolerance_rpm: float = MACHINE_DEFAULTS["speed_tolerance_rpm"],
    rafi_model=None,
    cv_memo_dir: str | os.PathLike | None = None,
    code_version: str | None = None,
    log=print,
    prior: dict | None = None,
    prior_origin: dict | None = None,
) -> dict:
    """Fit, cross-validate, choose, then validate the enabled models (what ``rule compare`` runs).

    Order (:data:`SELECTION_RULE`): every enabled kind, and the plain ridge whether enabled or not
    (:mod:`rafi.family.plain_ridge`), is fitted on the training runs and cross-validated by whole
    run on them (``options["cv"]``, nested: each fold re-chooses the hyperparameters on its own
    training runs); the champion is chosen among the candidates (the enabled kinds) from those
    held-out scores (:func:`choose_champion`; :func:`default_champion` when there is no fold); only
    then is every model validated, once, on the validation runs, and the champion qualified
    against ``gates``. The champion is offered whether it passes or not: a failing champion
    means a FAIL verdict, never a second pick. Between the CV and the validation every model
    gets its prediction interval, calibrated on its own out-of-fold CV residuals
    (:func:`rafi.family.interval_fit.calibrate_family`; memoised with the CV rows); ``rafi_model``
    keeps the interval its ``model.json`` carries (none: NaN bounds).

    ``options`` and ``gates`` are the machine's complete ``models:`` and ``qualification:``
    settings (:func:`rafi.settings.machine_settings`); the registry's decision judges with the
    same gates. ``rafi_model`` is the pipeline's fitted ``model.json`` (a ``RafiModel``); when
    given it is the ``rafi`` entry (no refit), else RAFI is fitted here. Fit and CV times go to
    ``log`` only, so the tables of two runs on the same inputs are identical. With
    ``cv_memo_dir`` and ``code_version`` (the digest of the code that runs this, the compare
    rule's ``code`` param) the CV rows come from the memo (:mod:`rafi.family.cv_memo`) when it
    holds this CV's key, and are stored there when computed. With ``prior`` (an artefact,
    :mod:`rafi.family.prior`) the adaptation candidates ``prior``, ``prior_gain``, ``prior_ridge``
    join the kinds (:func:`rafi.family.adapted.adaptation_factories`); the memo key covers its id.
    ``prior_origin`` (``origin`` and ``qualification``: :func:`rafi.family.prior.prior_record`)
    goes to the candidates' fitness block. With ``options["since_change"]``, when the CV's runs
    no model explains lie on one side of a change (:mod:`rafi.family.since_change`), the training
    runs recorded before it are set aside and the fits and the CV run again on the runs since.

    Returns
    -------
    dict
        ``summary`` (one row per model: the validation worst cases, ``selected`` (what CV chose
        inside the model, :func:`describe_selection`), the columns of :func:`selection_table` and
        those of :func:`cv_unpredicted` and :func:`rafi.family.plain_ridge.floor_columns`),
        ``per_run``, ``verdict`` (every model's gates per validation run, :data:`VERDICT_COLUMNS`,
        in the order of ``summary``), ``residuals``, ``cv``, ``selection`` (:func:`selection_table`),
        ``champion`` (name of the model offered), ``champion_passed`` (its gates on the
        validation runs), ``selection_basis`` (``"cv"`` or ``"default"``), ``best_name`` (=
        ``champion``) and ``best_artefact`` (its artefact), ``models`` (name -> fitted model),
        ``cv_memo`` (``"read"``, ``"written"`` or ``None``), ``since_change``
        (:func:`rafi.family.since_change.change_table`: the training runs in recorded order with
        the first CV's figures and the runs set aside; empty without a change).
    """
    settings = {
        "key_sensors": list(key_sensors),
        "terms": list(terms),
        "reference": reference,
        "machine": machine,
        "options": options,
        "hac_maxlags": hac_maxlags,
        "speed_tolerance_rpm": speed_tolerance_rpm,
    }
    factories = {kind: functools.partial(make_model, kind, **settings) for kind in options["enabled"]}
    adaptations: dict = {}
    floor = functools.partial(make_model, PLAIN_RIDGE, **settings)  # always scored, offered if enabled
    if prior is not None:
        origin = prior_origin or {}
        adaptations = adaptation_factories(
            prior,
            options=options,
            machine=machine,
            reference=reference,  # this machine's reference
            log=log,
            origin=origin.get("origin"),
            qualification=origin.get("qualification"),
            speed_tolerance_rpm=speed_tolerance_rpm,
        )
        factories.update(adaptations)
        settings = {**settings, "prior": prior.get("model_id")}  # the CV memo's key covers the prior
    candidates, factories = list(factories), with_plain_ridge(factories, floor)  # offered / scored
    offer_ensemble = options["offer"] == ENSEMBLE and prior is None  # judged from scratch only
    members = ensemble_members(options["enabled"], floor=PLAIN_RIDGE) if offer_ensemble else []

    def fit_on(table: pd.DataFrame, rafi):
        """Every model fitted and cross-validated on the training runs of ``table``, the
        ensemble of ``members`` beside them: ``models, cv, oof, memo, fit_table``."""
        models, cv, oof, memo, fit_table = _cross_validated(
            factories,
            table,
            runs_frame,
            settings,
            rafi_model=rafi,
            cv_memo_dir=cv_memo_dir,
            code_version=code_version,
            log=log,
        )
        speeds = trained_speeds(table) if members else None
        models, cv, oof = with_ensemble(
            models, cv, oof, members, machine=machine, trained_speeds_rpm=speeds, log=log
        )
        return models, cv, oof, memo, fit_table

    models, cv, oof, memo, fit_table = fit_on(runs_table, rafi_model)
    change = change_of(cv, runs_table, tolerance_rpm=speed_tolerance_rpm) if options["since_change"] else None
    since_change = change_table(change, cv, runs_table)
    if change is not None:  # the runs before a change are set aside: everything again on the rest
        log(f"{len(change.set_aside)} training runs {change.reason}")
        runs_table = set_aside_before(runs_table, change)
        # model.json learnt from every training run: RAFI is refitted here
        models, cv, oof, memo, fit_table = fit_on(runs_table, None)
    # every model's prediction interval, from its own OOF residuals (RAFI's model.json keeps its own)
    samples, calibrated_on = calibration_units(oof, scheme_of(fit_table, options["cv"]))
    blocks = calibrate_family(
        models,
        samples,
        options=options,
        scheme=calibrated_on,
        tolerance_rpm=speed_tolerance_rpm,
        keep={"rafi"} if rafi_model is not None and change is None else set(),
        log=log,
    )
    borrow_interval(models, blocks, SHARED_RIDGE, SHARED_GAIN, log=log)
    # the choice: training runs only, before any validation run is predicted
    offered = [*candidates, ENSEMBLE] if ENSEMBLE in models else candidates
    champion, selection, basis = _choose(cv, candidates, offered, ENSEMBLE in models, log)
    if champion in adaptations:  # a model from scratch far ahead: the prior's dynamics in doubt
        ahead = scratch_ahead(cv, candidates, list(adaptations))
        if ahead is not None:
            warning = dynamics_warning(*ahead)
            models[champion].add_warning(warning)
            log(f"warning: {warning['message']}")
        misfit = prior_misfit_warning(models, selection)
        if misfit is not None:
            models[champion].add_warning(misfit)
            log(f"warning: {misfit['message']}")
    log(f"champion (chosen on the training runs): {champion}")
    table, residuals, verdict = compare_models(
        models, runs_table, runs_frame, gates, champion=champion, return_residuals=True, return_verdict=True
    )
    summary = table.loc[table["scope"] == "model"].drop(columns=["scope", "run_id", "role", "speed_rpm"])
    summary = summary.assign(
        selected=summary["model"].map({k: describe_selection(m) for k, m in models.items()}),
    )
    summary = summary.merge(selection, on="model", how="left")
    summary = floor_columns(summary.merge(cv_unpredicted(cv), on="model", how="left"), offered, champion)
    per_run = table.loc[table["scope"] == "run"].drop(columns=["scope"])
    passed = bool(summary.loc[summary["model"] == champion, "passed"].astype(bool).all())
    return {
        "summary": summary.reset_index(drop=True),
        "per_run": per_run.reset_index(drop=True),
        "verdict": verdict,
        "residuals": residuals,
        "cv": cv,
        "selection": selection,
        "champion": champion,
        "champion_passed": passed,
        "selection_basis": basis,
        "best_name": champion,
        "best_artefact": models[champion].to_dict(),
        "models": models,
        "cv_memo": memo,
        "since_change": since_change,
    }
