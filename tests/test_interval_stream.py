"""The prediction interval of the streaming compensator (issue 26): streaming equals batch.

The logs and models are those of tests/test_compensator.py (synthetic schedules with speed
changes, a sensor drop-out, a short and a long logger gap). Each fitted artefact gets an
``interval`` block by hand (its id recomputed), is fed through the compensator as a controller
would feed it, and the interval of every sample is compared with the batch rule
(:func:`rafi.family.interval_rule.batch_bounds` over the layout of
:func:`rafi.family.whole_log.layout`, resets at the layout's restarts and each reference
group's first row) around the batch ``predict_detail`` value.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from test_compensator import KINDS, WINDOW, _find_runs, _fit, _in_window, _logs

from rafi import SENSORS
from rafi.artefact import compute_model_id, model_id_verifies
from rafi.deploy.compensator import Compensator
from rafi.family.interval_rule import INTERVAL_SCHEMA, batch_bounds, change_resets
from rafi.family.whole_log import layout
from rafi.method.validate import time_ordered

#: Half-widths far apart, so that a wrong cell cannot pass for a right one.
BLOCK = {
    "schema": INTERVAL_SCHEMA,
    "method": "split_conformal_by_run",
    "level": 0.9,
    "transient_s": 1800.0,
    "tolerance_rpm": 50.0,
    "half_width_um": {"settled": 1.5, "transient": 2.75, "outside": 4.125},
    "decorrelation_s": 600.0,
    "calibration": {"note": "set by hand for the test"},
}


def with_interval(artefact: dict, block: dict = BLOCK) -> dict:
    """``artefact`` with an ``interval`` block and its id recomputed (as the pipeline writes it)."""
    d = {**json.loads(json.dumps(artefact)), "interval": json.loads(json.dumps(block))}
    d["model_id"] = compute_model_id(d)
    assert model_id_verifies(d)
    return d


@pytest.fixture(scope="module", params=["run_start", "log_start"])
def data(request):
    rule = request.param
    table, frame = _find_runs(_logs(), [3000, 6000, 9000], rule)
    return rule, table, time_ordered(frame)


def stream(artefact: dict, frame: pd.DataFrame, rule: str) -> pd.DataFrame:
    """Every log through a fresh compensator, ``capture_reference`` at the first sample of every
    run (``run_start``) or segment (``log_start``); every field of every step, frame order."""
    out = []
    for _, log in frame.groupby("log", sort=False):
        log = log.sort_values("log_t_s")
        comp = Compensator.from_artefact(artefact)
        key = log["run_id"] if rule == "run_start" else log["segment"]
        starts = key.ne(key.shift()).to_numpy()
        temps = log[list(SENSORS)].to_numpy(dtype=float)
        t, rpm = log["log_t_s"].to_numpy(dtype=float), log["speed_rpm"].to_numpy(dtype=float)
        steps = []
        for k in range(len(log)):
            if starts[k] and k > 0:
                comp.capture_reference()
            steps.append(comp.step(t[k], rpm[k], temps[k])._asdict())
        out.append(pd.DataFrame(steps, index=log.index))
    return pd.concat(out).loc[frame.index]


def batch_interval(model, artefact: dict, frame: pd.DataFrame, rule: str) -> dict:
    """The batch interval of every row of ``frame`` (frame order), from the shared rule."""
    detail = model.predict_detail(frame)
    restart_gap_s = Compensator.from_artefact(artefact).restart_gap_s  # RAFI kinds: no filter, inf
    lay = layout(frame, rule=rule, window_s=WINDOW, restart_gap_s=restart_gap_s)
    outside = detail["outside_speed_range"].to_numpy(dtype=bool) | detail["outside_temp_range"].to_numpy(
        dtype=bool
    )
    got = batch_bounds(
        artefact["interval"],
        predicted_um=detail["predicted_um"].to_numpy(dtype=float)[lay.order],
        t_s=lay.t,
        speed_rpm=frame["speed_rpm"].to_numpy(dtype=float)[lay.order],
        reset=change_resets(lay.restart, lay.ref_group),
        outside=outside[lay.order],
    )
    out = {}
    for name, values in got.items():
        back = np.empty_like(values)
        back[lay.order] = values
        out[name] = back
    out["predicted_um"] = detail["predicted_um"].to_numpy(dtype=float)
    return out


@pytest.mark.parametrize("kind", KINDS)
def test_streaming_intervals_equal_the_batch_ones(data, kind):
    rule, table, frame = data
    model = _fit(kind, rule, table, frame)
    artefact = with_interval(model.to_dict())
    got = stream(artefact, frame, rule)
    want = batch_interval(model, artefact, frame, rule)
    after = ~_in_window(frame, rule)
    defined = after & np.isfinite(want["predicted_um"])
    assert defined.sum() > 0.9 * len(frame)
    cells = got["interval_cell"].to_numpy()
    np.testing.assert_array_equal(cells[defined], want["interval_cell"][defined])
    for col in ("lower_um", "upper_um"):
        np.testing.assert_allclose(got[col].to_numpy()[defined], want[col][defined], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(got["half_width_um"].to_numpy()[defined], want["half_width_um"][defined])
    # every cell is met, and the clock is reset by speed moves, not only at the runs' starts
    counts = pd.Series(cells[defined]).value_counts()
    assert set(counts.index) == {"settled", "transient", "outside"} and counts.min() > 20
    # the interval is around the model's value; none where the model has none
    um, width = got["compensation_um"].to_numpy(), got["upper_um"] - got["lower_um"]
    np.testing.assert_allclose(width, 2 * got["half_width_um"], rtol=0, atol=1e-12)
    np.testing.assert_allclose((got["upper_um"] + got["lower_um"])[defined] / 2, um[defined], atol=1e-9)
    none = got["status"].to_numpy() == "no_value"
    assert none.any() and np.isnan(got["lower_um"].to_numpy()[none]).all() and (cells[none] == "").all()
    # while the reference is collected: around 0 um, never outside (the flags are not known yet)
    window = ~after
    assert (got["status"].to_numpy()[window] == "referencing").all()
    lower, h = got["lower_um"].to_numpy(), got["half_width_um"].to_numpy()
    np.testing.assert_array_equal(lower[window], -h[window])
    assert set(cells[window]) <= {"transient", "settled"}


def test_streaming_intervals_equal_the_batch_ones_for_an_ensemble(data):
    """The ensemble's own block, its own change clock (reset at the shortest member's restart
    gap and at every capture), ``outside`` where any member is, widened by the largest member's
    range excess: the batch ``interval_columns`` of the ensemble (what validation reports)."""
    from rafi.family.interval_rule import EXCESS_SLOPE
    from rafi.family.intervals import interval_columns

    rule, table, frame = data
    model = _fit("ensemble", rule, table, frame)
    artefact = with_interval(model.to_dict(), {**BLOCK, "excess_slope": EXCESS_SLOPE})
    assert Compensator.from_artefact(artefact).restart_gap_s == min(
        m.get("hyperparameters", {}).get("filter_restart_gap_s", np.inf) for m in artefact["members"].values()
    )
    got = stream(artefact, frame, rule)
    detail = model.predict_detail(frame)
    outside = (detail["outside_speed_range"] | detail["outside_temp_range"]).to_numpy(dtype=bool)
    excess = detail["range_excess"].to_numpy(dtype=float)
    want = interval_columns(
        artefact, frame, detail["predicted_um"].to_numpy(dtype=float), outside, excess=excess
    )
    after = ~_in_window(frame, rule)
    assert np.isfinite(detail["predicted_um"].to_numpy()[after]).all()
    cells = got["interval_cell"].to_numpy()
    np.testing.assert_array_equal(cells[after], want["interval_cell"].to_numpy()[after])
    for col in ("lower_um", "upper_um"):
        np.testing.assert_allclose(got[col].to_numpy()[after], want[col].to_numpy()[after], rtol=0, atol=1e-9)
    # the component excess reads every feature, which the stream's filters and the batch's agree on
    # to about 1e-12 before the gains along the components scale it
    np.testing.assert_allclose(got["range_excess"].to_numpy()[after], excess[after], rtol=0, atol=1e-9)
    # every cell is met, and the excess widens some intervals
    counts = pd.Series(cells[after]).value_counts()
    assert set(counts.index) == {"settled", "transient", "outside"} and counts.min() > 20
    assert (excess[after] > 0.1).sum() > 20


def test_the_clock_resets_at_a_restart_a_capture_and_a_speed_move():
    """Known truth on a hand-written series: the cells follow the documented resets."""
    from test_limits import artefact as hand_artefact
    from test_limits import temps16

    block = {**BLOCK, "transient_s": 100.0}
    comp = Compensator.from_artefact(with_interval(hand_artefact(), block))  # window 60 s, gap 3600 s
    temps = temps16([20.0, 21.0, 22.0])

    def cells(times, speed=5000.0):
        return [comp.step(t, speed, temps).interval_cell for t in times]

    assert cells(range(0, 200, 10)) == ["transient"] * 10 + ["settled"] * 10  # reset at the first sample
    assert cells([200.0], speed=5040.0) == ["settled"]  # within tolerance_rpm of the anchor
    assert cells([210.0, 300.0, 310.0], speed=5060.0) == ["transient", "transient", "settled"]  # moved
    assert cells([310.0 + 3601.0, 310.0 + 3701.0], speed=5060.0) == ["transient", "settled"]  # restart
    comp.capture_reference()
    assert cells([4100.0, 4190.0, 4200.0], speed=5060.0) == ["transient", "transient", "settled"]
    s = comp.step(4210.0, 9500.0, temps)  # above the trained speeds, and a speed move
    assert (s.interval_cell, s.half_width_um, s.outside_speed_range) == ("outside", 4.125, True)


def test_an_artefact_without_the_block_runs_without_an_interval(data):
    rule, table, frame = data
    model = _fit("dynamic", rule, table, frame)
    plain = json.loads(json.dumps(model.to_dict()))
    assert "interval" not in plain
    log = frame[frame["log"] == frame["log"].iloc[0]]
    a, b = stream(plain, log, rule), stream(with_interval(plain), log, rule)
    np.testing.assert_array_equal(a["compensation_um"], b["compensation_um"])
    assert a[["lower_um", "upper_um", "half_width_um"]].isna().all().all()
    assert (a["interval_cell"] == "").all() and (b["interval_cell"] != "").any()


def test_a_broken_block_is_refused_with_its_keys_named():
    from test_limits import artefact as hand_artefact

    broken = with_interval(hand_artefact(), {"level": 0.9, "half_width_um": {"settled": 1.0}})
    with pytest.raises(ValueError, match="interval block"):
        Compensator.from_artefact(broken)


def test_the_replay_table_carries_the_interval_and_the_summary_its_coverage(data):
    """``rafi replay``: per-sample bounds equal to the batch ones, and per run the coverage and
    median width of the measurement against the model's interval after the reference window."""
    from test_replay import OPEN, _replay_every_log

    from rafi.deploy.replay import COLUMNS, SUMMARY_COLUMNS, replay_summary, summary_frame

    rule, table, frame = data
    model = _fit("grey_box", rule, table, frame)
    artefact = with_interval(model.to_dict())
    got = _replay_every_log(frame, artefact, OPEN)
    assert list(got.columns) == list(COLUMNS)
    want = batch_interval(model, artefact, frame, rule)
    ok = (got["status"] == "ok").to_numpy() & np.isfinite(want["predicted_um"])
    assert ok.sum() > 0.9 * len(frame)
    for col in ("lower_um", "upper_um"):
        np.testing.assert_allclose(got[col].to_numpy()[ok], want[col][ok], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(got["interval_cell"].to_numpy()[ok], want["interval_cell"][ok])
    summary = replay_summary(got)
    for rid, g in got.groupby("run_id"):
        use = g[(g["status"] != "referencing") & g["lower_um"].notna() & g["measured_um"].notna()]
        inside = (use["measured_um"] >= use["lower_um"]) & (use["measured_um"] <= use["upper_um"])
        assert summary[rid]["coverage"] == pytest.approx(inside.mean())
        assert summary[rid]["interval_width_um"] == pytest.approx(
            (use["upper_um"] - use["lower_um"]).median()
        )
    assert all(0 <= r["coverage"] <= 1 and r["interval_width_um"] >= 3.0 for r in summary.values())
    assert {"coverage", "interval_width_um"} <= set(summary_frame(summary, artefact=artefact).columns)
    assert {"coverage", "interval_width_um"} <= set(SUMMARY_COLUMNS)
    plain = replay_summary(_replay_every_log(frame, json.loads(json.dumps(model.to_dict())), OPEN))
    assert all(np.isnan(r["coverage"]) and np.isnan(r["interval_width_um"]) for r in plain.values())
