"""The report of a machine with several probes as the engineer signs it: the cover page
(rafi.report.probes_page, templates/probes.html.j2) and the PDF that appends every probe's own
report to it (``render_probes_pdf``), read back with poppler (pdftotext), an independent reader.

The fixture is a machine ``m`` with three probes: each unit ``m@<probe>`` is the report fixture
(tests/data/report_fixture/tapping-center-a) with the probe's settings, its report rendered with
the real template (what rule report writes), the cover built from the units' tables as rule
probes_report builds it (the mixed fleet read page by page, 2026-12-01: FL_THERMAL's cover was
wider than A4).
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml
from conftest import which_or_skip
from test_report import FIXTURE, _context
from test_report_layout import layout_defects, pdf_words

from rafi.report.probes_page import probe_row, probes_context, render_probes_html, render_probes_pdf
from rafi.report.render import render_html
from rafi.report.signoff import probes_signoff
from rafi.settings import machine_settings

ROOT = Path(__file__).resolve().parents[1]
MACHINE = "m"
#: The machine's probes (input.probes), one with a description (a second line in its table cell).
PROBES = {
    "ch1": {"column": "ch1(um)", "description": "spindle nose, axial (Z), on the tool holder"},
    "ch2": "ch2(um)",
    "ch3": "ch3(um)",
}

#: What the machine's settings say of the document (report.document); the approver is left to sign.
DOCUMENT = {"number": "QR-0042", "prepared_by": "A. Engineer"}


def _config() -> dict:
    cfg = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))
    machine = {"input": {"format": "csv", "probes": PROBES}, "report": {"document": DOCUMENT}}
    cfg["machines"][MACHINE] = machine
    return cfg


def _unit_paths(results: Path) -> dict:
    """The unit's tables rule probes_report reads (workflow/rules/report_common.smk)."""
    rel = {
        "summary": "comparison/summary.csv",
        "per_run": "comparison/per_run.csv",
        "decision": "registry/decision.json",
        "audit": "audit.csv",
        "validation": "validation/summary.csv",
        "model": "model.json",
    }
    return {key: str(results / path) for key, path in rel.items()}


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """The machine's units rendered as rule report renders them, and the cover's inputs."""
    tmp = tmp_path_factory.mktemp("probes")
    cfg = _config()
    rows, reports, revisions = [], {}, {}
    for probe in PROBES:
        unit = f"{MACHINE}@{probe}"
        results = tmp / "results" / unit
        shutil.copytree(FIXTURE, results)
        settings = machine_settings(cfg, unit)
        out = tmp / "reports" / unit
        out.mkdir(parents=True)
        ctx = _context(results, settings, machine=unit)
        revisions[probe] = ctx["signoff"]["revision"]
        (out / "qualification.html").write_text(render_html(ctx), encoding="utf-8")
        reports[unit] = out / "qualification.html"
        rows.append(probe_row(probe, settings, _unit_paths(results), f"../{unit}/qualification.html"))
    return {
        "tmp": tmp,
        "rows": rows,
        "reports": reports,
        "revisions": revisions,
        "settings": machine_settings(cfg, MACHINE),
    }


@pytest.fixture(scope="module")
def merged(project):
    """The cover's HTML and the whole PDF, written where rule probes_report writes them."""
    out = project["tmp"] / "reports" / MACHINE
    out.mkdir(parents=True, exist_ok=True)
    ctx = probes_context(MACHINE, project["rows"], project["settings"])
    html = render_probes_html(ctx)
    (out / "qualification.html").write_text(html, encoding="utf-8")
    (out / "qualification.pdf").write_bytes(render_probes_pdf(ctx, project["reports"]))
    return {"html": html, "pdf": out / "qualification.pdf", "dir": out}


def _page_texts(pdf: Path) -> list[str]:
    text = subprocess.run(
        [which_or_skip("pdftotext"), "-layout", str(pdf), "-"], capture_output=True, text=True, check=True
    ).stdout
    return text.split("\f")[:-1]


def _cover_pages(pdf: Path) -> int:
    """Pages before the first probe's own report (its title line)."""
    pages = _page_texts(pdf)
    return next(i for i, t in enumerate(pages) if f"RAFI qualification report: {MACHINE}@" in t)


def test_the_cover_table_stays_inside_the_page(merged, tmp_path):
    """FL_THERMAL's cover table ran past the right edge of A4: its "report" column clipped, its
    right border gone. Every word of the cover pages lies inside the text area of the page."""
    n_cover = _cover_pages(merged["pdf"])
    assert n_cover >= 1
    defects = layout_defects(merged["pdf"], tmp_path / "xml")
    on_cover = [d for d in defects if int(re.match(r"page (\d+):", d).group(1)) <= n_cover]
    assert on_cover == [], on_cover
    # the words of the report column are there (not clipped away)
    first = " ".join(w["text"] for w in pdf_words(merged["pdf"])[0]["words"])
    assert "report" in first and all(probe in first for probe in PROBES)


