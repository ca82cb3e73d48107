"""The model family (rafi.family): one interface, artefacts, dynamics recovery."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings

import numpy as np
import pandas as pd
import pytest

from rafi.artefact import compute_model_id
from rafi.family.base import finish_artefact
from rafi.family.compare import load_any, make_model, save_any
from rafi.family.dynamic import DynamicRidge
from rafi.family.features import (
    MAX_MISSING_FRACTION,
    first_order_recursion,
    lowpass_runs,
    reference_speed,
    sensors_left_out,
    speed_change_evidence,
    usable_sensors,
)
from rafi.family.grey_box import GreyBox
from rafi.family.published import PublishedRafi
from rafi.family.rafi_linear import RafiLinear
from rafi.family.ridge_global import RidgeGlobal
from rafi.family.temperature_ridge import TemperatureRidge
from rafi.settings import MACHINE_DEFAULTS
from rafi.twin.synthetic_runs import make_synthetic_runs

KEY = ["T1", "T2", "T3"]
SMALL_TERMS = ["1", "x1", "x2", "x3", "x1*x2", "x1^2"]


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # statsmodels VIF / conditioning warnings of fit_rafi
        yield


@pytest.fixture(scope="module")
def data():
    return make_synthetic_runs(seed=1, sample_s=120.0, n_sensors=4)


@pytest.fixture(scope="module")
def fitted(data):
    table, frame = data
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return {
            "rafi": PublishedRafi(key_sensors=KEY, terms=SMALL_TERMS).fit(table, frame),
            "rafi_linear": RafiLinear(key_sensors=KEY).fit(table, frame),
            "ridge_global": RidgeGlobal(alphas=[1e-4, 1e-2, 1.0]).fit(table, frame),
            "dynamic": DynamicRidge(taus_s=[0, 600, 2400], max_taus=2, alphas=[1e-4, 1e-2]).fit(table, frame),
            "grey_box": GreyBox(taus_s=[0, 600], speed_taus_s=[120, 600], alphas=[1e-4, 1e-2]).fit(
                table, frame
            ),
            "temperature_ridge": TemperatureRidge(taus_s=[0, 600, 2400], alphas=[1e-4, 1e-2]).fit(
                table, frame
            ),
        }


def _validation(table, frame):
    ids = table.loc[table["role"].str.startswith("validation"), "run_id"]
    return frame[frame["run_id"].isin(ids)]


# --------------------------------------------------------------------------- dynamics


def test_dynamic_recovers_the_lag_and_beats_static_models():
    # dz = sum_i g_i * lowpass(dT_i, 1800 s) + c (n^2 - n0^2); sensors respond in 300 / 500 s
    table, frame = make_synthetic_runs(
        seed=3, sample_s=60.0, n_sensors=2, sensor_taus_s=(300, 500), tau_lag_s=1800.0, noise_um=0.02
    )
    # the lag search alone: the heat input (the sensors' own driver here) would stand in for the lag
    dyn = DynamicRidge(taus_s=[0, 600, 1800, 4800], max_taus=1, heat_input=False).fit(table, frame)
    assert dyn.taus_ == [1800.0] and dyn.speed_taus_ == []
    assert not any(name.startswith("L") for name in dyn.feature_names_)
    val = _validation(table, frame)
    rmse = {}
    for name, m in {
        "dynamic": dyn,
        "ridge": RidgeGlobal().fit(table, frame),
        "rafi": PublishedRafi(key_sensors=["T1", "T2"], terms=["1", "x1", "x2", "x1*x2", "x1^2", "x2^2"]).fit(
            table, frame
        ),
    }.items():
        rmse[name] = float(np.sqrt(np.mean((val["dz_um"] - m.predict(val)) ** 2)))
    assert rmse["dynamic"] < 0.04  # noise is 0.02 um
    assert rmse["dynamic"] < 0.5 * rmse["ridge"]
    assert rmse["dynamic"] < 0.2 * rmse["rafi"]
    # the centrifugal coefficient (-0.02 um/krpm^2) is recovered
    c2 = dyn.coef_[dyn.feature_names_.index("n2_krpm2")]
    assert c2 == pytest.approx(-0.02, abs=0.003)


def _settled_lowpass(x: np.ndarray, sample_s: float, tau_s: float) -> np.ndarray:
    """The first-order low-pass ``y += (1 - exp(-dt/tau)) (x - y)`` from ``y[0] = x[0]``, by
    scipy's IIR filter (an oracle independent of :mod:`rafi.family.features`)."""
    from scipy.signal import lfilter

    if tau_s == 0:
        return x.copy()
    a = np.exp(-sample_s / tau_s)
    y, _ = lfilter([1 - a], [1, -a], x, zi=[a * x[0]])
    return y


