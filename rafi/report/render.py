"""Rendering of the qualification report: context -> HTML (jinja2) -> PDF (WeasyPrint).

One template (``rafi/report/templates/qualification.html.j2``) renders the HTML; the PDF is
rendered from the *same* HTML string, so the two never disagree. The figures are embedded,
so the HTML needs no other file. The PDF is a PDF/A-3b with the model, the audit and the
summary tables attached (:mod:`rafi.report.pdf_archive`).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from rafi.report.context import build_context
from rafi.report.inputs import figure_dirs, result_paths


def _environment(template_cache: str | os.PathLike | None = None):
    """The jinja2 environment of the report's templates (autoescaped, strict; the formatters of
    :data:`rafi.report.format.FILTERS` as filters).

    ``template_cache``: a folder for the compiled templates (jinja2's bytecode cache: an entry
    is keyed by the template's name and used only while its source is unchanged), so only the
    first report job of a run compiles them (about 0.3 s)."""
    import jinja2
    import markupsafe

    from rafi.report import fonts
    from rafi.report.format import FILTERS

    cache = None
    if template_cache is not None:
        Path(template_cache).mkdir(parents=True, exist_ok=True)
        cache = jinja2.FileSystemBytecodeCache(str(template_cache))
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("rafi.report", "templates"),
        autoescape=jinja2.select_autoescape(["html", "j2"], default_for_string=True),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
        bytecode_cache=cache,
    )
    env.filters.update(FILTERS)
    # the CJK families every font stack of the CSS ends in (rafi.report.fonts)
    env.globals["cjk_fonts"] = markupsafe.Markup(fonts.css_families())
    return env


def render_html(ctx: dict, *, template_cache: str | os.PathLike | None = None) -> str:
    """Render the qualification report HTML (self-contained); ``template_cache``: see
    :func:`_environment`. Where the text holds CJK characters and no CJK font is installed the
    report is rendered again with a note saying so (``font_note``,
    :func:`rafi.report.fonts.missing_font_note`)."""
    from rafi.report import fonts

    template = _environment(template_cache).get_template("qualification.html.j2")
    html = template.render({**ctx, "font_note": None})
    note = fonts.missing_font_note(html)
    return html if note is None else template.render({**ctx, "font_note": note})


def render_pdf(html: str, base_url: str | None = None, *, attach: dict | None = None) -> bytes:
    """Render the same HTML to a PDF/A-3b with WeasyPrint (A4, print CSS in the template).

    Parameters
    ----------
    html : str
    base_url : str, optional
    attach : dict, optional
        The report's input paths (name -> path); the files
        :func:`rafi.report.pdf_archive.attachment_specs` picks from them are attached to the PDF
        (the HTML carries none).
    """
    import gc

    import weasyprint

    from rafi.report.pdf_archive import attachment_specs, write_options

    options = write_options(attachment_specs(attach or {}))

    # WeasyPrint allocates millions of small objects; the cyclic garbage collector's passes
    # over them were about 15 % of the rendering time. Paused for this one document only.
    enabled = gc.isenabled()
    gc.disable()
    try:
        return weasyprint.HTML(string=html, base_url=base_url or ".").write_pdf(**options)
    finally:
        if enabled:
            gc.enable()


def generate(
    results_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    settings: dict,
    machine: str | None = None,
    config: dict | None = None,
    sign_key: str | None = None,
) -> dict:
    """Build, render and write ``qualification.html`` and ``.pdf`` atomically; return timings.

    Reads the standard paths under ``results_dir`` (:func:`rafi.report.inputs.result_paths`,
    figure folders included: rules ``report_tables`` and ``report_figures`` must have run).
    """
    from rafi.artefact import write_bytes_atomic, write_text_atomic

    results_dir = Path(results_dir)
    out_dir = Path(out_dir)
    t = {}
    t0 = time.perf_counter()
    paths = result_paths(results_dir)
    ctx = build_context(
        paths,
        figure_dirs(results_dir),
        machine=machine or results_dir.name,
        settings=settings,
        config=config,
        sign_key=sign_key,
    )
    t["context_s"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    html = render_html(ctx)
    t["html_s"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    pdf = render_pdf(html, attach=paths)
    t["pdf_s"] = time.perf_counter() - t2
    write_text_atomic(out_dir / "qualification.html", html)
    write_bytes_atomic(out_dir / "qualification.pdf", pdf)
    t["total_s"] = time.perf_counter() - t0
    t["verdict"] = ctx["verdict"]["status"]
    t["html_bytes"], t["pdf_bytes"] = len(html.encode()), len(pdf)
    return t
