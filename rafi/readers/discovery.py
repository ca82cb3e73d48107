"""Which raw files discovery may use: links that leave ``raw_dir``, files still being written.

Two checks of ``docs/raw-format.md`` run while Snakemake plans (standard library only):

* ``link_outside_raw``: a symbolic link (to a file or a folder) under ``raw_dir`` whose target
  lies outside ``raw_dir`` is never followed: the file is not read, and planning prints a
  warning naming the link and its target. Links from one place in ``raw_dir`` to another work.
* ``settling``: with ``settle_s`` > 0 (run setting; ``rafi nightly`` passes
  ``nightly_settle_s``), a file modified less than ``settle_s`` seconds ago may still be being
  written: it is left out of this run, with a warning, and read by the next one.

* ``not_a_file``: a name matching the pattern that is not a regular file (a folder, a FIFO, a
  socket, a device, a link that leads nowhere or to itself) is not read (a FIFO would block
  the reader), with a warning naming what it is.

Each warning line starts with its check id (``link_outside_raw: ...``, ``settling: ...``).
:func:`safe_name_problem` says why a name cannot name a machine's outputs (Snakemake refuses a
wildcard value that ends in a periodic repetition, control characters break its paths, and a
file name has at most 255 bytes).
"""

from __future__ import annotations

import os
import re
import stat
import time
from collections.abc import Iterable
from pathlib import Path

from rafi.errors import bound_message, short_path


def _real(path: Path) -> Path | None:
    """The resolved path (every link followed), or None for a loop of links."""
    try:
        return Path(os.path.realpath(path, strict=False))
    except (OSError, RuntimeError, ValueError):
        return None


def is_inside(path: str | os.PathLike, raw_dir: str | os.PathLike) -> bool:
    """True if ``path`` with every link resolved lies inside ``raw_dir`` (itself resolved)."""
    real, root = _real(Path(path)), _real(Path(raw_dir))
    return real is not None and root is not None and (real == root or real.is_relative_to(root))


def link_warning(path: str | os.PathLike, raw_dir: str | os.PathLike) -> str:
    """The ``link_outside_raw`` line for ``path`` (a link out of ``raw_dir``)."""
    real = _real(Path(path))
    target = short_path(real) if real is not None else "a loop of links"
    return bound_message(
        f"link_outside_raw: refused {short_path(path)}: a symbolic link to {target}, outside "
        f"raw_dir {short_path(raw_dir)}; it is not read - copy the file into raw_dir, or link to "
        "a place inside it"
    )


def split_outside(
    paths: Iterable[str | os.PathLike], raw_dir: str | os.PathLike
) -> tuple[list[Path], list[str]]:
    """Paths that resolve inside ``raw_dir``, and a ``link_outside_raw`` line for each other one.

    Parameters
    ----------
    paths : iterable of path
        Candidate raw files (under ``raw_dir``, as found by a glob).
    raw_dir : path
        The raw folder.

    Returns
    -------
    inside : list of Path
        The paths kept, in the given order.
    refused : list of str
        One warning line per path whose target (a link, or a linked folder on its way) lies
        outside ``raw_dir``.
    """
    inside: list[Path] = []
    refused: list[str] = []
    for path in map(Path, paths):
        if is_inside(path, raw_dir):
            inside.append(path)
        else:
            refused.append(link_warning(path, raw_dir))
    return inside, refused


def settling_files(
    paths: Iterable[str | os.PathLike], settle_s: float, now: float | None = None
) -> list[tuple[Path, float]]:
    """The files modified less than ``settle_s`` seconds before ``now``: they may still be written.

    Parameters
    ----------
    paths : iterable of path
        Raw files.
    settle_s : float
        Seconds a file must have been left alone; 0 (or less) means no file waits.
    now : float, optional
        Time of the decision (seconds since the epoch, as ``time.time()``; default now).

    Returns
    -------
    list of (Path, float)
        Each waiting file with its age in seconds (negative: modified in the future, a clock
        out of step; such a file waits too, until the clock passes its time and ``settle_s``).
        A file whose modification time cannot be read does not wait (the reader reports it).
    """
    if not settle_s or settle_s <= 0:
        return []
    now = time.time() if now is None else now
    waiting = []
    for path in map(Path, paths):
        try:
            mtime = os.stat(path).st_mtime
        except OSError:
            continue
        age = now - mtime
        if age < settle_s:
            waiting.append((path, age))
    return waiting


def settling_warning(path: str | os.PathLike, age_s: float, settle_s: float) -> str:
    """The ``settling`` line for a file that waits for the next run."""
    future = " (in the future: check the clocks)" if age_s < 0 else ""
    return bound_message(
        f"settling: waits for the next run: {short_path(path)} was modified {age_s:.0f} s ago"
        f"{future} (settle_s {settle_s:g})"
    )


