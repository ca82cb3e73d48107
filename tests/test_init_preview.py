"""``rafi init --preview`` and the column rules of ``rafi init`` on columns whose truth is known."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from layout_files import write_sheet_pair

from rafi.cli import main
from rafi.ops.init_preview import preview
from rafi.readers.infer import guess_column, guess_columns, sensor_names
from rafi.readers.native import format_raw_log
from rafi.twin.synthetic_logs import schedule_log

#: A continuous log: training-like steps with cool-downs between them (speed, s).
SCHEDULE = [(0, 120), (3000, 7200), (0, 3600), (6000, 7200), (0, 3600), (4500, 7200), (0, 1800)]


def project(tmp_path: Path, machine_entry: dict) -> Path:
    """A config with one machine whose raw folder holds one native continuous log."""
    folder = tmp_path / "raw" / "m"
    folder.mkdir(parents=True)
    frame, _ = schedule_log(SCHEDULE, period_s=10.0)
    text = format_raw_log(frame.drop(columns=["t_s", "segment"]), {"machine": "m", "sample_period_s": "10"})
    (folder / "log.csv").write_text(text, encoding="utf-8")
    config = tmp_path / "config.yaml"
    entry = {"sample_period_s": 10, **machine_entry}
    config.write_text(yaml.safe_dump({"raw_dir": str(tmp_path / "raw"), "machines": {"m": entry}}), "utf-8")
    return config


def warnings(lines: list[str]) -> list[str]:
    return [ln for ln in lines if ln.startswith("warning: ")]


def test_preview_lists_the_runs_and_warns_of_run_start_on_a_continuous_log(tmp_path):
    lines = preview(str(project(tmp_path, {"training_speeds_rpm": [3000, 6000]})), "m")
    runs = [ln for ln in lines if ln.startswith("  log#")]
    assert len(runs) == 6  # three steps (the first with its rest), three cool-downs
    assert "training" in runs[0] and "3000 r/min" in runs[0]
    assert "reference: run_start" in "\n".join(lines)
    (w,) = warnings(lines)  # the pipeline's warning, counting the runs as it does (cool-downs too)
    assert "`reference: {rule: log_start}`" in w and "read per run by design" in w
    assert "log log.csv holds 6 runs of one continuous recording" in w
    # one instruction for a `rafi plan` recording, as the end-of-run line says it (issue 47)
    assert "If the log is a recording of `rafi plan`'s programme, leave it" in w
    assert "For runs inside one continuous log set" not in w


def test_preview_says_no_run_is_at_a_training_speed_and_lists_the_speeds(tmp_path):
    entry = {"training_speeds_rpm": [12000], "reference": {"rule": "log_start"}}
    (w,) = warnings(preview(str(project(tmp_path, entry)), "m"))
    assert w.startswith("warning: no run at a training speed: training_speeds_rpm is [12000]")
    assert "3000, 4500, 6000 r/min" in w


def test_preview_says_so_when_no_constant_run_was_found(tmp_path):
    entry = {"training_speeds_rpm": [3000], "reference": {"rule": "log_start"}}
    entry["runs"] = {"min_constant_s": 100000}  # every step shorter: one varying run
    w = next(w for w in warnings(preview(str(project(tmp_path, entry)), "m")) if "training speed" in w)
    assert w.endswith("training_speeds_rpm is [3000], no constant run was found")  # not 'at no speed r/min'


def test_preview_names_a_run_s_length_and_the_limit_it_is_shorter_than(tmp_path):
    window = {"role": "training", "end": 1.0, "unit": "fraction"}
    entry = {"training_speeds_rpm": [3000], "runs": {"windows": [window], "min_run_s": 8000}}
    said = "\n".join(preview(str(project(tmp_path, entry)), "m"))
    assert "but shorter than runs.min_run_s (7200 s < 8000 s)" in said  # not '(7200 s)' alone


def test_preview_names_a_window_glob_and_an_override_that_match_nothing(tmp_path, capsys):
    entry = {
        "training_speeds_rpm": [3000, 6000],
        "reference": {"rule": "log_start"},
        "runs": {
            "windows": [{"role": "validation", "start": 20000, "unit": "elapsed_s", "log": "day2*"}],
            "overrides": {"nolog#3": "excluded"},
        },
    }
    config = project(tmp_path, entry)
    assert main(["init", "--preview", "--machine", "m", "--config", str(config)]) == 0
    out = capsys.readouterr().out
    assert "warning: runs.windows[0].log 'day2*' matches no file (files: log.csv)" in out
    assert "warning: runs.overrides['nolog#3'] matches no run id or file" in out


def test_preview_window_beyond_the_log_and_a_machine_not_configured(tmp_path, capsys):
    entry = {"training_speeds_rpm": [3000], "reference": {"rule": "log_start"}}
    entry["runs"] = {"windows": [{"role": "validation", "start": 10**6, "unit": "elapsed_s"}]}
    config = project(tmp_path, entry)
    assert any("runs.windows[0] holds no sample of log.csv" in w for w in warnings(preview(str(config), "m")))
    assert main(["init", "--preview", "--machine", "other", "--config", str(config)]) == 64
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "'other' is not under machines:" in err


def test_preview_reads_every_sheet_of_a_workbook_joined_with_its_partner(tmp_path):
    folder = tmp_path / "raw" / "m"
    folder.mkdir(parents=True)
    truth = write_sheet_pair(folder, days=4, rows=60)
    entry = {
        "sample_period_s": 60,
        "training_speeds_rpm": [1000],
        "input": {
            "format": "xlsx",
            "pattern": "*X*.xlsx",
            "sheet": "*",
            "columns": {"room": "Room", "bed": "Bed", "rear": "Motor Rear", "front": "Motor Front"},
            "time": {"kind": "none", "period_s": 60},
            "speed": {"constant_rpm": 1000},
            "displacement": {"column": "Dia Disp"},
            "join": {"replace": ["X", "Y"], "by": "row"},
        },
        "runs": {
            "min_constant_s": 1800,
            "windows": [
                {"role": "training", "log": "Sheet[1-3]"},
                {"role": "validation", "log": "Sheet4"},
            ],
        },
    }
    config = tmp_path / "config.yaml"
    config.write_text(yaml.safe_dump({"raw_dir": str(tmp_path / "raw"), "machines": {"m": entry}}), "utf-8")
    lines = preview(str(config), "m")
    runs = {ln.split()[0]: ln for ln in lines if ln.startswith("  Sheet")}
    assert sorted(runs) == sorted(truth)  # one log per sheet, named after it
    assert all("training" in runs[f"Sheet{d}"] for d in (1, 2, 3))
    assert "validation_single" in runs["Sheet4"] and "+  1.05 h" in runs["Sheet4"]  # 63 rows of 60 s
    assert warnings(lines) == []


def test_stdout_is_the_block_and_stderr_the_findings(tmp_path, capsys):
    frame, _ = schedule_log(SCHEDULE, period_s=10.0)
    path = tmp_path / "log.csv"
    path.write_text(format_raw_log(frame.drop(columns=["t_s", "segment"])), encoding="utf-8")
    assert main(["init", "--machine", "m", str(tmp_path)]) == 0
    out, err = capsys.readouterr()
    entry = yaml.safe_load(out)["machines"]["m"]
    assert entry["reference"] == {"rule": "log_start"}
    assert entry["training_speeds_rpm"] == [3000, 6000]  # 4500 lies between them
    assert "layout: one continuous log" in err and "col  header" in err


# --------------------------------------------------------------------------- column rules


def warm(start: float, rise: float, n: int = 600, noise: float = 0.02, seed: int = 0) -> np.ndarray:
    """A smooth warm-up from ``start`` by ``rise``."""
    rng = np.random.default_rng(seed)
    return start + rise * (1 - np.exp(-np.arange(n) / 150)) + rng.normal(0, noise, n)


def test_kelvin_fahrenheit_and_celsius():
    kelvin = guess_column(0, "Sensor A", list(warm(295.0, 8.0)))
    assert (kelvin.role, kelvin.unit, kelvin.check) == ("temperature", "K", None)
    room_f = guess_column(0, "Sensor B", list(warm(70.0, 10.0)))  # a room in deg F, or a warm machine
    assert room_f.role == "temperature" and room_f.check and "deg F" in room_f.check
    celsius = guess_column(0, "Sensor C", list(warm(21.0, 6.0)))
    assert (celsius.unit, celsius.check, celsius.confidence) == ("degC", None, "medium")
    named = guess_column(0, "Lager vorne [°C]", list(warm(21.0, 6.0)))
    assert named.confidence == "high"


def test_displacement_units_by_range_and_resolution():
    um = guess_column(0, "Kanal 1", list(np.round(warm(0.0, 25.0, noise=0.1), 3)))
    assert (um.role, um.unit, um.check) == ("displacement", "um", None)
    mm = guess_column(0, "Kanal 2", list(np.round(warm(0.0, 0.025, noise=0.0001), 4)))
    assert (mm.role, mm.unit, mm.check) == ("displacement", "mm", None)
    unsure = guess_column(0, "Kanal 3", list(np.round(warm(0.0, 0.8, noise=0.01), 2)))
    assert unsure.role == "displacement" and unsure.unit is None and "um or mm" in unsure.check


def test_time_speed_counter_and_text():
    t0 = dt.datetime(2026, 5, 4, 6, 0)
    stamps = [t0 + dt.timedelta(seconds=30 * k) for k in range(600)]
    speed = [0.0] * 100 + [3000.0] * 300 + [0.0] * 200
    cols = [stamps, list(range(1, 601)), speed, ["ok"] * 600, list(range(600))]
    got = guess_columns(["Zeit", "Nr", "Drehzahl", "Bemerkung", "Spalte 5"], cols)
    assert [g.role for g in got] == ["time", "other", "speed", "text", "other"]
    assert got[0].unit == "timestamp" and got[2].unit == "rpm"
    assert "second time column" in got[4].why  # elapsed seconds at 1 s, or a counter: not a clock twice
    alone = guess_column(0, "Spalte 5", list(range(600)))
    assert alone.role == "time" and "row counter" in alone.check


def test_a_german_time_stamp_header_is_time_not_temperature():
    from rafi.readers.infer import header_hints

    assert header_hints("Zeitstempel") == {"time"}  # "...stempel" holds "temp"
    assert header_hints("Datum") == {"time"}  # "...um" is not a unit
    assert header_hints("Z_um") == header_hints("Z [µm]") == header_hints("Weg µm") == {"displacement"}
    days = [dt.date(2023, 7, 1)] * 10 + [dt.date(2023, 7, 2)] * 10  # workbook date cells
    (date,) = guess_columns(["Datum"], [days])
    assert (date.role, date.confidence, date.check) == ("date", "high", None)
    assert header_hints("Gastemperatur [°C]") == {"temperature"}
    assert header_hints("Temp. Lager") == {"temperature"}
    t0 = dt.datetime(2023, 7, 1, 8, 0)
    stamps = [(t0 + dt.timedelta(seconds=60 * k)).strftime("%d.%m.%Y %H:%M:%S") for k in range(300)]
    (got,) = guess_columns(["Zeitstempel"], [stamps])
    assert got.role == "time" and got.check is None


@pytest.mark.parametrize(
    "headers, names",
    [
        (["Temperatur 3 [°C]", "Temperatur 1 [°C]"], ["T3", "T1"]),
        (["t1(°C)", "t12(°C)"], ["T1", "T12"]),
        (["Lager vorne [°C]", "Motor [°C]"], ["lager_vorne", "motor"]),
        (["溫度一", "溫度二"], ["T1", "T2"]),
        (["T 1", "T 1 (b)"], ["T1", "T2"]),
    ],
)
def test_sensor_names(headers, names):
    assert sensor_names(headers) == names


def test_a_title_line_and_a_units_row_around_the_header(tmp_path):
    """The units row names the roles the headers do not (``T1`` rises steadily, like a clock)."""
    from rafi.ops.init_survey import survey
    from rafi.readers.infer_files import read_unknown

    lines = ["Messprotokoll BAZ 7;;;;", "Zeit;Drehzahl;T1;T2;Weg", "s;1/min;°C;°C;µm"]
    for k in range(400):
        row = f"{k * 10};{0 if k < 20 else 3000};{21 + k * 0.01:.2f};{21.5 + k * 0.005:.2f};{k * 0.03:.2f}"
        lines.append(row.replace(".", ","))
    path = tmp_path / "title.csv"
    path.write_text("\n".join(lines) + "\n", encoding="cp1252")
    table = read_unknown(path)
    assert table.layout == {
        "delimiter": ";",
        "decimal": ",",
        "encoding": "cp1252",
        "header_row": 2,
        "skip_rows": 1,
    }
    s = survey("x", [table])
    assert [g.role for g in s.guesses] == ["time", "speed", "temperature", "temperature", "displacement"]
    assert [g.unit for g in s.guesses] == ["s", "rpm", "degC", "degC", "um"]


def test_preview_says_when_no_run_validates_and_its_split_gives_one(tmp_path):
    entry = {"training_speeds_rpm": [3000, 4500, 6000], "reference": {"rule": "log_start"}}
    (w,) = warnings(preview(str(project(tmp_path, entry)), "m"))
    assert w.startswith(
        "warning: only cool-downs validate: the pipeline qualifies a model on the spindle at rest"
    )
    hint = yaml.safe_load(w.split("e.g. the last 30 %: ", 1)[1])
    assert hint == {
        "runs": {
            "windows": [
                {"role": "training", "end": 0.7, "unit": "fraction"},
                {"role": "validation", "start": 0.7, "unit": "fraction"},
            ]
        }
    }
    split = tmp_path / "split"
    lines = preview(str(project(split, {**entry, **hint})), "m")
    assert warnings(lines) == []
    runs = [ln for ln in lines if ln.startswith("  log#")]
    assert any(" constant training " in ln for ln in runs)
    assert any(" constant validation_" in ln for ln in runs)


def test_a_candidate_without_a_validation_run_is_told_how_to_get_one():
    from rafi.ops.gates import gate_outcome

    passed, (reason,), _ = gate_outcome(None, None, {})
    assert not passed and reason.startswith("no validation runs: the candidate cannot be qualified; ")
    assert "runs.windows" in reason and "docs/raw-format.md#" in reason


def test_a_clock_in_hours_and_temperatures_in_deg_f_are_proposed_as_such(tmp_path, capsys):
    folder = tmp_path / "raw" / "m"
    folder.mkdir(parents=True)
    hours = np.arange(400) / 60.0  # a row a minute
    temps = 68.0 + 18.0 * (1.0 - np.exp(-np.arange(400) / 80.0))
    lines = ["Time (h),Z (mm),Sensor 1 (F),Sensor 2 (F)"]
    lines += [f"{h:.6f},{0.00001 * k:.6f},{t:.3f},{t - 2:.3f}" for k, (h, t) in enumerate(zip(hours, temps))]
    (folder / "run.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    assert main(["init", "--machine", "m", str(folder)]) == 0
    out = capsys.readouterr()
    block = yaml.safe_load(out.out)["machines"]["m"]
    assert block["sample_period_s"] == 60  # the period in seconds, not 0.0167 (hours)
    assert block["input"]["time"]["kind"] == "elapsed_h"
    assert block["input"]["temperature_unit"] == "F"
    assert "deg F: converted to deg C as read" in out.out  # not 'read as deg C'
    assert "convert" not in out.err  # nothing to convert by hand


@pytest.mark.parametrize("kind", ["epoch_s", "epoch_ms", "excel_days"])
def test_a_clock_written_as_a_number_is_proposed_as_its_kind_and_read_back(tmp_path, capsys, kind):
    """Unix seconds, Unix milliseconds and Excel's day numbers are dates, not elapsed seconds:
    proposed with their kind, no start asked for, the period in seconds, the block reads the
    file back at the dates written (openpyxl and the standard library as the oracles)."""
    from openpyxl.utils.datetime import to_excel

    from rafi.readers.input_spec import normalise_input_spec
    from rafi.readers.logs import read_log

    folder = tmp_path / "raw" / "m"
    folder.mkdir(parents=True)
    t0 = dt.datetime(2026, 3, 2, 6, 0)
    stamps = [t0 + dt.timedelta(seconds=60 * k) for k in range(400)]
    unix = [int((t - dt.datetime(1970, 1, 1)).total_seconds()) for t in stamps]
    clock = {
        "epoch_s": [str(u) for u in unix],
        "epoch_ms": [str(1000 * u) for u in unix],
        "excel_days": [f"{to_excel(t):.10f}" for t in stamps],
    }[kind]
    temps = 22.0 + 9.0 * (1.0 - np.exp(-np.arange(400) / 80.0))
    lines = ["Clock,RPM,T1,T2,Z_um"]
    lines += [f"{c},6000,{v:.3f},{v - 1:.3f},{0.05 * k:.3f}" for k, (c, v) in enumerate(zip(clock, temps))]
    (folder / "log.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    assert main(["init", "--machine", "m", str(folder)]) == 0
    out = capsys.readouterr()
    block = yaml.safe_load(out.out)["machines"]["m"]
    assert block["sample_period_s"] == 60
    assert block["input"]["time"] == {"kind": kind}
    assert "input.time.start" not in out.err and "elapsed seconds" not in out.err
    frame = read_log(folder / "log.csv", normalise_input_spec(block["input"]))
    assert frame["time"].tolist() == [pd.Timestamp(t) for t in stamps]


def test_a_date_and_a_time_of_day_column_are_proposed_as_one_clock_and_read_back(tmp_path, capsys):
    from rafi.readers.input_spec import normalise_input_spec
    from rafi.readers.logs import read_log

    folder = tmp_path / "raw" / "m"
    folder.mkdir(parents=True)
    t0 = dt.datetime(2023, 7, 1, 20, 0)
    stamps = [t0 + dt.timedelta(seconds=60 * k) for k in range(400)]  # across midnight
    temps = 22.0 + 9.0 * (1.0 - np.exp(-np.arange(400) / 80.0))
    lines = ["Date,Time,RPM,T1,T2,Z_um"]
    lines += [
        f"{t:%Y-%m-%d},{t:%H:%M:%S},6000,{v:.3f},{v - 1:.3f},{0.05 * k:.3f}"
        for k, (t, v) in enumerate(zip(stamps, temps))
    ]
    (folder / "log.csv").write_text("\n".join(lines) + "\n", encoding="utf-8")
    assert main(["init", "--machine", "m", str(folder)]) == 0
    out = capsys.readouterr()
    block = yaml.safe_load(out.out)["machines"]["m"]
    assert block["sample_period_s"] == 60
    assert block["input"]["columns"]["time"] == "Time"
    assert block["input"]["time"]["kind"] == "timestamp" and block["input"]["time"]["date_column"] == "Date"
    assert "Date" not in out.err.split("CHECK", 1)[-1]  # no check on the date column
    frame = read_log(folder / "log.csv", normalise_input_spec(block["input"]))
    assert frame["time"].tolist() == [pd.Timestamp(t) for t in stamps]


def test_a_time_of_day_without_a_date_is_not_a_clock():
    got = guess_columns(
        ["Time", "T1"], [["08:00:00", "08:00:30", "08:01:00"] * 50, list(np.linspace(20, 30, 150))]
    )
    assert got[0].role == "other" and "without a date column" in got[0].why


def test_a_utf16_text_export_is_named_as_such(tmp_path, capsys):
    """Excel's "Unicode text" export is UTF-16 with a byte-order mark: ``rafi init`` says so and
    what to do, not that it found no header (it read the bytes as cp1252)."""
    folder = tmp_path / "raw" / "m"
    folder.mkdir(parents=True)
    rows = ["Zeit\tDrehzahl\tT1\tZ [µm]"] + [
        f"{10 * k}\t3000\t{22 + 0.01 * k:.2f}\t{0.1 * k:.2f}" for k in range(50)
    ]
    (folder / "log.txt").write_text("\r\n".join(rows) + "\r\n", encoding="utf-16")
    assert main(["init", "--machine", "m", str(folder)]) != 0
    err = capsys.readouterr().err
    assert "UTF-16 encoded; save it as UTF-8 text" in err and "no header line" not in err
