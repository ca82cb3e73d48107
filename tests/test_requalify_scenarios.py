"""rafi.twin.requalify_scenarios: every draw stays in its documented range, the changed machine
differs from the prior's exactly as the truth says, and a seed always gives the same scenario."""

from __future__ import annotations

import math

import pytest

from rafi.twin.machines import AMBIENT, machine_params
from rafi.twin.requalify_scenarios import BASES, CHANGES, RANGES, SPINDLE_NODES, random_scenario
from rafi.twin.scenarios import KEY_SENSORS

SEEDS = range(200)


def inside(value: float, bounds: tuple) -> bool:
    return bounds[0] - 1e-9 <= value <= bounds[1] + 1e-9


@pytest.fixture(scope="module")
def drawn():
    return [random_scenario(s) for s in SEEDS]


def test_the_same_seed_gives_the_same_scenario_and_seeds_differ(drawn):
    again = random_scenario(7)
    assert (
        again.truth == drawn[7].truth
        and again.new == drawn[7].new
        and again.prior_params == drawn[7].prior_params
    )
    assert len({repr(d.truth) for d in drawn}) == len(drawn)


def test_every_base_and_every_change_is_drawn(drawn):
    assert {d.machine for d in drawn} == set(BASES)
    assert {d.change for d in drawn} == set(CHANGES)
    for d in drawn:  # the prior's machine is the base machine's shipped twin, unchanged
        assert d.prior_params == machine_params(d.machine) and d.truth["change"] == d.change


def ratio(new: dict, old: dict) -> dict:
    return {k: new[k] / old[k] for k in old if old[k]}


def test_a_repair_scales_the_spindle_capacities_by_one_factor_and_some_gains(drawn):
    spec = RANGES["repair"]
    repairs = [d for d in drawn if d.change == "repair"]
    assert repairs
    for d in repairs:
        t, old, new = d.truth, d.prior_params, d.new_params
        assert inside(t["capacity_factor"], spec["capacity_factor"])
        for node, r in ratio(new.capacity, old.capacity).items():
            assert math.isclose(r, t["capacity_factor"] if node in SPINDLE_NODES else 1.0)
        assert inside(len(t["gain_factors"]), spec["gain_nodes"])
        assert set(t["gain_factors"]) <= set(SPINDLE_NODES)
        for node, r in ratio(new.disp_gain, old.disp_gain).items():
            assert math.isclose(r, t["gain_factors"].get(node, 1.0))
            assert node not in t["gain_factors"] or inside(r, spec["gain_factor"])
        assert d.new.room_shift_c == 0 and d.new.wear == 0 and new.sensors == old.sensors


def test_a_sibling_has_other_gains_on_some_nodes_and_a_room_a_few_kelvin_off(drawn):
    spec = RANGES["sibling"]
    siblings = [d for d in drawn if d.change == "sibling"]
    assert siblings and {d.new.room_shift_c > 0 for d in siblings} == {True, False}
    for d in siblings:
        t = d.truth
        assert (
            inside(abs(t["room_shift_c"]), spec["room_shift_c"]) and d.new.room_shift_c == t["room_shift_c"]
        )
        assert inside(len(t["gain_factors"]), spec["gain_nodes"])
        for factor in t["gain_factors"].values():
            assert inside(factor, spec["gain_factor"])
        # the build spread (+-8 % at most) under the drawn gain factor
        for node, r in ratio(d.new_params.disp_gain, d.prior_params.disp_gain).items():
            assert inside(r / t["gain_factors"].get(node, 1.0), (math.exp(-0.08), math.exp(0.08)))


def test_a_season_moves_the_room_its_swing_and_the_cooler(drawn):
    spec = RANGES["season"]
    seasons = [d for d in drawn if d.change == "season"]
    assert seasons and {d.new.room_shift_c > 0 for d in seasons} == {True, False}
    for d in seasons:
        t = d.truth
        assert (
            inside(abs(t["room_shift_c"]), spec["room_shift_c"]) and d.new.room_shift_c == t["room_shift_c"]
        )
        assert inside(t["daily_amplitude_c"], spec["daily_amplitude_c"])
        assert d.new.daily_amplitude_c == t["daily_amplitude_c"]
        assert inside(t["cooler_offset_c"], spec["cooler_offset_c"])
        assert d.new_params.cooler_offset_c == t["cooler_offset_c"]
        assert (
            d.new_params.capacity == d.prior_params.capacity
            and d.new_params.sensors == d.prior_params.sensors
        )


def test_a_sensor_move_changes_one_key_sensor_only_as_the_truth_says(drawn):
    spec = RANGES["sensor_move"]
    moves = [d for d in drawn if d.change == "sensor_move"]
    assert moves
    for d in moves:
        t = d.truth
        assert t["sensor"] in KEY_SENSORS[d.machine] and t["to_node"] in SPINDLE_NODES
        assert inside(t["moved_share"], spec["moved_share"]) and inside(t["lag_factor"], spec["lag_factor"])
        assert inside(t["offset_shift_c"], spec["offset_shift_c"])
        old = {s.name: s for s in d.prior_params.sensors}
        new = {s.name: s for s in d.new_params.sensors}
        assert [n for n in old if old[n] != new[n]] == [t["sensor"]]
        o, n = old[t["sensor"]], new[t["sensor"]]
        om, nm = dict(o.mix), dict(n.mix)
        assert math.isclose(sum(nm.values()), sum(om.values()))  # the weights still sum as before
        assert math.isclose(nm[t["from_node"]], om[t["from_node"]] * (1 - t["moved_share"]))
        assert nm[t["to_node"]] > om.get(t["to_node"], 0.0) and nm[AMBIENT] == om[AMBIENT]
        assert math.isclose(n.lag_s, o.lag_s * t["lag_factor"])
        assert math.isclose(n.offset_c, o.offset_c + t["offset_shift_c"])


