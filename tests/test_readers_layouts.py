"""Layouts beyond one header row, one sheet and one file (docs/raw-format.md): files without a
header row, every sheet of a workbook as a log, temperatures and displacement in two files.

The files are written by tests/layout_files.py from canonical frames; each is read back with the
mapped reader and compared to the frame it was written from, exactly.
"""

from __future__ import annotations

from pathlib import Path

import jsonschema
import numpy as np
import openpyxl
import pandas as pd
import pytest
from layout_files import (
    CANONICAL,
    canonical_frame,
    write_daily_workbook,
    write_headerless_csv,
    write_headerless_xlsx,
    write_split_pair,
)

from rafi.contract.input import INPUT_SCHEMA
from rafi.contract.sensors import DEFAULT_SENSORS as SENSORS
from rafi.errors import InputSpecError, RawFormatError
from rafi.ops.clean_job import CleanSettings, clean_machine
from rafi.readers.input_spec import discover_logs, normalise_input_spec
from rafi.readers.log_sources import log_stamp, sheet_log_name, xlsx_sheet_names
from rafi.readers.logs import read_log
from rafi.readers.mapped import read_mapped


def _canonical(frame: pd.DataFrame) -> pd.DataFrame:
    return frame[CANONICAL].reset_index(drop=True)


# --------------------------------------------------------------------------- no header row


def test_headerless_xlsx_read_by_column_letters_equals_the_frame_written(tmp_path: Path):
    truth = canonical_frame(50, seed=3)
    path = tmp_path / "rig.xlsx"
    letters = write_headerless_xlsx(path, truth, extra=12)
    assert any(len(v) == 2 for v in letters.values())  # some columns past Z
    spec = {"format": "xlsx", "header_row": "none", "columns": {k: v.lower() for k, v in letters.items()}}
    got = read_mapped(path, spec)
    pd.testing.assert_frame_equal(_canonical(got), truth, check_dtype=False)
    assert list(got.index) == list(range(1, 51))  # row numbers as Excel shows them
    extras = [c for c in got.columns if c not in CANONICAL]
    assert len(extras) == 12 and all(c.startswith("column_") for c in extras)


def test_headerless_csv_read_by_positions_after_skipped_lines(tmp_path: Path):
    truth = canonical_frame(30, seed=4)
    path = tmp_path / "rig.csv"
    positions = write_headerless_csv(path, truth, preamble=2)
    spec = {"format": "csv", "header_row": None, "skip_rows": 2, "columns": positions}
    got = read_mapped(path, spec)
    pd.testing.assert_frame_equal(_canonical(got), truth, check_dtype=False)
    assert got.index[0] == 3  # the first data line of the file


def test_with_a_header_row_an_integer_is_a_position_and_a_string_a_header(tmp_path: Path):
    truth = canonical_frame(10, seed=5)
    path = tmp_path / "log.csv"
    out = truth.rename(columns={"disp_um": "Verlagerung", "T2": "B"})
    out["time"] = out["time"].dt.strftime("%Y-%m-%d %H:%M:%S")
    out.to_csv(path, index=False)
    # T2's header is the text "B"; disp_um is given by position; the other sensors by their names
    spec = {
        "format": "csv",
        "sensors": list(SENSORS),
        "columns": {"T2": "B", "disp_um": CANONICAL.index("disp_um") + 1},
    }
    got = read_mapped(path, spec)
    pd.testing.assert_frame_equal(_canonical(got), truth, check_dtype=False)


def test_header_row_on_a_headerless_file_says_row_1_looks_like_data(tmp_path: Path):
    path = tmp_path / "rig.xlsx"
    write_headerless_xlsx(path, canonical_frame(5), extra=0)
    with pytest.raises(RawFormatError, match=r"row 1 \(input.header_row\) looks like data") as info:
        read_mapped(path, {"format": "xlsx", "columns": {"T1": "0"}})
    assert "input.header_row: none" in str(info.value)


def test_a_letter_beyond_the_last_column_names_the_key_and_the_sheet(tmp_path: Path):
    path = tmp_path / "rig.xlsx"
    letters = write_headerless_xlsx(path, canonical_frame(5), extra=0)
    spec = {"format": "xlsx", "header_row": "none", "columns": {**letters, "T3": "Z"}}
    with pytest.raises(
        RawFormatError, match=r"input.columns.T3: column 'Z' .* beyond the 19 columns of sheet 'Daten'"
    ):
        read_mapped(path, spec)


def test_without_a_header_row_a_header_text_is_refused_naming_the_key():
    with pytest.raises(InputSpecError, match=r"^input.columns.T3: 'Temp 3' is not a column letter"):
        normalise_input_spec({"format": "csv", "header_row": "none", "columns": {"T3": "Temp 3"}})


