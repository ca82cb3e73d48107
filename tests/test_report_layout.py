"""Layout of every page of the shipped reports (issue 15 item 8).

The reports checked are the real ones: the Snakefile runs on a copy of the project with both
shipped machines (tapping-center-a trimmed to five logs; machining-center-b, the machine of
continuous logs, whole), as the end-to-end tests do (tests/project_copy.py). Each PDF is read
back with poppler, an independent reader:

- text: ``pdftotext -bbox-layout`` gives the page size and every word's box (its advance
  width times the font's ascent + descent, in points);
- images: ``pdftohtml -xml`` gives every image's box on its page.

Defects (:func:`layout_defects`), with the tolerances and why:

- **off the page**: a word or image box outside the media box by more than ``EDGE_TOL_PT``;
- **in the margin**: a word outside the text area of the template's ``@page`` margins by more
  than ``EDGE_TOL_PT`` (1 pt: WeasyPrint places boxes on exact CSS pixels, poppler rounds image
  boxes to whole points), except the running header (top margin) and the page footer (bottom
  margin); an image outside the text area: a figure wider than the column;
- **overlap**: two words whose boxes intersect by more than ``OVERLAP_X_PT`` horizontally
  **and** by more than ``OVERLAP_Y_FRAC`` of the smaller box's height vertically. Word boxes
  are taller than the glyphs (DejaVu's ascent + descent = 1.17 em), so lines set tighter than
  that touch without any glyph touching: the tightest in the report are table rows at
  ``line-height`` 1.4 (no intersection at all), and superscripts/subscripts drawn in the line
  (a few tenths of a point); 30 % of a word's height is about a third of an x-height, well
  below any two glyphs drawn on each other and above those.

Text inside a figure is pixels in the PDF: it is checked where it is drawn, with matplotlib's
own text extents (:func:`rafi.report.plot_layout.text_overlaps`), on the figures of the same
run drawn again.
"""

from __future__ import annotations

import re
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from conftest import which_or_skip

from rafi.report import plot_layout
from tests.project_copy import copy_project, copy_settled, run_snakemake

ROOT = Path(__file__).resolve().parents[1]
MACHINES = ("tapping-center-a", "machining-center-b")
#: The page frame of the reports (included by templates/qualification.html.j2 and probes.html.j2).
TEMPLATE = ROOT / "rafi" / "report" / "templates" / "styles" / "page.css.j2"
MM = 72.0 / 25.4

EDGE_TOL_PT = 1.0
#: WCAG 2 contrast ratio below which text is hard to see on its background: 3 is WCAG's
#: minimum for large text; the report's muted grey on its light bands is about 5.8.
MIN_CONTRAST = 3.0
OVERLAP_X_PT = 1.0
OVERLAP_Y_FRAC = 0.3

#: Lines allowed in the page margins: WeasyPrint's running header (@top-left, @top-right) and
#: the page footer (@bottom-center) of the template.
HEADER = re.compile(r"^(RAFI qualification report|rev\. [0-9a-f]+)")
FOOTER = re.compile(r"^Page \d+ of \d+$")


def page_margins_pt(template: Path = TEMPLATE) -> tuple[float, float, float, float]:
    """``(top, right, bottom, left)`` margins of the template's ``@page`` rule, in points."""
    css = template.read_text(encoding="utf-8")
    m = re.search(r"@page\s*\{[^}]*?margin:\s*([\d.]+)mm\s+([\d.]+)mm\s+([\d.]+)mm\s+([\d.]+)mm", css)
    assert m, "no `margin: T R B L` in mm in the template's @page rule"
    return tuple(float(v) * MM for v in m.groups())


def _tool(name: str) -> str:
    return which_or_skip(name)


def pdf_words(pdf: Path) -> list[dict]:
    """Pages of ``pdf`` as ``{width, height, words: [{text, line, box}]}`` (pdftotext -bbox-layout)."""
    xhtml = subprocess.run(
        [_tool("pdftotext"), "-bbox-layout", str(pdf), "-"], capture_output=True, text=True, check=True
    ).stdout
    ns = {"h": "http://www.w3.org/1999/xhtml"}
    root = ET.fromstring(xhtml)
    pages = []
    for page in root.iter(f"{{{ns['h']}}}page"):
        words, n_line = [], 0
        for line in page.iter(f"{{{ns['h']}}}line"):
            n_line += 1
            ws = list(line.iter(f"{{{ns['h']}}}word"))
            text = " ".join((w.text or "") for w in ws)
            for w in ws:
                box = tuple(float(w.get(k)) for k in ("xMin", "yMin", "xMax", "yMax"))
                words.append({"text": w.text or "", "line": n_line, "line_text": text, "box": box})
        pages.append({"width": float(page.get("width")), "height": float(page.get("height")), "words": words})
    return pages


