"""The nightly locks and Snakemake's own lock in the project (``.snakemake/locks``).

Nightly locks are exclusive, non-blocking ``flock`` s (filelock). A night for one machine (``rafi nightly
--machine M``) takes ``results/.nightly.M.lock`` only, so nights for different machines
run at the same time and two for the same machine refuse each other. A night for every machine
takes the fleet lock ``results/.nightly.lock`` and then every machine's lock, in sorted order
(:func:`night_locks`); all of them or none. Snakemake's lock is stale after a killed run and is
cleared (:func:`clear_stale_snakemake_lock`).
"""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Iterable
from pathlib import Path

import filelock
import psutil

from rafi.artefact import now_iso
from rafi.errors import LockHeld

#: The fleet lock under ``results_dir``: held by a night for every machine.
LOCK_NAME = ".nightly.lock"
#: The name of a machine's lock under ``results_dir`` (every nightly file starts with
#: ``.nightly`` or ``nightly``, so tools that skip the nightly's own files skip it too).
MACHINE_LOCK = ".nightly.{machine}.lock"


class NightlyLock:
    """Exclusive, non-blocking ``flock`` on ``path`` (:class:`filelock.UnixFileLock`), as a
    context manager.

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
        self._lock: filelock.UnixFileLock | None = None

    def __enter__(self) -> NightlyLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        lock = _flock(self.path, on_acquired=_write_holder)
        try:
            lock.acquire()
        except filelock.Timeout:
            raise LockHeld(self.path, _text(self.path)) from None
        except OSError as exc:  # a full disk: say which file (the lock was not taken)
            raise OSError(exc.errno, exc.strerror, str(self.path)) from None
        self._lock = lock
        return self

    def __exit__(self, *exc) -> None:
        self.release()

    def release(self) -> None:
        """Empty the file and drop the lock (idempotent)."""
        if self._lock is None:
            return
        lock, self._lock = self._lock, None
        try:
            with contextlib.suppress(OSError):
                os.truncate(self.path, 0)  # still this inode: filelock never replaces the file
        finally:
            lock.release(force=True)


def _flock(path: Path, on_acquired=None) -> filelock.UnixFileLock:
    """A non-blocking flock on ``path``; never the soft (marker-file) fallback, which would
    outlive a killed night."""
    return filelock.UnixFileLock(path, timeout=0, mode=0o644, fallback_to_soft=False, on_acquired=on_acquired)


def _write_holder(fd: int) -> None:
    """Name the holder in the lock file, in place on the locked descriptor (not through
    rafi.artefact's atomic replace: a renamed-over lock file would be a new inode that a second
    night could lock while this one still holds the old one)."""
    text = f"pid={os.getpid()} started={now_iso()} host={os.uname().nodename}\n".encode()
    os.ftruncate(fd, 0)
    os.pwrite(fd, text, 0)
    os.fsync(fd)


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
    return {int(m) for path in files for m in _PID.findall(_text(path))}


def _text(path: Path) -> str:
    """What a lock file says (empty if it cannot be read)."""
    with contextlib.suppress(OSError):
        return path.read_text(encoding="utf-8", errors="replace")
    return ""


def lock_is_free(path: str | os.PathLike) -> bool:
    """True if nobody holds the flock on ``path`` (a probe, for tests and status)."""
    lock = _flock(Path(path))
    try:
        lock.acquire()
    except filelock.Timeout:
        return False
    lock.release(force=True)
    return True


# --------------------------------------------------------------------------- Snakemake's lock
#
# Snakemake locks a working directory by writing .snakemake/locks/<n>.input.lock and
# <n>.output.lock (the files its run reads and writes) and deletes them when it ends. A run
# killed with SIGKILL cannot delete them, and every later run then refuses to start
# ("Directory cannot be locked") until someone runs `snakemake --unlock`. The files name no
# process, so whether a lock is still in use is decided from the processes themselves (psutil): a
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


def _parent_chain(pid: int) -> list[int]:
    """``pid`` and its parents (as far as they can be read)."""
    try:
        return [pid, *(p.pid for p in psutil.Process(pid).parents())]
    except psutil.Error:
        return [pid]


def live_snakemake_processes(directory: str | os.PathLike) -> list[tuple[int, str]]:
    """Processes running Snakemake (or one of its job scripts) in ``directory``.

    A process counts if its command line runs Snakemake (see :func:`_is_snakemake`) and its
    current directory or its ``--directory`` argument is ``directory``. Processes whose current
    directory cannot be read (another user's, for a non-root user) are not counted. This process
    and its parents never count.

    Parameters
    ----------
    directory : path
        The project (Snakemake's working directory).

    Returns
    -------
    list of (int, str)
        ``(pid, command line)``, sorted by pid; the command line cut to 200 characters.
    """
    target = os.path.realpath(directory)
    skip = set(_parent_chain(os.getpid()))
    found = []
    for process in psutil.process_iter(["pid", "cmdline", "cwd"], ad_value=None):
        pid, argv, cwd = process.info["pid"], process.info["cmdline"], process.info["cwd"]
        if pid in skip or not argv or not cwd or not _is_snakemake(argv):
            continue
        if target in _workdirs(argv, cwd):
            found.append((pid, " ".join(argv)[:200]))
    return sorted(found)


def coordinated_with(pid: int, coordinated: Iterable[int]) -> bool:
    """``pid`` is one of ``coordinated`` (nights holding nightly locks here, :func:`holder_pids`)
    or descends from one (a job script of such a night)."""
    return not set(coordinated).isdisjoint(_parent_chain(pid))


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
    coordinated = set(coordinated) - set(_parent_chain(os.getpid()))
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
