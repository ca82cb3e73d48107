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
        # margin, %, both scores; margin, both worst residuals (no forward folds: the whole-run
        # mean is the selection score, and the sentence says so)
        x, pct, mine, ridge, z, mine_val, ridge_val = _numbers(text)
        assert (
            abs(x - abs(cv_margin)) <= 0.005 + 1e-12
            and abs(pct - abs(row["plain_ridge_cv_margin_pct"])) <= 0.5
        )
        assert (
            abs(mine - np.mean(folds[champ])) <= 0.005 and abs(ridge - np.mean(folds[PLAIN_RIDGE])) <= 0.005
        )
        assert abs(z - abs(val_margin)) <= 0.005 + 1e-12
        assert abs(mine_val - worst[champ]) <= 0.005 and abs(ridge_val - worst[PLAIN_RIDGE]) <= 0.005
        cv_verb = "beats the plain ridge" if cv_margin > 0 else "trails the plain ridge"
        assert cv_verb in text and "in the whole-run CV, the selection score" in text
        assert "on the validation runs" in text and "training-run CV" not in text
        # the reason is there exactly when the offered model does not beat it on the training runs
        assert bool(floor_reason(floor_facts(summary))) == (cv_margin <= 0)


def test_a_missing_number_leaves_its_clause_out_and_no_number_the_sentence():
    folds = {"rafi": [2.0, 3.0], "grey_box": [1.0, 2.0], PLAIN_RIDGE: [2.0, 2.0]}
    worst = {"rafi": 5.0, "grey_box": 2.5, PLAIN_RIDGE: 3.0}
    summary, champ = _summary(folds, worst, ["rafi", "grey_box"])
    both = floor_sentence(floor_facts(summary))
    cv = (
        f"The offered model (grey_box) beats the plain ridge by 0.50{NBSP}µm (25 %) in the whole-run CV, the "
        f"selection score (mean held-out max |residual| 1.50{NBSP}µm against 2.00{NBSP}µm)"
    )
    val = f"by 0.50{NBSP}µm on the validation runs (worst max |residual| 2.50{NBSP}µm against 3.00{NBSP}µm)"
    assert champ == "grey_box" and both == f"{cv} and {val}."
    no_val = summary.assign(max_abs_after_um=np.nan)
    assert floor_sentence(floor_facts(no_val)) == f"{cv}."
    no_cv = summary.assign(selection_score_um=np.nan)
    assert floor_sentence(floor_facts(no_cv)) == f"The offered model (grey_box) beats the plain ridge {val}."
    assert floor_sentence(floor_facts(no_cv.assign(max_abs_after_um=np.nan))) == ""
    # a plain ridge that cannot predict a held-out run: no CV number, and nothing to explain
    inf = _summary({**folds, PLAIN_RIDGE: [2.0, np.nan]}, worst, ["rafi", "grey_box"])[0]
    assert "CV" not in floor_sentence(floor_facts(inf)) and floor_reason(floor_facts(inf)) == ""
    # no plain ridge row (a summary written before it was scored) or no champion: no passage
    assert floor_facts(summary[summary["model"] != PLAIN_RIDGE]) is None
    assert section_plain_ridge(summary.assign(champion=False)) is None


