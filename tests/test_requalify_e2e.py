"""Re-qualification end to end (issue 27): ``rafi plan`` -> the twin follows the plan -> ``rafi
nightly`` (the real Snakefile) -> a re-qualified champion with its parent in the registry.

Night 1 qualifies a machine on three shipped training runs and one validation run: its champion
is the prior. A sibling of the same series is then configured with ``models.prior: {machine:
...}`` (docs/operations.md, "Re-qualification in hours"), ``rafi plan`` writes its 2 h programme,
the twin with the sibling's build spread (``rafi simulate day --sibling``) runs it and one
validation run. Night 2 refuses the prior in one line: the first machine is not declared a
sibling (``models.prior_siblings``, issue 47). Declared, night 3 starts the sibling from the
prior: the programme is one heat-up (no whole-run CV fold), so the prior with one gain is offered
(:func:`rafi.family.selection.default_champion`; the first machine's champion is a CV-weighted
ensemble: the whole ensemble times one shared gain, ``prior_shared_gain``), judged by the same
gates, and held back by the prior's fitness warning (the prior's speeds the heat-up does not
cover); confirmed in ``checks.confirmed``, night 4 promotes it with its parent recorded.
"""

from __future__ import annotations

import copy
import json
import shutil

import pytest
import yaml
from project_copy import ROOT, copy_project, run_nightly, run_rafi, settle

from rafi.deploy.record_plan import read_plan

MACHINE = "tapping-center-a"
SIBLING = "tapping-center-a2"
TRAIN = ("train_03000rpm.csv", "train_09000rpm.csv", "train_15000rpm.csv", "valid_08000rpm.csv")


