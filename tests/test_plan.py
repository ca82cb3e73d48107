"""The test programme of a re-qualification (rafi/ops/plan.py): the rule of its docstring on worked
examples, then properties over random speeds, budgets and ranges: the plan fits the budget, every
recorded run lasts at least the minimum, the speeds stay in the range and are the prior's, and
``rafi record --plan`` (read_plan) reads the CSV back step for step."""

from __future__ import annotations

import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rafi.deploy.record_plan import read_plan
from rafi.errors import RafiUserError
from rafi.ops.plan import MAX_RUN_S, PLAN_TABLE_COLUMNS, REST_S, plan_csv, plan_programme, spread_order

PAPER = [3000, 6000, 9000, 12000, 15000, 18000]


def pipeline_runs(plan) -> list[float]:
    """Seconds of every run the pipeline cuts from a one-recording plan: consecutive steps at one
    speed, the first rest (under 300 s) part of the first heat-up."""
    runs: list[list] = []
    for speed, seconds in zip(plan["speed_rpm"], plan["duration_s"]):
        if runs and runs[-1][0] == speed:
            runs[-1][1] += seconds
        else:
            runs.append([speed, float(seconds)])
    if runs[0][0] == 0 and runs[0][1] < 300 and len(runs) > 1:
        runs[1][1] += runs.pop(0)[1]
    return [seconds for _, seconds in runs]


def test_spread_order_takes_the_highest_the_lowest_then_the_widest_gaps():
    assert spread_order(PAPER) == [18000, 3000, 9000, 6000, 12000, 15000]
    assert spread_order([5000, 5000.0]) == [5000]
    assert spread_order([]) == []


def test_four_hours_give_four_spread_speeds_with_a_cool_down_between_heat_ups_in_one_recording():
    plan = plan_programme(speeds_rpm=PAPER, budget_h=4)
    assert tuple(plan.columns) == PLAN_TABLE_COLUMNS and set(plan["run"]) == {"requal"}
    heat = plan[plan["kind"] == "heat-up"]
    assert list(heat["speed_rpm"]) == [18000, 3000, 9000, 6000]
    # 180 + 4 x 1800 + 3 x 1800 = 12780 s; of the 1620 s left the heat-ups take 405 s each, in
    # whole minutes 360 s; the 180 s rounding left go to the three cool-downs, 60 s each
    assert list(heat["duration_s"]) == [2160.0] * 4
    assert list(plan.loc[plan["kind"] == "cool-down", "duration_s"]) == [1860.0] * 3
    assert list(plan["kind"]) == ["rest"] + ["heat-up", "cool-down"] * 3 + ["heat-up"]
    assert plan.attrs["speeds_rpm"] == [18000, 3000, 9000, 6000]
    assert plan["duration_s"].sum() == 4 * 3600 and math.isclose(plan.attrs["total_h"], 4.0)
    assert list(plan["step"]) == list(range(1, 9)) and plan["start_h"].iloc[1] == REST_S / 3600


def test_one_heat_up_gets_no_cool_down_and_a_long_budget_stops_at_4_h_runs():
    for budget_h in (1.0, 1.5):
        short = plan_programme(speeds_rpm=PAPER, budget_h=budget_h)
        assert list(short["speed_rpm"]) == [0, 18000]
        assert list(short["duration_s"]) == [REST_S, 3600 - REST_S if budget_h == 1 else 5220]
    long = plan_programme(speeds_rpm=PAPER, budget_h=100)
    assert long["duration_s"].max() == MAX_RUN_S and long["duration_s"].sum() < 100 * 3600
    assert list(long["kind"]).count("cool-down") == 6


def test_the_range_in_use_keeps_its_speeds_and_uncertainty_buys_time_where_the_prior_is_unsure():
    plan = plan_programme(
        speeds_rpm=PAPER, budget_h=4, speed_range=(4000, 16000), uncertainty={6000: 1.0, 15000: 3.0}
    )
    heat = plan[plan["kind"] == "heat-up"].set_index("speed_rpm")["duration_s"]
    assert sorted(heat.index) == [6000, 9000, 12000, 15000]
    # speeds the mapping does not name count as its worst (3.0)
    assert heat[6000] < heat[15000] == heat[9000] == heat[12000]


def test_the_mistakes_are_one_line_user_errors():
    with pytest.raises(RafiUserError, match="shorter than the rest and one heat-up") as err:
        plan_programme(speeds_rpm=PAPER, budget_h=0.5)
    assert err.value.exit_status == 64 and "\n" not in str(err.value)
    with pytest.raises(RafiUserError, match="lies in the speed range"):
        plan_programme(speeds_rpm=PAPER, budget_h=4, speed_range=(100, 2000))
    with pytest.raises(RafiUserError, match="no training speed"):
        plan_programme(speeds_rpm=[0, -5], budget_h=4)
    with pytest.raises(RafiUserError, match="cannot start a file name"):
        plan_programme(speeds_rpm=PAPER, budget_h=4, name="../x")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    speeds=st.lists(st.integers(1, 40).map(lambda v: v * 500.0), min_size=1, max_size=9),
    budget_h=st.floats(0.6, 60.0),
    lo_hi=st.tuples(st.integers(0, 20000), st.integers(0, 20000)),
    use_range=st.booleans(),
    min_run_s=st.sampled_from([600.0, 1800.0, 3600.0]),
    transient_s=st.sampled_from([900.0, 1800.0]),
    weights=st.lists(st.floats(0.0, 10.0), min_size=9, max_size=9),
    use_weights=st.booleans(),
)
def test_every_plan_fits_its_budget_and_range_and_reads_back(
    tmp_path, speeds, budget_h, lo_hi, use_range, min_run_s, transient_s, weights, use_weights
):
    speed_range = (min(lo_hi), max(lo_hi)) if use_range else None
    uncertainty = dict(zip(speeds, weights)) if use_weights else None
    try:
        plan = plan_programme(
            speeds_rpm=speeds,
            budget_h=budget_h,
            speed_range=speed_range,
            min_run_s=min_run_s,
            transient_s=transient_s,
            uncertainty=uncertainty,
        )
    except RafiUserError as exc:
        run_s = max(min_run_s, transient_s)
        inside = [s for s in speeds if speed_range is None or speed_range[0] <= s <= speed_range[1]]
        assert not inside or budget_h * 3600 < REST_S + run_s, exc
        return
    assert plan["duration_s"].sum() <= budget_h * 3600 + 1e-6
    assert all(seconds >= max(min_run_s, transient_s) for seconds in pipeline_runs(plan))
    turning = plan.loc[plan["speed_rpm"] > 0, "speed_rpm"]
    assert set(turning) <= set(speeds) and len(set(turning)) == len(turning)
    if speed_range is not None:
        assert turning.between(*speed_range).all()
    path = tmp_path / "plan.csv"
    path.write_text(plan_csv(plan), encoding="utf-8")
    steps = read_plan(path).steps
    assert [(s.speed_rpm, s.duration_s, s.run) for s in steps] == list(
        zip(plan["speed_rpm"], plan["duration_s"], plan["run"])
    )
