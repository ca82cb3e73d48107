# The qualification report: results/<machine>/ tables -> reports/<machine>/qualification.{html,pdf}.
#
# The report job only presents: every number it shows is read from a table a rule wrote and
# every figure is a file of report_figures; it evaluates no model and draws nothing.
#   report_figures  one job per machine (after method, compare and replay), two steps:
#                   report_tables: what the report shows from evaluating the model
#                   (rafi.report.tables, with RafiModel.predict and rafi.method.fuzzy):
#                   results/<machine>/report/training_fit.parquet, training_fit.csv,
#                   fuzzy_example.json; then the figures of every group (rafi.report.figures:
#                   pipeline, comparison, replay), each to the folder
#                   results/<machine>/report/figures/<group>/ (directory(): which figures a
#                   group has depends on the data) with one PNG or SVG file per figure
#                   (report.figure_format) and index.csv (key,file)
#   report          the HTML (jinja2) and the PDF (WeasyPrint, from the same HTML string),
#                   figures embedded from the files (rafi.report.render)
#
# Besides the tables it shows the model comparison (comparison/summary.csv, per_run.csv,
# cv.csv) and the registry decision (registry/decision.json and registry/comparison.csv);
# inputs: report_inputs() in common.smk. The kind/created of a registered model id is read
# from registry/models/<id>.json (not an input: those files are registry side effects,
# immutable and named by their content hash, so decision.json - an input - already pins them).
# Uses helpers of common.smk: out(), machine_config(), report_paths(), log_path(),
# bench_path(), code_version(), and of report_common.smk: report_inputs(),
# report_figure_inputs(), report_figure_settings().


rule report_figures:
    """What the report shows, drawn ahead of it, in one job per machine: first the tables from
    evaluating the model (each training speed's fit on its own training runs, series + RMSE, and
    the worked example of the fuzzy blending; formerly rule report_tables), then the figures of
    every group (one file per figure + index.csv in the group's folder)."""
    input:
        unpack(report_figure_inputs),
    output:
        fit=out("training_fit"),
        rmse=out("training_fit_rmse"),
        fuzzy_example=out("fuzzy_example"),
        folders=[directory(out("figures", group=group)) for group in contract.FIGURE_GROUPS],
    log:
        report_tables=log_path("report_tables"),
        report_figures=log_path("report_figures"),
    benchmark:
        bench_path("report_figures")
    conda:
        "../envs/rafi.yaml"
    params:
        code=code_version("report_figures"),
        groups=list(contract.FIGURE_GROUPS),
        settings=report_figure_settings,
    script:
        "../scripts/report_figures.py"


rule report:
    """Qualification report of one machine: verdict (model on the machine + RAFI as published),
    data, equilibrium, ranking, models, fuzzy blending, validation, registry decision, model
    comparison, open choices, provenance (HTML + PDF, figures embedded)."""
    input:
        unpack(report_inputs),
    output:
        html=report(
            report_paths()["html"],
            caption="../report/qualification.rst",
            category="Qualification",
            subcategory="{machine}",
            labels={"machine": "{machine}", "file": "qualification.html"},
        ),
        pdf=report(
            report_paths()["pdf"],
            caption="../report/qualification_pdf.rst",
            category="Qualification",
            subcategory="{machine}",
            labels={"machine": "{machine}", "file": "qualification.pdf"},
        ),
    log:
        log_path("report"),
    benchmark:
        bench_path("report")
    conda:
        "../envs/rafi.yaml"
    params:
        code=code_version("report"),
        settings=lambda w: machine_config(w.machine),
        # the key of config.yaml that sets the probe's sign, or None: the default (section provenance)
        sign_key=lambda w: _probe_sign_key(config, w.machine),
        figure_groups=list(contract.FIGURE_GROUPS),
        paths={"raw_dir": str(RAW_DIR), "results_dir": RESULTS_DIR, "reports_dir": REPORTS_DIR},
        # not an output: compiled templates shared by the run's report jobs (keyed by the sources)
        template_cache=f"{RESULTS_DIR}/{contract.RUN_FILES['template_cache']}",
    script:
        "../scripts/report.py"


rule skipped_report:
    """Page of a machine skipped for want of a usable raw file (machine-level quarantine, see
    input_status.smk): the rejected files and why, in place of the qualification report."""
    input:
        status=out("input_status"),
        audit=out("audit"),
    output:
        html=skipped_page_path(),
    log:
        log_path("skipped_report"),
    conda:
        "../envs/rafi.yaml"
    params:
        code=code_version("skipped_report"),
    script:
        "../scripts/skipped_report.py"


# A machine with several probes (input.probes): one page with every probe's verdict, then each
# probe's own report (the PDF holds their pages). Its folder name is a machine's, so it would
# also match rule report's output: the ruleorder says which rule makes it.
ruleorder: probes_report > report


rule probes_report:
    """Qualification report of a machine with several probes: every probe's verdict on page 1,
    a section per probe, then each probe's own report."""
    input:
        unpack(probes_report_inputs),
    output:
        html=report(
            report_paths("{folder}")["html"],
            caption="../report/probes.rst",
            category="Qualification",
            subcategory="{folder}",
            labels={"machine": "{folder}", "file": "qualification.html"},
        ),
        pdf=report_paths("{folder}")["pdf"],
    log:
        log_path("probes_report", "{folder}"),
    wildcard_constraints:
        folder=MULTI_PROBE_FOLDER,
    conda:
        "../envs/rafi.yaml"
    params:
        code=code_version("probes_report"),
        probes=lambda w: PROBES[w.folder],
        settings=lambda w: {p: machine_config(unit_name(w.folder, p)) for p in PROBES[w.folder]},
        machine_settings=lambda w: machine_config(w.folder),
        sign_keys=lambda w: {p: _probe_sign_key(config, unit_name(w.folder, p)) for p in PROBES[w.folder]},
    script:
        "../scripts/probes_report.py"
