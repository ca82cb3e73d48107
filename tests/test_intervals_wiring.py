"""The prediction interval in the artefacts, the validation tables and the gate (issue 26)."""

from __future__ import annotations

import functools
import math

import numpy as np
import pandas as pd
import pytest

from rafi.family.compare import load_any, make_model
from rafi.family.crossval import cross_validate
from rafi.family.interval_fit import calibrate_family, calibration_units, rafi_interval, stacked_oof
from rafi.family.intervals import interval_columns, interval_of
from rafi.method.model import RafiModel
from rafi.method.validate import RESIDUAL_COLUMNS, SUMMARY_COLUMNS, qualify, validate_runs
from rafi.settings import MACHINE_DEFAULTS
from rafi.twin.synthetic_runs import make_runs

OPTIONS = MACHINE_DEFAULTS["models"]
GATES = {"max_residual_um": 100.0, "min_improvement_pct": None, "never_worse_than_uncompensated": False}


@pytest.fixture(scope="module")
def syn():
    return make_runs(runs_per_speed=2, duration_s=3600, sigma=0.3, seed=11, validation_speeds=(4500, 7500))


def _settings(syn):
    return {
        "key_sensors": syn.key_sensors,
        "terms": syn.terms,
        "reference": MACHINE_DEFAULTS["reference"],
        "machine": "m",
        "options": OPTIONS,
        "hac_maxlags": MACHINE_DEFAULTS["fit"]["hac_maxlags"],
        "speed_tolerance_rpm": 50.0,
    }


def _fit_and_calibrate(syn) -> tuple[dict, dict]:
    """rafi_linear and ridge_global fitted with their intervals (the run_family path)."""
    models, oof = {}, []
    for kind in ("rafi_linear", "ridge_global"):

        def factory(kind=kind):
            return make_model(kind, **_settings(syn))

        models[kind] = factory().fit(syn.runs_table, syn.runs_frame)
        cross_validate(factory, syn.runs_table, syn.runs_frame, OPTIONS["cv"], name=kind, oof=oof)
    blocks = calibrate_family(
        models,
        stacked_oof(oof),
        options=OPTIONS,
        scheme=OPTIONS["cv"],
        tolerance_rpm=50.0,
        log=lambda m: None,
    )
    return models, blocks


@pytest.fixture(scope="module")
def calibrated(syn):
    return _fit_and_calibrate(syn)


@pytest.mark.parametrize("kind", ["rafi_linear", "ridge_global"])
def test_the_artefact_carries_the_interval_and_its_id_covers_it(calibrated, kind):
    models, blocks = calibrated
    d = models[kind].to_dict()
    assert d["interval"] == blocks[kind] and interval_of(d) == blocks[kind]
    assert d["interval"]["tolerance_rpm"] == 50.0 and d["interval"]["level"] == OPTIONS["interval_level"]
    again = load_any(d)
    assert interval_of(again) == blocks[kind] and again.to_dict()["model_id"] == d["model_id"]
    edited = {
        **d,
        "interval": {**d["interval"], "half_width_um": {"settled": 0, "transient": 0, "outside": 0}},
    }
    with pytest.raises(ValueError, match="model_id"):
        load_any(edited)


