"""What a model in service rests on (issue 47, audit J): the confirmations of its warnings kept
in the registry, ``rafi nightly --promote`` of a candidate waiting for a confirmation, and
``rafi status`` of a machine whose last run a refused prior stopped.

The registry is written by the real decision (``rafi.ops.decide.run_decide``) of fake models
whose validation residuals are given (``test_registry``'s fakes); the candidate is adapted from
its machine's champion and carries the fitness warnings the audit's candidate had
(``prior_speeds``, ``prior_misfit``).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pandas as pd
import yaml
from decide_files import decide_on_files
from test_registry import GATES, NIGHTLY, RUNS, FakeModel, fake_validate

from rafi import artefact
from rafi.cli import main
from rafi.method.validate import qualify
from rafi.ops import decision_record as DR
from rafi.ops import fleet as F
from rafi.ops import nightly
from rafi.ops import promotion_trail as T
from rafi.ops.project import Paths
from rafi.ops.provenance import input_warnings, prior_warnings
from rafi.ops.registry import Registry
from rafi.ops.status import MachineStatus

M = "m1"
CHECKS = ("prior_speeds", "prior_misfit")


def _model(tag: str, after: dict, parent: str | None = None) -> dict:
    d = {"schema": "fake/1", "kind": "fake", "tag": tag, "fake_after": after, "data": {"a.csv": "aa"}}
    if parent:
        d["machine"] = M
        d["adaptation"] = {
            "parent": parent,
            "parent_machine": M,
            "method": "gain",
            "fitness": {
                "origin": "this machine",
                "warnings": [{"check": c, "message": f"{c} fires"} for c in CHECKS],
            },
        }
    d["model_id"] = artefact.compute_model_id(d)
    return d


def _decide(root: Path, cand: dict, confirmed=()) -> dict:
    return decide_on_files(
        root / "work",
        root / "results" / M / "registry",
        M,
        json.dumps(cand),
        RUNS,
        pd.DataFrame({"run_id": ["v1"], "t_s": [0.0]}),
        gates=GATES,
        nightly=NIGHTLY,
        model_from_dict=FakeModel,
        validate_runs=fake_validate,
        qualify=qualify,
        confirmed=confirmed,
    )


def _project(root: Path, confirmed=()) -> None:
    """The files ``rafi status`` and ``rafi nightly --promote`` need besides the registry."""
    (root / "raw" / M).mkdir(parents=True, exist_ok=True)
    (root / "raw" / M / "day1.csv").write_text("time\n")
    res = root / "results" / M
    res.mkdir(parents=True, exist_ok=True)
    (res / "audit.csv").write_text("file,status,reason\nday1.csv,ok,\n")
    (res / "input_status.json").write_text(json.dumps({"machine": M, "status": "usable", "rejected": []}))
    os.utime(res / "audit.csv", (1_000_000_000, 1_000_000_000))  # before every decision
    config = {"raw_dir": "raw", "results_dir": "results", "reports_dir": "reports"}
    if confirmed:
        config["machines"] = {M: {"checks": {"confirmed": list(confirmed)}}}
    (root / "config.yaml").write_text(yaml.safe_dump(config))


def _waiting(root: Path) -> tuple[dict, dict]:
    """A champion, then a candidate adapted from it that passed every gate and waits for the
    confirmation of its prior's fitness warnings (the audit's WAITING state)."""
    champ = _model("champ", {"v1": 5.0})
    assert _decide(root, champ)["decision"] == "promoted"
    cand = _model("cand", {"v1": 3.0}, parent=champ["model_id"])
    rec = _decide(root, cand)
    assert rec["decision"] == "rejected" and rec["gates_passed"] and rec["blocked_by"] == ["prior_fitness"]
    return champ, cand


def _status(root: Path, capsys) -> str:
    capsys.readouterr()
    main(["status", "--directory", str(root)])
    return capsys.readouterr().out


def _entries(champ: dict) -> list[str]:
    return [f'{{file: "{champ["model_id"][:12]}", check: {c}}}' for c in CHECKS]


# --------------------------------------------------------------------------- item 1: the trail


def test_each_confirmed_warning_keeps_the_entries_that_confirmed_it():
    prior = "ab" * 32
    model = {"machine": "m", "adaptation": {"parent": prior, "parent_machine": "m", "fitness": {}}}
    model["adaptation"]["fitness"]["warnings"] = [{"check": "prior_speeds", "message": "x"}]
    entries = [{"file": prior[:12], "check": "prior_speeds"}]
    entries.append({"file": f"{prior[:4]}*", "check": "prior_speeds"})
    found = prior_warnings(model, entries + [{"file": prior[:12], "check": "prior_misfit"}])
    assert found["confirmed"][0]["confirmed_by"] == entries and found["blocking"] == []
    status = {"warnings": [{"file": "v.csv", "sha256": "h", "check": "speed_range", "confirmed": True}]}
    confirmed = [{"file": "v*.csv", "check": "speed_range"}, {"file": "w.csv", "check": "speed_range"}]
    block = input_warnings(status, {"v.csv": "h"}, confirmed)
    assert block["confirmed"][0]["confirmed_by"] == [{"file": "v*.csv", "check": "speed_range"}]
    # the history line keeps both blocks: the next decision replaces decision.json
    record = {k: k for k in DR.HISTORY_FIELDS} | {"data": {"vanished": [], "changed": []}}
    line = DR.history_record(record | {"prior_fitness": found, "input_warnings": block}, {}, "T")
    assert line["prior_fitness"] == found and line["input_warnings"] == block


def test_the_promotion_line_says_which_entries_confirmed_the_priors_warnings(tmp_path, capsys):
    champ, cand = _waiting(tmp_path)
    pid = champ["model_id"][:12]
    confirmed = [{"file": pid, "check": "prior_speeds"}, {"file": f"{pid}*", "check": "prior_misfit"}]
    rec = _decide(tmp_path, cand, confirmed)
    assert rec["decision"] == "promoted"
    line = Registry(tmp_path / "results" / M / "registry", M).history()[-1]
    assert [w["confirmed_by"] for w in line["prior_fitness"]["confirmed"]] == [[c] for c in confirmed]
    assert line["input_warnings"] == {"blocking": [], "confirmed": [], "not_used": []}
    # the next night judges the same candidate (kept): the promotion's line still says it
    assert _decide(tmp_path, cand, confirmed)["decision"] == "kept"
    _project(tmp_path)
    text = _status(tmp_path, capsys)
    said = f'{{file: "{pid}", check: prior_speeds}}, {{file: "{pid}*", check: prior_misfit}}'
    assert (
        f"  prior warnings:   prior_speeds, prior_misfit: confirmed in checks.confirmed ({said}) at "
        f"the decision of {line['time']} that promoted it\n"
    ) in text


def test_a_promotion_line_from_before_the_trail_says_the_entries_were_not_recorded():
    history = [{"decision": "promoted", "champion_id_after": "x", "time": "T1", "blocked_by": []}]
    trail = T.promotion_trail(history, "x")
    said = T.trail_lines(trail, ["prior_speeds"])["prior"]
    assert said == (
        "confirmed at the decision of T1 that promoted it (the checks.confirmed entries were not recorded)"
    )
    assert T.trail_lines(trail, [])["prior"] == ""


# --------------------------------------------------------------------------- item 2: --promote


def test_promote_by_hand_refuses_a_candidate_waiting_for_a_confirmation(tmp_path, capsys):
    champ, cand = _waiting(tmp_path)
    _project(tmp_path)
    reg = Registry(tmp_path / "results" / M / "registry", M)
    before = reg.history_path.read_bytes(), reg.decision_path.read_bytes()
    code = main(["nightly", "--directory", str(tmp_path), "--machine", M, "--promote", cand["model_id"][:12]])
    err = capsys.readouterr().err.strip()
    assert code == 64 and err.count("\n") == 0
    pid = champ["model_id"][:12]
    assert err.startswith(
        f"rafi nightly: {M}: {cand['model_id'][:12]} not promoted: the fitness warnings prior_speeds, "
        f"prior_misfit of its prior {pid} ({M}) not confirmed; add checks.confirmed: "
        f"[{', '.join(_entries(champ))}] in {M}'s settings"
    )
    assert err.endswith("or promote it over them with --confirm-warnings (recorded in history.jsonl)")
    assert reg.champion_id() == champ["model_id"]
    assert (reg.history_path.read_bytes(), reg.decision_path.read_bytes()) == before
    # the option alone is a usage error
    assert main(["nightly", "--directory", str(tmp_path), "--machine", M, "--confirm-warnings"]) == 64


def test_promote_over_unconfirmed_warnings_is_recorded_and_status_says_so(tmp_path, capsys):
    champ, cand = _waiting(tmp_path)
    _project(tmp_path)
    night = ["nightly", "--directory", str(tmp_path), "--machine", M]
    assert main([*night, "--promote", cand["model_id"], "--confirm-warnings"]) == 0
    reg = Registry(tmp_path / "results" / M / "registry", M)
    assert reg.champion_id() == cand["model_id"]
    line = reg.history()[-1]
    over = line["by_hand"]["overridden"]
    assert line["decision"] == "rolled_back" and over["option"] == "--confirm-warnings"
    assert over["entries"] == _entries(champ) and over["operator"]
    assert [w["check"] for w in line["by_hand"]["prior_fitness"]["blocking"]] == list(CHECKS)
    assert json.loads(reg.decision_path.read_text())["by_hand"]["overridden"] == over
    # the drift reference and training speeds of the decision that judged it, not none
    judged = reg.history()[-2]
    assert line["candidate_summary"] == judged["candidate_summary"] and line["candidate_summary"]
    assert line["training"] == judged["training"] and line["data_files"] == judged["data_files"]
    text = _status(tmp_path, capsys)
    assert "(confirmed in checks.confirmed)" not in text
    assert (
        f"  prior warnings:   prior_speeds, prior_misfit: NOT CONFIRMED: promoted by hand at {line['time']} "
        f"with --confirm-warnings by {over['operator']} over fitness warnings prior_speeds, prior_misfit "
        f"of its prior {champ['model_id'][:12]} ({M}); to confirm add checks.confirmed: "
        f"[{', '.join(_entries(champ))}] in {M}'s settings\n"
    ) in text


def test_status_of_a_promotion_by_hand_from_before_the_check(tmp_path, capsys):
    """The audit's state: an earlier --promote put the waiting candidate in service and its line
    records nothing; the decision that judged it held it back for its prior's fitness."""
    champ, cand = _waiting(tmp_path)
    _project(tmp_path)
    reg = Registry(tmp_path / "results" / M / "registry", M)
    held = reg.history()[-1]["time"]
    reg.append_history(
        {"decision": "rolled_back", "candidate_id": cand["model_id"], "champion_id_after": cand["model_id"]}
    )
    reg.set_champion(cand["model_id"], reason="operator rollback", time="T2")
    rolled = reg.history()[-1]["time"]
    # the next night judges the model in service (kept): the decision that held it back stays the one
    assert _decide(tmp_path, cand)["decision"] == "kept"
    text = _status(tmp_path, capsys)
    assert (
        f"prior warnings:   prior_speeds, prior_misfit: NOT CONFIRMED: promoted by hand (rafi nightly "
        f"--promote) at {rolled} while the decision of {held} held it back for its prior's fitness "
        "warnings; no confirmation is recorded\n"
    ) in text


