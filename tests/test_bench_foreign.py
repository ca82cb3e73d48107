"""The pure parts of benchmarks/bench_foreign.py: the seeds, a blend's errors on the test rows, the
scores and the criterion's decision (the experiment itself is a benchmark)."""

from __future__ import annotations

import sys

import numpy as np
import pandas as pd
import pytest
from bench_loader import load_bench


@pytest.fixture(scope="module")
def bench():
    yield load_bench("bench_foreign")
    for name in ("bench_foreign", "bench_selection_rules"):
        sys.modules.pop(name, None)


def test_seeds_are_a_count_a_range_or_a_list_and_print_as_ranges(bench):
    assert bench.parse_seeds("3") == [0, 1, 2]
    assert bench.parse_seeds("5-8") == [5, 6, 7, 8]
    assert bench.parse_seeds("1,4,7") == [1, 4, 7]
    assert bench.seeds_text([0, 1, 2, 5, 7, 8]) == "0-2, 5, 7-8"


def _rows(measured: list, predictions: dict) -> pd.DataFrame:
    """Test rows of one day: every kind's prediction per row."""
    return pd.DataFrame(
        [
            {"model": k, "day": "d1", "run_id": "d1", "t_s": 60.0 * i, "measured_um": m, "predicted_um": p}
            for k, preds in predictions.items()
            for i, (m, p) in enumerate(zip(measured, preds))
        ]
    )


def test_a_blend_is_the_weighted_mean_and_an_unpredicted_row_counts_uncompensated(bench):
    rows = _rows([0.0, 2.0, 4.0, 6.0], {"a": [1.0, 3.0, 5.0, np.nan], "b": [-1.0, 1.0, 3.0, 6.0]})
    both = bench.blend_errors(rows, {"a": 0.5, "b": 0.5})
    assert both["error_um"].tolist() == pytest.approx([0.0, 0.0, 0.0, 6.0])  # row 4: a has none
    only_b = bench.blend_errors(rows, {"a": 0.0, "b": 1.0})  # a weight of 0 is no input
    assert only_b["error_um"].tolist() == pytest.approx([1.0, 1.0, 1.0, 0.0])
    s = bench.scores_of(both)
    assert s["mae"] == pytest.approx(1.5) and s["max"] == pytest.approx(6.0)
    assert s["none_mae"] == pytest.approx(3.0) and s["days"]["d1"]["none_max"] == pytest.approx(6.0)


def test_a_median_blend_takes_the_middle_member_and_an_unpredicted_row_counts_uncompensated(bench):
    rows = _rows(
        [0.0, 2.0, 4.0],
        {"a": [0.0, 2.5, 4.0], "b": [1.0, 2.0, np.nan], "c": [90.0, -50.0, 4.0]},
    )
    got = bench.blend_errors(rows, {"a": 0.3, "b": 0.4, "c": 0.3}, median=True)
    # row 1: 0 (0.3), 1 (0.4), 90 (0.3) -> 1; row 2: -50, 2, 2.5 -> 2; row 3: b has none
    assert got["error_um"].tolist() == pytest.approx([-1.0, 0.0, 4.0])


def test_the_handoff_gives_an_outside_members_weight_to_the_plain_ridge_row_by_row(bench):
    """Known truth by hand: on a row where ``dynamic`` is outside its weight goes to the plain ridge;
    the plain ridge itself is never handed on; inside, the ensemble's weights."""
    rows = _rows(
        [0.0, 2.0, 4.0],
        {"dynamic": [0.0, 90.0, 4.0], "grey_box": [1.0, 2.0, 3.0], "temperature_ridge": [2.0, 2.0, 5.0]},
    )
    outside = {("dynamic", 1): True, ("temperature_ridge", 2): True, ("grey_box", 2): True}
    rows["outside"] = [outside.get((m, i % 3), False) for i, m in enumerate(rows["model"])]
    w = {"dynamic": 0.5, "grey_box": 0.25, "temperature_ridge": 0.25}
    got = bench.blend_errors(rows, w, handoff=True)["error_um"].to_numpy()
    # row 0: inside, 0.25 * 1 + 0.25 * 2 = 0.75; row 1: dynamic's 0.5 to the ridge: 0.25 * 2 + 0.75 * 2
    # = 2; row 2: grey_box's 0.25 to the ridge (itself outside, kept): 0.5 * 4 + 0.5 * 5 = 4.5
    assert got == pytest.approx([-0.75, 0.0, -0.5])
    plain = bench.blend_errors(rows, w)["error_um"].to_numpy()
    assert plain[1] == pytest.approx(2.0 - (45.0 + 0.5 + 0.5))  # the runaway carries its weight


