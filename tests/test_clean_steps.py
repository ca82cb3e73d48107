"""The steps of rafi.method.clean one by one, each against data built with its truth."""

from __future__ import annotations

import numpy as np
import pytest

from rafi.errors import RawFormatError
from rafi.method.clean import (
    MAX_SPIKE_SAMPLES,
    SENSOR_COLUMNS,
    SENSOR_END,
    SPIKE_SIGMA_FLOOR,
    Grid,
    Samples,
    bridge_gaps,
    carry_speed,
    drop_duplicate_times,
    dropout_rows,
    fill_speed,
    find_spikes,
    interpolate_column,
    interpolate_dropouts,
    neighbours_in_segment,
    remove_open_circuit,
    replace_spikes,
    snap_to_grid,
    sort_by_time,
    spike_limit,
    true_runs,
)
from rafi.settings import BACKWARDS_TOLERANCE_SAMPLES

PERIOD = 5.0
NS = 1_000_000_000
T0 = 1_700_000_000 * NS
NAMES = ("speed_rpm", *SENSOR_COLUMNS, "ambient_c")


def samples(n: int = 40, *, seed: int = 0) -> Samples:
    """A regular log of ``n`` rows: times on the 5 s grid, random values, lines 2..n+1."""
    rng = np.random.default_rng(seed)
    times = T0 + np.arange(n, dtype="int64") * int(PERIOD * NS)
    values = rng.normal(20.0, 1.0, (n, len(NAMES)))
    return Samples(times, values, np.arange(2, n + 2, dtype="int64"))


def grid_of(values: np.ndarray, segment=None, present=None) -> Grid:
    """A grid over ``values`` (rows x columns), one segment unless given, every row present."""
    n = len(values)
    return Grid(
        index=np.arange(n, dtype="int64"),
        segment=np.zeros(n, "int64") if segment is None else np.asarray(segment, "int64"),
        line=np.arange(2, n + 2, dtype="int64"),
        present=np.ones(n, bool) if present is None else np.asarray(present, bool),
        values=np.asfortranarray(values),
        origin_ns=T0,
    )


def frozen(s: Samples) -> tuple:
    return s.times_ns.copy(), s.values.copy(), s.lines.copy()


def assert_unchanged(s: Samples, before: tuple) -> None:
    np.testing.assert_array_equal(s.times_ns, before[0])
    np.testing.assert_array_equal(s.values, before[1])
    np.testing.assert_array_equal(s.lines, before[2])


# --------------------------------------------------------------------------- helpers


@pytest.mark.parametrize("seed", range(5))
def test_true_runs_match_a_scan(seed):
    mask = np.random.default_rng(seed).random(200) < 0.4
    expected, i = [], 0
    while i < len(mask):
        if mask[i]:
            j = i
            while j + 1 < len(mask) and mask[j + 1]:
                j += 1
            expected.append((i, j))
            i = j + 1
        else:
            i += 1
    starts, ends = true_runs(mask)
    assert list(zip(starts.tolist(), ends.tolist())) == expected


@pytest.mark.parametrize("seed", range(5))
def test_neighbours_stay_in_their_segment(seed):
    rng = np.random.default_rng(seed)
    valid = rng.random(120) < 0.5
    segment = np.cumsum(rng.random(120) < 0.05)
    prev, nxt = neighbours_in_segment(valid, segment)
    for i in range(120):
        before = [j for j in range(i, -1, -1) if valid[j] and segment[j] == segment[i]]
        after = [j for j in range(i, 120) if valid[j] and segment[j] == segment[i]]
        assert prev[i] == (before[0] if before else -1)
        assert nxt[i] == (after[0] if after else -1)


# --------------------------------------------------------------------------- before the grid


def test_sort_by_time_sorts_local_swaps_and_reports_each():
    s = samples()
    order = np.arange(40)
    order[[10, 11]] = [11, 10]
    order[[30, 31, 32]] = [32, 30, 31]  # 2 periods back: still a local swap
    swapped = Samples(s.times_ns[order], s.values[order], s.lines)  # lines: the file's order
    before = frozen(swapped)
    out, rows = sort_by_time(swapped, PERIOD, "f.csv")
    np.testing.assert_array_equal(out.times_ns, s.times_ns)
    np.testing.assert_array_equal(out.values, s.values)
    assert [(r[0], r[2], r[3]) for r in rows] == [("reordered", 12, 13), ("reordered", 32, 33)]
    assert rows[1][5] == "line 33 is 10 s earlier than line 32; rows sorted by time"
    assert_unchanged(swapped, before)


