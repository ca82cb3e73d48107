"""``rafi init``: roles, units, period and layout found in logs written by generators that know the truth.

Layouts (each written here from the twin's frames, the truth kept beside it): native csv runs like
tapping-center-a's; the shipped machining-center-b workbook (German headers, one continuous log;
its truth is the shipped config); a semicolon csv with decimal commas, 6 temperatures and a
diameter probe in mm; a csv without a time or speed column; FL_THERMAL's real log (when present).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from rafi import SENSORS
from rafi.cli import main
from rafi.errors import SettingsError
from rafi.ops.init_cli import findings
from rafi.ops.init_config import add_machine, config_block, parse_block
from rafi.ops.init_survey import survey
from rafi.readers.infer_files import read_unknown
from rafi.readers.logs import read_log
from rafi.readers.native import format_raw_log
from rafi.settings import machine_settings, validate_config
from rafi.twin.synthetic_logs import schedule_log

ROOT = Path(__file__).resolve().parents[1]
SHIPPED_B = ROOT / "raw" / "machining-center-b" / "thermal_log_2026-10-14.xlsx"


def roles(s) -> dict[str, str]:
    """header -> role of every column of a survey."""
    return {g.header: g.role for g in s.guesses}


def canonical(schedule, *, period_s=5.0, seed=0) -> pd.DataFrame:
    """A canonical frame (time, speed_rpm, T1..T16, disp_um) following a speed schedule."""
    frame, _ = schedule_log(schedule, period_s=period_s, seed=seed)
    return frame.drop(columns=["t_s", "segment"])


def write_native_runs(folder: Path) -> dict[str, float]:
    """Native files, each a cold start at one speed: name -> speed (the truth)."""
    folder.mkdir(parents=True, exist_ok=True)
    speeds = {"train_03000rpm.csv": 3000.0, "train_09000rpm.csv": 9000.0, "valid_06000rpm.csv": 6000.0}
    for k, (name, rpm) in enumerate(speeds.items()):
        frame = canonical([(0, 180), (rpm, 7200)], seed=k)
        meta = {"machine": "m", "run_id": Path(name).stem, "sample_period_s": "5"}
        (folder / name).write_text(format_raw_log(frame, meta), encoding="utf-8")
    return speeds


#: A continuous log: (speed, s) steps, two of them short (1 h) after the long ones.
CONTINUOUS = [(0, 120), (2000, 14400), (0, 7200), (4000, 14400), (0, 7200), (3000, 14400), (0, 3600),
              (4500, 3600), (1500, 3600), (0, 3600)]  # fmt: skip


def write_six_sensor_csv(path: Path) -> dict:
    """Semicolon csv, decimal commas, German timestamps, 6 temperatures and a diameter in mm
    (``Durchmesser X``: no unit in the header): the truth of every column."""
    frame = canonical(CONTINUOUS, period_s=30.0)
    out = pd.DataFrame({"Datum Uhrzeit": frame["time"].dt.strftime("%d.%m.%Y %H:%M:%S")})
    out["Drehzahl [U/min]"] = frame["speed_rpm"].round().astype(int)
    for i in range(1, 7):
        out[f"TC{i} Spindel"] = frame[f"T{i + 5}"].round(2)
    out["Durchmesser X"] = (2 * frame["disp_um"] / 1000.0).round(4)
    text = out.to_csv(sep=";", decimal=",", index=False)
    path.write_text(text, encoding="utf-8")
    truth = {"Datum Uhrzeit": "time", "Drehzahl [U/min]": "speed", "Durchmesser X": "displacement"}
    truth.update({f"TC{i} Spindel": "temperature" for i in range(1, 7)})
    return truth


# --------------------------------------------------------------------------- native runs


def test_native_runs_roles_and_training_speeds_from_the_file_names(tmp_path):
    speeds = write_native_runs(tmp_path / "raw" / "m")
    s = survey("m", [read_unknown(p) for p in sorted((tmp_path / "raw" / "m").iterdir())])
    assert s.format == "native"
    truth = {
        "time": "time",
        "speed_rpm": "speed",
        **{t: "temperature" for t in SENSORS},
        "disp_um": "displacement",
    }
    assert roles(s) == truth
    assert s.kind == "runs"
    assert s.period_s == 5.0
    train = sorted(v for k, v in speeds.items() if k.startswith("train"))
    assert s.training["speeds"] == train
    for shape in s.shapes:  # each file: a rest, then one step at its speed
        assert [st.kind for st in shape.steps] == ["idle", "constant"]
        assert shape.steps[1].level_rpm == pytest.approx(speeds[shape.name], abs=1)
    entry = parse_block(config_block(s), "m")
    assert entry["input"] == {"format": "native"}
    assert entry["training_speeds_rpm"] == train
    assert "reference" not in entry  # separate cold starts: run_start, the default


# --------------------------------------------------------------------------- machining-center-b


@pytest.fixture(scope="module")
def b_survey():
    return survey("mcb", [read_unknown(SHIPPED_B)])


def shipped_b() -> dict:
    return yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))["machines"][
        "machining-center-b"
    ]


def test_german_workbook_proposes_the_shipped_mapping(b_survey):
    shipped = shipped_b()
    entry = parse_block(config_block(b_survey), "mcb")
    got, want = entry["input"], shipped["input"]
    for key in ("format", "pattern", "sheet", "header_row", "columns", "time"):
        assert got[key] == want[key], key
    # four probes, one model each; the shipped machine qualifies Z1 alone
    assert list(got["probes"]) == ["Z1", "Z2", "X1", "Y1"]  # the spindle axis first
    assert got["probes"]["Z1"] == {"column": want["displacement"]["column"]}
    assert got["displacement"]["unit"] == want["displacement"]["unit"]
    assert "sign" not in got["displacement"]  # the sign is the user's: left as a CHECK
    assert entry["sample_period_s"] == shipped["sample_period_s"]
    assert entry["training_speeds_rpm"] == shipped["training_speeds_rpm"]
    assert entry["reference"]["rule"] == "log_start"
    assert b_survey.kind == "continuous"
    # the chronological split falls at the end of the 5000 r/min run (25 h) of the twin's schedule
    assert entry["runs"]["windows"][0] == {"role": "training", "end": 90000, "unit": "elapsed_s"}


def test_german_workbook_unsure_items_are_marked_check(b_survey):
    block = config_block(b_survey)
    sign = [ln for ln in block.splitlines() if "sign:" in ln]
    assert sign == ["        # sign: -1"]  # commented out, the flip the data suggest
    assert "CHECK: it falls while the spindle heats" in block
    assert any(c.startswith("input.displacement.sign") for c in b_survey.checks)
    probes = [ln.split(" #")[0].strip() for ln in block.splitlines() if ": {column: " in ln]
    assert probes == [f'{p}: {{column: "Verlagerung {p} [µm]"}}' for p in ("Z1", "Z2", "X1", "Y1")]
    assert any(c.startswith("input.probes: 4 displacement columns") for c in b_survey.checks)
    assert [g.header for g in b_survey.probes][0] == "Verlagerung Z1 [µm]"


def test_german_workbook_reads_to_the_shipped_frame_after_the_docs_edit(b_survey, tmp_path):
    """The one edit of docs/init.md's worked example: uncomment the sign line."""
    block = config_block(b_survey).replace("# sign: -1", "sign: -1")
    config = {"machines": {"mcb": parse_block(block, "mcb"), "machining-center-b": shipped_b()}}
    validate_config(config)
    mine = read_log(SHIPPED_B, machine_settings(config, "mcb@Z1")["input"])
    theirs = read_log(SHIPPED_B, machine_settings(config, "machining-center-b")["input"])
    pd.testing.assert_frame_equal(mine, theirs)


