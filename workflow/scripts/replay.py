"""Rule replay: the candidate model, runs.csv and runs.parquet -> deploy/replay.parquet and
deploy/replay_summary.csv (rafi.deploy.replay; docs/deploy.md, section Replay)."""

import json

from _glue import read_runs, step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    from rafi.artefact import write_csv_atomic, write_parquet_atomic
    from rafi.deploy.limits import Limits
    from rafi.deploy.replay import replay_run_ids, replay_runs, replay_summary, summary_frame

    smk = snakemake  # noqa: F821
    table, frame = read_runs(smk)
    with open(smk.input.model, encoding="utf-8") as fh:
        artefact = json.load(fh)
    ids = replay_run_ids(table, smk.params.deploy["replay_roles"])
    replayed = replay_runs(frame, ids, artefact, Limits.from_settings(smk.params.deploy))
    summary = summary_frame(replay_summary(replayed), artefact=artefact)
    print(
        f"replayed {len(ids)} run(s) with {artefact['kind']} {artefact.get('model_id', '')[:12]}", flush=True
    )
    print(summary.T.to_string(), flush=True)
    write_parquet_atomic(replayed, smk.output.table)
    write_csv_atomic(summary, smk.output.summary)
