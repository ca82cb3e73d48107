"""The test programme of a re-qualification (rafi/ops/plan.py): the rule of its docstring on worked
examples, then properties over random speeds, budgets and ranges: the plan fits the budget, every
recorded run lasts at least the minimum, the speeds stay in the range and are the prior's, and
``rafi record --plan`` (read_plan) reads the CSV back step for step."""

from __future__ import annotations

import math

import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rafi.deploy.record_plan import read_plan
from rafi.errors import RafiUserError, SettingsError
from rafi.ops.plan import (
    MAX_RUN_S,
    PLAN_TABLE_COLUMNS,
    REST_S,
    covering_budget_h,
    plan_csv,
    plan_limits,
    plan_programme,
    plan_text,
    prior_speeds_left,
    prior_view,
    spread_order,
)
from rafi.settings import machine_settings

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


def _view(speeds=None, speed_range=None, tau=None, half=None):
    """A :func:`prior_view` of an artefact that says what is given."""
    artefact = {"kind": "dynamic" if speeds is None else "rafi", "model_id": "0" * 64, "machine": "m"}
    if speeds is not None:
        artefact["speeds"] = [{"speed_rpm": s} for s in speeds]
    if speed_range is not None:
        artefact["speed_range_rpm"] = list(speed_range)
    if tau is not None:
        artefact["selected"] = {"taus_s": [0, tau / 2], "speed_taus_s": [tau]}
    if half is not None:
        artefact["interval"] = {"half_width_um": half}
    return prior_view(artefact, tolerance_rpm=50)


def test_two_priors_trained_at_other_speeds_give_plans_at_other_speeds_and_no_prior_the_plain_one():
    plain = plan_programme(speeds_rpm=PAPER, budget_h=4)
    low = plan_programme(speeds_rpm=PAPER, budget_h=4, prior=_view(speeds=[3000, 6000, 9000]))
    high = plan_programme(speeds_rpm=PAPER, budget_h=4, prior=_view(speeds=[12000, 15000, 18000]))
    everywhere = plan_programme(speeds_rpm=PAPER, budget_h=4, prior=_view(speeds=PAPER))
    # the speeds the prior never had come first, spread; then the trained ones, farthest first
    assert low.attrs["speeds_rpm"] == [18000, 12000, 15000, 3000] and low.attrs["untrained_rpm"] == [
        18000,
        12000,
        15000,
    ]
    assert high.attrs["speeds_rpm"] == [9000, 3000, 6000, 18000]
    assert everywhere.attrs["speeds_rpm"] == plain.attrs["speeds_rpm"] == [18000, 3000, 9000, 6000]
    assert everywhere.attrs["untrained_rpm"] == []
    # a kind that records a range only: outside the range is untrained (its tolerance included)
    ranged = plan_programme(speeds_rpm=PAPER, budget_h=4, prior=_view(speed_range=(0, 11980)))
    assert ranged.attrs["untrained_rpm"] == [18000, 15000]
    for plan in (low, high, ranged):
        assert plan["duration_s"].sum() <= 4 * 3600
    heat = low[low["kind"] == "heat-up"]
    assert (
        heat["reason"]
        .iloc[0]
        .startswith("a speed the prior never trained at (trained at 3000, 6000, 9000 r/min)")
    )
    assert "trained by the prior" in heat["reason"].iloc[-1]
    assert "prior" not in " ".join(plain["reason"])  # no prior: the reasons do not invent one


def test_the_speeds_a_plan_leaves_to_the_prior_and_the_budget_that_tests_them_all():
    artefact = {"kind": "rafi", "model_id": "0" * 64, "speeds": [{"speed_rpm": s} for s in PAPER]}
    programme = {"speeds_rpm": PAPER, "prior": prior_view(artefact, tolerance_rpm=50)}
    four = plan_programme(budget_h=4, **programme)
    taken = four.attrs["speeds_rpm"]
    assert prior_speeds_left(four, artefact, tolerance_rpm=50) == sorted(set(PAPER) - set(taken))
    assert prior_speeds_left(four, None, tolerance_rpm=50) == []
    # six heat-ups of 1800 s with five cool-downs between them after the rest (step 2 of the rule)
    need = math.ceil((REST_S + 11 * 1800) / 36) / 100
    assert covering_budget_h(artefact, tolerance_rpm=50, **programme) == need
    assert prior_speeds_left(plan_programme(budget_h=need, **programme), artefact, tolerance_rpm=50) == []
    assert prior_speeds_left(plan_programme(budget_h=need - 0.01, **programme), artefact, tolerance_rpm=50)
    # a speed the machine's training speeds never come within the tolerance of: no budget tests it
    odd = artefact | {"speeds": [{"speed_rpm": 3000}, {"speed_rpm": 7000}]}
    assert covering_budget_h(odd, tolerance_rpm=50, **programme) is None
    assert covering_budget_h(odd, tolerance_rpm=1000, **programme) is not None
    # the range in use leaves the prior's high speeds out of every programme
    assert covering_budget_h(artefact, tolerance_rpm=50, speed_range=(0, 10000), **programme) is None


