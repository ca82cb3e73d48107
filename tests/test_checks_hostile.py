"""Per-file plausibility checks (issue 13): each check's message on a hostile variant of a shipped
raw file, and no false alarm on any shipped file (rafi.readers.checks.check_file).

The hostile variants are built from the shipped logs (known truth: the shipped files are good),
so a check is tested on realistic signals: noise, open-circuit readings, spikes and all.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rafi import SENSORS
from rafi.errors import RawFormatError
from rafi.readers.checks import FILE_CHECKS, check_file
from rafi.readers.logs import read_log
from rafi.settings import machine_settings

ROOT = Path(__file__).resolve().parents[1]
A = "tapping-center-a"
B = "machining-center-b"
SHIPPED = sorted((ROOT / "raw" / A).glob("*.csv")) + sorted((ROOT / "raw" / B).glob("*.xlsx"))
PROPS = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@functools.cache
def _config() -> dict:
    return yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))


def kwargs(machine: str) -> dict:
    """check_file keyword arguments of ``machine``, as the clean rule passes them."""
    ms = machine_settings(_config(), machine)
    return {
        "min_run_s": ms["runs"]["min_run_s"],
        "sample_period_s": ms["sample_period_s"],
        "open_circuit_values": ms["clean"]["open_circuit_values"],
        "training_speeds_rpm": ms["training_speeds_rpm"],
        "speed_tolerance_rpm": ms["speed_tolerance_rpm"],
        "machine": machine,
    }


@functools.cache
def _read(path: Path) -> pd.DataFrame:
    return read_log(path, machine_settings(_config(), path.parent.name)["input"])


def shipped(name: str = "train_09000rpm.csv", machine: str = A) -> pd.DataFrame:
    """A fresh copy of a shipped log's canonical frame."""
    frame = _read(ROOT / "raw" / machine / name)
    copy = frame.copy()
    copy.attrs = {k: (dict(v) if isinstance(v, dict) else v) for k, v in frame.attrs.items()}
    return copy


def run(frame: pd.DataFrame, machine: str = A, **overrides):
    return check_file(frame, f"raw/{machine}/log.csv", **{**kwargs(machine), **overrides})


def error_of(frame: pd.DataFrame, machine: str = A, **overrides) -> RawFormatError:
    with pytest.raises(RawFormatError) as info:
        run(frame, machine, **overrides)
    return info.value


def checks_of(report) -> list[str]:
    return [w.check for w in report.warnings]


# --------------------------------------------------------------------------- no false alarms


@pytest.mark.parametrize("path", SHIPPED, ids=[p.name for p in SHIPPED])
def test_shipped_files_trigger_no_check_and_have_a_positive_probe(path):
    report = check_file(_read(path), path, **kwargs(path.parent.name))
    assert report.warnings == []
    assert report.probe_sign == 1


@given(
    noise=st.floats(0.0, 0.05),
    disp_noise=st.floats(0.0, 0.3),
    seed=st.integers(0, 2**16),
    name=st.sampled_from(["train_03000rpm.csv", "valid_13500rpm.csv", "multi_condition.csv"]),
)
@PROPS
def test_a_good_file_with_noise_added_passes(noise, disp_noise, seed, name):
    f = shipped(name)
    rng = np.random.default_rng(seed)
    for s in SENSORS:  # open-circuit readings stay as they are
        f[s] = f[s].where(f[s].abs() > 500, f[s] + rng.normal(0, noise, len(f)))
    f["disp_um"] = f["disp_um"] + rng.normal(0, disp_noise, len(f))
    report = run(f)
    assert report.warnings == [] and report.probe_sign == 1


# --------------------------------------------------------------------------- temperature_unit


def test_degf_is_an_error_with_the_converted_value():
    f = shipped()
    for s in SENSORS:
        f[s] = f[s] * 1.8 + 32
    err = error_of(f)
    msg = str(err)
    assert "temperature_unit: temperatures look like deg F" in msg
    assert err.column == "T13" and "(= 21.8 deg C if deg F)" in msg and "10-35 deg C" in msg


