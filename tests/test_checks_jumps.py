"""displacement_step (rafi.readers.checks_jumps): a jump is a row-to-row change beyond the trend.

A smooth warm-up of up to 1.5 um per row never fires, at any sample period, however far its
5-row medians lie apart; a probe re-zeroed or bumped between two consecutive rows fires and names
those two lines and the change measured between them. Ground truth is the generated signal.
"""

from __future__ import annotations

import numpy as np
from hypothesis import assume, given
from hypothesis import strategies as st
from test_checks import frame
from test_checks_hostile import PROPS

from rafi import SENSORS
from rafi.readers.checks import check_file
from rafi.readers.checks_base import fmt
from rafi.readers.checks_jumps import JUMP_SHARE, row_jumps

#: Steepest warm-up of the tests, um per row.
SLOPE_UM = 1.5


def warm_up(amplitude, period_s, noise_um, n=150, seed=0):
    """A log whose displacement warms up exponentially to ``amplitude`` um, at most 1.5 um per
    row (at its start), with Gaussian noise; the temperatures warm up more slowly (they lead the
    growth in a real machine, but a straight-line copy would be a swapped-channel warning)."""
    rng = np.random.default_rng(seed)
    f = frame(n=n, period_s=period_s, seed=seed)
    t = np.arange(n) * period_s
    tau = amplitude * period_s / SLOPE_UM  # initial slope amplitude / tau = 1.5 um per row
    f["disp_um"] = amplitude * (1 - np.exp(-t / tau)) + rng.normal(0, noise_um, n)
    for i, s in enumerate(SENSORS):
        f[s] = 21 + 0.1 * i + 8 * (1 - np.exp(-t / (0.7 * tau))) + rng.normal(0, 0.02, n)
    return f


def check(f):
    return check_file(f, "raw/m/log.csv", open_circuit_values=[-999.0], training_speeds_rpm=[6000])


def steps_of(report):
    return [w for w in report.warnings if w.check == "displacement_step"]


@given(
    amplitude=st.floats(20, 60),
    period_s=st.integers(60, 300),
    noise_um=st.floats(0, 0.3),
    seed=st.integers(0, 2**16),
)
@PROPS
def test_a_smooth_warm_up_never_fires(amplitude, period_s, noise_um, seed):
    f = warm_up(amplitude, period_s, noise_um, seed=seed)
    assert np.abs(np.diff(f["disp_um"])).max() < 2.5  # the generator: no row-to-row jump
    assert steps_of(check(f)) == []


@given(
    amplitude=st.floats(20, 60),
    period_s=st.integers(60, 300),
    noise_um=st.floats(0, 0.3),
    jump_um=st.floats(10, 30),
    down=st.booleans(),
    at=st.floats(0.15, 0.85),
    seed=st.integers(0, 2**16),
)
@PROPS
def test_a_jump_between_two_rows_fires_at_its_line_with_the_change_measured(
    amplitude, period_s, noise_um, jump_um, down, at, seed
):
    f = warm_up(amplitude, period_s, noise_um, seed=seed)
    k = int(at * len(f))
    sign = -1.0 if down else 1.0
    disp = f["disp_um"].to_numpy().copy()
    disp[k:] += sign * jump_um
    f["disp_um"] = disp
    spread = np.percentile(disp, 98) - np.percentile(disp, 2)
    assume(jump_um >= JUMP_SHARE * spread + 1.0)  # under a quarter of the range: no step (documented)
    (w,) = steps_of(check(f))
    before, after = int(f.index[k - 1]), int(f.index[k])
    change = disp[k] - disp[k - 1]  # the row-to-row change as measured in the file
    assert (w.first_line, w.last_line) == (after, after)
    assert f"changes by {fmt(change)} um from line {before} to line {after}" in w.message
    assert abs(change - sign * jump_um) < 3.0


def test_a_re_zeroed_probe_in_a_warm_up_is_named_with_its_own_rows():
    f = warm_up(30, 120, 0.05, seed=3)
    k = 60
    disp = f["disp_um"].to_numpy().copy()
    level = disp[k]
    disp[k:] -= level
    f["disp_um"] = disp
    (w,) = steps_of(check(f))
    assert w.message.startswith(
        f"disp_um changes by {fmt(disp[k] - disp[k - 1])} um from line {f.index[k - 1]} to line "
        f"{f.index[k]} ({fmt(disp[k - 1])} to {fmt(disp[k])} um, "
    )
    assert "a bumped or re-zeroed probe" in w.message


def test_a_glitch_sample_or_a_two_row_spike_is_not_a_jump():
    v = np.linspace(0, 30, 200)
    v[80] += 20.0
    v[120:122] -= 15.0
    assert row_jumps(v, 5.0) == []


def test_row_jumps_skips_missing_rows_and_removes_the_trend():
    v = np.arange(40, dtype=float) * 2.0  # 2 um per row
    v[20:] += 6.0  # 8 um from row 19 to row 20: 6 um beyond the trend
    v[19] = np.nan
    (jump,) = row_jumps(v, 5.0)
    assert (jump.row_before, jump.row_after) == (18, 20)
    assert jump.change == v[20] - v[18] and jump.trend == 2.0
    assert row_jumps(v, 7.0) == []  # 10 um over two rows, 6 um of it beyond the 2 um per row trend