def test_temperature_ridge_is_ols_on_the_rises_and_their_fixed_filters_and_nothing_else():
    import statsmodels.api as sm

    table, frame = make_synthetic_runs(seed=5, sample_s=60.0, n_sensors=3, noise_um=0.0)
    taus, sensors = [0.0, 900.0, 3600.0], ["T1", "T2", "T3"]
    blocks = []
    for _, run in frame.groupby("run_id", sort=False):
        cols = [_settled_lowpass(run[f"d{s}"].to_numpy(), 60.0, tau) for tau in taus for s in sensors]
        blocks.append(pd.DataFrame(np.column_stack(cols), index=run.index))
    x = pd.concat(blocks).loc[frame.index].to_numpy()
    truth = np.array([0.8, -0.3, 0.5, 1.5, 0.2, -0.7, -0.9, 0.4, 1.1])
    frame = frame.assign(dz_um=x @ truth + 0.01 * np.random.default_rng(0).standard_normal(len(frame)))
    model = TemperatureRidge(taus_s=taus, alphas=[1e-13]).fit(table, frame)
    # every filter at once, no speed input of any kind
    assert model.taus_ == taus and model.sensors_ == sensors
    assert model.feature_names_ == [f"d{s}@{tau:g}s" for tau in taus for s in sensors]
    d = model.to_dict()
    assert d["selected"]["speed_terms"] is False and d["selected"]["speed_gain"] is False
    assert "speed_taus_s" not in d["selected"]
    # the coefficients are statsmodels' OLS without a constant on the training rows
    train = frame["run_id"].isin(table.loc[table["role"] == "training", "run_id"]).to_numpy()
    ols = sm.OLS(frame["dz_um"].to_numpy()[train], x[train]).fit()
    np.testing.assert_allclose(model.coef_, ols.params, rtol=0, atol=1e-6)
    # the filters are collinear, so the function is recovered, not each coefficient (noise 0.01 um)
    assert float(np.sqrt(np.mean((x @ model.coef_ - x @ truth) ** 2))) < 0.005
    val = _validation(table, frame)
    assert float(np.sqrt(np.mean((val["dz_um"] - model.predict(val)) ** 2))) < 0.02


def test_temperature_ridge_is_a_kind_of_the_settings_the_report_and_the_controller():
    from rafi.contract import MODEL_KINDS
    from rafi.deploy.compensator import KINDS as CONTROLLER_KINDS
    from rafi.family.compare import KINDS as FAMILY_KINDS
    from rafi.family.selection import SIMPLICITY
    from rafi.report.deployed_section import KIND_CLASSES

    assert "temperature_ridge" in MODEL_KINDS and tuple(CONTROLLER_KINDS) == (*MODEL_KINDS, "ensemble")
    assert set(FAMILY_KINDS) == set(MODEL_KINDS) == set(SIMPLICITY) == set(KIND_CLASSES)
    options = dict(MACHINE_DEFAULTS["models"], temperature_ridge_taus_s=[0, 1200])
    model = make_model(
        "temperature_ridge",
        key_sensors=KEY,
        terms=SMALL_TERMS,
        reference={"rule": "run_start", "window_s": 300},
        machine="m",
        options=options,
    )
    assert isinstance(model, TemperatureRidge) and model.taus_s == [0, 1200]
    # off by default: a user asks for it in models.enabled
    assert "temperature_ridge" not in MACHINE_DEFAULTS["models"]["enabled"]


def _shaft_data():
    """Runs whose displacement has a 4 um shaft part no sensor sees, L_300((n/1e4)^(5/3))."""
    return make_synthetic_runs(
        seed=3,
        sample_s=60.0,
        n_sensors=2,
        sensor_taus_s=(300, 500),
        tau_lag_s=1800.0,
        noise_um=0.02,
        shaft_um=4.0,
        shaft_tau_s=300.0,
    )


