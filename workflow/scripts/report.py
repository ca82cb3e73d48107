"""Snakemake glue of rule ``report``: the results tables and figure files in, the HTML and PDF out.

All the work is in :mod:`rafi.report.render` (context + rendering); this script only maps
``snakemake.input``/``params`` onto it and writes atomically. It evaluates no model and draws
no figure: the figures are the files of rule ``report_figures`` (input ``figures``).
"""

from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    from rafi.artefact import write_bytes_atomic, write_text_atomic
    from rafi.report.context import build_context
    from rafi.report.inputs import OPTIONAL_FILES, RESULT_FILES
    from rafi.report.render import render_html, render_pdf

    smk = snakemake  # noqa: F821
    names = set(RESULT_FILES) | set(OPTIONAL_FILES)
    paths = {k: str(v) for k, v in smk.input.items() if k in names}
    settings = dict(smk.params.settings)
    shown = {**smk.params.paths, "machine": smk.wildcards.machine, "settings": settings}
    folders = dict(zip(smk.params.figure_groups, smk.input.figures))
    ctx = build_context(
        paths,
        folders,
        machine=smk.wildcards.machine,
        settings=settings,
        config=shown,
        sign_key=smk.params.sign_key,
    )
    log.info(
        "context with %d section(s) built in %.2f s; verdict %s; %d figure(s) embedded",
        len(ctx["sections"]),
        ctx["build_seconds"],
        ctx["verdict"]["status"],
        len(ctx["figures_used"]),
    )
    html = render_html(ctx, template_cache=smk.params.template_cache)
    pdf = render_pdf(html, attach=paths)  # PDF/A-3b; model, audit, summaries attached
    write_text_atomic(smk.output.html, html)
    write_bytes_atomic(smk.output.pdf, pdf)
    print(f"wrote {smk.output.html} ({len(html)} bytes) and {smk.output.pdf} ({len(pdf)} bytes)", flush=True)
