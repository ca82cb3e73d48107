"""Readers of raw machine logs and their format checks.

``input_spec`` (the ``input:`` mapping and log discovery; standard library only, used while
Snakemake plans), ``parsing`` (text-level helpers), ``native`` (the native CSV format),
``mapped`` (csv/xlsx layouts described by config), ``logs`` (one entry point for any
format), ``checks`` (plausibility checks of a canonical frame).
"""
