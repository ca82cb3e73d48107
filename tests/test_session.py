"""The session of rafi deploy across a restart (rafi.deploy.session): kept or captured anew by
the documented rule, and a kept session continues as if the process had never stopped.

Two oracles from outside the code under test:
* the batch prediction of every model kind (``predict_detail``): a compensator restarted at any
  sample (its state through JSON into a fresh one, a new clock origin) still equals it after
  the reference window, as the uninterrupted compensator does (tests/test_compensator.py);
* the limit rules written again by hand in tests/test_live.py (``expected_commands``): a
  restart of the loop in every phase (referencing, ok, hold, ramp) gives the commands of that
  oracle with the restart as the docs say it (the command goes on from the value the
  controller holds, not moving at the first sample; the reference, the fault timer kept).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from test_compensator import _fit, _in_window, _stream
from test_live import DEPLOY, DT, KEY, artefact, expected_commands, scenario

from rafi import SENSORS
from rafi.deploy.compensator import Compensator
from rafi.deploy.limits import Limits, SafeCompensator
from rafi.deploy.session import (
    SCHEMA,
    SessionFile,
    SessionKeeper,
    compensator_state,
    decide,
    restore_compensator,
)
from rafi.method.validate import time_ordered

START_WALL = 1_800_000_000.0  # 2027-01-15: any wall clock serves


# --------------------------------------------------------------------------- the model's state


@pytest.mark.parametrize("kind", ["dynamic", "grey_box", "rafi"])
@pytest.mark.parametrize("cut", [2, 150, 420])  # inside the first window, mid-run, late
def test_a_restarted_compensator_equals_the_uninterrupted_one_and_the_batch(data, kind, cut):
    rule, table, frame = data
    model = _fit(kind, rule, table, frame)
    art = json.loads(json.dumps(model.to_dict()))
    frame = time_ordered(frame)
    whole = _stream(art, frame, rule)
    restarted = _stream(art, frame, rule, restart_at=cut, origin=5.0e5)
    np.testing.assert_array_equal(restarted["status"].to_numpy(), whole["status"].to_numpy())
    want = model.predict_detail(frame)["predicted_um"].to_numpy(dtype=float)
    defined = ~_in_window(frame, rule) & np.isfinite(want)
    got = restarted["um"].to_numpy()
    np.testing.assert_allclose(got[defined], want[defined], rtol=0, atol=1e-9)
    np.testing.assert_allclose(got, whole["um"].to_numpy(), rtol=0, atol=1e-9)


@pytest.mark.parametrize("cut", [2, 420])
def test_a_restarted_ensemble_equals_the_uninterrupted_one_and_the_batch(data, cut):
    """The ensemble's state is every member's (reference, window, filters) and its own change
    clock: restored at any sample, it goes on as the uninterrupted one, the interval too."""
    from test_interval_stream import with_interval

    rule, table, frame = data
    model = _fit("ensemble", rule, table, frame)
    art = with_interval(model.to_dict())
    frame = time_ordered(frame)
    state = compensator_state(Compensator.from_artefact(art))
    assert list(state["members"]) == list(model.weights_) and state["change_clock"] is not None
    whole = _stream(art, frame, rule)
    restarted = _stream(art, frame, rule, restart_at=cut, origin=5.0e5)
    np.testing.assert_array_equal(restarted["status"].to_numpy(), whole["status"].to_numpy())
    want = model.predict_detail(frame)["predicted_um"].to_numpy(dtype=float)
    after = ~_in_window(frame, rule)
    np.testing.assert_allclose(restarted["um"].to_numpy()[after], want[after], rtol=0, atol=1e-9)
    np.testing.assert_allclose(restarted["um"].to_numpy(), whole["um"].to_numpy(), rtol=0, atol=1e-9)
    lower = whole["lower_um"].to_numpy()
    assert np.isfinite(lower).all()  # the ensemble's interval, around 0 um while referencing
    np.testing.assert_allclose(restarted["lower_um"].to_numpy(), lower, rtol=0, atol=1e-9)


@pytest.fixture(scope="module", params=["run_start", "log_start"])
def data(request):
    from test_compensator import _find_runs, _logs

    rule = request.param
    table, frame = _find_runs(_logs(), [3000, 6000, 9000], rule)
    return rule, table, frame


def test_a_state_of_another_model_or_other_filters_is_refused():
    comp = Compensator.from_artefact(artefact())
    comp.step(0.0, 1000.0, np.full(16, 20.0))
    state = compensator_state(comp)
    other = Compensator.from_artefact(artefact(coef=[1.0, 2.0, 3.0]))
    with pytest.raises(ValueError, match="of model"):
        restore_compensator(other, state, 0.0)
    state["banks"] = {"rise": {"state": [[1.0]], "seen": [True]}}
    with pytest.raises(ValueError, match="filters"):
        restore_compensator(Compensator.from_artefact(artefact()), state, 0.0)


# --------------------------------------------------------------------------- keep or anew


def _stored(**over) -> dict:
    state = {
        "schema": SCHEMA,
        "unit": "m1",
        "sensors": list(SENSORS),
        "last_sample_at_s": START_WALL,
        "clock": "session",
        "clock_s": 100.0,
        "reference": {"temperatures": [20.0] * 16, "speed_rpm": 0.0},
        "model": {"window": None},
    }
    state.update(over)
    return state


def _decide(state, temps=None, *, now=START_WALL + 60.0, **kw):
    kw = {"unit": "m1", "sensors": SENSORS, "read_sensors": KEY, "cold_band_k": 1.0, "max_age_h": 24, **kw}
    return decide(state, now_s=now, temperatures=temps, **kw)


def _temps(**values) -> np.ndarray:
    out = np.full(16, 20.0)
    for name, value in values.items():
        out[SENSORS.index(name)] = value
    return out


@pytest.mark.parametrize(
    ("state", "kw", "reason"),
    [
        (None, {}, "no stored session"),
        (_stored(unit="m2"), {}, "of 'm2'"),
        (_stored(sensors=["A", "B"]), {}, "other sensors"),
        (_stored(reference=None), {}, "had not started its reference"),
        (_stored(), {"now": START_WALL + 25 * 3600}, "25.0 h old (deploy.session_max_age_h: 24)"),
        (_stored(), {"now": START_WALL - 600}, "the clock reads 10 min before"),
    ],
)
def test_a_session_that_cannot_be_trusted_is_not_kept(state, kw, reason):
    decision = _decide(state, _temps(T6=40.0), **kw)
    assert not decision.keep and reason in decision.reason


def test_the_cold_rule_looks_at_the_sensors_the_model_reads_above_their_reference():
    # every read sensor at most cold_band_k above its reference: cold (colder counts too)
    assert not _decide(_stored(), _temps(T6=21.0, T8=15.0, T9=20.5)).keep
    # one read sensor above the band: warm, and the line names it
    warm = _decide(_stored(), _temps(T6=21.0, T8=22.5, T9=20.0))
    assert warm.keep and "T8 is +2.5 K" in warm.reason and warm.gap_s == pytest.approx(60.0)
    # a sensor the model does not read does not make the machine warm
    assert not _decide(_stored(), _temps(T1=35.0)).keep
    # no value of any read sensor: nothing says it is cold, so it is kept
    assert _decide(_stored(), _temps(T6=np.nan, T8=np.nan, T9=np.nan)).keep
    # a band of 3 K makes the same machine cold
    assert not _decide(_stored(), _temps(T8=22.5), cold_band_k=3.0).keep


def test_both_sessions_on_a_followed_log_need_no_clock_shift():
    state = _stored(clock="log")
    assert _decide(state, _temps(T6=30.0), clock="log").gap_s is None
    assert _decide(state, _temps(T6=30.0), clock="session").gap_s == pytest.approx(60.0)


def test_the_file_is_written_whole_and_a_broken_one_only_means_anew(tmp_path):
    file = SessionFile(tmp_path / "m1" / "deploy" / "session.json")
    assert file.load() == (None, "no stored session")
    file.save(_stored())
    assert file.load()[0] == _stored()
    assert [p.name for p in file.path.parent.iterdir()] == ["session.json"]  # no temporary left
    with pytest.raises(ValueError):  # NaN is not JSON: the caller writes null
        file.save(_stored(clock_s=math.nan))
    assert file.load()[0] == _stored()  # the old file stays whole
    broken = [
        ("{", "is not JSON"),
        ('{"schema": "x"}', "is not a rafi.deploy-session/1"),
        (json.dumps(_stored(last_sample_at_s="yesterday")), "has no last_sample_at_s"),
    ]
    for text, why in broken:
        file.path.write_text(text)
        state, reason = file.load()
        assert state is None and why in reason
    SessionFile(tmp_path / "dry.json", write=False).save(_stored())
    assert not (tmp_path / "dry.json").exists()


# --------------------------------------------------------------------------- restart in every phase


class _Clock:
    def __init__(self, t):
        self.t = t

    def __call__(self):
        return self.t


def _safe(state_file, wall, *, clock="log", art=None, band=0.05):
    """A loaded SafeCompensator and its keeper; the scenario's rises are a few tenths of a K
    (its model has 30 um/K), hence a narrow cold band."""
    safe = SafeCompensator(limits=Limits.from_settings(DEPLOY)).load(art or artefact())
    keeper = SessionKeeper(
        SessionFile(state_file), unit="m1", clock=clock, cold_band_k=band, max_age_h=24, wall=wall
    )
    return safe, keeper


def _samples():
    """The scenario of tests/test_live.py as (t_s, speed, temps) from t = 0, every DT."""
    return [(DT * i, speed, temps) for i, (speed, temps) in enumerate(scenario())]


def _run_with_restart(tmp_path, cut: int, *, clock: str, origin: float, gap_s: float = DT):
    """Step the samples through a SafeCompensator, saving the session as the loop does; before
    sample ``cut`` the process "restarts": a new SafeCompensator, started from the value the
    controller holds (the last command) and offered the stored session. The second process'
    samples carry times from ``origin`` (clock ``session``) or the same times (``log``)."""
    path = tmp_path / f"cut{cut}-{clock}.json"
    samples = _samples()
    wall = _Clock(START_WALL)
    safe, keeper = _safe(path, wall, clock=clock)
    safe.start_from(0.0)
    keeper.offer(safe)
    commands = []
    for t, n, temps in samples[:cut]:
        wall.t = START_WALL + t
        commands.append(safe.step(t, n, temps))
        keeper.save(safe)
    keeper.save(safe, force=True)  # the stop (SIGTERM) saves
    held = commands[-1].command_um
    wall.t += gap_s
    safe, keeper = _safe(path, wall, clock=clock)
    safe.start_from(held)
    keeper.offer(safe)
    offset = 0.0 if clock == "log" else origin - samples[cut][0]
    for t, n, temps in samples[cut:]:
        wall.t = START_WALL + t + (gap_s - DT)
        commands.append(safe.step(t + offset, n, temps))
        if safe.session_note_:
            note = safe.session_note_
        keeper.save(safe)
    return commands, held, note


def _phase_cuts():
    """A sample index in each phase of the uninterrupted oracle: referencing, ok, hold, ramp."""
    statuses = [s for _, s in expected_commands([(t, n, temps) for t, n, temps in _samples()])]
    cuts = {}
    for i, status in enumerate(statuses):
        if i > 2 and status == statuses[i - 1] == statuses[i - 2]:
            cuts.setdefault(status, i)
    return cuts


def test_the_scenario_reaches_every_phase():
    assert set(_phase_cuts()) == {"referencing", "ok", "hold", "ramp"}


@pytest.mark.parametrize("phase", ["referencing", "ok", "hold", "ramp"])
@pytest.mark.parametrize(("clock", "origin"), [("log", 0.0), ("session", 3.0e6)])
def test_a_restart_in_every_phase_goes_on_as_the_documented_rules_say(tmp_path, phase, clock, origin):
    cut = _phase_cuts()[phase]
    got, held, note = _run_with_restart(tmp_path, cut, clock=clock, origin=origin)
    assert note.startswith("reference kept from the session of 5 s ago")
    want = expected_commands(_samples(), restarts={cut: held})
    assert [c.command_um for c in got] == pytest.approx([c for c, _ in want], abs=1e-9)
    assert [c.status for c in got] == [s for _, s in want]
    # bumpless: the first command after the restart is the value the controller holds
    assert got[cut].command_um == held


def test_a_restart_of_a_warm_machine_keeps_its_offset_where_a_fresh_start_would_zero_it(tmp_path):
    cut = _phase_cuts()["ok"] + 4
    got, held, _ = _run_with_restart(tmp_path, cut, clock="session", origin=1.0e4, gap_s=60.0)
    assert abs(held) > 2.0  # the machine is warm: a compensation is due
    # a start without the session captures the warm state: its reference window sends safe_um
    fresh = SafeCompensator(limits=Limits.from_settings(DEPLOY)).load(artefact()).start_from(held)
    fresh_cmds = [fresh.step(t, n, temps) for t, n, temps in _samples()[cut : cut + 6]]
    assert fresh_cmds[-1].status == "referencing" and abs(fresh_cmds[-1].command_um) < abs(held) - 2.0
    # the kept session goes on from the stored reference: no referencing, the offset stays
    kept = got[cut : cut + 6]
    assert all(c.status != "referencing" for c in kept)
    assert all(abs(c.command_um - held) <= DEPLOY["rate_um_per_s"] * DT * (i + 1) for i, c in enumerate(kept))


def test_a_new_champion_at_restart_gets_the_stored_reference(tmp_path):
    path = tmp_path / "s.json"
    wall = _Clock(START_WALL)
    safe, keeper = _safe(path, wall)
    safe.start_from(0.0)
    keeper.offer(safe)
    samples = _samples()
    cut = _phase_cuts()["ok"] + 4
    for t, n, temps in samples[:cut]:
        safe.step(t, n, temps)
        keeper.save(safe)
    keeper.save(safe, force=True)
    reference = safe.reference_temperatures_.copy()
    new = artefact(coef=[20.0, -5.0, 5.0])
    safe, keeper = _safe(path, wall, art=new)
    keeper.offer(safe.start_from(0.0))
    t, n, temps = samples[cut]
    command = safe.step(t, n, temps)
    assert "is new since: its filters start settled" in safe.session_note_
    key = [SENSORS.index(k) for k in KEY]
    assert command.model_um == pytest.approx(float(np.dot([20.0, -5.0, 5.0], temps[key] - reference[key])))


def test_a_cold_machine_and_an_old_session_capture_the_reference_anew(tmp_path):
    path = tmp_path / "s.json"
    wall = _Clock(START_WALL)
    safe, keeper = _safe(path, wall)
    keeper.offer(safe.start_from(0.0))
    samples = _samples()
    for t, n, temps in samples[:20]:
        safe.step(t, n, temps)
    keeper.save(safe, force=True)
    first = samples[0]  # the machine back at its reference state
    safe, keeper = _safe(path, wall)
    keeper.offer(safe.start_from(0.0))
    assert safe.step(*first).status == "referencing"
    assert safe.session_note_.startswith("reference captured anew: the machine is cold")
    wall.t = START_WALL + 30 * 3600
    safe, keeper = _safe(path, wall)
    keeper.offer(safe.start_from(0.0))
    assert safe.step(*samples[25]).status == "referencing"
    assert "30.0 h old" in safe.session_note_


@pytest.mark.parametrize("cut", [2, 300])  # inside the first reference window; late in a run, warm
def test_a_safe_ensemble_restarted_through_the_session_file_goes_on_as_if_uninterrupted(tmp_path, cut):
    """``rafi deploy`` with an ensemble champion, stopped and started again (the session file,
    a followed log's clock): from the restart on, the model's value, its interval, the faults and
    the statuses are those of the loop that never stopped."""
    from test_compensator import _find_runs, _logs
    from test_interval_stream import with_interval

    from rafi.settings import MACHINE_DEFAULTS

    rule = "run_start"
    table, frame = _find_runs(_logs(), [3000, 6000, 9000], rule)
    art = with_interval(_fit("ensemble", rule, table, frame).to_dict())
    log = frame[frame["log"] == "multi.csv"].sort_values("log_t_s")
    starts = log["run_id"].ne(log["run_id"].shift()).to_numpy()
    t, rpm = log["log_t_s"].to_numpy(dtype=float), log["speed_rpm"].to_numpy(dtype=float)
    temps = log[list(SENSORS)].to_numpy(dtype=float)
    limits = Limits.from_settings({**MACHINE_DEFAULTS["deploy"], "interval_s": 20.0, "range_margin_k": 0.2})

    def keeper(wall):
        return SessionKeeper(
            SessionFile(tmp_path / "s.json"),
            unit="m1",
            clock="log",
            cold_band_k=0.05,
            max_age_h=24,
            wall=wall,
        )

    def run(safe, ks, keep, wall):
        out = []
        for k in ks:
            wall.t = START_WALL + t[k]
            if starts[k] and k > 0:
                safe.capture_reference()
            out.append(safe.step(t[k], rpm[k], temps[k]))
            keep.save(safe)
        return out

    wall = _Clock(START_WALL)
    whole = run(SafeCompensator(limits=limits).load(art).start_from(0.0), range(len(t)), keeper(wall), wall)
    wall = _Clock(START_WALL)
    first, keep = SafeCompensator(limits=limits).load(art).start_from(0.0), keeper(wall)
    keep.offer(first)
    before = run(first, range(cut), keep, wall)
    keep.save(first, force=True)
    stored = json.loads((tmp_path / "s.json").read_text())
    assert list(stored["model"]["members"]) == list(art["weights"])
    wall.t += 1.0
    second, keep = SafeCompensator(limits=limits).load(art).start_from(before[-1].command_um), keeper(wall)
    keep.offer(second)
    after = run(second, range(cut, len(t)), keep, wall)
    assert second.session_note_.startswith("reference kept from the session of")
    got, want = before + after, whole
    for col in ("model_um", "lower_um", "upper_um"):
        np.testing.assert_allclose([getattr(c, col) for c in got], [getattr(c, col) for c in want], atol=1e-9)
    assert [c.status for c in got] == [c.status for c in want]
    assert [c.fault for c in got] == [c.fault for c in want]
    # the scenario reaches the rules the ensemble feeds: outside the trained range, a fault
    assert any(c.outside_range for c in want) and any(c.status == "hold" for c in want)
