"""Which of a machine's byte-identical raw files stays (rafi.ops.duplicates, the ``keep`` param of
rule input_status): the champion's, else the oldest, never by a newcomer's name; a link last.

On real files in a temporary folder (modification times set), with a registry written by
rafi.ops.registry, the way rule decide writes it.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

from rafi.artefact import compute_model_id
from rafi.ops import registry as R
from rafi.ops.duplicates import champion_training_files, copies_to_keep, duplicate_keepers

ROOT = Path(__file__).resolve().parents[1]
D, E = "d" * 64, "e" * 64


def test_the_champions_file_then_the_oldest_then_the_name():
    contents = {"b (copy).csv": D, "b.csv": D, "c.csv": E, "c2.csv": E, "alone.csv": "f" * 64}
    mtimes = {"b (copy).csv": 1, "b.csv": 2, "c.csv": 5, "c2.csv": 5}
    assert copies_to_keep(contents, trained_on={"b.csv": D}, mtimes=mtimes) == {D: "b.csv", E: "c.csv"}
    assert copies_to_keep(contents, trained_on={}, mtimes=mtimes) == {D: "b (copy).csv", E: "c.csv"}
    # the champion's file only if its content is still the champion's
    assert copies_to_keep(contents, trained_on={"b.csv": E}, mtimes=mtimes)[D] == "b (copy).csv"
    # a file without a time counts as the newest; a link goes before anything else
    assert copies_to_keep(contents, trained_on={}, mtimes={"b.csv": 2})[D] == "b.csv"
    linked = copies_to_keep(contents, trained_on={"b.csv": D}, mtimes=mtimes, links=["b.csv"])
    assert linked[D] == "b (copy).csv"


def _registry(tmp_path: Path, data: dict) -> Path:
    reg = R.Registry(tmp_path / "registry", "m1")
    model = {"schema": "fake/1", "kind": "fake", "data": data}
    model["model_id"] = compute_model_id(model)
    reg.save_model(model)
    reg.set_champion(model["model_id"], reason="test")
    return reg.root


def test_champion_training_files_from_the_registry(tmp_path):
    assert champion_training_files(tmp_path / "none") == {}
    root = _registry(tmp_path, {"a.csv": D})
    assert champion_training_files(root) == {"a.csv": D}
    (root / "champion.json").write_text(json.dumps({"model_id": "../x"}))
    assert champion_training_files(root) == {}
    (root / "champion.json").write_text("{not json")
    assert champion_training_files(root) == {}


def _raw(folder: Path, name: str, text: str, mtime: int) -> tuple[str, str]:
    path = folder / name
    path.write_text(text)
    os.utime(path, (mtime, mtime))
    return str(path), "sha256:" + hashlib.sha256(text.encode()).hexdigest()


def test_duplicate_keepers_of_a_machine(tmp_path):
    raw = tmp_path / "raw"
    raw.mkdir()
    files = {
        "train": _raw(raw, "train.csv", "same", 2_000_000_000),
        "train (copy)": _raw(raw, "train (copy).csv", "same", 1_000_000_000),  # older: `cp -p` then touched
        "other": _raw(raw, "other.csv", "other", 1_000_000_000),
    }
    paths = {stem: path for stem, (path, _) in files.items()}
    stamps = {stem: stamp for stem, (_, stamp) in files.items()}
    sha = stamps["train"].removeprefix("sha256:")
    assert duplicate_keepers(paths, stamps, tmp_path / "registry") == {sha: "train (copy).csv"}
    root = _registry(tmp_path, {"train.csv": sha})
    assert duplicate_keepers(paths, stamps, root) == {sha: "train.csv"}
    # no duplicates (an unreadable file has no content): nothing to keep, whatever the champion
    without = {**stamps, "train (copy)": "unreadable:EACCES"}
    assert duplicate_keepers(paths, without, root) == {}


def test_a_link_is_never_kept(tmp_path):
    raw = tmp_path / "raw"
    raw.mkdir()
    path, stamp = _raw(raw, "z_real.csv", "same", 2_000_000_000)
    (raw / "a_link.csv").symlink_to("z_real.csv")
    paths = {"z_real": path, "a_link": str(raw / "a_link.csv")}
    stamps = {"z_real": stamp, "a_link": stamp}
    root = _registry(tmp_path, {"a_link.csv": stamp.removeprefix("sha256:")})
    assert duplicate_keepers(paths, stamps, root) == {stamp.removeprefix("sha256:"): "z_real.csv"}


def test_planning_imports_no_pandas():
    """rafi.ops.duplicates runs while Snakemake plans (input_status.smk): standard library only."""
    code = "import sys, rafi.ops.duplicates; assert not {'pandas', 'numpy'} & set(sys.modules)"
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)