def test_write_adds_the_machine_and_refuses_an_existing_one(tmp_path, capsys):
    config = tmp_path / "config.yaml"
    shutil.copy(ROOT / "config.yaml", config)
    before = config.read_text(encoding="utf-8")
    rc = main(["init", "--machine", "machining-center-b", "--config", str(config), "--write", str(SHIPPED_B)])
    assert rc == 64
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'machining-center-b' is already under machines:" in err[0]
    assert config.read_text(encoding="utf-8") == before
    assert main(["init", "--machine", "mcb2", "--config", str(config), "--write", str(SHIPPED_B)]) == 0
    text = config.read_text(encoding="utf-8")
    assert text.startswith(before.rstrip("\n"))  # appended; nothing of the old text changed
    loaded = yaml.safe_load(text)
    assert list(loaded["machines"]) == ["tapping-center-a", "machining-center-b", "mcb2"]
    validate_config(loaded)
    assert machine_settings(loaded, "mcb2")["input"]["sheet"] == "Messdaten"


def test_add_machine_to_an_empty_mapping_and_to_no_mapping():
    block = "  m:\n    sample_period_s: 10\n"
    for text in ("raw_dir: raw\nmachines: {}\n", "raw_dir: raw\n", "machines:\n  a: {}\nraw_dir: raw\n"):
        new, loaded = add_machine(text, block, "m")
        assert loaded["machines"]["m"] == {"sample_period_s": 10}
        assert loaded["raw_dir"] == "raw"
    assert add_machine("", block, "m")[0] == "machines:\n" + block
    with pytest.raises(SettingsError, match="flow style"):
        add_machine("machines: {a: {sample_period_s: 5},\n  b: {}}\n", block, "m")


