"""Issue 45, loud outcomes: the end-of-run lines (rafi.ops.outcome), the job-log lines they read
(rafi.ops.run_messages) and the skipped folder's message (rafi.readers.discovery).

Pure functions on decision.json-like dicts, and read_outcome on a results tree written here.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

from rafi.method.run_checks import CONTINUOUS_LOG_DOCS
from rafi.ops.outcome import (
    DOCS,
    Outcome,
    RunFiles,
    awaiting_confirmation,
    decision_outcome,
    failed_gate_words,
    failed_step_outcome,
    outcome_line,
    outcome_lines,
    read_outcome,
    skipped_folders,
)
from rafi.ops.run_messages import failure_line, log_warnings, step_failed, warning_line
from rafi.readers.discovery import FOREIGN_FORMAT_DOCS, SKIP_PREFIX, folder_contents
from rafi.readers.input_spec import discover_machines

CANDIDATE = "92289bc7cc53af64b309c6d6ae601b9f0b152d333e47eccbdcc531b36bc5cafd"


def _verdict(rows):
    return [
        {"criterion": c, "run_id": r, "measured": m, "limit": lim, "passed": p} for c, r, m, lim, p in rows
    ]


def _decision(passed, verdict=(), decision="promoted", **over):
    return {
        "candidate_id": CANDIDATE,
        "decision": decision,
        "gates_passed": passed,
        "verdict": _verdict(verdict),
        "blocked_by": [],
        "reasons": [],
        "time": "2026-11-28T21:57:20Z",
        **over,
    }


def test_failed_gates_in_words_one_per_gate_with_the_worst_run():
    verdict = [
        ("max_residual_um", "a", 3.0, 12.0, True),
        ("max_residual_um", "b", 178.73, 12.0, False),
        ("max_residual_um", "c", 20.5, 12.0, False),
        ("min_improvement_pct", "a", 80.0, 30.0, True),
        ("min_improvement_pct", "b", -1217.8, 30.0, False),
        ("min_improvement_pct", "c", 10.0, 30.0, False),
        ("never_worse_than_uncompensated", "b", 178.73, 13.5, False),
        ("never_worse_than_uncompensated", "c", 20.5, 25.0, True),
    ]
    assert failed_gate_words(_verdict(verdict)) == [
        "max residual above 12 um on 2 of 3 run(s) (worst 178.73 um, run b)",
        "improvement below 30 % on 2 of 3 run(s) (worst -1217.80 %, run b)",
        "compensated residual above the uncompensated on 1 of 2 run(s) (worst: 178.73 um vs 13.50 um "
        "uncompensated, run b)",
    ]


def test_a_missing_measurement_is_the_worst():
    verdict = [
        ("max_residual_um", "a", 50.0, 12.0, False),
        ("max_residual_um", "b", float("nan"), 12.0, False),
    ]
    (words,) = failed_gate_words(_verdict(verdict))
    assert words.endswith("(worst ? um, run b)")
    assert failed_gate_words(_verdict([("max_residual_um", "a", 1.0, 12.0, True)])) == []


def test_pass_says_the_model_and_what_became_of_it():
    pass_ = decision_outcome("m", _decision(True), kind="dynamic", report="report r.html")
    assert outcome_line(pass_) == "m: PASS - model offered: dynamic 92289bc7cc53, promoted; report r.html"
    kept = decision_outcome("m", _decision(True, decision="kept"), kind="grey_box")
    assert outcome_line(kept) == "m: PASS - model offered: grey_box 92289bc7cc53, kept"
    blocked = decision_outcome(
        "m", _decision(True, decision="rejected", blocked_by=["input_warnings", "coverage"])
    )
    assert outcome_line(blocked) == (
        "m: PASS - model offered: 92289bc7cc53, not promoted (blocked by input_warnings, coverage)"
    )


def test_a_candidate_waiting_for_its_priors_confirmation_is_neither_pass_nor_fail():
    """Every gate passed, only the prior's fitness warning holds it back: WAITING, with the check,
    the prior and the checks.confirmed entry to add (rafi status says the same words)."""
    from rafi.ops.fleet import rejected_text

    prior = "6fca63e8ad59" + "0" * 52
    blocking = [
        {"check": "prior_speeds", "prior": prior, "machine": "a", "for_machine": "a2", "message": "x"}
    ]
    decision = _decision(True, decision="rejected", blocked_by=["prior_fitness"])
    decision["prior_fitness"] = {"blocking": blocking, "confirmed": []}
    waiting = decision_outcome("a2", decision, kind="ensemble", report="report r.html")
    words = (
        "waits for a confirmation of the prior fitness check prior_speeds of prior 6fca63e8ad59 (a): add "
        'checks.confirmed: [{file: "6fca63e8ad59", check: prior_speeds}] in a2\'s settings'
    )
    assert awaiting_confirmation(decision) == words
    assert outcome_line(waiting) == (
        f"a2: WAITING - model offered: ensemble 92289bc7cc53, passed every gate, not promoted: {words}; "
        "report r.html"
    )
    assert rejected_text(decision, has_champion=False) == (
        f"the last candidate 92289bc7cc53 passed every gate and {words}; no model in service until then"
    )
    # another block beside it (or a failed gate): not waiting for a confirmation alone
    other = {**decision, "blocked_by": ["prior_fitness", "relative_gate"]}
    assert awaiting_confirmation(other) is None
    assert outcome_line(decision_outcome("a2", other)).startswith("a2: PASS - ")
    assert rejected_text(other, has_champion=True) == "the last candidate was rejected; the champion stays"
    assert awaiting_confirmation({**decision, "gates_passed": False}) is None


def _input_warning(file="valid_50000rpm.csv", check="speed_range"):
    return {"file": file, "sha256": "ab" * 32, "check": check, "column": "speed", "message": "x"}


def test_a_candidate_waiting_for_an_input_warnings_confirmation_is_neither_pass_nor_fail():
    """Every gate passed, only an unconfirmed input warning holds it back (issue 47): it waits for
    a person's confirmation as a prior's fitness warning does - WAITING, with the file, the check
    and the checks.confirmed entry to add; both kinds at once are one list of entries."""
    from rafi.ops.fleet import rejected_text

    decision = _decision(True, decision="rejected", blocked_by=["input_warnings"], machine="a2")
    decision["input_warnings"] = {"blocking": [_input_warning()], "confirmed": [], "not_used": []}
    words = (
        "waits for a confirmation of the input warning speed_range on valid_50000rpm.csv: add "
        'checks.confirmed: [{file: "valid_50000rpm.csv", check: speed_range}] in a2\'s settings'
    )
    assert awaiting_confirmation(decision) == words
    line = outcome_line(decision_outcome("a2", decision, kind="dynamic"))
    assert line == (
        f"a2: WAITING - model offered: dynamic 92289bc7cc53, passed every gate, not promoted: {words}"
    )
    assert rejected_text(decision, has_champion=True) == (
        f"the last candidate 92289bc7cc53 passed every gate and {words}; the champion stays until then"
    )
    # two warnings and a prior's fitness check: every entry in one list, the input's first
    prior = "6fca63e8ad59" + "0" * 52
    both = {
        **decision,
        "blocked_by": ["input_warnings", "prior_fitness"],
        "input_warnings": {"blocking": [_input_warning(), _input_warning("b.csv", "probe_sign")]},
        "prior_fitness": {
            "blocking": [{"check": "prior_speeds", "prior": prior, "machine": "a", "for_machine": "a2"}]
        },
    }
    assert awaiting_confirmation(both) == (
        "waits for a confirmation of the input warnings speed_range on valid_50000rpm.csv, probe_sign on "
        "b.csv and the prior fitness check prior_speeds of prior 6fca63e8ad59 (a): add checks.confirmed: "
        '[{file: "valid_50000rpm.csv", check: speed_range}, {file: "b.csv", check: probe_sign}, '
        '{file: "6fca63e8ad59", check: prior_speeds}] in a2\'s settings'
    )
    # beside a block no confirmation lifts (coverage, the relative gate): not waiting, PASS as before
    other = {**decision, "blocked_by": ["input_warnings", "coverage"]}
    assert awaiting_confirmation(other) is None
    assert outcome_line(decision_outcome("a2", other)).startswith("a2: PASS - ")
    # a block named without its warnings (a decision.json cut short): nothing to name, not waiting
    assert awaiting_confirmation({**decision, "input_warnings": {"blocking": []}}) is None


def test_fail_says_each_failed_gate():
    verdict = [
        ("max_residual_um", "x#2", 178.73, 12.0, False),
        ("min_improvement_pct", "x#2", 50.0, 30.0, True),
    ]
    fail = decision_outcome(
        "m", _decision(False, verdict, decision="rejected"), kind="grey_box", report="report r"
    )
    assert fail.status == "FAIL"
    assert outcome_line(fail) == (
        "m: FAIL - model offered: grey_box 92289bc7cc53, not promoted: max residual above 12 um on 1 of "
        "1 run(s) (worst 178.73 um, run x#2); report r"
    )
    # no verdict row (no validation run): the decision's reason
    none = decision_outcome(
        "m",
        _decision(
            False, decision="rejected", reasons=["no validation runs: the candidate cannot be qualified"]
        ),
    )
    assert none.text.endswith("not promoted: no validation runs: the candidate cannot be qualified")


def test_a_failed_step_is_said_with_its_message_unless_it_follows():
    line = failure_line("runs", "machine=m", "training_speeds_rpm: no training run")
    assert failed_step_outcome("m", "runs", "logs/m/runs.log", line).text == (
        "step runs failed: training_speeds_rpm: no training run; no model offered"
    )
    assert "(its message is below)" in failed_step_outcome("m", "runs", "l", line, said_below=True).text
    assert "(details in logs/m/fit.log)" in failed_step_outcome("m", "fit", "logs/m/fit.log", None).text


def test_lines_are_ordered_fail_first_and_carry_probe_and_warnings():
    outcomes = {
        ("b", None): Outcome("b", "PASS", "model offered: x", report="report r"),
        ("a", None): Outcome("a", "skipped", "no file"),
        ("c", "X"): Outcome("c", "FAIL", "step runs failed", probe="X", warnings=("(runs): careful",)),
        ("c", "Y"): Outcome("c", "PASS", "model offered: y", probe="Y"),
        ("d", None): Outcome("d", "not judged", "in this run (no decision built; none yet)"),
    }
    lines = outcome_lines(list(outcomes), lambda m, p: outcomes[(m, p)])
    assert lines == [
        f"RAFI: outcome of this run, one line per machine ({DOCS}):",
        "  c [X]: FAIL - step runs failed\n    warning (runs): careful",
        "  a: skipped - no file",
        "  b: PASS - model offered: x; report r",
        "  c [Y]: PASS - model offered: y",
        "  d: not judged in this run (no decision built; none yet)",
    ]
    assert outcome_lines([], lambda m, p: None) == []


def test_job_log_lines(tmp_path: Path):
    log = tmp_path / "runs.log"
    warn = warning_line("runs", "machine=m", "log a.csv holds 3 runs")
    log.write_text(f"[runs] machine=m\n{warn}\n2026 WARNING x: {warn}\n[runs] done in 1.0 s\n")
    assert log_warnings(log) == ["(runs): log a.csv holds 3 runs"]  # the logging copy is no line of its own
    assert step_failed(log) == (False, None)
    fail = failure_line("runs", "machine=m", "bad")
    log.write_text(f"[runs] machine=m\n{fail}\n")
    assert step_failed(log) == (True, fail)
    log.write_text("[fit] machine=m\nTraceback (most recent call last):\nValueError: x\n")
    assert step_failed(log) == (True, None)
    log.write_text("")  # a step after the failed one of the same job never began
    assert step_failed(log) == (False, None)
    assert step_failed(tmp_path / "missing.log") == (False, None)
    assert log_warnings(tmp_path / "missing.log") == []


def _tree(tmp_path: Path):
    files = RunFiles(
        str(tmp_path / "results"),
        str(tmp_path / "reports"),
        str(tmp_path / "logs"),
        since=time.time() - 1,  # the file system clock is coarser
    )
    for sub in ("results/m/registry/models", "reports/m", "logs/m"):
        (tmp_path / sub).mkdir(parents=True)
    return files


def _age(path: Path, seconds: float = 3600) -> None:
    t = time.time() - seconds
    os.utime(path, (t, t))


def test_read_outcome_from_what_the_run_wrote(tmp_path: Path):
    files = _tree(tmp_path)
    results = tmp_path / "results" / "m"
    verdict = [("max_residual_um", "v", 20.0, 12.0, False)]
    (results / "registry" / "decision.json").write_text(
        json.dumps(_decision(False, verdict, decision="rejected"))
    )
    (results / "registry" / "models" / f"{CANDIDATE}.json").write_text(json.dumps({"kind": "ridge_global"}))
    html = tmp_path / "reports" / "m" / "qualification.html"
    html.write_text("<html>")
    (tmp_path / "logs" / "m" / "runs.log").write_text(warning_line("runs", "machine=m", "w1") + "\n")
    _age(tmp_path / "logs" / "m" / "runs.log")  # an earlier run's log still speaks for its outputs
    got = read_outcome("m", None, files)
    assert got.status == "FAIL" and got.report == f"report {html}"
    assert got.text.startswith(
        "model offered: ridge_global 92289bc7cc53, not promoted: max residual above 12 um"
    )
    assert got.warnings == ("(runs): w1",)

    _age(html)
    assert (
        read_outcome("m", None, files).report
        == f"report not rebuilt in this run ({html} is of an earlier one)"
    )
    html.unlink()
    assert read_outcome("m", None, files).report == "no report built in this run"

    _age(results / "registry" / "decision.json")  # not written by this run: not judged
    stale = read_outcome("m", "X", files)
    assert (stale.status, stale.probe) == ("not judged", "X")
    assert stale.text == "in this run (no decision built; the last is of 2026-11-28T21:57:20Z)"

    (tmp_path / "logs" / "m" / "fit.log").write_text(failure_line("fit", "machine=m", "bad fit") + "\n")
    failed = read_outcome("m", None, files)
    assert failed.status == "FAIL" and failed.text == "step fit failed: bad fit; no model offered"


def test_read_outcome_of_a_skipped_machine(tmp_path: Path):
    files = _tree(tmp_path)
    status = {
        "machine": "m",
        "status": "skipped",
        "rejected": [{"file": "a.csv", "reason": "line 3: not a number"}],
    }
    (tmp_path / "results" / "m" / "input_status.json").write_text(json.dumps(status))
    got = read_outcome("m", None, files)
    assert outcome_line(got) == "m: skipped - no usable raw file (1 rejected): a.csv: line 3: not a number"
    folder = read_outcome("n", None, files, {"n": "no file matches input.pattern '*.csv'"})
    assert outcome_line(folder) == "n: skipped - no file matches input.pattern '*.csv'"


def _touch(path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("x")


def test_a_folder_without_a_matching_file_says_what_it_holds_and_where_to_read(tmp_path: Path):
    for name in ("sheet_b.xlsx", "sheet_a.xlsx", "notes.txt", "README", ".hidden.csv", "sub/c.xlsx"):
        _touch(tmp_path / "fl-thermal" / name)
    _touch(tmp_path / "m1" / "a.csv")
    (tmp_path / "empty").mkdir()
    found, warnings = discover_machines(tmp_path, lambda m: {})
    assert list(found) == ["m1"]
    skipped = skipped_folders(warnings, SKIP_PREFIX)
    assert skipped["fl-thermal"] == (
        "no file matches input.pattern '*.csv'; the folder holds 5 file(s): README, notes.txt, "
        "sheet_a.xlsx, sheet_b.xlsx, sub/c.xlsx (.xlsx 3, (no extension) 1, .txt 1). A format or layout "
        f"other than the native CSV needs machines.fl-thermal.input in the config: {FOREIGN_FORMAT_DOCS}"
    )
    assert "the folder holds no file." in skipped["empty"]


def test_folder_contents_lists_the_first_names_only(tmp_path: Path):
    for k in range(8):
        _touch(tmp_path / f"log_{k}.dat")
    assert (
        folder_contents(tmp_path, shown=3)
        == "8 file(s): log_0.dat, log_1.dat, log_2.dat, ... (5 more) (.dat 8)"
    )


@pytest.mark.parametrize("doc", [DOCS, FOREIGN_FORMAT_DOCS, CONTINUOUS_LOG_DOCS])
def test_the_docs_anchors_the_messages_name_are_headings(doc):
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces as hyphens."""
    root = Path(__file__).resolve().parents[1]
    path, anchor = doc.split("#", 1)
    headings = [
        "".join(c for c in line.lstrip("#").strip().lower() if c.isalnum() or c in " -").replace(" ", "-")
        for line in (root / path).read_text(encoding="utf-8").splitlines()
        if line.startswith("#")
    ]
    assert anchor in headings


