"""benchmarks/bench_requalify.py: its verdict and table from hand-made numbers, and one tiny run
end to end (one scenario, one kind, a coarse sample period: the experiment itself is a benchmark)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from bench_loader import load_bench

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    yield load_bench("bench_requalify")
    sys.modules.pop("bench_requalify", None)


def result(prior_um_at_4h: float, scratch_um_at_4h: float = 6.0) -> dict:
    row = {"plan_h": 4.0, "training_runs": 7, "scratch_choice": "grey_box", "prior_choice": "prior_gain"}
    return {
        "scenario": "season",
        "full_um": 2.0,
        "full_choice": "grey_box",
        "unchanged_um": 2.5,
        "floor_um": 0.7,
        "hours": [
            {**row, "budget_h": 4.0, "scratch_um": scratch_um_at_4h, "prior_um": prior_um_at_4h},
            {**row, "budget_h": 8.0, "scratch_um": 2.1, "prior_um": 1.0},
        ],
    }


def test_the_verdict_judges_every_budget_of_4_h_or_less_against_15_percent_of_the_full_plan(bench):
    assert bench.verdict(result(2.2)).startswith("met at 4 h (full plan 2.00 um, 15 % limit 2.30 um): 4 h:")
    assert "4 h: 2.20 um, within 15 %, better than from scratch (6.00 um)" in bench.verdict(result(2.2))
    assert "8 h" not in bench.verdict(result(2.2))  # beyond the target's 4 h
    assert bench.verdict(result(2.4)).startswith("NOT met") and "NOT within 15 %" in bench.verdict(
        result(2.4)
    )
    assert bench.verdict(result(2.2, scratch_um_at_4h=2.1)).startswith("NOT met")
    assert "NOT better" in bench.verdict(result(2.2, scratch_um_at_4h=2.1))
    assert "not judged" in bench.verdict(result(math.nan))


def test_the_table_has_one_row_per_budget_and_the_comparisons_once_per_scenario(bench):
    lines = bench.markdown([result(2.2)]).splitlines()
    assert len(lines) == 4 and lines[0].count("|") == lines[2].count("|") == lines[3].count("|") == 11
    assert (
        "| season | 4.00 | 7 | - ; 6.00 | grey_box | - ; 2.20 | prior_gain | - ; 2.00 (grey_box) "
        "| - ; 2.50 | 0.70 |" == lines[2]
    )
    assert lines[3].startswith("|  | 4.00 | 7 | - ; 2.10 |")
    with_mae = result(2.2) | {"full_mae_um": 0.5, "unchanged_mae_um": 0.9}
    with_mae["hours"][0] |= {"prior_mae_um": 0.55, "scratch_mae_um": 1.5}
    assert bench.markdown([with_mae]).splitlines()[2] == (
        "| season | 4.00 | 7 | 1.50 ; 6.00 | grey_box | 0.55 ; 2.20 | prior_gain | 0.50 ; 2.00 (grey_box) "
        "| 0.90 ; 2.50 | 0.70 |"
    )


def test_the_verdict_needs_the_mae_within_15_percent_too_when_measured(bench):
    res = result(2.2) | {"full_mae_um": 0.5}
    res["hours"][0]["prior_mae_um"] = 0.57  # the worst within (2.2 <= 2.3), the MAE within (<= 0.575)
    assert bench.verdict(res).startswith(
        "met at 4 h (full plan MAE 0.50 ; worst 2.00 um, 15 % limit 0.57 ; 2.30"
    )
    res["hours"][0]["prior_mae_um"] = 0.6  # the MAE beyond 0.575
    assert bench.verdict(res).startswith(
        "NOT met"
    ) and "4 h: MAE 0.60 ; worst 2.20 um, NOT within" in bench.verdict(res)


def cand(score, folds, rmse, mae, worst) -> dict:
    return {
        "selection_score_um": score,
        "cv_mean_max_abs_um": score,
        "cv_fold_max_abs_um": folds,
        "cv_rmse_um": rmse,
        "validation_mae_um": mae,
        "validation_um": worst,
    }


CANDS = {  # hand-made: the CV's best is grey_box; prior_gain is within one SE of it; prior_time second
    "grey_box": cand(1.0, [0.5, 1.0, 1.5], 0.9, 1.0, 4.0),
    "prior_gain": cand(1.4, [1.4, 1.4, 1.4], 0.3, 0.5, 2.0),
    "prior_time": cand(1.2, [1.2, 1.2, 1.2], 0.2, 0.45, 2.1),
    "prior": cand(3.0, [3.0, 3.0, 3.0], 2.0, 2.0, 5.0),
}


def test_each_rule_picks_by_its_own_text(bench):
    # one SE of grey_box's folds: std([0.5, 1, 1.5]) / sqrt(3) = 0.289 -> bound 1.289: prior_time is
    # within, prior_gain (1.4) is not, so the simplest within is prior_time
    assert bench.rule_pick("cv", CANDS) == "grey_box"
    assert bench.rule_pick("cv", CANDS, "prior_gain") == "grey_box"  # recomputed, not the recorded pick
    assert bench.rule_pick("one_se_simplest", CANDS) == "prior_time"
    assert bench.rule_pick("mean_and_worst", CANDS) == "prior_time"  # 0.5 (0.2 + 1.2) = 0.7 lowest
    assert bench.rule_pick("adaptations_only", CANDS) == "prior_time"
    wide = CANDS | {"grey_box": cand(1.0, [0.1, 1.0, 1.9], 0.9, 1.0, 4.0)}  # SE 0.52: prior_gain within
    assert bench.rule_pick("one_se_simplest", wide) == "prior_gain"
    with pytest.raises(ValueError, match="unknown rule"):
        bench.rule_pick("best_on_validation", CANDS)


#: The same candidates where the CV's max score alone picks prior_gain (grey_box's folds worse).
CANDS_GAIN = CANDS | {
    "grey_box": cand(2.0, [1.5, 2.0, 2.5], 0.9, 1.0, 4.0),
    "prior_time": cand(1.5, [1.5, 1.5, 1.5], 0.2, 0.45, 2.1),
}
#: grey_box picked by the CV and within 15 % (ratios 1.1 ; 1.1), prior_time closer (0.9 ; 1.05).
CANDS_BOTH_PASS = CANDS | {"grey_box": cand(1.0, [0.5, 1.0, 1.5], 0.9, 0.55, 2.2)}


def random_result(
    seed: int, prior_choice: str, cands=None, full_mae: float = 0.5, full_worst: float = 2.0
) -> dict:
    cands = cands or CANDS
    return {
        "seed": seed,
        "machine": "tapping-center-a",
        "change": "season",
        "truth": {"change": "season", "room_shift_c": 3.0, "daily_amplitude_c": 1.0, "cooler_offset_c": -0.5},
        "full_mae_um": full_mae,
        "full_um": full_worst,
        "full_choice": "dynamic",
        "prior_choice": prior_choice,
        "prior_mae_um": cands[prior_choice]["validation_mae_um"],
        "prior_um": cands[prior_choice]["validation_um"],
        "scratch_choice": "grey_box",
        "scratch_mae_um": 1.0,
        "scratch_um": 4.0,
        "unchanged_mae_um": 2.0,
        "unchanged_um": 5.0,
        "candidates": cands,
    }


def test_rules_are_judged_by_the_share_within_15_percent_on_both_then_the_mean_ratio(bench):
    # full 0.5 ; 2.0 -> limits 0.575 ; 2.3: prior_gain (0.5 ; 2.0) and prior_time (0.45 ; 2.1) pass,
    # grey_box (1.0 ; 4.0) does not
    results = [random_result(0, "grey_box"), random_result(1, "prior_gain", CANDS_GAIN)]
    judged = bench.judge_rules(results)
    cv, se = judged["rules"]["cv"], judged["rules"]["one_se_simplest"]
    assert cv["share"] == 0.5 and cv["failed"] == [0] and cv["picks"] == {0: "grey_box", 1: "prior_gain"}
    assert (
        se["share"] == 1.0
        and se["failed"] == []
        and judged["winner"] in {"one_se_simplest", "mean_and_worst"}
    )
    assert math.isclose(cv["mean_ratio"], 0.5 * (0.5 * (2 + 2) + 0.5 * (1 + 1)))
    # same share: the lower mean ratio wins (prior_time 0.9 ; 1.05 against grey_box 1.1 ; 1.1)
    same = bench.judge_rules(
        [random_result(1, "grey_box", CANDS_BOTH_PASS)], rules=("cv", "adaptations_only")
    )
    assert same["rules"]["cv"]["share"] == same["rules"]["adaptations_only"]["share"] == 1.0
    assert same["rules"]["adaptations_only"]["mean_ratio"] < same["rules"]["cv"]["mean_ratio"]
    assert same["winner"] == "adaptations_only"
    # the product's rule stays on a full tie (both pick prior_gain)
    only_gain = {m: c for m, c in CANDS_GAIN.items() if m != "prior_time"}
    tie = bench.judge_rules([random_result(1, "prior_gain", only_gain)], rules=("cv", "adaptations_only"))
    assert tie["rules"]["adaptations_only"]["picks"] == tie["rules"]["cv"]["picks"] == {1: "prior_gain"}
    assert tie["winner"] == "cv"


def test_the_random_table_says_which_scenarios_fail_and_the_share_that_pass(bench):
    results = [random_result(0, "grey_box"), random_result(1, "prior_gain"), random_result(2, "prior_time")]
    lines = bench.random_markdown(results).splitlines()
    assert len(lines) == 2 + 3 + 2 + 5 + 1 + 8 and all(line.count("|") == 12 for line in lines[:5])
    assert lines[2].startswith("| 0 | tapping-center-a | season | room +3.0 K, swing 1.0 K, cooler -0.5 K |")
    assert lines[2].endswith("| 2.00 ; 2.00 | grey_box | 1.00 ; 4.00 (grey_box) | 2.00 ; 5.00 | **NO** |")
    assert lines[3].endswith("| yes |") and lines[4].endswith("| yes |")
    assert lines[6] == "Within 15 % of the full plan on both MAE and worst: 2 of 3 scenarios (67 %); fail: 0."
    assert lines[8].startswith("| base machine | change | scenarios |")


def test_the_misses_are_counted_by_base_machine_and_change_beside_the_best_in_hindsight(bench):
    # full 0.5 ; 2.0 -> limits 0.575 ; 2.3. CANDS: prior_gain 0.5 ; 2.0 and prior_time 0.45 ; 2.1
    # pass, grey_box 1.0 ; 4.0 does not; the prior unchanged 2.0 ; 5.0 and from scratch 1.0 ; 4.0 miss
    results = [random_result(0, "grey_box"), random_result(1, "prior_gain"), random_result(2, "prior_time")]
    results[2] = results[2] | {"machine": "machining-center-b", "change": "repair"}
    results[1] = results[1] | {"unchanged_mae_um": 0.55, "unchanged_um": 2.3}  # exactly at the limit
    hopeless = {m: c for m, c in CANDS.items() if m == "grey_box"}
    results.append(random_result(3, "grey_box", hopeless) | {"scratch_mae_um": 0.4, "scratch_um": 1.5})
    lines = bench.by_change_markdown(results).splitlines()
    assert lines[2] == "| machining-center-b | repair | 1 | 1 | 0 | 0 | 1 |"
    assert lines[3] == "| tapping-center-a | season | 3 | 1 | 1 | 1 | 2 |"
    assert lines[4] == "| all | | 4 | 2 | 1 | 1 | 3 |"


def test_the_share_within_each_tolerance_with_the_prior_unchanged_from_scratch_and_in_hindsight(bench):
    # full 0.5 ; 2.0. With the prior: grey_box 1.0 ; 4.0 (ratios 2, 2), prior_gain 0.5 ; 2.0 (1, 1),
    # prior_time 0.45 ; 2.1 (0.9, 1.05); the prior unchanged 2.0 ; 5.0 (4, 2.5) but one at 1.28 x the
    # full plan on both; from scratch 1.0 ; 4.0 (2, 2) but one at 1.18 x
    results = [random_result(0, "grey_box"), random_result(1, "prior_gain"), random_result(2, "prior_time")]
    results[0] = results[0] | {"unchanged_mae_um": 0.64, "unchanged_um": 2.56}
    results[1] = results[1] | {"scratch_mae_um": 0.59, "scratch_um": 2.36}
    lines = bench.tolerance_markdown(results, fractions=(0.15, 0.2, 0.3, 1.5)).splitlines()
    assert len(lines) == 2 + 4
    assert lines[2] == "| 15 % | 2 of 3 (67 %) | 0 of 3 (0 %) | 0 of 3 (0 %) | 3 of 3 (100 %) |"
    assert lines[3] == "| 20 % | 2 of 3 (67 %) | 0 of 3 (0 %) | 1 of 3 (33 %) | 3 of 3 (100 %) |"
    assert lines[4] == "| 30 % | 2 of 3 (67 %) | 1 of 3 (33 %) | 1 of 3 (33 %) | 3 of 3 (100 %) |"
    assert lines[5] == "| 150 % | 3 of 3 (100 %) | 1 of 3 (33 %) | 3 of 3 (100 %) | 3 of 3 (100 %) |"


def test_seeds_come_from_random_n_and_a_range(bench):
    assert bench.parse_seeds(3, None) == [0, 1, 2]
    assert bench.parse_seeds(None, "5-7") == [5, 6, 7] and bench.parse_seeds(None, "4") == [4]
    assert bench.parse_seeds(2, "1-3") == [0, 1, 2, 3]
    with pytest.raises(ValueError, match="A <= B"):
        bench.parse_seeds(None, "7-5")


def test_a_tiny_run_writes_the_table_and_the_json(bench, tmp_path, capsys):
    out = tmp_path / "rq.json"
    args = ["--scenario", "replaced_sensor", "--hours", "1.1", "--sample-period", "120"]
    assert bench.main([*args, "--kinds", "ridge_global", "--json", str(out)]) == 0
    record = json.loads(out.read_text())
    (res,) = record["scenarios"]
    (row,) = res["hours"]
    assert (
        row["training_runs"] == 1  # one heat-up, no cool-down
        and row["speeds_rpm"] == [18000.0]
        and row["scratch_choice"] == "ridge_global"  # one run, no fold: the default rule's first kind
    )
    # the full plan has folds: ridge_global and the plain ridge, blended (the default offer)
    assert res["full_choice"] == "ensemble" and 0 < res["floor_um"] < res["full_um"] < row["scratch_um"]
    assert math.isfinite(res["unchanged_um"]) and math.isfinite(row["prior_um"]) and row["prior_choice"]
    assert sorted(float(k) for k in res["prior_cv_by_speed_um"]) == [3000, 6000, 9000, 12000, 15000, 18000]
    # the prior is an ensemble (ridge_global and the plain ridge): adapted as a whole too
    assert set(row["candidates"]) == {
        "ridge_global",
        "prior",
        "prior_gain",
        "prior_time",
        "prior_ridge",
        "prior_shared_gain",
        "prior_shared_ridge",
    }
    printed = capsys.readouterr().out
    assert record["markdown"] in printed and "replaced_sensor:" in printed


def test_the_shared_adaptations_are_judged_against_today_by_share_and_mae_ratio(bench):
    """Hand-made scenarios (full plan MAE 1, worst 1): the product's CV picks among today's
    candidates, then with the shared gain, then with both; the shares, the mean MAE ratio and the
    paired difference against today are those computed here by hand."""

    def c(score, mae, worst):
        return {"selection_score_um": score, "validation_mae_um": mae, "validation_um": worst}

    def scenario(seed, **cands):
        return {"seed": seed, "full_mae_um": 1.0, "full_um": 1.0, "candidates": cands}

    results = [  # today: prior_gain in all three; A takes the shared gain in 0 and 1; B the time in 2
        scenario(0, prior_gain=c(2.0, 1.3, 1.0), prior_shared_gain=c(1.0, 1.1, 1.1)),
        scenario(1, prior_gain=c(2.0, 1.0, 1.0), prior_shared_gain=c(1.0, 1.2, 1.0)),
        scenario(
            2,
            prior_gain=c(2.0, 1.1, 1.1),
            prior_shared_gain=c(3.0, 1.0, 1.0),
            prior_shared_time=c(1.0, 2.0, 2.0),
        ),
    ]
    judged = bench.judge_shared(results)
    today, a, b = judged["today"], judged["A: + prior_shared_gain"], judged["B: + both"]
    assert today["picks"] == {0: "prior_gain", 1: "prior_gain", 2: "prior_gain"}
    assert a["picks"] == {0: "prior_shared_gain", 1: "prior_shared_gain", 2: "prior_gain"}
    assert b["picks"][2] == "prior_shared_time"
    assert (today["share_mae"], today["share_worst"], today["share_both"]) == (
        pytest.approx(2 / 3),
        1.0,
        pytest.approx(2 / 3),
    )
    assert (a["share_mae"], a["share_both"]) == (pytest.approx(2 / 3), pytest.approx(2 / 3))
    diffs = [1.1 - 1.3, 1.2 - 1.0, 0.0]  # A minus today, per scenario
    assert a["mean_mae_difference"] == pytest.approx(sum(diffs) / 3)
    assert a["se_mae_difference"] == pytest.approx(float(np.std(diffs, ddof=1) / np.sqrt(3)))
    assert not a["adopted"]  # the same share: not strictly higher
    assert b["share_both"] == pytest.approx(1 / 3) and not b["adopted"]
    better = [scenario(3, prior_gain=c(2.0, 1.3, 1.0), prior_shared_gain=c(1.0, 1.0, 1.0))]
    assert bench.judge_shared(results[:2] + better)["A: + prior_shared_gain"]["adopted"]
    table = bench.shared_markdown(judged)
    assert "| today | 67 % | 100 % | 67 % |" in table and "| 2 | prior_gain 1.10 ; 1.10 |" in table


def test_the_no_fold_default_is_judged_on_the_scenarios_without_a_fold(bench):
    """Hand-made scenarios (full plan MAE 1, worst 1) at 2 h: prior_gain against prior_shared_gain
    on those whose 2 h fit has no fold; the shares, the mean MAE ratio and the paired difference
    computed here by hand; a prior of one kind (no shared gain) counts as prior_gain for both."""

    def c(mae, worst):
        return {"selection_score_um": math.nan, "validation_mae_um": mae, "validation_um": worst}

    def scenario(seed, basis="default", **cands):
        fit = {"selection_basis": basis, "champion": "prior_gain", "candidates": cands}
        return {"seed": seed, "change": "repair", "full_mae_um": 1.0, "full_um": 1.0, "no_fold": {"2": fit}}

    results = [
        scenario(0, prior_gain=c(1.3, 1.0), prior_shared_gain=c(1.1, 1.1)),  # shared passes, gain not
        scenario(1, prior_gain=c(1.0, 1.0), prior_shared_gain=c(1.2, 1.0)),  # gain passes, shared not
        scenario(2, prior_gain=c(1.5, 1.1)),  # a prior of one kind: prior_gain for both
        scenario(3, basis="cv", prior_gain=c(9.0, 9.0), prior_shared_gain=c(1.0, 1.0)),  # a fold: out
        {"seed": 4, "full_mae_um": 1.0, "full_um": 1.0},  # not fitted at 2 h: out
    ]
    judged = bench.judge_no_fold(results, 2.0)
    assert judged["seeds"] == [0, 1, 2] and judged["left_out"] == [3]
    gain, shared = judged["defaults"]["prior_gain"], judged["defaults"]["prior_shared_gain"]
    assert shared["picks"] == {0: "prior_shared_gain", 1: "prior_shared_gain", 2: "prior_gain"}
    assert gain["n_both"] == shared["n_both"] == 1
    assert gain["mean_mae_ratio"] == pytest.approx((1.3 + 1.0 + 1.5) / 3)
    diffs = [1.1 - 1.3, 1.2 - 1.0, 0.0]
    assert shared["mean_mae_difference"] == pytest.approx(sum(diffs) / 3)
    assert shared["se_mae_difference"] == pytest.approx(float(np.std(diffs, ddof=1) / np.sqrt(3)))
    assert not shared["adopted"]  # the mean difference (0) is not below minus one SE
    # lower by more than one SE and the share not lower: adopted
    better = [
        scenario(0, prior_gain=c(1.3, 1.0), prior_shared_gain=c(1.1, 1.1)),
        scenario(1, prior_gain=c(1.4, 1.0), prior_shared_gain=c(1.1, 1.0)),
    ]
    assert bench.judge_no_fold(better, 2.0)["defaults"]["prior_shared_gain"]["adopted"]
    # lower by far, but one scenario fewer within 15 % on both: not adopted
    fewer = [
        scenario(5, prior_gain=c(1.0, 1.0), prior_shared_gain=c(0.9, 1.2)),
        scenario(6, prior_gain=c(1.3, 1.0), prior_shared_gain=c(1.0, 1.2)),
    ]
    judged_fewer = bench.judge_no_fold(fewer, 2.0)["defaults"]
    assert judged_fewer["prior_gain"]["n_both"] == 1 and judged_fewer["prior_shared_gain"]["n_both"] == 0
    assert judged_fewer["prior_shared_gain"]["mean_mae_difference"] == pytest.approx(-0.2)
    assert judged_fewer["prior_shared_gain"]["se_mae_difference"] == pytest.approx(0.1)
    assert not judged_fewer["prior_shared_gain"]["adopted"]
    # the moved members against the shared gain (NO_FOLD_MOVED): the shared gain is the base
    moved = [
        scenario(7, prior_shared_gain=c(1.3, 1.0), prior_shared_ridge=c(1.1, 1.0)),
        scenario(8, prior_shared_gain=c(1.2, 1.0), prior_shared_ridge=c(1.0, 1.1)),
    ]
    judged_moved = bench.judge_no_fold(moved, 2.0, defaults=bench.NO_FOLD_MOVED)["defaults"]
    assert judged_moved["prior_shared_gain"]["n_both"] == 0
    assert judged_moved["prior_shared_ridge"]["n_both"] == 2
    assert judged_moved["prior_shared_ridge"]["mean_mae_difference"] == pytest.approx(-0.2)
    assert judged_moved["prior_shared_ridge"]["adopted"]  # SE 0: lower by more than it
    table = bench.no_fold_markdown(judged, results)
    assert "| 0 | repair | prior_gain | 1.30 ; 1.00 (NO) | 1.10 ; 1.10 |" in table
    assert "| prior_gain | 1 of 3 | 3 of 3 | 1 of 3 | 1.267 | - | - |" in table
    assert table.endswith("Left out (a CV fold at 2 h): 3.")


def test_the_no_fold_fit_is_kept_beside_the_seed_and_not_run_again(bench, tmp_path, monkeypatch):
    calls = []

    def fake_fit(seed, hours, args, settings, cache):
        calls.append((seed, hours))
        return {"hours": hours, "selection_basis": "default", "champion": "prior_gain", "candidates": {}}

    monkeypatch.setattr(bench, "no_fold_fit", fake_fit)
    path = tmp_path / "seed-7.json"
    kept = {"seed": 7, "full_mae_um": 1.0}
    args = type("Args", (), {"no_fold_hours": 2.0})()
    res = bench.with_no_fold(kept, path, args, {}, {})
    assert calls == [(7, 2.0)] and res["no_fold"]["2"]["champion"] == "prior_gain" and "no_fold" not in kept
    assert json.loads(path.read_text()) == json.loads(json.dumps(res))
    assert bench.with_no_fold(json.loads(path.read_text()), path, args, {}, {})["no_fold"].keys() == {"2"}
    assert calls == [(7, 2.0)]  # kept: not fitted again
    args.no_fold_hours = None
    assert bench.with_no_fold(kept, path, args, {}, {}) is kept


def test_the_shared_gain_is_offered_unless_a_candidate_beats_it_by_one_paired_se(bench):
    """The paired per-fold differences decide: a candidate lower by less than their SE leaves the
    shared gain; one lower by more takes it; without an ensemble prior the CV's rule."""
    close = CANDS | {"prior_shared_gain": cand(1.1, [1.6, 1.1, 0.6], 0.3, 0.4, 1.9)}
    # grey_box - shared gain per fold: -1.1, -0.1, +0.9: mean -0.1, SE 0.577 -> not beaten by it;
    # prior_time: -0.4, +0.1, +0.6: mean +0.1 (not lower)
    assert bench.rule_pick("cv", close) == "grey_box"
    assert bench.rule_pick("shared_gain_unless_beaten", close) == "prior_shared_gain"
    assert bench.rule_pick("always_shared_gain", close) == "prior_shared_gain"
    far = CANDS | {"prior_shared_gain": cand(2.0, [2.0, 1.9, 2.1], 0.3, 0.4, 1.9)}
    # grey_box - shared gain: -1.5, -0.9, -0.6: mean -1.0, SE 0.265 -> beaten; prior_time
    # (-0.8, -0.7, -0.9: mean -0.8, SE 0.058) too: the lower CV score of the two, grey_box
    assert bench.shared_gain_unless_beaten(far) == "grey_box"
    only_time = far | {"grey_box": cand(1.9, [0.9, 1.9, 2.9], 0.9, 1.0, 4.0)}  # lower by 0.1, SE 0.58
    assert bench.rule_pick("shared_gain_unless_beaten", only_time) == "prior_time"
    assert bench.rule_pick("always_shared_gain", far) == "prior_shared_gain"
    for rule in ("shared_gain_unless_beaten", "always_shared_gain"):  # no ensemble prior
        assert bench.rule_pick(rule, CANDS) == "grey_box"


