"""The night's interval drift test (rafi.ops.drift.interval_drift) on residuals whose truth is known.

An unchanged machine is simulated as what the test sees of it: residuals that are an AR(1)
Gaussian process (a slow thermal error, correlation time ``TAU_S``) inside an interval whose
half-width is the true 90 % quantile, so P(outside) is exactly 0.1 at every sample. Its nights must
alarm in at most ``drift_false_alarm`` of the cases (plus the binomial slack of a finite number of
simulated nights); without the thinning they would alarm far more often (why it is there). A
machine shifted by a few sigma (an offset, or a gain drift growing with the displacement) must be
flagged nearly every night. Then: no interval -> ``no_interval`` (no crash), and the whole
decision with the evidence in ``decision.json``, the nightly status line, ``rafi status`` and the
fleet page.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import pandas as pd
import pytest
from scipy.signal import lfilter
from scipy.stats import binom, binomtest, norm
from test_decide_relative import GATES, NIGHTLY, RUNS, summary

from rafi.artefact import compute_model_id, json_text
from rafi.method.validate import qualify
from rafi.ops import decide as D
from rafi.ops import fleet as F
from rafi.ops import fleet_cli
from rafi.ops import registry as R
from rafi.ops.drift import interval_drift, thin_by_run
from rafi.ops.project import Paths
from rafi.ops.status import MachineStatus, interval_evidence
from rafi.report.fleet_page import fleet_page

DT_S = 10.0  # sample period
TAU_S = 300.0  # correlation time of the residual (AR(1): rho(lag) = exp(-lag / TAU_S))
RUN_S = 7200.0  # each validation run: 2 h
N_RUNS = 3  # new validation runs per night
LEVEL = 0.9
HALF_WIDTH = float(norm.ppf(0.5 + LEVEL / 2))  # the true 90 % quantile of |residual| (sigma 1)
DECORRELATION_S = TAU_S * np.log(10.0)  # the lag at which the autocorrelation is 0.1
INTERVAL = {"schema": "rafi.interval/1", "level": LEVEL, "decorrelation_s": DECORRELATION_S}
NEW_RUNS = [f"n{i}" for i in range(N_RUNS)]


def ar1_nights(rng: np.random.Generator, n_nights: int) -> np.ndarray:
    """Stationary AR(1) residuals with unit variance, shape (nights, runs, samples)."""
    phi = np.exp(-DT_S / TAU_S)
    n = int(RUN_S / DT_S)
    shocks = rng.standard_normal((n_nights, N_RUNS, n))
    shocks[..., 0] /= np.sqrt(1 - phi**2)  # the first sample from the stationary law
    return lfilter([np.sqrt(1 - phi**2)], [1.0, -phi], shocks, axis=-1)


def night_frame(resid: np.ndarray, predicted: np.ndarray | None = None) -> pd.DataFrame:
    """A night's residual frame as validate_runs writes it: one block per run; the interval is
    ``predicted +- HALF_WIDTH`` and the measurement ``predicted + resid``."""
    n = resid.shape[-1]
    t = np.arange(n) * DT_S
    pred = np.zeros_like(resid) if predicted is None else predicted
    return pd.DataFrame(
        {
            "run_id": np.repeat(NEW_RUNS, n),
            "t_s": np.tile(t, N_RUNS),
            "measured_um": (pred + resid).ravel(),
            "predicted_um": pred.ravel(),
            "lower_um": (pred - HALF_WIDTH).ravel(),
            "upper_um": (pred + HALF_WIDTH).ravel(),
        }
    )


def alarm_fraction(nights: np.ndarray, false_alarm: float, interval=INTERVAL, shift=None) -> float:
    alarms = 0
    for resid in nights:
        frame = night_frame(resid + (0.0 if shift is None else shift))
        alarms += interval_drift(frame, NEW_RUNS, interval, false_alarm)["detected"]
    return alarms / len(nights)


# --------------------------------------------------------------------------- the thinning


def test_thinning_keeps_one_usable_sample_per_spacing_from_each_runs_first():
    frame = pd.DataFrame(
        {
            "run_id": ["a"] * 7 + ["b"] * 3,
            "t_s": [0, 10, 20, 35, 60, 61, 95, 5, 1, 50],  # run b out of order
            "measured_um": [np.nan, 0, 0, 0, 0, 0, 0, 0, 0, 0],  # a's first sample has no measurement
            "lower_um": [-1, -1, -1, -1, -1, -1, np.nan, -1, -1, -1],  # a's last has no interval
            "upper_um": [1.0] * 10,
        }
    )
    kept = thin_by_run(frame, 25.0)
    assert kept.groupby("run_id")["t_s"].apply(list).to_dict() == {"a": [10, 35, 60], "b": [1, 50]}
    assert len(thin_by_run(frame, 0.0)) == 8  # every usable sample


def test_counts_the_evidence_and_the_p_value_of_the_one_sided_binomial():
    t = np.arange(10) * 100.0
    frame = pd.DataFrame(
        {
            "run_id": ["n0"] * 10 + ["old"] * 10,
            "t_s": np.concatenate([t, t]),
            "measured_um": [5.0, 0, 0, -5.0, 0, 0, 0, 0, 0, 3.0] + [9.0] * 10,
            "lower_um": -2.0,
            "upper_um": 2.0,
        }
    )
    out = interval_drift(frame, ["n0"], {"level": 0.9, "decorrelation_s": 100.0}, 0.05)
    assert (out["n"], out["k"], out["n_samples"]) == (10, 3, 10)  # the old run is not counted
    assert out["expected_k"] == pytest.approx(1.0) and out["observed_rate"] == 0.3
    assert out["p_value"] == pytest.approx(binomtest(3, 10, 0.1, alternative="greater").pvalue)
    assert out["status"] == "ok" and not out["detected"]  # p = 0.07 >= 0.05
    assert out["per_run"] == {"n0": {"n": 10, "k": 3, "n_samples": 10}}
    out = interval_drift(frame, ["n0"], {"level": 0.9, "decorrelation_s": 100.0}, 0.1)
    assert out["status"] == "recalibration_due" and out["detected"] and out["false_alarm"] == 0.1
    text = interval_evidence(out)
    assert text == (
        "3 of 10 new samples (one per 100 s, 1 run(s)) outside the 90 % interval, 1.0 expected; "
        "p = 0.07 < 0.1"
    )
    # on the interval's edge is inside
    frame.loc[frame["run_id"] == "n0", "measured_um"] = 2.0
    assert interval_drift(frame, ["n0"], {"level": 0.9, "decorrelation_s": 0.0}, 0.1)["k"] == 0


# --------------------------------------------------------------------------- an unchanged machine


@pytest.mark.parametrize(("false_alarm", "n_nights"), [(0.01, 1000), (0.05, 500)])
def test_an_unchanged_machine_alarms_at_most_at_the_stated_rate(false_alarm, n_nights):
    nights = ar1_nights(np.random.default_rng(260), n_nights)
    fraction = alarm_fraction(nights, false_alarm)
    # the bound: the stated rate plus the slack of a finite number of nights (a binomial
    # count of alarms exceeds this with probability 1e-3 when the true rate is the stated one)
    bound = binom.ppf(0.999, n_nights, false_alarm) / n_nights
    assert fraction <= bound, f"{fraction:.4f} of {n_nights} nights alarmed (bound {bound:.4f})"


def test_without_the_thinning_an_unchanged_machine_would_alarm_often():
    # the reason for decorrelation_s: the exceedances of one run come in bursts
    nights = ar1_nights(np.random.default_rng(261), 200)
    every_sample = {**INTERVAL, "decorrelation_s": 0.0}
    assert alarm_fraction(nights, 0.01, every_sample) > 0.15


# --------------------------------------------------------------------------- a changed machine


def test_an_offset_of_two_sigma_is_flagged_almost_every_night():
    nights = ar1_nights(np.random.default_rng(262), 200)
    assert alarm_fraction(nights, 0.01, shift=2.0) >= 0.95


def test_a_gain_drift_is_flagged_almost_every_night():
    # the measured displacement is 8 % larger than the model's (a changed machine): the residual
    # grows with the warm-up displacement (40 um at the end of each run: 3.2 sigma more)
    t = np.arange(int(RUN_S / DT_S)) * DT_S
    displacement = 40.0 * (1 - np.exp(-t / 1800.0))
    nights = ar1_nights(np.random.default_rng(263), 200)
    assert alarm_fraction(nights, 0.01, shift=0.08 * displacement) >= 0.95


# --------------------------------------------------------------------------- nothing to test


def _frame() -> pd.DataFrame:
    return night_frame(ar1_nights(np.random.default_rng(264), 1)[0])


@pytest.mark.parametrize(
    ("residuals", "interval", "reason"),
    [
        (_frame().drop(columns=["lower_um", "upper_um"]), INTERVAL, "no column lower_um, upper_um"),
        (None, INTERVAL, "no residuals of the champion"),
        (_frame(), None, "has no interval block"),
        (_frame(), {"level": 0.9}, "no numeric level and decorrelation_s"),
        (_frame(), {"level": 1.5, "decorrelation_s": 10}, "not usable"),
        (_frame().assign(lower_um=np.nan, upper_um=np.nan), INTERVAL, "no new sample has a finite"),
    ],
)
def test_without_an_interval_the_test_says_no_interval(residuals, interval, reason):
    out = interval_drift(residuals, NEW_RUNS, interval, 0.01)
    assert out["status"] == "no_interval" and not out["detected"] and reason in out["reason"]
    assert interval_evidence(out).startswith("interval not tested: ")


def test_no_new_runs():
    out = interval_drift(_frame(), [], INTERVAL, 0.01)
    assert out["status"] == "no_new_runs" and not out["detected"]


# --------------------------------------------------------------------------- the decision and status

PROMOTION = {
    "decision": "promoted",
    "time": "2026-04-01T00:00:00Z",
    "candidate_summary": {"max_residual_um": 5.0},
    "data_files": {"t3.csv": "h3", "t6.csv": "h6", "t9.csv": "h9", "b.csv": "hb"},  # v2, v3 new
}


def _residuals(shift: float) -> pd.DataFrame:
    """The champion's residuals on v1..v3 (v2 and v3 new since its promotion), shifted by ``shift``."""
    resid = ar1_nights(np.random.default_rng(265), 1)[0] + shift
    frame = night_frame(resid)
    return frame.assign(run_id=frame["run_id"].map(dict(zip(NEW_RUNS, ["v1", "v2", "v3"]))))


