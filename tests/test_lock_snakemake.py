"""Snakemake's lock in a project: which processes count as a live Snakemake run there
(psutil's process table replaced by a made-up one), and clearing a stale lock."""

from __future__ import annotations

import os
from pathlib import Path
from types import SimpleNamespace

import pytest

from rafi.ops import lock as L


def fake_processes(monkeypatch, procs: dict[int, tuple[list[str], Path | None]]) -> None:
    """psutil's process table as ``{pid: (argv, cwd)}``; a cwd of None is one psutil may not
    read (``ad_value``)."""

    def process_iter(attrs, ad_value):
        assert {"pid", "cmdline", "cwd"} <= set(attrs) and ad_value is None
        for pid, (argv, cwd) in procs.items():
            yield SimpleNamespace(
                info={"pid": pid, "cmdline": argv, "cwd": None if cwd is None else str(cwd)}
            )

    monkeypatch.setattr(L.psutil, "process_iter", process_iter)


@pytest.mark.parametrize(
    "argv, where, counts",
    [
        (["/venv/bin/python", "/venv/bin/snakemake", "--cores", "2"], "proj", True),
        (["snakemake", "-n"], "proj", True),
        (["python3", "-m", "snakemake", "--cores", "1"], "proj", True),
        (["python", ".snakemake/scripts/tmpa1b2.clean.py"], "proj", True),  # a job of a killed run
        (["/venv/bin/python", "/venv/bin/rafi", "nightly", "--cores", "2"], "proj", True),
        (["python", "-m", "rafi.cli", "nightly"], "proj", True),
        (["snakemake", "--directory", "PROJ", "--cores", "1"], "other", True),
        (["snakemake", "--directory=PROJ"], "other", True),
        (["snakemake", "-d", "proj"], "base", True),  # relative to its cwd
        (["snakemake", "--cores", "1"], "other", False),  # another project
        (["python", "-m", "pytest", "tests/test_snakemake.py"], "proj", False),
        (["bash"], "proj", False),
        (["/venv/bin/rafi", "simulate", "day"], "proj", False),
    ],
)
def test_which_processes_are_a_snakemake_run_in_the_project(tmp_path, monkeypatch, argv, where, counts):
    proj, other = tmp_path / "proj", tmp_path / "other"
    proj.mkdir()
    other.mkdir()
    argv = [a.replace("PROJ", str(proj)) for a in argv]
    cwd = {"proj": proj, "other": other, "base": tmp_path}[where]
    fake_processes(monkeypatch, {4242: (argv, cwd)})
    found = L.live_snakemake_processes(proj)
    assert found == ([(4242, " ".join(argv))] if counts else [])


def test_unreadable_process_entries_are_skipped(tmp_path, monkeypatch):
    proj = tmp_path / "proj"
    proj.mkdir()
    # 8: another user's process (its cwd cannot be read); 9: a kernel thread (no command line)
    fake_processes(monkeypatch, {7: (["snakemake"], proj), 8: (["snakemake"], None), 9: (None, proj)})
    assert L.live_snakemake_processes(proj) == [(7, "snakemake")]


def test_this_process_is_never_a_foreign_run(tmp_path):
    # the real /proc: this test process (cwd moved into the project) does not count
    proj = tmp_path / "proj"
    proj.mkdir()
    here = os.getcwd()
    os.chdir(proj)
    try:
        assert all(pid != os.getpid() for pid, _ in L.live_snakemake_processes(proj))
    finally:
        os.chdir(here)


def _locks(proj: Path) -> list[Path]:
    d = proj / ".snakemake" / "locks"
    d.mkdir(parents=True)
    made = [d / "0.input.lock", d / "0.output.lock", d / "1.input.lock"]
    for p in made:
        p.write_text("results/x.csv\n")
    (d / "notes.txt").write_text("not a lock\n")
    return made


def test_a_stale_lock_is_cleared(tmp_path, monkeypatch):
    proj = tmp_path / "proj"
    made = _locks(proj)
    assert L.snakemake_lock_files(proj) == sorted(made)
    monkeypatch.setattr(L, "live_snakemake_processes", lambda d: [])
    removed, live = L.clear_stale_snakemake_lock(proj)
    assert sorted(removed) == sorted(made) and live == []
    assert L.snakemake_lock_files(proj) == []
    assert (proj / ".snakemake" / "locks" / "notes.txt").exists()  # only Snakemake's lock files


def test_a_live_lock_is_left_alone(tmp_path, monkeypatch):
    proj = tmp_path / "proj"
    made = _locks(proj)
    monkeypatch.setattr(L, "live_snakemake_processes", lambda d: [(99, "snakemake --cores 1")])
    removed, live = L.clear_stale_snakemake_lock(proj)
    assert removed == [] and live == [(99, "snakemake --cores 1")]
    assert L.snakemake_lock_files(proj) == sorted(made)


def test_no_lock_no_process_scan(tmp_path, monkeypatch):
    def boom(d):  # pragma: no cover - must not be called
        raise AssertionError("scanned /proc without a lock")

    monkeypatch.setattr(L, "live_snakemake_processes", boom)
    assert L.clear_stale_snakemake_lock(tmp_path) == ([], [])
