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

Non-finite predictions: a kind that predicts nothing finite on a whole held-out unit gets weight
0 (the selection would never pick it); a sample where a kind that enters is NaN (a sensor's
dropout) is left out of the fit, as the CV's metrics leave it out of the kind's score.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
from scipy.optimize import nnls

from rafi.family.intervals import unit_weights

__all__ = ["simplex_least_squares", "residual_matrix", "sample_weights", "usable_kinds", "stacked_weights"]

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
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Out-of-fold residuals of every kind, one row per held-out sample.

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
    (numpy.ndarray, numpy.ndarray, numpy.ndarray)
        ``(n, len(kinds))`` residuals (NaN where the kind predicted NaN), and per row its
        held-out unit and its scheme. Samples without a finite residual of any kind (no
        measurement) are dropped.
    """
    blocks, units, schemes = [], [], []
    for scheme, o in oofs.items():
        if not len(o):
            continue
        o = o.set_index([*KEY, "model"])
        r = _wide(o["residual_um"], kinds)
        # no row at all: the kind could not fit that fold, which the CV scores as predicting 0
        missing = ~np.isfinite(_wide(o["residual_um"].notna().astype(float) + 1.0, kinds))
        index = o.index.droplevel("model").unique()
        dz = dz_at.reindex(pd.MultiIndex.from_arrays([index.get_level_values(c) for c in KEY[1:]]))
        r[missing] = np.broadcast_to(dz.to_numpy(dtype=float)[:, None], r.shape)[missing]
        keep = np.isfinite(r).any(axis=1)
        blocks.append(r[keep])
        units.append(index.get_level_values("unit").astype(str).to_numpy()[keep])
        schemes.append(np.full(int(keep.sum()), scheme, dtype=object))
    if not blocks:
        return np.empty((0, len(kinds))), np.empty(0, dtype=object), np.empty(0, dtype=object)
    return np.vstack(blocks), np.concatenate(units), np.concatenate(schemes)


def _wide(values: pd.Series, kinds: Sequence[str]) -> np.ndarray:
    """``values`` indexed by ``(*KEY, model)`` as a matrix: one row per key (in the order of
    first appearance), one column per kind; NaN where the kind has no row."""
    keys = values.index.droplevel("model").unique()
    return np.array(values.unstack("model").reindex(index=keys, columns=list(kinds)), dtype=float)


def sample_weights(units: np.ndarray, schemes: np.ndarray) -> np.ndarray:
    """Per sample, ``1 / (schemes * units of its scheme * samples of its unit)``: every scheme
    weighs the same in total and every held-out unit the same within its scheme; the sum is 1."""
    out = np.empty(len(units))
    names = pd.unique(np.asarray(schemes, dtype=object))
    for scheme in names:
        mine = np.asarray(schemes, dtype=object) == scheme
        held = np.asarray(units)[mine]
        out[mine] = unit_weights(held) / len(np.unique(held.astype(str))) / len(names)
    return out


def usable_kinds(r: np.ndarray, units: np.ndarray) -> list[int]:
    """The columns of ``r`` with a finite residual on some sample of every held-out unit: a kind
    with none on a unit cannot predict that run, which the selection scores as infinite
    (:func:`rafi.family.selection.choose_champion` never picks it), so it gets no weight. A NaN
    on a few samples (a sensor's dropout) is skipped, as the CV's metrics skip it."""
    finite = pd.DataFrame(np.isfinite(r)).groupby(np.asarray(units)).any()
    return [i for i in range(r.shape[1]) if len(finite) and bool(finite[i].all())]


def stacked_weights(oofs: Mapping[str, pd.DataFrame], kinds: Sequence[str], dz_at: pd.Series) -> dict:
    """The super learner's weights: kind -> weight over ``kinds``, fitted on the samples where
    every usable kind (:func:`usable_kinds`) has a finite residual, with :func:`sample_weights`;
    a kind that is not usable gets 0. Empty when no kind is usable (or there is no sample)."""
    r, units, schemes = residual_matrix(oofs, kinds, dz_at)
    # a unit is (scheme, unit): forward units are already distinct from the whole-run ones
    usable = usable_kinds(r, units)
    rows = np.isfinite(r[:, usable]).all(axis=1) if usable else np.zeros(len(r), bool)
    if not rows.any():
        return {}
    w = sample_weights(units[rows], schemes[rows])
    fitted = simplex_least_squares(np.sqrt(w)[:, None] * r[np.ix_(rows, usable)])
    out = dict.fromkeys(kinds, 0.0)
    out.update({kinds[i]: float(v) for i, v in zip(usable, fitted)})
    return out
