"""A machine's own temperature sensors (issue "Any real machine in one try"): the input mapping
names them, every step carries them, and machines of 4, 6, 22 and 40 sensors written by the twin
(rafi.twin.layouts) run end to end through the real Snakefile."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from project_copy import copy_project, run_rafi, run_snakemake

from rafi.contract.results import (
    COMPARISON_FILES,
    DECISION_FILES,
    PIPELINE_TABLES,
    REPLAY_FILES,
    result_file,
)
from rafi.contract.sensors import DEFAULT_SENSORS, frame_sensors, run_sensors
from rafi.errors import InputSpecError
from rafi.readers.input_spec import normalise_input_spec, probe_spec
from rafi.readers.log_sources import expand_logs
from rafi.readers.logs import read_log
from rafi.settings import machine_settings
from rafi.twin.layouts import DAILY_SHEETS, LAYOUTS, layout_config, layout_frame, write_layout

# --------------------------------------------------------------------------- resolution


def test_sensors_resolve_from_the_list_then_the_mapping_then_the_paper_rig():
    assert normalise_input_spec(None)["sensors"] == list(DEFAULT_SENSORS)
    assert normalise_input_spec({"sensors": ["a", "b"]})["sensors"] == ["a", "b"]
    mapped = {"format": "csv", "columns": {"time": "Zeit", "front": "F [C]", "speed_rpm": "n", "rear": "R"}}
    assert normalise_input_spec(mapped)["sensors"] == ["front", "rear"]


@pytest.mark.parametrize(
    ("spec", "key", "words"),
    [
        ({"sensors": ["T1", "T1"]}, "input.sensors", "listed twice"),
        ({"sensors": ["x", "dx"]}, "input.sensors", "rise of sensor 'x'"),
        ({"sensors": ["segment"]}, "input.sensors", "pipeline's own"),
        ({"sensors": [f"s{i}" for i in range(65)]}, "input.sensors", "1 to 64"),
        ({"format": "csv", "columns": {"1st": "A"}}, "input.columns.1st", "not a sensor name"),
    ],
)
def test_bad_sensor_names_name_the_key_and_the_cause(spec, key, words):
    with pytest.raises(InputSpecError, match=key) as info:
        normalise_input_spec(spec)
    assert words in str(info.value)


def test_frame_and_run_sensors_read_the_tables_layout():
    clean = pd.DataFrame(columns=["time", "t_s", "speed_rpm", "front", "rear", "disp_um", "segment", "amb"])
    assert frame_sensors(clean) == ("front", "rear")
    runs = pd.DataFrame(columns=["run_id", "front", "rear", "disp_um", "dfront", "drear", "dz_um"])
    assert run_sensors(runs) == ("front", "rear")
    assert run_sensors(["dT1", "dT2", "dz_um", "disp_um"]) == ("T1", "T2")  # rises only
    with pytest.raises(ValueError, match="canonical"):
        frame_sensors(["time", "front"])


# --------------------------------------------------------------------------- the twin's layouts


def test_a_layout_derives_its_extra_sensors_from_two_of_the_twins():
    layout = LAYOUTS["sensors-22"]
    n = 400
    log = pd.DataFrame({"time": pd.date_range("2026-01-01", periods=n, freq="30s"), "speed_rpm": 0.0})
    rng = np.random.default_rng(0)
    for s in DEFAULT_SENSORS:
        log[s] = 20 + np.cumsum(rng.normal(0, 0.05, n))
    log["disp_um"] = 0.0
    frame = layout_frame(layout, log, seed=3)
    assert frame_sensors(frame) == layout.sensors
    assert (frame["T5"] == log["T5"]).all()  # a twin sensor as it is
    a, b, w = layout.sources[20]
    mix = w * log[a] + (1 - w) * log[b]
    # a derived sensor follows its mix (low-passed, 0.02 K noise): close, not equal
    assert np.abs(frame["T21"] - mix).iloc[100:].max() < 1.0
    assert not np.allclose(frame["T21"], mix)


@pytest.mark.parametrize("name", sorted(LAYOUTS))
def test_each_layout_reads_back_with_its_config(tmp_path, name):
    files = write_layout(name, tmp_path)
    layout = LAYOUTS[name]
    spec = normalise_input_spec(layout_config(name)["input"])
    if layout.probes:  # read as its Z probe's unit reads it
        spec = probe_spec(spec, "Z")
    logs, _ = expand_logs(files, spec)
    source = next(iter(logs.values()))
    frame = read_log(source["path"], spec, sheet=source["sheet"], partner=source["partner"])
    assert frame_sensors(frame) == layout.sensors
    assert len(logs) == (DAILY_SHEETS if name == "sheets-18" else 5)  # a sheet a day; a log per pair
    assert frame["speed_rpm"].max() == pytest.approx(3000, abs=5)
    assert frame["disp_um"].abs().max() > 5.0  # um after the unit and sign of the mapping


# --------------------------------------------------------------------------- end to end

E2E_LAYOUTS = ("sensors-4", "sensors-6-diameter", "sensors-22", "sensors-40", "probes-xyz")
#: Every unit's outputs short of the report (rule all's, less reports/): what the checks of
#: :func:`check_unit` read. The report (HTML + PDF, most of a unit's run time) is made for the
#: layouts of :data:`REPORTED` only, one per concern of the report.
UNIT_RESULTS = (*PIPELINE_TABLES, *COMPARISON_FILES, *DECISION_FILES, *REPLAY_FILES)
#: Layouts run to their report: 40 sensors of the plant's own names (more than the twin's 16:
#: the widest tables and heatmaps); three probes (a report per probe and the machine's probes
#: report over them); a workbook with a log per sheet (run ids that are sheet names).
REPORTED = ("sensors-40", "probes-xyz", "sheets-18")


def unit_targets(units: list[str], folders: list[str]) -> list[str]:
    """Snakemake targets: every unit's :data:`UNIT_RESULTS`; the report of a unit, and of a
    machine folder with several probes, whose layout is in :data:`REPORTED`."""
    targets = [f"results/{unit}/{result_file(name)}" for unit in units for name in UNIT_RESULTS]
    reported = [u for u in units + folders if u.split("@")[0] in REPORTED]
    return targets + [f"reports/{u}/qualification.{ext}" for u in reported for ext in ("html", "pdf")]


def init_proposal(proj: Path, machine: str, files: list[Path]) -> dict:
    """The ``machines.<machine>:`` block ``rafi init`` proposes for ``files``, taken as written."""
    done = run_rafi(proj, "init", "--machine", machine, *map(str, files))
    assert done.returncode == 0, done.stderr
    return yaml.safe_load(done.stdout)["machines"][machine]


def check_unit(proj: Path, config: dict, unit: str) -> None:
    """What a unit of a twin layout run end to end must hold: rafi init's sensors in runs.parquet,
    key sensors among them (one of the twin's heated T6, T8, T9 included), a champion that halves
    the worst error, a replay, a clean audit and, if its layout is in :data:`REPORTED`, a report
    naming the first key sensor."""
    name = unit.split("@")[0]
    sensors = tuple(machine_settings(config, unit)["input"]["sensors"])  # rafi init's names
    assert len(sensors) == len(LAYOUTS[name].sensors)
    results = proj / "results" / unit
    runs = pd.read_parquet(results / "runs.parquet")
    assert run_sensors(runs) == sensors
    keys = pd.read_csv(results / "rank" / "key_sensors.csv")["sensor"].tolist()
    assert keys and set(keys) <= set(sensors)
    # the twin's heat goes through its T6, T8, T9: the layouts' names of those must be found
    twin_keys = {
        s for s, (a, b, _) in zip(sensors, LAYOUTS[name].sources) if a == b and a in ("T6", "T8", "T9")
    }
    assert set(keys) & twin_keys
    best = json.loads((results / "comparison" / "best_model.json").read_text())
    assert set(best["key_sensors"]) <= set(sensors)
    summary = pd.read_csv(results / "comparison" / "summary.csv")
    offered = summary[summary["champion"]].iloc[0]
    assert offered["max_abs_after_um"] < 0.5 * offered["max_abs_before_um"]
    replay = pd.read_csv(results / "deploy" / "replay_summary.csv")
    assert len(replay) > 0
    audit = pd.read_csv(results / "audit.csv")
    assert (audit["status"] == "ok").all()
    if name not in REPORTED:
        return
    html = (proj / "reports" / unit / "qualification.html").read_text(encoding="utf-8")
    assert keys[0] in html
    assert (proj / "reports" / unit / "qualification.pdf").stat().st_size > 10_000


@pytest.mark.slow
def test_machines_of_4_to_40_sensors_and_three_probes_run_end_to_end_from_rafi_inits_proposal(tmp_path):
    proj = copy_project(tmp_path / "proj", config=False)
    config = {"machines": {}}
    for name in E2E_LAYOUTS:
        files = write_layout(name, proj / "raw")
        config["machines"][name] = init_proposal(proj, name, files)
    (proj / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False, allow_unicode=True))
    raw_before = {p: p.read_bytes() for p in (proj / "raw").rglob("*") if p.is_file()}
    probes = {"dX": "dX [um]", "dY": "dY [um]", "dZ": "dZ [um]"}  # rafi init's names for them
    assert config["machines"]["probes-xyz"]["input"]["probes"] == {
        p: {"column": c} for p, c in probes.items()
    }
    units = [n for n in E2E_LAYOUTS if n != "probes-xyz"] + [f"probes-xyz@{p}" for p in probes]
    targets = unit_targets(units, ["probes-xyz"])

    done = run_snakemake(proj, *targets, cores=2, timeout=1500)
    assert done.returncode == 0, done.stderr[-3000:]
    for unit in units:
        check_unit(proj, config, unit)
    # several probes: one report, every probe's verdict on its first page, a section per probe
    page = (proj / "reports" / "probes-xyz" / "qualification.html").read_text(encoding="utf-8")
    for probe, column in probes.items():
        assert f'id="probe-{probe}"' in page and column in page
        assert f"../probes-xyz@{probe}/qualification.html" in page
    # the Y probe moves against the spindle's growth, with its own (negative) gain: its model says so
    y_model = json.loads((proj / "results" / "probes-xyz@dY" / "comparison" / "best_model.json").read_text())
    z_model = json.loads((proj / "results" / "probes-xyz@dZ" / "comparison" / "best_model.json").read_text())
    assert y_model["model_id"] != z_model["model_id"]
    assert {p: p.read_bytes() for p in (proj / "raw").rglob("*") if p.is_file()} == raw_before
    again = run_snakemake(proj, "-n", *targets, cores=2)
    assert "Nothing to be done" in again.stdout + again.stderr
    # a night of this machine alone (rafi nightly --machine probes-xyz) rebuilds its probes report
    (proj / "reports" / "probes-xyz" / "qualification.html").unlink()
    night = run_snakemake(proj, "-n", "nightly", "--config", "nightly_machines=probes-xyz", cores=2)
    assert night.returncode == 0 and "rule probes_report:" in night.stdout + night.stderr


#: The workbook and file layouts of issue 45: no header row, a sheet a day, two files a run.
E2E_FILE_LAYOUTS = ("headerless-xlsx", "sheets-18", "two-files")


@pytest.mark.slow
def test_a_headerless_workbook_18_daily_sheets_and_two_files_a_run_end_to_end_from_rafi_inits_proposal(
    tmp_path,
):
    proj = copy_project(tmp_path / "proj", config=False)
    config = {"machines": {}}
    for name in E2E_FILE_LAYOUTS:
        files = write_layout(name, proj / "raw")
        config["machines"][name] = init_proposal(proj, name, files)
    truth = {name: layout_config(name)["input"] for name in E2E_FILE_LAYOUTS}
    proposed = {name: config["machines"][name]["input"] for name in E2E_FILE_LAYOUTS}
    assert normalise_input_spec(proposed["headerless-xlsx"])["header_row"] is None
    assert (
        list(proposed["headerless-xlsx"]["columns"].values())
        == list(truth["headerless-xlsx"]["columns"].values())[:-1]
    )
    assert proposed["headerless-xlsx"]["displacement"]["column"] == "I"
    assert proposed["sheets-18"]["sheet"] == truth["sheets-18"]["sheet"]
    assert proposed["two-files"]["join"] == truth["two-files"]["join"]
    (proj / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False, allow_unicode=True))
    raw_before = {p: p.read_bytes() for p in (proj / "raw").rglob("*") if p.is_file()}

    done = run_snakemake(proj, *unit_targets(list(E2E_FILE_LAYOUTS), []), cores=2, timeout=1500)
    assert done.returncode == 0, done.stderr[-3000:]
    for name in E2E_FILE_LAYOUTS:
        check_unit(proj, config, name)
    # a log per sheet (named after it) and per pair of files (named after the temperatures' file)
    audit = pd.read_csv(proj / "results" / "sheets-18" / "audit.csv")
    assert sorted(audit["file"]) == [f"Tag {d:02d}" for d in range(1, DAILY_SHEETS + 1)]
    audit = pd.read_csv(proj / "results" / "two-files" / "audit.csv")
    assert len(audit) == 5 and all("temps" in f for f in audit["file"])
    assert {p: p.read_bytes() for p in (proj / "raw").rglob("*") if p.is_file()} == raw_before


# --------------------------------------------------------------------------- probes


def test_a_probe_is_a_unit_with_its_column_and_its_own_settings():
    from rafi.errors import SettingsError
    from rafi.settings import machine_units, split_unit, unit_name

    config = {
        "machines": {
            "lathe": {
                "input": {"format": "csv", "probes": {"X": "dx [um]", "Z": {"column": "dz", "sign": -1}}}
            },
            "lathe@Z": {"deploy": {"clamp_um": [-5.0, 5.0]}},
        }
    }
    assert machine_units(config, "lathe") == ["lathe@X", "lathe@Z"]
    assert split_unit("lathe@Z") == ("lathe", "Z") and unit_name("lathe", None) == "lathe"
    z = machine_settings(config, "lathe@Z")
    assert z["input"]["displacement"] == {"column": "dz", "unit": "um", "sign": -1}
    assert z["deploy"]["clamp_um"] == [-5.0, 5.0]
    assert machine_settings(config, "lathe@X")["deploy"]["clamp_um"] != [-5.0, 5.0]
    assert normalise_input_spec(z["input"]) == z["input"]  # a probe's mapping reads back as itself
    with pytest.raises(SettingsError, match="no probe 'Y'"):
        machine_settings(config, "lathe@Y")
    config["machines"]["lathe@X"] = {"input": {"format": "csv"}}
    with pytest.raises(SettingsError, match=r"machines.lathe@X.input: a probe reads its machine's files"):
        machine_settings(config, "lathe@X")


@pytest.mark.parametrize(
    ("spec", "key"),
    [
        (
            {"format": "csv", "probes": {"X": {"column": "a"}}, "displacement": {"column": "b"}},
            "displacement.column",
        ),
        ({"probes": {"X": {"column": "a"}}}, "input.probes"),  # native: one disp_um
        ({"format": "csv", "probes": {"1X": {"column": "a"}}}, "input.probes.1X"),
        ({"format": "csv", "probes": {"X": {"column": "a", "unit": "cm"}}}, "input.probes.X.unit"),
        ({"format": "csv", "probes": {"X": {"column": "a", "gain": 2}}}, "input.probes.X.gain"),
    ],
)
def test_bad_probes_name_the_key(spec, key):
    with pytest.raises(InputSpecError, match=key.replace(".", r"\.")):
        normalise_input_spec(spec)


def test_the_report_says_where_the_probe_measured():
    from rafi.report.verdict import probe_words

    probe = {"column": "dz", "unit": "um", "sign": 1, "description": "spindle nose, axial"}
    spec = {"displacement": {"column": "dz"}, "probes": {"Z": probe}}
    assert probe_words({"input": spec, "report": {}}) == "on probe Z (channel 'dz': spindle nose, axial)"
    assert (
        probe_words({"input": {"displacement": {"column": "Ø [mm]"}}, "report": {}}) == "on channel 'Ø [mm]'"
    )
    assert (
        probe_words({"input": {"displacement": {}}, "report": {"paper_rig": True}})
        == "on the spindle axis (Z)"
    )


def test_record_writes_the_machines_own_sensors_and_refuses_several_probes():
    from rafi.deploy.record_cli import recorded_columns
    from rafi.errors import SettingsError

    assert recorded_columns("a", normalise_input_spec(None)) == (
        "time",
        "speed_rpm",
        *DEFAULT_SENSORS,
        "disp_um",
    )
    own = normalise_input_spec({"sensors": ["front", "rear"]})
    assert recorded_columns("b", own) == ("time", "speed_rpm", "front", "rear", "disp_um")
    mapped = normalise_input_spec({"format": "csv", "columns": {"time": "Zeit", "motor": "M [C]"}})
    assert recorded_columns("c", mapped) == ("time", "speed_rpm", "motor", "disp_um")
    probes = normalise_input_spec({"format": "csv", "probes": {"X": "x", "Y": "y"}})
    with pytest.raises(SettingsError) as caught:
        recorded_columns("d", probes)
    assert str(caught.value) == (
        "machines.d.input.probes: the machine has several probes (X, Y); rafi record writes one "
        "displacement column (disp_um), not one per probe: record with the machine's own logger "
        "(docs/record.md)"
    )


def test_init_preview_of_a_machine_with_probes_lists_its_runs_once(tmp_path):
    from rafi.ops.init_preview import preview

    write_layout("probes-xyz", tmp_path / "raw", machine="xyz")
    config = {"raw_dir": str(tmp_path / "raw"), "machines": {"xyz": layout_config("probes-xyz")}}
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(config), encoding="utf-8")
    lines = preview(str(path), "xyz")
    assert lines[1].strip().startswith("probes: X, Y, Z")
    assert any("train_03000rpm" in line and "training" in line for line in lines)
    assert preview(str(path), "xyz@Y")[2:] == lines[3:]  # one probe: the same runs


def test_probes_by_machine_groups_the_units_of_several_probes():
    from rafi.settings import probes_by_machine

    units = ["a", "fl@ch1", "fl@ch2", "xyz@Z"]
    assert probes_by_machine(units) == {"fl": ["ch1", "ch2"], "xyz": ["Z"]}


@pytest.mark.slow
def test_a_night_of_a_machine_with_probes_says_every_probe(tmp_path):
    from project_copy import run_nightly, settle

    proj = copy_project(tmp_path / "proj", config=False)
    for path in write_layout("probes-xyz", proj / "raw", machine="xyz"):
        settle(path)
    config = {"machines": {"xyz": layout_config("probes-xyz")}}
    (proj / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")
    done = run_nightly(proj, "--machine", "xyz")
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    for probe in ("X", "Y", "Z"):
        assert (proj / "results" / f"xyz@{probe}" / "registry" / "decision.json").is_file()
        assert f"xyz@{probe}: PASS - model offered" in done.stdout, done.stdout
    status = run_rafi(proj, "status", "--directory", str(proj), "--json")
    rows = {row["machine"] for row in json.loads(status.stdout)["machines"]}
    assert rows == {"xyz@X", "xyz@Y", "xyz@Z"}, status.stderr


def test_a_folder_named_like_a_probe_is_skipped_with_a_reason(tmp_path):
    from rafi.readers.input_spec import discover_logs

    for name in ("lathe@Z", "lathe"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "a.csv").write_text("time,speed_rpm,T1,disp_um\n")
    found, warnings = discover_logs(tmp_path, lambda m: None)
    assert list(found) == ["lathe"]
    assert any("lathe@Z" in w and "cannot hold '@'" in w for w in warnings), warnings
