"""Rule equilibrium: runs -> equilibrium.csv (time to thermal equilibrium per training run)."""

from _glue import read_runs, step

with step(snakemake) as log:  # noqa: F821 - injected by Snakemake
    import rafi.artefact
    from rafi.method.equilibrium import equilibrium_table

    smk = snakemake  # noqa: F821
    table, frame = read_runs(smk)
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
