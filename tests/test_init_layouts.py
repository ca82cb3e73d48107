"""``rafi init`` on the workbook and file layouts of issue 45: files without a header row, a
workbook of one test per sheet, temperatures and displacement in two files a run.

The files are the twin's (:mod:`rafi.twin.layouts`, whose ``layout_config`` is the truth) and
the readers' test generators (tests/layout_files.py); each proposal is read back with the
pipeline's own readers.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import openpyxl
import pytest
from layout_files import (
    canonical_frame,
    write_daily_workbook,
    write_headerless_csv,
    write_sheet_pair,
    write_split_pair,
)

from rafi.ops.init_cli import findings
from rafi.ops.init_config import config_block, parse_block
from rafi.ops.init_pairs import main_pattern, pair_parts, sheet_glob
from rafi.ops.init_survey import probe_names, survey
from rafi.readers.infer_files import read_unknown, read_unknown_logs
from rafi.readers.input_spec import normalise_input_spec
from rafi.readers.log_sources import expand_logs
from rafi.readers.logs import read_log
from rafi.readers.mapped_table import excel_column
from rafi.twin.layouts import DAILY_SHEETS, LAYOUTS, PAIR_PARTS, layout_config, write_layout


def propose(machine: str, files: list[Path]) -> tuple[object, dict]:
    """The survey of ``files`` and the ``machines.<machine>`` entry rafi init proposes for them."""
    s = survey(machine, [t for f in files for t in read_unknown_logs(f)])
    return s, parse_block(config_block(s), machine)


def read_proposal(entry: dict, files: list[Path]) -> list:
    """Every log the proposal's ``input`` finds among ``files``, read as the pipeline reads it."""
    spec = normalise_input_spec(entry["input"])
    matching = [f for f in files if Path(f).match(spec["pattern"])]
    logs, _ = expand_logs(sorted(matching), spec)
    return [read_log(x["path"], spec, sheet=x["sheet"], partner=x["partner"]) for x in logs.values()]


# --------------------------------------------------------------------------- names


def test_pair_parts_finds_the_texts_that_tell_a_file_from_its_partner():
    mains = ["temps_0312.csv", "temps_0313.csv"]
    assert pair_parts(mains, ["disp_0313.csv", "disp_0312.csv"]) == ("temps", "disp")
    # whole words: the common 'temp' of the two names belongs to the texts
    assert pair_parts(["run1_temperatures.csv"], ["run1_tempdisp.csv"]) == ("temperatures", "tempdisp")
    assert pair_parts(mains, ["disp_0312.csv"]) is None  # a partner missing
    assert pair_parts(mains, ["disp_0312.csv", "disp_9999.csv"]) is None  # not partners by name
    assert main_pattern("temps", mains, ".csv") == "temps*.csv"
    assert main_pattern("temps", ["a_temps.csv", "temps_b.csv"], ".csv") == "*temps*.csv"


def test_sheet_glob_matches_exactly_the_log_sheets():
    days = [f"Tag {d:02d}" for d in range(1, 19)]
    assert sheet_glob(days, days) == "*"
    assert sheet_glob(days, ["Info", *days]) == "Tag *"
    assert sheet_glob(["Tag 01", "Tag 02"], ["Tag 01", "Tag 02", "Tag 03"]) is None  # Tag 03 differs
    assert sheet_glob(["Mon", "Tue"], ["Mon", "Tue", "Notes"]) is None  # no common start


# --------------------------------------------------------------------------- no header row


