"""Mapped readers (rafi.readers.mapped, rafi.readers.logs.read_log with an ``input:`` mapping)."""

from __future__ import annotations

import copy
import datetime as dt
import re
import subprocess
import sys
from pathlib import Path

import jsonschema
import numpy as np
import openpyxl
import pandas as pd
import pytest
import yaml

from rafi import REQUIRED_COLUMNS
from rafi.errors import InputSpecError, RawFormatError
from rafi.readers.checks import check_log
from rafi.readers.input_spec import INPUT_SCHEMA, find_logs, normalise_input_spec
from rafi.readers.logs import read_log
from rafi.readers.mapped import closest_headers, excel_column, sanitise_name
from rafi.readers.native import contract_violations

ROOT = Path(__file__).resolve().parents[1]
FOREIGN = ROOT / "tests" / "data" / "foreign"
XLSX = FOREIGN / "machining_center_b_small.xlsx"
CSV = FOREIGN / "machining_center_b_small.csv"


def doc_yaml_blocks() -> list[str]:
    text = (ROOT / "docs" / "raw-format.md").read_text(encoding="utf-8")
    return re.findall(r"```yaml\n(.+?)```", text, flags=re.S)


@pytest.fixture(scope="module")
def mcb_machine() -> dict:
    """The machining-center-b settings exactly as docs/raw-format.md shows them."""
    return yaml.safe_load(doc_yaml_blocks()[0])["machines"]["machining-center-b"]


@pytest.fixture()
def xlsx_spec(mcb_machine) -> dict:
    return copy.deepcopy(mcb_machine["input"])


@pytest.fixture()
def csv_spec(mcb_machine) -> dict:
    spec = copy.deepcopy(mcb_machine["input"])
    spec.pop("sheet")
    spec.update(yaml.safe_load(doc_yaml_blocks()[1]))
    return spec


@pytest.fixture(scope="module")
def xlsx_frame(mcb_machine):
    return read_log(XLSX, mcb_machine["input"])


def test_docs_example_is_valid_against_schema_and_normaliser(mcb_machine):
    jsonschema.Draft7Validator.check_schema(INPUT_SCHEMA)
    jsonschema.validate(mcb_machine["input"], INPUT_SCHEMA)
    spec = normalise_input_spec(mcb_machine["input"])
    assert spec["displacement"] == {"column": "Verlagerung Z1 [µm]", "unit": "um", "sign": -1}
    assert mcb_machine["sample_period_s"] == spec["sample_period_s"] == 15


def test_xlsx_layout_reads_into_the_canonical_frame(xlsx_frame):
    f = xlsx_frame
    assert contract_violations(f) == []
    assert list(f.columns[: len(REQUIRED_COLUMNS)]) == list(REQUIRED_COLUMNS)
    assert list(f.columns[len(REQUIRED_COLUMNS) :]) == [
        "verlagerung_x1_um",
        "verlagerung_y1_um",
        "verlagerung_z2_um",
        "bemerkung",
    ]
    assert f.index[0] == 2 and f.index[-1] == 241 and len(f) == 240  # Excel rows
    assert f["time"].iloc[0] == pd.Timestamp("2026-10-14T06:00:00")
    assert (f["time"].diff().dropna() == pd.Timedelta(seconds=15)).all()
    assert f.attrs["metadata"]["sample_period_s"] == 15.0
    assert f.attrs["metadata"]["sheet"] == "Messdaten"
    assert f.attrs["metadata"]["columns"]["disp_um"] == "Verlagerung Z1 [µm]"
    assert len(f.attrs["sha256"]) == 64 and f.attrs["source"].endswith(XLSX.name)
    assert f["bemerkung"].iloc[0] == "Start" and f["bemerkung"].iloc[1] == ""
    assert f["speed_rpm"].iloc[0] == 6000.0


