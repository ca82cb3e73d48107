"""Rule audit: stack the per-file summaries into results/<machine>/audit.csv."""

import pandas as pd
from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    import rafi.artefact

    smk = snakemake  # noqa: F821
    audit = pd.concat([pd.read_csv(p) for p in smk.input.summaries], ignore_index=True)
    quarantined = audit[audit["status"] != "ok"]
    print(f"{len(audit)} files, {len(quarantined)} quarantined", flush=True)
    for _, row in quarantined.iterrows():
        log.warning("quarantined %s: %s", row["file"], row["reason"])
    rafi.artefact.write_csv_atomic(audit, smk.output.audit)
