"""Key sensor ranking (rafi.method.rank) on synthetic runs with a known best sensor set."""

import json
import re

import numpy as np
import pandas as pd
import pytest

from rafi.method.rank import (
    choose_sensors,
    rank_sensors,
    selection_message,
    selection_score,
    training_speed_groups,
)
from rafi.twin.synthetic_runs import make_runs

SPEEDS = (3000, 6000, 9000)


@pytest.fixture(scope="module")
def clean():
    return make_runs(SPEEDS, sigma=0.05, seed=1, validation_speeds=(4500,))


@pytest.fixture(scope="module")
def t9_fault():
    # T9's recorded rise is disturbed at 6000 r/min (loose sensor): it fails there.
    return make_runs(SPEEDS, sigma=0.05, seed=1, sensor_faults={"T9": 1.0}, faults_at_speed=6000)


def test_recovers_known_key_sensors(clean):
    res = rank_sensors(clean.runs_table, clean.runs_frame)
    assert set(res.info["sensors"]) == {"T6", "T8", "T9"}
    assert list(res.key_sensors.columns) == ["sensor", "score_abs_r", "selected_by"]
    assert (res.key_sensors["selected_by"] == "threshold").all()
    assert res.key_sensors["score_abs_r"].is_monotonic_decreasing
    assert (res.key_sensors["score_abs_r"] > 0.97).all()
    assert res.info["fallback_used"] is False
    assert res.info["message"].startswith("3 sensors reach |r| > 0.97 at every training speed")
    assert set(res.info) == {"sensors", "threshold", "scope", "max_key_sensors", "fallback_used", "message"}
    json.dumps(res.info)  # JSON-serialisable


def test_correlation_table_layout_and_values(clean):
    res = rank_sensors(clean.runs_table, clean.runs_frame)
    corr = res.correlation
    assert list(corr.columns) == ["scope", "sensor", "r", "abs_r", "rank"]
    assert set(corr["scope"]) == {"3000", "6000", "9000", "pooled"}  # validation run not a scope
    assert (corr.groupby("scope").size() == 16).all()
    assert (corr.groupby("scope")["rank"].min() == 1).all()
    # r equals numpy's Pearson r on the training run at 6000 r/min
    f = clean.runs_frame
    sub = f[f["run_id"] == "train-6000-1"]
    expected = np.corrcoef(sub["dT13"], sub["dz_um"])[0, 1]
    got = corr.query("scope == '6000' and sensor == 'T13'")["r"].item()
    assert got == pytest.approx(expected, rel=1e-12)
    # pooled uses training runs only
    train = f[f["run_id"].str.startswith("train")]
    got = corr.query("scope == 'pooled' and sensor == 'T6'")["r"].item()
    assert got == pytest.approx(np.corrcoef(train["dT6"], train["dz_um"])[0, 1], rel=1e-12)
    # score of min_per_speed is the minimum |r| over speeds
    per_speed = corr[corr["scope"] != "pooled"].groupby("sensor")["abs_r"].min()
    for _, row in res.key_sensors.iterrows():
        assert row["score_abs_r"] == pytest.approx(per_speed[row["sensor"]])


def test_fallback_adds_next_best_with_message(t9_fault):
    res = rank_sensors(t9_fault.runs_table, t9_fault.runs_frame)
    ks = res.key_sensors
    assert list(ks["sensor"]) == ["T8", "T6", "T13"]
    assert list(ks["selected_by"]) == ["threshold", "threshold", "fallback"]
    assert ks["score_abs_r"].iloc[2] < 0.97
    assert res.info["fallback_used"] is True
    assert re.fullmatch(
        r"only 2 sensors reach \|r\| > 0\.97 at every training speed; T13 added "
        r"as the next best \(min \|r\| 0\.9\d\d\)",
        res.info["message"],
    ), res.info["message"]


def test_pooled_scope_uses_pooled_abs_r(t9_fault):
    res = rank_sensors(t9_fault.runs_table, t9_fault.runs_frame, scope="pooled")
    pooled = res.correlation.query("scope == 'pooled'").sort_values("abs_r", ascending=False)
    assert res.info["sensors"] == list(pooled["sensor"].iloc[:3])
    assert "over the pooled training runs" in res.info["message"]


def test_max_key_sensors_and_threshold(clean):
    res = rank_sensors(clean.runs_table, clean.runs_frame, max_key_sensors=2)
    assert len(res.info["sensors"]) == 2 and not res.info["fallback_used"]
    assert "the best 2 kept" in res.info["message"]
    res = rank_sensors(clean.runs_table, clean.runs_frame, threshold=0.9999)
    assert res.info["fallback_used"]
    assert res.info["message"].startswith("no sensor reaches |r| > 0.9999")
    assert (res.key_sensors["selected_by"] == "fallback").all()


def test_dropped_out_and_constant_sensors_are_never_selected():
    syn = make_runs(SPEEDS, sigma=0.05, seed=1, sensor_faults={"T8": "nan", "T6": "const"})
    res = rank_sensors(syn.runs_table, syn.runs_frame)
    corr = res.correlation
    assert corr.loc[corr["sensor"].isin(["T6", "T8"]), "r"].isna().all()
    assert corr.loc[corr["sensor"].isin(["T6", "T8"]), "rank"].isna().all()
    assert not {"T6", "T8"} & set(res.info["sensors"])
    assert res.info["sensors"][0] == "T9" and res.info["fallback_used"]


