"""Training on the runs since a change (rafi.family.since_change): the change found among the
runs no model explains, property tests of the search, and a machine whose probe was remounted the
other way for its last training days, through the real Snakefile with ``models.since_change``."""

from __future__ import annotations

import io

import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from remounted_machine import remounted_project

from rafi.family.since_change import (
    CHANGE_COLUMNS,
    MAX_EXCEPTION_SHARE,
    change_of,
    change_table,
    change_text,
    find_change,
    recorded_order,
    set_aside_before,
    set_aside_count,
    speeds_covered,
)
from rafi.ops.outcome import machine_warnings

ORDER = [f"r{i:02d}" for i in range(12)]


def test_named_runs_since_a_change_set_aside_the_runs_before_it():
    change = find_change(ORDER, {"r06", "r07", "r09", "r11"})  # r08, r10 unnamed: two exceptions
    assert change.first_run == "r06" and change.named_side == "since" and change.exceptions == 2
    assert change.set_aside == tuple(ORDER[:6])
    assert change.named == ("r06", "r07", "r09", "r11")


def test_named_runs_before_a_change_are_set_aside_with_it():
    change = find_change(ORDER, {"r00", "r01", "r02"})
    assert change.first_run == "r03" and change.named_side == "before" and change.exceptions == 0
    assert change.set_aside == ("r00", "r01", "r02")


def test_scattered_named_runs_find_no_change():
    assert find_change(ORDER, {"r01", "r05", "r10"}) is None  # every cut has more than 1.5 exceptions
    assert find_change(ORDER, set()) is None
    assert find_change(ORDER, {"elsewhere"}) is None  # a run not among the training runs


def test_at_least_three_runs_lie_since_the_change():
    # r10, r11 named: the cut at r10 would leave two runs; at r09 one exception, half of two named
    change = find_change(ORDER, {"r10", "r11"})
    assert change.first_run == "r09" and change.exceptions == 1
    assert find_change(ORDER, {"r11"}) is None  # the cut at r09: two exceptions for one named run
    assert find_change(ORDER, {"r10", "r11"}, min_since=2).first_run == "r10"


def test_the_earliest_of_equal_changes_is_taken():
    # r04 named alone: cuts at r04 (named since, exceptions = the 7 unnamed after) and r05 (named
    # before, exceptions 4) are no good; with r04-r11 all named the cut at r04 has none
    assert find_change(ORDER, set(ORDER[4:])).first_run == "r04"
    # two runs named on either side of one unnamed: cutting before or after it costs one
    change = find_change(ORDER[:8], {"r03", "r05", "r06", "r07"})
    assert change.first_run == "r03" and change.exceptions == 1


@settings(max_examples=200, deadline=None)
@given(n=st.integers(2, 30), data=st.data())
def test_a_change_found_separates_the_named_runs_within_its_exceptions(n, data):
    order = [f"run{i}" for i in range(n)]
    named = set(data.draw(st.lists(st.sampled_from(order), max_size=n, unique=True)))
    change = find_change(order, named)
    if change is None:
        return
    cut = order.index(change.first_run)
    before, since = set(order[:cut]), set(order[cut:])
    named_side, other = (since, before) if change.named_side == "since" else (before, since)
    exceptions = len(named_side - named) + len(other & named)
    assert exceptions == change.exceptions <= MAX_EXCEPTION_SHARE * len(named)
    assert len(since) >= 3 and change.set_aside == tuple(order[:cut]) and cut >= 1


@settings(max_examples=100, deadline=None)
@given(n=st.integers(4, 30), data=st.data())
def test_a_clean_suffix_or_prefix_is_found_exactly(n, data):
    order = [f"run{i}" for i in range(n)]
    cut = data.draw(st.integers(1, n - 3))
    suffix = data.draw(st.booleans())
    named = set(order[cut:]) if suffix else set(order[:cut])
    change = find_change(order, named)
    assert change is not None and change.exceptions == 0
    assert change.first_run == order[cut] and change.named_side == ("since" if suffix else "before")


def test_recorded_order_is_by_start_time_then_file():
    table = pd.DataFrame(
        {
            "run_id": ["b#1", "a#2", "a#1", "v#1"],
            "role": ["training", "training", "training", "validation_single"],
            "file": ["b.csv", "a.csv", "a.csv", "v.csv"],
            "start_s": [0.0, 600.0, 0.0, 0.0],
            "start_time": ["2026-06-02T08:00:00", "2026-06-01T09:00:00", "2026-06-01T08:00:00", ""],
        }
    )
    assert recorded_order(table) == ["a#1", "a#2", "b#1"]
    assert recorded_order(table.drop(columns=["start_time"])) == ["a#1", "a#2", "b#1"]


def test_logs_without_a_clock_are_in_the_natural_order_of_their_names():
    names = ["Sheet1", "Sheet10", "Sheet11", "Sheet12", "Sheet2", "Sheet9"]
    table = pd.DataFrame(
        {"run_id": names, "role": "training", "file": names, "start_s": 0.0, "start_time": float("nan")}
    )
    assert recorded_order(table) == ["Sheet1", "Sheet2", "Sheet9", "Sheet10", "Sheet11", "Sheet12"]