# --------------------------------------------------------------------------- 6 sensors, mm


def test_six_temperatures_and_a_diameter_in_mm(tmp_path):
    path = tmp_path / "probe.csv"
    truth = write_six_sensor_csv(path)
    table = read_unknown(path)
    assert table.format == "csv"
    assert (table.layout["delimiter"], table.layout["decimal"]) == (";", ",")
    s = survey("lathe", [table])
    assert roles(s) == truth
    disp = next(g for g in s.guesses if g.role == "displacement")
    assert disp.unit == "mm"
    assert list(s.sensors) == [f"T{i}" for i in range(1, 7)]
    assert s.period_s == 30.0
    assert s.time_format == "%d.%m.%Y %H:%M:%S"
    entry = parse_block(config_block(s), "lathe")
    assert entry["input"]["delimiter"] == ";" and entry["input"]["decimal"] == ","
    assert entry["input"]["time"] == {"kind": "timestamp", "format": "%d.%m.%Y %H:%M:%S"}
    assert entry["input"]["displacement"] == {"column": "Durchmesser X", "unit": "mm"}
    validate_config({"machines": {"lathe": entry}})
    machine_settings({"machines": {"lathe": entry}}, "lathe")


def test_continuous_log_proposes_log_start_a_split_and_min_constant(tmp_path):
    path = tmp_path / "probe.csv"
    write_six_sensor_csv(path)
    s = survey("lathe", [read_unknown(path)])
    assert s.kind == "continuous"
    levels = [(st.kind, round(st.level_rpm)) for st in s.shapes[0].steps if st.kind != "idle"]
    assert levels == [("constant", x) for x, _ in CONTINUOUS if x]
    # 2000, 4000 train; 3000 lies between them: validation from there on
    assert s.training["speeds"] == [2000, 4000]
    assert s.training["split_s"] == 120 + 14400 + 7200 + 14400
    value, _ = s.min_constant  # the 1 h steps become one varying run, the 4 h runs stay constant
    assert 3600 < value <= 14400


# --------------------------------------------------------------------------- no time column