def test_sign_is_applied_to_the_target_only(xlsx_frame):
    wb = openpyxl.load_workbook(XLSX, read_only=True, data_only=True)
    rows = list(wb["Messdaten"].iter_rows(values_only=True))
    wb.close()
    header = rows[0]
    z1 = np.array([r[header.index("Verlagerung Z1 [µm]")] for r in rows[1:]], dtype=float)
    z2 = np.array([r[header.index("Verlagerung Z2 [µm]")] for r in rows[1:]], dtype=float)
    np.testing.assert_array_equal(xlsx_frame["disp_um"].to_numpy(), -z1)
    np.testing.assert_array_equal(xlsx_frame["verlagerung_z2_um"].to_numpy(), z2)
    assert xlsx_frame["disp_um"].max() > 10  # growth towards the table is positive
    assert not np.signbit(xlsx_frame["disp_um"].to_numpy()[0])  # no -0.0


def test_xlsx_passes_the_checks(xlsx_frame, mcb_machine):
    check_log(
        xlsx_frame,
        XLSX,
        min_run_s=1800,
        sample_period_s=mcb_machine["sample_period_s"],
        open_circuit_values=[-999.0, 999.9, 850.0],
    )


def test_csv_export_gives_the_same_frame(xlsx_frame, csv_spec):
    g = read_log(CSV, csv_spec)
    assert contract_violations(g) == []
    assert g.index[0] == 2
    pd.testing.assert_frame_equal(xlsx_frame, g, check_exact=False, rtol=0, atol=1e-9)


def test_csv_in_utf8_with_bom_and_latin1(tmp_path, csv_spec, xlsx_frame):
    text = CSV.read_bytes().decode("latin-1")
    utf8 = tmp_path / "utf8.csv"
    utf8.write_bytes(b"\xef\xbb\xbf" + text.encode("utf-8"))
    spec = dict(csv_spec, encoding="utf-8")
    g = read_log(utf8, spec)
    pd.testing.assert_frame_equal(xlsx_frame, g, check_exact=False, rtol=0, atol=1e-9)
    with pytest.raises(RawFormatError, match=r"line 1: byte 0xb0 is not valid UTF-8.*input.encoding"):
        read_log(CSV, spec)  # latin-1 file read as UTF-8


def test_sheet_by_index(xlsx_spec, xlsx_frame):
    xlsx_spec["sheet"] = 1
    pd.testing.assert_frame_equal(read_log(XLSX, xlsx_spec), xlsx_frame)
    xlsx_spec["sheet"] = 0  # "Info": no such headers
    with pytest.raises(RawFormatError, match="sheet 'Info', row 1.*not found in the header row"):
        read_log(XLSX, xlsx_spec)
    xlsx_spec["sheet"] = 5
    with pytest.raises(RawFormatError, match="no sheet number 5.*'Info', 'Messdaten'"):
        read_log(XLSX, xlsx_spec)


def _write_xlsx(path, rows, title="Messdaten"):
    wb = openpyxl.Workbook()
    ws = wb.active
    ws.title = title
    for r in rows:
        ws.append(r)
    wb.save(path)


def _simple_header():
    return ["Zeit", "n [1/min]", *[f"Temp{i} [K]" for i in range(1, 17)], "Z [mm]", "Notiz"]


def _simple_spec(fmt="xlsx", **kw):
    spec = {
        "format": fmt,
        "columns": {
            "time": "Zeit",
            "speed_rpm": "n [1/min]",
            **{f"T{i}": f"Temp{i} [K]" for i in range(1, 17)},
            "disp_um": "Z [mm]",
        },
        "temperature_unit": "K",
        "displacement": {"unit": "mm"},
    }
    spec.update(kw)
    return spec


