"""benchmarks/_realdata_spindle.py, the 78 h spindle log of bench_realdata.py: its reader, its
configuration read by the project's own readers, the score against the raw log and the
independent ridge, on generated logs of its layout (the real one is never shipped)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from bench_loader import load_bench

from rafi.readers.input_spec import normalise_input_spec
from rafi.settings import machine_settings, validate_config

ROOT = Path(__file__).resolve().parents[1]

bench = load_bench("bench_realdata")
spindle = load_bench("_realdata_spindle")
runs_mod = load_bench("_realdata_runs")


def write_log(path: Path, rows: int = 900, seed: int = 0) -> pd.DataFrame:
    """A generated log of the spindle's layout (a UTF-8 BOM, ``delta L`` then ``T0``..``T15``,
    rows a minute apart): every sensor heats with its own time constant and gain, the room
    (``T15``) drifts up, and the displacement is 3 um per degree of ``T12``'s rise minus 2 um
    per degree of the room's, plus noise. Returns the frame written (the ground truth)."""
    rng = np.random.default_rng(seed)
    t_min = np.arange(rows, dtype=float)
    taus = np.linspace(60.0, 400.0, 16)
    gains = np.linspace(1.0, 20.0, 16)
    temps = 22.0 + gains * (1.0 - np.exp(-t_min[:, None] / taus)) + rng.normal(0, 0.02, (rows, 16))
    temps[:, 15] = 20.0 + 1.5 * t_min / rows + rng.normal(0, 0.02, rows)
    disp = 3.0 * (temps[:, 12] - temps[0, 12]) - 2.0 * (temps[:, 15] - temps[0, 15])
    frame = pd.DataFrame({spindle.DISPLACEMENT: disp + rng.normal(0, 0.05, rows)})
    for k, name in enumerate(spindle.TEMPERATURES):
        frame[name] = temps[:, k]
    path.write_text(frame.to_csv(index=False), encoding="utf-8-sig")
    return frame


def test_the_log_is_read_as_written_and_bad_cells_are_named(tmp_path):
    truth = write_log(tmp_path / "log.csv")
    frame = spindle.read_log(tmp_path / "log.csv")
    assert list(frame.columns) == [spindle.DISPLACEMENT, *spindle.TEMPERATURES]
    assert np.allclose(frame.to_numpy(), truth.to_numpy())
    text = (tmp_path / "log.csv").read_text(encoding="utf-8-sig").splitlines()
    text[5] = text[5].replace(",", ",x", 1)  # data row 5: the first temperature is not a number
    (tmp_path / "bad.csv").write_text("\n".join(text), encoding="utf-8")
    with pytest.raises(ValueError, match=r"line 6, column 'T0'"):
        spindle.read_log(tmp_path / "bad.csv")
    truth.drop(columns="T7").to_csv(tmp_path / "short.csv", index=False)
    with pytest.raises(ValueError, match=r"no column \['T7'\]"):
        spindle.read_log(tmp_path / "short.csv")


@pytest.mark.parametrize("split", list(spindle.SPLITS))
def test_the_configuration_gives_one_training_and_one_test_run_at_the_split(tmp_path, split):
    from rafi.ops.init_preview import preview

    folder = tmp_path / "raw" / spindle.MACHINE
    folder.mkdir(parents=True)
    write_log(folder / "log.csv")
    entry = spindle.machine_config(900, split)
    settings = {"raw_dir": str(tmp_path / "raw"), "machines": {spindle.MACHINE: entry}}
    validate_config(settings)
    merged = machine_settings(settings, spindle.MACHINE)
    assert merged["reference"]["rule"] == "log_start" and merged["training_speeds_rpm"] == [
        spindle.NOMINAL_RPM
    ]
    assert normalise_input_spec(merged["input"])["columns"]["t12"] == "T12"
    config = tmp_path / "config.yaml"
    config.write_text(yaml.safe_dump(settings), encoding="utf-8")
    lines = [ln for ln in preview(str(config), spindle.MACHINE) if ln.startswith("  log#")]
    starts_h = [ln.split()[1] for ln in lines]
    assert starts_h == ["0.00", f"{spindle.split_row(900, split) / 60:.2f}"]
    assert " training " in lines[0] and " validation_single " in lines[1]


def test_the_split_rows_are_the_stated_shares():
    assert spindle.split_row(4683, "publisher") == 4214  # the repository's int(0.9 n)
    assert spindle.split_row(4683, "heat-up") == 1561