def write_no_time(folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for k, rpm in enumerate((1500, 4500)):
        frame = canonical([(rpm, 3 * 3600)], period_s=60.0, seed=k)
        out = frame[list(SENSORS)].round(2)
        out["Z [um]"] = frame["disp_um"].round(2)
        (folder / f"warmup_{rpm}rpm.csv").write_text(out.to_csv(sep=";", index=False), encoding="utf-8")


def test_no_time_column_leaves_the_period_to_the_user(tmp_path, capsys):
    write_no_time(tmp_path / "raw")
    s = survey("rig", [read_unknown(p) for p in sorted((tmp_path / "raw").iterdir())])
    assert s.time is None and s.speed is None
    assert roles(s) == {**{t: "temperature" for t in SENSORS}, "Z [um]": "displacement"}
    assert any(c.startswith("input.time.period_s") for c in s.checks)
    assert s.speed_by_file == {"*1500rpm*": 1500.0, "*4500rpm*": 4500.0}
    block = config_block(s)
    assert "# period_s: 60" in block and "CHECK" in block
    assert "no time column" in "\n".join(findings(s))
    config = tmp_path / "config.yaml"
    config.write_text("raw_dir: raw\nmachines: {}\n", encoding="utf-8")
    args = ["init", "--machine", "rig", "--config", str(config), "--write", str(tmp_path / "raw")]
    assert main(args) == 64
    err = capsys.readouterr().err
    assert "input.time.period_s" in err and "nothing written" in err
    assert main([*args, "--period-s", "60"]) == 0
    assert "input.time.period_s" not in capsys.readouterr().out  # given: not a CHECK line any more
    entry = yaml.safe_load(config.read_text(encoding="utf-8"))["machines"]["rig"]
    assert entry["sample_period_s"] == 60 and entry["input"]["time"]["period_s"] == 60
    frame = read_log(
        tmp_path / "raw" / "warmup_1500rpm.csv",
        machine_settings({"machines": {"rig": entry}}, "rig")["input"],
    )
    assert (frame["speed_rpm"] == 1500).all()
    assert np.allclose(np.diff(frame["time"].to_numpy()).astype("timedelta64[s]").astype(float), 60)


def test_a_period_given_for_a_log_without_a_clock_reads_its_speed_steps(tmp_path, capsys):
    folder = tmp_path / "raw"
    folder.mkdir()
    frame = canonical(CONTINUOUS, period_s=60.0)
    out = frame[["speed_rpm", *SENSORS]].round(2).rename(columns={"speed_rpm": "Spindle Speed (RPM)"})
    out["Z Growth (um)"] = frame["disp_um"].round(2)
    (folder / "log.csv").write_text(out.to_csv(index=False), encoding="utf-8")
    tables = [read_unknown(folder / "log.csv")]
    s = survey("rig", tables)
    assert s.time is None and s.speed is not None and s.kind == "runs"
    said = "\n".join(findings(s))  # it said 'without a speed column or a clock' beside the speed it found
    assert "1 log(s) without a clock (no time column; --period-s gives one)" in said
    assert "speed column" not in said.split("layout:")[1].split("\n")[0]
    s = survey("rig", tables, period_s=60.0)  # as with a clock: the steps, the split, log_start
    assert s.kind == "continuous" and s.training["speeds"] == [2000, 4000]
    assert s.sign == 1 and not any(c.startswith("input.time.period_s") for c in s.checks)
    config = tmp_path / "config.yaml"
    args = ["init", "--machine", "rig", "--config", str(config), str(folder), "--period-s", "60"]
    assert main(args) == 0
    entry = yaml.safe_load(capsys.readouterr().out)["machines"]["rig"]
    assert entry["training_speeds_rpm"] == [2000, 4000] and entry["reference"] == {"rule": "log_start"}
    assert entry["runs"]["windows"][0]["end"] == 120 + 14400 + 7200 + 14400
    assert entry["input"]["time"] == {"kind": "none", "period_s": 60}


# --------------------------------------------------------------------------- FL_THERMAL


def fl_thermal() -> Path | None:
    for parent in ROOT.parents:
        candidate = parent / "shared" / "data" / "fl-thermal" / "data.xlsx"
        if candidate.is_file():
            return candidate
    return None


@pytest.mark.skipif(
    fl_thermal() is None, reason="FL_THERMAL's data.xlsx is not in ../shared/data/fl-thermal/"
)
def test_fl_thermal_time_speed_temperatures_and_five_probes():
    s = survey("fl-thermal", [read_unknown(fl_thermal())])
    assert s.time.header == "時間(s)" and s.time.unit == "s"
    assert s.speed.header == "spindle(RPM)"
    assert list(s.sensors) == [f"T{i}" for i in range(1, 17)]
    assert [g.header for g in s.probes] == [f"ch{i}(um)" for i in range(1, 6)]
    assert s.kind == "continuous" and s.period_s == 15.0
    assert s.training["speeds"] == [1250, 2500, 3750, 5000]
    assert s.min_constant[0] == 10800  # the tail's 1-2 h steps: one varying run (bench_realdata.py)
    entry = parse_block(config_block(s), "fl-thermal")
    validate_config({"machines": {"fl-thermal": entry}})
    assert entry["input"]["probes"] == {f"ch{i}": {"column": f"ch{i}(um)"} for i in range(1, 6)}
