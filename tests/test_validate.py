"""Validation by whole run and qualification (rafi.method.validate)."""

import math

import numpy as np
import pandas as pd
import pytest

from rafi.method.fit import fit_rafi
from rafi.method.model import RafiModel
from rafi.method.validate import (
    RESIDUAL_COLUMNS,
    SUMMARY_COLUMNS,
    VERDICT_COLUMNS,
    overall_passed,
    qualify,
    validate_runs,
)
from rafi.twin.synthetic_runs import KEY, TERMS, make_runs

GATES = {"max_residual_um": 12.0, "min_improvement_pct": 30.0, "never_worse_than_uncompensated": True}


def hand_case():
    """Model dz = 2 * dT6 at 3000 and 6000 r/min (trained on dT6 in [0, 2])."""
    m = RafiModel(["T6"], ["1", "x1"], created="2026-01-01T00:00:00Z", code_version="t")
    m.add_speed_model(3000, [0.0, 2.0], {"T6": (0.0, 2.0)})
    m.add_speed_model(6000, [0.0, 2.0], {"T6": (0.0, 2.0)})
    runs_table = pd.DataFrame(
        {
            "run_id": ["good", "bad", "idle", "train", "ex"],
            "role": ["validation_single", "validation_multi", "validation_idle", "training", "excluded"],
            "speed_rpm": [4500.0, 6000.0, 0.0, 3000.0, 3000.0],
            "duration_s": [15.0, 15.0, 15.0, 15.0, 15.0],
        }
    )
    t = [0.0, 5.0, 10.0, 15.0]
    rows = [
        ("good", 4500, [0, 1, 2, 3], [0, 2.5, 3.5, 7]),  # pred 0 2 4 6
        ("bad", 6000, [0, 1, 2, 3], [0, -1, 0, 1]),
        ("idle", 0, [3, 2, 1, 0], [6.5, 4.5, 2, 0.5]),
        ("train", 3000, [0, 1, 2, 3], [0, 2, 4, 6]),
        ("ex", 3000, [0, 1, 2, 3], [0, 2, 4, 6]),
    ]
    frames = [
        pd.DataFrame(
            {"run_id": r, "t_s": t, "speed_rpm": float(s), "dT6": dt, "dz_um": np.asarray(dz, float)}
        )
        for r, s, dt, dz in rows
    ]
    return m, runs_table, pd.concat(frames, ignore_index=True)


def test_summary_by_hand():
    m, table, frame = hand_case()
    summary, residuals = validate_runs(m, table, frame)
    assert list(summary.columns) == SUMMARY_COLUMNS
    assert list(summary["run_id"]) == ["good", "bad", "idle"]  # training/excluded not validated
    s = summary.set_index("run_id")
    # good: dz 0 2.5 3.5 7, predicted 0 2 4 6 -> residual 0 .5 -.5 1
    assert s.loc["good", "max_abs_before_um"] == 7.0
    assert s.loc["good", "max_abs_after_um"] == 1.0
    assert s.loc["good", "improvement_pct"] == pytest.approx(100 * 6 / 7)
    assert s.loc["good", "rmse_before_um"] == pytest.approx(math.sqrt(67.5 / 4))
    assert s.loc["good", "rmse_after_um"] == pytest.approx(math.sqrt(1.5 / 4))
    assert s.loc["good", "n_samples"] == 4
    assert s.loc["good", "n_outside_temp_range"] == 1  # dT6 = 3 > 2 + 0.1
    assert s.loc["good", "n_outside_speed_range"] == 0
    assert not s.loc["good", "worse_than_uncompensated"]
    assert s.loc["good", "paper_residual_um"] == pytest.approx(10.0287)
    # bad: dz 0 -1 0 1, residual 0 -3 -4 -5 -> worse than no compensation
    assert s.loc["bad", "max_abs_before_um"] == 1.0 and s.loc["bad", "max_abs_after_um"] == 5.0
    assert s.loc["bad", "improvement_pct"] == pytest.approx(-400.0)
    assert s.loc["bad", "worse_than_uncompensated"]
    assert np.isnan(s.loc["bad", "paper_residual_um"])  # not a single-speed run
    # idle at 0 r/min: below the trained speeds -> edge model, flagged
    assert s.loc["idle", "n_outside_speed_range"] == 4
    assert s.loc["idle", "max_abs_after_um"] == pytest.approx(0.5)
    assert s.loc["idle", "duration_s"] == 15.0

    assert list(residuals.columns) == RESIDUAL_COLUMNS
    assert len(residuals) == 12
    good = residuals[residuals["run_id"] == "good"]
    np.testing.assert_allclose(good["predicted_um"], [0, 2, 4, 6])
    np.testing.assert_allclose(good["residual_um"], [0, 0.5, -0.5, 1])
    assert list(good["outside_temp_range"]) == [False, False, False, True]


