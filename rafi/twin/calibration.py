"""Checks of the twin's data: the noise floor of the shipped runs and a minimal clean.

:func:`noise_floor` gives the max residual a perfect model would leave on each shipped run;
:func:`quick_clean` is the minimal cleaning used by the plots and by
``tests/test_twin_calibration.py`` (not the pipeline's cleaning).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from rafi import SENSORS
from rafi.twin.defects import OPEN_CIRCUIT_VALUES
from rafi.twin.recipes import shipped_specs, simulate_spec


def noise_floor(
    machine: str = "tapping-center-a",
    roles: Sequence[str] = ("valid", "multi"),
    reference_window_s: float = 60.0,
) -> pd.DataFrame:
    """Max |residual| a *perfect* model would leave on each shipped run: the logger's noise.

    Each run of :func:`shipped_specs` is simulated again with the same seed and no logger
    defects (noise and defects use independent random streams, so the noise is the shipped
    one); the displacement noise is the log minus the noise-free truth, referenced like
    ``dz`` (minus its median over the first ``reference_window_s``). Only runs whose file
    name starts with one of ``roles`` are included.

    Returns
    -------
    DataFrame
        ``run_id``, ``n_samples``, ``noise_std_um`` and ``floor_max_abs_um`` per run.
    """
    rows = []
    for spec in shipped_specs(machine):
        if not spec.file.startswith(tuple(roles)):
            continue
        run = simulate_spec(spec, defects=False)
        noise = run.log["disp_um"].to_numpy() - run.truth["disp_um"].to_numpy()
        t = run.nodes["t_s"].to_numpy()
        noise = noise - np.median(noise[t <= t[0] + reference_window_s])
        rows.append(
            {
                "run_id": spec.run_id,
                "n_samples": int(len(noise)),
                "noise_std_um": float(np.std(noise)),
                "floor_max_abs_um": float(np.max(np.abs(noise))),
            }
        )
    return pd.DataFrame(rows, columns=["run_id", "n_samples", "noise_std_um", "floor_max_abs_um"])


def quick_clean(frame: pd.DataFrame, sample_period_s: float = 5.0) -> pd.DataFrame:
    """Minimal cleaning for plots and calibration checks (not the pipeline's cleaning).

    Sort by time, drop duplicate times, set open-circuit values to NaN, replace isolated
    spikes (deviation from a 5-sample rolling median > 1 K or > 3 um) by NaN, and
    interpolate on the regular grid.  Adds ``t_s`` (seconds since the first sample).
    """
    f = frame.sort_values("time", kind="stable").drop_duplicates("time").reset_index(drop=True)
    cols = [*SENSORS, "disp_um"]
    vals = f[cols].astype(float)
    vals = vals.mask(vals.isin(OPEN_CIRCUIT_VALUES))
    med = vals.rolling(5, center=True, min_periods=1).median()
    limit = pd.Series({**{s: 1.0 for s in SENSORS}, "disp_um": 3.0})
    vals = vals.mask((vals - med).abs() > limit, axis=1)
    f[cols] = vals
    grid = pd.date_range(f["time"].iloc[0], f["time"].iloc[-1], freq=pd.Timedelta(seconds=sample_period_s))
    f = f.set_index("time")
    f = f.reindex(f.index.union(grid)).sort_index()
    f[["speed_rpm", *cols]] = f[["speed_rpm", *cols]].interpolate(method="time", limit_direction="both")
    f = f.loc[grid].reset_index(names="time")
    f["t_s"] = (f["time"] - f["time"].iloc[0]) / pd.Timedelta(seconds=1)
    return f
