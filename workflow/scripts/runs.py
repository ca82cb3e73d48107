"""Rule runs: clean logs of a machine -> runs.csv + runs.parquet.

Which files are usable comes from the checkpoint input_status (input_status.json: files whose
clean status is ok and that no machine-level check rejected, e.g. a byte-identical copy); their
sha256 from the per-file audit summaries. A clean table that cannot be read is left out like a
quarantined file (a line in the log), never a failed night.
"""

from pathlib import Path

import pandas as pd
from _glue import step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    import rafi.artefact
    from rafi.method.audit import stack_summaries
    from rafi.method.runs import find_runs
    from rafi.readers.input_spec import log_id
    from rafi.readers.quarantine import read_input_status

    smk = snakemake  # noqa: F821
    status = read_input_status(smk.input.status)
    audit = stack_summaries(pd.read_csv(p) for p in smk.input.summaries)
    usable = audit[(audit["status"] == "ok") & audit["file"].isin(status["usable"])]
    for name in sorted(set(audit.loc[audit["status"] == "ok", "file"]) - set(usable["file"])):
        print(f"left out {name}: rejected by input_status", flush=True)
    sha256 = dict(zip(usable["file"], usable["sha256"]))
    by_stem = {Path(p).name.removesuffix(".parquet"): p for p in smk.input.clean}
    frames = {}
    for name in usable["file"]:
        path = by_stem[log_id(Path(name).stem)]
        try:
            frames[name] = pd.read_parquet(path)
        except Exception as exc:  # noqa: BLE001 - an unreadable clean table quarantines its file
            log.warning(
                "left out %s as quarantined: its clean table %s cannot be read (%s: %s)",
                name,
                path,
                type(exc).__name__,
                " ".join(str(exc).split())[:300],
            )
            continue
        print(f"read clean {name}: {len(frames[name])} rows", flush=True)
    if not frames:
        # a run builds nothing of a skipped machine beyond its audit (input_status.smk): only
        # a target named on the command line (runs.csv, model.json, ...) gets here
        raise RuntimeError(
            f"no usable raw file for machine {smk.wildcards.machine}: all {len(audit)} "
            "quarantined or rejected (see audit.csv, input_status.json); the machine is skipped "
            "(skipped.html) and has no runs, model or report to build"
        )
    cfg = smk.params.runs
    table, frame = find_runs(
        frames,
        sha256,
        training_speeds_rpm=smk.params.training_speeds_rpm,
        speed_tolerance_rpm=smk.params.speed_tolerance_rpm,
        idle_below_rpm=cfg["idle_below_rpm"],
        min_run_s=cfg["min_run_s"],
        min_constant_s=cfg["min_constant_s"],
        overrides=cfg["overrides"],
        max_leading_rest_s=cfg["max_leading_rest_s"],
        windows=cfg["windows"],
        idle_training=cfg["idle_training"],
        allow_training_after_validation=cfg["allow_training_after_validation"],
        reference_rule=smk.params.reference["rule"],
        reference_window_s=smk.params.reference["window_s"],
    )
    print(f"{len(table)} runs; roles: {table['role'].value_counts().to_dict()}", flush=True)
    rafi.artefact.write_csv_atomic(table, smk.output.table)
    rafi.artefact.write_parquet_atomic(frame, smk.output.frame)
