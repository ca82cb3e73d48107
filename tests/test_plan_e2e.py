"""The plan's own path end to end (issue 47): ``rafi plan`` -> ``rafi simulate day --plan`` -> the
real Snakefile's clean and runs steps. The pipeline must cut the recording as the plan meant: the
rest before start is the first heat-up's (under ``runs.max_leading_rest_s`` of the resolved
settings), no step becomes an excluded run, each heat-up is a training run at its speed and the
first is referenced at rest."""

from __future__ import annotations

import pandas as pd
import pytest
import yaml
from project_copy import copy_project, run_rafi, run_snakemake

from rafi.deploy.record_plan import read_plan
from rafi.settings import read_machine_config

MACHINE = "tapping-center-a"


@pytest.mark.slow
def test_a_plan_followed_by_the_twin_is_cut_into_the_runs_the_plan_meant(tmp_path):
    proj = copy_project(tmp_path / "proj")
    cfg = yaml.safe_load((proj / "config.yaml").read_text(encoding="utf-8"))
    cfg["machines"] = {MACHINE: cfg["machines"][MACHINE]}
    (proj / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    _, settings = read_machine_config(proj / "config.yaml", MACHINE)

    plan = run_rafi(proj, "plan", "--machine", MACHINE, "--hours", "4", "--out", "p.csv")
    assert plan.returncode == 0, plan.stderr
    steps = read_plan(proj / "p.csv").steps
    assert steps[0].speed_rpm == 0 and steps[0].duration_s < settings["runs"]["max_leading_rest_s"]
    sim = run_rafi(
        proj, "simulate", "day", "--machine", MACHINE, "--plan", "p.csv", "--seed", "3", "--no-defects",
        "--out", "raw",
    )  # fmt: skip
    assert sim.returncode == 0, sim.stderr
    (log,) = sorted((proj / "raw" / MACHINE).glob("*.csv"))

    done = run_snakemake(proj, f"results/{MACHINE}/runs.csv", cores=2)
    assert done.returncode == 0, done.stderr[-3000:]
    runs = pd.read_csv(proj / "results" / MACHINE / "runs.csv")
    runs = runs[runs["file"] == log.name].sort_values("start_s").reset_index(drop=True)
    # one run per step, the rest inside the first heat-up; nothing excluded
    assert len(runs) == len(steps) - 1, runs[["run_id", "kind", "role", "duration_s", "note"]]
    assert "excluded" not in set(runs["role"])
    meant = steps[1:]
    for (_, run), step in zip(runs.iterrows(), meant):
        if step.speed_rpm > 0:
            assert run["kind"] == "constant" and run["role"] == "training"
            assert run["speed_rpm"] == pytest.approx(step.speed_rpm, abs=settings["speed_tolerance_rpm"])
        else:
            assert run["kind"] == "idle"
    first, period = runs.iloc[0], 5.0
    assert first["start_s"] == 0 and "rest" in str(first["note"])
    assert first["duration_s"] == pytest.approx(steps[0].duration_s + steps[1].duration_s, abs=2 * period)
    # the reference rows: the first heat-up's reference window lies on the machine at rest
    frame = pd.read_parquet(proj / "results" / MACHINE / "runs.parquet")
    head = frame[frame["run_id"] == first["run_id"]].sort_values("t_s")
    window = head[head["t_s"] < settings["reference"]["window_s"]]
    assert len(window) and (window["speed_rpm"] == 0).all()
    assert window["dz_um"].abs().max() < 0.5 and window["dT6"].abs().max() < 0.2
    at_speed = head[head["t_s"] >= steps[0].duration_s + 60]
    assert (at_speed["speed_rpm"] > 0).all() and at_speed["dz_um"].iloc[-1] > 5  # it grew from the rest
