"""The report's re-qualification section (issue 27): what qualified a model that started from a prior.

The report fixture is rendered as it is (no prior was a candidate: no section) and with the
adaptation candidates added the way rule compare writes them (``docs/models.md``,
"Re-qualification from a prior"): rows ``prior``, ``prior_gain`` and ``prior_ridge`` in
``comparison/summary.csv`` (the ``kind`` column is the prior's kind) and, when an adapted prior
is offered, its ``adaptation`` block in ``comparison/best_model.json``. Every number the section
shows is checked against those files, the coefficient moves against numpy on the same block.
"""

from __future__ import annotations

import html
import json
import re

import numpy as np
import pandas as pd
import pytest
import yaml
from html_tables import html_tables
from report_fixture import ROOT, copy_fixture, empty_figure_dirs, write_upstream_tables

from rafi.report.context import build_context
from rafi.report.render import render_html
from rafi.report.requalification_section import coefficient_moves, new_data
from rafi.settings import machine_settings

CONFIG = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))
PARENT = "ab" * 32
CHANGE = [
    {"name": "T1 rise", "prior": 2.0, "new": 2.5},
    {"name": "T2 rise", "prior": -1.0, "new": -1.0},
    {"name": "T3 L900", "prior": 0.5, "new": -0.25},
    {"name": "n^2", "prior": 0.0, "new": 0.1},
]


def _add_candidates(results, *, offered: str) -> pd.DataFrame:
    """Rows prior, prior_gain, prior_ridge beside the fixture's models; ``offered`` is the champion."""
    path = results / "comparison" / "summary.csv"
    summ = pd.read_csv(path)
    base = summ[summ["champion"]].iloc[0]
    extra = []
    for k, name in enumerate(("prior", "prior_gain", "prior_ridge")):
        row = base.copy()
        row["model"], row["kind"] = name, "dynamic"
        row["max_abs_after_um"] = 3.0 - k
        row["cv_mean_max_abs_um"] = 1.4 - 0.2 * k
        row["model_id"] = f"{k}" * 64
        extra.append(row)
    summ = pd.concat([summ, pd.DataFrame(extra)], ignore_index=True)
    summ["champion"] = summ["model"] == offered
    summ.to_csv(path, index=False)
    if offered in ("prior_gain", "prior_ridge"):
        best_path = results / "comparison" / "best_model.json"
        best = json.loads(best_path.read_text(encoding="utf-8"))
        best["adaptation"] = {
            "schema": "rafi.adaptation/1",
            "method": "ridge" if offered == "prior_ridge" else "gain",
            "parent": PARENT,
            "parent_machine": "tapping-center-a",
            "gain": None if offered == "prior_ridge" else 1.25,
            "alpha": 3.0 if offered == "prior_ridge" else None,
            "prior_data": {"old.csv": "cd" * 32},
            "coefficient_change": CHANGE,
        }
        best_path.write_text(json.dumps(best), encoding="utf-8")
    return summ


def _context(results):
    """The report's context of the results folder ``results`` (its upstream tables written)."""
    paths = write_upstream_tables(results)
    return build_context(
        paths,
        empty_figure_dirs(results),
        machine="tapping-center-a",
        settings=machine_settings(CONFIG, "tapping-center-a"),
    )


def _render(tmp, offered: str | None):
    results = copy_fixture(tmp)
    summ = _add_candidates(results, offered=offered) if offered else None
    ctx = _context(results)
    return ctx, render_html(ctx), summ, results


def _text(html: str) -> str:
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html))


def test_without_a_prior_there_is_no_section(tmp_path):
    ctx, html, _, _ = _render(tmp_path, None)
    assert ctx["requalification"] is None
    assert "sec-requalification" not in html and "Re-qualification from a prior" not in html


