"""The qualification report (rafi.report: tables, figures, context, render, the template) on a small fixture.

The fixture (tests/data/report_fixture/<machine>/, made by generate.py) holds results tables
in the docs/design.md formats, including comparison/* from rafi.family.compare.run_family and
registry/* from two nights of rafi.ops.registry.run_decide (the real producers). Each test first
does what rules report_tables and report_figures do (tables from the model, figure files), then
renders HTML + PDF in a tmp dir, open the HTML in headless Chromium, rasterise the PDF with pdftoppm and
check the layout with WeasyPrint. A variant shaped like machining-center-b (run ids
``thermal_log_2026-10-14#3``, an idle cool-down run, a rejected candidate, recalibration due,
speed-range adaptation, reference.rule log_start) checks the same sections and widths.
"""

from __future__ import annotations

import atexit
import hashlib
import json
import re
import shutil
import subprocess
import sys
import tempfile
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import which_or_skip
from markupsafe import escape
from report_fixture import write_upstream_tables

from rafi.artefact import compute_model_id
from rafi.family.selection import SELECTION_RULE
from rafi.method.validate import qualify
from rafi.report import figures, plots, tables
from rafi.report.context import build_context
from rafi.report.format import equation_text, fmt_duration, fmt_num, fmt_p, fmt_sig, micro, truthy
from rafi.report.inputs import figure_dirs, result_paths
from rafi.report.render import render_html, render_pdf
from rafi.report.verdict import aggregate_verdict
from rafi.settings import machine_settings

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "tests" / "data" / "report_fixture" / "tapping-center-a"
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--hide-scrollbars",
]
PAGE_RANGE = (10, 28)  # the model offered to the machine in full (section 2) adds 3-4 pages


@pytest.fixture(scope="session")
def browser_tools():
    """Chromium and pdftoppm (Debian's chromium and poppler-utils; .ci/run installs them)."""
    return {
        "chromium": which_or_skip("chromium", "chromium-browser", "google-chrome"),
        "pdftoppm": which_or_skip("pdftoppm"),
    }


def _settings(machine: str = "tapping-center-a"):
    cfg = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))
    return cfg, machine_settings(cfg, machine)


#: Figure folders drawn in this process, by what each was drawn from (:func:`_drawn_from`), kept
#: in a folder of their own: most tests here change a table the figures do not read, and get a copy
#: of the files drawing them again would give (drawing is most of a test's time).
_DRAWN: dict[tuple, Path] = {}
_DRAWN_DIR = Path(tempfile.mkdtemp(prefix="rafi-test-figures-"))
atexit.register(shutil.rmtree, _DRAWN_DIR, ignore_errors=True)


def _drawn_from(paths: dict, group: str, settings: dict) -> tuple:
    """What figure group ``group`` is drawn from: its settings and the bytes of every input."""

    def content(path: Path) -> str:
        path, digest = Path(path), hashlib.sha256()
        for f in sorted(path.rglob("*")) if path.is_dir() else [path]:
            if f.is_file():
                digest.update(str(f.relative_to(path.parent)).encode() + b"\0" + f.read_bytes())
        return digest.hexdigest()

    report = settings["report"]
    shown = (report["figure_format"], list(report["coolant_sensors"]), settings["qualification"])
    inputs = [content(paths[name]) for name in figures.FIGURE_GROUPS[group]]
    return (group, json.dumps(shown, sort_keys=True, default=str), *inputs)


def _upstream(results: Path, settings: dict) -> dict:
    """What rules report_tables and report_figures write before the report; the figure
    folders (``comparison`` only when comparison/ exists). A group whose inputs and settings were
    drawn before in this process is copied from that drawing (:data:`_DRAWN`)."""
    paths = write_upstream_tables(results)
    dirs = {}
    for group, folder in figure_dirs(results).items():
        if group == "comparison" and not (results / "comparison").is_dir():
            continue
        key = _drawn_from(paths, group, settings)
        if key not in _DRAWN:
            figures.draw_group(
                paths,
                group,
                folder,
                figure_format=settings["report"]["figure_format"],
                coolant_sensors=settings["report"]["coolant_sensors"],
                gates=settings["qualification"],
            )
            _DRAWN[key] = _DRAWN_DIR / str(len(_DRAWN))
            shutil.copytree(folder, _DRAWN[key])
        else:
            shutil.copytree(_DRAWN[key], folder, dirs_exist_ok=True)
        dirs[group] = folder
    return dirs


def _context(results: Path, settings: dict, **kw) -> dict:
    """The report's context after the upstream rules (:func:`_upstream`)."""
    dirs = _upstream(results, settings)
    return build_context(
        result_paths(results), dirs, machine=kw.pop("machine", results.name), settings=settings, **kw
    )


def _render(results: Path, out: Path, settings: dict, cfg: dict | None = None, machine=None):
    ctx = _context(results, settings, machine=machine or results.name, config=cfg)
    html = render_html(ctx)
    pdf = render_pdf(html)
    out.mkdir(parents=True, exist_ok=True)
    (out / "qualification.html").write_text(html, encoding="utf-8")
    (out / "qualification.pdf").write_bytes(pdf)
    return ctx, html


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """The full fixture (with registry/ and comparison/) rendered to HTML and PDF once."""
    tmp = tmp_path_factory.mktemp("report")
    results = tmp / "results" / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    cfg, settings = _settings()
    out = tmp / "reports" / "tapping-center-a"
    # what rule report shows as the configuration used: the paths, the machine and its settings
    shown = {**{k: cfg[k] for k in ("raw_dir", "results_dir", "reports_dir")}, "settings": settings}
    ctx, html = _render(results, out, settings, shown)
    return {"ctx": ctx, "html": html, "dir": out, "tmp": tmp, "results": results}


#: fixture run id -> a run id as machining-center-b's continuous logs produce them
B_RUN_IDS = {
    "val-4500": "thermal_log_2026-10-14#3",
    "val-8000": "thermal_log_2026-10-14#5",
    "val-10500": "thermal_log_2026-10-15#2",
    "val-13500": "thermal_log_2026-10-15#4",
    "val-16500": "thermal_log_2026-10-16#1",
    "multi-1": "thermal_log_2026-10-16#2",
    "train-9000": "thermal_log_2026-10-12#1",
}
B_IDLE = "thermal_log_2026-10-15#4"


