"""Rule compare stores every model's gates per validation run (comparison/verdict.csv, issue "The
report reads the stored verdict and decision; it recomputes nothing").

run_family's ``verdict`` holds, for every model in the order of its summary, the rows of
rafi.method.validate.qualify on that model's validation runs (criterion x run), named by the model
and its id; the per-run and per-model ``passed`` of the comparison agree with it. Data: the golden
synthetic runs of tests/test_crossval.py (6 training speeds, 4 validation runs).
"""

from __future__ import annotations

import warnings

import pandas as pd
import pytest
from test_selection import GATES, _data, _family

from rafi.family.compare import VERDICT_COLUMNS, named_verdict, stacked_verdicts
from rafi.method.validate import qualify

ENABLED = ["rafi", "rafi_linear", "ridge_global"]


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


@pytest.fixture(scope="module")
def family():
    table, frame = _data()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return _family(table, frame, enabled=ENABLED)


def test_the_verdict_is_qualify_of_every_model_in_the_summarys_order(family):
    verdict, per_run, summary = family["verdict"], family["per_run"], family["summary"]
    assert list(verdict.columns) == VERDICT_COLUMNS
    # the enabled kinds, then the plain ridge scored as the reference (rafi.family.plain_ridge)
    assert list(dict.fromkeys(verdict["model"])) == list(summary["model"]) == [*ENABLED, "temperature_ridge"]
    n_runs = per_run.groupby("model")["run_id"].nunique()
    for name, model_id in zip(summary["model"], summary["model_id"]):
        rows = verdict[verdict["model"] == name].reset_index(drop=True)
        assert set(rows["model_id"]) == {model_id} and model_id
        # the same rows as the gates on the model's validation results, in qualify's order
        expected = qualify(per_run[per_run["model"] == name].reset_index(drop=True), GATES)
        pd.testing.assert_frame_equal(rows[expected.columns.tolist()], expected, check_exact=True)
        assert len(rows) == 3 * n_runs[name]  # three gates on every validation run


def test_the_comparisons_passed_agrees_with_the_stored_verdict(family):
    verdict, per_run, summary = family["verdict"], family["per_run"], family["summary"]
    by_run = verdict.groupby(["model", "run_id"], sort=False)["passed"].all()
    stored = per_run.set_index(["model", "run_id"])["passed"]
    assert by_run.reindex(stored.index).tolist() == stored.tolist()
    by_model = verdict.groupby("model", sort=False)["passed"].all()
    assert by_model.reindex(summary["model"]).tolist() == summary["passed"].tolist()


def test_without_gates_the_verdict_is_an_empty_table_with_its_columns():
    table, frame = _data()
    res = _family(table, frame, gates={}, enabled=["rafi_linear"])
    assert res["verdict"].empty and list(res["verdict"].columns) == VERDICT_COLUMNS
    assert list(stacked_verdicts([]).columns) == VERDICT_COLUMNS


def test_named_verdict_keeps_qualifys_rows_and_names_them():
    summary = pd.DataFrame(
        {
            "run_id": ["r1", "r0"],
            "max_abs_before_um": [20.0, 10.0],
            "max_abs_after_um": [13.0, 4.0],
            "improvement_pct": [35.0, 60.0],
        }
    )
    rows = named_verdict(qualify(summary, GATES), "ridge_global", "abc")
    assert list(rows.columns) == VERDICT_COLUMNS
    assert list(rows["run_id"]) == ["r1"] * 3 + ["r0"] * 3  # the summary's run order
    assert list(rows["passed"]) == [False, True, True, True, True, True]
    assert set(rows["model"]) == {"ridge_global"} and set(rows["model_id"]) == {"abc"}


def test_a_sensor_dropout_in_a_validation_run_is_counted_per_model_and_named():
    """T4 (not a key sensor) missing for 10 samples of one validation run: the ridge model, which
    reads every sensor, gives no value there and says so; RAFI (T1-T3) compensates them."""
    table, frame = _data()
    run = table.loc[table["role"].str.startswith("validation"), "run_id"].iloc[0]
    rows = frame.index[frame["run_id"] == run][20:30]
    frame.loc[rows, "dT4"] = float("nan")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = _family(table, frame, enabled=ENABLED)
    per_run = out["per_run"].set_index(["model", "run_id"])
    n_run = int((frame["run_id"] == run).sum())
    assert per_run.loc[("ridge_global", run), ["n_unpredicted", "unpredicted_inputs"]].tolist() == [10, "T4"]
    assert per_run.loc[("ridge_global", run), "n_samples"] == n_run - 10
    for name in ("rafi", "rafi_linear"):
        assert per_run.loc[(name, run), "n_unpredicted"] == 0
        assert per_run.loc[(name, run), "n_samples"] == n_run
    summary = out["summary"].set_index("model")
    assert summary.loc["ridge_global", "n_unpredicted"] == 10
    assert summary.loc["ridge_global", "unpredicted_inputs"] == "T4"
    assert summary.loc["rafi", "n_unpredicted"] == 0 and summary.loc["rafi", "unpredicted_inputs"] == ""


def test_a_sensor_dropout_in_a_training_run_is_counted_in_the_cv_per_model_and_named():
    """T4 missing for 12 samples of one training run: held out in its whole-run fold, the ridge
    model gives no value there (cv.csv and summary.csv say so, by count and input) and its CV
    figures are over the other samples; RAFI (T1-T3) predicts them. No other run is touched."""
    table, frame = _data()
    run = table.loc[table["role"] == "training", "run_id"].iloc[1]
    rows = frame.index[frame["run_id"] == run][40:52]
    frame.loc[rows, "dT4"] = float("nan")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = _family(table, frame, enabled=ENABLED)
    cv = out["cv"]
    assert {"n_unpredicted", "unpredicted_inputs"} <= set(cv.columns)
    held = cv[cv["test_runs"].astype(str) == run].set_index("model")
    n_run = int((frame["run_id"] == run).sum())
    assert held.loc["ridge_global", ["n_unpredicted", "unpredicted_inputs"]].tolist() == [12, "T4"]
    assert held.loc["ridge_global", "n_samples"] == n_run - 12
    assert held.loc["rafi", "n_unpredicted"] == 0 and held.loc["rafi", "n_samples"] == n_run
    others = cv[cv["test_runs"].astype(str) != run]
    assert (others["n_unpredicted"] == 0).all() and (others["unpredicted_inputs"] == "").all()
    summary = out["summary"].set_index("model")
    assert summary.loc["ridge_global", ["cv_unpredicted", "cv_unpredicted_inputs"]].tolist() == [12, "T4"]
    assert summary.loc["rafi", "cv_unpredicted"] == 0 and summary.loc["rafi", "cv_unpredicted_inputs"] == ""
