"""Faults a night must survive without a person (issue 13 items 6 and 7).

* ``kill -9`` of a night leaves Snakemake's lock (``.snakemake/locks``) behind: the next
  ``rafi nightly`` sees that no Snakemake process works in the project, clears it (a line on
  stdout and in the nightly log) and runs normally. A lock of a *live* Snakemake run (someone
  running ``snakemake`` by hand) is respected: exit 75 naming its pid.
* A read-only or full ``results/`` gives one line naming the path and the errno, exit 73, no
  traceback. Tests run as root, for whom ``chmod`` forbids nothing: the real cases use a
  read-only bind mount and a tiny full tmpfs in a private mount namespace (``unshare -m``;
  skipped where that is not allowed); the same paths are also tested with the write
  monkeypatched to raise ``OSError(EROFS / ENOSPC / EIO)``.
"""

from __future__ import annotations

import argparse
import errno
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import require

from rafi.ops import nightly as N
from rafi.ops import snakemake_api
from rafi.ops import status as S
from rafi.ops.lock import LOCK_NAME, NightlyLock, lock_is_free, snakemake_lock_files
from rafi.ops.state import NIGHTLY_LOG
from tests.project_copy import copy_project
from tests.test_state_raw_hashes import edit_keeping_size_and_mtime

ROOT = Path(__file__).resolve().parents[1]
MACHINE = "tapping-center-a"
DAY = 86_400


def rafi_cmd(*args):
    return [sys.executable, "-m", "rafi.cli", *args]


def fake_project(tmp_path: Path, shell: str) -> Path:
    """A project whose target ``nightly`` needs ``out.txt``, made by ``shell``."""
    d = tmp_path / "proj"
    (d / "raw" / "m1").mkdir(parents=True)
    raw = d / "raw" / "m1" / "x.csv"
    raw.write_text("time\n")
    os.utime(raw, (time.time() - DAY, time.time() - DAY))  # settled
    (d / "config.yaml").write_text("raw_dir: raw\nresults_dir: results\nreports_dir: reports\n")
    (d / "Snakefile").write_text(
        f"rule nightly:\n    input: 'out.txt'\nrule make:\n    output: 'out.txt'\n    shell: '{shell}'\n"
    )
    return d


def wait_for(predicate, what: str, limit_s: float = 300.0, proc: subprocess.Popen | None = None):
    """Poll ``predicate`` until true (a bound on waiting, not a timed assertion)."""
    deadline = time.monotonic() + limit_s
    while not predicate():
        if proc is not None and proc.poll() is not None:
            out, err = proc.communicate()
            pytest.fail(f"process ended (exit {proc.returncode}) before {what}:\n{out}\n{err}")
        if time.monotonic() > deadline:
            pytest.fail(f"gave up waiting for {what}")
        time.sleep(0.1)


def kill_group(proc: subprocess.Popen) -> None:
    """``kill -9`` the process group of ``proc`` (started with ``start_new_session``)."""
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait(timeout=60)


# --------------------------------------------------------------------------- Snakemake's lock


