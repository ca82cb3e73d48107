"""Layouts are not physics (issue 47): a prior qualified on machining-center-b's workbook (xlsx, the
probe's sign -1 in ``input.displacement.sign``, ``reference: log_start`` on one continuous log)
serves a sibling logged as native CSV (sign +1, ``run_start`` on cold-start files). Both are read
by the real readers with their own configs, cleaned, cut into runs and referenced; the prior is
accepted, adapted with the sibling's reference and predicts the sibling's growth in the right
sign. A sensor the prior reads that the sibling lacks is still refused, in one line."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from project_copy import ROOT

from rafi.errors import PriorIncompatible
from rafi.family.adapted import AdaptedPrior
from rafi.family.prior import available_sensors, check_compatible
from rafi.method.clean import clean_log
from rafi.readers.logs import read_log
from rafi.settings import read_machine_config
from rafi.twin.machines import Ambient, DefectRates, machine_params
from rafi.twin.recipes import RunSpec, machining_center_b_spec
from rafi.twin.scenarios import sibling_params
from rafi.twin.schedules import constant_schedule, with_rest
from rafi.twin.synthetic_runs import runs_of_logs, small_family_model
from rafi.twin.writers import render_run, render_xlsx

B = "machining-center-b"
SIBLING = "machining-center-b2"
SIBLING_REFERENCE = {"rule": "run_start", "window_s": 60.0}


def _clean(path, spec, settings, period):
    frame = read_log(path, spec)
    clean, _ = clean_log(
        frame,
        file=path.name,
        sample_period_s=period,
        max_interpolate_gap_s=settings["clean"]["max_interpolate_gap_s"],
        spike_threshold=settings["clean"]["spike_threshold"],
        open_circuit_values=settings["clean"]["open_circuit_values"],
    )
    return frame, clean


@pytest.fixture(scope="module")
def layouts(tmp_path_factory):
    """The prior (a ``dynamic`` of machining-center-b's workbook) and the sibling's runs."""
    tmp = tmp_path_factory.mktemp("layouts")
    _, settings = read_machine_config(ROOT / "config.yaml", B)
    assert settings["input"]["format"] == "xlsx" and settings["input"]["displacement"]["sign"] == -1
    assert settings["reference"]["rule"] == "log_start"
    steps = ((2.0, 5000, "Warmlauf"), (1.5, 0, "Stillstand"), (2.0, 2500, "Warmlauf"), (1.5, 0, "Stillstand"))
    spec = machining_center_b_spec(seed=11, file="workbook.xlsx", schedule=steps)
    book = tmp / "workbook.xlsx"
    book.write_bytes(render_xlsx(replace(spec, defects=DefectRates.none())))
    raw = pd.read_excel(book, sheet_name="Messdaten")[settings["input"]["displacement"]["column"]]
    _, clean = _clean(book, settings["input"], settings, 15.0)
    table, frame = runs_of_logs(
        {"workbook": clean}, training_speeds_rpm=[2500, 5000], reference_rule="log_start", min_constant_s=1800
    )
    model = small_family_model(
        "dynamic", reference_rule="log_start", reference_window_s=60.0, filter_restart_gap_s=3600.0
    )
    model.machine = B
    prior = model.fit(table, frame).to_dict()
    assert prior["reference"]["rule"] == "log_start"

    params = sibling_params(machine_params(B), 1)
    logs = {}
    for k, rpm in enumerate((5000, 2500)):
        name = f"cold_{rpm:05d}rpm.csv"
        run = RunSpec(
            B, name, name[:-4], tuple(with_rest(constant_schedule(rpm, 2 * 3600.0))),
            f"2026-05-0{k + 4}T08:00:00", 300 + k, Ambient(base_c=21.0), "sibling", DefectRates.none(),
        )  # fmt: skip
        text, _ = render_run(run, name=SIBLING, params=params)
        (tmp / name).write_text(text, encoding="utf-8")
        logs[name[:-4]] = _clean(tmp / name, None, settings, 5.0)[1]
    sib_table, sib_frame = runs_of_logs(
        logs, training_speeds_rpm=[2500, 5000], reference_rule="run_start", min_constant_s=1800
    )
    return prior, raw, frame, sib_table, sib_frame


def test_a_workbook_prior_serves_a_native_csv_sibling_in_the_right_sign(layouts):
    prior, raw, frame, table, sib = layouts
    # the layouts differ: the workbook's probe counts growth negative, its reader turns it round
    assert raw.min() < -5 and raw.max() < 1 and frame["dz_um"].max() > 5
    check_compatible(prior, sensors_available=available_sensors(sib), unit=SIBLING)  # accepted
    adapted = AdaptedPrior(prior=prior, method="gain", reference=SIBLING_REFERENCE, machine=SIBLING)
    adapted.fit(table, sib)
    assert 0.5 < adapted.gain_ < 2.0  # a sibling: about the prior's size, and the same sign
    artefact = adapted.to_dict()
    assert artefact["reference"]["rule"] == "run_start" and artefact["machine"] == SIBLING
    train = sib[sib["run_id"].isin(table.loc[table["role"] == "training", "run_id"])]
    ok = train["dz_um"].notna().to_numpy()
    predicted = adapted.predict(train)[ok]
    measured = train["dz_um"].to_numpy()[ok]
    assert measured.max() > 5 and np.corrcoef(predicted, measured)[0, 1] > 0.95
    assert np.sqrt(np.mean((predicted - measured) ** 2)) < 0.2 * np.ptp(measured)


def test_a_sensor_the_prior_reads_that_the_sibling_lacks_is_refused_in_one_line(layouts):
    prior, _, _, _, sib = layouts
    lost = prior["key_sensors"][0]
    blind = sib.assign(**{f"d{lost}": np.nan, lost: np.nan})
    with pytest.raises(PriorIncompatible) as err:
        check_compatible(prior, sensors_available=available_sensors(blind), unit=SIBLING)
    message = str(err.value)
    assert "\n" not in message and f"sensor(s) {lost} it reads have no data here" in message
    assert message.startswith(f"prior {prior['model_id'][:12]}:")


def test_on_cold_start_files_the_reference_rules_are_the_same_physics(layouts):
    """The prior's ``log_start`` and the sibling's ``run_start`` measure these files from the same
    state (the cold machine at rest), so the prior predicts the same under either: the rule is
    how the logs were cut, and the adapted artefact carries the sibling's."""
    prior, _, _, table, sib = layouts
    as_logged = AdaptedPrior(prior=prior, method="as_is").fit(table, sib)  # the prior's log_start
    converted = AdaptedPrior(prior=prior, method="as_is", reference=SIBLING_REFERENCE).fit(table, sib)
    assert as_logged.to_dict()["reference"]["rule"] == "log_start"
    assert converted.to_dict()["reference"]["rule"] == "run_start"
    rows = sib["dz_um"].notna().to_numpy()
    a, b = (np.asarray(m.predict(sib))[rows] for m in (as_logged, converted))
    assert np.isfinite(b).all() and np.ptp(b) > 5
    assert np.max(np.abs(a - b)) < 0.05 * np.ptp(b)
