"""The pure parts of benchmarks/bench_realdata.py: the plain ridge reference, the test rows, the
mapping of the pipeline's residuals back to workbook rows and the machine's configuration."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from bench_loader import load_bench

from rafi.readers.input_spec import normalise_input_spec
from rafi.settings import machine_settings, validate_config

ROOT = Path(__file__).resolve().parents[1]


bench = load_bench("bench_realdata")

#: The workbook's time grid: 11 115 rows every 15 s.
T_S = np.arange(11_115) * 15.0


def test_test_and_training_rows_are_the_published_rows():
    test = bench.test_rows(T_S)
    assert test.sum() == 2141
    assert np.flatnonzero(test)[[0, -1]].tolist() == [6751, 8891]
    train = bench.training_rows(T_S)
    assert train.sum() == 6751 and not (train & test).any()


def test_lowpass_starts_at_the_first_value_and_reaches_63_percent_after_one_time_constant():
    x = np.zeros((1000, 2))
    x[0, 0] = 5.0  # the state starts at the first row: the filter decays from there
    x[10:, 1] = 1.0  # a unit step at t = 150 s
    y = bench.lowpass(x, np.arange(1000) * 15.0, 900.0)
    assert y[0, 0] == pytest.approx(5.0)
    assert y[60, 0] == pytest.approx(5.0 * np.exp(-1.0), rel=1e-9)  # 60 steps of 15 s = 900 s
    assert y[9, 1] == 0.0 and y[69, 1] == pytest.approx(1.0 - np.exp(-1.0), rel=1e-9)


def test_blocked_folds_cover_every_row_once_and_keep_the_gap():
    t = np.arange(3000) * 15.0
    folds = bench.blocked_folds(t, 5, 1800.0)
    held = np.concatenate([h for _, h in folds])
    assert np.array_equal(np.sort(held), np.arange(3000))
    for fit, block in folds:
        distance = np.minimum(np.abs(t[fit] - t[block[0]]), np.abs(t[fit] - t[block[-1]]))
        assert distance.min() > 1800.0 and not np.isin(fit, block).any()
        assert len(fit) >= 3000 - len(block) - 2 * 121


def _synthetic_log(seed: int = 3):
    """Temperatures that rise and fall with a speed schedule; a displacement that is a known
    combination of a rise and a 3600 s lag of another (what the ridge's features can express)."""
    rng = np.random.default_rng(seed)
    heat = ((T_S // 14_400) % 2 == 0).astype(float) * (T_S > 450)
    gains = rng.uniform(0.5, 3.0, 16)
    taus = rng.uniform(300, 600, 16)  # fast sensors: the 3600 s lag is in no rise
    temps = 25.0 + np.column_stack(
        [g * bench.lowpass(heat[:, None], T_S, tau)[:, 0] for g, tau in zip(gains, taus)]
    )
    temps += rng.normal(0, 0.01, temps.shape)
    rises = temps - temps[:20].mean(axis=0)
    truth = 0.3 + 4.0 * rises[:, 2] - 6.0 * bench.lowpass(rises[:, 7:8], T_S, 3600.0)[:, 0]
    return temps, truth


def test_plain_ridge_recovers_a_known_displacement():
    temps, truth = _synthetic_log()
    disp = truth + np.random.default_rng(4).normal(0, 0.05, len(truth))
    result = bench.plain_ridge(temps, disp, T_S)
    # noise of 0.05 um is a mean absolute error of 0.04 um; without the 3600 s filters it is 0.35
    assert result["test_mae_um"] < 0.06
    assert result["cv_rmse_um"] < 0.07 and not result["at_grid_edge"]


def test_plain_ridge_chooses_a_larger_penalty_for_noisier_data():
    temps, truth = _synthetic_log()
    rng = np.random.default_rng(5)
    quiet = bench.plain_ridge(temps, truth + rng.normal(0, 0.01, len(truth)), T_S)
    noisy = bench.plain_ridge(temps, truth + rng.normal(0, 5.0, len(truth)), T_S)
    assert noisy["alpha"] > quiet["alpha"]


def test_the_score_maps_residuals_to_workbook_rows_and_scores_only_test_rows():
    disp = np.sin(T_S / 20_000.0) * 10 + 0.25  # 0.25 um at t = 0: the probe's zero
    runs = pd.DataFrame({"run_id": ["log#9", "log#10"], "start_s": [101_265.0, 115_665.0]})
    parts = []
    for run_id, start, end in (("log#9", 101_265.0, 115_650.0), ("log#10", 115_665.0, 140_000.0)):
        rows = np.arange(int(start // 15), int(end // 15) + 1)
        measured = disp[rows] - bench.reference_um(disp, T_S)
        for model, error in (("exact", 0.0), ("off", 2.0)):
            parts.append(
                pd.DataFrame(
                    {
                        "run_id": run_id,
                        "t_s": T_S[rows] - start,
                        "measured_um": measured,
                        "predicted_um": measured - error,
                        "lower_um": measured - error - 1.0,
                        "upper_um": measured - error + 1.0,
                        "model": model,
                    }
                )
            )
    scored = bench.score_family(pd.concat(parts, ignore_index=True), runs, disp, T_S)
    assert scored["reference_um"] == pytest.approx(bench.reference_um(disp, T_S))
    assert scored["mae"]["exact"] == pytest.approx(0.0, abs=1e-12)
    assert scored["mae"]["off"] == pytest.approx(2.0)
    assert scored["rows"] == {"exact": 2141, "off": 2141} and scored["n_test"] == 2141
    assert scored["max_clean_diff_um"] == pytest.approx(0.0, abs=1e-12)
    # the interval +-1 um: the exact model's covers every test row, the one 2 um off none
    assert scored["coverage"] == {"exact": 1.0, "off": 0.0}
    assert scored["width_um"]["exact"] == pytest.approx(2.0) and scored["width_um"]["off"] == pytest.approx(
        2.0
    )


def test_a_residual_off_the_15_s_grid_is_refused():
    runs = pd.DataFrame({"run_id": ["a"], "start_s": [100.0]})
    residuals = pd.DataFrame({"run_id": ["a"], "t_s": [7.0]})
    with pytest.raises(ValueError, match="grid"):
        bench.log_rows(residuals, runs)


@pytest.mark.parametrize("config", bench.CONFIGS)
def test_the_machine_configuration_is_valid_settings(config):
    machine = bench.machine_name("ch3")
    settings = {"machines": {machine: bench.machine_config("ch3", config)}}
    validate_config(settings)
    merged = machine_settings(settings, machine)
    assert merged["reference"]["rule"] == "log_start"
    assert merged["training_speeds_rpm"] == [1250, 2500, 3750, 5000]
    spec = normalise_input_spec(merged["input"])
    assert spec["columns"]["disp_um"] == "ch3(um)" and spec["columns"]["T16"] == "t16(°C)"
    if config == "windows":
        assert merged["runs"]["idle_training"] is True and len(merged["runs"]["windows"]) == 2
    else:
        assert merged["runs"]["windows"] == [] or not merged["runs"]["windows"]
        assert (
            merged["runs"]["min_constant_s"] == 10800 and merged["runs"]["idle_training"] == "schedule"
        )  # the default
