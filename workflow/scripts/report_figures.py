"""Rule report_figures: what the report shows, drawn ahead of it, in one process per machine.

1. report_tables (log ``report_tables``): what the report shows from evaluating the model, as
   tables (:mod:`rafi.report.tables`: the model's own predict and fuzzy weights), written
   atomically: training_fit.parquet, training_fit.csv, fuzzy_example.json.
2. report_figures (log ``report_figures``): every figure group
   (:func:`rafi.report.figures.draw_group`), each into its folder (``output.folders``, in the
   order of ``params.groups``): one PNG or SVG file per figure and ``index.csv``, read by the
   report (:mod:`rafi.report.embed`). The pipeline group draws from the tables of step 1.
"""

from _glue import part, step

smk = snakemake  # noqa: F821 - injected by Snakemake

with step(part(smk, "report_tables")) as log:
    from rafi.report.tables import write_report_tables

    fit, rmse, example = write_report_tables(
        smk.input.model,
        smk.input.runs_csv,
        smk.input.runs_parquet,
        smk.input.diagnostics,
        fit_path=smk.output.fit,
        rmse_path=smk.output.rmse,
        example_path=smk.output.fuzzy_example,
    )
    print(f"{len(fit)} training-fit rows from {smk.input.runs_parquet}", flush=True)
    print(rmse.to_string(index=False), flush=True)

with step(part(smk, "report_figures")) as log:
    from rafi.report.figures import FIGURE_GROUPS, draw_group

    paths = {k: str(v) for k, v in smk.input.items()}
    paths.update(training_fit=smk.output.fit, fuzzy_example=smk.output.fuzzy_example)
    for group, folder in zip(smk.params.groups, smk.output.folders, strict=True):
        settings = smk.params.settings[group]
        keys = draw_group(
            {k: paths[k] for k in FIGURE_GROUPS[group] if k in paths},
            group,
            folder,
            figure_format=settings["report"]["figure_format"],
            coolant_sensors=list(settings["report"]["coolant_sensors"]),
            gates=dict(settings["qualification"]),
            deploy=dict(settings.get("deploy") or {}),
        )
        print(f"{group}: {len(keys)} figure(s): {', '.join(keys)}", flush=True)
