"""Snakemake glue of rule ``report``: the results tables in, the HTML and PDF report out.

All the work is in :mod:`rafi.report.build` (context + rendering) and :mod:`rafi.report.plots`;
this script only maps ``snakemake.input``/``params`` onto it and writes atomically. The
figures come drawn ahead from rule ``report_figures`` (input ``figures``); any figure they
do not hold is drawn here.
"""

import logging
import time

from rafi.artefact import write_bytes_atomic, write_text_atomic
from rafi.report import build as report

sm = snakemake  # noqa: F821 (injected by Snakemake)

logging.basicConfig(
    filename=sm.log[0], level=logging.INFO, filemode="w", format="%(asctime)s %(levelname)s %(message)s"
)
log = logging.getLogger("rafi.report.build")


def main() -> int:
    t0 = time.perf_counter()
    names = set(report.RESULT_FILES) | set(report.OPTIONAL_FILES)
    paths = {k: str(v) for k, v in sm.input.items() if k in names}
    settings = dict(sm.params.settings)
    shown = {**sm.params.paths, "machine": sm.wildcards.machine, "settings": settings}
    fig_args = {
        "figure_format": sm.params.report["figure_format"],
        "coolant_sensors": sm.params.report["coolant_sensors"],
    }
    figures, notes = report.load_figures(
        list(sm.input.figures), **fig_args, gates=settings.get("qualification") or {}
    )
    for note in notes:
        log.warning("figures drawn ahead: %s", note)
    ctx = report.build_context(
        paths, machine=sm.wildcards.machine, settings=settings, config=shown, figures=figures, **fig_args
    )
    log.info(
        "context with %d section(s) built in %.2f s; verdict %s; %d figure(s) drawn ahead, %d drawn here %s",
        len(ctx["sections"]),
        ctx["build_seconds"],
        ctx["verdict"]["status"],
        len(ctx["figures_reused"]),
        len(ctx["figures_drawn"]),
        ctx["figures_drawn"],
    )
    html = report.render_html(ctx)
    pdf = report.render_pdf(html)
    write_text_atomic(sm.output.html, html)
    write_bytes_atomic(sm.output.pdf, pdf)
    log.info(
        "wrote %s (%d bytes) and %s (%d bytes) in %.2f s",
        sm.output.html,
        len(html),
        sm.output.pdf,
        len(pdf),
        time.perf_counter() - t0,
    )
    return 0


try:
    main()
except Exception:
    log.exception("report failed")
    raise