def test_nan_at_one_speed_excludes_sensor_under_min_per_speed():
    syn = make_runs(SPEEDS, sigma=0.05, seed=1, sensor_faults={"T8": "nan"}, faults_at_speed=3000)
    res = rank_sensors(syn.runs_table, syn.runs_frame)
    assert "T8" not in res.info["sensors"]


def test_collinearity_matrix(clean):
    res = rank_sensors(clean.runs_table, clean.runs_frame)
    c = res.collinearity
    names = res.info["sensors"]
    assert list(c.index) == names and list(c.columns) == names
    np.testing.assert_allclose(np.diag(c), 1.0)
    np.testing.assert_allclose(c.to_numpy(), c.to_numpy().T)
    assert (c.to_numpy() > 0.9).all()  # the key sensors are strongly collinear


def test_speed_groups_and_errors(clean):
    table = clean.runs_table.copy()
    table.loc[0, "speed_rpm"] = 3004.0
    assert training_speed_groups(table) == {
        3004: ["train-3000-1"],
        6000: ["train-6000-1"],
        9000: ["train-9000-1"],
    }
    extra = clean.runs_table.iloc[[0]].assign(run_id="x", speed_rpm=3010.0)
    two = pd.concat([clean.runs_table, extra])
    assert training_speed_groups(two)[3005] == ["train-3000-1", "x"]
    with pytest.raises(ValueError, match="scope"):
        rank_sensors(clean.runs_table, clean.runs_frame, scope="median")
    with pytest.raises(ValueError, match="training"):
        rank_sensors(clean.runs_table.assign(role="excluded"), clean.runs_frame)


def test_a_short_dropout_only_removes_its_samples(clean):
    """A dropout left after cleaning removes its samples from r; below min_coverage the
    sensor is out."""
    full = rank_sensors(clean.runs_table, clean.runs_frame)
    frame = clean.runs_frame.copy()
    run = clean.runs_table.loc[clean.runs_table["role"] == "training", "run_id"].iloc[0]
    rows = np.flatnonzero(frame["run_id"].to_numpy() == run)
    frame.loc[frame.index[rows[100 : 100 + len(rows) // 20]], "dT8"] = np.nan  # 5 % missing
    short = rank_sensors(clean.runs_table, frame)
    assert short.info["sensors"] == full.info["sensors"] and "T8" in short.info["sensors"]
    r_full = full.correlation.set_index(["scope", "sensor"])["r"]
    r_short = short.correlation.set_index(["scope", "sensor"])["r"]
    assert abs(r_short[("pooled", "T8")] - r_full[("pooled", "T8")]) < 1e-3
    frame.loc[frame.index[rows[: len(rows) // 2]], "dT8"] = np.nan  # 50 % missing
    long = rank_sensors(clean.runs_table, frame, min_coverage=0.9)
    assert "T8" not in long.info["sensors"]


# --------------------------------------------------------------------------- the steps of rank_sensors


def test_selection_score_is_the_worst_speed_or_the_pooled_r():
    per_speed = [np.array([0.99, 0.80, np.nan]), np.array([0.95, 0.90, 0.99])]
    score, where, name = selection_score("min_per_speed", per_speed, np.array([0.5, -0.98, 0.9]))
    np.testing.assert_array_equal(score, [0.95, 0.80, np.nan])
    assert (where, name) == ("at every training speed", "min |r|")
    score, where, name = selection_score("pooled", per_speed, np.array([0.5, -0.98, 0.9]))
    np.testing.assert_array_equal(score, [0.5, 0.98, 0.9])
    assert name == "pooled |r|"


def test_choose_sensors_best_first_ties_by_number_then_fallback():
    score = np.array([0.90, 0.99, np.nan, 0.99, 0.98, 0.50])
    passing, chosen, fallback = choose_sensors(score, 0.97, 3)
    assert (passing, chosen, fallback) == ([1, 3, 4], [1, 3, 4], [])
    passing, chosen, fallback = choose_sensors(score, 0.985, 4)
    assert (passing, chosen, fallback) == ([1, 3], [1, 3], [4, 0])
    assert choose_sensors(score, 0.97, 2)[1] == [1, 3]
    with pytest.raises(ValueError, match="no sensor has a finite correlation"):
        choose_sensors(np.array([np.nan, np.nan]), 0.97, 3)


def test_selection_message_says_what_was_added_and_what_is_missing():
    sensors = ["T1", "T2", "T3"]
    score = np.array([0.99, 0.5, np.nan])
    kw = dict(threshold=0.97, max_key_sensors=3, where="at every training speed", score_name="min |r|")
    message = selection_message(sensors, score, [0], [0], [1], **kw)
    assert message == (
        "only 1 sensor reaches |r| > 0.97 at every training speed; T2 added as the next best "
        "(min |r| 0.500); only 2 sensor(s) have a finite correlation, fewer than max_key_sensors=3"
    )
    assert selection_message(sensors, score, [0], [0], [], **kw) == (
        "1 sensor reaches |r| > 0.97 at every training speed: T1 (min |r| 0.990)"
    )
    kw["max_key_sensors"] = 1
    assert selection_message(sensors, np.array([0.99, 0.98, 0]), [0, 1], [0], [], **kw).startswith(
        "2 sensors reach |r| > 0.97 at every training speed; the best 1 kept: T1"
    )