def _decide(shift: float, interval=INTERVAL):
    champ = {"model_id": "c" * 64, "kind": "fake", "interval": interval}
    champ_sum = summary({"v1": 4.0, "v2": 4.5, "v3": 4.8})  # within the max-residual margin
    return D.decide(
        machine="m1",
        candidate=D.Candidate(model=champ, summary=champ_sum, verdict=qualify(champ_sum, GATES)),
        champion=D.Champion(
            model_id=champ["model_id"], summary=champ_sum, model=champ, residuals=_residuals(shift)
        ),
        runs_table=RUNS,
        settings=D.DecisionSettings(gates=GATES, nightly=NIGHTLY),
        history=[PROMOTION | {"champion_id_after": champ["model_id"]}],
        time="2026-05-01T00:00:00Z",
    )


def test_the_decision_names_recalibration_due_with_the_evidence():
    rec = _decide(shift=2.0).record
    drift = rec["drift"]
    assert drift["status"] == "ok" and not drift["detected"]  # the max-residual check is as it was
    evidence = drift["interval"]
    assert evidence["status"] == "recalibration_due" and rec["recalibration_due"]
    assert evidence["runs"] == ["v2", "v3"] and set(evidence["per_run"]) == {"v2", "v3"}
    assert evidence["false_alarm"] == NIGHTLY["drift_false_alarm"] == 0.01
    assert evidence["p_value"] < 0.01 and evidence["k"] > evidence["expected_k"]
    line = [r for r in rec["reasons"] if "outside the 90 % interval" in r]
    assert len(line) == 1 and line[0].endswith("recalibration due (new training runs needed)")
    assert json_text(rec) == json_text(_decide(shift=2.0).record)  # byte-stable
    calm = _decide(shift=0.0).record
    assert calm["drift"]["interval"]["status"] == "ok" and not calm["recalibration_due"]
    old = _decide(shift=2.0, interval=None).record  # a champion from before intervals
    assert old["drift"]["interval"]["status"] == "no_interval" and not old["recalibration_due"]


