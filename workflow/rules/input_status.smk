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


from rafi.ops.duplicates import duplicate_keepers


checkpoint input_status:
    """Usable and rejected raw files of one machine; whether the machine is skipped; its
    audit.csv (the per-file audit summaries stacked)."""
    input:
        # per file: <stem>.summary.csv, and the checks' warnings (audit rows with action
        # warning) in <stem>.audit.csv
        clean=out("clean_dir"),
    output:
        status=out("input_status"),
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
        code=code_version("input_status"),
        machine=lambda w: w.machine,
        # removed when the machine is usable again (a page of an earlier night)
        skipped_page=lambda w: skipped_page_path(w.machine),
        # machine-level checks (docs/raw-format.md, "Checks")
        probe_sign=lambda w: machine_config(w.machine)["checks"]["probe_sign"],
        confirmed=lambda w: machine_config(w.machine)["checks"]["confirmed"],
        # of byte-identical files, a link inside raw/ is the copy that goes
        links=lambda w: raw_links(w.machine),
        # of byte-identical files, the one that stays: the champion's, else the oldest
        # (rafi.ops.duplicates; {} without duplicates)
        keep=lambda w: duplicate_keepers(
            machine_raw_paths(w),
            machine_raw_stamps(w),
            registry_dir(w.machine),
            names=machine_log_names(w),
        ),
    script:
        "../scripts/input_status.py"


rule input_check:
    """Run-level summary: was any raw file quarantined or any machine skipped?"""
    input:
        statuses=[out("input_status", m) for m in MACHINES],
    output:
        check=INPUT_CHECK,
    log:
        f"{LOGS_DIR}/input_check.log",
    conda:
        "../envs/rafi.yaml"
    params:
        code=code_version("input_check"),
    script:
        "../scripts/input_check.py"
