"""The live loop against a real asyncua server on 127.0.0.1 shaped like a SINUMERIK 840D sl
(tests/opcua_server.py): every value written on the server is checked against the oracle of
the limit rules (tests/test_live.py), through a stop and restart of the server, and the
refusals (an unqualified model, a wrong password, an anonymous write, a node of another type).

The loop runs with an injected clock and sleep: the "sleep" between two cycles puts the next
logged sample on the server's input nodes (or stops / restarts the server), so nothing here
depends on timing.
"""

from __future__ import annotations

import argparse
import json
import math
import signal

import numpy as np
import pytest
import yaml

pytest.importorskip("asyncua")

from opcua_server import PLC_COMP_NODE, SinumerikLikeServer, as_read, temp_node  # noqa: E402
from opcua_server import input_settings as inputs  # noqa: E402
from test_live import DEPLOY, DT, artefact, expected_commands, make_registry, scenario  # noqa: E402

from rafi import SENSORS  # noqa: E402
from rafi.deploy import live_cli  # noqa: E402
from rafi.deploy.opcua_client import OPCUA_DEFAULTS, OpcUaLink, opcua_settings  # noqa: E402
from rafi.errors import RafiUserError, UnqualifiedModel  # noqa: E402

INCR = 100000  # MD 10200: 0.01 um resolution
SIGN = -1


@pytest.fixture(scope="module")
def server():
    with SinumerikLikeServer(axis=3) as srv:
        yield srv


def write_config(tmp_path, server, *, deploy=None, machine="m1") -> argparse.Namespace:
    block = dict(DEPLOY)
    block.update(
        target={
            "kind": "sinumerik",
            "axis": {"name": "Z", "number": 3, "sign": SIGN, "limit_um": 50.0},
            "int_incr_per_mm": INCR,
        },
        opcua={
            "endpoint": server.endpoint,
            "inputs": inputs(),
            "timeout_s": 3,
            "reconnect_min_s": 1,
            "reconnect_max_s": 2,
            "allow_insecure": True,  # the NoSecurity test server: a password in plain text
        },
    )
    block.update(deploy or {})
    config = {"machines": {machine: {"deploy": block}}}
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(config))
    return argparse.Namespace(
        machine=machine, config=str(path), model=None, follow=None, dry_run=False, cycles=None, debug=False
    )


ENV = {"RAFI_OPCUA_USER": "seawriter", "RAFI_OPCUA_PASSWORD": "s3cret-Pw"}


def sd_writes(server) -> list[float]:
    return [w.value for w in server.client_writes() if w.node == server.sd_node()]


def test_every_value_written_follows_the_limits_through_a_server_restart(server, tmp_path):
    make_registry(tmp_path / "results" / "m1" / "registry", artefact())
    args = write_config(tmp_path, server)
    rows = scenario()
    log = []
    loop, link = live_cli.build(args, log=log.append, environ=ENV)
    clock = [5000.0]
    loop.clock = link.clock = lambda: clock[0]
    before = len(sd_writes(server))
    down = range(50, 54)  # cycles with the server stopped
    delivered, cycle = [], [0]

    def feed(c):
        speed, temps = rows[c]
        server.set_inputs(speed, temps)
        delivered.append((clock[0], speed, as_read(temps)))

    def sleep(seconds):
        clock[0] += seconds
        cycle[0] += 1
        c = cycle[0]
        if c == down.start:
            server.stop()
        elif c == down.stop:
            server.start()
        if c not in down and c < len(rows):
            feed(c)

    loop.sleep = sleep
    try:
        link.connect()
        feed(0)
        loop.run(max_cycles=len(rows))
    finally:
        link.close()
    written = sd_writes(server)[before:]
    # one write per sample the loop read; none while the server was down
    assert len(delivered) == len(rows) - len(down) == len(written) == loop.writes
    assert loop.outage_cycles == len(down) and link.losses == 1 and link.reconnects == 1
    assert any("connection lost" in m for m in log) and any("reconnected" in m for m in log)
    expected = expected_commands(delivered)
    got_um = [SIGN * v * 1000 for v in written]
    assert got_um == pytest.approx([c for c, _ in expected], abs=0.5e3 / INCR + 1e-9)
    # the rules, checked on the written values themselves
    lo, hi = DEPLOY["clamp_um"]
    assert all(lo - 1e-9 <= g <= hi + 1e-9 for g in got_um) and max(got_um) == pytest.approx(hi)
    steps = np.abs(np.diff([0.0, *got_um]))
    assert steps.max() <= DEPLOY["rate_um_per_s"] * DT + 1e3 / INCR  # also the first after the restart
    statuses = [s for _, s in expected]
    assert {"referencing", "ok", "hold", "ramp"} <= set(statuses)
    for i, s in enumerate(statuses):
        if s == "hold" and statuses[i - 1] == "hold":
            assert got_um[i] == pytest.approx(got_um[i - 1], abs=1e-9)  # held
        if s == "ramp":
            assert abs(got_um[i]) < abs(got_um[i - 1]) or got_um[i] == 0  # towards safe_um 0
    # every write was a Double with no timestamp (the server refuses any other), by the user
    assert {(w.variant_type, w.user) for w in server.client_writes()[before:]} == {("Double", "seawriter")}


