"""Machine-level quarantine (issue 12, item 9): a machine with no usable raw file is skipped and
reported, the other machines finish, and `rafi nightly` exits with 4 (input rejected), not 1.

Unit part: rafi.readers.quarantine (which machine is skipped, the run-level summary), the page of
a skipped machine (rafi.report.skipped) and the nightly status of a skipped machine, on summaries
written by the clean step's own functions. Slow part: the real Snakefile on a trimmed copy of
the shipped data plus a machine whose only raw files are two files of the bad-input corpus.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
from pathlib import Path

import pandas as pd
import pytest
from project_copy import copy_project, copy_settled, run_module, settle

from rafi.artefact import write_csv_atomic
from rafi.method.audit import quarantined, summarise_audit
from rafi.ops import nightly as N
from rafi.ops import status as S
from rafi.ops.project import Paths
from rafi.readers.quarantine import (
    SKIPPED,
    USABLE,
    input_check,
    is_skipped,
    machine_input_status,
    present_statuses,
    read_input_status,
    rejection_lines,
)
from rafi.report.skipped import skipped_page

ROOT = Path(__file__).resolve().parents[1]
BAD = ROOT / "tests" / "data" / "bad"
GOOD = "tapping-center-a"
BROKEN = "spindle-c"
KEEP = ("train_03000rpm", "train_09000rpm", "train_15000rpm", "valid_04500rpm", "multi_condition")
BAD_FILES = {"day1.csv": "text_in_numeric.csv", "day2.csv": "header_only.csv"}


# --------------------------------------------------------------------------- unit


def _summary(folder: Path, name: str, reason: str | None = None) -> Path:
    """The clean step's summary of one file: quarantined with ``reason``, or ok."""
    if reason is None:
        frame = summarise_audit(name, "ab" * 32, 3, pd.DataFrame({"segment": [0, 0, 1]}), pd.DataFrame())
    else:
        frame = quarantined(name, "cd" * 32, reason)[2]
    path = folder / f"{Path(name).stem}.summary.csv"
    write_csv_atomic(frame, path)
    return path


def test_a_machine_is_skipped_only_when_no_file_is_usable(tmp_path):
    bad = _summary(tmp_path, "bad.csv", "bad.csv, line 13, column 'T3': 'ERR' is not a number")
    worse = _summary(tmp_path, "worse.csv", "worse.csv, line 3: header found but no data rows")
    good = _summary(tmp_path, "good.csv")

    mixed = machine_input_status("m1", [bad, good])
    assert mixed["status"] == USABLE and not is_skipped(mixed)
    assert mixed["usable"] == ["good.csv"] and mixed["n_files"] == 2
    assert mixed["rejected"] == [
        {
            "file": "bad.csv",
            "sha256": "cd" * 32,
            "reason": "bad.csv, line 13, column 'T3': 'ERR' is not a number",
        }
    ]

    skipped = machine_input_status("m2", [bad, worse])
    assert skipped["status"] == SKIPPED and is_skipped(skipped)
    assert skipped["usable"] == [] and [f["file"] for f in skipped["rejected"]] == ["bad.csv", "worse.csv"]

    clean = machine_input_status("m3", [good])
    check = input_check([skipped, clean, mixed])
    assert check["input_rejected"] is True
    assert check["skipped_machines"] == ["m2"]
    assert [(f["machine"], f["file"]) for f in check["rejected_files"]] == [
        ("m1", "bad.csv"),
        ("m2", "bad.csv"),
        ("m2", "worse.csv"),
    ]
    assert check["machines"]["m2"] == {"status": SKIPPED, "n_files": 2, "n_rejected": 2}
    assert input_check([clean])["input_rejected"] is False

    lines = rejection_lines([clean, skipped, mixed])
    assert len(lines) == 2
    assert lines[0].startswith("m1: 1 of 2 raw file(s) quarantined") and "line 13" in lines[0]
    assert lines[1].startswith("m2: SKIPPED - no usable raw file (2 rejected)") and "no data rows" in lines[1]
    assert rejection_lines([clean]) == []


def test_input_status_files_round_trip_and_bad_ones_are_left_out(tmp_path):
    status = machine_input_status("m", [_summary(tmp_path, "bad.csv", "why")])
    path = tmp_path / "input_status.json"
    path.write_text(json.dumps(status), encoding="utf-8")
    assert read_input_status(path) == status
    (tmp_path / "other.json").write_text('{"status": "maybe"}', encoding="utf-8")
    with pytest.raises(ValueError, match="not a machine input status"):
        read_input_status(tmp_path / "other.json")
    assert present_statuses([path, tmp_path / "other.json", tmp_path / "missing.json"]) == [status]


