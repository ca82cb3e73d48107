"""Chinese, Japanese or Korean text in the report (rafi.report.fonts): drawn with a CJK font where
one is installed, else written as it is with a note naming the package.

The report is the fixture's (tests/report_fixture.py) with a sensor position in Chinese
(``report.instruments.sensor_positions``), as a machine with Chinese headers would label its
sensors. The PDF is read back with poppler (pdffonts, pdftotext): an independent reader.
"""

from __future__ import annotations

import re
import subprocess

import pytest
import yaml
from conftest import require, which_or_skip
from report_fixture import ROOT, copy_fixture, empty_figure_dirs, write_upstream_tables

from rafi.report import fonts
from rafi.report.context import build_context
from rafi.report.inputs import FIGURE_DIRS, result_paths
from rafi.report.render import render_html, render_pdf
from rafi.settings import machine_settings

MACHINE = "tapping-center-a"
#: "spindle front bearing"
POSITION = "主轴前轴承"


@pytest.fixture(scope="module")
def chinese_context(tmp_path_factory):
    results = copy_fixture(tmp_path_factory.mktemp("fonts"), MACHINE)
    write_upstream_tables(results)
    empty_figure_dirs(results)
    config = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))
    settings = machine_settings(config, MACHINE)
    settings["report"]["instruments"]["sensor_positions"] = {"T1": f"{POSITION} (spindle front bearing)"}
    dirs = {g: results / rel for g, rel in FIGURE_DIRS.items()}
    return build_context(result_paths(results), dirs, machine=MACHINE, settings=settings)


def test_cjk_runs_finds_han_kana_hangul_and_full_width_forms_only():
    assert fonts.cjk_runs("T1 温度1 [°C] µm – Verlagerung") == ["温度"]
    assert fonts.cjk_runs("センサ、온도（℃）") == ["センサ、온도（", "）"]  # ℃ is in DejaVu
    assert fonts.cjk_runs("DejaVu draws Ä ß Ω ≤ → ·") == []


def test_every_font_stack_of_the_report_ends_in_the_cjk_families(chinese_context):
    html = render_html(chinese_context)
    style = html[html.index("<style>") : html.index("</style>")]
    stacks = [part.split(";")[0] for part in style.split("font-family:")[1:]]
    assert stacks and all(fonts.css_families() in s for s in stacks), stacks
    assert '"Noto Sans CJK SC", "Noto Sans CJK JP", "WenQuanYi Zen Hei"' in fonts.css_families()


def test_without_a_cjk_font_the_text_stays_and_a_note_names_the_package(chinese_context, monkeypatch):
    monkeypatch.setattr(fonts, "installed_cjk_families", lambda: ())
    html = render_html(chinese_context)
    assert POSITION in html and 'id="font-note"' in html
    note = html[html.index('id="font-note"') :].split("</p>")[0]
    assert "apt-get install fonts-noto-cjk" in note and f"\u201c{POSITION}\u201d" in note


def test_no_note_where_a_font_exists_or_the_text_is_latin(chinese_context, monkeypatch):
    monkeypatch.setattr(fonts, "installed_cjk_families", lambda: ("Noto Sans CJK SC",))
    assert 'id="font-note"' not in render_html(chinese_context)
    monkeypatch.setattr(fonts, "installed_cjk_families", lambda: ())
    assert fonts.missing_font_note("<p>T1 (header 'Temperatur 1 [°C]'), 3 000 r/min</p>") is None
    assert "fonts-noto-cjk" in fonts.missing_font_note("<p>T1 (header '温度1')</p>")


def test_the_figures_fall_back_to_the_installed_cjk_fonts():
    from matplotlib import font_manager

    families = fonts.matplotlib_families()
    assert families[0] == "DejaVu Sans" and set(families[1:]) <= set(fonts.CJK_FAMILIES)
    known = {f.name for f in font_manager.fontManager.ttflist}
    assert set(families[1:]) <= known and set(families[1:]) == set(fonts.installed_cjk_families()) & known


def test_a_font_installed_after_matplotlibs_cache_was_built_is_added_from_fontconfig(monkeypatch):
    from matplotlib import font_manager

    require(None if fonts.installed_cjk_families() else "no CJK font (apt-get install fonts-noto-cjk)")
    added = []
    known = iter([set(), set(fonts.installed_cjk_families())])  # a stale cache, then after adding
    monkeypatch.setattr(fonts, "_matplotlib_names", lambda: next(known))
    monkeypatch.setattr(font_manager.fontManager, "addfont", added.append)
    assert fonts.matplotlib_families() == ["DejaVu Sans", *fonts.installed_cjk_families()]
    assert added and all(p.endswith((".ttc", ".ttf", ".otf")) for p in added), added


def test_the_pdf_embeds_a_cjk_font_and_holds_the_text(chinese_context, tmp_path):
    fonts.installed_cjk_families.cache_clear()
    missing = "no CJK font (apt-get install fonts-noto-cjk; .ci/run installs it)"
    require(None if fonts.installed_cjk_families() else missing)
    html = render_html(chinese_context)
    assert 'id="font-note"' not in html
    path = tmp_path / "report.pdf"
    path.write_bytes(render_pdf(html))
    listed = subprocess.run([which_or_skip("pdffonts"), path], capture_output=True, text=True, check=True)
    listed = listed.stdout
    embedded = [line for line in listed.splitlines() if any(k in line for k in ("CJK", "WenQuanYi", "Droid"))]
    assert embedded and all(" yes " in line for line in embedded), listed
    # the first installed family of the CSS stacks (Simplified Chinese glyphs with fonts-noto-cjk),
    # not whichever CJK face fontconfig's own fallback picks (Noto Sans CJK JP)
    first = re.sub(r"\W", "", fonts.installed_cjk_families()[0])
    assert any(first in re.sub(r"\W", "", line) for line in embedded), listed
    text = subprocess.run(
        [which_or_skip("pdftotext"), "-enc", "UTF-8", path, "-"], capture_output=True, text=True, check=True
    ).stdout
    assert POSITION in text
