"""rafi.method.runs.find_runs on synthetic speed schedules with known boundaries."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rafi import SENSORS
from rafi.method.runs import RUNS_FRAME_COLUMNS, RUNS_TABLE_COLUMNS, find_runs
from rafi.twin.synthetic_logs import CONTINUOUS_SCHEDULE, FIND_RUNS_KWARGS, schedule_log

H = 3600.0
TRAIN = FIND_RUNS_KWARGS["training_speeds_rpm"]
KW = FIND_RUNS_KWARGS
CONTINUOUS = CONTINUOUS_SCHEDULE
#: expected runs: (first piece, last piece, kind, role)
EXPECTED = [
    (0, 0, "constant", "training"),
    (1, 1, "idle", "training"),  # a cool-down between two training runs: the training schedule
    (2, 2, "constant", "training"),
    (3, 3, "idle", "excluded"),
    (4, 4, "constant", "validation_single"),
    (5, 5, "idle", "validation_idle"),
    (6, 6, "constant", "validation_single"),  # at a training speed, but after the 4500 validation run
    (7, 7, "idle", "validation_idle"),
    (8, 12, "varying", "validation_multi"),
]
#: one cold-start multi-condition test (4.5 h of short steps, one stop)
MULTI = [
    (3000, 1800),
    (9000, 2400),
    (0, 600),
    (15000, 1800),
    (4500, 2700),
    (12000, 3000),
    (6000, 1800),
    (18000, 2100),
]


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
        expected_source = "leak_guard" if row.Index == 6 else "auto"
        assert row.role_source == expected_source and row.file == "cont" and row.sha256 == "sha-cont"
    # runs tile the log: no sample lost or counted twice
    assert table["duration_s"].sum() == len(frame) * 5.0 and len(rf) == len(frame)
    assert np.all(table["start_s"].to_numpy()[1:] == table["end_s"].to_numpy()[:-1] + 5.0)
    constant = table[table["kind"] == "constant"]
    np.testing.assert_allclose(constant["speed_rpm"], [3000, 6000, 4500, 9000], atol=noise + 1)
    assert "min_run_s" in table.loc[3, "role_reason"]
    tail = table.iloc[-1]
    assert tail["speed_min_rpm"] <= 0.0 + noise and tail["speed_max_rpm"] >= 12000 - noise


def test_tables_have_the_design_columns():
    frame, _ = schedule_log(CONTINUOUS[:3])
    table, rf = runs(frame)
    assert list(table.columns) == list(RUNS_TABLE_COLUMNS)
    assert list(rf.columns) == list(RUNS_FRAME_COLUMNS)
    assert rf["time"].dtype == "datetime64[ns]" and rf["t_s"].dtype == np.float64
    assert table["segment"].dtype == np.int64
    for _rid, g in rf.groupby("run_id", sort=False):
        assert g["t_s"].iloc[0] == 0.0 and np.all(np.diff(g["t_s"]) == 5.0)
    assert table["reference"].iloc[0] == "median of the first 60 s of the run (run_start)"


def test_single_multi_step_file_is_one_varying_run():
    frame, pieces = schedule_log(MULTI, ramp_samples=1, speed_noise_rpm=10)
    table, rf = runs({"2026-03-16_multi.csv": frame})
    assert len(table) == 1
    row = table.iloc[0]
    assert row["run_id"] == "2026-03-16_multi"  # the stem: one run per file
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
    assert "otherwise: training" in t.loc["a", "role_reason"]
    assert t.loc["b#3", "role"] == "validation_single" and t.loc["b#3", "role_source"] == "config"
    assert t.loc["b#1", "role"] == "training" and t.loc["b#1", "role_source"] == "auto"
    with pytest.raises(ValueError, match="not one of"):
        runs(a, overrides={"a": "train"})


def test_reference_run_start_and_log_start():
    frame, _ = schedule_log(CONTINUOUS[:3], noise_temp=0.05, noise_disp=0.2, seed=4)
    t_run, f_run = runs(frame, reference_rule="run_start", reference_window_s=60)
    t_log, f_log = runs(frame, reference_rule="log_start", reference_window_s=60)
    assert t_log["reference"].iloc[0] == "median of the first 60 s of segment 0 of the log (log_start)"
    first12 = frame.iloc[:12]  # 60 s at 5 s = 12 samples
    third = t_run[t_run["run_id"] == "log#3"].iloc[0]
    start = int(third["start_s"] / 5)
    for s in ("T6", "T9"):
        ref_run = frame[s].iloc[start : start + 12].median()
        ref_log = first12[s].median()
        g_run = f_run[f_run["run_id"] == "log#3"]
        g_log = f_log[f_log["run_id"] == "log#3"]
        np.testing.assert_allclose(g_run[f"d{s}"], g_run[s] - ref_run)
        np.testing.assert_allclose(g_log[f"d{s}"], g_log[s] - ref_log)
    ref_z = frame["disp_um"].iloc[start : start + 12].median()
    np.testing.assert_allclose(
        f_run.loc[f_run["run_id"] == "log#3", "dz_um"], frame["disp_um"].iloc[start:] - ref_z
    )
    # log_start: the second heating run does not start from zero (the machine is still warm)
    g_log = f_log[f_log["run_id"] == "log#3"]
    assert g_log["dT6"].iloc[:12].median() > 0.3
    with pytest.raises(ValueError, match="reference_rule"):
        runs(frame, reference_rule="first")


def test_runs_never_span_segments_and_log_start_uses_the_segment():
    a, _ = schedule_log([(3000, 2 * H)], segment=0)
    b, _ = schedule_log(
        [(3000, 2 * H)], segment=1, t0_s=2 * H + 600, start=pd.Timestamp("2026-03-02T10:10:00"), seed=1
    )
    b[list(SENSORS)] += 1.0  # warmer after the gap
    frame = pd.concat([a, b], ignore_index=True)
    table, rf = runs({"log": frame}, reference_rule="log_start")
    assert table["segment"].tolist() == [0, 1] and table["run_id"].tolist() == ["log#1", "log#2"]
    assert table["start_s"].tolist() == [0.0, 2 * H + 600]
    second = rf[rf["run_id"] == "log#2"]
    assert abs(second["dT1"].iloc[:12].median()) < 0.05  # reference of segment 1, not 0


def test_sensor_without_reference_gets_nan_rises_and_a_note():
    frame, _ = schedule_log([(9000, 2 * H)])
    frame.loc[:20, "T5"] = np.nan  # left NaN by cleaning
    table, rf = runs(frame)
    assert rf["dT5"].isna().all() and rf["dT6"].notna().all()
    assert "T5" in table["note"].iloc[0]


def test_empty_input_gives_empty_tables():
    table, rf = find_runs({}, {}, **KW)
    assert len(table) == 0 and list(table.columns) == list(RUNS_TABLE_COLUMNS)
    assert len(rf) == 0 and list(rf.columns) == list(RUNS_FRAME_COLUMNS)


def test_every_sample_of_a_long_log_is_in_one_run():
    # the time of find_runs is measured by benchmarks/bench_steps.py (find_runs_37000)
    frame, _ = schedule_log(CONTINUOUS * 3, speed_noise_rpm=20)  # ~37 000 samples
    table, rf = runs(frame)
    assert len(rf) == len(frame)


# --------------------------------------------------------------------------- rest before start


def test_short_leading_rest_is_absorbed_into_the_run():
    """A cold start logged from rest: one run (the stem), t_s from the log start, reference on the rest."""
    frame, _ = schedule_log([(0, 180), (12000, 4 * H)], speed_noise_rpm=20, seed=3)
    table, rf = runs({"train_12000.csv": frame})
    assert table["run_id"].tolist() == ["train_12000"] and len(rf) == len(frame)
    row = table.iloc[0]
    assert (row["kind"], row["role"]) == ("constant", "training")
    # speed statistics ignore the rest
    assert abs(row["speed_rpm"] - 12000) <= 20 and row["speed_min_rpm"] >= 12000 - 20
    assert row["start_s"] == 0.0 and row["duration_s"] == 4 * H + 180
    assert "rest before start: 180 s" in row["note"]
    # t_s starts at the log start; the reference window (60 s) falls on the rest
    assert rf["t_s"].iloc[0] == 0.0 and rf["speed_rpm"].iloc[0] == 0.0
    ref = frame.iloc[:12]
    np.testing.assert_allclose(rf["dT6"], frame["T6"] - ref["T6"].median())
    np.testing.assert_allclose(rf["dz_um"], frame["disp_um"] - ref["disp_um"].median())


def test_rest_before_a_multi_condition_schedule_keeps_one_varying_run():
    steps = [p for p in MULTI if p[0] > 0]  # without the stop inside
    frame, _ = schedule_log([(0, 180)] + steps, speed_noise_rpm=10)
    table, rf = runs({"multi": frame})
    assert len(table) == 1 and table["run_id"].iloc[0] == "multi"
    row = table.iloc[0]
    assert (row["kind"], row["role"]) == ("varying", "validation_multi")
    assert row["speed_min_rpm"] >= 3000 - 10  # the rest does not count
    assert row["speed_max_rpm"] >= 18000 - 10
    assert row["duration_s"] == sum(d for _, d in steps) + 180
    # with the stop inside the schedule: still one run; the stop is part of it
    frame, _ = schedule_log([(0, 180)] + MULTI, ramp_samples=1, speed_noise_rpm=10)
    table, _ = runs({"multi": frame})
    assert len(table) == 1 and table["kind"].iloc[0] == "varying"
    assert table["speed_min_rpm"].iloc[0] == 0.0 and table["duration_s"].iloc[0] == 4.5 * H + 180


def test_long_leading_rest_stays_an_idle_run():
    frame, _ = schedule_log([(0, 400), (6000, 4 * H)])
    table, _ = runs({"log": frame})
    assert table["run_id"].tolist() == ["log#1", "log#2"]
    assert table["kind"].tolist() == ["idle", "constant"]
    assert table["role"].tolist() == ["excluded", "training"]  # 400 s < min_run_s
    assert table["start_s"].iloc[1] == 400.0 and table["note"].iloc[1] == ""
    # the same file with the key at 0: the short rest is never absorbed
    short, _ = schedule_log([(0, 180), (6000, 4 * H)])
    table0, _ = runs({"log": short}, max_leading_rest_s=0)
    assert table0["kind"].tolist() == ["idle", "constant"]


@pytest.mark.parametrize("ramp,noise", [(0, 0.0), (1, 20.0), (3, 30.0)])
def test_continuous_logs_are_unaffected_by_the_rest_rule(ramp, noise):
    frame, _ = schedule_log(CONTINUOUS, ramp_samples=ramp, speed_noise_rpm=noise, seed=ramp)
    with_rule, f1 = runs({"cont": frame})
    without, f0 = runs({"cont": frame}, max_leading_rest_s=0)
    pd.testing.assert_frame_equal(with_rule, without)
    pd.testing.assert_frame_equal(f1, f0)
    # idle stretches inside the log (also the short 600 s / 300 s ones) are not a leading rest
    assert (with_rule["note"].str.contains("rest before start") == False).all()  # noqa: E712


def test_rest_at_the_start_of_a_later_segment_is_absorbed_too():
    a, _ = schedule_log([(3000, 2 * H)], segment=0)
    b, _ = schedule_log(
        [(0, 120), (3000, 2 * H)],
        segment=1,
        t0_s=2 * H + 600,
        start=pd.Timestamp("2026-03-02T10:10:00"),
        seed=1,
    )
    table, rf = runs({"log": pd.concat([a, b], ignore_index=True)})
    assert table["run_id"].tolist() == ["log#1", "log#2"]
    assert table["start_s"].tolist() == [0.0, 2 * H + 600]
    assert "rest before start: 120 s" in table["note"].iloc[1]
    assert rf.loc[rf["run_id"] == "log#2", "speed_rpm"].iloc[0] == 0.0


# ----------------------------------------------------------------- roles by time windows

#: a continuous log: training speeds, cool-downs, a validation speed, then a tail of 1 h steps
#: at training speeds (the case that leaked: each step is exactly min_constant_s long)
CHRONO = [
    (3000, 4 * H),
    (0, 3 * H),
    (6000, 4 * H),
    (0, 3 * H),
    (4500, 3 * H),
    (0, 2 * H),
    (9000, H),
    (6000, H),
    (3000, H),
]
SPAN_S = sum(d for _, d in CHRONO) - 5.0  # first to last sample


def test_tail_after_validation_never_trains_with_automatic_roles():
    frame, pieces = schedule_log(CHRONO)
    table, _ = runs({"log": frame})
    tail = table[table["start_s"] >= pieces["start_s"][6] - 10]
    assert len(tail) == 3 and set(tail["kind"]) == {"constant"}
    # at training speeds and exactly min_constant_s long, but after the 4500 r/min validation run
    assert set(tail["role"]) == {"validation_single"} and set(tail["role_source"]) == {"leak_guard"}
    assert tail["role_reason"].str.contains("leak guard").all()
    # the cool-down between the training runs trains; the one after the last, before the
    # validation run, does not (runs.idle_training: schedule)
    assert table.loc[table["start_s"] < pieces["start_s"][4], "role"].tolist() == [
        "training",
        "training",
        "training",
        "validation_idle",
    ]


def test_fraction_window_cuts_runs_at_the_boundary():
    frame, _ = schedule_log(CHRONO)
    split = 0.4  # 9.2 h: inside the 6000 r/min run (7-11 h), which is cut there
    windows = [
        {"role": "training", "end": split, "unit": "fraction"},
        {"role": "validation", "start": split, "unit": "fraction"},
    ]
    table, rf = runs({"log": frame}, windows=windows, idle_training=False)
    boundary = split * SPAN_S
    # no run spans the boundary, and every sample is in exactly one run
    assert not ((table["start_s"] < boundary - 1e-6) & (table["end_s"] >= boundary)).any()
    assert len(rf) == len(frame) and table["duration_s"].sum() == len(frame) * 5.0
    before = table[table["end_s"] < boundary]
    after = table[table["start_s"] >= boundary]
    assert (before["role_source"] == "window").all() and (after["role_source"] == "window").all()
    # idle runs inside the training window are excluded (idle_training is false)
    assert set(before["role"]) == {"training", "excluded"}
    assert (before.loc[before["kind"] == "idle", "role"] == "excluded").all()
    assert set(after["role"]) <= {"validation_single", "validation_idle"}
    # the cut 6000 r/min run: its two parts keep their kind and get the window's role
    cut = table[(table["kind"] == "constant") & (table["speed_rpm"].round() == 6000)]
    assert cut["role"].tolist()[:2] == ["training", "validation_single"]
    assert "training window start-40 % of the log" in cut["role_reason"].iloc[0]
    # the frame carries the log's clock: log_t_s is the clean frame's t_s, in order
    np.testing.assert_array_equal(rf["log_t_s"].to_numpy(), frame["t_s"].to_numpy())
    assert set(rf["log"]) == {"log"} and (rf["segment"] == 0).all()


def test_window_units_agree():
    frame, _ = schedule_log(CHRONO)
    edge_s = 0.4 * SPAN_S
    t0 = pd.Timestamp(frame["time"].iloc[0])
    as_time = (t0 + pd.Timedelta(seconds=edge_s)).isoformat()
    tables = []
    for unit, value in (("fraction", 0.4), ("elapsed_s", edge_s), ("time", as_time)):
        windows = [
            {"role": "training", "end": value, "unit": unit},
            {"role": "validation", "start": value, "unit": unit},
        ]
        table, _ = runs({"log": frame}, windows=windows)
        tables.append(table[["run_id", "start_s", "end_s", "role"]])
    pd.testing.assert_frame_equal(tables[0], tables[1])
    pd.testing.assert_frame_equal(tables[0], tables[2])


def test_idle_training_makes_cool_downs_training_runs():
    frame, _ = schedule_log(CHRONO)
    windows = [
        {"role": "training", "end": 0.5, "unit": "fraction"},
        {"role": "validation", "start": 0.5, "unit": "fraction"},
    ]
    table, _ = runs({"log": frame}, windows=windows, idle_training=True)
    early = table[table["end_s"] < 0.5 * SPAN_S]
    assert (early.loc[early["kind"] == "idle", "role"] == "training").all()
    # automatic roles: cool-downs become training runs too
    table, _ = runs({"log": frame}, idle_training=True)
    assert (table.loc[(table["kind"] == "idle") & (table["start_s"] < 14 * H), "role"] == "training").all()


def test_leak_guard_refuses_training_window_after_validation_window():
    from rafi.errors import SettingsError

    frame, _ = schedule_log(CHRONO)
    unsafe = [
        {"role": "validation", "end": 0.3, "unit": "fraction"},
        {"role": "training", "start": 0.3, "unit": "fraction"},
    ]
    with pytest.raises(SettingsError) as err:
        runs({"log": frame}, windows=unsafe)
    text = str(err.value)
    assert "log log: training run" in text and "runs.allow_training_after_validation" in text
    assert "lies after or overlaps validation run" in text
    table, _ = runs({"log": frame}, windows=unsafe, allow_training_after_validation=True)
    trained = table[table["role"] == "training"]
    assert (
        len(trained) and trained["note"].str.contains("allowed by runs.allow_training_after_validation").all()
    )
    # a run-id override that trains after validation is refused the same way
    table, _ = runs({"log": frame})
    late = table.loc[table["role"] == "validation_single", "run_id"].iloc[-1]
    with pytest.raises(SettingsError, match="runs.allow_training_after_validation"):
        runs({"log": frame}, overrides={late: "training"})


@pytest.mark.parametrize(
    "windows,match",
    [
        (
            [
                {"role": "training", "end": 0.6, "unit": "fraction"},
                {"role": "validation", "start": 0.5, "unit": "fraction"},
            ],
            "overlap",
        ),
        ([{"role": "train", "end": 0.6}], "role 'train'"),
        ([{"role": "training", "end": 1.5, "unit": "fraction"}], "between 0 and 1"),
        ([{"role": "training", "end": 10, "unit": "hours"}], "unit 'hours'"),
        ([{"role": "training", "stop": 10}], "unknown key"),
        ([{"role": "training", "start": 7200, "end": 3600}], "end is not after start"),
    ],
)
def test_bad_windows_are_refused_naming_the_entry(windows, match):
    from rafi.errors import SettingsError

    frame, _ = schedule_log(CHRONO)
    with pytest.raises(SettingsError, match=match):
        runs({"log": frame}, windows=windows)


def test_time_window_on_a_log_without_a_clock_is_refused():
    from rafi.errors import SettingsError

    frame, _ = schedule_log(CHRONO)
    with pytest.raises(SettingsError, match="has no clock"):
        runs(
            {"log": frame.drop(columns=["time"])},
            windows=[{"role": "training", "end": "2026-01-01T00:00:00", "unit": "time"}],
        )


def test_window_applies_to_matching_logs_only():
    a, _ = schedule_log(CHRONO)
    b, _ = schedule_log(CHRONO, seed=1)
    windows = [{"role": "excluded", "unit": "fraction", "log": "b*"}]
    table, _ = runs({"a": a, "b": b}, windows=windows)
    assert (table.loc[table["file"] == "b", "role"] == "excluded").all()
    assert (table.loc[table["file"] == "a", "role_source"] != "window").all()


# --------------------------------------------------------------------------- no clock


def test_a_log_without_a_clock_gives_runs_without_clock_times(tmp_path):
    """A clean frame the reader marked as having no clock (elapsed seconds without
    input.time.start: ``attrs['metadata']['clock']`` False), read back from its Parquet file as
    rule runs reads it: the runs carry no start/end time and runs.parquet no time, but the same
    spans on the log's clock as the dated log."""
    frame, _ = schedule_log(CONTINUOUS[:3])
    path = tmp_path / "log.parquet"
    undated = frame.copy()
    undated.attrs = {"metadata": {"clock": False}}
    undated.to_parquet(path)
    table, rf = runs({"log": pd.read_parquet(path)})
    dated_table, dated_rf = runs({"log": frame})
    assert (table["start_time"] == "").all() and (table["end_time"] == "").all()
    assert (dated_table["start_time"] != "").all()
    assert rf["time"].isna().all() and dated_rf["time"].notna().all()
    cols = ["run_id", "start_s", "end_s", "role"]
    pd.testing.assert_frame_equal(table[cols], dated_table[cols])


