# The fleet overview (docs/operations.md, "rafi status"): reports/index.html, every machine's
# model in service, last decision, worst validation residual, drift, quarantined files and a
# link to its page, machines that need attention first (rafi.ops.fleet, rafi.report.fleet_page).
#
#   every machine's nightly targets (tables, decision, report or skipped page), and the page of
#   each machine with several probes (rule probes_report) when the reports are built
#     -> fleet_index   reports/index.html
#
# Part of `all`, and of `nightly` when the night covers every machine (common.smk); a
# night for some machines (`rafi nightly --machine M`) rewrites the page itself when it ends,
# and so does a night whose pipeline failed (this rule then does not run).


rule fleet_index:
    """Every machine's state on one page, machines that need attention first."""
    input:
        # one input function per machine (checkpoint input_status): its nightly targets
        [machine_targets(m, "nightly") for m in MACHINES],
        # a machine with several probes: its own page, which the overview links (with the reports)
        [probes_report_targets(f) for f in sorted(PROBES)] if _settings.truthy(RUN["nightly_report"]) else [],
    output:
        html=report(
            FLEET_INDEX,
            caption="../report/fleet_index.rst",
            category="Fleet",
            labels={"file": "index.html"},
        ),
    log:
        f"{LOGS_DIR}/fleet_index.log",
    conda:
        "../envs/rafi.yaml"
    params:
        code=code_version("fleet_index"),
        raw_dir=str(RAW_DIR),
        results_dir=RESULTS_DIR,
        reports_dir=lambda w, output: os.path.dirname(output.html),
        machines=MACHINES,
    script:
        "../scripts/fleet_index.py"
