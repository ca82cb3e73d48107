"""Foreign machines (rafi.twin.foreign, ``rafi simulate foreign``): seeded, as varied as promised,
their outside fractions what the written logs say, and read by the real Snakefile."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pandas as pd
import pytest
import yaml
from project_copy import copy_project, run_snakemake

from rafi.contract.sensors import run_sensors
from rafi.readers.input_spec import normalise_input_spec
from rafi.twin.foreign import OUTSIDE_KINDS, foreign_design, foreign_machine, write_foreign

#: The seeds whose designs the range tests draw (a design draws no day: cheap).
DESIGN_SEEDS = range(60)


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> tuple[Path, dict]:
    """Seed 6 written as a project's data: an over-speed and a long-run test day among its four."""
    out = tmp_path_factory.mktemp("foreign")
    machine, _ = write_foreign(6, out)
    return out, machine.truth


def test_a_seed_gives_the_same_machine_and_another_seed_another():
    a, b, c = foreign_machine(3), foreign_machine(3), foreign_machine(4)
    assert a.truth == b.truth and a.config == b.config
    assert list(a.logs) == list(b.logs)
    for stem in a.logs:
        pd.testing.assert_frame_equal(a.logs[stem], b.logs[stem])
    assert a.truth["sensors"] != c.truth["sensors"]
    assert not a.logs[next(iter(a.logs))].equals(c.logs[next(iter(c.logs))])


def test_setup_drift_moves_only_the_displacement_of_the_same_machine():
    plain, drifting = foreign_machine(5), foreign_machine(5, setup_drift=True)
    assert plain.truth["setup_drift_um"] == 0 and 0.5 <= drifting.truth["setup_drift_um"] <= 3.0
    assert plain.truth["sensors"] == drifting.truth["sensors"] and plain.config == drifting.config
    moved = []
    for stem, frame in plain.logs.items():
        other = drifting.logs[stem]
        pd.testing.assert_frame_equal(frame.drop(columns="disp_um"), other.drop(columns="disp_um"))
        moved.append((frame["disp_um"] - other["disp_um"]).abs().max())
    assert min(moved) > 0.1


def test_designs_span_the_promised_ranges():
    designs = [foreign_design(s) for s in DESIGN_SEEDS]
    counts = [len(d.params.sensors) for d in designs]
    assert 4 <= min(counts) <= 8 and 36 <= max(counts) <= 40  # 4-40 sensors, both ends reached
    assert len(set(counts)) > 20
    assert {d.base for d in designs} == {"tapping-center-a", "machining-center-b"}
    kinds = {day.kind for d in designs for day in d.days if day.role == "test"}
    assert set(OUTSIDE_KINDS) <= kinds
    for d in designs:
        names = [s.name for s in d.params.sensors]
        assert len(set(names)) == len(names)
        normalise_input_spec({"sensors": names})  # names the project accepts
        roles = [day.role for day in d.days]
        assert roles == sorted(roles, key=lambda r: r != "training")  # training days first
        tests = [day for day in d.days if day.role == "test"]
        assert 3 <= len(tests) <= 4 and any(day.kind in OUTSIDE_KINDS for day in tests)
        assert 2 <= len(d.speeds) <= 4 and roles.count("training") >= len(d.speeds) + 1
        lags = [s.lag_s for s in d.params.sensors if s.position != "ambient"]
        assert min(lags) >= 20 and max(lags) <= 900


def _read(path: Path) -> pd.DataFrame:
    return pd.read_csv(path, comment="#")


