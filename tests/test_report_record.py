"""The report's test record (rafi.report.test_record) and its uncertainty statements
(rafi.report.verdict.residual_statement, the noise floors beside the max residuals).

Every test builds a synthetic ``runs.parquet``/``runs.csv`` whose truth is known by
construction: logs with a known clock and sample period, an ambient sensor on a known linear
ramp, and a displacement whose range per run is known.
"""

from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pytest
from html_tables import html_tables

from rafi.report.render import _environment
from rafi.report.test_record import (
    fmt_period,
    instrument_record,
    log_record,
    run_record,
    sample_period,
    section_test_record,
    with_log_clock,
)
from rafi.settings import machine_settings

START = pd.Timestamp("2026-01-05 08:00:00")


def _log(name, n, period, runs, *, clock=True, amb=(20.0, 21.5), dz_amp=None, start=START):
    """One log of ``n`` samples every ``period`` s, cut into ``runs`` (list of (run_id, first
    index, last index)); T16 ramps linearly from ``amb[0]`` to ``amb[1]`` over the log; dz of a
    run is 3 um plus a sine of amplitude ``dz_amp[run_id]`` (range = 2 * amplitude)."""
    t = np.arange(n) * float(period)
    frame = pd.DataFrame(
        {
            "log": name,
            "log_t_s": t,
            "time": (start + pd.to_timedelta(t, unit="s")) if clock else pd.NaT,
            "T1": 25.0 + 0.001 * t,
            "T16": np.linspace(amb[0], amb[1], n),
            "speed_rpm": 0.0,
        }
    )
    frame["dT1"], frame["dT16"] = frame["T1"] - 25.0, frame["T16"] - amb[0]  # as runs.parquet: each rise
    frame["run_id"] = ""
    frame["t_s"] = np.nan
    frame["dz_um"] = np.nan
    for rid, i0, i1 in runs:
        k = np.arange(i1 - i0 + 1)
        frame.loc[i0:i1, "run_id"] = rid
        frame.loc[i0:i1, "t_s"] = k * float(period)
        # a sine of period 200 samples reaches +-amp exactly at k = 50 and 150 (runs >= 151 samples)
        frame.loc[i0:i1, "dz_um"] = 3.0 + dz_amp[rid] * np.sin(2 * np.pi * k / 200)
    return frame


@pytest.fixture()
def synthetic():
    """Log A: 2 runs, 10 s, clock, T16 20.0 -> 21.5 degC; log B: 1 run, 5 s, no clock, T16
    constant 19.0 but one sample missing."""
    a = _log("a.csv", 801, 10, [("a#1", 0, 400), ("a#2", 401, 800)], dz_amp={"a#1": 2.5, "a#2": 4.0})
    b = _log("b.csv", 201, 5, [("b", 0, 200)], clock=False, amb=(19.0, 19.0), dz_amp={"b": 1.25})
    b.loc[50, "T16"] = np.nan
    frame = pd.concat([a, b], ignore_index=True)
    runs = pd.DataFrame(
        {
            "run_id": ["a#1", "a#2", "b"],
            "file": ["a.csv", "a.csv", "b.csv"],
            "role": ["training", "validation_single", "validation_idle"],
            "speed_rpm": [3000.0, 6000.0, 0.0],
            "speed_min_rpm": [2998.0, 5997.0, 0.0],
            "speed_max_rpm": [3003.0, 6002.0, 0.0],
            "duration_s": [4010.0, 4000.0, 1005.0],
        }
    )
    return frame, runs


def test_sample_period_is_the_median_step():
    assert sample_period([0, 15, 30, 45, 60]) == 15.0
    # a gap and a duplicate do not move the median step
    assert sample_period([0, 5, 5, 10, 15, 20, 500, 505, 510]) == 5.0
    assert np.isnan(sample_period([3.0]))
    assert fmt_period(15.0) == "15\u00a0s" and fmt_period(0.5) == "0.50\u00a0s"