def test_scored_rows_take_the_raw_log_from_the_pipelines_reference(tmp_path):
    frame = write_log(tmp_path / "log.csv")
    disp = frame[spindle.DISPLACEMENT].to_numpy()
    runs = pd.DataFrame({"run_id": ["log#1", "log#2"], "start_s": [0.0, 600 * 60.0]})
    t_s = np.arange(300) * 60.0
    measured = disp[600:] - disp[0]
    parts = [
        pd.DataFrame(
            {"run_id": "log#2", "model": m, "t_s": t_s, "measured_um": measured, "predicted_um": measured + b}
        )
        for m, b in (("exact", 0.0), ("high", 0.5))
    ]
    scored, worst = spindle.scored_rows(pd.concat(parts, ignore_index=True), runs, disp)
    assert worst == pytest.approx(0.0, abs=1e-9)
    table = runs_mod.per_run(scored).set_index(["run_id", "model"])
    assert table.loc[("log#2", "exact"), "mae_um"] == pytest.approx(0.0, abs=1e-9)
    assert table.loc[("log#2", "high"), "mae_um"] == pytest.approx(0.5)
    assert table.loc[("log#2", "none"), "mae_um"] == pytest.approx(np.abs(measured).mean())
    off = pd.concat(parts, ignore_index=True).assign(t_s=lambda f: f["t_s"] + 7.0)
    with pytest.raises(ValueError, match="60 s rows"):
        spindle.scored_rows(off, runs, disp)


def test_the_independent_ridge_recovers_the_generated_displacement(tmp_path):
    frame = write_log(tmp_path / "log.csv")
    result = spindle.plain_ridge_split(frame, "publisher")
    assert result["test_mae_um"] < 0.15  # a sum of two rises, noise 0.05 um: the ridge holds it
    assert result["test_max_um"] >= result["test_mae_um"]


def test_outside_range_counts_the_test_rows_beyond_every_training_row(tmp_path):
    frame = write_log(tmp_path / "log.csv")
    out = spindle.outside_range(frame, "heat-up")
    temps = frame[list(spindle.TEMPERATURES)].to_numpy()
    k = spindle.split_row(len(frame), "heat-up")
    beyond = (temps[k:] > temps[:k].max(axis=0)) | (temps[k:] < temps[:k].min(axis=0))
    assert out["rows"] == len(frame) - k and out["outside"] == beyond.any(axis=1).sum() > 0
    assert "T15" in out["sensors"]  # the room keeps warming


def test_the_spindles_results_are_never_written_into_the_repository(tmp_path, capsys):
    path = tmp_path / "log.csv"
    path.write_bytes(b"")
    with pytest.raises(SystemExit):
        bench.parse_args(["--logs", "spindle-78h", "--spindle", str(path)])
    assert "spindle-78h are derived from data without a licence" in capsys.readouterr().err
    args = bench.parse_args(["--logs", "spindle-78h", "--spindle", str(path), "--out-dir", str(tmp_path)])
    assert args.plan == ["spindle-78h"]


def test_the_report_shows_each_split_and_the_independent_ridge_beside_the_family():
    scored = pd.DataFrame(
        {
            "run_id": "log#2",
            "model": ["ensemble", "temperature_ridge"] * 3,
            "target_um": [1.0, 1.0, 2.0, 2.0, 3.0, 3.0],
        }
        | {"predicted_um": [1.5, 1.0, 2.5, 2.0, 3.5, 3.0]}
    )
    ok = {
        "split": "publisher",
        "train_share": 0.9,
        "first_test_row": 4214,
        "ok": True,
        "champion": "ensemble",
        "selection": "chosen by cv",
        "plain_ridge_run": "fitted with the family",
        "max_clean_diff_um": 0.0,
        "outside": {"rows": 3, "outside": 1, "sensors": ["T14"]},
        "plain_ridge": {
            "alpha": 0.01,
            "cv_rmse_um": 1.0,
            "at_grid_edge": False,
            "test_mae_um": 0.25,
            "test_max_um": 0.5,
        },
        "per_run": runs_mod.per_run(scored).to_dict("records"),
        "test_runs": ["log#2"],
        "selected": {"ensemble": "weights"},
        "warnings": [],
    }
    failed = {"split": "heat-up", "train_share": 1 / 3, "first_test_row": 1561, "ok": False, "tail": "boom"}
    head = {"date": "2026-11-30", "command": "c", "host": "h", "cpus": 2}
    text = spindle.markdown({**head, "spindle": [ok, failed]})
    assert "## Split 'publisher': the first 90% of the rows train" in text
    assert "| log#2 | 3 | 0.50 / 0.50 | 0.00 / 0.00 | 0.25 / 0.50 | 2.00 / 3.00 |" in text
    assert "Test rows outside the training temperature range: 1 of 3 (T14)" in text
    assert "## Split 'heat-up'" in text and "snakemake FAILED" in text and "boom" in text
