"""The level-correction study (benchmarks/bench_interval_groups.py) on synthetic OOF samples whose
truth is known: exchangeable runs, each held out twice (a whole-run and a forward unit)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from bench_loader import load_bench

from rafi.family.forward_folds import fold_unit
from rafi.family.intervals import calibrate

OPTIONS = {"level": 0.9, "transient_s": 1800.0, "min_runs": 3}
SCHEME = "leave_one_run_out+forward_2"


def _oof(n_runs: int, per_run: int, *, seed: int) -> pd.DataFrame:
    """Runs with their own error scale (exchangeable between runs); each run held out by the
    whole-run folds and by one forward fold, whose model errs alike on it (correlated units)."""
    rng = np.random.default_rng(seed)
    parts = []
    for k in range(n_runs):
        run = f"log#{k}"
        base = rng.normal(0.0, rng.lognormal(0.0, 0.6), per_run)
        for unit, res in ((run, base), (fold_unit(k, run), base + rng.normal(0.0, 0.05, per_run))):
            parts.append(
                pd.DataFrame(
                    {
                        "model": "dynamic",
                        "unit": unit,
                        "run_id": run,
                        "t_s": 60.0 * np.arange(per_run),
                        "residual_um": res,
                        "since_change_s": 1e9,
                        "outside": False,
                    }
                )
            )
    return pd.concat(parts, ignore_index=True)


def _results(tmp_path, oof: pd.DataFrame, *, by_run: bool):
    """A machine's results folder as rule compare leaves it: the OOF memo and the offered model."""
    res = tmp_path / "m"
    (res / ".cv_memo").mkdir(parents=True)
    (res / "comparison").mkdir()
    oof.to_parquet(res / ".cv_memo" / "key.oof.parquet")
    block = calibrate(oof, tolerance_rpm=50.0, scheme=SCHEME, by_run=by_run, **OPTIONS)
    best = {"kind": "dynamic", "interval": block}
    (res / "comparison" / "best_model.json").write_text(json.dumps(best), encoding="utf-8")
    return res


@pytest.mark.parametrize("stored_by_run", [False, True])
def test_by_run_covers_a_new_run_at_the_level_and_by_unit_falls_short(tmp_path, stored_by_run):
    bench = load_bench("bench_interval_groups")
    coverage = []
    for seed in range(16):  # machines of 8 exchangeable runs, as few as a real log has
        res = _results(tmp_path / str(seed), _oof(8, 60, seed=seed), by_run=stored_by_run)
        out = bench.judge_machine(res, OPTIONS)
        assert out["units"] == 16 and out["runs"] == 8
        assert set(out["by_run"]["per_run"]) == {f"log#{k}" for k in range(8)}
        coverage.append([out["by_unit"]["coverage"], out["by_run"]["coverage"]])
    by_unit, by_run = np.array(coverage).T
    # a quantile that still holds the held-out run's twin unit is over-confident: never wider
    assert np.all(by_unit <= by_run) and by_unit.mean() < by_run.mean()
    # leaving the run out whole covers a new run at the level, on average over machines
    assert by_unit.mean() < 0.897 and 0.897 <= by_run.mean() <= 0.93


def test_the_bench_stops_when_the_stored_interval_is_not_the_memos(tmp_path):
    bench = load_bench("bench_interval_groups")
    oof = _oof(8, 40, seed=3)
    res = _results(tmp_path, oof, by_run=True)
    oof.assign(residual_um=2 * oof["residual_um"]).to_parquet(res / ".cv_memo" / "key.oof.parquet")
    with pytest.raises(SystemExit, match="recalibration"):
        bench.judge_machine(res, OPTIONS)