def test_grey_box_recovers_rise_lag_speed_power_filter_and_centrifugal_term():
    # dz = sum_i g_i L_1800(dT_i) + 4 um * L_300((n/1e4)^(5/3)) (an unmeasured fast part: no
    # sensor sees it) - 0.02 um/krpm^2 (n^2 - n0^2); every run starts 120 s at rest
    table, frame = _shaft_data()
    # the truth's filter constants as the grids (every filter enters at once): CV keeps the
    # heat-input block and the draw-in term, and the fit recovers their coefficients
    gb = GreyBox(
        taus_s=[1800],
        speed_taus_s=[300],
        speed_powers=[5 / 3],
        cv_metric="max_abs",
        centrifugal_lags_s=[0, 20],
    ).fit(table, frame)
    assert gb.taus_ == [1800.0] and gb.speed_taus_ == [300.0]
    assert gb.instantaneous_  # runs start at rest: the n^2 jump is identifiable
    assert gb.centrifugal_lag_s_ == 0.0  # the truth has no draw-in lag
    coef = dict(zip(gb.feature_names_, gb.coef_))
    assert coef["L300s(n^1.667)"] == pytest.approx(4.0, rel=0.03)
    assert coef["n2_krpm2"] == pytest.approx(-0.02, abs=0.003)
    val = _validation(table, frame)
    rmse = {}
    for name, m in {
        "grey_box": gb,
        "dynamic": DynamicRidge(taus_s=[0, 600, 1800, 4800], max_taus=1, heat_input=False).fit(table, frame),
    }.items():
        rmse[name] = float(np.sqrt(np.mean((val["dz_um"] - m.predict(val)) ** 2)))
    assert rmse["grey_box"] < 0.05  # noise is 0.02 um
    assert rmse["grey_box"] < 0.25 * rmse["dynamic"]  # the sensor-only model cannot see the shaft


def test_dynamic_with_the_heat_input_history_sees_the_unmeasured_shaft():
    # the data of the grey_box test above: a 4 um shaft term no sensor sees, L_300((n/1e4)^(5/3))
    table, frame = _shaft_data()
    grid = {"taus_s": [0, 600, 1800, 4800], "max_taus": 1, "speed_taus_s": [60, 300, 1200, 3600]}
    with_heat = DynamicRidge(**grid, heat_input=True).fit(table, frame)
    without = DynamicRidge(**grid, heat_input=False).fit(table, frame)
    # every heat-input filter and power at once, after the rises and the speed terms
    heat = [f"L{t}s(n^{p:.4g})" for t in (60, 300, 1200, 3600) for p in (0, 1, 5 / 3, 2)]
    assert with_heat.feature_names_[-len(heat) :] == heat and with_heat.speed_taus_ == [
        60.0,
        300.0,
        1200.0,
        3600.0,
    ]
    assert without.speed_taus_ == [] and not set(heat) & set(without.feature_names_)
    val = _validation(table, frame)
    rmse = {
        name: float(np.sqrt(np.mean((val["dz_um"] - m.predict(val)) ** 2)))
        for name, m in {"with": with_heat, "without": without}.items()
    }
    assert rmse["with"] < 0.1  # noise is 0.02 um
    assert rmse["with"] < 0.25 * rmse["without"]
    # the artefact says so and gives the same model back; without, the artefact has no such keys
    art = with_heat.to_dict()
    assert (
        art["hyperparameters"]["heat_input"] is True
        and art["selected"]["speed_taus_s"] == with_heat.speed_taus_
    )
    again = load_any(json.loads(json.dumps(art)))
    np.testing.assert_array_equal(again.predict(val), with_heat.predict(val))
    plain = without.to_dict()
    assert "heat_input" not in plain["hyperparameters"] and "speed_taus_s" not in plain["selected"]
    assert load_any(plain).heat_input is False


