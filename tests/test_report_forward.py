"""The report states the selection as it is when forward-in-time folds scored the models.

``comparison/cv.csv`` then holds rows of scheme ``forward_2`` beside the whole-run rows, and
``comparison/summary.csv`` the columns ``cv_forward_folds``, ``cv_forward_mean_max_abs_um`` and
``selection_score_um`` (the mean of the whole-run and the forward mean; the champion is its
lowest: :func:`rafi.family.selection.selection_table`). The report fixture (written before forward
folds existed, so it also stands for an old results folder) gets forward rows for every model,
listed *before* the whole-run rows, and its summary the columns the real ``selection_table``
computes from that ``cv.csv``. The forward scores are chosen so that the order by selection score
differs from the order by whole-run CV mean, while RAFI as published stays the champion (its
artefact is the fixture's ``best_model.json``): a report that sorted, scored or counted by the
whole-run columns alone, or read the scheme off the first row, fails here.
"""

from __future__ import annotations

import copy
import json
import re

import numpy as np
import pandas as pd
import pytest
import yaml
from html_tables import html_tables
from report_fixture import FIXTURE, ROOT, copy_fixture, empty_figure_dirs, write_upstream_tables
from test_report_intervals import BLOCK

from rafi.family.forward_folds import MIN_TRAIN, scheme_name
from rafi.family.selection import SELECTION_RULE, forward_rule, selection_rule, selection_table
from rafi.report.choices import section_choices
from rafi.report.comparison_section import _cv_stats, cv_schemes, selection_context, selection_score
from rafi.report.context import build_context
from rafi.report.intervals import calibration_folds, interval_context
from rafi.report.render import render_html
from rafi.settings import machine_settings

CONFIG = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))
FORWARD = scheme_name(2)
#: Max |residual| of each held-out run of the two forward folds (fold 0: runs 4-5, fold 1: 5-6).
AHEAD = {
    "rafi": [1.0, 1.2, 1.1, 1.3],
    "rafi_linear": [4.0, 4.5, 4.2, 4.4],
    "ridge_global": [1.5, 1.6, 1.4, 1.5],
    "dynamic": [2.0, 2.0, 2.0, 2.0],
}
CAL_SCHEME = f"leave_one_run_out+{FORWARD}"


def _forward_rows(cv: pd.DataFrame) -> pd.DataFrame:
    """Forward folds of the fixture's six training runs (origins after runs 3 and 4, two runs
    held out each), with the max |residual|s of :data:`AHEAD`."""
    runs = list(dict.fromkeys(cv["test_runs"]))
    rows = []
    for name, after in AHEAD.items():
        k = 0
        for fold, origin in enumerate(range(MIN_TRAIN, len(runs) - 1)):
            for rid in runs[origin : origin + 2]:
                rows.append(
                    {
                        "model": name,
                        "scheme": FORWARD,
                        "fold": fold,
                        "test_runs": rid,
                        "n_train_runs": origin,
                        "n_samples": 120,
                        "max_abs_before_um": 10.0,
                        "max_abs_after_um": after[k],
                        "improvement_pct": 100 * (1 - after[k] / 10.0),
                        "rmse_um": after[k] / 2,
                    }
                )
                k += 1
    return pd.DataFrame(rows, columns=cv.columns)