def test_a_headerless_workbook_gets_header_row_none_and_its_columns_by_letter(tmp_path):
    files = write_layout("headerless-xlsx", tmp_path)
    table = read_unknown(files[0])
    assert table.headerless and table.header == list("ABCDEFGHI")
    s, entry = propose("rig", files)
    truth = layout_config("headerless-xlsx")["input"]
    assert normalise_input_spec(entry["input"])["header_row"] is None
    columns = entry["input"]["columns"]
    assert (
        columns["time"] == truth["columns"]["time"] and columns["speed_rpm"] == truth["columns"]["speed_rpm"]
    )
    assert [v for k, v in columns.items() if k not in ("time", "speed_rpm")] == list("CDEFGH")
    assert entry["input"]["displacement"]["column"] == truth["columns"]["disp_um"]
    assert list(columns)[2:] == [f"T{k}" for k in range(1, 7)]  # no header to name them by
    assert any(c.startswith("input.columns: no header row") for c in s.checks)
    assert "# CHECK: no header row" in config_block(s)
    assert any("no header row" in line for line in findings(s))
    frames = read_proposal(entry, files)
    assert len(frames) == len(files)
    expected = openpyxl.load_workbook(sorted(files)[0], read_only=True).active  # the first log
    first = next(expected.iter_rows(values_only=True))
    assert frames[0]["disp_um"].iloc[0] == pytest.approx(first[-1])
    assert frames[0]["speed_rpm"].iloc[0] == pytest.approx(first[1])


def test_a_headerless_csv_behind_a_preamble_is_read_from_its_first_row_of_numbers(tmp_path):
    frame = canonical_frame(60, seed=3)
    path = tmp_path / "log.csv"
    positions = write_headerless_csv(path, frame, preamble=2)
    table = read_unknown(path)
    assert table.headerless and table.layout["skip_rows"] == 2 and table.n_rows == 60
    s, entry = propose("rig", [path])
    assert entry["input"]["header_row"] == "none" and entry["input"]["skip_rows"] == 2
    time = excel_column(positions["time"] - 1)  # the last column, written first in time
    assert entry["input"]["columns"]["time"] == time
    # one speed all along, no header to say so: not taken for a speed, left to the user
    assert "speed_rpm" not in entry["input"]["columns"]
    assert any(c.startswith("input.speed:") for c in s.checks)


def test_a_file_with_a_header_is_not_taken_for_a_headerless_one(tmp_path):
    files = write_layout("sensors-6-diameter", tmp_path)
    table = read_unknown(files[0])
    assert not table.headerless and table.layout["header_row"] == 1


# --------------------------------------------------------------------------- sheets


def test_a_workbook_of_daily_sheets_gets_a_sheet_pattern_and_every_sheet_is_a_log(tmp_path):
    files = write_layout("sheets-18", tmp_path)
    tables = read_unknown_logs(files[0])
    assert sorted(t.name for t in tables) == [f"Tag {d:02d}" for d in range(1, DAILY_SHEETS + 1)]
    s, entry = propose("tc", files)
    assert entry["input"]["sheet"] == "Tag *"  # the Info sheet is not a log
    assert len(s.shapes) == DAILY_SHEETS  # every sheet's speed steps were looked at
    assert sorted(entry["training_speeds_rpm"]) == [3000, 6000, 9000, 15000]  # no sheet says 'train'
    assert any("18 sheets share one layout" in line for line in findings(s))
    frames = read_proposal(entry, files)
    assert len(frames) == DAILY_SHEETS
    assert all(len(f.columns.intersection(["disp_um", "speed_rpm"])) == 2 for f in frames)


def test_sheets_of_one_layout_without_a_pattern_leave_the_sheet_to_check(tmp_path):
    path = tmp_path / "book.xlsx"
    write_daily_workbook(path, days=3, extra_sheets=("Notes",))
    wb = openpyxl.load_workbook(path)
    wb["Tag 03"].title = "Montag"
    wb.save(path)
    s, entry = propose("tc", [path])
    assert s.sheet_glob is None
    assert entry["input"]["sheet"] in ("Tag 01", "Tag 02", "Montag")
    assert any(c.startswith("input.sheet:") for c in s.checks)