def test_promote_after_the_confirmation_records_the_entries(tmp_path, capsys):
    champ, cand = _waiting(tmp_path)
    pid = champ["model_id"][:12]
    _project(tmp_path, confirmed=[{"file": pid, "check": c} for c in CHECKS])
    assert main(["nightly", "--directory", str(tmp_path), "--machine", M, "--promote", cand["model_id"]]) == 0
    line = Registry(tmp_path / "results" / M / "registry", M).history()[-1]
    assert line["by_hand"]["overridden"] is None
    assert [w["confirmed_by"] for w in line["by_hand"]["prior_fitness"]["confirmed"]] == [
        [{"file": pid, "check": c}] for c in CHECKS
    ]
    text = _status(tmp_path, capsys)
    assert (
        f"prior_speeds, prior_misfit: confirmed in checks.confirmed ({', '.join(_entries(champ))}) when "
        f"promoted by hand at {line['time']}\n"
    ) in text
    # a rollback to the model a decision promoted needs no confirmation now
    _project(tmp_path)
    night = ["nightly", "--directory", str(tmp_path), "--machine", M]
    assert main([*night, "--promote", champ["model_id"]]) == 0


# --------------------------------------------------------------------------- item 15: a refused prior


FOREIGN = (
    "prior 9cb3d9298248 is a model of tapping-center-a, neither m1 nor a declared sibling of it; if the "
    "two are of one design set models.prior_siblings: [tapping-center-a] in m1's settings, else "
    "models.prior: none"
)