def pdf_images(pdf: Path, work: Path) -> dict[int, list[tuple]]:
    """``page number (1-based) -> [image box (x0, y0, x1, y1)]`` in points (pdftohtml -xml)."""
    work.mkdir(parents=True, exist_ok=True)
    subprocess.run(
        [_tool("pdftohtml"), "-xml", "-q", "-zoom", "1", "-nodrm", str(pdf), str(work / "out")],
        check=True,
        capture_output=True,
    )
    root = ET.parse(work / "out.xml").getroot()
    found = {}
    for page in root.iter("page"):
        boxes = []
        for img in page.iter("image"):
            x, y, w, h = (float(img.get(k)) for k in ("left", "top", "width", "height"))
            boxes.append((x, y, x + w, y + h))
        found[int(page.get("number"))] = boxes
    return found


def _overlaps(words: list[dict]) -> list[tuple[dict, dict, float, float]]:
    """Pairs of words whose boxes intersect beyond the tolerances (sweep over y)."""
    order = sorted(words, key=lambda w: w["box"][1])
    found = []
    for i, a in enumerate(order):
        ax0, ay0, ax1, ay1 = a["box"]
        for b in order[i + 1 :]:
            bx0, by0, bx1, by1 = b["box"]
            if by0 >= ay1:
                break
            w = min(ax1, bx1) - max(ax0, bx0)
            h = min(ay1, by1) - max(ay0, by0)
            if w > OVERLAP_X_PT and h > OVERLAP_Y_FRAC * min(ay1 - ay0, by1 - by0):
                found.append((a, b, w, h))
    return found


def layout_defects(pdf: Path, work: Path, margins=None) -> list[str]:
    """Every layout defect of ``pdf`` as ``"page N: <what>: <text>"`` (rules in the module doc)."""
    top, right, bottom, left = margins or page_margins_pt()
    images = pdf_images(pdf, work)
    out = []
    for n, page in enumerate(pdf_words(pdf), start=1):
        W, H = page["width"], page["height"]
        area = (left, top, W - right, H - bottom)
        for w in page["words"]:
            x0, y0, x1, y1 = w["box"]
            where = f"page {n}: %s: {w['text']!r} in {w['line_text']!r}"
            if x0 < -EDGE_TOL_PT or y0 < -EDGE_TOL_PT or x1 > W + EDGE_TOL_PT or y1 > H + EDGE_TOL_PT:
                out.append(where % "off the page")
            elif x0 < area[0] - EDGE_TOL_PT or x1 > area[2] + EDGE_TOL_PT:
                out.append(where % "in the side margin")
            elif y1 <= area[1] + EDGE_TOL_PT:
                if not HEADER.match(w["line_text"]):
                    out.append(where % "in the top margin")
            elif y0 >= area[3] - EDGE_TOL_PT:
                if not FOOTER.match(w["line_text"]):
                    out.append(where % "in the bottom margin")
            elif y0 < area[1] - EDGE_TOL_PT or y1 > area[3] + EDGE_TOL_PT:
                out.append(where % "across the margin")
        for a, b, dx, dy in _overlaps(page["words"]):
            out.append(
                f"page {n}: overlap {dx:.1f} x {dy:.1f} pt: {a['text']!r} in {a['line_text']!r} "
                f"and {b['text']!r} in {b['line_text']!r}"
            )
        for x0, y0, x1, y1 in images.get(n, []):
            if x0 < area[0] - EDGE_TOL_PT or x1 > area[2] + EDGE_TOL_PT:
                out.append(
                    f"page {n}: image {x1 - x0:.0f} pt wide at x {x0:.0f}-{x1:.0f}: wider than the text area"
                )
            elif y0 < area[1] - EDGE_TOL_PT or y1 > area[3] + EDGE_TOL_PT:
                out.append(f"page {n}: image at y {y0:.0f}-{y1:.0f}: outside the text area")
    return out


def _luminance(rgb) -> float:
    lin = [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in rgb]
    return 0.2126 * lin[0] + 0.7152 * lin[1] + 0.0722 * lin[2]


def _over(colour, below) -> tuple:
    """``colour`` (a tinycss2 colour with alpha) painted over the opaque RGB ``below``."""
    rgb = colour.to("srgb").coordinates
    a = colour.alpha
    return tuple(a * c + (1 - a) * b for c, b in zip(rgb, below))


