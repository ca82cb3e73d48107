"""Rule compare: runs + key sensors + model.json -> comparison/summary.csv, per_run.csv,
residuals.parquet, best_model.json, cv.csv (docs/models.md)."""

import json

from _glue import as_table, read_runs, step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    import rafi.artefact
    from rafi.family.compare import load_any, run_family

    smk = snakemake  # noqa: F821
    table, frame = read_runs(smk)
    with open(smk.input.key_sensors, encoding="utf-8") as fh:
        key_sensors = json.load(fh)["sensors"]
    result = run_family(
        table,
        frame,
        key_sensors=key_sensors,
        terms=smk.params.fit["terms"],
        reference=smk.params.reference,
        machine=smk.params.machine,
        options=smk.params.models,
        gates=smk.params.gates,
        hac_maxlags=smk.params.fit["hac_maxlags"],
        speed_tolerance_rpm=smk.params.speed_tolerance_rpm,
        rafi_model=load_any(smk.input.model),
        log=lambda m: print(m, flush=True),
    )
    cols = ["model", "max_abs_after_um", "improvement_pct", "passed", "champion"]
    print(result["summary"][cols].to_string(index=False), flush=True)
    if result["champion"] is None:
        print(
            f"WARNING: no model passes the gates; best_model.json is {result['best_name']} "
            "(lowest worst-case residual) and is NOT qualified",
            flush=True,
        )
    rafi.artefact.write_csv_atomic(as_table(result["summary"]), smk.output.summary, index=False)
    rafi.artefact.write_csv_atomic(as_table(result["per_run"]), smk.output.per_run, index=False)
    rafi.artefact.write_parquet_atomic(result["residuals"], smk.output.residuals)
    rafi.artefact.write_csv_atomic(as_table(result["cv"]), smk.output.cv, index=False)
    rafi.artefact.write_text_atomic(smk.output.best_model, rafi.artefact.json_text(result["best_artefact"]))