def test_live_snakemake_lock_is_respected_and_a_killed_one_cleared(tmp_path):
    proj = fake_project(tmp_path, "sleep 120; echo ok > {output}")
    snake = subprocess.Popen(
        [sys.executable, "-m", "snakemake", "--cores", "1", "out.txt"],
        cwd=proj,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        wait_for(lambda: snakemake_lock_files(proj), "Snakemake's lock files", proc=snake)
        # someone runs snakemake by hand: the night does not touch its lock
        res = subprocess.run(rafi_cmd("nightly", "--directory", str(proj)), capture_output=True, text=True)
        assert res.returncode == S.EXIT_LOCKED == 75, res.stdout + res.stderr
        assert f"pid {snake.pid}" in res.stderr and "Snakemake is running in" in res.stderr
        assert "Traceback" not in res.stderr
        assert snakemake_lock_files(proj) and snake.poll() is None
        assert lock_is_free(proj / "results" / LOCK_NAME)
        # it is killed: its lock stays behind (what made every later night fail)
        kill_group(snake)
    finally:
        if snake.poll() is None:
            kill_group(snake)
    stale = snakemake_lock_files(proj)
    assert stale
    (proj / "Snakefile").write_text(
        (proj / "Snakefile").read_text().replace("sleep 120; ", "")  # the next run is quick
    )
    res = subprocess.run(
        rafi_cmd("nightly", "--directory", str(proj), "--cores", "1"), capture_output=True, text=True
    )
    assert res.returncode == S.EXIT_OK, res.stdout + res.stderr
    assert "cleared a stale Snakemake lock" in res.stdout
    assert all(p.name in res.stdout for p in stale)
    assert "cleared a stale Snakemake lock" in (proj / "results" / NIGHTLY_LOG).read_text()
    assert (proj / "out.txt").read_text() == "ok\n"
    assert not snakemake_lock_files(proj)


# --------------------------------------------------------------------------- read-only / full results


def _unshare_works() -> bool:
    if not shutil.which("unshare"):
        return False
    try:
        return subprocess.run(["unshare", "-m", "true"], capture_output=True, timeout=30).returncode == 0
    except (OSError, subprocess.SubprocessError):
        return False


@pytest.fixture
def private_mount_namespace():
    """Skip (fail under CI=true) where ``unshare -m`` cannot make a private mount namespace."""
    require(
        None
        if _unshare_works()
        else "no private mount namespace here (unshare -m): see the monkeypatched tests"
    )


needs_unshare = pytest.mark.usefixtures("private_mount_namespace")


def _nightly_in_namespace(proj: Path, setup: str) -> subprocess.CompletedProcess:
    """``rafi nightly`` in a private mount namespace after the shell commands ``setup``."""
    cmd = " ".join(f"'{a}'" for a in rafi_cmd("nightly", "--directory", str(proj), "--cores", "1"))
    return subprocess.run(
        ["unshare", "-m", "sh", "-c", f"set -e; {setup}; exec {cmd}"],
        capture_output=True,
        text=True,
        cwd=proj.parent,
        timeout=300,
    )


def _one_clear_line(res: subprocess.CompletedProcess, path: Path, errno_name: str) -> str:
    assert res.returncode == S.EXIT_CANTCREAT == 73, res.stdout + res.stderr
    assert "Traceback" not in res.stdout + res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, res.stderr
    assert str(path) in lines[0] and f"({errno_name})" in lines[0] and "exiting with 73" in lines[0]
    return lines[0]


@needs_unshare
def test_read_only_results_gives_one_line_and_73(tmp_path):
    """A read-only bind mount of results/ (root ignores chmod; a read-only mount it does not)."""
    proj = fake_project(tmp_path, "echo ok > {output}")
    results = proj / "results"
    results.mkdir()
    res = _nightly_in_namespace(proj, f"mount --bind -o ro '{results}' '{results}'")
    line = _one_clear_line(res, results, "EROFS")
    assert "Read-only file system" in line
    assert not (proj / "out.txt").exists()  # nothing ran


@needs_unshare
def test_full_results_gives_one_line_and_73(tmp_path):
    """results/ on a 64 KiB tmpfs filled to the last byte: ENOSPC."""
    proj = fake_project(tmp_path, "echo ok > {output}")
    results = proj / "results"
    results.mkdir()
    fill = f"dd if=/dev/zero of='{results}/fill' bs=4096 count=64 2>/dev/null || true"
    res = _nightly_in_namespace(proj, f"mount -t tmpfs -o size=64k tmpfs '{results}'; {fill}")
    line = _one_clear_line(res, results, "ENOSPC")
    assert "No space left on device" in line
    assert not (proj / "out.txt").exists()


def _args(proj: Path, **kw) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    N.add_arguments(parser)
    args = parser.parse_args(["--directory", str(proj), "--cores", "1"])
    for k, v in kw.items():
        setattr(args, k, v)
    return args


@pytest.mark.parametrize(
    "err, code, text",
    [
        (errno.EROFS, 73, "Read-only file system (EROFS)"),
        (errno.ENOSPC, 73, "No space left on device (ENOSPC)"),
        (errno.EIO, 74, "Input/output error (EIO)"),
    ],
)
def test_write_error_at_the_start_monkeypatched(tmp_path, monkeypatch, capsys, err, code, text):
    proj = fake_project(tmp_path, "echo ok > {output}")

    def refuse(self):
        raise OSError(err, os.strerror(err), str(self.path))

    monkeypatch.setattr(NightlyLock, "__enter__", refuse)
    assert N.run(_args(proj)) == code
    out = capsys.readouterr()
    assert text in out.err and str(proj / "results" / LOCK_NAME) in out.err
    assert len(out.err.strip().splitlines()) == 1 and "Traceback" not in out.err


def test_disk_full_during_the_night_is_73_not_1(tmp_path, monkeypatch, capsys):
    """A pipeline that failed because results/ filled up: the cause is said, exit 73."""
    proj = fake_project(tmp_path, "echo ok > {output}")
    probes = []

    def probe(folder):
        probes.append(folder)
        if len(probes) > 1:  # writable when the night starts, full after the jobs
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(folder))

    monkeypatch.setattr(N, "check_writable", probe)
    monkeypatch.setattr(
        snakemake_api, "run", lambda *a, **k: snakemake_api.Outcome(ok=False, failed=["make"], error="x")
    )
    assert N.run(_args(proj)) == S.EXIT_CANTCREAT
    err = capsys.readouterr().err
    assert "No space left on device (ENOSPC)" in err and str(proj / "results") in err
    assert len(probes) == 2