def test_header_row_skip_rows_kelvin_mm_and_timestamps(tmp_path):
    import datetime as dt

    rows = [["Messung B", None], [None], _simple_header(), ["s", "1/min"]]
    t0 = dt.datetime(2026, 10, 14, 8, 0, 0)
    for k in range(12):
        rows.append(
            [t0 + dt.timedelta(seconds=5 * k), 3000, *[293.15 + k] * 16, 0.001 * k, "ok" if k == 3 else None]
        )
    rows.insert(10, [None] * 5)  # an empty row in the data
    path = tmp_path / "b.xlsx"
    _write_xlsx(path, rows)
    f = read_log(path, _simple_spec(header_row=3, skip_rows=1))
    assert contract_violations(f) == []
    assert f.index[0] == 5 and 11 not in f.index and f.index[-1] == 17
    np.testing.assert_allclose(f["T1"].to_numpy(), 20.0 + np.arange(12))
    np.testing.assert_allclose(f["disp_um"].to_numpy(), np.arange(12.0))
    assert f["time"].iloc[1] == pd.Timestamp("2026-10-14T08:00:05")
    assert f["notiz"].tolist()[3] == "ok"


def test_csv_timestamp_with_strptime_format_and_decimal_comma(tmp_path):
    header = _simple_header()
    lines = [";".join(header)]
    for k in range(10):
        lines.append(
            ";".join([f"14.10.2026 08:00:{k * 5:02d}", "1.500", *["293,15"] * 16, f"0,{k:03d}", "x"])
        )
    path = tmp_path / "b.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    spec = _simple_spec(
        "csv", delimiter=";", decimal=",", time={"kind": "timestamp", "format": "%d.%m.%Y %H:%M:%S"}
    )
    f = read_log(path, spec)
    assert f["speed_rpm"].iloc[0] == 1500.0  # '.' as thousands separator
    assert f["T1"].iloc[0] == pytest.approx(20.0)
    assert f["disp_um"].iloc[3] == pytest.approx(3.0)
    assert f["time"].iloc[2] == pd.Timestamp("2026-10-14T08:00:10")
    path.write_text(path.read_text(encoding="utf-8").replace("293,15", "293.15", 1), encoding="utf-8")
    with pytest.raises(
        RawFormatError,
        match=r"line 2, column 'Temp1 \[K\]': '293.15' is not a "
        r"number \(decimal point in a file with",
    ):
        read_log(path, spec)
    spec["time"]["format"] = None
    path.write_text(path.read_text(encoding="utf-8").replace("293.15", "293,15", 1), encoding="utf-8")
    with pytest.raises(
        RawFormatError,
        match=r"line 2, column 'Zeit'.*is not a timestamp.*"
        r"time.format",
    ):
        read_log(path, spec)


def test_elapsed_default_start_and_timedelta_cells(tmp_path):
    import datetime as dt

    rows = [_simple_header()]
    for k in range(5):
        rows.append([dt.timedelta(seconds=10 * k), 0, *[300.0] * 16, 0.0 + k / 100, None])
    path = tmp_path / "e.xlsx"
    _write_xlsx(path, rows)
    f = read_log(path, _simple_spec(time={"kind": "elapsed_s"}))
    assert f["time"].iloc[0] == pd.Timestamp("2000-01-01T00:00:00")
    assert f["time"].iloc[4] == pd.Timestamp("2000-01-01T00:00:40")
    assert f["notiz"].isna().all()  # an empty extra column: all missing


