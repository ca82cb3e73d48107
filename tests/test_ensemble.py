"""The CV-weighted ensemble (rafi.family.ensemble, issue 46): its weights, its blend, its CV rows
checked against refits of every member, and its offer under ``models: offer: ensemble``.

Oracles: NumPy's masked weighted average for the blend; the weights written out by hand; the CV
rows recomputed from independent refits of every member on each fold (not from the OOF samples the
code blends). Data: the golden synthetic runs of tests/test_crossval.py.
"""

from __future__ import annotations

import functools
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from rafi.family import crossval
from rafi.family.compare import load_any, make_model, run_family
from rafi.family.ensemble import ENSEMBLE, NOT_MEMBERS, WeightedEnsemble, blend, cv_weights, ensemble_members
from rafi.family.plain_ridge import PLAIN_RIDGE
from rafi.settings import MACHINE_DEFAULTS

DATA = Path(__file__).parent / "data"
GATES = {"max_residual_um": 12.0, "min_improvement_pct": 30.0, "never_worse_than_uncompensated": True}
ENABLED = ["rafi_linear", "ridge_global", "dynamic"]
SETTINGS = {
    "key_sensors": ["T1", "T2", "T3"],
    "terms": MACHINE_DEFAULTS["fit"]["terms"],
    "reference": MACHINE_DEFAULTS["reference"],
    "machine": "synthetic",
}


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def _data():
    return (
        pd.read_csv(DATA / "golden_comparison_runs.csv"),
        pd.read_csv(DATA / "golden_comparison_frame.csv"),
    )


def _options(**changes):
    return {**MACHINE_DEFAULTS["models"], "enabled": ENABLED, **changes}


@pytest.fixture(scope="module")
def offered():
    table, frame = _data()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = run_family(
            table, frame, **SETTINGS, gates=GATES, options=_options(offer="ensemble"), log=lambda m: None
        )
    return table, frame, res


# --------------------------------------------------------------------------- the weights and the blend


def test_weights_are_inverse_squared_mean_whole_run_scores():
    cv = pd.DataFrame(
        {
            "model": ["a", "a", "b", "b", "c", "c", "a"],
            "scheme": ["leave_one_run_out"] * 6 + ["forward_2"],
            "max_abs_after_um": [1.0, 3.0, 4.0, 4.0, 1.0, np.nan, 100.0],
        }
    )
    w = cv_weights(cv, ["a", "b", "c"])
    # a: mean 2 -> 1/4; b: mean 4 -> 1/16; c: a held-out run unpredicted -> out; forward row ignored
    assert w == pytest.approx({"a": 0.25 / 0.3125, "b": 0.0625 / 0.3125})
    assert cv_weights(cv, ["a", "c"]) == {}  # one member with a score: no blend


def test_the_members_are_the_enabled_kinds_but_rafis_and_the_plain_ridge():
    assert NOT_MEMBERS == ("rafi", "rafi_linear")
    everything = ["rafi", "rafi_linear", "ridge_global", "dynamic", "grey_box"]
    assert ensemble_members(everything, floor=PLAIN_RIDGE) == [
        "ridge_global",
        "dynamic",
        "grey_box",
        PLAIN_RIDGE,
    ]
    assert ensemble_members([PLAIN_RIDGE, "dynamic"], floor=PLAIN_RIDGE) == [PLAIN_RIDGE, "dynamic"]
    assert ensemble_members(["rafi"], floor=PLAIN_RIDGE) == [PLAIN_RIDGE]  # one member: no blend


@settings(max_examples=200, deadline=None)
@given(
    arrays(np.float64, (7, 3), elements=st.one_of(st.floats(-50, 50), st.just(np.nan))),
    arrays(np.float64, 3, elements=st.floats(0.01, 5)),
)
def test_blend_is_the_weighted_mean_over_the_finite_members(p, w):
    oracle = np.ma.average(np.ma.masked_invalid(p), axis=1, weights=np.broadcast_to(w, p.shape))
    expected = oracle.filled(np.nan)
    np.testing.assert_allclose(blend(p, w), expected, rtol=1e-12, atol=1e-12, equal_nan=True)


# --------------------------------------------------------------------------- in a qualification


def test_the_ensemble_is_offered_and_ranked_first(offered):
    _, _, res = offered
    assert res["champion"] == ENSEMBLE and res["selection_basis"] == "cv"
    sel = res["selection"]
    assert sel["model"].iloc[0] == ENSEMBLE and sel["selection_rank"].iloc[0] == 1
    ens = res["models"][ENSEMBLE]
    # RAFI's kinds are fitted and scored as always, and not blended (NOT_MEMBERS)
    assert set(ens.weights_) == {"ridge_global", "dynamic", PLAIN_RIDGE}
    assert {"rafi_linear", *ens.weights_} <= set(res["summary"]["model"])
    assert sum(ens.weights_.values()) == pytest.approx(1.0)
    assert res["best_artefact"]["kind"] == ENSEMBLE and res["best_artefact"].get("interval")