def faint_text(html: str, min_ratio: float = MIN_CONTRAST) -> list[str]:
    """Text whose colour barely differs from the background it is drawn on, from WeasyPrint's
    layout of ``html``: the WCAG contrast ratio of the text's colour and the nearest painted
    background (white page below) under ``min_ratio``, as ``"page N: <text>: <ratio>"``."""
    import weasyprint
    from weasyprint.formatting_structure import boxes

    out = []
    for n, page in enumerate(weasyprint.HTML(string=html).render().pages, start=1):
        stack = [(page._page_box, (1.0, 1.0, 1.0))]
        while stack:
            box, below = stack.pop()
            bg = _over(box.style["background_color"], below)
            if isinstance(box, boxes.TextBox) and box.text.strip():
                fg = _over(box.style["color"], bg)
                hi, lo = sorted((_luminance(fg), _luminance(bg)), reverse=True)
                ratio = (hi + 0.05) / (lo + 0.05)
                if ratio < min_ratio:
                    out.append(f"page {n}: {box.text.strip()!r}: contrast {ratio:.2f}")
            stack.extend((child, bg) for child in getattr(box, "children", []))
    return out


# --------------------------------------------------------------------------- the checker itself


def _pdf(html: str, path: Path) -> Path:
    import weasyprint

    path.write_bytes(weasyprint.HTML(string=html).write_pdf())
    return path


PAGE_CSS = (
    "@page { size: A4; margin: 16mm 15mm 18mm 15mm;"
    " @bottom-center { content: 'Page ' counter(page) ' of ' counter(pages); } }"
)


def test_checker_finds_planted_defects_and_passes_a_clean_page(tmp_path):
    """Known truth: a clean page has no defect; each planted defect is found, and only it."""
    import base64
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.new("RGB", (40, 10), "white").save(buf, format="PNG")
    png = "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()
    body = (
        "<p>Plain text in two lines,<br>the second one here.</p><table><tr><td>a</td><td>b</td></tr></table>"
    )
    clean = f"<style>{PAGE_CSS}</style>{body}<img src='{png}' style='width: 100%'>"
    assert layout_defects(_pdf(clean, tmp_path / "clean.pdf"), tmp_path / "c") == []

    planted = f"""<style>{PAGE_CSS} .a {{ position: absolute; left: 20mm; }}</style>{body}
<p class="a" style="top: 60mm">Overlapping first</p><p class="a" style="top: 61mm">Overlapping second</p>
<p style="white-space: nowrap">{"runaway " * 40}</p>
<img src="{png}" style="width: 200mm">
<p class="a" style="top: 266mm">In the bottom margin</p>"""
    found = layout_defects(_pdf(planted, tmp_path / "planted.pdf"), tmp_path / "p")
    text = "\n".join(found)
    assert "overlap" in text and "Overlapping" in text, text
    assert re.search(r"(off the page|in the side margin): 'runaw", text), text
    assert "image" in text and "wider than the text area" in text, text
    assert "in the bottom margin: 'In'" in text, text
    planted_kinds = r"page 1: (overlap|image|off the page|in the side margin|in the bottom margin)\b"
    assert all(re.match(planted_kinds, f) for f in found), found
    assert not any("Plain" in f or "second one" in f for f in found), found  # the clean part stays clean


def test_text_overlaps_finds_the_idle_run_titles_of_the_old_layout():
    """The defect of issue 15 as it was drawn: three 2.3-inch panels side by side with titles
    "<run id>: <before> -> <after> µm" at 8 pt overlap each other and the last runs off the
    figure; the same titles broken in two lines at 6.5 pt, as plot_layout.fit_titles makes
    them, do not."""
    import matplotlib.pyplot as plt

    titles = [f"thermal_log_2026-10-14#{k}: 14.7 \u2192 1.08 \u00b5m" for k in (10, 12, 17)]
    titles[-1] += " (idle cool-down)"
    with plt.rc_context(plot_layout.STYLE):
        fig, axes = plt.subplots(1, 3, figsize=(plot_layout.PAGE_WIDTH_IN, 1.9))
        for ax, t in zip(axes, titles):
            ax.plot([0, 1], [0, 1])
            ax.set_title(t)
        found = plot_layout.text_overlaps(fig)
        plt.close(fig)
        kinds = sorted(f["kind"] for f in found)
        assert kinds.count("overlap") == 2 and "outside" in kinds, found
        assert all("title" in " ".join(f["texts"]) for f in found)

        fig, axes = plt.subplots(1, 3, figsize=(plot_layout.PAGE_WIDTH_IN, 1.9), layout="constrained")
        for ax, t in zip(axes, titles):
            ax.plot([0, 1], [0, 1])
            ax.set_title(t.replace(": ", ":\n"), fontsize=6.5)
            ax.set_xlabel("time (h)")
        assert plot_layout.text_overlaps(fig) == []
        plt.close(fig)