def test_a_variant_replaces_the_cv_only_if_the_confirmation_share_rises_and_nothing_falls(bench):
    """judge_default's shares, paired MAE differences and adopt_default's criterion, by hand."""

    def scenario(seed, **cands):
        return {"seed": seed, "full_mae_um": 1.0, "full_um": 1.0, "candidates": cands}

    def c(score, folds, mae, worst):
        return cand(score, folds, 1.0, mae, worst)

    results = [  # the CV takes grey_box (by noise) in 0 and 1, by far in 2
        scenario(
            0, grey_box=c(1.0, [0.5, 1.0, 1.5], 1.3, 1.0), prior_shared_gain=c(1.1, [1.6, 1.1, 0.6], 1.0, 1.0)
        ),
        scenario(
            1, grey_box=c(1.0, [0.5, 1.0, 1.5], 1.0, 1.0), prior_shared_gain=c(1.1, [1.6, 1.1, 0.6], 1.1, 1.1)
        ),
        scenario(
            2,
            grey_box=c(1.0, [1.0, 1.0, 1.1], 1.0, 1.0),
            prior_shared_gain=c(3.0, [3.0, 3.1, 2.9], 2.0, 2.0),
            prior_member_weights=c(0.5, [0.5, 0.5, 0.5], 5.0, 5.0),  # a judged-only candidate: dropped
        ),
    ]
    judged = bench.judge_default(results)
    cv, sg, always = judged["cv"], judged["shared_gain_unless_beaten"], judged["always_shared_gain"]
    assert cv["picks"] == {0: "grey_box", 1: "grey_box", 2: "grey_box"}
    assert sg["picks"] == {0: "prior_shared_gain", 1: "prior_shared_gain", 2: "grey_box"}
    assert always["picks"][2] == "prior_shared_gain"
    assert (cv["n_both"], sg["n_both"], always["n_both"]) == (2, 3, 2)
    diffs = [1.0 - 1.3, 1.1 - 1.0, 0.0]
    assert sg["mean_mae_difference"] == pytest.approx(np.mean(diffs))
    assert sg["se_mae_difference"] == pytest.approx(float(np.std(diffs, ddof=1) / np.sqrt(3)))
    assert sg["mae_ok"]
    assert bench.adopt_default(judged, judged) == "shared_gain_unless_beaten"
    worse = bench.judge_default(results[1:])  # 2 of 2 for both
    assert worse["shared_gain_unless_beaten"]["n_both"] == worse["cv"]["n_both"] == 2
    assert bench.adopt_default(judged, worse) == "cv"  # not strictly higher on the confirmation seeds
    assert bench.adopt_default(worse, judged) == "shared_gain_unless_beaten"  # equal on development
    table = bench.default_markdown(judged)
    assert "| shared_gain_unless_beaten | 3 of 3 | 3 of 3 | 3 of 3 |" in table


