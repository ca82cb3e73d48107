# The RAFI steps (docs/design.md, "Outputs under results/<machine>/"):
#
#   raw/<machine>/<stem>.<ext>
#     -> clean (per machine, files from a cache unless changed) -> runs -> equilibrium
#                 |             \-> rank -> fit -> validate
#                 \-> audit.csv (written by the checkpoint input_status, input_status.smk)
#
# runs reads the per-file audit summaries themselves (audit.csv is their concatenation), so
# audit.csv is not on the way to the model. runs ... validate are ONE job per machine (rule
# method, one log per step): docs/cluster.md, "Jobs per machine", says what that costs in
# incrementality and why it is worth it.
#
# Every config value a script uses arrives through `params:` (functions of the
# machine wildcard over machine_config()), so changing one value re-runs exactly the
# rules that use it and their downstream (rerun trigger `params`). So does the code a
# script runs: its digest is the param `code` (code_version() in common.smk).


rule clean:
    """Read, check and clean every raw log of a machine onto the regular sample grid, in one
    job (rafi.ops.clean_job): results/<machine>/clean/<stem>.parquet, .audit.csv, .summary.csv.

    Snakemake re-runs it when a raw file is added, removed or changed (its content hash is the
    param raw_stamps), or a setting or the code changed; it then cleans every file of the
    machine again (docs/cluster.md, "Jobs per machine"). A file that cannot be used: with
    on_bad_input=fail the job fails with the message (file, line, column); with quarantine it
    gets an empty table and a quarantined audit row with the message. on_bad_input is read
    from the run's config, not a param, so switching modes re-runs nothing; common.smk stops a
    fail-mode run at planning when an earlier run quarantined a file that is still there.
    """
    input:
        raw=machine_raw_inputs,
    output:
        folder=directory(out("clean_dir")),
    log:
        log_path("clean"),
    benchmark:
        bench_path("clean")
    conda:
        "../envs/rafi.yaml"
    params:
        code=code_version("clean"),
        raw_paths=machine_raw_paths,
        # the logs that are not a whole file: a sheet of a workbook, a file with its partner
        raw_parts=machine_raw_parts,
        # content hashes: a file edited with its size and mtime kept re-runs the job
        raw_stamps=machine_raw_stamps,
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


rule method:
    """The method's steps of one machine in one job (workflow/scripts/method.py): split the clean
    logs into runs (roles, rises from the reference state) -> time to thermal equilibrium
    (paper Table 1) -> Pearson ranking and key sensors -> one OLS regression per training speed
    (the model artefact) -> the fuzzy-blended model on every validation run. One log per step."""
    input:
        clean=out("clean_dir"),
        # the usable files (machine-level checks reject duplicates, reversed probes); ancient:
        # confirming a warning rewrites it but changes no usable file (a changed
        # checks.probe_sign re-runs the job through its param below)
        status=ancient(out("input_status")),
    output:
        # runs
        table=out("runs_csv"),
        frame=out("runs_parquet"),
        # equilibrium
        equilibrium=out("equilibrium"),
        # rank
        correlation=out("correlation"),
        key_sensors=out("key_sensors"),
        key_sensors_json=out("key_sensors_json"),
        collinearity=out("collinearity"),
        # fit
        coefficients=out("coefficients"),
        diagnostics=out("diagnostics"),
        vif=out("vif"),
        model=out("model"),
        # validate
        validation_summary=report(
            out("validation_summary"),
            caption="../report/validation_summary.rst",
            category="Validation",
            subcategory="{machine}",
            labels={"machine": "{machine}", "table": "validation/summary.csv"},
        ),
        residuals=out("residuals"),
    log:
        runs=log_path("runs"),
        equilibrium=log_path("equilibrium"),
        rank=log_path("rank"),
        fit=log_path("fit"),
        validate=log_path("validate"),
    benchmark:
        bench_path("method")
    conda:
        "../envs/rafi.yaml"
    params:
        code=code_version("method"),
        # runs
        training_speeds_rpm=lambda w: machine_config(w.machine)["training_speeds_rpm"],
        speed_tolerance_rpm=lambda w: machine_config(w.machine)["speed_tolerance_rpm"],
        runs=lambda w: machine_config(w.machine)["runs"],
        reference=lambda w: machine_config(w.machine)["reference"],
        probe_sign=lambda w: machine_config(w.machine)["checks"]["probe_sign"],
        # its globs must match a file (rafi.method.run_checks)
        speed_by_file=lambda w: machine_config(w.machine)["input"]["speed"]["constant_rpm_by_file"],
        # equilibrium, rank
        equilibrium=lambda w: machine_config(w.machine)["equilibrium"],
        rank=lambda w: machine_config(w.machine)["rank"],
        # fit
        machine=lambda w: w.machine,
        fit=lambda w: machine_config(w.machine)["fit"],
        fuzzy=lambda w: machine_config(w.machine)["fuzzy"],
        # the prediction interval of model.json: RAFI's whole-run CV (models: cv, interval_*)
        models=lambda w: machine_config(w.machine)["models"],
        # settings that shaped the model, stored in model.json for provenance
        model_config=lambda w: model_provenance(w.machine),
    script:
        "../scripts/method.py"