def test_every_sheet_is_a_log_when_every_sheet_holds_one(tmp_path):
    path = tmp_path / "book.xlsx"
    write_daily_workbook(path, days=4, extra_sheets=())
    s, entry = propose("tc", [path])
    assert entry["input"]["sheet"] == "*"


# --------------------------------------------------------------------------- two files


def test_files_in_pairs_by_name_are_joined(tmp_path):
    files = write_layout("two-files", tmp_path)
    s, entry = propose("tc", files)
    truth = layout_config("two-files")["input"]
    assert entry["input"]["join"] == truth["join"]
    assert entry["input"]["displacement"]["column"] == LAYOUTS["two-files"].displacement_header
    assert [Path(f).name for f in files if Path(f).match(entry["input"]["pattern"])] == [
        Path(f).name for f in files if Path(f).name.startswith(PAIR_PARTS[0])
    ]
    assert s.sign == 1  # the probe's direction read from the partner, row beside row
    frames = read_proposal(entry, files)
    assert len(frames) == 5
    assert frames[0]["disp_um"].abs().max() > 5.0


def test_split_pair_with_its_own_headers_names_the_partners_columns(tmp_path):
    frame = canonical_frame(60, seed=1)
    frame["disp_um"] = np.round(np.linspace(0, 20, 60), 3)  # a smooth warm-up
    main, partner = write_split_pair(tmp_path, frame, stem="0312")
    main2, partner2 = write_split_pair(
        tmp_path, canonical_frame(60, seed=2, start="2026-03-03 06:00"), stem="0313"
    )
    s, entry = propose("tc", [main, partner, main2, partner2])
    join = entry["input"]["join"]
    assert join["replace"] == ["temps", "disp"] and join["by"] == "time"
    assert join["input"]["columns"] == {"time": "Zeit", "disp_um": "Weg [um]"}  # the partner's time header
    frames = read_proposal(entry, [main, partner, main2, partner2])
    assert len(frames) == 2
    assert frames[0]["disp_um"].to_numpy() == pytest.approx(frame["disp_um"].to_numpy())


def test_files_of_two_layouts_not_in_pairs_are_not_joined(tmp_path):
    frame = canonical_frame(60, seed=1)
    main, partner = write_split_pair(tmp_path, frame, stem="0312")
    other = partner.rename(tmp_path / "weg_9999.csv")
    s, _ = propose("tc", [main, other])
    assert s.join is None
    assert any("another layout" in n for n in s.notes)


def test_daily_sheets_with_the_displacement_alone_in_a_one_column_partner_workbook(tmp_path):
    truth = write_sheet_pair(tmp_path, days=4)
    files = [tmp_path / "rig_X.xlsx", tmp_path / "rig_Y.xlsx"]
    (partner,) = {t.path for t in read_unknown_logs(files[1])}  # one column: still a table
    s, entry = propose("tc", files)
    spec = entry["input"]
    assert spec["sheet"] == "*" and spec["join"] == {"replace": ["X", "Y"], "by": "row"}
    assert spec["displacement"]["column"] == "Dia Disp" and spec["time"]["kind"] == "none"
    assert len(spec["columns"]) == 4  # the four temperatures under their own names
    said = "\n".join(findings(s))  # why each log is a run, and why the probe's sign is not read
    assert "layout: separate runs (4 log(s) without a speed column or a clock" in said
    assert "sign: the probe's convention is not in the data; without a speed column" in said
    spec["time"]["period_s"] = 60  # what the data cannot tell (a CHECK line)
    spec["speed"] = {"constant_rpm": 1000}
    frames = read_proposal({**entry, "sample_period_s": 60}, files)
    assert len(frames) == 4
    for frame, (temps, disp) in zip(frames, truth.values()):
        assert frame["disp_um"].to_numpy() == pytest.approx(disp)
        assert frame[list(spec["columns"])].to_numpy() == pytest.approx(temps)


# --------------------------------------------------------------------------- column order, offsets