def test_an_unqualified_model_is_refused_before_connecting(server, tmp_path):
    make_registry(tmp_path / "results" / "m1" / "registry", artefact())
    other = artefact(coef=[1.0, 2.0, 3.0])
    model = tmp_path / "other.json"
    model.write_text(json.dumps(other))
    args = write_config(tmp_path, server)
    args.model = str(model)
    before = len(server.client_writes())
    with pytest.raises(UnqualifiedModel, match="not the champion"):
        live_cli.build(args, environ=ENV)
    (tmp_path / "results" / "m1" / "registry" / "champion.json").unlink()
    args.model = None
    with pytest.raises(UnqualifiedModel, match="no champion"):
        live_cli.run(args)
    assert len(server.client_writes()) == before


def test_the_cli_runs_cycles_and_exits_0(server, tmp_path, monkeypatch, capsys):
    from rafi.cli import main

    make_registry(tmp_path / "results" / "m1" / "registry", artefact())
    args = write_config(tmp_path, server, deploy={"interval_s": 0.05})
    for k, v in ENV.items():
        monkeypatch.setenv(k, v)
    server.set_inputs(6000.0, [20.0] * 16)
    before = len(sd_writes(server))
    assert main(["deploy", "--machine", "m1", "--config", args.config, "--cycles", "3"]) == 0
    assert len(sd_writes(server)) == before + 3
    assert "3 cycles, 3 writes" in capsys.readouterr().out
    monkeypatch.setenv("RAFI_OPCUA_PASSWORD", "wrong")
    assert main(["deploy", "--machine", "m1", "--config", args.config, "--cycles", "1"]) == 64
    assert "refused for user 'seawriter': BadUserAccessDenied" in capsys.readouterr().err
    assert len(sd_writes(server)) == before + 3


def test_credentials_and_the_right_to_write(server):
    settings = opcua_settings(
        {"endpoint": server.endpoint, "inputs": inputs(), "timeout_s": 3, "allow_insecure": True}
    )
    with OpcUaLink(settings, user="seawriter", password="nope") as refused:  # closed: no thread left
        with pytest.raises(
            RafiUserError, match="the login was refused for user 'seawriter'.*wrong user or password"
        ):
            refused.connect()
    before, value = len(server.client_writes()), server.value(server.sd_node())
    with OpcUaLink(settings).connect() as anonymous:  # may read ...
        server.set_inputs(3000.0, [21.0] * 16)
        t, speed, temps = anonymous.read_sample(0.0)
        assert speed == 3000.0 and temps[0] == pytest.approx(21.0)
        with pytest.raises(RafiUserError, match="anonymous session: BadUserAccessDenied"):
            anonymous.write_value(server.sd_node(), 0.001, "Double")  # ... but not write
    assert len(server.client_writes()) == before and server.value(server.sd_node()) == value