def test_the_scenario_simulates_the_changed_machine_against_the_base(drawn):
    d = drawn[3]
    sc = d.scenario(sample_period_s=60.0)
    assert sc.machine == d.machine and sc.new == d.new and sc.old.params == d.prior_params
    assert sc.seed == d.seed and sc.key_sensors == KEY_SENSORS[d.machine] and sc.sample_period_s == 60.0


def test_the_issues_two_scenarios_are_built_as_the_issue_states_them():
    """issue_scenario: the repair scales every spindle node's heat capacity by 0.7, the shaft's
    gain by 1.3 and the housing's by 1.2 and nothing else; the sibling is the build spread of its
    seed with every gain of the machine times 1.2 or 1.35 and the room 2.5 K warmer."""
    from rafi.twin.requalify_scenarios import ISSUE_SCENARIOS, issue_scenario
    from rafi.twin.scenarios import sibling_params

    repair = issue_scenario("issue_repair", 3)
    old, new = machine_params("tapping-center-a"), repair.new_params
    for node, c in old.capacity.items():
        assert new.capacity[node] == pytest.approx(c * (0.7 if node in SPINDLE_NODES else 1.0))
    for node, g in old.disp_gain.items():
        assert new.disp_gain[node] == pytest.approx(g * {"shaft": 1.3, "housing": 1.2}.get(node, 1.0))
    named = (repair.machine, repair.change, repair.truth["issue"])
    assert named == ("tapping-center-a", "repair", "issue_repair")
    sibling = issue_scenario("issue_sibling", 3)
    build = sibling_params(machine_params("machining-center-b"), 3)
    factors = sibling.truth["gain_factors"]
    assert set(factors.values()) == {1.2, 1.35} and sibling.new.room_shift_c == 2.5
    for node, g in build.disp_gain.items():
        assert sibling.new_params.disp_gain[node] == pytest.approx(g * factors.get(node, 1.0))
    assert ISSUE_SCENARIOS == ("issue_repair", "issue_sibling")
    with pytest.raises(ValueError, match="unknown issue scenario"):
        issue_scenario("issue_flood", 3)


def test_a_random_design_keeps_the_sensor_layout_and_moves_every_constant_within_its_spread():
    """random_design: the same sensors (names, positions, offsets) and nodes, every constant times
    a factor in [exp(-2 s), exp(2 s)] (s the design spread), each sensor's mix still summing to 1
    over the same nodes; the same seed gives the same design, another seed another one."""
    import numpy as np

    from rafi.twin.requalify_scenarios import DESIGN_SPREAD, random_design

    base = machine_params("tapping-center-a")
    lo, hi = math.exp(-2 * DESIGN_SPREAD) - 1e-12, math.exp(2 * DESIGN_SPREAD) + 1e-12
    for seed in range(20):
        design = random_design(seed)
        assert design == random_design(seed) and design != random_design(seed + 1)
        factors = [design.capacity[n] / c for n, c in base.capacity.items()]
        factors += [design.links[k] / v for k, v in base.links.items()]
        factors += [design.disp_gain[n] / g for n, g in base.disp_gain.items() if g]
        factors += [design.bearing_front_w / base.bearing_front_w, design.rotor_w / base.rotor_w]
        factors += [d.lag_s / s.lag_s for d, s in zip(design.sensors, base.sensors)]
        assert all(lo <= f <= hi for f in factors)
        assert len(set(np.round(factors, 9))) > len(factors) // 2  # each its own factor
        for d, s in zip(design.sensors, base.sensors):
            assert (d.name, d.position, d.offset_c) == (s.name, s.position, s.offset_c)
            assert [n for n, _ in d.mix] == [n for n, _ in s.mix]
            assert sum(w for _, w in d.mix) == pytest.approx(1.0)
        assert design.speed_links.keys() == base.speed_links.keys()
        assert all(design.speed_links[k][2] == v[2] for k, v in base.speed_links.items())  # exponents kept


def test_a_design_pair_is_a_true_sibling_and_another_design_from_the_same_prior():
    from rafi.twin.requalify_scenarios import OTHER_DESIGN, design_pair, random_design
    from rafi.twin.scenarios import sibling_params

    sibling, other = design_pair(5)
    assert sibling.prior_params == other.prior_params == random_design(5)
    assert sibling.new_params == sibling_params(random_design(5), 5) and sibling.change == "sibling"
    assert other.new_params == random_design(5 + OTHER_DESIGN) and other.change == "other_design"
    assert other.truth["other_design_seed"] == 5 + OTHER_DESIGN and sibling.machine == other.machine
