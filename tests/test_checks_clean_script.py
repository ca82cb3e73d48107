"""The clean step (workflow/scripts/clean.py) in quarantine mode: ANY failure on one file
quarantines that file with a one-line reason (traceback in the log), warnings become audit rows,
and a clean table that cannot be read back quarantines the file too.

The script is run as Snakemake runs it (``snakemake`` injected as a global), with a stand-in
object carrying the params the rule passes (one machine with one raw file).
"""

from __future__ import annotations

import runpy
import shutil
import sys
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest

import rafi.readers.logs
from rafi.errors import RawFormatError

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "workflow" / "scripts" / "clean.py"
A = "tapping-center-a"


def _smk(tmp_path: Path, raw: Path, mode: str = "quarantine") -> SimpleNamespace:
    out = tmp_path / "results" / A / "clean"
    return SimpleNamespace(
        params=SimpleNamespace(
            raw_paths={raw.stem: str(raw)},
            raw_parts={},  # plain files: no sheet-log, no joined partner
            input_spec={"format": "native"},
            sample_period_s=5,
            clean={
                "max_interpolate_gap_s": 60,
                "spike_threshold": 8,
                "open_circuit_values": [-999.0, 999.9, 850.0],
            },
            checks={
                "min_run_s": 1800,
                "sample_period_s": 5,
                "open_circuit_values": [-999.0, 999.9, 850.0],
                "training_speeds_rpm": [3000, 6000, 9000, 12000, 15000, 18000],
                "speed_tolerance_rpm": 50,
                "machine": A,
            },
        ),
        config={"on_bad_input": mode},
        # the rule's output is the folder; the per-file paths are for the assertions
        output=SimpleNamespace(
            folder=str(out),
            parquet=str(out / f"{raw.stem}.parquet"),
            audit=str(out / f"{raw.stem}.audit.csv"),
            summary=str(out / f"{raw.stem}.summary.csv"),
        ),
        log=[str(tmp_path / "logs" / f"{raw.stem}.log")],
        rule="clean",
        wildcards={"machine": A},
    )


def _clean(smk) -> None:
    sys.path.insert(0, str(SCRIPT.parent))
    try:
        runpy.run_path(str(SCRIPT), init_globals={"snakemake": smk}, run_name="__main__")
    finally:
        sys.path.remove(str(SCRIPT.parent))


@pytest.fixture
def raw(tmp_path) -> Path:
    path = tmp_path / "raw" / A / "valid_16500rpm.csv"
    path.parent.mkdir(parents=True)
    shutil.copy2(ROOT / "raw" / A / "valid_16500rpm.csv", path)
    return path


def test_a_good_file_is_cleaned_with_its_probe_sign(tmp_path, raw):
    smk = _smk(tmp_path, raw)
    _clean(smk)
    summary = pd.read_csv(smk.output.summary).iloc[0]
    assert summary["status"] == "ok" and summary["warnings"] == 0 and summary["probe_sign"] == 1
    assert len(pd.read_parquet(smk.output.parquet)) > 1000


def test_a_warning_is_an_audit_row_and_counted(tmp_path, raw):
    text = raw.read_text(encoding="utf-8").replace("# machine: tapping-center-a", "# machine: lathe-7")
    raw.write_text(text, encoding="utf-8")
    smk = _smk(tmp_path, raw)
    _clean(smk)
    summary = pd.read_csv(smk.output.summary).iloc[0]
    assert summary["status"] == "ok" and summary["warnings"] == 1
    audit = pd.read_csv(smk.output.audit, keep_default_na=False)
    row = audit[audit["action"] == "warning"].iloc[0]
    assert row["detail"].startswith("metadata_machine: the file's metadata says machine 'lathe-7'")
    assert row["n_rows"] == 0 and row["first_line"] == "" and row["file"] == raw.name
    assert "metadata_machine" in Path(smk.log[0]).read_text()


@pytest.mark.parametrize(
    "exc",
    [
        PermissionError(13, "Permission denied"),
        OSError(5, "Input/output error"),
        MemoryError(),
        ValueError("cannot reindex on an axis with duplicate labels\nsecond line"),
    ],
    ids=["permission", "io", "memory", "pandas"],
)
def test_any_failure_reading_a_file_quarantines_it(tmp_path, raw, monkeypatch, exc):
    def fail(*args, **kwargs):
        raise exc

    monkeypatch.setattr(rafi.readers.logs, "read_log", fail)
    smk = _smk(tmp_path, raw)
    _clean(smk)
    summary = pd.read_csv(smk.output.summary).iloc[0]
    assert summary["status"] == "quarantined"
    reason = summary["reason"]
    assert reason.startswith(f"{raw.name}: could not be read or cleaned: {type(exc).__name__}")
    assert "\n" not in reason and len(reason) < 500
    assert reason.endswith(" [unreadable]") == isinstance(exc, OSError)
    assert len(pd.read_parquet(smk.output.parquet)) == 0
    assert "Traceback" in Path(smk.log[0]).read_text()  # the details are in the log


