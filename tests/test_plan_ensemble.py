"""``rafi plan`` from a CV-weighted ensemble prior (issue 47, item 3): the plan reads the whole
ensemble (its members' trained speeds and ranges, its own interval), not only its heaviest member.

Oracles: the ensemble is built by the code (``run_family`` with ``models: offer: ensemble`` on the
golden synthetic runs of tests/test_crossval.py); its trained speeds are the training runs' speeds
of those data, its interval and its members' weights and time constants are read here from the
artefact by hand; the plan from its heaviest member alone is the contrast.
"""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path

import pandas as pd
import pytest
import yaml
from report_fixture import ROOT

from rafi.cli import main
from rafi.deploy.record_plan import read_plan
from rafi.family.compare import run_family
from rafi.ops.plan import plan_programme, prior_view
from rafi.ops.registry import Registry, registry_dir
from rafi.settings import MACHINE_DEFAULTS

DATA = Path(__file__).parent / "data"
MACHINE = "tapping-center-a"
GATES = {"max_residual_um": 12.0, "min_improvement_pct": 30.0, "never_worse_than_uncompensated": True}
#: The machine's training speeds of the plans below: 4500 lies inside the ensemble's speed range
#: but at no speed its members trained at.
SPEEDS = [3000.0, 4500.0, 9000.0, 18000.0]
TOLERANCE = 50.0


@pytest.fixture(scope="module")
def ensemble():
    table = pd.read_csv(DATA / "golden_comparison_runs.csv")
    frame = pd.read_csv(DATA / "golden_comparison_frame.csv")
    options = {**MACHINE_DEFAULTS["models"], "enabled": ["rafi_linear", "ridge_global", "dynamic"]}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = run_family(
            table,
            frame,
            key_sensors=["T1", "T2", "T3"],
            terms=MACHINE_DEFAULTS["fit"]["terms"],
            reference=MACHINE_DEFAULTS["reference"],
            machine=MACHINE,
            gates=GATES,
            options={**options, "offer": "ensemble"},
            log=lambda m: None,
        )
    art = res["best_artefact"]
    assert art["kind"] == "ensemble" and art.get("interval")
    trained = sorted(float(s) for s in table.loc[table["role"] == "training", "speed_rpm"])
    return art, trained


def _heaviest(art: dict) -> tuple[str, dict]:
    weights = art["weights"]
    name = None
    for n, w in weights.items():  # the first of equals
        if name is None or w > weights[name]:
            name = n
    return name, art["members"][name]


def _taus(member: dict) -> list[float]:
    sel = member.get("selected") or {}
    taus = [*sel.get("taus_s", []), *sel.get("speed_taus_s", [])]
    if sel.get("centrifugal_lag_s") is not None:
        taus.append(sel["centrifugal_lag_s"])
    return [float(t) for t in taus if float(t) > 0]


def test_the_view_reads_the_whole_ensemble(ensemble):
    art, trained = ensemble
    name, member = _heaviest(art)
    view = prior_view(art, tolerance_rpm=TOLERANCE)
    # the speeds its training had: the ensemble's own record (its members, ridge kinds, record a
    # range only; RAFI's kinds are not members)
    assert art["trained_speeds_rpm"] == trained
    assert not any(m.get("speeds") for m in art["members"].values()) and "speeds" not in art
    assert view["trained_speeds_rpm"] == trained
    assert view["speed_range_rpm"] == (trained[0], trained[-1])
    # its own interval, calibrated on the blend: not the heaviest member's
    own = art["interval"]["half_width_um"]
    assert view["half_width_um"] == pytest.approx({k: float(v) for k, v in own.items()})
    assert own != member["interval"]["half_width_um"]
    # the time constants the adaptation moves: the heaviest member's (an ensemble has none)
    assert "selected" not in art and view["slowest_tau_s"] == max(_taus(member))
    assert view["tau_member"] == name and view["members"] == len(art["weights"])
    alone = prior_view(member, tolerance_rpm=TOLERANCE)
    if not member.get("speeds"):  # a ridge kind records a range only
        assert alone["trained_speeds_rpm"] is None


