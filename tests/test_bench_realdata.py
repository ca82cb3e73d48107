"""The pure parts of benchmarks/bench_realdata.py: the plain ridge reference, the test rows, the
mapping of the pipeline's residuals back to workbook rows and the machine's configuration."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import openpyxl
import pandas as pd
import pytest
import yaml
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


# --------------------------------------------------------------------------- every real log present

runs_mod = load_bench("_realdata_runs")
turning = load_bench("_realdata_turning")


def _scored(seed: int = 0) -> pd.DataFrame:
    """Two runs, two models: ``exact`` (predicts the target, a +-1 um interval), ``off`` (2 um
    low, no interval)."""
    rng = np.random.default_rng(seed)
    parts = []
    for run_id, n in (("a", 50), ("b", 30)):
        target = rng.normal(0, 5, n)
        parts.append(
            pd.DataFrame(
                {"run_id": run_id, "model": "exact", "target_um": target, "predicted_um": target}
                | {"lower_um": target - 1.0, "upper_um": target + 1.0}
            )
        )
        parts.append(
            pd.DataFrame({"run_id": run_id, "model": "off", "target_um": target, "predicted_um": target - 2})
        )
    return pd.concat(parts, ignore_index=True)


def test_per_run_scores_every_model_no_compensation_and_the_pooled_line():
    scored = _scored()
    table = runs_mod.per_run(scored).set_index(["run_id", "model"])
    assert list(table.index.get_level_values(0).unique()) == ["a", "b", "all"]
    assert table.loc[("a", "exact"), "mae_um"] == 0.0 and table.loc[("b", "off"), "max_um"] == pytest.approx(
        2.0
    )
    assert table.loc[("all", "exact"), "coverage"] == 1.0 and table.loc[("all", "exact"), "width_um"] == 2.0
    assert np.isnan(table.loc[("a", "off"), "coverage"])  # no interval: no coverage
    for run_id in ("a", "b"):
        target = scored.loc[(scored.run_id == run_id) & (scored.model == "off"), "target_um"].abs()
        assert table.loc[(run_id, "none"), "mae_um"] == pytest.approx(target.mean())
        assert table.loc[(run_id, "none"), "max_um"] == pytest.approx(target.max())
    assert table.loc[("all", "none"), "rows"] == 80


def test_per_run_interval_coverage_counts_the_rows_inside():
    scored = _scored()
    exact = scored["model"] == "exact"
    scored.loc[exact & (scored.run_id == "a"), "upper_um"] -= np.r_[np.full(10, 1.5), np.zeros(40)]
    table = runs_mod.per_run(scored).set_index(["run_id", "model"])
    assert table.loc[("a", "exact"), "coverage"] == pytest.approx(40 / 50)
    assert table.loc[("a", "exact"), "width_um"] == pytest.approx(2.0 - 15 / 50)
    assert table.loc[("all", "exact"), "coverage"] == pytest.approx(70 / 80)


def test_per_run_refuses_models_that_score_different_rows():
    scored = _scored().drop(index=[0])
    with pytest.raises(ValueError, match="run a: the models score different rows"):
        runs_mod.per_run(scored)


def test_the_per_run_tables_put_the_offered_model_first_and_no_compensation_last():
    table = runs_mod.per_run(_scored())
    lines = runs_mod.per_run_markdown(table, "off", {"my ridge": {"a": (1.5, 3.0)}})
    head = [c.strip() for c in lines[0].strip("|").split("|")]
    assert head == ["test run", "rows", "off (offered)", "exact", "my ridge", "no compensation"]
    row_a = [c.strip() for c in lines[2].strip("|").split("|")]
    assert row_a[:5] == ["a", "50", "2.00 / 2.00", "0.00 / 0.00", "1.50 / 3.00"]
    row_all = [c.strip() for c in lines[4].strip("|").split("|")]
    assert row_all[0] == "all" and row_all[4] == "- / -"  # the reference scored no pooled line
    cover = [ln for ln in lines if ln.startswith("| a |")][1]
    assert [c.strip() for c in cover.strip("|").split("|")] == ["a", "- / -", "100.0% / 2.00"]


def test_below_the_coverage_table_the_chance_a_perfect_interval_keeps_the_promise():
    # five runs whose mean coverage has a standard error of 0.05 (as in test_bench_foreign; the
    # chance is that of a perfect interval, so only the spread counts): 85-95 % is +-1.0 standard
    # error, Student's t with 4 degrees of freedom (tables: P(T <= 1.0) = 0.8130) gives 0.626;
    # 80-97 % gives 0.8248
    cov = 0.85 + np.array([-2, -1, 0, 1, 2]) * 0.05 * np.sqrt(5 / 2.5)
    table = pd.DataFrame(
        {
            "run_id": [*"abcde", "all", *"abcde"],
            "model": ["ens"] * 6 + ["ridge"] * 5,
            "rows": 10,
            "mae_um": 1.0,
            "max_um": 2.0,
            "coverage": [*cov, 0.9, *(cov * 0 + 0.5)],
            "width_um": 1.0,
        }
    )
    sentence = runs_mod.chance_sentence(table, "ens")
    assert "covers 70.9% to 99.1% of a test run's rows (spread 11.2 points over 5 runs)" in sentence
    assert "cover 85-95 % of the test rows with a chance of 0.63 (80-97 %: 0.82)" in sentence
    # runs that do not vary: a perfect interval would cover 90 % of each
    assert runs_mod.chance_sentence(table, "ridge").endswith("with a chance of 1.00 (80-97 %: 1.00).")
    assert runs_mod.chance_sentence(table.iloc[[0, 5]], "ens") is None  # one run: no spread to judge


def test_a_real_log_whose_data_is_absent_is_skipped(tmp_path):
    plan, skipped = bench.log_plan(list(bench.LOGS), tmp_path / "none.xlsx", None)
    assert plan == [] and len(skipped) == 3
    assert "fl-thermal: skipped, no workbook at" in skipped[0] and "--turning DIR" in skipped[1]
    assert skipped[2] == "spindle-78h: skipped, no --spindle FILE"
    (tmp_path / "ACE_X.xlsx").write_bytes(b"")  # one of the two: still absent
    plan, skipped = bench.log_plan(["turning-centre"], tmp_path / "none.xlsx", tmp_path)
    assert plan == [] and "no ACE_X.xlsx and ACE_Y.xlsx in" in skipped[0]
    (tmp_path / "ACE_Y.xlsx").write_bytes(b"")
    (tmp_path / "data.xlsx").write_bytes(b"")
    spindle = tmp_path / "log.csv"
    assert bench.log_plan(list(bench.LOGS), tmp_path / "data.xlsx", tmp_path, spindle)[1] == [
        f"spindle-78h: skipped, no file {spindle} (--spindle FILE)"
    ]
    spindle.write_bytes(b"")
    assert bench.log_plan(list(bench.LOGS), tmp_path / "data.xlsx", tmp_path, spindle) == (
        list(bench.LOGS),
        [],
    )


def test_without_any_real_log_the_bench_runs_nothing_and_succeeds(tmp_path, capsys):
    assert bench.main(["--data", str(tmp_path / "none.xlsx"), "--out-dir", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "no real log present: nothing run" in out and not (tmp_path / "out").exists()


def test_the_turning_centres_results_are_never_written_into_the_repository(tmp_path, capsys):
    for name in turning.FILES:
        (tmp_path / name).write_bytes(b"")
    assert bench.inside_repository(ROOT / "benchmarks" / "results") and not bench.inside_repository(tmp_path)
    for out_dir in ([], ["--out-dir", str(ROOT / "benchmarks" / "results")]):
        with pytest.raises(SystemExit):
            bench.parse_args(["--logs", "turning-centre", "--turning", str(tmp_path), *out_dir])
        assert "lies in the repository" in capsys.readouterr().err
    args = bench.parse_args(
        ["--logs", "turning-centre", "--turning", str(tmp_path), "--out-dir", str(tmp_path)]
    )
    assert args.plan == ["turning-centre"]


def write_turning(folder: Path, rows: int = 30, seed: int = 0) -> list[tuple]:
    """Generated workbooks of the turning centre's layout (its headers, 18 sheets ``Day 1`` ..),
    a displacement that is 2 um per degree of the third sensor's rise from the day's start plus
    an offset; days 13-18 run warmer (their temperatures beyond the training range). Returns
    ``(temperatures, displacement)`` per day."""
    rng = np.random.default_rng(seed)
    wx, wy = openpyxl.Workbook(), openpyxl.Workbook()
    wx.remove(wx.active)
    wy.remove(wy.active)
    truth = []
    for d in range(turning.DAYS):
        warm = 1.0 - np.exp(-np.arange(rows + d) / 10.0)
        gain = 8.0 if d >= turning.TRAIN_DAYS else 4.0 + 0.2 * d
        temps = 20.0 + np.outer(warm, np.linspace(1.0, gain, 6)) + rng.normal(0, 0.01, (rows + d, 6))
        disp = 40.0 + 2.0 * (temps[:, 2] - temps[0, 2])
        xs, ys = wx.create_sheet(f"Day {d + 1}"), wy.create_sheet(f"Day {d + 1}")
        xs.append(list(turning.TEMPERATURES))
        ys.append([turning.DISPLACEMENT])
        for k in range(rows + d):
            xs.append([float(v) for v in temps[k]])
            ys.append([float(disp[k])])
        truth.append((temps, disp))
    wx.save(folder / turning.FILES[0])
    wy.save(folder / turning.FILES[1])
    return truth


def test_the_turning_centres_configuration_is_read_by_the_projects_readers(tmp_path):
    from rafi.ops.init_preview import preview

    folder = tmp_path / "raw" / turning.MACHINE
    folder.mkdir(parents=True)
    truth = write_turning(folder)
    days = turning.read_days(folder)
    assert [d.name for d in days] == [f"Day {d}" for d in range(1, 19)]
    assert all(np.allclose(d.disp, t[1]) and np.allclose(d.temps, t[0]) for d, t in zip(days, truth))
    entry = turning.machine_config([d.name for d in days])
    entry["runs"].update(min_run_s=600, min_constant_s=600)  # the generated days are short
    settings = {"raw_dir": str(tmp_path / "raw"), "machines": {turning.MACHINE: entry}}
    validate_config(settings)
    config = tmp_path / "config.yaml"
    config.write_text(yaml.safe_dump(settings), encoding="utf-8")
    lines = preview(str(config), turning.MACHINE)
    roles = {ln.split()[0] + " " + ln.split()[1]: ln for ln in lines if ln.startswith("  Day ")}
    assert len(roles) == 18
    assert all(" training " in roles[f"Day {d}"] for d in range(1, 13))
    assert all(" validation_single " in roles[f"Day {d}"] for d in range(13, 19))


def test_outside_range_counts_the_test_rows_beyond_every_training_row(tmp_path):
    write_turning(tmp_path)
    days = turning.read_days(tmp_path)
    out = turning.outside_range(days)
    assert [r["day"] for r in out] == [f"Day {d}" for d in range(13, 19)]
    train = np.vstack([d.temps for d in days[:12]])
    for r, day in zip(out, days[12:]):
        beyond = (day.temps > train.max(axis=0)) | (day.temps < train.min(axis=0))
        assert r["outside"] == beyond.any(axis=1).sum() > 0 and r["rows"] == len(day.disp)
        assert "Spindle Front" in r["sensors"]  # the last sensor gains most on the warm days


def test_the_independent_ridge_recovers_a_displacement_of_the_rises(tmp_path):
    write_turning(tmp_path)
    result = turning.plain_ridge_days(turning.read_days(tmp_path))
    assert set(result["test"]) == {*(f"Day {d}" for d in range(13, 19)), "all"}
    assert result["test"]["all"][0] < 0.1  # 2 um per degree of one rise: a ridge of the rises holds it


def test_scored_rows_take_the_raw_displacement_from_the_runs_reference(tmp_path):
    write_turning(tmp_path)
    days = turning.read_days(tmp_path)
    runs = pd.DataFrame({"run_id": ["Day 13", "Day 14"], "file": ["Day 13", "Day 14"], "start_s": [0.0, 0.0]})
    parts = []
    for day in days[12:14]:
        measured = day.disp - day.disp[0]
        for model, bias in (("a", 0.0), ("b", 1.0)):
            parts.append(
                pd.DataFrame(
                    {"run_id": day.name, "model": model, "t_s": day.t_s, "measured_um": measured}
                    | {"predicted_um": measured + bias}
                )
            )
    scored, worst = turning.scored_rows(pd.concat(parts, ignore_index=True), runs, days)
    assert worst == pytest.approx(0.0, abs=1e-9)
    table = runs_mod.per_run(scored).set_index(["run_id", "model"])
    assert table.loc[("all", "a"), "mae_um"] == pytest.approx(0.0, abs=1e-9)
    assert table.loc[("all", "b"), "mae_um"] == pytest.approx(1.0)
    assert table.loc[("Day 13", "none"), "max_um"] == pytest.approx(
        np.abs(days[12].disp - days[12].disp[0]).max()
    )


def test_the_compare_steps_warnings_are_read_from_its_log(tmp_path):
    log = tmp_path / "compare.log"
    log.write_text(
        "fit ridge_global\n"
        "RAFI compare (machine=m) warning: 6 training runs recorded before a change were set aside\n"
        "RAFI runs (machine=m) warning: not the compare step\n",
        encoding="utf-8",
    )
    assert bench.compare_warnings(log) == ["compare: 6 training runs recorded before a change were set aside"]
    assert bench.compare_warnings(tmp_path / "missing.log") == []