def test_run_decide_keeps_the_champions_residuals_for_the_test(tmp_path):
    # the champion is tonight's candidate (no new training data): its residuals come from the
    # one evaluation of the candidate
    champ = {"schema": "fake/1", "kind": "fake", "interval": INTERVAL}
    champ["model_id"] = compute_model_id(champ)

    reg = R.Registry(tmp_path / "registry", "m1")
    reg.save_model(champ)
    reg.append_history(PROMOTION | {"champion_id_after": champ["model_id"]})
    reg.set_champion(champ["model_id"], reason="test")
    (tmp_path / "model.json").write_text(json.dumps(champ))
    RUNS.to_csv(tmp_path / "runs.csv", index=False)
    pd.DataFrame({"run_id": ["v1"], "t_s": [0.0]}).to_parquet(tmp_path / "runs.parquet")

    def validate(model, runs_table, runs_frame):
        return summary({"v1": 4.0, "v2": 4.5, "v3": 4.8}), _residuals(2.0)

    rec = D.run_decide(
        machine="m1",
        candidate_path=tmp_path / "model.json",
        runs_csv=tmp_path / "runs.csv",
        runs_parquet=tmp_path / "runs.parquet",
        registry_root=reg.root,
        decision_path=reg.decision_path,
        comparison_path=reg.comparison_path,
        gates=GATES,
        nightly=NIGHTLY,
        log=lambda m: None,
        model_from_dict=lambda d: d,
        validate_runs=validate,
        qualify=qualify,
    )
    assert rec["decision"] == "kept" and rec["recalibration_due"]
    stored = json.loads(reg.decision_path.read_text())
    assert stored["drift"]["interval"]["status"] == "recalibration_due"
    assert reg.history()[-1]["drift"]["interval"] == stored["drift"]["interval"]


