"""``rafi plan`` -> ``rafi record --plan`` on the machine -> the pipeline's segmentation (issue 47).

The local SINUMERIK-like OPC UA server (tests/opcua_server.py) stands for the controller and a
twin stands for the machine: the spindle speed node shows what ``rafi record`` writes to
``record.speed_command`` (plus the twin's speed noise), the temperatures and the probe are the
twin's at that moment. The recording goes through the pipeline's own reader, clean step and
segmentation (:func:`rafi.method.runs.find_runs`, the settings of the machine, resolved), and
must be cut as the plan meant: the rest before start is the first heat-up's (within
``runs.max_leading_rest_s``), one run per step and none excluded, the first heat-up referenced
on the machine at rest.

The plan is scaled down (runs of 5 min, the settings that set them, 30 min of plan) and the loop
runs on an injected clock (the sleep between two ticks moves the twin on), so nothing here depends
on timing.
"""

from __future__ import annotations

import argparse
from datetime import datetime

import numpy as np
import pytest
import yaml

from rafi import SENSORS
from rafi.cli import main
from rafi.deploy import record_cli
from rafi.deploy.record_plan import read_plan
from rafi.method.clean import clean_log
from rafi.method.runs import find_runs
from rafi.readers.native import read_raw_log
from rafi.settings import read_machine_config
from rafi.twin.day import plan_runs
from rafi.twin.schedules import sample_schedule, schedule_from_pairs
from rafi.twin.simulate import simulate_run

MACHINE = "tapping-center-a"
ENV = {"RAFI_OPCUA_USER": "seawriter", "RAFI_OPCUA_PASSWORD": "s3cret-Pw"}
START = "2026-03-11T09:00:00"
#: The scaled-down runs: a heat-up or cool-down of 5 min is a run (runs.min_run_s,
#: runs.min_constant_s) and the plan's shortest step (models.interval_transient_s).
RUN_S = 300


@pytest.fixture(scope="module")
def server():
    pytest.importorskip("asyncua")
    from opcua_server import SinumerikLikeServer

    with SinumerikLikeServer(axis=3) as srv:
        yield srv


def machine_config(tmp_path, server):
    from opcua_server import DISP_NODE, SPEED_COMMAND_NODE, input_settings

    block = {
        "runs": {"min_run_s": RUN_S, "min_constant_s": RUN_S},
        "models": {"interval_transient_s": RUN_S},
        "deploy": {"opcua": {"endpoint": server.endpoint, "inputs": input_settings(), "timeout_s": 3,
                             "allow_insecure": True}},
        "record": {"displacement": DISP_NODE, "speed_command": SPEED_COMMAND_NODE},
    }  # fmt: skip
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump({"machines": {MACHINE: block}}, sort_keys=False), encoding="utf-8")
    return path


def record(path, server, plan_path):
    """``rafi record --plan`` with the twin as the machine; returns the closed files and the twin's
    log (the machine as the plan meant to drive it)."""
    from opcua_server import SPEED_COMMAND_NODE

    plan = read_plan(plan_path)
    ((_, schedule, _),) = plan_runs(plan)  # one recording: the twin of the plan as meant
    twin = simulate_run(schedule, seed=5, start=START, defects=False).log
    meant = sample_schedule(schedule_from_pairs(schedule), 5.0)
    noise = twin["speed_rpm"].to_numpy() - meant  # the speed signal's noise, r/min
    args = argparse.Namespace(
        machine=MACHINE, config=str(path), follow=None, from_start=False, plan=str(plan_path), notes="",
        name="rec", duration=None, debug=False,
    )  # fmt: skip
    recorder, link = record_cli.build(args, log=lambda line: None, environ=ENV)
    start = datetime.fromisoformat(f"{START}+00:00").timestamp()
    clock, tick = [1000.0], [0]
    recorder.clock = recorder.files.clock = link.clock = lambda: clock[0]
    recorder.wall = lambda: start + clock[0] - 1000.0

    def show(k):
        """The machine at tick ``k``: the spindle at the speed last commanded, the twin's readings."""
        speed = float(server.value(SPEED_COMMAND_NODE))
        sample = twin.iloc[min(k, len(twin) - 1)]
        noisy = speed + noise[min(k, len(noise) - 1)] * (speed > 0)
        server.set_inputs(noisy, sample[list(SENSORS)].to_numpy(float), sample["disp_um"])

    write = recorder.command

    def command(speed_rpm):  # the controller takes the command at once: the spindle follows
        write(speed_rpm)
        if tick[0] < len(twin):
            show(tick[0])

    def sleep(seconds):
        clock[0] += seconds
        tick[0] += 1
        show(tick[0])

    recorder.command, recorder.sleep = command, sleep
    try:
        link.connect()
        record_cli.preflight(recorder, link)
        show(0)
        files = recorder.run()
    finally:
        link.close()
    return files, twin


