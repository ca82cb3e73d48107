"""`rafi record` (docs/record.md): the writer, the plan parser, the DAQ follower and the loop, then
end to end: the local SINUMERIK-like OPC UA server (tests/opcua_server.py) plays a twin log,
`rafi record` follows a plan and writes the raw file, `snakemake` qualifies it, and every
recorded value equals the played one to its node's resolution.

The loop runs with an injected clock and sleep: the "sleep" between two ticks puts the next
sample on the server (or stops / restarts it), so nothing here depends on timing.
"""

from __future__ import annotations

import argparse
import math
import os
import shutil
import signal
import stat
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from project_copy import ROOT, copy_project, run_snakemake

from rafi import SENSORS
from rafi.cli import main
from rafi.deploy import record_cli
from rafi.deploy.record import DaqFollower, Recorder
from rafi.deploy.record_files import (
    COLUMNS,
    RecordingFile,
    RecordingFiles,
    format_time,
    format_value,
    leftover_parts,
)
from rafi.deploy.record_plan import read_plan
from rafi.errors import RafiUserError, RawFormatError, SettingsError
from rafi.readers.input_spec import find_logs
from rafi.readers.native import read_raw_log

MACHINE = "tapping-center-a"
META = {"machine": MACHINE, "sample_period_s": "5", "notes": "cold start\ncoolant on"}


def env_with(first: Path) -> dict:
    """The environment with ``first`` at the front of PYTHONPATH (a project's frozen rafi)."""
    return {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(first), os.environ.get("PYTHONPATH")])),
    }


def row(t: str, speed="3000", temp="21.5", disp="1.25") -> list[str]:
    return [t, speed, *[temp] * 16, disp]


# --------------------------------------------------------------------------- values


def test_values_are_written_to_the_nodes_resolution():
    assert format_value(213, "Int16", 0.1) == "21.3"
    assert format_value(-5, "Int16", 0.1) == "-0.5"
    assert format_value(213, "Int16", 0.01, 273.15) == "275.28"
    assert format_value(float(np.float32(21.54)), "Float") == "21.54"
    assert float(np.float32(format_value(float(np.float32(1 / 3)), "Float"))) == float(np.float32(1 / 3))
    assert format_value(12.3456789012345, "Double") == "12.3456789012345"
    assert format_value(1e-7, "Double") == "0.0000001"  # never an exponent: the reader wants decimals
    assert format_value(-0.0, "Double") == "0" and format_value(0, "Int16", 0.1) == "0"
    assert format_value(0.012, "Double", 1000.0) == "12"  # a probe in mm, scale 1000
    assert format_value(math.nan, "Int16", 0.1) == "" and format_value(math.inf) == ""
    assert format_time(1772352005.0, 5) == "2026-03-01T08:00:05Z"
    assert format_time(1772352005.5, 0.5) == "2026-03-01T08:00:05.500Z"


# --------------------------------------------------------------------------- the writer


def test_a_file_is_written_under_a_hidden_name_and_renamed_read_only_when_closed(tmp_path):
    folder = tmp_path / "raw" / MACHINE
    f = RecordingFile(folder, "valid_08000rpm_20260301T080000Z", META)
    f.write_row(row("2026-03-01T08:00:00Z"))
    f.write_row(row("2026-03-01T08:00:05Z", temp="", disp=""))
    assert f.path.name == ".valid_08000rpm_20260301T080000Z.csv.part" and f.path.exists()
    assert find_logs(folder) == []  # the pipeline's discovery never sees a file being written
    assert leftover_parts(folder) == [f.path]
    final = f.close()
    assert final == folder / "valid_08000rpm_20260301T080000Z.csv" and not f.path.exists()
    assert find_logs(folder) == [final] and leftover_parts(folder) == []
    assert stat.S_IMODE(final.stat().st_mode) == 0o444
    frame = read_raw_log(final)  # the pipeline's reader, unchanged
    assert frame.attrs["metadata"] == {
        "machine": MACHINE,
        "sample_period_s": 5.0,
        "notes": "cold start\ncoolant on",
        "run_id": final.stem,
    }
    assert list(frame.columns) == list(COLUMNS) and len(frame) == 2
    assert frame["T7"].isna().tolist() == [False, True] and frame["disp_um"].isna().tolist() == [False, True]
    assert str(frame["time"].iloc[1]) == "2026-03-01 08:00:05"
    assert f.close() == final  # closing twice does nothing


