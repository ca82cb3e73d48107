"""The training envelope of a ridge kind: outside it, each feature is held at the envelope's edge.

A linear model extrapolates without limit: a `dynamic` ridge whose penalty sat at the edge of its
grid scored 228 um test MAE (864 um max) on a turning centre whose test days lay mostly above the
training temperatures, where no compensation was 23 um (issue 46). So every ridge kind records, at
its fit, the range of each of its features over the training rows (a rise, a filtered rise, a
speed term, a heat input), and predicts from the features *bounded* to that range widened by
:data:`ENVELOPE_MARGIN` of its span on each side: inside the envelope nothing changes, outside it
the model holds the value it has at the envelope's edge instead of extrapolating freely. The
artefact carries the envelope (``envelope``: ``margin`` and ``feature_ranges``), so the streaming
compensator bounds exactly as the batch code does (:mod:`rafi.deploy.compensator`); an artefact
without it is evaluated unbounded, as it was fitted.

NumPy only (the compensator imports it).
"""

from __future__ import annotations

import numpy as np

__all__ = ["ENVELOPE_MARGIN", "bound_features", "envelope_bounds", "fit_envelope", "join_envelope"]

#: The share of a feature's training span the envelope extends beyond it on each side. One span:
#: on the twin's linear physics a test at 1.5 x the highest trained speed loses 0.03 um against the
#: free extrapolation (0.1 of a span lost 3.5 um, ``tests/test_envelope.py``), while a model whose
#: features leave their training range far (a runaway) is held at most one span beyond it.
ENVELOPE_MARGIN = 1.0


def fit_envelope(features: np.ndarray, margin: float = ENVELOPE_MARGIN) -> dict:
    """The envelope of training ``features`` (rows x features) as the artefact records it.

    A feature without a finite training value gets ``[null, null]`` (never bounded).
    """
    x = np.asarray(features, dtype=float)
    ranges = []
    for column in x.T:
        finite = column[np.isfinite(column)]
        ranges.append([float(finite.min()), float(finite.max())] if finite.size else [None, None])
    return {"margin": float(margin), "feature_ranges": ranges}


def join_envelope(envelope: dict | None, features: np.ndarray) -> dict:
    """``envelope`` (a prior's) joined with the range of new training ``features``: an adapted
    model stands on both (:mod:`rafi.family.adapted`). Without a prior envelope: the new one."""
    new = fit_envelope(features, ENVELOPE_MARGIN if not envelope else float(envelope["margin"]))
    if not envelope or len(envelope["feature_ranges"]) != len(new["feature_ranges"]):
        return new
    joined = []
    for (a, b), (c, d) in zip(envelope["feature_ranges"], new["feature_ranges"]):
        lows = [v for v in (a, c) if v is not None]
        highs = [v for v in (b, d) if v is not None]
        joined.append([min(lows) if lows else None, max(highs) if highs else None])
    return {"margin": new["margin"], "feature_ranges": joined}


def envelope_bounds(envelope: dict | None, n_features: int) -> tuple[np.ndarray, np.ndarray] | None:
    """``(low, high)`` per feature: the training range widened by the margin (infinite where a
    feature has no range); None without an envelope (an artefact fitted before it).

    Raises
    ------
    ValueError
        An envelope of another number of features than the model's.
    """
    if not envelope:
        return None
    ranges = envelope["feature_ranges"]
    if len(ranges) != n_features:
        raise ValueError(f"the envelope has {len(ranges)} features, the model {n_features}")
    lo = np.array([-np.inf if a is None else float(a) for a, _ in ranges])
    hi = np.array([np.inf if b is None else float(b) for _, b in ranges])
    with np.errstate(invalid="ignore"):
        pad = float(envelope["margin"]) * np.where(np.isfinite(hi - lo), hi - lo, 0.0)
    return lo - pad, hi + pad


def bound_features(features: np.ndarray, bounds) -> tuple[np.ndarray, np.ndarray]:
    """``features`` held inside ``bounds`` (:func:`envelope_bounds`) and, per row, whether any
    feature was outside (NaN stays NaN and is never outside). Without bounds: unchanged."""
    x = np.asarray(features, dtype=float)
    if bounds is None:
        return x, np.zeros(x.shape[:-1], dtype=bool)
    lo, hi = bounds
    with np.errstate(invalid="ignore"):
        outside = ((x < lo) | (x > hi)).any(axis=-1)
    return np.clip(x, lo, hi), outside
