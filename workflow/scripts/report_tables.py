"""Rule report_tables: what the report shows from evaluating the model, as tables.

All the work is in :mod:`rafi.report.tables` (the model's own predict and fuzzy weights);
this script maps ``snakemake.input`` onto it and writes the tables atomically.
"""

import json

from _glue import read_runs, step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    import pandas as pd

    from rafi.artefact import jsonable, write_csv_atomic, write_parquet_atomic, write_text_atomic
    from rafi.report import tables

    smk = snakemake  # noqa: F821
    runs, frames = read_runs(smk)
    doc = json.loads(open(smk.input.model, encoding="utf-8").read())
    diagnostics = pd.read_csv(smk.input.diagnostics)
    fit = tables.training_fit(doc, runs, frames)
    rmse = tables.training_rmse(fit)
    example = tables.fuzzy_example(doc, diagnostics, runs, frames)
    print(rmse.to_string(index=False), flush=True)
    write_parquet_atomic(fit, smk.output.fit)
    write_csv_atomic(rmse, smk.output.rmse)
    write_text_atomic(smk.output.fuzzy_example, json.dumps(jsonable(example), indent=2) + "\n")
