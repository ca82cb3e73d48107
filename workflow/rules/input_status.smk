# Machine-level quarantine (docs/operations.md, "A skipped machine"): which machines have a
# usable raw file. Only known after the clean jobs, so it is a checkpoint per machine; the final
# targets of a machine (common.smk: machine_targets) depend on it:
#
#   clean/<stem>.summary.csv + .audit.csv (every file of the machine)
#     -> input_status (checkpoint)  results/<machine>/input_status.json (+ machine-level checks:
#          duplicate content, probe sign; every warning with `confirmed` from checks.confirmed)
#          usable  -> the machine's tables, comparison, decision and report as usual
#          skipped -> audit.csv and reports/<machine>/skipped.html only (report.smk)
#     -> input_check                results/input_check.json (every machine: was input rejected?)
#
# With on_bad_input=fail a bad file stops its clean job, so no machine is ever skipped.


checkpoint input_status:
    """Usable and rejected raw files of one machine; whether the machine is skipped; its
    audit.csv (the per-file audit summaries stacked)."""
    input:
        # per file: <stem>.summary.csv, and the checks' warnings (audit rows with action
        # warning) in <stem>.audit.csv
        clean=clean_dir(),
        code=rafi_code("input_status"),
        glue=script_helpers(),
    output:
        status=input_status_path(),
        # the per-file audit summaries stacked (was rule audit: one job less per machine)
        audit=report(
            out("audit"),
            caption="../report/audit.rst",
            category="Data audit",
            subcategory="{machine}",
            labels={"machine": "{machine}", "table": "audit.csv"},
        ),
    log:
        log_path("input_status"),
    conda:
        "../envs/rafi.yaml"
    params:
        machine=lambda w: w.machine,
        # removed when the machine is usable again (a page of an earlier night)
        skipped_page=lambda w: skipped_page_path(w.machine),
        # machine-level checks (docs/raw-format.md, "Checks")
        probe_sign=lambda w: machine_config(w.machine)["checks"]["probe_sign"],
        confirmed=lambda w: machine_config(w.machine)["checks"]["confirmed"],
        # of byte-identical files, a link inside raw/ is the copy that goes
        links=lambda w: raw_links(w.machine),
    script:
        "../scripts/input_status.py"


rule input_check:
    """Run-level summary: was any raw file quarantined or any machine skipped?"""
    input:
        statuses=[input_status_path(m) for m in MACHINES],
        code=rafi_code("input_check"),
        glue=script_helpers(),
    output:
        check=INPUT_CHECK,
    log:
        f"{LOGS_DIR}/input_check.log",
    conda:
        "../envs/rafi.yaml"
    script:
        "../scripts/input_check.py"
