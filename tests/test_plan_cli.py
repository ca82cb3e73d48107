"""``rafi plan`` (issue 27): the programme of a re-qualification, from the machine's settings and prior."""

from __future__ import annotations

import shutil

import pytest
from report_fixture import FIXTURE, ROOT

from rafi.cli import main
from rafi.deploy.record_plan import read_plan
from rafi.ops.plan import plan_limits, plan_programme, prior_view
from rafi.settings import machine_settings, read_machine_config

MACHINE = "tapping-center-a"


@pytest.fixture
def project(tmp_path, monkeypatch):
    shutil.copy2(ROOT / "config.yaml", tmp_path / "config.yaml")
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_without_a_prior_the_plan_is_written_read_back_and_fits_the_budget(project, capsys):
    assert main(["plan", "--machine", MACHINE, "--hours", "4"]) == 0
    out = capsys.readouterr().out
    assert "no prior" in out and f"rafi record --machine {MACHINE} --plan plan_{MACHINE}.csv" in out
    plan = read_plan(project / f"plan_{MACHINE}.csv")
    assert plan.total_s <= 4 * 3600
    _, settings = read_machine_config(project / "config.yaml", MACHINE)
    limits = plan_limits(settings)
    heat = [s for s in plan.steps if s.speed_rpm > 0]
    # every heat-up is long enough to be a constant run at a training speed: it trains by itself
    assert heat and all(s.duration_s >= settings["runs"]["min_constant_s"] for s in heat)
    assert all(s.speed_rpm in settings["training_speeds_rpm"] for s in heat)
    assert limits["min_run_s"] == max(settings["runs"]["min_run_s"], settings["runs"]["min_constant_s"])
    assert {s.run for s in plan.steps} == {f"requal_{MACHINE}"}  # one recording: one log


def test_the_speed_range_in_use_limits_the_speeds(project):
    assert main(["plan", "--machine", MACHINE, "--hours", "4", "--speed-range", "5000", "13000"]) == 0
    heat = {s.speed_rpm for s in read_plan(project / f"plan_{MACHINE}.csv").steps if s.speed_rpm > 0}
    assert heat and heat <= {6000.0, 9000.0, 12000.0}


def test_the_champion_is_the_prior_the_header_names(project, capsys):
    registry = project / "results" / MACHINE / "registry"
    shutil.copytree(FIXTURE / "registry", registry)
    assert main(["plan", "--machine", MACHINE, "--hours", "3", "--out", "p.csv"]) == 0
    out = capsys.readouterr().out
    assert "prior 1479963c6588 (rafi" in out and "p.csv" in out
    assert read_plan(project / "p.csv").total_s <= 3 * 3600
    # the speeds the prior was trained at that 3 h leave untested, and the budget that tests them all
    left = next(line for line in out.splitlines() if line.startswith("  left to the prior alone: "))
    assert "check: prior_speeds}" in left and '{file: "1479963c6588",' in left
    hours = left.rsplit("--hours ", 1)[1].split()[0]
    assert main(["plan", "--machine", MACHINE, "--hours", hours, "--out", "all.csv"]) == 0
    assert "left to the prior alone" not in capsys.readouterr().out
    assert (
        main(["plan", "--machine", MACHINE, "--hours", f"{float(hours) - 0.01:g}", "--out", "less.csv"]) == 0
    )
    assert "left to the prior alone" in capsys.readouterr().out
    # a range in use that leaves some of the prior's speeds out: no programme inside it tests them
    assert main(["plan", "--machine", MACHINE, "--hours", "9", "--speed-range", "5000", "13000"]) == 0
    assert "no programme inside --speed-range tests them all" in capsys.readouterr().out
    # --prior none: the same programme without a prior
    assert main(["plan", "--machine", MACHINE, "--hours", "3", "--prior", "none", "--out", "q.csv"]) == 0
    out = capsys.readouterr().out
    assert "no prior" in out and "left to the prior alone" not in out


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--machine", "nope"], "'nope' is not under machines:"),
        (["--machine", MACHINE, "--hours", "0"], "--hours 0: expected the recorded machine time"),
        (["--machine", MACHINE, "--hours", "0.5"], "give at least"),
        (["--machine", MACHINE, "--prior", "champion"], "has no champion; qualify"),
    ],
)
def test_mistakes_are_one_line_and_exit_64(project, capsys, args, expected):
    assert main(["plan", *args]) == 64
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and expected in err
    assert not list(project.glob("plan_*.csv"))