def segment(raw, name, settings):
    """The pipeline's clean step and segmentation of one raw log, with the machine's settings."""
    runs, clean = settings["runs"], settings["clean"]
    frame, _ = clean_log(
        raw, file=name, sample_period_s=float(settings["sample_period_s"]),
        max_interpolate_gap_s=clean["max_interpolate_gap_s"], spike_threshold=clean["spike_threshold"],
        open_circuit_values=clean["open_circuit_values"],
    )  # fmt: skip
    keys = ("idle_below_rpm", "min_run_s", "min_constant_s", "overrides", "max_leading_rest_s", "windows",
            "idle_training", "allow_training_after_validation")  # fmt: skip
    return find_runs(
        {name: frame}, {name: "x"}, training_speeds_rpm=settings["training_speeds_rpm"],
        speed_tolerance_rpm=settings["speed_tolerance_rpm"], reference_rule=settings["reference"]["rule"],
        reference_window_s=settings["reference"]["window_s"], **{k: runs[k] for k in keys},
    )  # fmt: skip


@pytest.mark.slow
def test_a_plan_recorded_from_opc_ua_is_cut_into_the_runs_the_plan_meant(server, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = machine_config(tmp_path, server)
    _, settings = read_machine_config(path, MACHINE)
    runs_cfg = settings["runs"]
    assert (
        main(["plan", "--machine", MACHINE, "--config", str(path), "--hours", "0.5", "--out", "p.csv"]) == 0
    )
    steps = read_plan(tmp_path / "p.csv").steps
    assert steps[0].speed_rpm == 0 and steps[0].duration_s < runs_cfg["max_leading_rest_s"]
    assert len(steps) >= 4 and len({s.run for s in steps}) == 1  # rest, heat-ups and cool-downs

    (log,), twin = record(path, server, tmp_path / "p.csv")
    raw = read_raw_log(log)
    period = float(settings["sample_period_s"])
    assert len(raw) == len(twin) and raw.attrs["metadata"]["plan"].startswith("p.csv")
    # the spindle ran the plan as the twin was simulated: the step in force at every tick
    np.testing.assert_array_equal(raw["speed_rpm"].to_numpy(), twin["speed_rpm"].to_numpy())
    table, frame = segment(raw, log.name, settings)
    runs = table.sort_values("start_s").reset_index(drop=True)
    # one run per step, the rest inside the first heat-up; nothing excluded
    assert len(runs) == len(steps) - 1, runs[["run_id", "kind", "role", "duration_s", "note"]]
    assert "excluded" not in set(runs["role"])
    lengths = [steps[0].duration_s + steps[1].duration_s] + [s.duration_s for s in steps[2:]]
    for (_, run), step, length in zip(runs.iterrows(), steps[1:], lengths):
        if step.speed_rpm > 0:
            assert run["kind"] == "constant" and run["role"] == "training"
            assert run["speed_rpm"] == pytest.approx(step.speed_rpm, abs=settings["speed_tolerance_rpm"])
        else:
            assert run["kind"] == "idle"
        assert run["duration_s"] == pytest.approx(length, abs=2 * period)
    first = runs.iloc[0]
    assert first["start_s"] == 0 and "rest" in str(first["note"])
    # the first heat-up's reference window lies on the machine at rest, cold
    head = frame[frame["run_id"] == first["run_id"]].sort_values("t_s")
    window = head[head["t_s"] < settings["reference"]["window_s"]]
    assert len(window) and (window["speed_rpm"] == 0).all()
    assert window["dz_um"].abs().max() < 0.5 and window["dT6"].abs().max() < 0.2
    at_speed = head[head["t_s"] >= steps[0].duration_s + 60]
    assert (at_speed["speed_rpm"] > 0).all() and at_speed["dz_um"].iloc[-1] > 2  # it grew from the rest
