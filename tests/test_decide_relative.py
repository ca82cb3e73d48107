"""Issue 13 item 4: gates relative to the model in service, coverage of the champion's speeds,
vanished or changed training files, and unconfirmed input warnings that block promotion.

Pure ``decide`` on hand-written validation summaries (every number known), plus ``run_decide``
with fake models and an ``input_status.json`` fixture (the "checks" helper writes the real one).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_registry import FakeModel

from rafi import artefact
from rafi.method.model import RafiModel
from rafi.method.validate import qualify
from rafi.ops import decide as D
from rafi.ops import gates, provenance
from rafi.ops import registry as R
from rafi.settings import MACHINE_DEFAULTS

GATES = {
    "max_residual_um": 12.0,
    "min_improvement_pct": 30.0,
    "never_worse_than_uncompensated": True,
    "min_coverage": None,
}
NIGHTLY = MACHINE_DEFAULTS["nightly"]
TERMS = ["1", "x1", "x2", "x3"]

RUNS = pd.DataFrame(
    {
        "run_id": ["r3000", "r6000", "r9000", "v1", "v2", "v3"],
        "file": ["t3.csv", "t6.csv", "t9.csv", "b.csv", "c.csv", "d.csv"],
        "role": [
            "training",
            "training",
            "training",
            "validation_single",
            "validation_single",
            "validation_multi",
        ],
        "speed_rpm": [3000.0, 6000.0, 9000.0, 4500.0, 7500.0, 6000.0],
        "sha256": ["h3", "h6", "h9", "hb", "hc", "hd"],
    }
)
TRAIN_DATA = {"t3.csv": "h3", "t6.csv": "h6", "t9.csv": "h9"}


def model(speeds=(3000, 6000, 9000), offset=0.0, data=None):
    """A real RAFI artefact trained on ``speeds`` (runs r<speed>)."""
    m = RafiModel(
        ["T6", "T8", "T9"],
        TERMS,
        reference={"rule": "run_start", "window_s": 60},
        machine="m1",
        data=data or {f"t{s // 1000}.csv": f"h{s // 1000}" for s in speeds},
        code_version="rafi test",
        created="2026-01-01T00:00:00Z",
    )
    for s in speeds:
        m.add_speed_model(
            s,
            [offset + s / 1000, 1.0, 2.0, 3.0],
            {k: [0.0, 5.0] for k in ("T6", "T8", "T9")},
            train_runs=[f"r{s}"],
            rmse_um=0.5,
            n=100,
        )
    return m.to_dict()


def summary(after: dict, before=20.0, floor=0.6):
    """Validation summary: run -> max |residual|; every run 20 um uncompensated, floor 0.6 um."""
    roles = dict(zip(RUNS["run_id"], RUNS["role"]))
    recs = []
    for rid, a in after.items():
        recs.append(
            {
                "run_id": rid,
                "role": roles[rid],
                "speed_rpm": 4500.0,
                "max_abs_before_um": before,
                "max_abs_after_um": a,
                "improvement_pct": 100 * (before - a) / before,
                "worse_than_uncompensated": bool(a > before),
                "noise_floor_um": floor,
            }
        )
    return pd.DataFrame(recs)


CHAMP = model(offset=0.0)
CHAMP_SUM = summary({"v1": 2.0, "v2": 3.0, "v3": 4.0})


def run(cand_sum, *, cand=None, champ=CHAMP, champ_sum=CHAMP_SUM, nightly=None, status=None, history=()):
    cand = cand or model(offset=1.0)
    return D.decide(
        machine="m1",
        candidate=D.Candidate(model=cand, summary=cand_sum, verdict=qualify(cand_sum, GATES)),
        champion=D.Champion(
            model_id=champ["model_id"] if champ else None,
            summary=champ_sum if champ else None,
            model=champ,
            verdict=qualify(champ_sum, GATES) if champ else None,
        ),
        runs_table=RUNS,
        settings=D.DecisionSettings(
            gates=GATES, nightly={**NIGHTLY, **(nightly or {})}, speed_tolerance_rpm=50
        ),
        history=list(history),
        input_status=status,
        time="2026-05-01T00:00:00Z",
    )


# --------------------------------------------------------------------------- relative gate


def test_worse_than_the_champion_beyond_the_noise_floor_is_rejected_though_absolute_gates_pass():
    # v2: 3.0 -> 4.5 um (worse by 1.5 um, noise floor 0.6 um); every absolute gate passes
    d = run(summary({"v1": 2.0, "v2": 4.5, "v3": 4.0}))
    r = d.record
    assert r["gates_passed"] and r["decision"] == "rejected"
    assert r["champion_id_after"] == CHAMP["model_id"] and r["blocked_by"] == ["relative_gate"]
    line = next(x for x in r["reasons"] if x.startswith("relative gate failed"))
    assert "run v2" in line and "4.5 um" in line and "3 um" in line and "margin 0.6 um" in line
    assert any("stays" in x for x in r["reasons"])
    assert [w["run_id"] for w in r["relative_gate"]["worse_runs"]] == ["v2"]
    comp = d.comparison.set_index("run_id")
    assert comp.loc["v2", "candidate_worse"] and not comp.loc["v1", "candidate_worse"]
    assert comp.loc["v2", "margin_um"] == 0.6 and comp.loc["v2", "noise_floor_um"] == 0.6
    assert comp.loc["v2", "candidate_minus_champion_um"] == pytest.approx(1.5)


def test_worse_within_the_noise_floor_is_promoted():
    d = run(summary({"v1": 2.5, "v2": 3.5, "v3": 4.6}))  # worse by 0.5, 0.5, 0.6 <= 0.6
    r = d.record
    assert r["decision"] == "promoted" and r["blocked_by"] == []
    assert any("not worse than champion" in x and "3 validation run" in x for x in r["reasons"])
    assert not d.comparison["candidate_worse"].any() and d.comparison["both_scored"].all()


def test_a_number_as_margin():
    s = summary({"v1": 2.0, "v2": 4.5, "v3": 4.0})
    assert run(s, nightly={"champion_margin_um": 2.0}).record["decision"] == "promoted"
    r = run(s, nightly={"champion_margin_um": 1.0}).record
    assert r["decision"] == "rejected" and any("margin 1 um" in x for x in r["reasons"])


def test_only_runs_both_models_are_scored_on_count():
    # the champion cannot be scored on v2 (no finite prediction): v2 is not compared
    champ_sum = summary({"v1": 2.0, "v2": float("nan"), "v3": 4.0})
    d = run(summary({"v1": 2.0, "v2": 9.0, "v3": 4.0}), champ_sum=champ_sum)
    assert d.record["decision"] == "promoted"
    assert d.record["relative_gate"]["n_runs_both_scored"] == 2
    assert not d.comparison.set_index("run_id").loc["v2", "both_scored"]


def test_missing_noise_floor_means_margin_zero():
    rel = gates.relative_gate(
        summary({"v1": 2.0}).drop(columns="noise_floor_um"),
        summary({"v1": 2.01}).drop(columns="noise_floor_um"),
        "noise",
    )
    assert bool(rel["candidate_worse"].iloc[0]) and np.isnan(rel["margin_um"].iloc[0])


def test_first_night_absolute_gates_only():
    r = run(summary({"v1": 9.0, "v2": 9.0, "v3": 9.0}), champ=None).record
    assert r["decision"] == "promoted" and not r["relative_gate"]["applied"]
    assert r["coverage"]["status"] == "no_champion" and r["data"]["vanished"] == []


# --------------------------------------------------------------------------- coverage


def test_candidate_missing_a_champion_speed_is_rejected():
    cand = model(speeds=(3000, 6000), offset=1.0)
    r = run(summary({"v1": 2.0, "v2": 3.0, "v3": 4.0}), cand=cand).record
    assert r["decision"] == "rejected" and r["blocked_by"] == ["coverage"]
    assert r["coverage"]["missing_speeds_rpm"] == [9000.0]
    assert any("no run at 9000 r/min" in x for x in r["reasons"])


def test_speed_within_the_tolerance_covers():
    champ = model(speeds=(3000, 6000, 9030))
    r = run(summary({"v1": 2.0, "v2": 3.0, "v3": 4.0}), champ=champ).record
    assert r["coverage"]["status"] == "ok" and r["decision"] == "promoted"


def test_coverage_of_a_global_model_from_its_training_runs_and_the_promotion_record():
    def glob(runs):
        d = {"schema": "rafi.model/1", "kind": "ridge_global", "train_runs": runs, "data": {}}
        d["model_id"] = artefact.compute_model_id(d)
        return d

    champ = glob(["r3000", "r6000", "r9000", "gone_run"])
    cand = glob(["r3000", "r6000", "r9000"])
    s = summary({"v1": 2.0, "v2": 3.0, "v3": 4.0})
    # the champion's run 'gone_run' is in no table and its speeds were not recorded: blocked
    r = run(s, cand=cand, champ=champ).record
    assert r["decision"] == "rejected" and r["coverage"]["unknown_runs"] == ["gone_run"]
    assert any("gone_run" in x and "cannot be confirmed" in x for x in r["reasons"])
    # speeds recorded at its promotion decide (12000 is missing from the candidate)
    prom = {
        "decision": "promoted",
        "champion_id_after": champ["model_id"],
        "training": {"speeds_rpm": [3000.0, 6000.0, 9000.0, 12000.0], "train_runs": []},
    }
    r = run(s, cand=cand, champ=champ, history=[prom]).record
    assert r["coverage"]["missing_speeds_rpm"] == [12000.0] and r["coverage"]["champion_source"] == (
        "promotion record"
    )
    prom["training"]["speeds_rpm"] = [3000.0, 9000.0]
    assert run(s, cand=cand, champ=champ, history=[prom]).record["decision"] == "promoted"
    assert provenance.trained_speeds(cand, RUNS)["speeds_rpm"] == [3000.0, 6000.0, 9000.0]


# --------------------------------------------------------------------------- vanished / changed files


def test_vanished_and_changed_training_files_are_reported():
    champ = model(data={**TRAIN_DATA, "t12.csv": "h12", "t15.csv": "h15", "old.csv": "hb"})
    status = {"rejected": [{"file": "t15.csv", "sha256": "h15", "reason": "unit: mm"}], "usable": []}
    runs = RUNS.assign(sha256=RUNS["sha256"].where(RUNS["file"] != "t6.csv", "h6-new"))
    s = summary({"v1": 2.0, "v2": 3.0, "v3": 4.0})
    r = D.decide(
        machine="m1",
        candidate=D.Candidate(model=model(offset=1.0), summary=s, verdict=qualify(s, GATES)),
        champion=D.Champion(model_id=champ["model_id"], summary=CHAMP_SUM, model=champ),
        runs_table=runs,
        settings=D.DecisionSettings(gates=GATES, nightly=NIGHTLY),
        history=[],
        input_status=status,
    ).record
    data = r["data"]
    assert [(v["file"], v["why"]) for v in data["vanished"]] == [
        ("t12.csv", "no longer in the raw folder"),
        ("t15.csv", "quarantined tonight: unit: mm"),
    ]
    assert data["changed"] == [{"file": "t6.csv", "sha256_champion": "h6", "sha256_now": "h6-new"}]
    assert data["renamed"] == [{"file": "old.csv", "now": "b.csv"}]  # same content, other name
    assert any("vanished: t12.csv" in x for x in r["reasons"])
    assert any("changed: t6.csv" in x for x in r["reasons"])
    # reported, not blocking by itself
    assert r["decision"] == "promoted"


# --------------------------------------------------------------------------- input warnings


def warning(file, check="probe_sign", confirmed=False, sha="hb"):
    return {
        "file": file,
        "sha256": sha,
        "check": check,
        "column": "dz",
        "message": f"{file}: dz falls while the temperatures rise (expected positive)",
        "confirmed": confirmed,
    }


def test_an_unconfirmed_warning_blocks_and_a_confirmed_one_does_not():
    s = summary({"v1": 2.0, "v2": 3.0, "v3": 4.0})
    r = run(s, status={"warnings": [warning("b.csv")]}).record
    assert r["decision"] == "rejected" and r["blocked_by"] == ["input_warnings"]
    assert r["champion_id_after"] == CHAMP["model_id"]
    assert (
        "input warning not confirmed: b.csv probe_sign: b.csv: dz falls while the temperatures rise "
        "(expected positive); confirm it in config checks.confirmed or fix the file"
    ) in r["reasons"]
    ok = run(s, status={"warnings": [warning("b.csv", confirmed=True)]}).record
    assert ok["decision"] == "promoted" and ok["input_warnings"]["confirmed"][0]["file"] == "b.csv"
    # on a file tonight's data does not use: listed, not blocking
    other = run(s, status={"warnings": [warning("x.csv", sha="hx")]}).record
    assert other["decision"] == "promoted" and other["input_warnings"]["not_used"][0]["file"] == "x.csv"
    # no 'warnings' key (before the checks land): no warnings
    assert run(s, status={"usable": []}).record["decision"] == "promoted"
    # first night too: no champion, still blocked
    first = run(s, champ=None, status={"warnings": [warning("c.csv")]}).record
    assert first["decision"] == "rejected" and first["champion_id_after"] is None


# --------------------------------------------------------------------------- driver


def fake_validate(m, runs_table, runs_frame):
    after = m.to_dict()["fake_after"]
    return summary({rid: after.get(rid, 5.0) for rid in ("v1", "v2", "v3")}), pd.DataFrame()


def fake_model(tag, after, runs=("r3000", "r6000", "r9000")):
    d = {"schema": "fake/1", "kind": "fake", "tag": tag, "fake_after": after, "train_runs": list(runs)}
    d["data"] = {f: h for f, h in TRAIN_DATA.items() if f"r{f[1]}000" in runs}
    d["model_id"] = artefact.compute_model_id(d)
    return d


def test_run_decide_reads_the_input_status_and_records_training_speeds(tmp_path: Path):
    reg = R.Registry(tmp_path / "registry", "m1")
    RUNS.to_csv(tmp_path / "runs.csv", index=False)
    pd.DataFrame({"run_id": ["v1"], "t_s": [0.0]}).to_parquet(tmp_path / "runs.parquet")
    status = tmp_path / "input_status.json"

    def night(cand, warnings=()):
        status.write_text(
            json.dumps({"status": "usable", "usable": [], "rejected": [], "warnings": warnings})
        )
        (tmp_path / "model.json").write_text(json.dumps(cand))
        return D.run_decide(
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
            model_from_dict=FakeModel,
            validate_runs=fake_validate,
            qualify=qualify,
            input_status_path=status,
            speed_tolerance_rpm=50,
        )

    good = fake_model("good", {"v1": 2.0})
    assert night(good)["decision"] == "promoted"
    assert reg.history()[-1]["training"]["speeds_rpm"] == [3000.0, 6000.0, 9000.0]
    better = fake_model("better", {"v1": 1.0})
    rec = night(better, [warning("c.csv", sha="hc")])
    assert rec["decision"] == "rejected" and reg.champion_id() == good["model_id"]
    comp = pd.read_csv(reg.comparison_path)
    assert {"noise_floor_um", "margin_um", "candidate_worse", "both_scored"} <= set(comp.columns)
    # confirmed: promoted
    assert night(better, [warning("c.csv", sha="hc", confirmed=True)])["decision"] == "promoted"
    # a candidate without the 9000 r/min run, better everywhere: rejected (coverage)
    partial = fake_model("partial", {"v1": 0.5}, runs=("r3000", "r6000"))
    rec = night(partial)
    assert rec["decision"] == "rejected" and rec["coverage"]["missing_speeds_rpm"] == [9000.0]
    assert reg.champion_id() == better["model_id"]


def test_the_champions_verdict_is_stored_for_the_report_and_absent_without_one():
    """decision.json carries the champion's gates as judged tonight (the report reads them)."""
    with_champion = run(summary({"v1": 2.0, "v2": 4.5, "v3": 4.0})).record
    stored = pd.DataFrame(with_champion["champion_verdict"])
    expected = qualify(CHAMP_SUM, GATES)
    assert stored[["criterion", "run_id", "passed"]].equals(expected[["criterion", "run_id", "passed"]])
    assert "champion_verdict" not in run(summary({"v1": 2.0}), champ=None).record


def test_training_files_gone_from_the_raw_folder_are_one_reason_the_others_one_each():
    from rafi.ops.provenance import GONE_NAMES_SHOWN, data_change_reasons

    gone = [
        {"file": f"train_{k}.csv", "sha256": f"h{k}", "why": "no longer in the raw folder"} for k in range(6)
    ]
    quarantined = {"file": "t15.csv", "sha256": "h15", "why": "quarantined tonight: unit: mm"}
    reasons = data_change_reasons({"vanished": [*gone, quarantined]}, "0123456789abcdef")
    assert (
        reasons[0]
        == "training file of champion 0123456789ab vanished: t15.csv (quarantined tonight: unit: mm)"
    )
    (together,) = reasons[1:]
    assert together.startswith("6 training files of champion 0123456789ab vanished: train_0.csv, ")
    assert f"... ({6 - GONE_NAMES_SHOWN} more)" in together and "train_5.csv" not in together
    assert data_change_reasons({"vanished": gone[:1]}, "c") == [
        "training file of champion c vanished: train_0.csv (no longer in the raw folder)"
    ]