def _row(rule: str, primary: float, guard: float, diff: float = 0.0, se: float = 0.0) -> dict:
    return {"rule": rule, "primary": primary, "guard_share": guard, "vs_current": diff, "vs_current_se": se}


def test_the_decision_guards_then_takes_the_lowest_primary_only_beyond_one_se(bench):
    current = _row(bench.CURRENT, 1.30, 0.05)
    rows = [
        current,
        _row("mean_max_forward", 1.10, 0.10, -0.20, 0.05),  # best primary, fails the guard
        _row("ridge_floor", 1.20, 0.05, -0.10, 0.04),  # passes, better by more than one SE
        _row("one_se_simplest", 1.25, 0.00, -0.05, 0.08),
        _row("kind:temperature_ridge", 1.00, 0.00, -0.3, 0.01),  # a kind always offered: not a rule
    ]
    d = bench.decide(rows)
    assert "mean_max_forward" not in d["passing_guard"] and "kind:temperature_ridge" not in d["passing_guard"]
    assert d["lowest_primary"] == "ridge_floor" and d["kept"] == "ridge_floor" and d["replaces_current"]
    rows[2] = _row("ridge_floor", 1.20, 0.05, -0.10, 0.12)  # within one SE: the current rule stays
    d = bench.decide(rows)
    assert d["lowest_primary"] == "ridge_floor" and d["kept"] == bench.CURRENT and not d["replaces_current"]


def test_the_best_single_kind_is_never_the_pipelines_ensemble(bench):
    rows = _rows([1.0, 2.0], {"ensemble": [1.0, 2.0], "dynamic": [0.0, 0.0], "grey_box": [1.0, 1.0]})
    assert bench.single_kinds(rows) == ["dynamic", "grey_box"]


def test_a_kept_seed_made_with_other_realism_is_refused_not_mixed(bench, tmp_path):
    import json

    folder = tmp_path / "seed-003"
    folder.mkdir()
    (folder / "result.json").write_text(json.dumps({"seed": 3, "setup_drift": False}))
    with pytest.raises(SystemExit, match="realism"):
        bench.judge_seed(3, tmp_path, 1, realism=("convection",))
    assert bench.judge_seed(3, tmp_path, 1)["seed"] == 3  # the plain machine's result is read
    (folder / "result.json").write_text(json.dumps({"seed": 3, "realism": ["convection"]}))
    with pytest.raises(SystemExit, match="realism"):
        bench.judge_seed(3, tmp_path, 1)
    assert bench.judge_seed(3, tmp_path, 1, realism=("convection",))["seed"] == 3


def test_a_kept_seed_made_with_another_plan_is_refused_and_the_plan_reaches_the_project(bench, tmp_path):
    import json

    folder = tmp_path / "seed-005"
    folder.mkdir()
    (folder / "result.json").write_text(json.dumps({"seed": 5}))
    with pytest.raises(SystemExit, match="plan=varied"):
        bench.judge_seed(5, tmp_path, 1, plan="production")
    (folder / "result.json").write_text(json.dumps({"seed": 5, "plan": "production"}))
    with pytest.raises(SystemExit, match="plan=production"):
        bench.judge_seed(5, tmp_path, 1)
    assert bench.judge_seed(5, tmp_path, 1, plan="production")["seed"] == 5
    (folder / "result.json").write_text(json.dumps({"seed": 5, "setup_change": {"from_day": "day06_train"}}))
    with pytest.raises(SystemExit, match="made with setup_change=True"):
        bench.judge_seed(5, tmp_path, 1)
    assert bench.judge_seed(5, tmp_path, 1, setup_change=True)["seed"] == 5
    truth = bench.make_project(5, tmp_path / "project", plan="production")
    assert truth["plan"] == "production" and len(truth["sensors"]) <= 8


