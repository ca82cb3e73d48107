"""Rule clean: every raw log of a machine -> results/<machine>/clean/<stem>.parquet,
<stem>.audit.csv and <stem>.summary.csv, in one process (rafi.ops.clean_job.clean_machine).

With on_bad_input=quarantine any failure on a file quarantines that file with a one-line reason
(the traceback goes to the log); with fail the job fails with the message (file, line, column).
"""

from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    from rafi.ops.clean_job import CleanSettings, clean_machine
    from rafi.settings import run_settings

    smk = snakemake  # noqa: F821
    settings = CleanSettings(
        input_spec=smk.params.input_spec,
        sample_period_s=smk.params.sample_period_s,
        clean=smk.params.clean,
        checks=smk.params.checks,
    )
    # on_bad_input is a run mode, not a param: the outputs are the same in both modes
    fail_mode = run_settings(smk.config)["on_bad_input"] == "fail"
    done = clean_machine(
        smk.params.raw_paths,
        smk.output.folder,
        settings,
        fail_mode=fail_mode,
        log=log,
        parts=smk.params.raw_parts,
    )
    counts = {s: list(done.values()).count(s) for s in ("ok", "quarantined")}
    print(f"{len(done)} raw file(s): {counts['ok']} cleaned, {counts['quarantined']} quarantined", flush=True)
