"""Limits and fault rules of the compensator (rafi.deploy.limits) and the qualified model
(rafi.deploy.qualified).

The model here is a hand-written ``ridge_global`` artefact: its value is ``c . (T - T0)``
with ``T0`` the temperatures of the reference window, so every expected command is computed
from that formula and the documented rules, not from the code under test.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rafi import SENSORS
from rafi.artefact import compute_model_id
from rafi.deploy.limits import Limits, SafeCompensator
from rafi.deploy.qualified import check_qualified, load_champion
from rafi.errors import SettingsError, TargetError, UnqualifiedModel
from rafi.ops.registry import Registry
from rafi.settings import MACHINE_DEFAULTS

KEY = ["T6", "T8", "T9"]
COEF = np.array([2.0, -1.0, 0.5])
BASE = np.array([20.0, 21.0, 22.0])  # the reference temperatures of KEY
WINDOW = 60.0
DT = 10.0


def artefact(*, taus=(0.0,), ranges=((-1, 10), (-1, 10), (-1, 10)), speed_range=(0.0, 9000.0)) -> dict:
    feats = [f"d{s}@{tau:g}s" for tau in taus for s in KEY]
    d = {
        "schema": "rafi.model/1",
        "kind": "ridge_global",
        "key_sensors": KEY,
        "features": feats,
        "coefficients": list(np.tile(COEF, len(taus))),
        "selected": {"taus_s": list(taus), "speed_gain": False, "speed_terms": False},
        "hyperparameters": {"speed_tolerance_rpm": 50, "filter_restart_gap_s": 3600},
        "regressor_ranges": {s: list(r) for s, r in zip(KEY, ranges)},
        "speed_range_rpm": list(speed_range),
        "reference": {"rule": "run_start", "window_s": WINDOW},
        "speed_reference": {"rule": "zero"},
    }
    d["model_id"] = compute_model_id(d)
    return d


def limits(**kw) -> Limits:
    wide = dict(
        MACHINE_DEFAULTS["deploy"],
        clamp_um=[-1e6, 1e6],
        rate_um_per_s=1e6,
        range_margin_k=1e6,
        speed_margin_rpm=1e6,
        interval_s=DT,  # one sample per write
    )
    return Limits.from_settings({**wide, **kw})


def temps16(key_values) -> np.ndarray:
    out = np.full(16, 25.0)
    for s, v in zip(KEY, key_values):
        out[SENSORS.index(s)] = v
    return out


def run(safe: SafeCompensator, rows, *, t0=0.0):
    """Feed ``rows`` of (speed, key temperatures) every DT seconds from t0; the commands."""
    return [safe.step(t0 + i * DT, n, temps16(k)) for i, (n, k) in enumerate(rows)]


def warm(n_ref: int, n_ramp: int, rate_k_per_sample=0.05, speed=6000.0):
    """A reference window at BASE, then every key temperature rising linearly."""
    rows = [(speed, BASE.copy()) for _ in range(n_ref)]
    rows += [(speed, BASE + rate_k_per_sample * (i + 1)) for i in range(n_ramp)]
    return rows


def model_value(key_values) -> float:
    return float(COEF @ (np.asarray(key_values) - BASE))


N_REF = int(WINDOW / DT)  # samples with t < t0 + window: the reference window


def test_without_a_model_compensation_is_off_and_nothing_is_sent():
    safe = SafeCompensator(limits=limits())
    cmd = safe.step(0.0, 6000.0, temps16(BASE))
    assert (cmd.status, cmd.command_um, cmd.send) == ("off", 0.0, False)
    assert not hasattr(safe, "compensator_")


def test_with_the_limits_wide_open_the_command_is_the_models_value():
    rows = warm(N_REF, 50)
    out = run(SafeCompensator(limits=limits()).load(artefact()), rows)
    assert [c.status for c in out[:N_REF]] == ["referencing"] * N_REF
    assert all(c.command_um == 0.0 for c in out[:N_REF])
    for c, (_, k) in zip(out[N_REF:], rows[N_REF:]):
        assert c.status == "ok" and c.send and c.fault == ""
        assert c.command_um == pytest.approx(model_value(k), abs=1e-12)
        assert not (c.clamped or c.rate_limited)


def test_the_clamp_bounds_the_command_and_says_so():
    rows = warm(N_REF, 200, rate_k_per_sample=0.1)  # the model reaches 1.5 * 0.1 * 200 = 30 um
    out = run(SafeCompensator(limits=limits(clamp_um=[-5.0, 12.0])).load(artefact()), rows)
    for c, (_, k) in zip(out[N_REF:], rows[N_REF:]):
        expected = min(model_value(k), 12.0)
        assert c.command_um == pytest.approx(expected, abs=1e-12)
        assert c.clamped == (model_value(k) > 12.0)
        assert c.status == "ok"
    assert max(c.command_um for c in out) == 12.0


def test_the_rate_limit_spreads_a_step_and_says_so():
    rate = 0.05  # um/s: 0.5 um per 10 s sample
    rows = [(6000.0, BASE.copy()) for _ in range(N_REF)]
    rows += [(6000.0, BASE + np.array([2.0, 0.0, 0.0]))] * 30  # a 4 um step of the model
    out = run(SafeCompensator(limits=limits(rate_um_per_s=rate)).load(artefact()), rows)
    after = out[N_REF:]
    expected = [min(0.5 * (i + 1), 4.0) for i in range(len(after))]
    assert [c.command_um for c in after] == pytest.approx(expected, abs=1e-12)
    assert [c.rate_limited for c in after] == [i < 7 for i in range(len(after))]  # 4.0 is reached freely
    assert all(c.model_um == pytest.approx(4.0) for c in after)


def test_after_a_long_gap_the_command_resumes_at_the_rate_limit_not_in_one_step():
    lim = limits(rate_um_per_s=0.05, interval_s=10.0, stuck_s=1e6)
    safe = SafeCompensator(limits=lim).load(artefact())
    run(safe, [(6000.0, BASE.copy())] * (N_REF + 1))
    cmd = safe.step(N_REF * DT + 3600.0, 6000.0, temps16(BASE + [2.0, 0, 0]))  # an hour later
    assert cmd.command_um == pytest.approx(0.5) and cmd.rate_limited


def test_a_sensor_dropping_out_holds_then_ramps_to_the_safe_value_then_recovers():
    lim = limits(hold_s=100.0, ramp_um_per_s=0.02, safe_um=0.0, rate_um_per_s=1.0)
    rows = warm(N_REF, 40, rate_k_per_sample=0.1)  # model 6 um at the end
    good = model_value(rows[-1][1])
    drop = [(6000.0, np.array([rows[-1][1][0], np.nan, rows[-1][1][2]]))] * 40  # T8 gone, 400 s
    back = [(6000.0, rows[-1][1])] * 20
    out = run(SafeCompensator(limits=lim).load(artefact()), rows + drop + back)
    fault = out[len(rows) : len(rows) + len(drop)]
    assert all("T8 missing" in c.fault for c in fault)
    t_fault = fault[0].t_s
    for c in fault:
        if c.t_s - t_fault < 100.0:
            assert (c.status, c.command_um) == ("hold", pytest.approx(good, abs=1e-12))
        else:  # ramps down at 0.02 um/s: 0.2 um per sample from the held value
            assert c.status == "ramp"
            steps = round((c.t_s - t_fault - 100.0) / DT) + 1
            assert c.command_um == pytest.approx(max(good - 0.2 * steps, 0.0), abs=1e-9)
    recovered = out[len(rows) + len(drop) :]
    assert all(c.status == "ok" and c.fault == "" for c in recovered)
    # back to the model's value under the rate limit (1 um/s: 10 um per sample: at once here)
    assert recovered[-1].command_um == pytest.approx(good, abs=1e-12)


def test_a_value_out_of_range_is_a_fault_and_never_reaches_the_filters():
    lim = limits(hold_s=1e6)
    art = artefact(taus=(600.0,))
    rows = warm(N_REF, 30)
    spike = list(rows)
    spike[N_REF + 10] = (6000.0, np.array([850.0, *rows[N_REF + 10][1][1:]]))  # open thermocouple
    nan = list(rows)
    nan[N_REF + 10] = (6000.0, np.array([np.nan, *rows[N_REF + 10][1][1:]]))
    with_spike = run(SafeCompensator(limits=lim).load(art), spike)
    with_nan = run(SafeCompensator(limits=lim).load(art), nan)
    assert "T6 out of range (850 degC)" in with_spike[N_REF + 10].fault
    assert with_spike[N_REF + 10].status == "hold"
    # the filter state after the spike is the one a missing value leaves (held)
    assert [c.model_um for c in with_spike[N_REF + 11 :]] == [c.model_um for c in with_nan[N_REF + 11 :]]


def test_a_stuck_sensor_is_a_fault_only_while_the_others_move():
    lim = limits(stuck_s=300.0, stuck_change_k=0.5, hold_s=1e6)
    n = 80
    moving = [(6000.0, np.array([BASE[0], BASE[1] + 0.05 * i, BASE[2] + 0.05 * i])) for i in range(n)]
    out = run(SafeCompensator(limits=lim).load(artefact()), moving)
    for i, c in enumerate(out):
        # T6 unchanged since t=0; T8 moved by 0.05 i K: stuck once 300 s passed and 0.5 K moved
        stuck = i * DT >= 300.0 and 0.05 * i >= 0.5 - 1e-12
        assert ("T6 stuck" in c.fault) == stuck, (i, c)
    still = [(6000.0, BASE.copy()) for _ in range(n)]  # the whole machine at rest: nothing stuck
    assert all(c.fault == "" for c in run(SafeCompensator(limits=lim).load(artefact()), still))


def test_outside_the_trained_range_holds_but_rest_is_normal_service():
    lim = limits(range_margin_k=1.0, speed_margin_rpm=500.0, hold_s=1e6)
    art = artefact(ranges=((-1, 3), (-1, 3), (-1, 3)), speed_range=(3000.0, 9000.0))
    rows = warm(N_REF, 60, rate_k_per_sample=0.1)  # rises reach 6 K: beyond 3 + 1 after 40
    out = run(SafeCompensator(limits=lim).load(art), rows)
    for i, c in enumerate(out[N_REF:]):
        rise = 0.1 * (i + 1)
        assert c.outside_range == (rise > 4.0 + 1e-9), (i, c)
        assert c.status == ("hold" if c.outside_range else "ok")
    fast = [(9600.0, BASE.copy())] * (N_REF + 3) + [(9400.0, BASE.copy())]
    out = run(SafeCompensator(limits=lim).load(art), fast)
    assert "speed 9600 r/min above trained 9000 r/min" in out[N_REF].fault
    assert out[-1].fault == ""  # within the margin
    rest = run(SafeCompensator(limits=lim).load(art), [(0.0, BASE.copy())] * (N_REF + 3))
    assert all(c.fault == "" for c in rest)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(
            st.floats(0.1, 5000.0),  # dt
            st.one_of(st.just(math.nan), st.floats(0.0, 20000.0)),  # speed
            st.lists(st.one_of(st.just(math.nan), st.floats(-50.0, 200.0)), min_size=3, max_size=3),
        ),
        min_size=1,
        max_size=60,
    ),
    st.floats(0.01, 5.0),
    st.floats(1.0, 100.0),
)
def test_whatever_comes_in_the_command_is_finite_clamped_and_rate_limited(samples, rate, clamp):
    lim = limits(clamp_um=[-clamp, clamp], rate_um_per_s=rate, interval_s=5.0, hold_s=50.0)
    safe = SafeCompensator(limits=lim).load(artefact(taus=(0.0, 300.0)))
    t, prev = 0.0, 0.0
    for dt, n, k in samples:
        t += dt
        c = safe.step(t, n, temps16(k))
        assert math.isfinite(c.command_um) and -clamp <= c.command_um <= clamp
        assert abs(c.command_um - prev) <= rate * min(dt, 5.0) + 1e-9
        assert c.status in ("referencing", "ok", "hold", "ramp")
        prev = c.command_um


def test_settings_come_from_the_deploy_block_and_bad_ones_are_refused():
    lim = Limits.from_settings(MACHINE_DEFAULTS["deploy"])
    assert lim.clamp_um == (-50.0, 50.0) and lim.rate_um_per_s == 0.2
    with pytest.raises(SettingsError, match="deploy.clamp_um"):
        limits(clamp_um=[5.0, -5.0])
    with pytest.raises(SettingsError, match="deploy.safe_um"):
        limits(clamp_um=[-5.0, 5.0], safe_um=10.0)
    with pytest.raises(SettingsError, match="deploy.rate_um_per_s"):
        limits(rate_um_per_s=0)


def test_only_the_registry_champion_is_qualified(tmp_path):
    reg = Registry(tmp_path / "m" / "registry")
    with pytest.raises(UnqualifiedModel, match="no champion"):
        load_champion(reg.root)
    champion, other = artefact(), artefact(taus=(0.0, 600.0))
    reg.save_model(champion)
    reg.save_model(other)
    reg.set_champion(champion["model_id"], reason="test")
    assert load_champion(reg.root) == champion
    check_qualified(champion, reg.root)
    with pytest.raises(UnqualifiedModel, match="not the champion"):
        check_qualified(other, reg.root)
    edited = dict(champion, coefficients=[9.0, 9.0, 9.0])
    with pytest.raises(UnqualifiedModel, match="does not verify"):
        check_qualified(edited, reg.root)
    path = reg.model_path(champion["model_id"])
    path.chmod(0o644)
    path.write_text(json.dumps(edited), encoding="utf-8")
    with pytest.raises(UnqualifiedModel, match="modified"):
        load_champion(reg.root)


def test_limits_and_qualification_run_without_pandas():
    code = (
        "import sys, json\n"
        "import rafi.deploy.limits, rafi.deploy.qualified\n"
        "print(json.dumps([m for m in ('pandas', 'statsmodels', 'snakemake') if m in sys.modules]))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert json.loads(out.stdout) == []


def test_clamped_is_said_only_when_the_clamp_changed_the_command_sent():
    """The model far beyond the clamp while the rate limit still holds the command back: only
    `rate limited`; the clamp acts once the command reaches it."""
    rows = [(6000.0, BASE.copy()) for _ in range(N_REF)] + [(6000.0, BASE + [20.0, 0, 0])] * 30  # 40 um
    out = run(
        SafeCompensator(limits=limits(clamp_um=[-12.0, 12.0], rate_um_per_s=0.2)).load(artefact()), rows
    )
    after = out[N_REF:]
    assert [c.command_um for c in after[:6]] == pytest.approx([2.0, 4.0, 6.0, 8.0, 10.0, 12.0])
    assert [(c.clamped, c.rate_limited) for c in after[:5]] == [(False, True)] * 5
    assert (after[5].clamped, after[5].rate_limited) == (True, False)  # 12 um: the clamp, not the rate
    assert all(c.clamped and not c.rate_limited for c in after[6:])


def test_the_command_starts_from_the_controller_and_a_fault_holds_it_there():
    lim = limits(rate_um_per_s=0.1, hold_s=30.0, ramp_um_per_s=0.05, safe_um=0.0)  # 1 um, 0.5 um a sample
    safe = SafeCompensator(limits=lim).load(artefact()).start_from(-6.8)
    drop = [(6000.0, np.array([20.0, np.nan, 22.0]))] * 6  # T8 missing from the first sample
    out = run(safe, drop)
    assert [c.status for c in out] == ["hold"] * 3 + ["ramp"] * 3
    assert [c.command_um for c in out] == pytest.approx([-6.8, -6.8, -6.8, -6.3, -5.8, -5.3])
    safe = SafeCompensator(limits=lim).load(artefact()).start_from(None)  # not known: safe_um
    assert run(safe, drop[:1])[0].command_um == 0.0
    ok = SafeCompensator(limits=lim).load(artefact()).start_from(5.0)
    assert [c.command_um for c in run(ok, [(6000.0, BASE)] * 3)] == pytest.approx(
        [5.0, 4.0, 3.0]
    )  # referencing
    ok.resume_from(-2.0)  # after a reconnect the controller holds another value
    assert ok.step(3600.0, 6000.0, temps16(BASE)).command_um == pytest.approx(-1.0)
    with pytest.raises(TargetError, match="holds 60 um, outside deploy.clamp_um"):
        SafeCompensator(limits=limits(clamp_um=[-50.0, 50.0])).load(artefact()).start_from(60.0)


def test_a_swapped_model_compensates_from_the_session_reference():
    """A new model swapped in while the machine is warm is referenced to the power-on state
    (all 16 sensors), not to the warm state of the swap, and reached at the rate limit."""
    safe = SafeCompensator(limits=limits(rate_um_per_s=0.1)).load(artefact())  # 1 um a sample
    rows = warm(N_REF, 20, rate_k_per_sample=0.05)
    run(safe, rows)
    assert safe.reference_temperatures_[[SENSORS.index(s) for s in KEY]] == pytest.approx(BASE)
    assert safe.reference_temperatures_[0] == 25.0  # every sensor, not only the model's
    other = dict(artefact(), key_sensors=["T1", "T8", "T9"])
    other["features"] = [f"d{s}@0s" for s in other["key_sensors"]]
    other["regressor_ranges"] = {s: [-1, 10] for s in other["key_sensors"]}
    other["model_id"] = compute_model_id(other)
    before = safe.command_um_
    safe.swap(other)
    warm_now = temps16(BASE + 1.0)
    warm_now[0] = 26.0  # T1 1 K above its power-on 25 degC
    steps = [safe.step((N_REF + 20 + i) * DT, 6000.0, warm_now) for i in range(40)]
    expected = float(COEF @ [1.0, 1.0, 1.0])  # the rises from the session's reference
    assert steps[0].status == "ok" and steps[0].model_um == pytest.approx(expected)
    assert abs(steps[0].command_um - before) <= 1.0 + 1e-12
    assert steps[-1].command_um == pytest.approx(expected)


def ensemble(members: dict, weights: dict) -> dict:
    """A hand-written ensemble artefact of the ``members`` (name -> artefact) with ``weights``."""
    d = {
        "schema": "rafi.model/1",
        "kind": "ensemble",
        "key_sensors": list(dict.fromkeys(s for a in members.values() for s in a["key_sensors"])),
        "reference": {"rule": "run_start", "window_s": WINDOW},
        "weights": weights,
        "members": members,
        "hyperparameters": {"filter_restart_gap_s": 3600},
    }
    d["model_id"] = compute_model_id(d)
    return d


def t1_model(coef=(3.0, 1.0, -2.0)) -> dict:
    """A ridge_global on T1, T8, T9."""
    d = dict(artefact(), key_sensors=["T1", "T8", "T9"], coefficients=list(coef))
    d["features"] = [f"d{s}@0s" for s in d["key_sensors"]]
    d["regressor_ranges"] = {s: [-1, 10] for s in d["key_sensors"]}
    d["model_id"] = compute_model_id(d)
    return d


def test_an_ensemble_blends_its_members_is_swapped_in_bumplessly_and_checks_every_sensor_they_read():
    """Known truth: the weighted mean of two hand-written ridges (weights 1 : 3), each from the
    session's reference; a sensor only one member reads is checked, and without it the bare
    ensemble is the other member alone."""
    from rafi.deploy.compensator import Compensator

    ens = ensemble({"a": artefact(), "b": t1_model()}, {"a": 1.0, "b": 3.0})
    safe = SafeCompensator(limits=limits(rate_um_per_s=0.1)).load(artefact())  # 1 um a sample
    run(safe, warm(N_REF, 20, rate_k_per_sample=0.05))
    before = safe.command_um_
    safe.swap(ens)
    assert safe.compensator_.kind == "ensemble"
    warm_now = temps16(BASE + 1.0)
    warm_now[0] = 27.0  # T1 2 K above its power-on 25 degC
    steps = [safe.step((N_REF + 20 + i) * DT, 6000.0, warm_now) for i in range(40)]
    a, b = float(COEF @ [1.0, 1.0, 1.0]), 3.0 * 2.0 + 1.0 * 1.0 - 2.0 * 1.0
    assert steps[0].status == "ok" and steps[0].model_um == pytest.approx(0.25 * a + 0.75 * b)
    assert abs(steps[0].command_um - before) <= 1.0 + 1e-12
    assert steps[-1].command_um == pytest.approx(0.25 * a + 0.75 * b)
    no_t1 = warm_now.copy()
    no_t1[0] = np.nan
    held = safe.step((N_REF + 60) * DT, 6000.0, no_t1)
    assert held.status == "hold" and held.fault == "T1 missing"
    bare = Compensator.from_artefact(ens)
    bare.set_reference(temps16(BASE), 6000.0)
    assert bare.step(0.0, 6000.0, no_t1).compensation_um == pytest.approx(a)


# ------------------------------------------------------------------ the interval fault (issue 26)
#: 2 um wide settled, 4 um in the 100 s after a reset of the change clock, 10 um outside.
INTERVAL = {
    "schema": "rafi.interval/1",
    "level": 0.9,
    "transient_s": 100.0,
    "tolerance_rpm": 50.0,
    "half_width_um": {"settled": 1.0, "transient": 2.0, "outside": 5.0},
}


def sure_artefact(block=INTERVAL) -> dict:
    d = {**artefact(), "interval": block}
    d["model_id"] = compute_model_id(d)
    return d


def _speed_step_rows():
    """The warm-up at 6000 r/min (t = 0..450 s), then 7000 r/min with the temperatures held."""
    rows = warm(N_REF, 40, rate_k_per_sample=0.1)
    return rows + [(7000.0, rows[-1][1])] * 20


def test_an_interval_wider_than_the_limit_holds_then_ramps_and_names_its_cause():
    lim = limits(hold_s=50.0, ramp_um_per_s=0.02, safe_um=0.0, rate_um_per_s=1.0, max_interval_um=3.0)
    rows = _speed_step_rows()
    out = run(SafeCompensator(limits=lim).load(sure_artefact()), rows)
    cause = "interval_wide: 4 um wider than deploy.max_interval_um 3 um"
    # the clock starts at power-on: the first 100 s are a transient (4 um > 3 um), held at the
    # value of the referencing state (safe_um); the reference window itself is not checked
    assert [c.status for c in out[:N_REF]] == ["referencing"] * N_REF
    assert [(c.status, c.command_um, c.fault) for c in out[N_REF:10]] == [("hold", 0.0, cause)] * (10 - N_REF)
    assert all(c.status == "ok" and c.fault == "" for c in out[10 : len(rows) - 20])
    good = model_value(rows[-21][1])
    assert out[len(rows) - 21].command_um == pytest.approx(good, abs=1e-12)
    # the speed step resets the clock: 100 s of a wide interval, held 50 s, then ramped, then ok
    step = out[len(rows) - 20 :]
    assert [c.fault for c in step[:10]] == [cause] * 10 and all(c.fault == "" for c in step[10:])
    assert [c.status for c in step[:10]] == ["hold"] * 5 + ["ramp"] * 5
    assert [c.command_um for c in step[:10]] == pytest.approx(
        [good] * 5 + [good - 0.2 * k for k in range(1, 6)]
    )
    assert all(c.status == "ok" and c.command_um == pytest.approx(good, abs=1e-12) for c in step[10:])
    # the interval reported is the model's, also while the command is held or ramped
    for c in out[N_REF:]:
        h = 2.0 if c.fault else 1.0
        assert (c.lower_um, c.upper_um, c.half_width_um) == pytest.approx((c.model_um - h, c.model_um + h, h))
        assert c.interval_cell == ("transient" if c.fault else "settled")


def test_the_interval_fault_is_off_by_default_and_without_the_block():
    assert MACHINE_DEFAULTS["deploy"]["max_interval_um"] is None and limits().max_interval_um is None
    rows = _speed_step_rows()
    off = run(SafeCompensator(limits=limits()).load(sure_artefact()), rows)
    assert all(c.status == "ok" and c.fault == "" for c in off[N_REF:])
    assert {c.interval_cell for c in off[N_REF:]} == {"transient", "settled"}  # reported all the same
    plain = run(SafeCompensator(limits=limits(max_interval_um=0.001)).load(artefact()), rows)
    assert all(c.status == "ok" and c.fault == "" for c in plain[N_REF:])
    assert all(math.isnan(c.lower_um) and c.interval_cell == "" for c in plain)
    for bad in (0, -1.0, True, "wide"):
        with pytest.raises(SettingsError, match="deploy.max_interval_um"):
            limits(max_interval_um=bad)
