"""Operations: the model registry (champion/challenger), ``rafi nightly`` and how it drives
Snakemake."""
