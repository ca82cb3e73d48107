"""`rafi record` into a machine whose own logs are in another format (docs/record.md, "How the
pipeline reads a recording"; rafi.readers.recordings): the recording is a native file, recognised
by its name and its `recorded_by` header, and read natively beside the machine's own logs.

End to end for the shipped mapped machine, machining-center-b (a 48 h xlsx log with German
headers, `*.xlsx`): the project's SINUMERIK-like OPC UA server (tests/opcua_server.py) plays a
twin log, `rafi record` records it into a copy of the project, and the real Snakefile's clean
step reads the recording beside the workbook: its clean table holds exactly the recorded rows.
"""

from __future__ import annotations

import argparse
import shutil
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from project_copy import ROOT, copy_project, run_snakemake, settle

from rafi.cli import main
from rafi.deploy import record_cli
from rafi.deploy.record_files import RecordingFile, file_stamp
from rafi.deploy.record_plan import RUN_NAME
from rafi.errors import SettingsError
from rafi.readers.input_spec import discover_logs, normalise_input_spec
from rafi.readers.logs import read_log
from rafi.readers.native import read_raw_log
from rafi.readers.recordings import (
    RECORDED_BY,
    find_recordings,
    has_recording_header,
    is_recording,
    is_recording_name,
    recording_spec,
)

MAPPED = "machining-center-b"
SENSORS16 = tuple(f"T{i}" for i in range(1, 17))
META = {"machine": MAPPED, "sample_period_s": "15", "recorded_by": f"{RECORDED_BY} 0.1.0"}


def native_row(t: str, n: int = 16) -> list[str]:
    return [t, "2500", *["21.5"] * n, "1.25"]


def recorded(folder: Path, stem: str, *, meta=META, columns=None) -> Path:
    """A closed recording of one row, as `rafi record` writes it."""
    f = RecordingFile(folder, stem, meta, **({"columns": columns} if columns else {}))
    f.write_row(native_row("2026-10-16T08:00:00Z", len(columns) - 3 if columns else 16))
    return f.close()


# --------------------------------------------------------------------------- the rule


run_names = st.from_regex(RUN_NAME, fullmatch=True)
starts = st.integers(min_value=0, max_value=7_258_118_399)  # 1970 .. 2199


@settings(max_examples=200, deadline=None)
@given(run=run_names, start=starts, n=st.integers(min_value=1, max_value=999))
def test_every_name_rafi_record_gives_is_a_recordings_name(run, start, n):
    stem = f"{run}_{file_stamp(start)}"
    assert is_recording_name(f"{stem}.csv")
    assert is_recording_name(f"{stem}_{n}.csv") and is_recording_name(f"{stem}_{n}_2.csv")
    assert not is_recording_name(f".{stem}.csv.part")  # being written: never a log
    assert not is_recording_name(f"{stem}.xlsx") and not is_recording_name(f"{stem}.csv.bak")


@pytest.mark.parametrize(
    "name",
    [
        "thermal_log_2026-10-14.csv",
        "rec_2026-10-16T080000Z.csv",  # dashes: not the recorder's stamp
        "rec_20261016T080000.csv",  # no Z
        "_20261016T080000Z.csv",  # no run
        "rec_20261016T080000Z.CSV",
        "rec_20261016T080000Z_x.csv",
    ],
)
def test_names_rafi_record_never_gives_are_not_recordings(name):
    assert not is_recording_name(name)


@settings(max_examples=100, deadline=None)
@given(notes=st.text(max_size=300).filter(lambda t: "\x00" not in t))
def test_the_header_says_recording_whatever_the_notes_and_notes_cannot_forge_it(tmp_path_factory, notes):
    folder = tmp_path_factory.mktemp("rec")
    real = recorded(folder, "rec_20261016T080000Z", meta={**META, "notes": notes})
    assert has_recording_header(real) and is_recording(real)
    # a machine's own file whose notes quote the line is not a recording
    forged = recorded(folder, "own_20261016T080000Z", meta={"machine": MAPPED, "notes": f"{notes}\n{notes}"})
    assert not has_recording_header(forged)
    forged2 = recorded(folder, "x_20261016T080000Z", meta={"notes": f"a\n# recorded_by: {RECORDED_BY} 1"})
    assert not has_recording_header(forged2)


