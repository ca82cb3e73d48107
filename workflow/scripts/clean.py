"""Rule clean: one raw log -> clean/<stem>.parquet, clean/<stem>.audit.csv, clean/<stem>.summary.csv."""

from pathlib import Path

from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    import rafi.artefact
    import rafi.method.audit
    import rafi.method.clean
    import rafi.readers.logs
    from rafi.errors import RawFormatError
    from rafi.readers.checks import check_log
    from rafi.settings import run_settings

    smk = snakemake  # noqa: F821
    src = Path(smk.params.raw_path)
    spec = smk.params.input_spec
    cfg = smk.params.clean
    sha = rafi.readers.logs.sha256_file(src)
    print(f"read {src} (format {spec.get('format', 'native')}, sha256 {sha[:12]})", flush=True)
    try:
        frame = rafi.readers.logs.read_log(src, spec)
        rows_in = len(frame)
        print(f"  {rows_in} rows, {frame.shape[1]} columns", flush=True)
        check_log(frame, src, **smk.params.checks)
        clean, actions = rafi.method.clean.clean_log(
            frame,
            file=src.name,
            sample_period_s=smk.params.sample_period_s,
            max_interpolate_gap_s=cfg["max_interpolate_gap_s"],
            spike_threshold=cfg["spike_threshold"],
            open_circuit_values=cfg["open_circuit_values"],
        )
        summary = rafi.method.audit.summarise_audit(src.name, sha, rows_in, clean, actions)
    except RawFormatError as exc:
        # on_bad_input is a run mode, not a param: the outputs are the same in both modes
        if run_settings(smk.config)["on_bad_input"] == "fail":
            raise
        log.warning("quarantined %s: %s", src.name, exc)
        print(f"  QUARANTINED: {exc}", flush=True)
        clean, actions, summary = rafi.method.audit.quarantined(src.name, sha, str(exc))
    else:
        counts = actions["action"].value_counts().to_dict() if len(actions) else {}
        print(f"  clean: {len(clean)} rows; actions: {counts or 'none'}", flush=True)

    rafi.artefact.write_parquet_atomic(clean, smk.output.parquet)
    rafi.artefact.write_csv_atomic(actions, smk.output.audit)
    rafi.artefact.write_csv_atomic(summary, smk.output.summary)
    print(f"wrote {smk.output.parquet}", flush=True)