def _independent_fractions(folder: Path, truth: dict) -> dict:
    """The outside fractions of every test day from the written files, by the definition in the
    module's docstring (0.1 K margin, 50 r/min, spindle turning from 100 r/min, rises from the
    median of the first 180 s), computed row by row."""
    stems = {d["stem"]: d["role"] for d in truth["days"]}
    frames = {stem: _read(folder / f"{stem}.csv") for stem in stems}
    sensors = [c for c in frames[next(iter(frames))].columns if c not in ("time", "speed_rpm", "disp_um")]

    def rises(f):
        return f[sensors] - f[sensors].iloc[:3].median()

    train = [f for stem, f in frames.items() if stems[stem] == "training"]
    t_all = pd.concat([f[sensors] for f in train])
    r_all = pd.concat([rises(f) for f in train])
    t_lo, t_hi = dict(t_all.min() - 0.1), dict(t_all.max() + 0.1)
    r_lo, r_hi = dict(r_all.min() - 0.1), dict(r_all.max() + 0.1)
    slow, fast = min(truth["training_speeds_rpm"]) - 50, max(truth["training_speeds_rpm"]) + 50
    out = {}
    for stem, f in frames.items():
        if stems[stem] != "test":
            continue
        counts = {"temperature": 0, "rise": 0, "speed": 0, "any": 0}
        for row, rise in zip(f.to_dict("records"), rises(f).to_dict("records")):
            t = any(not t_lo[s] <= row[s] <= t_hi[s] for s in sensors)
            q = any(not r_lo[s] <= rise[s] <= r_hi[s] for s in sensors)
            v = row["speed_rpm"] >= 100 and not slow <= row["speed_rpm"] <= fast
            for key, hit in (("temperature", t), ("rise", q), ("speed", v), ("any", t or q or v)):
                counts[key] += bool(hit)
        out[stem] = {key: n / len(f) for key, n in counts.items()}
    return out


def test_the_stated_outside_fractions_are_those_of_the_written_logs(written):
    out, truth = written
    mine = _independent_fractions(out / "raw" / truth["machine"], truth)
    assert set(mine) == {r["stem"] for r in truth["test_runs"]}
    for run in truth["test_runs"]:
        got = mine[run["stem"]]
        for key in ("temperature", "rise", "speed", "any"):
            assert run[f"outside_{key}"] == pytest.approx(got[key], abs=1e-12), (run["stem"], key)
    kinds = {r["kind"]: r for r in truth["test_runs"]}
    assert kinds["over_speed"]["outside_speed"] > 0.9  # above the training speeds but for the rest
    assert kinds["long_run"]["outside_any"] > 0.3  # warmer than any training day
    assert truth["test_runs"][0]["kind"] == "steps" and truth["test_runs"][0]["outside_speed"] == 0


def test_rafi_simulate_foreign_writes_a_project_and_prints_its_block(tmp_path):
    from rafi.cli import main

    assert main(["simulate", "foreign", "--seed", "2", "--out", str(tmp_path)]) == 0
    config = yaml.safe_load((tmp_path / "config.yaml").read_text())
    truth = json.loads((tmp_path / "truth.json").read_text())
    block = config["machines"]["foreign-2"]
    assert block == foreign_machine(2).config
    assert block["input"]["sensors"] == [s["name"] for s in truth["sensors"]]
    files = sorted(p.stem for p in (tmp_path / "raw" / "foreign-2").glob("*.csv"))
    assert files == [d["stem"] for d in truth["days"]]


@pytest.mark.slow
def test_the_pipeline_reads_a_foreign_machine_with_its_roles_and_sensors(tmp_path, written):
    out, truth = written
    proj = copy_project(tmp_path / "proj", config=False)
    shutil.copy2(out / "config.yaml", proj / "config.yaml")
    shutil.copytree(out / "raw", proj / "raw")
    machine = truth["machine"]
    done = run_snakemake(proj, f"results/{machine}/runs.csv", cores=2)
    assert done.returncode == 0, done.stderr[-3000:]
    runs = pd.read_csv(proj / "results" / machine / "runs.csv")
    day = {d["stem"]: d for d in truth["days"]}
    assert sorted(runs["file"].str.removesuffix(".csv")) == sorted(day)  # a run a day
    for file, role, speed in zip(runs["file"], runs["role"], runs["speed_rpm"]):
        d = day[file.removesuffix(".csv")]
        assert str(role).startswith("training" if d["role"] == "training" else "validation"), (file, role)
        if d["kind"] in ("constant", "over_speed", "long_run"):  # one speed all day: the run's
            assert speed == pytest.approx(d["speeds_rpm"][0], abs=5)
    frame = pd.read_parquet(proj / "results" / machine / "runs.parquet")
    assert list(run_sensors(frame)) == [s["name"] for s in truth["sensors"]]
