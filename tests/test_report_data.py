"""The report's Python builds data, the templates say it (rafi.report.format's table macro and
filters, the stored verdict of rule decide, the steps of the registry, comparison and model
sections), on small generated inputs whose truth is known."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest

from rafi.method.paper import RMSE_UM
from rafi.report.comparison_section import champion_beside_rafi, rafi_failure
from rafi.report.format import fmt_value, records
from rafi.report.model_sections import coefficient_rows, diagnostics_rows
from rafi.report.render import _environment
from rafi.report.verdict import (
    judged_verdict,
    per_run_gates,
    rafi_verdict,
    recomputed_verdict,
    registry_gates,
    stored_verdict,
)

GATES = {"max_residual_um": 12.0, "min_improvement_pct": 30.0, "never_worse_than_uncompensated": True}


def _table(template: str, **ctx) -> str:
    """``template`` (Jinja source importing frame_table) rendered with the report's environment."""
    source = '{% from "macros.html.j2" import frame_table %}' + template
    return _environment().from_string(source).render(**ctx)


def _cells(html: str) -> list[tuple[str, str]]:
    """``(class, text)`` of every body cell."""
    return re.findall(r'<td(?: class="([^"]*)")?>(.*?)</td>', html, flags=re.S)


# --------------------------------------------------------------------------- the table macro


def test_frame_table_formats_and_classes_each_column():
    frame = [
        {"run_id": "a_1#2", "after": 1.234, "passed": True, "worse": None},
        {"run_id": "b", "after": None, "passed": False, "worse": -0.5},
    ]
    html = _table(
        "{% call(row, col) frame_table(frame, ["
        '{"head": "run", "key": "run_id", "fmt": "run", "cls": "rowhead"},'
        '{"head": "after (µm)", "key": "after", "fmt": "num", "digits": 1, "unit": "µm"},'
        '{"head": "gate", "call": true, "cls_key": "passed", "cls_map": {true: "pass", false: "fail"}},'
        '{"head": "change", "key": "worse", "fmt": "num", "signed": true},'
        '], cls="num", widths=[40, 20, 20, 20]) %}{{ "PASS" if row.passed else "FAIL" }}{% endcall %}',
        frame=frame,
    )
    assert '<table class="num">' in html and html.count("<col ") == 4
    assert re.findall(r"<th>(.*?)</th>", html) == ["run", "after (µm)", "gate", "change"]
    assert _cells(html) == [
        ("rowhead", "a_<wbr>1<wbr>#2"),
        ("", "1.2\u00a0µm"),
        ("pass", "PASS"),
        ("", "\u2013"),
        ("rowhead", "b"),
        ("", "\u2013"),
        ("fail", "FAIL"),
        ("", "\u22120.50"),
    ]


def test_frame_table_without_a_frame_is_nothing_and_without_rows_its_headers():
    template = '{{ frame_table(frame, [{"head": "x", "key": "x"}]) }}'
    assert "<table" not in _table(template, frame=None)
    empty = _table(template, frame=[])
    assert "<th>x</th>" in empty and "<td" not in empty


def test_frame_table_class_from_the_row_and_escaping():
    html = _table(
        '{{ frame_table(frame, [{"head": "x", "key": "x", "cls_key": "state"}]) }}',
        frame=[{"x": "<b>", "state": "fail"}, {"x": "ok"}],
    )
    assert _cells(html) == [("fail", "&lt;b&gt;"), ("", "ok")]  # a row without the field: no class


def test_fmt_value_and_records():
    assert fmt_value(None) == "\u2013" and fmt_value("text") == "text"
    assert fmt_value(3000, "speed") == "3\u00a0000\u00a0r/min" and fmt_value(0.0004, "p") == "<\u00a00.001"
    assert fmt_value(0.012345, "sig", 3) == "0.0123"
    assert fmt_value(-2e-6, "sig", 2) == "\u22122.0\u00d710\u207b\u2076"
    assert fmt_value("abcdef0123456789", "short_id") == "abcdef012345"
    with pytest.raises(ValueError, match="unknown format"):
        fmt_value(1, "nope")
    frame = pd.DataFrame({"a": [1, 2], "b": [np.nan, 0.5]})
    assert records(frame) == [{"a": 1, "b": None}, {"a": 2, "b": 0.5}]
    assert records(frame, {"bee": "b"}) == [{"bee": None}, {"bee": 0.5}]
    assert type(records(frame)[0]["a"]) is int


# --------------------------------------------------------------------------- the stored verdict


def _summary(after: list[float], before: float = 20.0) -> pd.DataFrame:
    """A validation summary of runs r0, r1, ... with the max |residual| ``after``."""
    return pd.DataFrame(
        {
            "run_id": [f"r{k}" for k in range(len(after))],
            "role": "validation_single",
            "max_abs_before_um": before,
            "max_abs_after_um": after,
            "improvement_pct": [100 * (1 - a / before) for a in after],
        }
    )


def _comparison(champion: list[float], candidate: list[float]) -> pd.DataFrame:
    """registry/comparison.csv of runs r0, r1, ... (before 20 um)."""
    return pd.DataFrame(
        {
            "run_id": [f"r{k}" for k in range(len(champion))],
            "role": "validation_single",
            "max_abs_before_um": 20.0,
            "champion_max_abs_after_um": champion,
            "champion_improvement_pct": [100 * (1 - a / 20.0) for a in champion],
            "candidate_max_abs_after_um": candidate,
            "candidate_improvement_pct": [100 * (1 - a / 20.0) for a in candidate],
        }
    )


def _decision(verdict: pd.DataFrame, **kw) -> dict:
    """A decision.json with ``verdict`` stored as rule decide writes it."""
    return {"verdict": verdict.to_dict("records"), **kw}


