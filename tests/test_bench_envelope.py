"""The pure parts of benchmarks/bench_envelope.py: the output bound it judges, its scores per
kind and margin, and the decision by the criterion of its docstring (the runs are a benchmark)."""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd
import pytest
from bench_loader import load_bench


@pytest.fixture(scope="module")
def bench():
    yield load_bench("bench_envelope")
    sys.modules.pop("bench_envelope", None)


def test_the_bound_holds_a_prediction_inside_the_range_widened_by_m_spans(bench):
    pred = np.array([-30.0, -5.0, 0.0, 5.0, 10.0, 40.0])
    np.testing.assert_array_equal(bench.bound(pred, 0.0, 10.0, None), pred)
    np.testing.assert_array_equal(bench.bound(pred, 0.0, 10.0, 0.0), [0, 0, 0, 5, 10, 10])
    np.testing.assert_array_equal(bench.bound(pred, 0.0, 10.0, 1.0), [-10, -5, 0, 5, 10, 20])


def test_scores_per_kind_and_margin_with_the_worst_run(bench):
    rows = pd.DataFrame(
        {
            "model": ["k"] * 4,
            "run_id": ["a", "a", "b", "b"],
            "dz_um": [1.0, 2.0, 3.0, 4.0],
            "predicted_um": [1.0, 2.0, 30.0, 4.0],
            "lo": [0.0] * 4,
            "hi": [4.0] * 4,
        }
    )
    s = bench.scores(rows)["k"]
    assert s["free"]["mae"] == pytest.approx(27 / 4) and s["free"]["worst_run"] == pytest.approx(13.5)
    assert s["m=0"]["mae"] == pytest.approx(1 / 4)  # 30 held at 4: |3 - 4|
    assert s["m=1"]["mae"] == pytest.approx(5 / 4)  # held at 4 + 4 = 8


def _entry(name, foreign, outer, test=None):
    def block(maes):
        return {"k": {margin: {"mae": v, "worst_run": v} for margin, v in maes.items()}}

    return {
        "machine": name,
        "foreign": foreign,
        "offered": "k",
        "outer": block(outer),
        "test": block(test or {}),
    }


def test_the_decision_follows_the_criterion(bench):
    names = [bench.margin_name(m) for m in bench.MARGINS]
    flat = dict.fromkeys(names, 1.0)
    # nothing beats free: the widest candidate passing the guard
    entries = [_entry(f"f{i}", True, flat, flat) for i in range(4)]
    d = bench.decide(entries)
    assert d["choice"] == names[1] and "widest" in d["why"]
    # a tight bound that helps everywhere and costs nothing on the test days wins
    helped = {**flat, "m=0.1": 0.8, "m=0": 0.7}
    costly_test = {**flat, "m=0": 1.5}
    entries = [_entry(f"f{i}", True, {**helped, "m=0": 0.7 + 0.01 * i}, costly_test) for i in range(4)]
    d = bench.decide(entries)
    assert d["choice"] == "m=0.1"  # m=0 has the lower primary but fails the guard
