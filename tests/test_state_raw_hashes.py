"""Content decides change (issue 13 item 5): raw-file hashes, their cache, the nightly fingerprint,
and Snakemake re-running the clean job of a file edited with its size and mtime kept."""

from __future__ import annotations

import argparse
import errno
import hashlib
import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rafi.ops import nightly as N
from rafi.ops import raw_hashes as H
from rafi.ops.project import Paths
from rafi.ops.state import fingerprint
from tests.project_copy import copy_project, run_snakemake

ROOT = Path(__file__).resolve().parents[1]
MACHINE = "tapping-center-a"


def edit_keeping_size_and_mtime(path: Path) -> None:
    """Change one digit of ``path`` in place, then put its mtime (and atime) back, as
    ``cp -p`` / ``rsync -t`` / ``touch -r`` leave a file: same size, same mtime, new content."""
    before = path.stat()
    data = bytearray(path.read_bytes())
    i = len(data) - 1
    while not chr(data[i]).isdigit():
        i -= 1
    data[i] = ord("1") if data[i] != ord("1") else ord("2")
    path.write_bytes(bytes(data))
    os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns))
    after = path.stat()
    assert (after.st_size, after.st_mtime_ns) == (before.st_size, before.st_mtime_ns)


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# --------------------------------------------------------------------------- the cache


def test_edit_with_size_and_mtime_kept_changes_the_stamp(tmp_path):
    raw = tmp_path / "raw.csv"
    shutil.copy2(ROOT / "raw" / MACHINE / "valid_04500rpm.csv", raw)
    cache = tmp_path / "results" / H.CACHE_NAME
    first = H.raw_stamps([raw], cache)[str(raw)]
    assert first == f"sha256:{_sha(raw)}"
    edit_keeping_size_and_mtime(raw)
    second = H.raw_stamps([raw], cache)[str(raw)]
    assert second == f"sha256:{_sha(raw)}" and second != first


def test_an_unchanged_file_is_not_read_again(tmp_path):
    files = []
    for src in sorted((ROOT / "raw" / MACHINE).glob("*.csv"))[:3]:
        shutil.copy2(src, tmp_path / src.name)
        files.append(tmp_path / src.name)
    cache_path = tmp_path / "results" / H.CACHE_NAME
    cold = H.RawHashCache(cache_path)
    stamps = [cold.stamp(f) for f in files]
    assert cold.hashed == 3 and cold.reused == 0 and cold.save()
    warm = H.RawHashCache(cache_path)
    assert [warm.stamp(f) for f in files] == stamps
    assert warm.hashed == 0 and warm.reused == 3
    assert not warm.dirty  # nothing to write: the cache file is not rewritten
    # touching one file (new mtime and ctime, same content) re-reads that file only, same hash
    os.utime(files[0])
    again = H.RawHashCache(cache_path)
    assert [again.stamp(f) for f in files] == stamps and again.hashed == 1


@pytest.mark.parametrize(
    "content",
    ["", "not json", "[1, 2]", '{"version": 99, "files": {}}', '{"version": 1, "files": {"a": 3}}'],
)
def test_a_corrupt_or_foreign_cache_is_ignored(tmp_path, content):
    raw = tmp_path / "x.csv"
    raw.write_text("a,b\n1,2\n")
    cache = tmp_path / H.CACHE_NAME
    cache.write_text(content)
    assert H.raw_stamps([raw], cache)[str(raw)] == f"sha256:{_sha(raw)}"
    data = json.loads(cache.read_text())  # rewritten whole
    assert data["version"] == H.CACHE_VERSION and list(data["files"]) == [str(raw.resolve())]


def test_a_stale_cache_entry_is_not_trusted(tmp_path):
    """An entry whose stat key matches but whose hash is wrong can only come from a forged
    cache; a real edit always changes the key (ctime), so the edited file is read again."""
    raw = tmp_path / "x.csv"
    raw.write_text("a,b\n1,2\n")
    cache = tmp_path / H.CACHE_NAME
    H.raw_stamps([raw], cache)
    raw.write_text("a,b\n1,3\n")
    st_ = raw.stat()
    entry = json.loads(cache.read_text())["files"][str(raw.resolve())]
    assert entry[2] != st_.st_ctime_ns or entry[3] != st_.st_ino  # the key moved with the write
    assert H.raw_stamps([raw], cache)[str(raw)] == f"sha256:{_sha(raw)}"


def test_cache_cannot_be_written_is_not_an_error(tmp_path, monkeypatch):
    raw = tmp_path / "x.csv"
    raw.write_text("a\n")

    def refuse(*a, **k):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    monkeypatch.setattr(H.tempfile, "mkstemp", refuse)
    cache = H.RawHashCache(tmp_path / "results" / H.CACHE_NAME)
    assert cache.stamp(raw) == f"sha256:{_sha(raw)}"
    assert cache.save() is False and cache.dirty
    assert not (tmp_path / "results" / H.CACHE_NAME).exists()


