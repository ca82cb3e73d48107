"""Rule audit: stack the per-file summaries into results/<machine>/audit.csv."""

import pandas as pd
from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    from rafi.artefact import write_csv_atomic
    from rafi.method.audit import stack_summaries

    smk = snakemake  # noqa: F821
    audit = stack_summaries(pd.read_csv(p) for p in smk.input.summaries)
    quarantined = audit[audit["status"] != "ok"]
    print(f"{len(audit)} files, {len(quarantined)} quarantined", flush=True)
    for file, reason in zip(quarantined["file"], quarantined["reason"]):
        log.warning("quarantined %s: %s", file, reason)
    write_csv_atomic(audit, smk.output.audit)