def _machine_b_like(src: Path, dst: Path) -> None:
    """Copy the fixture and reshape it like machining-center-b: continuous-log run ids, one
    idle cool-down validation run, a rejected candidate with speed-range adaptation and a
    drifted champion (recalibration due)."""
    shutil.copytree(src, dst)
    for path in dst.rglob("*"):
        if path.suffix in (".csv", ".json", ".jsonl"):
            text = path.read_text(encoding="utf-8")
            for old, new in B_RUN_IDS.items():
                text = text.replace(f'"{old}"', f'"{new}"').replace(f"{old},", f"{new},")
                text = re.sub(rf"(?<=,){re.escape(old)}(?=[,\n])", new, text)
            path.write_text(text, encoding="utf-8")
        elif path.suffix == ".parquet":
            f = pd.read_parquet(path)
            if "run_id" in f:
                f["run_id"] = f["run_id"].astype(str).replace(B_RUN_IDS)
                f.to_parquet(path)
    model = json.loads((dst / "model.json").read_text(encoding="utf-8"))
    renamed_from, model["model_id"] = model["model_id"], compute_model_id(model)  # train_runs renamed
    (dst / "model.json").write_text(json.dumps(model, indent=2), encoding="utf-8")
    for rel in ("summary.csv", "per_run.csv", "verdict.csv"):  # the comparison's rafi is model.json
        path = dst / "comparison" / rel
        text = path.read_text(encoding="utf-8")
        path.write_text(text.replace(renamed_from, model["model_id"]), encoding="utf-8")
    for rel in ("runs.csv", "validation/summary.csv", "comparison/per_run.csv", "registry/comparison.csv"):
        f = pd.read_csv(dst / rel)
        f.loc[f["run_id"] == B_IDLE, "role"] = "validation_idle"
        f.to_csv(dst / rel, index=False)
    dec = json.loads((dst / "registry" / "decision.json").read_text())
    before = dec["champion_id_before"]
    dec.update(
        decision="rejected",
        champion_id_after=before,
        recalibration_due=True,
        reasons=[
            "gate max_residual_um failed on run thermal_log_2026-10-16#2: measured 13.1, limit 12",
            f"champion {before[:12]} stays",
        ],
        adaptation={
            "retrain_speed_range_rpm": [9000, 12000],
            "mode": "speed_range",
            "kept_from": before,
            "fitted_id": "c" * 64,
            "retrained_speeds_rpm": [9000],
        },
        retrained_speeds=[
            {
                "speed_rpm": 9000,
                "train_runs": ["thermal_log_2026-10-12#1"],
                "files": ["thermal_log_2026-10-12.xlsx"],
            }
        ],
    )
    dec["drift"].update(
        status="degraded",
        detected=True,
        new_max_residual_um=11.5,
        reference_max_residual_um=6.5,
        limit_um=8.5,
        degradation_um=5.0,
        new_runs=["thermal_log_2026-10-16#2"],
        per_run={"thermal_log_2026-10-16#2": 11.5},
    )
    (dst / "registry" / "decision.json").write_text(json.dumps(dec, indent=2))
    _continuous_logs(dst)


def _continuous_logs(dst: Path) -> None:
    """Runs ``<stem>#k`` become runs of the log ``<stem>.xlsx``, one after the other on its
    clock (runs.csv start_s/end_s, runs.parquet log/log_t_s), with the columns of issue 12
    (role_reason, start_time, end_time; role_source ``window`` on one run)."""
    runs = pd.read_csv(dst / "runs.csv")
    frame = pd.read_parquet(dst / "runs.parquet")
    ids = runs["run_id"].astype(str)
    cont = ids.str.contains("#")
    runs.loc[cont, "file"] = ids[cont].str.split("#").str[0] + ".xlsx"
    start = {}
    for _, g in runs[cont].groupby("file"):
        t = 0.0
        for rid in sorted(g["run_id"], key=lambda r: int(r.split("#")[1])):
            start[rid] = t
            t += float(g.loc[g["run_id"] == rid, "duration_s"].iloc[0])
    runs["start_s"] = ids.map(start).fillna(0.0)
    runs["end_s"] = runs["start_s"] + runs["duration_s"] - 120.0
    runs["role_reason"] = [f"reason of {r}: {role}" for r, role in zip(ids, runs["role"])]
    t0 = pd.Timestamp("2026-10-12T06:00:00")
    runs["start_time"] = [(t0 + pd.Timedelta(seconds=v)).isoformat() for v in runs["start_s"]]
    runs["end_time"] = [(t0 + pd.Timedelta(seconds=v)).isoformat() for v in runs["end_s"]]
    runs.loc[ids == B_IDLE, "role_source"] = "window"
    runs.to_csv(dst / "runs.csv", index=False)
    fid = frame["run_id"].astype(str)
    frame["log"] = fid.map(dict(zip(ids, runs["file"])))
    frame["log_t_s"] = frame["t_s"] + fid.map(dict(zip(ids, runs["start_s"]))).astype(float)
    frame.to_parquet(dst / "runs.parquet")


def _assert_nothing_wider_than_page(html: str) -> dict:
    import weasyprint
    from weasyprint.formatting_structure import boxes

    doc = weasyprint.HTML(string=html).render()
    checked = {"table": 0, "image": 0, "pages": len(doc.pages)}
    for page in doc.pages:
        pb = page._page_box
        right = pb.content_box_x() + pb.width + 0.5
        stack = [pb]
        while stack:
            box = stack.pop()
            kind = (
                "table"
                if isinstance(box, boxes.TableBox)
                else "image"
                if isinstance(box, boxes.ReplacedBox)
                else None
            )
            if kind:
                checked[kind] += 1
                edge = box.border_box_x() + box.border_width()
                assert edge <= right, f"{kind} ends at {edge:.1f}px > content edge {right:.1f}px"
            stack.extend(getattr(box, "children", []))
    return checked


def _text(html: str) -> str:
    """Visible-ish text of the HTML: tags (incl. <wbr>) removed, whitespace collapsed."""
    return " ".join(re.sub(r"<[^>]+>", "", html.replace("&lt;", "<")).split())


def _tables(html: str, cls: str) -> list[dict]:
    """The tables of class ``cls`` in the HTML: ``headers`` and ``cells`` (visible text per row)
    and ``widths`` (the number of <col> widths)."""
    out = []
    for m in re.finditer(rf'<table class="{re.escape(cls)}">(.*?)</table>', html, flags=re.S):
        body = m.group(1)
        rows = re.findall(r"<tr>(.*?)</tr>", body, flags=re.S)
        cells = [[_text(c) for c in re.findall(r"<t[dh][^>]*>(.*?)</t[dh]>", r, flags=re.S)] for r in rows]
        out.append({"headers": cells[0], "cells": cells[1:], "widths": body.count("<col ")})
    return out


class _DomSummary(HTMLParser):
    def __init__(self):
        super().__init__()
        self.h2 = []
        self.figures = {}
        self._in_h2 = False
        self._figure = None

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "h2":
            self._in_h2 = True
            self.h2.append("")
        elif tag == "figure":
            self._figure = a.get("id")
            self.figures[self._figure] = []
        elif tag in ("img", "svg") and self._figure is not None:
            self.figures[self._figure].append((tag, (a.get("src") or "")[:30]))

    def handle_endtag(self, tag):
        if tag == "h2":
            self._in_h2 = False
        elif tag == "figure":
            self._figure = None

    def handle_data(self, data):
        if self._in_h2:
            self.h2[-1] += data


