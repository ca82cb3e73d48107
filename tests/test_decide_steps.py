"""The steps of the champion / challenger decision (rafi.ops.decide, rafi.ops.gates,
rafi.ops.decision_record), each on hand-written inputs whose answer is known.

``decide`` as a whole is tested in test_registry.py and test_decide_relative.py; here each step
alone: the absolute gates read from qualify's verdict (per gate and run), the comparison with the
champion, provenance, what blocks, the decision's precedence, the drift line, the candidate of a
speed-range adaptation, and the parts of the record.
"""

from __future__ import annotations

import pandas as pd
import pytest
from test_decide_relative import CHAMP, CHAMP_SUM, GATES, RUNS, TRAIN_DATA, model, summary

from rafi.method.validate import qualify
from rafi.ops import decide as D
from rafi.ops import decision_record as DR
from rafi.ops import gates as G

NEVER = G.NEVER_WORSE


def runs(after: dict, before: float = 20.0) -> pd.DataFrame:
    """A validation summary of runs ``run_id -> max |residual|`` (any run id)."""
    return pd.DataFrame(
        {
            "run_id": list(after),
            "role": "validation_single",
            "max_abs_before_um": before,
            "max_abs_after_um": list(after.values()),
            "improvement_pct": [100 * (before - a) / before for a in after.values()],
            "worse_than_uncompensated": [a > before for a in after.values()],
        }
    )


# --------------------------------------------------------------------------- absolute gates


def test_each_failed_verdict_row_is_one_reason_naming_gate_and_run():
    s = runs({"v1": 13.0, "v2": 2.0})
    verdict = qualify(s, GATES)
    assert G.failed_gates(verdict) == [
        {"gate": "max_residual_um", "run": "v1", "measured": 13.0, "limit": 12.0}
    ]
    passed, reasons, measured = G.gate_outcome(s, verdict, GATES)
    assert not passed and reasons == ["gate max_residual_um failed on run v1: measured 13, limit 12"]
    assert measured["max_residual_um"] == 13.0 and measured["worse_than_uncompensated_runs"] == []


def test_a_row_without_a_run_names_none():
    failure = {"gate": "max_residual_um", "run": None, "measured": 13.0, "limit": 12.0}
    assert G.failed_gate_reason(failure) == "gate max_residual_um failed: measured 13, limit 12"
    verdict = pd.DataFrame(
        {"criterion": ["x"], "limit": [1.0], "measured": [2.0], "passed": [False], "run_id": [float("nan")]}
    )
    assert G.failed_gates(verdict)[0]["run"] is None


def test_never_worse_is_read_from_the_verdict_once_per_run():
    s = runs({"v1": 25.0, "v2": 2.0})
    passed, reasons, measured = G.gate_outcome(s, qualify(s, GATES), GATES)
    assert not passed and measured["worse_than_uncompensated_runs"] == ["v1"]
    assert [r for r in reasons if NEVER in r] == [f"gate {NEVER} failed on run v1: measured 25, limit 20"]


def test_the_verdict_decides_over_the_summarys_flag():
    s = runs({"v1": 5.0}).assign(worse_than_uncompensated=True)  # a flag the verdict contradicts
    passed, _, measured = G.gate_outcome(s, qualify(s, GATES), GATES)
    assert passed and measured["worse_than_uncompensated_runs"] == []


def test_a_run_the_verdict_did_not_judge_is_judged_from_the_summary_with_its_own_line():
    # the verdict judged r10 only; r1 (whose id is a prefix of r10's) is worse too
    s = runs({"r1": 25.0, "r10": 30.0})
    verdict = qualify(s[s["run_id"] == "r10"], GATES)
    passed, reasons, measured = G.gate_outcome(s, verdict, GATES)
    assert not passed and measured["worse_than_uncompensated_runs"] == ["r1", "r10"]
    assert [r for r in reasons if NEVER in r] == [
        f"gate {NEVER} failed on run r10: measured 30, limit 20",
        f"gate {NEVER} failed on run r1: compensated residual larger than uncompensated",
    ]
    assert G.worse_than_uncompensated(s, verdict, GATES) == (["r1", "r10"], ["r1"])