def test_each_node_is_written_with_its_own_type(server):
    settings = opcua_settings(
        {"endpoint": server.endpoint, "inputs": inputs(), "timeout_s": 3, "allow_insecure": True}
    )
    with OpcUaLink(settings, user="seawriter", password="s3cret-Pw").connect() as link:
        link.write_value(PLC_COMP_NODE, 0.0125, "Double")  # a Float node: written as Float
        link.write_value(server.sd_node(), 0.0125, "Double")
        with pytest.raises(RafiUserError, match="is of type Int16"):
            link.write_value(temp_node(1)[0], 0.0125, "Double")
    last = server.client_writes()[-2:]
    assert [(w.node, w.variant_type) for w in last] == [
        (PLC_COMP_NODE, "Float"),
        (server.sd_node(), "Double"),
    ]
    assert server.value(server.sd_node()) == 0.0125


# --------------------------------------------------------------------------- bumpless


def _held_server(value_mm: float, extra=None) -> SinumerikLikeServer:
    """A server of its own whose SD 43900 holds ``value_mm`` from the last session (and
    ``extra`` nodes: name -> (value, variant type); names under /NC/ are writable)."""
    from asyncua import ua

    srv = SinumerikLikeServer(axis=3)
    srv.values[srv.sd_node()] = (value_mm, ua.VariantType.Double)
    srv.values.update(extra or {})
    return srv.start()


HELD_UM = -6.8  # on the axis: SD 43900 = SIGN * -6.8 um = +0.0068 mm
CHANGED_UM = 3.0  # what someone sets during the outage


@pytest.mark.parametrize("fault_from_start", [False, True])
def test_every_write_is_bumpless_from_the_held_value_and_after_a_changed_reconnect(
    tmp_path, fault_from_start
):
    """The done-when test of issue 24: every write differs from the value before it on the
    controller (the held one first; after a reconnect, the one someone set meanwhile) by at most
    rate x interval (plus one resolution step of rounding), with or without a fault (T8, a
    sensor the model reads, BadSensorFailure) from the first sample."""
    from asyncua import ua

    rows = scenario()
    if fault_from_start:
        for _, temps in rows[:8]:  # inside the reference window (12 samples): T8 gets a reference
            temps[SENSORS.index("T8")] = math.nan
    srv = _held_server(SIGN * HELD_UM / 1000)
    try:
        make_registry(tmp_path / "results" / "m1" / "registry", artefact())
        args = write_config(tmp_path, srv)
        log = []
        loop, link = live_cli.build(args, log=log.append, environ=ENV)
        clock = [5000.0]
        loop.clock = link.clock = lambda: clock[0]
        down = range(50, 54)
        delivered, cycle = [], [0]

        def feed(c):
            speed, temps = rows[c]
            srv.set_inputs(speed, temps)
            delivered.append((clock[0], speed, as_read(temps)))

        def sleep(seconds):
            clock[0] += seconds
            cycle[0] += 1
            c = cycle[0]
            if c == down.start:
                srv.stop()
                srv.values[srv.sd_node()] = (SIGN * CHANGED_UM / 1000, ua.VariantType.Double)
            elif c == down.stop:
                srv.start()
            if c not in down and c < len(rows):
                feed(c)

        loop.sleep = sleep
        try:
            link.connect()
            feed(0)
            loop.run(max_cycles=len(rows))
        finally:
            link.close()
        got_um = [SIGN * v * 1000 for v in sd_writes(srv)]
    finally:
        srv.close()
    resumed = down.start  # the index in `delivered` of the first sample after the outage
    assert len(got_um) == len(delivered) == len(rows) - len(down)
    before = [HELD_UM, *got_um[:-1]]
    before[resumed] = CHANGED_UM
    steps = np.abs(np.subtract(got_um, before))
    assert got_um[0] == pytest.approx(HELD_UM, abs=1e-9)  # the first write is the held value
    assert steps.max() <= DEPLOY["rate_um_per_s"] * DT + 1e3 / INCR
    expected = expected_commands(delivered, start=HELD_UM, resumes={resumed: CHANGED_UM})
    assert got_um == pytest.approx([c for c, _ in expected], abs=0.5e3 / INCR + 1e-9)
    statuses = [s for _, s in expected]
    if fault_from_start:
        assert statuses[:8] == ["hold"] * 6 + ["ramp"] * 2  # held, then towards safe_um
        assert "ok" in statuses
        assert any("T8 missing" in line and "model: no value" in line for line in log)
    else:
        assert statuses[:12] == ["referencing"] * 12  # towards safe_um at the rate limit
    assert any("holds -6.800 um" in line for line in log) and any("+3.000 um after" in line for line in log)
    assert not any("nan" in line for line in log)


