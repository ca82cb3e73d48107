"""The nightly fast path: a fingerprint of everything that can make Snakemake re-run a job.

Equal to the value stored after the last successful night -> nothing can be out of date and
Snakemake is not started at all. Any doubt -> Snakemake decides.

A night for every machine keeps its fingerprint in ``results/.nightly.state.json`` and its log
in ``results/nightly.log``; a night for one machine ``M`` (``rafi nightly --machine M``, which
may run at the same time as nights for other machines) in ``results/.nightly.state.M.json`` and
``results/nightly.M.log``, and its fingerprint covers only ``raw/M`` and ``results/M`` of the
data, so the nights of other machines neither corrupt nor invalidate it.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import json
import os
from pathlib import Path

from rafi.artefact import canonical_json, json_text, now_iso, write_text_atomic
from rafi.ops.project import Paths, config_path
from rafi.ops.raw_hashes import CACHE_NAME as RAW_HASH_CACHE

STATE_NAME = ".nightly.state.json"
NIGHTLY_LOG = "nightly.log"


def _scope(machines) -> str | None:
    """The one machine of a night for one machine, else None (a night for every machine)."""
    if machines is None:
        return None
    machines = [machines] if isinstance(machines, str) else sorted(machines)
    return machines[0] if len(machines) == 1 else None


def state_name(machines=None) -> str:
    """``.nightly.state.json`` (every machine), ``.nightly.state.<machine>.json`` (one machine)."""
    one = _scope(machines)
    return STATE_NAME if one is None else f".nightly.state.{one}.json"


def log_name(machines=None) -> str:
    """``nightly.log`` (every machine), ``nightly.<machine>.log`` (one machine)."""
    one = _scope(machines)
    return NIGHTLY_LOG if one is None else f"nightly.{one}.log"


def _nightly_file(rel: str) -> bool:
    """A file of the nightly itself under ``results_dir``: its locks, states and logs (every name
    starts with ``.nightly`` or ``nightly.``), and the raw-hash cache."""
    top = rel.split(os.sep, 1)[0]
    if top == RAW_HASH_CACHE or top.startswith(".nightly"):
        return True
    return top.startswith("nightly.") and top.endswith(".log")


def _line(name: str, st: os.stat_result, ctime: bool) -> str:
    line = f"{name}\t{st.st_size}\t{st.st_mtime_ns}"
    return f"{line}\t{st.st_ctime_ns}\t{st.st_ino}" if ctime else line


def _tree(root: Path, skip=lambda rel: False, ctime: bool = False) -> list[str]:
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
            if skip(rel) or name.endswith(".part"):
                continue
            with contextlib.suppress(OSError):
                out.append(_line(rel, p.stat(), ctime))
    return out


def fingerprint(config_file: str | Path, paths: Paths, overrides: dict, machines=None) -> str:
    """SHA-256 of the config, the overrides, Snakefile and workflow/, the rafi package, raw/
    and results/ (names, sizes, modification times; for raw/ also inode change times and
    inodes; the nightly's own files and the raw-hash cache left out). For a night for one
    machine (``machines`` names one), only that machine's folders of raw/ and results/.

    Parameters
    ----------
    config_file : str or Path
        The pipeline config, relative to ``paths.directory`` unless absolute.
    paths : Paths
        The project.
    overrides : dict
        The ``--config`` values of the night.
    machines : str, list of str or None
        The machines of the night (None: every machine).

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
    }
    one = _scope(machines)
    if one is None:
        parts["raw"] = _tree(paths.raw_dir, ctime=True)
        parts["results"] = _tree(paths.results_dir, skip=_nightly_file)
    else:
        parts["raw"] = _tree(paths.raw_dir / one, ctime=True)
        parts["results"] = _tree(paths.results_dir / one)
    return hashlib.sha256(canonical_json(parts).encode("ascii")).hexdigest()


def read_state(paths: Paths, machines=None) -> dict:
    """The state stored by the last successful night of the same machines (``{}`` if none or
    unreadable)."""
    with contextlib.suppress(OSError, ValueError):
        return json.loads((paths.results_dir / state_name(machines)).read_text(encoding="utf-8"))
    return {}


def write_state(paths: Paths, fp: str, machines=None) -> None:
    """Store ``fp`` as the fingerprint of a successful night (atomic replace)."""
    write_text_atomic(
        paths.results_dir / state_name(machines), json_text({"fingerprint": fp, "time": now_iso()})
    )


def clear_state(paths: Paths, machines=None) -> None:
    """Forget the last fingerprint (after a failed night the next one asks Snakemake)."""
    with contextlib.suppress(FileNotFoundError):
        (paths.results_dir / state_name(machines)).unlink()
