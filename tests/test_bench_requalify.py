"""benchmarks/bench_requalify.py: its verdict and table from hand-made numbers, and one tiny run
end to end (one scenario, one kind, a coarse sample period: the experiment itself is a benchmark)."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

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
        "| season | 4.00 | 7 | 6.00 | grey_box | 2.20 | prior_gain | 2.00 (grey_box) | 2.50 | 0.70 |"
        == lines[2]
    )
    assert lines[3].startswith("|  | 4.00 | 7 | 2.10 |")


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
        and row["scratch_choice"] == "ridge_global"
    )
    assert res["full_choice"] == "ridge_global" and 0 < res["floor_um"] < res["full_um"] < row["scratch_um"]
    assert math.isfinite(res["unchanged_um"]) and math.isfinite(row["prior_um"]) and row["prior_choice"]
    assert sorted(float(k) for k in res["prior_cv_by_speed_um"]) == [3000, 6000, 9000, 12000, 15000, 18000]
    assert set(row["candidates"]) == {"ridge_global", "prior", "prior_gain", "prior_time", "prior_ridge"}
    printed = capsys.readouterr().out
    assert record["markdown"] in printed and "replaced_sensor:" in printed