def test_a_prior_of_an_undeclared_machine_is_refused_before_anything_is_recorded(project, capsys):
    """The night refuses a prior of a machine not declared in models.prior_siblings (PriorForeign);
    rafi plan refuses it up front with the same one line, not after the hours are recorded."""
    import json

    import yaml

    from rafi.errors import PriorForeign
    from rafi.family.prior import check_origin

    shutil.copytree(FIXTURE / "registry", project / "results" / MACHINE / "registry")
    registry = project / "results" / MACHINE / "registry"
    champion = json.loads((registry / "champion.json").read_text(encoding="utf-8"))["model_id"]
    prior = json.loads((registry / "models" / f"{champion}.json").read_text(encoding="utf-8"))
    other = "machining-center-b"
    with pytest.raises(PriorForeign) as night:  # the line the night's compare step prints
        check_origin(prior, other, ())
    assert main(["plan", "--machine", other, "--hours", "4", "--prior", MACHINE]) == 64
    err = capsys.readouterr().err.strip()
    assert err == f"rafi plan: {night.value}"
    assert f"models.prior_siblings: [{MACHINE}] in {other}'s settings" in err
    assert not list(project.glob("plan_*.csv"))
    # models.prior naming it in the config: refused the same way
    config = yaml.safe_load((project / "config.yaml").read_text(encoding="utf-8"))
    config["machines"][other]["models"] = {"prior": {"machine": MACHINE}}
    (project / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")
    assert main(["plan", "--machine", other, "--hours", "4"]) == 64
    assert capsys.readouterr().err.strip() == f"rafi plan: {night.value}"
    # declared a sibling: the programme is written
    config["machines"][other]["models"]["prior_siblings"] = [MACHINE]
    (project / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")
    assert main(["plan", "--machine", other, "--hours", "4"]) == 0
    assert f"prior {champion[:12]}" in capsys.readouterr().out
    assert (project / f"plan_{other}.csv").exists()


def test_the_prior_is_least_sure_outside_its_trained_speeds():
    settings = machine_settings({}, MACHINE)
    prior = {
        "kind": "dynamic",
        "model_id": "ab" * 32,
        "machine": "m",
        "speed_range_rpm": [3000.0, 9000.0],
        "selected": {"taus_s": [0, 600], "speed_taus_s": [1200]},
        "interval": {"half_width_um": {"settled": 1.0, "transient": 2.0, "outside": 5.0}},
    }
    view = prior_view(prior, tolerance_rpm=50)
    assert view["speed_range_rpm"] == (3000.0, 9000.0) and view["trained_speeds_rpm"] is None
    assert view["slowest_tau_s"] == 1200 and view["label"] == f"prior {'ab' * 6} (dynamic of m)"
    plan = plan_programme(
        speeds_rpm=[3000, 6000, 9000, 12000], budget_h=4, prior=view, **plan_limits(settings)
    )
    assert plan.attrs["speeds_rpm"][0] == 12000 and plan.attrs["untrained_rpm"] == [12000]
    assert (
        "never trained at (trained over 3000-9000 r/min); its interval there is the outside cell, +/-5"
        in (plan["reason"].iloc[1])
    )
    rafi_prior = prior_view({"speeds": [{"speed_rpm": 3000}, {"speed_rpm": 18000}]})
    assert rafi_prior["trained_speeds_rpm"] == [3000.0, 18000.0] and rafi_prior["speed_range_rpm"] == (
        3000,
        18000,
    )
    assert prior_view(None) is None and prior_view({"kind": "rafi"})["half_width_um"] == {}
    assert settings["runs"]["min_constant_s"] >= settings["runs"]["min_run_s"]


def test_the_speeds_a_re_qualified_prior_only_inherited_are_said_as_such():
    """A prior that is itself a re-qualification: of the speeds a programme leaves to it, those it
    had only from its own prior are named with that older prior."""
    from rafi.ops.plan_cli import speeds_left_text

    fitness = {"speeds_prior_only_rpm": [18000.0], "prior": {"model_id": "e" * 64, "machine": "mill-1"}}
    prior = {"model_id": "d" * 64, "machine": "mill-2", "adaptation": {"fitness": fitness}}
    line = speeds_left_text([12000.0, 18010.0], prior, 6.0, False, tolerance_rpm=50.0)
    assert line.startswith(
        "  left to the prior alone: 12000, 18010 r/min (trained by the prior, untested here; 18010 r/min "
        f"the prior had only from its own prior ({'e' * 12} of mill-1): no run at them since that model); "
    )
    plain = speeds_left_text([12000.0], prior, 6.0, False, tolerance_rpm=50.0)
    assert "(trained by the prior, untested here); the night's" in plain