def test_without_a_header_row_every_column_read_must_be_mapped():
    letters = {c: chr(65 + k) for k, c in enumerate(CANONICAL) if c != "T7"}
    with pytest.raises(InputSpecError, match=r"^input.columns.T7: missing: with header_row: none"):
        normalise_input_spec(
            {"format": "csv", "header_row": None, "sensors": list(SENSORS), "columns": letters}
        )


def test_two_canonical_columns_on_one_letter_are_refused():
    letters = {c: chr(65 + k) for k, c in enumerate(CANONICAL)}
    letters["T2"] = 3  # column C, as T1's "C"
    with pytest.raises(InputSpecError, match=r"^input.columns: column C is mapped to T1 and T2"):
        normalise_input_spec({"format": "csv", "header_row": "none", "columns": letters})


def test_header_row_zero_is_refused_naming_none():
    with pytest.raises(InputSpecError, match=r"^input.header_row: 0: .*or none"):
        normalise_input_spec({"format": "csv", "header_row": 0})


# --------------------------------------------------------------------------- a log per sheet


def _daily_machine(tmp_path: Path, days: int = 18) -> tuple[Path, dict]:
    folder = tmp_path / "raw" / "lathe"
    folder.mkdir(parents=True)
    truth = write_daily_workbook(folder / "daily tests.xlsx", days)
    return folder, truth


def test_every_sheet_of_an_18_sheet_workbook_is_a_log_equal_to_its_frame(tmp_path: Path):
    folder, truth = _daily_machine(tmp_path)
    spec = {"format": "xlsx", "sheet": "Tag *"}
    found, warnings = discover_logs(folder.parent, lambda m: spec)
    logs = found["lathe"]
    assert sorted(logs) == sorted(truth) and warnings == []
    for key, src in logs.items():
        assert src["sheet"] == key and Path(src["path"]).name == "daily tests.xlsx"
        got = read_log(src["path"], spec, sheet=src["sheet"], name=key)
        pd.testing.assert_frame_equal(_canonical(got), truth[key], check_dtype=False)
        assert got.attrs["metadata"]["sheet"] == key


def test_sheet_names_read_without_openpyxl_are_openpyxls(tmp_path: Path):
    _, truth = _daily_machine(tmp_path, days=5)
    path = tmp_path / "raw" / "lathe" / "daily tests.xlsx"
    assert xlsx_sheet_names(path) == openpyxl.load_workbook(path, read_only=True).sheetnames
    assert xlsx_sheet_names(path) == [*truth, "Notes"]


def test_a_sheet_name_shared_by_two_workbooks_is_prefixed_by_the_file_stem(tmp_path: Path):
    folder, _ = _daily_machine(tmp_path, days=2)
    write_daily_workbook(folder / "week.2.xlsx", 3)
    found, _ = discover_logs(folder.parent, lambda m: {"format": "xlsx", "sheet": "Tag*"})
    ids = sorted(found["lathe"])
    assert ids == ["Tag 03", "daily tests_Tag 01", "daily tests_Tag 02", "week_2_Tag 01", "week_2_Tag 02"]
    again, _ = discover_logs(folder.parent, lambda m: {"format": "xlsx", "sheet": "Tag*"})
    assert again == found


def test_sheet_log_names_are_file_name_safe():
    assert sheet_log_name("Tag 01") == "Tag 01"
    assert sheet_log_name("3.5 h / run {a}#1 %") == "3_5 h _ run _a__1 _"
    long = sheet_log_name("x" * 300)
    assert len(long.encode()) <= 100 and "." not in long and long != sheet_log_name("x" * 299)


def test_a_pattern_matching_no_sheet_of_one_workbook_warns_naming_file_pattern_and_sheets(tmp_path: Path):
    folder, _ = _daily_machine(tmp_path, days=2)
    wb = openpyxl.Workbook()
    wb.active.title = "Summary"
    wb.save(folder / "other.xlsx")
    found, warnings = discover_logs(folder.parent, lambda m: {"format": "xlsx", "sheet": "Tag *"})
    assert sorted(found["lathe"]) == ["Tag 01", "Tag 02"]
    (line,) = warnings
    assert "other.xlsx" in line and "input.sheet 'Tag *'" in line and "'Summary'" in line


def test_a_pattern_matching_no_sheet_of_any_workbook_is_an_error_naming_input_sheet(tmp_path: Path):
    _daily_machine(tmp_path, days=2)
    with pytest.raises(InputSpecError, match=r"machine 'lathe': input.sheet: 'Day \*' matches no sheet"):
        discover_logs(tmp_path / "raw", lambda m: {"format": "xlsx", "sheet": "Day *"})


