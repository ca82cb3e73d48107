"""Hyperparameter grids that scale with the data, and flags for a choice at a grid edge
(``docs/models.md``, "Grids").

A grid setting is a list of values or ``auto``. ``auto`` is derived from the training data:
the sample period ``P`` (median spacing of the training samples) and the median training-run
length ``L`` (:func:`data_scales`), by the rules of :data:`AUTO_RULES`. A choice at the edge of
its grid (the optimum may lie outside) is flagged in plain words (:func:`edge_flags`); the
artefact records the flags in ``selected.grid_edges`` and the fitted model in ``grid_edges_``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

from rafi.family.features import times

AUTO = "auto"

#: ``auto`` grids: (leading values, lowest value, highest value, ratio); ``P`` = sample period,
#: ``L`` = median training-run length. The grid is geometric from the lowest value up to the
#: value nearest the highest on a log scale (within a factor ``sqrt(ratio)``; never below the
#: lowest), rounded to 2 significant digits.
#:
#: * ``dynamic_taus_s``: 0 (the rise itself) and a geometric grid (ratio 3) from 4 P, the
#:   fastest lag a few samples resolve, up to L, the slowest one a run identifies;
#: * ``grey_box_taus_s``: 0 and rise filters from 24 P to L / 24, ratio 5 (the shipped
#:   ``[0, 120, 600]`` at 5 s and 4 h; every one enters the model at once);
#: * ``grey_box_speed_taus_s``: heat-input filters from 12 P to L / 6, ratio 3 (at 5 s and 4 h
#:   60, 180, 540, 1600 s; the shipped list was 60, 180, 600, 2400);
#: * ``grey_box_centrifugal_lags_s``: 0, P, 2 P, 4 P (the draw-in follows within seconds, so
#:   its lag is at most a few samples).
AUTO_RULES = {
    "dynamic_taus_s": ((0.0,), ("P", 4.0), ("L", 1.0), 3.0),
    "grey_box_taus_s": ((0.0,), ("P", 24.0), ("L", 1.0 / 24.0), 5.0),
    "grey_box_speed_taus_s": ((), ("P", 12.0), ("L", 1.0 / 6.0), 3.0),
    "grey_box_centrifugal_lags_s": ((0.0,), ("P", 1.0), ("P", 4.0), 2.0),
}


def data_scales(frame: pd.DataFrame) -> tuple[float, float]:
    """``(P, L)`` of the training samples in ``frame``: the median positive time step within a
    run (s) and the median run length (last minus first sample plus one step, s)."""
    t = times(frame)
    runs = frame["run_id"].astype(str).to_numpy() if "run_id" in frame.columns else np.zeros(len(t))
    steps, lengths = [], []
    for r in pd.unique(runs):
        tr = np.sort(t[runs == r])
        d = np.diff(tr)
        steps.append(d[d > 0])
        lengths.append(float(tr[-1] - tr[0]) if len(tr) else 0.0)
    d = np.concatenate(steps) if steps else np.zeros(0)
    period = float(np.median(d)) if len(d) else 1.0
    return period, float(np.median(lengths)) + period if lengths else period


def _round2(v: float) -> float:
    """``v`` rounded to 2 significant digits."""
    if v <= 0:
        return 0.0
    e = math.floor(math.log10(v)) - 1
    return float(round(v / 10**e) * 10**e)


def resolve(name: str, value, period_s: float, run_s: float) -> list[float]:
    """The grid of setting ``name``: ``value`` as floats, or the ``auto`` grid by its rule in
    :data:`AUTO_RULES`."""
    if not (isinstance(value, str) and value == AUTO):
        if isinstance(value, str):
            raise ValueError(f"{name}={value!r}: give a list of numbers or auto")
        return [float(v) for v in value]
    lead, (lo_unit, lo_k), (hi_unit, hi_k), ratio = AUTO_RULES[name]
    scale = {"P": float(period_s), "L": float(run_s)}
    lo, hi = lo_k * scale[lo_unit], hi_k * scale[hi_unit]
    values, v = [_round2(lo)], lo
    while v * math.sqrt(ratio) < hi * (1 - 1e-9) and len(values) < 50:  # up to the value nearest hi
        v *= ratio
        values.append(_round2(v))
    return [float(x) for x in lead] + sorted(set(values))


def _fmt(values: Sequence[float]) -> str:
    return ", ".join(f"{v:g}" for v in values)


def edge_flags(kind: str, chosen: dict, grids: dict) -> list[str]:
    """Plain-text flags for choices at an edge of their grid.

    ``chosen`` / ``grids`` map a grid's name to the chosen value(s) and the grid: ``alpha``
    (flagged at either end of the grid), a name ending in ``taus_s`` (a chosen set holding the
    largest or the smallest non-zero value; 0, the unfiltered input, is a natural bound), a
    name ending in ``lags_s`` (the largest value, or the smallest where it is not 0: no lag is
    a natural bound). A grid with one value has no edge to flag.
    """
    out = []
    for key, value in chosen.items():
        grid = sorted(float(v) for v in grids.get(key, []))
        if len(grid) < 2 or value is None:
            continue
        if key == "alpha":
            if float(value) in (grid[0], grid[-1]):
                end = "smallest" if float(value) == grid[0] else "largest"
                span = f"{grid[0]:g}..{grid[-1]:g}"
                out.append(f"{kind}: alpha {float(value):g} is the {end} of ridge_alphas ({span})")
        elif key.endswith("taus_s"):
            nonzero = [v for v in grid if v > 0]
            if not nonzero:
                continue
            what = "heat-input time constant" if "speed" in key else "time constant"
            for v in sorted(float(x) for x in value):
                if v <= 0:
                    continue
                if v == nonzero[-1]:
                    out.append(f"{kind}: {what} {v:g} s is the largest of the grid ({_fmt(nonzero)} s)")
                elif v == nonzero[0]:
                    out.append(
                        f"{kind}: {what} {v:g} s is the smallest non-zero value of the grid "
                        f"({_fmt(nonzero)} s)"
                    )
        elif key.endswith("lags_s"):
            v = float(value)
            if v == grid[-1]:
                out.append(f"{kind}: draw-in lag {v:g} s is the largest of the grid ({_fmt(grid)} s)")
            elif v == grid[0] and v > 0:
                out.append(f"{kind}: draw-in lag {v:g} s is the smallest of the grid ({_fmt(grid)} s)")
    return out
