"""The nightly lock: an exclusive, non-blocking ``flock`` on ``results/.nightly.lock``."""

from __future__ import annotations

import contextlib
import fcntl
import os
from pathlib import Path

from rafi.artefact import now_iso
from rafi.errors import LockHeld

LOCK_NAME = ".nightly.lock"


class NightlyLock:
    """Exclusive, non-blocking ``flock`` on ``path``, as a context manager.

    The kernel releases a flock when its process dies, so a crashed night never leaves a
    stale lock. The file itself is kept (deleting lock files races); while held it holds
    ``pid=<pid> started=<UTC time> host=<host>``, and it is emptied on release.

    Parameters
    ----------
    path : str or os.PathLike
        The lock file (created if missing).

    Raises
    ------
    rafi.errors.LockHeld
        On entry, when another process holds the lock (``holder`` is what it wrote).
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._fd: int | None = None

    def __enter__(self) -> NightlyLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            try:
                holder = os.pread(fd, 4096, 0).decode("utf-8", "replace")
            finally:
                os.close(fd)
            raise LockHeld(self.path, holder) from None
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd
        # Written in place on the locked descriptor, not through rafi.artefact's atomic
        # replace: a renamed-over lock file would be a new inode that a second night could
        # lock while this one still holds the old one.
        text = f"pid={os.getpid()} started={now_iso()} host={os.uname().nodename}\n".encode()
        os.ftruncate(fd, 0)
        os.pwrite(fd, text, 0)
        os.fsync(fd)
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def release(self) -> None:
        """Empty the file and drop the lock (idempotent)."""
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        try:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            os.close(fd)


def lock_is_free(path: str | os.PathLike) -> bool:
    """True if nobody holds the flock on ``path`` (a probe, for tests and status)."""
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        fcntl.flock(fd, fcntl.LOCK_UN)
        return True
    except BlockingIOError:
        return False
    finally:
        os.close(fd)