def test_a_kept_seed_made_with_other_models_settings_is_refused_and_a_variant_reaches_the_config(
    bench, tmp_path
):
    import json

    import yaml

    folder = tmp_path / "seed-004"
    folder.mkdir()
    (folder / "result.json").write_text(json.dumps({"seed": 4}))
    variant = {"cv_metric": "max_abs"}
    with pytest.raises(SystemExit, match="models"):
        bench.judge_seed(4, tmp_path, 1, models=variant)
    (folder / "result.json").write_text(json.dumps({"seed": 4, "models": variant}))
    with pytest.raises(SystemExit, match="models"):
        bench.judge_seed(4, tmp_path, 1)
    assert bench.judge_seed(4, tmp_path, 1, models=variant)["seed"] == 4
    proj = tmp_path / "project"
    bench.make_project(4, proj, models=variant)
    defaults = yaml.safe_load((proj / "config.yaml").read_text(encoding="utf-8"))["defaults"]["models"]
    assert defaults["cv_metric"] == "max_abs" and "temperature_ridge" in defaults["enabled"]


def _seed_result(bench, seed: int, scores: dict) -> dict:
    day = {"mae": 0.0, "none_mae": 5.0}
    test = {
        name: {"mae": mae, "max": mae, "none_mae": 5.0, "days": {"d1": {**day, "mae": mae}}}
        for name, mae in scores.items()
    }
    return {"seed": seed, "test": test, "test_runs": [{"stem": "d1", "outside_any": 1.0}], "outer": []}


def test_seeds_judged_without_the_outer_judge_join_on_what_every_seed_has(bench):
    """A seed run with --offered-only has the current rule (the pipeline's offered ensemble) and the
    kinds; a kept full seed has every rule too: the table keeps what both have."""
    full = _seed_result(
        bench, 0, {bench.CURRENT: 1.2, "ridge_floor": 1.1, "offered": 1.2, "kind:dynamic": 1.0}
    )
    lean = _seed_result(bench, 1, {bench.CURRENT: 0.9, "offered": 0.9, "kind:dynamic": 0.6})
    assert bench.offered_choices("ensemble", ["dynamic", "grey_box"]) == {
        bench.CURRENT: {"ensemble": 1.0},
        "kind:dynamic": {"dynamic": 1.0},
        "kind:grey_box": {"grey_box": 1.0},
    }
    rows = {r["rule"]: r for r in bench.rule_rows([full, lean])}
    assert set(rows) == {bench.CURRENT, "offered", "kind:dynamic"}
    assert rows[bench.CURRENT]["primary"] == pytest.approx((1.2 / 1.0 + 0.9 / 0.6) / 2)
    assert rows["kind:dynamic"]["primary"] == pytest.approx(1.0)


def test_a_days_coverage_weighs_its_runs_by_their_samples_and_leaves_other_days_out(bench):
    runs = pd.DataFrame(
        {
            "run_id": ["a#1", "a#2", "b#1", "t#1"],
            "file": ["day9_test.csv", "day9_test.csv", "day10_test.csv", "d1.csv"],
        }
    )
    per_run = pd.DataFrame(
        {
            "model": ["ensemble"] * 4 + ["dynamic"],
            "run_id": ["a#1", "a#2", "b#1", "t#1", "a#1"],
            "n_samples": [30, 10, 20, 50, 30],
            "coverage": [1.0, 0.5, 0.8, 0.0, 0.0],
        }
    )
    cov = bench.day_coverage(per_run, runs, "ensemble", ["day9_test", "day10_test"])
    assert cov.loc["day9_test", "n"] == 40 and cov.loc["day9_test", "coverage"] == pytest.approx(35 / 40)
    assert cov.loc["day10_test", "coverage"] == pytest.approx(0.8) and "d1" not in cov.index


def test_the_chance_of_a_perfect_interval_inside_the_band_follows_students_t(bench):
    # five days whose mean coverage has a standard error of 0.05: the band 0.80-0.97 around 0.90
    # is -2.0 and +1.4 standard errors; Student's t with 4 degrees of freedom (tables: P(T <= 1.4)
    # = 0.8829, P(T <= -2.0) = 0.0581) gives 0.8248
    days = pd.Series([0.9, 0.9, 0.9, 0.9, 0.9]) + np.array([-2, -1, 0, 1, 2]) * 0.05 * np.sqrt(5 / 2.5)
    assert days.std(ddof=1) / np.sqrt(5) == pytest.approx(0.05)
    assert bench.band_chance(days) == pytest.approx(0.8248, abs=1e-3)
    assert bench.band_chance(pd.Series([0.7, 0.7, 0.7])) == 1.0  # no spread: the mean is the truth
    assert np.isnan(bench.band_chance(pd.Series([0.9])))
    wider = pd.Series([0.9, 0.9, 0.9, 0.9, 0.9]) + np.array([-2, -1, 0, 1, 2]) * 0.1
    assert bench.band_chance(wider) < bench.band_chance(days)


