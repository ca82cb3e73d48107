"""Tests of `rafi nightly`: the lock, exit codes, progress from Snakemake's structured log records,
and (slow) two nights of the real pipeline on a trimmed copy of the shipped data.

Unit part: a tiny fake project (a Snakefile whose `nightly` target is up to date or fails),
so the lock and the exit paths are tested in seconds without the pipeline.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import logging
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from rafi.errors import LockHeld
from rafi.ops import nightly as N
from rafi.ops import snakemake_api
from rafi.ops import status as S
from rafi.ops.lock import LOCK_NAME, NightlyLock, lock_is_free
from rafi.ops.project import Paths
from rafi.ops.state import STATE_NAME, fingerprint

ROOT = Path(__file__).resolve().parents[1]
MACHINE = "tapping-center-a"


def rafi_cmd(*args):
    return [sys.executable, "-m", "rafi.cli", *args]


def fake_project(tmp_path: Path, *, fail: bool = False) -> Path:
    d = tmp_path / "proj"
    (d / "raw" / "m1").mkdir(parents=True)
    (d / "raw" / "m1" / "x.csv").write_text("time\n")
    day_old = time.time() - 86_400  # settled: older than nightly_settle_s (600 s by default)
    os.utime(d / "raw" / "m1" / "x.csv", (day_old, day_old))
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
        with NightlyLock(path):
            assert not lock_is_free(path)
            assert re.match(r"pid=\d+ started=\S+Z host=", path.read_text())
            raise RuntimeError("boom")
    assert lock_is_free(path)
    assert path.read_text() == ""


def test_lock_held_by_another_process_names_the_holder(tmp_path):
    path = tmp_path / ".nightly.lock"
    code = (
        "import sys, time; from rafi.ops.lock import NightlyLock\n"
        f"with NightlyLock({str(path)!r}):\n"
        "    print('locked', flush=True); time.sleep(30)\n"
    )
    holder = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(LockHeld) as info:
            with NightlyLock(path):
                pass  # pragma: no cover
        assert f"pid={holder.pid}" in info.value.holder
    finally:
        holder.kill()
        holder.wait()
    # the kernel drops the flock of a killed process: no stale lock
    assert lock_is_free(path)
    with NightlyLock(path):
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
        assert second.returncode == S.EXIT_LOCKED == 75
        assert "another nightly run is in progress" in second.stderr
        assert f"pid={first.pid}" in second.stderr
        out, err = first.communicate(timeout=120)
    finally:
        if first.poll() is None:
            first.kill()
    assert first.returncode == 0, err
    assert "nothing new since" in out
    lock = proj / "results" / LOCK_NAME
    assert lock_is_free(lock) and lock.read_text() == ""
    assert not no_partial_files(proj)


def test_failed_pipeline_exits_1_and_frees_the_lock(tmp_path):
    proj = fake_project(tmp_path, fail=True)
    res = subprocess.run(
        rafi_cmd("nightly", "--directory", str(proj), "--cores", "1"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == S.EXIT_PIPELINE_FAILED, res.stdout + res.stderr
    assert "FAILED" in res.stdout
    assert lock_is_free(proj / "results" / LOCK_NAME)


def test_nothing_to_do_takes_the_fast_path(tmp_path):
    # how long it takes is measured by benchmarks/bench_nightly.py, not here
    proj = fake_project(tmp_path)
    res = subprocess.run(
        rafi_cmd("nightly", "--directory", str(proj)), capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 0, res.stderr
    assert "nothing new since the first run" in res.stdout
    # the next night takes the fingerprint fast path (no Snakemake at all) ...
    assert (proj / "results" / STATE_NAME).exists()
    res = subprocess.run(
        rafi_cmd("nightly", "--directory", str(proj)), capture_output=True, text=True, timeout=60
    )
    assert res.returncode == 0 and "nothing new since" in res.stdout
    # ... until anything it covers changes: a new raw file makes Snakemake decide again
    stored = json.loads((proj / "results" / STATE_NAME).read_text())["fingerprint"]
    overrides = N.config_overrides(argparse.Namespace(machine=None, no_report=False))
    assert fingerprint("config.yaml", Paths.from_config(proj, {}), overrides) == stored
    (proj / "raw" / "m1" / "y.csv").write_text("time\n")
    assert fingerprint("config.yaml", Paths.from_config(proj, {}), overrides) != stored


def test_unknown_machine_is_a_usage_error(tmp_path):
    proj = fake_project(tmp_path)
    res = subprocess.run(
        rafi_cmd("nightly", "--directory", str(proj), "--machine", "nope"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert res.returncode == S.EXIT_USAGE


# --------------------------------------------------------------------------- exit codes


def test_severity_order():
    assert S.most_severe([]) == 0
    assert S.most_severe([4, 2]) == 2
    assert S.most_severe([4, 2, 3]) == 3
    assert S.most_severe([3, 1, 4]) == 1


def _status_dir(tmp_path, decision, audit_status="ok"):
    paths = Paths(tmp_path, tmp_path / "raw", tmp_path / "results")
    reg = paths.registry("m1")
    reg.mkdir(parents=True)
    (reg / "decision.json").write_text(json.dumps(decision))
    pd.DataFrame({"file": ["a.csv"], "status": [audit_status], "reason": ["stuck displacement"]}).to_csv(
        paths.results_dir / "m1" / "audit.csv", index=False
    )
    return paths


def test_machine_level_rejection_counts_as_rejected_input(tmp_path):
    """A byte-identical copy rejected in input_status.json (clean read it: audit says ok) is named in
    the nightly line and gives exit 4, like a quarantined file."""
    paths = _status_dir(tmp_path, {"decision": "kept", "time": "2026-05-01T00:00:00Z"})
    status = {
        "rejected": [{"file": "a.csv", "check": "duplicate_content", "reason": "byte-identical to b.csv"}]
    }
    (paths.results_dir / "m1" / "input_status.json").write_text(json.dumps(status))
    st = S.machine_status(paths, "m1", None)
    assert st.quarantined == ["a.csv (byte-identical to b.csv)"]
    assert 4 in st.codes() and "a.csv" in st.line()


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
    start = S.parse_time("2026-05-01T00:00:00Z") if tonight else S.parse_time("2026-06-01T00:00:00Z")
    st = S.machine_status(paths, "m1", start)
    assert st.tonight == tonight
    assert st.codes() == expected
    assert st.line().startswith("m1: ")


def _record(**fields) -> logging.LogRecord:
    record = logging.LogRecord("snakemake.logging", logging.INFO, __file__, 0, None, None, None)
    record.__dict__.update(fields)
    return record


def test_progress_handler_one_line_per_job():
    """Progress comes from the records' structured fields (LogEvent and its documented fields)."""
    from snakemake_interface_logger_plugins.common import LogEvent

    out = io.StringIO()
    tr = snakemake_api.ProgressHandler(out=out)
    for rec in [
        _record(event=LogEvent.RUN_INFO, stats={"clean": 1, "fit": 1, "nightly": 1, "total": 3}),
        _record(event=LogEvent.JOB_INFO, jobid=7, rule_name="clean", wildcards={"machine": "m", "stem": "a"}),
        _record(event=LogEvent.JOB_FINISHED, job_id=7),
        _record(event=LogEvent.PROGRESS, done=1, total=3),
        _record(event=LogEvent.JOB_INFO, jobid=0, rule_name="nightly", wildcards={}),
        _record(event=LogEvent.JOB_FINISHED, job_id=0),
        _record(event=LogEvent.JOB_ERROR, jobid=3, rule_name="fit"),
        _record(event=LogEvent.JOB_ERROR, jobid=3, rule_name="fit"),
        _record(msg="Finished jobid: 9 (Rule: report)"),  # printed text is not read
    ]:
        tr.handle(rec)
    assert tr.outcome.ran == [("clean", "machine=m, stem=a")]
    assert tr.outcome.failed == ["fit"]
    assert tr.outcome.planned == {"clean": 1} and tr.outcome.target_scheduled
    text = out.getvalue()
    assert "[1/2] done clean (machine=m, stem=a)" in text and "FAILED fit" in text
    assert "done nightly" not in text and text.count("FAILED fit") == 1