@given(ambient=st.floats(10.0, 35.0), scale=st.floats(1.7, 1.9), offset=st.floats(28.0, 36.0))
@PROPS
def test_any_affine_degf_conversion_of_a_good_file_is_caught(ambient, scale, offset):
    """The shipped log moved to another ambient (10-35 deg C) passes in deg C and fails in deg F
    (any scale near 9/5 and offset near 32, as loggers round them)."""
    f = shipped("train_15000rpm.csv")
    shift = ambient - float(np.nanmin(f[list(SENSORS)].iloc[:20].median()))
    for s in SENSORS:
        f[s] = f[s] + shift
    assert run(f).warnings == []
    for s in SENSORS:
        f[s] = f[s] * scale + offset
    assert "temperature_unit" in str(error_of(f))


def test_kelvin_is_an_error_not_an_out_of_range_temperature():
    f = shipped()
    for s in SENSORS:
        f[s] = f[s] + 273.15
    msg = str(error_of(f))
    assert "temperature_unit: temperatures look like kelvin" in msg and "if K" in msg
    assert "outside -40..200" not in msg


# --------------------------------------------------------------------------- speed_unit, speed_range


def test_rev_per_s_on_a_training_run_is_an_error():
    f = shipped()
    f["speed_rpm"] = f["speed_rpm"] / 60
    err = error_of(f)
    assert err.column == "speed_rpm"
    assert "speed_unit:" in str(err) and "150 x 60 = 9000" in str(err) and "rev/s" in str(err)


def test_rev_per_s_on_a_multi_speed_log_is_an_error():
    f = shipped("multi_condition.csv")
    f["speed_rpm"] = f["speed_rpm"] / 60
    assert "speed_unit:" in str(error_of(f))


def test_rev_per_s_on_a_validation_run_is_a_warning():
    f = shipped("valid_04500rpm.csv")
    f["speed_rpm"] = f["speed_rpm"] / 60
    report = run(f)
    assert checks_of(report) == ["speed_unit"]
    w = report.warnings[0]
    assert (
        w.column == "speed_rpm"
        and "never exceeds 75.03 r/min" in w.message
        and "x 60 = 4502 r/min" in w.message
    )


def test_a_slow_machine_is_not_taken_for_rev_per_s():
    """500 r/min on a machine trained at 1250-5000: x 60 would be far outside training."""
    f = shipped(B and "thermal_log_2026-10-14.xlsx", B)
    f["speed_rpm"] = np.where(f["speed_rpm"] > 0, 500.0, 0.0)
    assert "speed_unit" not in checks_of(run(f, B))


def test_a_run_far_above_the_training_speeds_is_a_warning():
    f = shipped("valid_16500rpm.csv")
    f["speed_rpm"] = np.where(f["speed_rpm"] > 0, 50_000.0, 0.0)
    report = run(f)
    assert checks_of(report) == ["speed_range"]
    w = report.warnings[0]
    assert "reaches 50000 r/min" in w.message and "highest training speed 18000" in w.message
    assert "extrapolate" in w.message and w.first_line is not None and w.last_line > w.first_line


def test_the_highest_shipped_validation_speed_is_within_range():
    f = shipped("valid_16500rpm.csv")
    assert run(f).warnings == []
    f["speed_rpm"] = np.where(f["speed_rpm"] > 0, 22_000.0, 0.0)  # 1.22 x 18000: not far above
    assert run(f).warnings == []


# --------------------------------------------------------------------------- displacement_unit


def test_millimetres_with_glitches_are_an_error():
    f = shipped()
    f["disp_um"] = f["disp_um"] / 1000
    f.loc[f.index[[100, 900, 2000]], "disp_um"] = [12.0, -8.0, 30.0]  # glitches widen max - min
    msg = str(error_of(f))
    assert "displacement_unit:" in msg and "values look like millimetres" in msg