def test_sort_by_time_refuses_a_clock_reset_at_its_line():
    s = samples()
    times = s.times_ns.copy()
    back = int((BACKWARDS_TOLERANCE_SAMPLES + 2) * PERIOD * NS)  # the next row 1 period earlier
    times[20:] -= back
    with pytest.raises(RawFormatError, match="backwards") as info:
        sort_by_time(Samples(times, s.values, s.lines), PERIOD, "f.csv")
    assert info.value.line == 22


def test_drop_duplicate_times_keeps_the_first_and_names_what_differs():
    s = samples(10)
    rows = np.array([0, 1, 2, 3, 3, 4, 5, 6, 6, 7])  # rows 3 and 6 twice
    dup = Samples(s.times_ns[rows], s.values[rows].copy(), np.arange(2, 12, dtype="int64"))
    dup.values[8, NAMES.index("T2")] += 1.0  # the second copy of row 6 differs in T2
    out, audit = drop_duplicate_times(dup, NAMES)
    np.testing.assert_array_equal(out.lines, [2, 3, 4, 5, 7, 8, 9, 11])
    np.testing.assert_array_equal(out.values, s.values[:8])
    assert [r[2] for r in audit] == [6, 10]
    assert "identical values; kept line 5" in audit[0][5]
    assert "differs in T2; kept line 9" in audit[1][5]


def test_remove_open_circuit_blanks_exactly_the_codes():
    s = samples(30)
    values = s.values.copy()
    t5, disp = NAMES.index("T5"), NAMES.index("disp_um")
    values[4:7, t5] = 850.0
    values[20, t5] = -999.0
    values[10, disp] = 999.9  # the displacement is a sensor too
    values[12, 0] = 850.0  # speed is not a sensor: kept
    coded = Samples(s.times_ns, values, s.lines)
    before = frozen(coded)
    out, rows = remove_open_circuit(coded, [-999.0, 999.9, 850.0])
    blank = np.zeros(values.shape, bool)
    blank[4:7, t5] = blank[20, t5] = blank[10, disp] = True
    np.testing.assert_array_equal(np.isnan(out.values), blank)
    np.testing.assert_array_equal(out.values[~blank], values[~blank])
    assert sorted((r[1], r[2], r[3], r[4]) for r in rows) == [
        ("T5", 6, 8, 3),
        ("T5", 22, 22, 1),
        ("disp_um", 12, 12, 1),
    ]
    assert_unchanged(coded, before)
    assert remove_open_circuit(coded, []) == (coded, [])


def test_snap_to_grid_rounds_jitter_and_drops_a_second_row_on_a_point():
    s = samples(20)
    rng = np.random.default_rng(3)
    jitter = rng.integers(-int(0.3 * PERIOD * NS), int(0.3 * PERIOD * NS), 20)
    jitter[0] = 0
    times = s.times_ns + jitter
    times[8] = times[7] + int(0.2 * PERIOD * NS)  # lands on row 7's grid point
    out, k, rows = snap_to_grid(Samples(times, s.values, s.lines), PERIOD, "f.csv", NAMES)
    np.testing.assert_array_equal(k, np.delete(np.arange(20), 8))
    np.testing.assert_array_equal(out.lines, np.delete(s.lines, 8))
    assert [r[0] for r in rows] == ["time_snapped", "duplicate_dropped"]
    assert rows[1][2] == 10 and "kept line 9" in rows[1][5]


def test_snap_to_grid_refuses_a_wrong_period():
    with pytest.raises(RawFormatError, match="median time between samples is 5 s"):
        snap_to_grid(samples(), 2 * PERIOD, "f.csv", NAMES)


def test_bridge_gaps_inserts_short_gaps_and_splits_at_long_ones():
    s = samples(30)
    kept = np.r_[0:10, 13:20, 35:43]  # 3 missing rows (20 s between samples), then 15 (80 s)
    taken = Samples(s.times_ns[: len(kept)], s.values[: len(kept)], s.lines[: len(kept)])
    grid, rows = bridge_gaps(taken, kept.astype("int64"), PERIOD, 60.0)
    np.testing.assert_array_equal(grid.index, np.r_[0:20, 35:43])
    np.testing.assert_array_equal(grid.segment, np.r_[np.zeros(20), np.ones(8)])
    np.testing.assert_array_equal(grid.present, np.isin(grid.index, kept))
    assert np.isnan(grid.values[10:13]).all() and (grid.line[10:13] == -1).all()
    np.testing.assert_array_equal(grid.values[grid.present], taken.values)
    assert [(r[0], r[2], r[3], r[4]) for r in rows] == [
        ("gap_interpolated", 11, 12, 3),
        ("gap_split", 18, 19, 15),
    ]
    assert grid.values.flags.f_contiguous