def test_the_skipped_page_lists_every_rejected_file_escaped(tmp_path):
    status = machine_input_status(
        "m<1>",
        [
            _summary(tmp_path, "a.csv", "a.csv, line 4: <script>alert(1)</script> & more"),
            _summary(tmp_path, "b.csv", "b.csv: file is empty"),
        ],
    )
    page = skipped_page(status, created="2026-05-01T00:00:00Z", audit_path="results/m/audit.csv")
    assert page.startswith("<!DOCTYPE html>") and page.rstrip().endswith("</html>")
    assert "m&lt;1&gt;: skipped" in page and "<script>" not in page
    assert "&lt;script&gt;alert(1)&lt;/script&gt; &amp; more" in page
    assert "b.csv: file is empty" in page and "All 2 raw files were" in page
    assert page.count("<tr><td>") == 2 and "results/m/audit.csv" in page
    with pytest.raises(ValueError, match="not skipped"):
        skipped_page(machine_input_status("m", [_summary(tmp_path, "g.csv")]), created="now")


def _status_paths(tmp_path: Path, decision: dict | None, statuses: list[str]) -> Paths:
    paths = Paths(tmp_path, tmp_path / "raw", tmp_path / "results")
    reg = paths.registry("m1")
    reg.mkdir(parents=True)
    if decision is not None:
        (reg / "decision.json").write_text(json.dumps(decision))
    pd.DataFrame(
        {
            "file": [f"f{i}.csv" for i in range(len(statuses))],
            "status": statuses,
            "reason": ["" if s == "ok" else "stuck displacement" for s in statuses],
        }
    ).to_csv(paths.results_dir / "m1" / "audit.csv", index=False)
    return paths


@pytest.mark.parametrize(
    "decision, statuses, skipped, expected",
    [
        # every file quarantined: skipped, input rejected (4); a decision is an earlier night's,
        # its rejection is not counted again; a champion that drifted is still due (3)
        (None, ["quarantined"], True, {4}),
        (
            {"decision": "rejected", "champion_id_after": "c" * 64, "time": "2026-05-01T00:00:00Z"},
            2 * ["quarantined"],
            True,
            {4},
        ),
        (
            {"decision": "kept", "recalibration_due": True, "time": "2026-05-01T00:00:00Z"},
            ["quarantined"],
            True,
            {3, 4},
        ),
        # one usable file: not skipped
        ({"decision": "rejected", "time": "2026-05-01T00:00:00Z"}, ["ok", "quarantined"], False, {2, 4}),
        ({"decision": "promoted", "time": "2026-05-01T00:00:00Z"}, ["ok"], False, set()),
    ],
)
def test_nightly_status_of_a_skipped_machine(tmp_path, decision, statuses, skipped, expected):
    paths = _status_paths(tmp_path, decision, statuses)
    st = S.machine_status(paths, "m1", S.parse_time("2026-05-01T00:00:00Z"))
    assert st.skipped is skipped
    assert st.codes() == expected
    line = st.line()
    assert ("SKIPPED" in line) is skipped
    if skipped:
        assert "f0.csv (stuck displacement)" in line
        champion = (decision or {}).get("champion_id_after")
        assert (f"champion {champion[:12]} stays" if champion else "no model in service") in line


def test_nightly_summary_line_and_exit_code(tmp_path, capsys):
    paths = _status_paths(tmp_path, None, ["quarantined"])
    code = N._report([S.machine_status(paths, "m1", None)])
    out = capsys.readouterr().out
    assert code == S.EXIT_QUARANTINED == 4
    assert "m1: SKIPPED" in out and "INPUT REJECTED: 1 raw file(s) quarantined, machine(s) skipped: m1" in out
    assert N._report([S.machine_status(paths, "m1", None)], pipeline_failed=True) == S.EXIT_PIPELINE_FAILED


# --------------------------------------------------------------------------- the real workflow


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _nightly(proj: Path) -> subprocess.CompletedProcess:
    return run_module(proj, "rafi.cli", "nightly", "--directory", str(proj), "--cores", "2", "--no-report")


@pytest.fixture
def project(tmp_path: Path) -> Path:
    """Two machines: GOOD (a trimmed copy of the shipped logs), BROKEN (two bad files only)."""
    proj = copy_project(tmp_path / "proj")
    (proj / "raw" / GOOD).mkdir(parents=True)
    for stem in KEEP:
        copy_settled(ROOT / "raw" / GOOD / f"{stem}.csv", proj / "raw" / GOOD / f"{stem}.csv")
    (proj / "raw" / BROKEN).mkdir()
    for name, source in BAD_FILES.items():
        copy_settled(BAD / source, proj / "raw" / BROKEN / name)
    return proj


