"""The CV-weighted ensemble: the family's kinds blended by their whole-run cross-validation scores.

Judged one level up (``docs/decisions.md``, 2026-11-29, "the selection rules across real logs and
foreign machines"): offering the weighted mean of every kind's prediction beat choosing one kind by
its CV score, on 22 foreign machines and on 5 of the 6 real-log channels. The weights are
``w_k ~ 1 / s_k^2``, ``s_k`` the kind's mean over the whole-run held-out runs of the max |residual|
(``comparison/cv.csv``, the forward folds left out), over the kinds with a finite, positive score
(:func:`cv_weights`): an inverse-variance weighting with the CV loss as the scale, fixed before any
validation run is predicted. The members (:func:`ensemble_members`) are the enabled kinds but RAFI's
two (:data:`NOT_MEMBERS`, fitted, scored and reported as always, not blended), and the plain ridge.

The prediction of a row is the weighted mean of the members' predictions over the members that
have a value there (:func:`blend`: the weights of the others are set aside and the rest
renormalised; no member with a value, no value). The flags are any member's; ``range_excess`` the
largest member's. The members are the fitted models themselves: each keeps its own filters,
reference, envelope and output cap. The ridge kinds cap their own prediction at the training
displacement range widened by :data:`rafi.family.envelope.OUTPUT_MARGIN` spans; RAFI's kinds, the
paper's method, do not, so the ensemble holds **every** member's prediction inside that same
range (``envelope.output_range`` of its artefact, a ridge member's) before it blends: no member
runs away inside the offered model (``outside_envelope`` marks the rows where one was held).

Its CV figures (:func:`ensemble_oof`, :func:`ensemble_cv_rows`) are the members' out-of-fold
residuals blended with the weights chosen from the same CV: optimistic by the choice of a handful
of weights (the one-level-up judge above is the honest figure), and without the cap on RAFI's
kinds (a fold's own training range is not in the OOF samples; a held-out training run seldom
leaves two spans). Its prediction interval is
calibrated on those blended residuals like every kind's on its own.

Artefact (``kind: ensemble``): ``weights`` (member name -> weight, summing to 1), ``members``
(name -> the member's own ``rafi.model/1`` artefact, with its own ``model_id``), and the union of
the members' ``key_sensors``, ``regressor_ranges``, ``speed_range_rpm``, ``train_runs`` and
``data``; ``trained_speeds_rpm`` (the constant training runs' speeds, where there are any);
``hyperparameters: filter_restart_gap_s`` is the shortest member's (the interval's change
clock restarts with the first member that restarts); ``envelope`` (``output_range``,
``output_margin``: the bound every member's prediction is held in; absent when no member has one);
``adaptation``: an ensemble prior re-qualified as a whole
(:class:`~rafi.family.adapted.SharedAdaptedEnsemble`), kept as read.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rafi.family.base import CODE_VERSION, FamilyModel, check_artefact, finish_artefact
from rafi.family.envelope import OUTPUT_MARGIN, bound_output, output_bounds
from rafi.family.forward_folds import fold_unit, is_forward

__all__ = [
    "ENSEMBLE",
    "NOT_MEMBERS",
    "WEIGHT_RULE",
    "WeightedEnsemble",
    "cv_weights",
    "ensemble_members",
    "blend",
    "ensemble_oof",
    "ensemble_cv_rows",
]

#: The ensemble's name in ``comparison/*.csv`` and its artefact's ``kind``.
ENSEMBLE = "ensemble"

#: The weighting, for people (the artefact and the report state it).
WEIGHT_RULE = (
    "weights proportional to 1 / s^2, s = the kind's mean over the held-out training runs (time "
    "blocks, where the training data hold too few runs) of the max |residual|; each row blends the "
    "members that have a value there"
)


#: The kinds fitted, scored and reported in every comparison but not blended: RAFI's per-speed
#: OLS, the paper's method, and its linear-in-speed variant. Judged one level up
#: (``docs/decisions.md``, 2026-11-29, "a robust blend and fewer members"): without them the
#: ensemble was as good on foreign machines (within one SE) and better on FL_THERMAL's training
#: runs, with two members fewer to run on the machine.
NOT_MEMBERS = ("rafi", "rafi_linear")


def ensemble_members(enabled, *, floor: str) -> list[str]:
    """The models the ensemble may blend: the ``enabled`` kinds but :data:`NOT_MEMBERS`, then the
    plain ridge ``floor`` (a member even where it is not enabled), each once, in that order."""
    return list(dict.fromkeys([*(k for k in enabled if k not in NOT_MEMBERS), floor]))


def cv_weights(cv: pd.DataFrame, members) -> dict[str, float]:
    """The ensemble's weights from the whole-run CV rows of ``comparison/cv.csv``.

    Parameters
    ----------
    cv : pandas.DataFrame
        :func:`rafi.family.crossval.cross_validate` rows (``model``, ``scheme``,
        ``max_abs_after_um``); rows of a forward scheme are left out.
    members : sequence of str
        The models that may enter, in the order of the result.

    Returns
    -------
    dict
        Member -> weight (summing to 1) over the members whose mean held-out max |residual| is
        finite and positive (a held-out run a member could not predict makes it infinite); empty
        when fewer than two such members remain (no blend).
    """
    if cv is None or not len(cv):
        return {}
    whole = cv.loc[~cv["scheme"].astype(str).map(is_forward).to_numpy(dtype=bool)]
    scores = {}
    for name in members:
        mine = whole["model"].astype(str) == str(name)
        mx = pd.to_numeric(whole.loc[mine, "max_abs_after_um"], errors="coerce").to_numpy(dtype=float)
        mean = float(mx.mean()) if len(mx) and np.isfinite(mx).all() else np.inf
        if np.isfinite(mean) and mean > 0:
            scores[str(name)] = mean
    if len(scores) < 2:
        return {}
    inverse = {k: 1.0 / s**2 for k, s in scores.items()}
    total = sum(inverse.values())
    return {k: v / total for k, v in inverse.items()}


def blend(predictions: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The weighted mean of each row over its finite entries.

    Parameters
    ----------
    predictions : ndarray, shape (n, k)
        One column per member.
    weights : ndarray, shape (k,)
        Non-negative weights.

    Returns
    -------
    ndarray, shape (n,)
        ``sum_k w_k p_k / sum_k w_k`` over the finite ``p_k`` of the row; NaN where none is finite.
    """
    p = np.asarray(predictions, dtype=float)
    w = np.broadcast_to(np.asarray(weights, dtype=float), p.shape)
    have = np.isfinite(p)
    total = np.where(have, w, 0.0).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        out = np.where(have, w * np.where(have, p, 0.0), 0.0).sum(axis=1) / total
    return np.where(total > 0, out, np.nan)