@given(
    n_glitches=st.integers(0, 25),
    size=st.floats(0.5, 500.0),
    seed=st.integers(0, 2**16),
)
@PROPS
def test_random_glitch_samples_do_not_hide_millimetres(n_glitches, size, seed):
    f = shipped("train_06000rpm.csv")
    f["disp_um"] = f["disp_um"] / 1000
    rng = np.random.default_rng(seed)
    rows = rng.choice(len(f), n_glitches, replace=False)
    f.loc[f.index[rows], "disp_um"] = rng.choice([-1, 1], n_glitches) * size
    assert "values look like millimetres" in str(error_of(f))


def test_nanometres_are_an_error():
    f = shipped()
    f["disp_um"] = f["disp_um"] * 1000
    msg = str(error_of(f))
    assert "displacement_unit:" in msg and "values look like nanometres" in msg and "2000 um" in msg


# --------------------------------------------------------------------------- swapped_channels


def test_t1_and_the_displacement_swapped_is_an_error():
    f = shipped()
    f["T1"], f["disp_um"] = f["disp_um"].copy(), f["T1"].copy()
    err = error_of(f)
    msg = str(err)
    assert err.column == "T1" and "swapped_channels: T1 and disp_um look swapped" in msg
    assert "other sensors start at" in msg and "inside that band" in msg


@pytest.mark.parametrize("name", ["train_03000rpm.csv", "valid_10500rpm.csv", "multi_condition.csv"])
@pytest.mark.parametrize("sensor", ["T1", "T8", "T13"])
def test_any_sensor_swapped_with_the_displacement_is_an_error(name, sensor):
    f = shipped(name)
    f[sensor], f["disp_um"] = f["disp_um"].copy(), f[sensor].copy()
    assert "swapped_channels" in str(error_of(f))


def _cool_down_at_rest(name: str = "train_18000rpm.csv") -> pd.DataFrame:
    """A heating run played backwards at rest: a file that starts during a cool-down, its
    hottest sensor (T8) 10.7 K above the others' median and falling to them."""
    f = shipped(name)
    cols = [*SENSORS, "disp_um"]
    f[cols] = f[cols].to_numpy()[::-1]
    f["speed_rpm"] = 0.0
    return f


def test_a_file_that_starts_during_a_cool_down_is_not_a_swap():
    report = run(_cool_down_at_rest())
    assert report.warnings == [] and report.probe_sign == 1


def test_a_hot_sensor_that_stays_hot_or_a_falling_displacement_in_a_sensor_column_still_counts():
    f = _cool_down_at_rest()
    others = [s for s in SENSORS if s != "T8"]
    f["T8"] = f[others].median(axis=1) + 10.7  # stays 10.7 K above the others: not cooling
    assert checks_of(run(f)) == ["swapped_channels"]
    f = _cool_down_at_rest()
    f["disp_um"] = 1.6 * f["disp_um"]  # from 45 um to 1 um: it ends far below the temperatures
    f["T8"], f["disp_um"] = f["disp_um"].copy(), f["T8"].copy()
    assert checks_of(run(f)) == ["swapped_channels"]


def test_swapped_on_the_foreign_machine():
    f = shipped("thermal_log_2026-10-14.xlsx", B)
    f["T4"], f["disp_um"] = f["disp_um"].copy(), f["T4"].copy()
    err = error_of(f, B)
    assert "swapped_channels" in str(err) and "header 'Temperatur 4 [°C]'" in str(err)


def test_displacement_mapped_to_a_temperature_is_an_error():
    f = shipped()
    f["disp_um"] = f["T9"]
    msg = str(error_of(f))
    assert "swapped_channels: disp_um holds the same values as T9" in msg


def test_a_displacement_that_behaves_like_a_temperature_is_a_warning():
    f = shipped()
    f["disp_um"] = f["T5"] + 0.3 + np.random.default_rng(0).normal(0, 0.05, len(f))
    report = run(f)
    assert checks_of(report) == ["swapped_channels"]
    assert (
        report.warnings[0].column == "disp_um" and "behaves like a temperature" in report.warnings[0].message
    )