def test_a_missing_measurement_fails_the_gate_but_is_not_worse():
    s = runs({"v1": float("nan")})
    passed, reasons, measured = G.gate_outcome(s, qualify(s, GATES), GATES)
    assert not passed and measured["worse_than_uncompensated_runs"] == []
    assert f"gate {NEVER} failed on run v1: measured nan, limit 20" in reasons


def test_never_worse_off_checks_nothing():
    s = runs({"v1": 25.0})
    gates = {**GATES, NEVER: False, "min_improvement_pct": None}
    assert G.worse_than_uncompensated(s, qualify(s, gates), gates) == ([], [])


# --------------------------------------------------------------------------- the champion


def test_no_champion_no_comparison():
    out = D.compare_with_champion(D.Champion(), CHAMP_SUM, "noise")
    assert out.table.empty and out.reasons == [] and out.worse.empty
    assert DR.relative_gate_record(out.table, None, "noise") == {
        "applied": False,
        "champion_margin_um": "noise",
        "n_runs_both_scored": 0,
        "passed": True,
        "worse_runs": [],
    }


def test_worse_than_the_champion_beyond_the_margin():
    champion = D.Champion(model_id=CHAMP["model_id"], summary=CHAMP_SUM, model=CHAMP)
    out = D.compare_with_champion(champion, summary({"v1": 2.0, "v2": 4.5, "v3": 4.0}), 1.0)
    assert list(out.worse["run_id"]) == ["v2"] and out.reasons[0].startswith("relative gate failed on run v2")
    record = DR.relative_gate_record(out.table, champion.model_id, 1.0)
    assert record["applied"] and not record["passed"] and record["n_runs_both_scored"] == 3
    assert record["worse_runs"][0]["candidate_minus_champion_um"] == pytest.approx(1.5)


# --------------------------------------------------------------------------- provenance and blocking


def test_provenance_takes_the_champions_files_from_its_artefact_else_its_promotion():
    champion = D.Champion(model_id="c" * 64, summary=CHAMP_SUM, model=None)
    promotion = {"data_files": {"t3.csv": "h3", "gone.csv": "hg"}}
    prov = D.check_provenance(model(), champion, promotion, RUNS, None, 50)
    assert prov.champion_data == promotion["data_files"]
    assert [v["file"] for v in prov.changes["vanished"]] == ["gone.csv"]
    with_model = D.check_provenance(
        model(), D.Champion("c" * 64, CHAMP_SUM, CHAMP), promotion, RUNS, None, 50
    )
    assert with_model.champion_data == TRAIN_DATA and with_model.changes["vanished"] == []
    alone = D.check_provenance(model(), D.Champion(), None, RUNS, None, 50)
    assert alone.champion_data == {} and alone.coverage["status"] == "no_champion"
    assert alone.tonight["b.csv"] == "hb"


def test_blocking_names_each_check_that_blocks():
    champion = D.Champion(model_id=CHAMP["model_id"], summary=CHAMP_SUM, model=CHAMP)
    status = {"warnings": [{"file": "b.csv", "sha256": "hb", "check": "probe_sign", "message": "m"}]}
    prov = D.check_provenance(model(speeds=(3000, 6000)), champion, None, RUNS, status, 50)
    worse = D.compare_with_champion(champion, summary({"v1": 9.0, "v2": 3.0, "v3": 4.0}), 0.5)
    blocking = D.blocking_checks(worse, prov, champion.model_id)
    assert blocking.names == ["relative_gate", "coverage", "input_warnings"]
    assert blocking.reasons[0].startswith("coverage: the candidate's training data has no run at 9000 r/min")
    assert blocking.reasons[1].startswith("input warning not confirmed: b.csv probe_sign: m")
    fine = D.check_provenance(model(), champion, None, RUNS, None, 50)
    same = D.compare_with_champion(champion, CHAMP_SUM, 0.5)
    assert D.blocking_checks(same, fine, champion.model_id) == D.Blocking(names=[], reasons=[])