def ensemble_oof(oof: pd.DataFrame, weights: dict, name: str = ENSEMBLE) -> pd.DataFrame:
    """The ensemble's out-of-fold samples from its members' (same columns as ``oof``).

    Every member held out the same runs in the same folds, so a sample is the same
    (``unit``, ``run_id``, ``t_s``) in every member's rows; the ensemble's residual is the blend of
    the members' residuals (:func:`blend`; the measured value is common to all), ``outside`` any
    member's, ``excess`` the largest, ``since_change_s`` the shortest (the clock of the first
    member that restarted).
    """
    cols = list(oof.columns)
    if not weights or not len(oof):
        return oof.iloc[0:0]
    names = list(weights)
    mine = oof.loc[oof["model"].astype(str).isin(names)]
    key = ["unit", "run_id", "t_s"]
    values = ["residual_um", "since_change_s", "excess"]
    wide = mine.assign(model=mine["model"].astype(str)).set_index([*key, "model"])[values].unstack("model")
    flags = mine.assign(outside=mine["outside"].astype(bool)).groupby(key, sort=True)["outside"].any()
    seen = set(mine["model"].astype(str).unique())
    present = [n for n in names if n in seen]
    residual = blend(wide["residual_um"][present].to_numpy(dtype=float), [weights[n] for n in present])
    out = pd.DataFrame(
        {
            "model": name,
            **{k: wide.index.get_level_values(k) for k in key},
            "residual_um": residual,
            "since_change_s": np.nanmin(wide["since_change_s"][present].to_numpy(dtype=float), axis=1),
            "outside": flags.reindex(wide.index).fillna(False).to_numpy(dtype=bool),
            "excess": np.nanmax(np.nan_to_num(wide["excess"][present].to_numpy(dtype=float)), axis=1),
        }
    )
    order = mine.drop_duplicates(key)[key]  # the members' own row order (units, then time)
    out = order.merge(out, on=key, how="left")
    return out[cols].reset_index(drop=True)