# --------------------------------------------------------------------------- browser / PDF


@pytest.mark.slow
def test_html_renders_in_chromium_with_every_section_and_figure(rendered, browser_tools, tmp_path):
    html_path = rendered["dir"] / "qualification.html"
    cmd = [browser_tools["chromium"], *CHROMIUM_FLAGS, f"--user-data-dir={tmp_path / 'profile'}"]
    dom = subprocess.run(
        [*cmd, "--dump-dom", html_path.as_uri()], capture_output=True, text=True, timeout=180, check=True
    ).stdout
    parsed = _DomSummary()
    parsed.feed(dom)
    headings = [" ".join(h.split()) for h in parsed.h2]
    for s in rendered["ctx"]["sections"]:
        assert f"{s['number']}. {s['title']}" in headings, (s, headings)
    for optional in ("Model registry: champion vs candidate", "Model comparison"):
        assert any(optional in h for h in headings)
    assert "Quarantined input" in dom
    expected = set(re.findall(r'<figure id="([^"]+)"', rendered["html"]))
    assert {
        "fig-training",
        "fig-heatmap",
        "fig-residuals",
        "fig-membership",
        "fig-validation-single",
        "fig-multi-1",
        "fig-comparison",
        "fig-comparison-resid-1",
    } <= expected
    assert set(parsed.figures) == expected
    for fid, content in parsed.figures.items():
        assert content, f"figure {fid} has no img/svg in the DOM"
        tag, src = content[0]
        assert tag == "svg" or src.startswith("data:image/png;base64,"), (fid, src)
    shot = tmp_path / "screenshot.png"
    subprocess.run(
        [*cmd, f"--screenshot={shot}", "--window-size=1200,2400", html_path.as_uri()],
        capture_output=True,
        timeout=180,
        check=True,
    )
    assert shot.is_file() and shot.stat().st_size > 20_000


@pytest.mark.slow
def test_pdf_page_count_and_rasterises(rendered, browser_tools, tmp_path):
    subprocess.run(
        [
            browser_tools["pdftoppm"],
            "-r",
            "50",
            "-png",
            str(rendered["dir"] / "qualification.pdf"),
            str(tmp_path / "page"),
        ],
        check=True,
        timeout=180,
    )
    pages = sorted(tmp_path.glob("page-*.png"))
    assert PAGE_RANGE[0] <= len(pages) <= PAGE_RANGE[1], len(pages)
    assert all(p.stat().st_size > 2_000 for p in pages)


def test_no_table_or_figure_wider_than_the_page(rendered):
    checked = _assert_nothing_wider_than_page(rendered["html"])
    assert PAGE_RANGE[0] <= checked["pages"] <= PAGE_RANGE[1], checked
    assert checked["table"] >= 16 and checked["image"] >= 8, checked


