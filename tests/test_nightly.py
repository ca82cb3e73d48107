"""Tests of `rafi nightly`: the lock, exit codes, progress parsing, and (slow) two nights of
the real pipeline on a trimmed copy of the shipped data.

Unit part: a tiny fake project (a Snakefile whose `nightly` target is up to date or fails),
so the lock and the exit paths are tested in seconds without the pipeline.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from rafi.ops import nightly as N

ROOT = Path(__file__).resolve().parents[1]
MACHINE = "tapping-center-a"


def rafi_cmd(*args):
    return [sys.executable, "-m", "rafi.cli", *args]


def fake_project(tmp_path: Path, *, fail: bool = False) -> Path:
    d = tmp_path / "proj"
    (d / "raw" / "m1").mkdir(parents=True)
    (d / "raw" / "m1" / "x.csv").write_text("time\n")
    (d / "config.yaml").write_text("raw_dir: raw\nresults_dir: results\nreports_dir: reports\n")
    (d / "done.txt").write_text("ok\n")
    if fail:
        (d / "Snakefile").write_text(
            "rule nightly:\n    input: 'out.txt'\nrule make:\n    output: 'out.txt'\n    shell: 'exit 3'\n"
        )
    else:
        (d / "Snakefile").write_text("rule nightly:\n    input: 'done.txt'\n")
    return d


def no_partial_files(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.name.endswith(".part")]


# --------------------------------------------------------------------------- lock


def test_lock_is_released_on_exception(tmp_path):
    path = tmp_path / "results" / ".nightly.lock"
    with pytest.raises(RuntimeError, match="boom"):
        with N.NightlyLock(path):
            assert not N.lock_is_free(path)
            assert re.match(r"pid=\d+ started=\S+Z host=", path.read_text())
            raise RuntimeError("boom")
    assert N.lock_is_free(path)
    assert path.read_text() == ""


def test_lock_held_by_another_process_names_the_holder(tmp_path):
    path = tmp_path / ".nightly.lock"
    code = (
        "import sys, time; from rafi.ops.nightly import NightlyLock\n"
        f"with NightlyLock({str(path)!r}):\n"
        "    print('locked', flush=True); time.sleep(30)\n"
    )
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(N.LockHeld) as info:
            with N.NightlyLock(path):
                pass  # pragma: no cover
        assert f"pid={holder.pid}" in info.value.holder
    finally:
        holder.kill()
        holder.wait()
    # the kernel drops the flock of a killed process: no stale lock
    assert N.lock_is_free(path)
    with N.NightlyLock(path):
        pass


def test_two_nightly_commands_one_runs_the_other_refuses(tmp_path):
    proj = fake_project(tmp_path)
    env = {**os.environ, N.HOLD_ENV: "4"}
    first = subprocess.Popen(
        rafi_cmd("nightly", "--directory", str(proj)),
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        line = first.stdout.readline()
        assert "acquired" in line, line
        second = subprocess.run(
            rafi_cmd("nightly", "--directory", str(proj)), capture_output=True, text=True, timeout=60
        )
        assert second.returncode == N.EXIT_LOCKED == 75
        assert "another nightly run is in progress" in second.stderr
        assert f"pid={first.pid}" in second.stderr
        out, err = first.communicate(timeout=120)
    finally:
        if first.poll() is None:
            first.kill()
    assert first.returncode == 0, err
    assert "nothing new since" in out
    lock = proj / "results" / N.LOCK_NAME
    assert N.lock_is_free(lock) and lock.read_text() == ""
    assert not no_partial_files(proj)


def test_failed_pipeline_exits_1_and_frees_the_lock(tmp_path):
    proj = fake_project(tmp_path, fail=True)
    res = subprocess.run(
        rafi_cmd("nightly", "--directory", str(proj), "--cores", "1"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == N.EXIT_PIPELINE_FAILED, res.stdout + res.stderr
    assert "FAILED" in res.stdout
    assert N.lock_is_free(proj / "results" / N.LOCK_NAME)


def test_nothing_to_do_is_quick(tmp_path):
    proj = fake_project(tmp_path)
    t0 = time.perf_counter()
    res = subprocess.run(
        rafi_cmd("nightly", "--directory", str(proj)), capture_output=True, text=True, timeout=60
    )
    elapsed = time.perf_counter() - t0
    assert res.returncode == 0, res.stderr
    assert "nothing new since the first run" in res.stdout
    assert elapsed < 10
    # the next night takes the fingerprint fast path (no Snakemake at all) ...
    assert (proj / "results" / N.STATE_NAME).exists()
    t0 = time.perf_counter()
    res = subprocess.run(
        rafi_cmd("nightly", "--directory", str(proj)), capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 0 and "nothing new since" in res.stdout
    assert time.perf_counter() - t0 < 5
    # ... until anything it covers changes: a new raw file makes Snakemake decide again
    (proj / "raw" / "m1" / "y.csv").write_text("time\n")
    assert (
        N.fingerprint(N.argparse.Namespace(config_file="config.yaml"), N.Paths.from_config(proj, {}), {})
        != json.loads((proj / "results" / N.STATE_NAME).read_text())["fingerprint"]
    )


def test_unknown_machine_is_a_usage_error(tmp_path):
    proj = fake_project(tmp_path)
    res = subprocess.run(
        rafi_cmd("nightly", "--directory", str(proj), "--machine", "nope"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == N.EXIT_USAGE


# --------------------------------------------------------------------------- exit codes


def test_severity_order():
    assert N.most_severe([]) == 0
    assert N.most_severe([4, 2]) == 2
    assert N.most_severe([4, 2, 3]) == 3
    assert N.most_severe([3, 1, 4]) == 1


def _status_dir(tmp_path, decision, audit_status="ok"):
    paths = N.Paths(tmp_path, tmp_path / "raw", tmp_path / "results")
    reg = paths.registry("m1")
    reg.mkdir(parents=True)
    (reg / "decision.json").write_text(json.dumps(decision))
    pd.DataFrame({"file": ["a.csv"], "status": [audit_status], "reason": ["stuck displacement"]}).to_csv(
        paths.results_dir / "m1" / "audit.csv", index=False
    )
    return paths


@pytest.mark.parametrize(
    "decision, audit, tonight, expected",
    [
        ({"decision": "promoted", "time": "2026-05-01T00:00:00Z"}, "ok", True, set()),
        ({"decision": "rejected", "time": "2026-05-01T00:00:00Z"}, "ok", True, {2}),
        ({"decision": "rejected", "time": "2026-05-01T00:00:00Z"}, "ok", False, set()),
        (
            {
                "decision": "kept",
                "recalibration_due": True,
                "time": "2026-05-01T00:00:00Z",
                "drift": {"new_max_residual_um": 9, "reference_max_residual_um": 5},
            },
            "ok",
            False,
            {3},
        ),
        ({"decision": "promoted", "time": "2026-05-01T00:00:00Z"}, "quarantined", True, {4}),
    ],
)
def test_machine_status_codes(tmp_path, decision, audit, tonight, expected):
    paths = _status_dir(tmp_path, decision, audit)
    start = N._parse_time("2026-05-01T00:00:00Z") if tonight else N._parse_time("2026-06-01T00:00:00Z")
    st = N.machine_status(paths, "m1", start)
    assert st.tonight == tonight
    assert st.codes() == expected
    assert st.line().startswith("m1: ")


def test_job_tracker_one_line_per_job():
    import io

    out = io.StringIO()
    tr = N.JobTracker(out=out)
    log = """