def test_log_record_spans_periods_and_ambient(synthetic):
    frame, _ = synthetic
    logs = log_record(frame, "T16").set_index("log")
    a, b = logs.loc["a.csv"], logs.loc["b.csv"]
    assert a["first_time"] == START and a["last_time"] == START + pd.Timedelta(seconds=8000)
    assert a["period_s"] == 10.0 and b["period_s"] == 5.0
    assert a["duration_s"] == 8010.0 and b["duration_s"] == 1005.0  # 801 * 10, 201 * 5
    assert a["n_samples"] == 801 and b["n_samples"] == 201
    assert a["ambient_min_c"] == pytest.approx(20.0)
    assert a["ambient_max_c"] == pytest.approx(21.5)
    assert a["ambient_variation_k"] == pytest.approx(1.5)
    assert pd.isna(b["first_time"]) and b["ambient_variation_k"] == 0.0  # the NaN sample ignored
    none = log_record(frame, None)
    assert none["ambient_variation_k"].isna().all()


def test_run_record_thermal_drift_is_the_dz_range(synthetic):
    frame, runs = synthetic
    rr = run_record(frame, runs, "T16").set_index("run_id")
    assert rr.loc["a#1", "thermal_drift_um"] == pytest.approx(5.0)
    assert rr.loc["a#2", "thermal_drift_um"] == pytest.approx(8.0)
    assert rr.loc["b", "thermal_drift_um"] == pytest.approx(2.5)
    assert rr.loc["a#1", "dz_min_um"] == pytest.approx(0.5) and rr.loc["a#1", "dz_max_um"] == pytest.approx(
        5.5
    )
    # the ramp of 1.5 K over 800 steps: run a#1 covers steps 0..400, a#2 401..800
    assert rr.loc["a#1", "ambient_variation_k"] == pytest.approx(1.5 * 400 / 800)
    assert rr.loc["a#2", "ambient_variation_k"] == pytest.approx(1.5 * 399 / 800)
    assert rr.loc["a#2", "first_time"] == START + pd.Timedelta(seconds=4010)
    assert list(rr.index) == ["a#1", "a#2", "b"] and rr.loc["a#2", "role"] == "validation_single"
    assert rr.loc["a#2", "speed_rpm"] == 6000.0 and rr.loc["b", "log"] == "b.csv"


def _settings(**report):
    cfg = {"machines": {"m": {"report": report}}} if report else {}
    return machine_settings(cfg, "m")


def test_instrument_record_lists_what_is_missing():
    s = _settings()
    inst = instrument_record(s["report"]["instruments"], None, ["T1", "T16"], {})
    missing = " ".join(inst["missing"])
    for what in (
        "machine serial",
        "controller",
        "probe",
        "ambient sensor",
        "sensor positions",
        "calibration",
    ):
        assert what in missing
    full = {
        "machine_serial": "SN 4711",
        "controller": "SINUMERIK 840D sl",
        "probe": "Pulsotronic KJ2-M8MB40-ANU",
        "sensor_positions": {"T1": "spindle front", "T16": "room air"},
        "calibration": {"probe": "2026-01-02", "T16": "2026-02-01", "T1": "last spring"},
    }
    inst = instrument_record(full, "T16", ["T1", "T16"], {"T16": "ambient"}, START)
    assert inst["missing"] == []
    flags = {name: flag for name, _, flag in inst["calibration"]}
    assert flags == {"probe": "", "T16": "after the last logged sample", "T1": "not an ISO 8601 date"}
    part = dict(full, sensor_positions={"T1": "spindle front"})
    assert instrument_record(part, "T16", ["T1", "T16"], {})["missing"] == [
        "positions of T16 (report.instruments.sensor_positions)"
    ]


def _render_section(ctx: dict) -> str:
    tpl = _environment().get_template("sections/test_record.html.j2")
    return tpl.render(
        test_record=ctx, section_by_id={"test_record": {"id": "test_record", "number": 3, "title": "T"}}
    )


def test_section_without_ambient_sensor_states_no_number(synthetic):
    frame, runs = synthetic
    res = {"runs_parquet": frame, "runs_csv": runs, "key_sensors_json": {"sensors": ["T1"]}}
    ctx = section_test_record(res, _settings())
    assert ctx["ambient"] is None
    html = _render_section(ctx)
    (logs,) = html_tables(html, "num test-logs")
    (per_run,) = html_tables(html, "num test-runs")
    assert not any("ambient" in h for h in logs["headers"])
    assert not any("temperature variation" in h for h in per_run["headers"])
    assert "Ambient temperature not measured" in html and "Test conditions missing" in html
    assert "\u00b0C" not in html  # no temperature is stated
    # the configured default (5 s) differs from log A's 10 s: said
    assert "10\u00a0s" in ctx["period_note"] and "sample_period_s = 5\u00a0s" in ctx["period_note"]


