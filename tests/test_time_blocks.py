"""Time-blocked folds for training data without a whole-run fold (issue 25, item 3).

A single long training run has no whole-run fold; rafi.family.time_blocks cuts its training time
into blocks with guard gaps. Tests: the fold builder with exact indices, a property test that no
training sample of any fold (outer or nested) lies within the gap of a held-out sample, the
displacement of a held-out block and its gaps reaching no fitted number, the filter grids cut at
gap / 3, and a single-run log made by a generator with known truth getting folds and a chosen
model from run_family (docs/models.md, "Time-blocked folds").
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from project_copy import copy_project, run_snakemake

from rafi.family.compare import cv_data, run_family
from rafi.family.crossval import GUARD, HELD_OUT, cross_validate, hold_out, split_runs, training_runs
from rafi.family.dynamic import DynamicRidge
from rafi.family.time_blocks import (
    GAP_PER_TAU,
    SCHEME,
    UNIT,
    block_count,
    max_filter_s,
    time_block_folds,
    time_block_units,
    training_clock,
)
from rafi.method.runs import find_runs
from rafi.settings import MACHINE_DEFAULTS
from rafi.twin.synthetic_logs import schedule_log

H = 3600.0
GATES = {"max_residual_um": 12.0, "min_improvement_pct": 30.0, "never_worse_than_uncompensated": True}


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def _runs(spec):
    """A per-run table and frame: ``spec`` = [(run_id, role, n_samples, period_s)], runs one after
    the other on one clock (``t_s`` from each run's start, ``log_t_s`` on the shared clock)."""
    rows, parts, t0 = [], [], 0.0
    for rid, role, n, period in spec:
        t = np.arange(n) * period
        rows.append({"run_id": rid, "role": role, "speed_rpm": 6000.0})
        parts.append(
            pd.DataFrame({"run_id": rid, "t_s": t, "abs_t": t0 + t, "speed_rpm": 6000.0, "dz_um": 0.0})
        )
        t0 += n * period + 600.0
    return pd.DataFrame(rows), pd.concat(parts, ignore_index=True)


# --------------------------------------------------------------------------- the fold builder


def test_blocks_and_gaps_of_one_run_with_exact_indices():
    """100 samples at 60 s (6000 s), 4 blocks, 600 s gaps: blocks of (6000 - 3 x 600) / 4 =
    1050 s, a block and its gap every 1650 s."""
    table, frame = _runs([("r", "training", 100, 60.0), ("v", "validation_single", 30, 60.0)])
    units, uframe = time_block_units(table, frame, n_blocks=4, gap_s=600.0)
    got = uframe.loc[uframe["run_id"] == "r", UNIT].to_numpy()
    want = np.array(
        ["r@block1"] * 18
        + ["r@gap1"] * 10
        + ["r@block2"] * 17
        + ["r@gap2"] * 10
        + ["r@block3"] * 18
        + ["r@gap3"] * 10
        + ["r@block4"] * 17
    )
    np.testing.assert_array_equal(got, want)
    assert (uframe.loc[uframe["run_id"] == "v", UNIT] == "v").all()
    assert list(units[UNIT]) == [
        "v",
        *[f"r@{u}" for u in "block1 gap1 block2 gap2 block3 gap3 block4".split()],
    ]
    folds = list(split_runs(units, "leave_one_run_out"))  # the unit table decides the scheme
    assert folds == [
        (["r@block2", "r@gap2", "r@block3", "r@gap3", "r@block4"], ["r@block1"]),
        (["r@block1", "r@block3", "r@gap3", "r@block4"], ["r@block2"]),
        (["r@block1", "r@gap1", "r@block2", "r@block4"], ["r@block3"]),
        (["r@block1", "r@gap1", "r@block2", "r@gap2", "r@block3"], ["r@block4"]),
    ]
    # held-out block 2 = rows 28..44; it trains on rows 0..17 and 55..99 (block 3, gap 3, block 4):
    # the nearest are 17 and 55, 660 s away; gap 1 (18..27) and gap 2 (45..54) are left out
    train_rows = np.flatnonzero(np.isin(got, folds[1][0]))
    assert set(train_rows) == set(range(0, 18)) | set(range(55, 100))
    assert set(np.flatnonzero(np.isin(got, folds[1][1]))) == set(range(28, 45))


def test_block_count_follows_the_training_time_only():
    assert block_count(24 * H, 60.0, 4, 3 * H) == (4, 3.75 * H)
    assert block_count(12 * H, 60.0, 4, 3 * H) == (2, 4.5 * H)  # 4 and 3 blocks would be < 3 h
    assert block_count(8 * H, 60.0, 4, 3 * H) is None  # 2 blocks of 2.5 h: shorter than the gap
    assert block_count(600.0, 60.0, 4, 0.0) == (4, 150.0)
    assert block_count(120.0, 60.0, 4, 0.0) == (2, 60.0)


def test_the_training_clock_never_runs_ahead_of_the_log_clock():
    t = np.array([0.0, 60, 120, 5000, 5060, 9000, 9060, 9120])
    runs = np.array(["a", "a", "a", "b", "b", "c", "c", "c"])
    clock, period = training_clock(t, runs)
    np.testing.assert_array_equal(clock, [0, 60, 120, 120, 180, 180, 240, 300])
    assert period == 60.0
    assert (np.subtract.outer(clock, clock) <= np.subtract.outer(t, t) + 1e-9)[np.tril_indices(len(t))].all()


@st.composite
def _single_run_layouts(draw):
    runs = draw(
        st.lists(st.tuples(st.integers(20, 160), st.sampled_from([15.0, 60.0])), min_size=1, max_size=3)
    )
    spec = [(f"t{i}", "training", n, p) for i, (n, p) in enumerate(runs)]
    spec.insert(draw(st.integers(0, len(spec))), ("v", "validation_single", 10, 60.0))
    return spec, draw(st.integers(2, 6)), draw(st.sampled_from([0.0, 300.0, 900.0, 2400.0]))


def _log_clock(frame, units):
    return {u: frame.loc[frame[UNIT] == u, "abs_t"].to_numpy() for u in units}


@settings(max_examples=60, deadline=None)
@given(_single_run_layouts())
def test_no_training_sample_lies_within_the_gap_of_a_held_out_sample(layout):
    """Outer folds and the nested folds inside each: every block held out once, never a gap,
    and every training sample more than gap_s (log clock) from every held-out sample."""
    spec, n_blocks, gap = layout
    table, frame = _runs(spec)
    got = time_block_units(table, frame, n_blocks=n_blocks, gap_s=gap)
    if got is None:
        return
    units, uframe = got
    blocks = sorted(u for u in units[UNIT] if "@block" in u)
    folds = list(time_block_folds(units))
    assert sorted(u for _, test in folds for u in test) == blocks
    for train, test in folds:
        clock = _log_clock(uframe, train + test)
        held = np.concatenate([clock[u] for u in test])
        trained = np.concatenate([clock[u] for u in train])
        assert np.abs(np.subtract.outer(trained, held)).min() > gap
        fold_table = hold_out(hold_out(units, test), set(units[UNIT]) - set(train) - set(test) - {"v"}, GUARD)
        for inner_train, inner_test in time_block_folds(fold_table):
            assert not (set(inner_train) | set(inner_test)) - set(train)
            inner = _log_clock(uframe, inner_train + inner_test)
            a = np.concatenate([inner[u] for u in inner_test])
            b = np.concatenate([inner[u] for u in inner_train])
            assert np.abs(np.subtract.outer(b, a)).min() > gap


# --------------------------------------------------------------------------- fits on the folds


TRAIN_SCHEDULE = [
    (0, 600),
    (9000, 6 * H),
    (3000, 5 * H),
    (12000, 4 * H),
    (6000, 6 * H),
    (0, 3 * H),
    (9000, 6 * H),
]
VALIDATION_SCHEDULE = [(0, 600), (12000, 3 * H), (3000, 3 * H), (9000, 2 * H)]


def _single_run_log(hours_train=24.0, seed=3):
    """The issue's case: one long log at one logged speed (no speed column: the reader gives every
    row 6000 r/min, a training speed) whose hidden duty varies, 60 s rows, no windows; a second
    log at 4500 r/min validates. Returns the runs and the truth: per log the noise-free
    displacement of the generator (um)."""
    schedule = [s for s in TRAIN_SCHEDULE]
    over = sum(d for _, d in schedule) - hours_train * H
    while over > 0:  # shorten the schedule from its end to ``hours_train``
        speed, d = schedule.pop()
        if d > over:
            schedule.append((speed, d - over))
        over -= d
    logs, truth = {}, {}
    for name, sched, rpm, k in (
        ("spindle_a", schedule, 6000.0, 0),
        ("spindle_b", VALIDATION_SCHEDULE, 4500.0, 1),
    ):
        log, _ = schedule_log(sched, period_s=60.0, seed=seed + k, noise_disp=0.1)
        clean, _ = schedule_log(sched, period_s=60.0, seed=seed + k, noise_temp=0.0, noise_disp=0.0)
        logs[name] = log.assign(speed_rpm=rpm)
        truth[name] = clean["disp_um"].to_numpy()
    table, frame = find_runs(
        logs,
        {k: "0" * 64 for k in logs},
        training_speeds_rpm=[6000],
        speed_tolerance_rpm=50,
        idle_below_rpm=100,
        min_run_s=1800,
        min_constant_s=3600,
        overrides={},
        reference_rule="run_start",
        reference_window_s=60,
    )
    return table, frame, truth


def _options(**changes):
    return {**MACHINE_DEFAULTS["models"], **changes}


def test_a_held_out_block_and_its_gaps_reach_no_fitted_number():
    """Poisoning the displacement of the held-out block and of the gaps beside it leaves the
    fold's model (coefficients, inner CV scores) bit-identical: the nested CV never trains on them."""
    table, frame, _ = _single_run_log()
    units, uframe = cv_data(table, frame, _options(), log=lambda m: None)
    train, test = list(time_block_folds(units))[1]
    guards = set(units.loc[units["role"] == "training", UNIT]) - set(train) - set(test)
    assert guards == {"spindle_a@gap1", "spindle_a@gap2"}
    fold_table = hold_out(hold_out(units, test), guards, GUARD)
    assert set(training_runs(fold_table, uframe)[1][UNIT]) == set(train)
    poisoned = uframe.assign(dz_um=np.where(uframe[UNIT].isin(set(test) | guards), 1e6, uframe["dz_um"]))

    def fit(f):
        return DynamicRidge(taus_s="auto", alphas=[1e-4, 1e-2], reference=MACHINE_DEFAULTS["reference"]).fit(
            fold_table, f
        )

    a, b = fit(uframe), fit(poisoned)
    np.testing.assert_array_equal(a.coef_, b.coef_)
    assert a.cv_table_ == b.cv_table_ and len(a.cv_table_)
    assert set(fold_table.loc[fold_table["role"] == HELD_OUT, UNIT]) == set(test)


def test_filter_grids_stop_at_a_third_of_the_gap():
    table, frame, _ = _single_run_log()
    units, uframe = cv_data(table, frame, _options(cv_time_block_gap_s=5400), log=lambda m: None)
    assert max_filter_s(units) == 5400 / GAP_PER_TAU
    m = DynamicRidge(taus_s=[0, 600, 1800, 5400], alphas=[1e-3], reference=MACHINE_DEFAULTS["reference"])
    m.fit(units, uframe)
    assert m.grids_["dynamic_taus_s"] == [0.0, 600.0, 1800.0]
    art = m.to_dict()
    assert art["selected"]["cv_folds"] == {
        "scheme": SCHEME,
        "blocks": 4,
        "gap_s": 5400.0,
        "max_filter_s": 1800.0,
    }
    assert art["train_runs"] == ["spindle_a"]
    # on the runs as they are (whole runs, no unit table) nothing is cut and nothing is recorded
    plain = DynamicRidge(taus_s=[0, 600, 1800, 5400], alphas=[1e-3], reference=MACHINE_DEFAULTS["reference"])
    assert "cv_folds" not in plain.fit(table, frame).to_dict()["selected"]


def test_a_single_run_log_gets_folds_and_a_chosen_model():
    """The done-when of issue 25: a single long training run, no windows, gets time-blocked CV
    folds and a model chosen by them (before: no fold, RAFI offered by the default rule)."""
    table, frame, truth = _single_run_log()
    assert list(table.loc[table["role"] == "training", "run_id"]) == ["spindle_a"]
    assert list(table.loc[table["role"] != "training", "role"]) == ["validation_single"]
    messages = []
    res = _family(table, frame, _options(), log=messages.append)
    cv = res["cv"]
    assert set(cv["scheme"]) == {SCHEME}
    assert set(cv["test_runs"]) == {f"spindle_a@block{k}" for k in (1, 2, 3, 4)}
    assert res["selection_basis"] == "cv"
    assert res["champion"] == res["selection"]["model"].iloc[0]
    assert (res["selection"]["cv_folds"] == 4).all()
    assert any("4 time blocks with 3 h guard gaps" in m for m in messages)
    champion = res["summary"].set_index("model").loc[res["champion"]]
    assert champion["max_abs_after_um"] < 0.5 * champion["max_abs_before_um"]
    # the models offered are fitted on every training sample, blocks and gaps alike
    dyn = res["models"]["dynamic"]
    assert dyn.n_ == int(np.isfinite(frame.loc[frame["run_id"] == "spindle_a", "dz_um"]).sum())
    assert dyn.train_runs_ == ["spindle_a"] and dyn.time_blocks_["blocks"] == 4
    # its prediction interval is calibrated on the held-out blocks: the blocks are the units
    cal = dyn.to_dict()["interval"]["calibration"]
    assert (cal["scheme"], cal["units"], cal["n_runs"]) == (SCHEME, "time blocks", 4)
    assert (
        "chosen on 4 time blocks with 3 h guard gaps"
        in res["summary"].set_index("model").loc["dynamic", "selected"]
    )
    # against the truth (the generator's noise-free displacement, from its reference sample) on
    # the validation log: the offered model is within 15 % of the 22 um change
    r = res["residuals"]
    r = r[(r["model"] == res["champion"]) & (r["run_id"] == "spindle_b")]
    true_dz = truth["spindle_b"] - truth["spindle_b"][0]
    error = r["predicted_um"].to_numpy() - true_dz[np.round(r["t_s"].to_numpy() / 60.0).astype(int)]
    assert np.abs(error).max() < 0.15 * np.abs(true_dz).max()


def _family(table, frame, options, *, log=lambda m: None) -> dict:
    """``run_family`` on a single-run log of :func:`_single_run_log` (its key sensors)."""
    return run_family(
        table,
        frame,
        key_sensors=["T6", "T8", "T9"],
        terms=MACHINE_DEFAULTS["fit"]["terms"],
        reference=MACHINE_DEFAULTS["reference"],
        machine="spindle",
        gates=GATES,
        options=options,
        log=log,
    )


def test_too_little_training_time_keeps_the_default_rule():
    table, frame, _ = _single_run_log(hours_train=8.0)
    assert cv_data(table, frame, _options(), log=lambda m: None)[0] is table
    res = _family(table, frame, _options(enabled=["rafi_linear", "ridge_global"]))
    assert res["selection_basis"] == "default" and res["cv"].empty


def test_whole_runs_keep_whole_run_folds():
    """Two or more training runs: the runs as they are, the configured scheme (nothing changes)."""
    table, frame, _ = _single_run_log()
    two = table.assign(role=np.where(table["run_id"] == "spindle_b", "training", table["role"]))
    got_table, got_frame = cv_data(two, frame, _options(), log=lambda m: None)
    assert got_table is two and got_frame is frame
    cv = cross_validate(
        lambda: DynamicRidge(taus_s=[0, 600], alphas=[1e-3], reference=MACHINE_DEFAULTS["reference"]),
        two,
        frame,
        name="dynamic",
    )
    assert set(cv["scheme"]) == {"leave_one_run_out"} and set(cv["test_runs"]) == {"spindle_a", "spindle_b"}


# --------------------------------------------------------------------------- what the report says


def test_the_report_says_time_blocks_where_it_would_say_whole_runs():
    from test_report_text import _section

    from rafi.family.selection import SELECTION_RULE, SELECTION_RULE_TIME_BLOCKS
    from rafi.report.choices import section_choices
    from rafi.report.comparison_section import selection_context
    from rafi.settings import machine_settings

    settings = machine_settings({"machines": {"m": {}}}, "m")
    for blocks, said, unsaid in (
        (
            True,
            "come from time-blocked cross-validation (too few training runs",
            "whole-run cross-validation",
        ),
        (False, "come from whole-run cross-validation (leave_one_run_out)", "time-blocked"),
    ):
        html = _section("choices", choices=section_choices(settings, {}, None, time_blocks=blocks))
        text = " ".join(html.split())
        assert said in text and unsaid not in text
    summary = pd.DataFrame(
        {
            "model": ["dynamic"],
            "cv_mean_max_abs_um": [1.0],
            "cv_max_abs_um": [1.5],
            "passed": [True],
            "max_abs_after_um": [2.0],
            "noise_floor_um": [0.5],
        }
    )
    sel = selection_context(summary, "dynamic", SCHEME)
    assert sel["rule"] == SELECTION_RULE_TIME_BLOCKS and sel["time_blocks"] and sel["basis"] == "cv"
    sel = selection_context(summary, "dynamic", "leave_one_run_out")
    assert sel["rule"] == SELECTION_RULE and not sel["time_blocks"]


# --------------------------------------------------------------------------- the real Snakefile

SINGLE_RUN_CONFIG = """
raw_dir: raw
results_dir: results
reports_dir: reports
on_bad_input: fail
defaults: {}
machines:
  spindle-d:
    sample_period_s: 60
    training_speeds_rpm: [6000]
    input:
      format: csv
      pattern: "*.csv"
      delimiter: ";"
      columns:
        disp_um: "Z [um]"
      time: {kind: none, period_s: 60, start: "2026-03-02T06:00:00"}
      speed: {constant_rpm: 6000}
    runs:
      windows:
        - {role: training, end: 0.6, unit: fraction}
        - {role: validation, start: 0.6, unit: fraction}
"""


def test_the_pipeline_offers_a_model_chosen_on_time_blocks_for_a_single_run_log(tmp_path):
    """The issue's second log in small: a motorised spindle at one speed, one row per minute, no
    time or speed column, 16 temperatures, a 60/40 split in two windows (the training part is one
    run). The real Snakefile: time-blocked folds, a champion chosen on them, a report that says so."""
    proj = copy_project(tmp_path / "project", config=False)
    (proj / "config.yaml").write_text(SINGLE_RUN_CONFIG, encoding="utf-8")
    schedule = [*TRAIN_SCHEDULE, (3000, 4 * H), (12000, 4 * H), (6000, 6 * H)]  # 44 h
    log, _ = schedule_log(schedule, period_s=60.0, seed=5)
    table = log[[f"T{i}" for i in range(1, 17)]].round(3).assign(**{"Z [um]": log["disp_um"].round(3)})
    (proj / "raw" / "spindle-d").mkdir(parents=True)
    table.to_csv(proj / "raw" / "spindle-d" / "spindle_44h.csv", sep=";", index=False)
    done = run_snakemake(proj, cores=2)
    assert done.returncode == 0, done.stderr[-3000:]
    out = proj / "results" / "spindle-d" / "comparison"
    runs = pd.read_csv(proj / "results" / "spindle-d" / "runs.csv")
    assert list(runs["role"]) == ["training", "validation_single"]
    cv = pd.read_csv(out / "cv.csv")
    assert set(cv["scheme"]) == {SCHEME}
    assert (cv.groupby("model").size() == 4).all()
    summary = pd.read_csv(out / "summary.csv")
    champion = summary.loc[summary["champion"].astype(bool), "model"].item()
    assert champion == summary.sort_values("selection_rank")["model"].iloc[0]
    assert np.isfinite(summary["cv_mean_max_abs_um"]).all()
    assert json.loads((out / "best_model.json").read_text())["kind"] == champion
    assert "4 time blocks with 3 h guard gaps" in (proj / "logs" / "spindle-d" / "compare.log").read_text()
    report = " ".join((proj / "reports" / "spindle-d" / "qualification.html").read_text().split())
    assert "weighted from those held-out scores" in report  # the ensemble, offered by default
    assert "by held-out time blocks of the training data" in report
    assert "whole-run CV on the training runs" not in report
