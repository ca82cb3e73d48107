"""Section 1 says what was judged, and what the compensator on the machine would leave (issue 46).

An independent audit read the report of a machine nobody here tuned on (``foreign-3``: no model
on the machine yet, the candidate passed every gate and waits for an input warning's
confirmation; a validation run beyond the trained speeds) against its tables and found:

1. the verdict box said "No validation results" and "0 checks" while ``registry/decision.json``
   held nine checks of the candidate, all passing; sections 2 and 3 said "No registry decision
   in this run" beside the registry section's decision;
2. "It passes every gate on them" stood alone while the replay with the controller's limits left
   26.4 um (day07) where the model alone left 2.85 um, and the run beyond the trained speeds was
   never replayed (only ``validation_multi`` runs were);
3. "the compensation is right to +/-X um, 9 times in 10" stood beside a measured coverage of
   2.3 %.

The report fixture (``tests/data/report_fixture/tapping-center-a``) is set up the way the audit's
results were, and every sentence is checked against the tables it is computed from.
"""

from __future__ import annotations

import html as html_lib
import json
import re

import pandas as pd
from report_fixture import copy_fixture, empty_figure_dirs, write_upstream_tables
from test_report_text import CONFIG, _Figs, _section
from test_report_text import _text as _tagged_text

from rafi.report.context import build_context
from rafi.report.intervals import worst_run_interval
from rafi.report.render import render_html
from rafi.report.replay_section import section_replay
from rafi.settings import machine_settings

MACHINE = "tapping-center-a"


def _no_champion(results, *, gates_passed: bool) -> dict:
    """The fixture's decision made the audit's: no model on the machine before or after, the
    candidate rejected, waiting for an input warning (``gates_passed``) or failing a gate."""
    path = results / "registry" / "decision.json"
    dec = json.loads(path.read_text(encoding="utf-8"))
    for row in dec["verdict"]:
        row["passed"] = gates_passed or row["run_id"] != "multi-1" or row["criterion"] != "max_residual_um"
    warning = {"file": "2026-03-16_multi_condition.csv", "sha256": "ab" * 32, "check": "speed_range"}
    dec |= {
        "decision": "rejected",
        "champion_id_before": None,
        "champion_id_after": None,
        "champion_summary": None,
        "gates_passed": gates_passed,
        "blocked_by": ["input_warnings"] if gates_passed else ["gates"],
        "input_warnings": {"blocking": [{**warning, "message": "x"}] if gates_passed else []},
    }
    path.write_text(json.dumps(dec), encoding="utf-8")
    return dec


def _text(html: str) -> str:
    """Visible text, without the spaces a tag leaves before punctuation (``<code>id</code>,``)."""
    text = html_lib.unescape(_tagged_text(html)).replace("\u00a0", " ")
    return re.sub(r"\( ", "(", re.sub(r" (?=[,;:.)])", "", text))


def _context(results) -> dict:
    paths = write_upstream_tables(results)
    return build_context(
        paths, empty_figure_dirs(results), machine=MACHINE, settings=machine_settings(CONFIG, MACHINE)
    )


def _scored(results) -> list[str]:
    comp = pd.read_csv(results / "registry" / "comparison.csv")
    return comp.loc[comp["candidate_max_abs_after_um"].notna(), "run_id"].astype(str).tolist()


# --------------------------------------------------------------------------- item 1


def test_without_a_model_on_the_machine_the_box_shows_the_candidates_stored_checks(tmp_path):
    """No champion, the candidate passed every gate and waits: the box is WAITING with the
    candidate's stored checks (criterion x validation run), never "No validation results" or
    "0 checks" beside a decision.json that holds them."""
    results = copy_fixture(tmp_path)
    dec = _no_champion(results, gates_passed=True)
    ctx = _context(results)
    v = ctx["verdict"]
    runs = _scored(results)
    n = sum(r["run_id"] in runs for r in dec["verdict"])
    assert v["status"] == "WAITING"
    assert v["n_checks"] == n > 0 and v["n_failed"] == 0
    assert [r["status"] for r in v["rows"]] == ["PASS"] * 3
    text = _text(render_html(ctx))
    assert "No validation results" not in text
    cand = dec["candidate_id"][:12]
    assert f"{n} checks (criterion × validation run) of the candidate {cand}, 0 failed" in text
    worst = max(r["measured"] for r in dec["verdict"] if r["criterion"] == "max_residual_um")
    assert f"Largest residual after compensation: {worst:.2f} µm" in text
    # the run and its noise floor apart in the PDF's text too (it read "run day08_test· noise floor")
    assert re.search(r"</span>\s+<span\s+class=\"muted\">&middot; noise floor of that run", render_html(ctx))


