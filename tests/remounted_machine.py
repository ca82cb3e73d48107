"""A production foreign machine whose probe was remounted the other way for its last training
days (the displacement's sign reversed: a change no sensor sees), run through the real Snakefile
up to the comparison (tests/test_unexplained.py, tests/test_since_change.py)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd
import yaml
from project_copy import copy_project, run_snakemake

from rafi.twin.foreign import write_foreign

#: The production machine's seed.
SEED = 7

#: How many of its last training days the probe was reversed on.
REVERSED_DAYS = 3


def remounted_project(out: Path, *, since_change: bool) -> tuple[Path, object, list[str]]:
    """Write the machine under ``out``, reverse its probe on its last :data:`REVERSED_DAYS`
    training days, run the pipeline up to ``comparison/cv.csv`` with ``models.since_change`` set
    to ``since_change``; returns the project, the machine and the reversed days' stems."""
    machine, _ = write_foreign(SEED, out / "data", plan="production")
    folder = out / "data" / "raw" / machine.name
    reversed_days = [d["stem"] for d in machine.truth["days"] if d["role"] == "training"][-REVERSED_DAYS:]
    for stem in reversed_days:
        path = folder / f"{stem}.csv"
        lines = path.read_text(encoding="utf-8").splitlines(keepends=True)
        header = next(i for i, line in enumerate(lines) if not line.startswith("#"))
        frame = pd.read_csv(path, comment="#")
        frame["disp_um"] = -frame["disp_um"]
        path.write_text("".join(lines[:header]) + frame.to_csv(index=False), encoding="utf-8")
    proj = copy_project(out / "proj", config=False)
    config = yaml.safe_load((out / "data" / "config.yaml").read_text(encoding="utf-8"))
    config.setdefault("defaults", {}).setdefault("models", {})["since_change"] = since_change
    (proj / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")
    shutil.copytree(out / "data" / "raw", proj / "raw")
    done = run_snakemake(proj, f"results/{machine.name}/comparison/cv.csv", cores=2)
    assert done.returncode == 0, done.stderr[-3000:]
    return proj, machine, reversed_days
