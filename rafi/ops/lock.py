"""The nightly locks and Snakemake's own lock in the project (``.snakemake/locks``).

Nightly locks are exclusive, non-blocking ``flock`` s. A night for one machine (``rafi nightly
--machine M``) takes ``results/.nightly.M.lock`` only, so nights for different machines
run at the same time and two for the same machine refuse each other. A night for every machine
takes the fleet lock ``results/.nightly.lock`` and then every machine's lock, in sorted order
(:func:`night_locks`); all of them or none. Snakemake's lock is stale after a killed run and is
cleared (:func:`clear_stale_snakemake_lock`).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
from collections.abc import Iterable
from pathlib import Path

from rafi.artefact import now_iso
from rafi.errors import LockHeld

#: The fleet lock under ``results_dir``: held by a night for every machine.
LOCK_NAME = ".nightly.lock"
#: The name of a machine's lock under ``results_dir`` (every nightly file starts with
#: ``.nightly`` or ``nightly``, so tools that skip the nightly's own files skip it too).
MACHINE_LOCK = ".nightly.{machine}.lock"


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
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, text, 0)
            os.fsync(fd)
        except OSError as exc:  # a full disk: say which file (closing the descriptor unlocks)
            self._fd = None
            os.close(fd)
            raise OSError(exc.errno, exc.strerror, str(self.path)) from None
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


def machine_lock_path(results_dir: str | os.PathLike, machine: str) -> Path:
    """``results/.nightly.<machine>.lock``: the nightly lock of one machine."""
    return Path(results_dir) / MACHINE_LOCK.format(machine=machine)


def night_locks(
    results_dir: str | os.PathLike, machines: Iterable[str], every_machine: bool
) -> contextlib.ExitStack:
    """Take the nightly locks of a night, all or none.

    Parameters
    ----------
    results_dir : path
        The project's ``results_dir``.
    machines : iterable of str
        The machines of the night.
    every_machine : bool
        The night covers every machine: the fleet lock (:data:`LOCK_NAME`) is taken first.

    Returns
    -------
    contextlib.ExitStack
        Holds the locks; closing it releases them (in reverse order). The locks are taken in a
        fixed order (the fleet lock, then the machines sorted by name), non-blocking, so two
        nights never wait for each other: the one that finds a lock held gives up at once.

    Raises
    ------
    rafi.errors.LockHeld
        A lock is held by another night (the locks taken so far are released first).
    """
    paths = [Path(results_dir) / LOCK_NAME] if every_machine else []
    paths += [machine_lock_path(results_dir, m) for m in sorted(set(machines))]
    stack = contextlib.ExitStack()
    try:
        for path in paths:
            stack.enter_context(NightlyLock(path))
    except BaseException:
        stack.close()
        raise
    return stack


_PID = re.compile(r"\bpid=(\d+)")


def holder_pids(results_dir: str | os.PathLike) -> set[int]:
    """Pids named in the nightly lock files (the fleet lock and every machine lock).

    A held lock names its holder; a released one is empty; one left by a killed night names a
    process that is gone. So a live ``rafi nightly`` named here is a night that holds its
    lock(s): it works on its own machines, under this module's locks.
    """
    root = Path(results_dir)
    files = [root / LOCK_NAME]
    with contextlib.suppress(OSError):
        files += sorted(root.glob(MACHINE_LOCK.format(machine="?*")))
    pids = set()
    for path in files:
        with contextlib.suppress(OSError):
            text = path.read_text(encoding="utf-8", errors="replace")
            pids.update(int(m) for m in _PID.findall(text))
    return pids


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


# --------------------------------------------------------------------------- Snakemake's lock
#
# Snakemake locks a working directory by writing .snakemake/locks/<n>.input.lock and
# <n>.output.lock (the files its run reads and writes) and deletes them when it ends. A run
# killed with SIGKILL cannot delete them, and every later run then refuses to start
# ("Directory cannot be locked") until someone runs `snakemake --unlock`. The files name no
# process, so whether a lock is still in use is decided from the processes themselves: a
# Snakemake run (or one of its job scripts) whose working directory is the project.

SNAKEMAKE_LOCK_DIR = Path(".snakemake") / "locks"
_LOCK_FILE = re.compile(r"\d+\.(input|output)\.lock")


def snakemake_lock_files(directory: str | os.PathLike) -> list[Path]:
    """The lock files Snakemake left in ``directory``'s ``.snakemake/locks`` (sorted)."""
    lock_dir = Path(directory) / SNAKEMAKE_LOCK_DIR
    with contextlib.suppress(OSError):
        return sorted(p for p in lock_dir.iterdir() if _LOCK_FILE.fullmatch(p.name) and p.is_file())
    return []