[Sat Nov 21 09:17:07 2026]
rule clean:
    input: raw/m/a.csv
    output: results/m/clean/a.parquet
    jobid: 7
    reason: Missing output files
    wildcards: machine=m, stem=a
    resources: tmpdir=/tmp
[Sat Nov 21 09:17:08 2026]
Finished jobid: 7 (Rule: clean)
1 of 3 steps (33%) done
localrule nightly:
    jobid: 0
Finished jobid: 0 (Rule: nightly)
Error in rule fit:
"""
    for line in log.splitlines():
        tr.feed(line + "\n")
    assert tr.ran == [("clean", "machine=m, stem=a")]
    assert tr.failed == ["fit"]
    text = out.getvalue()
    assert "done clean (machine=m, stem=a)" in text and "FAILED fit" in text


# --------------------------------------------------------------------------- integration


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _setup_project(tmp_path: Path) -> Path:
    proj = tmp_path / "proj"
    proj.mkdir()
    shutil.copytree(ROOT / "workflow", proj / "workflow")
    shutil.copy(ROOT / "config.yaml", proj / "config.yaml")
    snakefile = (ROOT / "Snakefile").read_text()
    if "registry.smk" not in snakefile and '"*.smk"' not in snakefile:  # until the lead adds the include line
        snakefile += '\n\ninclude: "workflow/rules/registry.smk"\n'
    (proj / "Snakefile").write_text(snakefile)
    raw = proj / "raw" / MACHINE
    raw.mkdir(parents=True)
    files = sorted((ROOT / "raw" / MACHINE).glob("*.csv"))
    keep = [
        f
        for f in files
        if re.search(r"(train|trn).*(3000|9000|15000)|valid.*(4500|13500)|multi", f.name, re.I)
    ]
    for f in keep or files:
        shutil.copy2(f, raw / f.name)
    return proj


def _nightly(proj: Path, *extra, env=None) -> subprocess.CompletedProcess:
    # --no-report keeps the test within its time budget (the report has its own tests)
    return subprocess.run(
        rafi_cmd("nightly", "--directory", str(proj), "--cores", "2", "--no-report", *extra),
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )


@pytest.mark.slow
def test_two_nights_on_the_pipeline(tmp_path):
    proj = _setup_project(tmp_path)
    res_dir = proj / "results" / MACHINE
    reg = res_dir / "registry"

    # night 1: everything runs, the first model is promoted
    n1 = _nightly(proj)
    assert n1.returncode in (0, 4), n1.stdout + n1.stderr
    d1 = json.loads((reg / "decision.json").read_text())
    assert d1["decision"] == "promoted", d1["reasons"]
    first_id = d1["candidate_id"]
    first_file = reg / "models" / f"{first_id}.json"
    first_hash = _sha(first_file)
    assert json.loads((reg / "champion.json").read_text())["model_id"] == first_id

    # a dry run right after has nothing to do; so does a second night
    dry = subprocess.run(
        [
            sys.executable,
            "-m",
            "snakemake",
            "-n",
            "--directory",
            str(proj),
            "--config",
            "on_bad_input=quarantine",
            "nightly_report=false",
            "--",
            "nightly",
        ],
        capture_output=True,
        text=True,
        cwd=proj,
    )
    assert "Nothing to be done" in dry.stdout + dry.stderr, dry.stdout + dry.stderr
    n1b = _nightly(proj)
    assert "nothing new since" in n1b.stdout

    # night 2: a new day of logs (ambient shifted, some wear)
    clean_before = {p.name: p.stat().st_mtime_ns for p in (res_dir / "clean").glob("*.parquet")}
    sim = subprocess.run(
        rafi_cmd(
            "simulate",
            "day",
            "--machine",
            MACHINE,
            "--out",
            str(proj / "raw"),
            "--seed",
            "7",
            "--ambient-shift",
            "3",
            "--wear",
            "0.3",
        ),
        capture_output=True,
        text=True,
        cwd=proj,
    )
    assert sim.returncode == 0, sim.stderr
    new_files = {p.stem for p in (proj / "raw" / MACHINE).glob("*.csv")} - {
        Path(n).stem for n in clean_before
    }
    assert new_files
    n2 = _nightly(proj)
    assert n2.returncode in (0, 2, 3, 4), n2.stdout + n2.stderr
    ran_clean = re.findall(r"done clean \(machine=[^,]+, stem=([^)]+)\)", n2.stdout)
    assert set(ran_clean) == new_files, n2.stdout
    for name, mtime in clean_before.items():
        assert (res_dir / "clean" / name).stat().st_mtime_ns == mtime
    d2 = json.loads((reg / "decision.json").read_text())
    assert d2["champion_id_before"] == first_id and d2["candidate_id"] != first_id
    assert len(list((reg / "models").glob("*.meta.json"))) == 2
    assert _sha(first_file) == first_hash
    hist = [json.loads(line) for line in (reg / "history.jsonl").read_text().splitlines()]
    assert [h["decision"] for h in hist][-1] == d2["decision"] and hist[-1]["reasons"]
    assert (reg / "comparison.csv").exists()

    # a broken training log (stuck displacement channel): rejected or quarantined, champion stays
    champion_before = json.loads((reg / "champion.json").read_text())["model_id"]
    sim = subprocess.run(
        rafi_cmd(
            "simulate",
            "day",
            "--machine",
            MACHINE,
            "--out",
            str(proj / "raw"),
            "--seed",
            "8",
            "--stuck-displacement",
        ),
        capture_output=True,
        text=True,
        cwd=proj,
    )
    assert sim.returncode == 0, sim.stderr
    # ... and, the same night, a file the reader cannot parse (issue 6: quarantine, carry on)
    broken = proj / "raw" / MACHINE / "2026-04-20_broken.csv"
    shutil.copy(ROOT / "tests" / "data" / "bad" / "text_in_numeric.csv", broken)
    broken_hash = _sha(broken)
    n3 = _nightly(proj)
    assert n3.returncode == N.EXIT_QUARANTINED, n3.stdout + n3.stderr
    d3 = json.loads((reg / "decision.json").read_text())
    assert json.loads((reg / "champion.json").read_text())["model_id"] == champion_before
    assert d3["decision"] in ("rejected", "kept")
    audit = pd.read_csv(res_dir / "audit.csv").set_index("file")
    stuck = [f for f in audit.index if "_s8_" in f]
    assert stuck and (audit.loc[stuck, "status"] == "quarantined").all()
    assert audit.loc[stuck, "reason"].str.contains("stuck").all()
    assert audit.loc[broken.name, "status"] == "quarantined"
    assert "line 13" in audit.loc[broken.name, "reason"]
    assert _sha(broken) == broken_hash  # raw files are never modified

    # two nightly commands at once: one runs, the other refuses
    procs = [
        subprocess.Popen(
            rafi_cmd("nightly", "--directory", str(proj), "--no-report"),
            env={**os.environ, N.HOLD_ENV: "3"},
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(2)
    ]
    codes = sorted(p.wait(timeout=300) for p in procs)
    assert N.EXIT_LOCKED in codes and codes.count(N.EXIT_LOCKED) == 1
    assert N.lock_is_free(proj / "results" / N.LOCK_NAME)
    assert not no_partial_files(proj / "results")
