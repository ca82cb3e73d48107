"""Foreign machines (rafi.twin.foreign, ``rafi simulate foreign``): seeded, as varied as promised,
their outside fractions what the written logs say, and read by the real Snakefile."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from project_copy import copy_project, run_snakemake

from rafi.contract.sensors import run_sensors
from rafi.readers.input_spec import normalise_input_spec
from rafi.twin.foreign import OUTSIDE_KINDS, foreign_design, foreign_machine, write_foreign

#: The seeds whose designs the range tests draw (a design draws no day: cheap).
DESIGN_SEEDS = range(60)


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> tuple[Path, dict]:
    """Seed 6 written as a project's data: an over-speed and a long-run test day among its four."""
    out = tmp_path_factory.mktemp("foreign")
    machine, _ = write_foreign(6, out)
    return out, machine.truth


def test_a_seed_gives_the_same_machine_and_another_seed_another():
    a, b, c = foreign_machine(3), foreign_machine(3), foreign_machine(4)
    assert a.truth == b.truth and a.config == b.config
    assert list(a.logs) == list(b.logs)
    for stem in a.logs:
        pd.testing.assert_frame_equal(a.logs[stem], b.logs[stem])
    assert a.truth["sensors"] != c.truth["sensors"]
    assert not a.logs[next(iter(a.logs))].equals(c.logs[next(iter(c.logs))])


def test_setup_drift_moves_only_the_displacement_of_the_same_machine():
    plain, drifting = foreign_machine(5), foreign_machine(5, setup_drift=True)
    assert plain.truth["setup_drift_um"] == 0 and 0.5 <= drifting.truth["setup_drift_um"] <= 3.0
    assert plain.truth["sensors"] == drifting.truth["sensors"] and plain.config == drifting.config
    moved = []
    for stem, frame in plain.logs.items():
        other = drifting.logs[stem]
        pd.testing.assert_frame_equal(frame.drop(columns="disp_um"), other.drop(columns="disp_um"))
        moved.append((frame["disp_um"] - other["disp_um"]).abs().max())
    assert min(moved) > 0.1


def test_designs_span_the_promised_ranges():
    designs = [foreign_design(s) for s in DESIGN_SEEDS]
    counts = [len(d.params.sensors) for d in designs]
    assert 4 <= min(counts) <= 8 and 36 <= max(counts) <= 40  # 4-40 sensors, both ends reached
    assert len(set(counts)) > 20
    assert {d.base for d in designs} == {"tapping-center-a", "machining-center-b"}
    kinds = {day.kind for d in designs for day in d.days if day.role == "test"}
    assert set(OUTSIDE_KINDS) <= kinds
    for d in designs:
        names = [s.name for s in d.params.sensors]
        assert len(set(names)) == len(names)
        normalise_input_spec({"sensors": names})  # names the project accepts
        roles = [day.role for day in d.days]
        assert roles == sorted(roles, key=lambda r: r != "training")  # training days first
        tests = [day for day in d.days if day.role == "test"]
        assert 3 <= len(tests) <= 4 and any(day.kind in OUTSIDE_KINDS for day in tests)
        assert 2 <= len(d.speeds) <= 4 and roles.count("training") >= len(d.speeds) + 1
        lags = [s.lag_s for s in d.params.sensors if s.position != "ambient"]
        assert min(lags) >= 20 and max(lags) <= 900


def _read(path: Path) -> pd.DataFrame:
    return pd.read_csv(path, comment="#")


