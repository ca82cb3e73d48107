"""Rule input_check: every machine's input_status.json -> results/input_check.json."""

from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    from rafi.artefact import json_text, write_text_atomic
    from rafi.readers.quarantine import input_check, read_input_status, rejection_lines

    smk = snakemake  # noqa: F821
    statuses = [read_input_status(p) for p in smk.input.statuses]
    for line in rejection_lines(statuses):
        log.warning("%s", line)
    check = input_check(statuses)
    print(f"input rejected: {check['input_rejected']}", flush=True)
    write_text_atomic(smk.output.check, json_text(check))