@pytest.mark.parametrize("kind, per_s", [("elapsed_s", 1.0), ("elapsed_min", 60.0), ("elapsed_h", 3600.0)])
def test_fahrenheit_and_elapsed_minutes_or_hours_read_as_the_same_log(tmp_path, kind, per_s):
    """The same log written in deg F with its clock in minutes or hours reads as in deg C and
    seconds: the temperatures (F - 32) x 5/9, the times the cells times 60 or 3600."""
    header = ["t", "n [1/min]", *[f"Temp{i} [F]" for i in range(1, 17)], "Z [mm]", "Notiz"]
    rows = [header]
    for k in range(6):
        rows.append([15.0 * k / per_s, 3000, *[68.0 + 1.8 * k] * 16, 0.001 * k, None])
    path = tmp_path / "f.xlsx"
    _write_xlsx(path, rows)
    spec = _simple_spec(time={"kind": kind}, temperature_unit="F")
    spec["columns"] = {"time": "t", "speed_rpm": "n [1/min]", "disp_um": "Z [mm]"}
    spec["columns"].update({f"T{i}": f"Temp{i} [F]" for i in range(1, 17)})
    f = read_log(path, spec)
    np.testing.assert_allclose(f["T7"].to_numpy(), 20.0 + np.arange(6.0))  # 68 F = 20 C, 1.8 F = 1 K
    seconds = (f["time"] - f["time"].iloc[0]).dt.total_seconds().to_numpy()
    np.testing.assert_allclose(seconds, 15.0 * np.arange(6), atol=1e-6)
    rows[3][0] = "soon"
    _write_xlsx(path, rows)
    word = {"elapsed_s": "seconds", "elapsed_min": "minutes", "elapsed_h": "hours"}[kind]
    with pytest.raises(
        RawFormatError, match=rf"row 4, column 't': 'soon' is not a number; expected elapsed {word}"
    ):
        read_log(path, spec)


@pytest.mark.parametrize("kind", ["epoch_s", "epoch_ms", "excel_days"])
def test_a_clock_written_as_a_number_reads_as_its_dates(tmp_path, kind):
    """Unix seconds or milliseconds and Excel's serial day numbers are dates: each cell's time is
    what the standard library (Unix time) or openpyxl (Excel's day numbers) makes of it;
    ``time.start`` is refused beside them."""
    from openpyxl.utils.datetime import from_excel, to_excel

    t0 = dt.datetime(2026, 3, 29, 0, 58, 0)
    stamps = [t0 + dt.timedelta(seconds=60 * k) for k in range(6)]
    if kind == "excel_days":
        cells = [f"{to_excel(t):.10f}" for t in stamps]
        expected = [from_excel(float(c)) for c in cells]
    else:
        unix = [(t - dt.datetime(1970, 1, 1)).total_seconds() for t in stamps]
        cells = [f"{u:.0f}" if kind == "epoch_s" else f"{u * 1000:.0f}" for u in unix]
        scale = 1.0 if kind == "epoch_s" else 1000.0
        expected = [dt.datetime.fromtimestamp(int(c) / scale, dt.UTC).replace(tzinfo=None) for c in cells]
    lines = [",".join(_simple_header()[:-1])]
    lines += [",".join([c, "3000", *["293.15"] * 16, f"{0.001 * k:.3f}"]) for k, c in enumerate(cells)]
    path = tmp_path / "clock.csv"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    spec = _simple_spec("csv", time={"kind": kind})
    f = read_log(path, spec)
    assert [t.to_pydatetime() for t in f["time"]] == expected
    assert f.attrs["metadata"].get("clock", True) is not False
    spec = _simple_spec("csv", time={"kind": kind, "start": "2026-01-01T00:00:00"})
    with pytest.raises(InputSpecError, match=rf"time.start.*with kind {kind}.*leave time.start out"):
        read_log(path, spec)


