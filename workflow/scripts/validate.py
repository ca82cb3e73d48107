"""Rule validate: model + runs -> validation/summary.csv, validation/residuals.parquet."""

from _glue import as_table, read_runs, step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    import rafi.artefact
    from rafi.method.model import load_model
    from rafi.method.validate import validate_runs

    smk = snakemake  # noqa: F821
    table, frame = read_runs(smk)
    model = load_model(smk.input.model)
    summary, residuals = validate_runs(model, table, frame)
    cols = [
        c
        for c in ("run_id", "speed_rpm", "max_abs_before_um", "max_abs_after_um", "improvement_pct")
        if c in summary.columns
    ]
    print(summary[cols].to_string(index=False), flush=True)
    rafi.artefact.write_csv_atomic(as_table(summary), smk.output.summary)
    rafi.artefact.write_parquet_atomic(residuals, smk.output.residuals)
