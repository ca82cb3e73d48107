"""The sign-off block and the archival PDF (issue 15 items 4 and 5).

- Revision (rafi.report.signoff): derived from the content; the same inputs give the same
  revision whatever the time of generation, the code commit or the names on the report; a
  change of the model on the machine, of RAFI's model, of a raw file or of a setting that
  changes results gives another.
- The first page's sign-off block: the configured values, or empty boxes to sign.
- The PDF read back with poppler (an independent reader): the XMP declares PDF/A-3b, every
  font is embedded, the output intent is there, and ``pdfdetach`` finds the model on the
  machine, model.json, audit.csv and the summaries, byte-equal to the files, with their
  descriptions (read from the inflated PDF objects with zlib).
"""

from __future__ import annotations

import copy
import json
import re
import subprocess
import zlib
from pathlib import Path

import pandas as pd
import pytest
import yaml
from conftest import which_or_skip
from report_fixture import copy_fixture, empty_figure_dirs, write_upstream_tables

from rafi.report.context import build_context
from rafi.report.inputs import FIGURE_DIRS, load_results, result_paths
from rafi.report.pdf_archive import attachment_specs
from rafi.report.render import render_html, render_pdf
from rafi.report.signoff import revision, revision_inputs, section_signoff
from rafi.settings import machine_settings

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "tests" / "data" / "report_fixture" / "tapping-center-a"
CONFIG = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))
MACHINE = "tapping-center-a"


def _results(tmp: Path) -> Path:
    """The report fixture with what rule report_figures writes besides figures (none here)."""
    results = copy_fixture(tmp, MACHINE)
    write_upstream_tables(results)
    empty_figure_dirs(results)
    return results


def _context(results: Path, settings: dict, **kw) -> dict:
    dirs = {g: results / rel for g, rel in FIGURE_DIRS.items()}
    return build_context(result_paths(results), dirs, machine=MACHINE, settings=settings, **kw)


@pytest.fixture(scope="module")
def fixture_results(tmp_path_factory):
    return _results(tmp_path_factory.mktemp("pdf"))


# --------------------------------------------------------------------------- revision


def _rev(res: dict, settings: dict) -> str:
    return section_signoff(res, settings)["revision"]


def test_revision_is_the_same_on_identical_inputs_and_changes_with_model_or_data(fixture_results):
    import datetime as dt

    settings = machine_settings(CONFIG, MACHINE)
    paths = result_paths(fixture_results)
    res = load_results(paths)
    base = _rev(res, settings)
    assert re.fullmatch(r"[0-9a-f]{10}", base)

    # the same inputs, generated at another time, read again: the same revision
    a = _context(fixture_results, settings, now=dt.datetime(2026, 1, 1, tzinfo=dt.UTC))
    b = _context(fixture_results, settings, now=dt.datetime(2027, 6, 30, 12, 5, tzinfo=dt.UTC))
    assert a["generated"] != b["generated"]
    assert a["signoff"]["revision"] == b["signoff"]["revision"] == base
    assert _rev(load_results(paths), copy.deepcopy(settings)) == base

    # what does not change a result: names on the report, presentation settings, code commit
    named = copy.deepcopy(settings)
    named["report"]["document"].update(number="QR-7", prepared_by="A. Person", approved_by="B. Person")
    named["report"]["figure_format"] = "svg"
    assert _rev(res, named) == base
    recommitted = {**res, "model": {**res["model"], "code_version": "rafi 9.9.9 (git 0123456789ab)"}}
    assert _rev(recommitted, settings) == base

    # what does: each changes the revision
    changed = {}
    audit = res["audit"].copy()
    audit.loc[0, "sha256"] = "0" * 64  # one raw file's content
    changed["raw file"] = {**res, "audit": audit}
    extra = pd.concat([res["audit"], res["audit"].iloc[[0]].assign(file="new.csv")], ignore_index=True)
    changed["a new raw file"] = {**res, "audit": extra}
    model = copy.deepcopy(res["model"])
    model["speeds"][0]["coefficients"][0] += 1e-9  # one coefficient of RAFI's model
    changed["RAFI model"] = {**res, "model": model}
    changed["model on the machine"] = {**res, "decision": {**res["decision"], "champion_id_after": "f" * 64}}
    revs = {k: _rev(v, settings) for k, v in changed.items()}
    gate = copy.deepcopy(settings)
    gate["qualification"]["max_residual_um"] += 0.5
    revs["a gate"] = _rev(res, gate)
    fit = copy.deepcopy(settings)
    fit["rank"]["threshold"] = 0.95
    revs["a method setting"] = _rev(res, fit)
    assert base not in revs.values(), revs
    assert len(set(revs.values())) == len(revs), revs


