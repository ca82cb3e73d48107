"""Validation by whole run and qualification (rafi.method.validate)."""

import math

import numpy as np
import pandas as pd
import pytest

from rafi.method.fit import fit_rafi
from rafi.method.model import RafiModel
from rafi.method.noise import expected_max_abs_noise, white_noise_sigma
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
    # RAFI has no training envelope: nothing is held at its edge
    assert (summary["n_outside_envelope"] == 0).all() and not residuals["outside_envelope"].any()


class _Enveloped:
    """RAFI with an ``outside_envelope`` column set where ``dT6 >= 2`` (as a ridge kind's
    ``predict_detail`` has it), NaN on the run ``bad`` (a detail that does not know)."""

    def __init__(self, inner):
        self.inner = inner

    def predict_detail(self, frame):
        out = self.inner.predict_detail(frame)
        flags = pd.Series(frame["dT6"].to_numpy() >= 2, index=out.index, dtype=object)
        flags[frame["run_id"].to_numpy() == "bad"] = np.nan
        return out.assign(outside_envelope=flags)


def test_samples_held_at_the_envelope_edge_are_flagged_and_counted_where_measured():
    m, table, frame = hand_case()
    good = frame["run_id"] == "good"
    frame.loc[good & (frame["t_s"] == 15.0), "dz_um"] = np.nan  # dT6 = 3: flagged, but not measured
    summary, residuals = validate_runs(_Enveloped(m), table, frame)
    s = summary.set_index("run_id")["n_outside_envelope"]
    # good: dT6 0 1 2 3 -> flagged at 2 and 3, the last without a measurement; idle: 3 2 1 0
    assert s.to_dict() == {"good": 1, "bad": 0, "idle": 2}
    assert summary["n_outside_envelope"].dtype == np.int64
    by_run = residuals.groupby("run_id", sort=False)["outside_envelope"].apply(list).to_dict()
    assert by_run == {
        "good": [False, False, True, True],
        "bad": [False] * 4,  # NaN: not known to be held
        "idle": [True, True, False, False],
    }


def test_missing_samples_are_skipped_in_metrics():
    m, table, frame = hand_case()
    frame.loc[(frame["run_id"] == "good") & (frame["t_s"] == 15.0), "dT6"] = np.nan
    summary, residuals = validate_runs(m, table, frame)
    s = summary.set_index("run_id").loc["good"]
    assert s["n_samples"] == 3 and s["max_abs_before_um"] == 3.5
    assert s["max_abs_after_um"] == 0.5
    assert residuals["predicted_um"].isna().sum() == 1
    # the sample it could not compensate is counted and its missing input named
    assert s["n_unpredicted"] == 1 and s["unpredicted_inputs"] == "T6"
    others = summary.set_index("run_id").drop(index="good")
    assert (others["n_unpredicted"] == 0).all() and (others["unpredicted_inputs"] == "").all()


def test_unpredicted_inputs_name_what_the_model_reads_and_the_speed():
    m, table, frame = hand_case()
    frame["dT9"] = 0.0  # a sensor the model does not read
    good = frame["run_id"] == "good"
    frame.loc[good & (frame["t_s"] == 5.0), ["dT6", "dT9"]] = np.nan
    frame.loc[good & (frame["t_s"] == 10.0), "speed_rpm"] = np.nan
    frame.loc[good & (frame["t_s"] == 15.0), "dz_um"] = np.nan  # no measurement: not counted
    frame.loc[good & (frame["t_s"] == 15.0), "dT6"] = np.nan
    s = validate_runs(m, table, frame)[0].set_index("run_id").loc["good"]
    assert s["n_samples"] == 1 and s["n_unpredicted"] == 2
    assert s["unpredicted_inputs"] == "T6, speed"  # T9 is missing too, but the model does not read it


def test_the_noise_floor_is_the_runs_whatever_the_model_compensates():
    """A run's noise floor comes from its measured dz alone: a model that gives no compensation on
    some samples (a dropout of a sensor it reads) gets the same floor as one that compensates
    every sample, the expected max |noise| over all the run's measured samples."""
    rng = np.random.default_rng(5)
    n = 400
    rise = np.linspace(0.0, 2.0, n)
    dz = 2.0 * rise + rng.normal(0.0, 0.2, n)
    dz[7] = np.nan  # no measurement: not a sample of the run
    frame = pd.DataFrame(
        {"run_id": "v", "t_s": 5.0 * np.arange(n), "speed_rpm": 4500.0, "dT6": rise, "dT9": rise, "dz_um": dz}
    )
    frame.loc[100:185, "dT9"] = np.nan  # 86 samples the T9 model cannot compensate
    table = pd.DataFrame({"run_id": ["v"], "role": ["validation_single"], "speed_rpm": [4500.0]})
    floors = {}
    for sensor in ("T6", "T9"):
        m = RafiModel([sensor], ["1", "x1"], created="2026-01-01T00:00:00Z", code_version="t")
        m.add_speed_model(3000, [0.0, 2.0], {sensor: (0.0, 2.0)})
        m.add_speed_model(6000, [0.0, 2.0], {sensor: (0.0, 2.0)})
        s = validate_runs(m, table, frame)[0].iloc[0]
        floors[sensor] = s["noise_floor_um"]
        assert s["n_unpredicted"] == (86 if sensor == "T9" else 0)
    sigma = white_noise_sigma(dz)
    assert floors["T6"] == floors["T9"] == expected_max_abs_noise(sigma, n - 1)


class _Opaque:
    """A model that does not say which sensors it reads: every rise with no value is named."""

    def __init__(self, inner):
        self.inner = inner

    def predict_detail(self, frame):
        return self.inner.predict_detail(frame)


