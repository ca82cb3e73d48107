"""The replay section's table "Limits and fault rules in force" (issue 26): the wide-interval rule
has a row (``deploy.max_interval_um`` or "off", and the samples it held / ramped in the replay),
and the sensor checks' row lists the replay's faults by class, one entry per class however many
measured values the messages name.

Real replays of the report fixture (``tests/report_fixture.py``, with the interval results of
``tests/test_report_intervals.py``) through the safe compensator, rendered by the real report.
The expected cells are computed here from the replay table's ``fault`` and ``status`` by the
wording ``docs/deploy.md`` documents, not by ``rafi.deploy.metrics``.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from html_tables import html_tables
from report_fixture import copy_fixture, write_upstream_tables
from test_report_intervals import CONFIG, WIDE_AT_UM, _draw_replay, add_interval_results

from rafi.deploy.limits import Limits
from rafi.deploy.replay import replay_runs, replay_summary, summary_frame
from rafi.report.context import build_context
from rafi.report.inputs import FIGURE_DIRS, figure_dirs
from rafi.report.render import render_html
from rafi.settings import machine_settings

MACHINE = "tapping-center-a"
RUNS = ("multi-1", "val-8000")
INTERVAL_ROW = "wide prediction interval"
SENSOR_ROW = "sensor checks: missing, out of range, stuck"


def _report(tmp: Path, **deploy) -> tuple[dict, pd.DataFrame, Path, dict]:
    """The fixture's ``RUNS`` replayed with config.yaml's limits changed by ``deploy`` (as rule
    replay writes it) and the report rendered with the same settings: the limits table by rule
    (``rule -> {header: cell}``), the replay table, the results folder and the settings."""
    results = copy_fixture(tmp)
    add_interval_results(results)
    settings = machine_settings(CONFIG, MACHINE)
    settings["deploy"] = {**settings["deploy"], **deploy}
    frame, table = pd.read_parquet(results / "runs.parquet"), pd.read_csv(results / "runs.csv")
    files = dict(zip(table["run_id"], table["file"]))
    frame["log"], frame["log_t_s"] = frame["run_id"].map(files), frame["t_s"]  # one run per log
    artefact = json.loads((results / "comparison" / "best_model.json").read_text(encoding="utf-8"))
    replayed = replay_runs(frame, list(RUNS), artefact, Limits.from_settings(settings["deploy"]))
    (results / "deploy").mkdir()
    replayed.to_parquet(results / "deploy" / "replay.parquet")
    summary_frame(replay_summary(replayed), artefact=artefact).to_csv(
        results / "deploy" / "replay_summary.csv", index=False
    )
    dirs = figure_dirs(results)
    for group in dirs:
        (results / FIGURE_DIRS[group]).mkdir(parents=True, exist_ok=True)
        (results / FIGURE_DIRS[group] / "index.csv").write_text("key,file\n", encoding="utf-8")
    _draw_replay(results, tmp, dirs["replay"])
    return _limits_table(results, settings), replayed, results, settings


def _limits_table(results: Path, settings: dict) -> dict:
    paths = write_upstream_tables(results)
    html = render_html(build_context(paths, figure_dirs(results), machine=MACHINE, settings=settings))
    (table,) = html_tables(html, "kv replay-limits")
    return {r["rule"]: r for r in table["records"]}


def _class_of(cause: str) -> str:
    """The fault class of one cause, by its documented wording."""
    if cause.startswith("interval_wide: "):
        return "interval_wide"
    if "outside trained range" in cause or "above trained" in cause:
        return "outside_range"
    if " out of range (" in cause:
        return "out_of_range"
    if cause == "speed missing":
        return "speed_missing"
    if cause.endswith(" missing"):
        return "missing"
    return "no_value" if cause == "no model value" else "other"


def _classes(fault: str) -> list[str]:
    return list(dict.fromkeys(_class_of(c) for c in fault.split("; ") if c))


@pytest.mark.parametrize("on", [True, False])
def test_the_limits_table_has_the_wide_interval_rule_and_what_it_did(tmp_path, on):
    """On (7 um: fires on the fixture's ``outside`` interval cell): the limit, and the samples
    held and ramped with the rule among their causes, over both replayed runs. Off (the default):
    "off" and "did not act" - the replay has no such fault. Without the replay table (a results
    folder from before it) the count is not claimed."""
    rows, replayed, results, settings = _report(tmp_path, max_interval_um=WIDE_AT_UM if on else None)
    row = rows[INTERVAL_ROW]
    wide = replayed["fault"].map(lambda f: "interval_wide" in _classes(f)).to_numpy()
    status = replayed["status"].to_numpy()
    held, ramped = int((wide & (status == "hold")).sum()), int((wide & (status == "ramp")).sum())
    if on:
        assert held > 0 and ramped > 0 and held + ramped == wide.sum()
        assert row["in force"] == "deploy.max_interval_um = 7.00 µm (upper − lower of the model's interval)"
        did = f"held on {held}, ramped on {ramped} of {len(replayed)} samples"
        assert row["what it did in the replay"] == did
        # the sensor checks do not repeat the rules with a row of their own
        assert "interval_wide" not in rows[SENSOR_ROW]["what it did in the replay"]
        (results / "deploy" / "replay.parquet").unlink()
        rows = _limits_table(results, settings)
        assert rows[INTERVAL_ROW]["what it did in the replay"] == "not known (no replay table)"
    else:
        assert not wide.any()
        assert row["in force"] == "off (deploy.max_interval_um none)"
        assert row["what it did in the replay"] == "did not act (off)"
    assert list(rows)[3:6] == ["trained range", INTERVAL_ROW, "fault rule: hold, then ramp"]


def test_the_sensor_checks_list_each_fault_class_once_with_its_count(tmp_path):
    """A valid range that cuts through the run (27 degC): the sensors out of range on many samples,
    each message with its own reading. The row lists each class once over both runs: the samples
    with a cause of the class and the first cause; the classes with a row of their own (trained
    range, wide interval) are not repeated here."""
    rows, replayed, _, _ = _report(tmp_path, temp_valid_c=[-10.0, 27.0], max_interval_um=WIDE_AT_UM)
    faults = replayed["fault"]
    assert faults[faults.str.contains(" out of range (", regex=False)].nunique() > 20
    want: dict = {}
    for fault in faults:
        causes = [c for c in fault.split("; ") if c]
        for kind in _classes(fault):
            if kind not in ("outside_range", "interval_wide"):
                n, first = want.get(kind, (0, next(c for c in causes if _class_of(c) == kind)))
                want[kind] = (n + 1, first)
    assert "out_of_range" in want
    text = "; ".join(f"{kind}: {n} (first: {first})" for kind, (n, first) in want.items())
    assert rows[SENSOR_ROW]["what it did in the replay"] == f"faults: {text}"