def test_rafi_nightly_prints_the_lines_and_names_a_folder_without_a_matching_file(tmp_path: Path, capsys):
    from argparse import Namespace

    from rafi.ops import nightly
    from rafi.ops.project import Paths, unmatched_folders

    _touch(tmp_path / "raw" / "fl" / "probe.xlsx")
    _touch(tmp_path / "raw" / "m" / "a.csv")
    paths = Paths(tmp_path, tmp_path / "raw", tmp_path / "results")
    unmatched = unmatched_folders(paths, {}, ["fl", "m"])
    assert list(unmatched) == ["fl"] and unmatched["fl"].startswith("no file matches input.pattern '*.csv'")
    registry = tmp_path / "results" / "m" / "registry"
    (registry / "models").mkdir(parents=True)
    (registry / "decision.json").write_text(json.dumps(_decision(True)))
    (registry / "models" / f"{CANDIDATE}.json").write_text(json.dumps({"kind": "dynamic"}))
    args = Namespace(reports_dir=tmp_path / "reports", unmatched=unmatched)
    nightly._say_outcomes(args, paths, ["fl", "m"], since=time.time() - 60)
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("RAFI: outcome of this run")
    assert out[1] == f"  fl: skipped - {unmatched['fl']}"
    assert out[2] == "  m: PASS - model offered: dynamic 92289bc7cc53, promoted; no report built in this run"