def test_revision_is_the_documented_hash():
    """docs/report.md: sha256 of the canonical JSON of {deployed, RAFI content id, raw files, settings}."""
    import hashlib

    audit = pd.DataFrame({"file": ["b.csv", "a.csv"], "sha256": ["2" * 64, "1" * 64]})
    settings = {"x": 1, "report": {}}
    inputs = revision_inputs(deployed_id="d" * 64, rafi_model=None, audit=audit, settings=settings)
    assert inputs == {
        "deployed_model": "d" * 64,
        "rafi_model": "",
        "raw_files": {"a.csv": "1" * 64, "b.csv": "2" * 64},
        "settings": {"x": 1},
    }
    text = (
        '{"deployed_model":"'
        + "d" * 64
        + '","rafi_model":"","raw_files":{"a.csv":"'
        + "1" * 64
        + '","b.csv":"'
        + "2" * 64
        + '"},"settings":{"x":1}}'
    )
    assert revision(inputs) == hashlib.sha256(text.encode()).hexdigest()[:10]


# --------------------------------------------------------------------------- sign-off block


def _signoff_cells(html: str) -> dict:
    table = re.search(r'<table class="signoff".*?</table>', html, re.S).group(0)
    heads = re.findall(r"<th>(.*?)</th>", table)
    cells = re.findall(r'<td class="([^"]*)">(.*?)</td>', table, re.S)
    return {h: (cls, re.sub(r"<[^>]+>", "", v)) for h, (cls, v) in zip(heads, cells, strict=True)}


def test_signoff_block_is_on_the_first_page_filled_or_blank(fixture_results):
    settings = machine_settings(CONFIG, MACHINE)
    html = render_html(_context(fixture_results, settings))
    cells = _signoff_cells(html)
    rev = cells["Revision"][1]
    assert re.fullmatch(r"[0-9a-f]{10}", rev)
    assert html.index('class="signoff"') < html.index('id="toc"')  # in the header, before the contents
    for label in ("Document no.", "Prepared by", "Approved by", "Date"):
        assert cells[label] == ("blank", ""), label  # a line to sign by hand

    doc = {"number": "QR-2026-014", "prepared_by": "J. Doe", "approved_by": "R. Roe"}
    doc["approved_date"] = "2026-11-23"
    filled = copy.deepcopy(settings)
    filled["report"]["document"].update(doc)
    cells = _signoff_cells(render_html(_context(fixture_results, filled)))
    assert cells["Document no."][1] == "QR-2026-014" and cells["Prepared by"][1] == "J. Doe"
    assert cells["Approved by"][1] == "R. Roe" and cells["Date"][1] == "2026-11-23"
    assert cells["Revision"][1] == rev  # the names are not part of the revision
    assert not any(cls == "blank" for cls, _ in cells.values())

    # a YAML date (approved_date: 2026-11-23 unquoted) is shown as ISO 8601
    import datetime as dt

    filled["report"]["document"]["approved_date"] = dt.date(2026, 11, 23)
    assert _signoff_cells(render_html(_context(fixture_results, filled)))["Date"][1] == "2026-11-23"


# --------------------------------------------------------------------------- the archival PDF


def _tool(name: str) -> str:
    return which_or_skip(name)


def _out(*cmd) -> str:
    return subprocess.run([_tool(cmd[0]), *cmd[1:]], capture_output=True, text=True, check=True).stdout


def _pdf_objects(pdf: bytes) -> bytes:
    """The PDF's bytes with every Flate stream inflated (object streams included)."""
    out = [pdf]
    for m in re.finditer(rb"stream\r?\n", pdf):
        start = m.end()
        try:
            out.append(zlib.decompressobj().decompress(pdf[start : start + 4_000_000]))
        except zlib.error:
            continue
    return b"\n".join(out)


@pytest.fixture(scope="module")
def archived(fixture_results, tmp_path_factory):
    settings = machine_settings(CONFIG, MACHINE)
    html = render_html(_context(fixture_results, settings))
    paths = result_paths(fixture_results)
    pdf = render_pdf(html, attach=paths)
    out = tmp_path_factory.mktemp("archived") / "qualification.pdf"
    out.write_bytes(pdf)
    return {"pdf": out, "html": html, "paths": paths, "bytes": pdf}


def test_pdf_declares_pdfa_3b_with_embedded_fonts_and_output_intent(archived):
    xmp = _out("pdfinfo", "-meta", archived["pdf"])
    part = re.search(r'pdfaid:part(?:="|>)(\d)', xmp)
    conf = re.search(r'pdfaid:conformance(?:="|>)([A-Za-z])', xmp)
    assert part and part.group(1) == "3", xmp
    assert conf and conf.group(1) == "B", xmp
    info = _out("pdfinfo", archived["pdf"])
    assert re.search(r"PDF version:\s+1\.7", info), info
    fonts = _out("pdffonts", archived["pdf"])
    rows = fonts.splitlines()[2:]
    assert rows and all(r.split()[-5] == "yes" for r in rows), fonts  # column "emb"
    objects = _pdf_objects(archived["bytes"])
    assert b"/OutputIntents" in objects and b"/GTS_PDFA1" in objects
    assert b"/SMask" not in objects  # the figures are opaque PNG: no soft mask


