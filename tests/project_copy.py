"""A runnable copy of this project in a temporary folder, for tests of the real Snakefile."""

from __future__ import annotations

import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def copy_project(proj: Path, *, config: bool = True) -> Path:
    """Copy ``Snakefile``, ``workflow/``, a frozen ``rafi/`` (its files are rule inputs) and, if
    ``config``, ``config.yaml`` into ``proj`` (created); returns ``proj``. No raw data."""
    proj.mkdir(parents=True, exist_ok=True)
    shutil.copy2(ROOT / "Snakefile", proj / "Snakefile")
    if config:
        shutil.copy2(ROOT / "config.yaml", proj / "config.yaml")
    for name in ("workflow", "rafi"):
        shutil.copytree(ROOT / name, proj / name, ignore=shutil.ignore_patterns("__pycache__"))
    return proj
