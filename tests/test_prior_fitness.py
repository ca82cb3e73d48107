"""The prior's fitness, stated and gated (issue 47): where a prior comes from, how far the
adaptation moved it, which speeds the new data cover, and the registry's decision on it.

Machine ``m-a`` is qualified on the generator's runs at six speeds through the real decision
(:func:`rafi.ops.decide.run_decide`: its promotion is the prior's own qualification); machine
``m-b`` asks for ``m-a``'s champion as its prior (``models.prior: {machine: m-a}``) with runs at
two speeds, its displacement ``factor`` times ``m-a``'s (the truth of a gain adaptation). Every
figure checked is known from the generator: the gain is ``factor``, the speeds are the ones the
runs were made at.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil

import numpy as np
import pytest
from decide_files import decide_on_files

from rafi.artefact import json_text
from rafi.errors import EX_USAGE, PriorForeign
from rafi.family.adapted import AdaptedPrior
from rafi.family.dynamic import DynamicRidge
from rafi.family.prior import prior_origin, prior_param, prior_promoted, prior_record, resolved_prior
from rafi.family.prior_fitness import BOUNDS, fitness_warnings
from rafi.ops import fleet as F
from rafi.ops import fleet_cli
from rafi.ops.project import Paths
from rafi.ops.provenance import prior_warning_reason
from rafi.ops.registry import registry_dir
from rafi.report.format import fmt_sig
from rafi.settings import MACHINE_DEFAULTS
from rafi.twin.synthetic_runs import machine_state, small_family_model

REFERENCE = {"rule": "run_start", "window_s": 60}
PRIOR_SPEEDS = (3000, 6000, 9000, 12000, 15000, 18000)
NEW_SPEEDS = (9000, 12000)


def _state(seed, prefix, factor=1.0, speeds=PRIOR_SPEEDS):
    return machine_state(
        seed=seed,
        prefix=prefix,
        factor=factor,
        duration_s=2 * 3600.0,
        sample_s=120.0,
        multi=False,
        train_speeds=speeds,
        validation_speeds=(10500,),
    )


def _decide(tmp_path, machine, artefact, state, confirmed=()):
    """The real decision of ``artefact`` on ``state``'s runs (``results/<machine>/registry``)."""
    return decide_on_files(
        tmp_path / f"work-{machine}",
        registry_dir(tmp_path / "results", machine),
        machine,
        json_text(artefact),
        state[0],
        state[1],
        gates=MACHINE_DEFAULTS["qualification"],
        nightly=MACHINE_DEFAULTS["nightly"],
        displacement_sign=1,
        confirmed=confirmed,
    )


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """``m-a`` qualified (its champion is the prior), and the runs of ``m-b``."""
    tmp_path = tmp_path_factory.mktemp("fitness")
    s1 = _state(0, "a-")
    prior = DynamicRidge(taus_s=[0, 600], max_taus=1, alphas=[1e-4], reference=REFERENCE, machine="m-a")
    prior = prior.fit(*s1).to_dict()
    first = _decide(tmp_path, "m-a", prior, s1)
    assert first["decision"] == "promoted", first["reasons"]
    return tmp_path, prior, first


def _param(root, siblings=(), state=None):
    hashes = state[0]["sha256"] if state is not None else []
    return prior_param(root / "results", "m-b", {"machine": "m-a"}, hashes, siblings=siblings)


def test_a_prior_of_an_undeclared_machine_is_refused_in_one_line(project):
    root, prior, _ = project
    s2 = _state(1, "b-", 1.2, NEW_SPEEDS)
    with pytest.raises(PriorForeign) as e:
        resolved_prior(_param(root, state=s2), s2[0], s2[1], log=lambda m: None)
    text = str(e.value)
    assert "\n" not in text and e.value.exit_status == EX_USAGE
    assert text.startswith(f"prior {prior['model_id'][:12]} is a model of m-a, neither m-b nor a declared")
    assert "models.prior_siblings: [m-a]" in text
    # declared a sibling (the machine, or the probe unit): accepted
    said = []
    for siblings in (["m-a"], ["m-a@X", "m-a"]):
        got = resolved_prior(_param(root, siblings, s2), s2[0], s2[1], log=said.append)
        assert got["model_id"] == prior["model_id"]
    assert f"prior {prior['model_id'][:12]} comes from declared sibling" in said