def test_an_existing_file_is_never_overwritten(tmp_path):
    folder = tmp_path / MACHINE
    folder.mkdir()
    (folder / "rec_x.csv").write_text("someone else's file\n")
    first = RecordingFile(folder, "rec_x", META)
    assert first.stem == "rec_x_2"
    first.write_row(row("2026-03-01T08:00:00Z"))
    # the name was free when the file was opened, and is taken by the time it is closed
    (folder / "rec_x_2.csv").write_text("written meanwhile\n")
    final = first.close()
    assert final.name == "rec_x_2_2.csv"
    assert (folder / "rec_x.csv").read_text() == "someone else's file\n"
    assert (folder / "rec_x_2.csv").read_text() == "written meanwhile\n"
    assert len(read_raw_log(final)) == 1


def test_an_empty_recording_leaves_no_file(tmp_path):
    f = RecordingFile(tmp_path, "rec_x", META)
    assert f.close() is None and list(tmp_path.iterdir()) == []


def test_a_write_cut_by_ctrl_c_is_cut_back_to_the_last_whole_row(tmp_path, monkeypatch):
    f = RecordingFile(tmp_path, "rec_x", META)
    f.write_row(row("2026-03-01T08:00:00Z"))
    real_write = os.write

    def half_then_interrupt(fd, data):
        real_write(fd, bytes(data[: len(data) // 2]))
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "write", half_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        f.write_row(row("2026-03-01T08:00:05Z"))
    monkeypatch.setattr(os, "write", real_write)
    frame = read_raw_log(f.close())
    assert len(frame) == 1 and f.rows == 1


def test_files_roll_over_at_max_file_s_and_at_a_new_run(tmp_path):
    now = [0.0]
    lines = []
    files = RecordingFiles(tmp_path, META, max_file_s=10, log=lines.append, clock=lambda: now[0])
    files.switch("a")
    for k in range(4):  # 0, 5, 10, 15 s: the third row opens a second file
        files.write([row(f"2026-03-01T08:00:{5 * k:02d}Z")], 1772352000.0 + 5 * k)
        now[0] += 5
    files.switch(None)  # a step that is not recorded closes the file at once
    files.write([row("2026-03-01T08:01:00Z")], 1772352060.0)
    files.switch("b")
    files.write([row("2026-03-01T08:02:00Z")], 1772352120.0)
    files.close()
    names = [p.name for p in files.closed]
    assert names == ["a_20260301T080000Z.csv", "a_20260301T080010Z.csv", "b_20260301T080200Z.csv"]
    assert [len(read_raw_log(p)) for p in files.closed] == [2, 2, 1]
    assert sum("closed" in line for line in lines) == 3


# --------------------------------------------------------------------------- the plan


def write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


def test_the_plan_is_read_with_runs_and_not_recorded_steps(tmp_path):
    plan = read_plan(
        write(
            tmp_path / "p.csv",
            "# a comment\n\nspeed_rpm,duration_s,run,note\n0,180,a,rest\n3000,600,a,\n0,3600,,cool-down\n",
        )
    )
    assert [(s.speed_rpm, s.duration_s, s.run, s.line) for s in plan.steps] == [
        (0.0, 180.0, "a", 4),
        (3000.0, 600.0, "a", 5),
        (0.0, 3600.0, None, 6),
    ]
    assert plan.total_s == 4380 and plan.starts() == [0, 180, 780]
    assert [plan.step_at(t) for t in (0, 179.9, 180, 779, 780, 4379, 4380)] == [0, 0, 1, 1, 2, 2, None]
    single = read_plan(write(tmp_path / "q.csv", "duration_s,speed_rpm\n60,100\n"), default_run="mine")
    assert single.steps[0].run == "mine" and single.steps[0].speed_rpm == 100


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("speed_rpm,duration_s\n3000,4h\n", "line 2, column 'duration_s': '4h' is not a duration in seconds"),
        (
            "speed_rpm,duration_s\n-5,60\n",
            "line 2, column 'speed_rpm': '-5' is not a speed in r/min 0 or more",
        ),
        ("speed_rpm,duration_s\n3000,0\n", "line 2, column 'duration_s': '0' is not a duration"),
        ('speed_rpm,duration_s\n3000,"1,5"\n', "line 2, column 'duration_s': '1,5' .*decimal comma"),
        ("# x\nspeed_rpm,duraton_s\n3000,60\n", "line 2, column 'duraton_s': unknown column"),
        ("speed_rpm,run\n3000,a\n", "line 1: the header has no column 'duration_s'"),
        ("speed_rpm,duration_s\n3000,60,7\n", "line 2: found 3 fields, expected 2"),
        ("speed_rpm,duration_s,run\n3000,60,a/b\n", "line 2, column 'run': 'a/b' cannot start a file name"),
        ("speed_rpm,duration_s,run\n3000,60,\n", "no step is recorded"),
        ("# only comments\n", "no steps"),
        ("speed_rpm,duration_s\n3000,9e9\n", "more than 60: a unit mistake"),
    ],
)
def test_a_plan_mistake_is_one_line_naming_file_line_and_column(tmp_path, text, expected):
    path = write(tmp_path / "plan.csv", text)
    with pytest.raises(RafiUserError, match=expected) as info:
        read_plan(path)
    message = str(info.value)
    assert message.startswith(f"plan {path}") and "\n" not in message and info.value.exit_status == 64


def test_the_shipped_plan_is_the_papers():
    plan = read_plan(ROOT / "docs" / "examples" / "paper-test-plan.csv")
    runs: dict[str, list] = {}
    for step in plan.steps:
        if step.run:
            runs.setdefault(step.run, []).append((step.speed_rpm, step.duration_s))
    for speed in (3000, 6000, 9000, 12000, 15000, 18000):  # training: 4 h each, after 180 s at rest
        assert runs[f"train_{speed:05d}rpm"] == [(0, 180), (speed, 4 * 3600)]
    for speed in (4500, 8000, 10500, 13500, 16500):  # single-speed validation: 2 to 4 h
        (rest, (got, seconds)) = runs[f"valid_{speed:05d}rpm"]
        assert rest == (0, 180) and got == speed and 2 * 3600 <= seconds <= 4 * 3600
    multi = runs["multi_condition"]
    assert multi[0] == (0, 180) and sum(d for _, d in multi[1:]) == 4.5 * 3600  # paper: 4.5 h
    assert {s for s, _ in multi[1:]} & {4500, 10500, 13500} and len(runs) == 12
    between = [s for s in plan.steps if s.run is None]
    assert len(between) == 11 and all(s.speed_rpm == 0 for s in between)  # cool-downs, not recorded


# --------------------------------------------------------------------------- the DAQ follower


def test_the_daq_file_is_followed_line_by_line(tmp_path):
    daq = tmp_path / "daq.csv"
    lines = []
    follower = DaqFollower(daq, from_start=True, log=lines.append)
    assert follower.read() == [] and "waiting for" in lines[0]
    header = "# DAQ 7\ntime,speed_rpm," + ",".join(SENSORS) + ",disp_um,extra\n"
    values = ",".join(["21.5"] * 16)
    daq.write_text(header + f"2026-03-01T08:00:00,3000,{values},1.5,x\n2026-03-01T08:00:05,30")
    got = follower.read()
    assert got == [["2026-03-01T08:00:00", "3000", *["21.5"] * 16, "1.5"]]  # the cut line waits
    with open(daq, "a") as fh:
        fh.write(f"00,{values},ERR,x\n2026-03-01T08:00:05,3000,{values},2,x\n")
        fh.write(f"2026-03-01T08:00:10,nan,{values},2.5,x\n")
    got = follower.read()
    assert [r[1] for r in got] == ["3000", ""] and got[0][-1] == ""  # ERR and nan: missing
    assert follower.skipped == 1 and "not later" in lines[-1]  # 08:00:05 twice
    bad = tmp_path / "bad.csv"
    bad.write_text("zeit,drehzahl\n1,2\n")
    with pytest.raises(RawFormatError, match="no column 'time'") as info:
        DaqFollower(bad, from_start=True).read()
    assert info.value.exit_status == 65


# --------------------------------------------------------------------------- the loop, with fakes


class FakeLink:
    def __init__(self):
        self.connected = True
        self.reconnects = 0

    def try_reconnect(self):
        self.connected = self.up
        self.reconnects += self.up
        return self.up


class FakeSource:
    """One row per tick; ConnectionError while ``down``."""

    def __init__(self, link):
        self.link, self.period_s = link, 5.0

    def read(self, wall_s):
        if not self.link.up:
            self.link.connected = False
            raise ConnectionError("server down")
        missing = "" if int(wall_s) % 20 == 0 else "1.5"
        return [row(format_time(wall_s), disp=missing)]


def fake_recorder(tmp_path, *, plan=None, down=(), late=(), stop_at=None, duration_s=None):
    clock = [100.0]
    link = FakeLink()
    link.up = True
    source = FakeSource(link)
    lines, commands = [], []
    files = RecordingFiles(tmp_path, META, log=lines.append, clock=lambda: clock[0])
    tick = [0]

    def sleep(seconds):
        clock[0] += seconds
        tick[0] += 1
        link.up = tick[0] not in down
        if tick[0] in late:
            clock[0] += 12.0  # the next tick comes more than two periods late
        if tick[0] == stop_at:
            raise KeyboardInterrupt

    recorder = Recorder(
        source, files, period_s=5, plan=plan, command=commands.append if plan else None, link=link,
        duration_s=duration_s, clock=lambda: clock[0], wall=lambda: 1772352000.0, sleep=sleep,
        log=lines.append,
    )  # fmt: skip
    return recorder, lines, commands


def test_a_lost_connection_is_a_gap_and_a_missing_value_an_empty_field(tmp_path):
    recorder, lines, _ = fake_recorder(tmp_path, down=range(10, 14), late=(20,), duration_s=150)
    (final,) = recorder.run()
    frame = read_raw_log(final)
    seconds = ((frame["time"] - frame["time"].iloc[0]).dt.total_seconds() / 5).astype(int).tolist()
    # ticks 10-13 down (4 samples); the sleep before tick 20 ended 12 s late: ticks 20, 21 skipped
    assert seconds == [k for k in range(30) if k not in (10, 11, 12, 13, 20, 21)]
    assert recorder.gaps == 2 and recorder.lost_samples == 6 and recorder.skipped_ticks == 2
    assert frame["disp_um"].isna().sum() == recorder.missing == 6  # every 20 s
    gap_lines = [line for line in lines if "gap from" in line or "a gap of" in line]
    assert len(gap_lines) == 4, gap_lines  # one when a gap starts, one when it is over
    assert "gap from 2026-03-01T08:00:50Z: server down; no rows until it is over" in gap_lines[0]
    assert "a gap of 4 samples (20 s)" in gap_lines[1]
    assert "2 samples late" in gap_lines[2]
    progress = [line for line in lines if "(being written)" in line]
    assert len(progress) == 3  # 0, 60 and 120 s of 150


def test_a_plan_commands_each_step_again_after_a_reconnect_and_0_at_the_end(tmp_path):
    plan = read_plan(
        write(tmp_path / "p.csv", "speed_rpm,duration_s,run\n0,20,a\n3000,30,a\n0,20,\n6000,30,b\n")
    )
    recorder, lines, commands = fake_recorder(tmp_path / "raw", plan=plan, down=(6,))
    files = recorder.run()
    assert commands == [0, 3000, 3000, 0, 6000, 0]  # 3000 again after the reconnect; 0 at the end
    assert [p.name for p in files] == ["a_20260301T080000Z.csv", "b_20260301T080110Z.csv"]
    assert [len(read_raw_log(p)) for p in files] == [9, 6]  # 10 ticks less the one lost; 6 ticks
    assert recorder.ticks == 20 and any("(not recorded)" in line for line in lines)


def test_ctrl_c_closes_and_renames_the_file(tmp_path):
    recorder, lines, _ = fake_recorder(tmp_path, stop_at=7)
    with pytest.raises(KeyboardInterrupt):
        recorder.run()
    (final,) = recorder.files.closed
    assert len(read_raw_log(final)) == 7 and leftover_parts(tmp_path) == []


# --------------------------------------------------------------------------- settings and the command


def config(tmp_path: Path, *, record=None, opcua=None, machine=MACHINE, period=5) -> Path:
    block = {"sample_period_s": period, "record": record or {}}
    if opcua is not None:
        block["deploy"] = {"opcua": opcua}
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump({"machines": {machine: block}}))
    return path


