"""Logs without a time column (row k at ``time.start + k * time.period_s``) and without a speed
column (``input.speed.constant_rpm`` / ``constant_rpm_by_file``): rafi.readers.input_assumed,
rafi.readers.mapped_time and the mapped reader.

Known truth: a generated log is written twice, once in full (time and speed columns) and once
without them; read back with the matching mapping, both give the same canonical frame.
"""

from __future__ import annotations

import re
from pathlib import Path

import jsonschema
import numpy as np
import openpyxl
import pandas as pd
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from project_copy import copy_project, run_snakemake

from rafi import REQUIRED_COLUMNS
from rafi.contract import NO_CLOCK_EPOCH
from rafi.errors import InputSpecError, RawFormatError
from rafi.method.clean import clean_log
from rafi.readers.checks import check_file, check_log
from rafi.readers.input_assumed import constant_speed
from rafi.readers.input_spec import INPUT_SCHEMA, discover_machines, normalise_input_spec
from rafi.readers.logs import read_log
from rafi.readers.native import contract_violations, format_raw_log
from rafi.settings import machine_settings
from rafi.twin.synthetic_logs import canonical_log

ROOT = Path(__file__).resolve().parents[1]
CONFIG_SCHEMA = yaml.safe_load((ROOT / "workflow" / "schemas" / "config.schema.yaml").read_text("utf-8"))


def generated(n: int, period_s: float, rpm: float, start: str, seed: int = 0) -> pd.DataFrame:
    log, _ = canonical_log(n, period_s=period_s, steps=((0.0, rpm),), start=pd.Timestamp(start), seed=seed)
    return log


def write_pair(folder: Path, log: pd.DataFrame, stem: str) -> tuple[Path, Path]:
    """The log in full, and the same rows without the time and speed columns."""
    full = folder / f"{stem}_full.csv"
    bare = folder / f"{stem}.csv"
    full.write_text(format_raw_log(log), encoding="utf-8")
    bare.write_text(format_raw_log(log.drop(columns=["time", "speed_rpm"])), encoding="utf-8")
    return full, bare


def bare_spec(period_s: float, start: str | None = None, **speed) -> dict:
    time = {"kind": "none", "period_s": period_s}
    if start is not None:
        time["start"] = start
    return {"format": "csv", "time": time, "speed": speed or {"constant_rpm": 3000}}


def assert_same_frame(bare: pd.DataFrame, full: pd.DataFrame) -> None:
    assert contract_violations(bare) == []
    assert list(bare.columns) == list(full.columns)
    pd.testing.assert_frame_equal(bare, full, check_like=False)


# --------------------------------------------------------------------------- known truth


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    n=st.integers(1, 400),
    period_ms=st.integers(100, 600_000),
    rpm=st.integers(0, 24_000),
    start_s=st.integers(0, 40 * 365 * 86400),
    seed=st.integers(0, 2**16),
)
def test_a_log_without_time_and_speed_columns_reads_as_the_full_log(
    tmp_path, n, period_ms, rpm, start_s, seed
):
    period = period_ms / 1000
    start = (pd.Timestamp("2000-01-01") + pd.Timedelta(seconds=start_s)).isoformat()
    log = generated(n, period, float(rpm), start, seed)
    full_path, bare_path = write_pair(tmp_path, log, f"log{seed}")
    full = read_log(full_path, {"format": "csv"})
    bare = read_log(bare_path, bare_spec(period, start, constant_rpm=rpm))
    assert_same_frame(bare, full)
    # the truth the log was generated from, not only the other reader
    k = np.arange(n)
    expected = pd.Timestamp(start) + pd.to_timedelta(k * period_ms, unit="ms")
    assert (bare["time"].to_numpy() == expected.to_numpy()).all()
    assert (bare["speed_rpm"] == rpm).all()
    meta = bare.attrs["metadata"]
    assert set(meta["assumed"]) == {"time", "speed_rpm"}
    assert meta["sample_period_s"] == period
    assert "time" not in meta["columns"] and "speed_rpm" not in meta["columns"]
    assert "assumed" not in full.attrs["metadata"]


