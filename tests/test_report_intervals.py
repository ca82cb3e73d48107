"""The prediction interval in the qualification report (issue 26, the report's part).

The report fixture (tests/data/report_fixture/tapping-center-a, written before intervals
existed) is rendered as it is - no band, no coverage, no sentence - and with the interval
results added the way the pipeline writes them (docs/design.md, the shared design of issue 26):
``lower_um``, ``upper_um``, ``interval_cell`` in both ``residuals.parquet``; ``coverage`` and
``interval_width_um`` in ``validation/summary.csv``, ``comparison/per_run.csv`` and
``comparison/summary.csv``, computed here from those residuals; the ``interval`` block in
``model.json`` and ``comparison/best_model.json``. Every number the sentences state is checked
against the tables of the same HTML, and every band against the axes the figure functions draw.
"""

from __future__ import annotations

import html as html_lib
import json
import re
import subprocess
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import which_or_skip
from html_tables import html_tables
from matplotlib.collections import PolyCollection
from report_fixture import copy_fixture, write_upstream_tables

from rafi.artefact import compute_model_id
from rafi.deploy.limits import Limits
from rafi.deploy.replay import replay_runs, replay_summary, summary_frame
from rafi.report import deployed_plot, plot_layout, plots, replay_plot
from rafi.report.context import build_context
from rafi.report.figures import FIGURE_GROUPS, draw_group
from rafi.report.inputs import FIGURE_DIRS, figure_dirs, result_paths
from rafi.report.intervals import residual_band, times_in, worst_run_interval
from rafi.report.render import render_html, render_pdf
from rafi.settings import machine_settings

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "tests" / "data" / "report_fixture" / "tapping-center-a"
CONFIG = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))
HALF = {"settled": 2.0, "transient": 3.0, "outside": 4.0}
TRANSIENT_S = 1800.0
BLOCK = {
    "schema": "rafi.interval/1",
    "method": "split_conformal_by_run",
    "level": 0.9,
    "transient_s": TRANSIENT_S,
    "tolerance_rpm": 250.0,
    "half_width_um": HALF,
    "decorrelation_s": 600.0,
    "calibration": {
        "scheme": "leave_one_run_out",
        "n_runs": 6,
        "n_samples": 812,
        "corrected_level": 0.904,
        "pooled_half_width_um": 0.674013294224082,
        "units": "runs",
        "cells": {
            "settled": {"n_runs": 6, "n_samples": 640},
            "transient": {"n_runs": 6, "n_samples": 150},
            "outside": {"n_runs": 2, "n_samples": 22},
        },
        # the cells that took the pooled value, as rafi.family.intervals.calibrate writes them
        "fallback": ["outside"],
    },
}


