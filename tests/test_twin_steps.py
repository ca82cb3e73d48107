"""The steps of the twin's generators (rafi.twin.hostile, synthetic_defects, simulate, cli), one at a time.

Each input is built here from known values, so every test knows what the step must return.
"""

from __future__ import annotations

import argparse

import numpy as np
import pandas as pd
import pytest

from rafi import SENSORS
from rafi.twin.cli import add_arguments
from rafi.twin.hostile import (
    OPEN_CIRCUIT,
    OUTCOMES,
    SOURCES,
    _degf_from_half_way,
    _long_notes,
    _re_zero_half_way,
    _recipes,
    _second_half,
    _to_mm_one_glitch,
)
from rafi.twin.machines import DefectRates, machine_params
from rafi.twin.simulate import _defect_rates, _freeze_displacement, _logged_readings
from rafi.twin.synthetic_defects import _defect_table, _Injection, _placer, _written_frame


def _log(n: int = 10) -> pd.DataFrame:
    """A native log's data: temperatures 20 + row / 10, displacement = row, speed 3000."""
    frame = pd.DataFrame({"time": [f"2026-03-01T08:00:{k:02d}" for k in range(n)], "speed_rpm": 3000.0})
    for sensor in SENSORS:
        frame[sensor] = 20.0 + np.arange(n) / 10
    frame["disp_um"] = np.arange(n, dtype=float)
    return frame


# --------------------------------------------------------------------------- hostile


def test_every_recipe_names_a_source_an_outcome_and_a_distinct_case():
    recipes = _recipes(long_bytes=1234)
    assert len({r.name for r in recipes}) == len(recipes) == 30
    assert {r.source for r in recipes} == set(SOURCES)
    assert {r.outcome for r in recipes} <= set(OUTCOMES)
    assert next(r for r in recipes if r.name == "long_line").what == "a notes line of 1234 bytes"


def test_second_half_starts_at_the_middle_row():
    assert _second_half(_log(5)).tolist() == [False, False, True, True, True]


def test_degf_from_half_way_converts_the_second_half_but_not_the_open_circuit_codes():
    frame = _log(6)
    frame.loc[4, "T2"] = OPEN_CIRCUIT[0]
    _degf_from_half_way({}, frame)
    expected = 20.0 + np.arange(6) / 10
    expected[3:] = expected[3:] * 9 / 5 + 32
    np.testing.assert_allclose(frame["T1"], expected)
    assert frame.loc[4, "T2"] == OPEN_CIRCUIT[0] and frame.loc[5, "T2"] == pytest.approx(expected[5])


def test_re_zero_half_way_makes_the_displacement_jump_to_zero():
    frame = _log(10)
    _re_zero_half_way({}, frame)
    assert frame["disp_um"].tolist() == [0, 1, 2, 3, 4, 0, 1, 2, 3, 4]


def test_mm_with_one_glitch_divides_every_other_sample_by_1000():
    frame = _log(40)
    _to_mm_one_glitch({}, frame)
    glitch = frame["disp_um"] == 35.0
    assert glitch.sum() == 1 and 10 <= int(np.flatnonzero(glitch)[0]) < 30
    np.testing.assert_allclose(frame["disp_um"][~glitch], np.arange(40)[~glitch.to_numpy()] / 1000.0)


def test_long_notes_writes_a_notes_line_of_the_asked_length():
    meta = {"machine": "m"}
    _long_notes(7)(meta, _log())
    assert meta == {"machine": "m", "notes": "xxxxxxx"}


# --------------------------------------------------------------------------- synthetic_defects


def test_placer_keeps_the_margin_between_defects_and_says_when_there_is_no_room():
    place = _placer(np.random.default_rng(0), 200, margin=6)
    taken = [(p, p + 3) for p in (place(3) for _ in range(6))]
    for a, (start, end) in enumerate(taken):
        assert 8 <= start and end <= 200 - 8
        for other_start, other_end in taken[a + 1 :]:
            assert other_start >= end + 6 or other_end + 6 <= start
    with pytest.raises(RuntimeError, match="could not place all defects"):
        for _ in range(100):
            place(3)