def test_xlsx_without_time_and_speed_columns(tmp_path):
    log = generated(120, 60.0, 3000.0, "2026-03-02T06:00:00")
    header = [c for c in log.columns if c not in ("time", "speed_rpm")]
    wb = openpyxl.Workbook()
    ws = wb.active
    ws.title = "Daten"
    ws.append(header)
    for row in log[header].itertuples(index=False):
        ws.append([None if isinstance(v, float) and np.isnan(v) else v for v in row])
    path = tmp_path / "spindle_3000.xlsx"
    wb.save(path)
    spec = {
        **bare_spec(60.0, "2026-03-02T06:00:00", constant_rpm_by_file={"*_3000*": 3000}),
        "format": "xlsx",
    }
    frame = read_log(path, spec)
    assert contract_violations(frame) == []
    assert (frame["time"].to_numpy() == log["time"].to_numpy()).all()
    assert (frame["speed_rpm"] == 3000.0).all()
    np.testing.assert_allclose(frame["disp_um"], log["disp_um"])
    assert list(frame.index) == list(range(2, 122))  # Excel rows
    assert frame.attrs["metadata"]["assumed"]["speed_rpm"].endswith("constant_rpm_by_file['*_3000*']")


def test_start_is_optional_and_blank_lines_are_not_samples(tmp_path):
    log = generated(6, 60.0, 1500.0, "2026-01-01")
    text = format_raw_log(log.drop(columns=["time", "speed_rpm"])).splitlines()
    path = tmp_path / "minutes.csv"
    path.write_text("\n".join(text[:3] + [""] + text[3:]) + "\n", encoding="utf-8")
    frame = read_log(path, bare_spec(60.0, constant_rpm=1500))
    assert list(frame.index) == [2, 3, 5, 6, 7, 8]  # the blank line 4 is skipped, not a sample
    # no time.start: the times count from NO_CLOCK_EPOCH for the arithmetic, and are no date
    assert list(frame["time"]) == list(pd.date_range(NO_CLOCK_EPOCH, periods=6, freq="60s"))
    assert frame.attrs["metadata"]["clock"] is False
    assert "no date (input.time.start not set)" in frame.attrs["metadata"]["assumed"]["time"]
    dated = read_log(path, bare_spec(60.0, "2026-01-01", constant_rpm=1500))
    assert "clock" not in dated.attrs["metadata"]
    assert "no date" not in dated.attrs["metadata"]["assumed"]["time"]


def test_elapsed_seconds_without_a_start_are_no_clock_and_with_one_are_dates(tmp_path):
    log = generated(30, 60.0, 1500.0, "2026-01-01")
    elapsed = log.assign(time=np.arange(len(log)) * 60.0 - 300.0)  # 5 min of pre-trigger samples
    path = tmp_path / "elapsed.csv"
    elapsed.to_csv(path, index=False)
    frame = read_log(path, {"format": "csv", "time": {"kind": "elapsed_s"}})
    assert frame.attrs["metadata"]["clock"] is False
    assert frame["time"].iloc[0] == pd.Timestamp(NO_CLOCK_EPOCH) - pd.Timedelta(seconds=300)
    # before the epoch, but a log without a clock has none to be unset
    assert "clock_unset" not in [w.check for w in check_file(frame, path).warnings]
    dated = read_log(path, {"format": "csv", "time": {"kind": "elapsed_s", "start": "2026-03-02T06:00"}})
    assert "clock" not in dated.attrs["metadata"]
    assert dated["time"].iloc[0] == pd.Timestamp("2026-03-02T05:55")
    unset = frame.copy()
    unset.attrs = {**frame.attrs, "metadata": {**frame.attrs["metadata"], "clock": True}}
    assert "clock_unset" in [w.check for w in check_file(unset, path).warnings]  # the check can fire


# --------------------------------------------------------------------------- speed per file