@pytest.mark.parametrize("offered", ["prior_ridge", "prior_gain"])
def test_the_section_states_the_prior_the_moves_and_the_comparison_from_the_tables(tmp_path, offered):
    ctx, html, summ, results = _render(tmp_path, offered)
    q = ctx["requalification"]
    ids = [s["id"] for s in ctx["sections"]]
    assert ids.index("verdict") < ids.index("requalification") < ids.index("data")
    assert q["parent"] == PARENT[:12] and f"<code>{PARENT[:12]}</code>" in html
    # the comparison table: one row per model of summary.csv, numbers as the table has them
    table = next(t for t in html_tables(html) if any("what it is" in h for h in t["headers"]))
    assert sorted(r["model"] for r in table["records"]) == sorted(summ["model"])
    worst = next(h for h in table["headers"] if "worst validation" in h)
    for rec in table["records"]:
        want = summ.loc[summ["model"] == rec["model"], "max_abs_after_um"].iloc[0]
        assert float(rec[worst]) == pytest.approx(want, abs=0.005)
    assert [r["model"] for r in table["records"] if r["offered"] == "offered"] == [offered]
    # the sentence: the offered model beside the prior unchanged and the best from scratch by CV
    scratch = summ[~summ["model"].isin(["prior", "prior_gain", "prior_ridge"])]
    best_scratch = scratch.loc[scratch["cv_mean_max_abs_um"].idxmin()]
    text = _text(html)
    offered_worst = summ.loc[summ["model"] == offered, "max_abs_after_um"].iloc[0]
    assert f"The offered model ({offered}) is within {offered_worst:.2f} \u00b5m" in text
    assert f"the prior unchanged {3.0:.2f} \u00b5m" in text
    assert f"({best_scratch['model']}) {best_scratch['max_abs_after_um']:.2f} \u00b5m" in text
    # the moves, against numpy on the same block
    prior = np.array([c["prior"] for c in CHANGE])
    new = np.array([c["new"] for c in CHANGE])
    moves = q["moves"]
    assert moves["n"] == 4 and moves["n_moved"] == int(np.sum(new != prior))
    rel = np.abs((new - prior)[prior != 0] / prior[prior != 0])
    assert moves["median_relative"] == pytest.approx(np.median(rel))
    assert moves["max_relative"] == pytest.approx(rel.max())
    assert [r["name"] for r in moves["rows"]] == [
        CHANGE[i]["name"] for i in np.argsort(-np.abs(new - prior), kind="stable")
    ]
    # the new data: the training runs of runs.csv
    runs = pd.read_csv(results / "runs.csv")
    tr = runs[runs["role"] == "training"]
    assert q["new_data"]["runs"] == len(tr)
    assert q["new_data"]["hours"] == pytest.approx(tr["duration_s"].sum() / 3600)


def test_with_an_ensemble_prior_the_member_candidates_are_named_as_its_heaviest_member(tmp_path):
    results = copy_fixture(tmp_path)
    summ = _add_candidates(results, offered="rafi")
    shared = summ[summ["model"] == "prior_gain"].assign(model="prior_shared_ridge", kind="ensemble")
    summ = pd.concat([summ, shared], ignore_index=True)
    summ.to_csv(results / "comparison" / "summary.csv", index=False)
    ctx = _context(results)
    rows = {r["model"]: r for r in ctx["requalification"]["rows"]}
    assert (
        rows["prior"]["member"] and rows["prior_gain"]["member"] and not rows["prior_shared_ridge"]["member"]
    )
    assert (
        rows["prior"]["what"] == "the ensemble prior's heaviest member (dynamic) as it is (nothing re-fitted)"
    )
    assert rows["prior_shared_ridge"]["what"].startswith("the ensemble prior as a whole")
    text = html.unescape(_text(render_html(ctx)))
    assert (
        "the ensemble prior's heaviest member alone (dynamic, the candidate prior) "
        f"unchanged {3.0:.2f} \u00b5m" in text
    )
    assert "the prior unchanged" not in text


def test_an_offered_model_from_scratch_says_the_prior_lost(tmp_path):
    ctx, html, summ, _ = _render(tmp_path, "rafi")
    q = ctx["requalification"]
    assert q["adaptation"] is None and q["moves"] is None
    assert "CV ranked rafi ahead of every candidate that starts from the prior" in _text(html)


def test_coefficient_moves_and_new_data_handle_what_is_missing():
    assert coefficient_moves(None) is None and coefficient_moves([]) is None
    assert coefficient_moves([{"name": "a"}]) is None
    only_zero = coefficient_moves([{"name": "a", "prior": 0.0, "new": 1.0}])
    assert only_zero["median_relative"] is None and only_zero["n_moved"] == 1
    assert new_data(None) is None
    assert (
        new_data(pd.DataFrame({"role": ["validation_single"], "duration_s": [1.0], "speed_rpm": [1.0]}))
        is None
    )


