"""The prediction interval's calibration (rafi.family.intervals): quantiles, cells, change clock,
decorrelation, and the coverage on synthetic data with a known noise."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from rafi.family.crossval import cross_validate
from rafi.family.forward_folds import fold_unit, unit_run
from rafi.family.interval_rule import ChangeClock
from rafi.family.intervals import (
    calibrate,
    corrected_level,
    coverage_and_width,
    decorrelation_s,
    interval_columns,
    interval_of,
    set_interval,
    since_change_of_frame,
    unit_weights,
    weighted_quantile,
)
from rafi.family.published import PublishedRafi
from rafi.twin.synthetic_runs import make_runs

REFERENCE = {"rule": "run_start", "window_s": 60.0}


def _oof(residuals: dict, since=1e9, outside=False) -> pd.DataFrame:
    """OOF samples from ``{unit: residuals}`` (5 s apart)."""
    parts = []
    for unit, res in residuals.items():
        res = np.asarray(res, dtype=float)
        parts.append(
            pd.DataFrame(
                {
                    "model": "m",
                    "unit": unit,
                    "run_id": unit,
                    "t_s": 5.0 * np.arange(len(res)),
                    "residual_um": res,
                    "since_change_s": since,
                    "outside": outside,
                }
            )
        )
    return pd.concat(parts, ignore_index=True)


# --------------------------------------------------------------------------- quantiles


@pytest.mark.parametrize("level", [0.5, 0.8, 0.9, 0.95, 0.999, 1.0])
def test_weighted_quantile_with_equal_weights_is_numpys_inverted_cdf(level):
    values = np.random.default_rng(1).normal(size=237)
    got = weighted_quantile(values, np.ones(237), level)
    assert got == np.quantile(values, level, method="inverted_cdf")


@pytest.mark.parametrize("level", [0.6, 0.9, 0.97])
def test_run_weights_equal_the_quantile_of_runs_repeated_to_the_same_size(level):
    rng = np.random.default_rng(2)
    runs = {"a": rng.normal(size=3), "b": rng.normal(3, size=6), "c": rng.normal(-1, size=2)}
    units = np.concatenate([[k] * len(v) for k, v in runs.items()])
    values = np.concatenate(list(runs.values()))
    # the oracle: every run repeated to 6 samples (lcm of 3, 6, 2) counts as much as the others
    repeated = np.concatenate([np.repeat(v, 6 // len(v)) for v in runs.values()])
    expected = np.quantile(repeated, level, method="inverted_cdf")
    assert weighted_quantile(values, unit_weights(units), level) == expected
    assert np.allclose(pd.Series(unit_weights(units)).groupby(units).sum(), 1.0)


def test_corrected_level_never_narrows_and_reaches_the_leave_one_run_out_coverage():
    rng = np.random.default_rng(3)
    residuals = {f"r{k}": rng.normal(0, 1 + 0.3 * k, 200) for k in range(6)}
    oof = _oof(residuals)
    a, units = oof["residual_um"].abs().to_numpy(), oof["unit"].to_numpy()
    lam = corrected_level(a, units, 0.9)
    assert 0.9 <= lam <= 1.0
    # at lam every run held out is covered 90 % of the time on average (by the others' quantile)
    cover = []
    for u in residuals:
        h = weighted_quantile(a[units != u], unit_weights(units[units != u]), lam)
        cover.append(np.mean(a[units == u] <= h))
    assert np.mean(cover) >= 0.9
    assert corrected_level(a[units == "r0"], units[units == "r0"], 0.9) == 1.0  # one run: its max


def test_by_run_the_correction_of_a_run_held_out_twice_is_that_of_the_run_once():
    rng = np.random.default_rng(5)
    residuals = {f"r{k}": rng.normal(0, 1 + 0.4 * k, 150) for k in range(5)}
    once = _oof(residuals)
    a, units = once["residual_um"].abs().to_numpy(), once["unit"].to_numpy()
    # every run also held out by a forward fold, predicted identically: two units of one run
    twice_a = np.concatenate([a, a])
    twice_units = np.concatenate([units, [fold_unit(1, u) for u in units]])
    assert list(unit_run(twice_units)) == list(np.concatenate([units, units]))
    expected = corrected_level(a, units, 0.9)
    assert corrected_level(twice_a, twice_units, 0.9, groups=unit_run(twice_units)) == expected
    # unit by unit, each copy is covered by a quantile that holds its twin: too small a correction
    by_unit_level = corrected_level(twice_a, twice_units, 0.9)
    assert 0.9 <= by_unit_level < expected
    # calibrate leaves a run out with all its units, and says so
    oof = pd.concat([once, once.assign(unit=[fold_unit(1, u) for u in units])], ignore_index=True)
    kw = dict(level=0.9, transient_s=1800, tolerance_rpm=50, min_runs=3, scheme="leave_one_run_out+forward_2")
    by_run, by_unit = calibrate(oof, **kw), calibrate(oof, by_run=False, **kw)
    assert by_run["calibration"]["corrected_level"] == expected
    assert by_unit["calibration"]["corrected_level"] == by_unit_level
    assert by_run["calibration"]["left_out"] == "run" and "left_out" not in by_unit["calibration"]
    blocks = calibrate(once, **{**kw, "scheme": "time_blocks"})
    assert blocks["calibration"]["left_out"] == "time block"
    assert blocks["calibration"]["corrected_level"] == expected  # no forward unit: as before


def test_unit_run_strips_only_a_forward_fold_prefix():
    units = ["data#3", "f0:data#3", "f12:thermal_log_2026-10-14#7", "f:x", "ff1:y", "b2"]
    assert list(unit_run(units)) == ["data#3", "data#3", "thermal_log_2026-10-14#7", "f:x", "ff1:y", "b2"]


def test_cells_fall_back_to_the_pooled_width_and_outside_is_never_narrower():
    rng = np.random.default_rng(4)
    settled = _oof({f"s{k}": rng.normal(0, 1, 100) for k in range(4)})
    transient = _oof({f"s{k}": rng.normal(0, 3, 20) for k in range(2)}, since=10.0)  # 2 runs only
    outside = _oof({f"s{k}": rng.normal(0, 0.2, 50) for k in range(4)}, outside=True)
    oof = pd.concat([settled, transient, outside], ignore_index=True)
    block = calibrate(
        oof, level=0.9, transient_s=1800, tolerance_rpm=50, min_runs=3, scheme="leave_one_run_out"
    )
    cal = block["calibration"]
    assert cal["fallback"] == ["transient"]
    assert cal["cells"]["transient"] == {"n_runs": 2, "n_samples": 40}
    h = block["half_width_um"]
    assert h["transient"] == cal["pooled_half_width_um"]
    # outside had 4 runs of small residuals: its own quantile, raised to the widest in-range cell
    assert h["outside"] == max(h["settled"], h["transient"])
    a, u = settled["residual_um"].abs().to_numpy(), settled["unit"].to_numpy()
    assert h["settled"] == weighted_quantile(a, unit_weights(u), cal["corrected_level"])
    assert block["schema"] == "rafi.interval/1" and block["method"] == "split_conformal_by_run"
    assert (
        calibrate(
            oof.assign(residual_um=np.nan), level=0.9, transient_s=1, tolerance_rpm=50, min_runs=3, scheme="x"
        )
        is None
    )


def test_decorrelation_is_one_spacing_for_independent_and_the_block_length_for_blocky_exceedances():
    rng = np.random.default_rng(5)
    oof = _oof({f"r{k}": np.zeros(2000) for k in range(3)})
    iid = rng.random(len(oof)) < 0.1
    assert decorrelation_s(oof, iid) == 5.0
    blocky = np.repeat(rng.random(len(oof) // 20) < 0.1, 20)  # exceedances in bursts of 20 samples
    d = decorrelation_s(oof, blocky)
    assert 15 * 5.0 <= d <= 20 * 5.0
    assert decorrelation_s(oof, np.zeros(len(oof), bool)) == 5.0
    # no exceedance (a calibration at level 1): the residuals' own autocorrelation decides
    smooth = np.repeat(rng.normal(size=len(oof) // 40), 40)  # residuals constant over 40 samples
    assert 30 * 5.0 <= decorrelation_s(oof, np.zeros(len(oof), bool), smooth) <= 40 * 5.0


# --------------------------------------------------------------------------- change clock on a frame


def _whole_log_frame() -> pd.DataFrame:
    """Two logs: speed steps, a NaN speed, a long gap; runs of two reference groups per log."""
    rows = []
    for log in ("a", "b"):
        t = np.r_[np.arange(0, 3000, 10.0), np.arange(8000, 9000, 10.0)]  # gap of 5000 s
        speed = np.where(t < 1000, 3000.0, np.where(t < 2000, 3030.0, 6000.0))
        speed[(t >= 1500) & (t < 1600)] = np.nan
        run = np.where(t < 2000, f"{log}#1", f"{log}#2")
        for ti, s, r in zip(t, speed, run):
            rows.append({"log": log, "log_t_s": ti, "t_s": ti, "run_id": r, "speed_rpm": s, "segment": 0})
    frame = pd.DataFrame(rows)
    return frame.sample(frac=1.0, random_state=1).reset_index(drop=True)  # any row order


@pytest.mark.parametrize("rule", ["run_start", "log_start"])
def test_since_change_of_a_frame_is_the_change_clock_sample_by_sample(rule):
    frame = _whole_log_frame()
    got = since_change_of_frame(frame, rule=rule, window_s=60, restart_gap_s=3600, tolerance_rpm=50)
    # the oracle: a ChangeClock per log in time order, reset at the log's first sample, after the
    # 5000 s gap and (run_start) at the first sample of each run
    expected = pd.Series(np.nan, index=frame.index)
    for _, rows in frame.sort_values(["log", "log_t_s"]).groupby("log", sort=False):
        clock = ChangeClock.create(50)
        prev_t, prev_run = None, None
        for i, row in rows.iterrows():
            reset = prev_t is None or row["log_t_s"] - prev_t > 3600
            reset = reset or (rule == "run_start" and row["run_id"] != prev_run)
            expected[i] = clock.update(row["log_t_s"], row["speed_rpm"], reset=reset)
            prev_t, prev_run = row["log_t_s"], row["run_id"]
    np.testing.assert_array_equal(got, expected.to_numpy())
    assert got.max() > 0 and (got == 0).sum() >= 4


# --------------------------------------------------------------------------- coverage


def test_a_model_without_an_interval_gives_nan_bounds():
    syn = make_runs(duration_s=1800, seed=6)
    model = PublishedRafi(key_sensors=syn.key_sensors, terms=syn.terms, reference=REFERENCE, machine="m")
    model.fit(syn.runs_table, syn.runs_frame)
    assert interval_of(model) is None and interval_of(model.to_dict()) is None
    detail = model.predict_detail(syn.runs_frame)
    cols = interval_columns(model, syn.runs_frame, detail["predicted_um"], detail["outside_temp_range"])
    assert cols["lower_um"].isna().all() and cols["upper_um"].isna().all()
    assert all(
        math.isnan(v) for v in coverage_and_width(syn.runs_frame["dz_um"], cols["lower_um"], cols["upper_um"])
    )


def test_coverage_on_fresh_runs_with_known_noise_is_within_the_binomial_band():
    """12 training runs, AR(1) noise (sigma 1 um, rho 0.9) on a known RAFI polynomial: fit, calibrate
    on the leave-one-run-out residuals, then measure the coverage on 5 fresh validation runs.

    The band: the samples are not independent. An AR(1) process with lag-1 correlation rho has about
    ``N (1 - rho) / (1 + rho)`` independent samples; the exceedance indicator is less correlated
    than the noise, so this is a lower bound (a wider band). The coverage varies with the validation
    samples (binomial, n_val) and with the calibration samples that set the half-width (n_cal):
    ``level +- 3 sqrt(p (1 - p) (1 / n_val + 1 / n_cal))``.
    """
    rho, sigma, level = 0.9, 1.0, 0.9
    syn = make_runs(
        runs_per_speed=4, sigma=sigma, rho=rho, seed=7, validation_speeds=(3000, 4500, 6000, 7500, 9000)
    )
    table, frame = syn.runs_table, syn.runs_frame

    def factory():
        return PublishedRafi(key_sensors=syn.key_sensors, terms=syn.terms, reference=REFERENCE, machine="m")

    model = factory().fit(table, frame)
    oof = []
    cross_validate(factory, table, frame, "leave_one_run_out", name="rafi", oof=oof)
    block = calibrate(oof[0], level=level, transient_s=1800, tolerance_rpm=50, min_runs=3, scheme="loro")
    assert block["calibration"]["n_runs"] == 12 and "settled" not in block["calibration"]["fallback"]
    set_interval(model, block)
    val = frame.loc[frame["run_id"].str.startswith("val")]
    detail = model.predict_detail(val)
    cols = interval_columns(model, val, detail["predicted_um"], detail["outside_temp_range"])
    coverage, width = coverage_and_width(val["dz_um"], cols["lower_um"], cols["upper_um"])
    shrink = (1 - rho) / (1 + rho)
    n_val, n_cal = len(val) * shrink, len(oof[0]) * shrink
    band = 3 * math.sqrt(level * (1 - level) * (1 / n_val + 1 / n_cal))
    assert abs(coverage - level) <= band, (coverage, band)
    # the half-width is about the noise's 90 % quantile (1.645 sigma), not the model's error
    assert 1.3 * sigma <= width / 2 <= 2.2 * sigma
    assert 5.0 <= block["decorrelation_s"] <= 600.0
