"""One OLS regression per training speed (paper equations 4-9), with full diagnostics.

For every training speed all training runs at that speed are stacked (run by run,
in time order) and ``dz_um`` is regressed on the polynomial terms of the key
sensor rises (terms grammar in :mod:`rafi.method.model`; paper: the 11 terms of a full
quadratic plus the triple product in ``x1 = dT6``, ``x2 = dT8``, ``x3 = dT9``).
Samples with a missing ``dz_um`` or a missing key-sensor rise are dropped.

Standard errors
---------------
5 s samples are strongly autocorrelated, so ordinary OLS standard errors are far
too small. Next to them we report Newey-West (HAC) errors: statsmodels
``cov_type="hac-panel"`` with one *group per run* (Bartlett kernel,
``maxlags=hac_maxlags`` samples, clamped to the shortest run length - 1, small
sample correction ``n/(n-k)``), so lagged products never pair samples of two
different runs. With one run per speed this equals ``cov_type="HAC"`` with
``use_correction=True``. ``p_hac`` uses the same t distribution (``df_resid``) as
the ordinary ``p`` (``df_correction=False``: statsmodels would otherwise use
``n_runs - 1`` degrees of freedom, which is 0 with one run per speed).

Diagnostics per speed
---------------------
``n``, ``r2``, ``r2_adj``, ``rmse_um`` (``sqrt(mean(residual^2))``, the paper's
Table 3 metric, no degrees-of-freedom correction), ``paper_rmse_um`` (Table 3 at
that speed, else NaN), ``aic``, ``bic``, ``condition_number`` (statsmodels'
``condition_number`` of the unscaled design), ``durbin_watson`` (differences
taken within runs only), Breusch-Pagan (``bp_stat``, ``bp_p``; auxiliary
regression on the design, a constant added if the terms lack one), Jarque-Bera
(``jb_stat``, ``jb_p``) and ``max_vif``. VIF per regressor from statsmodels
``variance_inflation_factor`` on the design, intercept column excluded (a
regressor that is an exact combination of the others gets ``inf``).
"""

from __future__ import annotations

import hashlib
import math
import warnings
from dataclasses import dataclass

import numpy as np
import pandas as pd

from rafi.method import paper
from rafi.method.model import RafiModel, design_matrix, parse_terms
from rafi.method.paper import paper_value
from rafi.method.rank import speed_training_runs, training_speed_groups
from rafi.settings import MACHINE_DEFAULTS

__all__ = [
    "FitResult",
    "fit_rafi",
    "fit_speed",
    "PAPER_RMSE_UM",
    "paper_value",
    "COEFFICIENT_COLUMNS",
    "DIAGNOSTIC_COLUMNS",
    "VIF_COLUMNS",
]

PAPER_RMSE_UM = paper.RMSE_UM
"""Training RMSE (um) per speed, paper Table 3."""

COEFFICIENT_COLUMNS = ["speed_rpm", "term", "coef", "se", "se_hac", "t", "p", "p_hac"]
DIAGNOSTIC_COLUMNS = [
    "speed_rpm",
    "n",
    "r2",
    "r2_adj",
    "rmse_um",
    "paper_rmse_um",
    "aic",
    "bic",
    "condition_number",
    "durbin_watson",
    "bp_stat",
    "bp_p",
    "jb_stat",
    "jb_p",
    "max_vif",
]
VIF_COLUMNS = ["speed_rpm", "term", "vif"]


@dataclass
class FitResult:
    """Output of :func:`fit_rafi`.

    Attributes
    ----------
    coefficients : pandas.DataFrame
        ``speed_rpm``, ``term``, ``coef``, ``se``, ``se_hac``, ``t``, ``p``, ``p_hac``.
    diagnostics : pandas.DataFrame
        One row per speed, columns :data:`DIAGNOSTIC_COLUMNS`.
    vif : pandas.DataFrame
        ``speed_rpm``, ``term``, ``vif`` (intercept excluded).
    model : rafi.method.model.RafiModel
        The deployable model (per-speed coefficients, regressor ranges, ...).
    """

    coefficients: pd.DataFrame
    diagnostics: pd.DataFrame
    vif: pd.DataFrame
    model: RafiModel


