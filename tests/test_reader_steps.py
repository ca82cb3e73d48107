"""The steps of the readers (rafi.readers.native, mapped, mapped_table, mapped_time), one at a time.

Each input is built here from known values, so every test knows what the step must return.
"""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from rafi import REQUIRED_COLUMNS, SENSORS
from rafi.errors import RawFormatError
from rafi.readers.input_spec import normalise_input_spec
from rafi.readers.mapped import (
    _add_extra_columns,
    _canonical_values,
    _column_positions,
    _mapped_metadata,
)
from rafi.readers.mapped_table import Table, read_csv_table, read_table
from rafi.readers.mapped_time import _cell_time, _cell_times, _elapsed_times, _text_times
from rafi.readers.native import _check_header, _parse_times, _parse_values, _split_rows

PATH = Path("log.csv")
HEADER = list(REQUIRED_COLUMNS)


def _row(k: int, speed: str = "3000") -> str:
    """Data line k of a native log: time 08:00:00 + 5 k s, T_i = i + k / 10, disp = k."""
    temps = ",".join(f"{i + k / 10:.1f}" for i in range(1, 17))
    return f"2026-03-01T08:00:{5 * k:02d},{speed},{temps},{k}.000"


def _table(header: list[str], rows: list[list], sheet: str | None = None) -> Table:
    return Table(PATH, header, rows, list(range(2, 2 + len(rows))), 1, sheet)


# --------------------------------------------------------------------------- native


def test_check_header_names_the_first_problem():
    _check_header(PATH, HEADER, 1)  # the canonical header passes
    with pytest.raises(RawFormatError, match=r"separated by ';'"):
        _check_header(PATH, [";".join(HEADER)], 1)
    with pytest.raises(RawFormatError, match=r"'T3' appears twice") as info:
        _check_header(PATH, [*HEADER, "T3"], 4)
    assert info.value.line == 4 and info.value.column == "T3"
    with pytest.raises(RawFormatError, match=r"missing from header: T5, disp_um;") as info:
        _check_header(PATH, [c for c in HEADER if c not in ("T5", "disp_um")], 1)
    assert info.value.column == "T5"


def test_check_header_of_another_logger_points_to_rafi_init():
    """A header sharing (nearly) nothing with the native layout is another logger's log in a
    folder without its input block: the message says so and names `rafi init`, instead of
    listing every native column twice."""
    foreign = ["Date Time", "Spindle Speed (RPM)", *[f"Spindle Temp {i} (F)" for i in range(1, 17)], "Z (um)"]
    with pytest.raises(RawFormatError) as info:
        _check_header(Path("raw/new-lathe/log.csv"), foreign, 1)
    text = str(info.value)
    assert "not the native layout" in text and "19 of 19 missing" in text
    assert "rafi init --machine NAME raw/new-lathe/" in text and "'Date Time'" in text
    assert "expected time" not in text and info.value.line == 1 and info.value.column == "time"


def test_split_rows_skips_blank_lines_strips_fields_and_numbers_each_line():
    body = [_row(0), "", f" {_row(1)} ".replace(",", " , "), "   ", _row(2)]
    rows, lines = _split_rows(PATH, body, HEADER, 3)
    assert lines == [4, 6, 8]  # header on line 3, blank lines 5 and 7
    assert [r[-1] for r in rows] == ["0.000", "1.000", "2.000"]
    assert all(len(r) == len(HEADER) and r == [f.strip() for f in r] for r in rows)


def test_split_rows_refuses_a_repeated_header_a_short_row_and_no_rows():
    with pytest.raises(RawFormatError, match="header line is repeated") as info:
        _split_rows(PATH, [_row(0), ",".join(HEADER)], HEADER, 1)
    assert info.value.line == 3
    with pytest.raises(RawFormatError) as info:
        _split_rows(PATH, [_row(0), _row(1).rsplit(",", 1)[0]], HEADER, 1)
    assert info.value.line == 3
    with pytest.raises(RawFormatError, match="header found but no data rows"):
        _split_rows(PATH, ["", ""], HEADER, 1)