def _refused(root: Path) -> None:
    """A machine whose last run the compare step stopped (PriorForeign): its job log and no decision."""
    _project(root)
    logs = root / "logs" / M
    logs.mkdir(parents=True)
    (logs / "fit.log").write_text("[fit] machine=m1\n[fit] done in 1.0 s\n")
    (logs / "compare.log").write_text(f"[compare] machine=m1\nRAFI compare (machine=m1) failed: {FOREIGN}\n")


def test_status_names_the_step_and_the_refusal_that_stopped_the_last_run(tmp_path, capsys):
    _refused(tmp_path)
    row = F.fleet_overview(Paths.from_config(tmp_path, {}), tmp_path / "reports", [M])[0]
    assert row["state"] == "failed"
    assert row["attention"][0]["text"] == (
        "no decision.json: the last run stopped before the decision: step compare failed: "
        f"{FOREIGN} (logs/{M}/compare.log)"
    )
    said = f"  ! no decision.json: the last run stopped before the decision: step compare failed: {FOREIGN}"
    assert said in _status(tmp_path, capsys)


def test_the_nights_status_line_names_the_step_that_failed_tonight(tmp_path, capsys):
    _refused(tmp_path)
    paths = Paths.from_config(tmp_path, {})
    failures = nightly._failures(paths, [M], 0.0)
    nightly._report([MachineStatus(M, None, [], False)], pipeline_failed=True, failures=failures)
    out = capsys.readouterr().out
    assert (
        f"rafi nightly: {M}: FAILED tonight, step compare failed: {FOREIGN} (logs/{M}/compare.log); "
        "last decision: none\n"
    ) in out
    assert "no decision yet" not in out
    # a log older than the night is not tonight's failure
    assert nightly._failures(paths, [M], 4_000_000_000.0) == {}
