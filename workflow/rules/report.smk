# The qualification report: results/<machine>/ tables -> reports/<machine>/qualification.{html,pdf}.
#
# One jinja2 template renders the HTML; WeasyPrint renders the PDF from the same HTML
# string (rafi.report), so the two never disagree. Uses helpers of common.smk:
# out(), machine_config(), report_paths(), log_path(), bench_path(), rafi_code(), RAFI_DIR.
#
# Besides the tables it shows the model comparison (comparison/summary.csv, per_run.csv,
# cv.csv, residuals.parquet) and the registry decision (registry/decision.json and
# registry/comparison.csv); inputs: report_inputs() in common.smk.
# The kind/created of a registered model id is read from registry/models/<id>.json (not an
# input: those files are registry side effects, immutable and named by their content hash,
# so decision.json - an input - already pins them).


rule report:
    """Qualification report of one machine: verdict (model on the machine + RAFI as published),
    data, equilibrium, ranking, models, fuzzy blending, validation, registry decision, model
    comparison, open choices, provenance (HTML + PDF, figures embedded)."""
    input:
        unpack(report_inputs),
    output:
        html=report_paths()["html"],
        pdf=report_paths()["pdf"],
    params:
        settings=lambda w: machine_config(w.machine),
        report=lambda w: report_settings(w.machine),
        paths={"raw_dir": str(config["raw_dir"]), "results_dir": RESULTS_DIR,
               "reports_dir": REPORTS_DIR},
    log:
        log_path("report"),
    benchmark:
        bench_path("report")
    conda:
        "../envs/rafi.yaml"
    script:
        "../scripts/report.py"
