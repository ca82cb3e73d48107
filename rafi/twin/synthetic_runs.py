"""Synthetic runs with known ground truth: ``runs_table`` and ``runs_frame`` (docs/design.md layout).

Two generators, both independent of the digital twin's physics:

* :func:`make_runs` - runs for the rank / fit / fuzzy / validate tests whose displacement is
  *exactly* a known RAFI polynomial of the key sensors' rises (the truth, per speed, is in
  the returned :class:`Synthetic`):

  - the key sensors T6, T8, T9 rise along first-order heating curves (amplitude and time
    constant depend on speed) plus small independent slow wiggles (coolant cycling), which
    keeps the 11-term design identifiable;
  - ``dz_um`` is the polynomial (``TERMS``, ``truth[speed]``) of the true rises plus noise
    (white or AR(1));
  - T13 follows the heating with an oscillation (min |r| over speeds ~ 0.96: the "next best"
    when a key sensor fails); the other sensors are coolant-like (slow drift, oscillation:
    |r| well below 0.97);
  - ``sensor_faults={"T9": amp}`` adds a disturbance to the *recorded* rise of a sensor after
    ``dz`` was computed (a loose sensor), lowering its correlation; ``{"T4": "nan"}`` blanks a
    sensor, ``{"T4": "const"}`` freezes it;
  - validation runs at speeds between the training speeds use the triangular blend of the
    neighbouring truth polynomials, so a correct RAFI model is exact there up to the noise.

* :func:`make_synthetic_runs` - runs for the model-family tests and benchmarks: sensor rises
  are first-order responses to a heat input, the displacement lags the sensors and has a
  centrifugal term (and optionally an unmeasured fast shaft part); the truth is in the
  arguments (time constants, gains).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from rafi import SENSORS
from rafi.family.features import SPEED_POWER_SCALE_RPM, lowpass_runs
from rafi.method.runs import RUNS_TABLE_COLUMNS
from rafi.twin.schedules import speed_at
from rafi.twin.signals import ar1, step_response

KEY = ("T6", "T8", "T9")
TERMS = ["1", "x1", "x2", "x3", "x1*x2", "x1*x3", "x2*x3", "x1^2", "x2^2", "x3^2", "x1*x2*x3"]
BASE_COEF = np.array([0.3, 1.2, 0.8, 0.5, 0.05, -0.03, 0.02, -0.04, 0.03, -0.02, 0.002])


@dataclass
class Synthetic:
    """Runs of :func:`make_runs` and the truth they were made from (``truth``: speed -> coefficients)."""

    runs_table: pd.DataFrame
    runs_frame: pd.DataFrame
    key_sensors: list = field(default_factory=lambda: list(KEY))
    terms: list = field(default_factory=lambda: list(TERMS))
    truth: dict = field(default_factory=dict)  # speed -> coefficient array


def truth_coefficients(speed: float) -> np.ndarray:
    """Known coefficients at a training speed (smoothly speed dependent)."""
    f = speed / 9000.0
    scale = np.array([1, f, 1 / f, 1, 1, f, 1, 1, 1 / f, 1, 1], dtype=float)
    return BASE_COEF * scale


def _poly(coef, x6, x8, x9):
    return (
        coef[0]
        + coef[1] * x6
        + coef[2] * x8
        + coef[3] * x9
        + coef[4] * x6 * x8
        + coef[5] * x6 * x9
        + coef[6] * x8 * x9
        + coef[7] * x6**2
        + coef[8] * x8**2
        + coef[9] * x9**2
        + coef[10] * x6 * x8 * x9
    )


def _noise(rng, n, sigma, rho):
    """White noise, or stationary AR(1) noise of std ``sigma`` for ``rho != 0``."""
    if not rho:
        return rng.normal(0.0, sigma, n)
    eps = rng.normal(0.0, sigma * np.sqrt(1 - rho**2), n)
    eps[0] = rng.normal(0.0, sigma)
    return ar1(eps, rho)


def _run_row(run_id: str, role: str, speed_rpm: float, **columns) -> dict:
    """A runs-table row: the run's identity (file name, hash) and ``columns``."""
    return {
        "run_id": run_id,
        "role": role,
        "speed_rpm": float(speed_rpm),
        "file": f"{run_id}.csv",
        "sha256": hashlib.sha256(run_id.encode()).hexdigest(),
        **columns,
    }


