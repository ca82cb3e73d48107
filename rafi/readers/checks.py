"""Plausibility checks on a freshly read log, before cleaning.

:func:`check_log` looks for mistakes that would otherwise pass silently through
the pipeline and spoil a model: a clock reset, a run too short to use, a sensor
that never delivered a value, a stuck displacement probe, displacement logged in
millimetres instead of micrometres, absurd speeds and temperatures. Each raises
:class:`rafi.errors.RawFormatError` naming the file, the line (or sheet and row)
and the column, and saying what to do. Problems the cleaning step repairs
(local swaps of adjacent rows, duplicates, single spikes, short dropouts,
documented open-circuit values) are left alone.

Thresholds (keyword arguments, defaults in brackets):

* time going back by more than ``backwards_tolerance_samples`` (3) sample periods
  from one row to the next -> clock reset. A step back of up to 3 periods (two
  adjacent rows swapped, a repeated sample) is left for cleaning.
* run shorter than ``min_run_s`` (0 = no check) from first to last timestamp.
* a canonical column (``speed_rpm``, ``T1``..``T16``, ``disp_um``) without a single
  value (empty, or only open-circuit values).
* displacement constant: standard deviation below ``stuck_std_um`` (1e-3 um) or
  more than ``stuck_fraction`` (95 %) of the values identical, with at least
  ``min_samples`` (10) values.
* displacement stuck: the same value in consecutive rows for ``stuck_max_s``
  (600 s) or longer while some temperature changes by ``stuck_min_temp_change_k``
  (1 K) or more in that stretch: the machine is growing, a live probe would move.
  (A coarse probe on a machine at rest may repeat its value for long; that passes.)
* displacement range (max - min) at most ``mm_max_range_um`` (0.2) while some
  temperature rises by at least ``mm_min_temp_rise_k`` (3 K) -> millimetres.
* speed below 0 or above ``max_speed_rpm`` (100000 r/min).
* temperature outside ``temp_range_c`` (-40..200 deg C), except the documented
  open-circuit values (``clean.open_circuit_values``).
"""

from __future__ import annotations

import os

import numpy as np
import pandas as pd

from rafi import SENSORS
from rafi.errors import RawFormatError
from rafi.method.clean import BACKWARDS_TOLERANCE_SAMPLES

#: Columns that must carry at least one value.
VALUE_COLUMNS = ("speed_rpm", *SENSORS, "disp_um")


class _Where:
    """Words an error for this frame: sheet/row for spreadsheets, file headers for mapped files."""

    def __init__(self, frame: pd.DataFrame, path):
        meta = frame.attrs.get("metadata") or {}
        self.path = path if path is not None else frame.attrs.get("source", "<log>")
        self.sheet = meta.get("sheet") if isinstance(meta, dict) else None
        cols = meta.get("columns") if isinstance(meta, dict) else None
        self.columns = cols if isinstance(cols, dict) else {}

    def label(self, canon: str) -> str:
        theirs = self.columns.get(canon)
        return f"{canon} (header {theirs!r})" if theirs and theirs != canon else canon

    def prefix(self, canon: str) -> str:
        label = self.label(canon)
        return f"{label}: " if label != canon else ""

    def error(self, message: str, *, line=None, column: str | None = None) -> RawFormatError:
        return RawFormatError(
            self.path, message, line=None if line is None else int(line), column=column, sheet=self.sheet
        )


def _longest_repeat(values: np.ndarray) -> tuple[int, int]:
    """Start and length of the longest stretch of identical consecutive non-NaN values."""
    if values.size == 0:
        return 0, 0
    same = np.concatenate(([False], (values[1:] == values[:-1])))
    starts = np.flatnonzero(~same)
    lengths = np.diff(np.append(starts, values.size))
    k = int(np.argmax(lengths))
    return int(starts[k]), int(lengths[k])


