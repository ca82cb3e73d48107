"""Section "Choices the paper leaves open" states the rules this run applied, from its results.

The audit of two machines nobody here tuned on (issue 46) read there that the champion "is the one
with the lowest selection score", among "the models in models.enabled" (temperature_ridge left
out), while the comparison and docs/models.md said the CV-weighted ensemble is offered whatever its
score (fl-thermal@ch1: its selection score 4.85 µm against dynamic's 3.81 µm), temperature_ridge
one of its members (weight 0.312); and that roles come from the speed (constant for at least
``runs.min_constant_s`` at a training speed -> training ...) while every role of both machines came
from ``runs.windows`` (foreign-3's varying day05_train trains). The paragraphs now say the rule of
the comparison's results (:func:`rafi.report.choices.champion_rule`) and where each role came from
(:func:`rafi.report.choices.role_rules`, from ``runs.csv``).
"""

from __future__ import annotations

import html

import pandas as pd
from test_report_text import _section, _text

from rafi.family.plain_ridge import PLAIN_RIDGE, floor_columns
from rafi.report.choices import champion_rule, role_rules, section_choices
from rafi.report.comparison_section import family_champion, model_rows, selection_context
from rafi.report.ensemble_section import ensemble_context
from rafi.settings import machine_settings

#: fl-thermal@ch1's summary.csv (model: selection score, whole-run CV, forward CV, kind).
FL = {
    "rafi": (74.77, 72.52, 77.02, "rafi"),
    "rafi_linear": (13.82, 12.62, 15.01, "rafi_linear"),
    "ridge_global": (11.26, 8.11, 14.41, "ridge_global"),
    "dynamic": (3.81, 2.94, 4.69, "dynamic"),
    "grey_box": (4.71, 4.51, 4.90, "grey_box"),
    PLAIN_RIDGE: (10.47, 3.50, 17.44, PLAIN_RIDGE),
    "ensemble": (4.85, 2.97, 6.72, "ensemble"),
}
WEIGHTS = {"dynamic": 0.442, PLAIN_RIDGE: 0.312, "grey_box": 0.187, "ridge_global": 0.058}


def _summary(champion: str = "ensemble", drop=()) -> pd.DataFrame:
    s = pd.DataFrame(
        [
            {
                "model": m,
                "kind": v[3],
                "model_id": m[0] * 64,
                "selection_score_um": v[0],
                "cv_mean_max_abs_um": v[1],
                "cv_forward_mean_max_abs_um": v[2],
                "cv_max_abs_um": v[1] * 2,
                "max_abs_after_um": 5.0,
                "passed": True,
                "champion": m == champion,
            }
            for m, v in FL.items()
            if m not in drop
        ]
    )
    candidates = [m for m in s["model"] if m != PLAIN_RIDGE]
    return floor_columns(s, candidates, champion)


def _comparison(summary: pd.DataFrame, best: dict | None) -> dict:
    """The keys of :func:`rafi.report.comparison_section.section_comparison` the rule reads."""
    champ = family_champion(summary)
    sel = selection_context(summary, champ, "leave_one_run_out", "forward_2")
    ens = ensemble_context(best, summary, "leave_one_run_out", "forward_2")
    if ens is not None:
        sel["ensemble"] = ens
        sel["rule"] = ens["selection_rule"] or sel["rule"]
    return {"selection": sel, "ensemble": ens, "models": model_rows(summary, champ, None), "champion": champ}


ENSEMBLE = {
    "kind": "ensemble",
    "model_id": "e" * 64,
    "weights": WEIGHTS,
    "members": {m: {"kind": m, "model_id": m[0] * 64} for m in WEIGHTS},
}


def _choices(settings, comparison=None, runs=None) -> str:
    ctx = section_choices(settings, {}, None, forward=2, comparison=comparison, runs=runs)
    return html.unescape(_text(_section("choices", choices=ctx)))


def _paragraph(text: str, title: str, after: str | None = None) -> str:
    """The paragraph ``title`` of the section's text, up to ``after`` (default: the end)."""
    text = text[text.index(title) :]
    return text[: text.index(after)] if after else text


