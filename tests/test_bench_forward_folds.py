"""The parts of benchmarks/bench_forward_folds.py: the forward-in-time folds, the candidates'
syntax, the cut of the frame to the training part, and one small scoring call end to end."""

from __future__ import annotations

import functools
import sys

import numpy as np
import pandas as pd
import pytest
from bench_loader import load_bench

from rafi.family import crossval
from rafi.family.ridge_global import RidgeGlobal
from rafi.twin.synthetic_runs import make_synthetic_runs


@pytest.fixture(scope="module")
def bench():
    yield load_bench("bench_forward_folds")
    sys.modules.pop("bench_forward_folds", None)
    sys.modules.pop("bench_selection_rules", None)


def _table(rows) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=["run_id", "file", "start_s", "role"]).assign(speed_rpm=1000.0)


def _one_log(n_train: int = 6) -> pd.DataFrame:
    rows = [(f"log#{k}", "log.csv", 3600.0 * k, "training") for k in range(1, n_train + 1)]
    return _table(rows[::-1])


def test_the_bench_uses_the_pipelines_forward_folds(bench):
    from rafi.family import forward_folds

    assert bench.forward_folds is forward_folds.forward_folds and bench.MIN_TRAIN == forward_folds.MIN_TRAIN


def test_training_part_keeps_each_log_up_to_its_last_training_run(bench):
    table = _one_log(3)
    frame = pd.DataFrame(
        {
            "run_id": [f"log#{k}" for k in range(6) for _ in range(2)],
            "log": "log.csv",
            "log_t_s": [3600.0 * k + d for k in range(6) for d in (0.0, 60.0)],
        }
    )
    kept = bench.training_part(table, frame)
    assert list(kept["run_id"].unique()) == ["log#0", "log#1", "log#2", "log#3"]
    per_run = bench.training_part(table, frame.drop(columns=["log", "log_t_s"]))
    assert list(per_run["run_id"].unique()) == ["log#1", "log#2", "log#3"]


def test_variant_syntax(bench):
    name, kind, over = bench.parse_variant(
        'slow:kind="grey_box",grey_box_slow_rises=true,grey_box_heat_input="always",dynamic_powers=[1, 2]'
    )
    assert (name, kind) == ("slow", "grey_box")
    assert over == {"grey_box_slow_rises": True, "grey_box_heat_input": "always", "dynamic_powers": [1, 2]}
    with pytest.raises(SystemExit, match="not JSON"):
        bench.parse_variant("slow:kind=grey_box")
    with pytest.raises(SystemExit, match='needs kind="KIND"'):
        bench.parse_variant("slow:grey_box_slow_rises=true")


def _make(kind, *, options, key_sensors):
    return (kind, options, key_sensors)


def test_candidates_build_variants_from_the_machine_settings(bench):
    factories = {
        k: functools.partial(_make, k, options={"a": 1, "b": 2}, key_sensors=["T1"])
        for k in ("dynamic", "rafi")
    }
    c = bench.candidates(factories, ["dynamic", "grey_box"], [("g2", "grey_box", {"b": 5})])
    assert list(c) == ["dynamic", "grey_box", "g2"]
    assert c["grey_box"]["factory"]() == ("grey_box", {"a": 1, "b": 2}, ["T1"])
    assert c["g2"]["factory"]() == ("grey_box", {"a": 1, "b": 5}, ["T1"])
    with pytest.raises(SystemExit, match="not a models: option"):
        bench.candidates(factories, [], [("g3", "grey_box", {"typo": 1})])
    with pytest.raises(SystemExit, match="name is taken"):
        bench.candidates(factories, [], [("rafi", "grey_box", {})])


class Spy:
    """Ridge that records what its fit may learn from and the rows it is given."""

    seen: list[tuple[set, set]] = []

    def __init__(self, alphas=(1e-3, 1e-1)):
        self.inner = RidgeGlobal(alphas=list(alphas))

    def fit(self, table, frame):
        Spy.seen.append((set(table.loc[table["role"] == "training", "run_id"]), set(frame["run_id"])))
        self.inner.fit(table, frame)
        return self

    def predict(self, frame):
        return self.inner.predict(frame)


def test_score_candidates_end_to_end_on_synthetic_runs(bench):
    table, frame = make_synthetic_runs(seed=2, sample_s=300.0, n_sensors=3)
    # one continuous log in time order: the six training runs, then the validation runs
    table = table.assign(file="log.csv", start_s=np.arange(len(table)) * 4 * 3600.0)
    cands = {
        "ridge_global": {"kind": "ridge_global", "overrides": {}, "factory": Spy},
        "rafi_linear": {
            "kind": "rafi_linear",
            "overrides": {},
            "factory": functools.partial(Spy, alphas=[1e3]),
        },
    }
    Spy.seen = []
    messages = []
    out = bench.score_candidates(table, frame, cands, min_train=3, log=messages.append)
    assert [len(out["folds"][s]["ridge_global"]) for s in ("whole_run", "F1", "F2")] == [6, 3, 2]
    assert [f["test_runs"] for f in out["folds"]["F2"]["ridge_global"]] == [
        ["train-12000", "train-15000"],
        ["train-15000", "train-18000"],
    ]
    for scheme, scores in out["scores"].items():
        assert set(scores) == set(cands) and all(np.isfinite(v) and v > 0 for v in scores.values())
        assert out["picks"][scheme] == min(scores, key=scores.get)
    f1 = out["folds"]["F1"]["ridge_global"]
    assert out["scores"]["F1"]["ridge_global"] == pytest.approx(np.mean([f["score_um"] for f in f1]))
    order = list(table["run_id"])
    validation = set(table.loc[table["role"] != "training", "run_id"])
    for learned, rows in Spy.seen:
        assert not learned & validation and not rows & validation  # validation rows are never read
    forward_fits = Spy.seen[12:15]  # ridge_global's F1 fits, after both candidates' whole-run fits
    for (learned, _), fold in zip(forward_fits, f1):
        assert max(order.index(r) for r in learned) < order.index(fold["test_runs"][0])
    assert "forward_1" not in crossval.SCHEMES and not out["errors"]
    assert len(messages) == 6


def test_separate_files_are_scored_whole_run_only(bench):
    table, frame = make_synthetic_runs(seed=2, sample_s=300.0, n_sensors=3, multi=False)
    table = table.assign(start_s=0.0)  # every run its own file, as the twins' cold starts
    cands = {"ridge_global": {"kind": "ridge_global", "overrides": {}, "factory": Spy}}
    messages = []
    out = bench.score_candidates(table, frame, cands, log=messages.append)
    assert list(out["scores"]) == ["whole_run"] and out["picks"] == {"whole_run": "ridge_global"}
    assert sum("not scored" in m for m in messages) == 2
    assert all(v["folds"] == 0 for v in out["forward_logs"]["F2"].values())
