"""Readers of raw machine logs and their format checks.

``input_spec`` (the ``input:`` mapping and log discovery; standard library only, used while
Snakemake plans), ``input_assumed`` (the mapping's stand-ins for a missing time or speed
column; standard library only), ``parsing`` (text-level helpers), ``native`` (the native CSV
format), ``mapped`` (csv/xlsx layouts described by config) with ``mapped_table`` (the rows
and their cell values), ``mapped_columns`` (where each column is), ``mapped_time`` (the clock:
a time column or the row number) and ``mapped_join`` (a partner file's columns),
``logs`` (one entry point for any format), ``checks`` (plausibility checks of a canonical
frame).
"""
