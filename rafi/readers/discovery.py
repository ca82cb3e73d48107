"""Which raw files discovery may use: links that leave ``raw_dir``, files still being written.

Two checks of ``docs/raw-format.md`` run while Snakemake plans (standard library only):

* ``link_outside_raw``: a symbolic link (to a file or a folder) under ``raw_dir`` whose target
  lies outside ``raw_dir`` is never followed: the file is not read, and planning prints a
  warning naming the link and its target. Links from one place in ``raw_dir`` to another work.
* ``settling``: with ``settle_s`` > 0 (run setting; ``rafi nightly`` passes
  ``nightly_settle_s``), a file modified less than ``settle_s`` seconds ago may still be being
  written: it is left out of this run, with a warning, and read by the next one.

Each warning line starts with its check id (``link_outside_raw: ...``, ``settling: ...``).
"""

from __future__ import annotations

import os
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