# --------------------------------------------------------------------------- on the grid


def test_spike_limit_floors():
    rng = np.random.default_rng(0)
    noisy = rng.normal(0.0, 0.5, 20000)
    assert spike_limit(noisy, 8.0) == pytest.approx(8.0 * 0.5, rel=0.05)
    quantised = np.r_[np.zeros(900), np.full(100, 0.1)]  # MAD 0: the resolution is the floor
    assert spike_limit(quantised, 8.0) == pytest.approx(0.8)
    assert spike_limit(np.zeros(50), 8.0) == 8.0 * SPIKE_SIGMA_FLOOR


def test_find_spikes_finds_single_samples_not_steps_nor_across_segments():
    rng = np.random.default_rng(1)
    column = 20.0 + rng.normal(0.0, 0.01, 200)
    column[100:] += 3.0  # a step: beyond one neighbour only
    column[[30, 150]] += [2.0, -2.0]  # spikes
    column[60] = np.nan
    column[61] += 2.0  # a spike next to a missing value: its neighbours are 59 and 62
    column[180] += 2.0  # a spike on the last row of a segment: one neighbour only
    segment = np.r_[np.zeros(181), np.ones(19)].astype("int64")
    grid = grid_of(np.column_stack([column]), segment=segment)
    spikes, before, after, limit = find_spikes(column, grid, PERIOD, 60.0, 8.0)
    assert spikes.tolist() == [30, 61, 150]
    assert before.tolist() == [29, 59, 149] and after.tolist() == [31, 62, 151]
    assert 0.05 < limit < 1.0
    # neighbours too far apart to bridge (15 s around row 61): not a spike
    assert find_spikes(column, grid, PERIOD, 10.0, 8.0)[0].tolist() == [30, 150]


def test_replace_spikes_blanks_sensors_only_and_keeps_the_input():
    n = 100
    values = np.full((n, SENSOR_END + 1), 10.0) + np.arange(n)[:, None] * 0.001
    values[40, 0] += 500.0  # a speed "spike" is a speed change: kept
    values[40, 3] += 5.0
    values[70, SENSOR_END] += 5.0  # an extra column: never a spike
    grid = grid_of(values)
    before = grid.values.copy()
    out, spike, rows = replace_spikes(grid, PERIOD, 60.0, 8.0, NAMES)
    expected = np.zeros(values.shape, bool)
    expected[40, 3] = True
    np.testing.assert_array_equal(spike, expected)
    np.testing.assert_array_equal(np.isnan(out.values), expected)
    assert [(r[0], r[1], r[2]) for r in rows] == [("spike_replaced", "T3", 42)]
    np.testing.assert_array_equal(grid.values, before)


def test_interpolate_column_recovers_a_line_and_leaves_long_or_open_stretches():
    truth = 0.5 * np.arange(60.0)
    column = truth.copy()
    column[[0, 1]] = np.nan  # segment start: nothing before
    column[10:13] = np.nan  # 20 s between valid samples
    column[30:45] = np.nan  # 80 s: too long
    column[59] = np.nan  # end
    grid = grid_of(np.column_stack([column]))
    out, missing = interpolate_column(column, grid, PERIOD, 60.0)
    np.testing.assert_allclose(out[10:13], truth[10:13], rtol=0, atol=1e-12)
    assert np.isnan(out[[0, 1, 59]]).all() and np.isnan(out[30:45]).all()
    np.testing.assert_array_equal(missing.rows, np.flatnonzero(np.isnan(column)))
    np.testing.assert_array_equal(missing.filled, np.isin(missing.rows, [10, 11, 12]))
    np.testing.assert_array_equal(missing.enclosed, ~np.isin(missing.rows, [0, 1, 59]))
    assert np.isnan(column[10])  # the input column is not touched


