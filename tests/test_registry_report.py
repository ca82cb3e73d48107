"""The report's registry section shows the checks against the champion in service (issue 13
item 4): the relative gate per run (champion, candidate, margin), the speed coverage, the
champion's vanished or changed training files and the input warnings that block promotion."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pandas as pd
from markupsafe import escape
from test_report import FIXTURE, _context, _settings, _upstream
from test_report_intervals import _text

from rafi.ops.drift import interval_drift
from rafi.report.context import build_context
from rafi.report.format import fmt_num, fmt_sig
from rafi.report.inputs import result_paths
from rafi.report.registry_section import section_registry
from rafi.report.render import render_html


def _rejected(dec: dict, comp: pd.DataFrame) -> tuple[dict, pd.DataFrame]:
    """The fixture's decision, made a rejection for all three new reasons."""
    champ = dec["champion_id_before"]
    comp = comp.copy()
    comp["candidate_max_abs_after_um"] = comp["champion_max_abs_after_um"]
    first = comp["run_id"].iloc[0]
    comp.loc[comp["run_id"] == first, "candidate_max_abs_after_um"] += 1.234
    comp["noise_floor_um"] = 0.61
    comp["margin_um"] = 0.61
    comp["both_scored"] = True
    comp["candidate_minus_champion_um"] = (
        comp["candidate_max_abs_after_um"] - comp["champion_max_abs_after_um"]
    )
    comp["candidate_worse"] = comp["candidate_minus_champion_um"] > comp["margin_um"]
    warning = {
        "file": "2026-03-12_val_10500rpm.csv",
        "sha256": "ab" * 32,
        "check": "probe_sign",
        "column": "dz",
        "message": "dz falls by 20.1 um while T1 rises by 9.8 degC (expected positive)",
        "confirmed": False,
    }
    dec = {
        **dec,
        "decision": "rejected",
        "champion_id_after": champ,
        "blocked_by": ["relative_gate", "coverage", "input_warnings"],
        "relative_gate": {
            "applied": True,
            "champion_margin_um": "noise",
            "n_runs_both_scored": int(len(comp)),
            "passed": False,
            "worse_runs": [{"run_id": first}],
        },
        "coverage": {
            "status": "missing",
            "blocking": True,
            "tolerance_rpm": 50.0,
            "champion_speeds_rpm": [3000.0, 9000.0, 15000.0],
            "champion_source": "artefact speeds",
            "candidate_speeds_rpm": [3000.0, 9000.0],
            "candidate_source": "artefact speeds",
            "missing_speeds_rpm": [15000.0],
            "unknown_runs": [],
        },
        "input_warnings": {
            "blocking": [warning],
            "confirmed": [{**warning, "file": "2026-03-16_multi_condition.csv", "check": "sparse_channel"}],
            "not_used": [],
        },
        "data": {
            **dec["data"],
            "vanished": [
                {"file": "train_15000rpm.csv", "sha256": "cd" * 32, "why": "no longer in the raw folder"}
            ],
            "changed": [
                {"file": "train_03000rpm.csv", "sha256_champion": "ef" * 32, "sha256_now": "01" * 32}
            ],
            "renamed": [],
        },
    }
    return dec, comp


def test_registry_section_shows_relative_gate_coverage_files_and_warnings(tmp_path: Path):
    results = tmp_path / "results" / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    dec, comp = _rejected(
        json.loads((results / "registry" / "decision.json").read_text()),
        pd.read_csv(results / "registry" / "comparison.csv"),
    )
    (results / "registry" / "decision.json").write_text(json.dumps(dec))
    comp.to_csv(results / "registry" / "comparison.csv", index=False)

    g = section_registry(
        {"decision": dec, "registry_comparison": comp, "runs_csv": pd.read_csv(results / "runs.csv")}, {}
    )
    a = g["against"]
    assert a["blocked"] == ["relative_gate", "coverage", "input_warnings"]
    assert not a["relative_gate"]["passed"] and a["coverage"]["blocking"]
    assert [w["group"] for w in a["warnings"]] == ["blocking", "confirmed"]
    states = [row["state"] for row in a["relative"]]
    assert states.count("worse") == 1 and states.count("not_worse") == len(comp) - 1
    assert [r["state"] for r in a["files"]] == ["vanished", "changed"]

    _, settings = _settings()
    html = render_html(_context(results, settings, machine="tapping-center-a"))
    for text in (
        "Against the champion in service",
        "because of: relative gate, coverage, input warnings",
        "WORSE than the champion on 1 of",
        "+1.23",  # candidate - champion on the worse run
        "0.61",  # its margin
        "has no run at 15\u00a0000\u00a0r/min",
        "train_15000rpm.csv",
        "no longer in the raw folder",
        "train_03000rpm.csv",
        "NOT CONFIRMED: blocks promotion",
        '<td class="pass">confirmed</td>',
        str(escape("dz falls by 20.1 um while T1 rises by 9.8 degC (expected positive)")),
        "checks.confirmed",
    ):
        assert text in html, text


def test_a_decision_from_before_the_checks_has_no_such_part():
    dec = json.loads((FIXTURE / "registry" / "decision.json").read_text())
    g = section_registry({"decision": dec, "registry_comparison": None}, {})
    assert g["against"] is None


