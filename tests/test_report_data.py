"""The report's Python builds data, the templates say it (rafi.report.format's table macro and
filters, the stored verdict of rule decide, the steps of the registry, comparison and model
sections), on small generated inputs whose truth is known."""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest

from rafi.method.paper import RMSE_UM
from rafi.method.validate import qualify
from rafi.report.comparison_section import champion_beside_rafi, rafi_failure
from rafi.report.format import fmt_value, records
from rafi.report.model_sections import coefficient_rows, diagnostics_rows
from rafi.report.render import _environment
from rafi.report.verdict import (
    NOT_STORED,
    SOURCE_CANDIDATE,
    SOURCE_CHAMPION,
    SOURCE_COMPARISON,
    comparison_verdict,
    judged_verdict,
    per_run_gates,
    rafi_verdict,
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
        ("n", "1.2\u00a0µm"),
        ("pass", "PASS"),
        ("n", "\u2013"),
        ("rowhead", "b"),
        ("n", "\u2013"),
        ("fail", "FAIL"),
        ("n", "\u22120.50"),
    ]


def test_a_number_column_never_wraps_and_a_cell_keeps_its_own_class():
    """Class ``n`` (``white-space: nowrap``) on every cell of a column of a number format or
    ``"nowrap": true``, beside the class its ``cls_key`` gives; none on a text column."""
    frame = [{"name": "prior_shared_ridge", "x": 1530.24, "p": 0.0004, "speed": 12000.0, "ok": False}]
    html = _table(
        "{% call(row, col) frame_table(frame, ["
        '{"head": "name", "key": "name"},'
        '{"head": "x", "key": "x", "fmt": "num", "cls_key": "ok", "cls_map": {false: "fail"}},'
        '{"head": "p", "key": "p", "fmt": "p"},'
        '{"head": "speed", "key": "speed", "fmt": "speed"},'
        '{"head": "range", "call": true, "nowrap": true},'
        "]) %}2 997\u201318 003 r/min{% endcall %}",
        frame=frame,
    )
    assert [c for c, _ in _cells(html)] == ["", "fail n", "n", "n", "n"]


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


def _decision(verdict: pd.DataFrame, champion: pd.DataFrame | None = None, **kw) -> dict:
    """A decision.json with ``verdict`` (and ``champion_verdict``) stored as rule decide writes it."""
    dec = {"verdict": verdict.to_dict("records"), **kw}
    if champion is not None:
        dec["champion_verdict"] = champion.to_dict("records")
    return dec


def _flipped(verdict: pd.DataFrame, run_id: str, criterion: str = "max_residual_um") -> pd.DataFrame:
    """``verdict`` with one row's ``passed`` flipped: a stored verdict no gate rule would give, so
    a test sees whether the report shows what is stored or judges again."""
    out = verdict.copy()
    row = (out["run_id"] == run_id) & (out["criterion"] == criterion)
    out.loc[row, "passed"] = ~out.loc[row, "passed"]
    return out


def _family_verdict(models: dict, gates: dict = GATES) -> pd.DataFrame:
    """comparison/verdict.csv as rule compare writes it: ``name -> (model_id, summary)``."""
    from rafi.family.compare import named_verdict, stacked_verdicts

    return stacked_verdicts(
        [named_verdict(qualify(summary, gates), name, mid) for name, (mid, summary) in models.items()]
    )


def test_both_registry_verdicts_are_read_not_recomputed():
    comp = _comparison([5.0, 13.0, 4.0], [3.0, 2.0, 1.0])
    # stored verdicts that differ from what the gates would give: the report says what is stored
    cand = _flipped(qualify(_summary([3.0, 2.0, 1.0]), GATES), "r2")
    champ = _flipped(qualify(_summary([5.0, 13.0, 4.0]), GATES), "r0")
    dec = _decision(cand, champ, candidate_id="new", champion_id_before="old", champion_id_after="new")
    res = {"decision": dec, "registry_comparison": comp}
    gates = registry_gates(res)
    assert gates["candidate"] == {"r0": (True, []), "r1": (True, []), "r2": (False, ["max_residual_um"])}
    assert gates["champion"] == {
        "r0": (False, ["max_residual_um"]),
        "r1": (False, ["max_residual_um"]),
        "r2": (True, []),
    }
    verdict, source = judged_verdict(res, dec)
    assert source == SOURCE_CANDIDATE and len(verdict) == 9 and not verdict["passed"].all()
    kept = {**dec, "champion_id_after": "old"}
    verdict, source = judged_verdict(res, kept)
    assert source == SOURCE_CHAMPION
    assert verdict.loc[verdict["run_id"] == "r0", "passed"].tolist() == [False, True, True]