def test_a_temperature_far_from_the_others_is_a_warning():
    f = shipped()
    f["T3"] = f["T3"] - 15.0
    report = run(f)
    assert checks_of(report) == ["swapped_channels"]
    assert report.warnings[0].column == "T3" and "from their median" in report.warnings[0].message


def test_a_probe_with_an_offset_is_not_taken_for_a_temperature():
    f = shipped()
    f["disp_um"] = f["disp_um"] + 150.0
    assert run(f).warnings == []


# --------------------------------------------------------------------------- constant_channel, stuck_logger


def test_one_constant_sensor_is_a_warning():
    f = shipped()
    f["T7"] = 22.5
    report = run(f)
    assert checks_of(report) == ["constant_channel"]
    w = report.warnings[0]
    assert (
        w.column == "T7"
        and "stays at 22.5 deg C" in w.message
        and "other sensors change by up to" in w.message
    )


def test_all_temperatures_constant_is_a_stuck_logger():
    f = shipped()
    for s in SENSORS:
        f[s] = float(f[s].iloc[0])
    err = error_of(f)
    assert "stuck_logger: all 16 temperatures are constant" in str(err) and "disp_um changes by" in str(err)


def test_a_logger_that_freezes_half_way_is_a_stuck_logger():
    f = shipped()
    frozen = f.index >= f.index[1200]
    for s in SENSORS:
        f.loc[frozen, s] = float(f.loc[f.index[1200], s])
    err = error_of(f)
    assert err.check == "stuck_logger" and err.line == f.index[1200]
    assert f"temperatures repeat the same values for {len(f) - 1200} rows" in str(err)


def test_a_short_freeze_or_a_freeze_at_rest_passes():
    f = shipped()
    short = (f.index >= f.index[1200]) & (f.index < f.index[1400])  # 17 min
    for s in SENSORS:
        f.loc[short, s] = float(f.loc[f.index[1200], s])
    assert "stuck_logger" not in checks_of(run(f))
    f = shipped()
    rest = f.index >= f.index[1200]
    for s in SENSORS:
        f.loc[rest, s] = float(f.loc[f.index[1200], s])
    f.loc[rest, "disp_um"] = float(f.loc[f.index[1200], "disp_um"]) + np.random.default_rng(2).normal(
        0, 0.2, rest.sum()
    )
    assert run(f).warnings == []


def test_a_machine_at_rest_is_not_a_stuck_logger():
    f = shipped()
    for s in SENSORS:
        f[s] = float(f[s].iloc[0])
    f["disp_um"] = 0.2 * np.sin(np.arange(len(f)) / 50.0)
    f["speed_rpm"] = 0.0
    assert "stuck_logger" not in [*checks_of(run(f))]


# --------------------------------------------------------------------------- sparse_channel


@pytest.mark.parametrize("column", ["disp_um", "speed_rpm"])
def test_a_required_channel_in_few_rows_is_an_error(column):
    f = shipped()
    keep = np.zeros(len(f), bool)
    keep[[10, 500, 1500]] = True
    f.loc[~keep, column] = np.nan
    err = error_of(f)
    assert err.column == column
    assert f"sparse_channel: {column} has a value in only 3 of {len(f)} rows (0 %, less than 50 %)" in str(
        err
    )


def test_a_sparse_temperature_is_a_warning_and_half_the_rows_pass():
    f = shipped()
    f.loc[f.index[::3], "T2"] = np.nan
    f.loc[f.index[1::3], "T2"] = np.nan
    f.loc[f.index[::2], "disp_um"] = np.nan  # 50 %: enough
    report = run(f)
    assert checks_of(report) == ["sparse_channel"] and report.warnings[0].column == "T2"
    assert "T2 has a value in only" in report.warnings[0].message


# --------------------------------------------------------------------------- probe_sign (per file)


def test_a_reversed_probe_has_sign_minus_one():
    f = shipped()
    f["disp_um"] = -f["disp_um"]
    report = run(f)
    assert report.probe_sign == -1 and report.warnings == []