def _with_forward(results, *, interval: bool = True) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The fixture's comparison with forward folds, as rule compare writes it: forward rows in
    ``cv.csv`` (first: the report must not depend on the order), the selection columns of the
    real selection table in ``summary.csv`` and, with ``interval``, an interval calibrated on
    both kinds of folds in ``best_model.json``."""
    comp = results / "comparison"
    whole = pd.read_csv(comp / "cv.csv")
    cv = pd.concat([_forward_rows(whole), whole], ignore_index=True)
    cv.to_csv(comp / "cv.csv", index=False)
    table = selection_table(cv).set_index("model")
    summ = pd.read_csv(comp / "summary.csv")
    for col in table.columns:
        summ[col] = summ["model"].map(table[col])
    assert table.index[0] == "rafi" and summ.loc[summ["champion"], "model"].tolist() == ["rafi"]
    summ.to_csv(comp / "summary.csv", index=False)
    if interval:
        best = json.loads((comp / "best_model.json").read_text(encoding="utf-8"))
        best["interval"] = copy.deepcopy(BLOCK)
        best["interval"]["calibration"]["scheme"] = CAL_SCHEME
        best["interval"]["calibration"]["left_out"] = "run"
        (comp / "best_model.json").write_text(json.dumps(best), encoding="utf-8")
    return summ, cv


def _render(tmp_path, *, forward: bool):
    results = copy_fixture(tmp_path)
    summ, cv = _with_forward(results) if forward else (None, None)
    paths = write_upstream_tables(results)
    settings = machine_settings(CONFIG, "tapping-center-a")
    ctx = build_context(paths, empty_figure_dirs(results), machine="tapping-center-a", settings=settings)
    return ctx, render_html(ctx), summ, cv


def _text(html: str) -> str:
    text = re.sub(r"<[^>]+>", " ", html).replace("&#39;", "'").replace("&amp;", "&")
    return " ".join(text.split())


def _num(text: str) -> float:
    return float(text.split()[0])


@pytest.fixture(scope="module")
def forward(tmp_path_factory):
    return _render(tmp_path_factory.mktemp("forward"), forward=True)


# ------------------------------------------------------------------- the section functions
def test_whole_run_folds_are_counted_apart_from_forward_folds(tmp_path):
    summ, cv = _with_forward(copy_fixture(tmp_path), interval=False)
    stats = _cv_stats(cv)
    assert set(stats) == set(AHEAD)
    for s in stats.values():
        assert (s["folds"], s["held_out"], s["scheme"]) == (6, 6, "leave_one_run_out")
        forward = (s["forward_folds"], s["forward_held_out"], s["forward_scheme"], s["horizon"])
        assert forward == (2, 4, FORWARD, 2)
    assert cv_schemes(cv) == ("leave_one_run_out", FORWARD)  # the first row is a forward one
    assert cv_schemes(cv[cv["scheme"] != FORWARD]) == ("leave_one_run_out", "")


def test_the_selection_context_scores_by_the_selection_score(tmp_path):
    summ, cv = _with_forward(copy_fixture(tmp_path), interval=False)
    sel = selection_context(summ, "rafi", *cv_schemes(cv))
    assert sel["rule"] == selection_rule("leave_one_run_out", FORWARD)
    assert sel["rule"].endswith(forward_rule(2)) and sel["horizon"] == 2
    row = summ.set_index("model").loc["rafi"]
    assert sel["score"] == pytest.approx(row["selection_score_um"])
    assert sel["score"] == pytest.approx((row["cv_mean_max_abs_um"] + np.mean(AHEAD["rafi"])) / 2)
    assert sel["whole_score"] == pytest.approx(row["cv_mean_max_abs_um"])
    assert sel["forward_score"] == pytest.approx(np.mean(AHEAD["rafi"]))
    # a summary.csv from before the forward folds: its whole-run mean was the score
    old = summ.drop(columns=["selection_score_um", "cv_forward_folds", "cv_forward_mean_max_abs_um"])
    sel = selection_context(old, "rafi", "leave_one_run_out")
    assert sel["rule"] == SELECTION_RULE and sel["horizon"] == 0 and sel["forward_score"] is None
    assert sel["score"] == pytest.approx(row["cv_mean_max_abs_um"])
    assert selection_score(old.iloc[0]) == old["cv_mean_max_abs_um"].iloc[0]


def test_the_calibration_folds_read_as_words():
    assert calibration_folds(CAL_SCHEME) == ("leave-one-run-out and forward folds, 2 runs ahead", 2)
    assert calibration_folds("leave_one_run_out+forward_1") == (
        "leave-one-run-out and forward folds, the next run",
        1,
    )
    assert calibration_folds("leave_one_run_out") == ("leave-one-run-out", 0)
    assert calibration_folds("time_blocks") == ("time-blocks", 0)
    assert calibration_folds("") == ("", 0)
    block = copy.deepcopy(BLOCK)
    block["calibration"]["scheme"] = CAL_SCHEME
    iv = interval_context({"interval": block})
    assert iv["scheme"] == "leave-one-run-out and forward folds, 2 runs ahead" and iv["forward"] == 2
    assert "_" not in iv["scheme"] and "+" not in iv["scheme"]
    assert not iv["by_run"]  # an artefact calibrated unit by unit (before 2026-11-26) says nothing
    block["calibration"]["left_out"] = "run"
    iv = interval_context({"interval": block})
    assert iv["by_run"] and "left out" not in dict(iv["other"])


def test_the_choices_say_what_chose():
    # without a comparison in the results the section states the rule of models.offer: here best
    # (an offered ensemble, and the rule as applied: tests/test_report_choices_applied.py)
    settings = machine_settings({"machines": {"m": {"models": {"offer": "best"}}}}, "m")
    from test_report_text import _section

    def said(**kw):
        return _text(_section("choices", choices=section_choices(settings, {}, None, **kw)))

    text = said(forward=2)
    assert "is the one with the lowest selection score: the mean of its mean held-out max |residual|" in text
    assert "scored on the next 2 runs" in text
    text = said()
    assert "is the one with the lowest mean held-out max |residual| in that cross-validation" in text
    assert "forward" not in text


# ------------------------------------------------------------------- the whole report
def test_the_comparison_table_shows_the_score_that_chose_and_both_parts(forward):
    ctx, html, summ, cv = forward
    table = next(t for t in html_tables(html, "num models"))
    assert len(table["widths"]) == len(table["headers"]) and sum(table["widths"]) <= 100
    choice = next(h for h in table["headers"] if "the choice" in h)
    whole = next(h for h in table["headers"] if h.startswith("whole-run CV: mean"))
    ahead = next(h for h in table["headers"] if h.startswith("forward CV"))
    assert choice.startswith("selection score") and "the next 2 runs" in ahead
    by_model = summ.set_index("model")
    for rec in table["records"]:
        row = by_model.loc[rec["model"].split()[0]]
        assert _num(rec[choice]) == pytest.approx(row["selection_score_um"], abs=0.005)
        assert _num(rec[whole]) == pytest.approx(row["cv_mean_max_abs_um"], abs=0.005)
        assert _num(rec[ahead]) == pytest.approx(row["cv_forward_mean_max_abs_um"], abs=0.005)
    text = _text(html)
    assert selection_rule("leave_one_run_out", FORWARD) in text
    assert "(6 folds per model;" in text and "(2 folds per model, 4 held-out runs)" in text
    r = by_model.loc["rafi"]
    assert (
        f"Champion: rafi (selection score {r['selection_score_um']:.2f} µm: the mean of its whole-run CV "
        f"mean max |residual| {r['cv_mean_max_abs_um']:.2f} µm and its forward CV mean max |residual| "
        f"{r['cv_forward_mean_max_abs_um']:.2f} µm" in text
    )


def test_the_verdict_line_names_the_score_that_chose(forward):
    ctx, html, summ, cv = forward
    r = summ.set_index("model").loc["rafi"]
    text = _text(html)
    assert (
        f"chosen by whole-run and forward-in-time CV on the training runs only (selection score "
        f"{r['selection_score_um']:.2f} µm" in text
    )
    assert "the validation runs were touched once, after the choice" in text


def test_the_deployed_section_ranks_by_the_selection_score_and_lists_both_folds(forward):
    ctx, html, summ, cv = forward
    d = ctx["deployed"]["cv"]
    order = summ[summ["model"] != "rafi"].sort_values("selection_score_um")["model"].tolist()
    assert [r["model"] for r in d["beaten"]] == order
    assert order != summ[summ["model"] != "rafi"].sort_values("cv_mean_max_abs_um")["model"].tolist()
    assert d["scheme"] == "leave-one-run-out" and d["horizon"] == 2 and d["n_forward_folds"] == 2
    mine = cv[cv["model"] == "rafi"]
    assert [f["test_runs"] for f in d["folds"]] == mine.loc[mine["scheme"] != FORWARD, "test_runs"].tolist()
    assert [f["max_abs_after_um"] for f in d["forward_folds"]] == AHEAD["rafi"]
    assert d["score"].startswith(f"{summ.set_index('model').loc['rafi', 'selection_score_um']:.2f}")
    sec = html[html.index('id="sec-deployed"') :]
    sec = sec[: sec.index("</section>")]
    beaten = next(t for t in html_tables(sec) if t["headers"][0] == "candidate")
    assert [r["candidate"] for r in beaten["records"]] == order
    assert {"selection score (µm)", "forward CV mean max |res.| (µm)"} <= set(beaten["headers"])
    folds = next(t for t in html_tables(sec) if t["headers"][0] == "forward fold")
    assert len(folds["records"]) == 4 and len(folds["widths"]) == len(folds["headers"])
    text = _text(sec)
    assert "by nested leave-one-run-out cross-validation on the training runs" in text
    assert "forward-2" not in text
    # the interval: calibrated on both kinds of folds, said in words
    assert "in the cross-validation (leave-one-run-out and forward folds, 2 runs ahead)" in text
    assert "held-out runs, a run held out by several forward folds counted once per fold" in text
    assert "correction of the level is measured leaving out each run with all its units" in text
    choices = _text(html[html.index('id="sec-choices"') :])
    assert "is the one with the lowest selection score" in choices
    assert "in the cross-validation (whole-run and forward folds)" in choices


def test_without_forward_folds_the_report_reads_as_before(tmp_path):
    ctx, html, _, _ = _render(tmp_path, forward=False)
    summ = pd.read_csv(FIXTURE / "comparison" / "summary.csv")
    table = next(t for t in html_tables(html, "num models"))
    assert len(table["widths"]) == len(table["headers"])
    assert not any("forward" in h or "selection score" in h for h in table["headers"])
    choice = next(h for h in table["headers"] if "the choice" in h)
    assert choice == "CV mean max |res.| (µm): the choice"
    for rec in table["records"]:
        want = summ.loc[summ["model"] == rec["model"].split()[0], "cv_mean_max_abs_um"].iloc[0]
        assert _num(rec[choice]) == pytest.approx(want, abs=0.005)
    for sec in ("sec-verdict", "sec-comparison", "sec-deployed", "sec-choices"):
        part = html[html.index(f'id="{sec}"') :]
        text = _text(part[: part.index("</section>")])
        assert "forward" not in text and "selection score" not in text, sec
    assert ctx["comparison"]["selection"]["horizon"] == 0 and ctx["deployed"]["cv"]["forward_folds"] is None


def test_the_choices_say_how_the_interval_widens_beyond_the_trained_range():
    """The widening is a choice the paper leaves open: said as the block was calibrated - not at
    all without a slope, with the key sensors and the speed, and with the components since
    2026-11-30 (``component_excess``)."""
    import html

    from test_report_text import _section

    settings = machine_settings({"machines": {"m": {}}}, "m")

    def said(block):
        iv = interval_context({"interval": block})
        return html.unescape(
            _text(_section("choices", choices=section_choices(settings, {}, None, interval=iv)))
        )

    before = said(copy.deepcopy(BLOCK))
    assert "Each compensation comes with a 90" in before and "grows with the distance" not in before
    keys = said({**copy.deepcopy(BLOCK), "excess_slope": 10.0})
    assert "Beyond the trained range it grows with the distance, h × (1 + 10 × excess)" in keys
    assert "in training spans." in keys and "principal components" not in keys
    both = said({**copy.deepcopy(BLOCK), "excess_slope": 10.0, "component_excess": True})
    assert "beyond the combinations of features the model was trained on (its features' principal" in both
    assert interval_context({"interval": {**BLOCK, "excess_slope": 10.0}})["components"] is False
