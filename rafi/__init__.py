"""RAFI: thermal-displacement compensation for CNC spindles (Chang et al. 2023).

Regression per training speed + fuzzy (triangular-membership) blending, run as a
Snakemake pipeline from raw machine logs to a qualification report.
"""

__version__ = "0.1.0"

SENSORS = tuple(f"T{i}" for i in range(1, 17))
"""Canonical temperature column names, deg C."""

REQUIRED_COLUMNS = ("time", "speed_rpm", *SENSORS, "disp_um")
"""Columns every canonical log frame carries, in this order."""