def test_a_model_that_does_not_name_its_sensors_gets_every_missing_rise():
    m, table, frame = hand_case()
    frame["dT9"] = 0.0
    good = frame["run_id"] == "good"
    frame.loc[good & (frame["t_s"] == 5.0), ["dT6", "dT9"]] = np.nan
    s = validate_runs(_Opaque(m), table, frame)[0].set_index("run_id").loc["good"]
    assert s["n_unpredicted"] == 1 and s["unpredicted_inputs"] == "T6, T9"


def test_qualify_verdict_every_gate_on_every_run():
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
    # issue 12: idle cool-downs are held to every gate (before: only never-worse)
    idle = verdict.loc[verdict["run_id"] == "idle"].set_index("criterion")
    assert list(idle.index) == ["max_residual_um", "min_improvement_pct", "never_worse_than_uncompensated"]
    assert idle.loc["max_residual_um", "measured"] == pytest.approx(0.5)
    assert idle.loc["min_improvement_pct", "measured"] == pytest.approx(100 * 6 / 6.5)
    assert len(verdict) == 9
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
    assert list(v["criterion"]) == ["max_residual_um"] * 3
    assert list(v["passed"]) == [False, False, True]  # idle: 0.5 um
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


def test_idle_run_above_the_residual_gate_fails():
    """A cool-down whose residual exceeds the gate fails it (issue 12: 12.88 um on an idle
    run of a real log was not marked against a 12 um gate)."""
    m, table, frame = hand_case()
    summary, _ = validate_runs(m, table, frame)
    s = summary.copy()
    s.loc[s["run_id"] == "idle", ["max_abs_before_um", "max_abs_after_um", "improvement_pct"]] = [
        30,
        12.88,
        57,
    ]
    v = qualify(s, GATES).set_index(["run_id", "criterion"])
    assert not v.loc[("idle", "max_residual_um"), "passed"]
    assert v.loc[("idle", "max_residual_um"), "measured"] == pytest.approx(12.88)


class FrameSpy:
    """Row-wise model (dz = 2 dT6) that records every frame ``predict_detail`` sees."""

    def __init__(self):
        self.frames = []

    def predict_detail(self, frame):
        self.frames.append(frame.copy())
        pred = 2.0 * frame["dT6"].to_numpy(dtype=float)
        return pd.DataFrame(
            {"predicted_um": pred, "outside_temp_range": False, "outside_speed_range": False},
            index=frame.index,
        )


class CumulativeModel(FrameSpy):
    """A model with state over the whole log: predicts the running sum of dT6 per log (the
    simplest causal filter); run by run it would restart at every run."""

    def predict_detail(self, frame):
        self.frames.append(frame.copy())
        group = frame["log"] if "log" in frame else frame["run_id"]
        pred = frame["dT6"].groupby(group.to_numpy(), sort=False).cumsum().to_numpy(dtype=float)
        return pd.DataFrame(
            {"predicted_um": pred, "outside_temp_range": False, "outside_speed_range": False},
            index=frame.index,
        )


def _one_log(frame):
    """The hand case as one log: runs in the order good, bad, idle, train, ex, shuffled rows."""
    f = frame.copy()
    order = {"train": 0, "good": 1, "ex": 2, "bad": 3, "idle": 4}
    f["log"] = "log.csv"
    f["log_t_s"] = f["run_id"].map(order) * 20.0 + f["t_s"]
    f["segment"] = 1
    return f.sample(frac=1.0, random_state=3)


def test_validate_predicts_the_whole_frame_once_in_log_order():
    m, table, frame = hand_case()
    spy = FrameSpy()
    summary, residuals = validate_runs(spy, table, _one_log(frame))
    assert len(spy.frames) == 1  # once per model, not once per run
    seen = spy.frames[0]
    assert len(seen) == len(frame)  # training and excluded rows included
    assert seen["log_t_s"].is_monotonic_increasing
    # row-wise: same numbers as the per-run RAFI evaluation of the same law
    ref, ref_res = validate_runs(m, table, frame)
    np.testing.assert_allclose(summary["max_abs_after_um"], ref["max_abs_after_um"])
    np.testing.assert_allclose(residuals["predicted_um"], ref_res["predicted_um"])
    assert list(residuals["t_s"]) == list(ref_res["t_s"])


def test_validate_stateful_model_sees_the_log_before_the_run():
    _, table, frame = hand_case()
    log = _one_log(frame)
    _, residuals = validate_runs(CumulativeModel(), table, log)
    # truth: the running sum over the whole log in time order, sliced at the run
    whole = log.sort_values("log_t_s")
    cum = whole["dT6"].cumsum().to_numpy()
    want = cum[whole["run_id"].to_numpy() == "good"]
    got = residuals.loc[residuals["run_id"] == "good", "predicted_um"].to_numpy()
    np.testing.assert_allclose(got, want)
    assert got[0] == pytest.approx(0 + 1 + 2 + 3)  # train's rises came before


def test_summary_has_a_noise_floor_per_run():
    syn = make_runs((3000, 6000), sigma=0.3, seed=11, duration_s=7200, validation_speeds=(4500,))
    m = FrameSpy()
    summary, _ = validate_runs(m, syn.runs_table, syn.runs_frame.assign(dT6=0.0))
    s = summary.iloc[0]
    assert s["noise_sigma_um"] == pytest.approx(0.3, rel=0.1)
    assert 3.0 * 0.3 < s["noise_floor_um"] < 4.6 * 0.3  # sqrt(2 ln 1440) ~ 3.8 sigma
