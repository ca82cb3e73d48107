"""Rule clean: one raw log -> clean/<stem>.parquet, clean/<stem>.audit.csv, clean/<stem>.summary.csv.

With on_bad_input=quarantine ANY failure reading, checking or cleaning the file (a RawFormatError,
but also an OSError, a PermissionError, a pandas ValueError, a MemoryError, ...) quarantines the
file with a one-line reason (the traceback goes to the log); so does a clean table that cannot be
read back. With fail the job fails with the message. A reason ends with ``[<check id>]`` when
the error is a documented check (docs/raw-format.md); ``[unreadable]`` for an OSError.
"""

from pathlib import Path

from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    import pandas as pd

    import rafi.artefact
    import rafi.method.audit
    import rafi.method.clean
    import rafi.readers.logs
    from rafi.errors import RawFormatError
    from rafi.readers.checks import check_file
    from rafi.settings import run_settings

    smk = snakemake  # noqa: F821
    src = Path(smk.params.raw_path)
    spec = smk.params.input_spec
    cfg = smk.params.clean
    # on_bad_input is a run mode, not a param: the outputs are the same in both modes
    fail_mode = run_settings(smk.config)["on_bad_input"] == "fail"
    sha = ""

    def quarantine(reason: str) -> None:
        """Write the quarantined outputs of this file."""
        print(f"  QUARANTINED: {reason}", flush=True)
        clean, actions, summary = rafi.method.audit.quarantined(src.name, sha, reason)
        rafi.artefact.write_parquet_atomic(clean, smk.output.parquet)
        rafi.artefact.write_csv_atomic(actions, smk.output.audit)
        rafi.artefact.write_csv_atomic(summary, smk.output.summary)

    try:
        sha = rafi.readers.logs.sha256_file(src)
        print(f"read {src} (format {spec.get('format', 'native')}, sha256 {sha[:12]})", flush=True)
        frame = rafi.readers.logs.read_log(src, spec)
        rows_in = len(frame)
        print(f"  {rows_in} rows, {frame.shape[1]} columns", flush=True)
        report = check_file(frame, src, **smk.params.checks)
        for w in report.warnings:
            log.warning("%s: %s", src.name, w.detail)
        print(f"  checks: {len(report.warnings)} warning(s), probe sign {report.probe_sign:+d}", flush=True)
        clean, actions = rafi.method.clean.clean_log(
            frame,
            file=src.name,
            sample_period_s=smk.params.sample_period_s,
            max_interpolate_gap_s=cfg["max_interpolate_gap_s"],
            spike_threshold=cfg["spike_threshold"],
            open_circuit_values=cfg["open_circuit_values"],
        )
        actions = rafi.method.audit.with_warnings(
            actions, rafi.method.audit.warning_rows(src.name, report.warnings)
        )
        summary = rafi.method.audit.summarise_audit(
            src.name, sha, rows_in, clean, actions, probe_sign=report.probe_sign
        )
    except Exception as exc:  # noqa: BLE001 - any failure on one file quarantines that file
        if fail_mode:
            raise
        reason = rafi.method.audit.quarantine_reason(exc, src.name)
        # a documented check needs no traceback; anything else keeps it in the log
        log.warning("quarantined %s: %s", src.name, reason, exc_info=not isinstance(exc, RawFormatError))
        quarantine(reason)
    else:
        counts = actions["action"].value_counts().to_dict() if len(actions) else {}
        print(f"  clean: {len(clean)} rows; actions: {counts or 'none'}", flush=True)
        rafi.artefact.write_parquet_atomic(clean, smk.output.parquet)
        rafi.artefact.write_csv_atomic(actions, smk.output.audit)
        rafi.artefact.write_csv_atomic(summary, smk.output.summary)
        # the next rule must be able to read what we wrote (e.g. huge metadata breaks parquet)
        try:
            back = pd.read_parquet(smk.output.parquet)
            if len(back) != len(clean):
                raise ValueError(f"{len(back)} rows read back, {len(clean)} written")
        except Exception as exc:  # noqa: BLE001
            why = (
                f"its clean table {smk.output.parquet} cannot be read back "
                f"({type(exc).__name__}: {rafi.method.audit.one_line(exc)})"
            )
            if fail_mode:
                raise RawFormatError(src, why, check="clean_table_unreadable") from exc
            log.warning("quarantined %s: %s", src.name, why, exc_info=True)
            quarantine(f"{src.name}: {why} [clean_table_unreadable]")
    print(f"wrote {smk.output.parquet}", flush=True)