def test_validation_gives_bounds_coverage_and_width(syn, calibrated):
    model = calibrated[0]["ridge_global"]
    bounds = functools.partial(interval_columns, model)
    summary, residuals = validate_runs(model, syn.runs_table, syn.runs_frame, bounds=bounds)
    assert list(summary.columns) == SUMMARY_COLUMNS and list(residuals.columns) == RESIDUAL_COLUMNS
    block = model.to_dict()["interval"]
    h = block["half_width_um"]
    width = residuals["upper_um"] - residuals["lower_um"]
    # beyond the trained range the half-width grows with the excess (interval_rule.widening)
    frame = syn.runs_frame.assign(range_excess=model.predict_detail(syn.runs_frame)["range_excess"])
    excess = residuals.merge(frame[["run_id", "t_s", "range_excess"]], on=["run_id", "t_s"], how="left")
    stretch = 1 + block["excess_slope"] * excess["range_excess"].to_numpy()
    assert (excess["range_excess"] > 0).any() and (excess["range_excess"] == 0).any()  # both kinds of rows
    # the key sensors' and the speed's excess is the "outside" cell's; the components' may be in range
    beyond_keys = residuals["outside_temp_range"] | residuals["outside_speed_range"]
    assert (residuals.loc[beyond_keys, "interval_cell"] == "outside").all()
    np.testing.assert_allclose(width, 2 * residuals["interval_cell"].map(h) * stretch, rtol=0, atol=1e-12)
    np.testing.assert_allclose((residuals["upper_um"] + residuals["lower_um"]) / 2, residuals["predicted_um"])
    for run_id, rows in residuals.groupby("run_id"):
        inside = (rows["measured_um"] >= rows["lower_um"]) & (rows["measured_um"] <= rows["upper_um"])
        row = summary.set_index("run_id").loc[run_id]
        assert row["coverage"] == inside.mean() and row["interval_width_um"] == width[rows.index].median()
    assert set(residuals["interval_cell"]) <= {"settled", "transient", "outside"}


def test_an_artefact_without_the_block_loads_and_gives_nan(syn):
    model = make_model("ridge_global", **_settings(syn)).fit(syn.runs_table, syn.runs_frame)
    d = model.to_dict()  # as written before issue 26: no "interval"
    assert "interval" not in d
    loaded = load_any(d)
    bounds = functools.partial(interval_columns, loaded)
    summary, residuals = validate_runs(loaded, syn.runs_table, syn.runs_frame, bounds=bounds)
    assert residuals[["lower_um", "upper_um"]].isna().all().all() and (residuals["interval_cell"] == "").all()
    assert summary["coverage"].isna().all() and summary["interval_width_um"].isna().all()
    assert summary["max_abs_after_um"].notna().all()


def test_the_pipelines_rafi_model_gets_its_interval_from_rafis_own_cv(syn, tmp_path):
    from rafi.method.fit import fit_rafi
    from rafi.method.model import load_model, save_model

    result = fit_rafi(
        syn.runs_table,
        syn.runs_frame,
        key_sensors=syn.key_sensors,
        terms=syn.terms,
        hac_maxlags=MACHINE_DEFAULTS["fit"]["hac_maxlags"],
        reference=MACHINE_DEFAULTS["reference"],
        machine="m",
        speed_tolerance_rpm=50.0,
        diagnostics=False,
    )
    settings = _settings(syn)
    factory = functools.partial(make_model, "rafi", **settings)
    block = rafi_interval(
        result.model,
        factory,
        syn.runs_table,
        syn.runs_frame,
        options=OPTIONS,
        speed_tolerance_rpm=50.0,
        log=lambda m: None,
    )
    assert block["calibration"]["n_runs"] == 6 and block["calibration"]["scheme"] == OPTIONS["cv"]
    save_model(result.model, tmp_path / "model.json")
    loaded = load_model(tmp_path / "model.json")
    assert loaded.interval_ == block and loaded.to_dict()["model_id"] == result.model.to_dict()["model_id"]
    older = RafiModel.from_dict(
        {k: v for k, v in result.model.to_dict().items() if k not in ("interval", "model_id")}
    )
    assert older.interval_ is None and "interval" not in older.to_dict()


def test_the_min_coverage_gate():
    summary = pd.DataFrame(
        {
            "run_id": ["a", "b", "c"],
            "max_abs_after_um": [1.0, 1.0, 1.0],
            "max_abs_before_um": [2.0, 2.0, 2.0],
            "improvement_pct": [50.0, 50.0, 50.0],
            "coverage": [0.85, 0.79, math.nan],
        }
    )
    off = qualify(summary, GATES)
    assert "min_coverage" not in set(off["criterion"])
    on = qualify(summary, {**GATES, "min_coverage": 0.8})
    rows = on.loc[on["criterion"] == "min_coverage"].set_index("run_id")
    assert rows["passed"].to_dict() == {"a": True, "b": False, "c": False}  # no interval: fails
    assert (rows["limit"] == 0.8).all() and rows.loc["b", "measured"] == 0.79
    assert MACHINE_DEFAULTS["qualification"]["min_coverage"] is None


