"""A runnable copy of this project in a temporary folder, for tests of the real Snakefile."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def copy_project(proj: Path, *, config: bool = True) -> Path:
    """Copy ``Snakefile``, ``workflow/``, a frozen ``rafi/`` (the code the test's jobs run, and
    whose digest is each rule's param ``code``) and, if ``config``, ``config.yaml`` into ``proj``
    (created); returns ``proj``. No raw data."""
    proj.mkdir(parents=True, exist_ok=True)
    shutil.copy2(ROOT / "Snakefile", proj / "Snakefile")
    if config:
        shutil.copy2(ROOT / "config.yaml", proj / "config.yaml")
    for name in ("workflow", "rafi"):
        shutil.copytree(ROOT / name, proj / name, ignore=shutil.ignore_patterns("__pycache__"))
    return proj


#: Age given to raw files copied into a test project: older than `rafi nightly`'s settle time
#: (run setting nightly_settle_s), so a night reads them. A fresh git clone has new mtimes.
SETTLED_AGE_S = 86_400


def settle(path: Path) -> Path:
    """Give ``path`` a modification time a day ago (a raw file nobody is writing any more)."""
    old = time.time() - SETTLED_AGE_S
    os.utime(path, (old, old))
    return path


def copy_settled(src: Path, dst: Path) -> Path:
    """Copy a raw file into a test project and :func:`settle` it; returns ``dst``."""
    shutil.copy2(src, dst)
    return settle(dst)


def run_module(proj: Path, module: str, *args: str, timeout: float = 900) -> subprocess.CompletedProcess:
    """``python -m module *args`` in ``proj``, the project's frozen ``rafi/`` first on the path;
    output captured."""
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(proj), os.environ.get("PYTHONPATH")])),
    }
    cmd = [sys.executable, "-m", module, *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, cwd=proj)


def run_rafi(proj: Path, *args: str, timeout: float = 900) -> subprocess.CompletedProcess:
    """``rafi *args`` in ``proj``, with the project's frozen ``rafi/`` first on the path; output
    captured."""
    return run_module(proj, "rafi.cli", *args, timeout=timeout)


def run_snakemake(
    proj: Path, *args: str, cores: int = 1, timeout: float = 600
) -> subprocess.CompletedProcess:
    """``snakemake --cores cores *args`` in ``proj`` (:func:`run_rafi`'s path and capture)."""
    return run_module(proj, "snakemake", "--cores", str(cores), *args, timeout=timeout)


def run_nightly(proj: Path, *args: str, timeout: float = 900) -> subprocess.CompletedProcess:
    """``rafi nightly --directory proj --cores 2 --no-report *args`` in ``proj`` (:func:`run_rafi`)."""
    return run_rafi(
        proj, "nightly", "--directory", str(proj), "--cores", "2", "--no-report", *args, timeout=timeout
    )
