"""Rule report_figures: one group of the report's figures, drawn ahead of the report as files.

All the work is in :func:`rafi.report.figures.draw_group`; this script maps
``snakemake.input``/``params`` onto it. The group's folder (``output.folder``) gets one
PNG or SVG file per figure and ``index.csv``, read by the report (:mod:`rafi.report.embed`).
"""

from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    from rafi.report.figures import FIGURE_GROUPS, draw_group

    smk = snakemake  # noqa: F821
    group = smk.wildcards.group
    settings = smk.params.settings
    keys = draw_group(
        {k: str(v) for k, v in smk.input.items() if k in FIGURE_GROUPS[group]},
        group,
        smk.output.folder,
        figure_format=settings["report"]["figure_format"],
        coolant_sensors=list(settings["report"]["coolant_sensors"]),
        gates=dict(settings["qualification"]),
        deploy=dict(settings.get("deploy") or {}),
    )
    print(f"{len(keys)} figure(s): {', '.join(keys)}", flush=True)