def _project(tmp_path):
    proj = copy_project(tmp_path / "proj")
    cfg = yaml.safe_load((proj / "config.yaml").read_text(encoding="utf-8"))
    machine = cfg["machines"][MACHINE]
    machine["training_speeds_rpm"] = [3000, 9000, 15000]
    machine["models"] = {"enabled": ["rafi", "ridge_global", "dynamic"]}  # the family's time, trimmed
    cfg["machines"] = {MACHINE: machine}
    cfg["nightly_settle_s"] = 0
    (proj / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    raw = proj / "raw" / MACHINE
    raw.mkdir(parents=True)
    for name in TRAIN:
        shutil.copy2(ROOT / "raw" / MACHINE / name, raw / name)
        settle(raw / name)
    return proj


def _decision(proj, machine: str) -> dict:
    return json.loads((proj / "results" / machine / "registry" / "decision.json").read_text(encoding="utf-8"))


@pytest.mark.slow
def test_plan_twin_night_gives_a_requalified_sibling_with_its_parent(tmp_path):
    proj = _project(tmp_path)

    # night 1: the first machine of the series is qualified; its champion is the prior
    night = run_nightly(proj)
    assert night.returncode in (0, 4), night.stdout + night.stderr
    first = _decision(proj, MACHINE)
    assert first["decision"] == "promoted", first["reasons"]
    prior_id = first["candidate_id"]

    # a sibling arrives: configured like the first, starting from its champion
    cfg = yaml.safe_load((proj / "config.yaml").read_text(encoding="utf-8"))
    cfg["machines"][SIBLING] = {
        **copy.deepcopy(cfg["machines"][MACHINE]),
        "models": {**cfg["machines"][MACHINE]["models"], "prior": {"machine": MACHINE}},
    }
    (proj / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    # not declared a sibling: rafi plan refuses the prior before anything is recorded, with the
    # line the night prints (night 2 below)
    plan = run_rafi(proj, "plan", "--machine", SIBLING, "--hours", "2", "--out", "plan.csv")
    assert plan.returncode == 64 and not (proj / "plan.csv").exists(), plan.stdout + plan.stderr
    assert f"prior {prior_id[:12]} is a model of {MACHINE}" in plan.stderr
    assert f"models.prior_siblings: [{MACHINE}]" in plan.stderr
    # declared for the plan; the declaration is taken back below to see the night refuse it too
    declared = copy.deepcopy(cfg)
    declared["machines"][SIBLING]["models"]["prior_siblings"] = [MACHINE]
    (proj / "config.yaml").write_text(yaml.safe_dump(declared, sort_keys=False), encoding="utf-8")
    plan = run_rafi(proj, "plan", "--machine", SIBLING, "--hours", "2", "--out", "plan.csv")
    assert plan.returncode == 0, plan.stderr
    (proj / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    assert f"prior {prior_id[:12]}" in plan.stdout and f"champion of {MACHINE}" in plan.stdout
    steps = read_plan(proj / "plan.csv").steps
    assert sum(s.duration_s for s in steps) <= 2 * 3600 and max(s.speed_rpm for s in steps) == 15000

    # the sibling (the twin with its build spread) runs the plan, and one validation run
    sim = run_rafi(
        proj, "simulate", "day", "--machine", MACHINE, "--name", SIBLING, "--sibling", "0",
        "--plan", "plan.csv", "--validation-speeds", "12000", "--seed", "9", "--no-defects", "--out", "raw",
    )  # fmt: skip
    assert sim.returncode == 0, sim.stderr
    new_files = sorted((proj / "raw" / SIBLING).glob("*.csv"))
    assert len(new_files) == 2
    for path in new_files:
        settle(path)

    # night 2: the first machine is not declared a sibling: its prior is refused in one line
    night = run_nightly(proj)
    out = night.stdout + night.stderr
    assert night.returncode == 1, out
    refused = [line for line in out.splitlines() if f"prior {prior_id[:12]} is a model of {MACHINE}" in line]
    assert refused and all(f"models.prior_siblings: [{MACHINE}]" in line for line in refused), out
    assert not (proj / "results" / SIBLING / "registry" / "decision.json").exists()

    # night 3: declared; the adapted prior passes the gates, its fitness warning holds it back
    cfg = yaml.safe_load((proj / "config.yaml").read_text(encoding="utf-8"))
    cfg["machines"][SIBLING]["models"]["prior_siblings"] = [MACHINE]
    (proj / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    night = run_nightly(proj)
    assert night.returncode in (2, 4), night.stdout + night.stderr
    held = _decision(proj, SIBLING)
    assert held["decision"] == "rejected" and held["blocked_by"] == ["prior_fitness"], held["reasons"]
    checks = [w["check"] for w in held["prior_fitness"]["blocking"]]
    assert "prior_speeds" in checks  # the heat-up covers one of the prior's three speeds

    # night 4: confirmed in checks.confirmed (the prior's id): promoted with its parent
    cfg["machines"][SIBLING]["checks"] = {"confirmed": [{"file": prior_id[:12], "check": c} for c in checks]}
    (proj / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")
    night = run_nightly(proj)
    assert night.returncode in (0, 4), night.stdout + night.stderr
    second = _decision(proj, SIBLING)
    assert second["decision"] == "promoted", second["reasons"]
    assert second["candidate_parent"] == prior_id
    registry = proj / "results" / SIBLING / "registry"
    champion = json.loads((registry / "champion.json").read_text(encoding="utf-8"))
    assert champion["model_id"] == second["candidate_id"] != prior_id
    model = json.loads((registry / "models" / f"{champion['model_id']}.json").read_text(encoding="utf-8"))
    adaptation = model["adaptation"]
    assert adaptation["parent"] == prior_id and adaptation["parent_machine"] == MACHINE
    # one heat-up: no fold, the default; the prior an ensemble (models: offer), so its shared gain
    assert model["kind"] == "ensemble" and adaptation["method"] == "shared_gain" and adaptation["gain"] > 0
    meta = json.loads((registry / "models" / f"{champion['model_id']}.meta.json").read_text(encoding="utf-8"))
    assert meta["parent"] == prior_id
    # what qualified it: the sibling's files only; the prior's training data stays its own
    assert set(model["data"]) <= {p.name for p in new_files}
    assert set(adaptation["prior_data"]) >= set(TRAIN[:3])
    summary = (proj / "results" / SIBLING / "comparison" / "summary.csv").read_text(encoding="utf-8")
    assert all(f"\n{name}," in summary for name in ("prior", "prior_gain", "prior_shared_gain"))
    assert adaptation["fitness"]["origin"] == "declared sibling"
    # its promotion time is the registry's, not the artefact's (the id depends on content only)
    assert "promoted" not in adaptation["fitness"]["prior"]
    assert f"(promoted {first['time']};" in run_rafi(proj, "status", "--machine", SIBLING).stdout
    status = run_rafi(proj, "status", "--machine", SIBLING)
    assert f"(adapted from {prior_id[:12]} of {MACHINE})" in status.stdout, status.stdout + status.stderr
    assert f"prior:            {prior_id[:12]} of {MACHINE}, declared sibling" in status.stdout