def _durbin_watson_within(resid: np.ndarray, groups: np.ndarray) -> float:
    """Durbin-Watson with first differences taken inside each run only."""
    diff = np.diff(resid)
    same = groups[1:] == groups[:-1]
    denom = float(np.sum(resid**2))
    return float(np.sum(diff[same] ** 2) / denom) if denom > 0 else float("nan")


def _ols_coefficients(y: np.ndarray, design: np.ndarray) -> np.ndarray:
    """OLS coefficients computed exactly as statsmodels' ``OLS(y, X).fit()`` does
    (``pinv(X) @ y``), without importing statsmodels."""
    return np.linalg.pinv(design, rcond=1e-15, hermitian=False) @ y


def fit_speed(
    y,
    x,
    terms,
    *,
    groups=None,
    hac_maxlags: int = MACHINE_DEFAULTS["fit"]["hac_maxlags"],
    diagnostics: bool = True,
    solutions=None,
) -> dict:
    """Fit one speed's OLS and compute its coefficient table and diagnostics.

    Parameters
    ----------
    y : array_like, shape (n,)
        ``dz_um``.
    x : array_like, shape (n, n_vars)
        Key sensor rises (K), columns in key-sensor order.
    terms : sequence of str
        Terms grammar (:mod:`rafi.method.model`).
    groups : array_like of int, shape (n,), optional
        Run of each sample; samples of a run must be contiguous and in time order.
        Default: one run.
    hac_maxlags : int, default 60
        Newey-West lags in samples.
    diagnostics : bool, default True
        False: the coefficients only (same numbers, computed as statsmodels does, without
        importing it), for refits whose diagnostics nobody reads (cross-validation folds,
        the model family's RAFI variants). ``se`` .. ``p_hac`` are then NaN, ``vif`` is
        empty, ``diagnostics`` holds only ``n`` and ``rmse_um``, and ``result`` is None.
    solutions : object, optional
        With ``diagnostics=False``: a memo of solutions (``solution(key, compute)``) shared
        by the fits of one scope; see :func:`_coefficients_only`.

    Returns
    -------
    dict
        ``coef``, ``se``, ``se_hac``, ``t``, ``p``, ``p_hac`` (arrays in term
        order), ``vif`` (dict term -> VIF), ``diagnostics`` (dict), ``resid``,
        ``fitted`` and ``result`` (the statsmodels results object).
    """
    y = np.asarray(y, dtype=float)
    terms = list(terms)
    exps, design, groups = _checked_design(x, terms, groups)
    if not diagnostics:
        return _coefficients_only(y, design, solutions)

    from statsmodels.regression.linear_model import OLS

    res = OLS(y, design).fit()
    _, counts = np.unique(groups, return_counts=True)
    lags = int(max(0, min(int(hac_maxlags), int(counts.min()) - 1)))
    hac = res.get_robustcov_results(
        cov_type="hac-panel", groups=groups, maxlags=lags, use_correction="hac", df_correction=False
    )
    resid = np.asarray(res.resid)
    vif, tests = _residual_tests(res, design, exps, terms)
    vif_values = [v for v in vif.values() if not math.isnan(v)]
    diagnostics = {
        "n": int(design.shape[0]),
        "r2": float(res.rsquared),
        "r2_adj": float(res.rsquared_adj),
        "rmse_um": float(np.sqrt(np.mean(resid**2))),
        "aic": float(res.aic),
        "bic": float(res.bic),
        "condition_number": tests["condition_number"],
        "durbin_watson": _durbin_watson_within(resid, groups),
        "bp_stat": tests["bp_stat"],
        "bp_p": tests["bp_p"],
        "jb_stat": tests["jb_stat"],
        "jb_p": tests["jb_p"],
        "max_vif": float(max(vif_values)) if vif_values else float("nan"),
        "hac_maxlags_used": lags,
    }
    return {
        "coef": np.asarray(res.params, dtype=float),
        "se": np.asarray(res.bse, dtype=float),
        "se_hac": np.asarray(hac.bse, dtype=float),
        "t": np.asarray(res.tvalues, dtype=float),
        "p": np.asarray(res.pvalues, dtype=float),
        "p_hac": np.asarray(hac.pvalues, dtype=float),
        "vif": vif,
        "diagnostics": diagnostics,
        "resid": resid,
        "fitted": np.asarray(res.fittedvalues, dtype=float),
        "result": res,
    }


