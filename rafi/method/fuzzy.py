"""Fuzzy blending of the per-speed regressions: triangular memberships in spindle speed.

RAFI fits one regression per training speed. For any other speed the compensation
is the membership-weighted sum of the regressions (paper, section "Fuzzy
inference"). Memberships are triangular functions centred on the sorted training
speeds ``c_1 < ... < c_k``: the membership in ``c_j`` is 1 at ``c_j`` and falls
linearly to 0 at the neighbouring centres. For a speed ``n`` with
``c_j <= n <= c_{j+1}`` the only nonzero weights are

    w_j     = (c_{j+1} - n) / (c_{j+1} - c_j)
    w_{j+1} = (n - c_j)     / (c_{j+1} - c_j)

so they always sum to 1 (a partition of unity) and exactly at a centre the weight
of that centre's model is 1.

Reading of the paper's worked example
-------------------------------------
The paper's text says that 4000 r/min lies 1000 and 2000 r/min from 3000 and 6000
r/min "respectively" and that the membership values are 0.334 and 0.666
"respectively". Taken literally that pairs 0.334 with the *nearer* model (3000)
and 0.666 with the farther one (6000), i.e. the farther regression would dominate,
which contradicts the triangular membership functions of the paper's Figure 11 and
the purpose of interpolation (a speed just above 3000 r/min would be predicted
almost entirely by the 6000 r/min model). We follow the triangular reading: 4000
r/min gets 2/3 on the 3000 r/min model and 1/3 on the 6000 r/min model. The paper's
0.334/0.666 are the same two numbers (rounded) assigned the other way round.

Outside the trained range
-------------------------
Below the lowest or above the highest training speed the edge model is used with
weight 1 (no extrapolation in speed), and the sample is flagged ``outside=True``.
Samples whose speed is NaN get NaN weights and ``outside=False``.

This module uses NumPy only (it is imported by the deployable model).
"""

from __future__ import annotations

import numpy as np

__all__ = ["prepare_centres", "triangular_weights", "membership_curves"]


def prepare_centres(centres_rpm) -> tuple[np.ndarray, np.ndarray]:
    """Validate centres; return (sorted centres, order that sorts the input): the ``prepared``
    argument of :func:`triangular_weights` for a caller that weighs one sample at a time."""
    c = np.asarray(centres_rpm, dtype=float).ravel()
    if c.size == 0:
        raise ValueError("centres_rpm is empty; at least one training speed is needed")
    if not np.all(np.isfinite(c)):
        raise ValueError(f"centres_rpm must be finite numbers, got {c.tolist()}")
    order = np.argsort(c, kind="stable")
    cs = c[order]
    if np.any(np.diff(cs) <= 0):
        raise ValueError(f"centres_rpm contains duplicate speeds: {c.tolist()}")
    return cs, order


def triangular_weights(
    speed_rpm, centres_rpm, *, tolerance_rpm: float = 0.0, prepared: tuple | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Triangular fuzzy membership weights of each sample's speed in each training speed.

    Parameters
    ----------
    speed_rpm : array_like, shape (n,) or scalar
        Spindle speed of each sample, r/min.
    centres_rpm : array_like, shape (k,)
        Training speeds (the centres of the membership functions), any order,
        no duplicates. Column ``j`` of the result belongs to ``centres_rpm[j]``.
    tolerance_rpm : float, default 0
        A sample is flagged ``outside`` only if its speed lies more than this
        below the lowest or above the highest centre (measured speeds jitter by a
        few r/min around a set point). The weights do not depend on it.
    prepared : tuple, optional
        :func:`prepare_centres` of ``centres_rpm``, computed once by the caller (the streaming
        compensator weighs one sample at a time); default: computed here.

    Returns
    -------
    weights : ndarray, shape (n, k)
        Membership weights; each row sums to 1 (NaN row for a NaN speed). At most
        two neighbouring entries per row are nonzero.
    outside : ndarray of bool, shape (n,)
        True where the speed is outside the trained range (edge model used).

    Examples
    --------
    >>> w, out = triangular_weights([4000], [3000, 6000, 9000])
    >>> w.round(4).tolist(), out.tolist()
    ([[0.6667, 0.3333, 0.0]], [False])
    """
    cs, order = prepare_centres(centres_rpm) if prepared is None else prepared
    s = np.atleast_1d(np.asarray(speed_rpm, dtype=float)).ravel()
    n, k = s.size, cs.size
    weights_sorted = np.zeros((n, k))
    finite = np.isfinite(s)
    if k == 1:
        weights_sorted[:, 0] = 1.0
    else:
        j = np.clip(np.searchsorted(cs, s, side="right") - 1, 0, k - 2)
        left, right = cs[j], cs[j + 1]
        w_right = np.clip((s - left) / (right - left), 0.0, 1.0)
        rows = np.arange(n)
        weights_sorted[rows, j] = 1.0 - w_right
        weights_sorted[rows, j + 1] = w_right
    weights_sorted[~finite] = np.nan
    outside = finite & ((s < cs[0] - tolerance_rpm) | (s > cs[-1] + tolerance_rpm))
    weights = np.empty_like(weights_sorted)
    weights[:, order] = weights_sorted
    return weights, outside


def membership_curves(centres, grid) -> np.ndarray:
    """Membership functions evaluated on a speed grid, for plotting (paper Figure 11).

    Parameters
    ----------
    centres : array_like, shape (k,)
        Training speeds, r/min.
    grid : array_like, shape (m,)
        Speeds at which to evaluate, r/min.

    Returns
    -------
    ndarray, shape (m, k)
        Column ``j`` is the membership function of ``centres[j]`` on ``grid``
        (edge memberships stay 1 beyond the trained range, as used for blending).
    """
    weights, _ = triangular_weights(grid, centres)
    return weights
