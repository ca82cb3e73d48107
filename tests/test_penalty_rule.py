"""The ridge kinds' penalty rule (``models.ridge_alpha_rule``): the folds' scores against
statsmodels' ridge refitted on each fold, the one-standard-error rule on curves whose answer is
known, and the kinds choosing by it."""

from __future__ import annotations

import numpy as np
import pytest
import statsmodels.api as sm

from rafi.family.compare import load_any, make_model, save_any
from rafi.family.dynamic import DynamicRidge
from rafi.family.ridge import cv_fold_scores, cv_scores, one_se_alpha
from rafi.family.ridge_global import RidgeGlobal
from rafi.settings import MACHINE_DEFAULTS
from rafi.twin.synthetic_runs import make_synthetic_runs

ALPHAS = [1e-6, 1e-4, 1e-2, 1.0]


def _folds(seed: int = 0, runs: int = 5, n: int = 40):
    """Whole-run folds (leave one run out) of a collinear design, as
    :func:`rafi.family.ridge.cv_folds` lays them out, and the raw per-run data."""
    rng = np.random.default_rng(seed)
    data = []
    for _ in range(runs):
        t = rng.normal(size=(n, 1))
        x = np.hstack([t, t + 0.01 * rng.normal(size=(n, 1)), rng.normal(size=(n, 1))])
        y = x @ np.array([2.0, -1.0, 0.5]) + 0.3 * rng.normal(size=n)
        data.append((x, y))
    folds = []
    for k in range(runs):
        train = [d for i, d in enumerate(data) if i != k]
        xt, yt = data[k]
        folds.append(
            {
                "g": sum(x.T @ x for x, _ in train),
                "c": sum(x.T @ y for x, y in train),
                "n": sum(len(y) for _, y in train),
                "x_test": xt,
                "y_test": yt,
                "g_test": xt.T @ xt,
                "c_test": xt.T @ yt,
                "yy_test": float(yt @ yt),
                "solution_key": None,
            }
        )
    return folds, data


@pytest.mark.parametrize("metric", ["rmse", "max_abs"])
def test_fold_scores_are_those_of_statsmodels_ridge_refitted_on_each_fold(metric):
    folds, data = _folds()
    cols = np.arange(3)
    got = cv_fold_scores(folds, cols, ALPHAS, metric)
    assert got.shape == (len(data), len(ALPHAS))
    for k in range(len(data)):
        x = np.vstack([d[0] for i, d in enumerate(data) if i != k])
        y = np.concatenate([d[1] for i, d in enumerate(data) if i != k])
        scale = np.sqrt(np.mean(x**2, axis=0))  # the kinds' unit-RMS scaling of the training rows
        xt, yt = data[k]
        for j, alpha in enumerate(ALPHAS):
            b = sm.OLS(y, x / scale).fit_regularized(alpha=alpha, L1_wt=0.0).params / scale
            res = yt - xt @ b
            want = np.sqrt(np.mean(res**2)) if metric == "rmse" else np.max(np.abs(res))
            assert got[k, j] == pytest.approx(want, rel=1e-7)
    pooled = cv_scores(folds, cols, ALPHAS, metric)
    if metric == "rmse":  # equal-sized folds: the pooled RMSE is the RMS of the folds'
        assert pooled == pytest.approx(np.sqrt(np.mean(got**2, axis=0)), rel=1e-10)
    else:
        assert pooled == pytest.approx(np.mean(got, axis=0), rel=1e-10)


def test_one_se_takes_the_largest_penalty_within_one_standard_error():
    alphas = [1e-3, 1e-2, 1e-1, 1.0, 10.0]
    scores = np.array([1.00, 1.04, 1.30, 1.08, 2.00])
    # the best alpha's four folds: 0.8, 1.0, 1.0, 1.2 -> sd 0.1633, SE 0.0816
    folds = np.tile(scores, (4, 1))
    folds[:, 0] = [0.8, 1.0, 1.0, 1.2]
    # within 1.0816: 1e-3, 1e-2 and, past the bump at 0.1, 1.0 (1.08): the largest is 1.0
    assert one_se_alpha(scores, folds, alphas) == 1.0
    folds[:, 0] = [0.95, 1.0, 1.0, 1.05]  # SE 0.0204: only 1e-3 itself
    assert one_se_alpha(scores, folds, alphas) == 1e-3
    assert one_se_alpha(scores, folds[:1], alphas) == 1e-3  # one fold: no standard error


def _collinear_runs():
    """Runs whose sensors lag one another closely (T2 ~ T1) under a noisy probe: a flat CV curve
    in the penalty, where the rules differ (1e-6 against 1e-4 on this seed)."""
    return make_synthetic_runs(
        seed=3, sample_s=120.0, n_sensors=4, sensor_taus_s=[900, 950, 1000, 1050], noise_um=0.5
    )


@pytest.mark.parametrize("cls", [RidgeGlobal, DynamicRidge])
def test_one_se_never_shrinks_less_than_the_lowest_score_and_stays_within_its_error(cls):
    table, frame = _collinear_runs()
    kw = {"alphas": [1e-8, 1e-6, 1e-4, 1e-2, 1.0]} | (
        {"taus_s": [0, 600], "max_taus": 1} if cls is DynamicRidge else {}
    )
    low = cls(**kw).fit(table, frame)
    se = cls(alpha_rule="one_se", **kw).fit(table, frame)
    assert se.alpha_ > low.alpha_  # the generator's flat curve: the rules differ
    assert low.to_dict()["hyperparameters"].get("alpha_rule") is None  # as before the setting
    assert se.to_dict()["hyperparameters"]["alpha_rule"] == "one_se"
    cv = {(str(r.get("taus_s")), str(r.get("speed_gain")), r["alpha"]): r["score_um"] for r in se.cv_table_}
    design = (str(se.taus_), str(se.speed_gain_))
    best = min(v for (t, g, _), v in cv.items() if (t, g) == design)
    assert cv[(*design, se.alpha_)] >= best
    assert np.sum((se.coef_ * se.scale_) ** 2) < np.sum((low.coef_ * low.scale_) ** 2)  # more shrinkage


def test_the_rule_reaches_the_kinds_from_the_settings_and_survives_the_artefact(tmp_path):
    table, frame = _collinear_runs()
    options = {**MACHINE_DEFAULTS["models"], "ridge_alpha_rule": "one_se", "dynamic_taus_s": [0, 600]}
    m = make_model(
        "dynamic",
        key_sensors=[],
        terms=[],
        reference=MACHINE_DEFAULTS["reference"],
        machine="m",
        options=options,
    )
    assert m.alpha_rule == "one_se"
    m.fit(table, frame)
    save_any(m, tmp_path / "m.json")
    back = load_any(tmp_path / "m.json")
    assert back.alpha_rule == "one_se" and back.alpha_ == m.alpha_
    np.testing.assert_array_equal(back.predict(frame), m.predict(frame))


def test_an_unknown_rule_is_refused_by_fit():
    table, frame = _collinear_runs()
    m = RidgeGlobal(alpha_rule="lowest")  # the constructor checks nothing
    with pytest.raises(ValueError, match="alpha_rule"):
        m.fit(table, frame)
