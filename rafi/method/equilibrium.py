"""Thermal equilibrium: when a constant-speed run stops growing (paper Table 1).

Definition used throughout the project (documented in the report):

1. The displacement rise ``dz`` is smoothed with a centred rolling median of
   ``smooth_window_s`` (removes logger noise and single spikes).
2. The final plateau is the median of the raw ``dz`` over the last
   ``plateau_window_s`` of the run.
3. The band is ``band_fraction`` of the total rise ``|plateau - dz(0)|``.
4. ``t_eq`` is the first time after which the smoothed ``dz`` stays inside
   ``plateau +- band`` until the end of the run.

Time origin: the **spindle start**. A cold-start log begins with the machine at rest
(the reference state, ``rafi.method.runs``: a short leading rest is part of the run), so the
times are counted from the first sample at which the spindle turns
(``start_s``; :func:`equilibrium_table` finds it as the first sample whose speed reaches
half the run's median speed); ``dz(0)`` in step 3 is still the reference (the rest, first
60 s of the run), so the total rise includes the centrifugal draw-in at the spindle start.
The first-order cross-check is fitted from the spindle start.

Uncertainty: ``t_eq_low`` / ``t_eq_high`` repeat step 4 with the band widened /
narrowed by ``band_spread`` (default 1.5x), which brackets how sensitive the
value is to the band choice. Cross-check: a first-order step response
``dz = c + A (1 - exp(-t / tau))`` is fitted by least squares, and
``t_eq_tau = tau * ln(1 / band_fraction)`` is the time the fitted curve needs to
come within the same band of its asymptote.

:func:`equilibrium_table` applies this to every ``training`` run of
``runs.csv`` / ``runs.parquet`` and sets the paper's Table 1 value beside it
(``paper_t_eq_s``, NaN for speeds the paper did not run).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import pandas as pd

from rafi.method import paper
from rafi.method.rank import speed_training_runs
from rafi.settings import MACHINE_DEFAULTS


@dataclass(frozen=True)
class EquilibriumResult:
    """Time to thermal equilibrium of one run, with its uncertainty and cross-check."""

    t_eq_s: float
    t_eq_low_s: float
    t_eq_high_s: float
    tau_s: float
    t_eq_tau_s: float
    plateau_um: float
    rise_um: float

    def as_dict(self) -> dict:
        return asdict(self)


def _time_in_band(t_s: np.ndarray, smooth: np.ndarray, plateau: float, band: float) -> float:
    outside = np.abs(smooth - plateau) > band
    if not outside.any():
        return float(t_s[0])
    last_out = np.flatnonzero(outside)[-1]
    if last_out + 1 >= len(t_s):
        return float("nan")
    return float(t_s[last_out + 1])


#: Bounds of the first-order fit's tau: ``TAU_MIN_S <= tau <= TAU_MAX_SPANS x`` the fitted span.
TAU_MIN_S = 1.0
TAU_MAX_SPANS = 50.0


def first_order_fit(t_s: np.ndarray, dz: np.ndarray) -> tuple[float, float, float]:
    """Fit ``dz = c + A (1 - exp(-t / tau))``; return ``(c, A, tau)`` (NaN on failure).

    ``tau`` is bounded to ``[TAU_MIN_S, TAU_MAX_SPANS x span]``.
    """
    ok = np.isfinite(t_s) & np.isfinite(dz)
    t, z = t_s[ok] - t_s[ok][0], dz[ok]
    if len(t) < 10:
        return (np.nan, np.nan, np.nan)
    span = max(t[-1], 1.0)
    amp0 = float(np.median(z[-max(len(z) // 10, 1) :]) - z[0])

    def model(tt, c, a, tau):
        return c + a * (1.0 - np.exp(-tt / tau))

    # imported here: the report's jobs import this module for its constants, and scipy.optimize
    # alone costs them about 0.25 s each
    from scipy.optimize import curve_fit

    try:
        popt, _ = curve_fit(
            model,
            t,
            z,
            p0=(float(z[0]), amp0 or 1.0, span / 4),
            bounds=([-np.inf, -np.inf, TAU_MIN_S], [np.inf, np.inf, TAU_MAX_SPANS * span]),
            maxfev=5000,
        )
    except (RuntimeError, ValueError):
        return (np.nan, np.nan, np.nan)
    return tuple(float(v) for v in popt)


def equilibrium_time(
    t_s,
    dz_um,
    *,
    band_fraction: float = MACHINE_DEFAULTS["equilibrium"]["band_fraction"],
    plateau_window_s: float = MACHINE_DEFAULTS["equilibrium"]["plateau_window_s"],
    smooth_window_s: float = MACHINE_DEFAULTS["equilibrium"]["smooth_window_s"],
    band_spread: float = 1.5,
    start_s: float | None = None,
) -> EquilibriumResult:
    """Time to thermal equilibrium of one constant-speed run.

    Parameters
    ----------
    t_s : array_like
        Seconds since the start of the run, increasing, regular.
    dz_um : array_like
        Displacement change from the reference state, micrometres.
    band_fraction : float
        Half-width of the equilibrium band as a fraction of the total rise.
    plateau_window_s : float
        Length of the final window whose median defines the plateau.
    smooth_window_s : float
        Centred rolling-median window applied before the band test.
    band_spread : float
        Factor by which the band is widened / narrowed for the uncertainty bracket.
    start_s : float, optional
        Time of the spindle start (same clock as ``t_s``); the times returned are counted
        from it and the first-order fit starts there. Default: the first sample (a run that
        starts with the spindle already turning).

    Returns
    -------
    EquilibriumResult
        ``t_eq_s`` is NaN when the run never settles inside the band.
    """
    t = np.asarray(t_s, dtype=float)
    z = np.asarray(dz_um, dtype=float)
    if t.shape != z.shape or t.ndim != 1 or len(t) < 3:
        raise ValueError("t_s and dz_um must be 1-D arrays of equal length (>= 3 samples)")
    dt = float(np.median(np.diff(t)))
    win = max(int(round(smooth_window_s / dt)), 1)
    smooth = pd.Series(z).rolling(win, center=True, min_periods=1).median().to_numpy()
    tail = t >= t[-1] - plateau_window_s
    plateau = float(np.nanmedian(z[tail]))
    start = float(np.nanmedian(z[t <= t[0] + min(60.0, plateau_window_s)]))
    rise = plateau - start
    band = band_fraction * abs(rise)
    t_eq = _time_in_band(t, smooth, plateau, band)
    t_low = _time_in_band(t, smooth, plateau, band * band_spread)
    t_high = _time_in_band(t, smooth, plateau, band / band_spread)
    t0 = float(t[0]) if start_s is None else float(start_s)
    on = t >= t0
    _, _, tau = first_order_fit(t[on], z[on]) if on.sum() >= 3 else (np.nan, np.nan, np.nan)
    t_eq_tau = tau * np.log(1.0 / band_fraction) if np.isfinite(tau) else np.nan
    return EquilibriumResult(
        t_eq_s=t_eq - t0,
        t_eq_low_s=t_low - t0,
        t_eq_high_s=t_high - t0,
        tau_s=tau,
        t_eq_tau_s=float(t_eq_tau),
        plateau_um=plateau,
        rise_um=rise,
    )


# --------------------------------------------------------------------------- table


def spindle_start(t_s, speed_rpm, run_speed_rpm: float | None = None) -> float:
    """Time of the first sample whose speed reaches half the run's speed (the spindle start).

    ``run_speed_rpm`` defaults to the median of ``speed_rpm``; without any valid speed the
    first sample's time is returned.
    """
    t = np.asarray(t_s, dtype=float)
    n = np.asarray(speed_rpm, dtype=float)
    if not len(t):
        return float("nan")
    ref = (
        run_speed_rpm
        if run_speed_rpm is not None and np.isfinite(run_speed_rpm)
        else (float(np.nanmedian(n)) if np.isfinite(n).any() else float("nan"))
    )
    if not np.isfinite(ref) or ref <= 0:
        return float(t[0])
    hit = np.flatnonzero(np.abs(n) >= 0.5 * ref)
    return float(t[hit[0]]) if len(hit) else float(t[0])


PAPER_T_EQ_S = paper.T_EQ_S

#: Columns of ``equilibrium.csv``, in order (``docs/design.md``).
EQUILIBRIUM_COLUMNS = (
    "run_id",
    "speed_rpm",
    "t_eq_s",
    "t_eq_low_s",
    "t_eq_high_s",
    "tau_s",
    "t_eq_tau_s",
    "plateau_um",
    "paper_t_eq_s",
    "method",
)


def paper_t_eq(speed_rpm: float) -> float:
    """Paper Table 1 equilibrium time for ``speed_rpm`` (within 50 r/min), else NaN."""
    if speed_rpm is None or not np.isfinite(speed_rpm):
        return float("nan")
    return paper.paper_value(float(speed_rpm), paper.T_EQ_S)


def equilibrium_table(
    runs_table: pd.DataFrame,
    runs_frame: pd.DataFrame,
    *,
    band_fraction: float = MACHINE_DEFAULTS["equilibrium"]["band_fraction"],
    plateau_window_s: float = MACHINE_DEFAULTS["equilibrium"]["plateau_window_s"],
    smooth_window_s: float = MACHINE_DEFAULTS["equilibrium"]["smooth_window_s"],
) -> pd.DataFrame:
    """Time to thermal equilibrium of every training run (``equilibrium.csv``).

    Parameters
    ----------
    runs_table : pandas.DataFrame
        ``runs.csv`` of :func:`rafi.method.runs.find_runs` (``run_id``, ``role``,
        ``speed_rpm``); only rows with ``role == 'training'`` are used.
    runs_frame : pandas.DataFrame
        ``runs.parquet`` (``run_id``, ``t_s``, ``dz_um``).
    band_fraction, plateau_window_s, smooth_window_s : float
        As in :func:`equilibrium_time`.

    Returns
    -------
    pandas.DataFrame
        One row per training run (order of ``runs_table``), columns
        ``EQUILIBRIUM_COLUMNS``. ``paper_t_eq_s`` is the paper's Table 1 value when
        the run's speed is within 50 r/min of a Table 1 speed, else NaN. Samples
        with NaN ``dz_um`` are dropped first; a run with fewer than 3 valid samples,
        or that never settles inside the band, has NaN times and says so in
        ``method``. Times are counted from the spindle start: the first sample whose
        ``speed_rpm`` reaches half the run's median speed (a leading rest of a cold
        start is part of the run, see :mod:`rafi.method.runs`); without ``speed_rpm`` in
        ``runs_frame``, from the run's first sample.
    """
    method = (
        f"band: first time after which the {smooth_window_s:g} s rolling median of dz stays "
        f"within {100 * band_fraction:g} % of the rise around the final plateau (median of "
        f"the last {plateau_window_s:g} s); low/high: band x1.5 / x1/1.5; "
        f"tau: first-order fit, t_eq_tau = tau ln(1/{band_fraction:g}); times from the spindle "
        f"start (first sample at >= half the run's median speed)"
    )
    rows = []
    training = speed_training_runs(runs_table) if len(runs_table) else runs_table
    groups = runs_frame.groupby("run_id", sort=False).indices if len(runs_frame) else {}
    t_all = runs_frame["t_s"].to_numpy(dtype=float) if len(runs_frame) else np.array([])
    z_all = runs_frame["dz_um"].to_numpy(dtype=float, na_value=np.nan) if len(runs_frame) else np.array([])
    n_all = (
        runs_frame["speed_rpm"].to_numpy(dtype=float, na_value=np.nan)
        if len(runs_frame) and "speed_rpm" in runs_frame
        else np.full(len(t_all), np.nan)
    )
    for run in training.itertuples(index=False):
        run_id = str(run.run_id)
        speed = float(run.speed_rpm)
        idx = groups.get(run_id, np.array([], dtype=int))
        t, z, n = t_all[idx], z_all[idx], n_all[idx]
        ok = np.isfinite(t) & np.isfinite(z)
        t, z, n = t[ok], z[ok], n[ok]
        row = {"run_id": run_id, "speed_rpm": speed, "paper_t_eq_s": paper_t_eq(speed)}
        if len(t) < 3:
            nan = float("nan")
            row.update(
                t_eq_s=nan,
                t_eq_low_s=nan,
                t_eq_high_s=nan,
                tau_s=nan,
                t_eq_tau_s=nan,
                plateau_um=nan,
                method=method + f"; not computed: {len(t)} valid samples",
            )
        else:
            res = equilibrium_time(
                t,
                z,
                band_fraction=band_fraction,
                plateau_window_s=plateau_window_s,
                smooth_window_s=smooth_window_s,
                start_s=spindle_start(t, n, speed),
            )
            row.update({k: v for k, v in res.as_dict().items() if k != "rise_um"})
            note = (
                "; never settled inside the band before the end of the run"
                if not np.isfinite(res.t_eq_s)
                else ""
            )
            row["method"] = method + note
        rows.append(row)
    table = pd.DataFrame(rows, columns=list(EQUILIBRIUM_COLUMNS))
    return table.astype({c: "float64" for c in EQUILIBRIUM_COLUMNS if c not in ("run_id", "method")})
