"""``input.time.date_from_name``: a logger that writes only the time of day in its rows and the date
in the file name (``spindle_2026-03-14.csv``, ``log_20260314.csv``, ``14.03.2026.csv``). The rows
get the file's date, a time of day more than 12 h before the row above is on the next day (a log
over midnight), any other step back stays a clock reset; without the key the reader names it and
``rafi init``, which finds the case and proposes the key (with a CHECK when the names' dates read
day first and month first)."""

from __future__ import annotations

import datetime as dt
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from layout_files import CLOCK_HEADERS, canonical_frame, write_time_of_day_log

from rafi import SENSORS
from rafi.errors import InputSpecError, RawFormatError
from rafi.ops.init_cli import findings
from rafi.ops.init_config import config_block, parse_block
from rafi.ops.init_survey import survey
from rafi.readers.checks import check_file
from rafi.readers.infer_files import read_unknown_logs
from rafi.readers.input_spec import normalise_input_spec
from rafi.readers.logs import read_log
from rafi.readers.name_dates import dates_in_name
from rafi.settings import machine_settings, validate_config

COLUMNS = {canon: header for canon, header in CLOCK_HEADERS.items()}


def spec(path: Path, date_from_name: str | None = "%Y-%m-%d", **time) -> dict:
    fmt = "xlsx" if path.suffix == ".xlsx" else "csv"
    layout = {"delimiter": ";"} if fmt == "csv" else {"sheet": "Daten"}
    clock = {"kind": "timestamp", **time}
    if date_from_name is not None:
        clock["date_from_name"] = date_from_name
    return {"format": fmt, **layout, "columns": COLUMNS, "time": clock}


NAMES = [
    ("spindle_{:%Y-%m-%d}", "%Y-%m-%d"),
    ("log_{:%Y%m%d}", "%Y%m%d"),
    ("{:%d.%m.%Y}", "%d.%m.%Y"),
]


@pytest.mark.parametrize("suffix", [".csv", ".xlsx"])
@pytest.mark.parametrize("name, date_format", NAMES)
def test_the_date_of_the_name_and_the_time_of_day_read_as_the_clock_over_midnight(
    tmp_path, name, date_format, suffix
):
    frame = canonical_frame(80, start="2026-03-14 23:20", period_s=60)  # runs over midnight
    path = write_time_of_day_log(tmp_path / (name.format(dt.date(2026, 3, 14)) + suffix), frame)
    got = read_log(path, spec(path, date_format))
    assert got["time"].tolist() == frame["time"].tolist()
    np.testing.assert_allclose(
        got[["speed_rpm", *SENSORS, "disp_um"]], frame[["speed_rpm", *SENSORS, "disp_um"]]
    )
    check_file(got, path, sample_period_s=60.0)  # rises: no clock reset at midnight


def test_a_log_of_three_days_rolls_over_at_each_midnight(tmp_path):
    frame = canonical_frame(60, start="2026-03-14 22:00", period_s=3600)
    path = write_time_of_day_log(tmp_path / "log_2026-03-14.csv", frame)
    got = read_log(path, spec(path))
    assert got["time"].tolist() == frame["time"].tolist()
    assert got["time"].dt.date.nunique() == 4


def test_a_time_going_back_within_the_day_is_still_a_clock_reset(tmp_path):
    frame = canonical_frame(60, start="2026-03-14 10:00", period_s=60)
    frame.loc[30:, "time"] -= pd.Timedelta(hours=3)  # 10:30 -> 07:30: a reset, not midnight
    path = write_time_of_day_log(tmp_path / "log_2026-03-14.csv", frame)
    got = read_log(path, spec(path))
    assert got["time"].iloc[30] == pd.Timestamp("2026-03-14 07:30")
    with pytest.raises(RawFormatError, match="a clock reset") as info:
        check_file(got, path, sample_period_s=60.0)
    assert info.value.check == "clock_reset" and info.value.line == 32


def test_a_twelve_hour_time_of_day_is_read_with_time_format(tmp_path):
    frame = canonical_frame(40, start="2026-03-14 11:40", period_s=60)
    path = write_time_of_day_log(tmp_path / "log_2026-03-14.csv", frame, time_format="%I:%M:%S %p")
    got = read_log(path, spec(path, format="%I:%M:%S %p"))
    assert got["time"].tolist() == frame["time"].tolist()