def test_parse_times_converts_offsets_to_utc_and_names_the_bad_line():
    got = _parse_times(PATH, ["2026-03-01T08:00:00", "2026-03-01T10:00:05+02:00"], [2, 3])
    assert list(got) == [np.datetime64("2026-03-01T08:00:00"), np.datetime64("2026-03-01T08:00:05")]
    assert got.dtype == "datetime64[ns]"
    for times, message in (
        (["2026-03-01T08:00:00", ""], "empty timestamp"),
        (["2026-03-01T08:00:00", "noon"], "'noon' is not an ISO-8601 timestamp"),
        (["2026-03-01T08:00:00", "time"], "header line is repeated"),
        (["2026-03-01T08:00:00", "2300-01-01T00:00:00"], "outside the supported years"),
    ):
        with pytest.raises(RawFormatError, match=message) as info:
            _parse_times(PATH, times, [7, 9])
        assert info.value.line == 9 and info.value.column == "time"


def test_parse_values_keeps_canonical_then_extra_order_and_types():
    header = ["note", *HEADER, "coolant_c"]
    columns = {name: ["1.5", ""] for name in header}
    columns["note"] = ["a", "b"]
    got = _parse_values(PATH, header, columns, [2, 3])
    assert list(got) == [*HEADER[1:], "note", "coolant_c"]
    assert np.isnan(got["T1"][1]) and got["disp_um"][0] == 1.5
    assert list(got["note"]) == ["a", "b"] and got["coolant_c"].dtype == "float64"
    columns["T7"] = ["1.5", "2,5"]
    with pytest.raises(RawFormatError, match=r"'2,5' is not a number \(decimal comma") as info:
        _parse_values(PATH, header, columns, [2, 3])
    assert info.value.line == 3 and info.value.column == "T7"


# --------------------------------------------------------------------------- mapped


MAPPING = {
    "format": "csv",
    "delimiter": ";",
    "columns": {"time": "Zeit", "speed_rpm": "n [1/min]", **{s: f"Temp {s}" for s in SENSORS}},
    "displacement": {"column": "Z [mm]", "unit": "mm", "sign": -1},
    "temperature_unit": "K",
}


def _mapped_header() -> list[str]:
    return ["Zeit", "n [1/min]", *(f"Temp {s}" for s in SENSORS), "Z [mm]"]


def test_column_positions_finds_each_mapped_header_wherever_it_is():
    spec = normalise_input_spec(MAPPING)
    header = ["Bediener", *reversed(_mapped_header())]
    positions = _column_positions(_table(header, []), spec)
    assert {canon: header[j] for canon, j in positions.items()} == {
        "time": "Zeit",
        "speed_rpm": "n [1/min]",
        **{s: f"Temp {s}" for s in SENSORS},
        "disp_um": "Z [mm]",
    }


def test_column_positions_names_a_missing_or_doubled_header():
    spec = normalise_input_spec(MAPPING)
    missing = [h for h in _mapped_header() if h != "Temp T3"] + ["Temp T 3"]
    with pytest.raises(
        RawFormatError, match=r"'Temp T3' \(input.columns.T3\) not found.*closest: 'Temp T 3'"
    ):
        _column_positions(_table(missing, []), spec)
    with pytest.raises(RawFormatError, match=r"'Z \[mm\]' appears 2 times \(columns S, T\)"):
        _column_positions(_table([*_mapped_header(), "Z [mm]"], []), spec)