# --------------------------------------------------------------------------- kill -9 of a real night


def _pipeline_project(tmp_path: Path) -> Path:
    proj = copy_project(tmp_path / "proj")
    with open(proj / "config.yaml", "a", encoding="utf-8") as fh:
        fh.write("\nnightly_settle_s: 0  # the logs are copied just before the night\n")
    raw = proj / "raw" / MACHINE
    raw.mkdir(parents=True)
    for f in sorted((ROOT / "raw" / MACHINE).glob("*.csv")):
        if re.search(r"train.*(3000|9000|15000)|valid.*(4500|13500)", f.name):
            shutil.copy2(f, raw / f.name)
    return proj


def _night(proj: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        rafi_cmd("nightly", "--cores", "2", "--no-report"),
        cwd=proj,  # the frozen copy of rafi/ in the project is the one imported
        capture_output=True,
        text=True,
        timeout=900,
    )


@pytest.mark.slow
def test_kill_9_mid_night_then_the_next_night_runs_without_a_manual_step(tmp_path):
    proj = _pipeline_project(tmp_path)
    reg = proj / "results" / MACHINE / "registry"
    first = subprocess.Popen(
        rafi_cmd("nightly", "--cores", "2", "--no-report"),
        cwd=proj,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    try:
        # mid-run: Snakemake holds its lock and has finished at least one job
        wait_for(
            lambda: (
                snakemake_lock_files(proj) and list((proj / "results" / MACHINE / "clean").glob("*.parquet"))
            ),
            "Snakemake's lock and a first clean output",
            proc=first,
        )
        kill_group(first)
    finally:
        if first.poll() is None:
            kill_group(first)
    assert snakemake_lock_files(proj), "the kill left no Snakemake lock: nothing to test"
    assert not (reg / "decision.json").exists()

    second = _night(proj)
    out = second.stdout + second.stderr
    assert second.returncode in (S.EXIT_OK, S.EXIT_QUARANTINED), out
    assert "cleared a stale Snakemake lock" in second.stdout, out
    assert "cleared a stale Snakemake lock" in (proj / "results" / NIGHTLY_LOG).read_text()
    assert not snakemake_lock_files(proj)
    decision = json.loads((reg / "decision.json").read_text())
    assert decision["decision"] == "promoted", decision.get("reasons")
    champion = json.loads((reg / "champion.json").read_text())["model_id"]
    assert champion == decision["candidate_id"]
    assert lock_is_free(proj / "results" / LOCK_NAME)

    # the night after has nothing new (fast path) ...
    third = _night(proj)
    assert third.returncode == second.returncode and "nothing new since" in third.stdout, third.stdout

    # ... until a raw file's content changes with its size and mtime kept: only its clean job
    # (and what depends on it) runs again
    edit_keeping_size_and_mtime(proj / "raw" / MACHINE / "valid_13500rpm.csv")
    fourth = _night(proj)
    assert fourth.returncode in (S.EXIT_OK, S.EXIT_REJECTED, S.EXIT_QUARANTINED), (
        fourth.stdout + fourth.stderr
    )
    # the machine's clean job runs again (param raw_stamps) and cleans its files again
    assert re.findall(r"done clean \(machine=([^,)]+)\)", fourth.stdout) == [MACHINE], fourth.stdout
    clean_log = (proj / "logs" / MACHINE / "clean.log").read_text(encoding="utf-8")
    cleaned = re.findall(r"^(\S+): (?:ok|quarantined)$", clean_log, flags=re.M)
    assert "valid_13500rpm" in cleaned, clean_log
