"""The nightly fast path: a fingerprint of everything that can make Snakemake re-run a job.

Equal to the value stored after the last successful night -> nothing can be out of date and
Snakemake is not started at all. Any doubt -> Snakemake decides.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import json
import os
from pathlib import Path

from rafi.artefact import canonical_json, json_text, now_iso, write_text_atomic
from rafi.ops.lock import LOCK_NAME
from rafi.ops.project import Paths, config_path
from rafi.ops.raw_hashes import CACHE_NAME as RAW_HASH_CACHE

STATE_NAME = ".nightly.state.json"
NIGHTLY_LOG = "nightly.log"


def _line(name: str, st: os.stat_result, ctime: bool) -> str:
    line = f"{name}\t{st.st_size}\t{st.st_mtime_ns}"
    return f"{line}\t{st.st_ctime_ns}\t{st.st_ino}" if ctime else line


def _tree(root: Path, skip=(), ctime: bool = False) -> list[str]:
    """``name<TAB>size<TAB>mtime_ns`` of every file under ``root`` (or of ``root`` itself);
    with ``ctime`` also the inode change time and the inode, which no user can set back: a
    content edit with size and mtime kept (``cp -p``, ``rsync -t``) still changes the line."""
    if root.is_file():
        return [_line(root.name, root.stat(), ctime)]
    out: list[str] = []
    if not root.is_dir():
        return out
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = sorted(d for d in dirnames if d not in ("__pycache__", ".snakemake"))
        for name in sorted(filenames):
            p = Path(dirpath) / name
            rel = str(p.relative_to(root))
            if rel in skip or name.endswith(".part"):
                continue
            with contextlib.suppress(OSError):
                out.append(_line(rel, p.stat(), ctime))
    return out


def fingerprint(config_file: str | Path, paths: Paths, overrides: dict) -> str:
    """SHA-256 of the config, the overrides, Snakefile and workflow/, the rafi package, raw/
    and results/ (names, sizes, modification times; for raw/ also inode change times and
    inodes; the nightly's own files and the raw-hash cache left out).

    Parameters
    ----------
    config_file : str or Path
        The pipeline config, relative to ``paths.directory`` unless absolute.
    paths : Paths
        The project.
    overrides : dict
        The ``--config`` values of the night.

    Returns
    -------
    str
        Hex digest.
    """
    cfg = config_path(paths.directory, config_file)
    spec = importlib.util.find_spec("rafi")
    rafi_dir = Path(spec.origin).parent if spec and spec.origin else Path(__file__).parents[1]
    parts = {
        "config": hashlib.sha256(cfg.read_bytes() if cfg.exists() else b"").hexdigest(),
        "overrides": overrides,
        "snakefile": _tree(paths.directory / "Snakefile"),
        "workflow": _tree(paths.directory / "workflow"),
        "rafi": _tree(rafi_dir),
        "raw": _tree(paths.raw_dir, ctime=True),
        "results": _tree(paths.results_dir, skip={LOCK_NAME, STATE_NAME, NIGHTLY_LOG, RAW_HASH_CACHE}),
    }
    return hashlib.sha256(canonical_json(parts).encode("ascii")).hexdigest()


def read_state(paths: Paths) -> dict:
    """The state stored by the last successful night (``{}`` if none or unreadable)."""
    with contextlib.suppress(OSError, ValueError):
        return json.loads((paths.results_dir / STATE_NAME).read_text(encoding="utf-8"))
    return {}


def write_state(paths: Paths, fp: str) -> None:
    """Store ``fp`` as the fingerprint of a successful night (atomic replace)."""
    write_text_atomic(paths.results_dir / STATE_NAME, json_text({"fingerprint": fp, "time": now_iso()}))


def clear_state(paths: Paths) -> None:
    """Forget the last fingerprint (after a failed night the next one asks Snakemake)."""
    with contextlib.suppress(FileNotFoundError):
        (paths.results_dir / STATE_NAME).unlink()