def test_the_promises_of_a_kept_machine_and_their_counts(bench, tmp_path):
    res = tmp_path / "seed-007" / "project" / "results" / "foreign-7"
    res.mkdir(parents=True)
    pd.DataFrame({"run_id": ["x#1", "y#1"], "file": ["d5_test.csv", "d6_test.csv"]}).to_csv(
        res / "runs.csv", index=False
    )
    (res / "comparison").mkdir()
    pd.DataFrame(
        {"model": ["ensemble"] * 2, "run_id": ["x#1", "y#1"], "n_samples": [10, 30], "coverage": [0.7, 0.9]}
    ).to_csv(res / "comparison" / "per_run.csv", index=False)
    result = {
        "seed": 7,
        "machine": "foreign-7",
        "offered": "ensemble",
        "test_runs": [{"stem": "d5_test"}, {"stem": "d6_test"}],
        "test": {
            "offered": {
                "mae": 0.5,
                "days": {"d5_test": {"mae": 0.4, "none_mae": 2.0}, "d6_test": {"mae": 0.6, "none_mae": 0.5}},
            },
            "kind:temperature_ridge": {"mae": 0.6},
        },
    }
    p = bench.promises(result, tmp_path / "seed-007")
    assert p["coverage"] == pytest.approx((7 + 27) / 40) and p["worse_than_none"] == 1 and p["test_days"] == 2
    assert p["day_sd"] == pytest.approx(np.std([0.7, 0.9], ddof=1))
    assert bench.promises(result, tmp_path / "seed-008") is None
    assert np.isnan(p["independent_ridge_mae"])  # the kept project lacks runs.parquet
    other = p | {"seed": 8, "offered_mae": 0.7, "coverage": 0.99, "band_chance": 0.5}
    other |= {"independent_ridge_mae": 0.8, "independent_ratio": 0.875}
    text = bench.promises_markdown([p, other])
    assert "| 7 | 0.500 | 0.600 | - | 1 of 2 | 85.0 % |" in text
    assert "| 8 | 0.700 | 0.600 | 0.800 (0.88) | 1 of 2 | 99.0 % |" in text
    assert "at or below the family's plain ridge on 1 of 2 machines" in text
    assert "at or below the plain ridge written apart on 1 of 1 (largest ratio 0.88)" in text
    assert "worse than no compensation: 2 of 4" in text
    assert "on 1 of 2 (0 below, 1 above)" in text


def test_two_versions_of_the_code_are_compared_machine_by_machine(bench):
    def row(seed, coverage, mae=0.5):
        return {"seed": seed, "coverage": coverage, "offered_mae": mae}

    before = [row(1, 0.70), row(2, 0.99), row(3, 0.90), row(9, 0.5)]
    after = [row(1, 0.85), row(2, 0.99), row(3, 0.80), row(4, 0.9)]  # seeds 4 and 9 unpaired
    paired = bench.paired_promises(before, after)
    assert paired["machines"] == 3 and [r["seed"] for r in paired["rows"]] == [1, 2, 3]
    assert paired["before"] == {"inside": 1, "below": 1, "above": 1}
    assert paired["after"] == {"inside": 2, "below": 0, "above": 1}
    assert paired["mean_deviation_before"] == pytest.approx((0.20 + 0.09 + 0.0) / 3)
    assert paired["mean_deviation_after"] == pytest.approx((0.05 + 0.09 + 0.10) / 3)
    assert paired["deviation_se"] == pytest.approx(np.std([-0.15, 0.0, 0.10], ddof=1) / np.sqrt(3))
    assert paired["same_mae"]
    assert not bench.paired_promises(before, [row(1, 0.85, mae=0.6)])["same_mae"]
    text = bench.paired_markdown(paired)
    assert "| 1 | 70.0 % | 85.0 % |" in text and "inside 80-97 % 1 -> 2, below 1 -> 0, above 1 -> 1" in text
    assert "the same on every machine" in text