def test_a_file_with_the_name_but_not_the_header_is_not_a_recording(tmp_path):
    path = tmp_path / "data_20261016T080000Z.csv"
    path.write_text("Zeit;Drehzahl\n0;2500\n", encoding="utf-8")
    assert is_recording_name(path.name) and not is_recording(path)
    path.write_text(f"# machine: m\ntime,speed_rpm\n# recorded_by: {RECORDED_BY}\n", encoding="utf-8")
    assert not is_recording(path)  # only the leading '#' lines are the header
    fifo = tmp_path / "rec_20261016T080000Z.csv"
    import os

    os.mkfifo(fifo)
    assert not is_recording(fifo)  # never opened: a FIFO would block


def test_a_recording_is_read_natively_with_the_machines_sensors():
    spec = normalise_input_spec(
        yaml.safe_load((ROOT / "config.yaml").read_text())["machines"][MAPPED]["input"]
    )
    assert recording_spec(spec) == {"format": "native", "sensors": list(SENSORS16), "sample_period_s": 15.0}
    own = normalise_input_spec({"format": "csv", "columns": {"time": "Zeit", "front": "V [C]", "rear": "H"}})
    assert recording_spec(own) == {"format": "native", "sensors": ["front", "rear"]}
    assert normalise_input_spec(recording_spec(spec))["format"] == "native"


# --------------------------------------------------------------------------- discovery


def mapped_spec() -> dict:
    return yaml.safe_load((ROOT / "config.yaml").read_text())["machines"][MAPPED]["input"]


def test_discovery_finds_recordings_beside_a_mapped_machines_own_logs(tmp_path):
    raw = tmp_path / "raw"
    folder = raw / MAPPED
    folder.mkdir(parents=True)
    shutil.copy2(ROOT / "raw" / MAPPED / "thermal_log_2026-10-14.xlsx", folder)
    rec = recorded(folder, "rec_20261016T080000Z")
    being_written = RecordingFile(folder, "rec_20261016T090000Z", META)
    being_written.write_row(native_row("2026-10-16T09:00:00Z"))  # not closed: hidden .part
    (folder / "notes_20261016T080000Z.csv").write_text("not a log\n", encoding="utf-8")
    found, warnings = discover_logs(raw, lambda m: mapped_spec())
    assert found == {
        MAPPED: {
            "thermal_log_2026-10-14": {
                "path": str(folder / "thermal_log_2026-10-14.xlsx"),
                "sheet": None,
                "partner": None,
                "recording": False,
            },
            rec.stem: {"path": str(rec), "sheet": None, "partner": None, "recording": True},
        }
    }
    assert warnings == []
    # a recording still settling waits like any file
    found, warnings = discover_logs(raw, lambda m: mapped_spec(), settle_s=3600)
    assert rec.stem not in found.get(MAPPED, {}) and any(w.startswith("settling:") for w in warnings)


def test_a_mapped_csv_machine_reads_its_own_csv_files_by_the_mapping_and_recordings_natively(tmp_path):
    raw = tmp_path / "raw"
    folder = raw / "m"
    folder.mkdir(parents=True)
    spec = {"format": "csv", "delimiter": ";", "columns": {"time": "Zeit", "speed_rpm": "n", "disp_um": "dz"}}
    own = folder / "log_20261016T070000Z.csv"  # the own logger's name happens to fit the rule
    header = ";".join(["Zeit", "n", *SENSORS16, "dz"])
    own.write_text(header + "\n" + ";".join(["2026-10-16 07:00:00", "0", *["20"] * 16, "0"]) + "\n")
    rec = recorded(folder, "rec_20261016T080000Z")
    found, _ = discover_logs(raw, lambda m: spec)
    logs = found["m"]
    assert logs[own.stem]["recording"] is False and logs[rec.stem]["recording"] is True
    assert read_log(own, spec)["speed_rpm"].tolist() == [0.0]
    assert read_log(rec, recording_spec(normalise_input_spec(spec)))["speed_rpm"].tolist() == [2500.0]


