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


def recorded_runs(plan) -> dict[str, float]:
    """Seconds per recorded run (consecutive steps with one name form a run)."""
    out: dict[str, float] = {}
    for run, seconds in zip(plan["run"], plan["duration_s"]):
        if run:
            out[run] = out.get(run, 0.0) + float(seconds)
    return out


def test_spread_order_takes_the_highest_the_lowest_then_the_widest_gaps():
    assert spread_order(PAPER) == [18000, 3000, 9000, 6000, 12000, 15000]
    assert spread_order([5000, 5000.0]) == [5000]
    assert spread_order([]) == []


def test_four_hours_give_four_spread_speeds_with_a_cool_down_between_heat_ups():
    plan = plan_programme(speeds_rpm=PAPER, budget_h=4)
    assert tuple(plan.columns) == PLAN_TABLE_COLUMNS
    heat = plan[plan["kind"] == "heat-up"]
    assert list(heat["speed_rpm"]) == [18000, 3000, 9000, 6000]
    # 4 x (180 + 1800) + 3 x 1800 = 13320 s; the 1080 s left: 270 s each, whole minutes: 240 s
    assert list(heat["duration_s"]) == [2040.0] * 4
    assert list(plan["kind"]) == ["rest", "heat-up", "cool-down"] * 3 + ["rest", "heat-up"]
    assert plan.attrs["speeds_rpm"] == [18000, 3000, 9000, 6000]
    assert math.isclose(plan.attrs["total_h"], plan["duration_s"].sum() / 3600)


def test_one_hour_is_one_heat_up_at_the_highest_speed_and_a_long_budget_stops_at_4_h_runs():
    short = plan_programme(speeds_rpm=PAPER, budget_h=1)
    assert list(short["speed_rpm"]) == [0, 18000] and list(short["duration_s"]) == [REST_S, 3600 - REST_S]
    long = plan_programme(speeds_rpm=PAPER, budget_h=100)
    assert long["duration_s"].max() == MAX_RUN_S and long["duration_s"].sum() < 100 * 3600


def test_the_range_in_use_keeps_its_speeds_and_uncertainty_buys_time_where_the_prior_is_unsure():
    plan = plan_programme(
        speeds_rpm=PAPER, budget_h=4, speed_range=(4000, 16000), uncertainty={6000: 1.0, 15000: 3.0}
    )
    heat = plan[plan["kind"] == "heat-up"].set_index("speed_rpm")["duration_s"]
    assert sorted(heat.index) == [6000, 9000, 12000, 15000]
    # speeds the mapping does not name count as its worst (3.0)
    assert heat[6000] < heat[15000] == heat[9000] == heat[12000]


def test_the_mistakes_are_one_line_user_errors():
    with pytest.raises(RafiUserError, match="shorter than one heat-up") as err:
        plan_programme(speeds_rpm=PAPER, budget_h=0.5)
    assert err.value.exit_status == 64 and "\n" not in str(err.value)
    with pytest.raises(RafiUserError, match="lies in the speed range"):
        plan_programme(speeds_rpm=PAPER, budget_h=4, speed_range=(100, 2000))
    with pytest.raises(RafiUserError, match="no training speed"):
        plan_programme(speeds_rpm=[0, -5], budget_h=4)


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
    assert all(seconds >= max(min_run_s, transient_s) for seconds in recorded_runs(plan).values())
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
