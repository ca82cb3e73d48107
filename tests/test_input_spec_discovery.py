"""Discovery refuses links out of raw_dir (link_outside_raw) and leaves files still being written
for the next run (settling): rafi.readers.input_spec.discover_machines / find_logs and
rafi.readers.discovery."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from rafi.readers.discovery import settling_files
from rafi.readers.input_spec import discover_machines, find_logs

ROOT = Path(__file__).resolve().parents[1]
NATIVE = {"format": "native"}
SHIPPED = ROOT / "raw" / "tapping-center-a"


def _raw(tmp_path: Path) -> Path:
    """raw/m1 with two shipped files, and a folder outside raw/ with a third."""
    raw = tmp_path / "raw"
    (raw / "m1").mkdir(parents=True)
    for name in ("train_03000rpm.csv", "valid_04500rpm.csv"):
        shutil.copy2(SHIPPED / name, raw / "m1" / name)
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    shutil.copy2(SHIPPED / "train_06000rpm.csv", outside / "secret.csv")
    return raw


def test_a_file_link_out_of_raw_is_refused_with_link_and_target(tmp_path):
    raw = _raw(tmp_path)
    (raw / "m1" / "stolen.csv").symlink_to(tmp_path / "elsewhere" / "secret.csv")
    found, warnings = discover_machines(raw, lambda m: NATIVE)
    assert sorted(found["m1"]) == ["train_03000rpm", "valid_04500rpm"]
    assert warnings == [
        f"link_outside_raw: refused {raw / 'm1' / 'stolen.csv'}: a symbolic link to "
        f"{(tmp_path / 'elsewhere' / 'secret.csv').resolve()}, outside raw_dir {raw}; it is not read - "
        "copy the file into raw_dir, or link to a place inside it"
    ]
    assert [p.name for p in find_logs(raw / "m1", NATIVE)] == ["train_03000rpm.csv", "valid_04500rpm.csv"]


def test_a_machine_folder_linked_out_of_raw_is_refused(tmp_path):
    raw = _raw(tmp_path)
    (raw / "m2").symlink_to(tmp_path / "elsewhere", target_is_directory=True)
    (raw / "m1" / "sub").symlink_to(tmp_path / "elsewhere", target_is_directory=True)
    found, warnings = discover_machines(
        raw, lambda m: {"format": "native", "pattern": ["*.csv", "sub/*.csv"]}
    )
    assert list(found) == ["m1"] and sorted(found["m1"]) == ["train_03000rpm", "valid_04500rpm"]
    assert len(warnings) == 2 and all(w.startswith("link_outside_raw: refused ") for w in warnings)
    assert any(f"refused {raw / 'm1' / 'sub' / 'secret.csv'}" in w for w in warnings)
    assert any(f"refused {raw / 'm2'}:" in w for w in warnings)


def test_links_inside_raw_still_work_and_raw_dir_itself_may_be_a_link(tmp_path):
    raw = _raw(tmp_path)
    (raw / "m2").mkdir()
    (raw / "m2" / "shared.csv").symlink_to(raw / "m1" / "train_03000rpm.csv")
    (raw / "m3").symlink_to(raw / "m1", target_is_directory=True)
    linked_root = tmp_path / "raw_link"
    linked_root.symlink_to(raw, target_is_directory=True)
    for root in (raw, linked_root):
        found, warnings = discover_machines(root, lambda m: NATIVE)
        assert warnings == []
        assert list(found["m2"]) == ["shared"] and sorted(found["m3"]) == sorted(found["m1"])


def test_a_link_loop_is_not_followed(tmp_path):
    raw = _raw(tmp_path)
    (raw / "m1" / "loop.csv").symlink_to(raw / "m1" / "loop.csv")
    found, warnings = discover_machines(raw, lambda m: NATIVE)
    assert "loop" not in found["m1"]
    assert len(warnings) == 1 and warnings[0].startswith("not_a_file: skipped ")
    assert "loop.csv" in warnings[0] and "leads nowhere" in warnings[0]


def _age(path: Path, seconds: float, now: float) -> None:
    os.utime(path, (now - seconds, now - seconds))


def test_a_young_file_waits_for_the_next_run_with_a_warning(tmp_path):
    raw = _raw(tmp_path)
    now = 2_000_000_000.0
    _age(raw / "m1" / "train_03000rpm.csv", 3600, now)
    _age(raw / "m1" / "valid_04500rpm.csv", 42.4, now)
    found, warnings = discover_machines(raw, lambda m: NATIVE, settle_s=600, now=now)
    assert list(found["m1"]) == ["train_03000rpm"]
    assert warnings == [
        f"settling: waits for the next run: {raw / 'm1' / 'valid_04500rpm.csv'} was modified 42 s ago "
        "(settle_s 600)"
    ]
    # the next run, ten minutes later, reads it
    found, warnings = discover_machines(raw, lambda m: NATIVE, settle_s=600, now=now + 600)
    assert sorted(found["m1"]) == ["train_03000rpm", "valid_04500rpm"] and warnings == []


def test_settle_s_0_waits_for_nothing_and_a_future_mtime_waits_only_with_settle_s(tmp_path):
    raw = _raw(tmp_path)
    now = 2_000_000_000.0
    _age(raw / "m1" / "train_03000rpm.csv", -3600, now)  # modified in the future
    _age(raw / "m1" / "valid_04500rpm.csv", 0, now)
    assert settling_files(sorted((raw / "m1").iterdir()), 0, now) == []
    found, warnings = discover_machines(raw, lambda m: NATIVE, now=now)
    assert len(found["m1"]) == 2 and warnings == []
    waiting = settling_files(sorted((raw / "m1").iterdir()), 60, now)
    assert [(p.name, age) for p, age in waiting] == [
        ("train_03000rpm.csv", -3600.0),
        ("valid_04500rpm.csv", 0.0),
    ]
    _, warnings = discover_machines(raw, lambda m: NATIVE, settle_s=60, now=now)
    assert "was modified -3600 s ago (in the future: check the clocks) (settle_s 60)" in warnings[0]
    assert (
        warnings[-1]
        == f"skipping machine folder {raw / 'm1'}: no usable file (0 refused link(s), 2 settling)"
    )


@pytest.mark.parametrize("settle_s", [0, 600])
def test_no_false_alarm_on_the_shipped_raw_folder(settle_s):
    found, warnings = discover_machines(
        ROOT / "raw",
        lambda m: {"format": "xlsx"} if m == "machining-center-b" else NATIVE,
        settle_s=settle_s,
        now=max(p.stat().st_mtime for p in (ROOT / "raw").rglob("*")) + settle_s,
    )
    assert warnings == [] and sorted(found) == ["machining-center-b", "tapping-center-a"]
    assert len(found["tapping-center-a"]) == len(list(SHIPPED.glob("*.csv")))
