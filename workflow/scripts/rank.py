"""Rule rank: runs -> rank/correlation.csv, key_sensors.csv/.json, collinearity.csv."""

from _glue import as_table, read_runs, step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    import rafi.artefact
    from rafi.method.rank import rank_sensors

    smk = snakemake  # noqa: F821
    table, frame = read_runs(smk)
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