def test_without_a_cv_fold_the_section_says_the_default_rule_chose(tmp_path):
    results = copy_fixture(tmp_path)
    summ = _add_candidates(results, offered="prior_gain")
    summ["cv_mean_max_abs_um"] = np.nan  # one heat-up of new data: no whole-run fold
    summ.to_csv(results / "comparison" / "summary.csv", index=False)
    ctx = _context(results)
    q = ctx["requalification"]
    assert (
        q["cv"] is False and q["scratch"]["model"] == "rafi"
    )  # the default rule among the from-scratch kinds
    text = _text(render_html(ctx))
    assert "give no whole-run cross-validation fold, so the default rule chose" in text
    assert "Whole-run cross-validation on the new training runs chose" not in text


def test_with_forward_folds_the_section_compares_by_the_selection_score(tmp_path):
    """The from-scratch model the selection takes is the lowest selection score (whole-run and
    forward mean), not the lowest whole-run mean; both parts are shown beside it."""
    results = copy_fixture(tmp_path)
    summ = _add_candidates(results, offered="prior_gain")
    ahead = {"rafi": 5.0, "rafi_linear": 1.0, "ridge_global": 3.0, "dynamic": 3.5}
    summ["cv_forward_folds"] = 2
    summ["cv_forward_mean_max_abs_um"] = summ["model"].map(ahead).fillna(summ["cv_mean_max_abs_um"])
    summ["selection_score_um"] = (summ["cv_mean_max_abs_um"] + summ["cv_forward_mean_max_abs_um"]) / 2
    summ.to_csv(results / "comparison" / "summary.csv", index=False)
    scratch = summ[summ["model"].isin(list(ahead))]
    assert scratch.loc[scratch["cv_mean_max_abs_um"].idxmin(), "model"] == "rafi"  # not what chooses
    ctx = _context(results)
    q = ctx["requalification"]
    assert q["forward"] is True and q["scratch"]["model"] == "rafi_linear"
    html = render_html(ctx)
    table = next(t for t in html_tables(html) if any("what it is" in h for h in t["headers"]))
    assert len(table["widths"]) == len(table["headers"])
    score = next(h for h in table["headers"] if h.startswith("selection score"))
    whole = next(h for h in table["headers"] if h.startswith("whole-run CV"))
    fwd = next(h for h in table["headers"] if h.startswith("forward CV"))
    for rec in table["records"]:
        row = summ[summ["model"] == rec["model"]].iloc[0]
        assert float(rec[score]) == pytest.approx(row["selection_score_um"], abs=0.005)
        assert float(rec[whole]) == pytest.approx(row["cv_mean_max_abs_um"], abs=0.005)
        assert float(rec[fwd]) == pytest.approx(row["cv_forward_mean_max_abs_um"], abs=0.005)
    text = _text(html)
    assert "Whole-run cross-validation and forward-in-time folds on the new training runs chose" in text
    assert "the from-scratch fit the selection takes on the same data (rafi_linear)" in text


