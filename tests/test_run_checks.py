"""Issue 45, loud outcomes: rafi.method.run_checks holds the runs against the configuration.

A config entry that matches nothing is an error naming its key; no training run is one line
naming training_speeds_rpm and the speeds the logs hold; a continuous log under run_start and a
training speed without a run are warnings. Logs from the synthetic schedules of
rafi.twin.synthetic_logs (their runs are known from the schedule).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rafi.errors import RafiUserError, SettingsError
from rafi.method.run_checks import (
    check_runs,
    continuous_log_warnings,
    log_spans,
    override_problems,
    speed_glob_problems,
    speed_groups,
    training_speed_problems,
    window_problems,
)
from rafi.method.runs import find_runs
from rafi.twin.synthetic_logs import CONTINUOUS_SCHEDULE, FIND_RUNS_KWARGS, schedule_log

H = 3600.0
#: One cold-start log per training speed: rest, then 2 h at the speed (one run each).
SINGLE = {f"train_{rpm}.csv": [(0, 120), (rpm, 2 * H)] for rpm in (3000, 6000)}


def _runs(frames, **over):
    return find_runs(frames, {k: "" for k in frames}, **{**FIND_RUNS_KWARGS, **over})


@pytest.fixture(scope="module")
def continuous():
    """The continuous schedule as one log: its frames and its runs under run_start."""
    frame, _ = schedule_log(CONTINUOUS_SCHEDULE)
    frames = {"cont.csv": frame}
    table, _ = _runs(frames)
    return frames, table


@pytest.fixture(scope="module")
def singles():
    frames = {name: schedule_log(s, seed=i)[0] for i, (name, s) in enumerate(SINGLE.items())}
    table, _ = _runs(frames)
    return frames, table


def _check(frames, table, **over):
    kw = dict(
        machine="m",
        runs={"windows": [], "overrides": {}},
        reference_rule="run_start",
        training_speeds_rpm=FIND_RUNS_KWARGS["training_speeds_rpm"],
        speed_tolerance_rpm=50,
        all_files=list(frames),
    )
    return check_runs(table, log_spans(frames), **{**kw, **over})


def test_a_continuous_log_under_run_start_warns_naming_log_start(continuous):
    frames, table = continuous
    kept = int((table["role"] != "excluded").sum())
    assert kept >= 2  # the schedule holds several runs
    (warning,) = continuous_log_warnings(table, "run_start")
    assert warning.startswith(f"log cont.csv holds {kept} runs of one continuous recording")
    assert "reference: {rule: log_start}" in warning and "docs/raw-format.md#" in warning
    assert continuous_log_warnings(table, "log_start") == []


def test_one_run_per_log_or_per_segment_does_not_warn(singles, continuous):
    assert continuous_log_warnings(singles[1], "run_start") == []
    # two runs, each in a segment of its own: two recordings, no warning
    table = continuous[1].head(2).assign(segment=[0, 1])
    assert continuous_log_warnings(table, "run_start") == []
    # an excluded run beside one kept run: one run that counts
    table = continuous[1].head(2).assign(role=["training", "excluded"])
    assert continuous_log_warnings(table, "run_start") == []


def test_no_training_run_is_one_line_naming_the_key_and_the_speeds_found(continuous):
    frames, _ = continuous
    table, _ = _runs(frames, training_speeds_rpm=[1000, 2000])
    assert not (table["role"] == "training").any()
    with pytest.raises(SettingsError) as info:
        _check(frames, table, training_speeds_rpm=[1000, 2000])
    msg = str(info.value)
    assert isinstance(info.value, RafiUserError) and "\n" not in msg
    assert msg.startswith("training_speeds_rpm: no training run on machine m: no run at 1000, 2000 r/min")
    # the schedule's constant pieces: 3000 (4 h, 1200 s), 6000 (4 h, 1200 s), 4500, 9000 (2 h,
    # 1200 s), 12000; the short ones are part of the varying tail, so each speed counts its runs
    expected = {}
    for speed, count in speed_groups(table.loc[table["kind"] == "constant", "speed_rpm"], 50):
        expected[round(speed)] = count
    assert expected == {3000: 1, 4500: 1, 6000: 1, 9000: 1}
    assert "constant-speed runs at 3000 (1), 4500 (1), 6000 (1), 9000 (1) r/min" in msg
    n_idle = int((table["kind"] == "idle").sum())
    assert f"1 varying, {n_idle} idle" in msg


def test_a_training_speed_without_a_run_is_a_warning_naming_it(singles):
    frames, table = singles
    warnings = training_speed_problems(table, [3000, 6000, 9000], 50, "m")
    assert warnings == [
        "training_speeds_rpm: no training run at 9000 r/min (configured 3000, 6000, 9000 r/min); the "
        "training runs are at 3000 (1), 6000 (1) r/min (run counts in brackets); the model is fitted "
        "at those speeds only"
    ]
    assert training_speed_problems(table, [3000, 6000], 50, "m") == []


def test_a_machine_left_at_the_default_training_speeds_is_told_so_and_what_to_set(singles):
    frames, table = singles
    table = table[table["speed_rpm"].round() != 3000]  # only 6000 r/min trains
    (warning,) = training_speed_problems(table, [3000, 6000, 9000, 12000, 15000, 18000], 50, "m")
    assert (
        "(the default 3000, 6000, 9000, 12000, 15000, 18000 r/min, the paper rig's: this machine sets none)"
        in (warning)
    )
    assert warning.endswith("set training_speeds_rpm: [6000]")


def test_a_machine_that_may_requalify_from_a_prior_is_told_the_untested_speeds_may_be_the_priors(singles):
    """``rafi plan``'s short programme leaves speeds to the prior: where a prior may be in use the
    warning adds that case and the prior_speeds confirmation; with ``models.prior: none`` it does not."""
    frames, table = singles
    table = table[table["speed_rpm"].round() != 3000]
    speeds = [3000, 6000, 9000, 12000, 15000, 18000]
    plain = training_speed_problems(table, speeds, 50, "m")
    assert training_speed_problems(table, speeds, 50, "m", prior="none") == plain
    (warning,) = training_speed_problems(table, speeds, 50, "m", prior="auto")
    assert warning.startswith(plain[0])
    assert warning.endswith(
        "; in a re-qualification from a prior (models.prior) these speeds are left to the prior, and "
        "the promotion waits for the prior_speeds confirmation (docs/models.md)"
    )
    assert _check(frames, table, training_speeds_rpm=speeds, prior={"machine": "m"}) == [warning]


def test_a_window_glob_matching_no_log_names_the_key_and_the_logs(singles):
    frames, table = singles
    windows = [{"role": "training", "log": "train_*"}, {"role": "validation", "log": "test_*"}]
    with pytest.raises(SettingsError) as info:
        _check(frames, table, runs={"windows": windows, "overrides": {}})
    assert str(info.value) == (
        "runs.windows[1].log: 'test_*' matches no log of machine m (logs: train_3000.csv, train_6000.csv)"
    )


def test_a_window_glob_matching_only_a_quarantined_file_is_no_error(singles):
    frames, table = singles
    windows = [{"role": "validation", "log": "test_*"}]
    spans = log_spans(frames)
    assert window_problems(windows, spans, "m", [*frames, "test_1.csv"]) == []


@pytest.mark.parametrize(
    "window, ok",
    [
        ({"role": "validation", "start": 1.5 * H}, True),  # inside the 2 h 2 min logs
        ({"role": "validation", "start": 3 * H}, False),  # after their end
        ({"role": "training", "end": 0}, False),  # ends before they start (end 0: nothing)
        (
            {
                "role": "validation",
                "start": "2000-01-01T00:00:00",
                "end": "2000-01-02T00:00:00",
                "unit": "time",
            },
            False,
        ),
        ({"role": "validation", "start": 0.5, "unit": "fraction"}, True),
    ],
)
def test_a_window_outside_every_log_names_the_key(singles, window, ok):
    frames, _ = singles
    problems = window_problems([window], log_spans(frames), "m")
    if ok:
        assert problems == []
    else:
        (problem,) = problems
        assert problem.startswith("runs.windows[0] (") and "lies outside every log it applies to" in problem
        assert "train_3000.csv: 0-2.03 h" in problem


def test_an_override_naming_no_run_names_the_key_and_the_runs(continuous):
    frames, table = continuous
    ok = {"cont#2": "excluded", "cont": "training", "cont.csv": "training"}
    assert override_problems(ok, table, "m") == []
    n = len(table)
    (problem,) = override_problems({f"cont#{n + 1}": "excluded"}, table, "m")
    assert problem.startswith(
        f"runs.overrides: 'cont#{n + 1}' names no run, log or file of machine m (runs: cont#1"
    )
    # a run of a quarantined file cannot be known: accepted
    assert override_problems({"gone#3": "excluded", "gone": "training"}, table, "m", ["gone.csv"]) == []


def test_a_speed_glob_matching_no_file_names_the_key():
    files = ["run_3000rpm.csv", "rest.csv"]
    assert speed_glob_problems({"*_3000rpm*": 3000}, files, "m") == []
    assert speed_glob_problems({"*_6000rpm*": 6000}, files, "m") == [
        "input.speed.constant_rpm_by_file: '*_6000rpm*' matches no file of machine m "
        "(files: rest.csv, run_3000rpm.csv)"
    ]
    # case-sensitive, as the reader matches them
    assert len(speed_glob_problems({"*_3000RPM*": 3000}, files, "m")) == 1


def test_every_problem_is_said_in_one_error(singles):
    frames, table = singles
    runs = {"windows": [{"role": "validation", "log": "x*"}], "overrides": {"nope": "training"}}
    with pytest.raises(SettingsError) as info:
        _check(frames, table, runs=runs, speed_by_file={"y*": 100})
    parts = str(info.value).split("; ")
    assert [p.split(":", 1)[0] for p in parts if p.startswith(("runs.", "input."))] == [
        "runs.windows[0].log",
        "runs.overrides",
        "input.speed.constant_rpm_by_file",
    ]


def test_check_runs_returns_the_warnings(continuous):
    frames, table = continuous
    warnings = _check(frames, table)
    assert len(warnings) == 2  # the training speeds without a run, and the continuous log
    # 9000 r/min comes after the 4500 r/min validation run: the leak guard makes it validation;
    # the training cool-down (idle) is no speed
    assert warnings[0].startswith(
        "training_speeds_rpm: no training run at 9000, 12000, 15000, 18000 r/min (the default 3000, "
    )
    assert warnings[0].endswith("set training_speeds_rpm: [3000, 6000]")
    assert "the training runs are at 3000 (1), 6000 (1) r/min" in warnings[0]
    assert warnings[1].startswith("log cont.csv holds")
    assert _check(frames, table, reference_rule="log_start", training_speeds_rpm=[3000, 6000]) == []


def test_speed_groups_join_speeds_within_the_tolerance():
    assert speed_groups([3000, 3020, 2990, 6000, np.nan, 6040, 9000], 50) == [
        (3000.0, 3),
        (6020.0, 2),
        (9000.0, 1),
    ]
    assert speed_groups([], 50) == []


def test_log_spans_from_t_s_or_time():
    t = pd.date_range("2026-01-01", periods=4, freq="10s")
    spans = log_spans(
        {
            "a": pd.DataFrame({"time": t}),
            "b": pd.DataFrame({"t_s": [5.0, 10.0, 25.0]}),
            "c": pd.DataFrame({"t_s": []}),
        }
    )
    assert spans["a"][0] == 30.0 and spans["a"][1][0] == np.datetime64("2026-01-01")
    assert spans["b"] == (20.0, None) and "c" not in spans


def test_rank_without_a_training_run_is_a_user_error_naming_the_key(singles):
    from rafi.method.rank import rank_sensors

    frames, _ = singles
    table, frame = _runs(frames, training_speeds_rpm=[1000])
    with pytest.raises(
        RafiUserError, match=r"^training_speeds_rpm: the runs table has no constant-speed run"
    ):
        rank_sensors(table, frame)