def test_rafi_nightly_counts_a_recording_as_a_file_of_the_mapped_machine(tmp_path):
    from rafi.ops.project import Paths, raw_logs, unmatched_folders

    config = {"machines": {MAPPED: {"input": mapped_spec()}}}
    paths = Paths(tmp_path, tmp_path / "raw", tmp_path / "results")
    folder = tmp_path / "raw" / MAPPED
    folder.mkdir(parents=True)
    assert MAPPED in unmatched_folders(paths, config, [MAPPED])  # an empty folder: skipped
    rec = recorded(folder, "rec_20261016T080000Z")
    assert raw_logs(paths, config, MAPPED) == [rec] and unmatched_folders(paths, config, [MAPPED]) == {}


def test_a_machine_with_several_probes_has_no_recordings(tmp_path):
    spec = normalise_input_spec({"format": "csv", "probes": {"X": "x", "Y": "y"}})
    recorded(tmp_path, "rec_20261016T080000Z")
    assert find_recordings(tmp_path, spec, tmp_path) == ([], [])


# --------------------------------------------------------------------------- refusals


def args_for(path: Path, machine: str, **kw) -> argparse.Namespace:
    base = dict(
        machine=machine, config=str(path), follow=None, from_start=False, plan=None, notes="", name="rec",
        duration=None, debug=False,
    )  # fmt: skip
    return argparse.Namespace(**{**base, **kw})


def write_config(tmp_path: Path, machine: str, block: dict) -> Path:
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump({"machines": {machine: block}}), encoding="utf-8")
    return path


OPCUA = {"endpoint": "opc.tcp://127.0.0.1:1", "inputs": {"speed_rpm": "/n", "T1": "/t1"}}


@pytest.mark.parametrize(
    ("machine", "block", "expected"),
    [
        (
            "xyz",
            {
                "input": {"format": "csv", "probes": {"X": "x (um)", "Y": "y (um)"}},
                "deploy": {"opcua": OPCUA},
            },
            "rafi record: machines.xyz.input.probes: the machine has several probes (X, Y); rafi record "
            "writes one displacement column (disp_um), not one per probe: record with the machine's own "
            "logger (docs/record.md)",
        ),
        (
            "lathe",
            {
                "input": {"sensors": ["front", "rear"]},
                "deploy": {"opcua": OPCUA},
                "record": {"displacement": "/z"},
            },
            "rafi record: deploy.opcua.inputs.T1: not a sensor of this machine (its sensors, input.sensors: "
            "front, rear); rafi record writes a column per sensor of the machine: name each input after its "
            "sensor",
        ),
        (
            "xyz@X",
            {},
            "rafi record: --machine 'xyz@X' names a probe of a machine (<machine>@<probe>); a recording "
            "belongs to the machine, whose folder its probes read: give the machine",
        ),
    ],
)
def test_what_the_pipeline_could_not_read_is_refused_before_recording(
    tmp_path, capsys, machine, block, expected
):
    path = write_config(tmp_path, machine, block)
    assert main(["record", "--machine", machine, "--config", str(path), "--duration", "60"]) == 64
    assert capsys.readouterr().err == expected + "\n"
    assert not (tmp_path / "raw").exists()  # nothing created, nothing connected
    with pytest.raises(SettingsError):
        record_cli.build(args_for(path, machine))


# --------------------------------------------------------------------------- own sensors, --follow


def test_a_machine_with_its_own_sensors_records_them_from_a_daq_file(tmp_path):
    """--follow a DAQ's native file of a machine with its own sensors: its columns are recorded,
    and the pipeline's discovery and reader take the recording (a mapped csv machine)."""
    sensors = ["front", "rear", "motor"]
    spec = {"format": "csv", "columns": {"time": "Zeit", "front": "V", "rear": "H", "motor": "M"}}
    path = write_config(tmp_path, "lathe", {"sample_period_s": 5, "input": spec})
    daq = tmp_path / "daq.csv"
    lines = ["time,speed_rpm,motor,front,rear,disp_um,T1"]  # any order; T1 is not the machine's
    lines += [
        f"2026-10-16T08:00:{5 * k:02d}Z,{1000 * k},{30 + k},{20 + k},{21 + k},{0.5 * k},99" for k in range(4)
    ]
    daq.write_text("\n".join(lines) + "\n", encoding="utf-8")
    out: list[str] = []
    args = args_for(path, "lathe", follow=str(daq), from_start=True, duration="5s")
    recorder, link = record_cli.build(args, log=out.append)
    assert link is None
    recorder.wall = lambda: 1792137600.0  # 2026-10-16T08:00:00Z
    recorder.sleep = lambda seconds: None
    (final,) = recorder.run()  # one tick: the four lines written so far
    assert final.parent == tmp_path / "raw" / "lathe" and is_recording(final)
    frame = read_raw_log(final, sensors)
    assert list(frame.columns) == ["time", "speed_rpm", *sensors, "disp_um"]
    assert frame["front"].tolist() == [20.0, 21.0, 22.0, 23.0] and frame["motor"].tolist() == [
        30.0,
        31.0,
        32.0,
        33.0,
    ]
    found, _ = discover_logs(tmp_path / "raw", lambda m: spec)
    (src,) = found["lathe"].values()
    assert src["recording"] is True
    back = read_log(src["path"], recording_spec(normalise_input_spec(spec)))
    pd.testing.assert_frame_equal(back, frame)