def test_section_with_ambient_sensor_and_instruments(synthetic):
    frame, runs = synthetic
    res = {"runs_parquet": frame, "runs_csv": runs, "key_sensors_json": {"sensors": ["T1"]}}
    inst = {
        "machine_serial": "SN 4711",
        "controller": "SINUMERIK 840D sl",
        "probe": "inductive probe",
        "sensor_positions": {"T1": "spindle front", "T16": "room air, 1 m from the machine"},
        "calibration": {"probe": "2025-12-01"},
    }
    ctx = section_test_record(res, _settings(ambient_sensor="T16", instruments=inst))
    assert ctx["missing"] == []
    html = _render_section(ctx)
    (logs,) = html_tables(html, "num test-logs")
    (per_run,) = html_tables(html, "num test-runs")
    a = [c["text"] for c in logs["rows"][0]]
    assert a[1] == "2026-01-05 08:00:00" and a[2] == "10:13:20" and a[5] == "10\u00a0s"
    # a speed ("12 000 r/min") never breaks after "r/": its cells are the number cells' (class n)
    speeds = [row[per_run["headers"].index("speed")] for row in per_run["rows"]]
    assert speeds and all("r/min" in c["text"] and "n" in c["cls"].split() for c in speeds)
    assert a[-3:] == ["20.00", "21.50", "1.50"]
    b = [c["text"] for c in logs["rows"][1]]
    # log B has no clock: its span in hours since its first sample (200 steps of 5 s), no date
    assert (b[1], b[2]) == ("+0.00\u00a0h", "+0.28\u00a0h") and b[5] == "5\u00a0s" and b[-1] == "0.00"
    assert ctx["no_clock"] == ["b.csv"] and "b.csv has elapsed" in html
    assert len(per_run["headers"]) == len(per_run["widths"]) == len(per_run["rows"][0])
    assert len(logs["headers"]) == len(logs["widths"]) == len(logs["rows"][0])
    drift = [r[-2]["html"] for r in per_run["rows"]]
    assert drift == ["<b>5.00</b>", "<b>8.00</b>", "<b>2.50</b>"]
    assert "Test conditions missing" not in html and "not measured" not in html
    assert "SN 4711" in html and "room air, 1 m from the machine" in html and "2025-12-01" in html
    assert "key sensor of RAFI" in html and "ambient" in html


def test_section_one_run_per_log_is_one_table(synthetic):
    frame, runs = synthetic
    frame = frame[frame["run_id"] != "a#2"].reset_index(drop=True)
    runs = runs[runs["run_id"] != "a#2"].reset_index(drop=True)
    ctx = section_test_record({"runs_parquet": frame, "runs_csv": runs}, _settings(ambient_sensor="T16"))
    assert ctx["runs"] is None
    (t,) = html_tables(_render_section(ctx), "num test-logs")
    assert len(t["headers"]) == len(t["widths"]) == len(t["rows"][0]) and 99 <= sum(t["widths"]) <= 100
    row = t["records"][0]
    assert row["role"] == "training" and row["speed"] == "3\u00a0000\u00a0r/min"
    drift = next(c["html"] for h, c in zip(t["headers"], t["rows"][0]) if h.startswith("thermal drift"))
    assert drift == "<b>5.00</b>"
    # a#1 alone: samples 0..400 of the ramp 20.0 -> 21.5 over 800 steps
    variation = next(v for h, v in row.items() if h.startswith("environmental"))
    assert variation == "0.75"
    assert "Logs and the thermal drift of their runs" in _render_section(ctx)


