"""Per-speed OLS fits with diagnostics (rafi.method.fit)."""

import numpy as np
import pytest
from statsmodels.regression.linear_model import OLS

from rafi.method.fit import (
    COEFFICIENT_COLUMNS,
    DIAGNOSTIC_COLUMNS,
    PAPER_RMSE_UM,
    VIF_COLUMNS,
    fit_rafi,
    fit_speed,
    paper_value,
    speed_rows,
    speed_samples,
    training_files,
)
from rafi.method.model import RafiModel, design_matrix, parse_terms
from rafi.twin.synthetic_runs import KEY, TERMS, make_runs

REF = {"rule": "run_start", "window_s": 60}


def fit(syn, **kw):
    kw.setdefault("hac_maxlags", 60)
    return fit_rafi(
        syn.runs_table,
        syn.runs_frame,
        key_sensors=list(KEY),
        terms=TERMS,
        reference=REF,
        machine="synthetic",
        **kw,
    )


@pytest.fixture(scope="module")
def white():
    syn = make_runs((3000, 7000, 9000), sigma=0.01, seed=1, duration_s=3600)
    return syn, fit(syn)


@pytest.fixture(scope="module")
def ar1():
    syn = make_runs((3000, 6000), sigma=0.05, rho=0.95, seed=1, duration_s=3600)
    return syn, fit(syn)


# ---------------------------------------------------------------- golden values


def golden_data():
    i = np.arange(40.0)
    x1 = np.linspace(0, 5, 40)
    x2 = 0.5 * x1 + np.sin(i)
    y = 1 + 2 * x1 - 0.5 * x2 + 0.1 * x1 * x2 + 0.05 * np.cos(3 * i)
    return y, np.c_[x1, x2]


def test_golden_small_deterministic_fit():
    # Golden numbers from numpy.linalg.lstsq and closed-form formulas (independent of statsmodels).
    y, x = golden_data()
    out = fit_speed(y, x, ["1", "x1", "x2", "x1*x2"], hac_maxlags=3)
    np.testing.assert_allclose(
        out["coef"], [1.003802790714419, 1.999465821250816, -0.502222769713059, 0.10012157163637], rtol=1e-10
    )
    np.testing.assert_allclose(
        out["se"], [0.014622405275878, 0.007478272799604, 0.013694602405599, 0.004116641800377], rtol=1e-10
    )
    d = out["diagnostics"]
    assert d["rmse_um"] == pytest.approx(0.033932158521353624, rel=1e-10)
    assert d["r2"] == pytest.approx(0.9998708337375576, rel=1e-12)
    assert d["durbin_watson"] == pytest.approx(3.825276566188576, rel=1e-10)
    assert d["n"] == 40


def newey_west_se(x, u, groups, lags):
    """Independent Newey-West (Bartlett) per group, small-sample factor n/(n-k)."""
    n, k = x.shape
    s = np.zeros((k, k))
    for g in np.unique(groups):
        xu = x[groups == g] * u[groups == g][:, None]
        s += xu.T @ xu
        for lag in range(1, lags + 1):
            w = 1 - lag / (lags + 1)
            gam = xu[lag:].T @ xu[:-lag]
            s += w * (gam + gam.T)
    bread = np.linalg.inv(x.T @ x)
    return np.sqrt(np.diag(bread @ s @ bread) * n / (n - k))


def test_hac_lags_never_cross_runs():
    rng = np.random.default_rng(3)
    n = 300
    x = np.c_[np.cumsum(rng.normal(size=n)), np.cumsum(rng.normal(size=n))]
    e = np.zeros(n)
    for t in range(1, n):
        e[t] = 0.8 * e[t - 1] + rng.normal()
    y = 1 + x @ [0.5, -0.2] + e
    groups = np.repeat([0, 1], [120, 180])
    terms = ["1", "x1", "x2"]
    out = fit_speed(y, x, terms, groups=groups, hac_maxlags=10)
    design = design_matrix(x, parse_terms(terms, 2))
    np.testing.assert_allclose(out["se_hac"], newey_west_se(design, out["resid"], groups, 10), rtol=1e-8)
    # one run: the same as statsmodels' plain HAC with the small-sample correction
    one = fit_speed(y, x, terms, hac_maxlags=10)
    ref = OLS(y, design).fit(cov_type="HAC", cov_kwds={"maxlags": 10, "use_correction": True})
    np.testing.assert_allclose(one["se_hac"], ref.bse, rtol=1e-10)
    # p_hac: t distribution with the OLS residual degrees of freedom
    from scipy import stats

    t_hac = out["coef"] / out["se_hac"]
    np.testing.assert_allclose(out["p_hac"], 2 * stats.t.sf(np.abs(t_hac), n - 3), rtol=1e-8)
    # lags are clamped to the shortest run
    short = fit_speed(y, x, terms, groups=np.repeat([0, 1], [5, 295]), hac_maxlags=60)
    assert short["diagnostics"]["hac_maxlags_used"] == 4


