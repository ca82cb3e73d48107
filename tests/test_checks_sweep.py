"""Hostile content found by sweeping variants over every shipped file of both machines (issue 13):
units on some sensors or from part way, many glitches, scale factors, rad/s, a speed stuck at
rest, copied sensors, a displacement made from a temperature; each check's message, and no false
alarm on the shipped files (tests/test_checks_hostile.py) or on twin days.

The variants are built from the shipped logs (known truth: the shipped files are good).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from test_checks_hostile import PROPS, SENSORS, A, B, checks_of, error_of, kwargs, run, shipped

from rafi.readers.checks import check_file
from rafi.readers.logs import read_log
from rafi.settings import machine_settings

OC = (-999.0, 999.9, 850.0)


def to_degf(f, names, rows=None):
    """Real readings of ``names`` (from row ``rows`` on, a boolean array) in deg F."""
    for s in names:
        v = f[s].astype(float)
        new = v.where(v.isin(OC), v * 1.8 + 32)
        f[s] = new if rows is None else v.where(~rows, new)


# --------------------------------------------------------------------------- temperature_unit


def test_degf_on_some_sensors_is_an_error_naming_them():
    f = shipped()
    to_degf(f, SENSORS[:8])
    err = error_of(f)
    assert err.check == "temperature_unit" and err.column == "T1"
    assert "8 sensor(s) look like deg F (T1, T2, T3, T4, T5, T6, T7, T8)" in str(err)
    assert "(= 22.6 deg C if deg F)" in str(err) and "the other 8 sensor(s) start at" in str(err)


def test_degf_on_one_sensor_is_an_error_not_only_a_far_sensor():
    f = shipped("thermal_log_2026-10-14.xlsx", B)
    to_degf(f, ["T5"])
    err = error_of(f, B)
    assert err.check == "temperature_unit" and "1 sensor(s) look like deg F (T5)" in str(err)
    assert "header 'Temperatur 5 [°C]'" in str(err)


def test_kelvin_on_some_sensors_is_a_unit_error_not_a_range_error():
    f = shipped()
    for s in SENSORS[8:]:
        f[s] = f[s].where(f[s].isin(OC), f[s] + 273.15)
    err = error_of(f)
    assert err.check == "temperature_unit" and "look like kelvin (T9," in str(err)


@given(names=st.sets(st.sampled_from(SENSORS), min_size=1, max_size=15))
@PROPS
def test_any_subset_of_sensors_in_degf_is_caught_and_nothing_crashes(names):
    f = shipped("valid_08000rpm.csv")
    to_degf(f, sorted(names))
    assert error_of(f).check == "temperature_unit"


def test_degf_from_half_way_is_an_error_at_the_line_it_starts():
    f = shipped("valid_13500rpm.csv")
    rows = np.arange(len(f)) >= len(f) // 2
    to_degf(f, SENSORS, rows)
    err = error_of(f)
    first = int(f.index[len(f) // 2])
    assert err.check == "temperature_unit" and err.line == first
    assert f"at line {first}, the deg F value of" in str(err) and "from this line on" in str(err)


def test_degf_until_half_way_is_an_error_too():
    f = shipped("multi_condition.csv")
    to_degf(f, SENSORS, np.arange(len(f)) < len(f) // 2)
    err = error_of(f)  # the coolest sensor starts in deg F
    assert err.check == "temperature_unit"
    f = shipped("multi_condition.csv")
    to_degf(f, SENSORS[:3], np.arange(len(f)) < len(f) // 2)
    assert error_of(f).check == "temperature_unit"


# --------------------------------------------------------------------------- displacement_unit


@given(share=st.floats(0.0, 0.08), value=st.sampled_from([35.0, -12.0, 999.0]), seed=st.integers(0, 99))
@PROPS
def test_mm_with_up_to_8_percent_glitches_is_an_error(share, value, seed):
    f = shipped("train_12000rpm.csv")
    f["disp_um"] = f["disp_um"] / 1000.0
    rows = np.random.default_rng(seed).choice(len(f), int(share * len(f)), replace=False)
    f.loc[f.index[rows], "disp_um"] = value
    assert error_of(f).check == "displacement_unit"


def test_mm_from_half_way_is_an_error_at_that_line():
    for name, machine in (("train_09000rpm.csv", A), ("thermal_log_2026-10-14.xlsx", B)):
        f = shipped(name, machine)
        half = np.arange(len(f)) >= len(f) // 2
        f["disp_um"] = np.where(half, f["disp_um"] / 1000.0, f["disp_um"])
        err = error_of(f, machine)
        assert err.check == "displacement_unit" and err.line == int(f.index[len(f) // 2])
        assert "a factor 1000: the values are in millimetres from this line on" in str(err)


@pytest.mark.parametrize(
    "factor, words", [(25.4, "too large (inches"), (1 / 25.4, "too small (mils"), (0.0254, "too small")]
)
@pytest.mark.parametrize("name", ["train_03000rpm.csv", "valid_16500rpm.csv", "multi_condition.csv"])
def test_a_scale_factor_on_the_displacement_is_a_warning(factor, words, name):
    f = shipped(name)
    f["disp_um"] = f["disp_um"] * factor
    report = run(f)
    assert checks_of(report) == ["displacement_unit"]
    w = report.warnings[0]
    assert w.column == "disp_um" and words in w.message and "outside the 0.2..15 um/K" in w.message


# --------------------------------------------------------------------------- speed_unit / speed_range


def test_rad_per_s_on_a_training_run_is_an_error():
    f = shipped("train_06000rpm.csv")
    f["speed_rpm"] = f["speed_rpm"] * 2 * np.pi / 60
    err = error_of(f)
    assert err.check == "speed_unit" and "x 9.549" in str(err) and "writes rad/s" in str(err)
    f = shipped("thermal_log_2026-10-14.xlsx", B)
    f["speed_rpm"] = f["speed_rpm"] * 2 * np.pi / 60
    assert "writes rad/s" in str(error_of(f, B))


@pytest.mark.parametrize("name", ["valid_04500rpm.csv", "valid_16500rpm.csv"])
def test_rad_per_s_on_a_validation_run_is_a_warning(name):
    f = shipped(name)
    f["speed_rpm"] = f["speed_rpm"] * 2 * np.pi / 60
    report = run(f)
    assert checks_of(report) == ["speed_range"]
    w = report.warnings[0]
    assert "below 0.8 x the lowest training speed 3000 r/min" in w.message
    assert "if rad/s" in w.message and w.column == "speed_rpm"


def test_a_run_just_below_the_lowest_training_speed_passes():
    f = shipped("valid_04500rpm.csv")
    f["speed_rpm"] = np.where(f["speed_rpm"] > 0, 2500.0, 0.0)  # 0.83 x 3000: not far below
    assert run(f).warnings == []


# --------------------------------------------------------------------------- constant_channel (speed)


@pytest.mark.parametrize("name, machine", [("train_15000rpm.csv", A), ("thermal_log_2026-10-14.xlsx", B)])
def test_a_speed_at_rest_while_the_machine_heats_is_a_warning(name, machine):
    f = shipped(name, machine)
    f["speed_rpm"] = 0.0
    report = run(f, machine)
    assert "constant_channel" in checks_of(report)
    w = next(w for w in report.warnings if w.check == "constant_channel")
    assert w.column == "speed_rpm" and "does not heat the machine" in w.message


def test_a_cool_down_at_rest_passes():
    f = shipped("thermal_log_2026-10-14.xlsx", B)
    rest = f.iloc[965:1675].copy()  # 4-7 h: the cool-down after the first run
    rest.attrs = f.attrs
    assert (rest["speed_rpm"] == 0).all()
    assert run(rest, B, min_run_s=0).warnings == []


# --------------------------------------------------------------------------- copied_channel


def test_every_sensor_a_copy_of_one_is_an_error():
    f = shipped()
    for s in SENSORS[1:]:
        f[s] = f["T1"].to_numpy()
    err = error_of(f)
    assert err.check == "copied_channel" and "all 16 temperatures hold the same values as T1" in str(err)


def test_one_copied_sensor_is_a_warning_naming_both():
    f = shipped("thermal_log_2026-10-14.xlsx", B)
    f["T9"] = f["T2"].to_numpy()
    report = run(f, B)
    assert checks_of(report) == ["copied_channel"]
    w = report.warnings[0]
    assert w.column == "T9" and "holds the same values as T2 (header 'Temperatur 2 [°C]')" in w.message


# --------------------------------------------------------------------------- swapped_channels (affine)


@given(scale=st.floats(0.5, 4.0), sensor=st.sampled_from(SENSORS))
@PROPS
def test_a_displacement_made_from_a_temperature_is_flagged(scale, sensor):
    f = shipped("train_18000rpm.csv")
    t = f[sensor].where(~f[sensor].isin(OC)).interpolate().bfill()
    f["disp_um"] = np.round(scale * (t - t.iloc[0]), 3)
    try:
        report = run(f)
    except Exception as err:  # a copy can also be certain (constant, stuck, swapped, unit)
        assert getattr(err, "check", None)
        return
    assert "swapped_channels" in checks_of(report) or "displacement_unit" in checks_of(report)


# --------------------------------------------------------------------------- no false alarms


def test_twin_days_trigger_no_check(tmp_path):
    """New days of both machines (other seeds, ambients, drift, wear, speeds) pass every check."""
    from rafi.twin.day import write_day

    written = write_day(tmp_path, machine=A, seed=5, ambient_shift=-10, validation_speeds=[4500], multi=True)
    written += write_day(
        tmp_path, machine=A, seed=6, ambient_shift=9, sensor_drift={"T3": 2.0}, speeds=[3000, 18000]
    )
    written += write_day(tmp_path, machine=B, seed=7, ambient_shift=8, wear=0.5, validation_speeds=[1500])
    from test_checks_hostile import _config

    for path in written:
        machine = path.parent.name
        frame = read_log(path, machine_settings(_config(), machine)["input"])
        report = check_file(frame, path, **kwargs(machine))
        assert report.warnings == [], (path.name, [w.detail for w in report.warnings])
        assert report.probe_sign >= 0, path.name  # never reversed (0: no clear evidence)


# --------------------------------------------------------------------------- part way: sign, steps, speed


def test_a_probe_sign_flipping_half_way_is_an_error_at_that_line():
    f = shipped("valid_10500rpm.csv")
    half = np.arange(len(f)) >= len(f) // 2
    f["disp_um"] = np.where(half, -f["disp_um"], f["disp_um"])
    err = error_of(f)
    assert err.check == "probe_sign" and err.line == int(f.index[len(f) // 2])
    assert "the probe's sign flips there" in str(err)


def test_a_re_zeroed_probe_is_a_warning_at_that_line():
    f = shipped("thermal_log_2026-10-14.xlsx", B)
    k = len(f) // 2
    f["disp_um"] = np.where(np.arange(len(f)) >= k, f["disp_um"] - f["disp_um"].iloc[k], f["disp_um"])
    report = run(f, B)
    assert checks_of(report) == ["displacement_step"]
    w = report.warnings[0]
    assert w.first_line == int(f.index[k]) and "a bumped or re-zeroed probe" in w.message


def test_a_small_offset_change_passes():
    f = shipped("train_06000rpm.csv")
    half = np.arange(len(f)) >= len(f) // 2
    f["disp_um"] = np.where(half, f["disp_um"] + 1.5, f["disp_um"])  # below 5 um
    assert run(f).warnings == []


@pytest.mark.parametrize("name", ["train_09000rpm.csv", "valid_04500rpm.csv", "multi_condition.csv"])
def test_speed_in_rev_per_s_from_half_way_is_an_error(name):
    f = shipped(name)
    half = np.arange(len(f)) >= len(f) // 2
    f["speed_rpm"] = np.where(half, f["speed_rpm"] / 60, f["speed_rpm"])
    err = error_of(f)
    assert err.check == "speed_unit" and "part of the log is written in rev/s" in str(err)


def test_a_clock_that_was_never_set_is_a_warning_and_shipped_clocks_are_not():
    for machine, name in ((A, "valid_04500rpm.csv"), (B, "thermal_log_2026-10-14.xlsx")):
        assert "clock_unset" not in checks_of(check_file(shipped(name, machine), name, **kwargs(machine)))
    frame = shipped("valid_04500rpm.csv")
    frame["time"] = frame["time"] - (frame["time"].min() - np.datetime64("1970-01-01T00:00:00"))
    (w,) = [w for w in check_file(frame, "x.csv", **kwargs(A)).warnings if w.check == "clock_unset"]
    assert w.column == "time" and "1970-01-01T00:00:00" in w.message and "never set" in w.message
