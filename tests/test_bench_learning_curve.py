"""The cut of benchmarks/bench_learning_curve.py: on a synthetic log with FL_THERMAL's schedule, the
real segmentation (rafi.method.runs.find_runs) under each cut's configuration trains the runs in
time order up to the cut and nothing after it, and validates the same rows at every cut."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from bench_loader import load_bench

from rafi.method.runs import find_runs
from rafi.ops.init_preview import runs_arguments
from rafi.settings import machine_settings, validate_config
from rafi.twin.synthetic_logs import schedule_log

ROOT = Path(__file__).resolve().parents[1]
H = 3600.0


bench = load_bench("bench_learning_curve")
rd = bench.rd

#: FL_THERMAL's schedule (its README): rest 0-450 s, four 4 h runs at the training speeds each
#: followed by a 4 h rest, 3500 r/min, a rest, the 1-2 h tail steps and a last rest; 11 115 rows.
SCHEDULE = [(0, 465.0)]
for _speed in (1250, 2500, 3750, 5000, 3500):
    SCHEDULE += [(_speed, 4 * H), (0, 4 * H)]
SCHEDULE += [(500, 2 * H), (1500, 2 * H), (2500, H), (4500, H), (0, 660.0)]

#: What trains at each cut, in time order ("idle": a cool-down).
TRAINS = {
    "2h": ["1250"],
    "4h": ["1250"],
    "8h": ["1250", "idle"],
    "16h": ["1250", "idle", "2500", "idle"],
    "24h": ["1250", "idle", "2500", "idle", "3750", "idle"],
    "28h": ["1250", "idle", "2500", "idle", "3750", "idle", "5000"],
}


@pytest.fixture(scope="module")
def log():
    frame, _ = schedule_log(SCHEDULE, period_s=rd.PERIOD_S, seed=7)
    assert len(frame) == 11_115 and frame["t_s"].iloc[-1] == 166_710.0
    return frame


def _runs(log, cut_s: float):
    machine = rd.machine_name("ch3")
    config = {"machines": {machine: bench.curve_config("ch3", cut_s)}}
    validate_config(config)
    return find_runs({"data": log}, {}, **runs_arguments(machine_settings(config, machine)))


def _log_times(table: pd.DataFrame, frame: pd.DataFrame, roles) -> np.ndarray:
    ids = table.loc[table["role"].astype(str).isin(roles), "run_id"]
    return np.sort(frame.loc[frame["run_id"].isin(ids), "log_t_s"].to_numpy(dtype=float))


@pytest.mark.parametrize("name", list(bench.CUTS))
def test_a_cut_trains_the_runs_before_it_and_validates_the_same_rows(log, name):
    cut_s, _ = bench.CUTS[name]
    table, frame = _runs(log, cut_s)
    facts = bench.training_facts(table, cut_s)
    assert facts["training_runs"] == TRAINS[name]
    trained = _log_times(table, frame, {"training"})
    assert trained.max() < cut_s  # nothing at or after the cut trains
    # every training-part sample of a run long enough to use, up to the cut, trains
    assert trained.min() == 465.0 and len(trained) == round((cut_s - 465.0) / rd.PERIOD_S)
    assert facts["training_h"] == pytest.approx((cut_s - 465.0) / H)
    # the rest of the training part is excluded: it neither trains nor validates
    between = _log_times(table, frame, {"excluded"})
    assert np.isin(np.arange(cut_s, rd.SPLIT_S, rd.PERIOD_S), between).all()
    # validation: every sample from 101 265 s on, whatever the cut (but the last 11 min rest,
    # shorter than min_run_s: excluded, as in bench_realdata), so every test row is scored
    validated = _log_times(table, frame, {"validation_single", "validation_multi", "validation_idle"})
    assert np.array_equal(validated, np.arange(rd.SPLIT_S, 166_065.0, rd.PERIOD_S))
    test = rd.test_rows(log["t_s"].to_numpy())
    assert np.isin(log["t_s"].to_numpy()[test], validated).all() and test.sum() == 2141


def test_the_whole_training_part_is_bench_realdata_windows_protocol():
    assert bench.CUTS["28h"][0] == rd.SPLIT_S
    assert bench.curve_config("ch1", rd.SPLIT_S) == rd.machine_config("ch1", "windows") | {
        "runs": {
            "idle_training": True,
            "windows": [
                {"role": "training", "end": 101_265, "unit": "elapsed_s"},
                {"role": "validation", "start": 101_265, "unit": "elapsed_s"},
            ],
        }
    }
    assert [w["role"] for w in bench.curve_runs(14_865.0)["windows"]] == [
        "training",
        "excluded",
        "validation",
    ]


def test_a_training_sample_after_the_cut_is_refused():
    table = pd.DataFrame(
        {
            "role": ["training", "validation_idle"],
            "kind": ["constant", "idle"],
            "speed_rpm": [1250.0, np.nan],
            "start_s": [465.0, 101_265.0],
            "end_s": [14_850.0, 115_650.0],
            "duration_s": [14_400.0, 14_400.0],
        }
    )
    assert bench.training_facts(table, 14_865.0)["training_runs"] == ["1250"]
    with pytest.raises(ValueError, match="after the cut"):
        bench.training_facts(table, 14_850.0)


def test_cuts_outside_the_training_part_and_unknown_names_are_refused():
    with pytest.raises(ValueError, match="outside the training part"):
        bench.curve_runs(rd.SPLIT_S + 15)
    with pytest.raises(ValueError, match="unknown cut"):
        bench.parse_cuts("2h,3days")
    cuts = bench.parse_cuts("4h, 36000")
    assert list(cuts) == ["4h", "10.0h"] and cuts["10.0h"][0] == 36_000.0
