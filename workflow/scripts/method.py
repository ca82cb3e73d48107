"""Rule method: the method's steps of one machine in one process (docs/design.md, "Outputs").

    runs         clean logs -> runs.csv + runs.parquet
    equilibrium  runs -> equilibrium.csv (time to thermal equilibrium per training run)
    rank         runs -> rank/correlation.csv, key_sensors.csv/.json, collinearity.csv
    fit          runs + key sensors -> fit/coefficients.csv, diagnostics.csv, vif.csv, model.json
                 (with its prediction interval, calibrated on RAFI's whole-run CV residuals)
    validate     model + runs -> validation/summary.csv, validation/residuals.parquet (coverage)

Formerly five rules (one Python start-up each); each step still has its own log file
(logs/<machine>/<step>.log) and reads its inputs from the files the step before it wrote, so
every table is what the separate rules wrote. A step that fails stops the job with its own name
in the message (``RAFI rank (machine=...) failed: ...``).

runs: which files are usable comes from the checkpoint input_status (input_status.json: files
whose clean status is ok and that no machine-level check rejected, e.g. a byte-identical copy);
their sha256 from the per-file audit summaries. A clean table that cannot be read is left out
like a quarantined file (a line in the log), never a failed night.
"""

import functools
import json
from pathlib import Path

from _glue import as_table, part, step, warn


def read_runs(table_path, frame_path):
    """``runs.csv`` and ``runs.parquet`` as the steps after runs read them."""
    import pandas as pd

    table = pd.read_csv(table_path)
    frame = pd.read_parquet(frame_path)
    print(f"read {table_path}: {len(table)} runs; {frame_path}: {len(frame)} rows", flush=True)
    return table, frame


def runs_step(smk, log):
    import pandas as pd

    import rafi.artefact
    from rafi.method.audit import stack_summaries
    from rafi.method.run_checks import check_runs, log_spans
    from rafi.method.runs import find_runs
    from rafi.ops.clean_job import files_in, output_paths
    from rafi.readers.input_spec import log_id
    from rafi.readers.quarantine import read_input_status

    status = read_input_status(smk.input.status)
    audit = stack_summaries(pd.read_csv(p) for p in files_in(smk.input.clean, "summary"))
    usable = audit[(audit["status"] == "ok") & audit["file"].isin(status["usable"])]
    for name in sorted(set(audit.loc[audit["status"] == "ok", "file"]) - set(usable["file"])):
        print(f"left out {name}: rejected by input_status", flush=True)
    sha256 = dict(zip(usable["file"], usable["sha256"]))
    frames = {}
    for name in usable["file"]:
        path = output_paths(smk.input.clean, log_id(Path(name).stem))["parquet"]
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
    # the config against the runs: an entry matching nothing stops here naming its key; a
    # suspicious setting is a warning line (repeated in the end-of-run lines)
    warnings = check_runs(
        table,
        log_spans(frames),
        machine=smk.wildcards.machine,
        runs=cfg,
        reference_rule=smk.params.reference["rule"],
        training_speeds_rpm=smk.params.training_speeds_rpm,
        speed_tolerance_rpm=smk.params.speed_tolerance_rpm,
        all_files=audit["file"].astype(str),
        speed_by_file=smk.params.speed_by_file,
        prior=smk.params.models.get("prior"),
    )
    for warning in warnings:
        warn(smk, "runs", warning)
    rafi.artefact.write_csv_atomic(table, smk.output.table)
    rafi.artefact.write_parquet_atomic(frame, smk.output.frame)


def equilibrium_step(smk, log):
    import rafi.artefact
    from rafi.method.equilibrium import equilibrium_table

    table, frame = read_runs(smk.output.table, smk.output.frame)
    cfg = smk.params.equilibrium
    result = equilibrium_table(
        table,
        frame,
        band_fraction=cfg["band_fraction"],
        plateau_window_s=cfg["plateau_window_s"],
        smooth_window_s=cfg["smooth_window_s"],
    )
    print(f"{len(result)} training runs:\n{result.to_string(index=False)}", flush=True)
    rafi.artefact.write_csv_atomic(result, smk.output.equilibrium)