def _two_job_project(tmp_path: Path) -> Path:
    proj = fake_project(tmp_path)
    (proj / "Snakefile").write_text(
        "rule nightly:\n    input: expand('out/{n}.txt', n=['a', 'b'])\n"
        "rule make:\n    output: 'out/{n}.txt'\n    shell: 'echo {wildcards.n} > {output}'\n"
    )
    return proj


def test_progress_and_dry_run_through_the_api(tmp_path):
    """Jobs done/total and the dry-run plan from the installed Snakemake (run on both ends of
    the supported range: .ci/lower-bound.sh)."""
    proj = _two_job_project(tmp_path)
    dry = subprocess.run(
        rafi_cmd("nightly", "--directory", str(proj), "--dry-run"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert dry.returncode == 0, dry.stdout + dry.stderr
    assert "would run make x2" in dry.stdout
    assert not (proj / "out").exists()
    res = subprocess.run(
        rafi_cmd("nightly", "--directory", str(proj), "--cores", "1"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == 0, res.stdout + res.stderr
    done = re.findall(r"\[(\d)/(\d)\] done make \(n=([ab])\)", res.stdout)
    assert [d[:2] for d in done] == [("1", "2"), ("2", "2")] and sorted(d[2] for d in done) == ["a", "b"]
    assert "2 job(s) in" in res.stdout and "m1: no decision yet" in res.stdout
    # Snakemake's own output goes to the log, not to the console
    log = (proj / "results" / "nightly.log").read_text()
    assert "Finished jobid" in log and "Finished jobid" not in res.stdout + res.stderr


def test_planning_error_exits_1_and_says_why(tmp_path):
    proj = fake_project(tmp_path)
    (proj / "Snakefile").write_text("rule nightly:\n    input: 'missing.txt'\n")
    res = subprocess.run(
        rafi_cmd("nightly", "--directory", str(proj), "--cores", "1"),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert res.returncode == S.EXIT_PIPELINE_FAILED, res.stdout + res.stderr
    assert "cannot be planned" in res.stderr and "missing.txt" in res.stderr
    assert not (proj / "results" / STATE_NAME).exists()
    assert lock_is_free(proj / "results" / LOCK_NAME)


# --------------------------------------------------------------------------- integration


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _setup_project(tmp_path: Path) -> Path:
    proj = tmp_path / "proj"
    proj.mkdir()
    shutil.copytree(ROOT / "workflow", proj / "workflow")
    shutil.copy(ROOT / "config.yaml", proj / "config.yaml")
    with open(proj / "config.yaml", "a", encoding="utf-8") as fh:
        fh.write("\nnightly_settle_s: 0  # the test writes logs and runs the night at once\n")
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
    # one clean job for the machine (Snakemake re-runs it): every file is cleaned again, the new
    # ones among them
    assert re.findall(r"done clean \(machine=([^,)]+)\)", n2.stdout) == [MACHINE], n2.stdout
    clean_log = (proj / "logs" / MACHINE / "clean.log").read_text(encoding="utf-8")
    ran_clean = re.findall(r"^(\S+): (?:ok|quarantined)$", clean_log, flags=re.M)
    assert set(ran_clean) == new_files | {Path(n).stem for n in clean_before}, clean_log
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
    assert n3.returncode == S.EXIT_QUARANTINED, n3.stdout + n3.stderr
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
    assert S.EXIT_LOCKED in codes and codes.count(S.EXIT_LOCKED) == 1
    assert lock_is_free(proj / "results" / LOCK_NAME)
    assert not no_partial_files(proj / "results")


def test_debug_reaches_the_pipeline_only_when_asked():
    args = argparse.Namespace(machine=None, no_report=True, debug=False)
    assert "debug" not in N.config_overrides(args, {})
    args.debug = True
    assert N.config_overrides(args, {})["debug"] == "true"