def _run(rng, run_id, speed, t, *, sigma, rho, faults, truth_fn):
    n = t.size
    f = speed / 9000.0
    heat = lambda amp, tau: step_response(t, amp, tau)  # noqa: E731
    wig = lambda amp, period: amp * np.sin(2 * np.pi * t / period + rng.uniform(0, 2 * np.pi))  # noqa: E731,E501
    x6 = heat(4.0 * f + 2.0, 2400.0 / f**0.5) + wig(0.15, rng.uniform(1500, 2500))
    x8 = heat(6.0 * f + 2.5, 3000.0 / f**0.5) + wig(0.15, rng.uniform(2600, 3600))
    x9 = heat(5.0 * f + 2.2, 2000.0 / f**0.5) + wig(0.12, rng.uniform(900, 1400))
    x6, x8, x9 = (v + rng.normal(0, 0.01, n) for v in (x6, x8, x9))  # recorded = true rises
    dz = truth_fn(x6, x8, x9) + _noise(rng, n, sigma, rho)
    rises = {}
    for i, s in enumerate(SENSORS, start=1):
        if s == "T6":
            r = x6
        elif s == "T8":
            r = x8
        elif s == "T9":
            r = x9
        elif s == "T13":
            r = heat(2.0 * f + 1.0, 2500.0) + wig(0.12 * f + 0.08, 1800.0)
        else:
            r = heat(0.3 * i / 16, 1500.0) + wig(0.4, 600 + 50 * i) + np.cumsum(rng.normal(0, 0.02, n))
        rises[s] = r if s in KEY else r + rng.normal(0, 0.01, n)
    for s, fault in faults.items():
        if fault == "nan":
            rises[s] = np.full(n, np.nan)
        elif fault == "const":
            rises[s] = np.zeros(n)
        else:
            rises[s] = rises[s] + float(fault) * np.sin(2 * np.pi * t / 1200.0)
    frame = pd.DataFrame(
        {
            "run_id": run_id,
            "t_s": t,
            "time": pd.Timestamp("2026-03-01T08:00:00") + pd.to_timedelta(t, "s"),
            "speed_rpm": float(speed),
        }
    )
    for s in SENSORS:
        frame[s] = 20.0 + rises[s]
    frame["disp_um"] = 5.0 + dz
    for s in SENSORS:
        frame[f"d{s}"] = rises[s]
    frame["dz_um"] = dz
    return frame