def test_without_a_model_on_the_machine_a_failed_candidate_is_shown_failing(tmp_path):
    results = copy_fixture(tmp_path)
    dec = _no_champion(results, gates_passed=False)
    ctx = _context(results)
    v = ctx["verdict"]
    assert v["status"] == "FAIL" and v["n_failed"] == 1
    failed = [r for r in v["rows"] if not r["passed"]]
    assert [r["criterion"] for r in failed] == ["max_residual_um"] and failed[0]["run_id"] == "run multi-1"
    text = _text(render_html(ctx))
    assert "No validation results" not in text
    kind = v["judged"]["candidate_kind"]
    assert kind == "rafi"  # the registry's artefact of the candidate
    assert (
        f"no model is qualified for this machine: the candidate {dec['candidate_id'][:12]} ({kind}) "
        "does not meet the qualification criteria"
    ) in text


def test_a_decision_without_a_model_on_the_machine_is_not_called_no_decision(tmp_path):
    """Sections 2 and 3 said "No registry decision in this run" whenever no model was on the
    machine; the registry decided (rejected): they say the offered model is not on the machine
    and why, and keep "no registry decision" for results without decision.json."""
    results = copy_fixture(tmp_path)
    dec = _no_champion(results, gates_passed=True)
    ctx = _context(results)
    d = ctx["deployed"]
    assert d["on_machine"] is False and d["no_model"]
    text = _text(render_html(ctx))
    assert "No registry decision in this run" not in text
    assert "It is not on the machine: it passed every gate and waits for a confirmation" in text
    # the replay section, on a summary of the offered model
    summary = pd.DataFrame(
        {
            "model_id": [ctx["deployed"]["model_id"]],
            "kind": ["dynamic"],
            "reference_rule": ["run_start"],
            "run_id": ["multi-1"],
            "log": ["a.csv"],
            "n_samples": [10],
            **{f"n_{s}": [0] for s in ("off", "referencing", "hold", "ramp", "clamped", "rate_limited")},
            "n_ok": [10],
            "n_fault": [0],
            "n_outside_range": [0],
            "faults": [""],
            "max_abs_command_minus_model_um": [0.0],
            "max_abs_measured_um": [9.0],
            "max_abs_residual_model_um": [1.0],
            "max_abs_residual_um": [1.0],
        }
    )
    settings = machine_settings(CONFIG, MACHINE)
    base = {"section_by_id": {"replay": {"id": "replay", "number": 3, "title": "replay"}}, "fig_replay0": 0}
    for decision, said, unsaid in (
        (
            dec,
            "is not on the machine: the registry decision of this run (rejected) leaves no model on the "
            "machine",
            "no registry decision",
        ),
        (None, "(no registry decision in this run)", "leaves no model"),
    ):
        rp = section_replay({"replay_summary": summary, "decision": decision}, settings, _Figs(), None)
        text = _text(_section("replay", replay=rp, **base))
        assert said in text and unsaid not in text


# --------------------------------------------------------------------------- item 3


def _interval_rows(run_cov: float) -> pd.DataFrame:
    return pd.DataFrame(
        {
            "run_id": ["a", "b"],
            "max_abs_after_um": [1.0, 3.0],
            "max_abs_before_um": [20.0, 30.0],
            "coverage": [0.95, run_cov],
            "interval_width_um": [2.0, 9.32],
        }
    )