def test_trailing_and_equal_margins_read_as_such():
    folds = {"rafi": [2.0, 3.0], "grey_box": [2.0, 2.2], PLAIN_RIDGE: [1.6, 2.0]}
    summary, _ = _summary(folds, {"rafi": 5.0, "grey_box": 2.5, PLAIN_RIDGE: 2.5}, ["rafi", "grey_box"])
    assert floor_sentence(floor_facts(summary)) == (
        f"The offered model (grey_box) trails the plain ridge by 0.30{NBSP}µm (17 %) in the whole-run CV, "
        f"the selection score (mean held-out max |residual| 2.10{NBSP}µm against 1.80{NBSP}µm) and equals it "
        f"on the validation runs (worst max |residual| 2.50{NBSP}µm against 2.50{NBSP}µm)."
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
    assert floor_sentence(facts) == (
        f"The offered model (rafi) trails the plain ridge by 1.00{NBSP}µm on the validation runs (worst max "
        f"|residual| 4.00{NBSP}µm against 3.00{NBSP}µm)."
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
        f"The offered model (rafi) trails the plain ridge by 0.25 µm ({pct:.0f} %) in the whole-run"
        " CV, the selection score (mean held-out max |residual|" in text
    )
    assert "and by 3.50 µm on the validation runs (worst max |residual|" in text
    assert "rafi is offered although it does not beat the plain ridge on the selection score" in text
    assert "not enabled on this machine, it is the reference only and is never offered" in text
    assert "plain ridge: reference, not offered" in html


# ------------------------------------------------------------- which score the margin is on (issue 46)
def _fl(probe: str) -> pd.DataFrame:
    """fl-thermal's comparison summary (the audit of issue 46, ``/tmp/auditF/fl``): the ridge kinds,
    the plain ridge (not enabled: a member of the ensemble) and the offered ensemble."""
    rows = {  # model: selection score, whole-run CV, forward CV, worst held-out run, validation worst
        "ch1": {
            "dynamic": (3.811682, 2.936952, 4.686412, 6.9345, 7.738235),
            "grey_box": (4.708872, 4.514267, 4.903476, 16.111, 6.409392),
            PLAIN_RIDGE: (10.46703, 3.496156, 17.43790, 9.8091, 5.966389),
            "ensemble": (4.848432, 2.972867, 6.723997, 9.3841, 4.070880),
        },
        "ch5": {
            "dynamic": (9.041992, 4.198130, 13.88585, 6.9586, 10.01596),
            "grey_box": (11.54466, 7.013280, 16.07604, 13.351, 7.162669),
            PLAIN_RIDGE: (7.580355, 5.138454, 10.02225, 7.6563, 6.427087),
            "ensemble": (7.407761, 4.586249, 10.22927, 6.9100, 7.571222),
        },
    }[probe]
    s = pd.DataFrame(
        [
            {
                "model": m,
                "kind": m,
                "selection_score_um": v[0],
                "cv_mean_max_abs_um": v[1],
                "cv_forward_mean_max_abs_um": v[2],
                "cv_max_abs_um": v[3],
                "max_abs_after_um": v[4],
                "champion": m == "ensemble",
            }
            for m, v in rows.items()
        ]
    )
    return floor_columns(s, ["dynamic", "grey_box", "ensemble"], "ensemble")


def test_the_margin_names_its_score_the_whole_run_and_forward_cv_and_their_mean():
    """fl-thermal@ch1 read "beats the plain ridge by 5.62 µm (54 %) in the training-run CV": the
    selection score's margin, driven by the plain ridge's forward folds (17.44 µm against 3.50
    whole-run), while the ensemble's weights use the whole-run CV alone, where it is 0.52 µm."""
    text = floor_sentence(floor_facts(_fl("ch1")))
    assert "in the training-run CV" not in text
    assert text.startswith(
        f"The offered model (ensemble) beats the plain ridge by 0.52{NBSP}µm (15 %) in the whole-run CV "
        f"(mean held-out max |residual| 2.97{NBSP}µm against 3.50{NBSP}µm), by 10.71{NBSP}µm (61 %) in the "
        f"forward CV (6.72{NBSP}µm against 17.44{NBSP}µm) and by 5.62{NBSP}µm (54 %) in the selection score, "
        f"their mean (4.85{NBSP}µm against 10.47{NBSP}µm)"
    )
    assert text.endswith(
        f"and by 1.90{NBSP}µm on the validation runs (worst max |residual| 4.07{NBSP}µm against "
        f"5.97{NBSP}µm)."
    )
    # ch5: ahead on the whole-run CV, behind on the forward folds, ahead on their mean by 0.17 um
    text = floor_sentence(floor_facts(_fl("ch5")))
    assert f"beats the plain ridge by 0.55{NBSP}µm (11 %) in the whole-run CV" in text
    assert f"trails it by 0.21{NBSP}µm (2 %) in the forward CV (10.23{NBSP}µm against 10.02{NBSP}µm)" in text
    assert f"beats it by 0.17{NBSP}µm (2 %) in the selection score, their mean" in text
    assert f"trails it by 1.14{NBSP}µm on the validation runs" in text


def test_an_offered_ensemble_is_offered_by_the_setting_whether_or_not_it_beats_the_plain_ridge():
    """``versus_plain_ridge`` says why the offered model is offered: an ensemble is offered under
    ``models: offer: ensemble`` whatever its score, so its reason is ``ensemble`` on both probes
    (fl-thermal@ch5's summary.csv read ``beats``), as docs/models.md says."""
    for probe in ("ch1", "ch5"):
        s = _fl(probe).set_index("model")
        assert s.loc["ensemble", "versus_plain_ridge"] == "ensemble"
        assert s.loc["ensemble", "plain_ridge_cv_margin_um"] > 0  # it does beat it on the selection score
        why = floor_reason(floor_facts(_fl(probe)))
        assert "offered by models: offer: ensemble" in why and "not because it beats the plain ridge" in why
        assert "its weights come from the whole-run CV only" in why