def args_for(path: Path, **kw) -> argparse.Namespace:
    base = dict(
        machine=MACHINE, config=str(path), follow=None, from_start=False, plan=None, notes="", name="rec",
        duration=None, debug=False,
    )  # fmt: skip
    return argparse.Namespace(**{**base, **kw})


@pytest.mark.parametrize(
    ("kw", "record", "expected"),
    [
        ({"machine": "nosuch"}, {}, "--machine 'nosuch' is not under machines: in .*known: tapping-center-a"),
        ({"name": "a b"}, {}, "--name 'a b': use letters"),
        ({"duration": "4 weeks"}, {}, "--duration '4 weeks': expected a time above 0"),
        ({"plan": "p.csv"}, {}, "--plan needs record.speed_command"),
        ({}, {}, "record.displacement is not set"),
        ({"follow": "daq.csv", "duration": "1h", "plan": "p.csv"}, {}, "--duration and --plan"),
        (
            {"plan": "short.csv"},
            {"speed_command": "x"},
            "plan short.csv, line 3, column 'duration_s': 2 s is shorter than the sample period 5 s",
        ),
    ],
)
def test_settings_mistakes_are_one_line_and_exit_64(tmp_path, monkeypatch, capsys, kw, record, expected):

    monkeypatch.chdir(tmp_path)
    write(tmp_path / "p.csv", "speed_rpm,duration_s\n3000,60\n")
    write(tmp_path / "short.csv", "speed_rpm,duration_s\n3000,60\n0,2\n")
    path = config(tmp_path, record=record, opcua={"endpoint": "opc.tcp://127.0.0.1:1", "inputs": inputs()})
    with pytest.raises(SettingsError, match=expected):
        record_cli.build(args_for(path, **kw))
    argv = ["record", "--config", str(path), "--machine", kw.get("machine", MACHINE)]
    for key in ("name", "duration", "plan", "follow"):
        if key in kw:
            argv += [f"--{key}", kw[key]]
    assert main(argv) == 64
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("rafi record: ")
    assert not (tmp_path / "raw").exists()  # nothing created