#: How the warning about a machine folder that discovery leaves out starts (``discover_machines``).
SKIP_PREFIX = "skipping machine folder "
#: The section of the docs on reading a format or layout other than the native CSV.
FOREIGN_FORMAT_DOCS = "docs/raw-format.md#bringing-your-own-layout"
#: How many entries of a folder :func:`folder_contents` looks at, at most.
SCAN_LIMIT = 10_000


def folder_contents(folder: str | os.PathLike, shown: int = 5) -> str:
    """What a machine folder holds, in words, for the warning of a folder no file of which matches
    ``input.pattern``: the number of files, the first ``shown`` names (sorted; sub-folders
    searched, hidden names left out) and each extension with its count.

    ``"3 file(s): a.xlsx, b.xlsx, notes.txt (.xlsx 2, .txt 1)"``, ``"no file"`` for an empty
    folder; only the first ``SCAN_LIMIT`` entries are looked at (``"at least"`` then). Names
    only: nothing is opened.
    """
    root = Path(folder)
    names, seen = [], 0
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        for name in filenames:
            seen += 1
            if not name.startswith("."):
                names.append((Path(dirpath) / name).relative_to(root).as_posix())
        if seen >= SCAN_LIMIT:
            break
    if not names:
        return "no file"
    names.sort()
    counts: dict[str, int] = {}
    for name in names:
        ext = Path(name).suffix.lower() or "(no extension)"
        counts[ext] = counts.get(ext, 0) + 1
    exts = ", ".join(f"{ext} {n}" for ext, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))
    more = f", ... ({len(names) - shown} more)" if len(names) > shown else ""
    at_least = "at least " if seen >= SCAN_LIMIT else ""
    return f"{at_least}{len(names)} file(s): {', '.join(names[:shown])}{more} ({exts})"


def no_match_reason(folder: str | os.PathLike, pattern, machine: str) -> str:
    """Why discovery skips a machine folder none of whose files matches ``input.pattern``, what
    the folder holds (:func:`folder_contents`) and where the docs say how to read another format."""
    return bound_message(
        f"no file matches input.pattern {pattern!r}; the folder holds {folder_contents(folder)}. "
        f"A format or layout other than the native CSV needs machines.{machine}.input in the "
        f"config: {FOREIGN_FORMAT_DOCS}"
    )


_KIND_WORDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a FIFO (named pipe)"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
)


def not_a_file(path: str | os.PathLike) -> str | None:
    """Why ``path`` is not a regular file a reader may open (``None``: it is one).

    Links are followed; a link that leads nowhere or to itself is named as such. The answer
    comes from ``stat`` alone: nothing is opened (opening a FIFO would wait for a writer).
    """
    try:
        mode = os.stat(path).st_mode
    except OSError as exc:
        if os.path.islink(path):
            return "a symbolic link that leads nowhere (its target is missing, or a loop of links)"
        return f"cannot be examined ({exc.strerror or type(exc).__name__})"
    if stat.S_ISREG(mode):
        return None
    for test, words in _KIND_WORDS:
        if test(mode):
            return words
    return "not a regular file"


def not_a_file_warning(path: str | os.PathLike, what: str) -> str:
    """The ``not_a_file`` line for ``path`` (``what``: :func:`not_a_file`)."""
    return bound_message(
        f"not_a_file: skipped {short_path(path)}: it is {what}, not a regular file; it matches the "
        "raw-file pattern but is not read - remove it from the machine folder or rename it"
    )


#: Snakemake's test for a wildcard value that "would lead to an infinite recursion"
#: (``snakemake.io.PeriodicityDetector``: a substring repeated 20 or more times at the end).
_PERIODIC_TAIL = re.compile(r"((?P<value>.+)(?P=value){19,99})$", re.DOTALL)

#: Most bytes of a name used in an output path (``clean/<log id>.summary.csv`` and the atomic
#: writer's temporary ``.<name>.XXXXXXXX.part`` must stay within 255 bytes).
NAME_MAX_BYTES = 150

_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


def periodic_tail(text: str) -> bool:
    """True if ``text`` ends with a substring repeated 20 or more times (Snakemake refuses it)."""
    return len(text) >= 20 and _PERIODIC_TAIL.search(text) is not None


def safe_name_problem(name: str) -> str | None:
    """Why ``name`` cannot be used as it is in a Snakemake output path (``None``: it can)."""
    if _CONTROL.search(name):
        return "it holds a control character (a line break, a tab)"
    if len(name.encode("utf-8", "surrogateescape")) > NAME_MAX_BYTES:
        return f"it is longer than {NAME_MAX_BYTES} bytes"
    if periodic_tail(name):
        return "it ends in a run of 20 or more repetitions, which Snakemake refuses as a wildcard value"
    return None