def test_missing_samples_are_skipped_in_metrics():
    m, table, frame = hand_case()
    frame.loc[(frame["run_id"] == "good") & (frame["t_s"] == 15.0), "dT6"] = np.nan
    summary, residuals = validate_runs(m, table, frame)
    s = summary.set_index("run_id").loc["good"]
    assert s["n_samples"] == 3 and s["max_abs_before_um"] == 3.5
    assert s["max_abs_after_um"] == 0.5
    assert residuals["predicted_um"].isna().sum() == 1


def test_qualify_verdict_and_idle_rule():
    m, table, frame = hand_case()
    summary, _ = validate_runs(m, table, frame)
    verdict = qualify(summary, GATES)
    assert list(verdict.columns) == VERDICT_COLUMNS
    v = verdict.set_index(["run_id", "criterion"])
    assert v.loc[("good", "max_residual_um"), "passed"]
    assert v.loc[("good", "min_improvement_pct"), "measured"] == pytest.approx(100 * 6 / 7)
    assert v.loc[("good", "never_worse_than_uncompensated"), "limit"] == 7.0
    assert v.loc[("bad", "max_residual_um"), "passed"]  # 5 um <= 12 um
    assert not v.loc[("bad", "min_improvement_pct"), "passed"]
    assert not v.loc[("bad", "never_worse_than_uncompensated"), "passed"]
    # idle runs: only the never-worse gate
    assert list(verdict.loc[verdict["run_id"] == "idle", "criterion"]) == ["never_worse_than_uncompensated"]
    assert len(verdict) == 7
    assert not overall_passed(verdict)
    assert overall_passed(verdict[verdict["run_id"] != "bad"])
    assert not overall_passed(verdict.iloc[0:0])


def test_qualify_gate_options():
    m, table, frame = hand_case()
    summary, _ = validate_runs(m, table, frame)
    v = qualify(
        summary,
        {"max_residual_um": 0.9, "min_improvement_pct": None, "never_worse_than_uncompensated": False},
    )
    assert list(v["criterion"]) == ["max_residual_um", "max_residual_um"]
    assert list(v["passed"]) == [False, False]
    with pytest.raises(ValueError, match="unknown"):
        qualify(summary, {"max_resid": 1})
    nan_row = summary.assign(max_abs_after_um=np.nan, improvement_pct=np.nan)
    assert not qualify(nan_row, GATES)["passed"].any()


def test_no_validation_runs_gives_empty_tables():
    m, table, frame = hand_case()
    summary, residuals = validate_runs(m, table[table["role"] == "training"], frame)
    assert summary.empty and list(summary.columns) == SUMMARY_COLUMNS
    assert residuals.empty and list(residuals.columns) == RESIDUAL_COLUMNS


def test_end_to_end_on_synthetic_truth():
    # validation speeds between training speeds follow the triangular blend of the truth,
    # so the fitted RAFI model compensates almost everything
    syn = make_runs((3000, 6000, 9000), sigma=0.02, seed=5, duration_s=3600, validation_speeds=(4500, 8000))
    fit = fit_rafi(
        syn.runs_table,
        syn.runs_frame,
        key_sensors=list(KEY),
        terms=TERMS,
        hac_maxlags=30,
        reference={"rule": "run_start", "window_s": 60},
        machine="s",
    )
    summary, residuals = validate_runs(fit.model, syn.runs_table, syn.runs_frame)
    assert list(summary["run_id"]) == ["val-4500", "val-8000"]
    assert (summary["improvement_pct"] > 95).all()
    assert (summary["rmse_after_um"] < 0.05).all()
    assert overall_passed(qualify(summary, GATES))
    assert len(residuals) == 2 * 720
