# The RAFI steps (docs/design.md, "Outputs under results/<machine>/"):
#
#   raw/<machine>/<stem>.<ext>
#     -> clean (per file) -> runs -> equilibrium
#                 |             \-> rank -> fit -> validate
#                 \-> audit (per machine)
#
# runs reads the per-file audit summaries themselves (audit.csv is their concatenation), so
# audit is not on the way to the model: it runs beside runs.
#
# Every config value a script uses arrives through `params:` (functions of the
# machine wildcard over machine_config()), so changing one value re-runs exactly the
# rules that use it and their downstream (rerun trigger `params`). The rafi modules a
# script calls are `input:` via rafi_code(), so editing them re-runs the rule too.


rule clean:
    """Read, check and clean one raw log onto the regular sample grid.

    A file that cannot be used (RawFormatError): with on_bad_input=fail the job fails with
    the message (file, line, column); with quarantine it gets an empty table and a
    quarantined audit row with the message. on_bad_input is read from the run's config, not
    a param, so switching modes re-runs nothing; common.smk stops a fail-mode run at
    planning when an earlier run quarantined a file that is still there.
    """
    input:
        raw=raw_file,
        code=rafi_code("clean"),
        glue=script_helpers(),
    output:
        parquet=out("clean_parquet"),
        audit=out("clean_audit"),
        summary=out("clean_summary"),
    log:
        log_path("clean/{stem}"),
    benchmark:
        bench_path("clean/{stem}")
    conda:
        "../envs/rafi.yaml"
    params:
        raw_path=raw_path,
        raw_stamp=raw_stamp,
        input_spec=lambda w: machine_config(w.machine)["input"],
        sample_period_s=lambda w: machine_config(w.machine)["sample_period_s"],
        clean=lambda w: machine_config(w.machine)["clean"],
        # plausibility checks (rafi.readers.checks.check_file, docs/raw-format.md "Checks")
        checks=lambda w: {
            "min_run_s": machine_config(w.machine)["runs"]["min_run_s"],
            "sample_period_s": machine_config(w.machine)["sample_period_s"],
            "open_circuit_values": machine_config(w.machine)["clean"]["open_circuit_values"],
            "training_speeds_rpm": machine_config(w.machine)["training_speeds_rpm"],
            "speed_tolerance_rpm": machine_config(w.machine)["speed_tolerance_rpm"],
            "machine": w.machine,
        },
    script:
        "../scripts/clean.py"


rule audit:
    """Stack the per-file audit summaries of a machine into results/<machine>/audit.csv."""
    input:
        summaries=clean_files("clean_summary"),
        code=rafi_code("audit"),
        glue=script_helpers(),
    output:
        audit=out("audit"),
    log:
        log_path("audit"),
    conda:
        "../envs/rafi.yaml"
    script:
        "../scripts/audit.py"


rule runs:
    """Split the clean logs into runs, assign roles and compute rises from the reference state."""
    input:
        clean=clean_files("clean_parquet"),
        summaries=clean_files("clean_summary"),
        # the usable files (machine-level checks reject duplicates, reversed probes); ancient:
        # confirming a warning rewrites it but changes no usable file (a changed
        # checks.probe_sign re-runs runs through its param below)
        status=ancient(input_status_path()),
        code=rafi_code("runs"),
        glue=script_helpers(),
    output:
        table=out("runs_csv"),
        frame=out("runs_parquet"),
    log:
        log_path("runs"),
    benchmark:
        bench_path("runs")
    conda:
        "../envs/rafi.yaml"
    params:
        training_speeds_rpm=lambda w: machine_config(w.machine)["training_speeds_rpm"],
        speed_tolerance_rpm=lambda w: machine_config(w.machine)["speed_tolerance_rpm"],
        runs=lambda w: machine_config(w.machine)["runs"],
        reference=lambda w: machine_config(w.machine)["reference"],
        probe_sign=lambda w: machine_config(w.machine)["checks"]["probe_sign"],
    script:
        "../scripts/runs.py"


rule equilibrium:
    """Time to thermal equilibrium of every training run (paper Table 1)."""
    input:
        table=out("runs_csv"),
        frame=out("runs_parquet"),
        code=rafi_code("equilibrium"),
        glue=script_helpers(),
    output:
        equilibrium=out("equilibrium"),
    log:
        log_path("equilibrium"),
    benchmark:
        bench_path("equilibrium")
    conda:
        "../envs/rafi.yaml"
    params:
        equilibrium=lambda w: machine_config(w.machine)["equilibrium"],
    script:
        "../scripts/equilibrium.py"


rule rank:
    """Pearson ranking of the sensors against the displacement; choose the key sensors."""
    input:
        table=out("runs_csv"),
        frame=out("runs_parquet"),
        code=rafi_code("rank"),
        glue=script_helpers(),
    output:
        correlation=out("correlation"),
        key_sensors=out("key_sensors"),
        key_sensors_json=out("key_sensors_json"),
        collinearity=out("collinearity"),
    log:
        log_path("rank"),
    benchmark:
        bench_path("rank")
    conda:
        "../envs/rafi.yaml"
    params:
        rank=lambda w: machine_config(w.machine)["rank"],
    script:
        "../scripts/rank.py"


rule fit:
    """One OLS regression per training speed on the key sensors' rises; the model artefact."""
    input:
        table=out("runs_csv"),
        frame=out("runs_parquet"),
        key_sensors=out("key_sensors_json"),
        code=rafi_code("fit"),
        glue=script_helpers(),
    output:
        coefficients=out("coefficients"),
        diagnostics=out("diagnostics"),
        vif=out("vif"),
        model=out("model"),
    log:
        log_path("fit"),
    benchmark:
        bench_path("fit")
    conda:
        "../envs/rafi.yaml"
    params:
        machine=lambda w: w.machine,
        fit=lambda w: machine_config(w.machine)["fit"],
        reference=lambda w: machine_config(w.machine)["reference"],
        fuzzy=lambda w: machine_config(w.machine)["fuzzy"],
        speed_tolerance_rpm=lambda w: machine_config(w.machine)["speed_tolerance_rpm"],
        # settings that shaped the model, stored in model.json for provenance
        model_config=lambda w: model_provenance(w.machine),
    script:
        "../scripts/fit.py"


rule validate:
    """Apply the fuzzy-blended model to every validation run: residuals and improvement."""
    input:
        table=out("runs_csv"),
        frame=out("runs_parquet"),
        model=out("model"),
        code=rafi_code("validate"),
        glue=script_helpers(),
    output:
        summary=report(
            out("validation_summary"),
            caption="../report/validation_summary.rst",
            category="Validation",
            subcategory="{machine}",
            labels={"machine": "{machine}", "table": "validation/summary.csv"},
        ),
        residuals=out("residuals"),
    log:
        log_path("validate"),
    benchmark:
        bench_path("validate")
    conda:
        "../envs/rafi.yaml"
    script:
        "../scripts/validate.py"
