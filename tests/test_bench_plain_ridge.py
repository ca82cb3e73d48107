"""benchmarks/bench_plain_ridge.py: the plain ridge on a project's own runs, on a generated
project whose displacement lies in the plain ridge's feature space (the truth is known)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from bench_loader import load_bench

bench = load_bench("bench_plain_ridge")
realdata = load_bench("bench_realdata")

STEP_S = 60.0
NOISE_UM = 0.01
BIAS_UM = 0.3


def _log(name: str, start: str, n_runs: int, roles: list[str], rng) -> tuple[pd.DataFrame, list[dict]]:
    run_s = 12_000.0
    t = np.arange(0.0, n_runs * run_s, STEP_S)
    k = np.arange(len(t))
    t1 = 20.0 + 3.0 * (1.0 - np.exp(-t / 3000.0)) + 0.4 * np.sin(t / 2500.0)
    t2 = 21.0 + 1.5 * np.sin(t / 4100.0 + 0.3) + 0.0001 * t
    t3 = np.full(len(t), 19.0)  # constant: not usable
    frame = pd.DataFrame(
        {
            "run_id": [f"{name}#{1 + int(i // (run_s / STEP_S))}" for i in k],
            "t_s": t % run_s,
            "time": pd.Timestamp(start) + pd.to_timedelta(t, unit="s"),
            "log": f"{name}.csv",
            "log_t_s": t,
            "T1": t1,
            "T2": t2,
            "T3": t3,
        }
    )
    rest = t < realdata.RIDGE_REST_S  # the log's reference (log_start), as bench_realdata takes it
    for name_ in ("T1", "T2", "T3"):
        frame[f"d{name_}"] = frame[name_] - frame.loc[rest, name_].mean()
    table = [
        {"run_id": f"{name}#{i + 1}", "role": role, "file": f"{name}.csv", "start_time": f"{start}+{i}"}
        for i, role in enumerate(roles)
    ]
    return frame, table


def _truth(frame: pd.DataFrame) -> np.ndarray:
    """A displacement inside the plain ridge's feature space: rises and filtered rises per log."""
    out = np.empty(len(frame))
    for rows in frame.groupby("log", sort=False).indices.values():
        part = frame.iloc[rows]
        t = part["log_t_s"].to_numpy()
        temps = part[["T1", "T2"]].to_numpy()
        rises = temps - temps[t < realdata.RIDGE_REST_S].mean(axis=0)
        slow = realdata.lowpass(rises, t, 3600.0)
        fast = realdata.lowpass(rises, t, 900.0)
        out[rows] = 1.5 * rises[:, 0] + 0.8 * fast[:, 1] - 0.5 * slow[:, 0]
    return out


def make_project(tmp_path, rng=None):
    """A project folder as the pipeline leaves it (what the bench reads); returns the result
    folder and the truth: validation samples, their noise and the offered model's residuals."""
    rng = np.random.default_rng(7) if rng is None else rng
    a, table_a = _log("a", "2026-01-01T00:00:00", 3, ["training", "training", "validation_single"], rng)
    b, table_b = _log("b", "2026-01-03T00:00:00", 2, ["training", "validation_multi"], rng)
    frame = pd.concat([b, a], ignore_index=True)  # not in log order: the bench sorts
    truth = _truth(frame)
    noise = rng.normal(0.0, NOISE_UM, len(frame))
    frame["dz_um"] = truth + noise
    runs = pd.DataFrame(table_a + table_b)
    res = tmp_path / "results" / "m1"
    (res / "comparison").mkdir(parents=True)
    frame.to_parquet(res / "runs.parquet")
    runs.to_csv(res / "runs.csv", index=False)
    pd.DataFrame({"model": ["ridge_global", "grey_box"], "champion": [False, True]}).to_csv(
        res / "comparison" / "summary.csv", index=False
    )
    valid = frame["run_id"].map(runs.set_index("run_id")["role"]).str.startswith("validation").to_numpy()
    part = frame.loc[valid, ["run_id", "t_s"]].assign(
        measured_um=frame.loc[valid, "dz_um"].to_numpy(), predicted_um=truth[valid] + BIAS_UM
    )
    both = pd.concat([part.assign(model="grey_box"), part.assign(model="ridge_global", predicted_um=0.0)])
    both.to_parquet(res / "comparison" / "residuals.parquet")
    return res, {"run_id": part["run_id"].to_numpy(), "residual": noise[valid] - BIAS_UM}


def test_the_plain_ridge_recovers_a_displacement_in_its_feature_space(tmp_path):
    res, _ = make_project(tmp_path)
    row = bench.machine_scores(res)
    assert row["n_sensors"] == 2  # T3 is constant in training
    assert row["n_validation_runs"] == 2
    # fitted on the training runs of both logs, scored on runs it never saw: the noise level
    assert row["scores"]["plain_ridge"]["mae_um"] < 3 * NOISE_UM


def test_the_offered_model_is_scored_on_its_own_validation_samples(tmp_path):
    res, truth = make_project(tmp_path)
    row = bench.machine_scores(res)
    expected = bench.run_scores(truth["run_id"], truth["residual"])
    assert row["offered_kind"] == "grey_box"
    for key in ("mae_um", "mean_max_um", "worst_max_um"):
        assert row["scores"]["offered"][key] == pytest.approx(expected[key], abs=1e-12)
    assert row["scores"]["offered"]["mae_um"] == pytest.approx(BIAS_UM, abs=3 * NOISE_UM)
    assert row["ratio_mae"] > 5