def test_the_section_names_the_priors_machine_its_qualification_and_fitness(tmp_path):
    """The fitness block (rafi.family.prior_fitness, from known inputs) as the section states it."""
    from rafi.family.prior_fitness import fitness_block

    results = copy_fixture(tmp_path)
    _add_candidates(results, offered="prior_gain")
    prior = {
        "model_id": PARENT,
        "machine": "tapping-center-a",
        "kind": "dynamic",
        "speed_range_rpm": [0.0, 18000.0],
        "regressor_ranges": {"T1": [0.0, 9.0]},
        # itself re-qualified from an older model that alone knew 18000 r/min
        "adaptation": {
            "fitness": {
                "speeds_prior_only_rpm": [18000.0],
                "prior": {"model_id": "b" * 64, "machine": "mill"},
            }
        },
    }
    qualification = {"promoted": "2026-11-01T02:03:04Z", "max_residual_um": 1.234, "n_runs": 3}
    qualification["speeds_rpm"] = [3000, 9000, 18000]
    block = fitness_block(
        prior,
        qualification=qualification,
        origin="declared sibling",
        method="gain",
        gain=1.76,
        time_factor=None,
        alpha=None,
        coefficient_change=CHANGE,
        prior_prediction=np.array([1.0, 2.0]),
        new_prediction=np.array([1.76, 3.52]),
        tested_speeds_rpm=[3000, 3000],
        tested_rises={"T1": [0.0, 4.0]},
        speed_tolerance_rpm=50,
    )
    best_path = results / "comparison" / "best_model.json"
    best = json.loads(best_path.read_text(encoding="utf-8"))
    best["adaptation"]["fitness"] = block
    best["model_id"] = "1" * 64  # the row prior_gain of summary.csv (_add_candidates): the model shown
    best_path.write_text(json.dumps(best), encoding="utf-8")
    # when the prior was made champion is its registry's fact, not the artefact's (the adapted
    # model's id depends on content only): read from the prior machine's history
    assert "promoted" not in block["prior"]
    promotion = {"decision": "promoted", "champion_id_after": PARENT, "time": "2026-11-01T02:03:04Z"}
    with open(results / "registry" / "history.jsonl", "a", encoding="utf-8") as history:
        history.write(json.dumps(promotion) + "\n")
    ctx = _context(results)
    text = " ".join(html.unescape(_text(render_html(ctx))).replace("\u00a0", " ").split())
    who = f"The prior: model {PARENT[:12]} (dynamic) of tapping-center-a , a sibling declared in"
    assert f"{who} models.prior_siblings" in text
    assert (
        "Its own qualification: promoted 2026-11-01T02:03:04Z, worst validation residual 1.23 µm on 3 runs"
        in text
    )
    assert "tested here 3 000 r/min; the prior's 3 000, 9 000, 18 000 r/min" in text
    assert (
        "(range 0–18 000 r/min); covered by the prior alone: 9 000, 18 000 r/min ; 18 000 r/min the prior "
        "had only from its own prior (bbbbbbbbbbbb of mill): no run at them since that model." in text
    )
    assert "prediction moved by 76.0 % of its size" in text
    # the model's section: its speeds, each range said as what it is
    assert (
        "speeds tested here 3 000 r/min; covered by the prior alone 9 000 and 18 000 r/min "
        "(the prior's range 0–18 000 r/min)" in text
    )
    assert f'confirm with {{file: "{PARENT[:12]}", check: prior_adaptation}}' in text
    assert f'confirm with {{file: "{PARENT[:12]}", check: prior_speeds}}' in text
    # and what to do instead: qualify without the prior / record runs at the missing speeds
    machine = best["machine"]
    instead = f"or qualify the machine without this prior (config.yaml: machines: {machine}: models:"
    assert f"check: prior_adaptation}} , {instead} {{prior: none}}" in text
    assert f"rafi plan --machine {machine} --prior none" in text
    assert "check: prior_speeds} , or record runs at those speeds" in text
    table = next(t for t in html_tables(render_html(ctx)) if any("tested here" in h for h in t["headers"]))
    assert [list(r.values()) for r in table["records"]] == [["T1", "0.0 … 4.0", "0.0 … 9.0", "4.0 … 9.0"]]


@pytest.mark.parametrize(
    ("method", "cv_scores", "said"),
    [
        ("shared_ridge", None, "at the penalty 10.0000 (fixed for every machine, not chosen by CV)"),
        ("ridge", [1.5, 1.2], "ridge strength 10.0000 (chosen by CV)"),
        (
            "ridge",
            [None, None],
            "ridge strength 10.0000 (no CV fold: the largest of models.prior_ridge_alphas",
        ),
    ],
)
def test_the_ridge_penalty_is_said_chosen_by_cv_only_where_a_cv_chose_it(tmp_path, method, cv_scores, said):
    """shared_ridge's penalty is fixed (SHARED_RIDGE_ALPHA, docs/models.md); prior_ridge's is
    chosen by whole-run CV on the training runs, or, without a fold, is the largest."""
    from rafi.family.adapted import SHARED_RIDGE_ALPHA

    results = copy_fixture(tmp_path)
    _add_candidates(results, offered="prior_ridge")
    best_path = results / "comparison" / "best_model.json"
    best = json.loads(best_path.read_text(encoding="utf-8"))
    best["adaptation"] |= {"method": method, "alpha": SHARED_RIDGE_ALPHA}
    if method == "shared_ridge":
        best["adaptation"]["gain"] = 1.0375
    else:  # the ridge kind's CV table of the penalties tried (score None: no fold)
        best["cv"] = [{"alpha": a, "score_um": sc} for a, sc in zip((1.0, SHARED_RIDGE_ALPHA), cv_scores)]
    best_path.write_text(json.dumps(best), encoding="utf-8")
    text = " ".join(html.unescape(_text(render_html(_context(results)))).replace("\u00a0", " ").split())
    assert said in text
    if method == "shared_ridge":  # one gain on the blend, then each member's own ridge (not one gain on all)
        assert "(chosen by CV)" not in text and "the prior's blend times one gain, 1.0375" in text
        assert "gain 1.0375 on every coefficient" not in text