def test_the_cover_has_the_page_frame_and_the_sign_off_block_of_a_units_report(merged, project):
    """FL_THERMAL's cover pages had no running header, no revision, no page number and no
    Document no. / Prepared / Approved block, where each probe's report has them."""
    pages = _page_texts(merged["pdf"])
    n_cover = _cover_pages(merged["pdf"])
    revision = re.search(r"rev\. ([0-9a-f]{10}) \u00b7", pages[0]).group(1)
    for page in pages[:n_cover]:
        assert f"RAFI qualification report \u2014 {MACHINE}" in page and f"rev. {revision}" in page
        assert re.search(r"\bPage \d+ of \d+\b", page), page[-300:]
    first = re.sub(r"\s+", " ", pages[0])
    for label in ("Document no.", "Revision", "Prepared by", "Approved by", "Date"):
        assert label in first
    assert DOCUMENT["number"] in first and DOCUMENT["prepared_by"] in first
    # the revision is a hash of the probes' reports' revisions, each said on the cover
    assert [row["revision"] for row in project["rows"]] == list(project["revisions"].values())
    assert all(rev in first for rev in project["revisions"].values())
    assert probes_signoff(project["settings"], project["revisions"])["revision"] == revision
    other = {**project["revisions"], "ch2": "0" * 10}
    assert probes_signoff(project["settings"], other)["revision"] != revision
    # the HTML has the same block (one template for both)
    assert 'id="signoff"' in merged["html"] and DOCUMENT["number"] in merged["html"]


def test_every_page_has_one_number_of_the_whole_pdf(merged, project):
    """FL_THERMAL's 126 pages kept each report's own "Page 1 of 24": no page could be cited. Every
    page now says "Page k of N" with k its place in the PDF and N its pages, and nothing else
    "Page ... of ..."; each probe's own page is said beside it ("m@ch1: page 3 of 24"), and the
    contents of each probe's report lead to the pages of the PDF its sections are on."""
    pages = _page_texts(merged["pdf"])
    n = len(pages)
    for k, page in enumerate(pages, start=1):
        assert re.findall(r"\bPage (\d+) of (\d+)\b", page) == [(str(k), str(n))], (k, page[-400:])
    starts = [i for i, t in enumerate(pages) if re.search(rf"RAFI qualification report: {MACHINE}@ch\d\n", t)]
    assert len(starts) == len(PROBES) and starts[0] == _cover_pages(merged["pdf"])
    ends = starts[1:] + [n]
    for probe, start, end in zip(PROBES, starts, ends):
        own = end - start
        for j in range(start, end):
            assert f"{MACHINE}@{probe}: page {j - start + 1} of {own}" in pages[j], (probe, j)
        toc = re.findall(r"^\s*(\d+)\. (.+?) \.{3,}\s*(\d+)\s*$", pages[start], flags=re.M)
        assert len(toc) >= 10, pages[start]
        for number, title, page_no in toc:
            assert start < int(page_no) <= end, (probe, title, page_no)
            text = re.sub(r"\s+", " ", pages[int(page_no) - 1])
            assert f"{number}. {title.strip()[:20]}" in text, (probe, number, title, page_no)


def _html_text(html: str) -> str:
    body = html[html.index("<body") :]
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", body))


def test_the_cover_says_where_the_reports_are_in_each_medium(merged):
    """The HTML said "Each probe's full report follows this page" where nothing follows it (it
    links them). The HTML says they are linked; the PDF says they follow, at which pages, and
    those are the pages each report is on."""
    html = _html_text(merged["html"])
    assert "follows this page" not in html and "follows in this PDF" not in html
    assert "Each probe's full report is linked" in html
    for probe in PROBES:
        assert f'href="../{MACHINE}@{probe}/qualification.html"' in merged["html"]
    pages = _page_texts(merged["pdf"])
    cover = re.sub(r"\s+", " ", " ".join(pages[: _cover_pages(merged["pdf"])]))
    assert "Each probe's full report follows" in cover and "linked" not in cover
    starts = [i for i, t in enumerate(pages) if re.search(rf"RAFI qualification report: {MACHINE}@ch\d\n", t)]
    ends = starts[1:] + [len(pages)]
    for probe, start, end in zip(PROBES, starts, ends):
        said = f"pages {start + 1}\u2013{end}"
        assert f"Full report: {said} of this PDF" in cover, (probe, said)
        assert cover.count(said) == 2, (probe, said)  # in its row too