def write_reordered_csv(path: Path, frame, order: list[str]) -> None:
    """``frame`` as a csv with readable headers, its columns in ``order`` (canonical names)."""
    headers = {"time": "Zeit", "speed_rpm": "Spindle speed [rpm]", "disp_um": "Z [um]"}
    out = frame[order].rename(columns=headers)
    out["Zeit"] = frame["time"].dt.strftime("%Y-%m-%d %H:%M:%S")
    path.write_text(out.to_csv(index=False), encoding="utf-8")


def test_files_with_the_same_columns_in_another_order_are_one_layout_and_all_surveyed(tmp_path):
    files, truth = [], []
    columns = list(canonical_frame(2).columns)
    for day, rpm in enumerate((1000, 3000, 6000)):
        frame = canonical_frame(60, seed=day, start=f"2026-06-0{day + 1} 06:00")
        frame["speed_rpm"] = float(rpm)
        order = list(np.random.default_rng(day).permutation(columns)) if day else columns
        files.append(tmp_path / f"2026060{day + 1}.csv")
        write_reordered_csv(files[-1], frame, order)
        truth.append(frame)
    s, entry = propose("daily", files)
    assert not any("another layout" in n for n in s.notes)
    assert any("in another order" in n for n in s.notes)
    assert len(s.logs) == len(s.shapes) == 3
    assert sorted(entry["training_speeds_rpm"]) == [1000, 3000, 6000]  # every file's speed, not the first's
    frames = read_proposal(entry, files)
    assert len(frames) == 3
    for frame, expected in zip(frames, truth):
        assert frame["disp_um"].to_numpy() == pytest.approx(expected["disp_um"].to_numpy())
        assert frame["T7"].to_numpy() == pytest.approx(expected["T7"].to_numpy())


def test_files_of_the_same_columns_written_with_another_delimiter_are_another_layout_said_at_the_pattern(
    tmp_path,
):
    """One block reads one delimiter and decimal mark: a file written with ``;`` and decimal
    commas beside ``,`` files is another layout (not surveyed, said), and the proposed pattern,
    which matches it too, carries a CHECK naming it."""
    columns = list(canonical_frame(2).columns)
    files = []
    for day in range(2):
        files.append(tmp_path / f"2026060{day + 1}.csv")
        write_reordered_csv(
            files[-1], canonical_frame(60, seed=day, start=f"2026-06-0{day + 1} 06:00"), columns
        )
    german = tmp_path / "2026060z.csv"
    text = files[1].read_text(encoding="utf-8")
    german.write_text(
        "\n".join(ln.replace(",", ";").replace(".", ",") for ln in text.splitlines()), encoding="utf-8"
    )
    s = survey("mixed", [t for f in [*files, german] for t in read_unknown_logs(f)])
    assert [t.path.name for t in s.logs] == ["20260601.csv", "20260602.csv"]
    assert any(n.startswith("2026060z.csv: another layout") for n in s.notes)
    block = config_block(s)
    check = next(ln for ln in block.splitlines() if "another layout" in ln)
    assert "CHECK" in check and "2026060z.csv" in check
    assert parse_block(block, "mixed")["input"]["pattern"] == "*.csv"