def make_runs(
    speeds=(3000, 6000, 9000),
    *,
    runs_per_speed: int = 1,
    duration_s: float = 7200,
    sample_s: float = 5.0,
    sigma: float = 0.05,
    rho: float = 0.0,
    seed: int = 1,
    validation_speeds=(),
    sensor_faults: dict | None = None,
    faults_at_speed: float | None = None,
) -> Synthetic:
    """Training (and optional validation) runs with a known polynomial truth.

    Parameters
    ----------
    speeds : training speeds, r/min.
    runs_per_speed : training runs per speed.
    duration_s, sample_s : run length and sample period.
    sigma, rho : displacement noise std (um) and AR(1) coefficient.
    seed : random seed.
    validation_speeds : speeds of ``validation_single`` runs (truth = triangular blend).
    sensor_faults : {sensor: amplitude | "nan" | "const"} applied to recorded rises.
    faults_at_speed : apply the faults only at this training speed (default: all runs).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, sample_s)
    speeds = sorted(float(s) for s in speeds)
    truth = {int(s): truth_coefficients(s) for s in speeds}
    frames, rows = [], []

    def add(run_id, speed, role, truth_fn, faults):
        fr = _run(rng, run_id, speed, t, sigma=sigma, rho=rho, faults=faults, truth_fn=truth_fn)
        frames.append(fr)
        rows.append(
            _run_row(
                run_id,
                role,
                speed,
                segment=0,
                start_s=0.0,
                end_s=float(t[-1]),
                duration_s=float(t[-1] - t[0]),
                speed_min_rpm=float(speed),
                speed_max_rpm=float(speed),
                kind="constant",
                role_source="auto",
                reference="run_start 60 s",
            )
        )

    faults = dict(sensor_faults or {})
    for s in speeds:
        for k in range(runs_per_speed):
            use = faults if faults_at_speed is None or faults_at_speed == s else {}
            coef = truth[int(s)]
            add(
                f"train-{int(s)}-{k + 1}", s, "training", lambda a, b, c, coef=coef: _poly(coef, a, b, c), use
            )
    for v in validation_speeds:
        w, _ = _weights(v, speeds)
        coefs = [truth[int(s)] for s in speeds]

        def blend(a, b, c, w=w, coefs=coefs):
            return sum(wj * _poly(cj, a, b, c) for wj, cj in zip(w, coefs) if wj)

        add(f"val-{int(v)}", v, "validation_single", blend, {})
    table = pd.DataFrame(rows)
    table = table[[c for c in RUNS_TABLE_COLUMNS if c in table]]  # the order of runs.csv
    frame = pd.concat(frames, ignore_index=True)
    return Synthetic(runs_table=table, runs_frame=frame, truth=truth)


def _weights(v, speeds):
    """Independent (scalar, loop-based) triangular weights for the ground truth."""
    c = list(speeds)
    w = [0.0] * len(c)
    if v <= c[0]:
        w[0] = 1.0
        return w, True
    if v >= c[-1]:
        w[-1] = 1.0
        return w, v > c[-1]
    for j in range(len(c) - 1):
        if c[j] <= v <= c[j + 1]:
            w[j + 1] = (v - c[j]) / (c[j + 1] - c[j])
            w[j] = 1.0 - w[j + 1]
            return w, False
    raise AssertionError("unreachable")


#: Multi-condition run of :func:`make_synthetic_runs`: ``(start_s, speed_rpm)`` change points.
MULTI_CONDITION = ((0, 0), (120, 6000), (3600, 12000), (7200, 4500), (10800, 16500), (13200, 9000))


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

    def simulate(run_id, changes, role):
        n = speed_at(t, changes)
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
        row = _run_row(run_id, role, np.median(n[t > 120]))
        return row, f

    rows, frames = [], []
    plan = [(f"train-{s}", ((0.0, 0.0), (120.0, s)), "training") for s in train_speeds]
    plan += [(f"val-{s}", ((0.0, 0.0), (120.0, s)), "validation_single") for s in validation_speeds]
    if multi:
        plan.append(("val-multi", MULTI_CONDITION, "validation_multi"))
    for run_id, changes, role in plan:
        r, f = simulate(run_id, changes, role)
        rows.append(r)
        frames.append(f)
    table = pd.DataFrame(rows)
    frame = pd.concat(frames, ignore_index=True)
    return table, frame


def machine_state(
    *, seed: int, prefix: str, factor: float = 1.0, **kwargs
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Runs of one state of a machine (:func:`make_synthetic_runs` with ``kwargs``): the run ids
    start with ``prefix`` and every run is its own file with its own content hash, and the
    displacement is ``factor`` times the generator's (a machine whose gain changed: the truth of
    a prior re-qualified by a gain is ``factor``)."""
    table, frame = make_synthetic_runs(seed=seed, **kwargs)
    frame = frame.assign(dz_um=frame["dz_um"] * factor)
    rename = {r: f"{prefix}{r}" for r in table["run_id"]}
    table = table.assign(run_id=table["run_id"].map(rename))
    frame = frame.assign(run_id=frame["run_id"].map(rename))
    table["file"] = table["run_id"] + ".csv"
    table["sha256"] = [hashlib.sha256(r.encode()).hexdigest() for r in table["run_id"]]
    return table, frame