def test_canonical_values_apply_unit_and_sign():
    spec = normalise_input_spec(MAPPING)
    table = _table(_mapped_header(), [[None] * 19] * 3)
    disp = _canonical_values(table, ["0.0125", None, "0"], "disp_um", 18, spec)
    np.testing.assert_array_equal(disp, [-12.5, np.nan, 0.0])
    assert not np.signbit(disp[2])  # no -0.0
    kelvin = _canonical_values(table, ["295.15"], "T4", 5, spec)
    np.testing.assert_allclose(kelvin, [22.0])
    speed = _canonical_values(table, ["3000"], "speed_rpm", 1, spec)
    assert speed.dtype == "float64" and speed[0] == 3000.0
    with pytest.raises(RawFormatError, match=r"a number \(mm\) for disp_um"):
        _canonical_values(table, ["x"], "disp_um", 18, spec)


def test_extra_columns_get_unique_sanitised_names_and_empty_unnamed_ones_are_left_out():
    spec = normalise_input_spec({**MAPPING, "keep_extra": True})
    header = [*_mapped_header(), "Öl [°C]", "", "", "ol_c", "Bediener"]
    rows = [[None] * 19 + ["19,5", None, "x", "1", "Anna"], [None] * 19 + ["20", None, None, "2", "Ben"]]
    table = _table(header, rows)
    frame = pd.DataFrame(index=pd.Index([2, 3], name="line"))
    frame["time"] = 0
    mapped = dict(zip(["time", "speed_rpm", *SENSORS, "disp_um"], range(19)))
    _add_extra_columns(frame, table, list(zip(*rows)), mapped, spec)
    assert list(frame.columns) == ["time", "ol_c", "column_v", "ol_c_2", "bediener"]
    assert frame["ol_c_2"].tolist() == [1.0, 2.0] and frame["bediener"].tolist() == ["Anna", "Ben"]
    assert frame["column_v"].tolist() == ["x", ""]


def test_mapped_metadata_says_what_was_read_and_what_was_assumed():
    spec = normalise_input_spec({**MAPPING, "sample_period_s": 5})
    table = _table(_mapped_header(), [], sheet="Daten")
    meta = _mapped_metadata(
        spec, table, {"time": 0, "disp_um": 18}, speed=(3000.0, "input.speed.constant_rpm")
    )
    assert meta["format"] == "csv" and meta["sheet"] == "Daten" and meta["sample_period_s"] == 5
    assert meta["columns"] == {"time": "Zeit", "disp_um": "Z [mm]"}
    assert list(meta["assumed"]) == ["speed_rpm"] and "3000 r/min" in meta["assumed"]["speed_rpm"]
    plain = _mapped_metadata(normalise_input_spec(MAPPING), _table(["a"], []), {}, speed=None)
    assert plain == {"format": "csv", "columns": {}}


def test_read_csv_table_skips_rows_and_trims_empty_trailing_fields(tmp_path):
    text = "# export\nZeit;Wert\nunits;C\n1;20,5;;\n\n2;21\n"
    spec = normalise_input_spec({"format": "csv", "delimiter": ";", "header_row": 2, "skip_rows": 1})
    table = read_csv_table(tmp_path / "a.csv", text.encode(), spec)
    assert table.header == ["Zeit", "Wert"] and table.header_row == 2
    assert table.rows == [["1", "20,5"], ["2", "21"]] and table.row_numbers == [4, 6]
    with pytest.raises(RawFormatError, match="not by the configured delimiter ';'"):
        read_csv_table(tmp_path / "a.csv", b"Zeit,Wert\n1,2\n", spec | {"header_row": 1})


def test_too_many_fields_hint_a_decimal_comma_only_where_the_counts_allow_it(tmp_path):
    spec = normalise_input_spec({"format": "csv", "header_row": 1})
    with pytest.raises(RawFormatError, match=r"line 2: found 3 fields, expected 2 .*a decimal comma"):
        read_csv_table(tmp_path / "a.csv", b"Zeit,Wert\n1,20,5\n", spec)
    preamble = b"Sample interval,60 s\ntime,speed,T1,T2,T3\n1,0,20.1,20.2,20.3\n"
    with pytest.raises(RawFormatError, match=r"line 3: found 5 fields, expected 2") as err:
        read_csv_table(tmp_path / "a.csv", preamble, spec | {"skip_rows": 1})
    assert "decimal comma" not in str(err.value)
    assert "line 1 (input.header_row) looks like a line above the table" in str(err.value)