# --------------------------------------------------------------------------- end to end


@pytest.fixture(scope="module")
def server():
    pytest.importorskip("asyncua")
    from opcua_server import SinumerikLikeServer

    with SinumerikLikeServer(axis=3) as srv:
        yield srv


def twin_samples(n: int) -> pd.DataFrame:
    """``n`` samples of a twin run at 2500 r/min (values only: the recorder stamps the times)."""
    from rafi.twin.schedules import constant_schedule, with_rest
    from rafi.twin.simulate import simulate_run

    log = simulate_run(
        with_rest(constant_schedule(2500, 15 * n)), seed=5, start="2026-10-16T08:00:00", defects=False
    ).log
    return log.iloc[:n].reset_index(drop=True)


def mapped_project(tmp_path: Path, server) -> Path:
    """A copy of the project with machining-center-b only: its shipped workbook, its settings
    and the OPC UA inputs of the local server."""
    from opcua_server import DISP_NODE, input_settings

    proj = copy_project(tmp_path / "proj")
    cfg = yaml.safe_load((proj / "config.yaml").read_text(encoding="utf-8"))
    machine = cfg["machines"][MAPPED]
    machine["deploy"] = {
        "opcua": {
            "endpoint": server.endpoint,
            "inputs": input_settings(),
            "timeout_s": 3,
            "allow_insecure": True,
        }
    }
    machine["record"] = {"displacement": DISP_NODE}
    cfg["machines"] = {MAPPED: machine}
    (proj / "config.yaml").write_text(
        yaml.safe_dump(cfg, sort_keys=False, allow_unicode=True), encoding="utf-8"
    )
    raw = proj / "raw" / MAPPED
    raw.mkdir(parents=True)
    settle(
        shutil.copy2(
            ROOT / "raw" / MAPPED / "thermal_log_2026-10-14.xlsx", raw / "thermal_log_2026-10-14.xlsx"
        )
    )
    return proj


def test_a_machine_with_its_own_sensors_records_them_from_opc_ua(server, tmp_path):
    """deploy.opcua.inputs names the machine's own sensors: each is a column of the recording,
    with the value of its node; an unset sensor is an empty column (one line says so)."""
    from opcua_server import DISP_NODE, SPEED_NODE, as_read, temp_node

    nodes = {"front": 1, "rear": 9, "motor": 2}  # T1 (Int16, 0.1 degC), T9 (Float), T2
    inputs = {"speed_rpm": SPEED_NODE}
    inputs |= {name: {"node": temp_node(i)[0], "scale": temp_node(i)[2]} for name, i in nodes.items()}
    opcua = {"endpoint": server.endpoint, "inputs": inputs, "timeout_s": 3, "allow_insecure": True}
    block = {
        "sample_period_s": 5,
        "input": {"sensors": [*nodes, "housing"]},
        "deploy": {"opcua": opcua},
        "record": {"displacement": DISP_NODE},
    }
    path = write_config(tmp_path, "lathe", block)
    lines: list[str] = []
    recorder, link = record_cli.build(args_for(path, "lathe", duration="15s"), log=lines.append, environ={})
    temps = np.array([20.0 + 0.37 * i for i in range(16)])
    clock = [0.0]
    recorder.clock = recorder.files.clock = link.clock = lambda: clock[0]
    recorder.wall = lambda: 1792137600.0 + clock[0]
    recorder.sleep = lambda seconds: clock.__setitem__(0, clock[0] + seconds)
    try:
        link.connect()
        server.set_inputs(3000.0, temps, 4.25)
        record_cli.preflight(recorder, link)
        (final,) = recorder.run()
    finally:
        link.close()
    assert "deploy.opcua.inputs has no node for housing: recorded as missing" in " ".join(lines)
    frame = read_raw_log(final, [*nodes, "housing"])
    assert list(frame.columns) == ["time", "speed_rpm", "front", "rear", "motor", "housing", "disp_um"]
    read = as_read(temps)
    assert len(frame) == 3 and frame["speed_rpm"].tolist() == [3000.0] * 3 and frame["housing"].isna().all()
    for name, i in nodes.items():
        np.testing.assert_allclose(frame[name].to_numpy(), [read[i - 1]] * 3, atol=1e-6)
    assert frame["disp_um"].tolist() == [4.25] * 3 and is_recording(final)