def test_the_moved_members_are_judged_as_a_candidate_as_the_default_and_always(bench):
    """judge_shared_ridge's picks for today, G, H, A and A+, adopt_shared_ridge and keep_the_net,
    by hand. Scenario 0: grey_box lower than the shared gain by noise, the moved members' CV poor
    (their folds extrapolate) but their validation within 15 %; scenario 1: grey_box beats the
    shared gain clearly and is right."""

    def scenario(seed, **cands):
        return {"seed": seed, "full_mae_um": 1.0, "full_um": 1.0, "candidates": cands}

    def c(score, folds, mae, worst):
        return cand(score, folds, 1.0, mae, worst)

    results = [
        scenario(
            0,
            grey_box=c(1.0, [0.5, 1.0, 1.5], 1.3, 1.0),
            prior_shared_gain=c(1.1, [1.6, 1.1, 0.6], 1.3, 1.0),
            prior_shared_ridge=c(3.0, [3.0, 3.0, 3.0], 1.0, 1.0),
        ),
        scenario(
            1,
            grey_box=c(1.0, [1.0, 1.0, 1.1], 1.0, 1.0),
            prior_shared_gain=c(3.0, [3.0, 3.1, 2.9], 2.0, 2.0),
            prior_shared_ridge=c(3.5, [3.5, 3.5, 3.5], 1.5, 1.0),
        ),
    ]
    judged = bench.judge_shared_ridge(results)
    picks = {name.split(":")[0]: v["picks"] for name, v in judged.items()}
    assert picks["today"] == {0: "prior_shared_gain", 1: "grey_box"}
    assert picks["G"] == picks["today"]  # the moved members never beat the shared gain clearly
    assert picks["H"] == {0: "grey_box", 1: "grey_box"}  # everything beats the moved members
    assert picks["A"] == {0: "prior_shared_ridge", 1: "prior_shared_ridge"}
    assert picks["A+"] == {0: "prior_shared_ridge", 1: "grey_box"}
    counts = {name.split(":")[0]: v["n_both"] for name, v in judged.items()}
    assert counts == {"today": 1, "G": 1, "H": 1, "A": 1, "A+": 2}
    a = judged["A: always prior_shared_ridge"]
    assert a["mean_mae_difference"] == pytest.approx(np.mean([1.0 - 1.3, 1.5 - 1.0]))
    assert bench.adopt_shared_ridge(judged, judged) == "today"  # no variant strictly higher
    assert bench.keep_the_net(judged)  # A+ 2 against A's 1, its MAE lower
    twice = bench.judge_shared_ridge([results[0], {**results[0], "seed": 2}])
    assert bench.adopt_shared_ridge(twice, twice).startswith("A:")  # 2 of 2 against 0; G, H: 0
    assert bench.keep_the_net(twice)  # equal: the net costs nothing there


