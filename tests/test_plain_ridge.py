"""The plain ridge in every qualification (issue 46, item 3): ``temperature_ridge`` is fitted and
scored in every comparison, offered only when enabled, and the report and ``summary.csv`` say by
how much the offered model beats it and why a model that does not is offered anyway.

Ground truth: per-fold max |residual|s drawn here (the selection score is their mean, computed
here with NumPy), validation worst cases drawn here, and the golden synthetic runs of
``tests/test_crossval.py`` for :func:`rafi.family.compare.run_family`.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from report_fixture import ROOT, copy_fixture, empty_figure_dirs, write_upstream_tables

from rafi.family.compare import run_family
from rafi.family.plain_ridge import FLOOR_COLUMNS, PLAIN_RIDGE, REASONS, floor_columns, floor_facts
from rafi.family.selection import SIMPLICITY, TIE_UM, choose_champion, default_champion, selection_table
from rafi.report.context import build_context
from rafi.report.format import NBSP
from rafi.report.plain_ridge import floor_reason, floor_sentence, section_plain_ridge
from rafi.report.render import render_html
from rafi.settings import MACHINE_DEFAULTS, machine_settings

DATA = Path(__file__).parent / "data"
GATES = {"max_residual_um": 12.0, "min_improvement_pct": 30.0, "never_worse_than_uncompensated": True}


def _cv(folds: dict) -> pd.DataFrame:
    """``cv.csv`` rows: model -> max |residual| of each held-out run (one fold each)."""
    return pd.DataFrame(
        [
            {"model": m, "scheme": "leave_one_run_out", "fold": k, "max_abs_after_um": v, "rmse_um": v / 3}
            for m, values in folds.items()
            for k, v in enumerate(values)
        ]
    )


def _summary(folds: dict, worst: dict, candidates: list) -> tuple[pd.DataFrame, str | None]:
    """A comparison summary as run_family builds it from drawn CV folds and validation worst
    cases: the selection table of ``folds`` among ``candidates``, the champion, the floor columns."""
    cv = _cv(folds)
    champion = choose_champion(cv, candidates) or default_champion(candidates)
    s = pd.DataFrame(
        {"model": list(folds), "kind": list(folds), "max_abs_after_um": [worst[m] for m in folds]}
    )
    s = s.merge(selection_table(cv, candidates), on="model", how="left")
    s["champion"] = s["model"] == champion
    return floor_columns(s, candidates, champion), champion


def _numbers(text: str) -> list[float]:
    return [float(x) for x in re.findall(r"\d+\.?\d*", text.replace(NBSP, " "))]


# ------------------------------------------------------------------------ the sentence's numbers
def test_the_sentence_states_the_margins_computed_from_the_folds():
    rng = np.random.default_rng(46)
    for _ in range(20):
        folds = {k: rng.uniform(0.5, 5.0, 6) for k in ("rafi", "ridge_global", "grey_box", PLAIN_RIDGE)}
        worst = {k: rng.uniform(1.0, 9.0) for k in folds}
        summary, champ = _summary(folds, worst, ["rafi", "ridge_global", "grey_box"])
        cv_margin = np.mean(folds[PLAIN_RIDGE]) - np.mean(folds[champ])  # the truth, from the folds
        val_margin = worst[PLAIN_RIDGE] - worst[champ]
        row = summary.set_index("model").loc[champ]
        assert row["plain_ridge_cv_margin_um"] == pytest.approx(cv_margin)
        assert row["plain_ridge_cv_margin_pct"] == pytest.approx(
            100 * cv_margin / np.mean(folds[PLAIN_RIDGE])
        )
        assert row["plain_ridge_validation_margin_um"] == pytest.approx(val_margin)
        text = floor_sentence(floor_facts(summary))
        assert text.startswith(f"The offered model ({champ}) ")
        x, pct, z = _numbers(text)
        assert (
            abs(x - abs(cv_margin)) <= 0.005 + 1e-12
            and abs(pct - abs(row["plain_ridge_cv_margin_pct"])) <= 0.5
        )
        assert abs(z - abs(val_margin)) <= 0.005 + 1e-12
        cv_verb = "beats the plain ridge" if cv_margin > 0 else "trails the plain ridge"
        assert cv_verb in text and "in the training-run CV" in text and "on the validation runs" in text
        # the reason is there exactly when the offered model does not beat it on the training runs
        assert bool(floor_reason(floor_facts(summary))) == (cv_margin <= 0)


def test_a_missing_number_leaves_its_clause_out_and_no_number_the_sentence():
    folds = {"rafi": [2.0, 3.0], "grey_box": [1.0, 2.0], PLAIN_RIDGE: [2.0, 2.0]}
    worst = {"rafi": 5.0, "grey_box": 2.5, PLAIN_RIDGE: 3.0}
    summary, champ = _summary(folds, worst, ["rafi", "grey_box"])
    both = floor_sentence(floor_facts(summary))
    assert champ == "grey_box" and both == (
        f"The offered model (grey_box) beats the plain ridge by 0.50{NBSP}µm (25 %) in the training-run CV"
        f" and by 0.50{NBSP}µm on the validation runs."
    )
    no_val = summary.assign(max_abs_after_um=np.nan)
    assert floor_sentence(floor_facts(no_val)) == (
        f"The offered model (grey_box) beats the plain ridge by 0.50{NBSP}µm (25 %) in the training-run CV."
    )
    no_cv = summary.assign(selection_score_um=np.nan)
    assert floor_sentence(floor_facts(no_cv)) == (
        f"The offered model (grey_box) beats the plain ridge by 0.50{NBSP}µm on the validation runs."
    )
    assert floor_sentence(floor_facts(no_cv.assign(max_abs_after_um=np.nan))) == ""
    # a plain ridge that cannot predict a held-out run: no CV number, and nothing to explain
    inf = _summary({**folds, PLAIN_RIDGE: [2.0, np.nan]}, worst, ["rafi", "grey_box"])[0]
    assert "training-run CV" not in floor_sentence(floor_facts(inf)) and floor_reason(floor_facts(inf)) == ""
    # no plain ridge row (a summary written before it was scored) or no champion: no passage
    assert floor_facts(summary[summary["model"] != PLAIN_RIDGE]) is None
    assert section_plain_ridge(summary.assign(champion=False)) is None


def test_trailing_and_equal_margins_read_as_such():
    folds = {"rafi": [2.0, 3.0], "grey_box": [2.0, 2.2], PLAIN_RIDGE: [1.6, 2.0]}
    summary, _ = _summary(folds, {"rafi": 5.0, "grey_box": 2.5, PLAIN_RIDGE: 2.5}, ["rafi", "grey_box"])
    assert floor_sentence(floor_facts(summary)) == (
        f"The offered model (grey_box) trails the plain ridge by 0.30{NBSP}µm (17 %) in the training-run CV"
        " and equals it on the validation runs."
    )


# ------------------------------------------------------------------------ why it is offered anyway
def test_not_enabled_the_plain_ridge_is_the_reason_and_the_enabled_kinds_are_named():
    folds = {"rafi": [2.0, 3.0], "grey_box": [2.0, 2.2], PLAIN_RIDGE: [1.6, 2.0]}
    summary, champ = _summary(folds, {m: 3.0 for m in folds}, ["rafi", "grey_box"])
    facts = floor_facts(summary)
    assert champ == "grey_box" and facts["reason"] == "not_enabled" and not facts["candidate"]
    assert summary.set_index("model").loc["grey_box", "versus_plain_ridge"] == "not_enabled"
    assert "not among the kinds enabled for this machine (models: enabled: rafi, grey_box)" in floor_reason(
        facts
    )
    # enabled, the same plain ridge is offered: it is the sentence, with nothing to explain
    summary, champ = _summary(folds, {m: 3.0 for m in folds}, ["rafi", "grey_box", PLAIN_RIDGE])
    facts = floor_facts(summary)
    assert champ == PLAIN_RIDGE and facts["reason"] == "is_plain_ridge" and floor_reason(facts) == ""
    assert floor_sentence(facts).startswith("The offered model is the plain ridge (temperature_ridge) itself")


def test_a_tie_names_the_tie_breaker_that_chose():
    half = TIE_UM / 4  # scores equal within TIE_UM: a tie
    enabled = ["ridge_global", PLAIN_RIDGE]
    # equal scores, the lower worst held-out run wins
    folds = {"grey_box": [2.0 + half, 2.0 + half], PLAIN_RIDGE: [1.0, 3.0]}
    summary, champ = _summary(folds, {m: 3.0 for m in folds}, ["grey_box", PLAIN_RIDGE])
    facts = floor_facts(summary)
    assert champ == "grey_box" and facts["reason"] == "tie" and facts["tie_breaker"] == "worst"
    assert (
        f"the lower worst held-out run (grey_box 2.00{NBSP}µm, the plain ridge 3.00{NBSP}µm)"
        in floor_reason(facts)
    )
    # equal scores and worst runs: the simpler kind
    folds = {"ridge_global": [2.0 + half, 3.0], PLAIN_RIDGE: [2.0, 3.0]}
    summary, champ = _summary(folds, {m: 3.0 for m in folds}, enabled)
    facts = floor_facts(summary)
    assert SIMPLICITY["ridge_global"] < SIMPLICITY[PLAIN_RIDGE]
    assert champ == "ridge_global" and facts["reason"] == "tie" and facts["tie_breaker"] == "simpler"
    assert "the simpler kind (ridge_global before temperature_ridge)" in floor_reason(facts)


def test_without_a_cv_fold_the_default_rule_is_the_reason():
    s = pd.DataFrame(
        {
            "model": ["rafi", "grey_box", PLAIN_RIDGE],
            "max_abs_after_um": [4.0, 2.0, 3.0],
            "selection_score_um": np.nan,
            "champion": [True, False, False],
        }
    )
    facts = floor_facts(floor_columns(s, ["rafi", "grey_box"], "rafi"))
    assert facts["reason"] == "no_cv"
    assert (
        floor_sentence(facts)
        == f"The offered model (rafi) trails the plain ridge by 1.00{NBSP}µm on the validation runs."
    )
    assert floor_reason(facts).startswith(
        "No cross-validation fold scored the models, so the default rule offered rafi"
    )


def test_the_current_rule_never_offers_a_kind_behind_an_enabled_plain_ridge():
    """Where the plain ridge is a candidate with a CV score, the offered model's selection score is
    at most the plain ridge's (or equal within TIE_UM): reason ``other`` never occurs, so the report
    never has to explain a candidate plain ridge that scores lower and is not offered."""
    rng = np.random.default_rng(7)
    kinds = ["rafi", "rafi_linear", "ridge_global", "dynamic", "grey_box", PLAIN_RIDGE]
    seen = set()
    for _ in range(80):
        folds = {k: rng.choice([1.0, 1.5, 2.0, 2.5], 4) for k in kinds}  # coarse: many ties
        if rng.random() < 0.2:  # some kind cannot predict a held-out run
            folds[str(rng.choice(kinds))][0] = np.nan
        enabled = [k for k in kinds if rng.random() < 0.6] or [PLAIN_RIDGE]
        enabled = enabled if PLAIN_RIDGE in enabled else [*enabled, PLAIN_RIDGE]
        summary, champ = _summary(folds, {k: 2.0 for k in kinds}, enabled)
        why = summary.set_index("model").loc[champ, "versus_plain_ridge"]
        assert why in REASONS and why not in ("other", "not_enabled")
        seen.add(why)
    assert {"beats", "is_plain_ridge", "tie"} <= seen


# ------------------------------------------------------------------------ run_family: always scored
def _golden():
    return pd.read_csv(DATA / "golden_comparison_runs.csv"), pd.read_csv(DATA / "golden_comparison_frame.csv")


def _family(table, frame, options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run_family(
            table,
            frame,
            key_sensors=["T1", "T2", "T3"],
            terms=MACHINE_DEFAULTS["fit"]["terms"],
            reference=MACHINE_DEFAULTS["reference"],
            machine="synthetic",
            gates=GATES,
            options=options,
            log=lambda m: None,
        )


@pytest.fixture(scope="module")
def disabled():
    """run_family with the settings of a machine whose config leaves temperature_ridge out."""
    # the best kind offered (the default blend has the plain ridge as a member: tests/test_ensemble.py)
    config = {"machines": {"m": {"models": {"enabled": ["rafi_linear", "ridge_global"], "offer": "best"}}}}
    options = machine_settings(config, "m")["models"]
    assert PLAIN_RIDGE not in options["enabled"]
    return _family(*_golden(), options)


def test_a_machine_that_disables_it_still_has_the_plain_ridge_in_its_comparison(disabled):
    table, _ = _golden()
    res = disabled
    s = res["summary"].set_index("model")
    assert list(s.index) == ["rafi_linear", "ridge_global", PLAIN_RIDGE]
    assert set(FLOOR_COLUMNS) <= set(s.columns)
    assert not s.loc[PLAIN_RIDGE, "candidate"] and s.loc[["rafi_linear", "ridge_global"], "candidate"].all()
    assert pd.isna(s.loc[PLAIN_RIDGE, "selection_rank"]) and not s.loc[PLAIN_RIDGE, "champion"]
    # its CV score and its validation scores, as every kind's
    n_train = int((table["role"] == "training").sum())
    assert (res["cv"]["model"] == PLAIN_RIDGE).sum() == n_train
    assert np.isfinite(
        s.loc[PLAIN_RIDGE, ["selection_score_um", "cv_mean_max_abs_um", "max_abs_after_um"]]
    ).all()
    n_val = int(table["role"].str.startswith("validation").sum())
    assert (res["per_run"]["model"] == PLAIN_RIDGE).sum() == n_val
    assert (res["verdict"]["model"] == PLAIN_RIDGE).any() and (res["residuals"]["model"] == PLAIN_RIDGE).any()
    # the champion's row says by how much it beats it (numbers from the two rows)
    champ = res["champion"]
    assert s.loc[champ, "plain_ridge_cv_margin_um"] == pytest.approx(
        s.loc[PLAIN_RIDGE, "selection_score_um"] - s.loc[champ, "selection_score_um"]
    )
    assert s.loc[champ, "plain_ridge_validation_margin_um"] == pytest.approx(
        s.loc[PLAIN_RIDGE, "max_abs_after_um"] - s.loc[champ, "max_abs_after_um"]
    )
    assert s.loc[champ, "versus_plain_ridge"] in REASONS
    assert (s.drop(index=champ)["versus_plain_ridge"] == "").all()


def test_the_reference_changes_neither_the_choice_nor_the_candidates_scores(disabled):
    """The choice and the ranks are those of the candidates' CV rows alone: as before the plain
    ridge was scored beside them."""
    res = disabled
    cv = res["cv"]
    alone = cv[cv["model"] != PLAIN_RIDGE]
    assert res["champion"] == choose_champion(alone)
    pd.testing.assert_frame_equal(
        res["selection"].iloc[:2].reset_index(drop=True), selection_table(alone), check_dtype=False
    )


def test_enabled_it_is_a_candidate_like_any_kind():
    options = {**MACHINE_DEFAULTS["models"], "enabled": ["rafi_linear", PLAIN_RIDGE], "offer": "best"}
    s = _family(*_golden(), options)["summary"].set_index("model")
    assert list(s.index) == ["rafi_linear", PLAIN_RIDGE]  # fitted once
    assert s["candidate"].all() and sorted(s["selection_rank"]) == [1, 2]


# ------------------------------------------------------------------------ the report's passage
def test_the_report_states_the_passage_from_this_machines_numbers(tmp_path):
    """The report fixture (RAFI offered) with a plain ridge row drawn here: the comparison section
    holds the sentence with the margins of the two rows, the reason (the plain ridge is not enabled
    and scores lower) and the plain ridge marked in the table as not offered."""
    results = copy_fixture(tmp_path)
    path = results / "comparison" / "summary.csv"
    summ = pd.read_csv(path)
    champ = summ.loc[summ["champion"]].iloc[0]
    ridge = champ.copy()
    ridge[["model", "kind", "champion", "passed", "model_id"]] = [
        PLAIN_RIDGE,
        PLAIN_RIDGE,
        False,
        True,
        "f" * 64,
    ]
    ridge["cv_mean_max_abs_um"] = champ["cv_mean_max_abs_um"] - 0.25  # scores better on the training runs
    ridge["max_abs_after_um"] = champ["max_abs_after_um"] - 3.5
    ridge["selection_rank"] = np.nan
    summ = pd.concat([summ, ridge.to_frame().T], ignore_index=True)
    summ = floor_columns(summ, list(summ["model"][:-1]), str(champ["model"]))
    summ.to_csv(path, index=False)
    paths = write_upstream_tables(results)
    config = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))
    settings = machine_settings(config, "tapping-center-a")
    ctx = build_context(paths, empty_figure_dirs(results), machine="tapping-center-a", settings=settings)
    html = render_html(ctx)
    passage = re.search(r'<p id="plain-ridge">(.*?)</p>', html, re.S).group(1)
    text = " ".join(re.sub(r"<[^>]+>", " ", passage).replace("&#39;", "'").split())  # NBSP: a space
    pct = 100 * 0.25 / (champ["cv_mean_max_abs_um"] - 0.25)
    assert (
        f"The offered model (rafi) trails the plain ridge by 0.25 µm ({pct:.0f} %) in the training-run"
        " CV" in text
    )
    assert "and by 3.50 µm on the validation runs." in text
    assert "rafi is offered although it does not beat the plain ridge in the training-run CV" in text
    assert "not enabled on this machine, it is the reference only and is never offered" in text
    assert "plain ridge: reference, not offered" in html
