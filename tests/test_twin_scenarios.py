"""Twin re-qualification scenarios (rafi/twin/scenarios.py): each new machine differs from the old
one in the stated way and only that, the runs carry their noise-free truth, a plan is followed step
for step, and everything is seeded."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from rafi.ops.plan import plan_programme
from rafi.twin.machines import Ambient, tapping_center_a
from rafi.twin.scenarios import (
    REPLACED,
    REWORN,
    SCENARIOS,
    SEASON,
    SIBLING_SPREAD,
    TwinMachine,
    combine,
    make_scenario,
    noise_floor,
    plan_pieces,
)

DT = 60.0
SPREAD_FIELDS = (
    "coolant_flow_w_per_k",
    "cooler_power_w",
    "bearing_front_w",
    "bearing_rear_w",
    "motor_magnetising_w",
    "motor_iron_w",
    "rotor_w",
    "centrifugal_um",
)


def scenario(name, seed=0):
    return make_scenario(name, seed=seed, sample_period_s=DT)


def twin_of_old(sc):
    """The same scenario with the old machine as the new one: the same seeds, no change."""
    return replace(sc, new=sc.old)


def test_the_old_machine_is_the_shipped_twin_in_every_scenario():
    for name in SCENARIOS:
        assert scenario(name).old == TwinMachine(tapping_center_a())


def test_a_sibling_spreads_every_constant_by_a_few_percent_and_keeps_the_design():
    base, new = tapping_center_a(), scenario("sibling").new
    assert new.wear == 0 and new.room_shift_c == 0 and new.daily_amplitude_c is None
    ratios = [new.params.capacity[k] / v for k, v in base.capacity.items()]
    ratios += [new.params.links[k] / v for k, v in base.links.items()]
    ratios += [new.params.disp_gain[k] / v for k, v in base.disp_gain.items()]
    ratios += [getattr(new.params, f) / getattr(base, f) for f in SPREAD_FIELDS]
    ratios += [n.lag_s / b.lag_s for n, b in zip(new.params.sensors, base.sensors)]
    for k, (g0, g1, e) in base.to_ambient.items():
        n0, n1, ne = new.params.to_ambient[k]
        assert ne == e and (g1 == 0) == (n1 == 0)
        ratios += [n0 / g0] + ([n1 / g1] if g1 else [])
    ratios = np.array(ratios)
    bound = np.exp(2 * SIBLING_SPREAD) + 1e-12
    assert ((ratios <= bound) & (ratios >= 1 / bound)).all()
    assert np.all(ratios != 1.0) and 0.02 < np.std(np.log(ratios)) < 0.06
    kept = replace(
        new.params,
        **{f: getattr(base, f) for f in ("capacity", "links", "speed_links", "to_ambient", "disp_gain")},
        **{f: getattr(base, f) for f in SPREAD_FIELDS},
        sensors=tuple(replace(n, lag_s=b.lag_s) for n, b in zip(new.params.sensors, base.sensors)),
    )
    assert kept == base
    assert scenario("sibling", seed=1).new != new and scenario("sibling", seed=0).new == new


def test_reworn_season_and_replaced_sensor_change_only_what_they_state():
    base = tapping_center_a()
    worn = scenario("reworn").new
    f = REWORN["preload_conductance_factor"]
    links = dict(base.links)
    links[("shaft", "front_bearing")] *= f
    links[("shaft", "rear_bearing")] *= f
    assert worn == TwinMachine(replace(base, links=links), wear=REWORN["wear"])
    season = scenario("season").new
    assert season == TwinMachine(
        replace(base, cooler_offset_c=SEASON["cooler_offset_c"]),
        room_shift_c=SEASON["room_shift_c"],
        daily_amplitude_c=SEASON["daily_amplitude_c"],
    )
    room = season.room(Ambient(base_c=21.7, drift_c_per_h=0.02))
    assert (room.base_c, room.daily_amplitude_c, room.drift_c_per_h) == (27.7, 1.5, 0.02)
    new = scenario("replaced_sensor").new
    changed = [(b, n) for b, n in zip(base.sensors, new.params.sensors) if b != n]
    assert [b.name for b, _ in changed] == [REPLACED["sensor"]]
    (b, n), gain, factor = changed[0], REPLACED["gain"], REPLACED["lag_factor"]
    assert n.offset_c == pytest.approx(b.offset_c + REPLACED["offset_c"])
    assert n.lag_s == pytest.approx(b.lag_s * factor)
    assert [w for _, w in n.mix] == pytest.approx([w * gain for _, w in b.mix])
    assert new == TwinMachine(replace(base, sensors=new.params.sensors))


def test_a_replaced_sensor_changes_its_own_rise_and_nothing_else():
    sc = scenario("replaced_sensor")
    new, same = sc.new_validation(), twin_of_old(sc).new_validation()
    pd.testing.assert_frame_equal(new.truth, same.truth)
    others = [c for c in new.frame.columns if c not in ("T8", "dT8")]
    pd.testing.assert_frame_equal(new.frame[others], same.frame[others])
    assert np.abs(new.frame["dT8"] - same.frame["dT8"]).max() > 0.2


@pytest.mark.parametrize("name", ["reworn", "season", "sibling"])
def test_the_physics_of_the_new_machine_moves_the_spindle_differently(name):
    sc = scenario(name)
    new, same = sc.new_validation(), twin_of_old(sc).new_validation()
    assert np.abs(new.truth["dz_true_um"] - same.truth["dz_true_um"]).max() > 0.5


def test_every_run_set_carries_its_truth_and_the_noise_floor_is_the_measured_minus_the_truth():
    sc = scenario("season")
    runs = combine(sc.new_full_training(), sc.new_validation())
    assert set(runs.table["role"]) == {"training", "validation_single", "validation_multi"}
    assert list(runs.table.loc[runs.table["role"] == "training", "speed_rpm"]) == [
        3000,
        6000,
        9000,
        12000,
        15000,
        18000,
    ]
    assert runs.table["run_id"].str.startswith("new-").all() and runs.table["sha256"].is_unique
    pd.testing.assert_frame_equal(runs.truth[["run_id", "t_s"]], runs.frame[["run_id", "t_s"]])
    noise = runs.frame["dz_um"] - runs.truth["dz_true_um"]
    assert 0.1 < noise.std() < 0.5 and runs.truth["dz_true_um"].abs().max() > 10
    valid = runs.frame["run_id"].isin(runs.table.loc[runs.table["role"] != "training", "run_id"])
    assert noise_floor(runs) == pytest.approx(noise[valid].abs().max())
    first = runs.frame.groupby("run_id")["t_s"].min()
    assert (first == 0).all()


def test_the_new_machine_follows_a_plan_as_one_log_cut_as_the_pipeline_cuts_it():
    sc = scenario("reworn")
    plan = plan_programme(speeds_rpm=[3000, 6000, 9000, 12000, 15000, 18000], budget_h=4)
    runs = sc.plan_runs(plan)
    assert list(runs.table["run_id"]) == [f"new-requal-{i:02d}" for i in range(1, 8)]
    # the rest before start belongs to the first heat-up; then heat-ups and cool-downs alternate
    assert list(runs.table["duration_s"]) == [180 + 2160, 1860, 2160, 1860, 2160, 1860, 2160]
    assert list(runs.table["speed_rpm"]) == [18000, 0, 3000, 0, 9000, 0, 6000]
    assert (runs.table["role"] == "training").all() and set(runs.table["log"]) == {"new-requal"}
    f = runs.frame
    assert (f["log"] == "new-requal").all() and np.array_equal(f["log_t_s"], np.arange(len(f)) * DT)
    first = f.groupby("run_id")["t_s"].min()
    assert (first == 0).all()
    for name in ("T8", "disp_um"):  # rises against each run's own first 60 s
        rise = "dz_um" if name == "disp_um" else f"d{name}"
        ref = f[f["t_s"] <= 60].groupby("run_id")[name].median()
        assert np.allclose(f[rise], f[name] - f["run_id"].map(ref))
    # the state carries over: a cool-down starts hot and the spindle shrinks back
    cool = f[f["run_id"] == "new-requal-02"]
    assert cool["dz_um"].iloc[-1] < -5 and cool["dT8"].iloc[-1] < -2
    again = sc.plan_runs(plan)
    pd.testing.assert_frame_equal(runs.frame, again.frame)
    other = make_scenario("reworn", seed=3, sample_period_s=DT).plan_runs(plan)
    assert not np.allclose(runs.frame["dz_um"], other.frame["dz_um"])


def test_the_plans_recording_referenced_at_the_log_start_keeps_the_readings_and_moves_the_zero():
    """``reference="log_start"``: the same absolute readings, the rises and the displacement
    against the log's first 60 s (so a cool-down starts hot instead of at 0); an unknown rule is
    refused."""
    sc = scenario("reworn")
    plan = plan_programme(speeds_rpm=[3000, 18000], budget_h=2)
    runs = sc.plan_runs(plan, reference="log_start")
    per_run, per_log = sc.plan_runs(plan).frame, runs.frame
    pd.testing.assert_frame_equal(
        per_run[["run_id", "t_s", "T8", "disp_um"]], per_log[["run_id", "t_s", "T8", "disp_um"]]
    )
    for name, rise in (("T8", "dT8"), ("disp_um", "dz_um")):
        ref = per_log.loc[per_log["log_t_s"] <= 60, name].median()
        assert np.allclose(per_log[rise], per_log[name] - ref)
    cool_downs = set(runs.table.loc[runs.table["speed_rpm"] == 0, "run_id"])
    starts = per_log[per_log["run_id"].isin(cool_downs)].groupby("run_id")["dz_um"].first()
    assert len(starts) and (starts > 5).all()  # a cool-down starts where the heat-up left the spindle
    first = per_log["run_id"] == per_log["run_id"].iloc[0]
    assert np.allclose(per_log.loc[first, "dz_um"], per_run.loc[first, "dz_um"])
    with pytest.raises(ValueError, match="reference 'cold'"):
        sc.plan_runs(plan, reference="cold")


def test_plan_pieces_cut_each_recording_into_its_runs_and_skip_what_is_not_recorded():
    plan = pd.DataFrame(
        {
            "speed_rpm": [0, 6000, 6000, 0, 0, 3000, 0],
            "duration_s": [120, 1800, 600, 3600, 240, 1800, 1800],
            "run": ["a", "a", "a", "a", None, "b", "b"],
        }
    )
    assert plan_pieces(plan, 60.0) == [
        ("a", [("01", 6000.0, 0, 42), ("02", 0.0, 42, 60)]),
        ("b", [("01", 3000.0, 106, 30), ("02", 0.0, 136, 30)]),
    ]


def test_run_ids_may_not_repeat_and_an_unknown_scenario_is_named():
    sc = scenario("season")
    with pytest.raises(ValueError, match="run ids repeat"):
        combine(sc.new_validation(), sc.new_validation())
    with pytest.raises(ValueError, match="unknown scenario 'winter'"):
        make_scenario("winter")


def test_machining_center_b_has_its_scenarios_too():
    sc = make_scenario("reworn", "machining-center-b", sample_period_s=120.0)
    old = sc.old_runs()
    assert list(old.table.loc[old.table["role"] == "training", "speed_rpm"]) == [1250, 2500, 3750, 5000]
    assert set(old.table["role"]) == {"training", "validation_single", "validation_multi"}


def test_a_second_draw_of_the_full_plan_is_the_same_plan_on_the_same_machine_with_fresh_noise():
    sc = scenario("reworn")
    first, again = sc.new_full_training(), sc.new_full_training(draw=1)
    cols = ["run_id", "role", "speed_rpm"]
    pd.testing.assert_frame_equal(first.table[cols], again.table[cols])
    pd.testing.assert_series_equal(first.frame["t_s"], again.frame["t_s"])
    noise_first = first.frame["dz_um"] - first.truth["dz_true_um"]
    noise_again = again.frame["dz_um"] - again.truth["dz_true_um"]
    assert not np.allclose(noise_first, noise_again)
    assert noise_again.std() == pytest.approx(noise_first.std(), rel=0.3)
    pd.testing.assert_frame_equal(again.frame, sc.new_full_training(draw=1).frame)
    assert not np.allclose(again.frame["dz_um"], sc.new_full_training(draw=2).frame["dz_um"])
    with pytest.raises(ValueError, match="draw"):
        sc.new_full_training(draw=-1)