# --------------------------------------------------------------------------- the runs warnings in state
#
# The re-qualification of tapping-center-a (issue 47): after the promotion (the prior's warnings
# confirmed) the end-of-run still said "the promotion waits for the prior_speeds confirmation",
# and the continuous-log warning said both "set `reference: {rule: log_start}`" and "a recording
# of `rafi plan`'s programme is read per run by design, leave it". The texts are run_checks' own.

PRIOR = "6fca63e8ad59" + "0" * 52


def _runs_warnings() -> tuple[str, str]:
    """The training-speeds warning with a prior and the continuous-log warning, as the runs step
    writes them (rafi.method.run_checks) for a `rafi plan` recording of tapping-center-a."""
    import pandas as pd

    from rafi.method.run_checks import continuous_log_warnings, training_speed_problems

    table = pd.DataFrame(
        {
            "run_id": ["r#1", "r#2", "r#3"],
            "file": "r.csv",
            "segment": 0,
            "role": "training",
            "kind": ["constant", "idle", "constant"],
            "speed_rpm": [18000.0, 0.0, 3000.0],
        }
    )
    (speeds,) = training_speed_problems(table, [3000, 9000, 18000], 50, "m", prior="auto")
    (continuous,) = continuous_log_warnings(table, "run_start")
    return f"(runs): {speeds}", f"(runs): {continuous}"


