"""Rule skipped_report: input_status.json of a skipped machine -> reports/<machine>/skipped.html."""

from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    from rafi.artefact import now_iso, write_text_atomic
    from rafi.readers.quarantine import read_input_status
    from rafi.report.skipped import skipped_page

    smk = snakemake  # noqa: F821
    status = read_input_status(smk.input.status)
    page = skipped_page(status, created=now_iso(), audit_path=smk.input.audit, status_path=smk.input.status)
    write_text_atomic(smk.output.html, page)
    print(f"wrote {smk.output.html}", flush=True)
