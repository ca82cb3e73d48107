"""Rule report_figures: one group of the report's figures, drawn ahead of the report.

All the work is in :func:`rafi.report.build.build_figures` (the report's own section code on the
group's inputs); this script maps ``snakemake.input``/``params`` onto it and writes the
encoded figures atomically as JSON (read back by the report with ``rafi.report.build.load_figures``).
"""

import json

from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    from rafi.artefact import write_text_atomic
    from rafi.report import build as report

    smk = snakemake  # noqa: F821
    group = smk.wildcards.group
    paths = {k: str(v) for k, v in smk.input.items() if k in report.FIGURE_GROUPS[group]}
    doc = report.build_figures(
        paths,
        group,
        figure_format=smk.params.figure_format,
        coolant_sensors=list(smk.params.coolant_sensors),
        gates=dict(smk.params.gates),
    )
    write_text_atomic(smk.output.figures, json.dumps(doc, sort_keys=True) + "\n")
    print(f"{len(doc['figures'])} figure(s): {', '.join(doc['figures'])}", flush=True)