def test_text_overlaps_clearance_is_one_point():
    """Texts 1.2 pt apart are clear; 0.8 pt apart, touching or overlapping they read as one
    (72 dpi: 1 px = 1 pt); a text 0.3 pt over the figure's edge is not cut, 0.7 pt is."""
    import matplotlib.pyplot as plt

    def pair(gap):
        fig = plt.figure(figsize=(3, 1), dpi=72)
        a = fig.text(0.1, 0.5, "AAAA", fontsize=10)
        fig.canvas.draw()
        bb = a.get_window_extent()
        fig.text((bb.x1 + gap) / fig.bbox.width, 0.5, "BBBB", fontsize=10)
        found = plot_layout.text_overlaps(fig)
        plt.close(fig)
        return [f for f in found if f["kind"] == "overlap"]

    assert pair(1.2) == []
    for gap in (0.8, 0.0, -0.3, -5.0):
        (found,) = pair(gap)
        assert found["by_pt"] == pytest.approx(gap * -1, abs=0.05), gap

    for over, expected in ((0.3, 0), (0.7, 1)):
        fig = plt.figure(figsize=(3, 1), dpi=72)
        t = fig.text(0.0, 0.5, "edge", fontsize=10, ha="right")
        fig.canvas.draw()
        t.set_x((t.get_window_extent().width - over) / fig.bbox.width)  # left edge at -over
        found = [f for f in plot_layout.text_overlaps(fig) if f["kind"] == "outside"]
        assert len(found) == expected, (over, found)
        plt.close(fig)


def test_text_overlaps_measures_turned_tick_labels_as_turned():
    """Run ids as x tick labels at 30 degrees: their upright boxes overlap even when spaced out,
    the turned ones only when crowded (12 labels on 2 inches), which is what the reader sees."""
    import matplotlib.pyplot as plt

    def labels(n, width_in):
        fig, ax = plt.subplots(figsize=(width_in, 2.0), layout="constrained")
        names = [f"thermal_log_2026-10-14#{k}" for k in range(n)]
        ax.bar(range(n), range(n))
        ax.set_xticks(range(n), names, rotation=30, ha="right")
        found = plot_layout.text_overlaps(fig)
        plt.close(fig)
        return [f for f in found if f["kind"] == "overlap"]

    with plt.rc_context(plot_layout.STYLE):
        assert labels(9, plot_layout.PAGE_WIDTH_IN) == []  # the comparison figure's layout
        crowded = labels(12, 2.0)
        assert len(crowded) >= 11 and all("x tick" in " ".join(f["texts"]) for f in crowded), crowded


def test_faint_text_finds_text_in_the_colour_of_its_background():
    """The badge defect: ``span.pass`` (green text) wins over ``.badge`` (white on green)."""
    css = ".badge { color: white; background: #1b7a3a; } .muted { color: #5f6368; }"
    ok = f"<style>{css}</style><p><span class='badge'>PASS</span> <span class='muted'>grey</span></p>"
    assert faint_text(ok) == []
    bad = f"<style>span.pass {{ color: #1b7a3a; }} {css}</style><p><span class='badge pass'>PASS</span></p>"
    assert faint_text(bad) == ["page 1: 'PASS': contrast 1.00"]
    pale = "<p style='background: #fff8e1'><span style='color: #ffe9a8'>pale</span></p>"
    assert len(faint_text(pale)) == 1


# --------------------------------------------------------------------------- the shipped reports


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory):
    """The Snakefile's reports of both shipped machines on a copy of the project."""
    proj = copy_project(tmp_path_factory.mktemp("layout") / "proj")
    keep = re.compile(r"train.*(03000|09000|15000)|valid_04500|multi_condition")
    for machine in MACHINES:
        (proj / "raw" / machine).mkdir(parents=True)
        for f in sorted((ROOT / "raw" / machine).iterdir()):
            if machine != "tapping-center-a" or keep.search(f.name):
                copy_settled(f, proj / "raw" / machine / f.name)
    targets = [f"reports/{m}/qualification.pdf" for m in MACHINES]
    done = run_snakemake(proj, *targets, cores=2, timeout=1200)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return proj