def test_no_evidence_gives_sign_zero():
    f = shipped()
    f["disp_um"] = np.random.default_rng(1).normal(0, 0.3, len(f))
    assert run(f).probe_sign == 0


def _room_ramp(frame: pd.DataFrame, kelvin: float) -> None:
    """Every sensor drifts by ``kelvin`` over the file, the displacement not at all."""
    for sensor in SENSORS:
        frame[sensor] = frame[sensor] + np.linspace(0.0, kelvin, len(frame))


def test_a_room_that_cools_while_the_spindle_heats_leaves_the_sign():
    # The row median of the temperatures falls with the room: correlated with it, the
    # displacement looked reversed (r = -0.61 here); the spindle's heat input does not.
    f = shipped()
    _room_ramp(f, -8.0)
    assert run(f).probe_sign == 1
    f["disp_um"] = -f["disp_um"]
    assert run(f).probe_sign == -1


def test_a_cool_down_at_rest_takes_its_sign_from_the_hottest_sensor_above_the_others():
    # A heating run played backwards at rest, in a room that warms by 8 K: the spindle's heat
    # input is flat, the median rises while the displacement falls (r = -0.61), the hottest
    # sensor's excess falls with it.
    f = shipped()
    cols = [*SENSORS, "disp_um"]
    f[cols] = f[cols].to_numpy()[::-1]
    f["speed_rpm"] = 0.0
    _room_ramp(f, 8.0)
    assert run(f).probe_sign == 1
    f["disp_um"] = -f["disp_um"]
    assert run(f).probe_sign == -1


# --------------------------------------------------------------------------- metadata


def test_metadata_naming_another_machine_is_a_warning():
    f = shipped()
    f.attrs["metadata"]["machine"] = "tapping-center-b"
    report = run(f)
    assert checks_of(report) == ["metadata_machine"]
    assert (
        "says machine 'tapping-center-b' but it lies in the folder of machine" in report.warnings[0].message
    )
    f.attrs["metadata"]["machine"] = "Tapping-Center-A "
    assert run(f).warnings == []


def test_metadata_period_off_by_more_than_half_is_an_error():
    f = shipped()
    f.attrs["metadata"]["sample_period_s"] = 60.0
    err = error_of(f, sample_period_s=None)
    assert err.column == "time"
    assert "metadata_period: the file's metadata sample_period_s is 60 s but the rows are 5 s apart" in str(
        err
    )
    f.attrs["metadata"]["sample_period_s"] = 7.0  # factor 1.4: tolerated
    assert run(f, sample_period_s=None).warnings == []


def test_rows_further_apart_than_configured_are_an_error_closer_a_warning():
    f = shipped()
    f.attrs["metadata"].pop("sample_period_s")
    assert "machine's sample_period_s (config.yaml) is 1 s" in str(error_of(f, sample_period_s=1.0))
    report = run(f, sample_period_s=15.0)
    assert checks_of(report) == ["metadata_period"] and "cleaning keeps one row per 15 s" in (
        report.warnings[0].message
    )


def test_every_check_id_is_documented():
    doc = (ROOT / "docs" / "raw-format.md").read_text(encoding="utf-8")
    section = doc[doc.index("## Checks") :]
    for check in (*FILE_CHECKS, "probe_sign", "duplicate_content"):
        assert f"`{check}`" in section, check


def test_errors_carry_their_check_id():
    f = shipped()
    f["disp_um"] = f["disp_um"] * 1000
    assert error_of(f).check == "displacement_unit"
    f = shipped()
    f.loc[f.index[40], "T4"] = 450.0
    assert error_of(f).check == "temperature_range"
    f = shipped()
    f["time"] = f["time"].where(f.index < 1000, f["time"] - pd.Timedelta(hours=1))
    assert error_of(f).check == "clock_reset"
    f = shipped()
    f["T6"] = np.nan
    assert error_of(f).check == "no_value"