def test_a_first_model_waiting_for_its_priors_confirmation_is_neither_pass_nor_fail(tmp_path):
    """No model on the machine, the candidate passed every gate and only its prior's fitness
    warning holds it back: the verdict says WAITING with the check and the entry to add, the words
    of the end-of-run line and rafi status (rafi.family.confirmation.awaiting_confirmation)."""
    results = copy_fixture(tmp_path)
    path = results / "registry" / "decision.json"
    decision = json.loads(path.read_text(encoding="utf-8"))
    blocking = [
        {
            "check": "prior_speeds",
            "prior": PARENT,
            "machine": "tapping-center-a",
            "for_machine": "a2",
            "message": "x",
        }
    ]
    decision |= {
        "decision": "rejected",
        "champion_id_before": None,
        "champion_id_after": None,
        "gates_passed": True,
        "blocked_by": ["prior_fitness"],
        "prior_fitness": {"blocking": blocking, "confirmed": []},
    }
    path.write_text(json.dumps(decision), encoding="utf-8")
    ctx = _context(results)
    assert ctx["verdict"]["status"] == "WAITING"
    text = " ".join(html.unescape(_text(render_html(ctx))).replace("\u00a0", " ").split())
    candidate = str(decision["candidate_id"])[:12]
    assert (
        f"no model is on the machine yet: the candidate {candidate} passed every gate and waits for a "
        f"confirmation of the prior fitness check prior_speeds of prior {PARENT[:12]} (tapping-center-a): "
        f'add checks.confirmed: [{{file: "{PARENT[:12]}", check: prior_speeds}}] in a2\'s settings'
    ) in text
    assert "no model is qualified for this machine" not in text


@pytest.mark.parametrize("champion", [False, True])
def test_a_candidate_waiting_for_an_input_warnings_confirmation_reads_waiting(tmp_path, champion):
    """Every gate passed and only an unconfirmed input warning holds the candidate back (issue 47):
    it waits for a confirmation as a prior's fitness check does. The verdict says WAITING, with or
    without a model on the machine (with one, its rows stay that model's checks and the box says it
    stays until then). Both name the warning and the checks.confirmed entry to add, the words of
    the end-of-run line and rafi status."""
    results = copy_fixture(tmp_path)
    path = results / "registry" / "decision.json"
    decision = json.loads(path.read_text(encoding="utf-8"))
    champ = decision["champion_id_before"] if champion else None
    warning = {"file": "2026-03-12_val_10500rpm.csv", "sha256": "ab" * 32, "check": "probe_sign"}
    decision |= {
        "decision": "rejected",
        "candidate_id": "cd" * 32,
        "champion_id_before": champ,
        "champion_id_after": champ,
        "gates_passed": True,
        "blocked_by": ["input_warnings"],
        "input_warnings": {"blocking": [{**warning, "message": "x", "confirmed": False}]},
    }
    path.write_text(json.dumps(decision), encoding="utf-8")
    ctx = _context(results)
    words = (
        "passed every gate and waits for a confirmation of the input warning probe_sign on "
        '2026-03-12_val_10500rpm.csv: add checks.confirmed: [{file: "2026-03-12_val_10500rpm.csv", '
        "check: probe_sign}] in tapping-center-a's settings"
    )
    text = " ".join(html.unescape(_text(render_html(ctx))).replace("\u00a0", " ").split())
    assert ctx["verdict"]["status"] == "WAITING"
    if champion:
        assert f"WAITING the candidate {'cd' * 6} {words}; the model on the machine stays until then" in text
        assert "Record new training runs" not in text and "record new training runs" not in text
    else:
        assert f"no model is on the machine yet: the candidate {'cd' * 6} {words}" in text
        assert "no model is qualified for this machine" not in text