def _is_snakemake(argv: list[str]) -> bool:
    """``argv`` runs Snakemake (``snakemake ...``, ``python -m snakemake ...``), one of the job
    scripts a Snakemake run starts (``python .snakemake/scripts/tmpXXXX.<script>.py``), or a
    ``rafi nightly`` (which runs Snakemake in its own process)."""
    names = [os.path.basename(a) for a in argv[:2]]
    modules = {argv[i + 1] for i in range(len(argv) - 1) if argv[i] == "-m"}
    if "snakemake" in names or "snakemake" in modules:
        return True
    if ("rafi" in names or modules & {"rafi.cli", "rafi"}) and "nightly" in argv:
        return True
    return "rafi.ops.nightly" in modules or any(".snakemake/scripts/" in a for a in argv)


def _workdirs(argv: list[str], cwd: str) -> set[str]:
    """Where a Snakemake process may be working: its current directory and, if given, its
    ``--directory`` / ``-d`` argument (relative to that directory; the API moves into the
    working directory, so the argument may already be behind it)."""
    dirs = {os.path.realpath(cwd)}
    for i, arg in enumerate(argv):
        value = None
        if arg in ("--directory", "-d") and i + 1 < len(argv):
            value = argv[i + 1]
        elif arg.startswith("--directory="):
            value = arg.split("=", 1)[1]
        if value:
            dirs.add(os.path.realpath(os.path.join(cwd, value)))
    return dirs


def _ancestors() -> set[int]:
    """This process and its parents (never counted as a foreign Snakemake run)."""
    return set(_parent_chain(os.getpid(), "/proc"))


def _parent_chain(pid: int, proc: str | os.PathLike) -> list[int]:
    """``pid`` and its parents, read from ``<proc>/<pid>/stat`` (as far as readable)."""
    chain: list[int] = []
    while pid > 1 and pid not in chain:
        chain.append(pid)
        try:
            with open(os.path.join(proc, str(pid), "stat"), encoding="utf-8", errors="replace") as fh:
                pid = int(fh.read().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            break
    return chain


def live_snakemake_processes(
    directory: str | os.PathLike, proc: str | os.PathLike = "/proc"
) -> list[tuple[int, str]]:
    """Processes running Snakemake (or one of its job scripts) in ``directory``.

    A process counts if its command line runs Snakemake (see :func:`_is_snakemake`) and its
    current directory (``/proc/<pid>/cwd``) or its ``--directory`` argument is ``directory``.
    Processes whose current directory cannot be read (another user's, for a non-root user) are
    not counted. This process and its parents never count.

    Parameters
    ----------
    directory : path
        The project (Snakemake's working directory).
    proc : path
        The proc file system (a test may pass a fake one).

    Returns
    -------
    list of (int, str)
        ``(pid, command line)``, sorted by pid; the command line cut to 200 characters.
    """
    target = os.path.realpath(directory)
    skip = _ancestors() if Path(proc) == Path("/proc") else set()
    found = []
    try:
        entries = [e for e in os.listdir(proc) if e.isdigit()]
    except OSError:
        entries = []
    for entry in entries:
        pid = int(entry)
        if pid in skip:
            continue
        try:
            with open(os.path.join(proc, entry, "cmdline"), "rb") as fh:
                argv = [a.decode("utf-8", "replace") for a in fh.read().split(b"\0") if a]
            if not argv or not _is_snakemake(argv):
                continue
            cwd = os.readlink(os.path.join(proc, entry, "cwd"))
        except OSError:
            continue
        if target in _workdirs(argv, cwd):
            found.append((pid, " ".join(argv)[:200]))
    return sorted(found)


def coordinated_with(pid: int, coordinated: Iterable[int], proc: str | os.PathLike = "/proc") -> bool:
    """``pid`` is one of ``coordinated`` (nights holding nightly locks here, :func:`holder_pids`)
    or descends from one (a job script of such a night)."""
    return not set(coordinated).isdisjoint(_parent_chain(pid, proc))


def clear_stale_snakemake_lock(
    directory: str | os.PathLike, coordinated: Iterable[int] = ()
) -> tuple[list[Path], list[tuple[int, str]]]:
    """Remove Snakemake's lock files in ``directory`` if no Snakemake process works there.

    What ``snakemake --unlock`` does, but only when the lock is stale: to be called while this
    process holds its nightly lock(s). Other nights (``coordinated``) do not make the lock
    live: a night for some machines runs Snakemake without its directory lock (``--nolock``,
    see ``rafi.ops.nightly``), and a night for every machine excludes every other night.

    Parameters
    ----------
    directory : path
        The project (Snakemake's working directory).
    coordinated : iterable of int
        Pids of other nights holding nightly locks here (:func:`holder_pids`).

    Returns
    -------
    removed : list of Path
        The lock files removed (empty if there were none, or if the lock is live).
    live : list of (int, str)
        The Snakemake processes working in ``directory`` (see
        :func:`live_snakemake_processes`) when there are lock files; the lock is then left alone.
    """
    files = snakemake_lock_files(directory)
    if not files:
        return [], []
    # another night (or its job) works under its own nightly locks: not a foreign run
    coordinated = set(coordinated) - _ancestors()
    live = [
        (pid, cmd)
        for pid, cmd in live_snakemake_processes(directory)
        if not coordinated_with(pid, coordinated)
    ]
    if live:
        return [], live
    removed = []
    for path in files:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()
            removed.append(path)
    return removed, []