# ---------------------------------------------------------------- synthetic truth


def test_recovers_known_coefficients(white):
    syn, res = white
    for speed, truth in syn.truth.items():
        est = res.coefficients[res.coefficients["speed_rpm"] == speed]
        assert list(est["term"]) == TERMS
        z = (est["coef"].to_numpy() - truth) / est["se"].to_numpy()
        assert np.all(np.abs(z) < 5), (speed, z)
        np.testing.assert_allclose(est["coef"], truth, atol=0.2)


def test_fitted_model_reproduces_truth_function(white):
    syn, res = white
    f = syn.runs_frame
    pred = res.model.predict(f)
    noise_free = f["dz_um"].to_numpy() - pred
    assert np.sqrt(np.mean(noise_free**2)) < 0.0105  # noise sigma 0.01 um


def test_table_layouts_and_sane_diagnostics(white):
    _, res = white
    assert list(res.coefficients.columns) == COEFFICIENT_COLUMNS
    assert list(res.diagnostics.columns) == DIAGNOSTIC_COLUMNS
    assert list(res.vif.columns) == VIF_COLUMNS
    d = res.diagnostics.set_index("speed_rpm")
    assert list(d.index) == [3000, 7000, 9000]
    assert (d["r2"] > 0.999).all() and (d["r2_adj"] <= d["r2"]).all()
    assert (d["rmse_um"].between(0.008, 0.012)).all()
    assert (d["durbin_watson"].between(1.7, 2.3)).all()  # white noise
    assert (d["n"] == 720).all()
    assert d.loc[3000, "paper_rmse_um"] == pytest.approx(0.639065688265986)
    assert d.loc[9000, "paper_rmse_um"] == pytest.approx(0.277440897959544)
    assert np.isnan(d.loc[7000, "paper_rmse_um"])
    assert (d["bp_p"].between(0, 1)).all() and (d["jb_p"].between(0, 1)).all()
    assert (d["condition_number"] > 1).all()
    assert set(res.vif["term"]) == set(TERMS) - {"1"}
    assert (res.vif["vif"] >= 1).all()
    np.testing.assert_allclose(res.vif.groupby("speed_rpm")["vif"].max().to_numpy(), d["max_vif"].to_numpy())
    c = res.coefficients
    np.testing.assert_allclose(c["t"], c["coef"] / c["se"])
    assert c[["p", "p_hac"]].stack().between(0, 1).all()


def test_rmse_is_paper_definition(white):
    syn, res = white
    f = syn.runs_frame[syn.runs_frame["run_id"] == "train-7000-1"]
    resid = f["dz_um"].to_numpy() - res.model.predict(f)
    got = res.diagnostics.set_index("speed_rpm").loc[7000, "rmse_um"]
    assert got == pytest.approx(np.sqrt(np.mean(resid**2)), rel=1e-9)


def test_autocorrelated_noise_low_dw_and_larger_hac_se(ar1):
    _, res = ar1
    assert (res.diagnostics["durbin_watson"] < 1.0).all()
    ratio = res.coefficients["se_hac"] / res.coefficients["se"]
    assert ratio.median() > 2 and (ratio > 1).mean() > 0.9


def test_model_attributes(white):
    syn, res = white
    m = res.model
    assert isinstance(m, RafiModel)
    np.testing.assert_array_equal(m.speeds_rpm_, [3000, 7000, 9000])
    assert m.train_runs_[0] == ["train-3000-1"]
    assert m.reference == REF and m.machine == "synthetic"
    f = syn.runs_frame[syn.runs_frame["run_id"] == "train-9000-1"]
    np.testing.assert_allclose(m.regressor_ranges_[2, 1], [f["dT8"].min(), f["dT8"].max()])
    assert m.data["train-3000-1.csv"] == syn.runs_table.loc[0, "sha256"]
    np.testing.assert_allclose(m.rmse_um_, res.diagnostics["rmse_um"])


def test_several_runs_per_speed_and_missing_samples():
    syn = make_runs((3000,), runs_per_speed=2, sigma=0.05, rho=0.9, seed=4, duration_s=1800)
    frame = syn.runs_frame.copy()
    frame.loc[frame.index[10:20], "dT6"] = np.nan
    frame.loc[frame.index[30], "dz_um"] = np.nan
    res = fit_rafi(
        syn.runs_table, frame, key_sensors=list(KEY), terms=TERMS, hac_maxlags=30, reference=REF, machine="m"
    )
    assert res.model.train_runs_[0] == ["train-3000-1", "train-3000-2"]
    assert list(res.diagnostics["n"]) == [2 * 360 - 11]