def test_a_log_without_a_clock_shows_hours_since_its_first_sample_never_a_date():
    """An elapsed-seconds log without input.time.start: runs.parquet's time is NaT (rafi.method.runs)
    and every span is hours on the log's clock (log_t_s), whatever the epoch behind the times."""
    cut = [("c#1", 0, 359), ("c#2", 360, 720)]
    log = _log("c.csv", 721, 20, cut, clock=False, dz_amp={"c#1": 1, "c#2": 2})
    runs = pd.DataFrame(
        {"run_id": ["c#1", "c#2"], "file": ["c.csv"] * 2, "role": ["training", "validation_single"]}
    )
    ctx = section_test_record({"runs_parquet": log, "runs_csv": runs}, _settings())
    html = _render_section(ctx)
    (logs,) = html_tables(html, "num test-logs")
    (per_run,) = html_tables(html, "num test-runs")
    assert [c["text"] for c in logs["rows"][0]][1:3] == ["+0.00\u00a0h", "+4.00\u00a0h"]  # 720 x 20 s
    spans = [[c["text"] for c in row][3:5] for row in per_run["rows"]]
    assert spans == [["+0.00\u00a0h", "+1.99\u00a0h"], ["+2.00\u00a0h", "+4.00\u00a0h"]]  # 359, 360 x 20 s
    assert "the log has elapsed" in html and "input.time.start" in html
    assert "Times are the logged clock" not in html and not re.search(r"\b(19|20)\d\d-\d\d-\d\d", html)


def test_section_without_runs_parquet_still_lists_the_conditions():
    ctx = section_test_record({"runs_parquet": None, "runs_csv": None}, _settings())
    assert ctx["logs"] is None and ctx["runs"] is None and ctx["missing"]
    assert "No per-sample table" in _render_section(ctx)


def test_old_runs_parquet_without_log_columns_gets_them_from_runs_csv(synthetic):
    frame, runs = synthetic
    old = frame.drop(columns=["log", "log_t_s"])
    runs = runs.assign(start_s=[0.0, 4010.0, 0.0])
    got = with_log_clock(old, runs)
    assert (got["log"] == frame["log"]).all()
    np.testing.assert_allclose(got["log_t_s"], frame["log_t_s"])
    pd.testing.assert_frame_equal(log_record(got, "T16"), log_record(frame, "T16"))


# --------------------------------------------------------------------------- uncertainty


def _validation_summary():
    return pd.DataFrame(
        {
            "run_id": ["v1", "v2", "idle"],
            "role": ["validation_single", "validation_multi", "validation_idle"],
            "duration_s": [3600.0, 7200.0, 1800.0],
            "max_abs_before_um": [10.0, 20.0, 5.0],
            "max_abs_after_um": [2.0, 3.5, 1.25],
            "improvement_pct": [80.0, 82.5, 75.0],
            "rmse_before_um": [6.0, 12.0, 3.0],
            "rmse_after_um": [0.8, 1.1, 0.4],
            "n_samples": [720, 1440, 360],
            "n_outside_temp_range": [0, 100, 20],
            "worse_than_uncompensated": [False, False, False],
            "noise_floor_um": [0.61, 0.93, 0.72],
        }
    )


def test_residual_statement_numbers_come_from_the_tables():
    from rafi.report.verdict import residual_statement

    model = {"speeds": [{"speed_rpm": 1000.0}, {"speed_rpm": 4000.0}]}
    res = {"validation_summary": _validation_summary(), "model": model}
    st = residual_statement(res, _settings(instruments={"probe": "KJ2 inductive"}))
    assert (st["noise_lo"], st["noise_hi"], st["n_runs"]) == ("0.61", "0.93\u00a0\u00b5m", 3)
    # without a comparison: RAFI as published's trained speeds and samples (the offered model's:
    # tests/test_report_trained_range.py)
    assert st["speeds"] == "1\u00a0000\u20134\u00a0000\u00a0r/min" and st["model"] == "RAFI as published"
    assert (st["n_temp"], st["n_samples"]) == (120, 2520) and st["probe"] == "KJ2 inductive"
    assert st["n_speed"] is None  # no n_outside_speed_range column: nothing said
    no_noise = _validation_summary().drop(columns="noise_floor_um")
    assert residual_statement({"validation_summary": no_noise, "model": model}, _settings()) is None
    # one trained speed is printed once, never "3 000-3 000 r/min"
    one = {"validation_summary": _validation_summary(), "model": {"speeds": [{"speed_rpm": 3000.0}]}}
    assert residual_statement(one, _settings())["speeds"] == "3\u00a0000\u00a0r/min"


