"""The model comparison's tables of a wide family, read back from the report's PDF.

A re-qualified machine scores up to 13 models (RAFI's two kinds, the ridge kinds, the prior's
variants, the plain ridge, the ensemble) beside forward CV and the interval's coverage: the
model table has 14 columns and the per-run table a column per model. The report fixture's
comparison is rewritten as such a family (:func:`write_wide_family`, numbers as long as the
shipped twins print: ``1 530.24``, ``−1 022.3``), the report rendered to PDF by the project's own
path (:func:`rafi.report.render.render_pdf`) and read back with poppler:

- every number of the two tables is whole on one line of the PDF text;
- every word of the section's PDF text is a word of its HTML: no number, header or name of the
  code broken inside itself or given a hyphen the HTML does not hold (a break after ``_``, ``-``,
  ``/`` or ``|`` is a break between the pieces of a word);
- every word stays inside the page's text area and no two overlap
  (:func:`test_report_layout.layout_defects`).
"""

from __future__ import annotations

import hashlib
import html as html_lib
import re
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from conftest import which_or_skip
from html_tables import html_tables
from report_fixture import copy_fixture, empty_figure_dirs, write_upstream_tables
from test_report_layout import layout_defects

from rafi.report.context import build_context
from rafi.report.format import fmt_num
from rafi.report.render import render_html, render_pdf
from rafi.settings import machine_settings

ROOT = Path(__file__).resolve().parents[1]
CONFIG = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))
MACHINE = "tapping-center-a"

#: A re-qualified family: model -> kind (tapping-center-a-rep's comparison).
WIDE_FAMILY = {
    "rafi": "rafi",
    "rafi_linear": "rafi_linear",
    "ridge_global": "ridge_global",
    "dynamic": "dynamic",
    "grey_box": "grey_box",
    "prior": "grey_box",
    "prior_gain": "grey_box",
    "prior_time": "grey_box",
    "prior_ridge": "grey_box",
    "prior_shared_gain": "ensemble",
    "prior_shared_ridge": "ensemble",
    "temperature_ridge": "temperature_ridge",
    "ensemble": "ensemble",
}
CHAMPION = "prior_shared_ridge"