@pytest.mark.parametrize("prior_was", ["adapted", "offered", "unknown"])
def test_an_ensemble_prior_is_said_offered_the_way_its_own_artefact_says(tmp_path, prior_was):
    """The passage on an ensemble prior adapted through its heaviest member says how that ensemble
    became its machine's champion, from its own artefact in that machine's registry (issue 47): an
    ensemble adapted as a whole was offered by that re-qualification's rule, not by models: offer:
    ensemble; an ensemble of its machine's own kinds by that setting; without its artefact, neither."""
    results = copy_fixture(tmp_path)
    _add_candidates(results, offered="prior_gain")
    best_path = results / "comparison" / "best_model.json"
    best = json.loads(best_path.read_text(encoding="utf-8"))
    best["adaptation"]["member"] = {
        "name": "dynamic",
        "kind": "dynamic",
        "model_id": "12" * 32,
        "weight": 0.6,
        "n_members": 3,
    }
    best_path.write_text(json.dumps(best), encoding="utf-8")
    prior = {"model_id": PARENT, "kind": "ensemble", "machine": "tapping-center-a"}
    if prior_was == "adapted":
        prior["adaptation"] = {"parent": "ef" * 32, "parent_machine": "lathe-b", "method": "shared_ridge"}
    if prior_was != "unknown":  # its machine's registry (here the same machine's)
        models = results / "registry" / "models"
        models.mkdir(parents=True, exist_ok=True)
        (models / f"{PARENT}.json").write_text(json.dumps(prior), encoding="utf-8")
    text = " ".join(html.unescape(_text(render_html(_context(results)))).replace("\u00a0", " ").split())
    text = re.sub(r" ([).,:])", r"\1", text)  # the space a tag left before punctuation
    lead = "An ensemble as the prior. The prior is a CV-weighted ensemble of 3 members"
    assert lead in text
    said = {
        "adapted": (
            f"{lead} (the champion of tapping-center-a: the ensemble prior {'ef' * 6} of lathe-b adapted as "
            "a whole, prior_shared_ridge, offered by that re-qualification's rule, not by models: offer: "
            "ensemble)."
        ),
        "offered": f"{lead} (the champion of tapping-center-a, qualified with models: offer: ensemble).",
        "unknown": f"{lead}. The re-qualification adapts its heaviest member",
    }[prior_was]
    assert said in text
    if prior_was != "offered":
        assert "qualified with models: offer: ensemble" not in text