def test_grey_box_recovers_the_draw_in_lag_and_fits_every_filter_at_once():
    # 5 s samples; the n^2 draw-in follows the speed with a 10 s lag (the twin's holder: 8 s)
    table, frame = make_synthetic_runs(
        seed=5,
        sample_s=5.0,
        duration_s=3600.0,
        n_sensors=2,
        sensor_taus_s=(300, 500),
        tau_lag_s=600.0,
        noise_um=0.02,
        shaft_um=2.0,
        shaft_tau_s=300.0,
        centrifugal_lag_s=10.0,
    )
    gb = GreyBox(
        taus_s=[0, 600], speed_taus_s=[120, 300, 1200], speed_powers=[5 / 3], centrifugal_lags_s=[0, 10, 60]
    ).fit(table, frame)
    assert gb.to_dict()["hyperparameters"]["filter_search"] == "all"
    assert gb.centrifugal_lag_s_ == 10.0
    assert gb.taus_ == [0.0, 600.0] and gb.speed_taus_ == [120.0, 300.0, 1200.0]
    assert "L10s(n2_krpm2)" in gb.feature_names_
    val = _validation(table, frame)
    assert float(np.sqrt(np.mean((val["dz_um"] - gb.predict(val)) ** 2))) < 0.05  # noise 0.02 um
    # the CV table records every candidate lag, and the artefact round trip keeps the choice
    assert {row["centrifugal_lag_s"] for row in gb.cv_table_} == {0.0, 10.0, 60.0}
    again = GreyBox.from_dict(gb.to_dict())
    assert again.centrifugal_lag_s_ == 10.0
    np.testing.assert_allclose(again.predict(val), gb.predict(val), rtol=0, atol=1e-12)


def test_grey_box_all_mode_may_leave_the_heat_input_terms_out():
    # no unmeasured part and runs referenced while spinning: the sensors explain dz, so CV is
    # free to drop the heat-input filters as a block
    table, _, spinning = _spinning(seed=6)
    gb = GreyBox(taus_s=[0], speed_taus_s=[300, 1200], alphas=[1e-6, 1e-3]).fit(table, spinning)
    scores = {(tuple(r["speed_taus_s"]), r["alpha"]): r["score_um"] for r in gb.cv_table_}
    assert {k[0] for k in scores} == {(), (300.0, 1200.0)}
    best = min(scores, key=scores.get)
    assert gb.speed_taus_ == list(best[0])


def test_grey_box_artefacts_keep_the_record_of_the_filter_search():
    # the subset search and the opt-ins were retired (issue 49); the artefact records the filter
    # search as before, so a grey_box's artefact and model id are unchanged
    table, _, spinning = _spinning(seed=6)
    gb = GreyBox(taus_s=[0], speed_taus_s=[300, 1200], alphas=[1e-6, 1e-3]).fit(table, spinning)
    art = json.loads(json.dumps(gb.to_dict()))
    hyper = art["hyperparameters"]
    assert (hyper["max_taus"], hyper["max_speed_taus"], hyper["filter_search"]) == (1, 2, "all")
    assert "heat_input" not in hyper and "slow_rises" not in hyper
    # an artefact made under the retired opt-ins still loads as the model it describes
    body = {k: v for k, v in art.items() if k not in ("schema", "created", "model_id")}
    body["hyperparameters"] = {**hyper, "heat_input": "always", "slow_rises": True}
    old = load_any(finish_artefact(body))
    np.testing.assert_array_equal(old.predict(spinning), gb.predict(spinning))


def test_grey_box_drops_the_unidentifiable_centrifugal_term():
    # cold-start runs referenced while already spinning (the first 120 s at rest cut off):
    # n - n0 is only jitter in training, so the instantaneous n^2 term is left out
    table, frame = make_synthetic_runs(
        seed=4, sample_s=60.0, n_sensors=2, noise_um=0.02, validation_speeds=(), multi=False
    )
    spinning = frame[frame["t_s"] >= 120.0].copy()
    spinning["speed_rpm"] += np.random.default_rng(0).normal(0, 2.0, len(spinning))
    gb = GreyBox(taus_s=[0], speed_taus_s=[300], alphas=[1e-3]).fit(table, spinning)
    assert not gb.instantaneous_ and "n2_krpm2" not in gb.feature_names_
    assert gb.to_dict()["selected"]["instantaneous_n2"] is False


def _spinning(seed=4):
    """Cold-start runs referenced while already spinning (rest cut off), speed jitter +-2 r/min."""
    table, frame = make_synthetic_runs(
        seed=seed, sample_s=60.0, n_sensors=2, noise_um=0.02, validation_speeds=(), multi=False
    )
    spinning = frame[frame["t_s"] >= 120.0].copy()
    spinning["t_s"] -= 120.0
    spinning["speed_rpm"] += np.random.default_rng(0).normal(0, 2.0, len(spinning))
    return table, frame, spinning