def test_one_trained_speed_is_printed_once_in_the_deployed_section_and_the_comparison():
    from rafi.report.comparison_section import _trained_speeds
    from rafi.report.deployed_section import _speed_span

    assert _speed_span([3000.0, 3000.0]) == "3\u00a0000 r/min"
    assert _speed_span([3000.0, 18000.0]) == "3\u00a0000 \u2026 18\u00a0000 r/min"
    one = {"speeds": [{"speed_rpm": 3000.0}, {"speed_rpm": 3000.0}]}
    assert _trained_speeds(one) == "trained speed 3\u00a0000\u00a0r/min"
    three = {"speeds": [{"speed_rpm": s} for s in (9000.0, 3000.0, 18000.0)]}
    assert _trained_speeds(three) == "trained speeds 3\u00a0000\u201318\u00a0000\u00a0r/min"
    ranged = {"speed_range_rpm": [0.0, 5000.0]}
    assert _trained_speeds(ranged) == "trained speeds 0\u20135\u00a0000\u00a0r/min"


def test_worst_residual_of_a_decision_carries_its_runs_noise_floor():
    from rafi.report.registry_section import worst_with_noise

    rec = {"max_residual_um": 3.5, "runs": {"v1": {"max_abs_after_um": 2.0}, "v2": {"max_abs_after_um": 3.5}}}
    noise = {"v1": 0.61, "v2": 0.93}
    assert worst_with_noise(rec, noise) == {"value": 3.5, "noise": 0.93}
    assert worst_with_noise(rec, {"v1": 0.61}) == {"value": 3.5, "noise": None}  # no floor for v2
    assert worst_with_noise(None, noise) == {"value": None, "noise": None}
    # as the registry section prints it
    macro = _environment().get_template("macros.html.j2").module.with_noise
    shown = str(macro(worst_with_noise(rec, noise)))
    assert shown == "3.50\u00a0\u00b5m (noise floor of that run 0.93\u00a0\u00b5m)"
    assert str(macro(worst_with_noise(rec, {"v1": 0.61}))) == "3.50\u00a0\u00b5m"
    assert str(macro(worst_with_noise(None, noise))) == "\u2013"


def test_idle_runs_are_listed_with_their_noise_floor():
    from rafi.report.model_sections import idle_rows

    s = _validation_summary()
    rows = idle_rows(s[s["role"] == "validation_idle"], {"idle": 0.72})
    assert len(rows) == 1 and idle_rows(s.iloc[0:0], {}) is None
    assert (rows[0]["max_abs_after_um"], rows[0]["noise_floor_um"]) == (1.25, 0.72)
    # as the validation section shows them
    validation = {"single": None, "ranges": None, "figure_single": None, "multi": [], "figure_idle": None}
    validation |= {"interval": None, "coverage": False, "band": False}  # results without an interval
    html = (
        _environment()
        .get_template("sections/validation.html.j2")
        .render(
            validation={**validation, "n_idle": 1, "idle": rows, "paper": False},
            section_by_id={"validation": {"id": "validation", "number": 7, "title": "Validation"}},
            fig_offset=0,
        )
    )
    cells = re.findall(r"<td[^>]*>(.*?)</td>", html)
    assert cells[3:5] == ["1.25", "0.72"]  # max |residual| after, noise floor


def test_the_thermal_drift_names_the_probe_it_was_measured_on(synthetic):
    """Section "Test record" says on which probe dz was measured with the verdict's words
    (:func:`rafi.report.probe.probe_words`), never the paper rig's spindle axis on another machine."""
    frame, runs = synthetic
    res = {"runs_parquet": frame, "runs_csv": runs}
    probes = {"format": "csv", "probes": {"ch3": {"column": "ch3(um)"}}}
    ch3 = machine_settings({"machines": {"m": {"input": probes}}}, "m@ch3")
    cases = [
        (ch3, "on probe ch3 (channel 'ch3(um)')"),
        (_settings(), "on the machine's displacement channel (disp_um)"),
        (_settings(paper_rig=True), "on the spindle axis (Z)"),
    ]
    for settings, words in cases:
        ctx = section_test_record(res, settings)
        assert ctx["measured"] == words
        text = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", "", _render_section(ctx))).replace("&#39;", "'")
        assert f"displacement change dz {words} over the run" in text
        if "spindle axis" not in words:
            assert "axial" not in text and "Z)" not in text
