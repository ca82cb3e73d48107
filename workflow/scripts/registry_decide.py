"""Rule decide: candidate vs champion -> registry/decision.json, registry/comparison.csv.

Also updates the registry (models/, history.jsonl, champion.json) as documented in
workflow/rules/registry.smk and rafi.ops.decide.run_decide.
"""

from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    from rafi.ops.decide import run_decide

    smk = snakemake  # noqa: F821
    record = run_decide(
        machine=smk.params.machine,
        candidate_path=smk.input.model,
        runs_csv=smk.input.table,
        runs_parquet=smk.input.frame,
        registry_root=smk.params.registry,
        decision_path=smk.output.decision,
        comparison_path=smk.output.comparison,
        gates=dict(smk.params.gates),
        nightly=dict(smk.params.nightly),
        log=lambda msg: print(msg, flush=True),
        candidate_summary_path=(smk.input.summary if smk.params.nightly["candidate"] == "fit" else None),
        candidate_residuals_path=smk.input.residuals,
        input_status_path=smk.input.status,
        speed_tolerance_rpm=float(smk.params.speed_tolerance_rpm),
        displacement_sign=int(smk.params.displacement_sign),
        confirmed=list(smk.params.confirmed),
    )
    print(
        f"decision: {record['decision']} (candidate {record['candidate_id'][:12]}, champion "
        f"after {str(record['champion_id_after'])[:12]}), recalibration_due="
        f"{record['recalibration_due']}",
        flush=True,
    )