# --------------------------------------------------------------------------- the decision


@pytest.fixture
def nothing_compared():
    return D.ChampionComparison(pd.DataFrame(), ["not worse"], "noise")


def test_the_candidate_that_is_the_champion_is_kept(nothing_compared):
    decision, reasons = D.promotion_decision(
        "a" * 64, "a" * 64, [], (True, ["passed"]), nothing_compared, D.Blocking([], [])
    )
    assert decision == "kept" and reasons == [
        f"candidate {'a' * 12} is the champion already (no new training data changed the model)"
    ]


def test_a_rolled_back_candidate_is_kept(nothing_compared):
    history = [
        {
            "decision": "rolled_back",
            "champion_id_before": "a" * 64,
            "champion_id_after": "b" * 64,
            "time": "T",
        }
    ]
    decision, reasons = D.promotion_decision(
        "a" * 64, "b" * 64, history, (True, ["passed"]), nothing_compared, D.Blocking([], [])
    )
    assert (
        decision == "kept" and reasons[1:] == ["passed"] and "rolled back by an operator at T" in reasons[0]
    )


def test_promoted_only_when_the_gates_pass_and_nothing_blocks(nothing_compared):
    args = ("a" * 64, "b" * 64, [])
    assert D.promotion_decision(*args, (True, ["passed"]), nothing_compared, D.Blocking([], [])) == (
        "promoted",
        ["passed", "not worse"],
    )
    decision, reasons = D.promotion_decision(
        *args, (True, ["passed"]), nothing_compared, D.Blocking(["coverage"], ["coverage: x"])
    )
    assert decision == "rejected" and reasons == [
        "passed",
        "not worse",
        "coverage: x",
        f"champion {'b' * 12} stays",
    ]
    decision, reasons = D.promotion_decision(
        "a" * 64, None, [], (False, ["gate x failed"]), nothing_compared, D.Blocking([], [])
    )
    assert decision == "rejected" and reasons[-1] == "no champion yet: the machine has no qualified model"


def test_drift_of_the_champion_and_its_line():
    promotion = {"time": "T0", "candidate_summary": {"max_residual_um": 2.0}, "data_files": {"b.csv": "hb"}}
    champion = D.Champion(model_id="c" * 64, summary=CHAMP_SUM)
    nightly = {"drift_margin_um": 1.0, "drift_false_alarm": 0.01}
    drift, new_runs = D.champion_drift(champion, promotion, RUNS, nightly)
    assert new_runs == ["v2", "v3"] and drift["detected"] and drift["new_max_residual_um"] == 4.0
    # a champion without residuals or interval block: the interval test says so, no crash
    assert drift["interval"]["status"] == "no_interval" and not drift["interval"]["detected"]
    assert drift["champion_id"] == "c" * 64 and drift["promoted_at"] == "T0"
    assert D.drift_reason(drift, "c" * 64, "kept").endswith("recalibration due (new training runs needed)")
    assert D.drift_reason(drift, "c" * 64, "promoted").endswith("resolved by tonight's promotion")
    waiting = D.drift_reason(drift, "c" * 64, "rejected", waiting=True)
    assert waiting.endswith("waits for a confirmation (the WAITING line)")
    assert "new training runs" not in waiting
    none, no_runs = D.champion_drift(D.Champion(), None, RUNS, nightly)
    assert no_runs == [] and not none["detected"] and none["interval"]["status"] == "no_champion"


# --------------------------------------------------------------------------- the candidate