def test_an_unreadable_file_is_quarantined_without_a_hash(tmp_path, raw, monkeypatch):
    def fail(path):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(rafi.readers.logs, "sha256_file", fail)
    smk = _smk(tmp_path, raw)
    _clean(smk)
    summary = pd.read_csv(smk.output.summary, keep_default_na=False).iloc[0]
    assert summary["status"] == "quarantined" and summary["sha256"] == ""
    assert "PermissionError" in summary["reason"] and "Permission denied" in summary["reason"]


def test_fail_mode_ends_with_one_line_naming_the_file_and_no_traceback(tmp_path, raw, monkeypatch):
    monkeypatch.setattr(rafi.readers.logs, "read_log", lambda *a, **k: (_ for _ in ()).throw(OSError("boom")))
    smk = _smk(tmp_path, raw, mode="fail")
    with pytest.raises(SystemExit) as exit_:
        _clean(smk)
    assert exit_.value.code == 1
    log = Path(smk.log[0]).read_text(encoding="utf-8")
    assert "Traceback" not in log
    last = log.strip().splitlines()[-1]
    assert last.startswith("RAFI clean (machine=tapping-center-a) failed: ")
    assert "could not be read or cleaned: OSError: boom" in last


def test_fail_mode_with_debug_raises_the_error_with_its_cause(tmp_path, raw, monkeypatch):
    monkeypatch.setattr(rafi.readers.logs, "read_log", lambda *a, **k: (_ for _ in ()).throw(OSError("boom")))
    smk = _smk(tmp_path, raw, mode="fail")
    smk.config["debug"] = True
    with pytest.raises(RawFormatError, match="OSError: boom") as raised:
        _clean(smk)
    assert isinstance(raised.value.__cause__, OSError)
    assert "Traceback" in Path(smk.log[0]).read_text(encoding="utf-8")


def test_a_clean_table_that_cannot_be_read_back_quarantines_the_file(tmp_path, raw, monkeypatch):
    real = pd.read_parquet

    def broken(path, *args, **kwargs):
        if Path(path).name == f"{raw.stem}.parquet" and not broken.done:
            broken.done = True
            raise OSError("Couldn't deserialize thrift: TProtocolException: Exceeded size limit")
        return real(path, *args, **kwargs)

    broken.done = False
    monkeypatch.setattr(pd, "read_parquet", broken)
    smk = _smk(tmp_path, raw)
    _clean(smk)
    summary = pd.read_csv(smk.output.summary).iloc[0]
    assert summary["status"] == "quarantined"
    assert "cannot be read back (OSError: Couldn't deserialize thrift" in summary["reason"]
    assert summary["reason"].endswith("[clean_table_unreadable]")
    assert len(real(smk.output.parquet)) == 0

    broken.done = False
    smk = _smk(tmp_path, raw, mode="fail")
    with pytest.raises((RawFormatError, SystemExit)):  # the glue turns a user error into an exit
        _clean(smk)
    assert "cannot be read back" in Path(smk.log[0]).read_text()


def test_a_check_error_names_its_check_id_in_brackets(tmp_path, raw):
    lines = raw.read_text(encoding="utf-8").splitlines()
    header = lines[4].split(",")
    k = header.index("speed_rpm")
    for i in range(5, len(lines)):
        fields = lines[i].split(",")
        fields[k] = f"{float(fields[k]) / 60:.2f}"  # rev/s on a validation run: a warning ...
        lines[i] = ",".join(fields)
    raw.write_text("\n".join(lines) + "\n", encoding="utf-8")
    smk = _smk(tmp_path, raw)
    _clean(smk)
    assert pd.read_csv(smk.output.summary).iloc[0]["warnings"] == 1
    smk.params.checks["training_speeds_rpm"] = [16500]  # ... an error once x 60 is a training speed
    _clean(smk)
    summary = pd.read_csv(smk.output.summary).iloc[0]
    assert summary["status"] == "quarantined"
    assert "speed_unit: speed_rpm holds 1 plateau(s)" in summary["reason"]
    assert summary["reason"].endswith(" [speed_unit]")


def test_quarantine_reason_is_one_line_with_its_check_id():
    from rafi.errors import RawFormatError
    from rafi.method.audit import REASON_CHARS, quarantine_reason

    err = RawFormatError("raw/m/a.csv", "temperatures look like deg F", column="T1", check="temperature_unit")
    assert quarantine_reason(err, "a.csv").endswith("deg F [temperature_unit]")
    untagged = RawFormatError("raw/m/a.csv", "no data rows")
    assert quarantine_reason(untagged, "a.csv") == str(untagged)
    io = quarantine_reason(PermissionError(13, "Permission denied"), "a.csv")
    assert io.startswith("a.csv: could not be read or cleaned: PermissionError") and io.endswith(
        "[unreadable]"
    )
    huge = quarantine_reason(ValueError("x\n" * 10_000), "a.csv")
    assert "\n" not in huge and len(huge) < REASON_CHARS + 100 and "[" not in huge
