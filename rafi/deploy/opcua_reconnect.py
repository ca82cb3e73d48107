"""When the OPC UA link tries a session again: a TCP probe of the port, and a short back-off.

The link (:class:`rafi.deploy.opcua_client.OpcUaLink`) asks :class:`ReconnectPolicy` once per
cycle of its caller (the live loop, the recorder, :func:`wait_for_controller`) whether to try a
full OPC UA session now:

* first a *probe*: a TCP connection to the endpoint's host and port, closed at once
  (:func:`port_problem`; no OPC UA message: it costs the server nothing). While the port does
  not answer (the controller is off, booting, or the network is down) no session is tried;
* when the port answers again after it did not, a session is tried at once: the first write
  comes one cycle (``deploy.interval_s``) after the server is back, however long it was away;
* while the port answers but the session fails (a server that is starting, or that refuses:
  too many sessions), the next try waits ``reconnect_min_s``, doubling up to ``reconnect_max_s``
  (:data:`rafi.deploy.opcua_client.OPCUA_DEFAULTS`): never a tight loop of sessions.

:func:`wait_for_controller` connects at the start of ``rafi deploy`` / ``rafi record
--wait-for-controller`` (the systemd units pass it, ``docs/service.md``): it tries with the same
policy until the controller answers, logs one line a minute, says ``STATUS=waiting for the
controller`` to systemd and feeds its watchdog. Standard library only.
"""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Callable
from urllib.parse import urlsplit

__all__ = [
    "DEFAULT_PORT",
    "ReconnectPolicy",
    "add_wait_option",
    "endpoint_address",
    "port_problem",
    "prefixed",
    "wait_for_controller",
]

#: The port of an ``opc.tcp://`` endpoint that names none (OPC UA's registered port).
DEFAULT_PORT = 4840
#: Seconds between two tries of :func:`wait_for_controller` (a probe each; a session when due).
WAIT_STEP_S = 1.0
#: Seconds between two lines of :func:`wait_for_controller` while it waits.
WAIT_REPORT_S = 60.0


def endpoint_address(endpoint: str) -> tuple[str, int]:
    """``(host, port)`` of an ``opc.tcp://host[:port][/path]`` endpoint (port 4840 if none).

    Parameters
    ----------
    endpoint : str
        The endpoint (``deploy.opcua.endpoint``, already checked to start with ``opc.tcp://``).

    Returns
    -------
    (str, int)
        The host (an IPv6 address without its brackets) and the port.
    """
    parts = urlsplit(endpoint)
    try:
        port = parts.port
    except ValueError:
        port = None
    return parts.hostname or "", port or DEFAULT_PORT


def port_problem(host: str, port: int, timeout_s: float) -> str | None:
    """Why a TCP connection to ``host``:``port`` does not open within ``timeout_s``; None if it
    opens (it is closed at once: no OPC UA message is sent).

    Parameters
    ----------
    host : str
        Name or address (every address the name resolves to is tried).
    port : int
        TCP port.
    timeout_s : float
        Seconds to wait for the connection (an unroutable host answers nothing).

    Returns
    -------
    str or None
        None: the port accepted the connection. Else one phrase for "cannot connect: ...": the
        connection refused, no answer in time, the name not found, the network unreachable.
    """
    where = f"{host}:{port}"
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return None
    except ConnectionRefusedError:
        return (
            f"{where} refused the connection (no server listens there: the controller is off or "
            "starting, or it is another port)"
        )
    except TimeoutError:
        return (
            f"no answer from {where} within {timeout_s:g} s (a wrong address, the network, or the "
            "controller is off)"
        )
    except socket.gaierror as exc:
        return f"the host name {host!r} is not known ({exc.strerror or exc})"
    except OSError as exc:
        return f"{where}: {exc.strerror or exc} (the network, or a wrong address)"