def _state(n: int = 20) -> _Injection:
    log = pd.DataFrame(
        {"time": pd.date_range("2026-03-01", periods=n, freq="5s"), "T1": np.arange(n, dtype=float)},
        index=pd.Index(np.arange(2, 2 + n), name="line"),
    )
    return _Injection(log, log.copy(), np.arange(n, dtype=float), np.ones(n, bool), [], [], place=None)


def test_written_frame_and_defect_table_follow_a_gap_a_swap_and_a_duplicate():
    state = _state()
    state.keep[5:7] = False  # rows 5 and 6 lost
    state.record("gap", "time", 5, 2, last_pos=7)
    state.order_keys[10] = 11.25  # row 10 written after row 11
    state.record("swap", "time", 10, 1, last_pos=10)
    state.extra_rows.append((15.5, 15, {"T1": 99.0}))  # row 15 written again, T1 changed
    state.record("duplicate_differ", "time", 15, 1, last_pos=15)
    frame, line_of = _written_frame(state, first_line=2)
    written = [0, 1, 2, 3, 4, 7, 8, 9, 11, 10, 12, 13, 14, 15, 99, 16, 17, 18, 19]
    assert frame["T1"].tolist() == written
    assert frame.index.tolist() == list(range(2, 2 + len(written)))
    table = _defect_table(state.defects, line_of)
    assert table[["kind", "line", "last_line", "position"]].values.tolist() == [
        ["gap", 6, 7, 5],  # the rows around the gap: 4 (line 6) and 7 (line 7)
        ["swap", 10, 11, 10],  # row 11 written first, on line 10
        ["duplicate_differ", 16, 16, 15],
    ]


# --------------------------------------------------------------------------- simulate


def test_defect_rates_from_true_false_or_given():
    assert _defect_rates(True) == DefectRates()
    assert _defect_rates(False) == DefectRates.none() == _defect_rates(None)
    light = DefectRates.light()
    assert _defect_rates(light) is light


def test_logged_readings_are_quantised_and_the_speed_is_zero_at_rest():
    params = machine_params("tapping-center-a")
    n = 500
    temps_true = np.full((n, 16), 25.0)
    disp_true = np.linspace(0.0, 20.0, n)
    speeds = np.where(np.arange(n) < 250, 0.0, 6000.0)
    temps, disp, speed = _logged_readings(
        params, temps_true, disp_true, speeds, 5.0, np.random.default_rng(1)
    )
    np.testing.assert_allclose(
        temps / params.temp_quantum_c, np.round(temps / params.temp_quantum_c), atol=1e-6
    )
    np.testing.assert_allclose(
        disp / params.disp_quantum_um, np.round(disp / params.disp_quantum_um), atol=1e-6
    )
    assert (speed[:250] == 0).all() and (speed[250:] == np.round(speed[250:])).all()
    assert abs(temps.mean() - 25.0) < 0.05 and np.abs(disp - disp_true).max() < 10 * params.disp_noise_um


def test_freeze_displacement_holds_the_value_from_a_quarter_of_the_run():
    disp = np.arange(100, dtype=float)
    record = _freeze_displacement(disp)
    assert (disp[:25] == np.arange(25)).all() and (disp[25:] == 25.0).all()
    assert (record["kind"], record["src"], record["n_rows"], record["value"]) == (
        "stuck_displacement",
        25,
        75,
        25.0,
    )


# --------------------------------------------------------------------------- cli


def test_add_arguments_adds_every_mode_with_its_options():
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    day = parser.parse_args(["day", "--sensor-drift", "t8:0.4", "--speeds", "3000, 6000", "--no-defects"])
    assert (day.mode, day.machine, day.sensor_drift, day.speeds, day.no_defects) == (
        "day",
        "tapping-center-a",
        [("T8", 0.4)],
        [3000, 6000],
        True,
    )
    assert parser.parse_args(["shipped"]).out == "raw"
    assert parser.parse_args(["hostile", "--out", "x"]).long_bytes == 200_000
    assert parser.parse_args(["plot", "raw/m"]).pattern == "train_*.csv"
    assert parser.parse_args(["noise-floor"]).machine == "tapping-center-a"
    with pytest.raises(SystemExit):
        parser.parse_args(["day", "--sensor-drift", "X1:0.4"])