def test_iso_times_with_a_utc_offset_are_read_as_utc_as_the_pipeline_reads_them(tmp_path):
    frame = canonical_frame(120, seed=4, start="2026-03-29 00:00")  # UTC; Europe/Berlin: DST at 01:00
    local = frame["time"].dt.tz_localize("UTC").dt.tz_convert("Europe/Berlin")
    cells = [t.isoformat() for t in local]  # '+01:00' then '+02:00'
    assert {c[-6:] for c in cells} == {"+01:00", "+02:00"}
    path = tmp_path / "log.csv"
    out = frame.rename(columns={"time": "Time", "speed_rpm": "Speed [rpm]", "disp_um": "Z [um]"})
    out["Time"] = cells
    path.write_text(out.to_csv(index=False), encoding="utf-8")
    s, entry = propose("tz", [path])  # it stopped with a TypeError (aware Timestamps)
    assert s.time is not None and s.time.unit == "timestamp" and "UTC" in s.time.why
    assert s.period_s == 60 and s.regular_share == 1.0  # the DST change is no gap: UTC is regular
    assert entry["input"]["time"] == {"kind": "timestamp"}
    (read,) = read_proposal(entry, [path])
    assert (read["time"].to_numpy() == frame["time"].to_numpy()).all()

    path.write_text(out.assign(Time=[f"{t:%Y-%m-%dT%H:%M:%S}Z" for t in frame["time"]]).to_csv(index=False))
    s, entry = propose("tz", [path])
    assert s.period_s == 60 and entry["input"]["time"] == {"kind": "timestamp"}


# --------------------------------------------------------------------------- text above and around


def test_a_key_value_preamble_above_the_header_is_not_taken_for_it(tmp_path):
    frame = canonical_frame(60, seed=5)
    out = frame.rename(columns={"time": "Timestamp", "speed_rpm": "Spindle Speed", "disp_um": "Z Displ"})
    units = ["", "rpm", *["degC"] * 16, "um"]
    preamble = "Machine,HMC-800 #3\nStart,2026-03-02 06:00:00\nSample interval,60 s\n\n"
    lines = out.to_csv(index=False).split("\n", 1)
    path = tmp_path / "export.csv"
    path.write_text(preamble + lines[0] + "\n" + ",".join(units) + "\n" + lines[1], encoding="utf-8")
    table = read_unknown(path)  # it took 'Sample interval,60 s' for the header of 19 columns
    assert table.layout["header_row"] == 5 and table.layout["skip_rows"] == 1
    assert table.header[0] == "Timestamp" and table.n_rows == 60
    s, entry = propose("pre", [path])
    assert entry["input"]["header_row"] == 5 and entry["input"]["skip_rows"] == 1
    (read,) = read_proposal(entry, [path])
    assert read["disp_um"].to_numpy() == pytest.approx(frame["disp_um"].to_numpy())


@pytest.mark.parametrize("delimiter, decimal", [(",", "."), (";", ",")])
def test_a_csv_with_every_field_in_double_quotes_is_read_as_the_pipeline_reads_it(
    tmp_path, delimiter, decimal
):
    import csv

    frame = canonical_frame(60, seed=6)
    out = frame.rename(columns={"time": "Time", "speed_rpm": "Speed [rpm]", "disp_um": "Disp Z (um)"})
    out["Time"] = frame["time"].dt.strftime("%d.%m.%Y %H:%M:%S")
    path = tmp_path / "quoted.csv"
    out.to_csv(path, sep=delimiter, decimal=decimal, index=False, quoting=csv.QUOTE_ALL)
    assert path.read_text().startswith('"Time"')
    table = read_unknown(path)  # 'no header line followed by rows of numbers'
    assert (table.layout["delimiter"], table.layout["decimal"]) == (delimiter, decimal)
    s, entry = propose("quoted", [path])
    assert s.time is not None and s.period_s == 60 and len(s.sensors) == 16
    (read,) = read_proposal(entry, [path])
    assert read["disp_um"].to_numpy() == pytest.approx(frame["disp_um"].to_numpy())
    assert read["T16"].to_numpy() == pytest.approx(frame["T16"].to_numpy())


# --------------------------------------------------------------------------- time formats


