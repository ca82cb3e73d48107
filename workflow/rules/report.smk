# The qualification report: results/<machine>/ tables -> reports/<machine>/qualification.{html,pdf}.
#
# One jinja2 template renders the HTML; WeasyPrint renders the PDF from the same HTML
# string (rafi.report.build), so the two never disagree. Uses helpers of common.smk:
# out(), machine_config(), report_paths(), log_path(), bench_path(), rafi_code(), RAFI_DIR,
# report_figures_path(), report_figure_inputs(), report_figure_gates().
#
# The figures are drawn ahead, by group, as soon as their inputs exist (rafi.report.build.build_figures):
#   pipeline    the method's figures: after validate, on the core compare leaves free
#   comparison  the model family's figures: after compare, beside decide
# so the report job itself only renders the HTML and the PDF (it draws a figure only if the
# one drawn ahead does not fit, e.g. the model on the machine is not the family's champion).
#
# Besides the tables it shows the model comparison (comparison/summary.csv, per_run.csv,
# cv.csv, residuals.parquet) and the registry decision (registry/decision.json and
# registry/comparison.csv); inputs: report_inputs() in common.smk.
# The kind/created of a registered model id is read from registry/models/<id>.json (not an
# input: those files are registry side effects, immutable and named by their content hash,
# so decision.json - an input - already pins them).


rule report_figures:
    """Figures of one group of the report, drawn ahead of it (encoded, in one JSON file)."""
    input:
        unpack(report_figure_inputs),
    output:
        figures=report_figures_path(),
    log:
        log_path("report_figures_{group}"),
    benchmark:
        bench_path("report_figures_{group}")
    wildcard_constraints:
        group="|".join(REPORT_FIGURE_GROUPS),
    conda:
        "../envs/rafi.yaml"
    params:
        figure_format=lambda w: report_settings(w.machine)["figure_format"],
        coolant_sensors=lambda w: report_settings(w.machine)["coolant_sensors"],
        gates=report_figure_gates,
    script:
        "../scripts/report_figures.py"


rule report:
    """Qualification report of one machine: verdict (model on the machine + RAFI as published),
    data, equilibrium, ranking, models, fuzzy blending, validation, registry decision, model
    comparison, open choices, provenance (HTML + PDF, figures embedded)."""
    input:
        unpack(report_inputs),
    output:
        html=report_paths()["html"],
        pdf=report_paths()["pdf"],
    log:
        log_path("report"),
    benchmark:
        bench_path("report")
    conda:
        "../envs/rafi.yaml"
    params:
        settings=lambda w: machine_config(w.machine),
        report=lambda w: report_settings(w.machine),
        paths={"raw_dir": str(config["raw_dir"]), "results_dir": RESULTS_DIR, "reports_dir": REPORTS_DIR},
    script:
        "../scripts/report.py"
