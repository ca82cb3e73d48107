"""The pure parts of benchmarks/bench_selection_rules.py: the speed-with-cool-down folds, the
selection rules it compares and the ensemble's weights (the experiment itself is a benchmark)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from bench_loader import load_bench

from rafi.family import crossval

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    yield load_bench("bench_selection_rules")
    sys.modules.pop("bench_selection_rules", None)


@pytest.fixture(scope="module")
def stacking():
    yield load_bench("_stacking")
    sys.modules.pop("_stacking", None)


def _schedule() -> pd.DataFrame:
    """FL_THERMAL's training part: 1250, rest, 2500, rest, 3750, rest, 5000; a rest before
    the first run, and a validation rest after the last (neither in a fold)."""
    rows = [
        ("r0", 0, "idle", "excluded"),
        ("r1", 1250, "constant", "training"),
        ("r2", 0, "idle", "training"),
        ("r3", 2500, "constant", "training"),
        ("r4", 0, "idle", "training"),
        ("r5", 3750, "constant", "training"),
        ("r6", 0, "idle", "training"),
        ("r7", 5000, "constant", "training"),
        ("r8", 0, "idle", "validation_idle"),
    ]
    t = pd.DataFrame(rows, columns=["run_id", "speed_rpm", "kind", "role"])
    return t.assign(start_s=np.arange(len(t)) * 14_400.0)


def test_speed_folds_hold_out_a_speed_with_the_cool_down_after_it(bench):
    folds = list(bench.speed_with_cooldown_folds(_schedule()))
    assert [test for _, test in folds] == [["r1", "r2"], ["r3", "r4"], ["r5", "r6"], ["r7"]]
    for train, test in folds:
        assert set(train) | set(test) == {"r1", "r2", "r3", "r4", "r5", "r6", "r7"}
        assert not set(train) & set(test)


def test_speed_folds_join_runs_at_one_speed_and_a_leading_rest_is_its_own_fold(bench):
    t = _schedule()
    t.loc[t["run_id"] == "r0", "role"] = "training"
    t.loc[t["run_id"] == "r5", "speed_rpm"] = 1260  # within 50 r/min of r1: the same speed
    tests = [test for _, test in bench.speed_with_cooldown_folds(t)]
    assert tests == [["r0"], ["r1", "r2", "r5", "r6"], ["r3", "r4"], ["r7"]]


def test_the_experiment_scheme_is_known_only_while_it_runs(bench):
    with bench.extra_scheme(bench.SPEED_SCHEME, bench.speed_with_cooldown_folds):
        assert len(list(crossval.split_runs(_schedule(), bench.SPEED_SCHEME))) == 4
    assert bench.SPEED_SCHEME not in crossval.SCHEMES
    with pytest.raises(ValueError, match="unknown CV scheme"):
        crossval.split_runs(_schedule(), bench.SPEED_SCHEME)


def _cv(scores: dict) -> pd.DataFrame:
    rows = [
        {"model": m, "test_runs": f"r{i}", "max_abs_after_um": v, "rmse_um": v / 2}
        for m, values in scores.items()
        for i, v in enumerate(values)
    ]
    return pd.DataFrame(rows)


def test_rules_differ_where_the_lower_mean_is_the_less_steady(bench):
    # dynamic: lower mean (5.0), one bad fold; grey_box: mean 5.5, steady
    cv = _cv({"dynamic": [2.0, 2.0, 2.0, 2.0, 17.0], "grey_box": [5.0, 5.5, 6.0, 5.5, 5.5]})
    assert bench.rule_mean_max(cv) == "dynamic"
    assert bench.rule_mean_plus_se(cv) == "grey_box"
    # dynamic is the simpler kind and the best mean: the one-SE rule keeps it
    assert bench.rule_one_se_simplest(cv) == "dynamic"


def test_one_se_rule_moves_to_a_simpler_kind_within_one_standard_error(bench):
    cv = _cv({"grey_box": [4.0, 5.0, 6.0], "ridge_global": [4.5, 5.5, 6.5], "rafi_linear": [9.0, 9.0, 9.0]})
    assert bench.rule_mean_max(cv) == "grey_box"
    assert bench.rule_one_se_simplest(cv) == "ridge_global"  # 5.5 <= 5.0 + 0.577


def test_the_rule_without_a_kind_picks_the_best_of_the_others(bench):
    cv = _cv({"temperature_ridge": [1.0, 2.0], "dynamic": [2.0, 2.5], "grey_box": [3.0, 3.0]})
    assert bench.rule_mean_max(cv) == "temperature_ridge"
    assert bench.rule_without("temperature_ridge")(cv) == "dynamic"
    assert bench.rule_without("grey_box")(cv) == "temperature_ridge"


def test_a_model_missing_a_fold_is_never_chosen_and_gets_no_weight(bench):
    cv = _cv({"dynamic": [1.0, np.nan], "grey_box": [3.0, 4.0]})
    for rule in (bench.rule_mean_max, bench.rule_mean_plus_se, bench.rule_one_se_simplest):
        assert rule(cv) == "grey_box"
    assert bench.ensemble_weights(cv) == {"grey_box": pytest.approx(1.0)}


def test_ensemble_weights_are_inverse_square_cv_losses(bench):
    w = bench.ensemble_weights(_cv({"dynamic": [1.0, 3.0], "grey_box": [4.0, 4.0]}))
    assert w["dynamic"] == pytest.approx(0.8) and w["grey_box"] == pytest.approx(0.2)
    dz = np.array([1.0, 2.0, 4.0])
    score = bench.ensemble_score(dz, {"dynamic": dz + 1.0, "grey_box": dz - 4.0}, w)
    assert score["max"] == pytest.approx(0.0, abs=1e-12)


def test_ridge_floor_keeps_the_plain_ridge_unless_a_kind_beats_it_by_more_than_one_se(bench):
    ridge = [3.0, 3.0, 3.0, 3.0]
    # dynamic is better on average (2.5 < 3) but its paired differences (-2, -2, +1, +1) have
    # mean -0.5 and standard error 0.866: not more than one SE -> the plain ridge
    noisy = _cv({"temperature_ridge": ridge, "dynamic": [1.0, 1.0, 4.0, 4.0], "grey_box": [5.0] * 4})
    assert bench.rule_mean_max(noisy) == "dynamic"
    assert bench.rule_ridge_floor(noisy) == "temperature_ridge"
    # grey_box better on every held-out run (-0.5 +- 0.05): it beats it; dynamic too, but grey_box's
    # mean is the lower -> the current rule among those that beat the ridge
    clear = _cv(
        {"temperature_ridge": ridge, "dynamic": [2.7, 2.8, 2.7, 2.8], "grey_box": [2.4, 2.5, 2.6, 2.5]}
    )
    assert bench.rule_ridge_floor(clear) == "grey_box"
    # without the plain ridge among the kinds, or with a run it cannot predict: the current rule
    assert bench.rule_ridge_floor(_cv({"dynamic": [1.0, 1.0], "grey_box": [2.0, 2.0]})) == "dynamic"
    broken = _cv({"temperature_ridge": [np.nan, 3.0], "dynamic": [4.0, 4.0], "grey_box": [5.0, 5.0]})
    assert bench.rule_ridge_floor(broken) == "dynamic"


def test_average_within_se_weighs_the_kinds_near_the_best_alike(bench):
    # grey_box mean 5.0, SE 0.577: ridge_global (5.5) is near, rafi_linear (9.0) is not
    cv = _cv({"grey_box": [4.0, 5.0, 6.0], "ridge_global": [4.5, 5.5, 6.5], "rafi_linear": [9.0, 9.0, 9.0]})
    assert bench.within_se_weights(cv) == {"grey_box": 0.5, "ridge_global": 0.5}
    assert bench.within_se_weights(_cv({"a": [1.0, 1.0], "b": [np.nan, 1.0]})) == {"a": 1.0}
    assert bench.AVERAGE in bench.BLENDS and "ridge_floor" in bench.RULES


def test_the_current_rule_reads_the_forward_rows_beside_the_whole_run_rows(bench):
    whole = _cv({"dynamic": [2.0, 2.0, 2.0], "grey_box": [3.0, 3.0, 3.0]})
    ahead = _cv({"dynamic": [9.0, 9.0], "grey_box": [4.0, 4.0]}).assign(scheme=bench.FORWARD, fold=0)
    cvs = {"leave_one_run_out": whole, bench.FORWARD: ahead}
    scheme, rule = bench.RULES["mean_max_forward"]
    assert bench.schemes_of(scheme) == ("leave_one_run_out", bench.FORWARD)
    assert len(bench.rows_of(cvs, scheme)) == 10
    # whole-run alone: dynamic (2 < 3); with the forward folds: (2 + 9) / 2 > (3 + 4) / 2
    assert bench.RULES["mean_max"][1](bench.rows_of(cvs, bench.RULES["mean_max"][0])) == "dynamic"
    assert rule(bench.rows_of(cvs, scheme)) == "grey_box"


# ----------------------------------------------------------------------------- the stacked ensemble


def _brute_force(a: np.ndarray, b: np.ndarray, step: float = 0.005) -> tuple[np.ndarray, float]:
    """The best point of a grid over the 3-simplex and its loss."""
    best, loss = None, np.inf
    for w0 in np.arange(0.0, 1.0 + 1e-12, step):
        for w1 in np.arange(0.0, 1.0 - w0 + 1e-12, step):
            w = np.array([w0, w1, max(0.0, 1.0 - w0 - w1)])
            val = float(np.sum((a @ w - b) ** 2))
            if val < loss:
                best, loss = w, val
    return best, loss


def test_simplex_least_squares_matches_a_known_answer_and_a_brute_force_grid(stacking):
    rng = np.random.default_rng(7)
    # a known interior answer: b is exactly 0.2 a0 + 0.5 a1 + 0.3 a2
    a = rng.normal(size=(40, 3))
    w = stacking.simplex_least_squares(a, a @ np.array([0.2, 0.5, 0.3]))
    assert w == pytest.approx([0.2, 0.5, 0.3], abs=1e-6)
    # an answer on an edge of the simplex: the unconstrained optimum has a negative weight
    for seed in range(5):
        a = np.random.default_rng(seed).normal(size=(30, 3))
        b = a @ np.array([1.4, -0.6, 0.2]) + 0.1 * np.random.default_rng(seed + 10).normal(size=30)
        w = stacking.simplex_least_squares(a, b)
        assert (w >= 0).all() and w.sum() == pytest.approx(1.0, abs=1e-9)
        grid, grid_loss = _brute_force(a, b)
        loss = float(np.sum((a @ w - b) ** 2))
        assert loss <= grid_loss + 1e-9  # no grid point is better
        assert w == pytest.approx(grid, abs=0.01)
    # the residual form (b = 0): two kinds with opposite errors cancel
    r = np.array([[1.0, -1.0], [2.0, -2.0], [-1.0, 1.0]])
    assert stacking.simplex_least_squares(r) == pytest.approx([0.5, 0.5], abs=1e-6)


def _oof(kind: str, residuals: dict, scheme_prefix: str = "") -> pd.DataFrame:
    """OOF samples of one kind: unit -> residuals, one sample per 15 s."""
    rows = [
        {"model": kind, "unit": f"{scheme_prefix}{unit}", "run_id": unit, "t_s": 15.0 * i, "residual_um": v}
        for unit, values in residuals.items()
        for i, v in enumerate(values)
    ]
    return pd.DataFrame(rows)


def _dz_at(dz: dict) -> pd.Series:
    keys = [(unit, 15.0 * i) for unit, values in dz.items() for i in range(len(values))]
    return pd.Series(
        [v for values in dz.values() for v in values], index=pd.MultiIndex.from_tuples(keys), dtype=float
    )


def test_stacking_weighs_each_held_out_unit_the_same_not_each_sample(stacking):
    # run "long" (9 samples): a errs +1, b errs -1; run "short" (1 sample): a errs +3, b errs 0.
    # Per unit: loss = (w - (1 - w))^2 + (3w)^2 -> w_a = 2 / 13; per sample it would be 18 / 45.
    long, short = [1.0] * 9, [3.0]
    oof = pd.concat(
        [_oof("a", {"long": long, "short": short}), _oof("b", {"long": [-1.0] * 9, "short": [0.0]})]
    )
    dz = _dz_at({"long": [0.0] * 9, "short": [0.0]})
    _, units, schemes = stacking.residual_matrix({"leave_one_run_out": oof}, ["a", "b"], dz)
    w = stacking.sample_weights(units, schemes)
    assert w.sum() == pytest.approx(1.0)
    assert sorted(set(np.round(w, 9))) == pytest.approx([1 / 18, 1 / 2])
    weights = stacking.stacked_weights({"leave_one_run_out": oof}, ["a", "b"], dz)
    assert weights["a"] == pytest.approx(2 / 13, abs=1e-6)
    assert weights["a"] + weights["b"] == pytest.approx(1.0)


def test_stacking_weighs_each_scheme_the_same(stacking):
    whole = pd.concat([_oof("a", {"r1": [1.0], "r2": [1.0]}), _oof("b", {"r1": [-1.0], "r2": [-1.0]})])
    ahead = pd.concat([_oof("a", {"r2": [2.0]}, "f0:"), _oof("b", {"r2": [0.0]}, "f0:")])
    dz = _dz_at({"r1": [0.0], "r2": [0.0]})
    _, units, schemes = stacking.residual_matrix(
        {"leave_one_run_out": whole, "forward_2": ahead, "forward_9": ahead[:0]}, ["a", "b"], dz
    )
    w = stacking.sample_weights(units, schemes)
    assert list(w) == pytest.approx([0.25, 0.25, 0.5])  # two whole-run units, one forward unit


def test_a_kind_with_no_finite_prediction_on_a_held_out_run_gets_weight_zero(bench, stacking):
    dz = _dz_at({"r1": [0.0, 0.0], "r2": [0.0, 0.0]})
    oof = pd.concat(
        [
            _oof("dynamic", {"r1": [0.1, 0.1], "r2": [np.nan, np.nan]}),  # the best, but not on r2
            _oof("grey_box", {"r1": [1.0, 1.0], "r2": [1.0, 1.0]}),
            _oof("ridge_global", {"r1": [-2.0, -2.0], "r2": [-2.0, -2.0]}),
        ]
    )
    w = stacking.stacked_weights({"leave_one_run_out": oof}, ["dynamic", "grey_box", "ridge_global"], dz)
    assert w["dynamic"] == 0.0
    assert w["grey_box"] == pytest.approx(2 / 3, abs=1e-6)
    assert w["ridge_global"] == pytest.approx(1 / 3, abs=1e-6)
    assert bench.positive(w) == {"grey_box": w["grey_box"], "ridge_global": w["ridge_global"]}


def test_a_nan_on_a_few_samples_leaves_those_samples_out_not_the_kind(stacking):
    # dynamic drops out on one sample of r2 (a sensor): the sample leaves the fit, dynamic stays
    dz = _dz_at({"r1": [0.0, 0.0], "r2": [0.0, 0.0, 0.0]})
    oof = pd.concat(
        [
            _oof("dynamic", {"r1": [1.0, 1.0], "r2": [np.nan, 1.0, 1.0]}),
            _oof("grey_box", {"r1": [-1.0, -1.0], "r2": [50.0, -1.0, -1.0]}),
        ]
    )
    w = stacking.stacked_weights({"leave_one_run_out": oof}, ["dynamic", "grey_box"], dz)
    assert w["dynamic"] == pytest.approx(0.5, abs=1e-6)  # grey_box's 50 um sample is not in the fit
    r, units, _ = stacking.residual_matrix({"leave_one_run_out": oof}, ["dynamic", "grey_box"], dz)
    assert stacking.usable_kinds(r, units) == [0, 1]
    # a measurement that is missing (dz NaN: every kind NaN) is no sample at all
    dz_gap = _dz_at({"r1": [0.0, np.nan]})
    gap = pd.concat([_oof("dynamic", {"r1": [1.0, np.nan]}), _oof("grey_box", {"r1": [-1.0, np.nan]})])
    r_gap, _, _ = stacking.residual_matrix({"leave_one_run_out": gap}, ["dynamic", "grey_box"], dz_gap)
    assert r_gap.tolist() == [[1.0, -1.0]]


def test_a_fold_a_kind_cannot_fit_counts_as_predicting_zero(stacking):
    # rafi has no OOF sample on run r2 (it could not fit that fold): its residual there is dz
    dz = _dz_at({"r1": [1.0], "r2": [4.0]})
    oof = pd.concat([_oof("rafi", {"r1": [0.0]}), _oof("grey_box", {"r1": [2.0], "r2": [-4.0]})])
    r, _, _ = stacking.residual_matrix({"leave_one_run_out": oof}, ["rafi", "grey_box"], dz)
    assert r.tolist() == [[0.0, 2.0], [4.0, -4.0]]
    w = stacking.stacked_weights({"leave_one_run_out": oof}, ["rafi", "grey_box"], dz)
    # min over w of (2 (1 - w))^2 + (8 w - 4)^2 (both units weigh the same): w = 9 / 17
    assert w["rafi"] == pytest.approx(9 / 17, abs=1e-6)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_weighted_median_blend_is_statsmodels_weighted_median(bench, seed):
    from statsmodels.stats.weightstats import DescrStatsW

    rng = np.random.default_rng(seed)
    predictions = rng.normal(size=(400, 5))
    predictions[rng.random(predictions.shape) < 0.3] = np.nan
    # integer weights make exact halves (the two middle values are averaged), zeros are left out
    weights = rng.random(5) if seed == 0 else rng.integers(0, 3, 5).astype(float)
    got = bench.blend_median(predictions, weights)
    for row, value in zip(predictions, got):
        usable = np.isfinite(row) & (weights > 0)
        if not usable.any():
            assert np.isnan(value)
            continue
        oracle = DescrStatsW(row[usable], weights=weights[usable]).quantile([0.5], return_pandas=False)[0]
        assert value == pytest.approx(oracle, abs=1e-12)


def test_the_weighted_median_blend_holds_against_one_member_running_away(bench):
    sane = np.array([[1.0, 1.2, 0.9, 500.0]])
    assert bench.blend_median(sane, np.array([0.4, 0.25, 0.15, 0.2]))[0] == pytest.approx(1.0)
    assert (
        bench.ensemble_score(
            np.array([1.0]), {"a": np.array([1.0]), "b": np.array([99.0])}, {"a": 0.6, "b": 0.4}, median=True
        )["max"]
        == 0.0
    )