def test_a_sheet_pattern_needs_format_xlsx():
    with pytest.raises(InputSpecError, match=r"^input.sheet: '\*': a sheet pattern applies to format xlsx"):
        normalise_input_spec({"format": "csv", "sheet": "*"})


def test_speed_globs_match_the_sheet_logs_name_before_the_file_name(tmp_path: Path):
    folder, _ = _daily_machine(tmp_path, days=3)
    spec = {
        "format": "xlsx",
        "sheet": "*",
        "speed": {"constant_rpm_by_file": {"Tag 02": 1500, "daily*": 4500}},
    }
    found, _ = discover_logs(folder.parent, lambda m: spec)
    path = found["lathe"]["Tag 02"]["path"]
    assert read_log(path, spec, sheet="Tag 02", name="Tag 02")["speed_rpm"].unique().tolist() == [1500.0]
    assert read_log(path, spec, sheet="Tag 01", name="Tag 01")["speed_rpm"].unique().tolist() == [4500.0]


def test_the_clean_step_writes_one_log_per_sheet_with_its_own_hash(tmp_path: Path):
    folder, truth = _daily_machine(tmp_path, days=3)
    spec = normalise_input_spec({"format": "xlsx", "sheet": "Tag *"})
    found, _ = discover_logs(folder.parent, lambda m: spec)
    logs = found["lathe"]
    settings = CleanSettings(
        input_spec=spec,
        sample_period_s=60.0,
        clean={"max_interpolate_gap_s": 300, "spike_threshold": 8.0, "open_circuit_values": []},
        checks={"sample_period_s": 60.0},
    )
    out = tmp_path / "clean"
    done = clean_machine(
        {k: s["path"] for k, s in logs.items()},
        out,
        settings,
        fail_mode=True,
        log=__import__("logging").getLogger("test"),
        parts={k: {"sheet": s["sheet"], "partner": None} for k, s in logs.items()},
    )
    assert done == {k: "ok" for k in truth}
    summaries = pd.concat(pd.read_csv(out / f"{k}.summary.csv") for k in truth)
    assert sorted(summaries["file"]) == sorted(truth)
    assert summaries["sha256"].nunique() == len(truth)
    for key in truth:
        assert len(pd.read_parquet(out / f"{key}.parquet")) == len(truth[key])


def test_log_stamps_differ_by_sheet_and_partner_and_keep_an_unreadable_file():
    a = "sha256:" + "0" * 64
    assert log_stamp(a) == a
    assert log_stamp(a, "Tag 01") != log_stamp(a, "Tag 02")
    assert log_stamp(a, None, "sha256:1") != log_stamp(a, None, "sha256:2")
    assert log_stamp("unreadable:EACCES", "Tag 01") == "unreadable:EACCES"


# --------------------------------------------------------------------------- two files joined

JOIN = {"replace": ["temps", "disp"], "columns": ["disp_um"]}


def _pair_spec(**join) -> dict:
    return {
        "format": "csv",
        "columns": {"time": "time", "disp_um": "Weg [um]"},
        "join": {**JOIN, **join, "input": {"columns": {"time": "Zeit", "disp_um": "Weg [um]"}}},
    }


def test_a_partner_joined_by_time_gives_the_frame_written(tmp_path: Path):
    truth = canonical_frame(60, seed=7)
    main, partner = write_split_pair(tmp_path, truth, shift_s=20)  # within half of 60 s
    got = read_log(main, _pair_spec(), partner=partner)
    pd.testing.assert_frame_equal(_canonical(got), truth, check_dtype=False)
    assert got.attrs["metadata"]["join"] == {
        "partner": partner.name,
        "by": "time",
        "columns": ["disp_um"],
        "unmatched_rows": 0,
    }


def test_rows_without_a_partner_row_are_empty_and_counted(tmp_path: Path):
    truth = canonical_frame(100, seed=8)
    main, partner = write_split_pair(tmp_path, truth, drop=2)
    got = read_log(main, _pair_spec(), partner=partner)
    missing = got["disp_um"].isna().to_numpy()
    assert missing.sum() == 2 and got.attrs["metadata"]["join"]["unmatched_rows"] == 2
    np.testing.assert_array_equal(got["disp_um"].to_numpy()[~missing], truth["disp_um"].to_numpy()[~missing])