def test_set_aside_runs_are_excluded_with_the_reason_and_the_table_is_a_copy():
    table = pd.DataFrame(
        {"run_id": ORDER, "role": ["training"] * 12, "role_reason": ["window"] * 12, "start_s": range(12)}
    )
    change = find_change(ORDER, set(ORDER[8:]))
    out = set_aside_before(table, change)
    assert (table["role"] == "training").all()  # the input is not touched
    assert out.loc[out["role"] == "excluded", "run_id"].tolist() == ORDER[:8]
    assert out.loc[0, "role_reason"].startswith("set aside: recorded before a change found at r08")


def test_the_change_table_holds_every_run_in_recorded_order_with_its_cv_figures():
    table = pd.DataFrame({"run_id": ORDER, "role": "training", "start_s": range(12), "speed_rpm": 1000.0})
    cv = _cv_naming(ORDER[8:])
    change = change_of(cv, table, tolerance_rpm=50)
    out = change_table(change, cv, table)
    assert list(out.columns) == list(CHANGE_COLUMNS) and out["run_id"].tolist() == ORDER
    assert out["order"].tolist() == list(range(1, 13))
    assert out.loc[out["set_aside"], "run_id"].tolist() == ORDER[:8]
    assert out.loc[out["unexplained"], "run_id"].tolist() == ORDER[8:]
    assert out["none_max_um"].eq(5.0).all() and out.loc[8, "best_max_um"] == 9.0
    assert change_text(out).startswith(
        "8 training runs recorded before a change found at r08 were set aside (r00 to r07): the 4 "
        "training runs no model explains lie from it on, with 0 exceptions"
    )
    back = pd.read_csv(io.StringIO(out.to_csv(index=False)))  # as the report reads it
    assert change_text(back) == change_text(out) and set_aside_count(back) == 8
    assert change_table(None, cv, table).empty and change_text(change_table(None, cv, table)) is None
    assert set_aside_count(None) == 0


def _cv_naming(runs) -> pd.DataFrame:
    """CV rows of one model on ``ORDER``, worse than no compensation on ``runs``."""
    rows = [("m", "leave_one_run_out", r, 5.0, 9.0 if r in runs else 1.0) for r in ORDER]
    return pd.DataFrame(
        rows, columns=["model", "scheme", "test_runs", "max_abs_before_um", "max_abs_after_um"]
    )


def test_change_of_reads_the_cv_rows():
    table = pd.DataFrame(
        {
            "run_id": ORDER,
            "role": ["training"] * 12,
            "start_s": range(12),
            "speed_rpm": [1000, 2000, 3000] * 4,
        }
    )
    assert change_of(_cv_naming(ORDER[9:]), table, tolerance_rpm=50).first_run == "r09"
    assert change_of(None, table, tolerance_rpm=50) is None


def test_no_change_where_the_runs_since_miss_a_speed_of_those_before():
    # a programme recorded in order of speed: the top speeds held out are extrapolations that
    # every model may miss; the runs since (9000-11000 r/min) do not cover the speeds before
    table = pd.DataFrame(
        {
            "run_id": ORDER,
            "role": "training",
            "start_s": range(12),
            "speed_rpm": [1000.0 * (i + 1) for i in range(12)],
        }
    )
    change = find_change(ORDER, set(ORDER[9:]))
    assert change is not None and not speeds_covered(change, table, tolerance_rpm=50)
    assert change_of(_cv_naming(ORDER[9:]), table, tolerance_rpm=50) is None


# ----------------------------------------------------------------------------- the real Snakefile
@pytest.fixture(scope="module")
def remounted(tmp_path_factory):
    """The machine with its probe reversed on its last training days (tests/remounted_machine.py),
    with ``models.since_change``."""
    return remounted_project(tmp_path_factory.mktemp("since-change"), since_change=True)


def test_the_runs_before_the_remounting_are_set_aside_and_the_models_learn_from_the_rest(remounted):
    proj, machine, reversed_days = remounted
    res = proj / "results" / machine.name
    runs = pd.read_csv(res / "runs.csv")  # the runs step's table is not rewritten
    training = runs.loc[runs["role"] == "training"]
    since = training["file"].str.removesuffix(".csv").isin(reversed_days)
    table = pd.read_csv(res / "comparison" / "since_change.csv")
    assert table["run_id"].tolist() == recorded_order(runs)
    assert sorted(table.loc[table["set_aside"], "run_id"]) == sorted(training.loc[~since, "run_id"])
    assert (table["named_side"] == "since").all()
    assert (table["exceptions"] <= MAX_EXCEPTION_SHARE * table["unexplained"].sum()).all()
    cv = pd.read_csv(res / "comparison" / "cv.csv")
    held = set(cv.loc[cv["scheme"] == "leave_one_run_out", "test_runs"].astype(str))
    assert held == set(training.loc[since, "run_id"])  # the CV saw the runs since the change only
    log = (proj / "logs" / machine.name / "compare.log").read_text(encoding="utf-8")
    said = [line for line in log.splitlines() if "were set aside" in line]
    assert len(said) == 1 and said[0].startswith(f"RAFI compare (machine={machine.name}) warning: ")
    assert any("were set aside" in w for w in machine_warnings(proj / "logs", machine.name))
