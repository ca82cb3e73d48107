"""The live loop (rafi.deploy.live) with fakes, the log follower, the target and credential
settings; and the helpers the OPC UA end-to-end test shares (a hand-written model with a known
formula, a registry holding it as champion, and an oracle of the documented limit rules).

The model is a hand-written ``ridge_global`` artefact whose value is ``c . (T - T0)`` (T0: the
median of the key temperatures over the reference window), so the expected command of every
sample follows from that formula and the rules of ``rafi.deploy.limits``' docstring, written
again here (:func:`expected_commands`), not from the code under test.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from rafi import SENSORS
from rafi.artefact import compute_model_id
from rafi.deploy.limits import Limits, SafeCompensator
from rafi.deploy.live import LiveLoop, LogFollower, build_target, check_target_limits
from rafi.deploy.opcua_client import load_credentials, opcua_settings
from rafi.deploy.target_sinumerik import DrySink
from rafi.errors import RafiUserError, SettingsError, TargetError
from rafi.settings import MACHINE_DEFAULTS

KEY = ["T6", "T8", "T9"]
COEF = [30.0, -10.0, 5.0]
WINDOW = 60.0
TOP_RPM = 9000.0
DT = 5.0


def artefact(coef=COEF) -> dict:
    d = {
        "schema": "rafi.model/1",
        "kind": "ridge_global",
        "key_sensors": KEY,
        "features": [f"d{s}@0s" for s in KEY],
        "coefficients": list(coef),
        "selected": {"taus_s": [0.0], "speed_gain": False, "speed_terms": False},
        "hyperparameters": {"speed_tolerance_rpm": 50, "filter_restart_gap_s": 3600},
        "regressor_ranges": {s: [-1000.0, 1000.0] for s in KEY},
        "speed_range_rpm": [0.0, TOP_RPM],
        "reference": {"rule": "run_start", "window_s": WINDOW},
        "speed_reference": {"rule": "zero"},
    }
    d["model_id"] = compute_model_id(d)
    return d


def make_registry(root, champion: dict) -> None:
    """``root`` (results/<m>/registry) with ``champion`` as its champion."""
    (root / "models").mkdir(parents=True, exist_ok=True)
    (root / "models" / f"{champion['model_id']}.json").write_text(json.dumps(champion))
    (root / "champion.json").write_text(json.dumps({"model_id": champion["model_id"]}))


#: The deploy settings of the tests: every rule reachable within a few dozen samples.
DEPLOY = dict(
    MACHINE_DEFAULTS["deploy"],
    clamp_um=[-20.0, 20.0],
    rate_um_per_s=0.4,  # 2 um per 5 s sample
    stuck_s=60.0,
    stuck_change_k=0.5,
    range_margin_k=1000.0,
    speed_margin_rpm=500.0,
    hold_s=30.0,
    safe_um=0.0,
    ramp_um_per_s=0.2,  # 1 um per sample
    interval_s=DT,
)


def temps16(key_values) -> np.ndarray:
    out = np.full(16, 25.0)
    for s, v in zip(KEY, key_values):
        out[SENSORS.index(s)] = v
    return out


# the oracle: the documented rules as one plain loop, on purpose not shaped like rafi.deploy.live
def expected_commands(  # noqa: C901, PLR0912
    samples, s=DEPLOY, coef=COEF, *, start=None, resumes=None, restarts=None
) -> list[tuple[float, str]]:
    """(command um, status) per sample by the documented rules, for the model c . (T - T0).

    ``start``: the value the controller holds at start (None: not known, ``safe_um``);
    ``resumes``: {sample index: the value read from the controller before that sample} (after a
    reconnect); ``restarts``: {sample index: the value the controller holds} where the process
    starts again with its stored session (docs/deploy.md, "A restart": the command starts from
    that value and does not move at that sample; the reference, its window and the fault timer
    go on; the stuck watch starts afresh). A hold keeps the last command sent in ``ok`` or
    ``referencing`` state, or the value read."""
    lo, hi = s["clamp_um"]
    vlo, vhi = s["temp_valid_c"]
    t0, ref, window, last_t = None, None, [], None
    cmd = good = s["safe_um"] if start is None else start
    bad_since = None
    since, value, others = [None] * 3, [None] * 3, [None] * 3
    out = []
    for index, (t, n, temps) in enumerate(samples):
        if resumes and index in resumes:
            cmd = good = resumes[index]
        if restarts and index in restarts:
            cmd = good = restarts[index]
            last_t = None
            since, value, others = [None] * 3, [None] * 3, [None] * 3
        key = np.array([temps[SENSORS.index(k)] for k in KEY], dtype=float)
        causes = []
        fed = key.copy()
        for i in range(3):
            if not math.isfinite(key[i]):
                causes.append("missing")
            elif not vlo <= key[i] <= vhi:
                causes.append("out of range")
                fed[i] = math.nan
        for i in range(3):
            if not math.isfinite(fed[i]):
                continue
            if since[i] is None or fed[i] != value[i]:
                since[i], value[i], others[i] = t, fed[i], fed.copy()
            elif t - since[i] >= s["stuck_s"]:
                moved = [abs(fed[j] - others[i][j]) for j in range(3) if j != i]
                if max((m for m in moved if math.isfinite(m)), default=0.0) >= s["stuck_change_k"]:
                    causes.append("stuck")
        if not math.isfinite(n):
            causes.append("speed missing")
        if t0 is None:
            t0 = t
        referencing = t < t0 + WINDOW
        if referencing:
            window.append(fed)
            model = math.nan
        else:
            if ref is None:
                ref = np.nanmedian(np.array(window), axis=0)
            model = float(np.dot(coef, fed - ref))
            if math.isfinite(n) and abs(n) > TOP_RPM + s["speed_margin_rpm"]:
                causes.append("speed outside")
        dt = 0.0 if last_t is None else max(t - last_t, 0.0)
        last_t = t
        if referencing and not causes:
            status, target, bad_since = "referencing", s["safe_um"], None
        elif causes or not math.isfinite(model):
            bad_since = t if bad_since is None else bad_since
            if t - bad_since < s["hold_s"]:
                status, target = "hold", good
            else:
                status = "ramp"
                step = s["ramp_um_per_s"] * min(dt, s["interval_s"])
                target = cmd + min(max(s["safe_um"] - cmd, -step), step)
        else:
            status, target, bad_since = "ok", model, None
        target = min(max(target, lo), hi)
        max_step = s["rate_um_per_s"] * min(dt, s["interval_s"])
        cmd = cmd + min(max(target - cmd, -max_step), max_step)
        if status in ("ok", "referencing"):
            good = cmd
        out.append((cmd, status))
    return out


def scenario() -> list[tuple[float, np.ndarray]]:
    """(speed, temperatures) per sample: reference, a rise into the clamp, a fall, T8 dropping
    out, T9 stuck while the others rise (hold, then ramp), recovery, a speed outside the trained
    range, recovery."""
    base = np.array([20.0, 21.0, 22.0])
    rows = []
    k = base.copy()

    def add(n, speed, step, *, freeze=None, drop=None):
        nonlocal k
        for _ in range(n):
            k = k + step
            if freeze is not None:
                k[freeze] -= step[freeze]
            vals = k.copy()
            if drop is not None:
                vals[drop] = math.nan
            rows.append((speed, temps16(vals)))

    add(12, 6000.0, np.zeros(3))  # the reference window
    add(18, 6000.0, np.full(3, 0.1))  # rise: rate limited, then clamped
    add(10, 6000.0, np.full(3, -0.1))  # fall
    add(3, 6000.0, np.zeros(3), drop=1)  # T8 drops out
    add(26, 6000.0, np.full(3, 0.1), freeze=2)  # T9 stuck: hold, then ramp
    add(8, 6000.0, np.full(3, 0.05))  # T9 moves again
    add(5, 12000.0, np.zeros(3))  # outside the trained speeds
    add(8, 6000.0, np.zeros(3))
    return rows


@pytest.mark.parametrize("start_um", [None, -6.8, 13.0])
def test_the_oracle_matches_the_safe_compensator_on_the_scenario(start_um):
    """The loop with fakes on the scenario: every write equals the oracle's command (no link),
    starting from the value the controller holds (None: a sink that cannot say)."""
    rows = scenario()
    clock = [1000.0]
    fed = []

    class Source:
        def read(self, now):
            i = len(fed)
            if i >= len(rows):
                return []
            fed.append((now, *rows[i]))
            return [fed[-1]]

        def after_outage(self, samples):
            return samples

    sink = DrySink()
    target, axis = build_target(
        {"kind": "sinumerik", "axis": {"name": "Z", "number": 3, "sign": -1, "limit_um": 50.0},
         "int_incr_per_mm": 1000000},
        sink=sink,
    )  # fmt: skip
    if start_um is not None:
        sink.start[target.node("TEMP_COMP_ABS_VALUE", "Z")] = -start_um / 1000  # sign -1
    safe = SafeCompensator(limits=Limits.from_settings(DEPLOY)).load(artefact())
    lines = []

    def sleep(s):
        clock[0] += s

    loop = LiveLoop(
        Source(),
        safe,
        target,
        axis=axis,
        interval_s=DT,
        clock=lambda: clock[0],
        sleep=sleep,
        log=lines.append,
    )
    assert loop.run(max_cycles=len(rows)) == len(rows)
    expected = expected_commands(fed, start=start_um)
    got = [-w.value * 1000 for w in sink.writes]
    assert got == pytest.approx([c for c, _ in expected], abs=1e-6)
    statuses = {st for _, st in expected}
    assert statuses == {"referencing", "ok", "hold", "ramp"}  # every rule was reached
    assert max(abs(g) for g in got) == pytest.approx(20.0)  # the clamp acted
    held = DEPLOY["safe_um"] if start_um is None else start_um
    steps = np.abs(np.diff([held, *got]))  # bumpless: the held value first
    assert steps[0] == 0 and steps.max() <= DEPLOY["rate_um_per_s"] * DT + 1e-9
    assert got[1] == pytest.approx(held + np.sign(DEPLOY["safe_um"] - held) * DEPLOY["rate_um_per_s"] * DT)
    assert "holds " in lines[0] and len(lines) == len(rows) + 1 and target.closed


class FakeLink:
    def __init__(self, up):
        self.up = up  # callable: is the server there
        self.connected = True
        self.tries = 0

    def try_reconnect(self):
        self.tries += 1
        self.connected = self.up()
        return self.connected


def test_no_write_and_no_sample_during_an_outage_then_resume():
    clock = [0.0]
    down = {3, 4, 5}
    stepped, written, starts = [], [], []

    class Source:
        def __init__(self, link):
            self.link = link

        def read(self, now):
            if int(now / DT) in down:
                self.link.connected = False
                raise ConnectionError("gone")
            return [(now, 6000.0, temps16([20, 21, 22]))]

        def after_outage(self, samples):
            return samples

    class Safe:
        limits = Limits.from_settings(DEPLOY)
        command_um_ = 0.0

        def start_from(self, value):
            starts.append(("start", value))

        def resume_from(self, value):
            starts.append(("resume", value))

        def step(self, t, n, temps):
            stepped.append(t)
            from rafi.deploy.limits import Command

            return Command(t, 1.0, "ok", 1.0, 1.0, False, False, "", False, True)

    class Target:
        is_open, closed, name = False, False, "fake"

        def open(self):
            self.is_open = True

        def read_current_um(self):
            return {"Z": float(len(written))}  # what the controller holds: read each time anew

        def write(self, t, values, status):
            written.append(t)

        def close(self):
            self.closed = True

    link = FakeLink(lambda: int(clock[0] / DT) not in down)
    link.connected = True

    def sleep(s):
        clock[0] += s

    loop = LiveLoop(Source(link), Safe(), Target(), axis="Z", interval_s=DT, link=link,
                    clock=lambda: clock[0], sleep=sleep, log=lambda m: None)  # fmt: skip
    loop.run(max_cycles=9)
    assert stepped == written == [0.0, 5.0, 10.0, 30.0, 35.0, 40.0]
    assert loop.outage_cycles == 3
    assert starts == [("start", 0.0), ("resume", 3.0)]  # read at start and after the outage


def test_nothing_is_written_while_off():
    written = []

    class Target:
        is_open, name = True, "fake"

        def read_current_um(self):
            return {"Z": None}

        def write(self, *a):
            written.append(a)

        def close(self):
            pass

    safe = SafeCompensator(limits=Limits.from_settings(DEPLOY))  # no model: status off

    class Source:
        def read(self, now):
            return [(now, 6000.0, temps16([20, 21, 22]))]

    loop = LiveLoop(Source(), safe, Target(), axis="Z", interval_s=1.0, clock=lambda: 0.0,
                    sleep=lambda s: None, log=lambda m: None)  # fmt: skip
    loop.run(max_cycles=5)
    assert written == [] and loop.last_command.status == "off"


def test_the_target_is_closed_on_ctrl_c():
    class Target:
        is_open, closed, name = True, False, "fake"

        def read_current_um(self):
            return {"Z": 1.5}

        def close(self):
            self.closed = True

    class Source:
        def read(self, now):
            raise KeyboardInterrupt

    target = Target()
    safe = SafeCompensator(limits=Limits.from_settings(DEPLOY))
    loop = LiveLoop(Source(), safe, target, axis="Z", interval_s=1.0, log=lambda m: None)
    with pytest.raises(KeyboardInterrupt):
        loop.run()
    assert target.closed


# --------------------------------------------------------------------------- the log follower


def test_the_follower_reads_complete_new_lines_only(tmp_path):
    path = tmp_path / "log.csv"
    header = "# machine: m\ntime,speed_rpm," + ",".join(SENSORS) + ",disp_um\n"
    old = "2026-03-01T08:00:00,3000," + ",".join(["20"] * 16) + ",0\n"
    path.write_text(header + old)
    follower = LogFollower(path)
    assert follower.read() == []  # lines already there are not new
    row = "2026-03-01T08:00:05,3000," + ",".join(["21.5"] * 3 + [""] + ["20"] * 12) + ",0.1"
    with open(path, "a") as fh:
        fh.write(row[:20])  # half a line: not yet
    assert follower.read() == []
    with open(path, "a") as fh:
        fh.write(row[20:] + "\r\n" + "garbage,1\n" + "2026-03-01T08:00:05,1," + ",".join(["1"] * 16) + ",0\n")
    samples = follower.read()
    assert len(samples) == 1  # the garbage line and the repeated time are skipped
    t, n, temps = samples[0]
    assert t == pytest.approx(1772352005.0) and n == 3000.0
    assert temps[0] == 21.5 and math.isnan(temps[3]) and temps[15] == 20.0
    path.write_text(header + row + "\n")  # replaced: read again from the start
    assert len(LogFollower(path, from_start=True).read()) == 1


# --------------------------------------------------------------------------- settings


def test_target_settings_are_checked_with_clear_messages():
    axis = {"name": "Z", "number": 3, "limit_um": 50.0}
    with pytest.raises(SettingsError, match="axis.sign is missing; it has no default"):
        build_target({"kind": "sinumerik", "axis": axis}, sink=DrySink())
    with pytest.raises(SettingsError, match="kind is 'fanuc'"):
        build_target({"kind": "fanuc"})
    with pytest.raises(SettingsError, match="deploy.target.colour is not a setting"):
        build_target({"kind": "csv", "axis": "Z", "path": "x.csv", "colour": 1})
    with pytest.raises(TargetError, match="sign"):
        build_target({"kind": "sinumerik", "axis": {**axis, "sign": 2}}, sink=DrySink())
    target, _ = build_target(
        {"kind": "sinumerik", "axis": {**axis, "sign": -1, "limit_um": 10.0}}, sink=DrySink()
    )
    with pytest.raises(TargetError, match="narrow deploy.clamp_um"):
        check_target_limits(target, "Z", Limits.from_settings(DEPLOY))  # clamp 20 > limit 10


def test_credentials_never_come_from_config_yaml(tmp_path, monkeypatch):
    with pytest.raises(SettingsError, match="credentials never go to config.yaml.*RAFI_OPCUA_USER"):
        opcua_settings({"endpoint": "opc.tcp://h:4840", "password": "x", "inputs": {"speed_rpm": "a"}})
    s = opcua_settings(
        {
            "endpoint": "opc.tcp://h:4840",
            "inputs": {"speed_rpm": "/a", "T1": {"node": "ns=3;i=5", "scale": 0.1}},
        }
    )
    assert s["inputs"] == {"speed_rpm": ("ns=2;s=/a", 1.0, 0.0), "T1": ("ns=3;i=5", 0.1, 0.0)}
    assert load_credentials(s, environ={}) == (None, None)
    assert load_credentials(s, environ={"RAFI_OPCUA_USER": "u", "RAFI_OPCUA_PASSWORD": "p"}) == ("u", "p")
    with pytest.raises(RafiUserError, match="both"):
        load_credentials(s, environ={"RAFI_OPCUA_USER": "u"})
    project = tmp_path / "project"
    project.mkdir()
    inside = project / "cred"
    inside.write_text("user: u\npassword: p\n")
    inside.chmod(0o600)
    with pytest.raises(RafiUserError, match="inside .*project"):
        load_credentials(s, project_dir=project, environ={"RAFI_OPCUA_CREDENTIALS": str(inside)})
    outside = tmp_path / "cred"
    outside.write_text("# the SeaWrite user\nuser: u\npassword: p: with colon\n")
    outside.chmod(0o644)
    with pytest.raises(RafiUserError, match="mode 644.*chmod 600"):
        load_credentials({**s, "credentials_file": str(outside)}, project_dir=project, environ={})
    os.chmod(outside, 0o600)
    assert load_credentials({**s, "credentials_file": str(outside)}, project_dir=project, environ={}) == (
        "u",
        "p: with colon",
    )


@pytest.mark.parametrize(
    ("session_folder", "champion"), [("writable", "single"), ("a file", "single"), ("writable", "ensemble")]
)
def test_rafi_deploy_follows_a_log_into_a_csv_target(tmp_path, session_folder, champion):
    """`rafi deploy --follow` with a CSV target: no OPC UA; each appended line gives one row,
    equal to the oracle's command. The session is kept in results/m1/deploy/session.json; where
    it cannot be written, the loop says so once and goes on. An ensemble champion (two members,
    0.5 and 1.5 times the oracle's coefficients, equal weights: the oracle's model) runs the same."""
    import argparse
    from datetime import datetime, timedelta

    import yaml
    from test_limits import ensemble

    from rafi.deploy import live_cli

    model = artefact()
    if champion == "ensemble":
        halves = {"low": artefact(coef=0.5 * np.asarray(COEF)), "high": artefact(coef=1.5 * np.asarray(COEF))}
        model = ensemble(halves, {"low": 1.0, "high": 1.0})
    make_registry(tmp_path / "results" / "m1" / "registry", model)
    block = dict(DEPLOY, target={"kind": "csv", "axis": "Z", "path": "out/commands.csv"})
    (tmp_path / "out").mkdir()
    (tmp_path / "config.yaml").write_text(yaml.safe_dump({"machines": {"m1": {"deploy": block}}}))
    log = tmp_path / "live.csv"
    log.write_text("time,speed_rpm," + ",".join(SENSORS) + ",disp_um\n")
    args = argparse.Namespace(
        machine="m1", config=str(tmp_path / "config.yaml"), model=None, follow=str(log), dry_run=False
    )
    if session_folder == "a file":
        (tmp_path / "results" / "m1" / "deploy").write_text("not a folder")
    said = []
    loop, link = live_cli.build(args, log=said.append, environ={})
    assert link is None
    rows = scenario()[:40]
    start = datetime(2026, 3, 1, 8)
    fed = []

    def append(i):
        speed, temps = rows[i]
        stamp = start + timedelta(seconds=DT * i)
        with open(log, "a") as fh:
            fh.write(f"{stamp.isoformat()},{speed:g}," + ",".join(f"{t:.2f}" for t in temps) + ",\n")
        fed.append((stamp.replace(tzinfo=None).timestamp(), speed, np.round(temps, 2)))

    def sleep(s):
        append(len(fed))

    loop.clock, loop.sleep = (lambda: 0.0), sleep
    assert loop.source.read() == []  # the follower starts at the end of the file (tail -f)
    append(0)
    loop.run(max_cycles=len(rows))
    lines = (tmp_path / "out" / "commands.csv").read_text().splitlines()
    assert lines[0] == "time_s,Z_um,status" and len(lines) == len(rows) + 1
    got = [float(line.split(",")[1]) for line in lines[1:]]
    assert got == pytest.approx([c for c, _ in expected_commands(fed)], abs=1e-9)
    problems = [m for m in said if "the session cannot be saved" in m]
    if session_folder == "a file":
        assert len(problems) == 1 and "a restart will capture its reference anew" in problems[0]
    else:
        stored = json.loads((tmp_path / "results" / "m1" / "deploy" / "session.json").read_text())
        assert not problems and stored["clock"] == "log" and stored["clock_s"] == fed[-1][0]
        assert stored["reference"] is not None and stored["unit"] == "m1"
        assert list(stored["model"].get("members", [])) == ([] if champion == "single" else ["low", "high"])
    why = "no stored session" if session_folder == "writable" else "session.json cannot be read"
    assert any(m.startswith("reference captured anew: ") and why in m for m in said)


def test_rafi_deploy_serves_its_metrics_while_it_runs(tmp_path):
    """deploy.metrics_port: an HTTP GET of /metrics while the loop runs reads the writes so
    far, the last command and the model in service (docs/service.md)."""
    import socket
    import urllib.request
    from datetime import datetime, timedelta

    import yaml
    from prometheus_client.parser import text_string_to_metric_families

    from rafi.deploy import live_cli

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    args = _deploy_args(tmp_path)
    config = yaml.safe_load((tmp_path / "config.yaml").read_text())
    config["machines"]["m1"]["deploy"]["metrics_port"] = port
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config))
    (tmp_path / "out").mkdir()
    make_registry(tmp_path / "results" / "m1" / "registry", artefact())
    loop, _ = live_cli.build(args, log=lambda m: None, environ={})
    rows, start, scraped = scenario()[:12], datetime(2026, 3, 1, 8), []

    def scrape() -> dict:
        text = urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10).read().decode()
        return {
            (sample.name, tuple(sorted(sample.labels.items()))): sample.value
            for family in text_string_to_metric_families(text)
            for sample in family.samples
        }

    def sleep(seconds):
        speed, temps = rows[loop.cycles]
        stamp = start + timedelta(seconds=DT * loop.cycles)
        with open(args.follow, "a") as fh:
            fh.write(f"{stamp.isoformat()},{speed:g}," + ",".join(f"{t:.2f}" for t in temps) + ",\n")
        scraped.append((loop.writes, loop.last_command, scrape()))

    loop.clock, loop.sleep = (lambda: 0.0), sleep
    try:
        sleep(0)
        loop.run(max_cycles=len(rows) - 1)
    finally:
        loop.metrics.close()
    labels = (("machine", "m1"),)
    for writes, command, values in scraped:
        if command is None:  # the follower starts at the end of the file: nothing read yet
            continue
        assert values[("rafi_deploy_writes_total", labels)] == writes
        assert values[("rafi_deploy_command_um", labels)] == pytest.approx(command.command_um, abs=1e-12)
        assert values[("rafi_deploy_status", (*labels, ("status", command.status)))] == 1
    assert scraped[-1][0] == len(rows) - 3 > 0
    model = (("machine", "m1"), ("model_id", artefact()["model_id"]))
    assert scraped[-1][2][("rafi_deploy_model_info", model)] == 1


# --------------------------------------------------------------------------- rafi deploy's messages


def _deploy_args(tmp_path, *, model=None, machine="m1"):
    import argparse

    import yaml

    block = dict(DEPLOY, target={"kind": "csv", "axis": "Z", "path": "out/commands.csv"})
    (tmp_path / "config.yaml").write_text(yaml.safe_dump({"machines": {"m1": {"deploy": block}}}))
    log = tmp_path / "live.csv"
    log.write_text("time,speed_rpm," + ",".join(SENSORS) + ",disp_um\n")
    return argparse.Namespace(
        machine=machine, config=str(tmp_path / "config.yaml"), model=model, follow=str(log), dry_run=False
    )


def test_deploy_names_the_machine_a_model_belongs_to_and_unknown_machines(tmp_path):
    from rafi.deploy import live_cli
    from rafi.errors import UnqualifiedModel

    make_registry(tmp_path / "results" / "m1" / "registry", artefact())
    other = artefact(coef=[1.0, 2.0, 3.0])
    make_registry(tmp_path / "results" / "m2" / "registry", other)
    path = tmp_path / "results" / "m2" / "registry" / "models" / f"{other['model_id']}.json"
    with pytest.raises(UnqualifiedModel, match=r"is machine m2's model, not this machine's \(m1\)") as err:
        live_cli.build(_deploy_args(tmp_path, model=str(path)), log=lambda m: None, environ={})
    assert err.value.exit_status == 65
    loop, _ = live_cli.build(_deploy_args(tmp_path, model="champion"), log=lambda m: None, environ={})
    assert loop.model_id == artefact()["model_id"]
    with pytest.raises(SettingsError, match="^unknown machine nosuch; config.yaml has: m1; results or raw"):
        live_cli.build(_deploy_args(tmp_path, machine="nosuch"), log=lambda m: None, environ={})
    fitted_elsewhere = dict(artefact(), machine="m2")
    fitted_elsewhere["model_id"] = compute_model_id(fitted_elsewhere)
    make_registry(tmp_path / "results" / "m1" / "registry", fitted_elsewhere)
    with pytest.raises(UnqualifiedModel, match="is machine m2's model .so its artefact says"):
        live_cli.build(_deploy_args(tmp_path), log=lambda m: None, environ={})


def test_an_edited_champion_is_named_by_its_whole_file_name(tmp_path):
    from rafi.deploy import live_cli
    from rafi.errors import UnqualifiedModel

    deep = tmp_path / ("a-rather-long-folder-name-" * 3) / "project"
    deep.mkdir(parents=True)
    champion = artefact()
    make_registry(deep / "results" / "m1" / "registry", champion)
    path = deep / "results" / "m1" / "registry" / "models" / f"{champion['model_id']}.json"
    path.write_text(json.dumps(dict(champion, coefficients=[9.0, 9.0, 9.0])))
    with pytest.raises(UnqualifiedModel) as err:
        live_cli.build(_deploy_args(deep), log=lambda m: None, environ={})
    assert f"model file {champion['model_id']}.json in " in str(err.value)
    assert "modified after promotion" in str(err.value) and "characters)" not in str(err.value)


def test_a_new_champion_is_swapped_in_and_ramped_to(tmp_path):
    """The registry promotes another model while the loop runs: the loop loads it at its next
    look (deploy.champion_check_s), keeps the session's reference and moves to the new model's
    value at the rate limit."""
    from rafi.deploy.champion_watch import ChampionWatch

    registry = tmp_path / "results" / "m1" / "registry"
    make_registry(registry, artefact())
    clock, fed, lines = [0.0], [], []
    rows = [(6000.0, temps16([20.0, 21.0, 22.0]))] * 14 + [(6000.0, temps16([20.4, 21.0, 22.0]))] * 60
    # T6 +0.4 K (below stuck_change_k): the new model gives -3.2 um from the session reference
    new = artefact(coef=[-8.0, 1.0, 1.0])

    class Source:
        def read(self, now):
            fed.append(rows[len(fed)])
            return [(now, *fed[-1])]

    def sleep(s):
        clock[0] += s
        if len(fed) == 30:
            make_registry(registry, new)  # rafi nightly promotes

    sink = DrySink()
    target, axis = build_target({"kind": "sinumerik", "axis": {"name": "Z", "number": 3, "sign": 1,
                                 "limit_um": 50.0}, "int_incr_per_mm": 1000000}, sink=sink)  # fmt: skip
    safe = SafeCompensator(limits=Limits.from_settings(DEPLOY)).load(artefact())
    watch = ChampionWatch(registry, artefact()["model_id"], check_s=60.0, log=lines.append)
    loop = LiveLoop(Source(), safe, target, axis=axis, interval_s=DT, clock=lambda: clock[0], sleep=sleep,
                    log=lines.append, champion=watch)  # fmt: skip
    loop.run(max_cycles=len(rows))
    got = [w.value * 1000 for w in sink.writes]
    assert np.abs(np.diff([0.0, *got])).max() <= DEPLOY["rate_um_per_s"] * DT + 1e-9
    assert got[29] == pytest.approx(COEF[0] * 0.4)  # the first model, settled
    assert got[-1] == pytest.approx(-3.2)  # the new model from the power-on reference
    assert loop.model_id == new["model_id"] and safe.compensator_.model_id == new["model_id"]
    assert any(line.startswith(f"new champion {new['model_id'][:12]} replaces") for line in lines)
    swapped = next(i for i, line in enumerate(lines) if line.startswith("new champion"))
    assert 30 <= swapped - 1 <= 30 + 60 / DT  # at the next look after the promotion


def test_the_loop_logs_and_exposes_the_models_interval_and_its_fault():
    """Issue 26: an artefact with an ``interval`` block and ``deploy.max_interval_um`` set below
    its transient width: every written line shows the model's interval, the transient after the
    reference is held with the cause named, and /metrics (read over HTTP) shows the interval of
    the last cycle and the interval_wide fault count."""
    import urllib.request

    from prometheus_client.parser import text_string_to_metric_families

    from rafi.deploy.metrics import LoopMetrics

    block = {"schema": "rafi.interval/1", "level": 0.9, "transient_s": 100.0, "tolerance_rpm": 50.0,
             "half_width_um": {"settled": 0.5, "transient": 1.5, "outside": 4.0}}  # fmt: skip
    model = {**artefact(), "interval": block}
    model["model_id"] = compute_model_id(model)
    rows = scenario()[:40]  # the reference window (60 s), then a rise
    clock, fed, lines = [0.0], [], []

    class Source:
        def read(self, now):
            fed.append((now, *rows[len(fed)]))
            return [fed[-1]]

        def after_outage(self, samples):
            return samples

    target, axis = build_target(
        {"kind": "sinumerik", "axis": {"name": "Z", "number": 3, "sign": -1, "limit_um": 50.0},
         "int_incr_per_mm": 1000000},
        sink=DrySink(),
    )  # fmt: skip
    safe = SafeCompensator(limits=Limits.from_settings(dict(DEPLOY, max_interval_um=2.0))).load(model)
    metrics = LoopMetrics(machine="m1", interval_s=DT)

    def sleep(seconds):
        clock[0] += seconds

    metrics.serve(0)
    try:
        loop = LiveLoop(
            Source(), safe, target, axis=axis, interval_s=DT, clock=lambda: clock[0], sleep=sleep,
            log=lines.append, metrics=metrics,
        )  # fmt: skip
        loop.run(max_cycles=len(rows))
        text = urllib.request.urlopen(f"http://127.0.0.1:{metrics.port}/metrics", timeout=10).read().decode()
    finally:
        metrics.close()
    got = {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
    }
    last = loop.last_command
    assert last.status == "ok" and last.interval_cell == "settled"
    m1 = (("machine", "m1"),)
    assert got[("rafi_deploy_interval_lower_um", m1)] == pytest.approx(last.model_um - 0.5, abs=1e-12)
    assert got[("rafi_deploy_interval_upper_um", m1)] == pytest.approx(last.model_um + 0.5, abs=1e-12)
    assert got[("rafi_deploy_interval_half_width_um", m1)] == 0.5
    assert got[("rafi_deploy_interval_cell", (("cell", "settled"), *m1))] == 1.0
    assert got[("rafi_deploy_interval_cell", (("cell", "transient"), *m1))] == 0.0
    # t = 60..95 s after the reference: a transient 3 um wide, 8 cycles held with the cause
    assert got[("rafi_deploy_faults_total", (("cause", "interval_wide"), *m1))] == 8
    written = [line for line in lines if " um (model" in line]
    assert len(written) == len(rows)
    wide = [line for line in written if "interval_wide: 3 um wider than deploy.max_interval_um 2 um" in line]
    # held for hold_s (30 s), then ramped: the cause and the model's interval on every line
    assert [line.split()[1] for line in wide] == ["hold"] * 6 + ["ramp"] * 2
    assert all("] transient)" in line for line in wide)
    assert (
        f"(model {last.model_um:+.3f} um in [{last.lower_um:+.3f}, {last.upper_um:+.3f}] settled)"
        in written[-1]
    )


def test_rafi_deploy_of_one_probe_reads_the_machines_own_sensors_into_that_probes_target(tmp_path):
    """A machine with its own sensors and two probes: `rafi deploy --machine lathe@Z` loads the Z
    probe's champion, follows a log of the machine's sensor columns, and writes to the Z probe's
    own target (`machines.lathe@Z.deploy.target`); the commands equal the oracle's."""
    import argparse
    from datetime import datetime, timedelta

    import yaml

    from rafi.deploy import live_cli

    own = dict(zip(KEY, ("front", "rear", "motor")))  # the twin's T6, T8, T9 under the lathe's names
    model = artefact()
    model["key_sensors"] = [own[s] for s in KEY]
    model["features"] = [f"d{own[s]}@0s" for s in KEY]
    model["regressor_ranges"] = {own[s]: r for s, r in model["regressor_ranges"].items()}
    model["machine"] = "lathe@Z"
    del model["model_id"]
    model["model_id"] = compute_model_id(model)
    make_registry(tmp_path / "results" / "lathe@Z" / "registry", model)
    (tmp_path / "out").mkdir()
    config = {
        "machines": {
            "lathe": {
                "input": {
                    "format": "csv",
                    "sensors": ["spare", "front", "rear", "motor"],
                    "probes": {"X": {"column": "dx"}, "Z": {"column": "dz", "sign": -1}},
                },
                "deploy": dict(DEPLOY, target={"kind": "csv", "axis": "X", "path": "out/x.csv"}),
            },
            "lathe@Z": {"deploy": {"target": {"kind": "csv", "axis": "Z", "path": "out/z.csv"}}},
        }
    }
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config))
    log = tmp_path / "live.csv"
    log.write_text("time,speed_rpm,spare,front,rear,motor,dz\n")
    args = argparse.Namespace(
        machine="lathe@Z", config=str(tmp_path / "config.yaml"), model=None, follow=str(log), dry_run=False
    )
    loop, link = live_cli.build(args, log=lambda m: None, environ={})
    rows = scenario()[:30]
    start = datetime(2026, 3, 1, 8)
    fed = []

    def append(i):
        speed, temps = rows[i]
        stamp = start + timedelta(seconds=DT * i)
        mine = [temps[SENSORS.index(s)] for s in KEY]
        with open(log, "a") as fh:
            fh.write(f"{stamp.isoformat()},{speed:g},99.0," + ",".join(f"{t:.2f}" for t in mine) + ",\n")
        fed.append((stamp.replace(tzinfo=None).timestamp(), speed, np.round(temps, 2)))

    loop.clock, loop.sleep = (lambda: 0.0), (lambda s: append(len(fed)))
    assert loop.source.read() == []  # the follower starts at the end of the file (tail -f)
    append(0)
    loop.run(max_cycles=len(rows))
    assert not (tmp_path / "out" / "x.csv").exists()  # the X probe's target is not this process's
    lines = (tmp_path / "out" / "z.csv").read_text().splitlines()
    assert lines[0] == "time_s,Z_um,status" and len(lines) == len(rows) + 1
    got = [float(line.split(",")[1]) for line in lines[1:]]
    assert got == pytest.approx([c for c, _ in expected_commands(fed)], abs=1e-9)


