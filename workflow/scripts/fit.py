"""Rule fit: runs + key sensors -> fit/coefficients.csv, diagnostics.csv, vif.csv, model.json."""

import json

from _glue import as_table, read_runs, step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    import rafi.artefact
    from rafi.method.fit import fit_rafi
    from rafi.method.model import save_model

    smk = snakemake  # noqa: F821
    table, frame = read_runs(smk)
    with open(smk.input.key_sensors, encoding="utf-8") as fh:
        key_sensors = json.load(fh)["sensors"]
    cfg = smk.params.fit
    print(f"fit on {key_sensors}, {len(cfg['terms'])} terms, HAC lags {cfg['hac_maxlags']}", flush=True)
    result = fit_rafi(
        table,
        frame,
        key_sensors=key_sensors,
        terms=cfg["terms"],
        hac_maxlags=cfg["hac_maxlags"],
        reference=smk.params.reference,
        machine=smk.params.machine,
        fuzzy_outside=smk.params.fuzzy["outside"],
        speed_tolerance_rpm=float(smk.params.speed_tolerance_rpm),
        config=smk.params.model_config,
    )
    print(as_table(result.diagnostics).to_string(index=False), flush=True)
    rafi.artefact.write_csv_atomic(as_table(result.coefficients), smk.output.coefficients)
    rafi.artefact.write_csv_atomic(as_table(result.diagnostics), smk.output.diagnostics)
    rafi.artefact.write_csv_atomic(as_table(result.vif), smk.output.vif)
    save_model(result.model, smk.output.model)  # atomic
    print(f"wrote {smk.output.model}", flush=True)
