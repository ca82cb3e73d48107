"""A run's speed is shown one way in every section: a varying run its range, from ``runs.csv``.

The audit of two machines nobody here tuned on (issue 46) read a varying validation run as
``multi 1 500`` in the table of the offered model (its median speed), as ``3 119–7 123 r/min`` in
the test record and the segmentation, and as ``0–7 123 r/min`` in the validation section, which
took the range from the residual samples, the rest before start (spindle at 0 r/min) included,
while ``runs.csv`` leaves the rest out of a run's speeds (:mod:`rafi.method.runs`). Every section
now prints :func:`rafi.report.format.fmt_run_speed` of the run's row of ``runs.csv``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rafi.report.deployed_section import _validation_rows
from rafi.report.format import NBSP, fmt_run_speed, run_speeds
from rafi.report.model_sections import other_runs
from rafi.report.segmentation_section import _row as segmentation_row
from rafi.report.test_record import _runs_rows, run_record

#: ``runs.csv`` of a machine with a varying validation run that starts with a rest at 0 r/min.
RUNS = pd.DataFrame(
    {
        "run_id": ["train", "multi", "single", "idle"],
        "file": ["a.csv", "b.csv", "c.csv", "c.csv"],
        "start_s": [0.0, 0.0, 0.0, 3600.0],
        "end_s": [3540.0, 3540.0, 3540.0, 7140.0],
        "duration_s": [3600.0, 3600.0, 3600.0, 3600.0],
        "speed_rpm": [3000.0, 6450.0, 14840.0, 0.0],
        "speed_min_rpm": [2997.0, 3119.0, 14837.0, 0.0],
        "speed_max_rpm": [3002.0, 7123.0, 14843.0, 0.0],
        "kind": ["constant", "varying", "constant", "idle"],
        "role": ["training", "validation_multi", "validation_single", "validation_idle"],
        "role_source": ["window"] * 4,
    }
)

RANGE = f"3{NBSP}119\u20137{NBSP}123{NBSP}r/min"


def _samples() -> pd.DataFrame:
    """The multi-condition run's samples: 3 min at rest (absorbed into the run), then the steps."""
    speed = np.r_[np.zeros(3), np.full(20, 3119.0), np.full(20, 7123.0), np.full(20, 5000.0)]
    n = len(speed)
    return pd.DataFrame(
        {
            "run_id": "multi",
            "model": "m",
            "t_s": 60.0 * np.arange(n),
            "speed_rpm": speed,
            "dz_um": np.linspace(0, 10, n),
            "residual_um": 0.1,
        }
    )


def test_the_formatter_shows_a_varying_run_as_its_range_and_any_other_as_its_speed():
    rows = RUNS.set_index("run_id")
    assert fmt_run_speed(rows.loc["multi"].to_dict()) == RANGE
    assert fmt_run_speed(rows.loc["train"].to_dict()) == f"3{NBSP}000{NBSP}r/min"  # not 2 997-3 002
    assert fmt_run_speed(rows.loc["idle"].to_dict()) == f"0{NBSP}r/min"
    # without a kind the spread of the ends decides
    assert fmt_run_speed({"speed_rpm": 6450.0, "speed_min_rpm": 3119.0, "speed_max_rpm": 7123.0}) == RANGE
    assert fmt_run_speed({"speed_rpm": 3000.0, "speed_min_rpm": 2997.0, "speed_max_rpm": 3002.0}) == (
        f"3{NBSP}000{NBSP}r/min"
    )
    assert run_speeds(RUNS)["multi"] == RANGE and run_speeds(None) == {}


class _NoFigures:
    def get(self, group, key):
        return None


def _multi_row() -> dict:
    """The validation section's row of the multi-condition run of :func:`_samples`."""
    summary = pd.DataFrame(
        {
            "run_id": ["multi"],
            "role": ["validation_multi"],
            "duration_s": [3600.0],
            "max_abs_before_um": [10.0],
            "max_abs_after_um": [1.0],
            "improvement_pct": [90.0],
            "n_outside_temp_range": [0],
            "n_outside_speed_range": [0],
            "n_samples": [63],
        }
    )
    (row,) = other_runs(summary, _samples(), {}, _NoFigures(), False, runs=RUNS)
    return row


def test_the_validation_section_takes_the_range_from_runs_csv_not_from_the_samples_with_the_rest():
    assert _multi_row()["speed"] == RANGE  # 0-7 123 r/min before: the rest before start counted


def test_every_section_prints_the_same_speed_for_the_same_run():
    per_run = pd.DataFrame(
        {
            "model": ["m", "m", "m"],
            "run_id": ["multi", "single", "idle"],
            "role": ["validation_multi", "validation_single", "validation_idle"],
            "speed_rpm": [6450.0, 14840.0, 0.0],  # per_run.csv: the run's median speed
            "max_abs_before_um": [10.0, 10.0, 10.0],
            "max_abs_after_um": [1.0, 1.0, 1.0],
            "passed": [True, True, True],
        }
    )
    offered = {r["run_id"]: r["speed"] for r in _validation_rows(per_run, "m", RUNS)}
    segmentation = {r["run_id"]: r["speed"] for r in (segmentation_row(r) for r in RUNS.to_dict("records"))}
    samples = pd.concat(
        [
            _samples(),
            pd.DataFrame({"run_id": ["train", "single", "idle"], "speed_rpm": [3000.0, 14840.0, 0.0]}),
        ]
    ).assign(dz_um=1.0)
    record = {r["run_id"]: r["speed"] for r in _runs_rows(run_record(samples, RUNS))}
    expected = run_speeds(RUNS)
    assert offered["multi"] == segmentation["multi"] == record["multi"] == RANGE  # not "6 450"
    for rid in ("single", "idle"):
        assert offered[rid] == segmentation[rid] == record[rid] == expected[rid]


def test_a_start_from_rest_is_not_counted_as_a_speed_change():
    """The multi-condition run of the shipped twin read "with 8 speed change(s)": 7 changes of speed
    and the spindle's start from the rest absorbed into the run. The start is said as such."""
    from rafi.report.model_sections import speed_changes

    assert speed_changes(_samples()["speed_rpm"]) == (2, True)  # 0 -> 3 119 is the start
    assert speed_changes(pd.Series([3000.0, 3000.0, 6000.0, 0.0, 6000.0])) == (3, False)  # a stop counts
    assert speed_changes(pd.Series([0.0, 0.0])) == (0, False)
    assert speed_changes(pd.Series([], dtype=float)) == (0, False)
    row = _multi_row()
    assert row["changes"] == 2 and row["from_rest"] is True
