"""rafi.runs.find_runs on synthetic speed schedules with known boundaries."""

from __future__ import annotations

import time

import numpy as np
import pandas as pd
import pytest

from rafi import SENSORS
from rafi.runs import RUNS_FRAME_COLUMNS, RUNS_TABLE_COLUMNS, find_runs

from synthetic import schedule_log

H = 3600.0
TRAIN = [3000, 6000, 9000, 12000, 15000, 18000]
KW = dict(training_speeds_rpm=TRAIN, speed_tolerance_rpm=50, idle_below_rpm=100, min_run_s=1800,
          min_constant_s=3600, overrides={}, reference_rule="run_start", reference_window_s=60)

#: 4 constant runs + idles (one too short) + a varying tail with a short stop inside it.
CONTINUOUS = [(3000, 4 * H), (0, H), (6000, 4 * H), (0, 600), (4500, 3 * H), (0, 2700),
              (9000, 2 * H), (0, H), (3000, 1200), (9000, 1200), (0, 300), (12000, 1200),
              (6000, 1200)]
#: expected runs: (first piece, last piece, kind, role)
EXPECTED = [(0, 0, "constant", "training"), (1, 1, "idle", "validation_idle"),
            (2, 2, "constant", "training"), (3, 3, "idle", "excluded"),
            (4, 4, "constant", "validation_single"), (5, 5, "idle", "validation_idle"),
            (6, 6, "constant", "training"), (7, 7, "idle", "validation_idle"),
            (8, 12, "varying", "validation_multi")]
#: one cold-start multi-condition test (4.5 h of short steps, one stop)
MULTI = [(3000, 1800), (9000, 2400), (0, 600), (15000, 1800), (4500, 2700), (12000, 3000),
         (6000, 1800), (18000, 2100)]


def runs(frames, **over):
    frames = frames if isinstance(frames, dict) else {"log": frames}
    return find_runs(frames, {k: f"sha-{k}" for k in frames}, **{**KW, **over})


@pytest.mark.parametrize("ramp,noise", [(0, 0.0), (1, 20.0), (2, 0.0), (3, 30.0), (1, 45.0)])
def test_continuous_log_boundaries_and_roles(ramp, noise):
    frame, pieces = schedule_log(CONTINUOUS, ramp_samples=ramp, speed_noise_rpm=noise, seed=ramp)
    table, rf = runs({"cont": frame})
    assert len(table) == len(EXPECTED)
    assert table["run_id"].tolist() == [f"cont#{k}" for k in range(1, 10)]
    for row, (p0, p1, kind, role) in zip(table.itertuples(), EXPECTED):
        assert (row.kind, row.role) == (kind, role), row
        # boundaries within two samples (ramp samples may go to either neighbour)
        slack = 5.0 * max(2, ramp)
        assert abs(row.start_s - pieces["start_s"][p0]) <= slack, row
        assert abs(row.end_s - pieces["end_s"][p1]) <= slack, row
        assert row.role_source == "auto" and row.file == "cont" and row.sha256 == "sha-cont"
    # runs tile the log: no sample lost or counted twice
    assert table["duration_s"].sum() == len(frame) * 5.0 and len(rf) == len(frame)
    assert np.all(table["start_s"].to_numpy()[1:] == table["end_s"].to_numpy()[:-1] + 5.0)
    constant = table[table["kind"] == "constant"]
    np.testing.assert_allclose(constant["speed_rpm"], [3000, 6000, 4500, 9000], atol=noise + 1)
    assert "min_run_s" in table.loc[3, "note"]
    tail = table.iloc[-1]
    assert tail["speed_min_rpm"] <= 0.0 + noise and tail["speed_max_rpm"] >= 12000 - noise


def test_tables_have_the_design_columns():
    frame, _ = schedule_log(CONTINUOUS[:3])
    table, rf = runs(frame)
    assert list(table.columns) == list(RUNS_TABLE_COLUMNS)
    assert list(rf.columns) == list(RUNS_FRAME_COLUMNS)
    assert rf["time"].dtype == "datetime64[ns]" and rf["t_s"].dtype == np.float64
    assert table["segment"].dtype == np.int64
    for rid, g in rf.groupby("run_id", sort=False):
        assert g["t_s"].iloc[0] == 0.0 and np.all(np.diff(g["t_s"]) == 5.0)
    assert table["reference"].iloc[0] == "median of the first 60 s of the run (run_start)"


def test_single_multi_step_file_is_one_varying_run():
    frame, pieces = schedule_log(MULTI, ramp_samples=1, speed_noise_rpm=10)
    table, rf = runs({"2026-03-16_multi.csv": frame})
    assert len(table) == 1
    row = table.iloc[0]
    assert row["run_id"] == "2026-03-16_multi"                # the stem: one run per file
    assert row["file"] == "2026-03-16_multi.csv"
    assert (row["kind"], row["role"]) == ("varying", "validation_multi")
    assert row["duration_s"] == 4.5 * H and len(rf) == len(frame)