def test_where_a_prior_comes_from():
    assert prior_origin("m", "m") == "this machine"
    assert prior_origin("a", "b", ["a"]) == "declared sibling"
    assert prior_origin("a@Z", "b@Z", ["a"]) == "declared sibling"  # every probe of a declared machine
    assert prior_origin("a@Z", "b@Z", ["a@X"]) is None
    assert prior_origin("m@X", "m@Y") is None  # another probe is another unit: declared or refused
    assert prior_origin("a", "b") is None and prior_origin(None, "b", ["a"]) is None


def _adapted(project, factor, speeds, method="gain"):
    root, prior, _ = project
    s2 = _state(1, "b-", factor, speeds)
    record = prior_record(_param(root, ["m-a"], s2), prior)
    model = AdaptedPrior(
        prior=prior,
        method=method,
        machine="m-b",
        origin=record["origin"],
        qualification=record["qualification"],
        speed_tolerance_rpm=50,
    )
    return model.fit(*s2), s2


def test_the_fitness_figures_are_the_generators_truth(project):
    root, prior, first = project
    fit, _ = _adapted(project, 1.8, NEW_SPEEDS)
    block = fit.to_dict()["adaptation"]["fitness"]
    assert block["origin"] == "declared sibling"
    # the prior's own qualification: its promotion in m-a's registry
    own = block["prior"]
    assert (own["model_id"], own["machine"], own["kind"]) == (prior["model_id"], "m-a", "dynamic")
    assert "promoted" not in own  # a fact of m-a's registry, not of the data: read where shown
    assert prior_promoted(root / "results", "m-a", prior["model_id"]) == first["time"]
    assert own["max_residual_um"] == pytest.approx(first["candidate_summary"]["max_residual_um"])
    # how far it moved: one gain, the generator's factor
    assert block["method"] == "gain" and block["gain"] == pytest.approx(1.8, rel=0.02)
    assert block["prediction_change"] == pytest.approx(0.8, rel=0.03)
    # one gain moves every coefficient by 0.8 of its size (a tie): the first is named, its sign its own
    largest = block["largest_coefficient_change"]
    assert largest["relative"] == pytest.approx(0.8 * np.sign(largest["prior"]), rel=0.03)
    first_moved = next(c for c in fit.coefficient_change_ if float(c["prior"]) != 0)
    assert largest["name"] == first_moved["name"]
    # speeds: tested here, the prior's, the prior's alone (two ranges, each said as such)
    assert block["speeds_tested_rpm"] == [9000.0, 12000.0]
    assert block["speed_range_tested_rpm"] == [9000.0, 12000.0]
    assert block["speeds_prior_rpm"] == [float(s) for s in PRIOR_SPEEDS]
    assert block["speed_range_prior_rpm"] == prior["speed_range_rpm"]
    assert block["speeds_prior_only_rpm"] == [3000.0, 6000.0, 15000.0, 18000.0]
    # temperatures: every sensor the prior reads, the prior's rise beyond the new data's
    rises = {t["sensor"]: t for t in block["temperature"]}
    assert set(rises) == set(prior["key_sensors"])
    for sensor, t in rises.items():
        assert t["prior"] == prior["regressor_ranges"][sensor]
        assert t["tested"][1] < t["prior"][1] and t["prior_only"][-1] == [t["tested"][1], t["prior"][1]]
    assert [w["check"] for w in block["warnings"]] == ["prior_adaptation", "prior_speeds"]
    lo, hi = BOUNDS["gain"]
    assert f"gain {block['gain']:.3g} outside [{lo:g}, {hi:g}]" in block["warnings"][0]["message"]
    assert "3000, 6000, 15000, 18000 r/min have no new training run" in block["warnings"][1]["message"]
    # the same inputs, the same bytes
    again, _ = _adapted(project, 1.8, NEW_SPEEDS)
    assert json_text(again.to_dict()["adaptation"]) == json_text(fit.to_dict()["adaptation"])