def _wide(rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` magnitudes from 0.5 to 2 000 (log-uniform): one to four digits before the point."""
    return np.exp(rng.uniform(np.log(0.5), np.log(2000.0), n))


def write_wide_family(results: Path, seed: int = 7) -> dict:
    """Rewrite ``comparison/summary.csv`` and ``per_run.csv`` of the fixture as the family of
    :data:`WIDE_FAMILY` with forward CV and the interval's coverage; returns the summary's rows
    by model (the numbers each table must show)."""
    rng = np.random.default_rng(seed)
    folder = results / "comparison"
    template = pd.read_csv(folder / "summary.csv").iloc[0]
    runs = pd.read_csv(folder / "per_run.csv")
    runs = runs[runs["model"] == runs["model"].iloc[0]]
    n = len(WIDE_FAMILY)
    whole, forward, worst, after = (_wide(rng, n) for _ in range(4))
    summary = pd.DataFrame(
        {
            **{k: [template[k]] * n for k in template.index},
            "model": list(WIDE_FAMILY),
            "kind": list(WIDE_FAMILY.values()),
            "model_id": [hashlib.sha256(m.encode()).hexdigest() for m in WIDE_FAMILY],
            "champion": [m == CHAMPION for m in WIDE_FAMILY],
            "cv_mean_max_abs_um": whole,
            "cv_forward_mean_max_abs_um": forward,
            "selection_score_um": (whole + forward) / 2,
            "cv_max_abs_um": worst,
            "selection_rank": rng.permutation(n) + 1,
            "max_abs_after_um": after,
            "improvement_pct": rng.uniform(-1500.0, 99.0, n),
            "n_outside_temp_range": rng.integers(0, 9000, n),
            "n_outside_speed_range": rng.integers(0, 3000, n),
            "passed": rng.random(n) < 0.5,
            "coverage": rng.uniform(0.3, 1.0, n),
            "interval_width_um": _wide(rng, n),
        }
    )
    summary["n_samples"] = summary["n_outside_temp_range"] + rng.integers(0, 3000, n)
    summary.to_csv(folder / "summary.csv", index=False)
    per_run = []
    for model, kind in WIDE_FAMILY.items():
        k = len(runs)
        per_run.append(
            runs.assign(
                model=model,
                kind=kind,
                champion=model == CHAMPION,
                max_abs_after_um=_wide(rng, k),
                improvement_pct=rng.uniform(-1500.0, 99.0, k),
                passed=rng.random(k) < 0.5,
                coverage=rng.uniform(0.3, 1.0, k),
                interval_width_um=_wide(rng, k),
            )
        )
    pd.concat(per_run).to_csv(folder / "per_run.csv", index=False)
    return {r["model"]: r for r in summary.to_dict("records")}


@pytest.fixture(scope="module")
def wide_report(tmp_path_factory) -> dict:
    """The fixture's report with the wide family: its HTML, its PDF and the PDF's text."""
    tmp = tmp_path_factory.mktemp("wide")
    results = copy_fixture(tmp, MACHINE)
    write_wide_family(results)
    paths = write_upstream_tables(results)
    settings = machine_settings(CONFIG, MACHINE)
    ctx = build_context(paths, empty_figure_dirs(results), machine=MACHINE, settings=settings)
    html = render_html(ctx)
    pdf = tmp / "qualification.pdf"
    pdf.write_bytes(render_pdf(html))
    text = subprocess.run(
        [which_or_skip("pdftotext"), "-layout", str(pdf), "-"], capture_output=True, text=True, check=True
    ).stdout
    return {"ctx": ctx, "html": html, "pdf": pdf, "text": text, "work": tmp / "layout", "results": results}


def _section(html: str) -> str:
    return re.search(r'<section id="sec-comparison">.*?</section>', html, flags=re.S).group(0)


#: The lines of the page's running header and footer (the template's @page rule).
RUNNING = re.compile(r"^\s*(RAFI qualification report \u2014 .*|Page \d+ of \d+)\s*$", flags=re.M)


def _pdf_section(text: str) -> str:
    """The PDF text from the comparison's heading to the next section's, without the running
    header and footer of its pages."""
    start = re.search(r"^\d+\. Model comparison$", text, flags=re.M)
    assert start, "no heading 'Model comparison' in the PDF text"
    end = re.compile(r"^\d+\. \S", flags=re.M).search(text, start.end())
    return RUNNING.sub("", text[start.start() : end.start() if end else len(text)])


def _words(text: str) -> set:
    """The words of ``text`` split at white space (the no-break space too) and after ``_ - / |``
    and the en dash: the places a line may break between the pieces of a word."""
    out = set()
    for token in re.split(r"[\s\u00a0\u202f]+", text):
        out.update(p for p in re.split(r"(?<=[_/|\-\u2013])", token) if p)
    return out


def _visible(fragment: str) -> str:
    fragment = re.sub(r"<wbr>", "", fragment)
    fragment = re.sub(r"<(br|/p|/li|/td|/th|/div|/h\d|/tr|/caption)[^>]*>", " ", fragment)
    return html_lib.unescape(re.sub(r"<[^>]+>", "", fragment))


def _comparison_tables(html: str) -> list[dict]:
    tables = [
        t for t in html_tables(_section(html)) if re.search(r"\b(models|per-run|per-model)\b", t["cls"])
    ]
    assert len(tables) == 2, [t["cls"] for t in tables]
    return tables


NUMBER = re.compile(r"\u2212?\d{1,3}(?:\u00a0\d{3})*(?:\.\d+)?")


def test_the_wide_family_is_in_both_tables(wide_report):
    models, per_run = _comparison_tables(wide_report["html"])
    assert [r["model"].split()[0] for r in models["records"]] == list(WIDE_FAMILY)
    assert len(models["headers"]) == 14
    # 13 models, 6 validation runs: a row per model, a column per run
    runs = wide_report["ctx"]["comparison"]["per_run"]
    assert len(per_run["headers"]) == 1 + len(runs) == 7
    named = [r["model"] for r in per_run["records"][2:]]
    assert named == [m + (" \u2605" if m == CHAMPION else "") for m in WIDE_FAMILY]
    stored = pd.read_csv(wide_report["results"] / "comparison" / "per_run.csv")
    for model, cells in zip(WIDE_FAMILY, per_run["rows"][2:]):
        want = stored[stored["model"] == model]["max_abs_after_um"]
        shown = [_visible(c["html"].split("<br>")[0]) for c in cells[1:]]
        assert shown == [fmt_num(v, 2) for v in want], model


def test_every_number_of_the_comparison_tables_is_whole_in_the_pdf(wide_report):
    pdf_text = _pdf_section(wide_report["text"])
    numbers = {
        m.group(0).replace("\u00a0", " ")
        for table in _comparison_tables(wide_report["html"])
        for row in table["rows"]
        for cell in row
        for m in NUMBER.finditer(_visible(cell["html"]))
    }
    assert any(len(n) >= 8 for n in numbers), sorted(numbers)  # "1 530.24", "−1 022.3"
    broken = sorted(n for n in numbers if n not in pdf_text)
    assert not broken, f"{len(broken)} number(s) broken across lines in the PDF: {broken}"


def test_no_word_of_the_section_is_broken_or_hyphenated_in_the_pdf(wide_report):
    html_words = _words(_visible(_section(wide_report["html"])))
    pdf_words = _words(_pdf_section(wide_report["text"]))
    foreign = sorted(pdf_words - html_words - {"\u2022"})  # the list's bullets
    assert not foreign, f"{len(foreign)} word(s) of the PDF are not words of the HTML: {foreign}"


def test_the_wide_tables_fit_the_page(wide_report):
    defects = layout_defects(wide_report["pdf"], wide_report["work"])
    assert not defects, f"{len(defects)} layout defect(s):\n" + "\n".join(defects)