def test_the_interval_sentence_claims_its_level_only_where_the_measured_coverage_holds_it():
    """The claim "right to +/-X, 9 times in 10" needs the coverage measured at that run and over
    every validation run to reach the level; else the sentence gives the coverage and says it is
    fewer than the level promises."""
    cases = {
        (0.76, 0.83): "both",
        (0.76, 0.95): "run",
        (0.95, 0.83): "all",
        (0.95, 0.92): None,
        (0.76, None): "run",
        (0.90, None): None,
    }
    for (run_cov, pooled), short in cases.items():
        iv = worst_run_interval(_interval_rows(run_cov), 0.9, coverage_all=pooled)
        assert iv["run_id"] == "b" and iv["coverage_pct"] == 100 * run_cov
        assert iv["short"] == short, (run_cov, pooled)
        assert iv["coverage_all_pct"] == (None if pooled is None else 100 * pooled)


def test_the_verdict_does_not_say_nine_in_ten_beside_a_coverage_that_refutes_it():
    from collections import defaultdict

    def said(iv):
        verdict = defaultdict(lambda: None, interval=iv, css="pass", status="PASS", stored=True, rows=[])
        return _text(_section("verdict", verdict=verdict))

    low = said(worst_run_interval(_interval_rows(0.76), 0.9, coverage_all=0.83))
    assert (
        "At the worst run b, the 90 % interval is ±4.66 µm (median width 9.32 µm); it held the measured "
        "dz on 76.0 % of that run's samples and on 83.0 % over every validation run, fewer than the 90 % "
        "it promises."
    ) in low
    assert "9 times in 10" not in low and "right to" not in low
    run_only = said(worst_run_interval(_interval_rows(0.76), 0.9, coverage_all=0.95))
    assert (
        "it held the measured dz on 76.0 % of that run's samples, fewer than the 90 % it promises "
        "(95.0 % over every validation run)."
    ) in run_only
    all_only = said(worst_run_interval(_interval_rows(0.95), 0.9, coverage_all=0.83))
    assert (
        "it held the measured dz on 95.0 % of that run's samples but on 83.0 % over every validation run, "
        "fewer than the 90 % it promises."
    ) in all_only
    held = said(worst_run_interval(_interval_rows(0.95), 0.9, coverage_all=0.92))
    assert (
        "At the worst run b, the compensation is right to ±4.66 µm, 9 times in 10: the 90 % interval "
        "(median width 9.32 µm) held the measured dz on 95.0 % of that run's samples and on 92.0 % over "
        "every validation run."
    ) in held


def test_the_foreign_machines_rafi_line_says_its_coverage_is_far_below_its_level(tmp_path):
    """The rendered report: RAFI's worst run covered at 2.3 % (foreign-3) - the sentence says so
    with the pooled coverage of comparison/summary.csv, and does not claim 9 times in 10."""
    from test_report_intervals import add_interval_results

    results = copy_fixture(tmp_path)
    add_interval_results(results)
    summ = pd.read_csv(results / "validation" / "summary.csv")
    worst = summ["max_abs_after_um"].idxmax()
    summ.loc[worst, "coverage"] = 0.023
    summ.to_csv(results / "validation" / "summary.csv", index=False)
    comp = pd.read_csv(results / "comparison" / "summary.csv")
    pooled = float(comp.loc[comp["model"] == "rafi", "coverage"].iloc[0])
    ctx = _context(results)
    text = _text(render_html(ctx))
    run = summ.loc[worst, "run_id"]
    rv = ctx["verdict"]["rafi"]["interval"]
    assert rv["short"] in ("run", "both") and rv["coverage_all_pct"] == 100 * pooled
    assert f"At its worst run {run}, the 90 % interval is ±" in text
    assert "it held the measured dz on 2.3 % of that run's samples" in text
    assert f"{100 * pooled:.1f} % over every validation run" in text
    # section 2's pooled coverage is a sentence of its own (it read "every validation run.Over all")
    assert "Over all its validation samples" in text and ".Over all" not in text


# --------------------------------------------------------------------------- item 2