def test_a_machine_of_its_own_sensors_and_runs_referenced_at_their_start(tmp_path):
    """Sensors not named T1..T16, two runs a log each referenced at its own start (run_start): the
    features change from the same reference as the target, so a displacement inside their space
    is recovered (before, the bench read T1..T16 only and the rises from the log's start)."""
    rng = np.random.default_rng(3)
    step, run_s = 60.0, 4 * 3600.0  # blocks of the penalty's CV keep rows beside their 3 h guard
    frames, table = [], []
    days = (["training", "training"], ["training", "training"], ["training", "validation_single"])
    for day, roles in enumerate(days):
        t = np.arange(0.0, 2 * run_s, step)
        spindle = (
            22.0
            + day
            + 4.0 * (1.0 - np.exp(-t / 2000.0))
            - 2.0 * (t >= run_s) * (1.0 - np.exp(-(t - run_s) / 1500.0))
        )
        bed = 21.0 + 0.5 * day + 0.8 * np.sin(t / 3000.0)
        run = np.where(t < run_s, 1, 2)
        part = pd.DataFrame(
            {
                "run_id": [f"d{day}#{r}" for r in run],
                "t_s": t - (run - 1) * run_s,
                "time": pd.Timestamp(f"2026-02-0{day + 1}") + pd.to_timedelta(t, unit="s"),
                "log": f"d{day}.csv",
                "log_t_s": t,
                "spindle_front": spindle,
                "bed": bed,
            }
        )
        start = part.groupby("run_id")[["spindle_front", "bed"]].transform("first")
        part["dspindle_front"] = part["spindle_front"] - start["spindle_front"]
        part["dbed"] = part["bed"] - start["bed"]
        slow = realdata.lowpass(part[["spindle_front"]].to_numpy(), t, 3600.0)[:, 0] - start["spindle_front"]
        part["dz_um"] = 2.0 * part["dspindle_front"] - 1.2 * part["dbed"] + 0.7 * slow
        part["dz_um"] += rng.normal(0.0, NOISE_UM, len(part))
        frames.append(part)
        table += [
            {"run_id": f"d{day}#{i + 1}", "role": r, "file": f"d{day}.csv"} for i, r in enumerate(roles)
        ]
    frame = pd.concat(frames, ignore_index=True)
    pred, record = bench.plain_ridge_predictions(frame, pd.DataFrame(table))
    assert record["sensors"] == ["spindle_front", "bed"]
    valid = (pred["run_id"] == "d2#2").to_numpy()
    err = frame.loc[valid, "dz_um"].to_numpy() - pred.loc[valid, "predicted_um"].to_numpy()
    assert np.abs(err).mean() < 5 * NOISE_UM


def test_run_scores_by_hand():
    scores = bench.run_scores(np.array(["r1", "r1", "r2"]), np.array([1.0, -3.0, 2.0]))
    assert scores == {"mae_um": 2.0, "mean_max_um": 2.5, "worst_max_um": 3.0, "worst_run": "r1"}


def test_the_filters_restart_at_every_log_and_the_logs_do_not_share_a_block_guard(tmp_path):
    res, _ = make_project(tmp_path)
    frame = bench.in_log_order(pd.read_parquet(res / "runs.parquet"))
    assert frame["log"].iloc[0] == "a.csv"  # the earlier log first, whatever the file order
    x = bench.plain_features(frame, ["T1", "T2"])
    alone = frame[frame["log"] == "b.csv"].reset_index(drop=True)
    assert np.array_equal(x[frame["log"].to_numpy() == "b.csv"], bench.plain_features(alone, ["T1", "T2"]))
    t = bench.end_to_end_time(frame)
    a_end = t[frame["log"].to_numpy() == "a.csv"].max()
    b_start = t[frame["log"].to_numpy() == "b.csv"].min()
    assert b_start - a_end == pytest.approx(2 * realdata.RIDGE_GAP_S)


def test_on_one_log_the_features_are_bench_realdatas(tmp_path):
    res, _ = make_project(tmp_path)
    frame = bench.in_log_order(pd.read_parquet(res / "runs.parquet"))
    one = frame[frame["log"] == "a.csv"].reset_index(drop=True)
    expected = realdata.ridge_features(one[["T1", "T2"]].to_numpy(), one["log_t_s"].to_numpy())
    assert np.allclose(bench.plain_features(one, ["T1", "T2"]), expected, atol=1e-12)


def test_a_missing_temperature_holds_its_last_value(tmp_path):
    res, _ = make_project(tmp_path)
    frame = pd.read_parquet(res / "runs.parquet")
    gap = (frame["log"] == "a.csv") & frame["log_t_s"].between(5000, 6000)
    frame.loc[gap, "T2"] = np.nan
    frame.to_parquet(res / "runs.parquet")
    ordered = bench.in_log_order(frame)
    x = bench.plain_features(ordered, ["T1", "T2"])
    assert np.isfinite(x).all()
    held = ordered.index[(ordered["log"] == "a.csv") & ordered["log_t_s"].between(5000, 6000)]
    assert np.all(x[held, 1] == x[held[0] - 1, 1])  # the rise of T2 stays at its last value
    assert bench.machine_scores(res)["scores"]["plain_ridge"]["mae_um"] < 0.5


def test_main_writes_the_table(tmp_path, capsys):
    make_project(tmp_path)
    assert bench.main(["--project", str(tmp_path), "--out", str(tmp_path / "out")]) == 0
    text = (tmp_path / "out.md").read_text(encoding="utf-8")
    assert "| m1 |" in text and "(grey_box)" in text
    assert "| m1 |" in capsys.readouterr().out


def test_a_project_that_has_not_run_is_named(tmp_path, capsys):
    assert bench.main(["--project", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path) in err and "snakemake --cores 2" in err
    assert not (tmp_path / "out.md").exists()