def test_speed_change_evidence_needs_a_step_from_the_reference_speed():
    table, frame, spinning = _spinning()
    n0 = reference_speed(frame, "run_start", 60.0)
    assert sorted(speed_change_evidence(frame, n0, 50.0, 60.0)) == sorted(table["run_id"])  # rest -> speed
    n0 = reference_speed(spinning, "run_start", 60.0)
    assert speed_change_evidence(spinning, n0, 50.0, 60.0) == []  # jitter only
    # n0 = 0 r/min for runs that never stand still (a log segment cut while spinning): no step
    assert speed_change_evidence(spinning, np.zeros(len(spinning)), 50.0, 60.0) == []


@pytest.mark.parametrize("cls", [RidgeGlobal, DynamicRidge])
def test_ridge_and_dynamic_drop_unidentifiable_speed_terms(cls):
    # issue 7 safety: speed terms fitted to jitter blew up (118-196 um) at the first speed change
    table, frame, spinning = _spinning()
    # the rule for the instantaneous speed terms alone (dynamic's heat-input history is a filtered
    # response to the speed, not a jump: test_dynamic_with_the_heat_input_history_sees_the_unmeasured_shaft)
    kw = {"taus_s": [0, 1200], "max_taus": 1, "heat_input": False} if cls is DynamicRidge else {}
    m = cls(**kw).fit(table, spinning)
    assert not m.speed_terms_ and "n_krpm" not in m.feature_names_ and "n2_krpm2" not in m.feature_names_
    assert m.to_dict()["selected"]["speed_terms"] is False
    back = load_any(m.to_dict())
    assert not back.speed_terms_
    steps = spinning[spinning["run_id"] == "train-3000"].copy()
    steps["speed_rpm"] = np.where(steps["t_s"] < 3600, 3000.0, 18000.0)  # a speed step
    np.testing.assert_allclose(back.predict(steps), m.predict(steps))
    jump = np.abs(np.diff(m.predict(steps)))
    assert jump.max() < 0.5  # no jump from the speed terms
    # with the rest kept, the terms are identified and used
    m2 = cls(**kw).fit(table, frame)
    assert m2.speed_terms_ and "n2_krpm2" in m2.feature_names_
    assert len(m2.identifying_runs_) == 6


def test_lowpass_zero_initial_state_is_a_cold_start():
    t = np.arange(0, 3000.0, 5.0)
    x = np.ones(len(t))
    y = lowpass_runs(x, t, np.zeros(len(t), dtype=int), [600.0], initial="zero")[:, 0]
    np.testing.assert_allclose(y, 1 - np.exp(-(t + 5.0) / 600.0), atol=1e-12)
    with pytest.raises(ValueError):
        lowpass_runs(x, t, np.zeros(len(t), dtype=int), [600.0], initial="warm")


def test_lowpass_is_causal_and_restarts_each_run():
    t = np.arange(0, 3000.0, 5.0)
    x = np.where(t >= 100, 1.0, 0.0)
    codes = np.zeros(len(t), dtype=int)
    y = lowpass_runs(x, t, codes, [0.0, 600.0])
    assert np.array_equal(y[:, 0], x)  # tau 0: pass-through
    expected = np.where(t >= 100, 1 - np.exp(-(t - 95) / 600.0), 0.0)  # ZOH step from the 100 s sample
    np.testing.assert_allclose(y[:, 1], np.where(t >= 100, expected, 0), atol=1e-2)
    # causal: changing the future does not change the past
    x2 = x.copy()
    x2[300:] = 5.0
    y2 = lowpass_runs(x2, t, codes, [600.0])
    assert np.array_equal(y2[:300, 0], y[:300, 1])
    # a second run starts settled on its own first sample (documented initial condition)
    codes2 = np.r_[np.zeros(300, int), np.ones(len(t) - 300, int)]
    y3 = lowpass_runs(x2, t, codes2, [600.0])
    assert y3[300, 0] == 5.0


