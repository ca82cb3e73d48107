"""The streaming compensator (rafi.deploy): streaming equals batch for every model kind and for
the CV-weighted ensemble of them all."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings

import numpy as np
import pandas as pd
import pytest

from rafi import SENSORS
from rafi.contract import MODEL_KINDS
from rafi.deploy.compensator import ENSEMBLE, Compensator, parse_exponents
from rafi.deploy.streaming import LowpassBank
from rafi.family.ensemble import WeightedEnsemble
from rafi.method.model import parse_terms
from rafi.method.validate import time_ordered
from rafi.twin.synthetic_logs import schedule_log
from rafi.twin.synthetic_runs import runs_of_logs, small_family_model

PERIOD = 20.0
WINDOW = 60.0
RESTART = 3600.0
KINDS = list(MODEL_KINDS)


def _log(pieces, seed, *, segments=()):
    """A clean frame of a schedule; ``segments``: (piece index, gap s) - a logger gap before
    that piece starts a new segment (the clean step's rule for a long gap)."""
    frame, truth = schedule_log(pieces, period_s=PERIOD, seed=seed, speed_noise_rpm=3.0)
    frame["disp_um"] += 7.0  # the displacement has an arbitrary zero
    for k, gap in segments:
        first = int(truth["first_row"].iloc[k])
        frame.loc[first:, "t_s"] += gap
        frame.loc[first:, "time"] += pd.Timedelta(seconds=gap)
        frame.loc[first:, "segment"] += 1
    return frame


def _logs():
    rest = (0, 180)
    logs = {
        f"train{i}.csv": _log([rest, (s, 3 * 3600), (0, 3600)], seed=i)
        for i, s in enumerate((3000, 6000, 9000))
    }
    multi = _log(
        [rest, (4500, 3600), (7500, 2400), (0, 1800), (6000, 3600), (0, 1200), (8000, 3600)],
        seed=7,
        segments=[(4, 600.0), (6, 2 * RESTART)],  # a short gap (carried) and a long one (restart)
    )
    multi.loc[200:203, "T8"] = np.nan  # a sensor drop-out: rises NaN, the filters hold
    multi.loc[300, "speed_rpm"] = np.nan  # a missing speed
    logs["multi.csv"] = multi
    return logs


def _find_runs(logs: dict, training_speeds_rpm: list, rule: str):
    """Runs of the synthetic logs with the settings every test here uses."""
    return runs_of_logs(
        logs, training_speeds_rpm=training_speeds_rpm, reference_rule=rule, reference_window_s=WINDOW
    )


@pytest.fixture(scope="module", params=["run_start", "log_start"])
def data(request):
    rule = request.param
    table, frame = _find_runs(_logs(), [3000, 6000, 9000], rule)
    assert {"log", "log_t_s", "segment"} <= set(frame.columns)
    return rule, table, frame


def _model(kind: str, rule: str):
    return small_family_model(
        kind,
        reference_rule=rule,
        reference_window_s=WINDOW,
        filter_restart_gap_s=RESTART,
        speed_gain="cv",
    )


def _fit(kind, rule, table, frame):
    """A fitted model of ``kind``; ``ensemble``: the ensemble of every kind (:func:`_ensemble`)."""
    if kind == ENSEMBLE:
        return _ensemble(rule, table, frame)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # statsmodels conditioning warnings of fit_rafi
        return _model(kind, rule).fit(table, frame)


def _ensemble(rule, table, frame) -> WeightedEnsemble:
    """The ensemble of every kind, fitted as above, with unequal weights 1 : 2 : ... : 6 (what
    the CV would give is any such set; the blend's arithmetic is what the stream must repeat)."""
    members = {kind: _fit(kind, rule, table, frame) for kind in KINDS}
    return WeightedEnsemble.from_fitted(members, {kind: float(i + 1) for i, kind in enumerate(KINDS)})


def _stream(
    artefact: dict, frame: pd.DataFrame, rule: str, *, restart_at: int | None = None, origin: float = 0.0
) -> pd.DataFrame:
    """Every log of ``frame`` through a fresh compensator (power-on at the log's first sample),
    ``capture_reference`` at the first sample of every run (``run_start``) or segment
    (``log_start``): what the controller would be told.

    ``restart_at``: before that sample of every log the process "restarts": the compensator's
    state goes through JSON into a fresh one (:mod:`rafi.deploy.session`) whose sample clock
    starts at ``origin``."""
    from rafi.deploy.session import compensator_state, restore_compensator

    out = []
    for _, log in frame.groupby("log", sort=False):
        log = log.sort_values("log_t_s")
        comp = Compensator.from_artefact(artefact)
        key = log["run_id"] if rule == "run_start" else log["segment"]
        starts = key.ne(key.shift()).to_numpy()
        temps = log[list(SENSORS)].to_numpy(dtype=float)
        t = log["log_t_s"].to_numpy(dtype=float)
        rpm = log["speed_rpm"].to_numpy(dtype=float)
        rows, shift = [], 0.0
        for k in range(len(log)):
            if k == restart_at and k > 0:
                state = json.loads(json.dumps(compensator_state(comp), allow_nan=False))
                comp, shift = Compensator.from_artefact(artefact), origin - t[k]
                restore_compensator(comp, state, shift)
            if starts[k] and k > 0:
                comp.capture_reference()
            s = comp.step(t[k] + shift, rpm[k], temps[k])
            rows.append(
                (s.compensation_um, s.status, s.outside_speed_range, s.outside_temp_range, s.lower_um)
            )
        columns = ["um", "status", "out_speed", "out_temp", "lower_um"]
        out.append(pd.DataFrame(rows, index=log.index, columns=columns))
    return pd.concat(out).loc[frame.index]


def _in_window(frame: pd.DataFrame, rule: str) -> np.ndarray:
    """Rows inside their reference window (``t < t0 + window``), computed here from the frame."""
    key = frame["run_id"] if rule == "run_start" else frame["log"] + "/" + frame["segment"].astype(str)
    t0 = frame.groupby(key)["log_t_s"].transform("min")
    return (frame["log_t_s"] < t0 + WINDOW - 1e-9).to_numpy()


@pytest.mark.parametrize("kind", KINDS)
def test_streaming_equals_batch_for_every_kind(data, kind):
    rule, table, frame = data
    model = _fit(kind, rule, table, frame)
    artefact = json.loads(json.dumps(model.to_dict()))  # through JSON, as a controller reads it
    if kind == "dynamic":  # every filter of the family is exercised, the heat-input history too
        assert min(artefact["selected"]["taus_s"]) > 0
        assert artefact["selected"]["speed_taus_s"] == [120.0, 900.0]
    if kind == "grey_box":
        sel = artefact["selected"]
        assert sel["speed_taus_s"] and sel["instantaneous_n2"] and sel["centrifugal_lag_s"] == 20.0
    frame = time_ordered(frame)
    batch = model.predict_detail(frame)
    got = _stream(artefact, frame, rule)
    want = batch["predicted_um"].to_numpy(dtype=float)
    window = _in_window(frame, rule)
    status = got["status"].to_numpy()
    # the reference window (the device does not know its median yet): 0 um, 'referencing'
    assert (status[window] == "referencing").all() and (got["um"].to_numpy()[window] == 0.0).all()
    after = ~window
    defined = after & np.isfinite(want)
    assert defined.sum() > 0.9 * len(frame)
    np.testing.assert_allclose(got["um"].to_numpy()[defined], want[defined], rtol=0, atol=1e-9)
    assert (status[defined] == "ok").all()
    undefined = after & ~np.isfinite(want)
    assert (status[undefined] == "no_value").all() and np.isnan(got["um"].to_numpy()[undefined]).all()
    # the T8 drop-out (4 samples) and the missing speed (1); filters hold through a NaN input:
    # dynamic's rise filters through the drop-out, grey_box's speed filters through the speed;
    # temperature_ridge has no speed input (its unfiltered rise misses the drop-out)
    assert undefined.sum() == {"dynamic": 1, "grey_box": 4, "temperature_ridge": 4}.get(kind, 5)
    for flag, col in (("out_speed", "outside_speed_range"), ("out_temp", "outside_temp_range")):
        assert np.array_equal(got[flag].to_numpy()[after], batch[col].to_numpy(dtype=bool)[after])
    # the compensation is not trivially zero: the models compensate microns
    assert np.abs(want[defined]).max() > 5.0


def test_streaming_equals_batch_for_the_ensemble_of_every_kind(data):
    """Every member its own compensator (filters, reference window, envelope), blended with the
    weights over the members with a value: the batch ``WeightedEnsemble.predict_detail``."""
    rule, table, frame = data
    model = _ensemble(rule, table, frame)
    artefact = json.loads(json.dumps(model.to_dict()))
    comp = Compensator.from_artefact(artefact)
    assert comp.kind == ENSEMBLE and list(comp.members) == KINDS
    assert comp.state_nbytes == sum(m.state_nbytes for m in comp.members.values()) > 0
    frame = time_ordered(frame)
    batch = model.predict_detail(frame)
    got = _stream(artefact, frame, rule)
    want = batch["predicted_um"].to_numpy(dtype=float)
    window = _in_window(frame, rule)
    status = got["status"].to_numpy()
    assert (status[window] == "referencing").all() and (got["um"].to_numpy()[window] == 0.0).all()
    after = ~window
    # every sample has a member with a value: the drop-out and the missing speed are blended
    # over the members that still have one (the weights of the others set aside)
    assert np.isfinite(want[after]).all() and (status[after] == "ok").all()
    members = np.column_stack([m.predict(frame) for m in model.members_.values()])
    assert (after & np.isnan(members).any(axis=1)).sum() == 5
    np.testing.assert_allclose(got["um"].to_numpy()[after], want[after], rtol=0, atol=1e-9)
    for flag, col in (("out_speed", "outside_speed_range"), ("out_temp", "outside_temp_range")):
        assert np.array_equal(got[flag].to_numpy()[after], batch[col].to_numpy(dtype=bool)[after])
    assert got["out_temp"].to_numpy()[after].any() and np.abs(want[after]).max() > 5.0
    # the blend is not any one member's value
    for k in range(members.shape[1]):
        assert np.nanmax(np.abs(members[after, k] - want[after])) > 0.01


def test_an_ensemble_refuses_a_member_it_cannot_run(data):
    rule, table, frame = data
    d = json.loads(json.dumps(_ensemble(rule, table, frame).to_dict()))
    from rafi.artefact import compute_model_id

    def rewritten(**changes):
        out = {**d, **changes}
        out["model_id"] = compute_model_id(out)
        return out

    nested = rewritten(members={**d["members"], "rafi": {**d, "kind": ENSEMBLE}})
    with pytest.raises(ValueError, match="member 'rafi' is of kind 'ensemble'"):
        Compensator.from_artefact(nested)
    edited = {**d["members"]["dynamic"], "coefficients": [0.0] * len(d["members"]["dynamic"]["coefficients"])}
    with pytest.raises(ValueError, match="ensemble member 'dynamic': model_id"):
        Compensator.from_artefact(rewritten(members={**d["members"], "dynamic": edited}))
    with pytest.raises(ValueError, match="not among its members"):
        Compensator.from_artefact(rewritten(weights={**d["weights"], "neural_net": 0.1}))
    with pytest.raises(ValueError, match="T6.*do not include"):
        Compensator.from_artefact(d, sensors=[s for s in SENSORS if s != "T6"])


def test_the_filters_restart_after_a_long_gap_and_carry_through_a_short_one():
    """Known truth: a step input through one filter: ``x1 + (x0 - x1) exp(-t / tau)``."""
    tau = 300.0
    bank = LowpassBank.create([tau, 0.0], 1)
    bank.restart()
    assert bank.update(np.array([np.nan]), 0.0).tolist()[0] != bank.update(np.array([np.nan]), 0.0)[0]  # NaN
    y = [bank.update(np.array([2.0]), 10.0)]  # settled on the first finite value
    for _ in range(30):
        y.append(bank.update(np.array([5.0]), 10.0))
    want = 5.0 + (2.0 - 5.0) * np.exp(-np.arange(31) * 10.0 / tau)
    np.testing.assert_allclose([v[0] for v in y], want, rtol=0, atol=1e-12)
    assert [v[1] for v in y] == [2.0] + [5.0] * 30  # tau = 0 passes the input through
    held = bank.update(np.array([np.nan]), 10.0)
    assert held[0] == y[-1][0] and np.isnan(held[1])  # a NaN input holds the state


def test_the_filters_follow_a_change_of_step_length():
    """Known truth for steps of any length: ``y_k = x + (y_(k-1) - x) exp(-dt_k / tau)``; the
    bank keeps the coefficients of the last step length, so a step of another length (and back)
    must use its own."""
    tau = 300.0
    bank = LowpassBank.create([tau], 1)
    y = bank.update(np.array([2.0]), 0.0)[0]
    assert y == 2.0
    for dt in [5.0, 5.0, 7.0, 5.0, 60.0, 60.0, 5.0]:
        want = 5.0 + (y - 5.0) * np.exp(-dt / tau)
        y = bank.update(np.array([5.0]), dt)[0]
        assert y == pytest.approx(want, abs=1e-12)


def test_the_weights_of_a_held_speed_are_those_of_the_speed(data):
    """RAFI's weights are kept for a held speed: every speed, held or new, gets the weights of
    rafi.method.fuzzy.triangular_weights (the batch code's function)."""
    from rafi.method.fuzzy import triangular_weights

    rule, table, frame = data
    comp = Compensator.from_artefact(_fit("rafi", rule, table, frame).to_dict())
    for rpm in [3000.0, 3000.0, 4500.0, 4500.0, 3000.0, np.nan, 17999.0]:
        w, out = comp.speed_weights(rpm)
        want_w, want_out = triangular_weights([rpm], comp.speeds_rpm, tolerance_rpm=comp.speed_range_rpm[0])
        np.testing.assert_array_equal(w, want_w)
        np.testing.assert_array_equal(out, want_out)


def test_a_given_reference_equals_the_captured_one():
    """ridge_global without filters: ``set_reference`` with the window medians gives the same
    numbers as capturing the window."""
    rule = "run_start"
    logs = {"a.csv": _log([(0, 180), (5000, 7200)], seed=3), "b.csv": _log([(0, 180), (9000, 7200)], seed=4)}
    table, frame = _find_runs(logs, [5000, 9000], rule)
    model = _fit("ridge_global", rule, table, frame)
    log = frame[frame["log"] == "a.csv"].sort_values("log_t_s")
    temps = log[list(SENSORS)].to_numpy(dtype=float)
    t, rpm = log["log_t_s"].to_numpy(), log["speed_rpm"].to_numpy()
    w = t < t[0] + WINDOW - 1e-9
    captured, given = Compensator.from_artefact(model.to_dict()), Compensator.from_artefact(model.to_dict())
    given.set_reference(np.median(temps[w], axis=0), np.median(rpm[t - t[0] <= WINDOW]))
    a = [captured.step(t[k], rpm[k], temps[k]) for k in range(len(t))]
    b = [given.step(t[k], rpm[k], temps[k]) for k in range(len(t))]
    assert b[0].status == "ok" and a[0].status == "referencing"
    assert all(x.compensation_um == y.compensation_um for x, y in zip(a, b) if x.status == "ok")


def test_an_edited_or_foreign_artefact_is_refused(data):
    rule, table, frame = data
    d = _fit("rafi_linear", rule, table, frame).to_dict()
    edited = {**d, "speeds": d["speeds"][:1]}
    with pytest.raises(ValueError, match="model_id"):
        Compensator.from_artefact(edited)
    with pytest.raises(ValueError, match="kind"):
        Compensator.from_artefact({**d, "kind": "neural_net"})


def test_rafi_terms_parse_as_the_pipeline_parses_them():
    terms = ["1", "x1", "x2", "x3", "x1*x2", "x1^2", "x1*x2*x3", "x1^2*x3", "x3 ^ 2"]
    assert np.array_equal(parse_exponents(terms, 3), parse_terms(terms, 3))
    with pytest.raises(ValueError):
        parse_exponents(["x4"], 3)


def test_the_compensator_runs_without_pandas_statsmodels_or_snakemake():
    code = (
        "import sys, json\n"
        "import rafi.deploy.compensator as c\n"
        "import rafi.deploy.ensemble_stream as e\n"
        "bad = [m for m in ('pandas', 'statsmodels', 'snakemake', 'scipy', 'sklearn') if m in sys.modules]\n"
        "print(json.dumps(bad))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert json.loads(out.stdout) == []