def rank_step(smk, log):
    import rafi.artefact
    from rafi.method.rank import rank_sensors

    table, frame = read_runs(smk.output.table, smk.output.frame)
    cfg = smk.params.rank
    result = rank_sensors(
        table,
        frame,
        threshold=cfg["threshold"],
        max_key_sensors=cfg["max_key_sensors"],
        scope=cfg["scope"],
        min_coverage=cfg["min_coverage"],
    )
    print(f"key sensors: {result.info.get('sensors')} ({result.info.get('message', '')})", flush=True)
    rafi.artefact.write_csv_atomic(as_table(result.correlation), smk.output.correlation)
    rafi.artefact.write_csv_atomic(as_table(result.key_sensors), smk.output.key_sensors)
    rafi.artefact.write_text_atomic(smk.output.key_sensors_json, rafi.artefact.json_text(result.info))
    collinearity = result.collinearity
    if collinearity.index.name is None and list(collinearity.index) == list(collinearity.columns):
        collinearity = collinearity.rename_axis("sensor")
    rafi.artefact.write_csv_atomic(as_table(collinearity), smk.output.collinearity)


def fit_step(smk, log):
    import rafi.artefact
    from rafi.family.interval_fit import rafi_interval
    from rafi.family.published import PublishedRafi
    from rafi.method.fit import fit_rafi
    from rafi.method.model import save_model

    table, frame = read_runs(smk.output.table, smk.output.frame)
    with open(smk.output.key_sensors_json, encoding="utf-8") as fh:
        key_sensors = json.load(fh)["sensors"]
    cfg = smk.params.fit
    print(f"fit on {key_sensors}, {len(cfg['terms'])} terms, HAC lags {cfg['hac_maxlags']}", flush=True)
    common = {
        "key_sensors": key_sensors,
        "terms": cfg["terms"],
        "hac_maxlags": cfg["hac_maxlags"],
        "reference": smk.params.reference,
        "machine": smk.params.machine,
        "speed_tolerance_rpm": float(smk.params.speed_tolerance_rpm),
    }
    result = fit_rafi(
        table, frame, **common, fuzzy_outside=smk.params.fuzzy["outside"], config=smk.params.model_config
    )
    print(as_table(result.diagnostics).to_string(index=False), flush=True)
    # the prediction interval: RAFI's own whole-run CV residuals on the training runs
    rafi_interval(
        result.model,
        functools.partial(PublishedRafi, **common),
        table,
        frame,
        options=smk.params.models,
        speed_tolerance_rpm=float(smk.params.speed_tolerance_rpm),
        log=lambda m: print(m, flush=True),
    )
    rafi.artefact.write_csv_atomic(as_table(result.coefficients), smk.output.coefficients)
    rafi.artefact.write_csv_atomic(as_table(result.diagnostics), smk.output.diagnostics)
    rafi.artefact.write_csv_atomic(as_table(result.vif), smk.output.vif)
    save_model(result.model, smk.output.model)  # atomic
    print(f"wrote {smk.output.model}", flush=True)


def validate_step(smk, log):
    import rafi.artefact
    from rafi.family.intervals import interval_columns
    from rafi.method.model import load_model
    from rafi.method.validate import validate_runs

    table, frame = read_runs(smk.output.table, smk.output.frame)
    model = load_model(smk.output.model)
    summary, residuals = validate_runs(model, table, frame, bounds=functools.partial(interval_columns, model))
    cols = [
        c
        for c in ("run_id", "speed_rpm", "max_abs_before_um", "max_abs_after_um", "improvement_pct")
        if c in summary.columns
    ]
    print(summary[cols].to_string(index=False), flush=True)
    rafi.artefact.write_csv_atomic(as_table(summary), smk.output.validation_summary)
    rafi.artefact.write_parquet_atomic(residuals, smk.output.residuals)


STEPS = {
    "runs": runs_step,
    "equilibrium": equilibrium_step,
    "rank": rank_step,
    "fit": fit_step,
    "validate": validate_step,
}

if __name__ == "__main__":
    smk = snakemake  # noqa: F821 - injected by Snakemake
    for name, run in STEPS.items():
        with step(part(smk, name)) as log:
            run(smk, log)