def test_the_noise_line_says_the_misses_against_a_perfect_models_mae(bench):
    def seed(prior_mae, full_mae, floor_mae):
        return {"prior_mae_um": prior_mae, "full_mae_um": full_mae, "floor_mae_um": floor_mae}

    results = [
        seed(0.30, 0.20, 0.25),  # misses: +0.10 um, 40 % of the noise MAE, full 0.8 x
        seed(0.50, 0.25, 0.20),  # misses: +0.25 um, 125 %, full 1.25 x
        seed(0.22, 0.20, 0.25),  # within 15 %: not counted
        seed(0.90, 0.20, float("nan")),  # kept before the noise MAE: not counted
    ]
    line = bench.noise_floor_line(results)
    assert "on the 2 scenarios whose 4 h model misses 15 % on MAE" in line
    assert "by a median 0.175 um (82% of the validation noise's own MAE" in line
    assert "median 0.225 um; the full plan's MAE is a median 1.02 x" in line
    assert bench.noise_floor_line(results[2:]) is None


def test_the_noise_mae_is_a_perfect_models_mae_over_the_validation_runs():

    import pandas as pd

    from rafi.twin.scenarios import noise_floor, noise_mae

    table = pd.DataFrame(
        {"run_id": ["t", "v1", "v2"], "role": ["training", "validation_single", "validation_multi"]}
    )
    frame = pd.DataFrame({"run_id": ["t", "t", "v1", "v1", "v2"], "dz_um": [9.0, 9.0, 1.5, 2.0, -1.0]})
    truth = pd.DataFrame({"dz_true_um": [0.0, 0.0, 1.0, 2.5, 0.0]})
    runs = SimpleNamespace(table=table, frame=frame, truth=truth)
    assert noise_mae(runs) == pytest.approx((0.5 + 0.5 + 1.0) / 3)  # the training run is not counted
    assert noise_floor(runs) == pytest.approx(1.0)


