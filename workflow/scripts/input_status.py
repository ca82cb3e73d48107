"""Checkpoint input_status: clean summaries and audits of a machine -> results/<machine>/input_status.json
and results/<machine>/audit.csv (the summaries stacked; formerly rule audit).

Per file: usable or quarantined (the clean summaries). Machine level (rafi.readers.checks_machine):
byte-identical copies (which one stays: param keep, rafi.ops.duplicates) and probe signs against
the configured or majority sign; every warning of the checks with ``confirmed`` resolved from
``checks.confirmed``.
"""

from pathlib import Path

from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    import pandas as pd

    from rafi.artefact import json_text, write_csv_atomic, write_text_atomic
    from rafi.method.audit import stack_summaries
    from rafi.ops.clean_job import files_in
    from rafi.readers.checks_machine import apply_machine_checks, audit_warnings, read_rows, warning_lines
    from rafi.readers.quarantine import is_skipped, machine_input_status

    smk = snakemake  # noqa: F821
    summaries = files_in(smk.input.clean, "summary")
    base = machine_input_status(smk.params.machine, summaries)
    rows = [row for path in summaries for row in read_rows(path)]
    warnings = [w for path in files_in(smk.input.clean, "audit") for w in audit_warnings(read_rows(path))]
    status = apply_machine_checks(
        base,
        rows,
        warnings,
        probe_sign=smk.params.probe_sign,
        confirmed=smk.params.confirmed,
        links=smk.params.links,
        keep=smk.params.keep,
    )
    for f in status["rejected"]:
        if f.get("check"):
            log.warning("rejected %s", f["reason"])
    for line in warning_lines(status):
        log.warning("warning %s", line)
    n_open = sum(1 for w in status["warnings"] if not w["confirmed"])
    print(
        f"{status['n_files']} raw file(s): {len(status['usable'])} usable, "
        f"{len(status['rejected'])} rejected -> {status['status']}; {len(status['warnings'])} "
        f"warning(s), {n_open} not confirmed",
        flush=True,
    )
    if is_skipped(status):
        log.warning("machine %s skipped: no usable raw file", smk.params.machine)
    else:
        page = Path(smk.params.skipped_page)
        if page.exists():
            page.unlink()
            print(f"removed {page} (the machine has a usable file again)", flush=True)
    # audit.csv: the per-file summaries stacked (one row per raw file)
    audit = stack_summaries(pd.read_csv(p) for p in summaries)
    quarantined = audit[audit["status"] != "ok"]
    print(f"audit: {len(audit)} files, {len(quarantined)} quarantined", flush=True)
    for file, reason in zip(quarantined["file"], quarantined["reason"]):
        log.warning("quarantined %s: %s", file, reason)
    write_csv_atomic(audit, smk.output.audit)
    write_text_atomic(smk.output.status, json_text(status))