def test_too_many_rows_without_a_partner_is_an_error_naming_both_files(tmp_path: Path):
    truth = canonical_frame(50, seed=9)
    main, partner = write_split_pair(tmp_path, truth, shift_s=3600)
    with pytest.raises(RawFormatError, match=r"temps_0312.csv.*partner file disp_0312.csv") as info:
        read_log(main, _pair_spec(), partner=partner)
    assert "input.join.max_unmatched" in str(info.value) and "2026-03-02 07:00:00" in str(info.value)


def test_a_partner_running_on_past_the_file_is_an_error(tmp_path: Path):
    truth = canonical_frame(50, seed=9)
    main, partner = write_split_pair(tmp_path, truth, extra=10)
    with pytest.raises(RawFormatError, match=r"10 of the partner's 60 rows lie outside this file's times"):
        read_log(main, _pair_spec(), partner=partner)


def test_a_partner_joined_by_row_gives_the_frame_written(tmp_path: Path):
    truth = canonical_frame(30, seed=10)
    main, partner = write_split_pair(tmp_path, truth)
    rows = pd.read_csv(partner).iloc[::-1]  # back in the file's order
    rows.to_csv(partner, index=False)
    got = read_log(main, _pair_spec(by="row"), partner=partner)
    pd.testing.assert_frame_equal(_canonical(got), truth, check_dtype=False)


def test_by_row_with_another_number_of_rows_is_an_error_naming_both_files(tmp_path: Path):
    main, partner = write_split_pair(tmp_path, canonical_frame(30, seed=10), drop=1)
    with pytest.raises(
        RawFormatError, match=r"temps_0312.csv.*30 data rows, but its partner file disp_0312.csv has 29"
    ):
        read_log(main, _pair_spec(by="row"), partner=partner)


def test_a_missing_partner_is_an_error_naming_the_expected_name(tmp_path: Path):
    main, partner = write_split_pair(tmp_path, canonical_frame(10))
    partner.unlink()
    with pytest.raises(RawFormatError, match=r"no partner file 'disp_0312.csv'.*input.join.replace"):
        read_log(main, _pair_spec(), partner=partner)


def test_partners_are_not_logs_and_a_missing_one_is_warned_about_while_planning(tmp_path: Path):
    folder = tmp_path / "raw" / "lathe"
    folder.mkdir(parents=True)
    write_split_pair(folder, canonical_frame(10), stem="a")
    _, gone = write_split_pair(folder, canonical_frame(10), stem="b")
    gone.unlink()
    (folder / "readme.csv").write_text("x\n1\n")
    found, warnings = discover_logs(folder.parent, lambda m: _pair_spec())
    logs = found["lathe"]
    assert sorted(logs) == ["temps_a", "temps_b"]
    assert logs["temps_a"]["partner"] == str(folder / "disp_a.csv") and logs["temps_a"]["sheet"] is None
    assert any("no partner file 'disp_b.csv'" in w for w in warnings)
    assert any("readme.csv" in w and "neither 'temps'" in w for w in warnings)


def test_join_keys_are_checked_naming_the_key():
    with pytest.raises(InputSpecError, match=r"^input.join.replace: "):
        normalise_input_spec({"format": "csv", "join": {"replace": ["temps"]}})
    with pytest.raises(InputSpecError, match=r"^input.join.by: 'date'"):
        normalise_input_spec({"format": "csv", "join": {"replace": ["a", "b"], "by": "date"}})
    with pytest.raises(InputSpecError, match=r"^input.join.columns: time is read from both"):
        normalise_input_spec({"format": "csv", "join": {"replace": ["a", "b"], "columns": ["time"]}})
    with pytest.raises(InputSpecError, match=r"^input.join.input.pattern: not a layout key"):
        normalise_input_spec({"format": "csv", "join": {"replace": ["a", "b"], "input": {"pattern": "*"}}})


def test_a_wrong_partner_layout_names_the_join_input_key(tmp_path: Path):
    main, partner = write_split_pair(tmp_path, canonical_frame(10))
    spec = _pair_spec()
    spec["join"]["input"]["header_row"] = 0
    with pytest.raises(InputSpecError, match=r"^input.join.input.header_row: 0"):
        read_log(main, spec, partner=partner)


# --------------------------------------------------------------------------- the schema


@pytest.mark.parametrize(
    "mapping",
    [
        {"format": "xlsx", "header_row": "none", "columns": {"T1": "C", "disp_um": 4}},
        {"format": "xlsx", "header_row": None, "sheet": "Tag *"},
        {"format": "csv", "join": {"replace": ["temps", "disp"], "by": "row", "input": {"header_row": 2}}},
    ],
)
def test_the_schema_accepts_the_new_keys(mapping):
    jsonschema.validate(mapping, INPUT_SCHEMA)


