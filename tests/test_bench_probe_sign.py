"""benchmarks/bench_probe_sign.py: the probe-sign check on a log cut into files, on a generated
log whose probe signs are known."""

from __future__ import annotations

import numpy as np
import pandas as pd
from bench_loader import load_bench

from rafi import SENSORS

bench = load_bench("bench_probe_sign")


def _log(flip_second_half_of: int | None = None) -> pd.DataFrame:
    """The FL_THERMAL layout (time, speed, 5 probes, 16 sensors), 15 s rows: heating runs at rest
    in between, a room that cools by 3 K over the log; probe 3 counts negative."""
    t = np.arange(0.0, 166_710.0, 15.0)
    speed = np.where(((t // 14_400) % 2 == 1) & (t < 144_000), 3000.0, 0.0)
    heat = pd.Series(speed).ewm(alpha=1 - np.exp(-15 / 1800)).mean().to_numpy() / 100.0
    room = 25.0 - 3.0 * t / t[-1]
    noise = np.random.default_rng(0).normal(0, 0.05, (len(t), 16))
    temps = room[:, None] + np.outer(heat, np.linspace(0.2, 1.0, 16)) + noise
    probes = np.column_stack([2.0 * heat, 1.5 * heat, -3.0 * heat, 1.0 * heat, 0.5 * heat])
    if flip_second_half_of is not None:
        probes[len(t) // 2 :, flip_second_half_of] *= -1
    columns = {"t": t, "rpm": speed}
    columns.update({f"ch{c + 1}": probes[:, c] for c in range(5)})
    columns.update({s: temps[:, j] for j, s in enumerate(SENSORS)})
    return pd.DataFrame(columns)


def test_a_probe_that_never_changes_gets_its_sign_in_every_piece_and_no_warning():
    table = bench.warnings_per_scheme(_log())
    expected = {"ch1": "+1", "ch2": "+1", "ch3": "-1", "ch4": "+1", "ch5": "+1"}
    for _, row in table.iterrows():
        assert set(row.signs.split()) == {expected[row.channel]}, (row.scheme, row.channel)
    assert table.between_files.sum() == 0 and table.convention.sum() == 0


def test_a_probe_reversed_half_way_is_warned_between_the_files_of_the_second_half():
    table = bench.warnings_per_scheme(_log(flip_second_half_of=0)).set_index(["scheme", "channel"])
    assert table.loc[("1/4", "ch1"), "signs"] == "+1 +1 -1 -1"
    # each file sees more of the other sign among the *other* files: every one is warned
    assert table.loc[("1/4", "ch1"), "between_files"] == 4 and table.loc[("1/8", "ch1"), "between_files"] == 8
    assert table.drop("ch1", level="channel").between_files.sum() == 0
