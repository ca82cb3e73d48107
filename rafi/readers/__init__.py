"""Readers of raw machine logs and their format checks.

``input_spec`` (the ``input:`` mapping and log discovery; standard library only, used while
Snakemake plans), ``input_assumed`` (the mapping's stand-ins for a missing time or speed
column; standard library only), ``parsing`` (text-level helpers), ``native`` (the native CSV
format), ``mapped`` (csv/xlsx layouts described by config) with ``mapped_cells`` (the table
and its cell values) and ``mapped_time`` (the clock: a time column or the row number),
``logs`` (one entry point for any format), ``checks`` (plausibility checks of a canonical
frame).
"""
