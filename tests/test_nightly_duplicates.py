"""The same data, the same model: three nights of `rafi nightly` on a trimmed copy of the shipped
data with the real Snakefile.

1. the first model is promoted;
2. a byte-identical copy ``train_03000rpm (copy).csv`` arrives (its name sorts before the
   original's, its modification time is older): the original, the file the champion was trained
   on, stays and the copy is quarantined; the candidate is the champion (``kept``);
3. the original is deleted, so the copy is the training file under another name: the model id is
   the same (content only), nothing is promoted, and the decision reports the rename.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from pathlib import Path

import pytest
from project_copy import SETTLED_AGE_S, copy_project, copy_settled, run_nightly

ROOT = Path(__file__).resolve().parents[1]
MACHINE = "tapping-center-a"
KEEP = ("train_03000rpm", "train_09000rpm", "train_15000rpm", "valid_04500rpm", "multi_condition")
ORIGINAL = "train_03000rpm.csv"
COPY = "train_03000rpm (copy).csv"

pytestmark = pytest.mark.slow


@pytest.fixture
def project(tmp_path: Path) -> Path:
    proj = copy_project(tmp_path / "proj")
    (proj / "raw" / MACHINE).mkdir(parents=True)
    for stem in KEEP:
        copy_settled(ROOT / "raw" / MACHINE / f"{stem}.csv", proj / "raw" / MACHINE / f"{stem}.csv")
    return proj


def test_a_copy_keeps_the_champions_file_and_a_renamed_file_gives_the_same_model(project: Path):
    raw = project / "raw" / MACHINE
    res = project / "results" / MACHINE
    reg = res / "registry"

    run_nightly(project)
    first = json.loads((reg / "decision.json").read_text())
    assert first["decision"] == "promoted", first["reasons"]
    champion = first["candidate_id"]
    assert ORIGINAL in first["data"]["candidate_data"]

    # a copy with an older mtime: neither its name nor its age may win over the champion's file
    shutil.copy(raw / ORIGINAL, raw / COPY)
    older = time.time() - 2 * SETTLED_AGE_S
    os.utime(raw / COPY, (older, older))
    run_nightly(project)
    status = json.loads((res / "input_status.json").read_text())
    assert ORIGINAL in status["usable"] and COPY not in status["usable"]
    (rejected,) = [r for r in status["rejected"] if r.get("check") == "duplicate_content"]
    assert rejected["file"] == COPY
    assert f"byte-identical to {ORIGINAL}" in rejected["reason"] and rejected["reason"].endswith(
        "delete the copy"
    )
    second = json.loads((reg / "decision.json").read_text())
    assert second["decision"] == "kept" and second["candidate_id"] == champion, second["reasons"]

    # the original deleted: the copy is the same training data under another name
    (raw / ORIGINAL).unlink()
    run_nightly(project)
    status = json.loads((res / "input_status.json").read_text())
    assert COPY in status["usable"] and status["rejected"] == []
    third = json.loads((reg / "decision.json").read_text())
    assert COPY in third["data"]["candidate_data"] and ORIGINAL not in third["data"]["candidate_data"]
    assert third["decision"] == "kept" and third["candidate_id"] == champion, third["reasons"]
    assert third["champion_id_after"] == champion
    assert third["data"]["renamed"] == [{"file": ORIGINAL, "now": COPY}] and third["data"]["vanished"] == []
    assert json.loads((reg / "champion.json").read_text())["model_id"] == champion
    decisions = [json.loads(line)["decision"] for line in (reg / "history.jsonl").read_text().splitlines()]
    assert decisions == ["promoted", "kept", "kept"]
    assert len(list((reg / "models").glob("*.meta.json"))) == 1
