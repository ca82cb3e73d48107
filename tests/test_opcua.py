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

import numpy as np
import pytest
import yaml

pytest.importorskip("asyncua")

from opcua_server import PLC_COMP_NODE, SPEED_NODE, SinumerikLikeServer, temp_node  # noqa: E402
from test_live import DEPLOY, DT, artefact, expected_commands, make_registry, scenario  # noqa: E402

from rafi.deploy import live_cli  # noqa: E402
from rafi.deploy.opcua_client import OpcUaLink, opcua_settings  # noqa: E402
from rafi.errors import RafiUserError, UnqualifiedModel  # noqa: E402

INCR = 100000  # MD 10200: 0.01 um resolution
SIGN = -1


@pytest.fixture(scope="module")
def server():
    with SinumerikLikeServer(axis=3) as srv:
        yield srv


def inputs() -> dict:
    out = {"speed_rpm": SPEED_NODE}
    for i in range(1, 17):
        name, _, scale = temp_node(i)
        out[f"T{i}"] = {"node": name, "scale": scale}
    return out


def as_read(temps) -> np.ndarray:
    """The temperatures as the client reads them: Int16 in 0.1 degC, Float (single) in degC."""
    out = []
    for i, t in enumerate(temps, start=1):
        _, vtype, scale = temp_node(i)
        if not math.isfinite(t):
            out.append(math.nan)
        elif vtype.name == "Int16":
            out.append(float(int(round(t / scale))) * scale)
        else:
            out.append(float(np.float32(t)))
    return np.array(out)


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
    with pytest.raises(RafiUserError, match="the login refused for user 'seawriter'.*wrong user or password"):
        OpcUaLink(settings, user="seawriter", password="nope").connect()
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
