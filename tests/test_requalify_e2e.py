"""Re-qualification end to end (issue 27): ``rafi plan`` -> the twin follows the plan -> ``rafi
nightly`` (the real Snakefile) -> a re-qualified champion with its parent in the registry.

Night 1 qualifies the machine on three shipped training runs and one validation run (the prior).
The old logs then leave ``raw/`` (docs/operations.md, "Re-qualification in hours"), ``rafi plan``
writes a 2 h programme, a sibling of the same series (``rafi simulate day --sibling``) runs it and
one validation run, and night 2 starts from the prior: the
programme is one heat-up (no whole-run CV fold), so the prior with one gain is offered
(:func:`rafi.family.selection.default_champion`), judged by the same gates, and promoted with
its parent recorded.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest
import yaml
from project_copy import ROOT, copy_project, run_nightly, settle

from rafi.deploy.record_plan import read_plan

MACHINE = "tapping-center-a"
TRAIN = ("train_03000rpm.csv", "train_09000rpm.csv", "train_15000rpm.csv", "valid_08000rpm.csv")


def _rafi(proj, *args) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(proj)}
    return subprocess.run(
        [sys.executable, "-m", "rafi.cli", *args],
        cwd=proj,
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )


def _project(tmp_path):
    proj = copy_project(tmp_path / "proj")
    cfg = yaml.safe_load((proj / "config.yaml").read_text(encoding="utf-8"))
    machine = cfg["machines"][MACHINE]
    machine["training_speeds_rpm"] = [3000, 9000, 15000]
    machine["models"] = {"enabled": ["rafi", "ridge_global", "dynamic"]}  # the family's time, trimmed
    cfg["machines"] = {MACHINE: machine}
    cfg["nightly_settle_s"] = 0
    (proj / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    raw = proj / "raw" / MACHINE
    raw.mkdir(parents=True)
    for name in TRAIN:
        shutil.copy2(ROOT / "raw" / MACHINE / name, raw / name)
        settle(raw / name)
    return proj


def _decision(proj) -> dict:
    return json.loads((proj / "results" / MACHINE / "registry" / "decision.json").read_text(encoding="utf-8"))


@pytest.mark.slow
def test_plan_twin_night_gives_a_requalified_champion_with_its_parent(tmp_path):
    proj = _project(tmp_path)
    registry = proj / "results" / MACHINE / "registry"

    # night 1: the machine's first qualification is the prior
    night = run_nightly(proj)
    assert night.returncode in (0, 4), night.stdout + night.stderr
    first = _decision(proj)
    assert first["decision"] == "promoted", first["reasons"]
    prior_id = first["candidate_id"]

    # the old logs leave raw/; rafi plan writes the programme from the prior
    archive = tmp_path / "archive"
    shutil.move(str(proj / "raw" / MACHINE), str(archive))
    (proj / "raw" / MACHINE).mkdir()
    plan = _rafi(proj, "plan", "--machine", MACHINE, "--hours", "2", "--out", "plan.csv")
    assert plan.returncode == 0, plan.stderr
    assert f"prior {prior_id[:12]}" in plan.stdout
    steps = read_plan(proj / "plan.csv").steps
    assert sum(s.duration_s for s in steps) <= 2 * 3600 and max(s.speed_rpm for s in steps) == 15000

    # a machine of the same series (its build spread) follows the plan; one validation run beside it
    sim = _rafi(
        proj, "simulate", "day", "--machine", MACHINE, "--plan", "plan.csv", "--validation-speeds", "12000",
        "--sibling", "0", "--seed", "9", "--no-defects", "--out", "raw",
    )  # fmt: skip
    assert sim.returncode == 0, sim.stderr
    for path in (proj / "raw" / MACHINE).glob("*.csv"):
        settle(path)

    # night 2: the prior is adapted to the new data and promoted with its parent
    night = run_nightly(proj)
    assert night.returncode in (0, 4), night.stdout + night.stderr
    second = _decision(proj)
    assert second["decision"] == "promoted", second["reasons"]
    assert second["candidate_parent"] == prior_id
    champion = json.loads((registry / "champion.json").read_text(encoding="utf-8"))
    assert champion["model_id"] == second["candidate_id"] != prior_id
    model = json.loads((registry / "models" / f"{champion['model_id']}.json").read_text(encoding="utf-8"))
    adaptation = model["adaptation"]
    assert adaptation["parent"] == prior_id and adaptation["method"] == "gain" and adaptation["gain"] > 0
    meta = json.loads((registry / "models" / f"{champion['model_id']}.meta.json").read_text(encoding="utf-8"))
    assert meta["parent"] == prior_id
    # what qualified it: the new files only, the prior's kind, its training data kept apart
    new_files = {p.name for p in (proj / "raw" / MACHINE).glob("*.csv")}
    assert set(model["data"]) <= new_files and not set(model["data"]) & {p.name for p in archive.glob("*")}
    summary = (proj / "results" / MACHINE / "comparison" / "summary.csv").read_text(encoding="utf-8")
    assert all(f"\n{name}," in summary for name in ("prior", "prior_gain"))
    status = _rafi(proj, "status", "--machine", MACHINE)
    assert f"(adapted from {prior_id[:12]})" in status.stdout, status.stdout + status.stderr
