"""The interval study's outer leave-one-run-out (benchmarks/bench_intervals.py) on synthetic OOF
samples whose truth is known."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from bench_loader import load_bench
from scipy.stats import binom

ROOT = Path(__file__).resolve().parents[1]


def _bench():
    return load_bench("bench_intervals")


def _oof(n_runs: int, per_run: int, *, seed: int, far_run: bool = False) -> pd.DataFrame:
    """Exchangeable runs: residuals N(0, 1) iid; speeds 1000 r/min apart, the last run far away."""
    rng = np.random.default_rng(seed)
    speeds = 1000.0 * np.arange(1, n_runs + 1)
    if far_run:
        speeds[-1] = 1000.0 * (3 * n_runs)
    rows = []
    for k in range(n_runs):
        rows.append(
            pd.DataFrame(
                {
                    "unit": f"run{k:02d}",
                    "residual": rng.normal(size=per_run),
                    "cell": "settled",
                    "pred": rng.normal(size=per_run),
                    "spread": np.abs(rng.normal(size=per_run)),
                    "x_dT1": rng.normal(size=per_run),
                    "x_speed": speeds[k],
                }
            )
        )
    return pd.concat(rows, ignore_index=True)


def test_outer_coverage_of_exchangeable_runs_is_within_the_binomial_band():
    bench = _bench()
    n_runs, per_run = 40, 50
    out = bench.outer_cv(_oof(n_runs, per_run, seed=3), "const", cells=False, correction="none")
    # iid samples: the pooled coverage of 2000 samples at level 0.9 (the quantile of 39 runs'
    # samples) lies in the 99.9 % binomial band of 2000 draws at 0.9.
    lo, hi = binom.interval(0.999, n_runs * per_run, 0.9)
    assert lo / (n_runs * per_run) <= out["coverage"] <= hi / (n_runs * per_run)
    # the width of N(0, 1)'s central 90 % is 2 x 1.645
    assert abs(out["median_width_um"] - 2 * 1.645) < 0.2


def test_a_run_far_from_the_others_is_far_in_both_distances():
    bench = _bench()
    data = bench.distances(_oof(6, 30, seed=4, far_run=True))
    far = data["unit"] == "run05"
    for name in ("mahal", "knn"):
        assert data.loc[far, name].min() > data.loc[~far, name].max()


def test_the_level_correction_never_narrows():
    bench = _bench()
    data = _oof(5, 40, seed=5)
    g = bench.difficulty(data, "const")
    plain = bench.fit_variant(data, g, cells=True, correction="none")
    corrected = bench.fit_variant(data, g, cells=True, correction="level")
    assert corrected["lam"] >= 0.9
    assert all(corrected["q"][c] >= plain["q"][c] for c in plain["q"])
