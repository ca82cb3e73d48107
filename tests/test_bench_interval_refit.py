"""The pure parts of the interval pipeline judged one level up (benchmarks/bench_interval_refit.py):
the learning-curve scaling on units whose mean square is known, the unit -> training runs map,
the variants' calibration samples, the coverage of a block."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from bench_loader import load_bench

from rafi.family.forward_folds import fold_unit


@pytest.fixture(scope="module")
def bench():
    return load_bench("bench_interval_refit")


def _units(mean_squares: dict) -> pd.DataFrame:
    """One OOF unit per name whose residuals are +-sqrt(mean square): its mean square is exact."""
    parts = []
    for unit, ms in mean_squares.items():
        r = np.sqrt(ms) * np.tile([1.0, -1.0], 10)
        parts.append(pd.DataFrame({"unit": unit, "residual_um": r, "since_change_s": 1e9, "outside": False}))
    return pd.concat(parts, ignore_index=True)


def test_learning_curve_factors_scale_each_unit_to_the_final_runs(bench):
    a, b, n = 0.5, 6.0, 8
    train = {"r1": 7, "f0:r5": 3, "f1:r6": 4, "f2:r7": 5}
    oof = _units({u: a + b / m for u, m in train.items()})
    got = bench.learning_curve_factors(oof, train, n)
    want = np.sqrt((a + b / n) / (a + b / oof["unit"].map(train).to_numpy(dtype=float)))
    np.testing.assert_allclose(got, want, rtol=1e-9)
    assert np.all(got < 1)  # fewer runs, larger residuals: every unit shrinks


def test_learning_curve_factors_are_one_without_a_curve(bench):
    same_m = {"r1": 7, "r2": 7, "r3": 7}
    oof = _units({"r1": 1.0, "r2": 2.0, "r3": 3.0})
    np.testing.assert_array_equal(bench.learning_curve_factors(oof, same_m, 8), 1.0)
    rising = {"r1": 7, "f0:r5": 3}  # more runs, larger residuals: no learning curve is seen
    oof = _units({"r1": 2.0, "f0:r5": 1.0})
    np.testing.assert_array_equal(bench.learning_curve_factors(oof, rising, 8), 1.0)


def test_a_negative_floor_leaves_the_estimation_error_alone(bench):
    # the straight line through these points crosses below zero at 1/m = 0: a is clipped to 0 and
    # the residual scale is all estimation error, which shrinks as sqrt(m / n)
    train = {"r1": 7, "f0:r5": 2, "f1:r6": 3}
    oof = _units({"r1": 0.01, "f0:r5": 5.0, "f1:r6": 2.0})
    got = bench.learning_curve_factors(oof, train, 8)
    np.testing.assert_allclose(got, np.sqrt(oof["unit"].map(train).to_numpy(dtype=float) / 8), rtol=1e-12)


def test_unit_train_runs_names_forward_units_by_fold(bench):
    whole = pd.DataFrame({"fold": [0, 1], "test_runs": ["a", "b"], "n_train_runs": [6, 6]})
    fwd = pd.DataFrame({"fold": [0, 1, 1], "test_runs": ["c", "c", "d"], "n_train_runs": [2, 3, 3]})
    got = bench.unit_train_runs({"leave_one_run_out": whole, "forward_2": fwd})
    assert got == {"a": 6, "b": 6, fold_unit(0, "c"): 2, fold_unit(1, "c"): 3, fold_unit(1, "d"): 3}


def test_the_whole_run_variant_keeps_the_whole_run_units_only(bench):
    oof = _units({"r1": 1.0, fold_unit(0, "r1"): 4.0, "r2": 1.0})
    got = bench.variant_oof("whole_run", oof, {}, 3)
    assert set(got["unit"]) == {"r1", "r2"}
    assert bench.variant_oof("every_unit", oof, {}, 3) is oof


def test_coverage_counts_samples_inside_their_cells_half_width(bench):
    held = pd.DataFrame(
        {
            "unit": "r1",
            "residual_um": [0.5, -1.5, 2.5, -0.2],
            "since_change_s": [1e9, 1e9, 10.0, 1e9],
            "outside": [False, False, False, True],
        }
    )
    block = {"transient_s": 100.0, "half_width_um": {"settled": 1.0, "transient": 3.0, "outside": 0.1}}
    cov, width = bench.coverage(block, held)
    assert cov == pytest.approx(2 / 4)  # 0.5 settled in, 1.5 settled out, 2.5 transient in, 0.2 outside out
    assert width == pytest.approx(np.median([2.0, 2.0, 6.0, 0.2]))
    assert np.isnan(bench.coverage(None, held)[0])
