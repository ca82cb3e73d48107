"""The shipped twin data reproduce the paper's numbers (docs/twin.md, calibration table).

Each file is read with the project's reader and given a minimal clean inside the test
(sort by time, drop duplicate times, open-circuit values / NaN / isolated spikes
interpolated), independent of the pipeline's cleaning step.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import statsmodels.api as sm

from rafi import SENSORS
from rafi.method.equilibrium import equilibrium_time
from rafi.readers.native import read_raw_log
from rafi.twin.calibration import quick_clean

ROOT = Path(__file__).resolve().parents[1]
RAW_A = ROOT / "raw" / "tapping-center-a"

PAPER_T_EQ_S = {3000: 10160, 6000: 9675, 9000: 6895, 12000: 6615, 15000: 5385, 18000: 5560}
TRAINING = sorted(PAPER_T_EQ_S)
VALIDATION = (4500, 8000, 10500, 13500, 16500)
KEY = ("T6", "T8", "T9")
COOLANT = ("T1", "T2", "T3", "T4", "T5", "T7", "T11", "T12", "T14", "T15")


def minimal_clean(path: Path) -> pd.DataFrame:
    """The twin's minimal cleaning (sort, de-duplicate, mask open-circuit values and isolated
    spikes, interpolate on the 5 s grid), not the pipeline's: these tests judge the data."""
    f = quick_clean(read_raw_log(path))
    assert f[[*SENSORS, "disp_um"]].notna().all().all()
    return f


def rises(f: pd.DataFrame) -> tuple[np.ndarray, pd.DataFrame]:
    first = f["t_s"] <= 60
    dz = (f["disp_um"] - f.loc[first, "disp_um"].median()).to_numpy()
    dT = f[list(SENSORS)] - f.loc[first, list(SENSORS)].median()
    return dz, dT


@pytest.fixture(scope="module")
def training():
    return {sp: minimal_clean(RAW_A / f"train_{sp:05d}rpm.csv") for sp in TRAINING}


def abs_r(dz, dT):
    return {s: abs(float(np.corrcoef(dT[s].to_numpy(), dz)[0, 1])) for s in SENSORS}


def rafi_rmse(dz, dT) -> float:
    x1, x2, x3 = (dT[s].to_numpy() for s in KEY)
    X = np.column_stack(
        [np.ones_like(x1), x1, x2, x3, x1 * x2, x1 * x3, x2 * x3, x1**2, x2**2, x3**2, x1 * x2 * x3]
    )
    res = sm.OLS(dz, X).fit()
    return float(np.sqrt(np.mean(res.resid**2)))


def spindle_start_s(f: pd.DataFrame) -> float:
    """Time of the first sample with the spindle turning (the logs start with a rest)."""
    return float(f.loc[f["speed_rpm"] >= 100, "t_s"].iloc[0])


def calibration_table(training) -> pd.DataFrame:
    rows = []
    for sp, f in training.items():
        dz, dT = rises(f)
        # reference = the cold machine at rest (first 60 s); t_eq counted from the spindle start
        eq = equilibrium_time(
            f["t_s"].to_numpy(),
            dz,
            band_fraction=0.05,
            plateau_window_s=900,
            smooth_window_s=300,
            start_s=spindle_start_s(f),
        )
        r = abs_r(dz, dT)
        rows.append(
            dict(
                speed_rpm=sp,
                rest_s=spindle_start_s(f),
                t_eq_s=eq.t_eq_s,
                paper_t_eq_s=PAPER_T_EQ_S[sp],
                peak_um=float(np.max(np.abs(dz))),
                r_T6=r["T6"],
                r_T8=r["T8"],
                r_T9=r["T9"],
                r_T16=r["T16"],
                max_r_coolant=max(r[s] for s in COOLANT),
                rmse_um=rafi_rmse(dz, dT),
            )
        )
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def table(training):
    return calibration_table(training)


def test_shipped_files_exist():
    names = {p.name for p in RAW_A.glob("*.csv")}
    expected = (
        {f"train_{sp:05d}rpm.csv" for sp in TRAINING}
        | {f"valid_{sp:05d}rpm.csv" for sp in VALIDATION}
        | {"multi_condition.csv"}
    )
    assert expected <= names


@pytest.mark.parametrize("speed", TRAINING)
def test_equilibrium_time_within_20_percent_of_table_1(table, speed):
    row = table.set_index("speed_rpm").loc[speed]
    assert abs(row.t_eq_s - row.paper_t_eq_s) <= 0.2 * row.paper_t_eq_s, row.to_dict()


