"""Nights for different machines run at the same time; two for the same machine refuse each other.

Real ``rafi nightly`` processes on a copy of the project with the shipped machines (the
tapping centre trimmed to five logs). Overlap is shown with the test hook that holds the locks
until a file exists (``RAFI_NIGHTLY_TEST_HOLD_UNTIL``): both nights have printed that they hold
their locks, and both lock files are held and name their holders, before either is let go. No
assertion on durations.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from rafi.ops import lock as L
from rafi.ops import nightly as N
from rafi.ops import status as S
from rafi.ops.state import log_name, state_name
from tests.project_copy import copy_project, copy_settled

ROOT = Path(__file__).resolve().parents[1]
A, B = "tapping-center-a", "machining-center-b"


def _project(tmp: Path) -> Path:
    proj = copy_project(tmp / "proj")
    for machine in (A, B):
        (proj / "raw" / machine).mkdir(parents=True)
    for f in sorted((ROOT / "raw" / A).glob("*.csv")):
        if re.search(r"train.*(3000|9000|15000)|valid.*(4500|13500)", f.name):
            copy_settled(f, proj / "raw" / A / f.name)
    for f in sorted((ROOT / "raw" / B).iterdir()):
        copy_settled(f, proj / "raw" / B / f.name)
    return proj


def _start(proj: Path, *args: str, go: Path | None = None) -> subprocess.Popen:
    env = dict(os.environ)
    if go is not None:
        env[N.HOLD_UNTIL_ENV] = str(go)
    return subprocess.Popen(
        [sys.executable, "-m", "rafi.cli", "nightly", "--cores", "1", "--no-report", *args],
        cwd=proj,  # the frozen copy of rafi/ in the project is the one imported
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )


def _acquired(proc: subprocess.Popen) -> str:
    """The first stdout line of a night (it says which locks it holds)."""
    line = proc.stdout.readline()
    if "acquired" not in line:
        out, err = proc.communicate(timeout=60)
        pytest.fail(f"no lock line (exit {proc.returncode}): {line}{out}\n{err}")
    return line


def _finish(proc: subprocess.Popen, first_line: str = "") -> tuple[int, str, str]:
    out, err = proc.communicate(timeout=600)
    return proc.returncode, first_line + out, err


def _kill(*procs: subprocess.Popen) -> None:
    for p in procs:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=60)


def _holder(results: Path, machine: str) -> str:
    return L.machine_lock_path(results, machine).read_text()


@pytest.fixture(scope="module")
def parallel(tmp_path_factory):
    """Two nights, one per machine, inside their locks at the same time, then let go together.

    A stale Snakemake lock (what a killed run leaves) is put in place while both wait: each
    night sees the other as a ``rafi nightly`` working in the project, which is not a foreign
    Snakemake run (it holds its own machine's lock), so the stale lock is cleared, not obeyed.
    """
    proj = _project(tmp_path_factory.mktemp("parallel"))
    results = proj / "results"
    go = proj.parent / "go"
    first = _start(proj, "--machine", A, go=go)
    second = None
    try:
        line_a = _acquired(first)
        second = _start(proj, "--machine", B, go=go)
        line_b = _acquired(second)
        # both inside their locks now: neither lock is free and each names its own night
        held = {m: (L.lock_is_free(L.machine_lock_path(results, m)), _holder(results, m)) for m in (A, B)}
        stale = proj / ".snakemake" / "locks"
        stale.mkdir(parents=True, exist_ok=True)
        (stale / "0.input.lock").write_text(f"{proj}/raw/{A}/x.csv\n")
        (stale / "0.output.lock").write_text(f"{proj}/results/{A}/x.parquet\n")
        go.write_text("go\n")
        res_a = _finish(first, line_a)
        res_b = _finish(second, line_b)
    finally:
        _kill(*(p for p in (first, second) if p is not None))
    return {"proj": proj, "held": held, "pids": (first.pid, second.pid), A: res_a, B: res_b}


@pytest.mark.slow
def test_two_machines_hold_their_locks_at_the_same_time_and_both_finish(parallel):
    proj, results = parallel["proj"], parallel["proj"] / "results"
    pid_a, pid_b = parallel["pids"]
    (free_a, holder_a), (free_b, holder_b) = parallel["held"][A], parallel["held"][B]
    assert not free_a and not free_b  # both held at once
    assert f"pid={pid_a} " in holder_a and f"pid={pid_b} " in holder_b
    for machine in (A, B):
        code, out, err = parallel[machine]
        assert code == S.EXIT_OK, out + err
        assert str(L.machine_lock_path(results, machine)) in out.splitlines()[0]
        assert "--nolock" in out  # Snakemake's directory lock is not shared between runs
        assert "Snakemake is running" not in err and "another nightly run" not in err
        decision = json.loads((results / machine / "registry" / "decision.json").read_text())
        assert decision["decision"] == "promoted", decision.get("reasons")
        # its own log and fast-path state: no other night wrote into them
        log = (results / log_name(machine)).read_text()
        assert log.count("===== rafi nightly") == 1 and f"pid {parallel['pids'][machine == B]}" in log
        assert (results / state_name(machine)).exists()
        assert L.lock_is_free(L.machine_lock_path(results, machine))
    # the stale Snakemake lock was cleared by one of them (the other found it gone)
    cleared = [m for m in (A, B) if "cleared a stale Snakemake lock" in parallel[m][1]]
    assert cleared and not L.snakemake_lock_files(proj)
    # neither touched the other's data or wrote the run-level files of a night for every machine
    assert not (results / "nightly.log").exists() and not (results / ".nightly.state.json").exists()
    assert not (results / "input_check.json").exists()
    # the nights for some machines rewrote the fleet overview when they ended
    page = (proj / "reports" / "index.html").read_text()
    assert A in page and B in page


def test_same_machine_refuses_with_75_naming_the_holder(parallel):
    proj, results = parallel["proj"], parallel["proj"] / "results"
    go = proj.parent / "go-same"
    first = _start(proj, "--machine", A, go=go)
    try:
        line = _acquired(first)
        second = subprocess.run(
            [sys.executable, "-m", "rafi.cli", "nightly", "--machine", A, "--no-report"],
            cwd=proj,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert second.returncode == S.EXIT_LOCKED == 75, second.stdout + second.stderr
        assert "another nightly run is in progress" in second.stderr
        assert f"pid={first.pid} " in second.stderr
        assert str(L.machine_lock_path(results, A)) in second.stderr
        # a night for every machine needs this machine's lock too: it refuses, and releases
        # the locks it had taken before (the fleet lock)
        every = subprocess.run(
            [sys.executable, "-m", "rafi.cli", "nightly", "--no-report"],
            cwd=proj,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert every.returncode == 75 and f"pid={first.pid} " in every.stderr, every.stderr
        assert L.lock_is_free(results / L.LOCK_NAME)
        assert L.lock_is_free(L.machine_lock_path(results, B))  # other machine: free all along
        go.write_text("go\n")
        code, out, err = _finish(first, line)
    finally:
        _kill(first)
    assert code == S.EXIT_OK, out + err
    assert "nothing new since" in out  # its own fast-path state, untouched by the other nights


def test_a_night_for_every_machine_holds_every_lock(parallel):
    proj, results = parallel["proj"], parallel["proj"] / "results"
    go = proj.parent / "go-every"
    every = _start(proj, go=go)
    try:
        line = _acquired(every)
        assert str(results / L.LOCK_NAME) in line
        for machine in (A, B):
            assert not L.lock_is_free(L.machine_lock_path(results, machine))
            assert f"pid={every.pid} " in _holder(results, machine)
        one = subprocess.run(
            [sys.executable, "-m", "rafi.cli", "nightly", "--machine", B, "--no-report"],
            cwd=proj,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert one.returncode == 75 and f"pid={every.pid} " in one.stderr, one.stderr
        go.write_text("go\n")
        code, out, err = _finish(every, line)
    finally:
        _kill(every)
    assert code == S.EXIT_OK, out + err
    assert "--nolock" not in out  # a night for every machine keeps Snakemake's lock
    assert (results / "input_check.json").exists() and (proj / "reports" / "index.html").exists()
    assert "===== rafi nightly" in (results / "nightly.log").read_text()


# --------------------------------------------------------------------------- the locks themselves


def _hold(path: Path) -> subprocess.Popen:
    """Another process holding the nightly lock ``path`` until killed."""
    code = (
        "import time; from rafi.ops.lock import NightlyLock\n"
        f"with NightlyLock({str(path)!r}):\n"
        "    print('locked', flush=True); time.sleep(120)\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, start_new_session=True
    )
    assert proc.stdout.readline().strip() == "locked"
    return proc


def test_night_locks_are_all_or_none(tmp_path):
    results = tmp_path / "results"
    holder = _hold(L.machine_lock_path(results, "m2"))
    try:
        with pytest.raises(L.LockHeld) as info:
            L.night_locks(results, ["m3", "m2", "m1"], every_machine=True)
        assert info.value.path == L.machine_lock_path(results, "m2")
        assert f"pid={holder.pid} " in info.value.holder
        # what it had taken before m2 (fleet lock, m1) is released; m3 was never taken
        for path in (
            results / L.LOCK_NAME,
            L.machine_lock_path(results, "m1"),
            L.machine_lock_path(results, "m3"),
        ):
            assert L.lock_is_free(path)
        assert L.holder_pids(results) == {holder.pid}
        # another machine's night is not held back
        with L.night_locks(results, ["m1", "m3"], every_machine=False):
            assert L.holder_pids(results) == {holder.pid, os.getpid()}
            assert L.lock_is_free(results / L.LOCK_NAME)
    finally:
        _kill(holder)
    # released locks are emptied; a killed holder's text stays (it names a process that is gone,
    # which no live process is: only live processes are checked against it) ...
    assert L.holder_pids(results) == {holder.pid}
    # ... and the kernel dropped its flock: the lock can be taken, and then names its new holder
    with L.night_locks(results, ["m1", "m2", "m3"], every_machine=True):
        assert not L.lock_is_free(L.machine_lock_path(results, "m2"))
        assert L.holder_pids(results) == {os.getpid()}


def test_a_job_of_another_night_is_coordinated():
    # real processes: a "night" (python) whose job is a shell running a script (sleep), and a
    # sleep someone started by hand (its parent: this test, not the night)
    night_code = "import subprocess; subprocess.run(['sh', '-c', 'sleep 60 & echo $!; wait'])\n"
    night = subprocess.Popen(
        [sys.executable, "-c", night_code], stdout=subprocess.PIPE, text=True, start_new_session=True
    )
    stranger = subprocess.Popen(["sleep", "60"], start_new_session=True)
    try:
        job = int(night.stdout.readline())
        assert L.coordinated_with(job, {night.pid}) and L.coordinated_with(night.pid, {night.pid})
        assert not L.coordinated_with(stranger.pid, {night.pid})
        assert not L.coordinated_with(job, set())
    finally:
        _kill(night, stranger)