def test_pdf_carries_the_attachments_byte_equal_with_descriptions(archived, tmp_path):
    paths = archived["paths"]
    listed = subprocess.run(
        [_tool("pdfdetach"), "-list", archived["pdf"]], capture_output=True, text=True, check=True
    ).stdout
    names = [line.split(": ", 1)[1] for line in listed.splitlines()[1:]]
    dec = json.loads(Path(paths["decision"]).read_text(encoding="utf-8"))
    champ = dec["champion_id_after"]
    registry_json = Path(paths["decision"]).parent / "models" / f"{champ}.json"
    kind = json.loads(registry_json.read_text(encoding="utf-8"))["kind"]
    expected = {
        f"model_on_the_machine_{kind}_{champ[:12]}.json": registry_json,
        "model.json": Path(paths["model"]),
        "audit.csv": Path(paths["audit"]),
        "validation_summary.csv": Path(paths["validation_summary"]),
        "comparison_summary.csv": Path(paths["comparison"]),
    }
    assert sorted(names) == sorted(expected), listed
    assert names == sorted(names)  # the EmbeddedFiles name tree is sorted
    subprocess.run([_tool("pdfdetach"), "-saveall", "-o", str(tmp_path), archived["pdf"]], check=True)
    for name, src in expected.items():
        assert (tmp_path / name).read_bytes() == src.read_bytes(), name
    objects = _pdf_objects(archived["bytes"])
    descs = [  # PDF literal strings: \( \) \\ escaped
        re.sub(rb"\\(.)", rb"\1", d).decode("latin-1")
        for d in re.findall(rb"/Desc \(((?:\\.|[^\\)])*)\)", objects)
    ]
    assert any(f"model id {champ}" in d for d in descs), descs
    assert any("Audit of the raw files" in d for d in descs), descs
    assert len(descs) >= len(expected)
    assert objects.count(b"/AFRelationship") >= len(expected)
    # the HTML stays self-contained: nothing of the attachments is linked from it
    assert "pdfdetach" not in archived["html"] and 'rel="attachment"' not in archived["html"]


def test_attachment_specs_skip_what_the_run_did_not_write(tmp_path):
    (tmp_path / "audit.csv").write_text("file,sha256\n", encoding="utf-8")
    paths = {"audit": tmp_path / "audit.csv", "model": tmp_path / "none.json", "decision": None}
    specs = attachment_specs(paths)
    assert [s["name"] for s in specs] == ["audit.csv"]
    (tmp_path / "registry").mkdir()
    (tmp_path / "registry" / "decision.json").write_text(json.dumps({"champion_id_after": None}))
    assert [s["name"] for s in attachment_specs({"decision": tmp_path / "registry" / "decision.json"})] == []


def test_compiled_templates_from_the_cache_give_the_same_html(fixture_results, tmp_path, monkeypatch):
    """Known truth: the HTML rendered without a cache. The first render fills the template cache,
    the second reads it (jinja2 compiles nothing): the same HTML both times."""
    import jinja2

    ctx = _context(fixture_results, machine_settings(CONFIG, MACHINE))
    want = render_html(ctx)
    cache = tmp_path / ".template_cache"
    assert render_html(ctx, template_cache=cache) == want
    assert len(list(cache.iterdir())) >= 2  # the page and the templates it includes
    compiled = []
    real_compile = jinja2.Environment.compile

    def spy(self, source, name=None, *args, **kwargs):
        compiled.append(name)
        return real_compile(self, source, name, *args, **kwargs)

    monkeypatch.setattr(jinja2.Environment, "compile", spy)
    assert render_html(ctx, template_cache=cache) == want
    assert compiled == []
    assert render_html(ctx) == want and compiled  # without the cache: compiled again


def test_the_revision_note_names_a_model_on_the_machine_only_where_there_is_one():
    """tapping-center-a-rep's WAITING report said "The revision is a hash of the model on the
    machine, ..." while no model was on it (its candidate waited for a confirmation)."""
    from test_report_text import _section

    audit = pd.DataFrame({"file": ["a.csv", "b.csv"], "sha256": ["1" * 64, "2" * 64]})
    settings = {"report": {"document": {}}}

    def note(decision):
        res = {"decision": decision, "model": {"kind": "rafi"}, "audit": audit}
        html = _section("signoff", signoff=section_signoff(res, settings))
        return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html)).strip()

    placed = note({"decision": "kept", "champion_id_after": "ab" * 32})
    assert "The revision is a hash of the model on the machine ( abababababab )" in placed
    waiting = note({"decision": "rejected", "champion_id_after": None, "candidate_id": "cd" * 32})
    assert "model on the machine" not in waiting and "No model is on the machine after this run" in waiting
    assert (
        "the SHA-256 of the 2 raw files read" in waiting and "when a model is put on the machine" in waiting
    )
    unregistered = note(None)
    assert "model on the machine" not in unregistered and "No registry decision in this run" in unregistered