def test_constant_speed_per_file_glob_then_machine_constant(tmp_path):
    spec = normalise_input_spec(
        {
            "format": "csv",
            "speed": {"constant_rpm": 500, "constant_rpm_by_file": {"*_3000*": 3000, "b*": 3000}},
        }
    )
    assert constant_speed("run_3000rpm.csv", spec) == (3000.0, "input.speed.constant_rpm_by_file['*_3000*']")
    assert constant_speed("b_3000.csv", spec)[0] == 3000.0  # two globs, one speed: fine
    assert constant_speed("warmup.csv", spec) == (500.0, "input.speed.constant_rpm")
    assert constant_speed("B_1500.csv", spec)[0] == 500.0  # case-sensitive: 'b*' does not match
    no_default = {**spec, "speed": {**spec["speed"], "constant_rpm": None}}
    assert constant_speed("warmup.csv", no_default) is None


def test_a_file_with_no_configured_speed_is_a_raw_format_error_naming_file_and_keys(tmp_path):
    log = generated(20, 5.0, 1000.0, "2026-01-01")
    _, bare = write_pair(tmp_path, log, "cooldown")
    spec = bare_spec(5.0, constant_rpm_by_file={"*_3000*": 3000})
    with pytest.raises(RawFormatError) as info:
        read_log(bare, spec)
    msg = str(info.value)
    assert "cooldown.csv" in msg and "'*_3000*'" in msg
    assert "input.speed.constant_rpm_by_file" in msg and "input.speed.constant_rpm" in msg


def test_two_globs_with_different_speeds_stop_the_run_naming_both(tmp_path):
    spec = bare_spec(5.0, constant_rpm_by_file={"*_3000*": 3000, "run_*": 1500})
    log = generated(20, 5.0, 3000.0, "2026-01-01")
    folder = tmp_path / "raw" / "m"
    folder.mkdir(parents=True)
    _, bare = write_pair(folder, log, "run_3000")
    (folder / "run_3000_full.csv").unlink()
    with pytest.raises(InputSpecError, match=r"'\*_3000\*' \(3000 r/min\), 'run_\*' \(1500 r/min\)"):
        read_log(bare, spec)
    with pytest.raises(
        InputSpecError, match=r"machine 'm': input.speed.constant_rpm_by_file: file 'run_3000.csv'"
    ):
        discover_machines(tmp_path / "raw", lambda m: spec)
    spec["speed"]["constant_rpm_by_file"]["run_*"] = 3000
    assert list(discover_machines(tmp_path / "raw", lambda m: spec)[0]["m"]) == ["run_3000"]


# --------------------------------------------------------------------------- the mapping


@pytest.mark.parametrize(
    "change, key",
    [
        ({"time": {"kind": "none"}}, "input.time.period_s: missing"),
        ({"time": {"kind": "none", "period_s": 0}}, "input.time.period_s"),
        ({"time": {"kind": "none", "period_s": True}}, "input.time.period_s"),
        ({"time": {"kind": "elapsed_s", "period_s": 60}}, "input.time.period_s: applies to time.kind: none"),
        ({"time": {"kind": "none", "period_s": 60}, "columns": {"time": "Zeit"}}, "input.columns.time"),
        ({"time": {"kind": "none", "period_s": 60, "format": "%H:%M"}}, "input.time.format"),
        ({"time": {"kind": "none", "period_s": 60}, "sample_period_s": 30}, "input.sample_period_s"),
        ({"time": {"kind": "clock"}}, "input.time.kind"),
        ({"speed": {"constant_rpm": -1}}, "input.speed.constant_rpm"),
        ({"speed": {"constant_rpm": True}}, "input.speed.constant_rpm"),
        ({"speed": {"constant_rpm": "3000"}}, "input.speed.constant_rpm"),
        ({"speed": {"constant_rpm_by_file": ["*"]}}, "input.speed.constant_rpm_by_file"),
        ({"speed": {"constant_rpm_by_file": {"": 3000}}}, "input.speed.constant_rpm_by_file"),
        ({"speed": {"constant_rpm_by_file": {"a*": None}}}, "input.speed.constant_rpm_by_file.a*"),
        ({"speed": {"rpm": 3000}}, "input.speed.rpm"),
        ({"speed": 3000}, "input.speed"),
        (
            {"speed": {"constant_rpm": 3000}, "columns": {"speed_rpm": "n"}},
            "conflicts with columns.speed_rpm",
        ),
        ({"format": "native", "speed": {"constant_rpm": 3000}}, "input.speed: applies to format csv or xlsx"),
        ({"format": "native", "time": {"kind": "none", "period_s": 5}}, "input.time: applies to format csv"),
    ],
)
def test_bad_mapping_names_the_key(change, key):
    spec = {"format": "csv", **change}
    with pytest.raises(InputSpecError, match=re.escape(key)):
        normalise_input_spec(spec)


