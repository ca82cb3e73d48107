"""systemd notifications (rafi.deploy.sd_notify) received on a real unix datagram socket, as
systemd's $NOTIFY_SOCKET would receive them: a path socket and an abstract one."""

from __future__ import annotations

import os
import socket
import tempfile

import pytest

from rafi.deploy.sd_notify import SdNotify


@pytest.fixture
def listener():
    """A bound datagram socket in a short temporary folder (unix paths are limited to 107 bytes)."""
    with tempfile.TemporaryDirectory(dir="/tmp") as folder:
        path = os.path.join(folder, "notify")
        with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
            sock.bind(path)
            sock.settimeout(10)
            yield path, sock


def received(sock) -> list[str]:
    return sock.recv(4096).decode("utf-8").split("\n")


def test_outside_systemd_every_call_does_nothing():
    notify = SdNotify({})
    assert not notify.enabled and notify.watchdog_s is None
    assert notify.ready("x") is False and notify.watchdog() is False and notify.stopping() is False


def test_the_messages_arrive_as_systemd_reads_them(listener):
    path, sock = listener
    notify = SdNotify({"NOTIFY_SOCKET": path})
    assert notify.enabled
    assert notify.ready("model 32b3bda3658a ->\n SINUMERIK axis Z")
    assert received(sock) == ["READY=1", "STATUS=model 32b3bda3658a -> SINUMERIK axis Z"]
    assert notify.watchdog()
    assert received(sock) == ["WATCHDOG=1"]
    assert notify.status("hold +1.250 um  T8 missing")
    assert received(sock) == ["STATUS=hold +1.250 um T8 missing"]
    assert notify.stopping()
    assert received(sock) == ["STOPPING=1"]


def test_an_abstract_socket():
    name = f"rafi-test-notify-{os.getpid()}"
    with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
        sock.bind("\0" + name)
        sock.settimeout(10)
        assert SdNotify({"NOTIFY_SOCKET": "@" + name}).watchdog()
        assert received(sock) == ["WATCHDOG=1"]


def test_a_failed_send_is_logged_once_and_never_raises(tmp_path):
    lines = []
    notify = SdNotify({"NOTIFY_SOCKET": str(tmp_path / "gone")}, log=lines.append)
    assert notify.watchdog() is False and notify.watchdog() is False
    assert len(lines) == 1 and lines[0].startswith(f"systemd notification to {tmp_path / 'gone'} failed")


def test_the_watchdog_period_and_its_owner():
    assert SdNotify({"WATCHDOG_USEC": "120000000"}).watchdog_s == 120.0
    assert SdNotify({"WATCHDOG_USEC": "120000000", "WATCHDOG_PID": str(os.getpid())}).watchdog_s == 120.0
    assert SdNotify({"WATCHDOG_USEC": "120000000", "WATCHDOG_PID": "1"}).watchdog_s is None  # another process
    notify = SdNotify({"WATCHDOG_USEC": "120000000"})
    assert notify.interval_warning(5.0) is None
    assert "more than half the unit's WatchdogSec (120 s)" in notify.interval_warning(90.0)
    assert SdNotify({"NOTIFY_SOCKET": "vsock:2:1234"}).enabled is False
