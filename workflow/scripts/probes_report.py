"""Rule probes_report: the probes' tables and reports -> reports/<machine>/qualification.{html,pdf}
of a machine with several probes (rafi.report.probes_page)."""

from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    import os

    from rafi.artefact import write_bytes_atomic, write_text_atomic
    from rafi.report.probes_page import probe_row, probes_context, render_probes_html, render_probes_pdf
    from rafi.settings import unit_name

    smk = snakemake  # noqa: F821
    keys = ("summary", "per_run", "decision", "audit", "replay", "validation", "model")
    page_dir = os.path.dirname(smk.output.html)
    rows = []
    for probe, html in zip(smk.params.probes, smk.input.reports):
        paths = {key: smk.input[f"{key}_{probe}"] for key in keys}
        href = os.path.relpath(html, page_dir)
        rows.append(probe_row(probe, smk.params.settings[probe], paths, href, smk.params.sign_keys[probe]))
    ctx = probes_context(smk.wildcards.folder, rows, smk.params.machine_settings)
    html = render_probes_html(ctx)
    units = [unit_name(smk.wildcards.folder, probe) for probe in smk.params.probes]
    pdf = render_probes_pdf(ctx, dict(zip(units, smk.input.reports)))
    write_text_atomic(smk.output.html, html)
    write_bytes_atomic(smk.output.pdf, pdf)
    print(
        f"{ctx['verdict']}: {ctx['n_pass']} of {len(rows)} probe(s) pass; wrote {smk.output.html}", flush=True
    )