# --------------------------------------------------------------------------- preflight


def _main(args, *argv) -> int:
    from rafi.cli import main

    return main(["deploy", "--machine", args.machine, "--config", args.config, *argv])


def test_preflight_lists_every_wrong_node_and_writes_nothing(tmp_path, monkeypatch, capsys):
    from asyncua import ua

    int16_sd = "/NC/_N_AX_SEA_ACX/$SA_TEMP_COMP_ABS_VALUE[u4]"  # an Int16 where SD 43900 should be
    read_only = "/Ro/$SA_TEMP_COMP_ABS_VALUE[u5]"  # a Double this user may not write
    extra = {int16_sd: (0, ua.VariantType.Int16), read_only: (0.0, ua.VariantType.Double)}
    srv = _held_server(0.0, extra)
    try:
        make_registry(tmp_path / "results" / "m1" / "registry", artefact())
        for k, v in ENV.items():
            monkeypatch.setenv(k, v)
        wrong_input = {**inputs(), "T8": "/Plc/DB100.DBW99"}
        axis = {"name": "Z", "number": 4, "sign": SIGN, "limit_um": 50.0}
        opcua = {"endpoint": srv.endpoint, "inputs": wrong_input, "timeout_s": 3, "allow_insecure": True}
        target = {"kind": "sinumerik", "axis": axis, "int_incr_per_mm": INCR}
        args = write_config(tmp_path, srv, deploy={"opcua": opcua, "target": target})
        assert _main(args, "--cycles", "2") == 64
        err = capsys.readouterr().err.splitlines()
        assert any(
            "deploy.opcua.inputs.T8: node ns=2;s=/Plc/DB100.DBW99: the server has no such" in e for e in err
        )
        assert any(f"node ns=2;s={int16_sd} is of type Int16" in e for e in err)
        assert err[-1] == "rafi deploy: 2 problems: nothing written"
        target = {**target, "axis": {**axis, "number": 5}, "node_template": "/Ro/$SA_{data}[u{axis}]"}
        args = write_config(tmp_path, srv, deploy={"target": target})
        assert _main(args, "--cycles", "2") == 64
        err = capsys.readouterr().err
        assert "is not writable for user 'seawriter'" in err and "Traceback" not in err
        assert srv.client_writes() == [] and srv.refused == []
    finally:
        srv.close()


def test_a_target_node_declared_with_an_abstract_data_type_is_judged_by_its_value(
    tmp_path, monkeypatch, capsys
):
    """A server may declare an NC variable as BaseDataType: the preflight then judges the value
    it holds (a Double: written; an Int16: refused), as the write itself does."""
    from asyncua import ua

    int16_sd = "/NC/_N_AX_SEA_ACX/$SA_TEMP_COMP_ABS_VALUE[u4]"
    srv = SinumerikLikeServer(axis=3)
    srv.values[int16_sd] = (0, ua.VariantType.Int16)
    for name in (srv.sd_node(), int16_sd):
        srv.declared_types[name] = ua.NodeId(ua.ObjectIds.BaseDataType)
    srv.start()
    try:
        make_registry(tmp_path / "results" / "m1" / "registry", artefact())
        for k, v in ENV.items():
            monkeypatch.setenv(k, v)
        args = write_config(tmp_path, srv)
        assert _main(args, "--cycles", "2") == 0, capsys.readouterr().err
        assert [w.variant_type for w in srv.client_writes() if w.node == srv.sd_node()] == ["Double"] * 2
        axis = {"name": "Z", "number": 4, "sign": SIGN, "limit_um": 50.0}
        target = {"kind": "sinumerik", "axis": axis, "int_incr_per_mm": INCR}
        args = write_config(tmp_path, srv, deploy={"target": target})
        capsys.readouterr()
        assert _main(args, "--cycles", "2") == 64
        assert f"node ns=2;s={int16_sd} is of type Int16" in capsys.readouterr().err
    finally:
        srv.close()