def test_a_date_column_and_a_time_of_day_column_read_as_one_clock(tmp_path):
    """Loggers that write the date and the time of day in two columns: text (csv, with a format
    for both joined by a space) and workbook date and time cells (xlsx) give the same times."""
    t0 = dt.datetime(2023, 7, 1, 23, 58, 0)
    stamps = [t0 + dt.timedelta(seconds=30 * k) for k in range(8)]  # across midnight
    header = ["Datum", "Uhrzeit", "n [1/min]", *[f"Temp{i} [K]" for i in range(1, 17)], "Z [mm]"]
    body = [[3000, *[293.15] * 16, 0.001 * k] for k in range(8)]
    lines = [";".join(header)]
    lines += [
        ";".join([t.strftime("%d.%m.%Y"), t.strftime("%H:%M:%S"), *map(str, b)]) for t, b in zip(stamps, body)
    ]
    csv = tmp_path / "d.csv"
    csv.write_text("\n".join(lines) + "\n", encoding="utf-8")
    columns = {"time": "Uhrzeit", "speed_rpm": "n [1/min]", "disp_um": "Z [mm]"}
    columns.update({f"T{i}": f"Temp{i} [K]" for i in range(1, 17)})
    time = {"kind": "timestamp", "date_column": "Datum", "format": "%d.%m.%Y %H:%M:%S"}
    f = read_log(csv, _simple_spec("csv", delimiter=";", columns=columns, time=time))
    assert f["time"].tolist() == [pd.Timestamp(t) for t in stamps]
    assert "datum" not in f.columns and "uhrzeit" not in f.columns  # the clock's columns are not extras
    xlsx = tmp_path / "d.xlsx"
    _write_xlsx(xlsx, [header, *[[t.date(), t.time(), *b] for t, b in zip(stamps, body)]])
    g = read_log(xlsx, _simple_spec(columns=columns, time={"kind": "timestamp", "date_column": "Datum"}))
    assert g["time"].tolist() == f["time"].tolist()
    with pytest.raises(InputSpecError, match=r"input\.time\.date_column"):
        normalise_input_spec({"format": "csv", "time": {"kind": "elapsed_s", "date_column": "Datum"}})
    lines[3] = lines[3].replace("01.07.2023", "", 1)  # a row without its date
    csv.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(RawFormatError, match=r"line 4, column 'Datum \+ Uhrzeit'"):
        read_log(csv, _simple_spec("csv", delimiter=";", columns=columns, time=time))


def test_duplicate_mapped_header_and_cell_beyond_header(tmp_path):
    header = _simple_header()
    header[5] = "Temp1 [K]"
    rows = [header] + [[k, 0, *[300.0] * 16, 0.01 * k, None] for k in range(5)]
    path = tmp_path / "d.xlsx"
    _write_xlsx(path, rows)
    spec = _simple_spec(time={"kind": "elapsed_s"})
    with pytest.raises(
        RawFormatError,
        match=r"sheet 'Messdaten', row 1, column 'Temp1 \[K\]': "
        r"header 'Temp1 \[K\]' appears 2 times \(columns C, F\)",
    ):
        read_log(path, spec)
    rows = [_simple_header()] + [[k, 0, *[300.0] * 16, 0.01 * k, None] for k in range(5)]
    rows[3] = rows[3] + [None, "stray"]
    _write_xlsx(path, rows)
    with pytest.raises(RawFormatError, match=r"row 4, column 'V'.*cell V4 holds 'stray'"):
        read_log(path, spec)


def test_keep_extra_false_drops_other_columns(xlsx_spec):
    xlsx_spec["keep_extra"] = False
    f = read_log(XLSX, xlsx_spec)
    assert list(f.columns) == list(REQUIRED_COLUMNS)


def test_missing_mapped_column_lists_closest(xlsx_spec):
    xlsx_spec["columns"]["T3"] = "Temperatur 3 [C]"
    with pytest.raises(RawFormatError) as info:
        read_log(XLSX, xlsx_spec)
    msg = str(info.value)
    assert "sheet 'Messdaten', row 1, column 'Temperatur 3 [C]'" in msg
    assert "input.columns.T3" in msg and "closest: 'Temperatur 3 [°C]'" in msg