def test_pdf_text_has_every_last_column_header(rendered, browser_tools):
    text = subprocess.run(
        ["pdftotext", "-layout", str(rendered["dir"] / "qualification.pdf"), "-"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    flat = " ".join(text.split())
    for header in (
        "role (source) why",  # the segmentation table's last two headers
        "status",
        "vs paper",
        "key sensor",
        "condition",
        "18 000 r/min",
        "RMSE after",
        "worse than",
        "candidate gates",
        "dynamic",
        "gates",
        "Model on the machine after this run",
        "RAFI as published",
        "PASS" if rendered["ctx"]["verdict"]["passed"] else "FAIL",
    ):
        assert header in flat, header


# --------------------------------------------------------------------------- content


def test_verdict_judges_the_model_on_the_machine_and_reports_rafi(rendered):
    v, html = rendered["ctx"]["verdict"], rendered["html"]
    dec = json.loads((FIXTURE / "registry" / "decision.json").read_text())
    after = dec["champion_id_after"]
    assert v["judged"]["id"] == after[:12] and v["judged"]["decision"] == dec["decision"]
    summary = pd.read_csv(FIXTURE / "comparison" / "summary.csv")
    kind = summary.loc[summary["model_id"] == after, "kind"].iloc[0]
    assert v["judged"]["kind"] == kind
    assert "Model on the machine after this run:" in html and after[:12] in html
    # the gate lines are the champion's (registry/comparison.csv), worst case over runs
    comp = pd.read_csv(FIXTURE / "registry" / "comparison.csv")
    col = "candidate" if after == dec["candidate_id"] else "champion"
    rows = {r["criterion"]: r for r in v["rows"]}
    assert set(rows) == {"max_residual_um", "min_improvement_pct", "never_worse_than_uncompensated"}
    assert rows["max_residual_um"]["measured"] == fmt_num(comp[f"{col}_max_abs_after_um"].max(), 2, "\u00b5m")
    assert v["passed"] == all(r["passed"] for r in v["rows"])
    # RAFI as published: its own worst case from validation/summary.csv, beside it
    rafi = {r["criterion"]: r for r in v["rafi"]["rows"]}
    worst = pd.read_csv(FIXTURE / "validation" / "summary.csv")["max_abs_after_um"].max()
    assert rafi["max_residual_um"]["measured"] == fmt_num(worst, 2, "\u00b5m")
    assert rafi["max_residual_um"]["passed"] == (worst <= 12.0)
    assert "RAFI as published" in html and v["rafi"]["status"] in html
    # quarantined input is flagged in the verdict area
    assert v["quarantined"] == 1 and "1 file quarantined" in html


def test_verdict_falls_back_to_rafi_without_decision(tmp_path):
    results = tmp_path / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    (results / "registry" / "decision.json").unlink()
    _, settings = _settings()
    ctx = _context(results, settings, machine="tapping-center-a")
    v = ctx["verdict"]
    assert v["judged"] is None and v["rafi"] is None
    summary = pd.read_csv(FIXTURE / "validation" / "summary.csv")
    rows = {r["criterion"]: r for r in v["rows"]}
    assert rows["max_residual_um"]["measured"] == fmt_num(summary["max_abs_after_um"].max(), 2, "\u00b5m")
    ids = [s["id"] for s in ctx["sections"]]
    assert "registry" not in ids and "comparison" in ids
    html = render_html(ctx)
    assert "Model on the machine after this run" not in html


def test_results_without_stored_verdicts_say_so_and_judge_nothing(tmp_path, monkeypatch):
    """Results written before comparison/verdict.csv and decision.json's verdicts: every verdict
    of the report is NOT STORED (re-run the pipeline), and no gate is judged to fill it in."""
    import rafi.method.validate

    def refuse(*args, **kwargs):
        raise AssertionError("the report judged a gate (rafi.method.validate.qualify)")

    monkeypatch.setattr(rafi.method.validate, "qualify", refuse)
    results = tmp_path / "with_decision" / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    (results / "comparison" / "verdict.csv").unlink()
    dec = json.loads((results / "registry" / "decision.json").read_text())
    for key in ("verdict", "champion_verdict"):
        dec.pop(key, None)
    (results / "registry" / "decision.json").write_text(json.dumps(dec))
    _, settings = _settings()
    ctx = _context(results, settings, machine="tapping-center-a")
    v, g = ctx["verdict"], ctx["registry"]
    assert (v["status"], v["stored"], v["rows"]) == ("NOT STORED", False, [])
    assert (v["rafi"]["status"], v["rafi"]["rows"]) == ("NOT STORED", [])
    assert not g["candidate"]["gates_stored"] and not g["champion"]["gates_stored"]
    assert {r["candidate_passed"] for r in g["runs"]} == {None} == {r["champion_passed"] for r in g["runs"]}
    text = _text(render_html(ctx))
    said = "not stored in this results folder; re-run the pipeline"
    assert f"the verdict on the model on the machine (rafi) is {said}" in text
    assert f"its verdict is {said}" in text and text.count(said) >= 4  # box, RAFI line, both gates
    assert "PASS on every run" not in text and "does not meet" not in text

    # no registry either: the box is RAFI's, not stored
    (results / "registry" / "decision.json").unlink()
    ctx = _context(results, settings, machine="tapping-center-a")
    assert ctx["verdict"]["status"] == "NOT STORED" and ctx["verdict"]["judged"] is None
    text = _text(render_html(ctx))
    assert f"the verdict on the compensation model (RAFI as published) is {said}" in text


def test_registry_section_is_structured_not_a_json_dump(rendered):
    ctx, html = rendered["ctx"], rendered["html"]
    dec = json.loads((FIXTURE / "registry" / "decision.json").read_text())
    g = ctx["registry"]
    assert g["decision"] == dec["decision"] and f'<span class="big">{dec["decision"].upper()}</span>' in html
    for reason in dec["reasons"]:  # with the report's one spelling of the micrometre
        assert str(escape(micro(reason))) in html
    assert dec["candidate_id"][:12] in html and dec["champion_id_before"][:12] in html
    # no flattened keys / raw JSON
    for bad in (
        "verdict.0",
        "verdict.1.",
        "candidate summary.runs",
        "candidate_summary",
        "data.files.",
        "drift.per_run",
        '{"',
    ):
        assert bad not in html, bad
    comp = pd.read_csv(FIXTURE / "registry" / "comparison.csv")
    assert len(g["runs"]) == len(comp)
    text = _text(html)
    for rid in comp["run_id"]:
        assert rid in text
    # drift numbers shown (the fixture's champion drifted; tonight's promotion resolved it)
    d = g["drift"]
    assert d["reference_um"] == dec["drift"]["reference_max_residual_um"]
    for value in (d["reference_um"], d["now"]["value"], d["margin_um"]):
        assert fmt_num(value, 2, "\u00b5m") in html
    assert d["detected"] == dec["drift"]["detected"]
    assert "Retrained speeds" in html and "Drift check" in html


def test_comparison_section(rendered):
    ctx, html = rendered["ctx"], rendered["html"]
    c = ctx["comparison"]
    summary = pd.read_csv(FIXTURE / "comparison" / "summary.csv")
    per_run = pd.read_csv(FIXTURE / "comparison" / "per_run.csv")
    assert len(c["models"]) == len(summary)
    assert len(c["per_run"]) == per_run["run_id"].nunique()
    (per_run_table,) = _tables(html, "num per-run")
    assert len(per_run_table["headers"]) == 3 + len(summary)  # run, before, noise floor, models
    assert len(per_run_table["cells"]) == per_run["run_id"].nunique()
    champ = summary.loc[summary["champion"], "model"]
    assert c["champion"] == (champ.iloc[0] if len(champ) else None)
    assert "RAFI as published is always reported as the paper" in html
    assert c["figure_bars"] and c["figures_resid"]
    assert c["figures_resid"][0]["run_id"] == "multi-1"
    rafi = summary[summary["kind"] == "rafi"].iloc[0]
    if not bool(rafi["passed"]):  # the fixture's RAFI fails the multi-condition run
        assert c["rafi_fail"] and "outside the trained temperature range" in html
        assert "terms extrapolate" in _text(html)
    for m in summary["model"]:
        assert f"<b>{m}</b>" in html
    assert "leave-one-run-out" in html  # CV from cv.csv
    # a kind column only where some model is not named after its kind
    (models_table,) = _tables(html, "num models")
    assert ("kind" in models_table["headers"]) == bool((summary["kind"] != summary["model"]).any())
    assert c["kind_column"] == ("kind" in models_table["headers"])
    assert models_table["widths"] == len(models_table["headers"])
    assert len(models_table["cells"]) == len(summary)
    gates = [row[-1] for row in models_table["cells"]]
    assert gates == ["PASS" if truthy(p) else "FAIL" for p in summary["passed"]]


def test_comparison_lists_what_cross_validation_chose(tmp_path):
    results = tmp_path / "results" / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    summary = pd.read_csv(results / "comparison" / "summary.csv")
    said = {m: f"alpha 5e-05; rises as is; choice of {m}" for m in summary["model"]}
    summary.assign(selected=summary["model"].map(said)).to_csv(
        results / "comparison" / "summary.csv", index=False
    )
    cfg, settings = _settings()
    ctx = _context(results, settings, machine="tapping-center-a", config=cfg)
    html = render_html(ctx)
    assert ctx["comparison"]["selected"] == list(said.items())
    assert "Chosen by cross-validation on the training runs" in html
    for m, what in said.items():
        assert f"<li><b>{m}</b>: {what}</li>" in html


def test_samples_a_model_could_not_compensate_are_said_where_its_figures_are(tmp_path):
    results = tmp_path / "results" / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    summary = pd.read_csv(results / "comparison" / "summary.csv")
    per_run = pd.read_csv(results / "comparison" / "per_run.csv")
    champion = str(summary.loc[summary["champion"].astype(bool), "model"].iloc[0])
    run = str(per_run.loc[per_run["model"] == champion, "run_id"].iloc[0])
    hit = (per_run["model"] == champion) & (per_run["run_id"] == run)
    n_scored = int(per_run.loc[hit, "n_samples"].iloc[0])
    per_run.assign(
        n_unpredicted=hit.astype(int) * 86, unpredicted_inputs=hit.map({True: "T11", False: ""})
    ).to_csv(results / "comparison" / "per_run.csv", index=False)
    mine = summary["model"] == champion
    summary.assign(
        n_unpredicted=mine.astype(int) * 86, unpredicted_inputs=mine.map({True: "T11", False: ""})
    ).to_csv(results / "comparison" / "summary.csv", index=False)
    cfg, settings = _settings()
    text = _text(render_html(_context(results, settings, machine="tapping-center-a", config=cfg)))
    assert f"It gave no compensation on 86 samples of {run} (T11 had no value there)." in text
    assert f"over the samples it compensated ({n_scored} of {n_scored + 86})" in text
    assert f"No value where an input it reads was missing: {champion} on 86 samples (T11)." in text


def test_samples_a_model_could_not_predict_in_the_cv_are_said_in_the_comparison(tmp_path):
    results = tmp_path / "results" / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    cfg, settings = _settings()
    before = _text(render_html(_context(results, settings, machine="tapping-center-a", config=cfg)))
    assert "Likewise in the cross-validation" not in before  # no column, no sentence
    summary = pd.read_csv(results / "comparison" / "summary.csv")
    blind = summary["model"].isin(["ridge_global", "grey_box"])
    summary.assign(
        cv_unpredicted=blind.astype(int) * 106, cv_unpredicted_inputs=blind.map({True: "T10, T8", False: ""})
    ).to_csv(results / "comparison" / "summary.csv", index=False)
    text = _text(render_html(_context(results, settings, machine="tapping-center-a", config=cfg)))
    order = [m for m in summary["model"] if m in ("ridge_global", "grey_box")]
    said = "; ".join(f"{m} on 106 samples (T10, T8)" for m in order)
    assert "CV figures are over the samples of the held-out training runs it predicted." in text
    assert f"No value where an input it reads was missing: {said}; on the controller" in text


def test_training_runs_no_model_explains_are_named_in_the_comparison(tmp_path):
    results = tmp_path / "results" / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    cfg, settings = _settings()
    before = _text(render_html(_context(results, settings, machine="tapping-center-a", config=cfg)))
    assert "Training runs no model explains" not in before
    cv = pd.read_csv(results / "comparison" / "cv.csv")
    held = cv["test_runs"] == "train-6000"
    cv.loc[held, "max_abs_after_um"] = cv.loc[held, "max_abs_before_um"] + 1.0 + np.arange(held.sum())
    cv.to_csv(results / "comparison" / "cv.csv", index=False)
    text = _text(render_html(_context(results, settings, machine="tapping-center-a", config=cfg)))
    best = cv.loc[held].iloc[0]
    runs = cv.loc[cv["scheme"] == "leave_one_run_out", "test_runs"].nunique()
    assert f"Training runs no model explains: On 1 of {runs} training runs held out by the" in text
    figures = f"{best['max_abs_after_um']:.2f} against {best['max_abs_before_um']:.2f} um"
    assert f"train-6000 {best['model']} {figures}" in text


def test_training_runs_set_aside_before_a_change_are_said_and_drawn_in_the_comparison(tmp_path):
    from rafi.family.since_change import change_of, change_table

    results = tmp_path / "results" / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    cfg, settings = _settings()
    runs = pd.DataFrame(
        {"run_id": [f"day{i}#1" for i in range(1, 7)], "role": "training", "start_s": 0.0, "speed_rpm": 6e3}
    ).assign(file=lambda t: t["run_id"].str.removesuffix("#1"))
    cv = pd.DataFrame(
        [("m", "leave_one_run_out", r, 5.0, 9.0 if i >= 3 else 1.0) for i, r in enumerate(runs["run_id"])],
        columns=["model", "scheme", "test_runs", "max_abs_before_um", "max_abs_after_um"],
    )
    change_table(None, cv, runs).to_csv(results / "comparison" / "since_change.csv", index=False)
    before = _text(render_html(_context(results, settings, machine="tapping-center-a", config=cfg)))
    assert "Training runs set aside" not in before and "set aside by" not in before  # empty: nothing said
    table = change_table(change_of(cv, runs, tolerance_rpm=50), cv, runs)
    table.to_csv(results / "comparison" / "since_change.csv", index=False)
    text = _text(render_html(_context(results, settings, machine="tapping-center-a", config=cfg)))
    said = "of which 3 training run(s) recorded before a change were set aside by the model comparison"
    assert said in text
    assert (
        "Training runs set aside: 3 training runs recorded before a change found at day4#1 were set "
        "aside (day1#1 to day3#1): the 3 training runs no model explains lie from it on, with 0 "
        "exceptions" in text
    )
    caption = "The training runs in the order they were recorded, each held out by the cross-validation"
    assert caption in text and caption not in before  # drawn by the figure rule only with runs set aside
    assert plots.fig_since_change(table, fmt="png").startswith(b"\x89PNG")


def test_machine_b_like_results_render_and_fit(tmp_path):
    results = tmp_path / "results" / "machining-center-b"
    _machine_b_like(FIXTURE, results)
    cfg, settings = _settings()
    settings = {**settings, "reference": {"rule": "log_start", "window_s": 60}}
    ctx, html = _render(results, tmp_path / "out", settings, cfg)
    text = _text(html)
    for rid in B_RUN_IDS.values():
        assert rid in text, rid
    g = ctx["registry"]
    assert g["decision"] == "rejected" and '<span class="big">REJECTED</span>' in html and g["drift"]["recal"]
    assert "Recalibration due" in html and ctx["verdict"]["recalibration_due"]
    assert g["adaptation"]["retrained"] and "thermal_log_2026-10-12.xlsx" in html
    assert "[9\u00a0000, 12\u00a0000\u00a0r/min]" in html
    v = ctx["verdict"]
    assert v["judged"]["decision"] == "rejected"
    assert (
        v["judged"]["id"]
        == json.loads((results / "registry" / "decision.json").read_text())["champion_id_before"][:12]
    )
    # the idle run gets only the never-worse gate, in the verdict and the per-run tables
    idle = [r for r in g["runs"] if r["run_id"] == B_IDLE]
    assert idle and idle[0]["role"] == "idle"
    if ctx["comparison"]["rafi_fail"]:
        assert ctx["comparison"]["rafi_fail"]["log_start"] and "do not start cold" in text
    checked = _assert_nothing_wider_than_page(html)
    assert checked["table"] >= 16 and checked["image"] >= 8


def test_no_report_module_builds_a_table_in_python():
    """The report's Python builds data; the templates set every table (one macro, frame_table).
    skipped.py is the exception: the page of a skipped machine is a standard-library-only page
    of its own (no jinja2, no report template), written before any report is built."""
    import rafi.report
    import rafi.report.format as fmt

    assert not hasattr(fmt, "table") and not hasattr(fmt, "cell")
    here = Path(rafi.report.__file__).parent
    for path in sorted(here.glob("*.py")):
        if path.name == "skipped.py":
            continue
        src = path.read_text(encoding="utf-8").lower()
        for tag in ("<table", "<td", "<th", "<tr", "<colgroup"):
            assert tag not in src, f"{path.name} writes {tag}"
    templates = here / "templates"
    for path in sorted(templates.rglob("*.j2")):
        assert "render_table" not in path.read_text(encoding="utf-8"), path.name


def test_segmentation_section_lists_every_run_and_why(tmp_path):
    results = tmp_path / "results" / "machining-center-b"
    _machine_b_like(FIXTURE, results)
    cfg, settings = _settings()
    ctx = _context(results, settings, machine="machining-center-b", config=cfg)
    html = render_html(ctx)
    runs = pd.read_csv(results / "runs.csv")
    sg = ctx["segmentation"]
    assert len(sg["table"]) == len(runs) and sg["n_runs"] == len(runs)
    (seg,) = _tables(html, "segmentation")
    assert len(seg["cells"]) == len(runs)
    assert sg["n_logs"] == runs["file"].nunique()
    text = _text(html)
    for r in runs.itertuples(index=False):
        assert r.role_reason in text, r.run_id
    assert "2026-10-12T06:00:00" in text  # the log's clock, where it has one
    assert "time window" in text  # role_source window, for people
    assert sg["figure"] is not None and 'id="fig-segmentation"' in html
    assert not sg["allow_late"] and "Training after validation allowed" not in html
    # a log with one run per file (the plain fixture) has no timeline
    plain = tmp_path / "results" / "tapping-center-a"
    shutil.copytree(FIXTURE, plain)
    assert _context(plain, settings)["segmentation"]["figure"] is None


def test_training_after_validation_is_said_prominently(tmp_path):
    results = tmp_path / "results" / "machining-center-b"
    _machine_b_like(FIXTURE, results)
    runs = pd.read_csv(results / "runs.csv")
    late = "thermal_log_2026-10-14#5"  # after the validation run #3 of the same log
    runs.loc[runs["run_id"] == late, "role"] = "training"
    runs.to_csv(results / "runs.csv", index=False)
    cfg, settings = _settings()
    settings = {**settings, "runs": {**settings["runs"], "allow_training_after_validation": True}}
    ctx = _context(results, settings, machine="machining-center-b", config=cfg)
    html = render_html(ctx)
    assert ctx["verdict"]["allow_late"] and ctx["verdict"]["late"] == [late]
    verdict_part = html[html.index('id="sec-verdict"') : html.index('id="sec-data"')]
    assert "Training after validation allowed" in verdict_part and late in verdict_part
    assert "allow_training_after_validation: true" in verdict_part


def test_selection_rule_and_noise_floor_are_shown(rendered):
    ctx, html = rendered["ctx"], rendered["html"]
    summary = pd.read_csv(FIXTURE / "comparison" / "summary.csv")
    champ = summary.loc[summary["champion"].map(truthy)].iloc[0]
    sel = ctx["comparison"]["selection"]
    assert sel["champion"] == champ["model"] and sel["basis"] == "cv"
    assert sel["passed"] == truthy(champ["passed"])
    text = _text(html)
    assert _text(str(escape(SELECTION_RULE))) in text
    assert "chosen by whole-run CV on the training runs only" in text
    if not truthy(champ["passed"]):  # the fixture's CV choice fails validation: no second pick
        assert "FAIL, with no second pick" in text
        assert sel["better_on_validation"]
    # the noise floor beside every max residual: verdict, validation, comparison, registry
    floors = pd.read_csv(FIXTURE / "validation" / "summary.csv").set_index("run_id")["noise_floor_um"]
    rows = {r["criterion"]: r for r in ctx["verdict"]["rows"]}
    worst = rows["max_residual_um"]["run_id"].removeprefix("run ")
    assert rows["max_residual_um"]["noise"] == fmt_num(floors[worst], 2, "\u00b5m")
    (single,) = [t for t in _tables(html, "num") if t["headers"][:3] == ["run", "speed", "duration"]]
    assert "noise floor" in single["headers"][5] and len(single["cells"]) == len(ctx["validation"]["single"])
    assert any("noise floor" in h for h in _tables(html, "num models")[0]["headers"])
    assert any("noise floor" in h for h in _tables(html, "num runs-cmp")[0]["headers"])
    assert "noise floor of that run" in text


def test_rafi_failure_reason_is_computed_from_the_data(rendered):
    c = rendered["ctx"]["comparison"]
    per_run = pd.read_csv(FIXTURE / "comparison" / "per_run.csv")
    bad = per_run[(per_run["model"] == "rafi") & ~per_run["passed"].map(truthy)]
    assert c["rafi_fail"]["n"] == len(bad)
    share = 100.0 * bad["n_outside_temp_range"] / bad["n_samples"]
    assert c["rafi_fail"]["max_temp_pct"] == pytest.approx(share.max())
    text = _text(rendered["html"])
    most = _text(fmt_num(share.max(), 0, "%"))
    assert f"(up to {most})" in text or f"(at most {most} of the samples outside)" in text
    assert c["rafi_fail"]["key_sensor_r"] is not None  # the key sensors' collinearity, rank/collinearity.csv
    assert f"|r| = {fmt_num(c['rafi_fail']['key_sensor_r'], 3)}" in text


def test_figures_are_the_files_of_report_figures(tmp_path):
    """Rule report_figures writes one file per figure and index.csv; the report embeds exactly
    those (a figure not listed is not drawn by the report), and needs the folder of every group
    it shows."""
    results = tmp_path / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    cfg, settings = _settings()
    dirs = _upstream(results, settings)
    index = {g: pd.read_csv(Path(d) / "index.csv") for g, d in dirs.items()}
    assert {
        "training_runs",
        "correlation_heatmap",
        "fit_residuals",
        "membership",
        "validation_single",
    } <= set(index["pipeline"]["key"])
    for g, frame in index.items():
        assert all((Path(dirs[g]) / f).is_file() and f.endswith(".png") for f in frame["file"])
    ctx = build_context(
        result_paths(results), dirs, machine="tapping-center-a", settings=settings, config=cfg
    )
    html = render_html(ctx)
    assert html.count('src="data:image/png;base64,') == len(ctx["figures_used"]) >= 8
    # a figure the group did not draw is absent from the report, not drawn by it
    pipe = index["pipeline"]
    pipe[pipe["key"] != "membership"].to_csv(Path(dirs["pipeline"]) / "index.csv", index=False)
    ctx = build_context(result_paths(results), dirs, machine="tapping-center-a", settings=settings)
    assert ctx["fuzzy"]["figure"] is None and 'id="fig-membership"' not in render_html(ctx)
    with pytest.raises(ValueError, match="no figure folder of group 'comparison'"):
        build_context(result_paths(results), {"pipeline": dirs["pipeline"]}, machine="m", settings=settings)
    with pytest.raises(ValueError, match="no path for"):
        figures.draw_group(
            {"comparison": results / "comparison" / "summary.csv"},
            "comparison",
            tmp_path / "f",
            figure_format="png",
            coolant_sensors=["T13"],
            gates=settings["qualification"],
        )


def test_residuals_beside_rafi_follow_the_registry(tmp_path):
    """RAFI's residuals are drawn ahead beside every other model, so the report shows them beside
    the model the registry put on the machine, also when that is not the family's champion."""
    results = tmp_path / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    _, settings = _settings()
    summary = pd.read_csv(results / "comparison" / "summary.csv")
    other = summary[~summary["champion"].map(truthy) & (summary["kind"] != "rafi")].iloc[0]
    dec_path = results / "registry" / "decision.json"
    dec = json.loads(dec_path.read_text())
    dec["champion_id_after"] = other["model_id"]
    dec_path.write_text(json.dumps(dec))
    ctx = _context(results, settings, machine="tapping-center-a")
    resid = ctx["comparison"]["figures_resid"]
    assert resid and all(f["other"] == other["model"] and f["figure"] for f in resid)
    assert f"comparison/comparison_residuals/{resid[0]['run_id']}/{other['model']}" in ctx["figures_used"]


def test_the_report_job_evaluates_no_model_and_draws_nothing(tmp_path):
    """Building and rendering the report imports neither matplotlib nor the model's code."""
    results = tmp_path / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    _, settings = _settings()
    dirs = _upstream(results, settings)
    code = (
        "import sys, json\n"
        "from rafi.report.context import build_context\n"
        "from rafi.report.render import render_html\n"
        "from rafi.report.inputs import result_paths\n"
        f"settings = json.loads({json.dumps(json.dumps(settings))})\n"
        f"dirs = {json.dumps({g: str(d) for g, d in dirs.items()})}\n"
        f"ctx = build_context(result_paths({str(results)!r}), dirs, machine='m', settings=settings)\n"
        "render_html(ctx)\n"
        "bad = [m for m in ('matplotlib', 'rafi.method.model', 'rafi.method.fuzzy', 'rafi.report.plots') "
        "if m in sys.modules]\n"
        "print(bad)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", out


def test_report_tables_come_from_the_model(tmp_path):
    """report_tables: the worked example and the training fit evaluated with RafiModel itself."""
    from rafi.method.model import RafiModel

    doc = json.loads((FIXTURE / "model.json").read_text())
    runs, frames = pd.read_csv(FIXTURE / "runs.csv"), pd.read_parquet(FIXTURE / "runs.parquet")
    ex = tables.fuzzy_example(doc, None, runs, frames)
    assert ex["example_rpm"] == 4000.0 and [n["centre_rpm"] for n in ex["neighbours"]] == [3000.0, 6000.0]
    w = [n["weight"] for n in ex["neighbours"]]
    assert w == pytest.approx([2 / 3, 1 / 3])
    z = [n["model_dz_um"] for n in ex["neighbours"]]
    assert ex["blended_dz_um"] == pytest.approx(w[0] * z[0] + w[1] * z[1])
    model = RafiModel.from_dict(doc)
    state = pd.DataFrame([ex["state"]]).assign(speed_rpm=3000.0)
    assert z[0] == pytest.approx(model.predict(state)[0])
    rmse = tables.training_rmse(tables.training_fit(doc, runs, frames))
    diag = pd.read_csv(FIXTURE / "fit" / "diagnostics.csv")
    assert np.allclose(rmse["rmse_um"], diag.sort_values("speed_rpm")["rmse_um"], rtol=0.02)
    assert tables.fuzzy_example({}, None, None, None)["example_rpm"] is None


def test_envelope_keeps_extremes_and_bounds_points():
    from rafi.report import plot_layout

    x = np.arange(100_000, dtype=float)
    y = np.sin(x / 500.0)
    y[12_345] = 7.0
    y[54_321] = -9.0
    y[70_000:70_500] = np.nan
    xe, ye = plot_layout.envelope(x, y, max_points=1000)
    assert len(xe) <= 1002 and np.all(np.diff(xe) >= 0)
    assert np.nanmax(ye) == 7.0 and np.nanmin(ye) == -9.0
    assert np.isnan(ye).any()  # an all-NaN bucket stays a gap
    xs, ys = plot_layout.envelope(x[:500], y[:500], max_points=1000)
    assert len(xs) == 500  # short series unchanged


def test_verdict_aggregates_the_worst_case_per_criterion():
    summary = pd.DataFrame(
        {
            "run_id": ["a", "b", "idle"],
            "role": ["validation_single", "validation_multi", "validation_idle"],
            "max_abs_before_um": [20.0, 30.0, 10.0],
            "max_abs_after_um": [5.0, 13.0, 11.0],
            "improvement_pct": [75.0, 56.7, -10.0],
        }
    )
    gates = {"max_residual_um": 12.0, "min_improvement_pct": 30.0, "never_worse_than_uncompensated": True}
    rows = {r["criterion"]: r for r in aggregate_verdict(qualify(summary, gates), {"b": 0.73})}
    assert not rows["max_residual_um"]["passed"] and "b" in rows["max_residual_um"]["run_id"]
    assert rows["max_residual_um"]["noise"] == "0.73\u00a0\u00b5m"  # the noise floor of run b
    # issue 12: the idle cool-down is held to every gate and is in the worst case
    assert not rows["min_improvement_pct"]["passed"] and "idle" in rows["min_improvement_pct"]["run_id"]
    assert rows["min_improvement_pct"]["n_runs"] == 3
    assert not rows["never_worse_than_uncompensated"]["passed"]
    assert rows["never_worse_than_uncompensated"]["measured"] == "1 of 3"
    # an idle run with the largest residual is the headline
    idle_worst = summary.assign(max_abs_after_um=[5.0, 6.6, 12.9], improvement_pct=[75, 78, 60])
    rows = {r["criterion"]: r for r in aggregate_verdict(qualify(idle_worst, gates))}
    assert rows["max_residual_um"]["measured"] == "12.90\u00a0\u00b5m"
    assert "idle" in rows["max_residual_um"]["run_id"]
    assert not rows["max_residual_um"]["passed"]


def test_sections_and_numbers(rendered):
    ctx, html = rendered["ctx"], rendered["html"]
    assert [s["id"] for s in ctx["sections"]] == [
        "verdict",
        "deployed",
        "data",
        "test_record",
        "segmentation",
        "equilibrium",
        "ranking",
        "models",
        "fuzzy",
        "validation",
        "registry",
        "comparison",
        "choices",
        "provenance",
    ]
    # figures numbered 1, 2, ... in document order, the offered model's first
    numbers = [int(n) for n in re.findall(r"<figcaption>Figure (\d+)\.", html)]
    assert numbers == list(range(1, len(numbers) + 1)) and len(numbers) >= 8
    assert re.search(r"<figcaption>Figure 1\. \w+ \(the model offered to the machine\)", html)
    assert "0.334 and 0.666, respectively" in html
    ex = ctx["fuzzy"]["example"]
    assert [n["weight"] for n in ex["neighbours"]] == pytest.approx([2 / 3, 1 / 3])
    assert "<b>0.667</b> on 3\u00a0000\u00a0r/min and <b>0.333</b> on 6\u00a0000\u00a0r/min" in html
    assert "10\u00a0160\u00a0s" in html  # paper Table 1, 3000 r/min
    assert "10.03" in html and "0.639" in html  # paper Tables 4 and 3
    assert "2026-03-18_broken_logger.csv" in html and "decimal comma" in html
    assert "rafi_linear" in html and "ridge_global" in html
    assert len(ctx["models"]["equations"]) == 6
    assert not ctx["models"]["mismatches"]  # model.json reproduces diagnostics RMSE
    for pkg in ("python", "numpy", "pandas", "statsmodels", "snakemake", "rafi"):
        assert f"<td>{pkg}</td>" in html
    assert "<code>report.paper_rig</code>" in html  # configuration: what differs from the defaults
    assert "run_start" in html and "min_per_speed" in html


def test_optional_sections_absent_without_their_files(tmp_path):
    results = tmp_path / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    shutil.rmtree(results / "registry")
    shutil.rmtree(results / "comparison")
    audit = pd.read_csv(results / "audit.csv")
    audit[audit["status"] == "ok"].to_csv(results / "audit.csv", index=False)
    info = json.loads((results / "rank" / "key_sensors.json").read_text())
    info.update(fallback_used=True, message="only 2 sensors passed |r| > 0.97; T9 added as fallback")
    (results / "rank" / "key_sensors.json").write_text(json.dumps(info))
    _, settings = _settings()
    settings["report"]["figure_format"] = "svg"
    ctx = _context(results, settings, machine="tapping-center-a")
    html = render_html(ctx)
    ids = [s["id"] for s in ctx["sections"]]
    assert "registry" not in ids and "comparison" not in ids
    assert "Model registry" not in html and "Model comparison" not in html
    assert "Quarantined input" not in html
    assert "Fallback used" in html and "T9 added as fallback" in html
    assert html.count("<svg") >= 6 and 'src="data:image/png' not in html


# --------------------------------------------------------------------------- formatting


@pytest.mark.parametrize(
    "value, args, expected",
    [
        (1234.5, (1, "\u00b5m"), "1\u00a0234.5\u00a0\u00b5m"),
        (-0.004, (2,), "0.00"),
        (-3.25, (2,), "\u22123.25"),
        (float("nan"), (2,), "\u2013"),
        (None, (2,), "\u2013"),
    ],
)
def test_fmt_num(value, args, expected):
    assert fmt_num(value, *args) == expected


def test_fmt_sig_and_p():
    assert fmt_sig(0.0012345, 3) == "0.00123"
    assert fmt_sig(568462, 2) == "5.7\u00d710\u2075"
    assert fmt_sig(-2.5e-5, 2) == "\u22122.5\u00d710\u207b\u2075"
    assert fmt_p(0.0004) == "<\u00a00.001"
    assert fmt_duration(14400) == "4.00\u00a0h"


def test_equation_text():
    eq = str(equation_text([0.12, 1.23, -0.5, 2e-6], ["1", "x1", "x1*x2", "x3^2"], {}))
    assert (
        "dz = 0.1200 + 1.230\u00a0x\u2081 \u2212 0.5000\u00a0x\u2081\u00b7x\u2082 + "
        "2.000\u00d710\u207b\u2076\u00a0x\u2083\u00b2"
    ) in eq


def test_input_warnings_and_machine_level_rejections_are_shown(tmp_path):
    """Issue 13: a suspicious file is listed with its check; unconfirmed ones raise an alert in the
    verdict; a file rejected for the machine (input_status.json) is listed as not used."""
    results = tmp_path / "results" / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    status = {
        "machine": "tapping-center-a",
        "status": "usable",
        "rejected": [
            {"file": "copy.csv", "sha256": "ab" * 32, "reason": "byte-identical to a.csv [duplicate_content]"}
        ],
        "warnings": [
            {"file": "b.csv", "sha256": "cd" * 32, "check": "metadata_machine", "column": None,
             "message": "the header names machine x", "confirmed": True},
            {"file": "a.csv", "sha256": "ef" * 32, "check": "probe_sign", "column": "disp_um",
             "message": "dz falls while the temperatures rise", "confirmed": False},
        ],
    }  # fmt: skip
    (results / "input_status.json").write_text(json.dumps(status), encoding="utf-8")
    cfg, settings = _settings()
    ctx = _context(results, settings, config=cfg)
    html = render_html(ctx)
    assert ctx["verdict"]["unconfirmed_warnings"] == 1
    assert [w["check"] for w in ctx["data"]["warnings"]] == ["probe_sign", "metadata_machine"]
    verdict_part = html[html.index('id="sec-verdict"') : html.index('id="sec-data"')]
    assert "1 input warning not confirmed" in _text(verdict_part)
    data_part = _text(html[html.index('id="sec-data"') :])
    assert "dz falls while the temperatures rise" in data_part and "not confirmed" in data_part
    assert "copy.csv" in data_part and "[duplicate_content]" in data_part
    # without input_status.json (older results) the section is simply absent
    (results / "input_status.json").unlink()
    ctx = _context(results, settings, config=cfg)
    assert ctx["data"]["warnings"] == [] and ctx["verdict"]["unconfirmed_warnings"] == 0


def _relative_luminance(rgba) -> float:
    def channel(c):
        return c / 12.92 if c <= 0.03928 else ((c + 0.055) / 1.055) ** 2.4

    rgb = rgba.to("srgb").coordinates if hasattr(rgba, "to") else (rgba.red, rgba.green, rgba.blue)
    r, g, b = (channel(v) for v in rgb)
    return 0.2126 * r + 0.7152 * g + 0.0722 * b


def _text_on_backgrounds(box, background=None):
    """(text, its colour, the nearest opaque background below it) for every text box."""
    own = box.style["background_color"]
    if own.alpha == 1 and box.element_tag not in ("html", "body"):
        background = own
    text = getattr(box, "text", "").strip()
    if text and background is not None:
        yield text, box.style["color"], background
    for child in getattr(box, "children", ()):
        yield from _text_on_backgrounds(child, background)


def test_text_on_coloured_backgrounds_is_legible(rendered):
    """Badges and banners: text drawn on a coloured background contrasts with it.

    WeasyPrint's cascade (the PDF's renderer) is the oracle for the colours actually used; the
    bound is WCAG 2's contrast ratio of 3 for bold/large text. A ``span.pass`` rule once won on
    specificity and drew the PASS badges green on green.
    """
    import weasyprint

    document = weasyprint.HTML(string=rendered["html"]).render()
    checked, illegible = 0, []
    for page in document.pages:
        for text, colour, background in _text_on_backgrounds(page._page_box):
            light, dark = sorted((_relative_luminance(colour), _relative_luminance(background)), reverse=True)
            checked += 1
            if (light + 0.05) / (dark + 0.05) < 3:
                illegible.append(text[:30])
    assert checked > 20
    assert not illegible, sorted(set(illegible))