def _replay_summary(model_id: str) -> pd.DataFrame:
    """A replay summary as rule replay writes it, with the audit's numbers of foreign-3: a run the
    limits left alone (day06) and two where they held the output (day07: the trained range, day08:
    a speed beyond the trained ones)."""
    return pd.DataFrame(
        {
            "model_id": [model_id] * 3,
            "kind": ["ensemble"] * 3,
            "reference_rule": ["run_start"] * 3,
            "run_id": ["day06_test", "day07_test", "day08_test"],
            "log": ["day06_test.csv", "day07_test.csv", "day08_test.csv"],
            "n_samples": [169, 149, 171],
            "n_off": [0, 0, 0],
            "n_referencing": [1, 1, 1],
            "n_ok": [168, 48, 2],
            "n_hold": [0, 79, 10],
            "n_ramp": [0, 21, 158],
            "n_clamped": [0, 0, 0],
            "n_rate_limited": [0, 3, 0],
            "n_fault": [0, 100, 168],
            "n_outside_range": [0, 100, 168],
            "faults": [
                "",
                "outside_range: 100 (first: Temp9 rise -2.85 K outside trained range)",
                "outside_range: 168 (first: speed 14840 r/min above trained 11240 r/min)",
            ],
            "max_abs_command_minus_model_um": [0.0, 24.10, 51.48],
            "max_abs_measured_um": [36.4, 39.2, 51.0],
            "max_abs_residual_model_um": [2.955, 2.853, 3.032],
            "max_abs_residual_um": [2.955, 26.393, 51.0],
        }
    )


NOISE = {"day06_test": 0.71, "day07_test": 0.52, "day08_test": 0.71}


def test_the_replay_gaps_are_the_runs_where_the_limits_leave_more_than_the_noise_floor():
    from rafi.report.replay_section import replay_gaps

    s = _replay_summary("ab" * 32)
    g = replay_gaps(s, NOISE, 12.0)
    assert g["id"] == "ab" * 6 and g["gate_um"] == 12.0
    assert [r["run_id"] for r in g["runs"]] == ["day08_test", "day07_test"]  # largest first; day06 equal
    day08, day07 = g["runs"]
    assert (day08["with_um"], day08["offline_um"], day08["n_samples"]) == (51.0, 3.032, 171)
    assert day08["actions"] == [["held its output", 10], ["ramped it", 158]] and day08["above_gate"]
    assert day07["actions"] == [["held its output", 79], ["ramped it", 21], ["rate-limited it", 3]]
    assert day07["faults"].startswith("outside_range: 100")
    # a difference inside the run's noise floor is not material; without a floor, any that shows
    clamped = replay_gaps(s.assign(n_hold=0, n_ramp=0, n_clamped=[0, 0, 181]), NOISE)["runs"][0]
    assert clamped["actions"] == [["clamped its output", 181]]
    close = s.assign(max_abs_residual_um=s["max_abs_residual_model_um"] + 0.5)
    assert replay_gaps(close, NOISE, 12.0) is None  # 0.5 um: inside every run's noise floor
    assert [r["run_id"] for r in replay_gaps(close, {}, 12.0)["runs"]] == [
        "day08_test",
        "day06_test",
        "day07_test",
    ]
    assert replay_gaps(s.assign(max_abs_residual_um=s["max_abs_residual_model_um"]), NOISE) is None
    assert replay_gaps(None) is None and replay_gaps(s.drop(columns="max_abs_residual_model_um")) is None
    assert not replay_gaps(s, NOISE)["runs"][0]["above_gate"]  # no gate given: never said above


def _with_replay(results, model_id: str) -> pd.DataFrame:
    """The fixture with the replay summary (its runs renamed to the audit's) and its champion passing."""
    (results / "deploy").mkdir(exist_ok=True)
    s = _replay_summary(model_id)
    runs = pd.read_csv(results / "runs.csv")["run_id"].astype(str).tolist()
    s["run_id"] = [r for r in runs if r.startswith(("val", "multi"))][:3]
    s.to_csv(results / "deploy" / "replay_summary.csv", index=False)
    summ = pd.read_csv(results / "comparison" / "summary.csv")
    summ.loc[summ["champion"].astype(bool), "passed"] = True
    summ.to_csv(results / "comparison" / "summary.csv", index=False)
    return s