@pytest.mark.parametrize(
    "change, key",
    [
        ({"format": "parquet"}, "input.format"),
        ({"colour": "red"}, "input.colour"),
        ({"format": "native", "sheet": "x"}, "input.sheet"),
        ({"displacement": {"unit": "cm"}}, "input.displacement.unit"),
        ({"displacement": {"sign": 2}}, "input.displacement.sign"),
        ({"displacement": {"probe": "Z"}}, "input.displacement.probe"),
        ({"columns": {"T 17": "x"}}, "input.columns.T 17"),
        ({"columns": {"log": "x"}}, "input.columns.log"),
        ({"sensors": ["T1"], "columns": {"T2": "x"}}, "input.columns.T2"),
        ({"sensors": ["T1", "T1"]}, "input.sensors"),
        ({"sensors": ["T1", "dT1"]}, "input.sensors"),
        ({"sensors": [f"T{i}" for i in range(65)]}, "input.sensors"),
        ({"sensors": []}, "input.sensors"),
        ({"columns": {"T1": "A", "T2": "A"}}, "input.columns"),
        ({"delimiter": ";;"}, "input.delimiter"),
        ({"delimiter": ",", "decimal": ","}, "input.decimal"),
        ({"encoding": "klingon"}, "input.encoding"),
        ({"header_row": 0}, "input.header_row"),
        ({"skip_rows": -1}, "input.skip_rows"),
        ({"time": {"kind": "relative"}}, "input.time.kind"),
        ({"time": {"start": "yesterday"}}, "input.time.start"),
        ({"time": {"format": "dd.mm.yyyy"}}, "input.time.format"),
        ({"sample_period_s": 0}, "input.sample_period_s"),
        ({"temperature_unit": "R"}, "input.temperature_unit"),
        ({"sheet": -1}, "input.sheet"),
        ({"pattern": ""}, "input.pattern"),
    ],
)
def test_bad_mapping_raises_input_spec_error(change, key):
    spec = {"format": "csv", **change}
    with pytest.raises(InputSpecError, match=re.escape(key)):
        normalise_input_spec(spec)


@pytest.mark.parametrize(
    "bad",
    [
        {"format": "parquet"},
        {"displacement": {"unit": "cm"}},
        {"displacement": {"sign": 2}},
        {"columns": {"T 17": "x"}},
        {"sensors": ["T1", "T1"]},
        {"header_row": 0},
        {"colour": "red"},
        {"time": {"kind": "relative"}},
        {"temperature_unit": "R"},
    ],
)
def test_schema_rejects_what_the_normaliser_rejects(bad):
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(bad, INPUT_SCHEMA)


def test_defaults():
    spec = normalise_input_spec(None)
    assert spec["format"] == "native" and spec["pattern"] == "*.csv"
    spec = normalise_input_spec({"format": "xlsx"})
    assert spec["pattern"] == "*.xlsx" and spec["sheet"] == 0 and spec["header_row"] == 1
    assert spec["time"] == {
        "kind": "timestamp",
        "start": None,
        "format": None,
        "period_s": None,
        "date_column": None,
        "date_from_name": None,
        "timezone": None,
    }
    assert spec["speed"] == {"constant_rpm": None, "constant_rpm_by_file": {}}
    assert spec["displacement"] == {"column": None, "unit": "um", "sign": 1}
    assert normalise_input_spec({"format": "csv", "delimiter": "tab"})["delimiter"] == "\t"


def test_native_accepts_filled_in_defaults_only():
    """A schema validator that fills defaults must not break native mappings."""
    spec = {
        "format": "native",
        "pattern": "*.csv",
        "sheet": 0,
        "delimiter": ",",
        "time": {"kind": "timestamp"},
        "displacement": {"sign": 1},
        "columns": {},
    }
    assert normalise_input_spec(spec)["format"] == "native"
    with pytest.raises(InputSpecError, match="input.displacement: applies to format csv"):
        normalise_input_spec({"format": "native", "displacement": {"sign": -1}})