def test_dry_run_writes_no_cache_and_leaves_no_partial_file(tmp_path):
    raw = tmp_path / "x.csv"
    raw.write_text("a\n")
    cache = tmp_path / "results" / H.CACHE_NAME
    H.raw_stamps([raw], cache, write=False)
    assert not cache.exists()
    H.raw_stamps([raw], cache)
    assert cache.exists() and not list(cache.parent.glob("*.part"))


def test_an_unreadable_file_gets_a_stamp_not_an_exception(tmp_path):
    gone = tmp_path / "gone.csv"
    assert H.raw_stamps([gone], tmp_path / H.CACHE_NAME)[str(gone)] == "unreadable:ENOENT"


@settings(max_examples=40, deadline=None)
@given(st.binary(min_size=1, max_size=4096), st.data())
def test_stamp_is_the_hash_of_the_current_content(content, data):
    """Property: whatever byte is changed (size and mtime kept), the stamp is the SHA-256 of
    the new content, through a warm cache."""
    with tempfile.TemporaryDirectory() as d:
        raw, cache = Path(d) / "f.bin", Path(d) / H.CACHE_NAME
        raw.write_bytes(content)
        assert H.raw_stamps([raw], cache)[str(raw)] == "sha256:" + hashlib.sha256(content).hexdigest()
        i = data.draw(st.integers(0, len(content) - 1))
        edited = bytearray(content)
        edited[i] = (edited[i] + data.draw(st.integers(1, 255))) % 256
        before = raw.stat()
        raw.write_bytes(bytes(edited))
        os.utime(raw, ns=(before.st_atime_ns, before.st_mtime_ns))
        got = H.raw_stamps([raw], cache)[str(raw)]
        assert got == "sha256:" + hashlib.sha256(bytes(edited)).hexdigest()


# --------------------------------------------------------------------------- nightly fingerprint


def test_fingerprint_sees_an_edit_with_size_and_mtime_kept(tmp_path):
    proj = tmp_path / "proj"
    (proj / "raw" / "m1").mkdir(parents=True)
    raw = proj / "raw" / "m1" / "x.csv"
    raw.write_text("time,T1\n0,20.5\n")
    (proj / "config.yaml").write_text("")
    paths = Paths.from_config(proj, {})
    over = N.config_overrides(argparse.Namespace(machine=None, no_report=False))
    before = fingerprint("config.yaml", paths, over)
    assert fingerprint("config.yaml", paths, over) == before  # stable
    # the raw-hash cache under results/ is no reason to ask Snakemake
    H.raw_stamps([raw], paths.results_dir / H.CACHE_NAME)
    assert fingerprint("config.yaml", paths, over) == before
    edit_keeping_size_and_mtime(raw)
    assert fingerprint("config.yaml", paths, over) != before


# --------------------------------------------------------------------------- Snakemake


def _clean_targets(machine: str, stems: list[str]) -> list[str]:
    return [f"results/{machine}/clean/{s}.parquet" for s in stems]


def _snakemake(proj: Path, *args: str) -> subprocess.CompletedProcess:
    return run_snakemake(proj, *args)


def test_snakemake_reruns_the_clean_job_of_a_file_edited_with_its_mtime_kept(tmp_path):
    proj = copy_project(tmp_path / "proj")
    stems = ["valid_04500rpm", "valid_13500rpm", "train_03000rpm"]
    (proj / "raw" / MACHINE).mkdir(parents=True)
    for s in stems:
        shutil.copy2(ROOT / "raw" / MACHINE / f"{s}.csv", proj / "raw" / MACHINE / f"{s}.csv")
    # one clean job per machine (its folder): Snakemake re-runs it, every file is cleaned again
    targets = [f"results/{MACHINE}/clean"]
    files = _clean_targets(MACHINE, stems)
    first = _snakemake(proj, *targets)
    assert first.returncode == 0, first.stdout + first.stderr
    cache = json.loads((proj / "results" / H.CACHE_NAME).read_text())
    assert len(cache["files"]) == len(stems)
    dry = _snakemake(proj, "-n", *targets)
    assert "Nothing to be done" in dry.stdout + dry.stderr, dry.stdout + dry.stderr

    edit_keeping_size_and_mtime(proj / "raw" / MACHINE / "valid_13500rpm.csv")
    dry = _snakemake(proj, "-n", *targets)
    out = dry.stdout + dry.stderr
    assert dry.returncode == 0, out
    assert f"machine={MACHINE}" in out and "Params have changed" in out, out
    mtimes = {s: (proj / t).stat().st_mtime_ns for s, t in zip(stems, files, strict=True)}
    again = _snakemake(proj, *targets)
    assert again.returncode == 0, again.stdout + again.stderr
    log = (proj / "logs" / MACHINE / "clean.log").read_text(encoding="utf-8")
    assert "valid_13500rpm: ok" in log and "3 raw file(s): 3 cleaned" in log, log
    after = {s: (proj / t).stat().st_mtime_ns for s, t in zip(stems, files, strict=True)}
    assert all(after[s] != mtimes[s] for s in stems)
    dry = _snakemake(proj, "-n", *targets)
    assert "Nothing to be done" in dry.stdout + dry.stderr
