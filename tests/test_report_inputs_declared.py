"""Every result table the report job reads is a declared input of rule ``report``.

The report job receives only its declared inputs (``workflow/scripts/report.py`` passes
``snakemake.input``); a table the section code reads but the rule does not declare is ``None`` in
the pipeline's report while every unit test (which loads the whole results folder) sees it. This
scans the report's section code for the result names it reads from ``res``.
"""

from __future__ import annotations

import re
from pathlib import Path

from rafi import contract

ROOT = Path(__file__).resolve().parents[1]
#: Modules of rule report_figures (their inputs are report_figure_inputs in report_common.smk).
FIGURE_JOB = {"figures.py", "tables.py", "replay_plot.py", "plots.py"}
READ = re.compile(r"\bres(?:\.get\(|\[)\"([a-z_]+)\"")


def _names_read_by_the_report_job() -> dict:
    read = {}
    for path in sorted((ROOT / "rafi" / "report").glob("*.py")):
        if path.name in FIGURE_JOB:
            continue
        for name in READ.findall(path.read_text(encoding="utf-8")):
            if name in contract.RESULT_FILES:  # res[...] of a frame's column is not a result
                read.setdefault(name, set()).add(path.name)
    return read


def test_every_result_the_report_reads_is_an_input_of_rule_report():
    declared = set(contract.REPORT_REQUIRED) | set(contract.REPORT_OPTIONAL)
    read = _names_read_by_the_report_job()
    assert {"replay", "comparison_residuals", "comparison_cv"} <= set(read)  # the scan sees them
    missing = {name: sorted(files) for name, files in read.items() if name not in declared}
    assert not missing, f"read by the report but not inputs of rule report: {missing}"
