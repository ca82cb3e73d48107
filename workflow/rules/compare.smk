# Model family comparison (docs/models.md): RAFI as published against rafi_linear,
# ridge_global, dynamic and grey_box on the same validation runs and gates, and the plain ridge
# (temperature_ridge) always, offered only when enabled; whole-run CV on the
# training runs only chooses the champion (best_model.json, passing or not); every model's gates
# per validation run go to verdict.csv (the report reads them, it judges nothing).
#
# Uses the helpers of common.smk (machine_config, out, log_path, bench_path, code_version). Settings: the machine's complete `models:` and
# `qualification:` sections (rafi.settings.machine_settings: every key present); the gates are
# the ones rule decide judges with. Fit times go to the log, never into the tables.


rule compare:
    """Fit the model family on the training runs, validate, cross-validate, pick the champion."""
    input:
        table=out("runs_csv"),
        frame=out("runs_parquet"),
        key_sensors=out("key_sensors_json"),
        model=out("model"),
    output:
        summary=report(
            out("comparison"),
            caption="../report/comparison_summary.rst",
            category="Model comparison",
            subcategory="{machine}",
            labels={"machine": "{machine}", "table": "comparison/summary.csv"},
        ),
        per_run=report(
            out("comparison_per_run"),
            caption="../report/comparison_per_run.rst",
            category="Model comparison",
            subcategory="{machine}",
            labels={"machine": "{machine}", "table": "comparison/per_run.csv"},
        ),
        residuals=out("comparison_residuals"),
        best_model=out("best_model"),
        cv=out("comparison_cv"),
        verdict=out("comparison_verdict"),
        since_change=out("comparison_since_change"),
    log:
        log_path("compare"),
    benchmark:
        bench_path("compare")
    conda:
        "../envs/rafi.yaml"
    params:
        code=code_version("compare"),
        # not an output: the CV rows memoised by content (rafi.family.cv_memo)
        cv_memo=lambda w: out("cv_memo", w.machine),
        machine=lambda w: w.machine,
        models=lambda w: machine_config(w.machine)["models"],
        fit=lambda w: machine_config(w.machine)["fit"],
        reference=lambda w: machine_config(w.machine)["reference"],
        speed_tolerance_rpm=lambda w: machine_config(w.machine)["speed_tolerance_rpm"],
        gates=lambda w: machine_config(w.machine)["qualification"],
        # models.prior resolved while planning (the registry is read, never an input)
        prior=compare_prior,
    script:
        "../scripts/compare.py"