def _independent_fractions(folder: Path, truth: dict) -> dict:
    """The outside fractions of every test day from the written files, by the definition in the
    module's docstring (0.1 K margin, 50 r/min, spindle turning from 100 r/min, rises from the
    median of the first 180 s), computed row by row."""
    stems = {d["stem"]: d["role"] for d in truth["days"]}
    frames = {stem: _read(folder / f"{stem}.csv") for stem in stems}
    sensors = [c for c in frames[next(iter(frames))].columns if c not in ("time", "speed_rpm", "disp_um")]

    def rises(f):
        return f[sensors] - f[sensors].iloc[:3].median()

    train = [f for stem, f in frames.items() if stems[stem] == "training"]
    t_all = pd.concat([f[sensors] for f in train])
    r_all = pd.concat([rises(f) for f in train])
    t_lo, t_hi = dict(t_all.min() - 0.1), dict(t_all.max() + 0.1)
    r_lo, r_hi = dict(r_all.min() - 0.1), dict(r_all.max() + 0.1)
    slow, fast = min(truth["training_speeds_rpm"]) - 50, max(truth["training_speeds_rpm"]) + 50
    out = {}
    for stem, f in frames.items():
        if stems[stem] != "test":
            continue
        counts = {"temperature": 0, "rise": 0, "speed": 0, "any": 0}
        for row, rise in zip(f.to_dict("records"), rises(f).to_dict("records")):
            t = any(not t_lo[s] <= row[s] <= t_hi[s] for s in sensors)
            q = any(not r_lo[s] <= rise[s] <= r_hi[s] for s in sensors)
            v = row["speed_rpm"] >= 100 and not slow <= row["speed_rpm"] <= fast
            for key, hit in (("temperature", t), ("rise", q), ("speed", v), ("any", t or q or v)):
                counts[key] += bool(hit)
        out[stem] = {key: n / len(f) for key, n in counts.items()}
    return out


def test_the_stated_outside_fractions_are_those_of_the_written_logs(written):
    out, truth = written
    mine = _independent_fractions(out / "raw" / truth["machine"], truth)
    assert set(mine) == {r["stem"] for r in truth["test_runs"]}
    for run in truth["test_runs"]:
        got = mine[run["stem"]]
        for key in ("temperature", "rise", "speed", "any"):
            assert run[f"outside_{key}"] == pytest.approx(got[key], abs=1e-12), (run["stem"], key)
    kinds = {r["kind"]: r for r in truth["test_runs"]}
    assert kinds["over_speed"]["outside_speed"] > 0.9  # above the training speeds but for the rest
    assert kinds["long_run"]["outside_any"] > 0.3  # warmer than any training day
    assert truth["test_runs"][0]["kind"] == "steps" and truth["test_runs"][0]["outside_speed"] == 0


def test_rafi_simulate_foreign_writes_a_project_and_prints_its_block(tmp_path):
    from rafi.cli import main

    assert main(["simulate", "foreign", "--seed", "2", "--out", str(tmp_path)]) == 0
    config = yaml.safe_load((tmp_path / "config.yaml").read_text())
    truth = json.loads((tmp_path / "truth.json").read_text())
    block = config["machines"]["foreign-2"]
    assert block == foreign_machine(2).config
    assert block["input"]["sensors"] == [s["name"] for s in truth["sensors"]]
    files = sorted(p.stem for p in (tmp_path / "raw" / "foreign-2").glob("*.csv"))
    assert files == [d["stem"] for d in truth["days"]]


