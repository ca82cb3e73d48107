"""``rafi simulate day --plan``: the twin follows a test plan (the file ``rafi plan`` writes)."""

from __future__ import annotations

import numpy as np
import pytest

from rafi.cli import main
from rafi.deploy.record_plan import read_plan
from rafi.readers.native import read_raw_log
from rafi.twin.day import plan_runs
from rafi.twin.schedules import REST_BEFORE_START_S

PLAN = (
    "speed_rpm,duration_s,run,note\n9000,2400,p1,heat\n0,1800,p1,cool\n0,600,,not recorded\n15000,1800,p2,\n"
)


def test_each_recording_of_the_plan_is_one_cold_start_log_with_the_plans_speeds(tmp_path):
    plan_path = tmp_path / "plan.csv"
    plan_path.write_text(PLAN, encoding="utf-8")
    runs = plan_runs(read_plan(plan_path))
    assert [stem for stem, _, _ in runs] == ["p1", "p2"]
    assert (
        main(["simulate", "day", "--plan", str(plan_path), "--out", str(tmp_path / "raw"), "--no-defects"])
        == 0
    )
    files = sorted((tmp_path / "raw" / "tapping-center-a").glob("*.csv"))
    assert [f.stem.split("_")[-1] for f in files] == ["p1", "p2"]
    for path, steps in zip(files, ([(9000, 2400), (0, 1800)], [(15000, 1800)])):
        log = read_raw_log(path)
        t = (log["time"] - log["time"].iloc[0]).dt.total_seconds().to_numpy()
        speed = log["speed_rpm"].to_numpy(float)
        assert t[-1] + 5 == pytest.approx(REST_BEFORE_START_S + sum(d for _, d in steps))
        start = REST_BEFORE_START_S
        assert np.all(speed[t < start] == 0)
        for rpm, duration in steps:
            inside = (t >= start + 60) & (t < start + duration - 60)  # away from the step edges
            assert np.allclose(speed[inside], rpm, atol=0.02 * max(rpm, 1) + 1)
            start += duration


def test_a_plan_mistake_is_one_line_and_exit_64(tmp_path, capsys):
    bad = tmp_path / "plan.csv"
    bad.write_text("speed_rpm,duration_s\n9000,-1\n", encoding="utf-8")
    assert main(["simulate", "day", "--plan", str(bad), "--out", str(tmp_path / "raw")]) == 64
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "line 2" in err and "duration_s" in err
    assert not (tmp_path / "raw").exists()


def test_a_recording_that_starts_at_rest_is_logged_as_the_plan_says_without_a_second_rest(tmp_path):
    plan_path = tmp_path / "plan.csv"
    plan_path.write_text("speed_rpm,duration_s,run\n0,180,r\n18000,3600,r\n0,1800,r\n", encoding="utf-8")
    ((stem, schedule, _),) = plan_runs(read_plan(plan_path))
    # the plan's 180 s rest is the whole rest: with the twin's own 180 s it would be 360 s, above
    # runs.max_leading_rest_s (300 s), and the pipeline would cut it as a run of its own
    assert stem == "r" and [(s.duration_s, s.speed_rpm) for s in schedule] == [
        (180.0, 0.0),
        (3600.0, 18000.0),
        (1800.0, 0.0),
    ]