def test_an_offered_ensemble_is_said_offered_whatever_its_score_with_its_members():
    settings = machine_settings({}, "m")
    rule = champion_rule(_comparison(_summary(), ENSEMBLE), settings)
    assert rule["how"] == "ensemble" and rule["champion"] == "ensemble"
    assert rule["lowest"] == {"model": "dynamic", "score": 3.81} and rule["score"] == 4.85
    assert [m["model"] for m in rule["members"]] == ["dynamic", PLAIN_RIDGE, "grey_box", "ridge_global"]
    assert PLAIN_RIDGE in rule["fitted"] and "rafi" not in rule["fitted"] and "ensemble" not in rule["fitted"]
    text = _paragraph(_choices(settings, _comparison(_summary(), ENSEMBLE)), "Model family")
    assert "is the one with the lowest" not in text
    assert "temperature_ridge (the plain ridge: not in models.enabled, scored in every qualification)" in text
    assert "is the CV-weighted ensemble of 4 of them (models: offer: ensemble)" in text
    assert "dynamic 0.442, temperature_ridge 0.312, grey_box 0.187, ridge_global 0.058" in text
    assert (
        "offered whatever its own selection score: here 4.85 µm, against dynamic's 3.81 µm, the lowest"
        in text
    )
    assert "the weights use the whole-run folds only" in text


def test_the_lowest_score_rule_is_said_where_it_chose():
    settings = machine_settings({"machines": {"m": {"models": {"offer": "best"}}}}, "m")
    comparison = _comparison(_summary("dynamic", drop=("ensemble",)), None)
    rule = champion_rule(comparison, settings)
    assert rule["how"] == "best" and rule["champion"] == "dynamic"
    text = _paragraph(_choices(settings, comparison), "Model family")
    assert (
        "The champion (the model offered to the machine), dynamic, is the one with the lowest selection score"
        in text
    )
    assert "CV-weighted" not in text


def test_an_adapted_ensemble_is_said_offered_by_the_requalifications_rule():
    settings = machine_settings({}, "m")
    s = _summary("ensemble").assign(model=lambda f: f["model"].replace({"ensemble": "prior_shared_ridge"}))
    adapted = {
        **ENSEMBLE,
        "adaptation": {"parent": "p" * 64, "parent_machine": "spindle-a", "method": "shared_ridge"},
    }
    rule = champion_rule(_comparison(s, adapted), settings)
    assert rule["how"] == "adapted" and rule["champion"] == "prior_shared_ridge"
    text = _paragraph(_choices(settings, _comparison(s, adapted)), "Model family")
    assert "offered by the re-qualification's rule" in text and "whatever the scores" in text
    assert "models: offer: ensemble" not in text and "is the one with the lowest" not in text


def _runs(source: str, kinds, roles, files=None) -> pd.DataFrame:
    n = len(kinds)
    return pd.DataFrame(
        {
            "run_id": [f"r{k}" for k in range(n)],
            "file": files or [f"day{k}.csv" for k in range(n)],
            "kind": kinds,
            "role": roles,
            "role_source": [source] * n,
            "speed_rpm": 1000.0,
        }
    )


def test_roles_from_windows_are_said_from_the_windows_not_the_speed_rule():
    windows = [
        {"role": "training", "log": "*_train*"},
        {"role": "validation", "log": "*_test*"},
    ]
    settings = machine_settings({"machines": {"m": {"runs": {"windows": windows}}}}, "m")
    runs = _runs(
        "window",
        ["constant", "varying", "varying", "constant"],
        ["training", "training", "validation_multi", "validation_single"],
        ["day01_train.csv", "day05_train.csv", "day06_test.csv", "day08_test.csv"],
    ).assign(run_id=["day01_train", "day05_train", "day06_test", "day08_test"])
    rules = role_rules(runs, settings)
    assert [(r["source"], r["n"]) for r in rules["sources"]] == [("window", 4)]
    assert rules["varying_training"] == ["day05_train"]
    text = _paragraph(_choices(settings, runs=runs), "Runs, roles", "Sensor dropouts")
    assert "at a training speed -> training" not in text
    assert "all 4 runs from the time windows of runs.windows" in text
    assert "training window start-end of the log (logs *_train*)" in text
    assert "validation window start-end of the log (logs *_test*)" in text
    assert "a varying run too (day05_train)" in text


def test_roles_by_speed_are_said_with_the_training_speeds():
    settings = machine_settings({"machines": {"m": {"training_speeds_rpm": [3000, 6000]}}}, "m")
    runs = _runs("auto", ["constant", "varying"], ["training", "validation_multi"])
    text = _paragraph(_choices(settings, runs=runs), "Runs, roles", "Sensor dropouts")
    assert "all 2 runs by their speed" in text
    assert "at a training speed (3000, 6000 r/min" in text.replace("\u00a0", "") and "-> training" in text
    assert "runs.windows" not in text