def test_equilibrium_time_decreases_overall_with_speed(table):
    t = table.set_index("speed_rpm")["t_eq_s"]
    assert t[18000] < t[9000] < t[3000]
    assert t[15000] < t[6000]
    rho = pd.Series(t.to_numpy()).corr(pd.Series(t.index.to_numpy(dtype=float)), method="spearman")
    assert rho <= -0.8


def test_training_elongation_grows_with_speed(table):
    peak = table.set_index("speed_rpm")["peak_um"]
    assert peak.is_monotonic_increasing or peak.diff().dropna().min() > -1.0
    assert 10.0 <= peak[3000] <= 18.0 and 22.0 <= peak[18000] <= 33.0


@pytest.mark.parametrize(
    "speed,low,high",
    [(4500, 13.0, 20.0), (8000, 15.0, 30.0), (10500, 15.0, 30.0), (13500, 20.0, 28.0), (16500, 15.0, 30.0)],
)
def test_validation_peak_elongation_in_paper_range(speed, low, high):
    f = minimal_clean(RAW_A / f"valid_{speed:05d}rpm.csv")
    dz, _ = rises(f)
    assert low <= np.max(np.abs(dz)) <= high


@pytest.mark.parametrize(
    "stem",
    [f"train_{sp:05d}rpm" for sp in TRAINING]
    + [f"valid_{sp:05d}rpm" for sp in VALIDATION]
    + ["multi_condition"],
)
def test_every_log_starts_with_a_rest_at_0_rpm(stem):
    """The logger starts with the cold machine at rest; the spindle starts after 180 s."""
    f = minimal_clean(RAW_A / f"{stem}.csv")
    assert spindle_start_s(f) == 180.0
    assert (f.loc[f["t_s"] < 180.0, "speed_rpm"] == 0).all()


def test_multi_condition_run_steps_across_speeds():
    full = minimal_clean(RAW_A / "multi_condition.csv")
    f = full[full["t_s"] >= spindle_start_s(full)].reset_index(drop=True)  # the steps after the rest
    speed = f["speed_rpm"].round(-2)
    steps = speed[speed.diff().abs() > 100]
    assert len(steps) >= 6
    levels = set(speed.unique())
    assert levels & set(TRAINING) and levels & set(VALIDATION)
    seg = (speed.diff().abs() > 100).cumsum()
    durations = f.groupby(seg)["t_s"].agg(lambda s: s.iloc[-1] - s.iloc[0] + 5)
    assert durations.between(20 * 60, 45 * 60).all(), durations
    assert 4.4 * 3600 <= f["t_s"].iloc[-1] - f["t_s"].iloc[0] + 5 <= 4.6 * 3600
    dz, _ = rises(full)  # from the rest, as the pipeline
    assert 15.0 <= np.max(np.abs(dz)) <= 30.0


@pytest.mark.parametrize("speed", TRAINING)
def test_key_sensors_correlate_and_coolant_does_not(table, speed):
    row = table.set_index("speed_rpm").loc[speed]
    assert min(row.r_T6, row.r_T8, row.r_T9) >= 0.97, row.to_dict()
    assert row.max_r_coolant < 0.95, row.to_dict()
    assert row.max_r_coolant < min(row.r_T6, row.r_T8, row.r_T9) - 0.03


@pytest.mark.parametrize("speed", TRAINING)
def test_rafi_fit_rmse_like_table_3(table, speed):
    rmse = table.set_index("speed_rpm").loc[speed, "rmse_um"]
    assert 0.15 <= rmse <= 1.0


def test_runs_are_on_different_days_with_different_rooms():
    days = set()
    for path in sorted(RAW_A.glob("*.csv")):
        raw = read_raw_log(path)
        assert raw.attrs["metadata"]["machine"] == "tapping-center-a"
        assert raw.attrs["metadata"]["sample_period_s"] == 5.0
        assert "rafi simulate shipped" in raw.attrs["metadata"]["notes"]
        days.add(raw["time"].min().date())
    assert len(days) == 12


if __name__ == "__main__":  # print the calibration table (docs/twin.md)
    tab = calibration_table({sp: minimal_clean(RAW_A / f"train_{sp:05d}rpm.csv") for sp in TRAINING})
    pd.set_option("display.width", 200)
    print(tab.round(3).to_string(index=False))
    for sp in VALIDATION:
        dz, _ = rises(minimal_clean(RAW_A / f"valid_{sp:05d}rpm.csv"))
        print(f"valid {sp}: peak {np.max(np.abs(dz)):.2f} um")
    dz, _ = rises(minimal_clean(RAW_A / "multi_condition.csv"))
    print(f"multi_condition: peak {np.max(np.abs(dz)):.2f} um")