def test_an_anonymous_session_is_refused_before_connecting(server, tmp_path, monkeypatch, capsys):
    make_registry(tmp_path / "results" / "m1" / "registry", artefact())
    for k in ("RAFI_OPCUA_USER", "RAFI_OPCUA_PASSWORD", "RAFI_OPCUA_CREDENTIALS"):
        monkeypatch.delenv(k, raising=False)
    args = write_config(tmp_path, server)
    before = len(server.client_writes()), len(server.refused)
    assert _main(args, "--cycles", "2") == 64
    err = capsys.readouterr().err
    assert "the sinumerik target writes to the controller, but no OPC UA user is configured" in err
    assert len(err.strip().splitlines()) == 1, err
    assert (len(server.client_writes()), len(server.refused)) == before


def test_a_dry_run_starts_from_the_controller_and_says_would_write(tmp_path, monkeypatch, capsys):
    srv = _held_server(SIGN * HELD_UM / 1000)
    try:
        make_registry(tmp_path / "results" / "m1" / "registry", artefact())
        for k in ("RAFI_OPCUA_USER", "RAFI_OPCUA_PASSWORD", "RAFI_OPCUA_CREDENTIALS"):
            monkeypatch.delenv(k, raising=False)  # a dry run needs no user with write rights
        args = write_config(tmp_path, srv, deploy={"interval_s": 0.05})
        srv.set_inputs(6000.0, [20.0] * 16)
        assert _main(args, "--cycles", "1", "--dry-run") == 0
        out = capsys.readouterr().out
        assert "holds -6.800 um: the command starts from -6.800 um" in out
        assert "-6.800 um (model +0.000 um)" in out
        assert "1 cycle, would write 1 value (dry run: nothing written), 0 cycles without" in out
        assert srv.client_writes() == []
    finally:
        srv.close()


# --------------------------------------------------------------------------- stopping


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_stop_while_connecting_is_one_line_and_exit_0(tmp_path, signum):
    """`rafi deploy` in its own process, against a server that accepts the TCP connection and
    never answers: Ctrl-C (SIGINT) or SIGTERM while it connects gives exit 0 and one line."""
    import os
    import socket
    import subprocess
    import sys
    from pathlib import Path

    import rafi

    make_registry(tmp_path / "results" / "m1" / "registry", artefact())
    with socket.socket() as mute:
        mute.bind(("127.0.0.1", 0))
        mute.listen(1)
        mute.settimeout(180)
        endpoint = f"opc.tcp://127.0.0.1:{mute.getsockname()[1]}"
        opcua = {"endpoint": endpoint, "inputs": inputs(), "timeout_s": 120, "allow_insecure": True}
        args = write_config(tmp_path, argparse.Namespace(endpoint=endpoint), deploy={"opcua": opcua})
        env = {**os.environ, **ENV, "PYTHONPATH": str(Path(rafi.__file__).parent.parent)}
        cmd = [sys.executable, "-m", "rafi.cli", "deploy", "--machine", "m1", "--config", args.config]
        proc = subprocess.Popen(
            cmd,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            # as from a terminal: a runner that starts the tests in the background (`cmd &` in a
            # script) hands down SIGINT ignored, and Python then never raises KeyboardInterrupt
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        )
        try:
            conn, _ = mute.accept()  # the client is connecting now, and waits for an answer
            with conn:
                proc.send_signal(signum)
                out, err = proc.communicate(timeout=180)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
    name = "Ctrl-C" if signum == signal.SIGINT else "SIGTERM"
    assert proc.returncode == 0, err
    *warnings, last = out.splitlines()
    assert last == (
        f"rafi deploy: stopped while connecting ({name}); nothing was written; the controller keeps its value"
    )
    assert len(warnings) == 1 and "WARNING allow_insecure: the password" in warnings[0]
    # nothing else: no traceback, no "Task was destroyed but it is pending!", no asyncua line
    assert err == "", err