@pytest.mark.slow
@pytest.mark.parametrize("machine", MACHINES)
def test_every_page_of_the_shipped_reports_is_clear(pipeline, machine, tmp_path):
    pdf = pipeline / "reports" / machine / "qualification.pdf"
    pages = pdf_words(pdf)
    assert len(pages) >= 10 and all(p["words"] for p in pages)
    defects = layout_defects(pdf, tmp_path)
    defects += faint_text((pipeline / "reports" / machine / "qualification.html").read_text(encoding="utf-8"))
    assert not defects, f"{len(defects)} layout defect(s) in {machine}'s report:\n" + "\n".join(defects)


@pytest.mark.slow
@pytest.mark.parametrize("machine", MACHINES)
def test_no_figure_text_overlaps(pipeline, machine, tmp_path, monkeypatch):
    """Every figure of the run drawn again from the same inputs, its text checked at draw time
    (:func:`rafi.report.plot_layout.text_overlaps`, one render per figure)."""
    import yaml

    from rafi.report import deployed_plot, figures, plots, replay_plot, segmentation_plot
    from rafi.report.inputs import FIGURE_DIRS, result_paths
    from rafi.settings import machine_settings

    checked: list[list] = []

    def checking(render):
        def wrapper(fig, *args, **kwargs):
            checked.append(plot_layout.text_overlaps(fig))
            return render(fig, *args, **kwargs)

        return wrapper

    for module in (plots, replay_plot, deployed_plot, segmentation_plot):
        monkeypatch.setattr(module, "render", checking(module.render))
    cfg = yaml.safe_load((pipeline / "config.yaml").read_text(encoding="utf-8"))
    settings = machine_settings(cfg, machine)
    paths = result_paths(pipeline / "results" / machine)
    keys = []
    for group in FIGURE_DIRS:
        keys += figures.draw_group(
            {k: paths[k] for k in figures.FIGURE_GROUPS[group]},
            group,
            tmp_path / group,
            figure_format="png",
            coolant_sensors=list(settings["report"]["coolant_sensors"]),
            gates=dict(settings["qualification"]),
            deploy=dict(settings["deploy"]),
        )
    assert len(keys) == len(checked) >= 5
    found = [
        f"{key}: {p['kind']} {p['by_pt']} pt: {' / '.join(p['texts'])}"
        for key, problems in zip(keys, checked)
        for p in problems
    ]
    assert not found, f"{len(found)} text defect(s) in {machine}'s figures:\n" + "\n".join(found)


@pytest.mark.slow
@pytest.mark.parametrize("machine", MACHINES)
def test_rule_report_writes_the_archival_pdf(pipeline, machine, tmp_path):
    """Through Snakemake (workflow/scripts/report.py): PDF/A-3b, and the attachments are the
    run's files, byte for byte (the renderer itself: tests/test_report_pdf.py)."""
    import json

    pdf = pipeline / "reports" / machine / "qualification.pdf"
    xmp = subprocess.run([_tool("pdfinfo"), "-meta", pdf], capture_output=True, text=True, check=True).stdout
    assert 'pdfaid:part="3"' in xmp and 'pdfaid:conformance="B"' in xmp, xmp
    # the figures are opaque RGB: no soft mask (transparency) enters the PDF from them
    listed = subprocess.run([_tool("pdfimages"), "-list", pdf], capture_output=True, text=True, check=True)
    listed = listed.stdout
    images = [line.split() for line in listed.splitlines()[2:]]
    assert images and all(row[2] == "image" and row[5] == "rgb" for row in images), listed
    subprocess.run([_tool("pdfdetach"), "-saveall", "-o", str(tmp_path), pdf], check=True)
    results = pipeline / "results" / machine
    champion = json.loads((results / "registry" / "decision.json").read_text())["champion_id_after"]
    expected = {
        "model.json": results / "model.json",
        "audit.csv": results / "audit.csv",
        "validation_summary.csv": results / "validation" / "summary.csv",
        "comparison_summary.csv": results / "comparison" / "summary.csv",
    }
    (deployed,) = tmp_path.glob(f"model_on_the_machine_*_{champion[:12]}.json")
    expected[deployed.name] = results / "registry" / "models" / f"{champion}.json"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(expected)
    for name, src in expected.items():
        assert (tmp_path / name).read_bytes() == src.read_bytes(), name
    html = (pipeline / "reports" / machine / "qualification.html").read_text(encoding="utf-8")
    assert "model_on_the_machine_" not in html  # the HTML carries no attachment