def test_the_fitness_checks_are_the_champions_warnings_and_none_without_an_adaptation(bench):
    from types import SimpleNamespace

    adapted = SimpleNamespace(
        fitness_={
            "warnings": [
                {"check": "prior_speeds", "message": "..."},
                {"check": "prior_dynamics", "message": "..."},
                {"check": "something_else", "message": "not a fitness check"},
            ]
        }
    )
    assert bench.fitness_checks(adapted) == ["prior_speeds", "prior_dynamics"]
    assert bench.fitness_checks(SimpleNamespace()) == [] and bench.fitness_checks(None) == []
    assert bench.other_base("tapping-center-a") == "machining-center-b"
    assert bench.other_base("machining-center-b") == "tapping-center-a"


def test_the_false_sibling_table_says_which_promotions_are_stopped_and_by_what(bench):
    rows = []
    for seed, checks in ((0, ["prior_speeds"]), (1, ["prior_adaptation", "prior_speeds"]), (2, [])):
        res = random_result(seed, "prior_gain", CANDS_GAIN)
        rows.append(res | {"prior_machine": "machining-center-b", "warnings": checks, "budget_h": 4.0})
    lines = bench.false_sibling_markdown(rows).splitlines()
    assert len(lines) == 2 + 3 + 2 and all(line.count("|") == 10 for line in lines[:5])
    assert lines[2].startswith("| 0 | tapping-center-a | season | machining-center-b | prior_gain |")
    assert lines[2].endswith("| prior_speeds | yes |")
    assert lines[3].endswith("| prior_adaptation, prior_speeds | yes |")
    assert lines[4].endswith("| none | **NO** |")
    assert lines[-1].startswith("Promotion stopped until confirmed: 2 of 3 scenarios (not stopped: 2); ")
    assert lines[-1].endswith("whatever the prior's origin): 1 of 3.")


