"""Rule clean: one raw log -> clean/<stem>.parquet, clean/<stem>.audit.csv, clean/<stem>.summary.csv."""

from pathlib import Path

import pandas as pd

from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    import rafi.clean
    import rafi.io
    from rafi import SENSORS
    from rafi.errors import RawFormatError

    smk = snakemake  # noqa: F821
    src = Path(smk.input.raw)
    spec = smk.params.input_spec
    cfg = smk.params.clean
    sha = rafi.io.sha256_file(src)
    print(f"read {src} (format {spec.get('format', 'native')}, sha256 {sha[:12]})", flush=True)

    try:
        if hasattr(rafi.io, "read_log"):
            frame = rafi.io.read_log(src, spec)
        else:
            frame = rafi.io.read_raw_log(src)
        rows_in = len(frame)
        print(f"  {rows_in} rows, {frame.shape[1]} columns", flush=True)
        if smk.params.checks:  # rafi.checks exists (see rule clean, params.checks)
            from rafi.checks import check_log
            frame = check_log(frame, src, **smk.params.checks)
        clean, actions = rafi.clean.clean_log(
            frame, file=src.name, sample_period_s=smk.params.sample_period_s,
            max_interpolate_gap_s=cfg["max_interpolate_gap_s"],
            spike_threshold=cfg["spike_threshold"],
            open_circuit_values=cfg["open_circuit_values"])
        summary = rafi.clean.summarise_audit(src.name, sha, rows_in, clean, actions)
    except RawFormatError as exc:
        if smk.params.on_bad_input != "quarantine":
            raise
        log.warning("quarantined %s: %s", src.name, exc)
        print(f"  QUARANTINED: {exc}", flush=True)
        columns = ["time", "t_s", "speed_rpm", *SENSORS, "disp_um", "segment"]
        clean = pd.DataFrame({c: pd.Series(dtype="float64") for c in columns})
        clean["time"] = clean["time"].astype("datetime64[ns]")
        clean["segment"] = clean["segment"].astype("int64")
        actions = pd.DataFrame(columns=["file", "action", "column", "first_line", "last_line",
                                        "n_rows", "detail"])
        summary = pd.DataFrame([{
            "file": src.name, "sha256": sha, "rows_in": pd.NA, "rows_out": 0,
            "duplicates_dropped": 0, "reordered": 0, "spikes_replaced": 0,
            "values_interpolated": 0, "gaps_interpolated": 0, "segments": 0,
            "status": "quarantined", "reason": str(exc)}])
    else:
        counts = actions["action"].value_counts().to_dict() if len(actions) else {}
        print(f"  clean: {len(clean)} rows; actions: {counts or 'none'}", flush=True)

    rafi.io.write_parquet_atomic(clean, smk.output.parquet)
    rafi.io.write_csv_atomic(pd.DataFrame(actions), smk.output.audit)
    rafi.io.write_csv_atomic(summary, smk.output.summary)
    print(f"wrote {smk.output.parquet}", flush=True)