def test_single_training_file_keeps_its_stem_and_starts_cold():
    frame, _ = schedule_log([(12000, 4 * H)])
    table, rf = runs({"train_12000": frame})
    assert table["run_id"].tolist() == ["train_12000"]
    assert table["role"].tolist() == ["training"]
    assert abs(rf["dz_um"].iloc[:12].median()) < 1e-9
    assert rf["dz_um"].iloc[-1] > 10


def test_speed_outside_tolerance_is_validation_single():
    frame, _ = schedule_log([(6080, 2 * H)])
    assert runs(frame)[0]["role"].tolist() == ["validation_single"]
    frame, _ = schedule_log([(6040, 2 * H)])
    assert runs(frame)[0]["role"].tolist() == ["training"]


def test_overrides_by_stem_and_by_run_id():
    a, _ = schedule_log([(6000, 4 * H)])
    b, _ = schedule_log(CONTINUOUS[:3])
    table, _ = runs({"a": a, "b": b}, overrides={"a": "excluded", "b#3": "validation_single"})
    t = table.set_index("run_id")
    assert t.loc["a", "role"] == "excluded" and t.loc["a", "role_source"] == "config"
    assert "automatic role: training" in t.loc["a", "note"]
    assert t.loc["b#3", "role"] == "validation_single" and t.loc["b#3", "role_source"] == "config"
    assert t.loc["b#1", "role"] == "training" and t.loc["b#1", "role_source"] == "auto"
    with pytest.raises(ValueError, match="not one of"):
        runs(a, overrides={"a": "train"})


def test_reference_run_start_and_log_start():
    frame, _ = schedule_log(CONTINUOUS[:3], noise_temp=0.05, noise_disp=0.2, seed=4)
    t_run, f_run = runs(frame, reference_rule="run_start", reference_window_s=60)
    t_log, f_log = runs(frame, reference_rule="log_start", reference_window_s=60)
    assert t_log["reference"].iloc[0] == "median of the first 60 s of segment 0 of the log (log_start)"
    first12 = frame.iloc[:12]                                   # 60 s at 5 s = 12 samples
    third = t_run[t_run["run_id"] == "log#3"].iloc[0]
    start = int(third["start_s"] / 5)
    for s in ("T6", "T9"):
        ref_run = frame[s].iloc[start:start + 12].median()
        ref_log = first12[s].median()
        g_run = f_run[f_run["run_id"] == "log#3"]
        g_log = f_log[f_log["run_id"] == "log#3"]
        np.testing.assert_allclose(g_run[f"d{s}"], g_run[s] - ref_run)
        np.testing.assert_allclose(g_log[f"d{s}"], g_log[s] - ref_log)
    ref_z = frame["disp_um"].iloc[start:start + 12].median()
    np.testing.assert_allclose(f_run.loc[f_run["run_id"] == "log#3", "dz_um"],
                               frame["disp_um"].iloc[start:] - ref_z)
    # log_start: the second heating run does not start from zero (the machine is still warm)
    g_log = f_log[f_log["run_id"] == "log#3"]
    assert g_log["dT6"].iloc[:12].median() > 0.3
    with pytest.raises(ValueError, match="reference_rule"):
        runs(frame, reference_rule="first")


def test_runs_never_span_segments_and_log_start_uses_the_segment():
    a, _ = schedule_log([(3000, 2 * H)], segment=0)
    b, _ = schedule_log([(3000, 2 * H)], segment=1, t0_s=2 * H + 600,
                        start=pd.Timestamp("2026-03-02T10:10:00"), seed=1)
    b[list(SENSORS)] += 1.0                                    # warmer after the gap
    frame = pd.concat([a, b], ignore_index=True)
    table, rf = runs({"log": frame}, reference_rule="log_start")
    assert table["segment"].tolist() == [0, 1] and table["run_id"].tolist() == ["log#1", "log#2"]
    assert table["start_s"].tolist() == [0.0, 2 * H + 600]
    second = rf[rf["run_id"] == "log#2"]
    assert abs(second["dT1"].iloc[:12].median()) < 0.05       # reference of segment 1, not 0


def test_sensor_without_reference_gets_nan_rises_and_a_note():
    frame, _ = schedule_log([(9000, 2 * H)])
    frame.loc[:20, "T5"] = np.nan                              # left NaN by cleaning
    table, rf = runs(frame)
    assert rf["dT5"].isna().all() and rf["dT6"].notna().all()
    assert "T5" in table["note"].iloc[0]


def test_empty_input_gives_empty_tables():
    table, rf = find_runs({}, {}, **KW)
    assert len(table) == 0 and list(table.columns) == list(RUNS_TABLE_COLUMNS)
    assert len(rf) == 0 and list(rf.columns) == list(RUNS_FRAME_COLUMNS)


def test_find_runs_is_fast():
    frame, _ = schedule_log(CONTINUOUS * 3, speed_noise_rpm=20)    # ~37 000 samples
    runs(frame)
    t0 = time.perf_counter()
    table, rf = runs(frame)
    assert time.perf_counter() - t0 < 0.5
    assert len(rf) == len(frame)