def test_a_recording_of_the_mapped_machine_is_cleaned_by_the_real_snakefile(server, tmp_path):
    from opcua_server import as_read

    n = 130  # 32.5 min at the machine's 15 s: longer than runs.min_run_s (1800 s), or the check refuses it
    samples = twin_samples(n + 1)
    proj = mapped_project(tmp_path, server)
    args = args_for(proj / "config.yaml", MAPPED, duration=f"{15 * n}s", notes="twin at 2500 r/min")
    recorder, link = record_cli.build(args, log=lambda line: None, environ={})
    start = datetime.fromisoformat("2026-10-16T08:00:00+00:00").timestamp()
    clock = [1000.0]
    recorder.clock = recorder.files.clock = link.clock = lambda: clock[0]
    recorder.wall = lambda: start + clock[0] - 1000.0
    on_server = [0]

    def feed(k):
        sample = samples.iloc[k]
        server.set_inputs(sample["speed_rpm"], sample[list(SENSORS16)].to_numpy(float), sample["disp_um"])
        on_server[0] = k

    read_at: list[int] = []
    source_read = recorder.source.read

    def read(wall_s):
        read_at.append(on_server[0])
        return source_read(wall_s)

    recorder.source.read = read

    def sleep(seconds):
        clock[0] += seconds
        if seconds > 0:
            feed(min(on_server[0] + 1, n))

    recorder.sleep = sleep
    try:
        link.connect()
        record_cli.preflight(recorder, link)
        feed(0)
        (final,) = recorder.run()
    finally:
        link.close()
    assert final.parent == proj / "raw" / MAPPED and final.name == "rec_20261016T080000Z.csv"
    assert is_recording(final) and len(read_at) == n

    # the real Snakefile plans and runs the machine's clean step: the workbook by its mapping,
    # the recording as a native file
    done = run_snakemake(proj, "results/machining-center-b/clean", "-q", cores=1)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    clean = proj / "results" / MAPPED / "clean"
    log_text = (proj / "logs" / MAPPED / "clean.log").read_text(encoding="utf-8")
    assert "format native: a recording of rafi record" in log_text and "format xlsx" in log_text
    for stem in ("thermal_log_2026-10-14", final.stem):
        assert pd.read_csv(clean / f"{stem}.summary.csv")["status"].tolist() == ["ok"]

    # what the pipeline read is what the server held at each read, to the nodes' resolution
    table = pd.read_parquet(clean / f"{final.stem}.parquet")
    played = samples.iloc[read_at].reset_index(drop=True)
    assert len(table) == n
    times = pd.date_range("2026-10-16T08:00:00", periods=n, freq="15s")
    assert table["time"].tolist() == times.tolist()
    assert table["speed_rpm"].tolist() == played["speed_rpm"].tolist()
    np.testing.assert_array_equal(table["disp_um"].to_numpy(), played["disp_um"].to_numpy())
    want = np.array([as_read(t) for t in played[list(SENSORS16)].to_numpy(float)])
    got = table[list(SENSORS16)].to_numpy()
    np.testing.assert_allclose(got[:, :8], want[:, :8], atol=1e-9)  # Int16 in 0.1 degC
    np.testing.assert_array_equal(got[:, 8:].astype(np.float32), want[:, 8:].astype(np.float32))  # Float