def test_a_value_that_rounds_to_zero_is_printed_plus_zero():
    from rafi.deploy.um_format import signed_um

    assert [signed_um(v) for v in (-0.0, 0.0, -0.0004, 4e-13, -1e-12)] == ["+0.000"] * 5
    assert [signed_um(v) for v in (-0.0006, 4.5125, -4.5)] == ["-0.001", "+4.513", "-4.500"]
    assert signed_um(-0.0, width=9) == "   +0.000" and signed_um(1.5, digits=1) == "+1.5"
    assert signed_um(float("nan")) == "+nan"


def test_the_progress_line_says_when_the_model_was_held_at_its_envelope_edge():
    """The flag of ``Command.outside_envelope`` is in the write's progress line, and only there."""
    from rafi.deploy.limits import Command

    clock, lines, written = [0.0], [], []
    held = [False, True, False]

    class Source:
        def read(self, now):
            return [(now, 6000.0, temps16([20, 21, 22]))]

        def after_outage(self, samples):
            return samples

    class Safe:
        limits = Limits.from_settings(DEPLOY)
        command_um_ = 0.0

        def start_from(self, value):
            pass

        def step(self, t, n, temps):
            out = Command(t, 1.0, "ok", 1.0, 1.0, False, False, "", False, True)
            return out._replace(outside_envelope=held[len(written)])

    class Target:
        is_open, name = True, "fake"

        def read_current_um(self):
            return {"Z": 0.0}

        def write(self, t, values, status):
            written.append(t)

        def close(self):
            pass

    def sleep(s):
        clock[0] += s

    loop = LiveLoop(Source(), Safe(), Target(), axis="Z", interval_s=DT, clock=lambda: clock[0], sleep=sleep,
                    log=lines.append)  # fmt: skip
    assert loop.run(max_cycles=3) == 3
    writes = [line for line in lines if " um (model " in line]
    assert ["[held at the envelope's edge]" in line for line in writes] == held