def _project(tmp_path, decision: dict):
    root = tmp_path / "proj"
    (root / "raw" / "m1").mkdir(parents=True)
    (root / "raw" / "m1" / "day1.csv").write_text("time\n")
    res = root / "results" / "m1"
    (res / "registry").mkdir(parents=True)
    (res / "audit.csv").write_text("file,status,reason\nday1.csv,ok,\n")
    (res / "input_status.json").write_text(json.dumps({"status": "usable", "rejected": []}))
    (res / "registry" / "champion.json").write_text(json.dumps({"model_id": "c" * 64, "since": "T"}))
    (res / "registry" / "decision.json").write_text(json_text(decision))
    (root / "config.yaml").write_text("raw_dir: raw\nresults_dir: results\nreports_dir: reports\n")
    return root


def test_status_and_the_fleet_page_show_recalibration_due_with_the_evidence(tmp_path, capsys):
    rec = _decide(shift=2.0).record
    evidence = interval_evidence(rec["drift"]["interval"])
    assert evidence.startswith(f"{rec['drift']['interval']['k']} of ") and "p = " in evidence
    # the nightly's line
    line = MachineStatus("m1", rec, [], tonight=True).line()
    assert f"RECALIBRATION DUE: {evidence}" in line and "max residual" not in line
    # rafi status
    root = _project(tmp_path, rec)
    parser = argparse.ArgumentParser()
    fleet_cli.add_arguments(parser)
    html = tmp_path / "index.html"
    assert fleet_cli.run(parser.parse_args(["--directory", str(root), "--html", str(html)])) == 3
    out = capsys.readouterr().out
    assert "m1: RECALIBRATION_DUE" in out and f"  interval drift:   {evidence}\n" in out
    assert f"new data fall outside the interval too often ({evidence})" in out
    assert "drifted" not in out  # the max-residual check did not fire
    row = F.fleet_overview(Paths.from_config(root, {}), root / "reports")[0]
    assert row["drift"]["interval"]["p_value"] == rec["drift"]["interval"]["p_value"]
    page = html.read_text()
    assert "<th>interval drift</th>" in page and '<span class="state rank1">recalibration due</span>' in page
    assert evidence.replace("<", "&lt;") in page
    # a decision from before the interval test: no interval column content, no crash
    del rec["drift"]["interval"]
    row = F.fleet_overview(Paths.from_config(_project(tmp_path / "old", rec), {}), root / "reports")[0]
    assert row["drift"]["interval"] is None and "<th>interval drift</th>" in fleet_page([row], created="now")


def test_a_drift_beside_a_candidate_waiting_for_a_confirmation_says_so_not_recalibration_due():
    """The champion drifts while tonight's candidate (new runs, every gate passed) is held only by
    an unconfirmed input warning: the drift line points at the WAITING candidate instead of asking
    for new training runs, which the night already has."""
    champ = {"model_id": "c" * 64, "kind": "fake", "interval": INTERVAL}
    cand = {"model_id": "d" * 64, "kind": "fake", "interval": INTERVAL}
    champ_sum = summary({"v1": 4.0, "v2": 4.5, "v3": 4.8})
    record = D.decide(
        machine="m1",
        candidate=D.Candidate(model=cand, summary=champ_sum, verdict=qualify(champ_sum, GATES)),
        champion=D.Champion(
            model_id=champ["model_id"], summary=champ_sum, model=champ, residuals=_residuals(2.0)
        ),
        runs_table=RUNS,
        settings=D.DecisionSettings(gates=GATES, nightly=NIGHTLY),
        history=[PROMOTION | {"champion_id_after": champ["model_id"]}],
        input_status={"warnings": [{"check": "speed_range", "message": "a speed beyond the range"}]},
        time="2026-05-01T00:00:00Z",
    ).record
    assert record["decision"] == "rejected" and record["blocked_by"] == ["input_warnings"]
    line = [r for r in record["reasons"] if "outside the 90 % interval" in r]
    assert len(line) == 1 and line[0].endswith("waits for a confirmation (the WAITING line)")
    assert not any("new training runs needed" in r for r in record["reasons"])
