"""Cutting one log into runs by its speed (steps 0-7 of :mod:`rafi.method.runs`' docstring).

:func:`split_log` cuts every segment of a log with :func:`segment_runs` (smoothed speed ->
idle samples -> pieces of near-constant speed (:func:`speed_pieces`) -> constant and varying
stretches, ramps absorbed, stops inside a schedule merged, a short rest at the start absorbed);
:func:`cut_at` cuts the runs again at the boundaries of time windows. Runs are
:class:`RunSpan`: row indices of the log, never crossing a segment.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pandas as pd

#: Width (s) of the centred rolling median applied to the speed before cutting it into
#: pieces (at least 3 samples): removes speed noise and isolated ramp samples, keeps steps sharp.
SPEED_SMOOTH_S = 60.0

#: A varying stretch of at most this many samples next to a constant run is a ramp.
RAMP_MAX_SAMPLES = 3


class RunSpan(NamedTuple):
    """One run of a log: rows ``start:end`` of the segment ``seg_start:seg_end`` (row indices of
    the log), its kind and the number of rest samples it absorbed at its start."""

    segment: int
    seg_start: int
    seg_end: int
    start: int
    end: int
    kind: str
    rest: int


def sample_period(t_s: np.ndarray, seg: np.ndarray) -> float:
    """The median time step inside segments (1 s without one)."""
    if len(t_s) < 2:
        return 1.0
    d = np.diff(t_s)[seg[1:] == seg[:-1]]
    d = d[d > 0]
    return float(np.median(d)) if len(d) else 1.0


def speed_pieces(speed: np.ndarray, idle: np.ndarray, tol: float) -> list[list]:
    """Pieces ``[start, end_exclusive, is_idle]`` of one segment, in time order.

    Idle stretches (``idle``) are one piece each; a non-idle piece continues while the speed
    stays within ``tol`` of the speed at its first sample, and adjacent non-idle pieces whose
    medians differ by at most ``tol`` are merged again (speed noise around one set point).
    """
    n = len(speed)
    pieces: list[list] = []
    change = np.flatnonzero(np.diff(idle.astype(np.int8))) + 1
    bounds = np.concatenate(([0], change, [n]))
    for a, b in zip(bounds[:-1], bounds[1:]):
        if idle[a]:
            pieces.append([a, b, True])
            continue
        i = a
        while i < b:
            anchor = speed[i]
            j, w = i + 1, 64
            end = b
            while j < b:
                stop = min(b, j + w)
                out = np.abs(speed[j:stop] - anchor) > tol
                if out.any():
                    end = j + int(np.argmax(out))
                    break
                j, w = stop, w * 2
            pieces.append([i, end, False])
            i = end
    # merge adjacent non-idle pieces whose medians agree (speed noise around one set point)
    merged: list[list] = []
    for p in pieces:
        if merged and not p[2] and not merged[-1][2] and merged[-1][1] == p[0]:
            q = merged[-1]
            if abs(np.median(speed[q[0] : q[1]]) - np.median(speed[p[0] : p[1]])) <= tol:
                q[1] = p[1]
                continue
        merged.append(list(p))
    return merged


def segment_runs(
    speed: np.ndarray,
    period: float,
    *,
    tol: float,
    idle_below: float,
    min_constant_s: float,
    max_leading_rest_s: float = 0.0,
) -> list[tuple[int, int, str, int]]:
    """Runs ``(start, end_exclusive, kind, rest_samples)`` of one segment, in time order.

    ``rest_samples`` > 0 for a run that absorbed the segment's leading rest (its first
    ``rest_samples`` samples are the rest, idle).
    """
    win = max(3, 2 * int(round(SPEED_SMOOTH_S / 2 / period)) + 1)
    smooth = pd.Series(speed).rolling(win, center=True, min_periods=1).median().to_numpy()
    idle = ~(smooth >= idle_below)  # NaN speed counts as idle
    pieces = speed_pieces(smooth, idle, tol)
    min_const_n = min_constant_s / period
    groups: list[list] = []  # [start, end_exclusive, kind]
    for a, b, is_idle in pieces:
        kind = "idle" if is_idle else ("constant" if (b - a) >= min_const_n - 1e-9 else "varying")
        if kind == "varying" and groups and groups[-1][2] == "varying" and groups[-1][1] == a:
            groups[-1][1] = b  # consecutive short pieces: one stretch
        else:
            groups.append([a, b, kind])
    # ramps: a tiny varying stretch next to a constant run is absorbed by it
    kept: list[list] = []
    for k, g in enumerate(groups):
        if g[2] == "varying" and g[1] - g[0] <= RAMP_MAX_SAMPLES:
            nxt = groups[k + 1] if k + 1 < len(groups) else None
            if nxt is not None and nxt[2] == "constant" and nxt[0] == g[1]:
                nxt[0] = g[0]
                continue
            if kept and kept[-1][2] == "constant" and kept[-1][1] == g[0]:
                kept[-1][1] = g[1]
                continue
        kept.append(g)
    # a short idle stretch between two varying stretches is a stop inside the schedule
    out: list[list] = []
    for g in kept:
        if out and g[2] == "varying" and out[-1][2] == "varying":
            out[-1][1] = g[1]
            continue
        if (
            len(out) >= 2
            and g[2] == "varying"
            and out[-1][2] == "idle"
            and out[-2][2] == "varying"
            and (out[-1][1] - out[-1][0]) < min_const_n
        ):
            out.pop()
            out[-1][1] = g[1]
            continue
        out.append(g)
    rest = [0] * len(out)
    # a short rest at the segment start belongs to the following run (cold start from rest)
    if (
        len(out) >= 2
        and out[0][2] == "idle"
        and out[1][2] != "idle"
        and out[0][0] == 0
        and (out[0][1] - out[0][0]) * period < float(max_leading_rest_s) - 1e-9
    ):
        n_rest = out[0][1] - out[0][0]
        out[1][0] = out[0][0]
        out.pop(0)
        rest = [n_rest] + [0] * (len(out) - 1)
    return [(int(a), int(b), kind, int(r)) for (a, b, kind), r in zip(out, rest)]


def split_log(
    speed: np.ndarray,
    segment: np.ndarray,
    period: float,
    *,
    tol: float,
    idle_below: float,
    min_constant_s: float,
    max_leading_rest_s: float,
) -> list[RunSpan]:
    """The runs of every segment of a log (:func:`segment_runs` on each), in time order.

    ``speed`` and ``segment`` are the log's speed and segment per sample; ``period`` its
    sample period. Returns row indices of the log.
    """
    spans = []
    change = np.flatnonzero(segment[1:] != segment[:-1]) + 1
    for s0, s1 in zip(np.concatenate(([0], change)), np.concatenate((change, [len(segment)]))):
        for a, b, kind, rest in segment_runs(
            speed[s0:s1],
            period,
            tol=tol,
            idle_below=idle_below,
            min_constant_s=min_constant_s,
            max_leading_rest_s=max_leading_rest_s,
        ):
            spans.append(
                RunSpan(int(segment[s0]), int(s0), int(s1), int(s0 + a), int(s0 + b), kind, int(rest))
            )
    return spans


def cut_at(found: list[RunSpan], cuts: np.ndarray) -> list[RunSpan]:
    """``found`` runs split at the sample indices ``cuts`` (window boundaries)."""
    out = []
    for segment, s0, s1, a, b, kind, rest in found:
        inner = [int(c) for c in cuts if a < c < b]
        for x, y in zip([a, *inner], [*inner, b]):
            out.append(RunSpan(segment, s0, s1, x, y, kind, min(rest, y - x) if x == a else 0))
    return out