def test_rafi_simulate_foreign_into_a_project_adds_its_machine_and_keeps_the_others(tmp_path, capsys):
    """``--out`` a project that has machines: the config keeps them (and its comments), the logs go
    to its raw_dir, the truth beside the config under the machine's name; the same command again
    changes nothing; a machine of that name with other settings is refused, nothing written."""
    from rafi.cli import main

    text = "# the plant's machines\nraw_dir: logs\nmachines:\n  lathe-1:\n    sample_period_s: 30\n"
    (tmp_path / "config.yaml").write_text(text, encoding="utf-8")
    assert main(["simulate", "foreign", "--seed", "2", "--out", str(tmp_path)]) == 0
    after = (tmp_path / "config.yaml").read_text(encoding="utf-8")
    assert after.startswith(text)
    config = yaml.safe_load(after)
    assert config["machines"]["lathe-1"] == {"sample_period_s": 30}
    assert config["machines"]["foreign-2"] == foreign_machine(2).config
    assert sorted((tmp_path / "logs" / "foreign-2").glob("*.csv")) and not (tmp_path / "raw").exists()
    truth = json.loads((tmp_path / "truth-foreign-2.json").read_text())
    assert truth == json.loads(json.dumps(foreign_machine(2).truth))
    assert not (tmp_path / "truth.json").exists()
    assert main(["simulate", "foreign", "--seed", "2", "--out", str(tmp_path)]) == 0  # again: the same
    assert (tmp_path / "config.yaml").read_text(encoding="utf-8") == after
    config["machines"]["foreign-2"]["sample_period_s"] = 30
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config), encoding="utf-8")
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    capsys.readouterr()
    assert main(["simulate", "foreign", "--seed", "2", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "foreign-2" in err and "already under machines" in err and len(err.strip().splitlines()) == 1
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


@pytest.mark.slow
def test_the_pipeline_reads_a_foreign_machine_with_its_roles_and_sensors(tmp_path, written):
    out, truth = written
    proj = copy_project(tmp_path / "proj", config=False)
    shutil.copy2(out / "config.yaml", proj / "config.yaml")
    shutil.copytree(out / "raw", proj / "raw")
    machine = truth["machine"]
    done = run_snakemake(proj, f"results/{machine}/runs.csv", cores=2)
    assert done.returncode == 0, done.stderr[-3000:]
    runs = pd.read_csv(proj / "results" / machine / "runs.csv")
    day = {d["stem"]: d for d in truth["days"]}
    assert sorted(runs["file"].str.removesuffix(".csv")) == sorted(day)  # a run a day
    for file, role, speed in zip(runs["file"], runs["role"], runs["speed_rpm"]):
        d = day[file.removesuffix(".csv")]
        assert str(role).startswith("training" if d["role"] == "training" else "validation"), (file, role)
        if d["kind"] in ("constant", "over_speed", "long_run"):  # one speed all day: the run's
            assert speed == pytest.approx(d["speeds_rpm"][0], abs=5)
    frame = pd.read_parquet(proj / "results" / machine / "runs.parquet")
    assert list(run_sensors(frame)) == [s["name"] for s in truth["sensors"]]


# ----------------------------------------------------------------------------- realism
#: Seed 4: three training days, two hot-room test days (the fixed chiller shows), small and quick.
REAL_SEED = 4


@pytest.fixture(scope="module")
def plain_and_real() -> tuple:
    """Seed 4 without realism, with every effect, with the hidden source alone, with the reseat alone."""
    return (
        foreign_machine(REAL_SEED),
        foreign_machine(REAL_SEED, realism="all"),
        foreign_machine(REAL_SEED, realism=("hidden_source",)),
        foreign_machine(REAL_SEED, realism=("sensor_mount",)),
    )


def test_realism_off_draws_nothing_and_the_realistic_integrator_without_effects_is_the_linear_one():
    from rafi.twin.foreign import Day
    from rafi.twin.physics import integrate, integrate_realistic

    plain, none = foreign_machine(2), foreign_machine(2, realism="none")
    assert "realism" not in plain.truth and plain.parts == {} and plain.truth == none.truth
    for stem, frame in plain.logs.items():
        pd.testing.assert_frame_equal(frame, none.logs[stem])
    design = foreign_design(2)
    day: Day = design.days[-1]
    speeds = np.repeat([0.0, 4000.0, 6000.0], 120)
    room = np.full(len(speeds), day.ambient.base_c)
    linear, cool_a = integrate(design.params, speeds, room, 60.0)
    same, cool_b = integrate_realistic(design.params, speeds, room, 60.0)
    np.testing.assert_allclose(same, linear, atol=1e-9)
    assert (cool_a == cool_b).all()
    unit, _ = integrate_realistic(design.params, speeds, room, 60.0, convection_exponent=1.0)
    np.testing.assert_allclose(unit, linear, atol=1e-9)  # dT ** 1: the linear law


def test_realism_keeps_the_machine_and_its_noise_and_adds_exactly_the_stated_contribution(plain_and_real):
    plain, real, _, _ = plain_and_real
    assert real.config == plain.config and real.truth["sensors"] == plain.truth["sensors"]
    assert real.truth["days"] == plain.truth["days"]
    assert real.truth["realism"]["effects"] == [
        "hidden_source",
        "convection",
        "fixed_chiller",
        "sensor_mount",
        "warm_start",
    ]
    quantum = foreign_design(REAL_SEED).params.disp_quantum_um  # the logs' displacement step
    for stem, frame in plain.logs.items():
        other = real.logs[stem]
        pd.testing.assert_series_equal(frame["speed_rpm"], other["speed_rpm"])
        added = (other["disp_um"] - frame["disp_um"]).to_numpy()
        stated = real.parts[stem]["realism_um"].to_numpy()
        assert np.abs(added - stated).max() <= quantum + 1e-9, stem  # the same noise: only the effects differ
        day = real.truth["realism"]["days"][stem]
        assert day["realism_mae_um"] == pytest.approx(np.abs(stated).mean(), abs=1e-4)
    test_days = [r["stem"] for r in real.truth["test_runs"]]
    assert max(real.truth["realism"]["days"][s]["realism_mae_um"] for s in test_days) > 1.0


def test_the_hidden_source_is_nonzero_on_test_days_at_another_level_and_seen_by_the_log(plain_and_real):
    plain, _, hidden, _ = plain_and_real
    source = hidden.truth["realism"]["hidden_source"]
    roles = {d["stem"]: d["role"] for d in plain.truth["days"]}
    for stem, day in source["days"].items():
        low_or_high = 0.2 <= day["level"] <= 0.5 or 1.6 <= day["level"] <= 2.5
        assert 0.8 <= day["level"] <= 1.2 if roles[stem] == "training" else low_or_high, stem
    node = source["node"]
    params = foreign_design(REAL_SEED).params  # the logs' steps of displacement and temperature
    quantum, step_c = params.disp_quantum_um, params.temp_quantum_c
    for stem, part in hidden.parts.items():
        assert part["hidden_source_um"].abs().mean() > 0.05, stem  # on every day, test days too
        # alone, the source is the whole contribution, and the log shows it against the plain one
        np.testing.assert_allclose(part["hidden_source_um"], part["realism_um"], atol=1e-9)
        added = hidden.logs[stem]["disp_um"] - plain.logs[stem]["disp_um"]
        assert np.abs(added.to_numpy() - part["hidden_source_um"].to_numpy()).max() <= quantum + 1e-9
        for s in hidden.truth["sensors"]:
            seen = hidden.logs[stem][s["name"]] - plain.logs[stem][s["name"]]
            stated = part[f"hidden_source:{s['name']}"]
            assert np.abs(seen.to_numpy() - stated.to_numpy()).max() <= step_c + 1e-9, (stem, s["name"])
    # the sensor most on the source's node sees it on the day the source runs highest; not every
    # sensor sees as much (partially observed)
    high = max(source["days"], key=lambda stem: source["days"][stem]["level"])
    effect = {
        s["name"]: hidden.parts[high][f"hidden_source:{s['name']}"].abs().max()
        for s in hidden.truth["sensors"]
    }
    on_node = max(hidden.truth["sensors"], key=lambda s: s["mix"].get(node, 0.0))["name"]
    assert effect[on_node] > 0.1
    assert min(effect.values()) < 0.5 * effect[on_node]


def test_reseated_sensors_read_otherwise_from_their_day_on_and_nothing_else_changes(plain_and_real):
    plain, _, _, mount = plain_and_real
    drawn = mount.truth["realism"]["sensor_mount"]
    moved = {s["name"] for s in drawn["sensors"]}
    assert 1 <= len(moved) <= 3
    for s in drawn["sensors"]:
        assert s["lag_s"][0] != s["lag_s"][1] and s["ambient_share"][0] != s["ambient_share"][1]
    stems = list(plain.logs)
    start = stems.index(drawn["from_day"])
    for k, stem in enumerate(stems):
        a, b = plain.logs[stem], mount.logs[stem]
        if k < start:
            pd.testing.assert_frame_equal(a, b)
            continue
        pd.testing.assert_frame_equal(a.drop(columns=list(moved)), b.drop(columns=list(moved)))
        for name in moved:
            assert (a[name] - b[name]).abs().max() > 0.02, (stem, name)


def test_convection_cools_a_hot_machine_and_a_fixed_chiller_holds_its_set_point():
    from rafi.twin.machines import NODE_INDEX
    from rafi.twin.physics import CONVECTION_REF_K, integrate, integrate_realistic

    design = foreign_design(1)
    params = design.params
    speeds = np.full(600, max(design.speeds))  # 10 h at 60 s at the top speed: near the steady state
    room = np.full(len(speeds), 22.0)
    linear, _ = integrate(params, speeds, room, 60.0)
    convect, _ = integrate_realistic(params, speeds, room, 60.0, convection_exponent=1.3)
    for node in ("motor_base", "housing"):  # losing to still air and hotter than 2 K
        i = NODE_INDEX[node]
        rise_lin, rise_conv = linear[-1, i] - 22.0, convect[-1, i] - 22.0
        assert rise_lin > CONVECTION_REF_K  # hotter than where the two laws agree ...
        assert rise_conv < rise_lin - 0.1  # ... it loses more than the linear law says
    tank = NODE_INDEX["tank"]
    rest = np.zeros(600)
    warm = np.full(600, 26.0)
    tracking, _ = integrate(params, rest, warm, 60.0)
    fixed, cooler = integrate_realistic(params, rest, warm, 60.0, cooler_set_c=23.0)
    assert abs(tracking[-120:, tank].mean() - 26.0) < 0.5  # tracks the room: it stays at 26
    assert abs(fixed[-120:, tank].mean() - 23.0) < params.cooler_hysteresis_c  # holds 23 degC
    assert cooler[-120:].any() and not cooler[-120:].all()  # by cycling


def test_realism_is_deterministic_per_seed_and_drawn_anew_per_seed():
    a, b, c = (foreign_machine(s, realism=("hidden_source", "convection")) for s in (REAL_SEED, REAL_SEED, 0))
    assert a.truth == b.truth
    for stem in a.logs:
        pd.testing.assert_frame_equal(a.logs[stem], b.logs[stem])
        pd.testing.assert_frame_equal(a.parts[stem], b.parts[stem])
    assert a.truth["realism"]["hidden_source"] != c.truth["realism"]["hidden_source"]
    assert a.truth["realism"]["convection"] != c.truth["realism"]["convection"]


def test_rafi_simulate_foreign_realism_writes_what_was_drawn_and_refuses_an_unknown_effect(tmp_path, capsys):
    from rafi.cli import main

    assert (
        main(["simulate", "foreign", "--seed", "2", "--out", str(tmp_path), "--realism", "convection"]) == 0
    )
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert (
        truth["realism"]["effects"] == ["convection"]
        and 1.2 <= truth["realism"]["convection"]["exponent"] <= 1.33
    )
    assert main(["simulate", "foreign", "--seed", "2", "--out", str(tmp_path / "x"), "--realism", "sun"]) == 2
    err = capsys.readouterr().err
    assert "sun" in err and "hidden_source" in err and not (tmp_path / "x").exists()


def test_a_warm_start_begins_where_the_previous_day_left_after_its_rest_and_training_days_stay_cold():
    from rafi.twin.foreign import night
    from rafi.twin.machines import NODE_INDEX

    plain, warm = foreign_machine(REAL_SEED), foreign_machine(REAL_SEED, realism=("warm_start",))
    rest = warm.truth["realism"]["warm_start"]["rest_h"]
    roles = {d["stem"]: d["role"] for d in plain.truth["days"]}
    assert rest and all(roles[stem] == "test" and 1.0 <= h <= 10.0 for stem, h in rest.items())
    quantum = foreign_design(REAL_SEED).params.disp_quantum_um
    for stem, frame in plain.logs.items():
        if stem not in rest:
            pd.testing.assert_frame_equal(frame, warm.logs[stem])  # cold as without
            continue
        part = warm.parts[stem]["realism_um"].to_numpy()
        assert part[0] == pytest.approx(0.0, abs=1e-9)  # the probe zeroed on the warm machine
        added = (warm.logs[stem]["disp_um"] - frame["disp_um"]).to_numpy()
        assert np.abs(added - part).max() <= quantum + 1e-9
    # the night: a hot machine cools toward the room, the heavy column slowest
    params = foreign_design(REAL_SEED).params
    hot = np.full(len(NODE_INDEX), 30.0)
    after = night(params, hot, 20.0, 3.0)
    assert (after < 30.0).all() and (after > 20.0).any()
    column, housing = NODE_INDEX["column"], NODE_INDEX["housing"]
    assert after[column] - 20.0 > after[housing] - 20.0


def test_production_designs_repeat_one_job_through_a_season():
    from rafi.twin.foreign import (
        PRODUCTION_SEASON_K_PER_DAY,
        PRODUCTION_SHOP_WARMING_K_PER_H,
        PRODUCTION_STEP_MIN,
    )

    designs = [foreign_design(s, "production") for s in DESIGN_SEEDS]
    counts = [len(d.params.sensors) for d in designs]
    assert min(counts) == 4 and max(counts) == 8
    trends = []
    for d, varied in zip(designs, (foreign_design(s) for s in DESIGN_SEEDS)):
        assert d.params.disp_gain == varied.params.disp_gain  # the same machine, fewer sensors
        roles = [day.role for day in d.days]
        assert 8 <= roles.count("training") <= 12 and 4 <= roles.count("test") <= 6
        assert roles == sorted(roles, key=lambda r: r != "training")
        jobs = [[s for s in day.schedule if s.speed_rpm > 0] for day in d.days]
        assert all([s.speed_rpm for s in job] == [s.speed_rpm for s in jobs[0]] for job in jobs)  # one job
        assert set(s.speed_rpm for s in jobs[0]) == set(d.speeds)  # every training speed, so RAFI has runs
        lengths = np.array([[s.duration_s for s in job] for job in jobs]) / 60.0
        assert (
            lengths.min() >= 0.9 * PRODUCTION_STEP_MIN[0] > 60.0
            and lengths.max() <= 1.1 * PRODUCTION_STEP_MIN[1]
        )
        warming = [day.ambient.drift_c_per_h for day in d.days]
        assert 0.8 * PRODUCTION_SHOP_WARMING_K_PER_H[0] <= min(warming)
        assert max(warming) <= 1.2 * PRODUCTION_SHOP_WARMING_K_PER_H[1]
        levels = np.array([day.ambient.base_c for day in d.days])
        trends.append(np.polyfit(np.arange(len(levels)), levels, 1)[0])
    trends = np.array(trends)
    assert (trends > 0).any() and (trends < 0).any()  # seasons warming and cooling
    # the drawn trend's size, blurred by each day's own room (sd 0.7 K): the median within the range
    assert PRODUCTION_SEASON_K_PER_DAY[0] <= np.median(np.abs(trends)) <= PRODUCTION_SEASON_K_PER_DAY[1]


def test_production_machines_leave_their_training_range_on_test_days():
    machines = [foreign_machine(seed, plan="production") for seed in range(8)]
    assert machines[0].truth["plan"] == "production" and "plan" not in foreign_machine(0).truth
    mostly_outside = [max(run["outside_temperature"] for run in m.truth["test_runs"]) > 0.5 for m in machines]
    assert sum(mostly_outside) >= 4  # the season carries a test day beyond the training temperatures
    for m in machines:
        numbers = [int(d["stem"][3:5]) for d in m.truth["days"]]
        assert numbers == sorted(numbers) and len(set(numbers)) == len(numbers)  # day since the first
    with pytest.raises(ValueError, match="unknown plan 'weekly'"):
        foreign_design(0, "weekly")


def test_rafi_simulate_foreign_plan_production_writes_that_machine(tmp_path):
    from rafi.cli import main

    assert main(["simulate", "foreign", "--seed", "3", "--out", str(tmp_path), "--plan", "production"]) == 0
    truth = json.loads((tmp_path / "truth.json").read_text())
    assert truth["plan"] == "production" and 4 <= len(truth["sensors"]) <= 8
    files = sorted(p.name for p in (tmp_path / "raw" / "foreign-3").glob("*.csv"))
    assert files == [f"{d['stem']}.csv" for d in truth["days"]]
    with pytest.raises(SystemExit):
        main(["simulate", "foreign", "--seed", "3", "--out", str(tmp_path / "x"), "--plan", "weekly"])
    assert main(["simulate", "foreign", "--seed", "3", "--out", str(tmp_path / "c"), "--setup-change"]) == 0
    assert "from_day" in json.loads((tmp_path / "c" / "truth.json").read_text())["setup_change"]


def test_a_setup_change_moves_only_the_displacement_from_its_day_on():
    from rafi.twin.foreign import SETUP_CHANGE_FACTOR

    plain = foreign_machine(3, plan="production")
    changed = foreign_machine(3, plan="production", setup_change=True)
    change = changed.truth["setup_change"]
    assert "setup_change" not in plain.truth and plain.config == changed.config
    training = [d["stem"] for d in plain.truth["days"] if d["role"] == "training"]
    assert training.index(change["from_day"]) >= len(training) // 2 and change["from_day"] != training[-1]
    gains = plain.truth["disp_gain_um_per_k"]
    assert change["node"] == max(gains, key=lambda k: abs(gains[k]))
    assert SETUP_CHANGE_FACTOR[0] <= change["factor"] <= SETUP_CHANGE_FACTOR[1]
    stems = list(plain.logs)
    for k, stem in enumerate(stems):
        a, b = plain.logs[stem], changed.logs[stem]
        pd.testing.assert_frame_equal(a.drop(columns="disp_um"), b.drop(columns="disp_um"))
        moved = (a["disp_um"] - b["disp_um"]).abs().max()
        assert (moved > 1.0) if k >= stems.index(change["from_day"]) else (moved == 0.0), (stem, moved)