def test_dropout_rows_report_only_dropped_values_of_a_stretch():
    column = np.arange(40.0)
    column[5:10] = np.nan
    column[20:35] = np.nan
    grid = grid_of(np.column_stack([column]))
    _, missing = interpolate_column(column, grid, PERIOD, 60.0)
    dropped = ~np.isin(missing.rows, [5, 6, 20, 21, 22])  # the others were inserted rows or spikes
    rows = dropout_rows("T4", missing, dropped, grid.line, 60.0)
    assert [(r[0], r[2], r[3], r[4]) for r in rows] == [
        ("dropout_interpolated", 9, 11, 3),
        ("dropout_left_nan", 25, 36, 12),
    ]
    assert "80 s between valid samples (> max_interpolate_gap_s = 60 s)" in rows[1][5]


def test_interpolate_dropouts_leaves_the_speed_and_reports_per_column():
    values = np.tile(np.arange(30.0)[:, None], (1, 3))
    values[4:6] = np.nan
    present = np.ones(30, bool)
    present[5] = False  # row 5 was inserted for a gap
    grid = grid_of(values, present=present)
    out, rows = interpolate_dropouts(grid, np.zeros(values.shape, bool), PERIOD, 60.0, NAMES[:3])
    assert np.isnan(out.values[4:6, 0]).all()
    np.testing.assert_array_equal(out.values[:, 1:], np.tile(np.arange(30.0)[:, None], (1, 2)))
    assert [(r[0], r[1], r[2], r[4]) for r in rows] == [("dropout_interpolated", c, 6, 1) for c in NAMES[1:3]]


def test_speed_is_carried_forward_else_backward_within_its_segment():
    speed = np.array([np.nan, np.nan, 100, np.nan, 200, np.nan, np.nan, 300, np.nan])
    segment = np.array([0, 0, 0, 0, 0, 1, 1, 1, 1])
    filled, has_previous = carry_speed(speed, segment)
    np.testing.assert_array_equal(filled, [100, 100, 100, 100, 200, 300, 300, 300, 300])
    np.testing.assert_array_equal(has_previous, [0, 0, 1, 1, 1, 0, 0, 1, 1])
    values = np.column_stack([speed, np.zeros(9)])
    present = np.array([1, 1, 1, 0, 1, 1, 1, 1, 1], bool)  # row 3 inserted: no speed_filled row
    out, rows = fill_speed(grid_of(values, segment=segment, present=present))
    np.testing.assert_array_equal(out.values[:, 0], filled)
    assert [(r[2], r[3], r[4], "previous" in r[5]) for r in rows] == [
        (2, 3, 2, False),
        (7, 8, 2, False),
        (10, 10, 1, True),
    ]


def test_find_spikes_finds_short_bursts_but_not_a_longer_plateau():
    rng = np.random.default_rng(2)
    column = 20.0 + rng.normal(0.0, 0.01, 300)
    column[40:42] += 2.0  # two samples
    column[90:93] -= 1.5  # three samples
    column[140:142] += [3.0, 3.0]
    column[142] += 1.0  # a glitch of two and a smaller third: one spike of three samples
    column[200 : 200 + MAX_SPIKE_SAMPLES + 1] += 2.0  # longer than a spike: a change of state
    column[250:252] += [2.0, -2.0]  # up then down: two single spikes side by side, one glitch
    grid = grid_of(np.column_stack([column]))
    spikes, before, after, _ = find_spikes(column, grid, PERIOD, 60.0, 8.0)
    assert spikes.tolist() == [40, 41, 90, 91, 92, 140, 141, 142, 250, 251]
    assert before.tolist() == [39, 39, 89, 89, 89, 139, 139, 139, 249, 249]
    assert after.tolist() == [42, 42, 93, 93, 93, 143, 143, 143, 252, 252]


def test_replace_spikes_reports_a_burst_once_with_its_lines():
    n = 100
    values = np.full((n, SENSOR_END + 1), 10.0) + np.arange(n)[:, None] * 0.001
    values[50:52, 5] += [4.0, 4.5]
    grid = grid_of(values)
    out, spike, rows = replace_spikes(grid, PERIOD, 60.0, 8.0, NAMES)
    assert np.flatnonzero(spike[:, 5]).tolist() == [50, 51] and spike.sum() == 2
    assert [r[:5] for r in rows] == [("spike_replaced", "T5", 52, 53, 2)]
    assert rows[0][5].startswith("2 samples 14.05, 14.551 vs neighbours 10.049 and 10.052")
