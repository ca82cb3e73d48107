"""One noise floor per validation run on every page of the report (rafi.report.inputs.noise_floors).

A run's noise floor is a property of its measured dz (rafi.method.validate.run_noise_floor). Results
written before it was counted over all the run's measured samples hold, for a run where a model gave
no compensation on some samples, a different floor in that model's rows (``comparison/per_run.csv``,
``registry/comparison.csv``) than in ``validation/summary.csv``: the report states the one figure of
:func:`noise_floors` wherever it names the run's floor.
"""

from __future__ import annotations

import pandas as pd

from rafi.report.comparison_section import model_rows, rafi_failure, selection_context
from rafi.report.deployed_section import _validation_rows, deployed_panels
from rafi.report.inputs import model_noise_floors, noise_floors
from rafi.report.registry_section import relative_rows
from rafi.settings import machine_settings

#: The run's floor over all its measured samples, and the floor an older table held in the rows of
#: the ensemble, which gave no compensation on 86 of its samples.
RUN_FLOOR, STALE_FLOOR = 0.605, 0.603


def _results() -> dict:
    runs = ["valid_13500rpm", "valid_16500rpm"]
    per_run = pd.DataFrame(
        {
            "model": ["ensemble", "ensemble", "rafi", "rafi"],
            "kind": ["ensemble", "ensemble", "rafi", "rafi"],
            "run_id": runs * 2,
            "role": ["validation_single"] * 4,
            "speed_rpm": [13500.0, 16500.0] * 2,
            "n_samples": [2860, 1390, 2916, 1476],
            "max_abs_before_um": [24.0, 22.0] * 2,
            "max_abs_after_um": [1.2, 1.5, 3.0, 2.5],
            "n_outside_temp_range": [0] * 4,
            "n_outside_speed_range": [0] * 4,
            "passed": [True, True, False, False],
            "noise_floor_um": [0.64, STALE_FLOOR, 0.64, RUN_FLOOR],
        }
    )
    summary = pd.DataFrame(
        {
            "model": ["ensemble", "rafi"],
            "kind": ["ensemble", "rafi"],
            "n_samples": [4250, 4392],
            "max_abs_after_um": [1.5, 3.0],
            "passed": [True, False],
            "champion": [True, False],
            "noise_floor_um": [STALE_FLOOR, 0.64],  # the floor of each model's worst run, as stored
        }
    )
    validation = pd.DataFrame({"run_id": runs, "noise_floor_um": [0.64, RUN_FLOOR]})
    registry = pd.DataFrame(
        {
            "run_id": runs,
            "champion_max_abs_after_um": [1.3, 1.6],
            "candidate_max_abs_after_um": [1.2, 1.5],
            "candidate_minus_champion_um": [-0.1, -0.1],
            "noise_floor_um": [0.64, STALE_FLOOR],
            "margin_um": [0.64, STALE_FLOOR],
            "both_scored": [True, True],
            "candidate_worse": [False, False],
        }
    )
    return {
        "comparison": summary,
        "comparison_per_run": per_run,
        "validation_summary": validation,
        "registry_comparison": registry,
    }


def test_every_place_states_the_runs_one_noise_floor():
    res = _results()
    noise = noise_floors(res)
    assert noise == {"valid_13500rpm": 0.64, "valid_16500rpm": RUN_FLOOR}
    floors = model_noise_floors(res)
    assert floors == {"ensemble": RUN_FLOOR, "rafi": 0.64}  # each model's worst run's floor
    # the offered model's table of its validation runs and its residual panels
    rows = _validation_rows(res["comparison_per_run"], "ensemble", None, noise)
    assert [r["noise_floor_um"] for r in rows] == [0.64, RUN_FLOOR]
    (panels,) = deployed_panels(
        res["comparison"],
        res["comparison_per_run"],
        pd.DataFrame({"model": "ensemble", "run_id": ["valid_16500rpm"], "t_s": [0.0]}).assign(
            measured_um=1.0, residual_um=0.1
        ),
        noise,
    )
    assert [p["noise_floor"] for p in panels] == [RUN_FLOOR]
    # against the champion (registry/comparison.csv)
    assert [r["noise_floor_um"] for r in relative_rows(res["registry_comparison"], noise)] == [
        0.64,
        RUN_FLOOR,
    ]
    # the model comparison: a model's worst run, the champion's, RAFI's failing runs
    by_model = {
        r["model"]: r["noise_floor_um"] for r in model_rows(res["comparison"], "ensemble", None, None, floors)
    }
    assert by_model == {"ensemble": RUN_FLOOR, "rafi": 0.64}
    assert selection_context(res["comparison"], "ensemble", noise=floors)["noise"] == RUN_FLOOR
    bad = res["comparison_per_run"][res["comparison_per_run"]["model"] == "rafi"]
    fail = rafi_failure(bad, res, machine_settings({}, "m"))
    assert [r["noise_floor_um"] for r in fail["runs"]] == [0.64, RUN_FLOOR]