def test_the_adapted_id_does_not_depend_on_when_the_prior_was_promoted(project):
    """The same data and the same prior give the same model id, whenever and wherever the prior
    was made champion (a checks.confirmed entry written once matches every re-run)."""
    root, prior, first = project
    s2 = _state(1, "b-", 1.8, NEW_SPEEDS)
    record = prior_record(_param(root, ["m-a"], s2), prior)
    ids = []
    for promoted in (first["time"], "2031-01-01T00:00:00Z", None):
        qualification = {**record["qualification"], "promoted": promoted}
        model = AdaptedPrior(
            prior=prior,
            method="gain",
            machine="m-b",
            origin=record["origin"],
            qualification=qualification,
            speed_tolerance_rpm=50,
        )
        ids.append(model.fit(*s2).to_dict()["model_id"])
    assert len(set(ids)) == 1, ids


def test_an_adaptation_inside_its_bounds_on_the_priors_speeds_warns_of_nothing(project):
    fit, _ = _adapted(project, 1.2, PRIOR_SPEEDS)
    block = fit.to_dict()["adaptation"]["fitness"]
    assert block["gain"] == pytest.approx(1.2, rel=0.02) and block["speeds_prior_only_rpm"] == []
    assert block["warnings"] == []
    # the bounds, each alone
    assert fitness_warnings({"time_factor": 2.0})[0]["message"].endswith("time factor 2 outside [0.71, 1.41]")
    assert fitness_warnings({"time_factor": 1.41, "gain": 0.67, "prediction_change": 0.5}) == []
    assert "prediction moved by 60 %" in fitness_warnings({"prediction_change": 0.6})[0]["message"]


def test_the_fitness_warnings_block_promotion_until_confirmed(project, tmp_path):
    root, prior, _ = project
    fit, s2 = _adapted(project, 1.8, NEW_SPEEDS)
    artefact = fit.to_dict()
    pid = prior["model_id"][:12]
    rec = _decide(tmp_path, "m-b", artefact, s2)
    assert rec["decision"] == "rejected" and rec["gates_passed"], rec["reasons"]
    assert rec["blocked_by"] == ["prior_fitness"]
    lines = [r for r in rec["reasons"] if r.startswith("prior fitness not confirmed")]
    assert len(lines) == 2 and all(f"prior {pid} of m-a" in r for r in lines)
    assert f'{{file: "{pid}", check: prior_adaptation}}' in lines[0]
    # beside the confirmation, what to do instead: qualify without the prior / record the runs
    machine = artefact["machine"]
    assert f"machines: {machine}: models: {{prior: none}}" in lines[0]
    assert f"rafi plan --machine {machine} --prior none" in lines[0]
    assert "prior_speeds" in lines[1] and f"rafi plan --machine {machine} names the --hours" in lines[1]
    assert "--prior none" not in lines[1]
    # one confirmed, the other still blocks
    half = [{"file": pid, "check": "prior_adaptation"}]
    rec = _decide(tmp_path, "m-b", artefact, s2, confirmed=half)
    assert rec["decision"] == "rejected" and rec["blocked_by"] == ["prior_fitness"]
    assert [w["check"] for w in rec["prior_fitness"]["confirmed"]] == ["prior_adaptation"]
    # both confirmed (the full id or a glob of it): promoted
    both = [
        {"file": prior["model_id"], "check": "prior_adaptation"},
        {"file": f"{pid}*", "check": "prior_speeds"},
    ]
    rec = _decide(tmp_path, "m-b", artefact, s2, confirmed=both)
    assert rec["decision"] == "promoted", rec["reasons"]
    assert rec["candidate_parent"] == prior["model_id"] and rec["candidate_parent_machine"] == "m-a"


def _project_files(root, machine):
    """What rafi status needs besides the registry: the raw folder and an audit older than the
    decision."""
    (root / "raw" / machine).mkdir(parents=True, exist_ok=True)
    (root / "raw" / machine / "day1.csv").write_text("time\n")
    res = root / "results" / machine
    (res / "audit.csv").write_text("file,status,reason\nday1.csv,ok,\n")
    (res / "input_status.json").write_text(
        json.dumps({"machine": machine, "status": "usable", "rejected": []})
    )
    decision = res / "registry" / "decision.json"
    stamp = decision.stat().st_mtime - 10
    os.utime(res / "audit.csv", (stamp, stamp))