def test_errors():
    syn = make_runs((3000,), sigma=0.05, seed=1, duration_s=50)
    with pytest.raises(ValueError, match="x4"):
        fit_rafi(
            syn.runs_table,
            syn.runs_frame,
            key_sensors=list(KEY),
            terms=["1", "x4"],
            hac_maxlags=5,
            reference=REF,
            machine="m",
        )
    with pytest.raises(ValueError, match="3000 r/min.*more samples than terms"):
        fit_rafi(
            syn.runs_table,
            syn.runs_frame,
            key_sensors=list(KEY),
            terms=TERMS,
            hac_maxlags=5,
            reference=REF,
            machine="m",
        )
    with pytest.raises(ValueError, match="dT99"):
        fit_rafi(
            syn.runs_table,
            syn.runs_frame,
            key_sensors=["T99"],
            terms=["1", "x1"],
            hac_maxlags=5,
            reference=REF,
            machine="m",
        )


def test_coefficients_only_path_matches_the_full_fit_and_skips_statsmodels(white):
    syn, full = white
    quick = fit(syn, diagnostics=False)
    # same coefficients bit for bit (pinv(X) @ y, as statsmodels' OLS), same deployable model
    np.testing.assert_array_equal(quick.coefficients["coef"], full.coefficients["coef"])
    assert quick.model.to_dict()["speeds"] == full.model.to_dict()["speeds"]
    np.testing.assert_allclose(quick.diagnostics["rmse_um"], full.diagnostics["rmse_um"], rtol=1e-12)
    assert quick.coefficients["se_hac"].isna().all() and quick.vif.empty
    assert quick.diagnostics["r2"].isna().all()
    code = (
        "import sys; import rafi.family.compare as mf, rafi.family.crossval, rafi.method.validate; "
        "assert 'statsmodels' not in sys.modules and 'scipy.signal' not in sys.modules, sorted(sys.modules)"
    )
    import subprocess
    import sys

    subprocess.run([sys.executable, "-c", code], check=True)


# --------------------------------------------------------------------------- the steps of fit_rafi


def test_speed_samples_stack_runs_in_order_and_drop_incomplete_samples():
    syn = make_runs((3000,), runs_per_speed=2, sigma=0.05, seed=2, duration_s=600)
    frame = syn.runs_frame.copy()
    ids = ["train-3000-2", "train-3000-1"]  # the order of the runs table's group
    shuffled = frame.sample(frac=1.0, random_state=0)  # rows out of time order
    shuffled.loc[shuffled["t_s"] == 25.0, "dT8"] = np.nan  # one sample per run lost
    x, y, runs = speed_samples(shuffled, ids, ["dT6", "dT8"], 3000)
    n = len(frame) // 2 - 1
    np.testing.assert_array_equal(runs, np.repeat([0, 1], n))
    for k, rid in enumerate(ids):
        run = frame[(frame["run_id"] == rid) & (frame["t_s"] != 25.0)].sort_values("t_s")
        np.testing.assert_array_equal(x[runs == k], run[["dT6", "dT8"]].to_numpy())
        np.testing.assert_array_equal(y[runs == k], run["dz_um"].to_numpy())
    frame["dz_um"] = np.nan
    with pytest.raises(ValueError, match="no complete samples .* at 3000 r/min"):
        speed_samples(frame, ids, ["dT6"], 3000)


def test_training_files_of_constant_training_runs_only():
    syn = make_runs((3000, 6000), validation_speeds=(4500,), seed=1, duration_s=600)
    table = syn.runs_table.assign(
        file=["a.csv", None, "v.csv"], sha256=["h-a", "h-b", "h-v"], kind=["constant", "constant", "constant"]
    )
    assert training_files(table) == {"a.csv": "h-a"}
    table.loc[0, "sha256"] = None
    assert training_files(table) == {"a.csv": None}
    assert training_files(syn.runs_table.drop(columns=["sha256"])) == {}


def test_speed_rows_one_per_term_and_the_paper_rmse():
    fit = {
        "coef": np.array([1.0, 2.0]),
        "se": np.array([0.1, 0.2]),
        "se_hac": np.array([0.3, 0.4]),
        "t": np.array([10.0, 10.0]),
        "p": np.array([0.0, 0.0]),
        "p_hac": np.array([0.01, 0.02]),
        "vif": {"x1": 1.0},
        "diagnostics": {"n": 100, "rmse_um": 0.5},
    }
    coefs, diag, vifs = speed_rows(6000, ["1", "x1"], fit)
    assert [list(row) for row in coefs] == [COEFFICIENT_COLUMNS] * 2
    assert coefs[1]["se_hac"] == 0.4 and coefs[0]["term"] == "1"
    assert list(diag) == DIAGNOSTIC_COLUMNS and diag["n"] == 100 and np.isnan(diag["r2"])
    assert diag["paper_rmse_um"] == paper_value(6000, PAPER_RMSE_UM)
    assert vifs == [{"speed_rpm": 6000, "term": "x1", "vif": 1.0}]
