"""rafi.method.equilibrium on first-order responses with a known time constant."""

from __future__ import annotations

import io

import numpy as np
import pandas as pd
import pytest

from rafi.method.equilibrium import (
    EQUILIBRIUM_COLUMNS,
    PAPER_T_EQ_S,
    equilibrium_table,
    equilibrium_time,
    paper_t_eq,
)
from rafi.method.runs import find_runs
from rafi.twin.synthetic_logs import first_order_run, schedule_log

H = 3600.0
EQ = dict(band_fraction=0.05, plateau_window_s=900.0, smooth_window_s=300.0)
RUNS = dict(
    speed_tolerance_rpm=50,
    idle_below_rpm=100,
    min_run_s=1800,
    min_constant_s=3600,
    overrides={},
    reference_rule="run_start",
    reference_window_s=60,
)


@pytest.mark.parametrize(
    "tau,duration,rise",
    [(1000.0, 4 * H, 12.0), (2000.0, 4 * H, 20.0), (3000.0, 7 * H, 25.0), (2000.0, 4 * H, -8.0)],
)
def test_equilibrium_time_recovers_first_order_time_constant(tau, duration, rise):
    t, dz = first_order_run(
        tau_s=tau, rise_um=rise, duration_s=duration, noise_um=0.1, offset_um=1.5, seed=int(tau)
    )
    res = equilibrium_time(t, dz, **EQ)
    expected = tau * np.log(1 / 0.05)  # = tau ln(rise / band)
    assert res.t_eq_s == pytest.approx(expected, rel=0.04)
    assert res.tau_s == pytest.approx(tau, rel=0.03)
    assert res.t_eq_tau_s == pytest.approx(expected, rel=0.03)
    assert res.t_eq_low_s <= res.t_eq_s <= res.t_eq_high_s
    assert res.rise_um == pytest.approx(rise, abs=0.5)  # start = median of the first 60 s
    assert res.plateau_um == pytest.approx(1.5 + rise, abs=0.1)


def test_band_fraction_moves_t_eq_as_ln():
    t, dz = first_order_run(tau_s=1500.0, rise_um=20.0, duration_s=5 * H, noise_um=0.02)
    for f in (0.02, 0.05, 0.1):
        res = equilibrium_time(t, dz, band_fraction=f, plateau_window_s=900, smooth_window_s=300)
        assert res.t_eq_s == pytest.approx(1500 * np.log(1 / f), rel=0.05), f


def test_equilibrium_time_rejects_bad_input():
    with pytest.raises(ValueError):
        equilibrium_time([0, 5], [0, 1])
    with pytest.raises(ValueError):
        equilibrium_time(np.arange(10.0), np.arange(9.0))


def test_paper_table_lookup():
    assert paper_t_eq(3000) == 10160 and paper_t_eq(18030) == 5560
    assert np.isnan(paper_t_eq(4500)) and np.isnan(paper_t_eq(float("nan")))
    assert PAPER_T_EQ_S[9000] == 6895


@pytest.fixture(scope="module")
def runs():
    a, _ = schedule_log([(3000, 4 * H)], seed=1)
    b, _ = schedule_log([(7000, 4 * H)], seed=2)
    c, _ = schedule_log([(4500, 3 * H)], seed=3)  # validation: not in the table
    d, _ = schedule_log([(3000, 4 * H), (0, H), (12000, 4 * H)], seed=4)
    return find_runs(
        {"a": a, "b": b, "c": c, "d.csv": d}, {}, training_speeds_rpm=[3000, 7000, 12000], **RUNS
    )


def test_equilibrium_table(runs):
    table, frame = runs
    eq = equilibrium_table(table, frame, **EQ)
    assert list(eq.columns) == list(EQUILIBRIUM_COLUMNS)
    assert eq["run_id"].tolist() == ["a", "b", "d#1", "d#3"]
    e = eq.set_index("run_id")
    assert e.loc["a", "paper_t_eq_s"] == 10160 and e.loc["d#1", "paper_t_eq_s"] == 10160
    assert e.loc["d#3", "paper_t_eq_s"] == 6615 and np.isnan(e.loc["b", "paper_t_eq_s"])
    # the synthetic displacement is first order with tau = 2400 s
    np.testing.assert_allclose(e.loc[["a", "b", "d#1"], "t_eq_s"], 2400 * np.log(20), rtol=0.05)
    np.testing.assert_allclose(e.loc[["a", "b", "d#1"], "tau_s"], 2400, rtol=0.05)
    assert e["method"].str.contains("5 % of the rise").all()
    assert (e["speed_rpm"] == [3000.0, 7000.0, 3000.0, 12000.0]).all()


def test_equilibrium_table_from_csv_round_trip(runs):
    table, frame = runs
    buf = io.StringIO()
    table.to_csv(buf, index=False)
    back = pd.read_csv(io.StringIO(buf.getvalue()))
    pd.testing.assert_frame_equal(equilibrium_table(back, frame, **EQ), equilibrium_table(table, frame, **EQ))


def test_equilibrium_table_ignores_nan_and_handles_empty_runs(runs):
    table, frame = runs
    holes = frame.copy()
    holes.loc[holes.index[100:160], "dz_um"] = np.nan
    eq = equilibrium_table(table, holes, **EQ)
    assert eq["t_eq_s"].notna().all()
    empty = equilibrium_table(table, frame[frame["run_id"] != "b"], **EQ).set_index("run_id")
    assert np.isnan(empty.loc["b", "t_eq_s"]) and "not computed" in empty.loc["b", "method"]
    none = equilibrium_table(table[table["role"] != "training"], frame, **EQ)
    assert len(none) == 0 and list(none.columns) == list(EQUILIBRIUM_COLUMNS)


def test_rest_before_start_does_not_shift_t_eq():
    """A run that starts with 180 s at rest: t_eq is counted from the spindle start."""
    tau, rest = 1500.0, 180.0
    t, dz = first_order_run(tau_s=tau, rise_um=15.0, duration_s=4 * H, noise_um=0.05, seed=3)
    t_rest = np.arange(0.0, rest, 5.0)
    t_all = np.concatenate([t_rest, t + rest])
    z_all = np.concatenate([np.full(len(t_rest), np.median(dz[t <= 60])), dz])
    base = equilibrium_time(t, dz, **EQ)
    res = equilibrium_time(t_all, z_all, start_s=rest, **EQ)
    assert res.t_eq_s == pytest.approx(base.t_eq_s, abs=10.0)
    assert res.tau_s == pytest.approx(tau, rel=0.05)
    # the table finds the spindle start from the speed
    frame = pd.DataFrame(
        {"run_id": "r", "t_s": t_all, "dz_um": z_all, "speed_rpm": np.where(t_all < rest, 0.0, 9000.0)}
    )
    table = pd.DataFrame({"run_id": ["r"], "role": ["training"], "speed_rpm": [9000.0]})
    eq = equilibrium_table(table, frame, **EQ)
    assert eq["t_eq_s"].iloc[0] == pytest.approx(base.t_eq_s, abs=10.0)
