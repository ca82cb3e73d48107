"""``input.footer_rows``: summary rows at the end of each file (``Mean``, ``Max``) are dropped when
the key says so, stop the reader naming the file, the line and the key when it does not (never
read as samples), and ``rafi init`` finds them and proposes the key."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from layout_files import write_table

from rafi import SENSORS
from rafi.errors import InputSpecError, RawFormatError
from rafi.ops.init_config import config_block, parse_block
from rafi.ops.init_survey import survey
from rafi.readers.infer_files import footer_rows, read_unknown_logs
from rafi.readers.input_spec import normalise_input_spec
from rafi.readers.logs import read_log
from rafi.settings import machine_settings, validate_config
from rafi.twin.synthetic_logs import schedule_log

COLUMNS = {"time": "Time", "speed_rpm": "Spindle speed", **{s: f"TC{s[1:]}" for s in SENSORS}}
SPEC = {"format": "csv", "columns": COLUMNS, "displacement": {"column": "Displacement Z"}}


def daily_table(rpm: float, n: int = 180, seed: int = 0) -> pd.DataFrame:
    """A day's log at 60 s under the tester's headers."""
    frame, _ = schedule_log([(0, 180), (rpm, n * 60 - 180)], period_s=60.0, seed=seed)
    frame = frame.iloc[:n]
    out = pd.DataFrame({"Time": frame["time"].dt.strftime("%Y-%m-%d %H:%M:%S")})
    out["Spindle speed"] = frame["speed_rpm"].round()
    for s in SENSORS:
        out[f"TC{s[1:]}"] = frame[s].round(2)
    out["Displacement Z"] = frame["disp_um"].round(2)
    return out


def with_summary(table: pd.DataFrame, labels=("Mean", "Max")) -> pd.DataFrame:
    rows = []
    for label in labels:
        values = table.drop(columns="Time").agg("mean" if label != "Max" else "max").round(2)
        rows.append({"Time": label, **values.to_dict()})
    return pd.concat([table, pd.DataFrame(rows)], ignore_index=True)


def write(table: pd.DataFrame, path: Path) -> Path:
    return write_table(table, path)


def spec_for(path: Path, **more) -> dict:
    return {**SPEC, "format": "xlsx" if path.suffix == ".xlsx" else "csv", **more}


@pytest.mark.parametrize("labels", [("Mean", "Max"), ("Average",), ("Min", "Max", "Std", "Sum")])
@pytest.mark.parametrize("suffix", [".csv", ".xlsx"])
def test_footer_rows_are_dropped_and_the_frame_is_the_samples(tmp_path, labels, suffix):
    table = daily_table(2500)
    path = write(with_summary(table, labels), tmp_path / f"day{suffix}")
    frame = read_log(path, spec_for(path, footer_rows=len(labels)))
    plain = read_log(write(table, tmp_path / f"plain{suffix}"), spec_for(path))
    pd.testing.assert_frame_equal(frame, plain)
    assert frame.index[-1] == len(table) + 1  # the last sample's line: the summary rows are gone


@pytest.mark.parametrize("suffix", [".csv", ".xlsx"])
def test_without_the_key_a_summary_row_stops_the_reader_naming_the_key(tmp_path, suffix):
    table = daily_table(2500)
    path = write(with_summary(table), tmp_path / f"day{suffix}")
    with pytest.raises(RawFormatError) as info:
        read_log(path, spec_for(path))
    message = str(info.value)
    row = len(table) + 2
    where = f"sheet 'Log', row {row}" if suffix == ".xlsx" else f"line {row}"
    assert message.startswith(f"{path}, {where}, column 'Time': 'Mean' is not a timestamp")
    assert "the last 2 rows hold text in the time column ('Mean', 'Max')" in message
    assert "a summary row? set input.footer_rows: 2" in message


def test_a_bad_time_in_the_middle_is_the_usual_error(tmp_path):
    table = with_summary(daily_table(2500))
    table.loc[50, "Time"] = "Mean"
    path = write(table, tmp_path / "day.csv")
    for footer in (0, 2):
        with pytest.raises(RawFormatError) as info:
            read_log(path, spec_for(path, footer_rows=footer))
        message = str(info.value)
        assert "line 52, column 'Time': 'Mean' is not a timestamp; expected an ISO-8601" in message
        assert "footer_rows" not in message


def test_a_footer_key_on_a_file_without_summary_rows_is_refused(tmp_path):
    table = daily_table(2500)
    path = write(table, tmp_path / "day.csv")
    with pytest.raises(RawFormatError) as info:
        read_log(path, spec_for(path, footer_rows=2))
    message = str(info.value)
    assert f"line {len(table)}, column 'Time'" in message
    assert "is a sample" in message and "input.footer_rows: 2" in message
    with pytest.raises(RawFormatError, match="input.footer_rows: 200 .* only 180 data rows"):
        read_log(path, spec_for(path, footer_rows=200))


@pytest.mark.parametrize("value", [-1, True, 1.5, "2"])
def test_a_wrong_footer_rows_is_refused_naming_the_key(value):
    with pytest.raises(InputSpecError, match="input.footer_rows: .* expected an integer >= 0"):
        normalise_input_spec({"format": "csv", "footer_rows": value})


def test_footer_rows_found_only_below_times_or_numbers():
    times = [f"2026-06-01 08:{m:02d}:00" for m in range(30)]
    assert footer_rows([times + ["Mean", "Max"], list(range(32))]) == 2
    assert footer_rows([list(range(30)) + ["Average"]]) == 1
    assert footer_rows([times]) == 0
    assert footer_rows([times + ["NaN"] + times]) == 0  # in the middle: not a footer
    assert footer_rows([["a", "b", "c", "d"]]) == 0  # text all along


@pytest.mark.parametrize("suffix", [".csv", ".xlsx"])
def test_init_finds_the_summary_rows_and_proposes_the_key(tmp_path, suffix):
    folder = tmp_path / "raw" / "m"
    folder.mkdir(parents=True)
    paths = [
        write(with_summary(daily_table(rpm, seed=k)), folder / f"2026-06-0{k + 1}_thermal{suffix}")
        for k, rpm in enumerate((1250, 2500))
    ]
    s = survey("m", [t for p in paths for t in read_unknown_logs(p)])
    assert s.time is not None and s.time.header == "Time" and s.time.unit == "timestamp"
    assert s.period_s == 60.0
    assert any("summary" in n and "'Mean', 'Max'" in n for n in s.notes)
    block = config_block(s)
    entry = parse_block(block, "m")
    assert entry["input"]["footer_rows"] == 2
    assert entry["input"]["time"] == {"kind": "timestamp"}
    config = {"machines": {"m": entry}}
    validate_config(config)
    settings = machine_settings(config, "m")
    for path in paths:
        frame = read_log(path, settings["input"])
        assert len(frame) == 180 and frame["time"].is_monotonic_increasing