def test_a_champion_without_a_stored_verdict_is_not_judged():
    """A decision.json written before champion_verdict: the champion's gates are not stored, and
    the report says so instead of judging them (a comparison/verdict.csv without the champion's
    id does not stand in for it)."""
    comp = _comparison([5.0, 13.0], [3.0, 2.0])
    dec = _decision(qualify(_summary([3.0, 2.0]), GATES), candidate_id="new", champion_id_before="old")
    family = _family_verdict({"rafi": ("new", _summary([3.0, 2.0]))})
    res = {"decision": dec, "registry_comparison": comp, "comparison_verdict": family}
    gates = registry_gates(res)
    assert gates["champion"] is None and gates["candidate"] == {"r0": (True, []), "r1": (True, [])}
    assert judged_verdict(res, {**dec, "champion_id_after": "old"}) == (None, NOT_STORED)
    # no registry/comparison.csv column for the champion: no results, nothing to store
    assert (
        registry_gates({**res, "registry_comparison": comp.drop(columns="champion_max_abs_after_um")})[
            "champion"
        ]
        == {}
    )


def test_the_stored_verdict_covers_the_runs_the_comparison_scores():
    comp = _comparison([5.0, 6.0], [3.0, np.nan])  # the candidate has no finite prediction on r1
    stored = qualify(_summary([3.0, np.nan]), GATES)
    dec = _decision(stored, candidate_id="c", champion_id_before="k", champion_id_after="c")
    assert set(stored_verdict(dec, ["r0"])["run_id"]) == {"r0"}
    assert registry_gates({"decision": dec, "registry_comparison": comp})["candidate"] == {"r0": (True, [])}
    assert stored_verdict({"decision": "kept"}) is None  # written before the verdict was stored
    assert stored_verdict(dec, key="champion_verdict") is None
    assert per_run_gates(None, ["x"]) == {"x": (True, [])}


def test_rafi_as_published_reads_the_decision_or_the_comparison():
    summary = _summary([3.0, 14.0])
    stored = qualify(_summary([3.0, 2.0]), GATES)  # differs on r1: which one is shown?
    family = _family_verdict({"rafi": ("m", summary), "ridge_global": ("g", _summary([1.0, 1.0]))})
    res = {"validation_summary": summary, "model": {"model_id": "m"}, "comparison_verdict": family}
    res["decision"] = _decision(stored, candidate_id="m", champion_id_after="m")
    verdict, source = rafi_verdict(res)
    assert source == SOURCE_CANDIDATE and verdict["passed"].all()
    res["decision"] = _decision(stored, candidate_id="other", champion_id_after="other")
    verdict, source = rafi_verdict(res)
    assert source == SOURCE_COMPARISON and len(verdict) == 6
    assert verdict["passed"].tolist() == qualify(summary, GATES)["passed"].tolist()
    # a model.json without an id: its rows by the name rafi
    verdict, source = rafi_verdict({**res, "model": {}})
    assert source == SOURCE_COMPARISON and len(verdict) == 6 and not verdict["passed"].all()
    # another model.json than the comparison's, or no comparison/verdict.csv: not stored
    assert rafi_verdict({**res, "model": {"model_id": "x"}}) == (None, NOT_STORED)
    assert rafi_verdict({**res, "comparison_verdict": None}) == (None, NOT_STORED)


def test_a_model_compared_without_gates_has_an_empty_stored_verdict():
    family = _family_verdict({"rafi": ("m", _summary([3.0]))}, gates={})
    assert list(family.columns) == ["model", "model_id", "run_id", "criterion", "limit", "measured", "passed"]
    summary = pd.DataFrame({"model": ["rafi"], "model_id": ["m"]})
    res = {"comparison_verdict": family, "comparison": summary}
    assert comparison_verdict(res, "m").empty and comparison_verdict(res, None, "rafi").empty
    assert comparison_verdict(res, "other") is None and comparison_verdict({}, "m") is None


def test_the_report_imports_no_gate_judgement():
    """rafi/report judges no gate: no module of it imports rafi.method.validate (ast over the
    package's sources, so a lazy import inside a function counts too)."""
    import ast
    from pathlib import Path

    import rafi.report

    found = []
    for path in sorted(Path(rafi.report.__file__).parent.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            found += [f"{path.name}: {n}" for n in names if n.startswith("rafi.method.validate")]
    assert found == []


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
    assert (
        f["max_speed_pct"] is None
        and f["trained_speeds"] == "trained speeds 3\u00a0000\u20139\u00a0000\u00a0r/min"
        and f["log_start"]
    )
    assert [r["outside_temp_pct"] for r in f["runs"]] == [25.0, 5.0]
    frames = {"rafi": "rafi", "passed": pd.DataFrame({"rafi": [False], "ridge": [True]})}
    beside = champion_beside_rafi(frames, "ridge", "ridge")
    assert beside == {"name": "ridge", "passes": True, "on_machine": True}
    assert champion_beside_rafi(frames, "rafi", None) is None