def test_tonight_candidate_without_a_range_is_the_fit():
    fitted = model(offset=1.0)
    candidate, adaptation = D.tonight_candidate(fitted, CHAMP["model_id"], CHAMP, None)
    assert candidate is fitted and adaptation == {
        "retrain_speed_range_rpm": None,
        "mode": "full",
        "fitted_id": fitted["model_id"],
        "retrained_speeds_rpm": [3000, 6000, 9000],
    }
    same, adaptation = D.tonight_candidate(CHAMP, CHAMP["model_id"], CHAMP, None)
    assert adaptation["retrained_speeds_rpm"] == []


def test_tonight_candidate_with_a_range_merges_into_the_champion():
    fitted = model(offset=1.0)
    candidate, adaptation = D.tonight_candidate(fitted, CHAMP["model_id"], CHAMP, [5000, None])
    assert adaptation["mode"] == "speed_range" and adaptation["kept_from"] == CHAMP["model_id"]
    assert adaptation["retrained_speeds_rpm"] == [6000, 9000]
    assert [s["coefficients"][0] for s in candidate["speeds"]] == [3.0, 7.0, 10.0]
    alone, adaptation = D.tonight_candidate(fitted, None, None, [5000, None])
    assert alone is fitted and adaptation["note"] == "no champion yet: the full new fit is the candidate"
    other_terms = {**CHAMP, "terms": ["1", "x1"]}
    full, adaptation = D.tonight_candidate(fitted, CHAMP["model_id"], other_terms, [5000, None])
    assert full is fitted and adaptation["mode"] == "full"
    assert adaptation["note"].startswith("speed-range adaptation impossible: terms differ")


# --------------------------------------------------------------------------- the record


def test_new_since_promotion_and_the_history_line():
    tonight = {"a.csv": "ha", "b.csv": "hb", "b2.csv": "hb", "c.csv": "hc"}
    assert DR.new_since_promotion(tonight, None) == []
    assert DR.new_since_promotion(tonight, {"old_a.csv": "ha", "b.csv": "hb"}) == ["c.csv"]
    record = {k: k for k in DR.HISTORY_FIELDS} | {"data": {"vanished": ["v"], "changed": ["c"]}, "x": 1}
    line = DR.history_record(record, tonight, "T")
    assert list(line) == [*DR.HISTORY_FIELDS, "data_files", "vanished", "changed", "time"]
    assert line["data_files"] == tonight and line["vanished"] == ["v"] and line["time"] == "T"


def test_summary_record_states_the_worst_case():
    assert DR.summary_record(None) is None
    record = DR.summary_record(runs({"v1": 5.0, "v2": 25.0}))
    assert record["n_runs"] == 2 and record["max_residual_um"] == 25.0
    assert record["min_improvement_pct"] == pytest.approx(-25.0)
    assert (
        record["runs"]["v2"]["worse_than_uncompensated"]
        and not record["runs"]["v1"]["worse_than_uncompensated"]
    )


def test_a_candidate_adapted_from_the_champion_covers_the_champions_speeds():
    from rafi.ops.provenance import speed_coverage, with_prior_speeds

    champion = {"speeds_rpm": [3000.0, 9000.0, 15000.0], "source": "artefact speeds", "unknown_runs": []}
    tonight = {"speeds_rpm": [9000.0], "source": "training runs", "train_runs": ["p1"], "unknown_runs": []}
    adapted = {"kind": "dynamic", "adaptation": {"parent": "c" * 64}}
    # from scratch on tonight's one speed: two of the champion's speeds are missing
    assert speed_coverage(champion, tonight, 50)["missing_speeds_rpm"] == [3000.0, 15000.0]
    # adapted from the champion: what it learnt at its speeds is kept
    both = with_prior_speeds(adapted, tonight, "c" * 64, champion)
    assert both["speeds_rpm"] == [3000.0, 9000.0, 15000.0] and "prior cccccccccccc" in both["source"]
    assert speed_coverage(champion, both, 50)["status"] == "ok"
    # adapted from another model, or not adapted: the speeds are tonight's only
    assert with_prior_speeds(adapted, tonight, "d" * 64, champion) is tonight
    assert with_prior_speeds({"kind": "dynamic"}, tonight, "c" * 64, champion) is tonight
