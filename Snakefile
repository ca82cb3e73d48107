# RAFI: raw machine logs -> thermal-compensation model -> qualification report.
#
#   snakemake --cores 2                  # every machine under raw/: tables + reports
#   snakemake --cores 2 tables           # the tables of docs/design.md only
#   snakemake --cores 2 --config on_bad_input=quarantine
#
# Machines are the folders of `raw_dir`; settings are `defaults` deep-merged with
# `machines.<name>` (config.yaml, validated by workflow/schemas/config.schema.yaml).
# Outputs: docs/design.md. Helpers: workflow/rules/common.smk; the steps:
# workflow/rules/pipeline.smk; every other workflow/rules/*.smk is included too
# (report.smk, owned by the report step, makes `all` request the reports).

from pathlib import Path

from snakemake.utils import min_version

min_version("8.20")


configfile: "config.yaml"


include: "workflow/rules/common.smk"


# Helper-only files (`*_common.smk`: functions, no rules - as `snakemake --lint` wants
# them apart) are included before the rule files that use them.
RULE_FILES = sorted(
    (
        p.name
        for p in Path(workflow.basedir, "workflow", "rules").glob("*.smk")
        if p.name != "common.smk"
    ),
    key=lambda name: (not name.endswith("_common.smk"), name),
)
HAVE_REPORT = "report.smk" in RULE_FILES


rule all:
    input:
        all_pipeline_tables(),
        [path for m in MACHINES for path in report_paths(m).values()] if HAVE_REPORT else [],
    default_target: True


# The tables of docs/design.md only (no report), every machine.
rule tables:
    input:
        all_pipeline_tables(),


for rule_file in RULE_FILES:

    include: f"workflow/rules/{rule_file}"