def runs_of_logs(
    logs: dict,
    *,
    training_speeds_rpm: Sequence[float] = (3000, 6000, 9000),
    reference_rule: str = "run_start",
    reference_window_s: float = 60.0,
    min_constant_s: float = 1800,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Rule ``runs``' table and frame of synthetic clean logs (``{name: frame}``, e.g. from
    :func:`rafi.twin.synthetic_logs.schedule_log`), with the settings the tests and benchmarks
    of whole logs share: 50 r/min speed tolerance, idle below 100 r/min, runs of 600 s at least,
    no overrides, zero hashes."""
    from rafi.method.runs import find_runs

    return find_runs(
        logs,
        {name: "0" * 64 for name in logs},
        training_speeds_rpm=list(training_speeds_rpm),
        speed_tolerance_rpm=50,
        idle_below_rpm=100,
        min_run_s=600,
        min_constant_s=min_constant_s,
        overrides={},
        reference_rule=reference_rule,
        reference_window_s=reference_window_s,
    )


#: Settings of the small family models fitted on :func:`runs_of_logs` output in the tests.
SMALL_MODEL_KEY_SENSORS = ["T6", "T8", "T9"]
SMALL_MODEL_TERMS = ["1", "x1", "x2", "x3", "x1*x2", "x1^2", "x2^2"]


def small_family_model(
    kind: str,
    *,
    reference_rule: str,
    reference_window_s: float,
    filter_restart_gap_s: float,
    speed_gain="cv",
    alphas: Sequence[float] = (1e-6, 1e-4, 1e-2),
):
    """An unfitted model of the family with small grids, for logs of :func:`runs_of_logs`.

    Parameters
    ----------
    kind : {"rafi", "rafi_linear", "ridge_global", "dynamic", "grey_box", "temperature_ridge"}
    reference_rule, reference_window_s : the reference state (``reference:`` settings).
    filter_restart_gap_s : float
        The filters restart after a gap longer than this.
    speed_gain : {True, False, "cv"}
        ``ridge_global``'s speed-dependent gains.
    alphas : sequence of float
        The ridge grid.

    Returns
    -------
    estimator
        Not fitted; call ``fit(table, frame)``.
    """
    from rafi.family.dynamic import DynamicRidge
    from rafi.family.grey_box import GreyBox
    from rafi.family.published import PublishedRafi
    from rafi.family.rafi_linear import RafiLinear
    from rafi.family.ridge_global import RidgeGlobal
    from rafi.family.temperature_ridge import TemperatureRidge

    ref = {"rule": reference_rule, "window_s": reference_window_s}
    alphas = list(alphas)
    restart = filter_restart_gap_s
    if kind == "rafi":
        return PublishedRafi(key_sensors=SMALL_MODEL_KEY_SENSORS, terms=SMALL_MODEL_TERMS, reference=ref)
    if kind == "rafi_linear":
        return RafiLinear(key_sensors=SMALL_MODEL_KEY_SENSORS, reference=ref)
    if kind == "ridge_global":
        return RidgeGlobal(alphas=alphas, reference=ref, speed_gain=speed_gain, filter_restart_gap_s=restart)
    if kind == "temperature_ridge":
        return TemperatureRidge(
            taus_s=[0, 600, 2400], alphas=alphas, reference=ref, filter_restart_gap_s=restart
        )
    if kind == "dynamic":
        return DynamicRidge(
            taus_s=[600, 2400],
            max_taus=2,
            heat_input=True,  # the heat-input history: every filter of the family exercised
            speed_taus_s=[120, 900],
            alphas=alphas,
            reference=ref,
            filter_restart_gap_s=restart,
        )
    if kind == "grey_box":
        return GreyBox(
            taus_s=[0, 600],
            speed_taus_s=[120, 900],
            centrifugal_lags_s=[20],
            alphas=alphas,
            reference=ref,
            filter_restart_gap_s=restart,
        )
    raise ValueError(f"unknown model kind {kind!r}")