def test_an_unreachable_server_at_start_exits_69(tmp_path, capsys):
    from opcua_server import DISP_NODE, free_port

    opcua = {
        "endpoint": f"opc.tcp://127.0.0.1:{free_port()}",
        "inputs": inputs(),
        "timeout_s": 2,
        "allow_insecure": True,
    }
    path = config(tmp_path, record={"displacement": DISP_NODE}, opcua=opcua)
    assert record_cli.run(args_for(path)) == 69
    assert "cannot connect" in capsys.readouterr().err and not (tmp_path / "raw" / MACHINE).exists()


def test_sigterm_closes_the_file_with_one_line_and_exit_0(tmp_path):
    """A real process and a real signal: `rafi record --follow` of a DAQ file at 1 s."""
    path = config(tmp_path, period=1)
    daq = tmp_path / "daq.csv"
    daq.write_text("time,speed_rpm,disp_um\n2026-03-01T08:00:00,0,0.5\n2026-03-01T08:00:01,0,0.6\n")
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])),
    }
    cmd = [sys.executable, "-m", "rafi.cli", "record", "--machine", MACHINE, "--config", str(path)]
    proc = subprocess.Popen(
        [*cmd, "--follow", str(daq), "--from-start", "--notes", "signal test"],
        cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    folder = tmp_path / "raw" / MACHINE
    deadline = time.monotonic() + 60
    while not leftover_parts(folder) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)  # waits for the recording to start; no assertion on how long it took
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert err == "" and "Traceback" not in out
    (final,) = find_logs(folder)
    frame = read_raw_log(final)
    assert frame["disp_um"].tolist() == [0.5, 0.6] and frame["T1"].isna().all()
    assert frame.attrs["metadata"]["notes"] == "signal test"
    assert out.strip().splitlines()[-1].startswith("rafi record: stopped; 2 rows, 0 gaps")