def test_a_tiny_false_sibling_run_takes_the_other_machines_prior(bench, tmp_path, capsys):
    out = tmp_path / "fs.json"
    args = ["--false-siblings", "--seeds", "0-0", "--sample-period", "120", "--kinds", "ridge_global"]
    assert bench.main([*args, "--json", str(out)]) == 0
    (res,) = json.loads(out.read_text())["scenarios"]
    assert res["machine"] == bench.random_scenario(0).machine
    assert res["prior_machine"] == bench.other_base(res["machine"]) != res["machine"]
    assert isinstance(res["warnings"], list) and set(res["warnings"]) <= set(bench.CHECKS)
    from rafi.twin.day import TRAINING_SPEEDS

    # the plan tests this machine's speeds, not the prior's machine's
    assert res["speeds_rpm"] and set(res["speeds_rpm"]) <= set(TRAINING_SPEEDS[res["machine"]])
    printed = capsys.readouterr().out
    assert "| prior of |" in printed and f"| {res['prior_machine']} |" in printed
    assert (tmp_path / "fs.md").read_text().strip() == printed.strip()


def test_the_other_design_table_says_what_stopped_each_and_how_far_the_prior_lies_off(bench):
    rows = []
    for seed, change, checks in (
        (0, "sibling", ["prior_speeds"]),
        (0, "other_design", ["prior_dynamics", "prior_speeds"]),
        (1, "sibling", []),
        (1, "other_design", ["prior_speeds"]),
    ):
        res = random_result(seed, "prior_gain", CANDS_GAIN) | {"change": change, "warnings": checks}
        rows.append(res | {"budget_h": 4.0, "prior_half_width_um": 0.5})
    rows[3] |= {"prior_mae_um": 2.0}  # 4 x the full plan's 0.5
    lines = bench.other_design_markdown(rows).splitlines()
    assert len(lines) == 2 + 4 + 1 + 2 and all(line.count("|") == 9 for line in lines[:6])
    # the prior as it is scores 3.0 um in the CV (CANDS_GAIN) against its own half width 0.5 um
    assert lines[2] == "| 0 | sibling | prior_gain | 0.50 ; 2.00 | 1.00 ; 1.00 | 6.0 | prior_speeds | yes |"
    assert lines[4].endswith("| none | **NO** |") and "| 4.00 ; 1.00 |" in lines[5]
    assert lines[7] == (
        "true siblings: promotion stopped on 1 of 2, by a warning on the prior (not `prior_speeds`) on 0; "
        "within 15 % of the full plan on both: 2; the prior as it is beyond 11 of its own half widths: 0."
    )
    assert lines[8] == (
        "other designs declared siblings: promotion stopped on 2 of 2, by a warning on the prior (not "
        "`prior_speeds`) on 1; within 15 % of the full plan on both: 1; the prior as it is beyond 11 of "
        "its own half widths: 0."
    )
    assert math.isnan(bench.prior_misfit({"candidates": {}, "prior_half_width_um": 0.5}))


