"""An adapted prior's speed range, per prior kind (issue 47, item 1): "the artefact's speed range
is what was tested here plus what the prior covers, each said as such".

Every adapted artefact carries ``speed_range_rpm`` (the range it stands on: the prior's joined
with the new runs') and, in ``adaptation.fitness``, ``speed_range_tested_rpm`` and
``speed_range_prior_rpm`` each on its own. Known truth: the generator's speeds. The prior is fitted
on a machine state trained at 6000, 12000 and 18000 r/min and re-qualified on one tested at 3000
and 6000 r/min (make_synthetic_runs, displacement x1.2), so tested here is 3000-6000, the prior
covers 6000-18000 and the artefact stands on 3000-18000.
"""

from __future__ import annotations

import json
import warnings

import pytest

from rafi.artefact import compute_model_id, model_id_verifies
from rafi.deploy.compensator import Compensator
from rafi.family.adapted import AdaptedPrior
from rafi.family.compare import load_any, make_model, run_family
from rafi.family.ensemble import WeightedEnsemble
from rafi.settings import MACHINE_DEFAULTS
from rafi.twin.synthetic_runs import machine_state

REFERENCE = {"rule": "run_start", "window_s": 60}
SENSORS = ["T1", "T2", "T3"]
PRIOR_SPEEDS = (6000.0, 12000.0, 18000.0)
NEW_SPEEDS = (3000.0, 6000.0)
KINDS = ["rafi", "rafi_linear", "ridge_global", "dynamic", "grey_box", "temperature_ridge"]
#: Ensembles of the kinds given: one whose heaviest member is a ridge kind, one of RAFI's kinds
#: (their weights come from the CV; the test reads which member is heaviest from the artefact).
ENSEMBLES = {
    "ensemble_ridge": ["ridge_global", "dynamic"],
    "ensemble_rafi": ["rafi", "rafi_linear"],
}
OPTIONS = {**MACHINE_DEFAULTS["models"], "dynamic_taus_s": [0.0, 600.0, 1800.0], "dynamic_max_taus": 2}


def _state(seed, factor, prefix, train, validation):
    return machine_state(
        seed=seed,
        prefix=prefix,
        factor=factor,
        train_speeds=train,
        validation_speeds=validation,
        multi=False,
        duration_s=3 * 3600.0,
        sample_s=120.0,
    )


@pytest.fixture(scope="module")
def states():
    old = _state(0, 1.0, "old-", PRIOR_SPEEDS, (9000.0,))
    new = _state(1, 1.2, "new-", NEW_SPEEDS, (4500.0,))
    return old, new


def _prior(kind: str, table, frame) -> dict:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # statsmodels' conditioning warnings of RAFI's fits
        if kind in ENSEMBLES:
            # RAFI's kinds are not members of a new ensemble (NOT_MEMBERS): theirs is built from
            # their fits, as an artefact made before that holds them
            offer = "best" if kind == "ensemble_rafi" else "ensemble"
            res = run_family(
                table,
                frame,
                key_sensors=SENSORS,
                terms=MACHINE_DEFAULTS["fit"]["terms"],
                reference=REFERENCE,
                machine="old",
                gates=MACHINE_DEFAULTS["qualification"],
                options={**OPTIONS, "enabled": ENSEMBLES[kind], "offer": offer},
                log=lambda m: None,
            )
            if kind == "ensemble_rafi":
                weights = {"rafi": 0.6, "rafi_linear": 0.4}
                return WeightedEnsemble.from_fitted(res["models"], weights, machine="old").to_dict()
            art = res["best_artefact"]
            assert art["kind"] == "ensemble"
            return art
        model = make_model(
            kind,
            key_sensors=SENSORS,
            terms=MACHINE_DEFAULTS["fit"]["terms"],
            reference=REFERENCE,
            machine="old",
            options=OPTIONS,
        )
        return model.fit(table, frame).to_dict()