def ensemble_cv_rows(cv: pd.DataFrame, oof: pd.DataFrame, name: str = ENSEMBLE) -> pd.DataFrame:
    """The ensemble's ``comparison/cv.csv`` rows from its OOF samples (:func:`ensemble_oof`).

    Each (fold, held-out run) row of the members (``cv``, the first member's row as the template)
    gets the ensemble's ``max_abs_after_um``, ``rmse_um`` and ``improvement_pct`` over the samples
    the blend predicted, and ``n_unpredicted`` (measured samples without a value).
    """
    if not len(oof) or not len(cv):
        return cv.iloc[0:0]
    first = str(cv["model"].iloc[0])
    template = cv.loc[cv["model"].astype(str) == first]
    residual = dict(tuple(oof.groupby(oof["unit"].astype(str), sort=False)["residual_um"]))
    rows = []
    for row in template.to_dict("records"):
        unit = _unit(row)
        r = residual.get(unit)
        out = {**row, "model": name}
        r = np.asarray(r, dtype=float) if r is not None else np.zeros(0)
        ok = np.isfinite(r)
        before = float(row["max_abs_before_um"])
        after = float(np.max(np.abs(r[ok]))) if ok.any() else np.nan
        out["max_abs_after_um"] = after
        out["rmse_um"] = float(np.sqrt(np.mean(r[ok] ** 2))) if ok.any() else np.nan
        gain = before > 0 and np.isfinite(after)
        out["improvement_pct"] = 100.0 * (1.0 - after / before) if gain else np.nan
        out["n_samples"] = int(ok.sum())
        out["n_unpredicted"] = 0
        out["unpredicted_inputs"] = ""
        rows.append(out)
    return pd.DataFrame(rows, columns=cv.columns)


def _unit(row: dict) -> str:
    """The OOF unit of one CV row: the held-out run, or ``f<fold>:<run>`` in a forward fold."""
    run = str(row["test_runs"])
    return fold_unit(int(row["fold"]), run) if is_forward(str(row["scheme"])) else run


def _union_ranges(ranges: list[dict]) -> dict:
    out: dict = {}
    for rng in ranges:
        for sensor, (lo, hi) in (rng or {}).items():
            a, b = out.get(sensor, (np.inf, -np.inf))
            out[sensor] = [float(min(a, lo)), float(max(b, hi))]
    return out