def test_the_candidates_verdict_is_read_not_recomputed():
    comp = _comparison([5.0, 13.0, 4.0], [3.0, 2.0, 1.0])
    # a stored verdict that differs from what the gates would give: the report says what is stored
    stored = recomputed_verdict(_summary([3.0, 2.0, 1.0]), GATES)
    stored.loc[(stored["run_id"] == "r2") & (stored["criterion"] == "max_residual_um"), "passed"] = False
    dec = _decision(stored, candidate_id="new", champion_id_before="old", champion_id_after="new")
    gates = registry_gates(dec, comp, GATES)
    assert gates["candidate"] == {"r0": (True, []), "r1": (True, []), "r2": (False, ["max_residual_um"])}
    # no file stores the champion's verdict: recomputed from its results
    assert gates["champion"] == {"r0": (True, []), "r1": (False, ["max_residual_um"]), "r2": (True, [])}
    verdict, source = judged_verdict({"registry_comparison": comp}, dec, GATES)
    assert source.startswith("read from registry/decision.json") and len(verdict) == 9
    assert not verdict["passed"].all()
    kept = {**dec, "champion_id_after": "old"}
    verdict, source = judged_verdict({"registry_comparison": comp}, kept, GATES)
    assert source == "computed from registry/comparison.csv (champion columns)"
    assert verdict.loc[verdict["run_id"] == "r1", "passed"].tolist() == [False, True, True]


def test_the_stored_verdict_covers_the_runs_the_comparison_scores():
    comp = _comparison([5.0, 6.0], [3.0, np.nan])  # the candidate has no finite prediction on r1
    stored = recomputed_verdict(_summary([3.0, np.nan]), GATES)
    dec = _decision(stored, candidate_id="c", champion_id_before="k", champion_id_after="c")
    assert set(stored_verdict(dec, ["r0"])["run_id"]) == {"r0"}
    assert registry_gates(dec, comp, GATES)["candidate"] == {"r0": (True, [])}
    assert stored_verdict({"decision": "kept"}) is None  # written before the verdict was stored
    assert per_run_gates(None, ["x"]) == {"x": (True, [])}


def test_rafi_as_published_reads_the_decision_when_it_was_the_candidate():
    summary = _summary([3.0, 14.0])
    stored = recomputed_verdict(_summary([3.0, 2.0]), GATES)  # differs on r1: which one is shown?
    res = {"validation_summary": summary, "model": {"model_id": "m"}}
    res["decision"] = _decision(stored, candidate_id="m", champion_id_after="m")
    verdict, source = rafi_verdict(res, GATES)
    assert source.startswith("read from") and verdict["passed"].all()
    res["decision"] = _decision(stored, candidate_id="other", champion_id_after="other")
    verdict, source = rafi_verdict(res, GATES)
    assert source == "from rafi.method.validate.qualify" and not verdict["passed"].all()


# --------------------------------------------------------------------------- section steps


def test_a_recomputed_rmse_that_differs_is_flagged():
    diag = pd.DataFrame({"speed_rpm": [3000.0, 6000.0], "n": [100, 100], "rmse_um": [0.50, 0.40]})
    check = pd.DataFrame({"speed_rpm": [3000, 6000], "rmse_um": [0.505, 0.60]})  # 1 % and 50 % off
    rows, mismatches = diagnostics_rows(diag, check)
    assert [r["speed_rpm"] for r in rows] == [3000, 6000] and rows[0]["paper_rmse_um"] == RMSE_UM[3000]
    assert mismatches == [{"speed_rpm": 6000, "table_um": 0.40, "recomputed_um": 0.60}]
    assert diagnostics_rows(None, check) == ([], [])


def test_coefficients_by_term_and_speed():
    coefs = pd.DataFrame(
        {
            "speed_rpm": [3000.0, 3000.0, 6000.0],
            "term": ["1", "x1", "1"],
            "coef": [0.1, 1.5, 0.2],
            "se_hac": [0.01, 0.1, 0.02],
            "p_hac": [0.5, 1e-5, 0.2],
        }
    )
    speeds, rows = coefficient_rows(coefs, ["1", "x1"])
    assert speeds == [3000, 6000]
    assert rows[1]["term"] == "x1" and rows[1]["by_speed"][6000] is None  # no x1 at 6000 r/min
    assert rows[1]["by_speed"][3000] == {"coef": 1.5, "se_hac": 0.1, "p_hac": 1e-5}
    assert coefficient_rows(None, ["1"]) == ([], None)


def test_why_rafi_fails_is_computed_from_the_runs():
    bad = pd.DataFrame(
        {
            "run_id": ["a", "b"],
            "max_abs_after_um": [14.0, 13.0],
            "noise_floor_um": [0.6, 0.7],
            "n_samples": [200, 100],
            "n_outside_temp_range": [50, 5],  # 25 % and 5 %
            "n_outside_speed_range": [0, 0],
        }
    )
    res = {"model": {"speeds": [{"speed_rpm": 3000}, {"speed_rpm": 9000}]}}
    f = rafi_failure(bad, res, {"reference": {"rule": "log_start"}})
    assert (f["n"], f["n_extrapolated"], f["max_temp_pct"]) == (2, 1, 25.0)
    assert f["max_speed_pct"] is None and f["trained_speeds"] == [3000.0, 9000.0] and f["log_start"]
    assert [r["outside_temp_pct"] for r in f["runs"]] == [25.0, 5.0]
    frames = {"rafi": "rafi", "passed": pd.DataFrame({"rafi": [False], "ridge": [True]})}
    beside = champion_beside_rafi(frames, "ridge", "ridge")
    assert beside == {"name": "ridge", "passes": True, "on_machine": True}
    assert champion_beside_rafi(frames, "rafi", None) is None
