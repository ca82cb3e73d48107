"""The training envelope of the ridge kinds (rafi.family.envelope): inside it nothing changes,
outside it each feature is held at the envelope's edge, so a model never extrapolates freely.

Known truth from the twin's logs (rafi.twin.synthetic_logs): a machine trained at 3000 and
6000 r/min and tested for hours at 9000 r/min is hotter than ever in training; with the smallest
penalty (the runaway's grid edge) every ridge kind, bounded, is better than no compensation on
that run, and at most a fraction of a micrometre worse than its free extrapolation on this
linear physics.
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from hotter_runs import hotter_than_ever_runs, streamed
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from rafi.family.envelope import (
    OUTPUT_MARGIN,
    bound_features,
    bound_output,
    envelope_bounds,
    fit_envelope,
    join_envelope,
    output_bounds,
)
from rafi.twin.synthetic_runs import small_family_model

RIDGE_KINDS = ["temperature_ridge", "dynamic", "ridge_global", "grey_box"]
finite = st.floats(-1e3, 1e3, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(
    train=arrays(float, st.tuples(st.integers(2, 20), st.integers(1, 5)), elements=finite),
    test=st.lists(finite, min_size=5, max_size=5),
    margin=st.floats(0, 3),
)
def test_inside_nothing_changes_outside_a_feature_sits_on_the_edge(train, test, margin):
    env = fit_envelope(train, margin=margin)
    lo, hi = envelope_bounds(env, train.shape[1])
    span = train.max(axis=0) - train.min(axis=0)
    np.testing.assert_allclose(lo, train.min(axis=0) - margin * span)
    np.testing.assert_allclose(hi, train.max(axis=0) + margin * span)
    x = np.array(test[: train.shape[1]])
    bounded, outside = bound_features(x[None, :], (lo, hi))
    inside = (x >= lo) & (x <= hi)
    assert bool(outside[0]) == (not inside.all())
    np.testing.assert_array_equal(bounded[0][inside], x[inside])
    np.testing.assert_array_equal(bounded[0][~inside], np.where(x < lo, lo, hi)[~inside])
    bounded_train, out_train = bound_features(train, (lo, hi))
    np.testing.assert_array_equal(bounded_train, train)  # the training rows are inside
    assert not out_train.any()


def test_nan_and_features_without_a_range_are_never_bounded():
    env = fit_envelope(np.array([[1.0, np.nan], [3.0, np.nan]]), margin=1.0)
    assert env["feature_ranges"] == [[1.0, 3.0], [None, None]]
    bounds = envelope_bounds(json.loads(json.dumps(env)), 2)
    bounded, outside = bound_features(np.array([[np.nan, 1e9], [9.0, -1e9]]), bounds)
    assert np.isnan(bounded[0, 0]) and bounded[0, 1] == 1e9 and not outside[0]
    assert bounded[1, 0] == 5.0 and outside[1]
    assert envelope_bounds(None, 2) is None
    with pytest.raises(ValueError, match="2 features, the model 3"):
        envelope_bounds(env, 3)


def test_an_adapted_model_stands_on_the_prior_envelope_and_its_new_data():
    prior = fit_envelope(np.array([[0.0, 5.0], [2.0, 6.0]]), margin=1.0)
    joined = join_envelope(prior, np.array([[-1.0, 5.5], [1.0, 9.0]]))
    assert joined == {"margin": 1.0, "feature_ranges": [[-1.0, 2.0], [5.0, 9.0]]}
    assert join_envelope(None, np.array([[1.0]]))["feature_ranges"] == [[1.0, 1.0]]
    with_output = fit_envelope(np.array([[0.0], [2.0]]), np.array([1.0, 4.0]))
    joined = join_envelope(with_output, np.array([[3.0]]), np.array([-2.0]))
    assert joined["output_range"] == [-2.0, 4.0] and joined["output_margin"] == OUTPUT_MARGIN
    # a prior fitted before the output bound: the adapted model's range is its new data's
    assert join_envelope(prior, np.array([[1.0, 5.0]]), np.array([2.0, 3.0]))["output_range"] == [2.0, 3.0]


@settings(max_examples=60, deadline=None)
@given(
    target=arrays(float, st.integers(2, 30), elements=finite),
    predicted=arrays(float, st.integers(1, 10), elements=st.floats(-1e5, 1e5, allow_nan=False)),
)
def test_a_prediction_is_held_inside_the_training_range_widened_by_the_output_margin(target, predicted):
    env = json.loads(json.dumps(fit_envelope(np.zeros((len(target), 1)), target)))
    lo, hi = output_bounds(env)
    span = target.max() - target.min()
    np.testing.assert_allclose(
        [lo, hi], [target.min() - OUTPUT_MARGIN * span, target.max() + OUTPUT_MARGIN * span]
    )
    held, outside = bound_output(predicted, (lo, hi))
    inside = (predicted >= lo) & (predicted <= hi)
    np.testing.assert_array_equal(outside, ~inside)
    np.testing.assert_array_equal(held[inside], predicted[inside])
    np.testing.assert_array_equal(held[~inside], np.where(predicted < lo, lo, hi)[~inside])
    assert not bound_output(target, (lo, hi))[1].any()  # the training targets are inside
    assert output_bounds({"margin": 1.0, "feature_ranges": []}) is None  # fitted before the bound
    assert bound_output(np.array([np.nan]), (lo, hi))[1].tolist() == [False]


@pytest.fixture(scope="module")
def hotter_than_ever():
    table, frame = hotter_than_ever_runs()
    assert set(table.loc[table["run_id"] == "test", "role"]) == {"validation_single"}
    return table, frame


@pytest.mark.parametrize("kind", RIDGE_KINDS)
def test_outside_the_envelope_a_model_is_better_than_no_compensation(hotter_than_ever, kind):
    table, frame = hotter_than_ever
    model = small_family_model(
        kind, reference_rule="run_start", reference_window_s=60, filter_restart_gap_s=3600, alphas=(1e-8,)
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit(table, frame)
    test = frame[frame["log"] == "test.csv"]
    detail = model.predict_detail(test)
    y = test["dz_um"].to_numpy(dtype=float)
    ok = np.isfinite(detail["predicted_um"].to_numpy())
    assert detail["outside_envelope"].to_numpy()[ok].mean() > 0.3  # the run does leave it
    bounded = np.abs(y - detail["predicted_um"].to_numpy())[ok].mean()
    free = np.abs(y - detail["unbounded_um"].to_numpy())[ok].mean()
    none = np.abs(y)[ok].mean()
    noise = 0.1  # the twin's displacement noise (schedule_log's noise_disp)
    assert bounded <= none + noise and bounded < 0.5 * none
    assert bounded <= free + 0.5 or kind == "temperature_ridge"  # its free extrapolation is the worse
    # the artefact carries the envelope: the streaming compensator bounds as the batch code does
    art = json.loads(json.dumps(model.to_dict()))
    assert len(art["envelope"]["feature_ranges"]) == len(art["features"])
    steps = streamed(model, test)
    flags = np.array([s.outside_envelope for s in steps])
    after = test["log_t_s"].to_numpy() >= test["log_t_s"].min() + 60.0  # after the reference window
    np.testing.assert_array_equal(flags[after], detail["outside_envelope"].to_numpy()[after])
    got = np.array([s.compensation_um for s in steps])
    np.testing.assert_allclose(got[after], detail["predicted_um"].to_numpy()[after], rtol=0, atol=1e-9)


@pytest.mark.parametrize("kind", ["dynamic", "temperature_ridge"])
def test_a_runaway_is_capped_at_the_output_bound_in_batch_and_stream(hotter_than_ever, kind):
    """A fit gone wrong (its coefficients 40 x what the data gave, as a near-singular fit at the
    grid's edge can make them) predicts far beyond anything trained: the prediction is held at the
    training displacement range widened by the output margin, the same in the compensator."""
    table, frame = hotter_than_ever
    model = small_family_model(
        kind, reference_rule="run_start", reference_window_s=60, filter_restart_gap_s=3600
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit(table, frame)
    model.coef_ = model.coef_ * 40.0
    test = frame[frame["log"] == "test.csv"]
    detail = model.predict_detail(test)
    training = frame[frame["run_id"].isin(table.loc[table["role"] == "training", "run_id"])]
    y = training["dz_um"].to_numpy(dtype=float)
    lo, hi = y.min() - OUTPUT_MARGIN * np.ptp(y), y.max() + OUTPUT_MARGIN * np.ptp(y)
    pred, free = detail["predicted_um"].to_numpy(), detail["unbounded_um"].to_numpy()
    ok = np.isfinite(pred)
    assert (np.abs(free[ok]) > hi).mean() > 0.5  # it does run away
    assert pred[ok].min() >= lo - 1e-9 and pred[ok].max() <= hi + 1e-9
    assert np.isclose(pred[ok].max(), hi) or np.isclose(pred[ok].min(), lo)
    assert detail["outside_envelope"].to_numpy()[np.abs(free - pred) > 1e-9].all()
    steps = streamed(model, test)
    after = test["log_t_s"].to_numpy() >= test["log_t_s"].min() + 60.0
    got = np.array([s.compensation_um for s in steps])
    np.testing.assert_allclose(got[after], pred[after], rtol=0, atol=1e-9)
    flags = np.array([s.outside_envelope for s in steps])
    np.testing.assert_array_equal(flags[after], detail["outside_envelope"].to_numpy()[after])


def test_beyond_the_trained_range_the_interval_widens_the_same_in_batch_and_stream(hotter_than_ever):
    """The 9000 r/min run lies beyond the trained speeds and rises: its interval is the cell's
    half-width times 1 + slope x excess, the excess measured from the training ranges; the
    streaming compensator gives the same bounds (after the reference window)."""
    from rafi.family.interval_rule import EXCESS_SLOPE, INTERVAL_SCHEMA
    from rafi.family.intervals import interval_columns, set_interval

    table, frame = hotter_than_ever
    model = small_family_model(
        "dynamic", reference_rule="run_start", reference_window_s=60, filter_restart_gap_s=3600
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit(table, frame)
    block = {
        "schema": INTERVAL_SCHEMA,
        "level": 0.9,
        "transient_s": 600.0,
        "tolerance_rpm": 50.0,
        "half_width_um": {"settled": 0.5, "transient": 0.8, "outside": 1.0},
        "excess_slope": EXCESS_SLOPE,
    }
    set_interval(model, block)
    test = frame[frame["log"] == "test.csv"]
    detail = model.predict_detail(test)
    excess = detail["range_excess"].to_numpy()
    speed_excess = (9000 - 6000) / 6000  # the speed alone: half a trained span beyond 6000 r/min
    assert excess.max() >= speed_excess - 1e-9 and excess.min() >= 0
    outside = (detail["outside_temp_range"] | detail["outside_speed_range"]).to_numpy()
    batch = interval_columns(model, test, detail["predicted_um"].to_numpy(), outside, excess=excess)
    half = (batch["upper_um"] - batch["lower_um"]).to_numpy() / 2
    np.testing.assert_allclose(half[outside], 1.0 * (1 + EXCESS_SLOPE * excess[outside]), rtol=1e-12)
    assert half[outside].max() > 1.0 + EXCESS_SLOPE * 0.4  # it does widen
    steps = streamed(model, test)
    after = test["log_t_s"].to_numpy() >= test["log_t_s"].min() + 60.0
    streamed_half = np.array([s.half_width_um for s in steps])
    np.testing.assert_allclose(streamed_half[after], half[after], rtol=0, atol=1e-9)


def test_an_ensemble_holds_a_member_without_its_own_cap_in_batch_and_stream(hotter_than_ever):
    """An ensemble's member that does not cap itself (RAFI's kinds; here a ridge kind whose
    artefact predates the output bound, run away 40 x) is held at the training displacement range
    widened by the output margin before the blend, the same in the compensator; the run is still
    better compensated than not at all."""
    from rafi.family.ensemble import WeightedEnsemble, blend

    table, frame = hotter_than_ever
    members = {}
    for kind in ("dynamic", "temperature_ridge"):
        members[kind] = small_family_model(
            kind, reference_rule="run_start", reference_window_s=60, filter_restart_gap_s=3600
        )
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            members[kind].fit(table, frame)
    wild = members["temperature_ridge"]
    wild.coef_ = wild.coef_ * 40.0
    wild.envelope_ = {k: v for k, v in wild.envelope_.items() if k not in ("output_range", "output_margin")}
    ensemble = WeightedEnsemble.from_fitted(members, {"dynamic": 0.7, "temperature_ridge": 0.3})
    test = frame[frame["log"] == "test.csv"]
    training = frame[frame["run_id"].isin(table.loc[table["role"] == "training", "run_id"])]
    y = training["dz_um"].to_numpy(dtype=float)
    lo, hi = y.min() - OUTPUT_MARGIN * np.ptp(y), y.max() + OUTPUT_MARGIN * np.ptp(y)
    each = np.column_stack([members[k].predict(test) for k in ("dynamic", "temperature_ridge")])
    assert (np.abs(each[:, 1]) > hi).mean() > 0.5  # the uncapped member does run away
    detail = ensemble.predict_detail(test)
    expected = blend(np.clip(each, lo, hi), [0.7, 0.3])
    np.testing.assert_allclose(detail["predicted_um"], expected, rtol=1e-12, atol=1e-9)
    dz = test["dz_um"].to_numpy(dtype=float)
    ok = np.isfinite(detail["predicted_um"].to_numpy())
    assert np.abs(dz - detail["predicted_um"].to_numpy())[ok].mean() < np.abs(dz)[ok].mean()
    steps = streamed(ensemble, test)
    after = test["log_t_s"].to_numpy() >= test["log_t_s"].min() + 60.0
    got = np.array([s.compensation_um for s in steps])
    np.testing.assert_allclose(got[after], detail["predicted_um"].to_numpy()[after], rtol=0, atol=1e-9)
    flags = np.array([s.outside_envelope for s in steps])
    np.testing.assert_array_equal(flags[after], detail["outside_envelope"].to_numpy()[after])