def _status(root, machine, capsys) -> str:
    """What ``rafi status --machine <machine>`` prints."""
    parser = argparse.ArgumentParser()
    fleet_cli.add_arguments(parser)
    (root / "config.yaml").write_text("raw_dir: raw\nresults_dir: results\nreports_dir: reports\n")
    capsys.readouterr()
    fleet_cli.run(parser.parse_args(["--directory", str(root), "--machine", machine]))
    return capsys.readouterr().out


def test_status_names_the_prior_its_machine_and_its_fitness(project, tmp_path, capsys):
    root, prior, first = project
    fit, s2 = _adapted(project, 1.8, NEW_SPEEDS)
    pid = prior["model_id"][:12]
    confirmed = [{"file": pid, "check": c} for c in ("prior_adaptation", "prior_speeds")]
    rec = _decide(tmp_path, "m-b", fit.to_dict(), s2, confirmed=confirmed)
    assert rec["decision"] == "promoted"
    _project_files(tmp_path, "m-b")
    # the prior's machine in the same project: its promotion time is read from its registry
    shutil.copytree(registry_dir(root / "results", "m-a"), registry_dir(tmp_path / "results", "m-a"))
    rows = F.fleet_overview(Paths.from_config(tmp_path, {}), tmp_path / "reports", ["m-b"])
    champion = rows[0]["champion"]
    assert champion["parent"] == prior["model_id"] and champion["parent_machine"] == "m-a"
    assert champion["prior"]["origin"] == "declared sibling"
    assert champion["prior"]["promoted"] == first["time"]
    lines = _status(tmp_path, "m-b", capsys).splitlines()
    assert f"(adapted from {pid} of m-a)" in lines[1]
    own = f"{pid} of m-a, declared sibling (promoted {first['time']}; worst "
    assert lines[2].startswith(f"  prior:            {own}")
    gain = champion["prior"]["gain"]
    moved = champion["prior"]["largest_coefficient_change"]
    factor = f"{fmt_sig(moved['new'] / moved['prior'], 3)} times its prior value"  # the report's words
    adaptation = (
        f"  adaptation:       gain, gain {gain:.3g}, the coefficient that moved most relative to its prior"
    )
    assert lines[3].startswith(adaptation) and moved["name"] in lines[3] and factor in lines[3]
    speeds = "tested here 9000, 12000 r/min; the prior's alone 3000, 6000, 15000, 18000"
    assert lines[4] == f"  speeds:           {speeds}"
    assert "prior_adaptation, prior_speeds" in lines[5]
    # the first promotion checked no model in service: said once, no contradiction below it
    text = "\n".join(lines)
    assert "drift:            not checked yet (the model was promoted by the last decision)" in text
    assert "no model in service" not in text and "interval drift:   -\n" in text  # the page's "-"


def test_status_after_a_promotion_shows_no_drift_of_the_replaced_champion(tmp_path, capsys):
    """A promotion replacing a degraded champion: its drift figures are the replaced model's."""
    old, new = "a" * 64, "b" * 64
    reg = tmp_path / "results" / "m" / "registry"
    (reg / "models").mkdir(parents=True)
    (reg / "champion.json").write_text(json.dumps({"model_id": new, "since": "2026-11-29T00:00:00Z"}))
    (reg / "models" / f"{new}.json").write_text(json.dumps({"model_id": new, "kind": "grey_box"}))
    interval = {"status": "recalibration_due", "detected": True, "n": 40, "k": 20, "level": 0.9}
    interval |= {
        "expected_k": 4.0,
        "p_value": 0.0,
        "false_alarm": 0.01,
        "decorrelation_s": 600,
        "per_run": {},
    }
    decision = {
        "decision": "promoted",
        "time": "2026-11-29T00:00:00Z",
        "candidate_id": new,
        "champion_id_before": old,
        "champion_id_after": new,
        "recalibration_due": False,
        "drift": {"status": "degraded", "detected": True, "degradation_um": 4.53, "limit_um": 2.0},
    }
    decision["drift"]["interval"] = interval
    (reg / "decision.json").write_text(json.dumps(decision))
    _project_files(tmp_path, "m")
    rows = F.fleet_overview(Paths.from_config(tmp_path, {}), tmp_path / "reports", ["m"])
    assert rows[0]["state"] == "ok" and not rows[0]["recalibration_due"]
    assert rows[0]["drift"]["status"] == "not_checked" and rows[0]["drift"]["checked_model"] == old
    text = _status(tmp_path, rows[0]["machine"], capsys)
    assert "4.53" not in text and "degraded" not in text and "interval drift:   -\n" in text
    assert "not checked yet (the last check was of aaaaaaaaaaaa, the model replaced)" in text
    # the model in service kept after a night: its own drift again
    decision |= {"decision": "kept", "champion_id_before": new, "candidate_id": new}
    (reg / "decision.json").write_text(json.dumps(decision))
    rows = F.fleet_overview(Paths.from_config(tmp_path, {}), tmp_path / "reports", ["m"])
    assert "degraded, +4.53 um" in _status(tmp_path, "m", capsys)


