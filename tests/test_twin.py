"""The spindle digital twin (rafi.twin) and the `rafi simulate` command."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from rafi import REQUIRED_COLUMNS, SENSORS
from rafi.readers.native import read_raw_log
from rafi.twin.calibration import noise_floor
from rafi.twin.defects import DEFECT_COLUMNS
from rafi.twin.machines import NODES, Ambient, DefectRates, machine_params
from rafi.twin.physics import heat_sources
from rafi.twin.recipes import machining_center_b_spec
from rafi.twin.schedules import constant_schedule, multi_condition_schedule, schedule_from_pairs
from rafi.twin.simulate import simulate_run
from rafi.twin.writers import B_COLUMNS, read_b_layout, render_xlsx, simulate_b

ROOT = Path(__file__).resolve().parents[1]
RAW = ROOT / "raw"


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


# --------------------------------------------------------------------------- model


def test_import_is_light():
    code = (
        "import sys, rafi.twin.simulate, rafi.twin.recipes, rafi.twin.writers, rafi.twin.day, "
        "rafi.twin.calibration, rafi.twin.plots; "
        "print(any(m.split('.')[0] in ('matplotlib', 'openpyxl', 'statsmodels') for m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert out.stdout.strip() == "False", out.stderr


def test_four_hour_run_has_every_sample():
    # its time is measured by benchmarks/bench_steps.py (twin_4h_run), not here
    run = simulate_run(constant_schedule(9000, 4 * 3600), seed=1)
    assert len(run.truth) == 2880


def test_same_seed_same_log_other_seed_other_log():
    sched = multi_condition_schedule(((10, 3000), (10, 12000)))
    a = simulate_run(sched, seed=3)
    b = simulate_run(sched, seed=3)
    c = simulate_run(sched, seed=4)
    pd.testing.assert_frame_equal(a.log, b.log)
    pd.testing.assert_frame_equal(a.defects, b.defects)
    assert not a.log[list(SENSORS)].equals(c.log[list(SENSORS)])


def test_cold_start_nodes_at_ambient_and_heating_with_speed():
    run = simulate_run(constant_schedule(12000, 3600), seed=0, defects=False, noise=False)
    first = run.nodes.iloc[0]
    for node in NODES:
        assert first[node] == pytest.approx(first["ambient"])
    last = run.nodes.iloc[-1]
    assert last["shaft"] > last["housing"] > last["ambient"]
    assert last["coolant"] > last["tank"]  # outlet warmer than inlet


def test_truth_has_canonical_columns_and_no_noise():
    run = simulate_run(constant_schedule(3000, 1800), seed=2, defects=False, noise=False)
    assert list(run.truth.columns) == list(REQUIRED_COLUMNS)
    assert list(run.log.columns) == list(REQUIRED_COLUMNS)
    pd.testing.assert_frame_equal(run.log, run.truth)
    assert run.defects.empty
    assert run.truth["time"].diff().dropna().eq(pd.Timedelta(seconds=5)).all()
    assert list(run.defects.columns) == list(DEFECT_COLUMNS)


def test_noise_and_quantisation_like_a_logger():
    run = simulate_run(constant_schedule(6000, 3600), seed=5, defects=False)
    temps = run.log[list(SENSORS)].to_numpy()
    assert np.allclose(temps * 100, np.round(temps * 100), atol=1e-6)  # 0.01 degC steps
    resid = (run.log["T6"] - run.truth["T6"]).std()
    assert 0.03 < resid < 0.12
    dresid = (run.log["disp_um"] - run.truth["disp_um"]).std()
    assert 0.1 < dresid < 0.4


def test_equilibrium_earlier_and_elongation_larger_at_high_speed():
    def curve(sp):
        run = simulate_run(
            constant_schedule(sp, 4 * 3600),
            seed=0,
            defects=False,
            noise=False,
            ambient=Ambient(daily_amplitude_c=0.0, wander_c=0.0),
        )
        return run.nodes["disp_thermal_um"].to_numpy()

    low, high = curve(3000), curve(18000)
    assert high[-1] > low[-1] > 5
    k = 1440  # 2 h: fraction of the 4 h rise reached
    assert high[k] / high[-1] > low[k] / low[-1]


def test_centrifugal_jump_at_speed_change():
    sched = schedule_from_pairs([(600, 3000), (600, 18000)])
    run = simulate_run(sched, seed=0, defects=False, noise=False)
    cf = run.nodes["disp_centrifugal_um"].to_numpy()
    assert cf[125] - cf[115] < -1.0  # draw-in jump within a few samples
    assert abs(cf[121] - cf[-1]) < 0.1


def test_heat_sources_grow_with_speed():
    p = machine_params("tapping-center-a")
    q = [heat_sources(p, n).sum() for n in (0, 3000, 9000, 18000)]
    assert q[0] == 0 and q[1] < q[2] and q[1] < q[3]  # motor losses fall in field weakening
    shaft = [heat_sources(p, n)[NODES.index("shaft")] for n in (3000, 9000, 18000)]
    assert shaft[0] < shaft[1] < shaft[2]
    fb = [heat_sources(p, n)[NODES.index("front_bearing")] for n in (5000, 10000)]
    assert fb[1] / fb[0] == pytest.approx(2 ** (5 / 3))


def test_sensor_drift_and_wear_options():
    sched = constant_schedule(9000, 3600)
    base = simulate_run(sched, seed=1, defects=False, noise=False)
    drift = simulate_run(sched, seed=1, defects=False, noise=False, sensor_drift={"T8": 0.4})
    worn = simulate_run(sched, seed=1, defects=False, noise=False, wear=0.2)
    assert (drift.truth["T8"] - base.truth["T8"]).abs().max() == pytest.approx(0.4)
    assert worn.truth["disp_um"].iloc[-1] > base.truth["disp_um"].iloc[-1]


def test_stuck_displacement_option():
    run = simulate_run(constant_schedule(6000, 3600), seed=1, defects=False, stuck_displacement=True)
    tail = run.log["disp_um"].iloc[len(run.log) // 3 :]
    assert tail.nunique() == 1
    assert "stuck_displacement" in set(run.defects["kind"])


# --------------------------------------------------------------------------- defects


@pytest.fixture(scope="module")
def defective():
    rates = DefectRates(
        missing_row=0.004,
        restart_gap_prob=1.0,
        duplicate_row=0.003,
        spike_per_1000_rows=3.0,
        dropout_prob=1.0,
        swap_per_1000_rows=2.0,
    )
    return simulate_run(constant_schedule(12000, 4 * 3600), seed=11, defects=rates)


def test_defect_table_matches_the_log(defective):
    log, truth, d = defective.log, defective.truth, defective.defects
    kinds = set(d["kind"])
    assert {"missing_row", "restart_gap", "duplicate_row", "spike", "dropout", "swapped_rows"} <= kinds
    for _, row in d[d["kind"] == "duplicate_row"].iterrows():
        p = row["row"]
        pd.testing.assert_series_equal(log.iloc[p], log.iloc[p - 1], check_names=False)
    for _, row in d[d["kind"] == "swapped_rows"].iterrows():
        p = row["row"]
        assert log["time"].iat[p] > log["time"].iat[p + 1]
    for _, row in d[d["kind"] == "restart_gap"].iterrows():
        p = row["row"]
        gap = (log["time"].iat[p] - log["time"].iat[p - 1]).total_seconds()
        assert 20 <= gap - 5 <= 50 + 5
        assert gap <= 60  # interpolable (max_interpolate_gap_s)
    for _, row in d[d["kind"] == "spike"].iterrows():
        p, col = row["row"], row["column"]
        true = truth.set_index("time").loc[log["time"].iat[p], col]
        assert abs(log[col].iat[p] - true) > (2.5 if col != "disp_um" else 7.0)
    for _, row in d[d["kind"] == "dropout"].iterrows():
        seg = log[row["column"]].iloc[row["row"] : row["row"] + row["n_rows"]]
        assert seg.isna().all() or seg.isin([-999.0, 850.0]).all()
    missing = set(truth["time"]) - set(log["time"])
    n_missing = d.loc[d["kind"].isin(["missing_row", "restart_gap"]), "n_rows"].sum()
    assert len(missing) == n_missing
    assert len(log) == len(truth) - n_missing + (d["kind"] == "duplicate_row").sum()


def test_default_defect_rates_are_low():
    run = simulate_run(constant_schedule(6000, 4 * 3600), seed=21)
    d = run.defects
    assert len(d) < 40
    assert (d["kind"] == "restart_gap").sum() <= 1
    assert (d["kind"] == "dropout").sum() <= 1


def test_no_defects_option():
    run = simulate_run(constant_schedule(6000, 3600), seed=21, defects=False)
    assert run.defects.empty and len(run.log) == len(run.truth)


# --------------------------------------------------------------------------- shipped files / CLI


def test_shipped_native_files_read_with_the_project_reader():
    files = sorted((RAW / "tapping-center-a").glob("*.csv"))
    assert len(files) == 12
    for path in files:
        frame = read_raw_log(path)
        assert list(frame.columns[:19]) == list(REQUIRED_COLUMNS)
        md = frame.attrs["metadata"]
        assert md["machine"] == "tapping-center-a" and md["run_id"] == path.stem
        assert md["sample_period_s"] == 5.0
        assert "seed" in md["notes"] and "rafi simulate shipped --out raw" in md["notes"]


def test_shipped_regenerates_byte_for_byte(tmp_path):
    from rafi.cli import main

    assert main(["simulate", "shipped", "--out", str(tmp_path)]) == 0
    for machine in ("tapping-center-a", "machining-center-b"):
        shipped = sorted(p.name for p in (RAW / machine).iterdir())
        fresh = sorted(p.name for p in (tmp_path / machine).iterdir())
        assert shipped == fresh
        for name in shipped:
            assert sha(RAW / machine / name) == sha(tmp_path / machine / name), name


def test_machining_center_b_layout():
    import openpyxl

    path = RAW / "machining-center-b" / "thermal_log_2026-10-14.xlsx"
    wb = openpyxl.load_workbook(path, read_only=True)
    assert wb.sheetnames == ["Info", "Messdaten"]
    wb.close()
    frame = read_b_layout(path)
    assert list(frame.columns) == list(B_COLUMNS)
    assert frame.columns[0] == "Zeit [s]" and frame.columns[-1] == "Bemerkung"
    t = frame["Zeit [s]"].to_numpy()
    assert t[0] == 0 and (np.diff(t) > 0).all() and np.median(np.diff(t)) == 15
    assert 46 * 3600 <= t[-1] < 48 * 3600
    speed = frame["Drehzahl [1/min]"]
    assert {1250, 2500, 3750, 5000, 3500, 0} <= set(speed.round(-1).astype(int))
    tail = speed[frame["Zeit [s]"] > 33 * 3600]
    assert (tail.between(100, 1200)).any()  # below the lowest trained speed
    assert frame["Temperatur 6 [°C]"].isna().sum() < 50
    assert frame["Bemerkung"].notna().sum() < 60


def test_machining_center_b_ends_like_a_real_log():
    """After the varying 4 h: a cool-down, steps whose speed only decreases, one of them exactly
    ``runs.min_constant_s`` long at a training speed (after the validation run), a final cool-down."""
    import yaml

    from rafi.settings import MACHINE_DEFAULTS

    frame = read_b_layout(RAW / "machining-center-b" / "thermal_log_2026-10-14.xlsx")
    t = frame["Zeit [s]"].to_numpy()
    level = frame["Drehzahl [1/min]"].round(-2).astype(int).to_numpy()
    tail = t >= 37 * 3600
    t, level = t[tail], level[tail]
    starts = np.concatenate(([0], np.flatnonzero(np.diff(level)) + 1))
    ends = np.concatenate((starts[1:], [len(level)]))
    steps = [(int(level[a]), int(b - a), float(t[a]) / 3600) for a, b in zip(starts, ends)]
    assert [s[0] for s in steps] == [0, 4500, 2500, 1500, 500, 0]
    assert [s[2] for s in steps] == [37.0, 40.0, 42.0, 43.0, 44.0, 45.0]
    n_2500 = steps[2][1]
    assert n_2500 * 15 == MACHINE_DEFAULTS["runs"]["min_constant_s"] == 3600  # no row missing
    cfg = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))
    assert 2500 in cfg["machines"]["machining-center-b"]["training_speeds_rpm"]


def test_machining_center_b_cell_values_deterministic(tmp_path):
    spec = machining_center_b_spec()
    target = tmp_path / "b.xlsx"
    target.write_bytes(render_xlsx(spec))
    a = read_b_layout(target)
    b = read_b_layout(RAW / "machining-center-b" / "thermal_log_2026-10-14.xlsx")
    pd.testing.assert_frame_equal(a, b)


def test_machining_center_b_z1_is_reversed_displacement():
    frame, run = simulate_b(machining_center_b_spec())
    by_time = run.truth.set_index(
        ((run.truth["time"] - run.truth["time"].iat[0]) / pd.Timedelta(seconds=1)).round().astype(int)
    )
    truth = by_time.loc[frame["Zeit [s]"], "disp_um"].to_numpy()
    z1 = frame["Verlagerung Z1 [µm]"].to_numpy()
    ok = np.abs(z1 + truth) < 5
    assert ok.mean() > 0.99
    assert np.corrcoef(-frame["Verlagerung Z2 [µm]"], truth)[0, 1] > 0.95


def test_day_mode_writes_new_names_and_never_overwrites(tmp_path):
    from rafi.cli import main

    args = [
        "simulate",
        "day",
        "--machine",
        "tapping-center-a",
        "--out",
        str(tmp_path),
        "--seed",
        "7",
        "--ambient-shift",
        "3.0",
        "--sensor-drift",
        "T8:0.4",
        "--wear",
        "0.1",
        "--speeds",
        "3000,6000",
        "--validation-speeds",
        "4500",
        "--multi",
        "--hours",
        "1",
    ]
    assert main(args) == 0
    files = sorted((tmp_path / "tapping-center-a").glob("*.csv"))
    names = [p.name for p in files]
    assert len(files) == 4 and all("_s7_" in n for n in names)
    shipped = {p.name for p in (RAW / "tapping-center-a").glob("*.csv")}
    assert not set(names) & shipped
    frame = read_raw_log(files[0])
    assert "--ambient-shift 3" in frame.attrs["metadata"]["notes"]
    assert frame["T1"].median() > 23.5  # the room is 3 K warmer
    assert main(args) == 1  # same names: refused, nothing overwritten
    assert main(args[:8] + ["--seed", "8", "--speeds", "3000", "--stuck-displacement", "--hours", "1"]) == 0


def test_day_mode_machining_center_b(tmp_path):
    from rafi.cli import main

    assert (
        main(
            [
                "simulate",
                "day",
                "--machine",
                "machining-center-b",
                "--out",
                str(tmp_path),
                "--seed",
                "3",
                "--speeds",
                "2500",
                "--hours",
                "1",
            ]
        )
        == 0
    )
    (path,) = (tmp_path / "machining-center-b").glob("*.xlsx")
    assert "_s3" in path.name
    frame = read_b_layout(path)
    assert list(frame.columns) == list(B_COLUMNS)


def test_help_documents_every_option():
    from rafi.cli import build_parser

    parser = build_parser()
    top = subprocess.run(
        [sys.executable, "-m", "rafi.cli", "simulate", "--help"], capture_output=True, text=True, cwd=ROOT
    )
    assert top.returncode == 0 and "rafi simulate shipped --out raw" in top.stdout
    sim = next(a for a in parser._subparsers._group_actions[0].choices.items() if a[0] == "simulate")[1]
    modes = sim._subparsers._group_actions[0].choices
    assert set(modes) == {"shipped", "day", "hostile", "noise-floor", "plot", "layout", "foreign"}
    for name, sub in modes.items():
        for action in sub._actions:
            if action.dest == "help":
                continue
            assert action.help and action.help.strip(), (name, action.dest)
        out = subprocess.run(
            [sys.executable, "-m", "rafi.cli", "simulate", name, "--help"],
            capture_output=True,
            text=True,
            cwd=ROOT,
        )
        assert out.returncode == 0, out.stderr


def test_plot_command(tmp_path):
    pytest.importorskip("matplotlib")
    from rafi.cli import main

    assert (
        main(
            [
                "simulate",
                "plot",
                str(RAW / "tapping-center-a"),
                "--out",
                str(tmp_path),
                "--pattern",
                "train_03000rpm.csv",
            ]
        )
        == 0
    )
    assert (tmp_path / "twin-train_03000rpm.png").stat().st_size > 10000
    assert (tmp_path / "twin-overview.png").exists()


def test_noise_floor_of_the_shipped_validation_runs():
    # the documented floor (docs/models.md): the max of the 0.2 um displacement noise per run
    floor = noise_floor("tapping-center-a")
    assert list(floor["run_id"]) == [
        "valid_04500rpm",
        "valid_08000rpm",
        "valid_10500rpm",
        "valid_13500rpm",
        "valid_16500rpm",
        "multi_condition",
    ]
    np.testing.assert_allclose(floor["noise_std_um"], 0.2, atol=0.01)
    assert (
        (floor["floor_max_abs_um"] > 3 * floor["noise_std_um"])
        & (floor["floor_max_abs_um"] < 5 * floor["noise_std_um"])
    ).all()
    assert floor.set_index("run_id").loc["valid_04500rpm", "floor_max_abs_um"] == pytest.approx(
        0.730, abs=0.001
    )


# --------------------------------------------------------------------------- shared primitives


def test_schedule_spellings_and_signal_primitives_agree():
    from rafi.twin.schedules import Step, sample_schedule, speed_at
    from rafi.twin.signals import ar1, first_order, step_response

    steps = [Step(60.0, 0.0), Step(120.0, 6000.0), Step(0.0, 9000.0), Step(30.0, 3000.0)]
    sampled = sample_schedule(steps, 5.0)
    t = np.arange(len(sampled)) * 5.0
    np.testing.assert_array_equal(sampled, speed_at(t, [(0.0, 0.0), (60.0, 6000.0), (180.0, 3000.0)]))
    with pytest.raises(ValueError, match="empty"):
        sample_schedule([Step(1.0, 3000.0)], 5.0)

    u = np.full(200, 4.0)
    np.testing.assert_allclose(first_order(u, 5.0, 50.0, y0=4.0), u)  # starts settled
    np.testing.assert_array_equal(first_order(u, 5.0, 0.0), u)  # tau 0: pass-through
    # from rest, sample k of the lag is the analytic step response one sample later
    np.testing.assert_allclose(
        first_order(u, 5.0, 50.0), step_response((np.arange(200) + 1) * 5.0, 4.0, 50.0)
    )
    a = 0.9
    noise = ar1(np.random.default_rng(0).normal(0.0, 1.0, 200_000), a, np.sqrt(1 - a * a))
    assert np.std(noise) == pytest.approx(1.0, abs=0.02)
    assert np.corrcoef(noise[1:], noise[:-1])[0, 1] == pytest.approx(a, abs=0.01)


def test_hostile_command_writes_the_corpus_and_its_ground_truth(tmp_path):
    from rafi.cli import main
    from rafi.twin.hostile import OUTCOMES

    out = tmp_path / "raw" / "m"
    assert (
        main(["simulate", "hostile", "--out", str(out), "--shipped", str(ROOT / "raw" / "tapping-center-a")])
        == 0
    )
    written = sorted(p.name for p in out.iterdir())
    assert "hostile_degF.csv" in written and "hostile_link_outside.csv" in written
    assert (out / "hostile_link_outside.csv").is_symlink()
    assert not (out / "hostile_link_outside.csv").resolve().is_relative_to(out.parent)
    shipped = ROOT / "raw" / "tapping-center-a"
    assert main(["simulate", "hostile", "--out", str(shipped), "--shipped", str(shipped)]) == 2
    assert OUTCOMES[0] == "quarantined"


def test_hostile_corpus_sources_regenerate_byte_for_byte_without_the_shipped_folder(tmp_path):
    from rafi.twin.hostile import SOURCES
    from rafi.twin.hostile_files import shipped_sources

    simulated = shipped_sources(tmp_path / "nothing-here")
    shipped = ROOT / "raw" / "tapping-center-a"
    assert simulated == {name: (shipped / name).read_text(encoding="utf-8") for name in SOURCES}