def test_an_ensemble_and_its_heaviest_member_alone_give_different_plans(ensemble):
    art, trained = ensemble
    name, member = _heaviest(art)
    assert not member.get("speeds"), "the contrast needs a heaviest member that records a range only"
    # runs of 30 min (plan_programme's defaults): four heat-ups in 4 h, room for the time constant
    whole = plan_programme(speeds_rpm=SPEEDS, budget_h=4, prior=prior_view(art, tolerance_rpm=TOLERANCE))
    alone = plan_programme(speeds_rpm=SPEEDS, budget_h=4, prior=prior_view(member, tolerance_rpm=TOLERANCE))
    # 4500 r/min: inside the members' range, at none of their trained speeds -> first for the
    # ensemble; inside the heaviest member's range, which is all it records -> last alone
    assert whole.attrs["untrained_rpm"] == [4500.0] and alone.attrs["untrained_rpm"] == []
    assert whole.attrs["speeds_rpm"] == [4500.0, 18000.0, 9000.0, 3000.0]
    assert alone.attrs["speeds_rpm"] == [18000.0, 3000.0, 9000.0, 4500.0]
    own, its = art["interval"]["half_width_um"], member["interval"]["half_width_um"]
    first = whole[whole["kind"] == "heat-up"].iloc[0]
    listed = ", ".join(f"{s:g}" for s in trained)
    assert first["reason"].startswith(
        f"a speed the prior never trained at (its {len(art['weights'])} members trained at {listed} r/min); "
        f"the ensemble's own interval there is the outside cell, +/-{own['outside']:.3g} um"
    )
    tau = max(_taus(member))
    assert (
        f"the prior's slowest time constant ({tau:g} s, of its heaviest member {name}: the one the "
        "adaptation re-fits)" in first["reason"]
    )
    top = whole[(whole["kind"] == "heat-up") & (whole["speed_rpm"] == 18000)].iloc[0]
    assert f"(trained by the prior, the ensemble's own interval +/-{own['settled']:.3g} um)" in top["reason"]
    first_alone = alone[alone["kind"] == "heat-up"].iloc[0]
    assert first_alone["speed_rpm"] == 18000 and first_alone["reason"].startswith("the highest speed")
    assert f"(trained by the prior, interval +/-{its['settled']:.3g} um)" in first_alone["reason"]
    assert "members" not in first_alone["reason"]


def test_time_left_goes_where_the_ensembles_own_interval_is_widest(ensemble):
    art, _ = ensemble
    _, member = _heaviest(art)
    run_s = 1800.0  # plan_programme's defaults: runs of 30 min
    own = art["interval"]["half_width_um"]
    assert own["outside"] > own["settled"]
    views = {
        "whole": prior_view(art, tolerance_rpm=TOLERANCE),
        "alone": prior_view(member, tolerance_rpm=TOLERANCE),
    }
    for view in views.values():
        view["slowest_tau_s"] = None  # the time constants aside: only the interval shares the time
    plans = {k: plan_programme(speeds_rpm=SPEEDS, budget_h=8, prior=v) for k, v in views.items()}
    heat = {
        k: dict(zip(p.loc[p["kind"] == "heat-up", "speed_rpm"], p.loc[p["kind"] == "heat-up", "duration_s"]))
        for k, p in plans.items()
    }
    # the ensemble: the untrained 4500 r/min gets outside / settled times the extra of a trained one
    extra = {s: d - run_s for s, d in heat["whole"].items()}
    ratio = own["outside"] / own["settled"]
    assert extra[4500.0] == pytest.approx(ratio * extra[18000.0], abs=60.0 * (1 + ratio))
    assert extra[18000.0] == extra[9000.0] == extra[3000.0] > 0
    # its heaviest member alone: every speed trained, the same share each
    assert len(set(heat["alone"].values())) == 1
    assert heat["whole"][4500.0] > heat["alone"][4500.0]


def _heat_reasons(path: Path) -> list[str]:
    """The ``reason`` of each heat-up of a plan CSV (the recorder's reader ignores the column)."""
    plan = pd.read_csv(path, skiprows=1)  # the first line is the plan's '#' comment
    return plan.loc[plan["speed_rpm"] > 0, "reason"].tolist()


def test_rafi_plan_with_an_ensemble_champion_reads_it_whole(ensemble, tmp_path, monkeypatch, capsys):
    art, _ = ensemble
    name, member = _heaviest(art)
    config = yaml.safe_load((ROOT / "config.yaml").read_text())
    config["machines"][MACHINE]["training_speeds_rpm"] = SPEEDS
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    monkeypatch.chdir(tmp_path)
    registry = Registry(registry_dir(tmp_path / "results", MACHINE), MACHINE)
    registry.save_model(art)
    registry.set_champion(art["model_id"], reason="test: an ensemble champion")
    # the machine's own runs (runs.min_constant_s, 1 h): four heat-ups take 8 h
    assert main(["plan", "--machine", MACHINE, "--hours", "8", "--out", "whole.csv"]) == 0
    out = capsys.readouterr().out
    n = len(art["weights"])
    assert f"prior {art['model_id'][:12]} (ensemble of {n} members, champion of {MACHINE})" in out
    steps = [s for s in read_plan(tmp_path / "whole.csv").steps if s.speed_rpm > 0]
    assert [s.speed_rpm for s in steps] == [4500.0, 18000.0, 9000.0, 3000.0]
    reasons = _heat_reasons(tmp_path / "whole.csv")
    assert reasons[0].startswith(f"a speed the prior never trained at (its {n} members trained at")
    # the same machine with the heaviest member alone as champion: another plan
    registry.save_model(member)
    registry.set_champion(member["model_id"], reason="test: the heaviest member alone")
    assert main(["plan", "--machine", MACHINE, "--hours", "8", "--out", "alone.csv"]) == 0
    assert f"({member['kind']}, champion of" in capsys.readouterr().out
    steps = [s for s in read_plan(tmp_path / "alone.csv").steps if s.speed_rpm > 0]
    assert [s.speed_rpm for s in steps] == [18000.0, 3000.0, 9000.0, 4500.0]
    assert not any("never trained" in r for r in _heat_reasons(tmp_path / "alone.csv"))
    shutil.rmtree(tmp_path / "results")