def _with_interval(frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` (a residuals table) with the interval columns: the cell of each sample from its
    flags and time, ``[predicted - h, predicted + h]``."""
    outside = frame["outside_temp_range"].astype(bool) | frame["outside_speed_range"].astype(bool)
    cell = np.where(outside, "outside", np.where(frame["t_s"] < TRANSIENT_S, "transient", "settled"))
    h = pd.Series(cell).map(HALF).to_numpy(float)
    pred = frame["predicted_um"].to_numpy(float)
    return frame.assign(lower_um=pred - h, upper_um=pred + h, interval_cell=cell)


def _coverage(frame: pd.DataFrame) -> pd.Series:
    """``coverage`` and ``interval_width_um`` of a residuals table's samples (the design's
    definitions: samples with a finite measurement and interval)."""
    m, lo, hi = (frame[c].to_numpy(float) for c in ("measured_um", "lower_um", "upper_um"))
    ok = np.isfinite(m) & np.isfinite(lo) & np.isfinite(hi)
    inside = (m[ok] >= lo[ok]) & (m[ok] <= hi[ok])
    return pd.Series({"coverage": inside.mean(), "interval_width_um": float(np.median(hi[ok] - lo[ok]))})


def add_interval_results(results: Path) -> None:
    """Add what the interval pipeline writes to a results folder of the fixture."""
    for rel in ("validation/residuals.parquet", "comparison/residuals.parquet"):
        _with_interval(pd.read_parquet(results / rel)).to_parquet(results / rel)
    resid = pd.read_parquet(results / "validation" / "residuals.parquet")
    cov = resid.groupby("run_id").apply(_coverage, include_groups=False)
    summ = pd.read_csv(results / "validation" / "summary.csv")
    summ.join(cov, on="run_id").to_csv(results / "validation" / "summary.csv", index=False)
    cres = pd.read_parquet(results / "comparison" / "residuals.parquet")
    per_run = pd.read_csv(results / "comparison" / "per_run.csv")
    cov = cres.groupby(["model", "run_id"]).apply(_coverage, include_groups=False)
    per_run.join(cov, on=["model", "run_id"]).to_csv(results / "comparison" / "per_run.csv", index=False)
    pooled = cres.groupby("model").apply(_coverage, include_groups=False)
    summary = pd.read_csv(results / "comparison" / "summary.csv")
    summary.join(pooled, on="model").to_csv(results / "comparison" / "summary.csv", index=False)
    renamed = {}
    for rel in ("model.json", "comparison/best_model.json"):
        doc = json.loads((results / rel).read_text(encoding="utf-8"))
        doc["interval"] = BLOCK
        renamed[doc["model_id"]] = doc["model_id"] = compute_model_id(doc)  # the id covers the block
        (results / rel).write_text(json.dumps(doc, indent=2), encoding="utf-8")
    _rename_ids(results, renamed)


def _rename_ids(results: Path, renamed: dict) -> None:
    """Every text result and registry file (and registry file name) with the new ids, as a run
    of the pipeline with intervals would have written them."""
    for path in sorted(results.rglob("*")):
        if path.is_file() and path.suffix in (".json", ".jsonl", ".csv"):
            text = path.read_text(encoding="utf-8")
            for old, new in renamed.items():
                text = text.replace(old, new)
            path.write_text(text, encoding="utf-8")
    for path in sorted((results / "registry" / "models").glob("*")):
        name = path.name
        for old, new in renamed.items():
            name = name.replace(old, new)
        path.rename(path.with_name(name))
    for new in renamed.values():
        stored = results / "registry" / "models" / f"{new}.json"
        if stored.exists():
            doc = json.loads(stored.read_text(encoding="utf-8"))
            doc["interval"] = BLOCK
            stored.write_text(json.dumps(doc, indent=2), encoding="utf-8")


def _render(tmp: Path, *, interval: bool, draw: bool = False) -> tuple[dict, str, Path]:
    """The fixture's context and HTML (with or without the interval results); ``draw``: the
    figures of rule report_figures, else empty figure folders."""
    results = copy_fixture(tmp)
    if interval:
        add_interval_results(results)
    paths = write_upstream_tables(results)
    settings = machine_settings(CONFIG, "tapping-center-a")
    dirs = figure_dirs(results)
    for group, folder in dirs.items():
        if draw and group != "replay":
            draw_group(
                paths,
                group,
                folder,
                figure_format="png",
                coolant_sensors=settings["report"]["coolant_sensors"],
                gates=settings["qualification"],
            )
        else:
            (results / FIGURE_DIRS[group]).mkdir(parents=True, exist_ok=True)
            (results / FIGURE_DIRS[group] / "index.csv").write_text("key,file\n", encoding="utf-8")
    ctx = build_context(paths, dirs, machine="tapping-center-a", settings=settings)
    return ctx, render_html(ctx), results


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    """The fixture rendered without and with the interval results."""
    return {flag: _render(tmp_path_factory.mktemp(f"iv{int(flag)}"), interval=flag) for flag in (False, True)}


def _text(html: str) -> str:
    text = re.sub(r"<style>.*?</style>", "", html, flags=re.S)
    text = html_lib.unescape(re.sub(r"<[^>]+>", " ", text))
    return re.sub(r"\s+", " ", text)


def _number(text: str) -> float:
    return float(text.replace("\u2212", "-").replace("\u00a0", "").replace("\u202f", "").split()[0])


def _table_with(html: str, head: str) -> list[dict]:
    """The records of the first table with a header containing ``head``."""
    for t in html_tables(html):
        if any(head in h for h in t["headers"]):
            return t["records"]
    raise AssertionError(f"no table with a header {head!r}")


def _column(records: list[dict], head: str) -> str:
    return next(h for h in records[0] if head in h)


# --------------------------------------------------------------------------- without / with


def test_older_results_show_no_band_no_coverage_no_sentence(both):
    ctx, html, _ = both[False]
    text = _text(html)
    assert "coverage" not in text.lower()
    assert "interval" not in text.lower()
    assert ctx["verdict"]["interval"] is None and ctx["verdict"]["rafi"]["interval"] is None
    assert ctx["deployed"]["interval"] is None and ctx["choices"]["interval"] is None
    assert not ctx["validation"]["coverage"] and not ctx["comparison"]["coverage"]


def test_the_interval_is_in_every_residual_table_and_section(both):
    ctx, html, _ = both[True]
    text = _text(html)
    assert "9 times in 10" in text
    assert re.search(r"Prediction interval\s+Each compensation comes with a 90\s% interval", text)
    assert "How sure: the 90\u00a0% prediction interval" in html
    for head in ("90\u00a0% interval: coverage (%)", "median interval width (µm)"):
        assert head in html
    # the single-speed, the idle-free fixture's validation table and the deployed table carry both
    single = _table_with(html, "paper Table 4") if ctx["paper_rig"] else _table_with(html, "speed")
    assert _column(single, "coverage") and _column(single, "median interval width")
    # the cells of the deployed section: every cell, its half-width and its fallback as stored
    cells = _table_with(html, "half-width h")
    assert [r["cell"] for r in cells] == list(HALF)
    assert [_number(r["half-width h (µm)"]) for r in cells] == list(HALF.values())
    assert [r["pooled value used"] for r in cells] == ["no", "no", "yes"]
    # the calibration's other plain entries: worded keys left out, "key: value", floats rounded
    other = dict(ctx["deployed"]["interval"]["other"])
    assert other == {"corrected level": "0.904", "pooled half width um": "0.674", "units": "runs"}
    assert "corrected level: 0.904; pooled half width um: 0.674; units: runs." in text
    assert ctx["deployed"]["interval"]["near_largest"] is None and "The level correction" not in text
    # the model comparison: pooled coverage per model, and per run under each model's residual
    table = next(t for t in html_tables(html) if any("median width" in h for h in t["headers"]))
    i = next(k for k, h in enumerate(table["headers"]) if "median width" in h)
    summary = pd.read_csv(both[True][2] / "comparison" / "summary.csv")
    for row, (cov, width) in zip(table["rows"], summary[["coverage", "interval_width_um"]].to_numpy()):
        shown = [_number(re.sub(r"<[^>]+>", "", p)) for p in row[i]["html"].split("<br>")]
        assert shown == [round(100 * cov, 1), round(width, 2)]
    per_run = pd.read_csv(both[True][2] / "comparison" / "per_run.csv")
    table = next(t for t in html_tables(html, "num per-run"))
    for row in table["rows"]:
        run_id = re.sub(r"<[^>]+>", "", row[0]["html"].split("<br>")[0])
        for k, model in enumerate(ctx["comparison"]["run_models"]):
            cov_line = re.sub(r"<[^>]+>", "", row[3 + k]["html"].split("<br>")[2]).split("·")
            want = per_run[(per_run["model"] == model) & (per_run["run_id"] == run_id)].iloc[0]
            assert [_number(v) for v in cov_line] == [
                round(100 * want["coverage"], 1),
                round(want["interval_width_um"], 2),
            ]


def test_the_verdict_sentences_equal_the_tables(both):
    ctx, html, results = both[True]
    text = _text(html)
    # the level is claimed ("right to", "9 times in 10") only where the measured coverage holds it
    pattern = (
        r"At (?:the|its) worst run (\S+) , (?:the compensation is right to \u00b1(\S+)\s?µm , 9 times in 10: "
        r"the 90\s% interval \(median width (\S+)\s?µm\) held|the 90\s% interval is \u00b1(\S+)\s?µm "
        r"\(median width (\S+)\s?µm\); it held) the measured dz on (\S+)\s?% of that run's samples"
    )
    found = [(r, h1 or h2, w1 or w2, cov) for r, h1, w1, h2, w2, cov in re.findall(pattern, text)]
    assert len(found) == 2, found  # the model on the machine and RAFI as published
    # the model on the machine (RAFI here): the deployed section's row of that run
    deployed = _table_with(html, "gates")
    deployed = [r for r in deployed if "validation run" in r]
    for run_id, half, width, cov in found:
        row = next(r for r in deployed if r["validation run"].replace(" ", "") == run_id)
        assert _number(row[_column(deployed, "median interval width")]) == _number(width)
        assert _number(row[_column(deployed, "coverage")]) == _number(cov)
        assert abs(_number(half) - _number(width) / 2) <= 0.006
    # the worst run is the verdict's: the largest max residual of validation/summary.csv
    summ = pd.read_csv(results / "validation" / "summary.csv")
    worst = summ.loc[summ["max_abs_after_um"].idxmax()]
    assert found[0][0] == found[1][0] == worst["run_id"]
    assert _number(found[1][3]) == round(100 * worst["coverage"], 1)
    # the multi-condition paragraph states the same coverage as the table of RAFI's runs
    said = re.search(r"holds the measured dz on (\S+)\s?% of the samples \(coverage\)", text)
    assert said and _number(said.group(1)) == round(100 * worst["coverage"], 1)


def test_a_verdict_without_a_level_says_nothing():
    rows = pd.DataFrame(
        {
            "run_id": ["a", "b"],
            "max_abs_after_um": [1.0, 3.0],
            "coverage": [0.9, 0.8],
            "interval_width_um": [2, 4],
        }
    )
    assert worst_run_interval(rows, None) is None
    assert worst_run_interval(rows.drop(columns="coverage"), 0.9) is None
    assert worst_run_interval(rows.assign(coverage=[0.9, np.nan]), 0.9) is None  # at the worst run
    got = worst_run_interval(rows, 0.9)
    assert got["run_id"] == "b" and got["half_width_um"] == 2.0 and got["coverage_pct"] == 80.0
    assert got["uncompensated_um"] is None  # no uncompensated figure to compare with
    assert times_in(0.9) == "9 times in 10" and times_in(0.95) == "19 times in 20" and times_in(1.0) is None


def test_an_interval_wider_than_the_displacement_itself_is_said():
    """At the worst run the half-width (2 um) against the largest uncompensated change: said only
    when wider than it, with that figure (the machine's own table), in the verdict's sentence."""
    from collections import defaultdict

    from test_report_text import _section

    rows = pd.DataFrame(
        {
            "run_id": ["a", "b"],
            "max_abs_after_um": [1.0, 3.0],
            "max_abs_before_um": [9.0, 1.5],
            "coverage": [0.9, 0.8],
            "interval_width_um": [2.0, 4.0],
        }
    )
    wide = worst_run_interval(rows, 0.9)
    assert wide["uncompensated_um"] == 1.5
    assert worst_run_interval(rows.assign(max_abs_before_um=[9.0, 2.0]), 0.9)["uncompensated_um"] is None
    assert worst_run_interval(rows, 0.9, run_id="a")["uncompensated_um"] is None

    def said(iv):  # a verdict with nothing else to say (every other key absent)
        verdict = defaultdict(lambda: None, interval=iv, css="fail", status="FAIL", stored=True, rows=[])
        return _text(_section("verdict", verdict=verdict))

    text = said(wide)
    assert "That is wider than the displacement change itself on that run (at most 1.50" in text
    assert "cannot be told from none" in text
    narrow = worst_run_interval(rows.assign(max_abs_before_um=[9.0, 2.0]), 0.9)
    assert "At the worst run b" in said(narrow) and "wider than the displacement" not in said(narrow)


# --------------------------------------------------------------------------- figures


@pytest.fixture
def kept(monkeypatch):
    """The figures the plotting functions draw, kept open instead of rendered."""
    figs = []
    for module in (plots, replay_plot):
        monkeypatch.setattr(module, "render", lambda fig, fmt="png": figs.append(fig) or b"")
    yield figs
    for fig in figs:
        plt.close(fig)


def _run(n: int = 200, *, band: bool = True) -> pd.DataFrame:
    t = np.arange(n) * 60.0
    meas = 10 * (1 - np.exp(-t / 3000.0))
    pred = meas + 0.5 * np.sin(t / 500.0)
    f = pd.DataFrame(
        {
            "t_s": t,
            "speed_rpm": np.where(t < t[n // 2], 3000.0, 6000.0),
            "measured_um": meas,
            "predicted_um": pred,
            "residual_um": meas - pred,
            "outside_temp_range": t > t[-20],
            "outside_speed_range": False,
        }
    )
    return _with_interval(f) if band else f


def _bands(ax) -> list[PolyCollection]:
    return [c for c in ax.collections if isinstance(c, PolyCollection) and "interval" in str(c.get_label())]


def _band_limits(band: PolyCollection) -> tuple[float, float]:
    y = np.concatenate([p.vertices[:, 1] for p in band.get_paths()])
    return float(y.min()), float(y.max())


def test_residual_plots_have_the_band_around_zero(kept):
    plots.fig_validation_single({"run a": _run(), "run b": _run(band=False)}, level=0.9)
    (fig,) = kept
    with_band, without = fig.axes[:2]
    (band,) = _bands(with_band)
    assert band.get_label() == "90\u00a0% interval"
    assert _band_limits(band) == (-max(HALF.values()), max(HALF.values()))  # lower - predicted, ...
    assert not _bands(without)
    assert "90\u00a0% interval" in [t.get_text() for t in fig.legends[0].get_texts()]


def test_the_prediction_plot_has_the_band_around_the_prediction(kept):
    f = _run()
    plots.fig_multi_condition(f, temp_sensors=[], level=0.9)
    (band,) = _bands(kept[0].axes[-1])
    lo, hi = _band_limits(band)
    assert lo == pytest.approx(f["lower_um"].min()) and hi == pytest.approx(f["upper_um"].max())
    plots.fig_multi_condition(_run(band=False), temp_sensors=[], level=0.9)
    assert not _bands(kept[1].axes[-1])


def test_comparison_and_deployed_residual_plots_have_a_band_per_model(kept):
    plots.fig_comparison_residuals({"rafi": _run(), "ridge": _run(), "old": _run(band=False)}, level=0.9)
    assert [b.get_label() for b in _bands(kept[0].axes[0])] == [
        "90\u00a0% interval rafi",
        "90\u00a0% interval ridge",
    ]
    f = _run()
    panels = [
        {
            "title": "a",
            "frame": f,
            "noise_floor": 0.5,
            "band": residual_band(f),
            "band_label": "90\u00a0% interval",
        },
        {"title": "b", "frame": _run(band=False), "noise_floor": 0.5},
    ]
    fig = deployed_plot.build_figure(panels)
    try:
        assert len(_bands(fig.axes[1])) == 1 and not _bands(fig.axes[3])
    finally:
        plt.close(fig)


def test_a_long_band_is_thinned_but_holds_every_sample(kept):
    f = _run(20_000)
    plots.fig_validation_single({"long": f}, level=0.9)
    (band,) = _bands(kept[0].axes[0])
    assert sum(len(p.vertices) for p in band.get_paths()) < 10_000
    lo, hi = residual_band(f)
    assert _band_limits(band) == (lo.min(), hi.max())


def test_the_figures_and_the_pdf_are_built_with_the_interval(tmp_path):
    ctx, html, results = _render(tmp_path, interval=True, draw=True)
    assert ctx["deployed"]["figures"] and ctx["validation"]["figure_single"]
    assert ctx["comparison"]["figures_resid"]
    text = _text(html)
    assert (
        "Orange band: the 90 % interval on the residual's scale, [lower − predicted, upper − predicted]"
        in text
    )
    pdf = tmp_path / "qualification.pdf"
    pdf.write_bytes(render_pdf(html))
    words = subprocess.run(
        [which_or_skip("pdftotext"), "-layout", str(pdf), "-"], capture_output=True, text=True, check=True
    ).stdout
    assert "9 times in 10" in words and "How sure: the 90" in words


# --------------------------------------------------------------------------- replay figure


def _replayed(results: Path, runs=("multi-1",), max_interval_um=None) -> pd.DataFrame:
    """The fixture's validation ``runs`` replayed through the safe compensator with the limits
    of config.yaml (and ``deploy.max_interval_um``), as rule replay writes it
    (``deploy/replay.parquet`` and ``deploy/replay_summary.csv``); the replay table is returned."""
    frame, table = pd.read_parquet(results / "runs.parquet"), pd.read_csv(results / "runs.csv")
    files = dict(zip(table["run_id"], table["file"]))
    frame["log"], frame["log_t_s"] = frame["run_id"].map(files), frame["t_s"]  # one run per log
    artefact = json.loads((results / "comparison" / "best_model.json").read_text(encoding="utf-8"))
    deploy = {**machine_settings(CONFIG, "tapping-center-a")["deploy"], "max_interval_um": max_interval_um}
    replayed = replay_runs(frame, list(runs), artefact, Limits.from_settings(deploy))
    (results / "deploy").mkdir()
    replayed.to_parquet(results / "deploy" / "replay.parquet")
    summary = summary_frame(replay_summary(replayed), artefact=artefact)
    summary.to_csv(results / "deploy" / "replay_summary.csv", index=False)
    return replayed


def _draw_replay(results: Path, tmp: Path, folder: Path | None = None) -> list[str]:
    """Figure group ``replay`` of rule report_figures, drawn into ``folder``."""
    paths = result_paths(results)
    return draw_group(
        {k: paths[k] for k in FIGURE_GROUPS["replay"]},
        "replay",
        folder or tmp / "replay-figures",
        figure_format="png",
        coolant_sensors=[],
        gates={},
        deploy={"clamp_um": [-50.0, 50.0]},
    )


def test_the_replay_figure_has_the_band_around_the_model(kept, tmp_path):
    """A real replay of a model with an interval block: the figure of rule report_figures has
    one band, named by the replayed artefact's level, whose edges are the replay table's
    ``lower_um`` and ``upper_um`` at every sample (133 samples: not thinned)."""
    results = copy_fixture(tmp_path)
    add_interval_results(results)
    replayed = _replayed(results)
    assert _draw_replay(results, tmp_path) == ["replay/multi-1"]
    (fig,) = kept
    (band,) = _bands(fig.axes[0])
    assert band.get_label() == "90\u00a0% interval"
    assert "90\u00a0% interval" in [t.get_text() for t in fig.legends[0].get_texts()]
    f = replayed.sort_values("t_s", kind="stable")
    h = (f["t_s"] - f["t_s"].iloc[0]).to_numpy(float) / 3600.0
    lo, hi, model = (f[c].to_numpy(float) for c in ("lower_um", "upper_um", "model_um"))
    assert np.isfinite(lo).all() and (hi - lo > 0).all() and ((lo <= model) & (model <= hi)).all()
    drawn = {(round(x, 9), round(y, 9)) for p in band.get_paths() for x, y in p.vertices}
    for edge in (lo, hi):
        assert {(round(x, 9), round(y, 9)) for x, y in zip(h, edge)} <= drawn
    assert _band_limits(band) == (lo.min(), hi.max())


def test_a_replay_without_an_interval_draws_as_before(kept, tmp_path):
    """The model without an interval block (an older artefact: NaN bounds) and a replay table
    from before intervals (no such columns): no band, and the curves are drawn."""
    results = copy_fixture(tmp_path)
    replayed = _replayed(results)
    assert replayed["lower_um"].isna().all()
    _draw_replay(results, tmp_path)
    old = replayed.drop(columns=["lower_um", "upper_um", "interval_cell"])
    replay_plot.fig_replay(old, clamp_um=(-50.0, 50.0), level=0.9, title="old")
    for fig in kept:
        ax = fig.axes[0]
        assert not _bands(ax)
        labels = [line.get_label() for line in ax.get_lines()]
        assert {"measured dz", "command (what is written)", "model value"} <= set(labels)
    assert len(kept) == 2


def test_a_replay_table_without_interval_columns_still_renders(tmp_path):
    results = copy_fixture(tmp_path)
    old = _replayed(results).drop(columns=["lower_um", "upper_um", "interval_cell"])
    assert replay_plot.fig_replay(old, level=None, fmt="png")[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("interval", [False, True])
def test_the_replay_caption_names_the_band_where_the_figure_has_one(tmp_path, interval):
    results = copy_fixture(tmp_path)
    if interval:
        add_interval_results(results)
    _replayed(results)
    paths = write_upstream_tables(results)
    settings = machine_settings(CONFIG, "tapping-center-a")
    dirs = figure_dirs(results)
    for group in dirs:
        (results / FIGURE_DIRS[group]).mkdir(parents=True, exist_ok=True)
        (results / FIGURE_DIRS[group] / "index.csv").write_text("key,file\n", encoding="utf-8")
    assert _draw_replay(results, tmp_path, dirs["replay"]) == ["replay/multi-1"]
    ctx = build_context(paths, dirs, machine="tapping-center-a", settings=settings)
    html = render_html(ctx)
    text = _text(html)
    assert "Replay of run multi-1" in text and 'id="fig-replay-1"' in html
    named = "the model's value (orange, dashed) with its prediction interval (light orange band) and"
    assert (named in text) is interval


# --------------------------------------------------------------------------- replay: table and rule

#: The widths of the fixture's interval cells are 4, 6 and 8 um (HALF): at 7 um the rule fires
#: on the ``outside`` cell only - alone, and together with the trained-range fault.
WIDE_AT_UM = 7.0


def _replay_html(tmp: Path, *, interval: bool, edit=None, max_interval_um=None) -> tuple[str, Path]:
    """The report HTML of the fixture with runs multi-1 and val-8000 replayed; ``edit`` changes
    ``replay_summary.csv`` (a frame -> a frame) before the report reads it."""
    results = copy_fixture(tmp)
    if interval:
        add_interval_results(results)
    _replayed(results, ("multi-1", "val-8000"), max_interval_um)
    if edit is not None:
        path = results / "deploy" / "replay_summary.csv"
        edit(pd.read_csv(path)).to_csv(path, index=False)
    paths = write_upstream_tables(results)
    dirs = figure_dirs(results)
    for group in dirs:
        (results / FIGURE_DIRS[group]).mkdir(parents=True, exist_ok=True)
        (results / FIGURE_DIRS[group] / "index.csv").write_text("key,file\n", encoding="utf-8")
    _draw_replay(results, tmp, dirs["replay"])
    settings = machine_settings(CONFIG, "tapping-center-a")
    return render_html(build_context(paths, dirs, machine="tapping-center-a", settings=settings)), results


def _replay_runs_table(html: str) -> dict:
    (table,) = html_tables(html, "num replay-runs")
    return table


def test_the_replay_table_shows_the_replay_s_coverage_and_width_as_stored(tmp_path):
    """Coverage (%, 1 digit) and median width (um, 2 digits) of replay_summary.csv per run, as the
    comparison shows them; a run without them (blanked here, as a model without an interval
    writes it) shows a dash. The caption of a run where the wide-interval rule fired says so."""

    def older_val_8000(s):
        s.loc[s["run_id"] == "val-8000", ["coverage", "interval_width_um"]] = np.nan
        return s

    html, results = _replay_html(tmp_path, interval=True, edit=older_val_8000, max_interval_um=WIDE_AT_UM)
    table = _replay_runs_table(html)
    cov_head, width_head = "in the 90\u00a0% interval (%)", "median interval width (µm)"
    assert table["headers"][-2:] == [cov_head, width_head] and len(table["widths"]) == len(table["headers"])
    summary = pd.read_csv(results / "deploy" / "replay_summary.csv").set_index("run_id")
    assert np.isfinite(summary.loc["multi-1", ["coverage", "interval_width_um"]].to_numpy(float)).all()
    rows = {r["run"]: r for r in table["records"]}
    assert set(rows) == {"multi-1", "val-8000"}
    assert _number(rows["multi-1"][cov_head]) == round(100 * summary.loc["multi-1", "coverage"], 1)
    assert _number(rows["multi-1"][width_head]) == round(summary.loc["multi-1", "interval_width_um"], 2)
    assert rows["val-8000"][cov_head] == rows["val-8000"][width_head] == "\u2013"
    text = _text(html)
    assert "interval too wide" in text.split("Replay of run multi-1")[1].split("Figure")[0]


@pytest.mark.parametrize("case", ["no interval block", "older table"])
def test_the_replay_table_has_no_interval_columns_without_a_coverage(tmp_path, case):
    """A model without an interval block (NaN coverage in every run) or a summary written
    before intervals (no such columns): the table as before, no interval column, no dash."""

    def drop(s):
        return s.drop(columns=["coverage", "interval_width_um"])

    interval = case == "older table"
    html, _ = _replay_html(tmp_path, interval=interval, edit=drop if interval else None)
    table = _replay_runs_table(html)
    assert len(table["headers"]) == len(table["widths"]) == 7
    assert not [h for h in table["headers"] if "interval" in h]
    assert "interval too wide" not in _text(html)


def _holds(ax) -> dict:
    """The hold / ramp shading of the replay axes: label -> (PolyCollection, its x vertices)."""
    return {
        c.get_label(): (c, {round(x, 9) for p in c.get_paths() for x, _ in p.vertices})
        for c in ax.collections
        if isinstance(c, PolyCollection) and "(hold / ramp)" in str(c.get_label())
    }


def test_a_hold_by_the_wide_interval_rule_is_shaded_apart(kept, tmp_path):
    """A real replay with deploy.max_interval_um = 7 um: the replay table names the rule in
    ``fault``; the figure of rule report_figures shades the samples held or ramped because of
    the interval alone in an artist of their own ("interval too wide (hold / ramp)", its own
    colour and legend entry), and those with another cause too as the fault rule."""
    results = copy_fixture(tmp_path)
    add_interval_results(results)
    replayed = _replayed(results, max_interval_um=WIDE_AT_UM)
    assert _draw_replay(results, tmp_path) == ["replay/multi-1"]
    f = replayed.sort_values("t_s", kind="stable")
    h = (f["t_s"] - f["t_s"].iloc[0]).to_numpy(float) / 3600.0
    held = f["status"].isin(["hold", "ramp"]).to_numpy()
    causes = f["fault"].str.split("; ")
    wide = causes.map(lambda c: any(x.startswith("interval_wide: ") for x in c)).to_numpy()
    alone = held & causes.map(lambda c: all(x.startswith("interval_wide: ") for x in c)).to_numpy()
    assert alone.any() and (held & ~alone).any() and (held & wide & ~alone).any()
    assert f["fault"][wide].str.contains("wider than deploy.max_interval_um 7 um").all()
    (fig,) = kept
    shades = _holds(fig.axes[0])
    assert set(shades) == {"interval too wide (hold / ramp)", "fault rule (hold / ramp)"}
    mine, x_mine = shades["interval too wide (hold / ramp)"]
    other, x_other = shades["fault rule (hold / ramp)"]
    assert x_mine == {round(x, 9) for x in h[alone]}
    assert x_other == {round(x, 9) for x in h[held & ~alone]}
    assert tuple(mine.get_facecolor()[0]) != tuple(other.get_facecolor()[0])
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert {"interval too wide (hold / ramp)", "fault rule (hold / ramp)"} <= set(legend)
    assert not plot_layout.text_overlaps(fig)  # the extra legend entry fits


def test_without_the_fault_column_every_hold_is_the_fault_rule(kept, tmp_path):
    """A replay table without ``fault`` cannot tell the cause: every hold / ramp is shaded as the
    fault rule, and there is no interval-too-wide entry."""
    results = copy_fixture(tmp_path)
    add_interval_results(results)
    replayed = _replayed(results, max_interval_um=WIDE_AT_UM)
    replay_plot.fig_replay(replayed.drop(columns="fault"), level=0.9)
    (fig,) = kept
    shades = _holds(fig.axes[0])
    assert set(shades) == {"fault rule (hold / ramp)"}
    f = replayed.sort_values("t_s", kind="stable")
    h = (f["t_s"] - f["t_s"].iloc[0]).to_numpy(float) / 3600.0
    held = f["status"].isin(["hold", "ramp"]).to_numpy()
    assert shades["fault rule (hold / ramp)"][1] == {round(x, 9) for x in h[held]}


def test_a_level_correction_near_the_largest_residual_is_said_in_words(both):
    from copy import deepcopy

    from rafi.report.intervals import interval_context

    block = deepcopy(BLOCK)
    block["calibration"].update(corrected_level=0.995, n_runs=4)
    assert interval_context({"interval": block})["near_largest"] == 0.995
    block["calibration"]["corrected_level"] = 0.98
    assert interval_context({"interval": block})["near_largest"] is None
    ctx = deepcopy(both[True][0])
    ctx["deployed"]["interval"].update(near_largest=0.995, n_runs=4)
    text = _text(render_html(ctx))
    assert (
        "The level correction (each calibration unit left out in turn) took the 0.995 quantile of the "
        "held-out residuals, not the 0.90, with 4 calibration units: each cell's half-width sits near "
        "its largest held-out residual." in text
    )


def test_a_borrowed_interval_is_said_whose_it_is(both):
    from copy import deepcopy

    from rafi.report.intervals import interval_context

    block = deepcopy(BLOCK)
    assert interval_context({"interval": block})["borrowed_from"] is None
    block["calibration"]["borrowed_from"] = "prior_shared_gain"
    iv = interval_context({"interval": block})
    assert iv["borrowed_from"] == "prior_shared_gain" and all(k != "borrowed_from" for k, _ in iv["other"])
    ctx = deepcopy(both[True][0])
    ctx["deployed"]["interval"].update(borrowed_from="prior_shared_gain")
    text = _text(render_html(ctx))
    assert "These half-widths are those of prior_shared_gain , fitted on the same prior and runs" in text
    # the calibration's own sentence names whose held-out runs they are, not "the model"
    lender = "the model that lends this one its half-widths (below)"
    assert f"each predicted by prior_shared_gain , {lender}, refitted without it" in text
    assert "each predicted by the model refitted" not in text
    plain = deepcopy(both[True][0])
    plain["deployed"]["interval"].update(borrowed_from=None)
    plain_text = _text(render_html(plain))
    assert "These half-widths are those of" not in plain_text
    assert "each predicted by the model refitted without it" in plain_text


def test_the_cells_that_took_the_pooled_value_are_those_the_calibration_names():
    """A real calibration (rafi.family.intervals.calibrate) with two runs in the transient cell:
    the table says which cells took the pooled value as ``calibration.fallback`` lists them."""
    from rafi.family.intervals import calibrate
    from rafi.report.intervals import interval_context

    rng = np.random.default_rng(4)

    def oof(units: dict, since: float, outside: bool) -> pd.DataFrame:
        return pd.concat(
            [
                pd.DataFrame(
                    {
                        "model": "m",
                        "unit": u,
                        "run_id": u,
                        "t_s": 5.0 * np.arange(len(r)),
                        "residual_um": r,
                        "since_change_s": since,
                        "outside": outside,
                    }
                )
                for u, r in units.items()
            ],
            ignore_index=True,
        )

    frame = pd.concat(
        [
            oof({f"s{k}": rng.normal(0, 1, 100) for k in range(4)}, 1e9, False),
            oof({f"s{k}": rng.normal(0, 3, 20) for k in range(2)}, 10.0, False),  # 2 runs: falls back
            oof({f"s{k}": rng.normal(0, 0.2, 50) for k in range(4)}, 1e9, True),
        ],
        ignore_index=True,
    )
    block = calibrate(
        frame, level=0.9, transient_s=1800, tolerance_rpm=50, min_runs=3, scheme="leave_one_run_out"
    )
    assert block["calibration"]["fallback"] == ["transient"]
    iv = interval_context({"interval": block})
    fell = {c["cell"]: c["fallback"] for c in iv["cells"]}
    assert fell == {"settled": False, "transient": True, "outside": False}
    assert iv["fallbacks"] == ["transient"]
    # the list is worded in the table, not repeated among the calibration's other entries
    assert all(k != "fallback" for k, _ in iv["other"])
    none = {**block, "calibration": {**block["calibration"], "fallback": []}}
    assert not any(c["fallback"] for c in interval_context({"interval": none})["cells"])
