"""The pages that summarise several units say where the controller's limits leave more than the
largest-residual gate, as each unit's own verdict does (the mixed fleet read page by page,
2026-12-01): fl-thermal ch3's report said "with the controller's limits ... on data#9 a worst
residual of 21.12 µm (model alone 3.80 µm, above the 12.00 µm limit ...)", while the machine's
page, reports/index.html and ``rafi status`` said PASS / ok and nothing else.

The replay does not gate (docs/decisions.md, 2026-12-01): the state and the verdict stay; the
summaries say it, from the same function as the unit's verdict
(:func:`rafi.report.replay_section.replay_gaps`).
"""

from __future__ import annotations

import html
import json
import re
from pathlib import Path

import pandas as pd
from test_fleet_status import ID, _decision, _machine, _summary

from rafi.ops import fleet as F
from rafi.ops import fleet_cli
from rafi.ops.project import Paths
from rafi.report.fleet_page import fleet_page
from rafi.report.replay_section import above_gate_words, replay_gaps

GATE = 12.0
#: ch3's replay as the audit found it: data#9 clamped on 181 of 960 samples, 21.12 µm with the
#: limits against 3.80 µm of the model alone; data#10 the same with and without.
CH3 = [("data#9", 3.80, 21.12, 181), ("data#10", 7.04, 7.04, 0)]
#: A gap the limits leave that stays under the gate: said by the unit's replay section, not here.
UNDER = [("data#9", 3.80, 9.50, 40)]


def _replay(runs, model_id: str) -> pd.DataFrame:
    return pd.DataFrame(
        {
            "model_id": model_id,
            "kind": "ensemble",
            "run_id": [r[0] for r in runs],
            "n_samples": 960,
            "n_clamped": [r[3] for r in runs],
            "max_abs_residual_model_um": [r[1] for r in runs],
            "max_abs_residual_um": [r[2] for r in runs],
        }
    )


def _text(page: str) -> str:
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html.unescape(page))).replace("\u00a0", " ")


def test_the_words_name_each_run_the_limits_leave_above_the_gate_and_only_those():
    words = above_gate_words(replay_gaps(_replay(CH3, ID["X"]), gate_um=GATE))
    assert words is not None
    words = words.replace("\u00a0", " ")
    assert "would leave 21.12 µm on data#9 (model alone 3.80 µm)" in words
    assert "above the 12.00 µm limit of the largest-residual gate" in words
    assert "data#10" not in words and "the gates judge the model alone" in words
    plain = above_gate_words(replay_gaps(_replay(CH3, ID["X"]), gate_um=GATE), plain=True)
    assert "21.12 um on data#9 (model alone 3.80 um)" in plain and "12.00 um limit" in plain
    assert above_gate_words(replay_gaps(_replay(UNDER, ID["X"]), gate_um=GATE)) is None
    assert above_gate_words(replay_gaps(_replay(CH3, ID["X"]), gate_um=None)) is None


def _probe_files(d: Path, replay) -> dict:
    d.mkdir()
    row = {"model": "ensemble", "kind": "ensemble", "champion": True, "passed": True}
    pd.DataFrame([row | {"max_abs_after_um": 7.04, "max_abs_before_um": 71.12}]).to_csv(
        d / "summary.csv", index=False
    )
    per_run = [
        {"model": "ensemble", "run_id": r[0], "max_abs_before_um": 60.0, "max_abs_after_um": r[1]}
        for r in CH3
    ]
    pd.DataFrame(per_run).to_csv(d / "per_run.csv", index=False)
    (d / "decision.json").write_text(json.dumps({"decision": "kept"}))
    paths = {
        k: str(d / f"{k}.{'json' if k == 'decision' else 'csv'}") for k in ("summary", "per_run", "decision")
    }
    if replay is not None:
        replay.to_csv(d / "replay.csv", index=False)
        paths["replay"] = str(d / "replay.csv")
    return paths