def test_dynamic_prediction_does_not_depend_on_row_order(data, fitted):
    table, frame = data
    val = _validation(table, frame)
    shuffled = val.sample(frac=1.0, random_state=0)
    a = pd.Series(fitted["dynamic"].predict(val), index=val.index)
    b = pd.Series(fitted["dynamic"].predict(shuffled), index=shuffled.index)
    np.testing.assert_allclose(a.sort_index(), b.sort_index(), rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- interface and artefacts


@pytest.mark.parametrize(
    "kind", ["rafi", "rafi_linear", "ridge_global", "dynamic", "grey_box", "temperature_ridge"]
)
def test_round_trip_gives_identical_predictions(kind, data, fitted, tmp_path):
    table, frame = data
    model = fitted[kind]
    d = model.to_dict()
    assert d["schema"] == "rafi.model/1" and d["kind"] == kind
    assert d["model_id"] == compute_model_id(d)
    assert d["key_sensors"] and d["reference"]["rule"] == "run_start"
    path = tmp_path / "m.json"
    save_any(model, path)
    again = load_any(path)
    assert again.to_dict()["model_id"] == d["model_id"]
    val = _validation(table, frame)
    assert np.array_equal(model.predict(val), again.predict(val))
    da, db = model.predict_detail(val), again.predict_detail(val)
    for col in ("predicted_um", "outside_speed_range", "outside_temp_range"):
        assert col in da.columns
        assert np.array_equal(da[col].to_numpy(), db[col].to_numpy())
    assert da.index.equals(val.index)


def test_load_any_delegates_rafi_to_rafimodel(fitted):
    from rafi.method.model import RafiModel

    assert isinstance(load_any(fitted["rafi"].to_dict()), RafiModel)
    assert isinstance(load_any(json.loads(json.dumps(fitted["rafi_linear"].to_dict()))), RafiLinear)


def test_edited_artefact_is_rejected(fitted):
    for kind in ("rafi_linear", "ridge_global", "dynamic", "grey_box", "temperature_ridge"):
        d = fitted[kind].to_dict()
        d["coefficients" if "coefficients" in d else "terms"] = d.get("coefficients", ["1"])[:1] * 2
        with pytest.raises(ValueError):
            load_any(d)
    with pytest.raises(ValueError, match="unknown model kind"):
        load_any({"schema": "rafi.model/1", "kind": "nope"})


def test_fit_uses_training_runs_only(data, fitted):
    table, frame = data
    train = set(table.loc[table["role"] == "training", "run_id"])
    for kind, m in fitted.items():
        assert set(m.train_runs_) == train, kind
    # poison the validation runs: every fitted number stays the same
    poisoned = frame.copy()
    val = poisoned["run_id"].str.startswith("val")
    poisoned.loc[val, "dz_um"] = 1e6
    poisoned.loc[val, "dT1"] = -1e3
    settings = {
        "key_sensors": KEY,
        "terms": SMALL_TERMS,
        "reference": MACHINE_DEFAULTS["reference"],
        "machine": None,
    }
    for kind in ("ridge_global", "dynamic", "grey_box"):
        opts = {
            **MACHINE_DEFAULTS["models"],
            "ridge_alphas": [1e-4, 1e-2, 1.0],
            "dynamic_taus_s": [0, 600, 2400],
            "grey_box_taus_s": [0, 600],
            "grey_box_speed_taus_s": [120, 600],
        }
        a = make_model(kind, **settings, options=opts)
        b = make_model(kind, **settings, options=opts)
        a.fit(table, frame)
        b.fit(table, poisoned)
        assert a.alpha_ == b.alpha_ and a.taus_ == b.taus_
        assert np.array_equal(a.coef_, b.coef_)


def test_predict_needs_no_statsmodels(fitted, data, tmp_path):
    table, frame = data
    val = _validation(table, frame)
    val.to_csv(tmp_path / "val.csv", index=False)
    for kind, m in fitted.items():
        save_any(m, tmp_path / f"{kind}.json")
    code = (
        "import sys, pandas as pd\n"
        "from rafi.family.compare import load_any\n"
        f"f = pd.read_csv({str(tmp_path / 'val.csv')!r})\n"
        "for k in ('rafi', 'rafi_linear', 'ridge_global', 'dynamic', 'grey_box'):\n"
        f"    load_any({str(tmp_path)!r} + '/' + k + '.json').predict_detail(f)\n"
        "bad = [m for m in sys.modules if m.startswith(('statsmodels', 'sklearn'))]\n"
        "assert not bad, bad\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_usable_sensors_skip_constant_and_mostly_missing_ones_and_keep_a_short_dropout(data):
    table, frame = data
    f = frame.copy()
    f["dT3"] = 0.25
    full = RidgeGlobal(alphas=[1e-3]).fit(table, f)
    f.loc[f.index[:5], "dT4"] = np.nan  # a dropout of 5 samples: the rows go, not the sensor
    m = RidgeGlobal(alphas=[1e-3]).fit(table, f)
    assert m.sensors_ == ["T1", "T2", "T4"]
    assert set(m.regressor_ranges_) == {"T1", "T2", "T4"}
    assert np.isfinite(list(m.regressor_ranges_.values())).all()
    assert m.n_ == full.n_ - 5
    share = MAX_MISSING_FRACTION + 0.01  # more than the limit: the sensor goes
    f.loc[f.index[: int(np.ceil(share * len(f)))], "dT4"] = np.nan
    m = RidgeGlobal(alphas=[1e-3]).fit(table, f)
    assert m.sensors_ == ["T1", "T2"] and m.n_ == full.n_
    # the reasons, for the sensors of the data only (T5..T16 are not in it)
    f["dT2"] = np.nan
    reasons = sensors_left_out(f)
    assert set(reasons) == {"T2", "T3", "T4"} and reasons["T2"] == "no value" and reasons["T3"] == "constant"
    assert reasons["T4"] == f"missing on {100 * np.ceil(share * len(f)) / len(f):.1f} % of the rows"
    assert usable_sensors(f) == ["T1"]


@pytest.mark.parametrize("taus", [[5.0], [60.0, 2400.0], [1e-3, 300.0]])
def test_first_order_recursion_matches_the_sample_loop(taus):
    rng = np.random.default_rng(1)
    x = rng.normal(size=(5000, len(taus))).cumsum(axis=0)  # long enough for several blocks
    g = -np.expm1(-5.0 / np.asarray(taus))
    y0 = rng.normal(size=len(taus))
    want = np.empty_like(x)
    y = y0.copy()
    for k in range(len(x)):
        y = (1 - g) * y + g * x[k]
        want[k] = y
    got = first_order_recursion(x, 1 - g, g, y0)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.abs(want).max())


@pytest.mark.parametrize(
    "cls", [PublishedRafi, RafiLinear, RidgeGlobal, DynamicRidge, GreyBox, TemperatureRidge]
)
def test_constructor_only_stores_its_arguments(cls):
    """scikit-learn conventions: keyword arguments stored as given, defaults from rafi.settings,
    nothing fitted (no attribute ending in ``_``) before ``fit``."""
    kw = {"key_sensors": ("T1", "T2", "T3")} if cls in (PublishedRafi, RafiLinear) else {"alphas": (1e-3,)}
    m = cls(**kw)
    for name, value in kw.items():
        assert getattr(m, name) is value
    assert not [a for a in vars(m) if a.endswith("_")]
    assert m.reference is MACHINE_DEFAULTS["reference"]
    assert type(m)(**m.get_params()).get_params() == m.get_params()
    with pytest.raises(TypeError):
        cls(("T1", "T2", "T3"))  # keyword arguments only


@pytest.mark.parametrize(
    ("cls", "bad"),
    [
        (RidgeGlobal, {"speed_gain": "sometimes"}),
        (RidgeGlobal, {"cv_metric": "mae"}),
        (GreyBox, {"centrifugal_lags_s": [-5.0]}),
    ],
)
def test_hyperparameters_are_checked_by_fit(cls, bad, data):
    table, frame = data
    m = cls(**bad)  # the constructor checks nothing
    with pytest.raises(ValueError):
        m.fit(table, frame)


@pytest.mark.parametrize(
    ("kind", "heat_input", "speed_gain", "offered"),
    [
        (DynamicRidge, True, "cv", {False}),  # the heat input carries the speed dependence
        (DynamicRidge, False, "cv", {False, True}),
        (DynamicRidge, True, True, {True}),  # an explicit setting is kept
        (RidgeGlobal, None, "cv", {False, True}),  # ridge_global is unchanged
    ],
)
def test_speed_gain_cv_offers_dynamic_with_heat_input_no_gain(kind, heat_input, speed_gain, offered):
    table, frame = make_synthetic_runs(seed=3, sample_s=120.0, n_sensors=3, noise_um=0.05)
    kw = {"heat_input": heat_input} if heat_input is not None else {}
    m = kind(alphas=[1e-3, 1e-1], speed_gain=speed_gain, **kw).fit(table, frame)
    assert {bool(r["speed_gain"]) for r in m.cv_table_} == offered
    assert m.speed_gain_ in offered
    gain_columns = [n for n in m.feature_names_ if n.endswith("*n_krpm")]
    assert bool(gain_columns) == m.speed_gain_