# --------------------------------------------------------------------------- cold or only at rest
#
# foreign-5 (2026-12-01) said "(reference state = cold machine at rest)" of every run that starts from
# rest, also of day09_test, which its generator started warm (1.26 h after the day before). The
# generator's warm starts (rafi.twin.foreign, effect warm_start) are the ground truth: a run is said
# cold only where its temperatures at the reference sit in the machine's at-rest pattern.


def _foreign_runs(seed: int, realism) -> tuple[pd.DataFrame, dict]:
    from rafi.ops.init_preview import runs_arguments
    from rafi.settings import machine_settings
    from rafi.twin.foreign import foreign_machine

    m = foreign_machine(seed, realism=realism)
    settings = machine_settings({"machines": {m.name: m.config}}, m.name)
    table, _ = find_runs(dict(m.logs), {}, **runs_arguments(settings))
    return table.set_index("run_id"), m.truth["realism"]["warm_start"]["rest_h"]


@pytest.mark.parametrize("seed, realism", [(5, ("warm_start",)), (5, "all"), (10, ("warm_start",))])
def test_a_warm_start_is_said_at_rest_and_a_cold_start_cold(seed, realism):
    table, warm_h = _foreign_runs(seed, realism)
    rested = table[table["note"].str.contains("rest before start", regex=False)]
    assert len(rested) == len(table)  # every day starts from rest
    shortly = [stem for stem, h in warm_h.items() if h < 2.0]  # still warm: 1-2 h after the day before
    assert shortly  # the generator drew one for these seeds
    for stem in shortly:
        assert "(reference state = machine at rest)" in table.loc[stem, "note"], stem
    cold = [d for d in table.index if d not in warm_h]  # stood overnight: the training days among them
    for stem in cold:
        assert "(reference state = cold machine at rest)" in table.loc[stem, "note"], stem


def test_too_few_starts_from_rest_are_never_said_cold():
    frame, _ = schedule_log([(0, 180), (12000, 4 * H)], speed_noise_rpm=20, seed=3)
    table, _ = runs({"train_12000.csv": frame})
    assert "(reference state = machine at rest)" in table["note"].iloc[0]
