"""Triangular fuzzy memberships (rafi.method.fuzzy)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rafi.method.fuzzy import membership_curves, triangular_weights

PAPER_CENTRES = [3000, 6000, 9000, 12000, 15000, 18000]


def test_paper_example_4000_rpm_triangular_reading():
    # 4000 r/min: 1000 from 3000, 2000 from 6000 -> nearer model gets 2/3 (module docstring
    # explains why the paper's "0.334 and 0.666 respectively" is read this way).
    w, out = triangular_weights([4000], PAPER_CENTRES)
    np.testing.assert_allclose(w[0], [2 / 3, 1 / 3, 0, 0, 0, 0], rtol=0, atol=1e-15)
    assert not out[0]
    assert round(w[0, 1], 3) == 0.333 and round(w[0, 0], 3) == 0.667


def test_exactly_at_centre_and_edges():
    w, out = triangular_weights(PAPER_CENTRES, PAPER_CENTRES)
    np.testing.assert_array_equal(w, np.eye(6))
    assert not out.any()


def test_outside_range_uses_edge_model_and_flags():
    w, out = triangular_weights([0, 2999.9, 18000.1, 25000], PAPER_CENTRES)
    np.testing.assert_array_equal(w[0], [1, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(w[1], [1, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(w[2], [0, 0, 0, 0, 0, 1])
    np.testing.assert_array_equal(out, [True, True, True, True])


def test_tolerance_only_changes_the_flag():
    w0, out0 = triangular_weights([18020, 2990], PAPER_CENTRES)
    w1, out1 = triangular_weights([18020, 2990], PAPER_CENTRES, tolerance_rpm=50)
    np.testing.assert_array_equal(w0, w1)
    assert out0.all() and not out1.any()


def test_unsorted_centres_keep_input_column_order():
    w, _ = triangular_weights([4000, 7000], [6000, 3000, 9000])
    np.testing.assert_allclose(w, [[1 / 3, 2 / 3, 0], [2 / 3, 0, 1 / 3]])


def test_nan_speed_single_centre_and_bad_centres():
    w, out = triangular_weights([np.nan, 4000], PAPER_CENTRES)
    assert np.isnan(w[0]).all() and not out[0]
    w, out = triangular_weights([3000, 5000], [3000])
    np.testing.assert_array_equal(w, [[1], [1]])
    np.testing.assert_array_equal(out, [False, True])
    with pytest.raises(ValueError, match="duplicate"):
        triangular_weights([1], [3000, 3000])
    with pytest.raises(ValueError, match="empty"):
        triangular_weights([1], [])


def test_scalar_input():
    w, out = triangular_weights(4500.0, PAPER_CENTRES)
    assert w.shape == (1, 6)
    np.testing.assert_allclose(w[0, :2], [0.5, 0.5])


def test_membership_curves_shape_and_peaks():
    grid = np.linspace(0, 21000, 2101)
    m = membership_curves(PAPER_CENTRES, grid)
    assert m.shape == (grid.size, 6)
    for j, c in enumerate(PAPER_CENTRES):
        assert m[np.argmin(np.abs(grid - c)), j] == 1.0
    assert m[grid == 7500, 1][0] == pytest.approx(0.5)


centres_st = st.lists(st.integers(0, 40000), min_size=1, max_size=8, unique=True)


@settings(max_examples=100, deadline=None)
@given(centres=centres_st, speeds=st.lists(st.floats(-1e4, 6e4, allow_nan=False), min_size=1, max_size=30))
def test_weights_are_a_partition_of_unity(centres, speeds):
    w, out = triangular_weights(speeds, centres)
    s = np.asarray(speeds)
    c = np.asarray(centres, dtype=float)
    assert w.shape == (len(speeds), len(centres))
    assert np.all(w >= 0) and np.all(w <= 1)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, rtol=0, atol=1e-12)
    # at most two nonzero weights, on neighbouring centres
    order = np.argsort(c)
    for row in w[:, order]:
        nz = np.flatnonzero(row)
        assert len(nz) <= 2 and (len(nz) < 2 or nz[1] - nz[0] == 1)
    # linear reproduction: the blend of the centres is the speed clipped to the range
    np.testing.assert_allclose(w @ c, np.clip(s, c.min(), c.max()), rtol=1e-9, atol=1e-6)
    np.testing.assert_array_equal(out, (s < c.min()) | (s > c.max()))


def test_prepared_centres_give_the_same_weights():
    """The streaming compensator prepares the centres once (``prepared=``): the same weights and
    flags, bit for bit, as preparing them on each call, centres in any order."""
    from rafi.method.fuzzy import prepare_centres

    centres = [9000, 3000, 18000, 6000]
    prepared = prepare_centres(centres)
    rng = np.random.default_rng(7)
    for s in [*rng.uniform(0, 20000, 50), 3000.0, 18000.0, np.nan, -0.0]:
        w, out = triangular_weights([s], centres, tolerance_rpm=50.0)
        wp, outp = triangular_weights([s], centres, tolerance_rpm=50.0, prepared=prepared)
        np.testing.assert_array_equal(wp, w)
        np.testing.assert_array_equal(outp, out)
