"""Resolving and checking a prior (rafi.family.prior) against a real registry folder."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from rafi.errors import EX_DATAERR, EX_USAGE, PriorIncompatible, PriorUnavailable
from rafi.family.adapted import AdaptedPrior
from rafi.family.dynamic import DynamicRidge
from rafi.family.prior import (
    check_compatible,
    choose_prior,
    prior_chain,
    prior_param,
    registry_meta,
    resolved_prior,
    seen_data,
)
from rafi.ops.registry import Registry, registry_dir
from rafi.ops.status import MachineStatus
from rafi.twin.synthetic_runs import machine_state

REFERENCE = {"rule": "run_start", "window_s": 60}


def _state(seed: int, prefix: str, factor: float = 1.0):
    return machine_state(
        seed=seed, prefix=prefix, factor=factor, duration_s=2 * 3600.0, sample_s=120.0, multi=False
    )


@pytest.fixture(scope="module")
def lineage():
    """A champion adapted on state 2 from a model fitted on state 1: (grand, adapted, states)."""
    s1, s2 = _state(0, "s1-"), _state(1, "s2-", 1.2)
    grand = DynamicRidge(taus_s=[0, 600], max_taus=1, alphas=[1e-4], reference=REFERENCE, machine="m")
    grand = grand.fit(*s1).to_dict()
    adapted = AdaptedPrior(prior=grand, method="gain", machine="m").fit(*s2).to_dict()
    return grand, adapted, s1, s2


def _registry(results, machine, models, champion, sign=None):
    reg = Registry(registry_dir(results, machine), machine)
    for m in models:
        reg.save_model(m, source="test", extra=registry_meta(m, sign))
    reg.set_champion(champion["model_id"], reason="test")
    return reg


def test_the_chain_walks_the_parents_and_the_choice_skips_what_saw_these_runs(tmp_path, lineage):
    grand, adapted, s1, s2 = lineage
    reg = _registry(tmp_path, "m", [grand, adapted], adapted, sign=1)
    meta = json.loads(reg.meta_path(adapted["model_id"]).read_text())
    assert meta["parent"] == grand["model_id"]  # the registry records the parent
    assert meta["config"]["input"]["displacement"]["sign"] == 1
    assert "parent" not in json.loads(reg.meta_path(grand["model_id"]).read_text())
    chain = prior_chain(tmp_path, "m", "auto")
    assert [c["model_id"] for c in chain] == [adapted["model_id"], grand["model_id"]]
    assert seen_data(adapted) == set(s2[0].query("role == 'training'")["sha256"]) | seen_data(grand)
    # tonight's data are state 2's logs: the champion learnt from them, its parent did not
    prior, reason = choose_prior(chain, s2[0])
    assert prior["model_id"] == grand["model_id"]
    assert reason.startswith(f"prior {grand['model_id'][:12]} (dynamic of m") and "1 newer model" in reason
    # new logs (state 3): the champion itself is the prior
    s3 = _state(2, "s3-")
    assert choose_prior(chain, s3[0])[0]["model_id"] == adapted["model_id"]
    # logs the whole chain has seen: no prior
    both = pd.concat([s1[0], s2[0]])
    assert choose_prior(chain, both) == (
        None,
        "no prior: the champion and its 1 parent(s) learnt from some of these logs",
    )
    assert prior_chain(tmp_path, "m", "none") == []


def test_a_parent_cycle_or_a_missing_parent_ends_the_chain(tmp_path, lineage):
    _, adapted, _, _ = lineage
    _registry(tmp_path, "m", [adapted], adapted)  # the parent is not in this registry
    assert [c["model_id"] for c in prior_chain(tmp_path, "m", "champion")] == [adapted["model_id"]]


def test_a_required_prior_that_does_not_exist_names_the_registry(tmp_path, lineage):
    assert prior_chain(tmp_path, "m", "auto") == []
    with pytest.raises(PriorUnavailable, match=r"models.prior: champion: .*m/registry has no champion") as e:
        prior_chain(tmp_path, "m", "champion")
    assert e.value.exit_status == EX_USAGE
    with pytest.raises(PriorUnavailable, match=r"\{machine: sib\}: .*sib/registry has no champion"):
        prior_chain(tmp_path, "m", {"machine": "sib"})
    with pytest.raises(PriorUnavailable, match="is not a prior"):
        prior_chain(tmp_path, "m", "latest")
    grand, _, _, _ = lineage
    _registry(tmp_path, "sib", [grand], grand)
    assert [c["model_id"] for c in prior_chain(tmp_path, "m", {"machine": "sib"})] == [grand["model_id"]]


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            {"sensors_available": ["T1", "T2", "T4", "T5"]},
            r"sensor\(s\) T3 it reads have no data here; a replaced",
        ),
        ({"unit": "m2@Z"}, r"qualified for probe X \(m@X\), this is probe Z \(m2@Z\); another axis"),
    ],
)
def test_an_incompatible_prior_says_what_differs(lineage, change, message):
    grand, _, _, _ = lineage
    prior = {**grand, "machine": "m@X"}
    ok = {"sensors_available": ["T1", "T2", "T3", "T4", "T5"], "unit": "m2@X"}
    check_compatible(prior, **ok)  # compatible: no error
    check_compatible(prior, sensors_available=ok["sensors_available"], unit="m2")  # one probe: maps
    with pytest.raises(PriorIncompatible, match=rf"^prior {grand['model_id'][:12]}: {message}") as e:
        check_compatible(prior, **{**ok, **change})
    assert e.value.exit_status == EX_DATAERR and "\n" not in str(e.value)


def test_the_registry_keeps_the_sign_the_logs_were_read_with_as_provenance():
    rafi_like = {"config": {"input": {"displacement": {"sign": -1}}}, "model_id": "x"}
    assert "config" not in registry_meta(rafi_like, 1)  # the artefact's own snapshot is kept
    assert registry_meta({"model_id": "y"}, -1)["config"]["input"]["displacement"]["sign"] == -1


def test_the_planning_param_and_the_job_agree(tmp_path, lineage):
    grand, adapted, s1, s2 = lineage
    reg = _registry(tmp_path, "m", [grand, adapted], adapted, sign=-1)
    # the raw files are state 2's: the champion is skipped while planning already
    param = prior_param(tmp_path, "m", "auto", s2[0]["sha256"])
    assert param["chain"] == [grand["model_id"]] and param["registry"] == str(reg.root)
    said = []
    prior = resolved_prior(param, s2[0], s2[1], unit="m", log=said.append)
    assert prior == grand and said[0].startswith(f"prior {grand['model_id'][:12]}")
    # every model saw the raw files: an empty param, the same as without a registry
    empty = prior_param(tmp_path, "m", "auto", pd.concat([s1[0], s2[0]])["sha256"])
    assert empty["chain"] == [] and empty["registry"] is None
    assert empty == prior_param(tmp_path / "none", "m", "auto", [])  # as without a registry
    assert resolved_prior(empty, s2[0], s2[1], log=said.append) is None
    assert said[-1].startswith("no prior: the registry of m has no champion, or every model")
    # a sensor the prior reads has no data here: refused with one line
    blind = s2[1].assign(dT3=float("nan"))
    with pytest.raises(PriorIncompatible, match="sensor\\(s\\) T3 it reads have no data here"):
        resolved_prior(param, s2[0], blind, log=said.append)


def test_a_sibling_with_several_probes_serves_the_same_probe(tmp_path, lineage):
    grand, _, _, _ = lineage
    _registry(tmp_path, "sib@Z", [grand], grand)
    chain = prior_chain(tmp_path, "m@Z", {"machine": "sib"})
    assert [c["model_id"] for c in chain] == [grand["model_id"]]
    assert prior_param(tmp_path, "m@Z", {"machine": "sib"}, [])["source"] == "sib@Z"
    with pytest.raises(PriorUnavailable, match=r"sib/registry has no champion"):
        prior_chain(tmp_path, "m", {"machine": "sib"})  # one probe here: the sibling's own registry


def test_status_shows_the_parent():
    d = {
        "decision": "promoted",
        "champion_id_after": "a" * 64,
        "candidate_id": "a" * 64,
        "candidate_parent": "b" * 64,
        "candidate_parent_machine": "sib",
    }
    line = MachineStatus("m", d, [], tonight=True).line()
    assert "(adapted from bbbbbbbbbbbb of sib)" in line


def test_the_nights_line_says_waiting_for_a_candidate_held_for_a_confirmation():
    """A candidate that passed every gate and waits only for a confirmation of its prior's fitness:
    the night's status line says WAITING and what to add, not "rejected"."""
    d = {
        "decision": "rejected",
        "gates_passed": True,
        "blocked_by": ["prior_fitness"],
        "prior_fitness": {
            "blocking": [{"check": "prior_speeds", "prior": "b" * 64, "machine": "sib", "for_machine": "m"}]
        },
        "champion_id_after": None,
        "candidate_id": "a" * 64,
        "candidate_parent": "b" * 64,
        "candidate_parent_machine": "sib",
    }
    line = MachineStatus("m", d, [], tonight=True).line()
    assert line.startswith("m: WAITING tonight; champion ")
    assert "rejected" not in line
    assert line.endswith(
        "waits for a confirmation of the prior fitness check prior_speeds of prior bbbbbbbbbbbb (sib): add "
        'checks.confirmed: [{file: "bbbbbbbbbbbb", check: prior_speeds}] in m\'s settings'
    )
    assert MachineStatus("m", {**d, "gates_passed": False}, [], tonight=True).line().startswith("m: rejected")
