"""Issue 13: "a deleted training file silently yields a champion without that speed".

On a trimmed copy of the shipped data with the real Snakefile: the first night promotes a
champion trained at 3000, 9000 and 15000 r/min; the 15000 r/min training file is deleted; the
next night's candidate (within the noise of the champion on every validation run) is rejected
because it does not cover 15000 r/min, the vanished file is named in decision.json, and the
champion stays.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest
from project_copy import copy_project, run_snakemake

ROOT = Path(__file__).resolve().parents[1]
MACHINE = "tapping-center-a"
KEEP = ("train_03000rpm", "train_09000rpm", "train_15000rpm", "valid_04500rpm", "multi_condition")

pytestmark = pytest.mark.slow


def _night(proj: Path) -> dict:
    done = run_snakemake(proj, "nightly", "--config", "nightly_report=false", timeout=900)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return json.loads((proj / "results" / MACHINE / "registry" / "decision.json").read_text())


def test_deleted_training_file_does_not_yield_a_champion_without_its_speed(tmp_path: Path):
    proj = copy_project(tmp_path / "proj")
    raw = proj / "raw" / MACHINE
    raw.mkdir(parents=True)
    for stem in KEEP:
        shutil.copy2(ROOT / "raw" / MACHINE / f"{stem}.csv", raw / f"{stem}.csv")

    first = _night(proj)
    assert first["decision"] == "promoted" and first["champion_id_before"] is None
    assert first["training"]["speeds_rpm"] == [3000.0, 9000.0, 15000.0]
    champion = first["candidate_id"]

    (raw / "train_15000rpm.csv").unlink()
    second = _night(proj)
    assert second["candidate_id"] != champion
    assert second["decision"] == "rejected" and second["champion_id_after"] == champion
    assert "coverage" in second["blocked_by"] and second["coverage"]["missing_speeds_rpm"] == [15000.0]
    assert any("no run at 15000 r/min" in r for r in second["reasons"])
    assert [v["file"] for v in second["data"]["vanished"]] == ["train_15000rpm.csv"]
    assert any("vanished: train_15000rpm.csv" in r for r in second["reasons"])
    pointer = json.loads((proj / "results" / MACHINE / "registry" / "champion.json").read_text())
    assert pointer["model_id"] == champion
    comp = pd.read_csv(proj / "results" / MACHINE / "registry" / "comparison.csv")
    assert comp["both_scored"].all() and (comp["margin_um"] > 0).all()