def test_the_machine_page_says_it_in_the_row_of_each_probe_it_concerns(tmp_path):
    from rafi.report.probes_page import probe_row, probes_context, render_probes_html
    from rafi.settings import machine_settings

    config = {
        "defaults": {"qualification": {"max_residual_um": GATE}},
        "machines": {"fl": {"input": {"format": "csv", "probes": {"ch1": "ch1(um)", "ch3": "ch3(um)"}}}},
    }
    rows = []
    for probe, runs in (("ch1", UNDER), ("ch3", CH3)):
        paths = _probe_files(tmp_path / probe, _replay(runs, ID["X"]))
        settings = machine_settings(config, f"fl@{probe}")
        rows.append(probe_row(probe, settings, paths, f"../fl@{probe}/qualification.html"))
    assert rows[0]["replay_above_gate"] is None
    assert "21.12\u00a0µm on data#9" in rows[1]["replay_above_gate"]
    ctx = probes_context("fl", rows)
    assert ctx["verdict"] == "PASS" and ctx["above_gate"] == ["ch3"]  # said, not judged
    text = _text(render_probes_html(ctx))
    assert "more than the largest-residual gate allows on probe ch3" in text
    assert (
        "ch3: with the controller's limits (the replay) the compensator would leave 21.12 µm on data#9"
        in text
    )
    assert "ch1: with the controller's limits" not in text
    # without a replay (an older run) nothing is said
    bare = probe_row("ch3", machine_settings(config, "fl@ch3"), _probe_files(tmp_path / "bare", None), "x")
    assert bare["replay_above_gate"] is None


def _fleet(tmp_path: Path, replayed: str = "X") -> Path:
    root = tmp_path / "p"
    for probe in ("ch1", "ch3"):
        decision = _decision(
            "kept", "X", "X", champion_summary=_summary("data#10", 7.04), gates={"max_residual_um": GATE}
        )
        _machine(root, f"fl@{probe}", champion="X", kind="ensemble", decision=decision)
        deploy = root / "results" / f"fl@{probe}" / "deploy"
        deploy.mkdir()
        _replay(CH3 if probe == "ch3" else UNDER, ID[replayed]).to_csv(
            deploy / "replay_summary.csv", index=False
        )
    (root / "config.yaml").write_text("raw_dir: raw\nresults_dir: results\nreports_dir: reports\n")
    return root


def test_status_and_the_fleet_page_say_it_of_the_model_in_service(tmp_path, capsys):
    root = _fleet(tmp_path)
    rows = F.fleet_overview(Paths.from_config(root, {}), root / "reports", ["fl@ch1", "fl@ch3"])
    by = {r["machine"]: r for r in rows}
    assert [by[m]["state"] for m in ("fl@ch1", "fl@ch3")] == ["ok", "ok"]  # the replay does not gate
    assert by["fl@ch1"]["replay_above_gate"] is None
    said = by["fl@ch3"]["replay_above_gate"]
    assert "21.12 um on data#9 (model alone 3.80 um), above the 12.00 um limit" in said
    text = fleet_cli.format_rows([r | {"report_path": None} for r in rows])
    ch1 = text[text.index("fl@ch1:") : text.index("fl@ch3:")]
    assert f"  replay:           {said}" in text[text.index("fl@ch3:") :] and "replay:" not in ch1
    assert f"  replay:           @ch3: {said}" in text[: text.index("fl@ch1:")]  # the machine's line
    page = _text(fleet_page(rows, created="now"))
    # the machine's row names the probe, before the probes' rows; the probe's row says it again
    machine_row = page[page.index("the most urgent state of its probes") : page.index("@ch1")]
    assert f"@ch3: {said}" in machine_row
    assert page.count(said) == 2


def test_a_replay_of_another_model_than_the_one_in_service_is_not_said_of_it(tmp_path):
    root = _fleet(tmp_path, replayed="C")  # tonight's candidate, not promoted
    rows = F.fleet_overview(Paths.from_config(root, {}), root / "reports", ["fl@ch3"])
    assert rows[0]["replay_above_gate"] is None
