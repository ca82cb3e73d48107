"""The box on the features' principal components (rafi.family.envelope, ``models:
component_envelope``): a combination of in-range features the fit never saw is held at the
training cloud's edge, a row inside is unchanged to the bit, and the streaming compensator bounds
as the batch code does.

Known truth: two sensors that moved together in training (the second the first plus a little
noise), a displacement that follows the first only, and a fit with large opposite coefficients
that the training rows cannot tell from the truth (what a near-singular fit at the grid's edge
makes). A test row where the second sensor leaves the first by 3 K, each inside its own training
range, makes the free fit run away (90 um); bounded, the unseen direction adds at most one training span of
the displacement to the model at the nearest combination training saw (the sensors' mean).
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
    ENVELOPE_MARGIN,
    bound_components,
    component_bounds,
    component_excess,
    component_reach,
    component_scores,
    fit_envelope,
    join_envelope,
)
from rafi.twin.synthetic_runs import small_family_model

#: Values at a logger's resolution (a milli-unit): features are kelvin, scaled speeds and their filters.
finite = st.integers(-(10**6), 10**6).map(lambda i: i / 1000.0)
wide = st.integers(-(10**7), 10**7).map(lambda i: i / 1000.0)


def _collinear_pair(seed: int = 0, n: int = 400):
    rng = np.random.default_rng(seed)
    t1 = rng.uniform(0.0, 10.0, n)
    x = np.column_stack([t1, t1 + rng.normal(0.0, 0.001, n)])
    y = t1 + rng.normal(0.0, 0.05, n)
    return x, y


def test_an_unseen_combination_of_in_range_features_is_held_near_the_truth():
    x, y = _collinear_pair()
    coef = np.array([31.0, -30.0])  # large and opposite: on the training rows as good as the truth
    assert np.abs(x @ coef - x[:, 0]).max() < 0.2
    env = json.loads(json.dumps(fit_envelope(x, y, components=True)))
    bounds = component_bounds(env, 2, coef)
    test = np.array([[5.0, 8.0], [5.0, 5.0]])  # each feature inside its range; the first unseen
    held, outside = bound_components(test, bounds)
    assert outside.tolist() == [True, False]
    truth = test[:, 0]
    free = np.abs(test @ coef - truth)
    bounded = np.abs(held @ coef - truth)
    assert free[0] > 50.0  # the free fit runs away
    # held where the unseen direction adds one training span (m * Y) to the model at the nearest
    # combination training saw (the sensors' mean, 6.5 K: half their 3 K disagreement off)
    assert bounded[0] < 0.5 * 3.0 + ENVELOPE_MARGIN * np.ptp(y) + 0.3
    assert bounded[0] < 0.15 * free[0]
    np.testing.assert_array_equal(held[1], test[1])  # a row inside is unchanged to the bit
    # the held row's scores sit on the widened edge of the clipped component
    columns, center, scale, vectors, lo, hi = bounds
    scores = ((held[0, columns] - center) / scale) @ vectors.T
    assert np.all(scores >= lo - 1e-9) and np.all(scores <= hi + 1e-9)
    assert np.isclose(scores, hi).any() or np.isclose(scores, lo).any()


def test_the_component_excess_is_what_the_prediction_reaches_beyond_the_trained_combinations():
    """The interval's widening beyond the trained combinations (rafi.family.interval_rule): 0 on
    every training row, and for a row off the training line what holding it at the components'
    unpadded training ranges would take off the prediction, in training displacement spans."""
    x, y = _collinear_pair()
    coef = np.array([31.0, -30.0])
    env = json.loads(json.dumps(fit_envelope(x, y, components=True)))
    reach = component_reach(env, 2, coef)
    assert np.all(component_excess(x, reach) == 0.0)
    test = np.array([[5.0, 8.0], [5.0, 5.0], [5.0, 11.0], [np.nan, 1.0]])
    excess = component_excess(test, reach)
    assert excess[1] == 0.0 and excess[3] == 0.0 and excess[2] > 1.9 * excess[0] > 0.0
    # the oracle: the rows held at the training score ranges (no margin) by bound_components
    columns, center, scale, vectors, lo, hi, _ = reach
    held, outside = bound_components(test[:3], (columns, center, scale, vectors, lo, hi))
    assert outside.tolist() == [True, False, True]
    np.testing.assert_allclose(
        excess[:3], np.abs((test[:3] - held) @ coef) / np.ptp(y), rtol=1e-9, atol=1e-12
    )
    # nothing to measure against: no components, no coefficients, no output range
    assert component_reach(fit_envelope(x, y), 2, coef) is None
    assert (
        component_reach(env, 2, None) is None
        and component_reach(fit_envelope(x, components=True), 2, coef) is None
    )
    assert np.all(component_excess(test, None) == 0.0)


def test_one_set_of_scores_serves_the_bound_and_the_excess():
    """The compensator and the batch code compute the component scores once for both: the
    bound and the excess read from them are those each computes on its own, to the bit."""
    x, y = _collinear_pair()
    coef = np.array([31.0, -30.0])
    env = json.loads(json.dumps(fit_envelope(x, y, components=True)))
    bounds, reach = component_bounds(env, 2, coef), component_reach(env, 2, coef)
    test = np.array([[5.0, 8.0], [5.0, 5.0], [5.0, 11.0], [np.nan, 1.0], [-40.0, 40.0]])
    scores = component_scores(test, bounds)
    np.testing.assert_array_equal(scores, component_scores(test, reach))  # the same components
    held, outside = bound_components(test, bounds, scores)
    held_alone, outside_alone = bound_components(test, bounds)
    np.testing.assert_array_equal(held, held_alone)
    np.testing.assert_array_equal(outside, outside_alone)
    assert outside.tolist() == [True, False, True, False, True]
    np.testing.assert_array_equal(component_excess(test, reach, scores), component_excess(test, reach))
    assert component_scores(test, None) is None


@settings(max_examples=60, deadline=None)
@given(
    train=arrays(float, st.tuples(st.integers(3, 25), st.integers(2, 5)), elements=finite),
    test=arrays(
        float,
        st.tuples(st.integers(1, 6), st.integers(5, 5)),
        elements=st.integers(-(10**7), 10**7).map(lambda i: i / 1000.0),
    ),
)
def test_training_rows_are_inside_and_a_held_row_has_every_score_inside(train, test):
    env = fit_envelope(train, components=True)
    bounds = component_bounds(json.loads(json.dumps(env)), train.shape[1])
    if bounds is None:  # fewer than two varying features: nothing to combine
        assert (np.ptp(train, axis=0) > 0).sum() < 2 or "components" not in env
        return
    held_train, out_train = bound_components(train, bounds)
    assert not out_train.any()
    np.testing.assert_array_equal(held_train, train)
    x = test[:, : train.shape[1]]
    held, outside = bound_components(x, bounds)
    columns, center, scale, vectors, lo, hi = bounds
    np.testing.assert_array_equal(held[~outside], x[~outside])  # inside: unchanged to the bit
    if outside.any():
        scores = ((held[outside][:, columns] - center) / scale) @ vectors.T
        tol = 1e-7 * (1.0 + np.abs(scores).max())
        assert np.all(scores >= lo - tol) and np.all(scores <= hi + tol)
    untouched = np.setdiff1d(np.arange(train.shape[1]), columns)  # constant columns never move
    np.testing.assert_array_equal(held[:, untouched], x[:, untouched])


def test_a_thin_direction_the_model_reads_with_a_small_gain_is_not_held():
    """The same pair, the fit reading the first sensor only (the truth): the sensors' 3 K
    disagreement leaves the thin training cloud but adds nothing the model would not stand by,
    so the row is not held (a box on the scores alone would read it as the sensors' mean)."""
    x, y = _collinear_pair()
    coef = np.array([1.0, 0.0])
    env = fit_envelope(x, y, components=True)
    test = np.array([[5.0, 8.0]])
    held, outside = bound_components(test, component_bounds(env, 2, coef))
    assert not outside[0]
    np.testing.assert_array_equal(held, test)
    assert bound_components(test, component_bounds(env, 2))[1][0]  # by the score span alone: held


def test_nan_rows_and_constant_features_and_the_margin():
    x, y = _collinear_pair(n=50)
    x = np.column_stack([x, np.ones(len(x))])  # a constant column: no component reads it
    env = fit_envelope(x, components=True)
    assert env["components"]["columns"] == [0, 1]
    assert fit_envelope(np.ones((5, 3)), components=True).get("components") is None
    assert "components" not in fit_envelope(x)  # off by default
    bounds = component_bounds(env, 3)
    rng = np.asarray(env["components"]["score_ranges"])
    np.testing.assert_allclose(bounds[5] - bounds[4], (1 + 2 * ENVELOPE_MARGIN) * (rng[:, 1] - rng[:, 0]))
    # with the model's gains: each range widened by the margin times Y / |gain| where that is larger
    coef = np.array([0.5, 0.5, 7.0])
    env_y = fit_envelope(x, y, components=True)
    _, _, scale, vectors, lo, hi = component_bounds(env_y, 3, coef)
    gain = np.abs(vectors @ (scale * coef[:2]))
    reach = np.maximum(rng[:, 1] - rng[:, 0], np.ptp(y) / gain)
    np.testing.assert_allclose(hi - lo, rng[:, 1] - rng[:, 0] + 2 * ENVELOPE_MARGIN * reach)
    held, outside = bound_components(np.array([[np.nan, 1e6, 1.0]]), bounds)
    assert not outside[0] and held[0, 1] == 1e6
    with pytest.raises(ValueError, match="column 1, the model has 1"):
        component_bounds(env, 1)


def test_an_adapted_model_keeps_the_prior_components_and_widens_their_ranges():
    x, y = _collinear_pair(n=60)
    prior = fit_envelope(x, y, components=True)
    new = np.array([[20.0, 20.0], [-5.0, -5.0]])  # further along the main component
    joined = join_envelope(prior, new, np.array([20.0, -5.0]))
    assert joined["components"]["vectors"] == prior["components"]["vectors"]
    bounds = component_bounds(joined, 2)
    assert not bound_components(new, bounds)[1].any()  # the new data stand inside
    assert "components" not in join_envelope(fit_envelope(x, y), new)  # a prior without: none


@pytest.fixture(scope="module")
def hotter_than_ever():
    return hotter_than_ever_runs()


@pytest.mark.parametrize("kind", ["dynamic", "grey_box", "ridge_global", "temperature_ridge"])
def test_a_ridge_kind_with_components_bounds_the_same_in_batch_and_stream(hotter_than_ever, kind):
    """On the twin's linear physics a run hotter than any training run leaves the components'
    box; the bounded model stays better than no compensation, and the compensator, built from the
    artefact, gives the batch prediction and flags."""
    table, frame = hotter_than_ever
    model = small_family_model(
        kind, reference_rule="run_start", reference_window_s=60, filter_restart_gap_s=3600, alphas=(1e-8,)
    )
    model.component_envelope = True
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit(table, frame)
    art = json.loads(json.dumps(model.to_dict()))
    assert art["hyperparameters"]["component_envelope"] is True
    assert art["envelope"]["components"]["vectors"]
    test = frame[frame["log"] == "test.csv"]
    detail = model.predict_detail(test)
    y = test["dz_um"].to_numpy(dtype=float)
    pred = detail["predicted_um"].to_numpy()
    ok = np.isfinite(pred)
    assert np.abs(y - pred)[ok].mean() < 0.5 * np.abs(y)[ok].mean()
    steps = streamed(model, test)
    after = test["log_t_s"].to_numpy() >= test["log_t_s"].min() + 60.0  # after the reference window
    got = np.array([s.compensation_um for s in steps])
    np.testing.assert_allclose(got[after], pred[after], rtol=0, atol=1e-9)
    flags = np.array([s.outside_envelope for s in steps])
    np.testing.assert_array_equal(flags[after], detail["outside_envelope"].to_numpy()[after])
    # the same model without components: the rows inside both boxes predict the same
    plain = small_family_model(
        kind, reference_rule="run_start", reference_window_s=60, filter_restart_gap_s=3600, alphas=(1e-8,)
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plain.fit(table, frame)
    inside = ~detail["outside_envelope"].to_numpy() & ok
    np.testing.assert_array_equal(plain.predict_detail(test)["predicted_um"].to_numpy()[inside], pred[inside])