def test_a_us_12_hour_clock_is_proposed_as_a_time_format_the_pipeline_reads(tmp_path):
    frame = canonical_frame(150, seed=7, start="2026-10-31 10:50")  # AM, noon, PM
    out = frame.rename(columns={"time": "Date Time", "speed_rpm": "Spindle Speed (RPM)", "disp_um": "Z (um)"})
    out["Date Time"] = frame["time"].dt.strftime("%m/%d/%Y %I:%M:%S %p")
    assert {"10/31/2026 11:59:00 AM", "10/31/2026 12:00:00 PM", "10/31/2026 01:00:00 PM"} <= set(
        out["Date Time"]
    )
    path = tmp_path / "us.csv"
    path.write_text(out.to_csv(index=False), encoding="utf-8")
    s, entry = propose("us", [path])  # 'no time column'
    assert s.time is not None and s.period_s == 60 and s.regular_share == 1.0
    assert entry["input"]["time"] == {"kind": "timestamp", "format": "%m/%d/%Y %I:%M:%S %p"}
    assert not any(c for c in s.checks if "day/month" in c)  # the 31st is a day
    (read,) = read_proposal(entry, [path])
    assert (read["time"].to_numpy() == frame["time"].to_numpy()).all()

    out["Date Time"] = frame["time"].dt.strftime("03/02/2026 %I:%M:%S %p")  # 2 March or 3 February
    path.write_text(out.to_csv(index=False), encoding="utf-8")
    s, _ = propose("us", [path])
    assert s.time.check == "day/month or month/day? both read every cell; set time.format"


# --------------------------------------------------------------------------- names


def test_probe_names_leave_the_unit_at_the_end_of_a_header_out():
    assert probe_names(["X_um", "Y_mm", "Z_um"]) == ["X", "Y", "Z"]
    assert probe_names(["dX_um", "dZ_µm"]) == ["dX", "dZ"]
    assert probe_names(["Z_um", "Z_mm"]) == ["Z_um", "Z_mm"]  # one name for two probes: kept whole
    assert probe_names(["ch1(um)", "ch2(um)"]) == ["ch1", "ch2"]


def test_probes_of_a_log_are_proposed_under_their_axis_names(tmp_path):
    frame = canonical_frame(120, seed=8)
    frame["speed_rpm"] = np.where(np.arange(120) < 10, 0.0, 3000.0)
    warm = 1 - np.exp(-np.arange(120) / 40)
    out = frame.drop(columns=["disp_um"]).rename(columns={"time": "Time", "speed_rpm": "Speed [rpm]"})
    out["Z_um"], out["Y_mm"] = np.round(12 * warm, 3), np.round(0.004 * warm, 4)
    path = tmp_path / "log.csv"
    path.write_text(out.to_csv(index=False), encoding="utf-8")
    _, entry = propose("axes", [path])
    assert entry["input"]["probes"] == {"Z": {"column": "Z_um"}, "Y": {"column": "Y_mm", "unit": "mm"}}


def test_each_probe_is_said_with_its_own_direction_while_the_spindle_heats(tmp_path):
    """Three probes of one machine: the twin's Y probe moves against the spindle's growth (its gain
    is negative in the layout, the ground truth). ``rafi init`` said one direction, the first
    probe's, for all; now each probe's line says its own and the checks name the one that differs."""
    gains = {name: gain for name, _, gain, _ in LAYOUTS["probes-xyz"].probes}
    files = write_layout("probes-xyz", tmp_path / "raw")
    s = survey("probes-xyz", [t for p in files for t in read_unknown_logs(p)])
    assert [sign for sign, _ in s.probe_signs] == [1 if gains[n] > 0 else -1 for n in ("X", "Y", "Z")]
    assert (s.sign, s.sign_why) == s.probe_signs[0]
    lines = {ln.split(":")[0].strip(): ln for ln in config_block(s).splitlines() if ": {column: " in ln}
    assert "falls while the spindle heats" in lines["dY"]
    assert "rises while the spindle heats" in lines["dX"] and "rises while the spindle heats" in lines["dZ"]
    (apart,) = [c for c in s.checks if c.startswith("input.probes: unlike")]
    assert "dY it falls" in apart and "dZ" not in apart
    entry = parse_block(config_block(s), "probes-xyz")
    assert all("sign" not in p for p in entry["input"]["probes"].values())  # the user's decision
