"""systemd's notification protocol (``sd_notify``), without the ``systemd`` package.

Under a unit with ``Type=notify`` systemd sets ``$NOTIFY_SOCKET`` (a unix datagram socket: a
path, or ``@name`` in the abstract namespace) and, with ``WatchdogSec=``, ``$WATCHDOG_USEC``.
A notification is one datagram of ``KEY=value`` lines (``man sd_notify``). Outside systemd
(no ``$NOTIFY_SOCKET``) every call does nothing, so the loop calls it unconditionally::

    notify = SdNotify()
    notify.ready(f"model {model_id[:12]} -> {target}")  # after connecting, before the first cycle
    notify.watchdog()                                    # once per cycle
    notify.status("ok +1.234 um")                        # optional: shown by systemctl status
    notify.stopping()                                    # on Ctrl-C / SIGTERM

A failed send is logged once and otherwise ignored: the notification never stops the loop
(systemd's watchdog then restarts a loop that really stopped pinging). Standard library only.
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable, Mapping

__all__ = ["SdNotify"]


class SdNotify:
    """Send notifications to systemd (module docstring).

    Parameters
    ----------
    environ : mapping, optional
        The environment (default ``os.environ``): ``NOTIFY_SOCKET``, ``WATCHDOG_USEC``,
        ``WATCHDOG_PID``.
    log : callable
        ``log(line)`` for the first failed send.
    """

    def __init__(self, environ: Mapping | None = None, *, log: Callable[[str], None] = print):
        env = os.environ if environ is None else environ
        self.address = env.get("NOTIFY_SOCKET") or None
        if self.address is not None and not self.address.startswith(("/", "@")):
            self.address = None  # vsock: and other kinds this module does not speak
        self.log = log
        self._warned = False
        usec, pid = env.get("WATCHDOG_USEC"), env.get("WATCHDOG_PID")
        mine = pid is None or pid == str(os.getpid())
        self.watchdog_s = int(usec) / 1e6 if (usec and usec.isdigit() and int(usec) > 0 and mine) else None

    @property
    def enabled(self) -> bool:
        """True under systemd with ``Type=notify`` (``$NOTIFY_SOCKET`` set)."""
        return self.address is not None

    def send(self, *fields: str) -> bool:
        """Send ``KEY=value`` fields in one datagram; True if sent."""
        if self.address is None:
            return False
        target = "\0" + self.address[1:] if self.address.startswith("@") else self.address
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC) as sock:
                sock.connect(target)
                sock.sendall("\n".join(fields).encode("utf-8"))
        except OSError as exc:
            if not self._warned:
                self._warned = True
                self.log(f"systemd notification to {self.address} failed ({exc.strerror or exc}); continuing")
            return False
        return True

    @staticmethod
    def _status(text: str | None) -> tuple[str, ...]:
        return () if text is None else ("STATUS=" + " ".join(str(text).split()),)

    def ready(self, status: str | None = None) -> bool:
        """The service is up (``READY=1``): systemd considers the start done."""
        return self.send("READY=1", *self._status(status))

    def watchdog(self) -> bool:
        """The loop is alive (``WATCHDOG=1``); call once per cycle."""
        return self.send("WATCHDOG=1")

    def status(self, text: str) -> bool:
        """A one-line status for ``systemctl status``."""
        return self.send(*self._status(text))

    def stopping(self, status: str | None = None) -> bool:
        """The service is stopping (``STOPPING=1``)."""
        return self.send("STOPPING=1", *self._status(status))

    def interval_warning(self, interval_s: float) -> str | None:
        """A warning line if one cycle may outlast half the watchdog (else None)."""
        if self.watchdog_s is None or interval_s <= self.watchdog_s / 2:
            return None
        return (
            f"deploy.interval_s {interval_s:g} s is more than half the unit's WatchdogSec "
            f"({self.watchdog_s:g} s): raise WatchdogSec to at least 3 x (interval_s + opcua.timeout_s)"
        )