def test_calibration_units_leave_out_the_forward_units():
    oof = pd.DataFrame(
        {
            "unit": ["log#1", "f0:log#3", "f1:log#3", "log#3", "log#2@block1"],
            "residual_um": [1.0, 2.0, 3.0, 4.0, 5.0],
        }
    )
    samples, scheme = calibration_units(oof, "leave_one_run_out")
    assert list(samples["unit"]) == ["log#1", "log#3", "log#2@block1"] and scheme == "leave_one_run_out"
    assert calibration_units(oof.iloc[:0], "time_blocks")[1] == "time_blocks"


def test_an_interval_calibrated_before_the_component_excess_is_evaluated_as_it_was(syn, calibrated):
    """Since 2026-11-30 a ridge kind's range excess holds its component excess and the calibrated
    block says so; a block calibrated before (without the key) widens with the key sensors' and the
    speed's excess alone, in batch and in the streaming compensator."""
    import copy

    from rafi.deploy.compensator import Compensator
    from rafi.family.envelope import component_excess, component_reach, key_range_excess
    from rafi.family.features import rise_column
    from rafi.family.intervals import set_interval

    model = calibrated[0]["ridge_global"]
    block = interval_of(model)
    assert block["component_excess"] is True
    frame = syn.runs_frame
    new = model.predict_detail(frame)["range_excess"].to_numpy()
    before = copy.deepcopy(model)
    set_interval(before, {k: v for k, v in block.items() if k != "component_excess"})
    old = before.predict_detail(frame)["range_excess"].to_numpy()
    rises = frame[[rise_column(s) for s in model.sensors_]].to_numpy(dtype=float)
    ranges = np.array([model.regressor_ranges_[s] for s in model.sensors_])
    keys = key_range_excess(rises, frame["speed_rpm"].to_numpy(dtype=float), ranges, model.speed_range_rpm_)
    np.testing.assert_allclose(old, keys, rtol=0, atol=1e-12)
    reach = component_reach(model.envelope_, len(model.coef_), model.coef_)
    parts = component_excess(model._design_of(frame), reach)
    np.testing.assert_allclose(new, keys + parts, rtol=0, atol=1e-12)
    assert (parts > 0).any()
    # the compensator reads the artefact's block the same way
    assert Compensator.from_artefact(model.to_dict()).reach is not None
    assert Compensator.from_artefact(before.to_dict()).reach is None


def test_a_borrowed_interval_is_the_lenders_said_so_and_covered_by_the_id(syn):
    """``borrow_interval``: the borrower's artefact carries the lender's half-widths, its
    calibration names the lender, its id covers the block; nothing without a lender's block."""
    from rafi.family.interval_fit import borrow_interval

    models, blocks = _fit_and_calibrate(syn)  # its own: borrowing changes the models in place
    own_id = models["ridge_global"].to_dict()["model_id"]
    assert blocks["ridge_global"]["half_width_um"] != blocks["rafi_linear"]["half_width_um"]
    said = []
    block = borrow_interval(models, blocks, "ridge_global", "rafi_linear", log=said.append)
    d = models["ridge_global"].to_dict()
    assert d["interval"] == block == blocks["ridge_global"]
    assert block["half_width_um"] == blocks["rafi_linear"]["half_width_um"]
    assert block["calibration"]["borrowed_from"] == "rafi_linear"
    assert "borrowed_from" not in blocks["rafi_linear"]["calibration"]  # the lender's own is untouched
    assert d["model_id"] != own_id and said == [
        "interval of ridge_global: rafi_linear's (the same prior and runs), not its own CV's"
    ]
    assert borrow_interval(models, {**blocks, "dynamic": None}, "ridge_global", "dynamic") is None
    assert borrow_interval(models, blocks, "grey_box", "rafi_linear") is None