def _fitness(state: str) -> dict:
    w = {"check": "prior_speeds", "prior": PRIOR, "machine": "m", "for_machine": "m", "message": "x"}
    return {
        "prior_fitness": {
            "blocking": [w] if state == "blocking" else [],
            "confirmed": [w] if state == "confirmed" else [],
        }
    }


def test_the_prior_speeds_clause_says_what_the_decision_in_place_says():
    from rafi.ops.outcome import warning_in_state

    speeds, _ = _runs_warnings()
    waits = "and the promotion waits for the prior_speeds confirmation (docs/models.md)"
    assert speeds.endswith(waits)
    assert warning_in_state(speeds, None) == speeds  # no decision (a step failed before it): as written
    assert warning_in_state(speeds, {**_decision(True), **_fitness("blocking")}) == speeds
    promoted = warning_in_state(speeds, {**_decision(True, decision="promoted"), **_fitness("confirmed")})
    assert "waits" not in promoted
    assert promoted.endswith(
        "; in this re-qualification from a prior these speeds are left to the prior, its prior_speeds "
        'warning confirmed in checks.confirmed ({file: "6fca63e8ad59", check: prior_speeds}; docs/models.md)'
    )
    # a decision without the warning (no prior tonight): the clause about a prior goes
    plain = warning_in_state(speeds, _decision(True, decision="promoted"))
    assert plain == speeds[: speeds.index("; in a re-qualification")]