@pytest.mark.parametrize(
    "mapping",
    [
        {"header_row": "no"},
        {"columns": {"T1": 0}},
        {"join": {"replace": ["a"]}},
        {"join": {"replace": ["a", "b"], "by": "date"}},
        {"join": {"replace": ["a", "b"], "input": {"pattern": "*"}}},
    ],
)
def test_the_schema_refuses_wrong_values(mapping):
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate({"format": "csv", **mapping}, INPUT_SCHEMA)


# --------------------------------------------------------------------------- the real Snakefile


@pytest.mark.slow
def test_the_workflow_cleans_every_sheet_of_a_workbook_and_reruns_on_a_changed_sheet(tmp_path: Path):
    import os

    import yaml
    from project_copy import copy_project, run_snakemake, settle

    proj = copy_project(tmp_path / "proj")
    config = yaml.safe_load((proj / "config.yaml").read_text(encoding="utf-8"))
    config["machines"] = {"lathe": {"input": {"format": "xlsx", "sheet": "Tag *"}, "sample_period_s": 60}}
    (proj / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")
    folder = proj / "raw" / "lathe"
    folder.mkdir(parents=True)
    book = folder / "daily tests.xlsx"
    truth = write_daily_workbook(book, 18)
    settle(book)

    dry = run_snakemake(proj, "-n", "results/lathe/clean")
    assert dry.returncode == 0, dry.stderr[-3000:]
    run = run_snakemake(proj, "results/lathe/clean")
    assert run.returncode == 0, run.stderr[-3000:]
    clean = proj / "results" / "lathe" / "clean"
    assert sorted(p.name[: -len(".parquet")] for p in clean.glob("*.parquet")) == sorted(truth)
    for name, frame in truth.items():
        assert len(pd.read_parquet(clean / f"{name}.parquet")) == len(frame)
    summaries = pd.concat(pd.read_csv(p) for p in clean.glob("*.summary.csv"))
    assert set(summaries["status"]) == {"ok"} and summaries["sha256"].nunique() == 18

    assert "Nothing to be done" in (run_snakemake(proj, "-n", "results/lathe/clean").stdout)
    # one cell of one sheet changed, size and mtime kept: the content stamps re-run the job
    st = book.stat()
    wb = openpyxl.load_workbook(book)
    wb["Tag 07"]["C2"] = float(wb["Tag 07"]["C2"].value) + 1.0
    wb.save(book)
    os.utime(book, ns=(st.st_atime_ns, st.st_mtime_ns))
    again = run_snakemake(proj, "-n", "results/lathe/clean")
    assert again.returncode == 0 and "Nothing to be done" not in again.stdout
    assert "clean" in again.stdout


@pytest.mark.slow
def test_the_workflow_joins_a_partner_and_reruns_when_only_the_partner_changes(tmp_path: Path):
    import os

    import yaml
    from project_copy import copy_project, run_snakemake, settle

    proj = copy_project(tmp_path / "proj")
    config = yaml.safe_load((proj / "config.yaml").read_text(encoding="utf-8"))
    spec = _pair_spec()
    config["machines"] = {"rig": {"input": spec, "sample_period_s": 60}}
    (proj / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")
    folder = proj / "raw" / "rig"
    folder.mkdir(parents=True)
    truth = canonical_frame(45, seed=11)
    main, partner = write_split_pair(folder, truth)
    for path in (main, partner):
        settle(path)

    run = run_snakemake(proj, "results/rig/clean")
    assert run.returncode == 0, run.stderr[-3000:]
    clean = pd.read_parquet(proj / "results" / "rig" / "clean" / "temps_0312.parquet")
    np.testing.assert_allclose(clean["disp_um"].to_numpy(), truth["disp_um"].to_numpy())
    assert not (proj / "results" / "rig" / "clean" / "disp_0312.parquet").exists()

    st = partner.stat()
    partner.write_text(partner.read_text(encoding="utf-8").replace(",", ",1", 1), encoding="utf-8")
    os.utime(partner, ns=(st.st_atime_ns, st.st_mtime_ns))
    again = run_snakemake(proj, "-n", "results/rig/clean")
    assert again.returncode == 0 and "Nothing to be done" not in again.stdout


@pytest.mark.parametrize("sheet", ["Tag 01", "3.5 h", "a.b.xlsx", "x/y:z", "{w}%#1", "Ä" * 80, "  "])
def test_a_sheet_logs_name_is_its_own_stem_and_log_id(sheet):
    from rafi.method.runs import _stem
    from rafi.readers.input_spec import log_id

    name = sheet_log_name(sheet)
    assert Path(name).stem == name and log_id(name) == name and _stem(name) == name