def test_an_ensemble_prior_adapted_as_a_whole_is_read_as_the_engineer_signs_it(tmp_path):
    """Issue 47, audit of 2026-12-01 (items 1, 3, 6, 8, 13), rendered: the candidate
    prior_shared_ridge, offered by the re-qualification's rule although prior_shared_gain scored
    lower, promoted once its prior's fitness warning was confirmed. Section 3 says the rule that
    applied, each member's coefficients as moved (new / prior, not one gain), the warning as
    confirmed, and the ensemble prior on the machine beside its heaviest member alone; section 1
    and the registry say the promotion rested on the confirmation; the registry's candidate is
    the adapted ensemble, not an ensemble of this run's kinds."""
    results = copy_fixture(tmp_path)
    summ = _add_candidates(results, offered="rafi")
    base = summ[summ["model"] == "prior_gain"].iloc[0]
    shared = [
        base.copy().set_axis(base.index) for _ in range(2)
    ]  # prior_shared_gain (lowest score), prior_shared_ridge (offered whatever the scores)
    for row, name, score, worst in zip(
        shared, ("prior_shared_gain", "prior_shared_ridge"), (0.5, 9.25), (2.1, 1.9)
    ):
        row["model"], row["kind"], row["cv_mean_max_abs_um"], row["max_abs_after_um"] = (
            name,
            "ensemble",
            score,
            worst,
        )
        row["model_id"] = name[-1] * 64
    summ = pd.concat([summ, pd.DataFrame(shared)], ignore_index=True)
    summ["champion"] = summ["model"] == "prior_shared_ridge"
    summ.to_csv(results / "comparison" / "summary.csv", index=False)
    candidate = "9c" * 32
    change = {
        "dynamic": [
            {"name": "dT1@0s", "prior": 0.4, "new": 0.6},
            {"name": "dT2@0s", "prior": -0.2, "new": -0.1},
        ],
        "ridge_global": [{"name": "dT11@0s", "prior": -0.05302628193778224, "new": -0.5617482702903772}],
    }
    members = {
        name: {
            "kind": name,
            "model_id": f"{k}" * 64,
            "adaptation": {"method": "ridge", "coefficient_change": c},
        }
        for k, (name, c) in enumerate(change.items())
    }
    warning = {"check": "prior_speeds", "message": "the prior's speed(s) 9000 r/min have no new training run"}
    best = {
        "kind": "ensemble",
        "model_id": candidate,
        "machine": "tapping-center-a",
        "weights": {"dynamic": 0.7, "ridge_global": 0.3},
        "members": members,
        "adaptation": {
            "method": "shared_ridge",
            "parent": PARENT,
            "parent_machine": "tapping-center-a",
            "gain": 1.251,
            "alpha": 10.0,
            "members": {n: {"kind": n, "model_id": m["model_id"]} for n, m in members.items()},
            "fitness": {
                "prior": {"model_id": PARENT, "machine": "tapping-center-a", "kind": "ensemble"},
                "largest_coefficient_change": {
                    "name": "ridge_global: dT11@0s",
                    "prior": -0.05302628193778224,
                    "new": -0.5617482702903772,
                    "relative": -9.593770669222064,
                },
                "warnings": [warning],
            },
        },
    }
    (results / "comparison" / "best_model.json").write_text(json.dumps(best), encoding="utf-8")
    path = results / "registry" / "decision.json"
    decision = json.loads(path.read_text(encoding="utf-8"))
    confirmed = {**warning, "prior": PARENT, "machine": "tapping-center-a", "for_machine": "tapping-center-a"}
    decision |= {
        "decision": "promoted",
        "candidate_id": candidate,
        "champion_id_before": PARENT,
        "champion_id_after": candidate,
        "gates_passed": True,
        "blocked_by": [],
        "prior_fitness": {"blocking": [], "confirmed": [{**confirmed, "confirmed": True}]},
    }
    path.write_text(json.dumps(decision), encoding="utf-8")
    ctx = _context(results)
    text = " ".join(html.unescape(_text(render_html(ctx))).replace("\u00a0", " ").split())
    text = re.sub(r" ([).,:;])", r"\1", text)
    entry = f"{{file: {PARENT[:12]}, check: prior_speeds}}"
    words = (
        f"the prior fitness check prior_speeds of prior {PARENT[:12]} (tapping-center-a), confirmed in "
        f"checks.confirmed: [{entry}]"
    )
    # items 1: section 1, section 3 and the registry say the promotion rested on the confirmation
    assert f"promoted (see Model registry): it rested on a person's confirmation: {words}" in text
    assert f"Promoted on a confirmation. It rested on a person's confirmation: {words}" in text
    assert "Fitness warnings, confirmed: this model went on the machine on this confirmation" in text
    assert f"confirmed by {entry}" in text and f"confirm with {entry}" not in text
    assert "they block promotion until confirmed" not in text
    # item 6: the rule that applied, with the scores it applied to
    assert "whatever the scores" in text and "chose between the prior as it is" not in text
    assert "prior_shared_ridge 9.25 µm, the lowest prior_shared_gain 0.50 µm" in text
    # item 3: one gain on the blend, then each member's own moves as new / prior
    assert "gain 1.2510 on every coefficient" not in text
    assert "the prior's blend times one gain, 1.2510," in text
    assert "over the 3 coefficients of the 2 members new / prior runs from 0.500 to 10.6" in text
    assert "ridge_global dT11@0s −0.05303 −0.5617 10.6" in text
    assert (
        "ridge_global: dT11@0s, −0.05303 → −0.5617: 10.6 times its prior value" in text and "−959" not in text
    )
    # item 13: the ensemble prior on the machine and its heaviest member alone, each named
    on_machine = decision["champion_summary"]["max_residual_um"]
    assert (
        f"the ensemble prior as it is ({PARENT[:12]}, on the machine before this run) "
        f"{on_machine:.2f} µm, its heaviest member alone (dynamic, the candidate prior) unchanged 3.00 µm"
    ) in text
    # item 8: the registry's candidate is the adapted ensemble
    assert "the CV-weighted ensemble blends" not in text
    assert (
        f"the candidate is an adapted ensemble: the 2 members of the prior {PARENT[:12]} of tapping-center-a "
        "as this run moved them (prior_shared_ridge), with the prior's weights, kept as they are"
    ) in text