@pytest.mark.parametrize(
    ("kind", "method"),
    [
        ("ridge_global", "ridge"),
        ("dynamic", "time"),
        ("grey_box", "gain"),
        ("grey_box", "time"),
        ("grey_box", "ridge"),
    ],
)
def test_the_speed_range_is_the_tested_and_the_priors_each_said_as_such_for_every_ridge_kind(kind, method):
    """A prior trained at 3000-12000 r/min, new runs at 9000 and 15000: the artefact stands on
    3000-15000 (the compensator's range), of which 9000-15000 tested here and 3000-12000 the
    prior's, 3000, 6000 and 12000 without a new run, whatever the prior's kind and the adaptation."""
    prior_speeds, new_speeds = (3000, 6000, 9000, 12000), (9000, 15000)
    model = small_family_model(
        kind, reference_rule="run_start", reference_window_s=60, filter_restart_gap_s=3600
    )
    model.machine = "m-a"
    prior = model.fit(*_state(0, "a-", speeds=prior_speeds)).to_dict()
    assert prior["kind"] == kind and prior["speed_range_rpm"] == [3000.0, 12000.0]
    adapted = AdaptedPrior(
        prior=prior, method=method, machine="m-b", origin="declared sibling",
        qualification={"speeds_rpm": list(prior_speeds)}, speed_tolerance_rpm=50,
    ).fit(*_state(1, "b-", 1.2, new_speeds))  # fmt: skip
    art = adapted.to_dict()
    block = art["adaptation"]["fitness"]
    assert art["kind"] == kind and block["method"] == method
    assert art["speed_range_rpm"] == [3000.0, 15000.0]
    assert block["speeds_tested_rpm"] == [9000.0, 15000.0] and block["speed_range_tested_rpm"] == [
        9000.0,
        15000.0,
    ]
    assert block["speeds_prior_rpm"] == [3000.0, 6000.0, 9000.0, 12000.0]
    assert block["speed_range_prior_rpm"] == [3000.0, 12000.0]
    assert block["speeds_prior_only_rpm"] == [3000.0, 6000.0, 12000.0]
    assert [w["check"] for w in block["warnings"] if w["check"] == "prior_speeds"] == ["prior_speeds"]
    # the stored artefact reads back with the same ranges (the compensator flags by the union)
    assert type(adapted.model_).from_dict(art).speed_range_rpm_ == [3000.0, 15000.0]


def test_status_names_the_adaptation_of_every_member_with_its_ridge_penalty():
    """An ensemble prior adapted with every member moved (``shared_ridge``): ``rafi status`` says the
    method, the shared gain and the fixed ridge penalty from the artefact's adaptation block."""
    from rafi.ops.fleet import prior_summary
    from rafi.ops.fleet_cli import describe_prior

    artefact = {
        "adaptation": {
            "parent": "a" * 64,
            "parent_machine": "m-a",
            "method": "shared_ridge",
            "gain": 1.2345,
            "alpha": 10.0,
            "time_factor": None,
            "fitness": {"origin": "this machine", "warnings": []},
        }
    }
    summary = prior_summary(artefact)
    assert summary["alpha"] == 10.0 and summary["method"] == "shared_ridge"
    lines = describe_prior(summary)
    assert lines[1] == "  adaptation:       shared_ridge, gain 1.23, ridge penalty 10"


