"""The stacked ensemble (super learner) of ``bench_selection_rules.py``: simplex weights over the
family's kinds fitted on their out-of-fold predictions.

The weights ``w`` (``w >= 0``, ``sum w = 1``) minimise the weighted squared error of
``sum_k w_k * OOF_k`` over the held-out samples of the CV on the training runs. Because the
weights sum to 1, the ensemble's residual is ``dz - sum_k w_k pred_k = sum_k w_k r_k``: the fit
needs the out-of-fold residuals alone (:data:`rafi.family.intervals.OOF_COLUMNS`, what
:func:`rafi.family.crossval.cross_validate` returns with ``oof=``), no second copy of the data.

Sample weights: every CV scheme (whole-run, forward) weighs the same in total, and within a
scheme every held-out unit (a run of a fold: ``f<fold>:<run>`` under forward folds) weighs the
same, ``1 / (samples of the unit)`` per sample, so a long run does not outweigh a short one.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
from scipy.optimize import nnls

__all__ = ["simplex_least_squares", "residual_matrix", "stacked_weights"]

#: The key of one out-of-fold sample within a scheme.
KEY = ["unit", "run_id", "t_s"]


def simplex_least_squares(a: np.ndarray, b: np.ndarray | None = None) -> np.ndarray:
    """``argmin ||a w - b||^2`` subject to ``w >= 0`` and ``sum(w) = 1``.

    Parameters
    ----------
    a : numpy.ndarray
        ``(n, k)`` design, finite.
    b : numpy.ndarray, optional
        ``(n,)`` target; zeros when omitted (the residual form of :func:`stacked_weights`).

    Returns
    -------
    numpy.ndarray
        ``(k,)`` weights on the simplex.

    Notes
    -----
    :func:`scipy.optimize.nnls` on the standard augmentation: one more row ``M * 1`` with target
    ``M``, ``M`` far above the scale of ``a`` and ``b``, so that a violation of ``sum w = 1`` costs
    far more than any fit; the small remaining violation is removed by normalising.
    """
    a = np.asarray(a, dtype=float)
    b = np.zeros(len(a)) if b is None else np.asarray(b, dtype=float)
    k = a.shape[1]
    if k == 1:
        return np.ones(1)
    scale = max(float(np.linalg.norm(a)), float(np.linalg.norm(b)), 1e-12)
    big = 1e3 * scale
    design = np.vstack([a, np.full((1, k), big)])
    target = np.append(b, big)
    w, _ = nnls(design, target, maxiter=50 * k)
    total = w.sum()
    return w / total if total > 0 else np.full(k, 1.0 / k)


def residual_matrix(
    oofs: Mapping[str, pd.DataFrame], kinds: Sequence[str], dz_at: pd.Series
) -> tuple[np.ndarray, np.ndarray]:
    """Out-of-fold residuals of every kind, one row per held-out sample, and the sample weights.

    Parameters
    ----------
    oofs : mapping
        Scheme -> the OOF samples of every kind under it (``model`` = kind); a scheme with no
        sample is left out.
    kinds : sequence of str
        The columns, in order.
    dz_at : pandas.Series
        The measured displacement indexed by ``(run_id, t_s)``: the residual of a kind that
        could not fit a fold (no OOF sample there), which the CV scores as a prediction of 0.

    Returns
    -------
    (numpy.ndarray, numpy.ndarray)
        ``(n, len(kinds))`` residuals (NaN where the kind predicted NaN) and ``(n,)`` weights
        summing to 1 (each scheme equally, each unit equally within it). Samples without a
        finite residual of any kind (no measurement) are dropped.
    """
    blocks, weights = [], []
    schemes = [s for s, o in oofs.items() if len(o)]
    for scheme in schemes:
        o = oofs[scheme].set_index([*KEY, "model"])
        r = _wide(o["residual_um"], kinds)
        # no row at all: the kind could not fit that fold, which the CV scores as predicting 0
        missing = ~np.isfinite(_wide(o["residual_um"].notna().astype(float) + 1.0, kinds))
        index = o.index.droplevel("model").unique()
        dz = dz_at.reindex(pd.MultiIndex.from_arrays([index.get_level_values(c) for c in KEY[1:]]))
        r[missing] = np.broadcast_to(dz.to_numpy(dtype=float)[:, None], r.shape)[missing]
        keep = np.isfinite(r).any(axis=1)
        units = index.get_level_values("unit").astype(str).to_numpy()[keep]
        _, inverse, counts = np.unique(units, return_inverse=True, return_counts=True)
        blocks.append(r[keep])
        weights.append(1.0 / counts[inverse] / len(counts) / len(schemes))
    if not blocks:
        return np.empty((0, len(kinds))), np.empty(0)
    return np.vstack(blocks), np.concatenate(weights)


def _wide(values: pd.Series, kinds: Sequence[str]) -> np.ndarray:
    """``values`` indexed by ``(*KEY, model)`` as a matrix: one row per key (in the order of
    first appearance), one column per kind; NaN where the kind has no row."""
    keys = values.index.droplevel("model").unique()
    return np.array(values.unstack("model").reindex(index=keys, columns=list(kinds)), dtype=float)


def stacked_weights(oofs: Mapping[str, pd.DataFrame], kinds: Sequence[str], dz_at: pd.Series) -> dict:
    """The super learner's weights: kind -> weight, over ``kinds`` (:func:`residual_matrix`);
    a kind whose out-of-fold prediction is not finite on some sample gets 0 and does not enter
    the fit. Empty when no kind has a finite prediction everywhere (or there is no sample)."""
    r, w = residual_matrix(oofs, kinds, dz_at)
    usable = [i for i, _ in enumerate(kinds) if len(r) and np.isfinite(r[:, i]).all()]
    if not usable:
        return {}
    fitted = simplex_least_squares(np.sqrt(w)[:, None] * r[:, usable])
    out = dict.fromkeys(kinds, 0.0)
    out.update({kinds[i]: float(v) for i, v in zip(usable, fitted)})
    return out
