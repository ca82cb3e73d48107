"""Unit tests of rafi.ops.registry, adapt, gates, drift and decide: immutable model store,
append-only history, champion pointer, speed-range merge, champion/challenger decision on fake
summaries, drift check, rollback.

Fake models: any object with ``predict(frame)`` and ``to_dict()``; validation summaries are
written by hand, so every gate can be failed on purpose.
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from decide_files import decide_on_files

from rafi import artefact, errors
from rafi.family.compare import run_family
from rafi.method.model import RafiModel
from rafi.method.validate import qualify
from rafi.ops import adapt, drift, gates
from rafi.ops import decide as D
from rafi.ops import registry as R
from rafi.settings import MACHINE_DEFAULTS

TERMS = ["1", "x1", "x2", "x3"]
GATES = {
    "max_residual_um": 12.0,
    "min_improvement_pct": 30.0,
    "never_worse_than_uncompensated": True,
    "min_coverage": None,
}
NIGHTLY = MACHINE_DEFAULTS["nightly"]


def make_model(speeds=(3000, 6000, 9000), offset=0.0, sensors=("T6", "T8", "T9"), data=None):
    m = RafiModel(
        list(sensors),
        TERMS,
        reference={"rule": "run_start", "window_s": 60},
        machine="m1",
        data=data or {"a.csv": "aa"},
        code_version="rafi test",
        created="2026-01-01T00:00:00Z",
    )
    for s in speeds:
        m.add_speed_model(
            s,
            [offset + s / 1000, 1.0, 2.0, 3.0],
            {k: [0.0, 5.0] for k in sensors},
            train_runs=[f"r{s}"],
            rmse_um=0.5,
            n=100,
        )
    return m.to_dict()


def summary(rows):
    """rows: (run_id, role, before, after)."""
    recs = []
    for rid, role, before, after in rows:
        recs.append(
            {
                "run_id": rid,
                "role": role,
                "speed_rpm": 4500.0,
                "max_abs_before_um": before,
                "max_abs_after_um": after,
                "improvement_pct": 100 * (before - after) / before,
                "worse_than_uncompensated": after > before,
            }
        )
    return pd.DataFrame(recs)


RUNS = pd.DataFrame(
    {
        "run_id": ["r3000", "r6000", "v1", "v2", "v3"],
        "file": ["a.csv", "a.csv", "b.csv", "c.csv", "d.csv"],
        "role": ["training", "training", "validation_single", "validation_single", "validation_multi"],
        "sha256": ["aa", "aa", "bb", "cc", "dd"],
    }
)


# --------------------------------------------------------------------------- model store


def test_save_model_is_write_once_and_verified(tmp_path):
    reg = R.Registry(tmp_path / "registry", "m1")
    d = make_model()
    path, created = reg.save_model(d, source="model.json")
    assert created and path.name == f"{d['model_id']}.json"
    assert json.loads(path.read_text()) == d
    st = path.stat()
    meta = json.loads(reg.meta_path(d["model_id"]).read_text())
    assert meta["data"] == {"a.csv": "aa"} and "git_commit" in meta["code_version"]
    # a second save of the same model (even with another 'created') leaves the file alone
    again = dict(d, created="2027-01-01T00:00:00Z")
    path2, created2 = reg.save_model(again)
    assert not created2 and path2 == path
    assert path.stat().st_mtime_ns == st.st_mtime_ns and path.stat().st_ino == st.st_ino
    assert json.loads(path.read_text())["created"] == d["created"]
    assert not os.access(path, os.W_OK) or os.geteuid() == 0  # read-only file mode
    assert oct(path.stat().st_mode & 0o777) == oct(0o444)


def test_edited_content_is_never_registered_or_overwritten(tmp_path):
    reg = R.Registry(tmp_path / "registry", "m1")
    d = make_model()
    path, _ = reg.save_model(d)
    original = path.read_bytes()
    forged = json.loads(json.dumps(d))
    forged["speeds"][0]["coefficients"][0] = 99.0  # same id, different content
    with pytest.raises(errors.RegistryError, match="does not match"):
        reg.save_model(forged)
    assert path.read_bytes() == original
    # a tampered registry file is detected, and not repaired silently
    os.chmod(path, 0o644)
    path.write_text(path.read_text().replace('"rmse_um": 0.5', '"rmse_um": 0.7', 1))
    tampered = path.read_bytes()
    with pytest.raises(errors.RegistryError, match="modified"):
        reg.save_model(d)
    assert path.read_bytes() == tampered


def test_write_once_never_replaces(tmp_path):
    p = tmp_path / "x.json"
    assert artefact.write_once(p, "one\n")
    assert not artefact.write_once(p, "two\n")
    assert p.read_text() == "one\n"
    assert [f.name for f in tmp_path.iterdir()] == ["x.json"]  # no temp file left


def test_history_is_append_only(tmp_path):
    reg = R.Registry(tmp_path / "registry", "m1")
    reg.append_history({"decision": "promoted", "candidate_id": "a"})
    first = reg.history_path.read_bytes()
    reg.append_history({"decision": "rejected", "candidate_id": "b"})
    data = reg.history_path.read_bytes()
    assert data.startswith(first) and data.count(b"\n") == 2
    # a torn last line (crash mid-write) is skipped and does not swallow the next record
    with open(reg.history_path, "ab") as fh:
        fh.write(b'{"decision": "promo')
    reg.append_history({"decision": "kept", "candidate_id": "c"})
    assert [r["candidate_id"] for r in reg.history()] == ["a", "b", "c"]
    assert reg.history_path.read_bytes().startswith(data)
    assert all(r["schema"] == R.HISTORY_SCHEMA and r["machine"] == "m1" for r in reg.history())


def test_champion_pointer(tmp_path):
    reg = R.Registry(tmp_path / "registry", "m1")
    with pytest.raises(errors.RegistryError):
        reg.set_champion("0" * 64, reason="x")
    d = make_model()
    reg.save_model(d)
    reg.set_champion(d["model_id"], reason="test")
    assert reg.champion_id() == d["model_id"]
    assert reg.resolve(d["model_id"][:8]) == d["model_id"]
    assert not [p for p in reg.root.iterdir() if p.name.endswith(".part")]


# --------------------------------------------------------------------------- merge


def test_merge_speed_models_takes_only_the_range_from_the_new_fit():
    champ = make_model(speeds=(3000, 6000, 9000, 12000), offset=0.0, data={"old.csv": "o"})
    cand = make_model(speeds=(3000, 6000, 9000, 12000), offset=100.0, data={"new.csv": "n"})
    merged = adapt.merge_speed_models(cand, champ, 6000, 9000)  # inclusive bounds
    coef0 = {s["speed_rpm"]: s["coefficients"][0] for s in merged["speeds"]}
    assert coef0 == {3000: 3.0, 6000: 106.0, 9000: 109.0, 12000: 12.0}
    assert merged["data"] == {"old.csv": "o", "new.csv": "n"}
    assert merged["model_id"] == artefact.compute_model_id(merged)
    assert merged["model_id"] not in (cand["model_id"], champ["model_id"])
    # the merged dict is a valid model with the same id as the model class computes
    assert RafiModel.from_dict(merged).model_id == merged["model_id"]
    assert adapt.speeds_from(merged, cand) == [6000, 9000]
    # open ends and full range
    assert adapt.merge_speed_models(cand, champ, None, None)["speeds"] == cand["speeds"]
    low = adapt.merge_speed_models(cand, champ, None, 4000)
    assert [s["coefficients"][0] for s in low["speeds"]] == [103.0, 6.0, 9.0, 12.0]


def test_merge_keeps_speeds_only_one_side_has():
    champ = make_model(speeds=(3000, 6000), offset=0.0)
    cand = make_model(speeds=(6000, 9000), offset=100.0)
    merged = adapt.merge_speed_models(cand, champ, 6000, 6000)
    got = {s["speed_rpm"]: s["coefficients"][0] for s in merged["speeds"]}
    assert got == {3000: 3.0, 6000: 106.0, 9000: 109.0}


def test_merge_refuses_incompatible_models():
    champ = make_model(sensors=("T6", "T8", "T9"))
    cand = make_model(sensors=("T6", "T8", "T10"))
    with pytest.raises(errors.IncompatibleModels, match="key_sensors"):
        adapt.merge_speed_models(cand, champ, 0, 10000)


# --------------------------------------------------------------------------- gates / decision


def _decide(cand_summary, champ_summary=None, champion_id=None, history=(), candidate=None, nightly=None):
    cand = candidate or make_model(offset=1.0)
    return D.decide(
        machine="m1",
        candidate=D.Candidate(model=cand, summary=cand_summary, verdict=qualify(cand_summary, GATES)),
        champion=D.Champion(model_id=champion_id, summary=champ_summary),
        runs_table=RUNS,
        settings=D.DecisionSettings(
            gates=GATES, nightly={**NIGHTLY, "drift_margin_um": 1.0, **(nightly or {})}
        ),
        history=list(history),
        time="2026-05-01T00:00:00Z",
    )


def test_candidate_passing_every_gate_is_promoted():
    d = _decide(summary([("v1", "validation_single", 20, 5), ("v2", "validation_multi", 20, 8)]))
    r = d.record
    assert r["decision"] == "promoted" and r["gates_passed"]
    assert r["champion_id_after"] == r["candidate_id"] and r["champion_id_before"] is None
    assert r["measured"]["max_residual_um"] == 8
    assert set(d.comparison.columns) >= {
        "run_id",
        "champion_max_abs_after_um",
        "candidate_max_abs_after_um",
        "candidate_improvement_pct",
    }


@pytest.mark.parametrize(
    "rows, gate",
    [
        ([("v1", "validation_single", 40, 13)], "max_residual_um"),
        ([("v1", "validation_single", 10, 8)], "min_improvement_pct"),
    ],
)
def test_each_gate_can_reject(rows, gate):
    r = _decide(summary(rows), champion_id="c" * 64).record
    assert r["decision"] == "rejected" and r["champion_id_after"] == "c" * 64
    assert any(gate in reason for reason in r["reasons"])
    assert any("stays" in reason for reason in r["reasons"])


def test_never_worse_gate_applies_to_any_single_run():
    # excellent on two runs, worse than uncompensated on one idle cool-down run
    rows = [
        ("v1", "validation_single", 30, 2),
        ("v2", "validation_multi", 30, 3),
        ("v3", "validation_idle", 4, 5),
    ]
    r = _decide(summary(rows)).record
    assert r["decision"] == "rejected"
    assert r["measured"]["worse_than_uncompensated_runs"] == ["v3"]
    assert any("never_worse" in x and "v3" in x for x in r["reasons"])
    # even if a qualify() implementation forgot the per-run check, the decision catches it
    passed, reasons, _ = gates.gate_outcome(summary(rows), qualify(summary(rows), {}), GATES)
    assert not passed and any("v3" in x for x in reasons)


def test_no_validation_run_is_not_a_pass():
    r = _decide(
        summary([]).reindex(
            columns=["run_id", "role", "max_abs_before_um", "max_abs_after_um", "improvement_pct"]
        )
    ).record
    assert r["decision"] == "rejected"


def test_candidate_equal_to_champion_is_kept():
    cand = make_model(offset=1.0)
    r = _decide(
        summary([("v1", "validation_single", 20, 5)]),
        champion_id=cand["model_id"],
        champ_summary=summary([("v1", "validation_single", 20, 5)]),
        candidate=cand,
    ).record
    assert r["decision"] == "kept" and r["champion_id_after"] == cand["model_id"]


# --------------------------------------------------------------------------- drift


def test_drift_check_numbers():
    champ = summary([("v1", "validation_single", 20, 5), ("v3", "validation_multi", 20, 9.5)])
    out = drift.drift_check(champ, ["v3"], reference_max_residual_um=7.0, margin_um=2.0)
    assert out["detected"] and out["status"] == "degraded"
    assert out["new_max_residual_um"] == 9.5 and out["limit_um"] == 9.0
    assert out["degradation_um"] == pytest.approx(2.5)
    ok = drift.drift_check(champ, ["v3"], reference_max_residual_um=8.0, margin_um=2.0)
    assert not ok["detected"] and ok["status"] == "ok"
    assert drift.drift_check(champ, [], 7.0, 2.0)["status"] == "no_new_runs"
    assert drift.drift_check(None, ["v3"], 7.0, 2.0)["status"] == "no_champion"


def test_new_validation_runs_by_hash():
    assert drift.new_validation_runs(RUNS, {"a.csv": "aa", "b.csv": "bb"}) == ["v2", "v3"]
    assert drift.new_validation_runs(RUNS, None) == []


def test_decision_reports_recalibration_due_from_history():
    champ = make_model(offset=0.0)
    cid = champ["model_id"]
    history = [
        {
            "decision": "promoted",
            "champion_id_after": cid,
            "time": "2026-04-01T00:00:00Z",
            "candidate_summary": {"max_residual_um": 5.0},
            "data_files": {"a.csv": "aa", "b.csv": "bb"},
        }
    ]
    champ_sum = summary(
        [
            ("v1", "validation_single", 20, 5),
            ("v2", "validation_single", 20, 7.5),
            ("v3", "validation_multi", 20, 5.5),
        ]
    )
    # candidate identical to the champion (no new training data) -> kept, drift flagged
    r = _decide(champ_sum, champ_sum, cid, history, candidate=champ).record
    assert r["decision"] == "kept" and r["recalibration_due"]
    assert r["drift"]["new_runs"] == ["v2", "v3"] and r["drift"]["new_max_residual_um"] == 7.5
    assert r["drift"]["reference_max_residual_um"] == 5.0 and r["drift"]["limit_um"] == 6.0
    assert r["data"]["new_since_champion"] == ["c.csv", "d.csv"]
    assert any("recalibration due" in x for x in r["reasons"])
    comp = _decide(champ_sum, champ_sum, cid, history, candidate=champ).comparison
    assert comp.set_index("run_id")["new_since_champion"].to_dict() == {"v1": False, "v2": True, "v3": True}
    # within the margin: no recalibration
    r2 = _decide(champ_sum, champ_sum, cid, history, candidate=champ, nightly={"drift_margin_um": 3.0}).record
    assert not r2["recalibration_due"] and r2["drift"]["status"] == "ok"


# --------------------------------------------------------------------------- driver with fakes


class FakeModel:
    """A model whose residual on each validation run is given by its dict (fake 'quality')."""

    def __init__(self, d):
        self.d = d

    def predict(self, frame):
        return np.zeros(len(frame))

    def to_dict(self):
        return self.d


def fake_validate(model, runs_table, runs_frame):
    after = model.to_dict()["fake_after"]
    rows = [
        (rid, role, 20.0, after.get(rid, 5.0))
        for rid, role in zip(runs_table["run_id"], runs_table["role"])
        if role.startswith("validation")
    ]
    return summary(rows), pd.DataFrame()


def fake_model(tag, after):
    d = {"schema": "fake/1", "kind": "fake", "tag": tag, "fake_after": after, "data": {"a.csv": "aa"}}
    d["model_id"] = artefact.compute_model_id(d)
    return d


def _run(tmp_path, cand, nightly=None):
    return decide_on_files(
        tmp_path,
        tmp_path / "registry",
        "m1",
        json.dumps(cand),
        RUNS,
        pd.DataFrame({"run_id": ["v1"], "t_s": [0.0]}),
        gates=GATES,
        nightly={**NIGHTLY, **(nightly or {})},
        model_from_dict=FakeModel,
        validate_runs=fake_validate,
        qualify=qualify,
    )


def test_run_decide_promotes_rejects_and_rolls_back(tmp_path):
    reg = R.Registry(tmp_path / "registry", "m1")
    good = fake_model("good", {"v1": 5.0})
    r1 = _run(tmp_path, good)
    assert r1["decision"] == "promoted" and reg.champion_id() == good["model_id"]
    first_bytes = reg.model_path(good["model_id"]).read_bytes()
    assert reg.decision_path.stat().st_mtime_ns >= reg.champion_path.stat().st_mtime_ns

    bad = fake_model("bad", {"v2": 25.0})  # worse than uncompensated on v2
    r2 = _run(tmp_path, bad)
    assert r2["decision"] == "rejected" and reg.champion_id() == good["model_id"]
    assert r2["champion_id_before"] == r2["champion_id_after"] == good["model_id"]
    assert reg.has_model(bad["model_id"])  # rejected candidates are kept for the record
    assert reg.model_path(good["model_id"]).read_bytes() == first_bytes
    comp = pd.read_csv(reg.comparison_path)
    assert comp.set_index("run_id").loc["v2", "candidate_max_abs_after_um"] == 25.0

    better = fake_model("better", {"v1": 3.0})
    assert _run(tmp_path, better)["decision"] == "promoted"
    hist = reg.history()
    assert [h["decision"] for h in hist] == ["promoted", "rejected", "promoted"]
    assert all(h["reasons"] and h["gates"] == GATES for h in hist)

    # operator rollback to the first model; the nightly must not re-promote 'better'
    R.promote(reg.root, "m1", good["model_id"][:10], decision_path=reg.decision_path)
    assert reg.champion_id() == good["model_id"]
    assert json.loads(reg.decision_path.read_text())["decision"] == "rolled_back"
    r4 = _run(tmp_path, better)
    assert r4["decision"] == "kept" and reg.champion_id() == good["model_id"]
    assert "rolled back" in r4["reasons"][0]
    assert [h["decision"] for h in reg.history()] == [
        "promoted",
        "rejected",
        "promoted",
        "rolled_back",
        "kept",
    ]
    with pytest.raises(errors.RegistryError):
        R.promote(reg.root, "m1", "ffff")


def test_run_decide_speed_range_with_real_models(tmp_path):
    """Speed-range adaptation end to end on real RafiModel dicts (fake validation)."""
    champ = make_model(speeds=(3000, 6000, 9000), offset=0.0)
    cand = make_model(speeds=(3000, 6000, 9000), offset=50.0)
    for d in (champ, cand):
        d["fake_after"] = {}
    # fake_after is not part of the hashed content of a RafiModel; ids stay consistent
    reg = R.Registry(tmp_path / "registry", "m1")
    champ_clean = {k: v for k, v in champ.items() if k != "fake_after"}
    reg.save_model(champ_clean)
    reg.append_history(
        {
            "decision": "promoted",
            "champion_id_after": champ["model_id"],
            "candidate_summary": {"max_residual_um": 5.0},
            "data_files": {"a.csv": "aa"},
        }
    )
    reg.set_champion(champ["model_id"], reason="test")
    cand_clean = {k: v for k, v in cand.items() if k != "fake_after"}

    def model_from_dict(d):
        return FakeModel({**d, "fake_after": {}})

    (tmp_path / "model.json").write_text(json.dumps(cand_clean))
    RUNS.to_csv(tmp_path / "runs.csv", index=False)
    pd.DataFrame({"run_id": ["v1"]}).to_parquet(tmp_path / "runs.parquet")
    rec = D.run_decide(
        machine="m1",
        candidate_path=tmp_path / "model.json",
        runs_csv=tmp_path / "runs.csv",
        runs_parquet=tmp_path / "runs.parquet",
        registry_root=reg.root,
        decision_path=reg.decision_path,
        comparison_path=reg.comparison_path,
        gates=GATES,
        nightly={**NIGHTLY, "retrain_speed_range_rpm": [5000, 10000]},
        log=lambda m: None,
        model_from_dict=model_from_dict,
        validate_runs=fake_validate,
        qualify=qualify,
    )
    assert rec["decision"] == "promoted"
    assert rec["adaptation"]["mode"] == "speed_range"
    assert [s["speed_rpm"] for s in rec["retrained_speeds"]] == [6000, 9000]
    assert rec["retrained_speeds"][0]["train_runs"] == ["r6000"]
    assert rec["retrained_speeds"][0]["files"] == ["a.csv"]
    stored = reg.load_model_dict(rec["candidate_id"])
    assert [s["coefficients"][0] for s in stored["speeds"]] == [3.0, 56.0, 59.0]
    assert RafiModel.from_dict(stored).model_id == rec["candidate_id"]


# ------------------------------------------------------------ the nightly with the family's champion


def test_idle_cool_down_above_the_residual_gate_rejects():
    """Issue 12: every gate applies to idle cool-downs too (12.88 um on a cool-down vs a 12 um
    gate was not marked before); the measured worst case covers them."""
    rows = [("v1", "validation_single", 30, 2), ("v3", "validation_idle", 30, 12.88)]
    r = _decide(summary(rows)).record
    assert r["decision"] == "rejected"
    assert any("max_residual_um failed on run v3" in x for x in r["reasons"])
    assert r["measured"]["max_residual_um"] == pytest.approx(12.88)


def test_failing_family_champion_is_not_promoted(tmp_path):
    """The champion chosen on the training runs (best_model.json) goes to rule decide as the
    candidate; with gates it fails it is rejected (no second pick), with gates it passes it is
    promoted. Real models, real validation (rafi.method.validate)."""
    data = Path(__file__).parent / "data"
    table = pd.read_csv(data / "golden_comparison_runs.csv")
    frame = pd.read_csv(data / "golden_comparison_frame.csv")
    table.to_csv(tmp_path / "runs.csv", index=False)
    frame.to_parquet(tmp_path / "runs.parquet")

    def night(gates_, registry):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = run_family(
                table,
                frame,
                key_sensors=["T1", "T2", "T3"],
                terms=MACHINE_DEFAULTS["fit"]["terms"],
                reference=MACHINE_DEFAULTS["reference"],
                machine="m1",
                gates=gates_,
                options={**MACHINE_DEFAULTS["models"], "enabled": ["rafi_linear", "ridge_global", "dynamic"]},
                log=lambda m: None,
            )
            path = tmp_path / "best_model.json"
            path.write_text(artefact.json_text(res["best_artefact"]))
            rec = D.run_decide(
                machine="m1",
                candidate_path=path,
                runs_csv=tmp_path / "runs.csv",
                runs_parquet=tmp_path / "runs.parquet",
                registry_root=tmp_path / registry,
                decision_path=tmp_path / registry / "decision.json",
                comparison_path=tmp_path / registry / "comparison.csv",
                gates=gates_,
                nightly=NIGHTLY,
                log=lambda m: None,
            )
        return res, rec

    res, _ = night(GATES, "probe")
    champ = res["summary"].set_index("model").loc[res["champion"]]
    strict = {**GATES, "max_residual_um": float(champ["max_abs_after_um"]) * 0.9}
    res_s, rec_s = night(strict, "strict")
    assert res_s["champion"] == res["champion"] and not res_s["champion_passed"]
    assert rec_s["candidate_id"] == res["best_artefact"]["model_id"]
    assert rec_s["decision"] == "rejected" and rec_s["champion_id_after"] is None
    assert R.Registry(tmp_path / "strict", "m1").champion_id() is None
    res_l, rec_l = night(GATES, "loose")
    assert res_l["champion_passed"] and rec_l["decision"] == "promoted"
    assert R.Registry(tmp_path / "loose", "m1").champion_id() == res["best_artefact"]["model_id"]
