"""Synthetic training/validation runs for the model family, with the truth they were made from."""

from __future__ import annotations

import hashlib
from collections.abc import Sequence

import numpy as np
import pandas as pd

from rafi.family.models import SPEED_POWER_SCALE_RPM, lowpass_runs


def make_synthetic_runs(
    *,
    seed: int = 0,
    sample_s: float = 60.0,
    duration_s: float = 4 * 3600.0,
    n_sensors: int = 5,
    sensor_taus_s: Sequence[float] | None = None,
    tau_lag_s: float = 1200.0,
    centrifugal_um_per_krpm2: float = -0.02,
    train_speeds=(3000, 6000, 9000, 12000, 15000, 18000),
    validation_speeds=(4500, 10500, 16500),
    multi: bool = True,
    noise_um: float = 0.05,
    shaft_um: float = 0.0,
    shaft_tau_s: float = 300.0,
    shaft_power: float = 5.0 / 3.0,
    centrifugal_lag_s: float = 0.0,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Small deterministic runs for tests and benchmarks (not the digital twin).

    Sensor rises are first-order responses (time constants ``sensor_taus_s``, default 600..3000 s)
    to a heat input
    ``~ n^1.3``; the displacement lags the sensors: ``dz = sum_i g_i L_tau_lag(dT_i) +
    c (n^2 - n0^2)`` (+ noise). Every run starts with 120 s at rest (the 60 s reference window)
    so the centrifugal term is identifiable. ``shaft_um`` > 0 adds an unmeasured fast part
    (the shaft): ``shaft_um * L_shaft_tau_s((n / 10000)^shaft_power)``, zero before the run
    (no sensor sees it; the grey-box speed-power filter must recover it). ``centrifugal_lag_s``
    > 0 passes the ``n^2`` term through a first-order lag. Returns ``(runs_table, runs_frame)`` in the
    ``docs/design.md`` layout (rises only for ``T1..T{n_sensors}``).
    """
    rng = np.random.default_rng(seed)
    sensor_tau = (
        np.linspace(600.0, 3000.0, n_sensors)
        if sensor_taus_s is None
        else np.asarray(sensor_taus_s, dtype=float)
    )
    sensor_gain = np.linspace(2.0, 8.0, n_sensors)  # K at 18000 r/min
    disp_gain = np.linspace(1.0, -0.3, n_sensors)  # um/K
    t = np.arange(0.0, duration_s + 1e-9, sample_s)

    def simulate(run_id, speed_fn, role):
        n = speed_fn(t)
        heat = (n / 18000.0) ** 1.3
        codes = np.zeros(len(t), dtype=int)
        dT = np.column_stack(
            [lowpass_runs(heat * sensor_gain[i], t, codes, [sensor_tau[i]])[:, 0] for i in range(n_sensors)]
        )
        lag = lowpass_runs(dT, t, codes, [tau_lag_s])
        n0 = np.median(n[t <= 60.0])
        n2 = ((n / 1000) ** 2 - (n0 / 1000) ** 2)[:, None]
        dz = (
            lag @ disp_gain + centrifugal_um_per_krpm2 * lowpass_runs(n2, t, codes, [centrifugal_lag_s])[:, 0]
        )
        if shaft_um:
            dz = (
                dz
                + shaft_um
                * lowpass_runs(
                    (n / SPEED_POWER_SCALE_RPM) ** shaft_power, t, codes, [shaft_tau_s], initial="zero"
                )[:, 0]
            )
        dz = dz + rng.normal(0.0, noise_um, len(t))
        dT = dT + rng.normal(0.0, 0.01, dT.shape)
        f = pd.DataFrame({"run_id": run_id, "t_s": t, "speed_rpm": n})
        for i in range(n_sensors):
            f[f"dT{i + 1}"] = dT[:, i]
        f["dz_um"] = dz
        row = {
            "run_id": run_id,
            "role": role,
            "speed_rpm": float(np.median(n[t > 120])),
            "file": f"{run_id}.csv",
            "sha256": hashlib.sha256(run_id.encode()).hexdigest(),
        }
        return row, f

    rows, frames = [], []
    step = lambda s: lambda tt: np.where(tt >= 120.0, float(s), 0.0)  # noqa: E731
    for s in train_speeds:
        r, f = simulate(f"train-{s}", step(s), "training")
        rows.append(r), frames.append(f)
    for s in validation_speeds:
        r, f = simulate(f"val-{s}", step(s), "validation_single")
        rows.append(r), frames.append(f)
    if multi:
        sched = np.array([[0, 0], [120, 6000], [3600, 12000], [7200, 4500], [10800, 16500], [13200, 9000]])

        def multi_fn(tt):
            return sched[np.searchsorted(sched[:, 0], tt, side="right") - 1, 1].astype(float)

        r, f = simulate("val-multi", multi_fn, "validation_multi")
        rows.append(r), frames.append(f)
    table = pd.DataFrame(rows)
    frame = pd.concat(frames, ignore_index=True)
    return table, frame