class WeightedEnsemble(FamilyModel):
    """The CV-weighted ensemble of fitted models (module docstring).

    It learns nothing itself: its members are fitted models and its weights come from their
    cross-validation (:func:`cv_weights`), so it is built from them (:meth:`from_fitted`) or from
    its artefact (:meth:`from_dict`), never by ``fit``.

    Parameters
    ----------
    machine : str or None
        The machine (the artefact's ``machine``).

    Attributes
    ----------
    members_ : dict
        Name -> fitted model, in the order of ``weights_``.
    weights_ : dict
        Name -> weight (summing to 1).
    interval_ : dict or None
        The prediction interval block (:func:`rafi.family.intervals.set_interval`).
    grid_edges_ : list of str
        Every member's grid-edge flags, prefixed by its name.
    """

    kind = ENSEMBLE

    def __init__(self, *, machine: str | None = None):
        self.machine = machine

    def fit(self, runs_table: pd.DataFrame, runs_frame: pd.DataFrame):
        raise TypeError("a WeightedEnsemble is built from fitted members (from_fitted), not fitted")

    @classmethod
    def from_fitted(
        cls, members: dict, weights: dict, *, machine: str | None = None, trained_speeds_rpm=None
    ) -> WeightedEnsemble:
        """The ensemble of the fitted ``members`` (name -> model) with ``weights`` (name -> weight).

        Only the members named in ``weights`` enter; the weights are renormalised to sum to 1.
        ``trained_speeds_rpm``: the speeds of the constant training runs (RAFI's speed groups),
        recorded for people and ``rafi plan`` (its members record a range only); None: not said.
        """
        names = [n for n in weights if n in members]
        if len(names) < 2:
            raise ValueError(f"an ensemble needs two members with a weight; got {names}")
        total = float(sum(weights[n] for n in names))
        m = cls(machine=machine)
        m.members_ = {n: members[n] for n in names}
        m.weights_ = {n: float(weights[n]) / total for n in names}
        m.interval_ = None
        bounds = [_output_part(getattr(members[n], "envelope_", None)) for n in names]
        m.envelope_ = next((b for b in bounds if b is not None), None)
        m.grid_edges_ = [f"{n}: {e}" for n in names for e in getattr(members[n], "grid_edges_", [])]
        m.trained_speeds_rpm_ = None if trained_speeds_rpm is None else [float(v) for v in trained_speeds_rpm]
        return m

    def predict_detail(self, frame: pd.DataFrame) -> pd.DataFrame:
        """``predicted_um`` (the blend), the members' flags (any) and ``range_excess`` (largest)."""
        details = [self.members_[n].predict_detail(frame) for n in self.weights_]
        w = np.array(list(self.weights_.values()))
        held, beyond = bound_output(
            np.column_stack([d["predicted_um"].to_numpy(dtype=float) for d in details]),
            output_bounds(self.envelope_),
        )
        pred = blend(held, w)
        unbounded = np.column_stack(
            [d.get("unbounded_um", d["predicted_um"]).to_numpy(dtype=float) for d in details]
        )

        def any_of(col):
            return np.column_stack(
                [d[col].to_numpy(dtype=bool) if col in d else np.zeros(len(d), bool) for d in details]
            ).any(axis=1)

        none = pd.Series(0.0, index=frame.index)
        excess = np.column_stack(
            [np.nan_to_num(d.get("range_excess", none).to_numpy(dtype=float)) for d in details]
        )
        return pd.DataFrame(
            {
                "predicted_um": pred,
                "outside_speed_range": any_of("outside_speed_range"),
                "outside_temp_range": any_of("outside_temp_range"),
                "outside_envelope": any_of("outside_envelope") | beyond.any(axis=1),
                "unbounded_um": blend(unbounded, w),
                "range_excess": excess.max(axis=1),
            },
            index=frame.index,
        )

    def to_dict(self) -> dict:
        """The ``rafi.model/1`` artefact: the members' own artefacts and the weights."""
        # a member's ``created`` is when this artefact was written, not part of the member
        arts = {n: _without_created(m.to_dict()) for n, m in self.members_.items()}
        first = next(iter(arts.values()))
        sensors = list(dict.fromkeys(s for a in arts.values() for s in a.get("key_sensors", [])))
        speeds = [a["speed_range_rpm"] for a in arts.values() if a.get("speed_range_rpm") is not None]
        lows = [float(lo) for lo, _ in speeds if lo is not None]
        highs = [float(hi) for _, hi in speeds if hi is not None]
        gaps = [
            float((a.get("hyperparameters") or {}).get("filter_restart_gap_s", np.inf)) for a in arts.values()
        ]
        data = {}
        for a in arts.values():
            data.update(a.get("data") or {})
        body = {
            "kind": self.kind,
            "machine": self.machine if self.machine is not None else first.get("machine"),
            "key_sensors": sensors,
            "target": first.get("target", "displacement change dz (um) from the reference state"),
            "reference": first.get("reference"),
            "rule": WEIGHT_RULE,
            "weights": dict(self.weights_),
            "members": arts,
            "hyperparameters": {"filter_restart_gap_s": min(gaps) if gaps else float("inf")},
            "regressor_ranges": _union_ranges([_ranges_of(a) for a in arts.values()]),
            "speed_range_rpm": [min(lows), max(highs)] if lows and highs else None,
            "train_runs": sorted({str(r) for a in arts.values() for r in a.get("train_runs", [])}),
            "data": dict(sorted(data.items())),
            "code_version": CODE_VERSION,
        }
        if getattr(self, "trained_speeds_rpm_", None) is not None:
            body["trained_speeds_rpm"] = list(self.trained_speeds_rpm_)
        if self.envelope_ is not None:
            body["envelope"] = self.envelope_
        if getattr(self, "interval_", None) is not None:
            body["interval"] = self.interval_
        if getattr(self, "adaptation_", None) is not None:  # an ensemble prior adapted as a whole
            body["adaptation"] = dict(self.adaptation_)
        return finish_artefact(body)

    @classmethod
    def from_dict(cls, d: dict, *, load) -> WeightedEnsemble:
        """The ensemble from its artefact (refused if edited); ``load`` reads each member's artefact
        by its own kind (:func:`rafi.family.compare.load_any`, which passes itself: this module
        does not import the kinds)."""
        check_artefact(d, cls.kind)
        members = {n: load(a) for n, a in d["members"].items()}
        m = cls.from_fitted(
            members, d["weights"], machine=d.get("machine"), trained_speeds_rpm=d.get("trained_speeds_rpm")
        )
        m.interval_ = d.get("interval")
        m.envelope_ = _output_part(d.get("envelope"))
        m.adaptation_ = d["adaptation"] if isinstance(d.get("adaptation"), dict) else None
        return m

    def heaviest_member(self) -> str:
        """The member with the largest weight (the first of equals)."""
        return max(self.weights_, key=lambda n: self.weights_[n])


def _without_created(artefact: dict) -> dict:
    """``artefact`` without its ``created`` stamp (its ``model_id`` does not cover it)."""
    return {k: v for k, v in artefact.items() if k != "created"}


def _output_part(envelope: dict | None) -> dict | None:
    """The output bound of a member's envelope (``output_range``, ``output_margin``), or None."""
    if output_bounds(envelope) is None:
        return None
    margin = float(envelope.get("output_margin", OUTPUT_MARGIN))
    return {"output_range": [float(v) for v in envelope["output_range"]], "output_margin": margin}


def _ranges_of(artefact: dict) -> dict:
    """A member's key-sensor rise ranges: a ridge kind's ``regressor_ranges``, or the union over
    RAFI's speeds."""
    if artefact.get("regressor_ranges"):
        return artefact["regressor_ranges"]
    return _union_ranges([sp.get("regressor_ranges") for sp in artefact.get("speeds", [])])