def test_its_prediction_is_the_weighted_mean_of_its_members(offered):
    _, frame, res = offered
    ens = res["models"][ENSEMBLE]
    members = np.column_stack([res["models"][n].predict(frame) for n in ens.weights_])
    oracle = np.ma.average(
        np.ma.masked_invalid(members),
        axis=1,
        weights=np.broadcast_to(list(ens.weights_.values()), members.shape),
    )
    np.testing.assert_allclose(
        ens.predict(frame), oracle.filled(np.nan), rtol=1e-12, atol=1e-9, equal_nan=True
    )


def test_its_artefact_round_trips_and_refuses_an_edit(offered):
    _, frame, res = offered
    art = res["best_artefact"]
    again = load_any(art)
    np.testing.assert_allclose(
        again.predict(frame), res["models"][ENSEMBLE].predict(frame), rtol=0, atol=1e-12
    )
    assert again.to_dict()["members"].keys() == art["members"].keys()
    edited = {**art, "weights": {k: 1.0 / len(art["weights"]) for k in art["weights"]}}
    with pytest.raises(ValueError, match="model_id"):
        load_any(edited)


def test_its_cv_rows_are_those_of_refitted_members_blended(offered):
    table, frame, res = offered
    ens = res["models"][ENSEMBLE]
    cv = res["cv"]
    mine = cv.loc[(cv["model"] == ENSEMBLE) & (cv["scheme"] == "leave_one_run_out")]
    assert len(mine) == int((table["role"] == "training").sum())
    for _, (held,) in crossval.leave_one_run_out(table):
        fold = crossval.hold_out(table, [held])
        rows = frame.loc[frame["run_id"].astype(str) == str(held)]
        preds = [
            functools.partial(make_model, n, **SETTINGS, options=_options())().fit(fold, frame).predict(rows)
            for n in ens.weights_
        ]
        r = rows["dz_um"].to_numpy() - blend(np.column_stack(preds), list(ens.weights_.values()))
        got = float(mine.loc[mine["test_runs"].astype(str) == str(held), "max_abs_after_um"].iloc[0])
        assert got == pytest.approx(np.nanmax(np.abs(r)), rel=1e-9, abs=1e-9), held


def test_the_ensemble_is_offered_by_default():
    assert MACHINE_DEFAULTS["models"]["offer"] == ENSEMBLE
    table, frame = _data()
    res = run_family(table, frame, **SETTINGS, gates=GATES, options=_options(), log=lambda m: None)
    assert res["champion"] == ENSEMBLE


def test_best_offers_one_kind_and_builds_no_ensemble():
    table, frame = _data()
    res = run_family(
        table, frame, **SETTINGS, gates=GATES, options=_options(offer="best"), log=lambda m: None
    )
    assert res["champion"] in ENABLED and ENSEMBLE not in res["models"]
    assert ENSEMBLE not in set(res["cv"]["model"])


def test_fit_is_refused():
    with pytest.raises(TypeError, match="from_fitted"):
        WeightedEnsemble().fit(None, None)


def test_every_member_is_held_inside_two_training_spans_before_the_blend(offered):
    table, frame, res = offered
    # an ensemble that holds a member without its own cap (RAFI's linear kind; artefacts made
    # before NOT_MEMBERS hold one)
    weights = {**res["models"][ENSEMBLE].weights_, "rafi_linear": 0.2}
    ens = WeightedEnsemble.from_fitted(res["models"], weights, machine="synthetic")
    train = frame["run_id"].isin(table.loc[table["role"] == "training", "run_id"])
    lo, hi = frame.loc[train, "dz_um"].min(), frame.loc[train, "dz_um"].max()
    assert ens.envelope_["output_range"] == pytest.approx([lo, hi])
    far = frame.loc[train].copy()
    rises = [c for c in far.columns if c.startswith("dT")]
    far[rises] = far[rises] * 8.0  # the key sensors far beyond their training rises
    members = np.column_stack([res["models"][n].predict(far) for n in ens.weights_])
    pad = 2.0 * (hi - lo)
    assert (np.abs(members) > hi + pad).any(), "some member runs away there (the case under test)"
    expected = blend(np.clip(members, lo - pad, hi + pad), list(ens.weights_.values()))
    detail = ens.predict_detail(far)
    np.testing.assert_allclose(detail["predicted_um"], expected, rtol=1e-12, atol=1e-9)
    assert detail["outside_envelope"].to_numpy()[(members > hi + pad).any(axis=1)].all()
