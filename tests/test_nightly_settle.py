"""`rafi nightly` and files still being written: it passes ``settle_s`` (run setting
``nightly_settle_s``, default 600 s) to Snakemake, names the files that wait for the next
night, and does not let the next night take the fast path past them."""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rafi.ops import nightly as N
from rafi.ops import snakemake_api
from rafi.ops.project import Paths, settling
from rafi.ops.state import STATE_NAME

DAY = 86_400

pytest.importorskip("rafi.readers.discovery")  # settling_files (the readers' side of settle_s)


def rafi_cmd(*args):
    return [sys.executable, "-m", "rafi.cli", *args]


def project(tmp_path: Path, config: str = "") -> Path:
    d = tmp_path / "proj"
    (d / "raw" / "m1").mkdir(parents=True)
    old = d / "raw" / "m1" / "x.csv"
    old.write_text("time\n")
    os.utime(old, (time.time() - DAY, time.time() - DAY))
    (d / "config.yaml").write_text("raw_dir: raw\nresults_dir: results\nreports_dir: reports\n" + config)
    (d / "done.txt").write_text("ok\n")
    (d / "Snakefile").write_text("rule nightly:\n    input: 'done.txt'\n")
    return d


def test_settle_s_comes_from_nightly_settle_s():
    ns = argparse.Namespace(machine=None, no_report=False)
    assert N.config_overrides(ns)["settle_s"] == 600
    assert N.config_overrides(ns, {"nightly_settle_s": 30})["settle_s"] == 30
    assert N.config_overrides(ns, {"nightly_settle_s": 0, "settle_s": 99})["settle_s"] == 0


def test_settling_lists_young_files_of_the_nights_machines(tmp_path):
    proj = project(tmp_path)
    young = proj / "raw" / "m1" / "y.csv"
    young.write_text("time\n")
    (proj / "raw" / "m2").mkdir()
    (proj / "raw" / "m2" / "z.csv").write_text("time\n")
    paths = Paths.from_config(proj, {})
    now = time.time()
    got = settling(paths, {}, ["m1"], 600, now)
    assert [p for p, _ in got] == [Path("raw/m1/y.csv")] and 0 <= got[0][1] < 600
    assert settling(paths, {}, ["m1"], 0, now) == []
    assert [p.name for p, _ in settling(paths, {}, ["m1", "m2"], 600, now)] == ["y.csv", "z.csv"]


@pytest.mark.slow
def test_a_night_names_the_files_that_wait_and_the_next_one_asks_snakemake(tmp_path):
    proj = project(tmp_path)
    (proj / "raw" / "m1" / "y.csv").write_text("time\n")
    res = subprocess.run(rafi_cmd("nightly", "--directory", str(proj)), capture_output=True, text=True)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "settle_s=600" in res.stdout
    assert "waits for the next night" in res.stdout and "raw/m1/y.csv" in res.stdout
    assert "x.csv" not in res.stdout
    # the machine's status line says its files were not judged (not only the old decision)
    (line,) = [ln for ln in res.stdout.splitlines() if ln.startswith("rafi nightly: m1: ")]
    assert line.endswith(
        "; 1 new raw file(s) not judged tonight: they wait for the next night (nightly_settle_s)"
    )
    # no fast path past a file that waited
    assert not (proj / "results" / STATE_NAME).exists()
    os.utime(proj / "raw" / "m1" / "y.csv", (time.time() - DAY, time.time() - DAY))
    res = subprocess.run(rafi_cmd("nightly", "--directory", str(proj)), capture_output=True, text=True)
    assert res.returncode == 0 and "waits for the next night" not in res.stdout
    assert "not judged tonight" not in res.stdout
    assert (proj / "results" / STATE_NAME).exists()


def test_nightly_settle_s_0_waits_for_nothing(tmp_path, monkeypatch, capsys):
    proj = project(tmp_path, "nightly_settle_s: 0\n")
    (proj / "raw" / "m1" / "y.csv").write_text("time\n")
    seen = {}

    def fake_run(directory, config_file, overrides, **kw):
        seen.update(overrides)
        return snakemake_api.Outcome()

    monkeypatch.setattr(snakemake_api, "run", fake_run)
    parser = argparse.ArgumentParser()
    N.add_arguments(parser)
    assert N.run(parser.parse_args(["--directory", str(proj)])) == 0
    assert seen["settle_s"] == 0 and seen["on_bad_input"] == "quarantine"
    assert "waits for the next night" not in capsys.readouterr().out
