"""The model id is content only (rafi.artefact.compute_model_id): the same data gives the same
model, whatever its files are called and whenever it was made; an artefact written before (its
id hashing the names) still verifies everywhere an artefact is checked.
"""

from __future__ import annotations

import copy

import pytest

from rafi import artefact
from rafi.deploy.compensator import Compensator
from rafi.errors import RegistryError
from rafi.method.model import RafiModel
from rafi.ops import registry as R
from rafi.readers.input_spec import log_id

TERMS = ["1", "x1", "x2", "x3"]
SHA = {"3000": "3" * 64, "9000": "9" * 64, "multi": "m" * 64}


def rafi_model(names: dict[str, str], created="2026-01-01T00:00:00Z", coefficient=1.0) -> dict:
    """A RAFI artefact trained on the files ``names`` (content key -> file name): one run per file
    at 3000 and 9000 r/min, two runs (``<log id>#1``, ``#2``) of the multi-speed file."""
    m = RafiModel(
        ["T6", "T8", "T9"],
        TERMS,
        reference={"rule": "run_start", "window_s": 60},
        machine="m1",
        data={names[key]: SHA[key] for key in names},
        code_version="rafi test",
        created=created,
    )
    multi = log_id(names["multi"].rsplit(".", 1)[0])  # run ids are log ids (docs/design.md)
    for key, speed in (("3000", 3000), ("9000", 9000)):
        stem = log_id(names[key].rsplit(".", 1)[0])
        m.add_speed_model(
            speed,
            [coefficient, 1.0, 2.0, 3.0],
            {k: [0.0, 5.0] for k in ("T6", "T8", "T9")},
            train_runs=[stem, f"{multi}#{1 if speed == 3000 else 2}"],
            rmse_um=0.5,
            n=100,
        )
    return m.to_dict()


NAMES = {"3000": "train_03000rpm.csv", "9000": "train_09000rpm.csv", "multi": "multi.csv"}
RENAMED = {"3000": "train_03000rpm (copy).csv", "9000": "t9.csv", "multi": "log_{date}.csv"}


def test_renamed_training_files_give_the_same_id():
    original, renamed = rafi_model(NAMES), rafi_model(RENAMED)
    assert original["data"] != renamed["data"]
    assert original["speeds"][0]["train_runs"] == ["train_03000rpm", "multi#1"]
    assert renamed["speeds"][0]["train_runs"] == ["train_03000rpm (copy)", "log_%7Bdate%7D#1"]
    assert original["model_id"] == renamed["model_id"] == artefact.compute_model_id(renamed)


def test_the_id_follows_content_coefficients_and_runs_not_time():
    base = rafi_model(NAMES)
    assert rafi_model(NAMES, created="2030-06-01T00:00:00Z")["model_id"] == base["model_id"]
    assert rafi_model(NAMES, coefficient=1.5)["model_id"] != base["model_id"]
    changed = copy.deepcopy(base)
    changed["data"]["train_03000rpm.csv"] = "0" * 64  # same name, other content
    assert artefact.compute_model_id(changed) != base["model_id"]
    swapped = copy.deepcopy(base)  # the 3000 r/min model trained on the multi-speed file's other run
    swapped["speeds"][0]["train_runs"] = ["train_03000rpm", "multi#2"]
    assert artefact.compute_model_id(swapped) != base["model_id"]


def test_identity_content_replaces_names_by_hashes():
    content = artefact.identity_content(rafi_model(NAMES))
    assert "created" not in content and "model_id" not in content
    assert content["data"] == sorted(SHA.values())
    assert content["speeds"][0]["train_runs"] == [SHA["3000"], f"{SHA['multi']}#1"]
    # keys too (a per-file setting), unless two would become one
    keyed = artefact.identity_content(
        {"data": {"a.csv": "h"}, "config": {"by_file": {"a.csv": 1, "b.csv": 2}}}
    )
    assert keyed["config"]["by_file"] == {"h": 1, "b.csv": 2}
    clash = artefact.identity_content({"data": {"a.csv": "h"}, "x": {"a": 1, "a.csv": 2}})
    assert clash["x"] == {"a": 1, "a.csv": 2}
    assert artefact.identity_content({"kind": "k", "created": "t"}) == {"kind": "k"}


def _named(d: dict) -> dict:
    """``d`` as it was written before ids were content only (its id hashing the file names)."""
    old = {k: v for k, v in d.items() if k != "model_id"}
    old["model_id"] = artefact.named_model_id(old)
    return old


def test_an_artefact_with_a_former_id_still_verifies_and_an_edited_one_does_not():
    old = _named(rafi_model(NAMES))
    assert old["model_id"] != artefact.compute_model_id(old)
    assert artefact.model_id_verifies(old)
    edited = copy.deepcopy(old)
    edited["speeds"][0]["coefficients"][0] = 9.0
    assert not artefact.model_id_verifies(edited)
    assert not artefact.model_id_verifies({**old, "model_id": "0" * 64})
    assert not artefact.model_id_verifies({k: v for k, v in old.items() if k != "model_id"})
    assert RafiModel.from_dict(old).model_id == artefact.compute_model_id(old)
    with pytest.raises(ValueError, match="does not match the content"):
        RafiModel.from_dict(edited)
    assert Compensator.from_artefact(old).model_id == old["model_id"]
    with pytest.raises(ValueError, match="edited or corrupted"):
        Compensator.from_artefact(edited)


def test_a_registry_keeps_its_former_ids(tmp_path):
    reg = R.Registry(tmp_path / "registry", "m1")
    old = _named(rafi_model(NAMES))
    reg.save_model(old)
    reg.set_champion(old["model_id"], reason="promoted before the upgrade")
    assert reg.load_model_dict(old["model_id"]) == old
    new = rafi_model(RENAMED)
    assert new["model_id"] != old["model_id"]  # one new id at the upgrade, then stable
    reg.save_model(new)
    reg.model_path(old["model_id"]).chmod(0o644)
    reg.model_path(old["model_id"]).write_text(artefact.json_text({**old, "machine": "other"}))
    with pytest.raises(RegistryError, match="the registry file was modified"):
        reg.load_model_dict(old["model_id"])


def test_an_ensembles_id_ignores_when_its_members_were_written():
    """Each ``to_dict`` of a member stamps a new ``created``: the ensemble's id must not follow it
    (rafi.family.ensemble: the same members and weights are the same model)."""
    member = rafi_model(NAMES)

    def ensemble(created: str, coefficient: float = 1.0) -> dict:
        m = rafi_model(NAMES, coefficient=coefficient)
        body = {"kind": "ensemble", "weights": {"a": 0.6, "b": 0.4}, "data": dict(member["data"])}
        body["members"] = {"a": {**m, "created": created}, "b": {**member, "created": created}}
        return {**body, "model_id": artefact.compute_model_id(body)}

    first, later = ensemble("2026-01-01T00:00:00Z"), ensemble("2030-06-01T00:00:01Z")
    assert first["model_id"] == later["model_id"]
    assert artefact.model_id_verifies(later) and artefact.model_id_verifies({**first, "created": "x"})
    assert ensemble("2026-01-01T00:00:00Z", coefficient=1.5)["model_id"] != first["model_id"]
    reweighted = {**first, "weights": {"a": 0.5, "b": 0.5}}
    assert not artefact.model_id_verifies(reweighted)
