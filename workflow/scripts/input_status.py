"""Checkpoint input_status: the clean summaries of a machine -> results/<machine>/input_status.json."""

from pathlib import Path

from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    from rafi.artefact import json_text, write_text_atomic
    from rafi.readers.quarantine import is_skipped, machine_input_status

    smk = snakemake  # noqa: F821
    status = machine_input_status(smk.params.machine, smk.input.summaries)
    print(
        f"{status['n_files']} raw file(s): {len(status['usable'])} usable, "
        f"{len(status['rejected'])} rejected -> {status['status']}",
        flush=True,
    )
    if is_skipped(status):
        log.warning("machine %s skipped: no usable raw file", smk.params.machine)
    else:
        page = Path(smk.params.skipped_page)
        if page.exists():
            page.unlink()
            print(f"removed {page} (the machine has a usable file again)", flush=True)
    write_text_atomic(smk.output.status, json_text(status))