@pytest.mark.parametrize(
    "start",
    [
        "2026-10-14T06:00:00",
        "2026-10-14 06:00",
        "2026-10-14",
        "1678-01-01",
        "2261-12-31T00:00:00",
        "2261-12-31T00:00:01",
        "1677-12-31",
        "0999-01-01",
        "2026-02-30",
        "2026-10-14T24:00:00",
        "2026-10-14T06:00:00Z",
        "2026-10-14T06:00:00+02:00",
        "2026-10-14T06:00:00.5",
        "20261014",
        "2026-W42-3",
        "14.10.2026",
        "yesterday",
    ],
)
def test_time_start_checked_without_pandas_as_pandas_would(start):
    """rafi.readers.input_spec checks plain ISO times without pandas (planning imports no pandas); every
    value gets the outcome of the pandas check (pd.Timestamp within rafi.readers.parsing.TIME_MIN/MAX)."""
    from rafi.readers.input_spec import _plain_start_ok
    from rafi.readers.parsing import TIME_MAX, TIME_MIN

    try:
        ts = pd.Timestamp(start)
        ts = ts.tz_convert(None) if ts.tzinfo is not None else ts
        pandas_ok = bool(TIME_MIN <= ts <= TIME_MAX)
    except (ValueError, TypeError):
        pandas_ok = False
    if _plain_start_ok(start):
        assert pandas_ok and pd.Timestamp(start).to_pydatetime() == dt.datetime.fromisoformat(start)
    spec = {"format": "csv", "time": {"kind": "elapsed_s", "start": start}}
    if pandas_ok:
        assert normalise_input_spec(spec)["time"]["start"] == start
    else:
        with pytest.raises(InputSpecError, match="input.time.start"):
            normalise_input_spec(spec)


def test_planning_imports_no_pandas():
    """What workflow/rules/common.smk imports (rafi.settings, rafi.readers.input_spec,
    rafi.ops.code_deps) loads neither pandas nor NumPy."""
    code = (
        "import sys, rafi.readers.input_spec as c, rafi.readers.quarantine, rafi.settings as s, "
        "rafi.ops.code_deps; c.find_logs('.', {'format': 'csv', 'time': "
        "{'start': '2026-10-14T06:00:00'}}); s.candidate_model_path('m', 'results', 'fit'); "
        "s.machine_settings({}, 'm');"
        "assert not {'pandas', 'numpy'} & set(sys.modules), sorted(sys.modules)"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT)


def test_find_logs_skips_lock_and_hidden_files(tmp_path):
    for name in ("a.xlsx", "~$a.xlsx", ".b.xlsx", "c.csv", "d.XLSX.bak"):
        (tmp_path / name).write_bytes(b"x")
    assert [p.name for p in find_logs(tmp_path, {"format": "xlsx"})] == ["a.xlsx"]
    got = find_logs(tmp_path, {"format": "csv", "pattern": ["*.csv", "*.xlsx"]})
    assert [p.name for p in got] == ["a.xlsx", "c.csv"]


def test_helpers():
    assert sanitise_name("Verlagerung X1 [µm]") == "verlagerung_x1_um"
    assert sanitise_name("Temperatur 1 [°C]") == "temperatur_1_c"
    assert sanitise_name("Größe %") == "grosse_pct"
    assert sanitise_name("1. Wert") == "c_1_wert"
    assert sanitise_name("***") == "column"
    assert [excel_column(i) for i in (0, 25, 26, 701)] == ["A", "Z", "AA", "ZZ"]
    heads = [f"Temperatur {i} [°C]" for i in range(1, 17)]
    assert closest_headers("Temperatur 3 [C]", heads)[0] == "Temperatur 3 [°C]"
    assert closest_headers("Temp 3", ["Zeit", "Drehzahl"]) == []


def test_shipped_config_matches_the_documented_mapping(mcb_machine):
    """Once config.yaml maps machining-center-b, it must be the documented mapping."""
    cfg = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))
    machine = (cfg.get("machines") or {}).get("machining-center-b")
    if not machine or "input" not in machine:
        pytest.skip("config.yaml has no input mapping for machining-center-b yet")
    assert normalise_input_spec(machine["input"]) == normalise_input_spec(mcb_machine["input"])


def test_shipped_foreign_raw_file_reads_and_checks(mcb_machine):
    files = sorted((ROOT / "raw" / "machining-center-b").glob("*.xlsx"))
    if not files:
        pytest.skip("raw/machining-center-b has no xlsx yet")
    for path in files:
        f = read_log(path, mcb_machine["input"])
        assert contract_violations(f) == []
        check_log(f, path, min_run_s=0, sample_period_s=15, open_circuit_values=[-999.0, 999.9, 850.0])
        assert f["disp_um"].quantile(0.9) > 0  # sign -1 makes growth positive
