"""asyncua's own log, routed into the log of ``rafi deploy``: one line per event, repeats summed.

asyncua logs through :mod:`logging` (loggers ``asyncua.*``, and ``asyncuagds.*`` for its trust
store); left alone, that goes to stderr as raw dumps next to rafi's one-line messages, several
times per event (``close_session`` / ``close_secure_channel was called but connection is
closed`` at every outage, a ``ServiceFault (BadUserAccessDenied, diagnostics: ...)`` before rafi's own
message about the refused login). While an :class:`~rafi.deploy.opcua_client.OpcUaLink` is
open, :func:`route_library_log` sends every record that its event-loop thread logs to an
:class:`LibraryLogRouter` instead:

* each message is given rafi's level (:data:`LEVELS`: what rafi says itself, or what is normal
  for a session, drops to DEBUG; asyncua's plain-text password warning is dropped, rafi has its
  own); a record below the router's level (WARNING by default) is not shown;
* a shown record becomes one line, ``OPC UA (asyncua) <level>: <first line>`` (no traceback);
* the same line again within ``window_s`` seconds is counted, not shown; the count follows as
  ``... (repeated N times)`` when the window ends or the link closes.

Records of other threads (a server in the same process, another link) go on as before.
Standard library only.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Callable

__all__ = ["LEVELS", "LIBRARY_LOGGERS", "LibraryLogRouter", "route_library_log", "unroute_library_log"]

#: The loggers routed while a link is open.
LIBRARY_LOGGERS = ("asyncua", "asyncuagds")

#: (pattern, level) applied to a message in this order; level None: dropped.
LEVELS: tuple[tuple[re.Pattern, int | None], ...] = tuple(
    (re.compile(pattern), level)
    for pattern, level in (
        # rafi prints its own warning (allow_insecure) or refuses the plain text before connecting
        (r"^Sending plain-text password", None),
        # normal while a connection ends or was lost: rafi logs "connection lost" once
        (r"close_(session|secure_channel) was called but connection is closed", logging.DEBUG),
        (r"^Requested session timeout to be", logging.DEBUG),
        # a refusal's raw dump: rafi's one-line message names the status and what to do
        (r"^ServiceFault \(", logging.DEBUG),
        (r"fault response", logging.DEBUG),
        (r"^Not trusted certificate used", logging.DEBUG),
        (r"^certificate does not contain the hostname", logging.DEBUG),
        (r"^Error while processing message", logging.DEBUG),
    )
)


def _rafi_level(message: str, level: int) -> int | None:
    for pattern, rafi_level in LEVELS:
        if pattern.search(message):
            return rafi_level
    return level


class LibraryLogRouter:
    """asyncua's records of one link, to that link's ``log(message)``.

    Parameters
    ----------
    log : callable
        ``log(message)``: rafi's log of the link.
    level : int
        Records below this level (after :data:`LEVELS`) are not shown.
    window_s : float
        The same line within this many seconds of its first showing is counted, not shown.
    clock : callable
        Seconds (default ``time.monotonic``).
    """

    def __init__(self, log: Callable[[str], None], *, level=logging.WARNING, window_s=60.0, clock=None):
        self.log = log
        self.level = level
        self.window_s = float(window_s)
        self.clock = clock or time.monotonic
        self._seen: dict[str, list] = {}  # line -> [first shown at, repeats since]
        self._lock = threading.Lock()

    def handle(self, record: logging.LogRecord) -> None:
        """Show ``record`` as one line, or count it as a repeat, or drop it."""
        try:
            message = record.getMessage()
        except Exception:  # a library's malformed format arguments
            message = str(record.msg)
        level = _rafi_level(message, record.levelno)
        if level is None or level < self.level:
            return
        first = message.strip().splitlines()[0] if message.strip() else record.name
        line = f"OPC UA (asyncua) {logging.getLevelName(level).lower()}: {first}"
        now = self.clock()
        with self._lock:
            due = self._expired(now)
            seen = self._seen.get(line)
            if seen is not None:
                seen[1] += 1
                line = None
            else:
                self._seen[line] = [now, 0]
        for text in due:
            self.log(text)
        if line is not None:
            self.log(line)

    def _expired(self, now: float) -> list[str]:
        due = []
        for line, (shown_at, repeats) in list(self._seen.items()):
            if now - shown_at >= self.window_s:
                del self._seen[line]
                if repeats:
                    due.append(f"{line} (repeated {repeats} times)")
        return due

    def flush(self) -> None:
        """Report every pending repeat count and forget the lines shown."""
        with self._lock:
            due = [f"{line} (repeated {n} times)" for line, (_, n) in self._seen.items() if n]
            self._seen.clear()
        for text in due:
            self.log(text)


class _Dispatch(logging.Handler):
    """The one handler on the library's loggers: a record goes to the router of the thread that
    logged it, else on to the root logger's handlers (as if the logger still propagated)."""

    def __init__(self):
        super().__init__(logging.DEBUG)
        self.routes: dict[int, LibraryLogRouter] = {}

    def emit(self, record: logging.LogRecord) -> None:
        router = self.routes.get(record.thread)
        if router is not None:
            router.handle(record)
        else:
            root = logging.getLogger()
            if record.levelno >= root.getEffectiveLevel():
                root.handle(record)


_dispatch = _Dispatch()
_propagate: dict[str, bool] = {}
_guard = threading.Lock()


def route_library_log(thread_id: int, router: LibraryLogRouter) -> None:
    """Send the library's records logged by thread ``thread_id`` to ``router``."""
    with _guard:
        if not _dispatch.routes:
            for name in LIBRARY_LOGGERS:
                logger = logging.getLogger(name)
                _propagate[name] = logger.propagate
                logger.addHandler(_dispatch)
                logger.propagate = False
        _dispatch.routes[thread_id] = router


def unroute_library_log(thread_id: int, router: LibraryLogRouter | None = None) -> None:
    """Stop routing the records of ``thread_id`` (only if they still go to ``router``, when it is
    given: a thread id is reused once its thread ended, and may route a newer link's records by
    then); the last one restores the loggers as they were."""
    with _guard:
        if router is not None and _dispatch.routes.get(thread_id) is not router:
            router = None
        else:
            router = _dispatch.routes.pop(thread_id, None)
        if not _dispatch.routes and _propagate:
            for name in LIBRARY_LOGGERS:
                logger = logging.getLogger(name)
                logger.removeHandler(_dispatch)
                logger.propagate = _propagate.pop(name, True)
    if router is not None:
        router.flush()