def test_read_table_refuses_an_empty_workbook(tmp_path):
    with pytest.raises(RawFormatError, match="file is empty; expected an .xlsx workbook"):
        read_table(tmp_path / "a.xlsx", b"", normalise_input_spec({"format": "xlsx"}))


# --------------------------------------------------------------------------- mapped_time


def test_elapsed_times_accept_seconds_and_duration_cells():
    spec = normalise_input_spec(
        {"format": "xlsx", "time": {"kind": "elapsed_s", "start": "2026-10-14T06:00:00+02:00"}}
    )
    cells = [0, "2.5", dt.time(0, 1, 0), dt.timedelta(hours=1, microseconds=500)]
    got = _elapsed_times(_table(["t"], [[c] for c in cells]), cells, spec, "t", 0)
    start = pd.Timestamp("2026-10-14T04:00:00")
    assert list(got) == [start + pd.Timedelta(seconds=s) for s in (0, 2.5, 60, 3600.0005)]
    with pytest.raises(RawFormatError, match=r"empty time; expected elapsed seconds") as info:
        _elapsed_times(_table(["t"], [[0], [None]]), [0, None], spec, "t", 0)
    assert info.value.line == 3


def test_text_times_parse_all_at_once_or_leave_it_to_the_cells():
    got = _text_times([" 14.10.2026 08:00:00", "14.10.2026 08:00:05 "], "%d.%m.%Y %H:%M:%S")
    assert list(got) == [pd.Timestamp("2026-10-14T08:00:00"), pd.Timestamp("2026-10-14T08:00:05")]
    assert _text_times(["2026-10-14T08:00:00", ""], None) is None
    assert _text_times(["2026-10-14T08:00:00", "later"], None) is None
    assert _text_times([dt.datetime(2026, 10, 14)], None) is None
    assert _text_times([], None) is None


def test_cell_time_reads_datetimes_dates_and_text_with_offsets():
    assert _cell_time(dt.datetime(2026, 10, 14, 8), None) == pd.Timestamp("2026-10-14T08:00")
    assert _cell_time(dt.date(2026, 10, 14), None) == pd.Timestamp("2026-10-14")
    assert _cell_time("2026-10-14T10:00:00+02:00", None) == pd.Timestamp("2026-10-14T08:00")
    assert _cell_time("14/10/2026 08:00", "%d/%m/%Y %H:%M") == pd.Timestamp("2026-10-14T08:00")
    for not_a_time in ("14/10/2026", 45000.5, None, "  "):
        assert _cell_time(not_a_time, None) is None


def test_cell_times_name_the_first_bad_cell_with_its_excel_address():
    table = _table(["Zeit"], [[dt.datetime(2026, 10, 14)], ["noon"]], sheet="Daten")
    with pytest.raises(
        RawFormatError, match=r"'noon' is not a timestamp; expected an ISO-8601 time.*\(cell A3\)"
    ):
        _cell_times(table, [dt.datetime(2026, 10, 14), "noon"], None, "Zeit", 0)
    with pytest.raises(RawFormatError, match=r"in the format '%H:%M'"):
        _cell_times(table, ["noon"], "%H:%M", "Zeit", 0)
    with pytest.raises(RawFormatError, match=r"empty timestamp"):
        _cell_times(table, [dt.datetime(2026, 10, 14), None], None, "Zeit", 0)
    with pytest.raises(RawFormatError, match=r"outside the supported years"):
        _cell_times(table, [dt.datetime(2300, 1, 1)], None, "Zeit", 0)