def test_the_misfit_warning_fires_beyond_its_share_of_the_priors_own_half_width():
    """prior_misfit: the prior as it is, on the new runs, more than MISFIT_HALF_WIDTHS of its own
    pooled 90 % half widths off; nothing at or below it, without a calibrated interval, or without a
    finite score."""
    from rafi.family.prior_fitness import CHECKS, MISFIT_HALF_WIDTHS, misfit_warning

    prior = {"interval": {"calibration": {"pooled_half_width_um": 0.5}}}
    limit = MISFIT_HALF_WIDTHS * 0.5
    assert misfit_warning(limit, prior) is None and misfit_warning(limit * 0.5, prior) is None
    warning = misfit_warning(limit + 0.01, prior)
    assert warning["check"] == "prior_misfit" and "prior_misfit" in CHECKS
    assert f"{(limit + 0.01) / 0.5:.1f} times its own 90 % half width (0.5 um" in warning["message"]
    assert "\n" not in warning["message"]
    for other in ({}, {"interval": {"calibration": {"pooled_half_width_um": None}}}):
        assert misfit_warning(100.0, other) is None
    assert misfit_warning(float("nan"), prior) is None
    assert warning["message"].startswith("the prior as it is lies ")
    # an ensemble prior: the candidate prior is its heaviest member as it is, the half width the ensemble's
    ensemble = prior | {
        "kind": "ensemble",
        "weights": {"a": 0.3, "b": 0.7},
        "members": {"a": {"kind": "dynamic"}, "b": {"kind": "grey_box"}},
    }
    message = misfit_warning(limit + 0.01, ensemble)["message"]
    assert message.startswith("the ensemble prior's heaviest member (grey_box) as it is lies ")
    assert "times the ensemble's 90 % half width (0.5 um" in message


def test_a_warning_that_the_prior_does_not_describe_the_machine_says_to_qualify_without_it():
    for check in ("prior_misfit", "prior_dynamics", "prior_adaptation"):
        w = {"prior": "a" * 64, "machine": "m-a", "for_machine": "m-b@z2", "check": check, "message": "x"}
        line = prior_warning_reason(w)
        assert line.startswith(f"prior fitness not confirmed: prior {'a' * 12} of m-a: x; ")
        assert f'{{file: "{"a" * 12}", check: {check}}}' in line
        # a probe unit's machine is its folder's name in config.yaml and rafi plan
        assert "machines: m-b: models: {prior: none}" in line
        assert "rafi plan --machine m-b --prior none" in line
    speeds = {"prior": "b" * 12, "machine": "m-a", "check": "prior_speeds", "message": "y"}
    line = prior_warning_reason(speeds)
    assert "record runs at those speeds (rafi plan --machine <machine> names the --hours" in line


def test_status_says_which_speeds_the_prior_had_only_from_its_own_prior():
    """A prior that was itself re-qualified: ``rafi status`` adds the speeds it only inherited, with
    the older prior and the machine they were never tested on."""
    from rafi.ops.fleet import prior_summary
    from rafi.ops.fleet_cli import describe_prior

    fitness = {
        "origin": "this machine",
        "warnings": [],
        "speeds_tested_rpm": [3000.0],
        "speeds_prior_only_rpm": [12000.0, 18000.0],
        "speeds_inherited": {
            "speeds_rpm": [18000.0],
            "from": {"model_id": "c" * 64, "machine": "m-0"},
            "via": "m-a",
        },
    }
    artefact = {
        "adaptation": {"parent": "a" * 64, "parent_machine": "m-a", "method": "gain", "fitness": fitness}
    }
    lines = describe_prior(prior_summary(artefact))
    assert lines[2] == (
        "  speeds:           tested here 3000 r/min; the prior's alone 12000, 18000; 18000 r/min the prior "
        f"had only from its own prior ({'c' * 12} of m-0): no run at them since that model"
    )