def test_a_tiny_other_design_run_requalifies_a_sibling_and_another_design_from_one_prior(bench, tmp_path):
    out = tmp_path / "od.json"
    args = ["--other-designs", "--seeds", "0-0", "--sample-period", "120", "--kinds", "ridge_global"]
    assert bench.main([*args, "--json", str(out)]) == 0
    sibling, other = json.loads(out.read_text())["scenarios"]
    assert (sibling["change"], other["change"]) == ("sibling", "other_design")
    assert sibling["truth"]["design_seed"] == other["truth"]["design_seed"] == 0
    assert sibling["prior_half_width_um"] == other["prior_half_width_um"] > 0  # one prior for both
    assert sibling["full_mae_um"] != other["full_mae_um"]  # two machines
    assert set(sibling["warnings"]) <= set(bench.CHECKS) and set(other["warnings"]) <= set(bench.CHECKS)
    for res in (sibling, other):  # the product's prior_misfit is the table's ratio beyond its limit
        if res["prior_choice"].startswith("prior"):
            fired = "prior_misfit" in res["warnings"]
            assert fired == (bench.prior_misfit(res) > bench.MISFIT_HALF_WIDTHS)


def test_a_second_full_plan_is_counted_beside_the_others_only_when_every_record_holds_one(bench):
    # full 0.5 ; 2.0. The full plan again: 0.55 ; 2.2 (1.1, 1.1: within 15 %), 0.5 ; 2.5 (1.0,
    # 1.25: within 30 % only) and 0.7 ; 2.0 (1.4: within 150 % only)
    results = [random_result(0, "grey_box"), random_result(1, "prior_gain"), random_result(2, "prior_time")]
    assert not bench.has_repeat(results)
    assert "again" not in bench.tolerance_markdown(results)
    assert "again" not in bench.by_change_markdown(results)
    again = [(0.55, 2.2), (0.5, 2.5), (0.7, 2.0)]
    results = [r | dict(zip(bench.REPEAT_KEYS, a)) for r, a in zip(results, again)]
    assert bench.has_repeat(results) and not bench.has_repeat(results[:2] + [random_result(3, "grey_box")])
    lines = bench.tolerance_markdown(results, fractions=(0.15, 0.3, 1.5)).splitlines()
    assert lines[0].endswith("| best candidate in hindsight | the full plan again |")
    assert lines[2].endswith("| 1 of 3 (33 %) |") and lines[3].endswith("| 2 of 3 (67 %) |")
    assert lines[4].endswith("| 3 of 3 (100 %) |")
    rows = bench.by_change_markdown(results).splitlines()
    assert rows[1].count("---") == 8 and rows[-1] == "| all | | 3 | 2 | 0 | 0 | 3 | 1 |"


def test_a_kept_second_full_plan_is_read_back_and_none_is_fitted_unless_asked(bench, monkeypatch):
    def no_fit(*a, **k):
        raise AssertionError("fitted")

    monkeypatch.setattr(bench, "repeat_full", no_fit)
    res = random_result(0, "grey_box")
    assert bench.with_repeat_full(res, None, SimpleNamespace(repeat_full=False), {}) is res
    kept = res | dict(zip(bench.REPEAT_KEYS, (0.5, 2.0)))
    assert bench.with_repeat_full(kept, None, SimpleNamespace(repeat_full=True), {}) is kept