def _checked_design(x, terms: list[str], groups) -> tuple[list, np.ndarray, np.ndarray]:
    """The term exponents, the design matrix of ``x`` and the run of each sample (default: one run).

    Raises
    ------
    ValueError
        Not more samples than terms, or ``groups`` of the wrong length or not sorted.
    """
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        x = x[:, None]
    exps = parse_terms(terms, x.shape[1])
    design = design_matrix(x, exps)
    n, k = design.shape
    if n <= k:
        raise ValueError(f"{n} samples for {k} terms; need more samples than terms")
    groups = np.zeros(n, dtype=int) if groups is None else np.asarray(groups)
    if groups.shape != (n,):
        raise ValueError("groups must have one entry per sample")
    if np.any(groups[1:] < groups[:-1]):
        raise ValueError("groups must be sorted (samples of a run contiguous)")
    return exps, design, groups


def _coefficients_only(y: np.ndarray, design: np.ndarray, solutions=None) -> dict:
    """:func:`fit_speed`'s result without diagnostics: coefficients, residuals, ``n``, RMSE.

    With ``solutions`` (an object with ``solution(key, compute)``, e.g. the
    :class:`rafi.family.feature_memo.FeatureMemo` of a fit's scope) the coefficients are computed
    once per content of ``y`` and ``design``: the CV folds that keep a speed's runs refit the
    same samples, and the pseudo-inverse is most of a fold's time. The same function on the same
    bytes, so the coefficients are identical to the last bit."""
    if solutions is None:
        coef = _ols_coefficients(y, design)
    else:
        digest = hashlib.blake2b(digest_size=20)
        for a in (y, design):
            a = np.ascontiguousarray(a, dtype=float)
            digest.update(repr(a.shape).encode())
            digest.update(a.tobytes())
        coef = solutions.solution(("rafi_ols", digest.hexdigest()), lambda: _ols_coefficients(y, design))
    fitted = design @ coef
    resid = y - fitted
    nan = np.full(design.shape[1], np.nan)
    return {
        "coef": coef,
        "se": nan,
        "se_hac": nan,
        "t": nan,
        "p": nan,
        "p_hac": nan,
        "vif": {},
        "diagnostics": {"n": int(design.shape[0]), "rmse_um": float(np.sqrt(np.mean(resid**2)))},
        "resid": resid,
        "fitted": fitted,
        "result": None,
    }