def test_the_champions_gates_are_its_stored_verdict(tmp_path: Path):
    """A candidate other than the champion: the champion's gates per run are decision.json's
    ``champion_verdict`` as stored (here one row no gate rule would give), the candidate's its
    ``verdict``; without ``champion_verdict`` (and without the model's rows of
    comparison/verdict.csv) the champion's gates are not stored."""
    results = tmp_path / "results" / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    path = results / "registry" / "decision.json"
    dec = json.loads(path.read_text())
    champion_rows = [dict(r) for r in dec["verdict"]]
    first = champion_rows[0]  # a passing max_residual_um row of the first run
    assert first["criterion"] == "max_residual_um" and first["passed"]
    first["passed"] = False
    dec.update(candidate_id="c" * 64, champion_id_after=dec["champion_id_before"], decision="rejected")
    dec["champion_verdict"] = champion_rows
    path.write_text(json.dumps(dec))
    _, settings = _settings()
    ctx = _context(results, settings, machine="tapping-center-a")
    g = ctx["registry"]
    runs = {r["run_id"]: r for r in g["runs"]}
    assert runs[first["run_id"]]["champion_passed"] is False
    assert runs[first["run_id"]]["champion_failed"] == ["max_residual_um"]
    assert runs[first["run_id"]]["candidate_passed"] is True
    assert g["champion"]["gates_stored"] and g["champion"]["n_failed"] >= 1
    # the verdict judges the champion kept on the machine: its stored verdict, named as such
    assert ctx["verdict"]["source"].startswith("read from registry/decision.json (champion_verdict")
    assert "FAIL: residual" in render_html(ctx)

    # without champion_verdict: the same model's rows of comparison/verdict.csv (it is model.json)
    del dec["champion_verdict"]
    path.write_text(json.dumps(dec))
    ctx = _context(results, settings, machine="tapping-center-a")
    assert ctx["verdict"]["source"] == "read from comparison/verdict.csv (rule compare's verdict)"
    assert ctx["registry"]["champion"]["gates_stored"]
    # and without that file either: not stored, not judged
    (results / "comparison" / "verdict.csv").unlink()
    ctx = _context(results, settings, machine="tapping-center-a")
    assert not ctx["registry"]["champion"]["gates_stored"] and ctx["registry"]["candidate"]["gates_stored"]
    assert {r["champion_passed"] for r in ctx["registry"]["runs"]} == {None}
    assert ctx["verdict"]["status"] == "NOT STORED"


def _interval_evidence(results: Path, half_width_um: float) -> dict:
    """``drift.interval`` as rule decide writes it (:func:`rafi.ops.drift.interval_drift`): the
    fixture champion's residuals on its new validation run with a 90 % interval of
    ``+-half_width_um`` around the prediction, one sample per 600 s, false-alarm rate 0.01."""
    resid = pd.read_parquet(results / "validation" / "residuals.parquet")
    pred = resid["predicted_um"].to_numpy(float)
    resid = resid.assign(lower_um=pred - half_width_um, upper_um=pred + half_width_um)
    block = {"level": 0.9, "decorrelation_s": 600.0}
    return interval_drift(resid, ["multi-1"], block, 0.01)


def test_the_drift_check_shows_the_interval_test_from_decision_json(tmp_path: Path):
    """decision.json with the interval drift test's evidence: the section states the thinned
    count outside the interval, the expected count at 1 - level, the p-value against the
    false-alarm rate and the verdict, every number as stored; without the evidence (the
    fixture's older decision.json, or an interval not tested) it says nothing about it."""
    results = tmp_path / "results" / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    path = results / "registry" / "decision.json"
    original = json.loads(path.read_text())
    _, settings = _settings()
    dirs = _upstream(results, settings)

    def render(dec: dict) -> tuple[dict, str]:
        path.write_text(json.dumps(dec))
        ctx = build_context(result_paths(results), dirs, machine="tapping-center-a", settings=settings)
        return ctx["registry"]["drift"], _text(render_html(ctx))

    narrow, wide = _interval_evidence(results, 2.0), _interval_evidence(results, 1e3)
    assert narrow["detected"] and narrow["k"] > narrow["expected_k"] and not wide["detected"]
    for iv in (narrow, wide):
        dec = json.loads(json.dumps(original))
        dec["drift"]["interval"] = json.loads(json.dumps(iv))  # as stored
        d, text = render(dec)
        assert d["interval"]["n"] == iv["n"] and d["interval"]["k"] == iv["k"]
        verdict = "<" if iv["detected"] else "\u2265"
        for part in (
            f"Interval check: {iv['k']} of {iv['n']} new samples lie outside the champion's 90 % interval, "
            f"{fmt_num(iv['expected_k'], 1)} expected (10 %); binomial p = {fmt_sig(iv['p_value'], 2)} "
            f"{verdict} the false-alarm rate 0.01",
            f"new samples outside the interval {iv['k']} of {iv['n']} "
            f"({fmt_num(100 * iv['k'] / iv['n'], 1, '%')}; thinned to one per 600 s of each run "
            f"from {iv['n_samples']} samples, 1 run(s))",
            f"expected outside (1 \u2212 level) 10 % of {iv['n']}: {fmt_num(iv['expected_k'], 1)}",
            f"binomial p / false-alarm rate {fmt_sig(iv['p_value'], 2)} / 0.01",
        ):
            part = re.sub(r"\s+", " ", part)  # as _text: a no-break space is a space
            assert part in text, part
        assert iv["n_samples"] == 133 and iv["n"] < iv["n_samples"]  # thinned
    # the narrow interval: tonight kept the champion, so the recalibration is due
    assert original["decision"] == "kept" and original["recalibration_due"]
    assert (
        "more often than its level allows, recalibration due."
        in render({**original, "drift": {**original["drift"], "interval": narrow}})[1]
    )
    assert "as often as the level allows, no recalibration due from this check." in text  # wide
    untested = {**original, "drift": {**original["drift"], "interval": {"status": "no_interval"}}}
    for dec in (original, untested):
        d, text = render(dec)
        assert d["interval"] is None
        assert "Interval check" not in text and "binomial p" not in text
        assert "Drift check" in text and "max residual at promotion" in text