@pytest.mark.parametrize(
    "bad",
    [
        {"time": {"kind": "clock"}},
        {"time": {"period_s": 0}},
        {"speed": {"constant_rpm": -1}},
        {"speed": {"rpm": 1}},
        {"speed": {"constant_rpm_by_file": {"a*": "fast"}}},
    ],
)
def test_both_schemas_reject_what_the_normaliser_rejects(bad):
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, INPUT_SCHEMA)
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"machines": {"m": {"input": bad}}}, CONFIG_SCHEMA)


def test_the_documented_example_validates_and_reads_as_documented(tmp_path):
    text = (ROOT / "docs" / "raw-format.md").read_text(encoding="utf-8")
    section = text.split("### Logs without a time or speed column", 1)[1].split("\n## ", 1)[0]
    config = yaml.safe_load(re.findall(r"```yaml\n(.+?)```", section, flags=re.S)[0])
    sample = re.findall(r"```\n(.+?)```", section, flags=re.S)[0]
    jsonschema.validate(config, CONFIG_SCHEMA)
    jsonschema.validate(config["machines"]["test-rig-c"]["input"], INPUT_SCHEMA)
    settings_ = machine_settings(config, "test-rig-c")
    for name, rpm in (("warmup_1500rpm.csv", 1500.0), ("warmup_3000rpm.csv", 3000.0)):
        (tmp_path / name).write_text(sample, encoding="utf-8")
        frame = read_log(tmp_path / name, settings_["input"])
        assert contract_violations(frame) == []
        assert list(frame["time"]) == [
            pd.Timestamp("2026-03-02T06:00:00"),
            pd.Timestamp("2026-03-02T06:01:00"),
        ]
        assert list(frame["speed_rpm"]) == [rpm, rpm]
        assert list(frame["disp_um"]) == [0.0, 0.41] and frame["T6"].iloc[1] == 21.71
    # the audit detail quoted in the docs is the reader's own wording
    quoted = re.search(r"e\.g\.\s+`(no speed column: [^`]+)`", section).group(1)
    spec = {**settings_["input"], "speed": {"constant_rpm_by_file": {"*_3000rpm*": 3000}}}
    assert read_log(tmp_path / "warmup_3000rpm.csv", spec).attrs["metadata"]["assumed"]["speed_rpm"] == quoted


def test_machine_period_must_match_the_rows_period():
    config = {"machines": {"m": {"input": bare_spec(60.0)}}}
    with pytest.raises(InputSpecError, match=r"input.time.period_s: 60 s differs from the machine's "):
        machine_settings(config, "m")
    config["machines"]["m"]["sample_period_s"] = 60
    assert machine_settings(config, "m")["input"]["sample_period_s"] == 60.0


# --------------------------------------------------------------------------- downstream


def test_checked_and_cleaned_with_the_assumption_in_the_audit(tmp_path):
    log = generated(300, 60.0, 3000.0, "2026-03-02T06:00:00")
    full_path, bare_path = write_pair(tmp_path, log, "spindle")
    frames = {}
    for name, path, spec in (
        ("full", full_path, {"format": "csv"}),
        ("bare", bare_path, bare_spec(60.0, "2026-03-02T06:00:00")),
    ):
        frame = read_log(path, spec)
        check_log(frame, path, min_run_s=0, sample_period_s=60.0)
        frames[name] = clean_log(
            frame,
            file=path.name,
            sample_period_s=60.0,
            max_interpolate_gap_s=300.0,
            spike_threshold=8.0,
            open_circuit_values=[],
        )
    (clean_full, audit_full), (clean_bare, audit_bare) = frames["full"], frames["bare"]
    pd.testing.assert_frame_equal(clean_bare, clean_full)
    assumed = audit_bare[audit_bare["action"] == "assumed"]
    assert list(assumed["column"]) == ["time", "speed_rpm"]
    assert (assumed["n_rows"] == 300).all() and (assumed["first_line"] == 2).all()
    assert "3000 r/min for every row" in assumed["detail"].iloc[1]
    assert "assumed" not in set(audit_full["action"])
    assert clean_bare.attrs["metadata"]["assumed"]["time"].startswith("no time column")
    assert list(clean_bare.columns[:3]) == ["time", "t_s", "speed_rpm"]
    assert set(REQUIRED_COLUMNS) <= set(clean_bare.columns)