def _residual_tests(res, design: np.ndarray, exps, terms: list[str]) -> tuple[dict, dict]:
    """VIF per regressor (intercept excluded) and the tests of a fitted OLS (statsmodels
    ``res``): ``bp_stat``, ``bp_p`` (Breusch-Pagan, NaN where it fails), ``jb_stat``, ``jb_p``,
    ``condition_number``."""
    from statsmodels.stats.diagnostic import het_breuschpagan
    from statsmodels.stats.outliers_influence import variance_inflation_factor
    from statsmodels.stats.stattools import jarque_bera

    n, k = design.shape
    resid = np.asarray(res.resid)
    intercept = [j for j, e in enumerate(exps) if not e.any()]
    vif: dict[str, float] = {}
    with warnings.catch_warnings(), np.errstate(divide="ignore", invalid="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        warnings.simplefilter("ignore", UserWarning)  # "poorly conditioned": see condition_number
        for j, term in enumerate(terms):
            if j in intercept:
                continue
            if k == 1:
                vif[term] = 1.0
                continue
            vif[term] = float(variance_inflation_factor(design, j))
        bp_exog = design if intercept else np.column_stack([np.ones(n), design])
        try:
            bp_stat, bp_p, _, _ = het_breuschpagan(resid, bp_exog)
        except (ValueError, np.linalg.LinAlgError):
            bp_stat, bp_p = float("nan"), float("nan")
        jb_stat, jb_p, _, _ = jarque_bera(resid)
        cond = float(res.condition_number)
    tests = {
        "bp_stat": float(bp_stat),
        "bp_p": float(bp_p),
        "jb_stat": float(jb_stat),
        "jb_p": float(jb_p),
        "condition_number": cond,
    }
    return vif, tests


def fit_rafi(
    runs_table: pd.DataFrame,
    runs_frame: pd.DataFrame,
    *,
    key_sensors,
    terms,
    hac_maxlags: int = MACHINE_DEFAULTS["fit"]["hac_maxlags"],
    reference: dict | None = None,
    machine: str | None = None,
    fuzzy_outside: str = MACHINE_DEFAULTS["fuzzy"]["outside"],
    speed_tolerance_rpm: float = MACHINE_DEFAULTS["speed_tolerance_rpm"],
    config: dict | None = None,
    diagnostics: bool = True,
    solutions=None,
) -> FitResult:
    """Fit the RAFI model: one OLS per training speed on the key sensors' rises.

    Parameters
    ----------
    runs_table : pandas.DataFrame
        One row per run; ``role == "training"`` runs are used, grouped by speed
        (:func:`rafi.method.rank.training_speed_groups`). If it has ``file`` and
        ``sha256`` columns they are stored in the model's ``data``.
    runs_frame : pandas.DataFrame
        Stacked samples: ``run_id``, ``t_s``, ``dT<i>`` of the key sensors, ``dz_um``.
    key_sensors : sequence of str
        E.g. ``["T6", "T8", "T9"]`` (``x1``, ``x2``, ``x3``).
    terms : sequence of str
        Terms grammar, e.g. the config's 11 terms.
    hac_maxlags : int, default 60
        Newey-West lags in samples (see module docstring).
    reference : dict, optional
        Reference rule stored in the model, e.g. ``{"rule": "run_start", "window_s": 60}``.
    machine : str, optional
        Machine name stored in the model.
    fuzzy_outside : str, default "edge"
        What the model does outside the trained speeds (stored in the model).
    speed_tolerance_rpm : float, default 50
        Speeds this close to a training speed count as that speed (stored in the model).
    config : dict, optional
        The settings that made the model, stored in the artefact for provenance.
    diagnostics : bool, default True
        False: coefficients only (:func:`fit_speed`); the model is the same, the
        coefficient table's standard errors and the diagnostics are NaN, ``vif`` is empty.
    solutions : object, optional
        With ``diagnostics=False``: the per-speed solutions shared by the fits of one scope
        (:func:`fit_speed`); the CV of the model family passes its feature memo.

    Returns
    -------
    FitResult

    Raises
    ------
    ValueError
        No training runs, missing columns, a term using a sensor that is not a key
        sensor, or too few samples at a speed.
    """
    key_sensors = [str(s) for s in key_sensors]
    terms = [str(t) for t in terms]
    if not key_sensors:
        raise ValueError("key_sensors is empty")
    parse_terms(terms, len(key_sensors))
    xcols = [f"d{s}" for s in key_sensors]
    missing = [c for c in ["run_id", "dz_um", *xcols] if c not in runs_frame.columns]
    if missing:
        raise ValueError(f"runs_frame lacks column(s) {missing}")
    groups = training_speed_groups(runs_table)

    model = RafiModel(
        key_sensors,
        terms,
        reference=reference,
        machine=machine,
        data=training_files(runs_table),
        fuzzy_outside=fuzzy_outside,
        speed_tolerance_rpm=speed_tolerance_rpm,
        config=config,
    )
    coef_rows, diag_rows, vif_rows = [], [], []
    for speed, ids in groups.items():
        x, y, runs = speed_samples(runs_frame, ids, xcols, speed)
        try:
            fit = fit_speed(
                y,
                x,
                terms,
                groups=runs,
                hac_maxlags=hac_maxlags,
                diagnostics=diagnostics,
                solutions=solutions,
            )
        except ValueError as exc:
            raise ValueError(f"fit at {speed} r/min: {exc}") from None
        coefs, diag, vifs = speed_rows(speed, terms, fit)
        coef_rows += coefs
        diag_rows.append(diag)
        vif_rows += vifs
        ranges = {s: (float(np.min(x[:, i])), float(np.max(x[:, i]))) for i, s in enumerate(key_sensors)}
        position, used = {rid: i for i, rid in enumerate(ids)}, set(runs.tolist())
        used_runs = [rid for rid in ids if position[rid] in used]
        model.add_speed_model(
            speed, fit["coef"], ranges, train_runs=used_runs, rmse_um=diag["rmse_um"], n=diag["n"]
        )

    coefficients = pd.DataFrame(coef_rows, columns=COEFFICIENT_COLUMNS)
    diagnostics = pd.DataFrame(diag_rows, columns=DIAGNOSTIC_COLUMNS)
    vif = pd.DataFrame(vif_rows, columns=VIF_COLUMNS)
    for tab in (coefficients, diagnostics, vif):
        tab["speed_rpm"] = tab["speed_rpm"].astype("int64")
    diagnostics["n"] = diagnostics["n"].astype("int64")
    return FitResult(coefficients=coefficients, diagnostics=diagnostics, vif=vif, model=model)


def training_files(runs_table: pd.DataFrame) -> dict:
    """File -> SHA-256 (None if unknown) of the training runs RAFI learns from
    (:func:`rafi.method.rank.speed_training_runs`); empty without ``file`` and ``sha256``."""
    data: dict[str, str] = {}
    if {"file", "sha256"} <= set(runs_table.columns):
        train = speed_training_runs(runs_table)
        for f, h in zip(train["file"], train["sha256"]):
            if pd.notna(f):
                data[str(f)] = None if pd.isna(h) else str(h)
    return data


def speed_samples(
    runs_frame: pd.DataFrame, ids: list[str], xcols: list[str], speed
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The regression data of one training speed: the runs ``ids`` stacked in that order, each in
    time order (``t_s``, where present), samples with a missing ``dz_um`` or rise dropped.

    Returns the rises ``x`` (columns ``xcols``), ``dz_um`` and each sample's run (its index in
    ``ids``). ValueError (naming ``speed``) when no complete sample is left.
    """
    need = ["run_id", "dz_um", *xcols]
    code = {rid: i for i, rid in enumerate(ids)}
    sub = runs_frame.loc[
        runs_frame["run_id"].astype(str).isin(ids), need + (["t_s"] if "t_s" in runs_frame else [])
    ]
    sub = sub.assign(_run=sub["run_id"].astype(str).map(code))
    sub = sub.sort_values(["_run", "t_s"] if "t_s" in sub.columns else ["_run"], kind="stable")
    sub = sub.loc[sub[["dz_um", *xcols]].notna().all(axis=1)]
    if sub.empty:
        raise ValueError(
            f"no complete samples (dz_um and {', '.join(xcols)}) in the training runs at {speed} r/min: {ids}"
        )
    return (
        sub[xcols].to_numpy(dtype=float),
        sub["dz_um"].to_numpy(dtype=float),
        sub["_run"].to_numpy(dtype=int),
    )


def speed_rows(speed, terms: list[str], fit: dict) -> tuple[list[dict], dict, list[dict]]:
    """One speed's rows of ``coefficients.csv`` (per term), ``diagnostics.csv`` (its paper
    RMSE added) and ``vif.csv``, from a :func:`fit_speed` result."""
    coefs = [
        {
            "speed_rpm": speed,
            "term": term,
            **{c: fit[c][j] for c in ("coef", "se", "se_hac", "t", "p", "p_hac")},
        }
        for j, term in enumerate(terms)
    ]
    vifs = [{"speed_rpm": speed, "term": term, "vif": v} for term, v in fit["vif"].items()]
    d = fit["diagnostics"]
    d = {
        "speed_rpm": speed,
        **{c: d.get(c, float("nan")) for c in DIAGNOSTIC_COLUMNS[1:]},
        "paper_rmse_um": paper_value(speed, PAPER_RMSE_UM),
    }
    return coefs, {c: d[c] for c in DIAGNOSTIC_COLUMNS}, vifs