def _heaviest_kind(prior: dict) -> str:
    if prior["kind"] != "ensemble":
        return prior["kind"]
    weights = prior["weights"]
    name = max(weights, key=lambda n: weights[n])
    return prior["members"][name]["kind"]


@pytest.mark.parametrize("kind", [*KINDS, *ENSEMBLES])
def test_every_adapted_artefact_says_what_was_tested_here_and_what_the_prior_covers(states, kind):
    (t1, f1), (t2, f2) = states
    prior = _prior(kind, t1, f1)
    base_kind = _heaviest_kind(prior)
    if kind == "ensemble_rafi":
        assert base_kind in ("rafi", "rafi_linear")
    if kind == "ensemble_ridge":
        assert base_kind in ("ridge_global", "dynamic")
    adapted = AdaptedPrior(prior=prior, method="gain", machine="new").fit(t2, f2)
    art = json.loads(json.dumps(adapted.to_dict()))
    assert art["kind"] == base_kind and model_id_verifies(art)
    fit = art["adaptation"]["fitness"]
    # each said as such: tested here, covered by the prior; the artefact stands on both
    assert fit["speed_range_tested_rpm"] == [min(NEW_SPEEDS), max(NEW_SPEEDS)]
    assert fit["speeds_tested_rpm"] == sorted(NEW_SPEEDS)
    assert fit["speed_range_prior_rpm"] == [min(PRIOR_SPEEDS), max(PRIOR_SPEEDS)]
    assert art["speed_range_rpm"] == [min(NEW_SPEEDS), max(PRIOR_SPEEDS)]
    # the prior's own speeds where an artefact records them (RAFI's per-speed models, an
    # ensemble's own record or its RAFI member's); the speeds only the prior covers are a warning
    records_speeds = kind in ("rafi", "rafi_linear", "ensemble_rafi", "ensemble_ridge")
    if records_speeds:
        assert fit["speeds_prior_rpm"] == list(PRIOR_SPEEDS)
        assert fit["speeds_prior_only_rpm"] == [12000.0, 18000.0]
    else:  # a range only, no registry record: its ends stand for its speeds
        assert fit["speeds_prior_rpm"] is None and fit["speeds_prior_only_rpm"] == [18000.0]
    said = {w["check"]: w["message"] for w in fit["warnings"]}
    only = ", ".join(f"{s:g}" for s in fit["speeds_prior_only_rpm"])
    assert said["prior_speeds"].startswith(f"the prior's speed(s) {only} r/min have no new training run")
    # the artefact loads by its kind and keeps its range and its id
    again = load_any(art)
    assert again.to_dict()["model_id"] == art["model_id"]
    assert again.to_dict()["speed_range_rpm"] == art["speed_range_rpm"]
    Compensator.from_artefact(art)  # the machine's reader verifies the id and reads the model


def test_an_adapted_rafi_artefact_written_before_the_range_still_loads(states):
    (t1, f1), (t2, f2) = states
    prior = _prior("rafi", t1, f1)
    art = json.loads(json.dumps(AdaptedPrior(prior=prior, method="gain").fit(t2, f2).to_dict()))
    older = {k: v for k, v in art.items() if k not in ("speed_range_rpm", "model_id")}
    older["model_id"] = compute_model_id(older)  # as written before the key existed
    again = load_any(older).to_dict()
    assert again["model_id"] == older["model_id"] and "speed_range_rpm" not in again
    edited = {**older, "speed_range_rpm": [0.0, 30000.0]}  # a range added by hand is an edit
    with pytest.raises(ValueError, match="model_id"):
        load_any(edited)
    # a RAFI model fitted from scratch carries no range of its own (its per-speed models say it)
    assert "speed_range_rpm" not in prior