# --------------------------------------------------------------------------- end to end


def twin_log() -> pd.DataFrame:
    """A 43 min single-speed validation run of the twin (180 s at rest, 40 min at 8000 r/min),
    with sensor faults the PLC flags as BadSensorFailure."""
    from rafi.twin.schedules import constant_schedule, with_rest
    from rafi.twin.simulate import simulate_run

    log = simulate_run(
        with_rest(constant_schedule(8000, 2400)), seed=11, start="2026-03-11T09:00:00", defects=False
    ).log
    log.loc[100:102, "T3"] = np.nan  # an Int16 node
    log.loc[150, "T12"] = np.nan  # a Float node
    log.loc[300, "disp_um"] = np.nan  # the Double probe
    return log


@pytest.fixture(scope="module")
def server():
    pytest.importorskip("asyncua")
    from opcua_server import SinumerikLikeServer

    with SinumerikLikeServer(axis=3) as srv:
        yield srv


ENV = {"RAFI_OPCUA_USER": "seawriter", "RAFI_OPCUA_PASSWORD": "s3cret-Pw"}
DOWN = range(200, 204)  # ticks with the server stopped


def project(tmp_path: Path, server) -> Path:
    from opcua_server import DISP_NODE, SPEED_COMMAND_NODE, free_port

    proj = copy_project(tmp_path / "proj")
    cfg = yaml.safe_load((proj / "config.yaml").read_text(encoding="utf-8"))
    machine = cfg["machines"][MACHINE]
    machine["deploy"] = {
        "opcua": {
            "endpoint": server.endpoint, "inputs": inputs(), "timeout_s": 3, "allow_insecure": True,
            "reconnect_min_s": 1, "reconnect_max_s": 2,
        }
    }  # fmt: skip
    machine["record"] = {
        "displacement": DISP_NODE, "speed_command": SPEED_COMMAND_NODE, "metrics_port": free_port(),
    }  # fmt: skip
    cfg["machines"] = {MACHINE: machine}
    (proj / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    raw = proj / "raw" / MACHINE
    raw.mkdir(parents=True)
    for name in ("train_03000rpm.csv", "train_09000rpm.csv", "train_15000rpm.csv"):
        shutil.copy2(ROOT / "raw" / MACHINE / name, raw / name)
    write(proj / "plan.csv", "speed_rpm,duration_s,run\n0,180,valid_08000rpm\n8000,2400,valid_08000rpm\n")
    return proj


def inputs() -> dict:
    from opcua_server import input_settings  # asyncua: only the OPC UA tests need it

    return input_settings()


def as_read(temps) -> np.ndarray:
    from opcua_server import as_read

    return as_read(temps)


def scrape(recorder) -> dict:
    """``/metrics`` of a recorder by HTTP GET: ``{(name, labels): value}``."""
    import urllib.request

    from prometheus_client.parser import text_string_to_metric_families

    url = f"http://127.0.0.1:{recorder.metrics.port}/metrics"
    text = urllib.request.urlopen(url, timeout=10).read().decode()
    return {
        (sample.name, tuple(sorted(sample.labels.items()))): sample.value
        for family in text_string_to_metric_families(text)
        for sample in family.samples
    }


@pytest.mark.slow
def test_record_a_twin_log_from_opc_ua_and_qualify_it_with_snakemake(server, tmp_path):
    from opcua_server import SPEED_COMMAND_NODE

    log = twin_log()
    proj = project(tmp_path, server)
    args = args_for(proj / "config.yaml", plan=str(proj / "plan.csv"), notes="twin, seed 11")
    lines: list[str] = []
    recorder, link = record_cli.build(args, log=lines.append, environ=ENV)
    start = datetime.fromisoformat("2026-03-11T09:00:00+00:00").timestamp()
    clock = [1000.0]
    recorder.clock = recorder.files.clock = link.clock = lambda: clock[0]
    recorder.wall = lambda: start + clock[0] - 1000.0
    played, tick, scraped = [], [0], {}
    raw = proj / "raw" / MACHINE
    seen_while_recording = []

    def feed(k):
        sample = log.iloc[k]
        server.set_inputs(sample["speed_rpm"], sample[list(SENSORS)].to_numpy(float), sample["disp_um"])
        played.append(k)

    def sleep(seconds):
        clock[0] += seconds
        tick[0] += 1
        k = tick[0]
        if k == DOWN.start:
            server.stop()
        elif k == DOWN.stop:
            server.start()
        if k == 100:
            seen_while_recording.extend(p.name for p in find_logs(raw))
            scraped.update(rows=recorder.files.rows, missing=recorder.missing, metrics=scrape(recorder))
        if k == DOWN.stop + 1:
            scraped.update(after_outage=scrape(recorder))
        if k not in DOWN and k < len(log):
            feed(k)

    recorder.sleep = sleep
    writes_before = len(server.client_writes())
    try:
        link.connect()
        record_cli.preflight(recorder, link)
        feed(0)
        (final,) = recorder.run()
    finally:
        link.close()

    # the pipeline never saw the file while it was written
    assert "valid_08000rpm" not in " ".join(seen_while_recording) and len(seen_while_recording) == 3
    assert final.name == "valid_08000rpm_20260311T090000Z.csv" and leftover_parts(raw) == []
    # the plan: 0, then 8000 r/min, again after the reconnect, then 0 at the end; Double, by the user
    commands = [w for w in server.client_writes()[writes_before:] if w.node == SPEED_COMMAND_NODE]
    assert [w.value for w in commands] == [0.0, 8000.0, 8000.0, 0.0]
    assert {(w.variant_type, w.user) for w in commands} == {("Double", "seawriter")}
    assert sum("gap from" in line or "a gap of" in line for line in lines) == 2 and recorder.gaps == 1
    assert sum("WARNING allow_insecure: the password of user 'seawriter'" in line for line in lines) == 1

    # the metrics, read by HTTP while recording: rows and missing values so far, the file, the gap
    machine = (("machine", MACHINE),)
    metrics = scraped["metrics"]
    assert metrics[("rafi_record_rows_total", machine)] == scraped["rows"] > 90
    assert metrics[("rafi_record_missing_values_total", machine)] == scraped["missing"]
    assert metrics[("rafi_record_connected", machine)] == 1
    (path,) = [dict(k[1])["path"] for k in metrics if k[0] == "rafi_record_file_info"]
    assert Path(path).name.startswith(".valid_08000rpm") and path.endswith(".part")
    after = scraped["after_outage"]
    assert (
        after[("rafi_record_gaps_total", machine)] == 1
        and after[("rafi_record_reconnects_total", machine)] == 1
    )

    # every recorded value is the played one, to its node's resolution
    rec = read_raw_log(final)
    assert rec.attrs["metadata"]["notes"] == "twin, seed 11"
    assert rec.attrs["metadata"]["sample_period_s"] == 5.0 and rec.attrs["metadata"]["machine"] == MACHINE
    expected = log.iloc[played].reset_index(drop=True)
    assert len(rec) == len(log) - len(DOWN) == len(expected)
    ticks = ((rec["time"] - pd.Timestamp("2026-03-11T09:00:00")).dt.total_seconds() / 5).astype(int)
    assert ticks.tolist() == played  # a gap of exactly the samples the server was down
    assert rec["speed_rpm"].tolist() == expected["speed_rpm"].tolist()  # Double
    np.testing.assert_array_equal(rec["disp_um"].to_numpy(), expected["disp_um"].to_numpy())  # Double
    got = rec[list(SENSORS)].to_numpy()
    want = np.array([as_read(t) for t in expected[list(SENSORS)].to_numpy(float)])
    np.testing.assert_allclose(got[:, :8], want[:, :8], atol=1e-9)  # Int16, 0.1 degC
    np.testing.assert_array_equal(got[:, 8:].astype(np.float32), want[:, 8:].astype(np.float32))  # Float
    assert np.isnan(got).sum() == 4 and rec["disp_um"].isna().sum() == 1  # bad status: missing

    # snakemake qualifies it: checked, cleaned, split into a validation run and scored
    done = run_snakemake(proj, "tables", "-q", cores=2)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    results = proj / "results" / MACHINE
    audit = pd.read_csv(results / "audit.csv").set_index("file")
    assert audit.loc[final.name, "status"] == "ok"
    summary = pd.read_csv(results / "validation" / "summary.csv").set_index("run_id")
    scored = summary.loc[final.stem]
    assert scored["role"].startswith("validation") and scored["n_samples"] > 480
    assert math.isfinite(scored["max_abs_after_um"])
    assert stat.S_IMODE(final.stat().st_mode) == 0o444  # the pipeline read it, nothing changed it


def test_a_node_the_server_lacks_is_refused_before_recording(server, tmp_path, capsys):
    from opcua_server import DISP_NODE

    opcua = {
        "endpoint": server.endpoint,
        "inputs": {**inputs(), "T8": "/Plc/DB100.DBW99"},
        "timeout_s": 3,
        "allow_insecure": True,
    }
    path = config(tmp_path, record={"displacement": DISP_NODE}, opcua=opcua)
    assert main(["record", "--machine", MACHINE, "--config", str(path)]) == 64
    err = capsys.readouterr().err
    assert err == (
        "rafi record: deploy.opcua.inputs.T8: the server has no node ns=2;s=/Plc/DB100.DBW99 "
        "(BadNodeIdUnknown); check the node id (docs/record.md)\n"
    )
    assert not (tmp_path / "raw").exists()


def test_a_refused_speed_command_stops_with_64_and_no_half_file(server, tmp_path, monkeypatch, capsys):
    from opcua_server import DISP_NODE, SPEED_COMMAND_NODE, temp_node

    for name in ("RAFI_OPCUA_USER", "RAFI_OPCUA_PASSWORD", "RAFI_OPCUA_CREDENTIALS"):
        monkeypatch.delenv(name, raising=False)
    opcua = {"endpoint": server.endpoint, "inputs": inputs(), "timeout_s": 3, "allow_insecure": True}
    plan = str(write(tmp_path / "plan.csv", "speed_rpm,duration_s\n3000,60\n"))
    raw = tmp_path / "raw" / MACHINE
    before = len(server.client_writes())
    # an Int16 node is refused as the speed command before anything is read or written
    record = {"displacement": DISP_NODE, "speed_command": temp_node(1)[0]}
    path = str(config(tmp_path, record=record, opcua=opcua))
    assert main(["record", "--machine", MACHINE, "--config", path, "--plan", plan]) == 64
    assert "record.speed_command: node ns=2;s=/Plc/DB100.DBW0 is of type Int16" in capsys.readouterr().err
    # an anonymous session may read but not write: the first step's write is refused
    record["speed_command"] = SPEED_COMMAND_NODE
    path = str(config(tmp_path, record=record, opcua=opcua))
    assert main(["record", "--machine", MACHINE, "--config", path, "--plan", plan]) == 64
    err = capsys.readouterr().err
    assert "refused for an anonymous session: BadUserAccessDenied" in err and err.count("\n") == 1
    assert len(server.client_writes()) == before
    assert leftover_parts(raw) == [] and find_logs(raw) == []  # no sample was recorded: no file
