"""Forward-in-time folds (rafi.family.forward_folds) and their place in the selection and the
intervals: folds from the runs table alone, the CV through the pipeline's own ``cross_validate``,
the selection score, and ``run_family`` end to end on a continuous synthetic log."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from test_selection import _family as selection_family

from rafi.family.crossval import cross_validate, has_folds, split_runs
from rafi.family.forward_folds import (
    configured_scheme,
    forward_folds,
    forward_logs,
    horizon_of,
    is_forward,
    scheme_name,
)
from rafi.family.ridge_global import RidgeGlobal
from rafi.family.selection import choose_champion, selection_rule, selection_table
from rafi.settings import MACHINE_DEFAULTS
from rafi.twin.synthetic_runs import make_synthetic_runs


def _table(rows) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=["run_id", "file", "start_s", "role"]).assign(speed_rpm=1000.0)


def _one_log(n_train: int = 6) -> pd.DataFrame:
    """A continuous log: an excluded rest, ``n_train`` training runs, two validation runs; the
    rows out of time order (the folds must sort by start)."""
    rows = [("log#0", "log.csv", 0.0, "excluded")]
    rows += [(f"log#{k}", "log.csv", 3600.0 * k, "training") for k in range(1, n_train + 1)]
    rows += [(f"log#{k}", "log.csv", 3600.0 * k, "validation_single") for k in (n_train + 1, n_train + 2)]
    return _table(rows[::-1])


def test_forward_folds_train_on_the_past_and_hold_out_the_next_run():
    folds = list(forward_folds(_one_log(6), horizon=1, min_train=3))
    assert folds == [
        (["log#1", "log#2", "log#3"], ["log#4"]),
        (["log#1", "log#2", "log#3", "log#4"], ["log#5"]),
        (["log#1", "log#2", "log#3", "log#4", "log#5"], ["log#6"]),
    ]
    start = dict(zip(_one_log(6)["run_id"], _one_log(6)["start_s"]))
    for train, test in folds:
        assert not set(train) & set(test)
        assert max(start[r] for r in train) < min(start[r] for r in test)


def test_horizon_two_holds_out_the_next_two_runs_and_needs_both():
    folds = list(forward_folds(_one_log(6), horizon=2, min_train=3))
    assert [test for _, test in folds] == [["log#4", "log#5"], ["log#5", "log#6"]]
    assert [len(train) for train, _ in folds] == [3, 4]


def test_min_train_rule():
    assert [len(tr) for tr, _ in forward_folds(_one_log(6), horizon=1, min_train=5)] == [5]
    assert list(forward_folds(_one_log(3), horizon=1, min_train=3)) == []
    assert list(forward_folds(_one_log(4), horizon=2, min_train=3)) == []
    assert forward_logs(_one_log(6), horizon=2) == {"log.csv": {"training_runs": 6, "folds": 2}}


def test_separate_logs_have_no_time_order_and_give_no_folds():
    # a continuous log of 5 training runs and three cold-start files of one run each, the files
    # dated between the log's runs: no fold crosses a log, and the files' runs are never used
    rows = [(f"log#{k}", "log.csv", 3600.0 * k, "training") for k in range(1, 6)]
    rows += [(f"cold_{k}", f"cold_{k}.csv", 3600.0 * k + 100, "training") for k in range(1, 4)]
    table = _table(rows)
    folds = list(forward_folds(table, horizon=1, min_train=3))
    assert [test for _, test in folds] == [["log#4"], ["log#5"]]
    assert all(r.startswith("log#") for train, test in folds for r in train + test)
    only_files = table.loc[table["file"] != "log.csv"]
    assert list(forward_folds(only_files, horizon=1, min_train=1)) == []
    logs = forward_logs(table, horizon=1)
    assert logs["log.csv"]["folds"] == 2 and logs["cold_1.csv"] == {"training_runs": 1, "folds": 0}


def test_runs_without_a_log_and_start_have_no_time_order_and_give_no_folds():
    assert list(forward_folds(_one_log().drop(columns="start_s"))) == []
    assert list(forward_folds(_one_log().drop(columns="file"), horizon=1, min_train=1)) == []


def test_scheme_names():
    assert scheme_name(2) == "forward_2" and horizon_of("forward_2") == 2
    assert is_forward("forward_1") and not is_forward("forward_") and not is_forward("leave_one_run_out")
    assert configured_scheme({"cv_forward_runs": 2}) == "forward_2"
    assert configured_scheme({"cv_forward_runs": 0}) is None
    assert configured_scheme(MACHINE_DEFAULTS["models"]) == "forward_2"
    with pytest.raises(ValueError, match="not a forward scheme"):
        horizon_of("leave_one_run_out")
    with pytest.raises(ValueError, match="at least 1 run"):
        list(forward_folds(_one_log(), horizon=0))


def test_split_runs_knows_forward_schemes_by_name():
    table = _one_log(6)
    assert list(split_runs(table, "forward_2")) == list(forward_folds(table, horizon=2))
    assert has_folds(table, "forward_2") and not has_folds(_one_log(4), "forward_2")
    with pytest.raises(ValueError, match="unknown CV scheme"):
        split_runs(table, "forward")


def _continuous_log():
    """Six training runs in one log, in time order, then the validation runs."""
    table, frame = make_synthetic_runs(seed=2, sample_s=300.0, n_sensors=3)
    return table.assign(file="log.csv", start_s=np.arange(len(table)) * 4 * 3600.0), frame


def test_forward_cv_fits_only_on_the_past_and_labels_each_fold_and_run_as_a_unit():
    table, frame = _continuous_log()
    order = list(table["run_id"])
    seen = []

    class Spy(RidgeGlobal):
        def fit(self, runs_table, runs_frame):
            seen.append(set(runs_table.loc[runs_table["role"] == "training", "run_id"]))
            return super().fit(runs_table, runs_frame)

    oof = []
    cv = cross_validate(lambda: Spy(alphas=[1e-3, 1e-1]), table, frame, "forward_2", name="m", oof=oof)
    assert set(cv["scheme"]) == {"forward_2"} and cv["fold"].nunique() == 2
    assert list(cv["n_train_runs"]) == [3, 3, 4, 4]
    folds = [list(g["test_runs"]) for _, g in cv.groupby("fold")]
    # the outer fits (one per fold; the inner CV's fits are within the same runs)
    outer = [s for s in seen if len(s) in (3, 4)]
    for learned, test in zip([outer[0], outer[-1]], folds):
        assert max(order.index(r) for r in learned) < min(order.index(r) for r in test)
    units = set(oof[0]["unit"])
    assert units == {f"f{k}:{r}" for k, test in enumerate(folds) for r in test}
    assert set(oof[0]["run_id"]) == {r for test in folds for r in test}


def _cv_rows(scheme, scores):
    return pd.DataFrame(
        [
            {
                "model": m,
                "scheme": scheme,
                "fold": k,
                "test_runs": f"r{k}",
                "max_abs_after_um": v,
                "rmse_um": v / 3,
            }
            for m, values in scores.items()
            for k, v in enumerate(values)
        ]
    )


def test_the_selection_score_is_the_mean_of_whole_run_and_forward_scores():
    whole = _cv_rows("leave_one_run_out", {"a": [2.0, 2.0, 2.0], "b": [3.0, 3.0, 3.0]})
    ahead = _cv_rows("forward_2", {"a": [9.0, 9.0], "b": [5.0, 5.0]})
    t = selection_table(pd.concat([whole, ahead], ignore_index=True)).set_index("model")
    assert t.loc["a", "cv_mean_max_abs_um"] == 2.0 and t.loc["a", "cv_forward_mean_max_abs_um"] == 9.0
    assert t.loc["a", "selection_score_um"] == pytest.approx(5.5)
    assert t.loc["b", "selection_score_um"] == pytest.approx(4.0)
    assert t.loc["a", "cv_folds"] == 3 and t.loc["a", "cv_forward_folds"] == 2
    assert choose_champion(pd.concat([whole, ahead])) == "b"
    # without forward rows: the whole-run CV alone, as before
    alone = selection_table(whole).set_index("model")
    assert choose_champion(whole) == "a" and np.isnan(alone.loc["a", "cv_forward_mean_max_abs_um"])
    assert (alone["selection_score_um"] == alone["cv_mean_max_abs_um"]).all()
    assert (alone["cv_forward_folds"] == 0).all()


def test_a_model_that_cannot_predict_a_forward_run_is_not_chosen():
    whole = _cv_rows("leave_one_run_out", {"a": [1.0, 1.0], "b": [3.0, 3.0]})
    ahead = _cv_rows("forward_2", {"a": [1.0, np.nan], "b": [5.0, 5.0]})
    assert choose_champion(pd.concat([whole, ahead])) == "b"


def test_the_rule_text_says_when_forward_folds_chose():
    assert "forward folds" not in selection_rule("leave_one_run_out")
    text = selection_rule("leave_one_run_out", "forward_2")
    assert "next 2 runs" in text and "lowest mean of the two scores" in text


def _family(table, frame, **changes):
    return selection_family(table, frame, enabled=["ridge_global", "rafi_linear"], **changes)


def test_run_family_scores_forward_folds_and_calibrates_on_the_whole_run_units():
    table, frame = _continuous_log()
    res = _family(table, frame)
    cv = res["cv"]
    assert {"leave_one_run_out", "forward_2"} == set(cv["scheme"])
    sel = res["selection"].set_index("model")
    for name, g in cv.loc[cv["scheme"] == "forward_2"].groupby("model"):
        assert sel.loc[name, "cv_forward_mean_max_abs_um"] == pytest.approx(g["max_abs_after_um"].mean())
    assert res["champion"] == sel["selection_score_um"].idxmin()
    # the intervals calibrate on the whole-run units alone
    block = res["models"][res["champion"]].to_dict()["interval"]["calibration"]
    assert block["scheme"] == "leave_one_run_out"
    assert block["n_runs"] == 6

    off = _family(table, frame, cv_forward_runs=0)
    assert set(off["cv"]["scheme"]) == {"leave_one_run_out"}
    assert off["cv"].equals(cv.loc[cv["scheme"] == "leave_one_run_out"].reset_index(drop=True))
    assert (
        off["models"][off["champion"]].to_dict()["interval"]["calibration"]["scheme"] == "leave_one_run_out"
    )
    # the forward folds change the selection's scores, not the (whole-run) intervals
    for name, model in off["models"].items():
        assert model.to_dict()["interval"] == res["models"][name].to_dict()["interval"]


def test_separate_files_get_no_forward_folds():
    table, frame = make_synthetic_runs(seed=2, sample_s=300.0, n_sensors=3, multi=False)
    table = table.assign(start_s=0.0)
    assert forward_logs(table, 2)
    assert set(_family(table, frame)["cv"]["scheme"]) == {"leave_one_run_out"}


def test_ridge_kinds_choose_their_hyperparameters_on_the_whole_run_folds():
    # the forward folds score the selection; a kind's own CV table is that of its whole-run folds
    table, frame = _continuous_log()
    res = _family(table, frame)
    off = _family(table, frame, cv_forward_runs=0)
    fitted, alone = res["models"]["ridge_global"].to_dict(), off["models"]["ridge_global"].to_dict()
    assert fitted["cv"] == alone["cv"] and fitted["selected"]["alpha"] == alone["selected"]["alpha"]
    assert "cv_forward_folds" not in fitted["selected"]
