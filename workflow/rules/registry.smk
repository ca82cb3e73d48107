# Model registry and champion/challenger decision (rafi.ops.decide, rafi.ops.registry; docs/operations.md).
#
#   candidate model (config nightly.candidate = family's best model or fit's model.json)
#     + runs.csv, runs.parquet, validation/summary.csv and residuals.parquet (reused when the
#     candidate is the fitted model; the residuals feed the interval drift test), input_status.json
#     (its warnings block promotion until confirmed, as do the fitness warnings of a candidate
#     adapted from a prior: checks.confirmed)  ->  registry/decision.json and
#     registry/comparison.csv
#
# The registry's own files are side effects, not outputs: see the note in common.smk.
# The script writes the declared outputs last, after champion.json.


rule decide:
    """Judge tonight's candidate against the champion; promote only if every gate passes."""
    input:
        model=candidate_model,
        table=out("runs_csv"),
        frame=out("runs_parquet"),
        summary=out("validation_summary"),
        residuals=out("residuals"),
        status=out("input_status"),
    output:
        decision=report(
            out("decision"),
            caption="../report/registry_decision.rst",
            category="Registry decision",
            subcategory="{machine}",
            labels={"machine": "{machine}", "file": "registry/decision.json"},
        ),
        comparison=report(
            out("registry_comparison"),
            caption="../report/registry_comparison.rst",
            category="Registry decision",
            subcategory="{machine}",
            labels={"machine": "{machine}", "file": "registry/comparison.csv"},
        ),
    log:
        log_path("decide"),
    benchmark:
        bench_path("decide")
    conda:
        "../envs/rafi.yaml"
    params:
        code=code_version("registry_decide"),
        machine=lambda w: w.machine,
        gates=lambda w: qualification_gates(w.machine),
        nightly=lambda w: nightly_settings(w.machine),
        speed_tolerance_rpm=lambda w: machine_config(w.machine)["speed_tolerance_rpm"],
        registry=lambda w: registry_dir(w.machine),
        # kept in the meta of the models it registers (provenance: how the logs were read)
        displacement_sign=lambda w: machine_config(w.machine)["input"]["displacement"]["sign"],
        # the warnings a person has looked at: a prior's fitness warnings block promotion until here
        confirmed=lambda w: machine_config(w.machine)["checks"]["confirmed"],
    script:
        "../scripts/registry_decide.py"


# `rafi nightly` builds this target (restricted by `--config nightly_machines=M`; the
# report is left out with `--config nightly_report=false`, i.e. `rafi nightly --no-report`).
# A machine skipped for want of a usable raw file (input_status.smk) gets no decide job: no
# candidate, no decision, its champion stays; it builds audit.csv and its skipped page only.
rule nightly:
    input:
        nightly_targets(),
