"""The systemd units of docs/systemd (docs/service.md): checked by ``systemd-analyze verify``
(it needs no running systemd, only the unit and the programs it names), and their command
lines parsed by rafi's own argument parser.

``verify`` refuses a unit whose ExecStart program does not exist, so each unit is verified on a
copy whose project folder (/opt/rafi) is a temporary folder holding an executable
``.venv/bin/rafi``; everything else is the shipped text. A warning (an unknown key, a value
that does not parse) fails the test, not only a non-zero status.
"""

from __future__ import annotations

import configparser
import shlex
import subprocess
from pathlib import Path

import pytest
from conftest import which_or_skip

from rafi.cli import COMMANDS, build_parser

UNITS = Path(__file__).resolve().parents[1] / "docs" / "systemd"
NAMES = ["rafi-deploy@.service", "rafi-record@.service"]
PROJECT = "/opt/rafi"


def unit(name: str) -> configparser.ConfigParser:
    """The unit's sections; a key given twice keeps its last value (``Environment`` aside)."""
    parser = configparser.ConfigParser(strict=False, interpolation=None, delimiters=("=",))
    parser.optionxform = str
    parser.read_string((UNITS / name).read_text(encoding="utf-8"))
    return parser


def test_the_units_are_the_two_documented():
    assert sorted(p.name for p in UNITS.iterdir()) == sorted(NAMES)
    service = (UNITS.parent / "service.md").read_text(encoding="utf-8")
    for name in NAMES:
        assert f"docs/systemd/{name}" in service


@pytest.mark.parametrize("name", NAMES)
def test_systemd_analyze_verify(name, tmp_path):
    analyze = which_or_skip("systemd-analyze")
    project = tmp_path / "opt"
    rafi = project / ".venv" / "bin" / "rafi"
    rafi.parent.mkdir(parents=True)
    rafi.write_text("#!/bin/sh\nexit 0\n")
    rafi.chmod(0o755)
    text = (UNITS / name).read_text(encoding="utf-8")
    assert text.count(PROJECT) >= 3
    (tmp_path / name).write_text(text.replace(PROJECT, str(project)))
    instance = tmp_path / name.replace("@.", "@tapping-center-a.")
    done = subprocess.run(
        [analyze, "verify", str(instance)], capture_output=True, text=True, timeout=120, check=False
    )
    assert (done.returncode, done.stderr.strip(), done.stdout.strip()) == (0, "", "")


@pytest.mark.parametrize("name", NAMES)
def test_what_the_units_promise(name):
    service = unit(name)["Service"]
    assert service["Restart"] == "on-failure" and float(service["RestartSec"]) > 0
    assert service["RestartPreventExitStatus"].split() == ["64", "65"]
    assert service["Type"] == "notify" and int(service["WatchdogSec"]) >= 60
    assert service["User"] not in ("root", "nobody") and service["WorkingDirectory"] == PROJECT
    assert service["ProtectSystem"] == "strict" and service["NoNewPrivileges"] == "yes"
    assert service["PrivateTmp"] == "yes"
    assert set(service["RestrictAddressFamilies"].split()) >= {"AF_INET", "AF_INET6", "AF_UNIX"}
    text = (UNITS / name).read_text(encoding="utf-8")
    assert "PASSWORD" not in text and "RAFI_OPCUA_CREDENTIALS=%d/opcua" in text  # a path, never the secret
    assert "PrivateNetwork" not in text  # OPC UA needs the network


@pytest.mark.parametrize("name", NAMES)
def test_the_command_line_is_one_rafi_accepts(name):
    argv = shlex.split(unit(name)["Service"]["ExecStart"].replace("%i", "tapping-center-a"))
    assert argv[0] == f"{PROJECT}/.venv/bin/rafi"
    command = argv[1]
    if command not in COMMANDS:
        pytest.skip(f"rafi {command} is not a sub-command of this build yet")
    args = build_parser().parse_args(argv[1:])
    assert (args.command, args.machine, args.config) == (
        command,
        "tapping-center-a",
        f"{PROJECT}/config.yaml",
    )
    assert getattr(args, "cycles", None) is None and not getattr(args, "dry_run", False)
    assert args.wait_for_controller  # a controller that boots later than the PC is waited for


@pytest.mark.parametrize("name", NAMES)
def test_restarts_never_leave_the_unit_failed_for_good(name):
    """No start limit (StartLimitIntervalSec=0), or one that restarts RestartSec apart can never
    reach: StartLimitBurst starts need at least (burst - 1) x RestartSec."""
    parsed = unit(name)
    interval = float(parsed["Unit"].get("StartLimitIntervalSec", "10"))
    burst = int(parsed["Unit"].get("StartLimitBurst", "5"))
    restart_s = float(parsed["Service"]["RestartSec"])
    assert interval == 0 or (burst - 1) * restart_s > interval
