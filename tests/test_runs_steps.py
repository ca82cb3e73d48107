"""The steps of rafi.method.runs (segmentation, role cascade, reference state, frame assembly)
one by one, on data built with its truth."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rafi.method.runs import (
    RUNS_FRAME_COLUMNS,
    LogArrays,
    RunSpan,
    assign_role,
    cut_at,
    log_arrays,
    reference_state,
    run_rules,
    run_samples,
    segment_runs,
    speed_pieces,
    speed_statistics,
    split_log,
    stack_runs,
)
from rafi.method.windows import Window
from rafi.twin.synthetic_logs import FIND_RUNS_KWARGS

PERIOD = 5.0
SEGMENT_KW = dict(tol=50.0, idle_below=100.0, min_constant_s=600.0)


def rules(**over):
    kw = {"windows": [], "idle_training": False, "allow_training_after_validation": False}
    return run_rules(**{**FIND_RUNS_KWARGS, **kw, **over})


def schedule(*pieces, noise=0.0, seed=0):
    """Speed per sample of ``(speed_rpm, samples)`` pieces, and the true piece starts."""
    rng = np.random.default_rng(seed)
    speed = np.concatenate([np.full(n, float(v)) for v, n in pieces])
    speed[speed > 0] += rng.uniform(-noise, noise, int((speed > 0).sum()))
    starts = np.cumsum([0] + [n for _, n in pieces])
    return speed, starts


# --------------------------------------------------------------------------- segmentation


def test_speed_pieces_follow_set_points_through_noise():
    speed, _ = schedule((3000, 40), (3200, 30), (3000, 25), noise=20.0, seed=1)
    idle = np.zeros(len(speed), bool)
    idle[60:65] = True  # an idle stretch inside the second piece
    pieces = speed_pieces(speed, idle, 50.0)
    assert [tuple(p) for p in pieces] == [
        (0, 40, False),
        (40, 60, False),
        (60, 65, True),
        (65, 70, False),
        (70, 95, False),
    ]


def test_segment_runs_absorb_ramps_and_merge_stops_inside_a_schedule():
    ramp = [(1500, 1), (2500, 1)]  # two ramp samples (at most RAMP_MAX_SAMPLES) before the run
    speed, starts = schedule((0, 40), *ramp, (3000, 200), (0, 60), (6000, 40), (0, 20), (9000, 40), (0, 200))
    runs = segment_runs(speed, PERIOD, max_leading_rest_s=300.0, **SEGMENT_KW)
    # the 200 s rest before the start is absorbed, with the ramp, by the first constant run
    assert runs[0] == (0, int(starts[4]), "constant", 40)
    # short steps with a 100 s stop between them: one varying run, the stop included
    assert runs[1][2] == "idle" and runs[2] == (int(starts[5]), int(starts[8]), "varying", 0)
    assert runs[3] == (int(starts[8]), len(speed), "idle", 0)


def test_segment_runs_keep_a_long_leading_rest_as_its_own_run():
    speed, starts = schedule((0, 80), (3000, 200))
    runs = segment_runs(speed, PERIOD, max_leading_rest_s=300.0, **SEGMENT_KW)
    assert runs == [(0, 80, "idle", 0), (80, 280, "constant", 0)]


def test_split_log_never_crosses_a_segment():
    speed, _ = schedule((3000, 300))
    segment = np.r_[np.zeros(120), np.ones(180)].astype("int64")
    spans = split_log(speed, segment, PERIOD, max_leading_rest_s=0.0, **SEGMENT_KW)
    assert spans == [RunSpan(0, 0, 120, 0, 120, "constant", 0), RunSpan(1, 120, 300, 120, 300, "constant", 0)]


def test_cut_at_splits_runs_and_keeps_the_rest_in_the_first_part():
    spans = [RunSpan(0, 0, 100, 0, 60, "constant", 30), RunSpan(0, 0, 100, 60, 100, "idle", 0)]
    cut = cut_at(spans, np.array([20, 60, 90]))
    assert [(s.start, s.end, s.kind, s.rest) for s in cut] == [
        (0, 20, "constant", 20),
        (20, 60, "constant", 0),
        (60, 90, "idle", 0),
        (90, 100, "idle", 0),
    ]


# --------------------------------------------------------------------------- roles


@pytest.mark.parametrize(
    "kind,speed,duration,expected",
    [
        ("constant", 6020.0, 3600.0, "training"),
        ("constant", 6100.0, 3600.0, "validation_single"),
        ("varying", 6000.0, 3600.0, "validation_multi"),
        ("idle", 0.0, 3600.0, "validation_idle"),
        ("constant", 6000.0, 600.0, "excluded"),  # shorter than min_run_s
    ],
)
def test_automatic_roles(kind, speed, duration, expected):
    role, source, reason = assign_role(kind, speed, duration, None, ("log#1", "log", "log.csv"), rules())
    assert (role, source) == (expected, "auto") and reason


def test_role_cascade_idle_training_then_window_then_override():
    names = ("log#2", "log", "log.csv")
    assert assign_role("idle", 0.0, 3600.0, None, names, rules(idle_training=True))[:2] == (
        "training",
        "auto",
    )
    validation = Window("validation", 0.0, np.inf, "validation window start-end of the log")
    role, source, reason = assign_role("constant", 6000.0, 3600.0, validation, names, rules())
    assert (role, source) == ("validation_single", "window") and "validation window" in reason
    # the run id wins over the stem, and both over the window
    over = rules(overrides={"log": "excluded", "log#2": "training"})
    role, source, reason = assign_role("constant", 6000.0, 3600.0, validation, names, over)
    assert (role, source) == ("training", "config")
    assert reason.startswith("run-id override 'log#2'") and "otherwise: validation_single" in reason
    assert (
        assign_role("varying", 0.0, 3600.0, None, names, rules(overrides={"log.csv": "excluded"}))[0]
        == "excluded"
    )


def test_run_rules_refuse_unknown_rules_and_roles():
    with pytest.raises(ValueError, match="reference_rule"):
        rules(reference_rule="end")
    with pytest.raises(ValueError, match="override 'x'"):
        rules(overrides={"x": "testing"})


# --------------------------------------------------------------------------- reference and frame


def log_of(n=100, *, segment=None):
    t_s = np.arange(n) * PERIOD
    temps = 20.0 + np.outer(np.arange(n), np.arange(1, 17)) * 0.01
    temps[:, 4] = np.nan  # T5 never valid
    disp = 0.1 * np.arange(n)
    seg = np.zeros(n, "int64") if segment is None else segment
    times = (pd.Timestamp("2026-01-01") + pd.to_timedelta(t_s, unit="s")).to_numpy()
    return LogArrays(t_s, seg, np.full(n, 3000.0), temps, disp, times, PERIOD)


def test_reference_is_the_median_of_the_window_of_the_run_or_its_segment():
    log = log_of()
    span = RunSpan(0, 0, 100, 40, 100, "constant", 0)
    ref = reference_state(log, span, rules(reference_window_s=30))  # samples 40..45
    np.testing.assert_allclose(ref.temps[[0, 15]], 20.0 + 42.5 * 0.01 * np.array([1, 16]))
    assert ref.disp_um == pytest.approx(4.25) and ref.missing == ["T5"]
    assert ref.text == "median of the first 30 s of the run (run_start)"
    ref = reference_state(log, span, rules(reference_rule="log_start", reference_window_s=30))
    assert ref.disp_um == pytest.approx(0.25) and "segment 0 of the log (log_start)" in ref.text
    one = reference_state(log, span, rules(reference_window_s=0.1))  # at least one sample
    assert one.disp_um == pytest.approx(4.0)


def test_run_samples_are_the_rises_from_the_reference():
    log = log_of()
    span = RunSpan(0, 0, 100, 40, 100, "constant", 0)
    ref = reference_state(log, span, rules(reference_window_s=30))
    run = run_samples(log, span, ref, run_id="log#2", key="log.csv")
    assert (run["run_id"], run["log"], run["n"]) == ("log#2", "log.csv", 60)
    cols = run["columns"]
    np.testing.assert_array_equal(cols["t_s"], np.arange(60) * PERIOD)
    np.testing.assert_array_equal(cols["log_t_s"], log.t_s[40:])
    np.testing.assert_allclose(cols["dz_um"], log.disp[40:] - 4.25)
    assert np.isnan(cols["dT5"]).all()
    np.testing.assert_allclose(cols["dT16"], (np.arange(40, 100) - 42.5) * 0.16)
    frame = stack_runs(
        [run, run_samples(log, RunSpan(0, 0, 100, 0, 40, "idle", 0), ref, run_id="a", key="k")]
    )
    assert list(frame.columns) == list(RUNS_FRAME_COLUMNS) and len(frame) == 100
    assert frame["run_id"].tolist() == ["log#2"] * 60 + ["a"] * 40 and frame["segment"].dtype == np.int64


def test_empty_stack_is_typed():
    frame = stack_runs([])
    assert list(frame.columns) == list(RUNS_FRAME_COLUMNS) and len(frame) == 0
    assert frame["time"].dtype == "datetime64[ns]" and frame["segment"].dtype == np.int64


def test_speed_statistics_ignore_missing_values():
    assert speed_statistics(np.array([np.nan, 10.0, 30.0, 20.0])) == (20.0, 10.0, 30.0)
    assert all(np.isnan(speed_statistics(np.array([np.nan, np.nan]))))


def test_log_arrays_without_time_columns_or_segments():
    frame = pd.DataFrame(
        {
            "time": pd.date_range("2026-01-01", periods=4, freq="5s"),
            "speed_rpm": 1.0,
            "T1": np.nan,
            "disp_um": 0.0,
        }
    )
    log = log_arrays(frame)
    np.testing.assert_array_equal(log.t_s, [0.0, 5.0, 10.0, 15.0])
    assert log.period == 5.0 and (log.segment == 0).all() and np.isnan(log.temps).all()
    assert log.temps.shape == (4, 1) and log.sensors == ("T1",)