@pytest.mark.parametrize("time_format", ["%I:%M:%S %p", "%I:%M %p", "%I:%M:%S%p"])
def test_a_twelve_hour_time_of_day_is_read_without_a_format(tmp_path, time_format):
    """``02:15:30 PM`` is a time of day as ``14:15:30`` is: read without ``input.time.format``,
    over noon and midnight (12 AM is 0 h, 12 PM is noon)."""
    frame = canonical_frame(200, start="2026-03-14 11:10", period_s=300)  # past noon and midnight
    path = write_time_of_day_log(tmp_path / "log_2026-03-14.csv", frame, time_format=time_format)
    got = read_log(path, spec(path))
    want = frame["time"] if "%S" in time_format else frame["time"].dt.floor("min")
    assert got["time"].tolist() == want.tolist()


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.integers(0, 86399), st.sampled_from(["%I:%M:%S %p", "%I:%M:%S %P", "%-I:%M:%S %p", "%I:%M:%S%p"]))
def test_every_second_of_the_day_on_a_twelve_hour_clock_reads_back(second, fmt):
    from rafi.readers.name_dates import is_time_of_day, time_of_day_seconds

    text = (dt.datetime(2026, 3, 14) + dt.timedelta(seconds=second)).strftime(fmt)
    assert is_time_of_day(text) and time_of_day_seconds(text) == second


@pytest.mark.parametrize("text", ["13:00 PM", "0:30 AM", "12:60 PM", "12:00 XM", "12 PM"])
def test_what_no_twelve_hour_clock_writes_is_no_time_of_day(text):
    from rafi.readers.name_dates import is_time_of_day, time_of_day_seconds

    assert not is_time_of_day(text) and time_of_day_seconds(text) is None


def test_local_times_of_day_across_a_fall_back_read_as_utc(tmp_path):
    utc = pd.date_range("2026-10-24T21:00", "2026-10-25T03:00", freq="60s")
    frame = canonical_frame(len(utc), period_s=60)
    frame["time"] = utc.tz_localize("UTC").tz_convert("Europe/Berlin").tz_localize(None)
    path = write_time_of_day_log(tmp_path / "log_2026-10-24.csv", frame)
    got = read_log(path, spec(path, timezone="Europe/Berlin"))
    assert got["time"].tolist() == list(utc)


@pytest.mark.parametrize("suffix", [".csv", ".xlsx"])
def test_without_the_key_a_time_of_day_names_the_key_and_rafi_init(tmp_path, suffix):
    path = write_time_of_day_log(tmp_path / f"log_2026-03-14{suffix}", canonical_frame(20))
    with pytest.raises(RawFormatError) as info:
        read_log(path, spec(path, None))
    message = str(info.value)
    where = "sheet 'Daten', row 2" if suffix == ".xlsx" else "line 2"
    assert message.startswith(f"{path}, {where}, column 'Uhrzeit': ")
    assert "is a time of day without a date" in message
    assert "input.time.date_from_name" in message and "rafi init" in message


def test_a_native_log_with_a_time_of_day_names_the_key_and_rafi_init(tmp_path):
    frame = canonical_frame(20)
    table = frame.assign(time=frame["time"].dt.strftime("%H:%M:%S"))
    path = tmp_path / "log_2026-03-14.csv"
    table.to_csv(path, index=False)
    with pytest.raises(RawFormatError) as info:
        read_log(path)
    message = str(info.value)
    assert message.startswith(f"{path}, line 2, column 'time': '06:00:00' is a time of day without a date")
    assert "input.time.date_from_name" in message and "rafi init" in message


@pytest.mark.parametrize(
    "name, fragment",
    [
        ("spindle.csv", "no date in the form '%Y-%m-%d' (input.time.date_from_name) in the file name"),
        ("log_2026-13-01.csv", "no date in the form '%Y-%m-%d'"),
        ("log_2026-03-14_to_2026-03-15.csv", "two dates in the form '%Y-%m-%d'"),
    ],
)
def test_a_name_without_one_date_names_the_file_and_the_key(tmp_path, name, fragment):
    path = write_time_of_day_log(tmp_path / name, canonical_frame(20))
    with pytest.raises(RawFormatError, match=re.escape(fragment)) as info:
        read_log(path, spec(path))
    assert str(info.value).startswith(f"{path}: ")


def test_a_cell_that_is_no_time_of_day_names_its_line(tmp_path):
    frame = canonical_frame(20)
    path = write_time_of_day_log(tmp_path / "log_2026-03-14.csv", frame)
    text = path.read_text(encoding="utf-8").replace("06:05:00", "06:05:61")
    path.write_text(text, encoding="utf-8")
    with pytest.raises(RawFormatError, match=r"line 7, column 'Uhrzeit': '06:05:61' is not a time of day"):
        read_log(path, spec(path))