def test_the_continuous_log_warning_gives_one_instruction_for_a_rafi_plan_recording():
    from rafi.ops.outcome import warning_in_state

    _, continuous = _runs_warnings()
    said = warning_in_state(continuous, None)
    assert said.startswith("(runs): log r.csv holds 3 runs of one continuous recording")
    assert said.endswith(
        "If the log is a recording of `rafi plan`'s programme, leave it: such a recording is read per run "
        "by design (docs/record.md); set `reference: {rule: log_start}` only for runs cut out of one "
        f"continuous log of production ({CONTINUOUS_LOG_DOCS})"
    )
    assert "For runs inside one continuous log set" not in said
    assert warning_in_state(said, None) == said


def test_read_outcome_says_the_runs_warnings_as_the_promotion_left_them(tmp_path: Path):
    files = _tree(tmp_path)
    speeds, continuous = _runs_warnings()
    log = tmp_path / "logs" / "m" / "runs.log"
    log.write_text(
        "".join(warning_line("runs", "machine=m", w.split(": ", 1)[1]) + "\n" for w in (speeds, continuous))
    )
    _age(log)  # the runs step ran on an earlier night; tonight's decision confirmed and promoted
    decision = {**_decision(True, decision="promoted"), **_fitness("confirmed")}
    (tmp_path / "results" / "m" / "registry" / "decision.json").write_text(json.dumps(decision))
    got = read_outcome("m", None, files)
    assert got.status == "PASS" and got.text.endswith("promoted")
    assert not any("waits" in w for w in got.warnings)
    assert not any("For runs inside one continuous log set" in w for w in got.warnings)
    # the runs step re-ran after that decision (tonight's failed before deciding): as written
    _age(tmp_path / "results" / "m" / "registry" / "decision.json", 7200)
    assert "promotion waits" in read_outcome("m", None, files).warnings[0]