def test_passes_every_gate_is_said_beside_what_the_compensator_would_leave(tmp_path):
    """foreign-3: the candidate waits, the replayed model is the box's and the offered one. The
    box says, from the replay, what the compensator would leave where it differs from the model
    alone; the selection's "passes every gate" says it is offline; section 2 points to it."""
    results = copy_fixture(tmp_path)
    dec = _no_champion(results, gates_passed=True)
    s = _with_replay(results, dec["candidate_id"])
    ctx = _context(results)
    v = ctx["verdict"]
    assert v["replay_in_box"] and v["replay_offered"]
    first, second = s["run_id"].iloc[2], s["run_id"].iloc[1]
    assert [r["run_id"] for r in v["replay"]["runs"]] == [first, second]
    text = _text(render_html(ctx))
    n = ctx["section_by_id"]["replay"]["number"]
    assert (
        f"With the controller's limits (the replay, section {n}) the compensator on the machine would "
        f"leave more than the model alone: on {first} a worst residual of 51.00 µm (model alone 3.03 µm, "
        "above the 12.00 µm limit of the largest-residual gate): it held its output on 10, ramped it on 158 "
        "of 171 samples (fault rule: outside_range: 168 (first: speed 14840 r/min above trained 11240 "
        f"r/min)); on {second} 26.39 µm (model alone 2.85 µm, above the 12.00 µm limit of the "
        "largest-residual gate): it held its output on 79, ramped it on 21, rate-limited it on 3 of 149 "
        "samples"
    ) in text
    assert "The gates judge the model alone (offline), not the replay." in text
    assert (
        "It passes every gate on them offline (the model alone); with the controller's limits it leaves "
        f"up to 51.00 µm ({first}, above)."
    ) in text
    assert (
        "These are the model alone (offline); with the controller's limits the compensator would leave "
        f"up to 51.00 µm on {first} (section {n}, the replay)."
    ) in text
    assert "It passes every gate on them." not in text


def test_the_replay_of_another_model_than_the_boxs_is_said_beside_the_offered_models_gates(tmp_path):
    """The model on the machine is another one: the box is not the replayed model's and says
    nothing of the replay; the sentence on the offered model's gates says it in full. Without a
    material difference nothing is added."""
    results = copy_fixture(tmp_path)
    path = results / "registry" / "decision.json"
    dec = json.loads(path.read_text(encoding="utf-8"))
    _with_replay(results, dec["candidate_id"])
    dec |= {"champion_id_before": "ee" * 32, "champion_id_after": "ee" * 32, "decision": "rejected"}
    path.write_text(json.dumps(dec), encoding="utf-8")
    ctx = _context(results)
    assert ctx["verdict"]["replay_offered"] and not ctx["verdict"]["replay_in_box"]
    text = _text(render_html(ctx))
    assert "It passes every gate on them. With the controller's limits (the replay, section" in text
    assert text.count("would leave more than the model alone") == 1
    s = pd.read_csv(results / "deploy" / "replay_summary.csv")
    s.assign(max_abs_residual_um=s["max_abs_residual_model_um"]).to_csv(
        results / "deploy" / "replay_summary.csv", index=False
    )
    ctx = _context(results)
    text = _text(render_html(ctx))
    assert ctx["verdict"]["replay"] is None and "It passes every gate on them." in text
    assert "would leave more than the model alone" not in text and "These are the model alone" not in text


def test_every_validation_run_is_replayed_by_default_and_a_long_list_is_counted_in_the_title():
    """foreign-3's run beyond the trained speeds (validation_single) was never replayed: only
    validation_multi runs were. Every validation role is replayed by default (a replay costs
    about a second per run); beyond three runs the section's title counts them."""
    from rafi.method.runs import ROLES
    from rafi.report.replay_section import section_title

    roles = machine_settings(CONFIG, MACHINE)["deploy"]["replay_roles"]
    assert set(roles) == {r for r in ROLES if r.startswith("validation")}
    title = section_title({"runs": [{"run_id": f"r{k}"} for k in range(3)]}, "x")
    assert title == "The model on the machine: replay of r0, r1, r2"
    assert section_title({"runs": [{"run_id": f"r{k}"} for k in range(9)]}, "x").endswith("replay of 9 runs")