@pytest.mark.parametrize(
    "time, fragment",
    [
        ({"date_from_name": "%Y-%m"}, "expected a date format with a day, a month and a year"),
        ({"date_from_name": "%Y-%m-%d %H"}, "'%H' is not a date code"),
        ({"date_from_name": "2026-03-14"}, "expected a date format with a day, a month and a year"),
        ({"date_from_name": 20260314}, "expected a date format"),
        ({"date_from_name": "%Y-%m-%d", "kind": "elapsed_s"}, "applies to time.kind timestamp only"),
        ({"date_from_name": "%Y-%m-%d", "date_column": "Datum"}, "the date is in a column"),
    ],
)
def test_a_bad_date_from_name_is_a_one_line_config_error(time, fragment):
    with pytest.raises(InputSpecError, match=f"^input.time.date_from_name: .*{fragment}") as info:
        normalise_input_spec({"format": "csv", "time": time})
    assert "\n" not in str(info.value)


def test_date_from_name_is_a_csv_and_xlsx_key_and_validates_in_the_config():
    with pytest.raises(InputSpecError, match="input.time: applies to format csv or xlsx"):
        normalise_input_spec({"format": "native", "time": {"date_from_name": "%Y%m%d"}})
    assert normalise_input_spec({"format": "csv"})["time"]["date_from_name"] is None
    config = {"machines": {"m": {"input": {"format": "csv", "time": {"date_from_name": "%Y%m%d"}}}}}
    validate_config(config)
    assert machine_settings(config, "m")["input"]["time"]["date_from_name"] == "%Y%m%d"


# --------------------------------------------------------------------------- rafi init


def write_folder(
    folder: Path, names: list[str], start_times: list[str], time_format: str = "%H:%M:%S"
) -> dict[str, pd.DataFrame]:
    folder.mkdir(parents=True, exist_ok=True)
    truth = {}
    for k, (name, start) in enumerate(zip(names, start_times)):
        frame = canonical_frame(240, seed=k, start=start, period_s=30)
        frame.loc[:20, "speed_rpm"] = 0.0  # a step: a speed column, not a constant
        truth[name] = frame
        write_time_of_day_log(folder / name, frame, time_format=time_format)
    return truth


def read_with_block(folder: Path, block: str) -> dict[str, pd.DataFrame]:
    config = {"machines": {"m": parse_block(block, "m")}}
    validate_config(config)
    spec_ = machine_settings(config, "m")["input"]
    return {p.name: read_log(p, spec_) for p in sorted(folder.glob("*.csv"))}


def test_init_proposes_the_date_in_the_names_and_the_block_reads_the_logs(tmp_path):
    folder = tmp_path / "raw" / "m"
    names = ["spindle_2026-03-14.csv", "spindle_2026-03-15.csv"]
    truth = write_folder(folder, names, ["2026-03-14 22:30", "2026-03-15 08:00"])
    s = survey("m", [t for p in sorted(folder.iterdir()) for t in read_unknown_logs(p)])
    assert s.time is not None and s.time.header == "Uhrzeit" and s.date is None
    assert s.date_from_name == "%Y-%m-%d" and s.period_s == 30.0
    assert not any(c.startswith("input.time") for c in s.checks)
    lines = "\n".join(findings(s))
    assert "the date in the file names" in lines
    block = config_block(s)
    assert 'date_from_name: "%Y-%m-%d"' in block
    for name, frame in read_with_block(folder, block).items():
        assert frame["time"].tolist() == truth[name]["time"].tolist()


def test_init_proposes_the_date_in_the_names_for_a_twelve_hour_clock_too(tmp_path):
    folder = tmp_path / "raw" / "m"
    names = ["spindle_2026-03-14.csv", "spindle_2026-03-15.csv"]
    truth = write_folder(folder, names, ["2026-03-14 22:30", "2026-03-15 11:50"], time_format="%I:%M:%S %p")
    s = survey("m", [t for p in sorted(folder.iterdir()) for t in read_unknown_logs(p)])
    assert s.time is not None and s.time.unit == "timeofday" and s.date_from_name == "%Y-%m-%d"
    assert s.period_s == 30.0
    for name, frame in read_with_block(folder, config_block(s)).items():
        assert frame["time"].tolist() == truth[name]["time"].tolist()