# --------------------------------------------------------------------------- end to end

#: Files of the end-to-end machine: name -> constant speed (training 6000/12000/18000, one
#: validation speed, and a cool-down at rest matched by the machine-wide constant 0).
E2E_FILES = {
    "warmup_6000rpm.csv": 6000,
    "warmup_12000rpm.csv": 12000,
    "warmup_18000rpm.csv": 18000,
    "check_9000rpm.csv": 9000,
    "rest.csv": 0,
}


@pytest.mark.slow
def test_a_machine_without_time_and_speed_columns_runs_through_the_workflow(tmp_path):
    """The real Snakefile on a machine whose csv logs have neither a time nor a speed column
    (one row per minute, one speed per file from its name): every table is made, the clean
    parquet and the runs carry the configured clock and speeds, and the audit says so."""

    work = copy_project(tmp_path / "project", config=False)
    raw = work / "raw" / "rig-c"
    raw.mkdir(parents=True)
    for i, (name, rpm) in enumerate(E2E_FILES.items()):
        log = generated(360, 60.0, float(rpm), "2026-03-02T06:00:00", seed=i)
        raw.joinpath(name).write_text(format_raw_log(log.drop(columns=["time", "speed_rpm"])), "utf-8")
    start = "2026-03-02T06:00:00"
    machine = {
        "sample_period_s": 60,
        "training_speeds_rpm": [6000, 12000, 18000],
        "input": {
            "format": "csv",
            "pattern": "*.csv",
            "time": {"kind": "none", "period_s": 60, "start": start},
            "speed": {
                "constant_rpm_by_file": {f"*_{rpm}rpm*": rpm for rpm in E2E_FILES.values() if rpm},
                "constant_rpm": 0,
            },
        },
    }
    config = {"defaults": {}, "machines": {"rig-c": machine}}
    (work / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")
    proc = run_snakemake(work, "tables", cores=2, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-5000:]

    results = work / "results" / "rig-c"
    audit = pd.read_csv(results / "audit.csv")
    assert set(audit["status"]) == {"ok"} and set(audit["file"]) == set(E2E_FILES)
    runs = pd.read_csv(results / "runs.csv")
    for name, rpm in E2E_FILES.items():
        mine = runs[runs["file"] == name]
        assert len(mine) >= 1 and (mine["speed_rpm"] == rpm).all(), mine
        clean = pd.read_parquet(results / "clean" / name.replace(".csv", ".parquet"))
        assert clean["time"].iloc[0] == pd.Timestamp(start) and clean["time"].diff().iloc[1:].eq("60s").all()
        assert set(clean.attrs["metadata"]["assumed"]) == {"time", "speed_rpm"}
        actions = pd.read_csv(results / "clean" / name.replace(".csv", ".audit.csv"))
        assumed = actions[actions["action"] == "assumed"]
        assert list(assumed["column"]) == ["time", "speed_rpm"]
        assert f"{rpm} r/min for every row" in assumed["detail"].iloc[1]
        assert ("constant_rpm_by_file" in assumed["detail"].iloc[1]) == (rpm > 0)
    assert set(runs.loc[~runs["speed_rpm"].isin([0, 9000]), "role"]) == {"training"}
    assert set(runs.loc[runs["speed_rpm"] == 0, "kind"]) == {"idle"}
    assert set(runs.loc[runs["speed_rpm"] == 9000, "role"]) == {"validation_single"}
    assert (results / "model.json").is_file()
    summary = pd.read_csv(results / "validation" / "summary.csv")
    assert set(summary["run_id"]) == {"check_9000rpm", "rest"}