def _deploy_process(args, *extra, env_extra=None):
    """``rafi deploy`` of ``args`` in its own process, SIGINT as from a terminal."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    import rafi

    env = {**os.environ, **ENV, "PYTHONPATH": str(Path(rafi.__file__).parent.parent), **(env_extra or {})}
    cmd = [sys.executable, "-m", "rafi.cli", "deploy", "--machine", "m1", "--config", args.config, *extra]
    return subprocess.Popen(
        cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip


def test_a_stop_mid_write_says_the_phase_it_was_in_not_reconnecting(server, tmp_path):
    """Ctrl-C arrives while the server handles the first write (the server sends it before it
    answers): the line names the loop's phase then, not "reconnecting" (the link is closed with the
    target only afterwards)."""
    make_registry(tmp_path / "results" / "m1" / "registry", artefact())
    args = write_config(tmp_path, server)
    node = server.sd_node()
    proc = _deploy_process(args)
    server.on_write = lambda w: proc.send_signal(signal.SIGINT) if w.node == node else None
    try:
        out, err = proc.communicate(timeout=120)
    finally:
        server.on_write = None
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    stopped = [line for line in out.splitlines() if "stopped while" in line]
    assert stopped == [
        "rafi deploy: stopped while referencing (Ctrl-C); the target is closed, the last value stays "
        "on the controller"
    ], out
    assert err == "", err


@pytest.mark.parametrize("outage_cycles", [4, 14, 60])  # 20 s, 70 s and 300 s at 5 s a cycle
def test_the_first_write_comes_in_the_first_cycle_after_the_server_is_back(server, tmp_path, outage_cycles):
    """Whatever the outage's length, with the default reconnect settings: no session is tried
    while the port does not answer (a TCP probe each cycle), and the cycle after the server is
    back reconnects and writes. The metrics say ``outage`` meanwhile and have no model value while
    referencing."""
    from rafi.deploy.metrics import LoopMetrics

    make_registry(tmp_path / "results" / "m1" / "registry", artefact())
    args = write_config(tmp_path, server)
    config = yaml.safe_load(open(args.config))
    opcua = config["machines"]["m1"]["deploy"]["opcua"]
    del opcua["reconnect_min_s"], opcua["reconnect_max_s"]  # the defaults
    open(args.config, "w").write(yaml.safe_dump(config))
    rows = scenario()
    log = []
    loop, link = live_cli.build(args, log=log.append, environ=ENV)
    loop.metrics = metrics = LoopMetrics(machine="m1")
    clock = [5000.0]
    loop.clock = link.clock = lambda: clock[0]
    first_down = 20
    down = range(first_down, first_down + outage_cycles)
    n = first_down + outage_cycles + 5
    cycle, seen = [0], []

    def gauge(name, **labels):
        return metrics.registry.get_sample_value(name, {"machine": "m1", **labels})

    def sleep(seconds):  # after cycle c: what the cycle left, then the world of cycle c + 1
        status = loop.last_command.status if loop.last_command else None
        outage = gauge("rafi_deploy_status", status="outage")
        seen.append((cycle[0], len(sd_writes(server)), link.reconnect.tries, status, outage,
                     gauge("rafi_deploy_model_um")))  # fmt: skip
        clock[0] += seconds
        cycle[0] += 1
        c = cycle[0]
        if c == down.start:
            server.stop()
        elif c == down.stop:
            server.start()
        if c not in down:
            server.set_inputs(*rows[c % len(rows)])

    loop.sleep = sleep
    try:
        link.connect()
        server.set_inputs(*rows[0])
        loop.run(max_cycles=n)
    finally:
        link.close()
    writes = [w for _, w, *_ in seen]
    tries = [t for _, _, t, *_ in seen]
    back = down.stop
    assert writes[first_down] == writes[first_down - 1]  # the cycle that lost the connection
    assert len(set(writes[first_down:back])) == 1  # nothing written while the server was away
    assert tries[back - 1] == tries[first_down - 1]  # no session tried while its port was closed
    assert writes[back] == writes[back - 1] + 1  # the first cycle after its return writes
    assert tries[back] == tries[back - 1] + 1 and link.reconnects == 1
    outage = {c: o for c, _, _, _, o, _ in seen}
    assert all(outage[c] == 1 for c in down) and outage[back] == 0 and outage[first_down - 1] == 0
    referencing = [model for _, _, _, status, _, model in seen if status == "referencing"]
    assert referencing and all(math.isnan(m) for m in referencing)  # 0 um is the reference, no value
    assert any(math.isfinite(m) for _, _, _, status, _, m in seen if status == "ok")
    # the link's lines prefixed as the command's own, once per event; none of asyncua's
    link_lines = [line for line in log if "OPC UA" in line]
    assert [line.split(" (")[0] for line in link_lines] == [
        f"rafi deploy: OPC UA {server.endpoint}: WARNING allow_insecure: the password of user 'seawriter' is "
        "sent unencrypted",
        f"rafi deploy: OPC UA {server.endpoint}: connection lost",
        f"rafi deploy: OPC UA {server.endpoint}: reconnected",
    ], link_lines


class _RefusingPort:
    """Accepts every TCP connection and closes it: a probe (no byte sent) or an OPC UA session
    (its Hello arrives first: counted in ``sessions``)."""

    def __init__(self):
        import socket
        import threading

        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.endpoint = f"opc.tcp://127.0.0.1:{self.sock.getsockname()[1]}"
        self.sessions = self.probes = 0
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self):
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            with conn:
                conn.settimeout(10)
                try:
                    hello = conn.recv(64)
                except OSError:
                    hello = b""
                if hello.startswith(b"HEL"):
                    self.sessions += 1
                else:
                    self.probes += 1

    def close(self):
        import socket

        self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()
        self._thread.join(10)


def test_a_port_that_answers_but_refuses_sessions_is_not_hammered():
    """Tried every second for 60 s: a session at the first try, then after 1, 2, 4, 8, 8 ... s
    (reconnect_min_s doubling up to reconnect_max_s, the defaults), counted by the server."""
    port = _RefusingPort()
    clock = [0.0]
    link = OpcUaLink(opcua_settings({"endpoint": port.endpoint, "inputs": inputs(), "timeout_s": 3}))
    link.clock = lambda: clock[0]
    try:
        for second in range(60):
            clock[0] = float(second)
            assert link.try_reconnect() is False
    finally:
        link.close()
        port.close()
    expected, t, wait = [], 0.0, OPCUA_DEFAULTS["reconnect_min_s"]
    while t < 60:
        expected.append(t)
        t, wait = t + wait, min(2 * wait, OPCUA_DEFAULTS["reconnect_max_s"])
    assert port.sessions == len(expected) == 10  # at 0, 1, 3, 7, 15, 23, 31, 39, 47, 55 s
    assert "closed the connection before the session was open" in link.last_error


def test_a_failed_connect_says_why_and_never_connection_lost(tmp_path):
    """Nothing ever connected: the port refused, or never answered (a full backlog drops the
    handshake, as an unroutable address does), or closed the connection: said as such."""
    import socket

    refused = socket.socket()
    refused.bind(("127.0.0.1", 0))
    closed_port = refused.getsockname()[1]
    refused.close()
    full = socket.socket()
    full.bind(("127.0.0.1", 0))
    full.listen(0)
    queued = socket.create_connection(full.getsockname(), timeout=5)  # fills the backlog
    closing = _RefusingPort()
    cases = {
        f"opc.tcp://127.0.0.1:{closed_port}": f"127.0.0.1:{closed_port} refused the connection",
        f"opc.tcp://127.0.0.1:{full.getsockname()[1]}": (
            f"no answer from 127.0.0.1:{full.getsockname()[1]} within 1 s"
        ),
        closing.endpoint: "the server closed the connection before the session was open",
    }
    try:
        for endpoint, why in cases.items():
            log = []
            settings = opcua_settings({"endpoint": endpoint, "inputs": inputs(), "timeout_s": 1})
            link = OpcUaLink(settings, log=log.append)
            with link, pytest.raises(ConnectionError) as failed:
                link.connect()
            message = str(failed.value)
            assert message.startswith(f"OPC UA {endpoint}: cannot connect: {why}"), message
            assert "connection lost" not in message and log == [] and link.losses == 0
    finally:
        queued.close()
        full.close()
        closing.close()


class _Notify:
    """What systemd would be told (rafi.deploy.sd_notify.SdNotify's calls)."""

    def __init__(self):
        self.calls = []

    def ready(self, status=None):
        self.calls.append(("ready", status))

    def watchdog(self):
        self.calls.append(("watchdog", None))


def test_waiting_for_a_controller_that_boots_late(tmp_path):
    """The server starts 130 s (of an injected clock) after the first try: one line when the wait
    begins and one a minute, READY=1 with the waiting status, the watchdog fed at every try, no
    session tried while the port is closed, connected at the first try after the server is up."""
    from rafi.deploy.opcua_reconnect import wait_for_controller

    late = SinumerikLikeServer(axis=3)  # not started yet
    clock = [0.0]
    log, notify = [], _Notify()
    link = OpcUaLink(opcua_settings({"endpoint": late.endpoint, "inputs": inputs(), "timeout_s": 3}))
    link.log = lambda m: log.append(f"link: {m}")
    link.clock = lambda: clock[0]
    steps = []

    def sleep(seconds):
        clock[0] += seconds
        steps.append(clock[0])
        if clock[0] == 130.0:
            late.start()

    try:
        waited = wait_for_controller(
            link, log=log.append, notify=notify, sleep=sleep, on_wait=lambda: log.append("on_wait")
        )
        assert link.connected and waited == 130.0 and steps[-1] == 130.0
        assert link.read_inputs()["speed_rpm"] == 0.0
    finally:
        link.close()
        late.close()
    assert log[0].startswith("waiting for the controller (OPC UA " + late.endpoint + ": cannot connect: ")
    assert "refused the connection" in log[0] and log[1] == "on_wait"
    still = [line for line in log if line.startswith("still waiting")]
    assert [line.split(" (")[0] for line in still] == [
        "still waiting for the controller after 60 s",
        "still waiting for the controller after 120 s",
    ]
    assert log[-1] == f"link: OPC UA {late.endpoint}: connected" and len(log) == 5
    assert notify.calls[0] == ("ready", f"waiting for the controller at {late.endpoint}")
    assert notify.calls[1:] == [("watchdog", None)] * len(steps)
    assert link.reconnect.tries == 2 and link.reconnects == 0  # the first connect and the last


def test_rafi_deploy_waits_for_a_late_controller_under_systemd(tmp_path):
    """``rafi deploy --wait-for-controller`` (as the unit runs it) with the controller off: it
    tells systemd it is up and waiting, feeds the watchdog, and once the server starts (when the
    first watchdog ping arrived) connects, writes and ends its cycles with exit 0; without the
    flag the same start is exit 69."""
    import socket

    make_registry(tmp_path / "results" / "m1" / "registry", artefact())
    late = SinumerikLikeServer(axis=3)
    args = write_config(tmp_path, late)
    proc = _deploy_process(args, "--cycles", "1")
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 69 and "refused the connection" in err, (out, err)
    address = str(tmp_path / "notify")
    datagrams = []
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sd:
        sd.bind(address)
        sd.settimeout(60)
        proc = _deploy_process(
            args, "--wait-for-controller", "--cycles", "2", env_extra={"NOTIFY_SOCKET": address}
        )
        try:
            while not datagrams or datagrams[-1] != "WATCHDOG=1":
                datagrams.append(sd.recv(4096).decode())
            late.start()  # the controller boots now
            out, err = proc.communicate(timeout=120)
            sd.settimeout(0)
            while True:
                try:
                    datagrams.append(sd.recv(4096).decode())
                except BlockingIOError:
                    break
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            writes = len(sd_writes(late))
            late.close()
    assert proc.returncode == 0, (out, err)
    assert datagrams[0] == f"READY=1\nSTATUS=waiting for the controller at {late.endpoint}"
    ready = [i for i, d in enumerate(datagrams) if d.startswith("READY=1\nSTATUS=model ")]
    assert len(ready) == 1 and "WATCHDOG=1" in datagrams[1 : ready[0]]
    assert writes == 2
    lines = out.splitlines()
    waiting = [
        i for i, line in enumerate(lines) if line.startswith("rafi deploy: waiting for the controller (")
    ]
    connected = lines.index(f"rafi deploy: OPC UA {late.endpoint}: connected")
    assert len(waiting) == 1 and waiting[0] < connected and "exit" not in out
    assert err == "", err