@pytest.mark.slow
def test_a_machine_without_a_usable_file_is_skipped_and_the_others_finish(project: Path):
    res, rep = project / "results", project / "reports"
    raw_before = {p: _sha(p) for p in (project / "raw" / BROKEN).iterdir()}

    # a plain quarantine run: the good machine gets its report, the broken one its page, and
    # the end of the run says that input was rejected
    first = run_module(project, "snakemake", "--cores", "2", "--config", "on_bad_input=quarantine")
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr[-3000:]
    assert (rep / GOOD / "qualification.html").is_file()
    assert json.loads((res / GOOD / "registry" / "decision.json").read_text())["decision"] == "promoted"
    status = json.loads((res / BROKEN / "input_status.json").read_text())
    assert status["status"] == "skipped" and status["usable"] == []
    reasons = {f["file"]: f["reason"] for f in status["rejected"]}
    assert set(reasons) == set(BAD_FILES)
    assert "line 13, column 'T3'" in reasons["day1.csv"] and "no data rows" in reasons["day2.csv"]
    page = (rep / BROKEN / "skipped.html").read_text()
    assert f"{BROKEN}: skipped" in page and "day1.csv" in page and "day2.csv" in page
    assert not (rep / BROKEN / "qualification.html").exists()
    for absent in ("runs.csv", "model.json", "registry"):
        assert not (res / BROKEN / absent).exists(), absent
    audit = pd.read_csv(res / BROKEN / "audit.csv")
    assert set(audit["status"]) == {"quarantined"}
    check = json.loads((res / "input_check.json").read_text())
    assert check["input_rejected"] and check["skipped_machines"] == [BROKEN]
    assert check["machines"][GOOD] == {"status": "usable", "n_files": len(KEEP), "n_rejected": 0}
    said = first.stdout + first.stderr
    assert "INPUT WAS REJECTED" in said and f"{BROKEN}: SKIPPED - no usable raw file (2 rejected)" in said
    assert {p: _sha(p) for p in raw_before} == raw_before

    # nothing to do afterwards; the interactive (fail) mode still refuses the quarantined files
    dry = run_module(project, "snakemake", "--cores", "2", "-n", "--config", "on_bad_input=quarantine")
    assert "Nothing to be done" in dry.stdout + dry.stderr, dry.stdout[-3000:] + dry.stderr[-3000:]
    strict = run_module(project, "snakemake", "--cores", "2", "-n")
    assert strict.returncode != 0 and "2 raw file(s) cannot be used" in strict.stdout + strict.stderr

    # rafi nightly: nothing new, but input is rejected: exit 4, the broken machine named
    night = _nightly(project)
    assert night.returncode == S.EXIT_QUARANTINED == 4, night.stdout + night.stderr
    assert f"{BROKEN}: SKIPPED - no usable raw file" in night.stdout and "no model in service" in night.stdout
    assert f"machine(s) skipped: {BROKEN}" in night.stdout
    assert not (res / BROKEN / "registry").exists()

    # usable logs arrive for the broken machine: it is processed, its page goes away
    # (their metadata names the broken machine: a file naming another machine is a warning that
    # blocks promotion, issue 13 check metadata_machine)
    for stem in KEEP:
        text = (project / "raw" / GOOD / f"{stem}.csv").read_text(encoding="utf-8")
        text = text.replace(f"# machine: {GOOD}", f"# machine: {BROKEN}")
        (project / "raw" / BROKEN / f"{stem}.csv").write_text(text, encoding="utf-8")
        settle(project / "raw" / BROKEN / f"{stem}.csv")
    night = _nightly(project)
    assert night.returncode == S.EXIT_QUARANTINED, night.stdout + night.stderr  # day1/day2 still bad
    reg = res / BROKEN / "registry"
    assert json.loads((reg / "decision.json").read_text())["decision"] == "promoted"
    assert json.loads((res / BROKEN / "input_status.json").read_text())["status"] == "usable"
    assert not (rep / BROKEN / "skipped.html").exists()
    assert "SKIPPED" not in night.stdout and "machine(s) skipped" not in night.stdout

    # ... and are taken away again: skipped, and nothing in its registry moves
    registry_before = {p.name: _sha(p) for p in reg.rglob("*") if p.is_file()}
    champion = json.loads((reg / "champion.json").read_text())["model_id"]
    for stem in KEEP:
        (project / "raw" / BROKEN / f"{stem}.csv").unlink()
    night = _nightly(project)
    assert night.returncode == S.EXIT_QUARANTINED, night.stdout + night.stderr
    assert f"{BROKEN}: SKIPPED" in night.stdout and f"champion {champion[:12]} stays" in night.stdout
    assert {p.name: _sha(p) for p in reg.rglob("*") if p.is_file()} == registry_before
    assert (rep / BROKEN / "skipped.html").is_file()
    again = run_module(
        project,
        "snakemake",
        "-n",
        "--config",
        "on_bad_input=quarantine",
        "nightly_report=false",
        "--",
        "nightly",
    )
    assert "Nothing to be done" in again.stdout + again.stderr, again.stdout[-3000:] + again.stderr[-3000:]


@pytest.mark.slow
def test_fail_mode_still_stops_at_the_bad_file(project: Path):
    run = run_module(project, "snakemake", "--cores", "2")
    assert run.returncode != 0
    said = run.stdout + run.stderr
    # the first bad file a job reads stops the run (which one depends on the job order)
    assert "day1.csv, line 13, column 'T3'" in said or "day2.csv, line 3: header found but no data" in said
    assert not (project / "results" / BROKEN / "input_status.json").exists()
    assert not (project / "reports" / BROKEN / "skipped.html").exists()
