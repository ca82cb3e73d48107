"""Machine-level checks (rafi.readers.checks_machine) and their plumbing through the workflow.

Unit part: duplicates, probe sign against the configured sign or the machine's other files,
confirmed warnings, on summaries and audits written by the clean step's own functions. Slow part:
the real Snakefile on a trimmed copy of the shipped data with one warned file (a reversed probe)
and one byte-identical copy: input_status.json lists both, runs.csv does not hold the copy.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pandas as pd
import pytest
from project_copy import copy_project, run_module

from rafi.artefact import write_csv_atomic
from rafi.method.audit import quarantined, summarise_audit, warning_rows, with_warnings
from rafi.readers.checks_base import CheckWarning
from rafi.readers.checks_machine import (
    apply_machine_checks,
    audit_warnings,
    duplicate_rejections,
    is_confirmed,
    listed_warnings,
    probe_sign_findings,
    read_rows,
    warning_lines,
)
from rafi.readers.quarantine import input_check, machine_input_status, rejection_lines

ROOT = Path(__file__).resolve().parents[1]
A = "tapping-center-a"


# --------------------------------------------------------------------------- unit


def _file(folder: Path, name: str, *, sha: str, sign: int = 1, warnings=(), reason=None):
    """Summary and audit of one file, written as the clean step writes them."""
    stem = Path(name).stem
    if reason is not None:
        clean, actions, summary = quarantined(name, sha, reason)
    else:
        actions = with_warnings(pd.DataFrame(columns=["file", "action"]), warning_rows(name, warnings))
        summary = summarise_audit(
            name, sha, 3, pd.DataFrame({"segment": [0, 0, 0]}), actions, probe_sign=sign
        )
    write_csv_atomic(summary, folder / f"{stem}.summary.csv")
    write_csv_atomic(actions, folder / f"{stem}.audit.csv")
    return folder / f"{stem}.summary.csv", folder / f"{stem}.audit.csv"


def _status(folder: Path, files: list[tuple[Path, Path]], **kw) -> dict:
    summaries = [s for s, _ in files]
    base = machine_input_status("m", summaries)
    rows = [r for s in summaries for r in read_rows(s)]
    warnings = [w for _, a in files for w in audit_warnings(read_rows(a))]
    return apply_machine_checks(base, rows, warnings, **kw)


def test_summary_and_audit_record_warnings_and_probe_sign(tmp_path):
    w = CheckWarning("speed_range", "speed_rpm", "speed_rpm reaches 50000 r/min", 7, 900)
    summary, audit = _file(tmp_path, "a.csv", sha="a" * 64, sign=-1, warnings=[w, CheckWarning("x", "", "m")])
    row = pd.read_csv(summary).iloc[0]
    assert row["warnings"] == 2 and row["probe_sign"] == -1 and row["status"] == "ok"
    rows = pd.read_csv(audit, keep_default_na=False)
    assert list(rows["action"]) == ["warning", "warning"]
    assert list(rows["detail"]) == ["speed_range: speed_rpm reaches 50000 r/min", "x: m"]
    assert list(rows["first_line"]) == ["7", ""] and list(rows["n_rows"]) == [0, 0]
    q = pd.read_csv(_file(tmp_path, "q.csv", sha="b" * 64, reason="q.csv: bad")[0]).iloc[0]
    assert q["warnings"] == 0 and q["probe_sign"] == 0 and q["status"] == "quarantined"


def test_a_byte_identical_copy_is_rejected_the_first_by_name_stays(tmp_path):
    files = [
        _file(tmp_path, "b_copy.csv", sha="d" * 64),
        _file(tmp_path, "a.csv", sha="d" * 64),
        _file(tmp_path, "c.csv", sha="e" * 64),
    ]
    status = _status(tmp_path, files)
    assert status["usable"] == ["a.csv", "c.csv"] and status["status"] == "usable"
    (rej,) = status["rejected"]
    assert rej["file"] == "b_copy.csv" and rej["check"] == "duplicate_content"
    assert rej["reason"].startswith(
        "b_copy.csv: duplicate_content: byte-identical to a.csv (sha256 dddddddddddd)"
    )
    # the run-level summary and the end-of-run lines name it
    assert input_check([status])["rejected_files"][0]["file"] == "b_copy.csv"
    assert "byte-identical to a.csv" in rejection_lines([status])[0]


def test_of_a_file_and_a_link_to_it_the_link_goes_whatever_the_names(tmp_path):
    files = [_file(tmp_path, "a_link.csv", sha="d" * 64), _file(tmp_path, "train.csv", sha="d" * 64)]
    status = _status(tmp_path, files, links=["a_link.csv"])
    assert status["usable"] == ["train.csv"]
    (rej,) = status["rejected"]
    assert rej["file"] == "a_link.csv" and rej["reason"].endswith("remove the link")


def test_the_file_to_keep_stays_whatever_its_name(tmp_path):
    files = [
        _file(tmp_path, "train (copy).csv", sha="d" * 64),
        _file(tmp_path, "train.csv", sha="d" * 64),
        _file(tmp_path, "c.csv", sha="e" * 64),
    ]
    status = _status(tmp_path, files, keep={"d" * 64: "train.csv"})
    assert status["usable"] == ["train.csv", "c.csv"]
    (rej,) = status["rejected"]
    assert rej["file"] == "train (copy).csv"
    assert "byte-identical to train.csv" in rej["reason"] and rej["reason"].endswith("delete the copy")
    # without a choice for that content (or one naming no usable file): the first by name
    for keep in ({}, {"d" * 64: "gone.csv"}, {"e" * 64: "c.csv"}):
        assert _status(tmp_path, files, keep=keep)["rejected"][0]["file"] == "train.csv"


def test_a_link_goes_even_when_it_is_the_file_to_keep():
    sha = {"link.csv": "d" * 64, "real.csv": "d" * 64}
    found = duplicate_rejections(
        ["link.csv", "real.csv"], sha, links=["link.csv"], keep={"d" * 64: "link.csv"}
    )
    assert [(f, check) for f, check, _ in found] == [("link.csv", "duplicate_content")]
    assert found[0][2].endswith("remove the link")
    assert duplicate_rejections(["a.csv", "b.csv"], {"a.csv": "", "b.csv": ""}) == []


def test_probe_sign_findings_and_listed_warnings():
    rejections, warnings = probe_sign_findings({"a.csv": 1, "b.csv": 1, "c.csv": -1, "d.csv": 0}, "auto")
    assert rejections == [] and [w["file"] for w in warnings] == ["c.csv"]
    assert "2 of the machine's other 2 file(s) with a clear sign say +1" in warnings[0]["message"]
    rejections, warnings = probe_sign_findings({"a.csv": 1, "c.csv": -1}, "negative")
    assert [r[0] for r in rejections] == ["a.csv"] and warnings == []
    listed = listed_warnings(
        [{"file": "a.csv", "check": "x", "message": "m"}, {"file": "gone.csv", "check": "x"}],
        ["a.csv"],
        {"a.csv": "h"},
        [{"file": "a*", "check": "x"}],
    )
    assert listed == [
        {"file": "a.csv", "sha256": "h", "check": "x", "column": "", "message": "m", "confirmed": True}
    ]


def test_quarantined_files_are_not_duplicates_of_usable_ones(tmp_path):
    files = [
        _file(tmp_path, "a.csv", sha="d" * 64),
        _file(tmp_path, "b.csv", sha="d" * 64, reason="b.csv: x"),
    ]
    status = _status(tmp_path, files)
    assert status["usable"] == ["a.csv"] and [r.get("check") for r in status["rejected"]] == [None]


def test_auto_probe_sign_warns_the_file_against_the_majority(tmp_path):
    files = [_file(tmp_path, f"f{i}.csv", sha=str(i) * 64) for i in range(3)]
    files.append(_file(tmp_path, "rev.csv", sha="9" * 64, sign=-1))
    files.append(_file(tmp_path, "idle.csv", sha="8" * 64, sign=0))
    status = _status(tmp_path, files)
    assert status["rejected"] == [] and len(status["usable"]) == 5
    (w,) = status["warnings"]
    assert (w["file"], w["check"], w["column"], w["confirmed"]) == ("rev.csv", "probe_sign", "disp_um", False)
    assert w["sha256"] == "9" * 64
    assert (
        "falls while the spindle heats the machine (probe sign -1); 3 of the machine's other 3 file(s)"
        in w["message"]
    )
    assert status["probe_sign"] == {
        "setting": "auto",
        "files": {"f0.csv": 1, "f1.csv": 1, "f2.csv": 1, "rev.csv": -1, "idle.csv": 0},
    }


def test_auto_probe_sign_follows_a_machine_whose_probe_counts_the_other_way(tmp_path):
    files = [_file(tmp_path, f"f{i}.csv", sha=str(i) * 64, sign=-1) for i in range(3)]
    assert _status(tmp_path, files)["warnings"] == []
    files.append(_file(tmp_path, "pos.csv", sha="9" * 64, sign=1))
    assert [w["file"] for w in _status(tmp_path, files)["warnings"]] == ["pos.csv"]


def test_a_single_file_is_expected_positive(tmp_path):
    status = _status(tmp_path, [_file(tmp_path, "only.csv", sha="1" * 64, sign=-1)])
    assert "convention is positive" in status["warnings"][0]["message"]
    assert _status(tmp_path, [_file(tmp_path, "only.csv", sha="1" * 64, sign=1)])["warnings"] == []


@pytest.mark.parametrize("setting, rejected", [("positive", "neg.csv"), ("negative", "pos.csv")])
def test_a_configured_probe_sign_rejects_the_opposite_file(tmp_path, setting, rejected):
    files = [
        _file(tmp_path, "pos.csv", sha="1" * 64, sign=1),
        _file(tmp_path, "neg.csv", sha="2" * 64, sign=-1),
    ]
    files.append(_file(tmp_path, "none.csv", sha="3" * 64, sign=0))
    status = _status(tmp_path, files, probe_sign=setting)
    (rej,) = status["rejected"]
    assert rej["file"] == rejected and rej["check"] == "probe_sign"
    assert f"but checks.probe_sign is {setting}" in rej["reason"]
    assert rejected not in status["usable"] and status["warnings"] == []
    with pytest.raises(ValueError, match="checks.probe_sign"):
        _status(tmp_path, files, probe_sign="up")


def test_every_file_rejected_skips_the_machine(tmp_path):
    status = _status(tmp_path, [_file(tmp_path, "neg.csv", sha="2" * 64, sign=-1)], probe_sign="positive")
    assert status["status"] == "skipped" and status["usable"] == []


def test_per_file_warnings_are_gathered_and_confirmed_by_glob_and_exact_id(tmp_path):
    fast = CheckWarning("speed_range", "speed_rpm", "reaches 50000 r/min", 4, 100)
    meta = CheckWarning("metadata_machine", "", "says machine 'x'")
    files = [
        _file(tmp_path, "valid_50000rpm.csv", sha="1" * 64, warnings=[fast, meta]),
        _file(tmp_path, "z_copy.csv", sha="1" * 64, warnings=[meta]),  # rejected: its warning goes too
    ]
    confirmed = [{"file": "valid_5*rpm.csv", "check": "speed_range"}, {"file": "*", "check": "metadata"}]
    status = _status(tmp_path, files, confirmed=confirmed)
    assert [(w["file"], w["check"], w["confirmed"]) for w in status["warnings"]] == [
        ("valid_50000rpm.csv", "speed_range", True),
        ("valid_50000rpm.csv", "metadata_machine", False),
    ]
    assert (
        status["warnings"][0]["message"] == "reaches 50000 r/min"
        and status["warnings"][0]["column"] == "speed_rpm"
    )
    lines = warning_lines(status)
    assert lines[0] == "valid_50000rpm.csv: speed_range: reaches 50000 r/min [confirmed]"
    assert not lines[1].endswith("[confirmed]")


def test_confirmation_is_case_sensitive_and_uses_the_file_name_only():
    entry = [{"file": "Valid_*.csv", "check": "speed_range"}]
    assert is_confirmed("raw/m/Valid_1.csv", "speed_range", entry)
    assert not is_confirmed("valid_1.csv", "speed_range", entry)
    assert not is_confirmed("Valid_1.csv", "speed_unit", entry)
    assert not is_confirmed("Valid_1.csv", "speed_range", [])


# --------------------------------------------------------------------------- the real workflow


def _reversed_copy(src: Path, dst: Path) -> None:
    """``src`` with the sign of disp_um flipped (a probe mounted the other way)."""
    lines = src.read_text(encoding="utf-8").splitlines()
    out, k = [], None
    for line in lines:
        if line.startswith("#"):
            out.append(line)
            continue
        fields = line.split(",")
        if k is None:
            k = fields.index("disp_um")
        elif fields[k]:
            fields[k] = f"{-float(fields[k]):.3f}"
        out.append(",".join(fields))
    dst.write_text("\n".join(out) + "\n", encoding="utf-8")


@pytest.mark.slow
def test_the_workflow_lists_warnings_and_leaves_out_a_duplicate(tmp_path):
    proj = copy_project(tmp_path / "proj")
    raw = proj / "raw" / A
    raw.mkdir(parents=True)
    for stem in ("train_03000rpm", "train_09000rpm", "train_15000rpm", "valid_04500rpm"):
        shutil.copy2(ROOT / "raw" / A / f"{stem}.csv", raw / f"{stem}.csv")
    shutil.copy2(raw / "train_09000rpm.csv", raw / "train_09000rpm_copy.csv")
    _reversed_copy(raw / "valid_04500rpm.csv", raw / "valid_04500rpm_rev.csv")
    res = proj / "results" / A
    target = f"results/{A}/runs.csv"

    first = run_module(proj, "snakemake", "--cores", "2", "--config", "on_bad_input=quarantine", "--", target)
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr[-3000:]
    status = json.loads((res / "input_status.json").read_text())
    assert status["status"] == "usable" and "train_09000rpm_copy.csv" not in status["usable"]
    (dup,) = status["rejected"]
    assert dup["file"] == "train_09000rpm_copy.csv" and dup["check"] == "duplicate_content"
    assert "byte-identical to train_09000rpm.csv" in dup["reason"]
    (warning,) = status["warnings"]
    assert warning["file"] == "valid_04500rpm_rev.csv" and warning["check"] == "probe_sign"
    assert warning["confirmed"] is False
    runs = pd.read_csv(res / "runs.csv")
    assert "train_09000rpm_copy.csv" not in set(runs["file"]) and "valid_04500rpm_rev.csv" in set(
        runs["file"]
    )
    assert "left out train_09000rpm_copy.csv" in (proj / "logs" / A / "runs.log").read_text()
    summary = pd.read_csv(res / "clean" / "valid_04500rpm_rev.summary.csv").iloc[0]
    assert summary["probe_sign"] == -1 and summary["warnings"] == 0

    # confirming the warning rewrites input_status.json but re-runs nothing downstream of it
    config = (proj / "config.yaml").read_text(encoding="utf-8")
    config += (
        f"  {A}:\n    checks:\n      confirmed:\n"
        '        - {file: "valid_04500rpm_rev*", check: probe_sign}\n'
    )
    (proj / "config.yaml").write_text(config, encoding="utf-8")
    runs_before = (res / "runs.csv").stat().st_mtime_ns
    second = run_module(
        proj, "snakemake", "--cores", "2", "--config", "on_bad_input=quarantine", "--", target
    )
    assert second.returncode == 0, second.stdout[-3000:] + second.stderr[-3000:]
    assert json.loads((res / "input_status.json").read_text())["warnings"][0]["confirmed"] is True
    assert (res / "runs.csv").stat().st_mtime_ns == runs_before

    # a clean table that cannot be read: its file is left out of runs, the rule does not fail
    (res / "clean" / "train_15000rpm.parquet").write_bytes(b"not a parquet file")
    os.utime(res / "input_status.json")  # runs must run again
    third = run_module(
        proj, "snakemake", "--cores", "2", "--config", "on_bad_input=quarantine", "-R", "method", "--", target
    )
    assert third.returncode == 0, third.stdout[-3000:] + third.stderr[-3000:]
    assert "train_15000rpm.csv" not in set(pd.read_csv(res / "runs.csv")["file"])
    assert "left out train_15000rpm.csv as quarantined" in (proj / "logs" / A / "runs.log").read_text()
