# RAFI: raw machine logs -> thermal-compensation model -> qualification report.
#
#   snakemake --cores 2                  # every machine under raw/: tables + reports
#   snakemake --cores 2 tables           # the tables of docs/design.md only
#   snakemake --cores 2 --config on_bad_input=quarantine   # carry on past a bad raw file
#
# Machines are the folders of `raw_dir` (a machine with several probes: one unit per probe,
# <machine>@<probe>). Every setting has its default in one place, rafi/contract/ (RUN_SETTINGS in
# run.py, MACHINE_SETTINGS in machine.py, INPUT_DEFAULTS in input.py), which rafi/settings.py
# merges with `defaults:` and `machines: <name>:` of config.yaml (rafi.settings.machine_settings).
# Outputs: docs/design.md. Helpers (functions only): workflow/rules/common.smk; the
# method's steps: pipeline.smk; the model family: compare.smk; champion/challenger:
# registry.smk; the replay of recorded runs through the compensator with its limits (the
# model on the machine, offline): deploy.smk; the qualification report: report.smk; the fleet
# overview reports/index.html: fleet.smk; which
# machines have a usable raw file (a machine without one is skipped, the others carry on):
# input_status.smk.

from snakemake.utils import min_version

min_version("8.20")


configfile: "config.yaml"


include: "workflow/rules/common.smk"
include: "workflow/rules/report_common.smk"
include: "workflow/rules/pipeline.smk"
include: "workflow/rules/input_status.smk"
include: "workflow/rules/compare.smk"
include: "workflow/rules/registry.smk"
include: "workflow/rules/deploy.smk"
include: "workflow/rules/report.smk"
include: "workflow/rules/fleet.smk"


rule all:
    default_target: True
    input:
        all_targets(),


# The tables of docs/design.md only (no comparison, registry or report), every machine.
rule tables:
    input:
        all_pipeline_tables(),


# A run that rejected input (a quarantined file, a skipped machine) says so at its end; then one
# line per machine: PASS / FAIL / skipped, the model offered, why it failed, the report
# (docs/operations.md, "End-of-run lines"); then the one-line message of every failed job.
onsuccess:
    say_rejected_input()
    say_outcomes()


onerror:
    say_rejected_input()
    say_outcomes(failed=True)
    say_failures()
