"""rafi.method.clean against synthetic logs with injected defects and known truth."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from rafi import SENSORS
from rafi.errors import RawFormatError
from rafi.method.audit import SUMMARY_COLUMNS, summarise_audit
from rafi.method.clean import AUDIT_COLUMNS, clean_log
from rafi.readers.native import format_raw_log, read_raw_log
from rafi.twin.synthetic_logs import CLEAN_KWARGS, OPEN_CIRCUIT, canonical_log, inject_defects

KW = CLEAN_KWARGS
SENSORS = list(SENSORS)
SENSOR_COLS = [*SENSORS, "disp_um"]


def clean(frame, **over):
    return clean_log(frame, **{**KW, **over})


def counts(audit):
    return audit.groupby("action")["n_rows"].sum().to_dict()


@pytest.fixture(scope="module")
def log_truth():
    return canonical_log(3000, seed=3)


@pytest.fixture(scope="module")
def defective(log_truth):
    log, truth = log_truth
    frame, defects = inject_defects(
        log,
        duplicates=3,
        duplicates_differ=2,
        swaps=4,
        spikes=6,
        bursts=4,
        dropouts=5,
        open_circuit=3,
        gaps=4,
        seed=11,
    )
    out, audit = clean(frame)
    return log, truth, frame, defects, out, audit


# --------------------------------------------------------------------------- no defects


def test_clean_log_without_defects_is_identity(log_truth):
    log, _ = log_truth
    out, audit = clean(log)
    assert list(out.columns) == ["time", "t_s", "speed_rpm", *SENSORS, "disp_um", "segment", "ambient_c"]
    assert len(out) == len(log)
    assert (out["segment"] == 0).all() and out["segment"].dtype == np.int64
    assert out["time"].dtype == "datetime64[ns]"
    np.testing.assert_array_equal(out["t_s"], np.arange(len(log)) * 5.0)
    for c in ["speed_rpm", *SENSOR_COLS, "ambient_c"]:
        np.testing.assert_array_equal(out[c].to_numpy(), log[c].to_numpy(), err_msg=c)
    # only the text extra is reported
    assert audit["action"].tolist() == ["column_dropped"]
    assert audit["column"].tolist() == ["operator"]
    assert list(audit.columns) == list(AUDIT_COLUMNS)


def test_audit_table_is_empty_but_typed_without_extras():
    log, _ = canonical_log(200, extras=False)
    out, audit = clean(log)
    assert len(audit) == 0 and list(audit.columns) == list(AUDIT_COLUMNS)
    assert audit["first_line"].dtype == np.int64


# --------------------------------------------------------------------------- injected defects


def test_audit_counts_equal_injected_counts(defective):
    _, _, frame, defects, out, audit = defective
    c = counts(audit)
    inj = defects.groupby("kind")["n_rows"].sum().to_dict()
    assert c["duplicate_dropped"] == inj["duplicate"] + inj["duplicate_differ"]
    assert c["reordered"] == inj["swap"]
    assert c["spike_replaced"] == inj["spike"]
    assert c["open_circuit_removed"] == inj["open_circuit"]
    assert c["gap_interpolated"] == inj["gap"]  # rows inserted
    assert (audit["action"] == "gap_interpolated").sum() == (defects["kind"] == "gap").sum()
    # open-circuit values become dropouts that are interpolated
    assert c["dropout_interpolated"] == inj["dropout"] + inj["open_circuit"]
    assert "gap_split" not in c and "dropout_left_nan" not in c
    assert len(out) == 3000  # back on the full grid
    summary = summarise_audit("log.csv", "f" * 64, len(frame), out, audit)
    assert list(summary.columns) == list(SUMMARY_COLUMNS)
    s = summary.iloc[0]
    assert s["rows_in"] == len(frame) and s["rows_out"] == 3000
    assert s["duplicates_dropped"] == 5 and s["reordered"] == 4 and s["spikes_replaced"] == inj["spike"]
    assert inj["spike"] > 10  # six single samples and four bursts of 2-3 samples
    assert s["gaps_interpolated"] == 4 and s["segments"] == 1
    assert s["values_interpolated"] == inj["dropout"] + inj["open_circuit"]
    assert s["status"] == "ok" and s["reason"] == ""


def test_audit_lines_are_the_source_lines(defective):
    _, _, frame, defects, _, audit = defective
    match = {
        "duplicate": "duplicate_dropped",
        "duplicate_differ": "duplicate_dropped",
        "swap": "reordered",
        "spike": "spike_replaced",
        "open_circuit": "open_circuit_removed",
        "dropout": "dropout_interpolated",
        "gap": "gap_interpolated",
    }
    for d in defects.itertuples():
        rows = audit[(audit["action"] == match[d.kind]) & (audit["first_line"] == d.line)]
        assert len(rows) == 1, d
        r = rows.iloc[0]
        assert r["last_line"] == d.last_line and r["n_rows"] == d.n_rows, (d, r)
        if d.kind in ("spike", "dropout", "open_circuit"):
            assert r["column"] == d.column
    # the line numbers really point at the rows of the frame that was cleaned
    for d in defects[defects["kind"] == "spike"].itertuples():
        truth_value = frame.loc[d.line - 1, d.column]
        assert abs(frame.loc[d.line, d.column] - truth_value) > 4


def test_duplicate_with_other_values_keeps_first_and_says_so(defective):
    _, _, frame, defects, out, audit = defective
    differ = defects[defects["kind"] == "duplicate_differ"]
    for d in differ.itertuples():
        row = audit[(audit["action"] == "duplicate_dropped") & (audit["first_line"] == d.line)]
        assert "differs in T1" in row["detail"].iloc[0]
        kept = frame.loc[d.line - 1]
        t = out.loc[out["time"] == kept["time"], "T1"]
        assert t.iloc[0] == kept["T1"]  # first row kept, not the copy


def test_values_match_truth_after_cleaning(defective):
    log, truth, _, defects, out, _ = defective
    out = out.set_index(log.index)  # same grid as the defect-free log
    touched = np.zeros(len(log), bool)
    ambiguous = np.zeros(len(log), bool)  # a gap over the speed step: the jump time is unknown
    step = np.flatnonzero(np.diff(log["speed_rpm"].to_numpy())) + 1
    for d in defects.itertuples():
        window = slice(max(d.position - 1, 0), d.position + d.n_rows + 1)
        touched[window] = True
        if d.kind == "gap" and ((step >= window.start) & (step < window.stop)).any():
            ambiguous[window] = True
    untouched = ~touched
    for c in ["speed_rpm", *SENSOR_COLS, "ambient_c"]:
        # rows no defect touched come through bit-identical
        np.testing.assert_array_equal(out[c].to_numpy()[untouched], log[c].to_numpy()[untouched])
        if c == "speed_rpm":  # piecewise constant: only the logged set points appear
            assert set(out[c]) == set(log[c])
            continue
        # repaired rows are within noise of the truth (temps: sigma 0.02 K, disp 0.1 um)
        tol = 0.5 if c == "disp_um" else 0.12
        err = np.abs(out[c].to_numpy() - truth[c].to_numpy())
        assert err[touched & ~ambiguous].max() < tol, c
    np.testing.assert_array_equal(out["time"].to_numpy(), log["time"].to_numpy())
    assert out[SENSOR_COLS].notna().all().all()


def test_raw_frame_is_never_mutated(defective):
    log, _, frame, _, _, _ = defective
    snapshot = frame.copy(deep=True)
    attrs = {"metadata": {"machine": "m"}, "source": "x", "sha256": "0"}
    frame.attrs = attrs
    out, _ = clean(frame)
    pd.testing.assert_frame_equal(frame, snapshot)
    assert frame.attrs == attrs and out.attrs == attrs
    out.attrs["metadata"]["machine"] = "changed"
    assert frame.attrs["metadata"]["machine"] == "m"
    out.iloc[:, 2:] = 0.0
    pd.testing.assert_frame_equal(frame, snapshot)


# --------------------------------------------------------------------------- gaps and time


def test_long_gap_splits_into_segments_and_is_never_bridged(log_truth):
    log, _ = log_truth
    frame, defects = inject_defects(log, long_gaps=1, gaps=1, seed=2)
    out, audit = clean(frame)
    assert sorted(out["segment"].unique()) == [0, 1]
    long = defects[defects["kind"] == "long_gap"].iloc[0]
    split = audit[audit["action"] == "gap_split"]
    assert len(split) == 1
    assert split["first_line"].iloc[0] == long.line and split["last_line"].iloc[0] == long.last_line
    assert split["n_rows"].iloc[0] == long.n_rows
    assert len(out) == len(log) - long.n_rows  # nothing inserted in the long gap
    assert out[SENSOR_COLS].notna().all().all()
    first_of_1 = out.index[out["segment"] == 1][0]
    assert out["t_s"].iloc[first_of_1] - out["t_s"].iloc[first_of_1 - 1] == 5.0 * (long.n_rows + 1)
    assert summarise_audit("f", "s", len(frame), out, audit)["segments"].iloc[0] == 2


def test_gap_limit_is_the_time_between_valid_samples(log_truth):
    log, _ = log_truth
    # 11 missing rows -> 60 s between samples: interpolated; 12 missing -> 65 s: split
    for missing, segments in ((11, 1), (12, 2)):
        frame = log.drop(log.index[100 : 100 + missing])
        out, audit = clean(frame)
        assert out["segment"].nunique() == segments, missing


def test_backwards_clock_jump_raises_with_line():
    log, _ = canonical_log(600, extras=False)
    frame = log.copy()
    frame.loc[frame.index >= 302, "time"] -= pd.Timedelta(hours=1)  # clock reset at line 302
    with pytest.raises(RawFormatError) as err:
        clean(frame)
    e = err.value
    assert e.line == 302 and e.column == "time" and e.path == "log.csv"
    assert "timestamps go backwards by 3595 s at line 302; expected increasing times" in str(e)


def test_small_swap_is_sorted_not_an_error():
    log, _ = canonical_log(100, extras=False)
    order = list(range(100))
    order[10], order[12] = order[12], order[10]  # a row 2 places late
    frame = log.iloc[order]
    out, audit = clean(frame)
    pd.testing.assert_series_equal(out["T1"], log["T1"].reset_index(drop=True))
    assert counts(audit)["reordered"] == 2  # two backwards steps


def test_jittered_timestamps_are_snapped_to_the_grid():
    log, _ = canonical_log(500, extras=False)
    rng = np.random.default_rng(0)
    frame = log.copy()
    frame["time"] = frame["time"] + pd.to_timedelta(rng.uniform(-1.2, 1.2, 500), unit="s")
    frame.iloc[0, 0] = log["time"].iloc[0]
    out, audit = clean(frame)
    np.testing.assert_array_equal(out["time"].to_numpy(), log["time"].to_numpy())
    np.testing.assert_array_equal(out["t_s"], np.arange(500) * 5.0)
    assert (audit["action"] == "time_snapped").sum() == 1


def test_two_rows_on_one_grid_point_keep_the_first():
    log, _ = canonical_log(100, extras=False)
    frame = log.copy()
    frame.loc[frame.index[20], "time"] = frame["time"].iloc[19] + pd.Timedelta(seconds=1)
    out, audit = clean(frame)
    dup = audit[audit["action"] == "duplicate_dropped"]
    assert len(dup) == 1 and dup["first_line"].iloc[0] == log.index[20]
    assert "same 5 s grid point" in dup["detail"].iloc[0]
    assert out["T2"].iloc[19] == log["T2"].iloc[19]
    assert np.isclose(out["T2"].iloc[20], (log["T2"].iloc[19] + log["T2"].iloc[21]) / 2)


def test_wrong_sample_period_is_reported():
    log, _ = canonical_log(100, extras=False)
    with pytest.raises(RawFormatError, match="median time between samples is 5 s"):
        clean(log, sample_period_s=1.0)


# --------------------------------------------------------------------------- values


def test_speed_is_never_blended_across_a_gap():
    log, _ = canonical_log(400, steps=((0, 6000.0), (1000.0, 9000.0)), extras=False)
    # rows 198..202 (t = 990..1010 s) missing: the speed changes inside the gap
    frame = log.drop(log.index[198:203])
    out, audit = clean(frame)
    assert set(out["speed_rpm"].unique()) == {6000.0, 9000.0}
    assert (out["speed_rpm"].iloc[:203] == 6000.0).all()  # carried forward
    assert (out["speed_rpm"].iloc[203:] == 9000.0).all()


def test_speed_dropout_takes_previous_value():
    log, _ = canonical_log(100, extras=False)
    frame = log.copy()
    frame.loc[frame.index[40:43], "speed_rpm"] = np.nan
    frame.loc[frame.index[0], "speed_rpm"] = np.nan
    out, audit = clean(frame)
    assert out["speed_rpm"].notna().all() and set(out["speed_rpm"]) == {6000.0}
    assert counts(audit)["speed_filled"] == 4


def test_step_in_displacement_is_not_a_spike():
    log, _ = canonical_log(600, steps=((0, 3000.0), (1500.0, 18000.0)), extras=False, noise_disp=0.05)
    frame = log.copy()
    frame.loc[frame.index >= frame.index[300], "disp_um"] += 8.0  # a real jump
    out, audit = clean(frame)
    assert "spike_replaced" not in set(audit["action"])
    np.testing.assert_array_equal(out["disp_um"], frame["disp_um"].to_numpy())


def test_spike_detection_floor_on_quantised_signal():
    log, _ = canonical_log(300, extras=False, noise_temp=0.0)
    frame = log.copy()
    frame[SENSORS] = frame[SENSORS].round(2)  # slow, quantised: MAD of diffs ~ 0
    frame.loc[frame.index[150], "T4"] += 1.0
    out, audit = clean(frame)
    spikes = audit[audit["action"] == "spike_replaced"]
    assert spikes[["column", "first_line"]].values.tolist() == [["T4", int(frame.index[150])]]


def test_long_dropout_is_left_nan_and_recorded():
    log, _ = canonical_log(300, extras=False)
    frame = log.copy()
    frame.loc[frame.index[100:130], "T7"] = np.nan  # 155 s between valid samples
    frame.loc[frame.index[:3], "T8"] = np.nan  # at the start of the log
    out, audit = clean(frame)
    assert out["T7"].iloc[100:130].isna().all() and out["T7"].notna().sum() == 270
    assert out["T8"].iloc[:3].isna().all()
    left = audit[audit["action"] == "dropout_left_nan"].set_index("column")
    assert left.loc["T7", "n_rows"] == 30
    assert (left.loc["T7", "first_line"], left.loc["T7", "last_line"]) == (frame.index[100], frame.index[129])
    assert left.loc["T8", "n_rows"] == 3 and "start or end of a segment" in left.loc["T8", "detail"]
    # what the later steps do with it, as they do it (rafi.family.features.usable_sensors)
    assert "ridge models leave the sensor out" in left.loc["T7", "detail"]
    s = summarise_audit("f", "s", 300, out, audit).iloc[0]
    assert s["values_interpolated"] == 0


def test_open_circuit_recorded_per_sensor_and_line_range():
    log, _ = canonical_log(200, extras=False)
    frame = log.copy()
    frame.loc[frame.index[50:53], "T3"] = OPEN_CIRCUIT
    frame.loc[frame.index[80], "T3"] = 850.0
    frame.loc[frame.index[80], "T12"] = 999.9
    out, audit = clean(frame)
    oc = audit[audit["action"] == "open_circuit_removed"]
    got = sorted(oc[["column", "first_line", "last_line", "n_rows"]].values.tolist())
    i = frame.index
    assert got == sorted([["T3", i[50], i[52], 3], ["T3", i[80], i[80], 1], ["T12", i[80], i[80], 1]])
    assert out[SENSORS].abs().max().max() < 100


def test_summary_counts_and_names_the_values_left_missing():
    """Values the cleaning could not fill are counted and named in the file's summary row (sensor,
    source lines, open circuit or absent), beside the values it interpolated."""
    log, _ = canonical_log(400, extras=False)
    frame = log.copy()
    i = frame.index
    frame.loc[i[100:156], "T8"] = OPEN_CIRCUIT  # 56 values: 285 s between valid samples
    frame.loc[i[200:286], "T11"] = np.nan  # 86 values absent from the file
    frame.loc[i[300:302], "T5"] = OPEN_CIRCUIT  # 2 values: bridged
    out, audit = clean(frame)
    s = summarise_audit("f.csv", "s", len(frame), out, audit).iloc[0]
    assert s["values_left_missing"] == 56 + 86 == out[["T8", "T11"]].isna().sum().sum()
    assert s["open_circuit_removed"] == 56 + 2 and s["values_interpolated"] == 2
    spans = s["missing_spans"].split("; ")
    assert spans == [
        f"T8 lines {i[100]}-{i[155]}: 56 open-circuit value(s) removed and left missing",
        f"T11 lines {i[200]}-{i[285]}: 86 value(s) absent from the file and left missing",
    ]
    s = summarise_audit("g.csv", "s", len(log), *clean(log)).iloc[0]
    assert (s["values_left_missing"], s["open_circuit_removed"], s["missing_spans"]) == (0, 0, "")


def test_numeric_extras_kept_and_interpolated_text_extras_dropped(log_truth):
    log, truth = log_truth
    frame = log.copy()
    frame.loc[frame.index[500:504], "ambient_c"] = np.nan
    out, audit = clean(frame)
    assert "operator" not in out.columns and out["ambient_c"].dtype == np.float64
    np.testing.assert_allclose(out["ambient_c"], truth["ambient_c"].to_numpy(), atol=1e-6)
    assert "operator" in audit.loc[audit["action"] == "column_dropped", "column"].tolist()


def test_read_raw_log_round_trip_points_at_file_lines(tmp_path):
    log, _ = canonical_log(400, extras=False)
    frame, defects = inject_defects(log, spikes=3, duplicates=1, swaps=1, seed=5)
    path = tmp_path / "raw.csv"
    path.write_text(format_raw_log(frame, metadata={"machine": "m", "sample_period_s": 5}), encoding="utf-8")
    raw = read_raw_log(path)  # header on line 3 now
    out, audit = clean(raw, file=path.name)
    lines = path.read_text(encoding="utf-8").splitlines()
    for r in audit[audit["action"] == "spike_replaced"].itertuples():
        fields = lines[r.first_line - 1].split(",")
        header = lines[2].split(",")
        value = float(fields[header.index(r.column)])
        assert abs(value - float(r.detail.split()[0])) < 1e-9
    assert counts(audit) == {"spike_replaced": 3, "duplicate_dropped": 1, "reordered": 1}


# --------------------------------------------------------------------------- property + speed


@settings(
    max_examples=15,
    deadline=None,
    database=None,
    print_blob=True,
    phases=[Phase.explicit, Phase.generate],
    suppress_health_check=[HealthCheck.too_slow],
)
@given(
    dup=st.integers(0, 4),
    swaps=st.integers(0, 4),
    spikes=st.integers(0, 5),
    bursts=st.integers(0, 3),
    dropouts=st.integers(0, 4),
    gaps=st.integers(0, 4),
    seed=st.integers(0, 10_000),
)
def test_audit_counts_property(dup, swaps, spikes, bursts, dropouts, gaps, seed):
    log, truth = canonical_log(1200, extras=False, seed=seed % 7)
    frame, defects = inject_defects(
        log,
        duplicates=dup,
        swaps=swaps,
        spikes=spikes,
        bursts=bursts,
        dropouts=dropouts,
        gaps=gaps,
        seed=seed,
    )
    out, audit = clean(frame)
    s = summarise_audit("f", "s", len(frame), out, audit).iloc[0]
    kinds = defects["kind"].value_counts()
    assert s["duplicates_dropped"] == kinds.get("duplicate", 0)
    assert s["reordered"] == kinds.get("swap", 0)
    assert s["spikes_replaced"] == defects.loc[defects["kind"] == "spike", "n_rows"].sum()
    assert s["gaps_interpolated"] == kinds.get("gap", 0)
    assert s["values_interpolated"] == defects.loc[defects["kind"] == "dropout", "n_rows"].sum()
    assert s["rows_out"] == 1200 and s["segments"] == 1
    err = np.abs(out[SENSORS].to_numpy() - truth[SENSORS].to_numpy())
    assert err.max() < 0.15


def test_a_long_log_with_two_long_gaps_gives_three_segments():
    # the time of clean is measured by benchmarks/bench_steps.py (clean_3000, clean_30000)
    big, _ = canonical_log(30000, extras=False, seed=1)
    big, _ = inject_defects(
        big, duplicates=20, swaps=20, spikes=40, dropouts=40, gaps=20, long_gaps=2, seed=3
    )
    out, audit = clean(big)
    assert out["segment"].nunique() == 3


def test_backwards_limit_is_three_samples():
    log, _ = canonical_log(100, extras=False)
    order = list(range(100))
    moved = order.pop(40)
    order.insert(44, moved)  # 4 samples late -> 20 s backwards
    with pytest.raises(RawFormatError, match="backwards by 20 s"):
        clean(log.iloc[order])
    order = list(range(100))
    order.insert(43, order.pop(40))  # 3 samples late: a local swap
    out, audit = clean(log.iloc[order])
    assert counts(audit)["reordered"] == 1
    np.testing.assert_array_equal(out["T3"], log["T3"].to_numpy())