def test_init_checks_a_date_that_reads_day_first_and_month_first(tmp_path):
    folder = tmp_path / "raw" / "m"
    names = ["03.04.2026.csv", "05.04.2026.csv"]
    truth = write_folder(folder, names, ["2026-04-03 08:00", "2026-04-05 08:00"])
    s = survey("m", [t for p in sorted(folder.iterdir()) for t in read_unknown_logs(p)])
    assert s.date_from_name == "%d.%m.%Y"
    check = next(c for c in s.checks if c.startswith("input.time.date_from_name:"))
    assert "day first or month first" in check and "03.04.2026" in check
    block = config_block(s)
    assert 'date_from_name: "%d.%m.%Y"' in block
    assert "# CHECK: the file names' dates read day first or month first (03.04.2026.csv)" in block
    for name, frame in read_with_block(folder, block).items():
        assert frame["time"].tolist() == truth[name]["time"].tolist()


def test_init_takes_the_one_order_that_reads_every_name(tmp_path):
    folder = tmp_path / "raw" / "m"
    names = ["03.04.2026.csv", "14.04.2026.csv"]  # 14 is no month: day first
    write_folder(folder, names, ["2026-04-03 08:00", "2026-04-14 08:00"])
    s = survey("m", [t for p in sorted(folder.iterdir()) for t in read_unknown_logs(p)])
    assert s.date_from_name == "%d.%m.%Y"
    assert not any(c.startswith("input.time.date_from_name") for c in s.checks)


def test_init_without_a_date_in_the_names_leaves_the_time_of_day_unread(tmp_path):
    folder = tmp_path / "raw" / "m"
    write_folder(folder, ["spindle_a.csv"], ["2026-03-14 08:00"])
    s = survey("m", [t for p in sorted(folder.iterdir()) for t in read_unknown_logs(p)])
    assert s.time is None and s.date_from_name is None
    assert "date_from_name" not in config_block(s)


# --------------------------------------------------------------------------- properties

NAME_FORMATS = ["%Y-%m-%d", "%Y%m%d", "%d.%m.%Y", "%Y_%m_%d", "%d-%m-%Y"]


@settings(max_examples=200, deadline=None, derandomize=True)
@given(
    day=st.dates(dt.date(1900, 1, 1), dt.date(2200, 12, 31)),
    fmt=st.sampled_from(NAME_FORMATS),
    prefix=st.text("abcXYZ_- ", max_size=8),
    suffix=st.sampled_from([".csv", ".xlsx", "_spindle.csv", " (2).csv"]),
)
def test_the_date_written_in_a_name_is_found_in_it(day, fmt, prefix, suffix):
    assert dates_in_name(f"{prefix}{day.strftime(fmt)}{suffix}", fmt) == [day]


@settings(
    max_examples=40,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(
    start=st.datetimes(dt.datetime(2000, 1, 1), dt.datetime(2100, 1, 1)).map(
        lambda t: t.replace(microsecond=0)
    ),
    period_s=st.sampled_from([1, 7, 60, 600, 3600, 5 * 3600]),
    n=st.integers(2, 60),
)
def test_a_log_of_steps_under_twelve_hours_reads_back_its_clock(tmp_path, start, period_s, n):
    frame = canonical_frame(n, start=start.isoformat(), period_s=period_s)
    path = write_time_of_day_log(tmp_path / f"log_{start:%Y%m%d}.csv", frame)
    got = read_log(path, spec(path, "%Y%m%d"))
    assert got["time"].tolist() == frame["time"].tolist()


def test_init_reads_the_native_header_over_a_time_of_day_as_csv(tmp_path):
    """The native layout's header over times of day: the native reader cannot read it, so the
    block is a csv one with the date from the names."""
    folder = tmp_path / "raw" / "m"
    folder.mkdir(parents=True)
    frame = canonical_frame(120, start="2026-03-14 23:00", period_s=30)
    frame.loc[:10, "speed_rpm"] = 0.0
    frame.assign(time=frame["time"].dt.strftime("%H:%M:%S")).to_csv(folder / "run_20260314.csv", index=False)
    s = survey("m", read_unknown_logs(folder / "run_20260314.csv"))
    assert s.format == "csv" and s.date_from_name == "%Y%m%d"
    block = config_block(s)
    assert "format: csv" in block and 'date_from_name: "%Y%m%d"' in block
    got = read_with_block(folder, block)["run_20260314.csv"]
    assert got["time"].tolist() == frame["time"].tolist()
