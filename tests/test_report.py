"""The qualification report (rafi.report, rafi.plots, the template) on a small fixture.

The fixture (tests/data/report_fixture/<machine>/) holds results tables in the
docs/design.md formats; the tests render HTML + PDF in a tmp dir, open the HTML in
headless Chromium, rasterise the PDF with pdftoppm and check the layout with WeasyPrint.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pandas as pd
import pytest
import yaml

from rafi import report

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "tests" / "data" / "report_fixture" / "tapping-center-a"
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--disable-dev-shm-usage", "--hide-scrollbars"]
PAGE_RANGE = (8, 22)


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.fixture(scope="session")
def browser_tools():
    """Chromium and pdftoppm; installed with apt-get when missing (CI runs as root)."""
    if _chromium() is None or shutil.which("pdftoppm") is None:
        try:
            subprocess.run(["apt-get", "update"], check=True, capture_output=True, timeout=600)
            subprocess.run(["apt-get", "install", "-y", "chromium", "poppler-utils"], check=True,
                           capture_output=True, timeout=1200)
        except (OSError, subprocess.SubprocessError) as exc:
            pytest.skip(f"chromium/pdftoppm missing and apt-get install failed: {exc}")
    if _chromium() is None or shutil.which("pdftoppm") is None:
        pytest.skip("chromium or pdftoppm not available after apt-get install")
    return {"chromium": _chromium(), "pdftoppm": shutil.which("pdftoppm")}


def _settings():
    cfg = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))
    return cfg, dict(cfg["defaults"])


def _with_optional(results: Path) -> None:
    (results / "registry").mkdir(parents=True, exist_ok=True)
    (results / "registry" / "decision.json").write_text(json.dumps({
        "decision": "promote candidate", "reason": "candidate passes all gates, champion fails one",
        "champion": {"model_id": "a" * 64, "max_residual_um": 13.2, "passed": False},
        "candidate": {"model_id": "b" * 64, "max_residual_um": 9.8, "passed": True}}))
    (results / "comparison").mkdir(parents=True, exist_ok=True)
    pd.DataFrame({"model": ["rafi", "ridge", "linear_T6"], "max_residual_um": [9.8, 11.0, 15.2],
                  "rmse_um": [2.1, 2.6, 4.4], "min_improvement_pct": [31.0, 28.5, 12.0],
                  "passed": [True, False, False]}).to_csv(results / "comparison" / "summary.csv",
                                                          index=False)


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """Full fixture + optional inputs rendered to HTML and PDF once for the module."""
    tmp = tmp_path_factory.mktemp("report")
    results = tmp / "results" / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    _with_optional(results)
    cfg, settings = _settings()
    out = tmp / "reports" / "tapping-center-a"
    ctx = report.build_context(report.result_paths(results), machine="tapping-center-a",
                               settings=settings, config=cfg)
    html = report.render_html(ctx)
    pdf = report.render_pdf(html)
    out.mkdir(parents=True)
    (out / "qualification.html").write_text(html, encoding="utf-8")
    (out / "qualification.pdf").write_bytes(pdf)
    return {"ctx": ctx, "html": html, "dir": out, "tmp": tmp, "results": results}


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
    dom = subprocess.run([*cmd, "--dump-dom", html_path.as_uri()], capture_output=True, text=True,
                         timeout=180, check=True).stdout
    parsed = _DomSummary()
    parsed.feed(dom)
    headings = [" ".join(h.split()) for h in parsed.h2]
    for s in rendered["ctx"]["sections"]:
        assert f"{s['number']}. {s['title']}" in headings, (s, headings)
    for optional in ("Model registry: champion vs candidate", "Model comparison"):
        assert any(optional in h for h in headings)
    assert "Quarantined input" in dom
    expected = set(re.findall(r'<figure id="([^"]+)"', rendered["html"]))
    assert {"fig-training", "fig-heatmap", "fig-residuals", "fig-membership",
            "fig-validation-single", "fig-multi-1"} <= expected
    assert set(parsed.figures) == expected
    for fid, content in parsed.figures.items():
        assert content, f"figure {fid} has no img/svg in the DOM"
        tag, src = content[0]
        assert tag == "svg" or src.startswith("data:image/png;base64,"), (fid, src)
    shot = tmp_path / "screenshot.png"
    subprocess.run([*cmd, f"--screenshot={shot}", "--window-size=1200,2400", html_path.as_uri()],
                   capture_output=True, timeout=180, check=True)
    assert shot.is_file() and shot.stat().st_size > 20_000


@pytest.mark.slow
def test_pdf_page_count_and_rasterises(rendered, browser_tools, tmp_path):
    subprocess.run([browser_tools["pdftoppm"], "-r", "50", "-png",
                    str(rendered["dir"] / "qualification.pdf"), str(tmp_path / "page")],
                   check=True, timeout=180)
    pages = sorted(tmp_path.glob("page-*.png"))
    assert PAGE_RANGE[0] <= len(pages) <= PAGE_RANGE[1], len(pages)
    assert all(p.stat().st_size > 2_000 for p in pages)


def test_no_table_or_figure_wider_than_the_page(rendered):
    import weasyprint
    from weasyprint.formatting_structure import boxes

    doc = weasyprint.HTML(string=rendered["html"]).render()
    assert PAGE_RANGE[0] <= len(doc.pages) <= PAGE_RANGE[1]
    checked = {"table": 0, "image": 0}
    for page in doc.pages:
        pb = page._page_box
        right = pb.content_box_x() + pb.width + 0.5
        stack = [pb]
        while stack:
            box = stack.pop()
            kind = ("table" if isinstance(box, boxes.TableBox) else
                    "image" if isinstance(box, boxes.ReplacedBox) else None)
            if kind:
                checked[kind] += 1
                edge = box.border_box_x() + box.border_width()
                assert edge <= right, f"{kind} ends at {edge:.1f}px > content edge {right:.1f}px"
            stack.extend(getattr(box, "children", []))
    assert checked["table"] >= 12 and checked["image"] >= 6, checked


def test_pdf_text_has_every_last_column_header(rendered):
    if shutil.which("pdftotext") is None:
        pytest.skip("pdftotext (poppler-utils) not installed")
    text = subprocess.run(["pdftotext", "-layout", str(rendered["dir"] / "qualification.pdf"), "-"],
                          capture_output=True, text=True, check=True).stdout
    flat = " ".join(text.split())
    for header in ("sha256 (first 12)", "status", "vs paper", "key sensor", "condition",
                   "18 000 r/min", "RMSE after", "worse than", "PASS" if rendered["ctx"]["verdict"][
                       "passed"] else "FAIL"):
        assert header in flat, header


# --------------------------------------------------------------------------- content

def test_verdict_is_worst_case_per_criterion(rendered):
    v = rendered["ctx"]["verdict"]
    rows = {r["criterion"]: r for r in v["rows"]}
    assert set(rows) == {"max_residual_um", "min_improvement_pct", "never_worse_than_uncompensated"}
    summary = pd.read_csv(FIXTURE / "validation" / "summary.csv")
    worst = summary["max_abs_after_um"].max()
    assert rows["max_residual_um"]["measured"] == report.fmt_num(worst, 2, "\u00b5m")
    assert rows["max_residual_um"]["passed"] == (worst <= 12.0)
    assert v["passed"] == all(r["passed"] for r in v["rows"])
    assert v["status"] in rendered["html"]


def test_fallback_qualify_matches_design_rules():
    summary = pd.DataFrame({"run_id": ["a", "b", "idle"],
                            "role": ["validation_single", "validation_multi", "validation_idle"],
                            "max_abs_before_um": [20.0, 30.0, 10.0],
                            "max_abs_after_um": [5.0, 13.0, 11.0],
                            "improvement_pct": [75.0, 56.7, -10.0]})
    gates = {"max_residual_um": 12.0, "min_improvement_pct": 30.0,
             "never_worse_than_uncompensated": True}
    rows = {r["criterion"]: r for r in report.aggregate_verdict(report.qualify_fallback(summary, gates))}
    assert not rows["max_residual_um"]["passed"] and "b" in rows["max_residual_um"]["run_id"]
    assert rows["min_improvement_pct"]["passed"]          # idle run is not held to it
    assert not rows["never_worse_than_uncompensated"]["passed"]
    assert rows["never_worse_than_uncompensated"]["measured"] == "1 of 3"


def test_sections_and_numbers(rendered):
    ctx, html = rendered["ctx"], rendered["html"]
    assert [s["id"] for s in ctx["sections"]] == ["verdict", "data", "equilibrium", "ranking",
                                                  "models", "fuzzy", "validation", "registry",
                                                  "comparison", "choices", "provenance"]
    assert "0.334 and 0.666, respectively" in html
    ex = ctx["fuzzy"]["example"]
    assert ex["w0"] == "0.667" and ex["w1"] == "0.333"
    assert "10\u00a0160\u00a0s" in html          # paper Table 1, 3000 r/min
    assert "10.03" in html and "0.639" in html      # paper Tables 4 and 3
    assert "2026-03-18_broken_logger.csv" in html and "decimal comma" in html
    assert "promote candidate" in html and "linear_T6" in html
    assert len(ctx["models"]["equations"]) == 6
    assert not ctx["models"]["mismatches"]          # model.json reproduces diagnostics RMSE
    for pkg in ("python", "numpy", "pandas", "statsmodels", "snakemake", "rafi"):
        assert f"<td>{pkg}</td>" in html
    assert "max_residual_um: 12.0" in html          # config dump
    assert "run_start" in html and "min_per_speed" in html


def test_optional_sections_absent_without_their_files(tmp_path):
    results = tmp_path / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    audit = pd.read_csv(results / "audit.csv")
    audit[audit["status"] == "ok"].to_csv(results / "audit.csv", index=False)
    info = json.loads((results / "rank" / "key_sensors.json").read_text())
    info.update(fallback_used=True, message="only 2 sensors passed |r| > 0.97; T9 added as fallback")
    (results / "rank" / "key_sensors.json").write_text(json.dumps(info))
    _, settings = _settings()
    ctx = report.build_context(report.result_paths(results), machine="tapping-center-a",
                               settings=settings, figure_format="svg")
    html = report.render_html(ctx)
    ids = [s["id"] for s in ctx["sections"]]
    assert "registry" not in ids and "comparison" not in ids
    assert "Model registry" not in html and "Model comparison" not in html
    assert "Quarantined input" not in html
    assert "Fallback used" in html and "T9 added as fallback" in html
    assert html.count("<svg") >= 6 and 'src="data:image/png' not in html


# --------------------------------------------------------------------------- formatting

@pytest.mark.parametrize("value, args, expected", [
    (1234.5, (1, "\u00b5m"), "1\u00a0234.5\u00a0\u00b5m"),
    (-0.004, (2,), "0.00"),
    (-3.25, (2,), "\u22123.25"),
    (float("nan"), (2,), "\u2013"),
    (None, (2,), "\u2013"),
])
def test_fmt_num(value, args, expected):
    assert report.fmt_num(value, *args) == expected


def test_fmt_sig_and_p():
    assert report.fmt_sig(0.0012345, 3) == "0.00123"
    assert report.fmt_sig(568462, 2) == "5.7\u00d710\u2075"
    assert report.fmt_sig(-2.5e-5, 2) == "\u22122.5\u00d710\u207b\u2075"
    assert report.fmt_p(0.0004) == "<\u00a00.001"
    assert report.fmt_duration(14400) == "4.00\u00a0h"


def test_equation_text():
    eq = str(report.equation_text([0.12, 1.23, -0.5, 2e-6], ["1", "x1", "x1*x2", "x3^2"], {}))
    assert ("dz = 0.1200 + 1.230\u00a0x\u2081 \u2212 0.5000\u00a0x\u2081\u00b7x\u2082 + "
            "2.000\u00d710\u207b\u2076\u00a0x\u2083\u00b2") in eq