def test_the_interval_buys_time_where_the_prior_is_least_sure():
    half = {"settled": 1.0, "transient": 2.0, "outside": 4.0}
    plan = plan_programme(speeds_rpm=PAPER, budget_h=6, prior=_view(speeds=[3000, 6000, 9000], half=half))
    heat = plan[plan["kind"] == "heat-up"].set_index("speed_rpm")["duration_s"]
    untrained = [s for s in heat.index if s > 9000]
    assert untrained and all(heat[s] > heat[t] for s in untrained for t in heat.index if t <= 9000)
    assert "outside cell, +/-4 um" in plan.loc[plan["kind"] == "heat-up", "reason"].iloc[0]


def test_the_slowest_time_constant_gets_a_heat_up_and_a_cool_down_of_two_of_it_first():
    tau, limits = 2400.0, plan_limits(machine_settings({}, "tapping-center-a"))  # runs of 1 h at least
    plan = plan_programme(speeds_rpm=PAPER, budget_h=4, prior=_view(speeds=PAPER, tau=tau), **limits)
    plain = plan_programme(speeds_rpm=PAPER, budget_h=4, **limits)
    rows = plan.reset_index(drop=True)
    assert list(rows["kind"][:3]) == ["rest", "heat-up", "cool-down"]
    assert rows["duration_s"][1] >= 2 * tau and rows["duration_s"][2] >= 2 * tau
    assert rows["duration_s"][2] > plain["duration_s"].iloc[2] < 2 * tau  # without the prior: too short
    assert "slowest time constant (2400 s)" in rows["reason"][1] and "as it cools" in rows["reason"][2]
    assert plan["duration_s"].sum() <= 4 * 3600
    # a short budget gives what it has, never more
    short = plan_programme(speeds_rpm=PAPER, budget_h=1.2, prior=_view(speeds=PAPER, tau=tau), **limits)
    assert short["duration_s"].sum() <= 1.2 * 3600 and list(short["kind"]) == ["rest", "heat-up"]
    # a time constant of no whole minutes: up to two of it, in whole minutes (2 x 1234.5 s = 41.15 min)
    odd = plan_programme(speeds_rpm=PAPER, budget_h=2.5, prior=_view(speeds=PAPER, tau=1234.5))
    assert odd["kind"].iloc[2] == "cool-down" and odd["duration_s"].iloc[2] == 41 * 60.0
    assert all(float(d / 60).is_integer() for d in odd["duration_s"])  # the rest is 180 s


def test_the_rest_comes_from_the_resolved_settings_and_stays_under_the_leading_rest_limit():
    settings = machine_settings({}, "tapping-center-a")
    assert plan_limits(settings)["rest_s"] == REST_S < settings["runs"]["max_leading_rest_s"]
    tight = {**settings, "runs": {**settings["runs"], "max_leading_rest_s": 150}}
    rest = plan_limits(tight)["rest_s"]
    assert settings["reference"]["window_s"] <= rest < 150
    assert plan_programme(speeds_rpm=PAPER, budget_h=2, **plan_limits(tight))["duration_s"].iloc[0] == rest
    with pytest.raises(SettingsError, match=r"^runs.max_leading_rest_s 100 s leaves the plan no rest") as err:
        plan_limits({**settings, "runs": {**settings["runs"], "max_leading_rest_s": 100}})
    assert "\n" not in str(err.value)


def test_every_step_says_why_it_is_there_in_the_csv_and_the_printed_programme(tmp_path):
    plan = plan_programme(speeds_rpm=PAPER, budget_h=4, prior=_view(speeds=[3000], tau=1800))
    path = tmp_path / "plan.csv"
    path.write_text(plan_csv(plan), encoding="utf-8")
    read = pd.read_csv(path, comment="#")
    assert list(read.columns) == ["speed_rpm", "duration_s", "run", "note", "reason"]
    assert read["reason"].str.len().min() > 20 and list(read["reason"]) == list(plan["reason"])
    assert len(read_plan(path).steps) == len(plan)
    text = plan_text(plan).splitlines()
    assert len(text) == len(plan) + 1 and all(r in line for r, line in zip(plan["reason"], text[1:]))


@settings(max_examples=40, deadline=None)
@given(
    speeds=st.lists(st.integers(1, 40).map(lambda v: v * 500.0), min_size=1, max_size=9),
    trained=st.lists(st.integers(1, 40).map(lambda v: v * 500.0), min_size=1, max_size=6),
    budget_h=st.floats(0.6, 30.0),
    tau=st.one_of(st.none(), st.floats(60.0, 30000.0)),
)
def test_a_prior_never_takes_the_plan_beyond_its_budget_or_under_the_shortest_run(
    speeds, trained, budget_h, tau
):
    try:
        plan = plan_programme(
            speeds_rpm=speeds,
            budget_h=budget_h,
            min_run_s=1800,
            transient_s=1800,
            prior=_view(trained, tau=tau),
        )
    except RafiUserError:
        assert budget_h * 3600 < REST_S + 1800
        return
    assert plan["duration_s"].sum() <= budget_h * 3600 + 1e-6
    assert all(seconds >= 1800 for seconds in pipeline_runs(plan))
    assert plan["duration_s"].max() <= MAX_RUN_S
    # extra time, the time constant's included, in whole minutes beyond the shortest run
    extra = plan.loc[plan["kind"] != "rest", "duration_s"] - 1800
    assert all(math.isclose(e / 60, round(e / 60), abs_tol=1e-9) for e in extra)
    untrained = [s for s in plan.attrs["speeds_rpm"] if all(abs(s - t) > 50 for t in trained)]
    assert plan.attrs["speeds_rpm"][: len(untrained)] == untrained  # least sure first