@pytest.mark.parametrize("kind", list(ENSEMBLES))
def test_a_shared_gain_artefact_says_what_was_tested_here_and_what_the_prior_covers(states, kind):
    """An ensemble prior adapted as a whole (``prior_shared_gain``, RAFI's members too): the
    ensemble artefact stands on the prior's range joined with the new speeds, its fitness block
    says each as such and warns of the speeds only the prior covers."""
    from rafi.family.adapted import SharedAdaptedEnsemble

    (t1, f1), (t2, f2) = states
    prior = _prior(kind, t1, f1)
    adapted = SharedAdaptedEnsemble(prior=prior, method="shared_gain", machine="new").fit(t2, f2)
    art = json.loads(json.dumps(adapted.to_dict()))
    assert art["kind"] == "ensemble" and model_id_verifies(art) and art["machine"] == "new"
    assert art["weights"] == pytest.approx(prior["weights"])
    fit = art["adaptation"]["fitness"]
    assert fit["speed_range_tested_rpm"] == [min(NEW_SPEEDS), max(NEW_SPEEDS)]
    assert fit["speed_range_prior_rpm"] == [min(PRIOR_SPEEDS), max(PRIOR_SPEEDS)]
    assert art["speed_range_rpm"] == [min(NEW_SPEEDS), max(PRIOR_SPEEDS)]
    assert 18000.0 in fit["speeds_prior_only_rpm"]
    assert "prior_speeds" in {w["check"] for w in fit["warnings"]}
    again = load_any(art)
    assert again.to_dict()["model_id"] == art["model_id"]
    Compensator.from_artefact(art)


@pytest.mark.parametrize("kind", ["rafi", "ridge_global"])
def test_a_prior_that_is_itself_a_requalification_says_which_speeds_it_only_inherited(states, kind):
    """A chain: the old machine's model re-qualified on ``new`` (tested at 3000 and 6000 r/min),
    that model the prior of ``newer`` (tested at the same speeds). The speeds ``newer`` leaves to
    its prior were never tested on ``new`` either: the fitness block and the warning name the
    older prior they come from; a first re-qualification carries no such key (its bytes and id
    unchanged)."""
    (t1, f1), (t2, f2) = states
    first = _prior(kind, t1, f1)
    middle = json.loads(
        json.dumps(AdaptedPrior(prior=first, method="gain", machine="new").fit(t2, f2).to_dict())
    )
    assert "speeds_inherited" not in middle["adaptation"]["fitness"]
    left = middle["adaptation"]["fitness"]["speeds_prior_only_rpm"]
    assert left  # the generator's prior speeds above the new ones
    last = AdaptedPrior(prior=middle, method="gain", machine="newer").fit(t2, f2).to_dict()
    fit = last["adaptation"]["fitness"]
    assert fit["speeds_prior_only_rpm"] == left
    assert fit["speeds_inherited"] == {
        "speeds_rpm": left,
        "from": {"model_id": first["model_id"], "machine": "old"},
        "via": "new",
    }
    said = {w["check"]: w["message"] for w in fit["warnings"]}["prior_speeds"]
    speeds = ", ".join(f"{s:g}" for s in left)
    assert said.endswith(
        f"; {speeds} r/min the prior had only from its own prior ({first['model_id'][:12]} of old): "
        "no run at them since that model"
    )


def test_an_adapted_ensemble_prior_passes_on_what_it_only_inherited(states):
    """The chain through ensembles adapted as a whole (the moved members, offered by default): the
    second re-qualification names the speeds its prior had only from the first model."""
    from rafi.family.adapted import SharedAdaptedEnsemble

    (t1, f1), (t2, f2) = states
    first = _prior("ensemble_ridge", t1, f1)
    middle = SharedAdaptedEnsemble(prior=first, method="shared_ridge", machine="new").fit(t2, f2).to_dict()
    middle = json.loads(json.dumps(middle))
    left = middle["adaptation"]["fitness"]["speeds_prior_only_rpm"]
    last = SharedAdaptedEnsemble(prior=middle, method="shared_ridge", machine="newer").fit(t2, f2).to_dict()
    fit = last["adaptation"]["fitness"]
    assert left and fit["speeds_prior_only_rpm"] == left
    assert fit["speeds_inherited"] == {
        "speeds_rpm": left,
        "from": {"model_id": first["model_id"], "machine": "old"},
        "via": "new",
    }
