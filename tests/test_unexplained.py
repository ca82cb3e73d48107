"""Training runs no model explains (rafi.family.unexplained): the rule on CV rows, and on a machine
whose probe was remounted the other way for some training days, through the real Snakefile."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from remounted_machine import remounted_project

from rafi.family.unexplained import COLUMNS, unexplained_runs, unexplained_text
from rafi.ops.outcome import machine_warnings


def _cv(rows: list[tuple]) -> pd.DataFrame:
    """CV rows ``(model, scheme, run, before, after)``."""
    return pd.DataFrame(
        rows, columns=["model", "scheme", "test_runs", "max_abs_before_um", "max_abs_after_um"]
    )


def test_a_run_is_named_only_when_every_model_is_worse_than_no_compensation():
    cv = _cv(
        [
            ("a", "leave_one_run_out", "r1", 10.0, 12.0),
            ("b", "leave_one_run_out", "r1", 10.0, 11.0),
            ("a", "leave_one_run_out", "r2", 10.0, 12.0),
            ("b", "leave_one_run_out", "r2", 10.0, 3.0),  # one model explains r2
            ("a", "leave_one_run_out", "r3", 5.0, np.nan),  # a never predicted r3: it does not count
            ("b", "leave_one_run_out", "r3", 5.0, 6.0),
            ("a", "forward_2", "f0:r2", 10.0, 40.0),  # a forward fold predicts from fewer runs: ignored
            ("b", "forward_2", "f0:r2", 10.0, 40.0),
        ]
    )
    table = unexplained_runs(cv)
    assert list(table.columns) == list(COLUMNS)
    assert table["run"].tolist() == ["r1", "r3"]
    assert table.set_index("run").loc["r1", ["best_model", "best_max_um", "none_max_um"]].tolist() == [
        "b",
        11.0,
        10.0,
    ]
    assert table.set_index("run").loc["r3", "models"] == 1
    text = unexplained_text(cv)
    assert text.startswith("On 2 of 3 training runs held out by the cross-validation every model")
    assert "r1 b 11.00 against 10.00 um; r3 b 6.00 against 5.00 um" in text


def test_time_blocks_of_a_single_run_are_called_so():
    cv = _cv([("a", "time_blocks", "b0", 4.0, 5.0), ("a", "time_blocks", "b1", 4.0, 1.0)])
    assert unexplained_text(cv).startswith("On 1 of 2 time blocks of the training data held out")


def test_nothing_is_said_without_such_a_run_or_without_the_table():
    fine = _cv([("a", "leave_one_run_out", "r1", 10.0, 2.0), ("a", "leave_one_run_out", "r2", 8.0, 8.0)])
    assert unexplained_runs(fine).empty and unexplained_text(fine) is None  # equal is not worse
    assert unexplained_runs(None).empty and unexplained_text(None) is None
    assert unexplained_runs(pd.DataFrame({"model": ["a"]})).empty  # an older table without the columns


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["m1", "m2", "m3"]),
            st.sampled_from(["r1", "r2", "r3", "r4"]),
            st.floats(0.0, 50.0),
            st.one_of(st.floats(0.0, 50.0), st.just(float("nan"))),
        ),
        max_size=24,
        unique_by=lambda t: (t[0], t[1]),
    )
)
def test_a_named_run_has_no_model_at_or_below_no_compensation(rows):
    before = {}
    for _, run, b, _ in rows:
        before.setdefault(run, b)  # no compensation is a property of the run
    cv = _cv([(m, "leave_one_run_out", run, before[run], after) for m, run, _, after in rows])
    named = set(unexplained_runs(cv)["run"])
    for run in before:
        scores = [after for _, r, _, after in rows if r == run and np.isfinite(after)]
        assert (run in named) == (bool(scores) and min(scores) > before[run])


# ----------------------------------------------------------------------------- the real Snakefile
@pytest.fixture(scope="module")
def remounted(tmp_path_factory):
    """The machine with its probe reversed on its last training days (tests/remounted_machine.py),
    the warning alone: with ``models.since_change`` the runs before those days are set aside
    (tests/test_since_change.py) and the CV of the rest is another."""
    return remounted_project(tmp_path_factory.mktemp("remounted"), since_change=False)


def test_the_remounted_days_are_the_runs_no_model_explains_and_the_log_says_so(remounted):
    proj, machine, reversed_days = remounted
    res = proj / "results" / machine.name
    runs = pd.read_csv(res / "runs.csv")
    day_of = dict(zip(runs["run_id"].astype(str), runs["file"].str.removesuffix(".csv")))
    table = unexplained_runs(pd.read_csv(res / "comparison" / "cv.csv"))
    assert {day_of[r] for r in table["run"]} == set(reversed_days)
    log = (proj / "logs" / machine.name / "compare.log").read_text(encoding="utf-8")
    said = [
        line
        for line in log.splitlines()
        if line.startswith(f"RAFI compare (machine={machine.name}) warning: ")
    ]
    assert len(said) == 1 and f"On {len(table)} of " in said[0] and all(r in said[0] for r in table["run"])
    # the end-of-run lines (and rafi nightly) repeat the warnings of a machine's logs under its line
    assert any(w.startswith("(compare): On ") for w in machine_warnings(proj / "logs", machine.name))