def _open_circuit_mask(values: np.ndarray, open_circuit_values) -> np.ndarray:
    mask = np.zeros(values.shape, dtype=bool)
    for v in open_circuit_values or ():
        mask |= np.isclose(values, float(v), rtol=0.0, atol=1e-6)
    return mask


def check_log(
    frame: pd.DataFrame,
    path: str | os.PathLike | None = None,
    *,
    min_run_s: float = 0.0,
    sample_period_s: float | None = None,
    open_circuit_values=(),
    backwards_tolerance_samples: float = BACKWARDS_TOLERANCE_SAMPLES,
    max_speed_rpm: float = 100_000.0,
    temp_range_c: tuple[float, float] = (-40.0, 200.0),
    stuck_std_um: float = 1e-3,
    stuck_fraction: float = 0.95,
    stuck_max_s: float = 600.0,
    stuck_min_temp_change_k: float = 1.0,
    mm_max_range_um: float = 0.2,
    mm_min_temp_rise_k: float = 3.0,
    min_samples: int = 10,
) -> pd.DataFrame:
    """Raise :class:`RawFormatError` on an implausible log; return ``frame`` unchanged otherwise.

    Parameters
    ----------
    frame : pandas.DataFrame
        Canonical frame from :func:`rafi.readers.logs.read_log` (index = source line/row).
    path : str or os.PathLike, optional
        File named in messages (default ``frame.attrs['source']``).
    min_run_s : float
        Shortest acceptable log (first to last timestamp), seconds; 0 disables.
    sample_period_s : float, optional
        Nominal sample period; default ``attrs['metadata']['sample_period_s']``, else
        the median positive time step.
    open_circuit_values : iterable of float
        Documented open-circuit readings (``clean.open_circuit_values``): allowed
        outside the temperature range and counted as missing.
    backwards_tolerance_samples, max_speed_rpm, temp_range_c, stuck_std_um,
    stuck_fraction, stuck_max_s, stuck_min_temp_change_k, mm_max_range_um, mm_min_temp_rise_k, min_samples
        Thresholds, see the module docstring.

    Returns
    -------
    pandas.DataFrame
        ``frame`` itself (not copied), so calls can be chained.
    """
    where = _Where(frame, path)
    lines = frame.index.to_numpy()
    n = len(frame)
    if n == 0:
        raise where.error("no data rows")

    # -- sensors without any value ------------------------------------------------------
    values: dict[str, np.ndarray] = {}
    for name in VALUE_COLUMNS:
        v = frame[name].to_numpy(dtype=float, na_value=np.nan)
        oc = _open_circuit_mask(v, open_circuit_values) if name in SENSORS else np.zeros(n, bool)
        v = np.where(oc, np.nan, v)
        values[name] = v
        if np.isnan(v).all():
            extra = " or open-circuit" if oc.any() else ""
            raise where.error(
                f"{where.label(name)} has no value in any of the {n} rows (all "
                f"empty{extra}): sensor not connected or wrong column mapped",
                column=name,
            )

    # -- time: clock reset, duration ------------------------------------------------------
    t = frame["time"].to_numpy(dtype="datetime64[ns]").astype("int64") / 1e9
    steps = np.diff(t)
    if sample_period_s is None:
        meta = frame.attrs.get("metadata") or {}
        sample_period_s = meta.get("sample_period_s") if isinstance(meta, dict) else None
    if sample_period_s is None:
        pos = steps[steps > 0]
        sample_period_s = float(np.median(pos)) if pos.size else 1.0
    sample_period_s = float(sample_period_s)
    limit = backwards_tolerance_samples * sample_period_s
    back = np.flatnonzero(steps < -limit)
    if back.size:
        k = int(back[0]) + 1
        prev, cur = frame["time"].iloc[k - 1], frame["time"].iloc[k]
        raise where.error(
            f"time goes back from {prev:%Y-%m-%dT%H:%M:%S} to {cur:%Y-%m-%dT%H:%M:%S} "
            f"({-steps[k - 1]:.0f} s, more than {backwards_tolerance_samples:g} samples of "
            f"{sample_period_s:g} s): a clock reset? split the file there or correct the clock",
            line=lines[k],
            column="time",
        )
    duration = float(np.nanmax(t) - np.nanmin(t)) if n else 0.0
    if min_run_s and duration < min_run_s:
        raise where.error(
            f"log covers only {duration:.0f} s, shorter than the minimum run of "
            f"{min_run_s:g} s (runs.min_run_s)",
            line=lines[-1],
            column="time",
        )

    # -- speed --------------------------------------------------------------------------
    s = values["speed_rpm"]
    bad = np.flatnonzero((s < 0) | (s > max_speed_rpm))
    if bad.size:
        k = int(bad[0])
        raise where.error(
            f"{where.prefix('speed_rpm')}speed {s[k]:g} r/min is {'negative' if s[k] < 0 else 'absurd'}; "
            f"expected 0..{max_speed_rpm:g} r/min",
            line=lines[k],
            column="speed_rpm",
        )

    # -- temperatures -------------------------------------------------------------------
    lo, hi = temp_range_c
    first_bad = None
    for name in SENSORS:
        v = values[name]
        idx = np.flatnonzero((v < lo) | (v > hi))
        if idx.size and (first_bad is None or idx[0] < first_bad[0]):
            first_bad = (int(idx[0]), name)
    if first_bad is not None:
        k, name = first_bad
        oc = ", ".join(f"{x:g}" for x in open_circuit_values or ()) or "none configured"
        raise where.error(
            f"{where.prefix(name)}temperature {values[name][k]:g} deg C is outside {lo:g}..{hi:g} deg C "
            f"and not a documented open-circuit value ({oc}; "
            "clean.open_circuit_values)",
            line=lines[k],
            column=name,
        )

    # -- displacement: stuck probe, millimetres -----------------------------------------
    d = values["disp_um"]
    d_ok = d[~np.isnan(d)]
    if d_ok.size >= min_samples:
        std = float(np.std(d_ok))
        uniq, counts = np.unique(d_ok, return_counts=True)
        top = float(counts.max()) / d_ok.size
        if std < stuck_std_um or top > stuck_fraction:
            raise where.error(
                f"{where.label('disp_um')} is constant (std {std:.2g} um, "
                f"{100 * top:.0f} % of the values equal {uniq[counts.argmax()]:g}): stuck or "
                "disconnected probe, or the wrong channel is mapped",
                column="disp_um",
            )
        first, length = _longest_repeat(d)
        if stuck_max_s > 0 and length * sample_period_s >= stuck_max_s:
            stretch = slice(first, first + length)
            change = max(
                (
                    float(np.nanmax(values[s][stretch]) - np.nanmin(values[s][stretch]))
                    for s in SENSORS
                    if np.isfinite(values[s][stretch]).any()
                ),
                default=0.0,
            )
            if change >= stuck_min_temp_change_k:
                raise where.error(
                    f"{where.label('disp_um')} is stuck at {d[first]:g} um for {length} rows "
                    f"({length * sample_period_s / 60:.0f} min, lines {lines[first]}-"
                    f"{lines[first + length - 1]}) while temperatures change by {change:.1f} K: "
                    "a live probe would move; check the probe and its cable",
                    line=lines[first],
                    column="disp_um",
                )
        rise = 0.0
        for name in SENSORS:
            v = values[name]
            v = v[~np.isnan(v)]
            if v.size >= min_samples:
                lo_q, hi_q = np.percentile(v, [1, 99])
                rise = max(rise, float(hi_q - lo_q))
        spread = float(d_ok.max() - d_ok.min())
        if spread <= mm_max_range_um and rise >= mm_min_temp_rise_k:
            raise where.error(
                f"{where.label('disp_um')} varies by only {spread:.3g} um while temperatures change "
                f"by {rise:.1f} K: values look like millimetres; set displacement.unit: mm in "
                "the machine's input mapping (config.yaml)",
                column="disp_um",
            )
    return frame