class ReconnectPolicy:
    """Whether to try a session now (module docstring).

    Parameters
    ----------
    min_s, max_s : float
        ``reconnect_min_s`` and ``reconnect_max_s``: the first wait after a failed session on an
        answering port, and the cap of its doubling.
    clock : callable
        Seconds (``time.monotonic``; a test injects one).
    probe : callable
        ``probe() -> str | None``: why the port does not answer, None if it does
        (:func:`port_problem` bound to the endpoint).

    Attributes
    ----------
    problem : str or None
        What the last probe said (None: the port answered).
    """

    def __init__(self, min_s: float, max_s: float, *, clock: Callable[[], float], probe: Callable[[], bool]):
        self.min_s, self.max_s = float(min_s), float(max_s)
        self.clock, self.probe = clock, probe
        self.backoff = self.min_s
        self.next_try = -math.inf
        self.port_was_down = True  # the first probe that answers tries at once
        self.problem: str | None = None
        self.probes = 0
        self.tries = 0

    def check_port(self) -> str | None:
        """Probe the port now: :attr:`problem` (None: it answers)."""
        self.probes += 1
        self.problem = self.probe()
        if self.problem is not None:
            self.port_was_down = True
        return self.problem

    def due(self) -> bool:
        """Probe the port; True if a session should be tried now."""
        if self.check_port() is not None:
            return False
        if self.port_was_down:  # the server is back (or the link was just lost): try at once
            self.port_was_down = False
            self.backoff = self.min_s
            return True
        return self.clock() >= self.next_try

    def failed(self) -> None:
        """A session was tried and failed: wait the back-off (doubled for the next failure) unless
        the port stops answering meanwhile."""
        self.tries += 1
        self.port_was_down = False
        self.next_try = self.clock() + self.backoff
        self.backoff = min(self.backoff * 2.0, self.max_s)

    def connected(self) -> None:
        """A session is up: the back-off starts again from ``min_s``."""
        self.tries += 1
        self.backoff = self.min_s
        self.next_try = -math.inf

    def lost(self) -> None:
        """The session was lost: the next probe that answers tries at once."""
        self.port_was_down = True
        self.next_try = -math.inf


def wait_for_controller(
    link, *, log: Callable[[str], None], notify=None, step_s: float = WAIT_STEP_S,
    report_s: float = WAIT_REPORT_S, sleep: Callable[[float], None] = time.sleep,
    clock: Callable[[], float] | None = None, on_wait: Callable[[], None] | None = None,
) -> float:  # fmt: skip
    """Connect ``link``, waiting for the controller as long as it takes.

    Parameters
    ----------
    link : rafi.deploy.opcua_client.OpcUaLink
        Not connected; :meth:`~rafi.deploy.opcua_client.OpcUaLink.connect` and
        :meth:`~rafi.deploy.opcua_client.OpcUaLink.try_reconnect`.
    log : callable
        ``log(line)``: one line when the wait begins, one per ``report_s`` while it lasts.
    notify : rafi.deploy.sd_notify.SdNotify, optional
        Told ``READY=1`` with ``STATUS=waiting for the controller ...`` when the wait begins (the
        service is up: it waits, and systemd's start timeout does not end it), then ``WATCHDOG=1``
        every step.
    step_s, report_s : float
        Seconds between two tries (each a probe; a session when the policy says so), and between
        two lines.
    sleep, clock : callable
        The wait and the clock (default ``time.sleep`` and the link's clock).
    on_wait : callable, optional
        Called once when the wait begins (the metrics: not connected).

    Returns
    -------
    float
        Seconds waited (0 when the first try connected).

    Raises
    ------
    RafiUserError
        The server refuses the login or the certificate: waiting cannot cure it.
    """
    clock = clock or link.clock
    try:
        link.connect()
        return 0.0
    except ConnectionError as exc:
        first = str(exc)
    started = clock()
    reported = started
    log(f"waiting for the controller ({first}); trying again until it answers, one line a minute")
    if notify is not None:
        notify.ready(f"waiting for the controller at {link.endpoint}")
    if on_wait is not None:
        on_wait()
    while True:
        sleep(step_s)
        if notify is not None:
            notify.watchdog()
        if link.try_reconnect():
            return clock() - started
        now = clock()
        if now - reported >= report_s:
            reported = now
            last = link.last_error or "the port does not answer"
            log(f"still waiting for the controller after {now - started:.0f} s ({last})")


def add_wait_option(parser) -> None:
    """Add ``--wait-for-controller`` (``rafi deploy`` and ``rafi record``) to an argparse parser."""
    parser.add_argument(
        "--wait-for-controller",
        action="store_true",
        help="if the controller cannot be reached at start, wait for it (a try every second, one line "
        "a minute) instead of exiting 69; the systemd units pass it (docs/service.md)",
    )


def prefixed(log, prefix: str):
    """``log`` with ``"<prefix>: "`` before each line (the link's lines, as the command's own)."""
    return lambda message: log(f"{prefix}: {message}")
