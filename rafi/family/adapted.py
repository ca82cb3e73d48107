"""The adaptation family: a prior (a fitted artefact of the family, :mod:`rafi.family.prior`)
re-qualified on new data (``docs/models.md``, "Re-qualification from a prior").

Four candidates (five with an ensemble prior), each cross-validated by whole run on the new
training runs beside the from-scratch kinds (:func:`adaptation_factories`; names in
``comparison/*.csv``):

* ``prior``       - the prior as it is (``method="as_is"``: nothing fitted);
* ``prior_gain``  - every coefficient of the prior times one gain ``b``
  (``method="gain"``): ``b = sum(p y) / sum(p p)`` over the training samples, ``p`` the prior's
  prediction, ``y`` the measured displacement change. No offset: a change is 0 at the reference
  state by construction;
* ``prior_time``  - ridge kinds only (``method="time"``): every filter time constant of the
  prior (rise filters, heat-input filters, the draw-in lag) times one factor ``f`` of
  :data:`TIME_FACTORS` and every coefficient times one gain ``b``: a machine whose thermal
  response became slower or faster. ``f`` is chosen by whole-run CV on the training runs (each
  held out in turn, ``b`` fitted on the others, ``models: cv_metric``); without a fold ``f = 1``;
* ``prior_ridge`` - ridge kinds only (``method="ridge"``): ``coef = coef_prior + delta``,
  ``delta`` the ridge solution of the residual ``y - X coef_prior`` on the prior's own features
  ``X`` (scaled to unit RMS): a ridge penalised towards the prior's coefficients, its strength
  ``alpha`` chosen by whole-run CV inside the training runs (nested) on ``models: prior_ridge_alphas``.

A prior that is a CV-weighted ensemble (:mod:`rafi.family.ensemble`) is adapted through its
heaviest member (:func:`rafi.family.prior.prior_base`): the four candidates re-fit that member and
the adapted artefact is of its kind; the block's ``parent`` is the ensemble (the registry's model)
and its ``member`` names the member re-fitted (``name``, ``kind``, ``model_id``, ``weight``,
``n_members``). And it is adapted as a whole by two more candidates:

* ``prior_shared_gain`` - every member keeps its coefficients and the prior's weights, the blend
  times one gain ``g`` fitted as ``prior_gain``'s on the prior's blended prediction
  (:class:`SharedAdaptedEnsemble`, ``method="shared_gain"``): an artefact ``kind: ensemble``
  whose members' coefficients are the prior's times ``g``, the block on the ensemble (no
  ``member``; ``members`` names the prior's). Judged on random re-qualification scenarios
  (issue 47, ``benchmarks/bench_requalify.py``); one time factor shared too (``prior_time``'s
  way over every member) was judged beside it and is not offered;
* ``prior_shared_ridge`` - the shared gain, then every ridge member's coefficients moved toward
  the new data: ``g c_prior + delta``, ``delta`` the ridge (:func:`ridge_toward`) of the shared
  gain's residual on the member's own features at the fixed penalty :data:`SHARED_RIDGE_ALPHA`
  (``method="shared_ridge"``; other members the gain alone). Offered with an ensemble prior
  whatever the CV scores (:func:`rafi.family.selection.choose_champion`; issue 47, judged on
  random re-qualification scenarios, ``docs/decisions.md`` 2026-11-30).

What is never re-fitted: the prior's sensors and terms, and its filter time constants other than
by the one factor of ``prior_time``; the from-scratch kinds beside re-choose those. The fitted
artefact is one of the **prior's kind** (same features and hyperparameters, new coefficients;
``prior_time``: scaled filter constants), so ``rafi.family.compare.load_any``, the streaming
compensator and the intervals run it unchanged; it carries the block
``adaptation`` (:data:`ADAPTATION_SCHEMA`) and its ``data`` are the new training data. The block's
``fitness`` (:func:`rafi.family.prior_fitness.fitness_block`) says where the prior comes from, its
own qualification, how far the adaptation moved it and which speeds and temperature rises the new
data cover against those only the prior covers; its ``warnings`` block promotion until confirmed.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
import pandas as pd

from rafi.artefact import compute_model_id, now_iso
from rafi.family.base import FamilyModel, check_artefact, data_hashes
from rafi.family.dynamic import DynamicRidge
from rafi.family.envelope import join_envelope
from rafi.family.grey_box import GreyBox
from rafi.family.prior import RIDGE_KINDS, ensemble_member, prior_base, prior_sensors
from rafi.family.prior_fitness import fitness_block, prior_speed_range
from rafi.family.ridge import cv_folds, cv_scores, fit_rows_of, ridge_gram, rms_scale
from rafi.family.ridge_global import RidgeGlobal
from rafi.family.temperature_ridge import TemperatureRidge
from rafi.family.time_blocks import unit_column
from rafi.method.rank import trained_speeds
from rafi.settings import MACHINE_DEFAULTS

__all__ = [
    "ADAPTATION_SCHEMA",
    "METHODS",
    "CANDIDATES",
    "ENSEMBLE_CANDIDATES",
    "AdaptedPrior",
    "SharedAdaptedEnsemble",
    "adaptation_factories",
]

MODELS = MACHINE_DEFAULTS["models"]
ADAPTATION_SCHEMA = "rafi.adaptation/1"
METHODS = ("as_is", "gain", "time", "ridge")
#: The candidates' names in the family's tables -> their method.
CANDIDATES = {"prior": "as_is", "prior_gain": "gain", "prior_time": "time", "prior_ridge": "ridge"}
#: The candidates offered only for a CV-weighted ensemble prior -> their method
#: (:class:`SharedAdaptedEnsemble`: one gain shared by every member; issue 47. One time factor
#: shared too was judged beside it and not offered: ``benchmarks/bench_requalify.py``).
ENSEMBLE_CANDIDATES = {"prior_shared_gain": "shared_gain", "prior_shared_ridge": "shared_ridge"}
#: The penalty of ``prior_shared_ridge`` (dimensionless: the ridge of :func:`ridge_toward` on
#: features scaled to unit RMS), fixed: whole-run CV on the few runs of a re-qualification cannot
#: choose it (issue 47, ``docs/decisions.md`` 2026-11-30).
SHARED_RIDGE_ALPHA = 10.0
#: The shared methods of :class:`SharedAdaptedEnsemble`.
SHARED_METHODS = tuple(ENSEMBLE_CANDIDATES.values())
#: The methods that need a prior of a ridge kind (features @ coefficients, filter constants).
RIDGE_METHODS = ("time", "ridge")
#: The factors ``time`` scales the prior's filter time constants by (steps of sqrt 2).
TIME_FACTORS = (0.5, 0.71, 1.0, 1.41, 2.0)
RIDGE_CLASSES = {
    "ridge_global": RidgeGlobal,
    "dynamic": DynamicRidge,
    "grey_box": GreyBox,
    "temperature_ridge": TemperatureRidge,
}


class AdaptedPrior(FamilyModel):
    """A prior artefact, re-fitted on the new training runs by ``method`` (module docstring).

    Parameters
    ----------
    prior : dict
        The prior's artefact (``model.json`` content of any kind of the family).
    method : {"as_is", "gain", "time", "ridge"}
        What is re-fitted; ``time`` and ``ridge`` need a prior of a ridge kind (:data:`RIDGE_KINDS`).
    alphas : sequence of float
        Penalties of ``ridge`` (``models: prior_ridge_alphas``).
    cv : str
        The whole-run CV scheme that chooses ``alpha`` (``models: cv``).
    cv_metric : str
        ``rmse`` or ``max_abs`` (``models: cv_metric``).
    machine : str or None
        Machine name recorded in the artefact (None: the prior's).
    reference : dict or None
        This machine's ``reference:`` settings (``rule``, ``window_s``; None: the prior's). The
        reference is how this machine's logs are cut and referenced, not physics: the prior's
        features are computed under it (its filters over each run from cold under ``run_start``,
        over the whole log under ``log_start``) and the adapted artefact carries it, so a prior
        qualified on a continuous log serves a machine logged as cold-start files and the
        reverse (``docs/operations.md``, "Layouts are not physics").
    origin : str or None
        Where the prior comes from (:func:`rafi.family.prior.check_origin`: ``this machine`` or
        ``declared sibling``; None: not checked, a prior given in-process).
    qualification : dict or None
        The prior's own qualification (:func:`rafi.family.prior.prior_qualification`).
    speed_tolerance_rpm : float
        A speed of the prior within this of a new training run's is covered (the fitness block).

    Attributes
    ----------
    model_ : fitted model of the prior's kind
        The adapted model (a ``RafiModel`` for the kinds ``rafi`` / ``rafi_linear``).
    gain_ : float or None
        ``b`` of ``gain``.
    alpha_chosen_ : float or None
        ``alpha`` of ``ridge``.
    time_factor_ : float or None
        ``f`` of ``time``.
    coefficient_change_ : list of dict
        ``name``, ``prior``, ``new`` per coefficient.
    grid_edges_ : list of str
        ``alpha`` at an edge of its grid.
    fitness_ : dict
        The ``fitness`` block (:func:`rafi.family.prior_fitness.fitness_block`).
    """

    def __init__(
        self,
        *,
        prior: dict,
        method: str = "gain",
        alphas: Sequence[float] = MODELS["prior_ridge_alphas"],
        cv: str = MODELS["cv"],
        cv_metric: str = MODELS["cv_metric"],
        machine: str | None = None,
        reference: dict | None = None,
        origin: str | None = None,
        qualification: dict | None = None,
        speed_tolerance_rpm: float = MACHINE_DEFAULTS["speed_tolerance_rpm"],
    ):
        self.prior = prior
        self.method = method
        self.alphas = alphas
        self.cv = cv
        self.cv_metric = cv_metric
        self.machine = machine
        self.reference = reference
        self.origin = origin
        self.qualification = qualification
        self.speed_tolerance_rpm = speed_tolerance_rpm

    @property
    def base(self) -> dict:
        """The artefact re-fitted: the prior, or a CV-weighted ensemble prior's heaviest member
        (:func:`rafi.family.prior.prior_base`)."""
        return prior_base(self.prior)

    @property
    def kind(self) -> str:
        """The kind of the artefact re-fitted (:attr:`base`): the adapted artefact is one of that kind."""
        return str(self.base.get("kind"))

    def __repr__(self) -> str:
        pid = str(self.prior.get("model_id", ""))[:12]
        return f"AdaptedPrior(prior={pid!r} ({self.kind}), method={self.method!r})"

    # -- fit
    def _check_params(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method={self.method!r}: use one of {', '.join(METHODS)}")
        if self.method in RIDGE_METHODS and self.kind not in RIDGE_KINDS:
            kinds = ", ".join(RIDGE_KINDS)
            raise ValueError(
                f"method={self.method!r} needs a prior of a ridge kind ({kinds}), not {self.kind}"
            )

    def _base(self):
        """A fresh fitted model of the prior (the one whose coefficients change): the ridge kinds'
        own class, RAFI's :class:`~rafi.method.model.RafiModel` for ``rafi`` / ``rafi_linear``."""
        base = self.base
        if self.kind in RIDGE_KINDS:
            model = RIDGE_CLASSES[self.kind].from_dict(base)
        elif self.kind in ("rafi", "rafi_linear"):
            from rafi.method.model import RafiModel

            check_artefact(base, self.kind)  # refused if edited (its id is under its own kind)
            model = RafiModel.from_dict({**base, "kind": "rafi"}, verify_id=False)
        else:
            raise ValueError(f"a prior of kind {self.kind!r} cannot be adapted")
        if self.reference is not None:  # this machine's logs' reference (``reference``)
            model.reference = {**(model.reference or {}), **dict(self.reference)}
        return model

    def fit(self, runs_table: pd.DataFrame, runs_frame: pd.DataFrame):
        """Re-fit the prior on the training runs of ``runs_table`` by ``method``; returns ``self``."""
        return self._fit(runs_table, runs_frame)

    def fit_gain(
        self, runs_table: pd.DataFrame, runs_frame: pd.DataFrame, *, gain: float, alpha: float | None = None
    ):
        """As :meth:`fit` with the gain (and, for ``method="ridge"``, the penalty) given, not
        fitted: a member of an ensemble prior adapted with every member (:class:`SharedAdaptedEnsemble`).
        ``method="gain"``: every coefficient times ``gain``; ``method="ridge"`` (``alpha`` given):
        ``gain`` times every coefficient plus the ridge solution at ``alpha`` of the residual of
        that on the prior's own features. Returns ``self``."""
        if self.method not in ("gain", "ridge") or (self.method == "ridge") != (alpha is not None):
            raise ValueError(
                f"fit_gain needs method='gain' without alpha or method='ridge' with one, not "
                f"method={self.method!r}, alpha={alpha!r}"
            )
        return self._fit(runs_table, runs_frame, gain=float(gain), alpha=alpha)

    def add_warning(self, warning: dict):
        """Append ``warning`` (``{check, message}``) to the fitness block's warnings: one found
        beside the fit, by the family's CV (``prior_dynamics``, ``prior_misfit``,
        :func:`rafi.family.compare.run_family`); the artefact carries it and its promotion waits for
        a confirmation. Returns ``self``."""
        self.fitness_["warnings"] = [*self.fitness_.get("warnings", []), dict(warning)]
        self.model_.adaptation_["fitness"] = self.fitness_
        return self

    def _fit(
        self,
        runs_table: pd.DataFrame,
        runs_frame: pd.DataFrame,
        gain: float | None = None,
        alpha: float | None = None,
    ):
        self._check_params()
        model = self._base()
        table, frame, rows = _training_rows(runs_table, runs_frame)
        y = frame.loc[rows, "dz_um"].to_numpy(dtype=float)
        ridge_kind = self.kind in RIDGE_KINDS
        x = np.asarray(model._design(frame)[0], dtype=float)[rows] if ridge_kind else None
        before = np.array(model.coef_, dtype=float)
        pred = x @ before if ridge_kind else np.asarray(model.predict(frame.loc[rows]), dtype=float)
        ok = np.isfinite(pred) & np.isfinite(y)
        prior_prediction = pred.copy()  # the prior's own, for the fitness block
        self.gain_ = self.alpha_chosen_ = self.time_factor_ = None
        self.grid_edges_, cv_table = [], []
        if self.method == "time":
            units = frame.loc[rows, unit_column(frame, table)].astype(str).to_numpy()
            model, x, cv_table = self._time(frame, rows, y, units)
            pred = x @ before
            ok = np.isfinite(pred) & np.isfinite(y)
            self.gain_ = _gain(pred[ok], y[ok])
            model.coef_ = before * self.gain_
        elif self.method == "gain":
            self.gain_ = gain if gain is not None else _gain(pred[ok], y[ok])
            model.coef_ = before * self.gain_
        elif self.method == "ridge" and alpha is not None:  # a member of a shared ridge: both given
            self.gain_, self.alpha_chosen_ = gain, float(alpha)
            model.coef_ = before * gain + ridge_toward(x[ok], y[ok] - gain * pred[ok], [alpha])[:, 0]
        elif self.method == "ridge":
            units = frame.loc[rows, unit_column(frame, table)].astype(str).to_numpy()
            delta, cv_table = self._ridge(x[ok], y[ok] - pred[ok], units[ok], table)
            model.coef_ = before + delta
        after = np.asarray(model.coef_, dtype=float)
        new_prediction = x @ after if ridge_kind else pred * (self.gain_ or 1.0)
        residual = y[ok] - new_prediction[ok]
        self.coefficient_change_ = _coefficient_change(model, self.kind, before, after)
        self.fitness_ = self._fitness(table, frame.loc[rows], prior_prediction, new_prediction)
        self._restamp(model, table, frame.loc[rows], residual, cv_table)
        self.model_ = model
        return self

    def _fitness(self, table: pd.DataFrame, train: pd.DataFrame, before: np.ndarray, after: np.ndarray):
        """The ``fitness`` block of this adaptation (:func:`rafi.family.prior_fitness.fitness_block`):
        the new training runs' speeds and rises against the prior's."""
        from rafi.family.features import rise_column

        rises = {}
        for sensor in prior_sensors(self.prior):
            column = rise_column(sensor)
            values = train[column].to_numpy(dtype=float) if column in train else np.array([])
            values = values[np.isfinite(values)]
            if values.size:
                rises[sensor] = [float(values.min()), float(values.max())]
        return fitness_block(
            self.prior,
            base=self.base,
            qualification=self.qualification,
            origin=self.origin,
            method=self.method,
            gain=self.gain_,
            time_factor=self.time_factor_,
            alpha=self.alpha_chosen_,
            coefficient_change=self.coefficient_change_,
            prior_prediction=before,
            new_prediction=after,
            tested_speeds_rpm=table["speed_rpm"].astype(float).tolist(),
            tested_rises=rises,
            speed_tolerance_rpm=float(self.speed_tolerance_rpm),
        )

    def _time(self, frame: pd.DataFrame, rows: np.ndarray, y: np.ndarray, units: np.ndarray):
        """The prior with its time constants scaled by the factor of :data:`TIME_FACTORS` that
        whole-run CV prefers (each training unit held out in turn, the gain fitted on the
        others; one unit: no fold, factor 1), its training design and the CV table."""
        scores, fitted = [], []
        for factor in TIME_FACTORS:
            model = _retimed(self._base(), factor)
            feats, names = model._design(frame)
            x = np.asarray(feats, dtype=float)[rows]
            fitted.append((model, x, names))
            scores.append(_held_out_gain_score(x @ np.asarray(model.coef_, float), y, units, self.cv_metric))
        finite = [s for s in scores if np.isfinite(s)]
        if finite:  # ties go to the factor nearest 1 (the prior's own constants)
            best = min(
                range(len(scores)), key=lambda i: (np.round(scores[i] / 1e-9), abs(np.log(TIME_FACTORS[i])))
            )
        else:
            best = TIME_FACTORS.index(1.0)
        self.time_factor_ = float(TIME_FACTORS[best])
        if finite and best in (0, len(TIME_FACTORS) - 1):
            self.grid_edges_ = [f"prior_time factor {self.time_factor_:g} at an edge of {list(TIME_FACTORS)}"]
        model, x, names = fitted[best]
        model.feature_names_ = list(names)
        table = [
            {"factor": f, "score_um": float(s) if np.isfinite(s) else None}
            for f, s in zip(TIME_FACTORS, scores)
        ]
        return model, x, table

    def _ridge(self, x: np.ndarray, r: np.ndarray, units: np.ndarray, table: pd.DataFrame):
        """``delta`` of ``ridge`` and its CV table: ``alpha`` by whole-run CV on the training
        runs (no fold: the largest, the prior's side), then the ridge on all of them."""
        alphas = [float(a) for a in self.alphas]
        cols = np.arange(x.shape[1])
        folds = cv_folds(x, r, units, table, self.cv)
        if folds:
            scores = cv_scores(folds, cols, alphas, self.cv_metric)
            best = int(np.argmin(np.round(scores / 1e-9)))
        else:
            scores, best = np.full(len(alphas), np.nan), int(np.argmax(alphas))
        self.alpha_chosen_ = alphas[best]
        if len(alphas) > 1 and folds and self.alpha_chosen_ in (min(alphas), max(alphas)):
            edge = f"prior_ridge alpha {self.alpha_chosen_:g} at an edge of models.prior_ridge_alphas"
            self.grid_edges_ = [edge]
        delta = ridge_toward(x, r, [self.alpha_chosen_])[:, 0]
        cv_table = [
            {"alpha": a, "score_um": float(s) if np.isfinite(s) else None} for a, s in zip(alphas, scores)
        ]
        return delta, cv_table

    def _restamp(self, model, table, train: pd.DataFrame, residual: np.ndarray, cv_table: list) -> None:
        """Give the adapted model its new data, provenance and ``adaptation`` block."""
        train_runs = sorted(set(map(str, table["run_id"])))
        data = data_hashes(table, train_runs)
        block = {
            "schema": ADAPTATION_SCHEMA,
            "method": self.method,
            "parent": self.prior.get("model_id"),
            "parent_machine": self.prior.get("machine"),
            "gain": self.gain_,
            "alpha": self.alpha_chosen_,
            "time_factor": self.time_factor_,
            "prior_data": _lineage_data(self.prior),
            "coefficient_change": self.coefficient_change_,
            "fitness": self.fitness_,
        }
        member = ensemble_member(self.prior)
        if member is not None:  # a CV-weighted ensemble prior: the member re-fitted (parent: the ensemble)
            block["member"] = member
        model.interval_ = None  # the prior's interval is not this model's (calibrate_family sets one)
        model.adaptation_ = block
        if self.machine is not None:
            model.machine = self.machine
        if self.kind in RIDGE_KINDS:
            model.data_ = data
            model.train_runs_ = train_runs
            model.rmse_um_ = float(np.sqrt(np.mean(residual**2))) if len(residual) else float("nan")
            model.n_ = int(len(residual))
            model.cv_table_ = cv_table
            model.regressor_ranges_, model.speed_range_rpm_ = _joined_ranges(model, table, train)
            target = train["dz_um"].to_numpy(dtype=float)
            prior_envelope = getattr(model, "envelope_", None)
            model.envelope_ = join_envelope(prior_envelope, model._design(train)[0], target)
        else:  # RafiModel: the per-speed records stay the prior's; the data are the new ones
            model.data = data
            model.created = now_iso()
            model.speed_range_rpm_ = _joined_speed_range(prior_speed_range(self.base), table)

    # -- evaluation
    def predict_detail(self, frame: pd.DataFrame) -> pd.DataFrame:
        """The adapted model's ``predict_detail`` (the prior's kind's own code)."""
        return self.model_.predict_detail(frame)

    def predict(self, frame: pd.DataFrame) -> np.ndarray:
        """The adapted model's prediction (um) per row of ``frame``."""
        return np.asarray(self.model_.predict(frame), dtype=float)

    def describe(self) -> str:
        """What the adaptation chose, in one line for people."""
        what = {
            "as_is": "as it is (nothing fitted)",
            "gain": f"every coefficient times {self.gain_:.4g}" if self.gain_ is not None else "gain",
            "time": f"time constants times {self.time_factor_:g}, coefficients times {self.gain_:.4g}"
            if self.time_factor_ is not None
            else "time",
            "ridge": f"ridge towards its coefficients, alpha {self.alpha_chosen_:g}"
            if self.alpha_chosen_ is not None
            else "ridge",
        }[self.method]
        pid = str(self.prior.get("model_id", ""))[:12]
        member = ensemble_member(self.prior)
        if member is not None:
            text = (
                f"prior {pid} (ensemble of {self.prior.get('machine')}) through its heaviest member "
                f"{member['name']} ({self.kind}, weight {member['weight']:.3f}) {what}"
            )
        else:
            text = f"prior {pid} ({self.kind} of {self.prior.get('machine')}) {what}"
        return text + ("; AT A GRID EDGE: " + "; ".join(self.grid_edges_) if self.grid_edges_ else "")

    # -- artefact
    def to_dict(self) -> dict:
        """The adapted artefact: of the prior's kind, with the ``adaptation`` block."""
        d = self.model_.to_dict()
        if d.get("kind") != self.kind:  # rafi_linear: RAFI's layout under its own kind
            d["kind"] = self.kind
            d["model_id"] = compute_model_id(d)
        return d


class SharedAdaptedEnsemble(FamilyModel):
    """A CV-weighted ensemble prior (:mod:`rafi.family.ensemble`) re-qualified as a whole: every
    member keeps the prior's weight, and one gain is shared by all of them (``shared_gain``, the
    candidate ``prior_shared_gain``; issue 47); with ``shared_ridge`` (``prior_shared_ridge``)
    every ridge member's coefficients are then moved toward the new data by a ridge at the fixed
    penalty :data:`SHARED_RIDGE_ALPHA` (:meth:`AdaptedPrior.fit_gain` with ``alpha``).

    ``g = sum(p y) / sum(p p)`` over the new training samples, ``p`` the prior's blended
    prediction (its own bound and blend), ``y`` the measured displacement change: least squares
    through the reference, as ``prior_gain`` for one model. The blend of the members times ``g``
    is every member's coefficients times ``g``: the adapted artefact is a ``kind: ensemble`` of
    the members so adapted (each an :class:`AdaptedPrior` with the shared gain given, its own
    ``adaptation`` block, its envelope joined with the new data), with the prior's weights and
    this adaptation's block on the ensemble, so the compensator, the replay and the intervals run
    it as any ensemble. A gain fitted on a blend is the truth's only where the members agree with
    it: averaging members that disagree shrinks the blend and the gain grows to make up for it.

    Parameters
    ----------
    prior : dict
        The ensemble prior's artefact (``kind: ensemble`` with ``weights`` and ``members``).
    method : {"shared_gain", "shared_ridge"}
        What is shared (:data:`SHARED_METHODS`): the gain alone, or the gain and one ridge
        penalty for every member's move.
    cv, cv_metric, machine, reference, origin, qualification, speed_tolerance_rpm
        As :class:`AdaptedPrior`.
    alphas : sequence of float
        Not used (the factories pass every candidate the same settings).

    Attributes
    ----------
    model_ : WeightedEnsemble
        The adapted ensemble (``weights_``, ``members_``, ``envelope_``: its own).
    adapted_members_ : dict
        Name -> the member's :class:`AdaptedPrior` (the shared gain given).
    gain_ : float
        The shared gain ``g``.
    alpha_chosen_ : float or None
        ``shared_ridge``: :data:`SHARED_RIDGE_ALPHA` (fixed, not fitted); else None.
    time_factor_ : None
        Nothing else fitted.
    coefficient_change_ : list of dict
        ``name`` (``<member>: <coefficient>``), ``prior``, ``new``.
    grid_edges_ : list of str
        Empty (no grid).
    fitness_ : dict
        The ``fitness`` block (:func:`rafi.family.prior_fitness.fitness_block`).
    """

    kind = "ensemble"

    def __init__(
        self,
        *,
        prior: dict,
        method: str = "shared_gain",
        alphas: Sequence[float] = MODELS["prior_ridge_alphas"],
        cv: str = MODELS["cv"],
        cv_metric: str = MODELS["cv_metric"],
        machine: str | None = None,
        reference: dict | None = None,
        origin: str | None = None,
        qualification: dict | None = None,
        speed_tolerance_rpm: float = MACHINE_DEFAULTS["speed_tolerance_rpm"],
    ):
        self.prior = prior
        self.method = method
        self.alphas = alphas
        self.cv = cv
        self.cv_metric = cv_metric
        self.machine = machine
        self.reference = reference
        self.origin = origin
        self.qualification = qualification
        self.speed_tolerance_rpm = speed_tolerance_rpm

    def __repr__(self) -> str:
        pid = str(self.prior.get("model_id", ""))[:12]
        return f"SharedAdaptedEnsemble(prior={pid!r}, method={self.method!r})"

    def _check_params(self) -> tuple[dict, dict]:
        if self.method not in SHARED_METHODS:
            raise ValueError(f"method={self.method!r}: use one of {', '.join(SHARED_METHODS)}")
        weights = {str(k): float(v) for k, v in (self.prior.get("weights") or {}).items()}
        arts = self.prior.get("members") or {}
        if self.prior.get("kind") != "ensemble" or len(weights) < 2 or any(n not in arts for n in weights):
            raise ValueError(
                f"method={self.method!r} needs a CV-weighted ensemble prior with its members' artefacts, "
                f"not kind {self.prior.get('kind')!r}"
            )
        return weights, arts

    def _member(self, art: dict, method: str) -> AdaptedPrior:
        """An :class:`AdaptedPrior` of one member (its gain given by :meth:`fit`)."""
        return AdaptedPrior(
            prior=art,
            method=method,
            cv=self.cv,
            cv_metric=self.cv_metric,
            machine=self.machine,
            reference=self.reference,
            origin=self.origin,
            qualification=self.qualification,
            speed_tolerance_rpm=self.speed_tolerance_rpm,
        )

    def _blend(self, weights: dict, arts: dict, frame: pd.DataFrame) -> np.ndarray:
        """The prior's blended prediction on ``frame`` (its own bound and blend)."""
        from rafi.family.ensemble import WeightedEnsemble

        models = {name: self._member(arts[name], "as_is")._base() for name in weights}
        ensemble = WeightedEnsemble.from_fitted(models, weights, machine=self.prior.get("machine"))
        return np.asarray(ensemble.predict(frame), dtype=float)

    def fit(self, runs_table: pd.DataFrame, runs_frame: pd.DataFrame):
        """Fit the shared gain on the training runs of ``runs_table``; returns ``self``."""
        from rafi.family.ensemble import WeightedEnsemble

        weights, arts = self._check_params()
        table, frame, rows = _training_rows(runs_table, runs_frame)
        y = frame.loc[rows, "dz_um"].to_numpy(dtype=float)
        prior_prediction = self._blend(weights, arts, frame)[rows]
        self.time_factor_, self.alpha_chosen_, self.grid_edges_ = None, None, []
        ok = np.isfinite(prior_prediction) & np.isfinite(y)
        self.gain_ = _gain(prior_prediction[ok], y[ok])
        if self.method == "shared_ridge":
            self.alpha_chosen_ = SHARED_RIDGE_ALPHA
        members = {}
        for name in weights:
            moved = self.method == "shared_ridge" and arts[name].get("kind") in RIDGE_KINDS
            member = self._member(arts[name], "ridge" if moved else "gain")
            alpha = self.alpha_chosen_ if moved else None
            members[name] = member.fit_gain(runs_table, runs_frame, gain=self.gain_, alpha=alpha)
        self.adapted_members_ = members
        machine = self.machine if self.machine is not None else self.prior.get("machine")
        # a ridge member: its adapted model (envelope and bound); RAFI's: the adapted wrapper (its kind)
        fitted = {n: m.model_ if m.kind in RIDGE_KINDS else m for n, m in members.items()}
        model = WeightedEnsemble.from_fitted(
            fitted,
            weights,
            machine=machine,
            trained_speeds_rpm=_joined_trained_speeds(self.prior, table),
        )
        new_prediction = np.asarray(model.predict(frame), dtype=float)[rows]
        self.coefficient_change_ = [
            {**c, "name": f"{n}: {c['name']}"} for n, m in members.items() for c in m.coefficient_change_
        ]
        self.fitness_ = self._fitness(table, frame.loc[rows], prior_prediction, new_prediction)
        self.adaptation_ = {
            "schema": ADAPTATION_SCHEMA,
            "method": self.method,
            "parent": self.prior.get("model_id"),
            "parent_machine": self.prior.get("machine"),
            "gain": self.gain_,
            "alpha": self.alpha_chosen_,
            "time_factor": self.time_factor_,
            "prior_data": _lineage_data(self.prior),
            "members": {
                n: {"kind": arts[n].get("kind"), "model_id": arts[n].get("model_id")} for n in weights
            },
            "fitness": self.fitness_,
        }
        self.model_ = model
        return self

    def add_warning(self, warning: dict):
        """As :meth:`AdaptedPrior.add_warning`, on the ensemble's own fitness block. Returns ``self``."""
        self.fitness_["warnings"] = [*self.fitness_.get("warnings", []), dict(warning)]
        self.adaptation_["fitness"] = self.fitness_
        return self

    def _fitness(self, table: pd.DataFrame, train: pd.DataFrame, before: np.ndarray, after: np.ndarray):
        """The ``fitness`` block: the new training runs' speeds and rises against the ensemble's."""
        from rafi.family.features import rise_column

        rises = {}
        for sensor in self.prior.get("key_sensors") or []:
            column = rise_column(sensor)
            values = train[column].to_numpy(dtype=float) if column in train else np.array([])
            values = values[np.isfinite(values)]
            if values.size:
                rises[sensor] = [float(values.min()), float(values.max())]
        return fitness_block(
            self.prior,
            qualification=self.qualification,
            origin=self.origin,
            method=self.method,
            gain=self.gain_,
            time_factor=self.time_factor_,
            alpha=self.alpha_chosen_,
            coefficient_change=self.coefficient_change_,
            prior_prediction=before,
            new_prediction=after,
            tested_speeds_rpm=table["speed_rpm"].astype(float).tolist(),
            tested_rises=rises,
            speed_tolerance_rpm=float(self.speed_tolerance_rpm),
        )

    @property
    def weights_(self) -> dict:
        """The adapted ensemble's weights (the prior's)."""
        return self.model_.weights_

    @property
    def members_(self) -> dict:
        """The adapted ensemble's fitted members (name -> model)."""
        return self.model_.members_

    @property
    def envelope_(self):
        """The adapted ensemble's output bound."""
        return self.model_.envelope_

    def predict_detail(self, frame: pd.DataFrame) -> pd.DataFrame:
        """The adapted ensemble's ``predict_detail``."""
        return self.model_.predict_detail(frame)

    def predict(self, frame: pd.DataFrame) -> np.ndarray:
        """The adapted ensemble's prediction (um) per row of ``frame``."""
        return np.asarray(self.model_.predict(frame), dtype=float)

    def describe(self) -> str:
        """What the adaptation chose, in one line for people."""
        pid = str(self.prior.get("model_id", ""))[:12]
        n = len(self.prior.get("weights") or {})
        what = f"blend times {self.gain_:.4g}"
        if self.method == "shared_ridge":
            penalty = f"{self.alpha_chosen_:g}"
            what += f", every member moved toward the new data (a ridge at the fixed penalty {penalty})"
        return (
            f"prior {pid} (ensemble of {self.prior.get('machine')}, {n} members, the prior's weights) {what}"
        )

    def to_dict(self) -> dict:
        """The adapted artefact: a ``kind: ensemble`` of the adapted members with the ``adaptation`` block."""
        self.model_.adaptation_ = self.adaptation_
        return self.model_.to_dict()


def _joined_trained_speeds(prior: dict, table: pd.DataFrame) -> list[float] | None:
    """The prior's ``trained_speeds_rpm`` joined with the new constant training runs' speeds."""
    new = trained_speeds(table) or []
    old = [float(v) for v in prior.get("trained_speeds_rpm") or []]
    both = sorted(set(old) | set(new))
    return both or None


def _gain(pred: np.ndarray, y: np.ndarray) -> float:
    """Least-squares gain of ``y`` on ``pred`` without intercept (1 when ``pred`` is all 0)."""
    denominator = float(pred @ pred)
    return float(pred @ y) / denominator if denominator > 0 else 1.0


def _held_out_gain_score(pred: np.ndarray, y: np.ndarray, units: np.ndarray, metric: str) -> float:
    """Mean over the units of the held-out error of ``gain * pred``, the gain fitted on the other
    units (``rmse`` or ``max_abs``); NaN with fewer than two units."""
    ok = np.isfinite(pred) & np.isfinite(y)
    names = sorted(set(units[ok]))
    if len(names) < 2:
        return float("nan")
    errors = []
    for name in names:
        test = ok & (units == name)
        train = ok & (units != name)
        r = y[test] - _gain(pred[train], y[train]) * pred[test]
        errors.append(float(np.sqrt(np.mean(r**2))) if metric == "rmse" else float(np.max(np.abs(r))))
    return float(np.mean(errors))


def ridge_toward(x: np.ndarray, r: np.ndarray, alphas: Sequence[float]) -> np.ndarray:
    """The moves (p x n_alphas) from a model's coefficients that a ridge of the residual ``r`` on
    its features ``x`` (scaled to unit RMS, :func:`rafi.family.ridge.rms_scale`) gives at each
    penalty of ``alphas`` (:func:`rafi.family.ridge.ridge_gram`'s ``min |r - x d|^2/n + alpha |d|^2``
    on the scaled features), in the features' own units."""
    sc = rms_scale(x)
    xs = x / sc
    return ridge_gram(xs.T @ xs, xs.T @ r, len(r), alphas) / sc[:, None]


def _retimed(model, factor: float):
    """``model`` (a fitted ridge kind) with every filter time constant times ``factor``."""
    model.taus_ = [float(t) * factor for t in model.taus_]
    if getattr(model, "speed_taus_", None) is not None:  # heat-input filters (grey_box, dynamic)
        model.speed_taus_ = [float(t) * factor for t in model.speed_taus_]
    if getattr(model, "centrifugal_lag_s_", None) is not None:  # grey_box's draw-in lag
        model.centrifugal_lag_s_ = float(model.centrifugal_lag_s_) * factor
    return model


def _training_rows(runs_table: pd.DataFrame, runs_frame: pd.DataFrame):
    """``(table, frame, rows)`` as the ridge kinds fit: the training runs, the whole logs holding
    them (per-run frames: the training rows), the mask of the training rows with a finite dz."""
    table, frame, rows = fit_rows_of(runs_table, runs_frame)
    if not rows.any():
        raise ValueError("no training sample to adapt the prior on")
    return table, frame, rows


def _lineage_data(prior: dict) -> dict:
    """``file -> sha256`` of everything the prior learnt from
    (:func:`rafi.family.prior.seen_data`), by file name
    (a name met twice with another content gets its hash appended)."""
    out = dict(prior.get("data") or {})
    for name, digest in ((prior.get("adaptation") or {}).get("prior_data") or {}).items():
        key = name if out.get(name, digest) == digest else f"{name}@{str(digest)[:12]}"
        out[key] = digest
    return out


def _coefficient_change(model, kind: str, before: np.ndarray, after: np.ndarray) -> list[dict]:
    """``name``, ``prior``, ``new`` per coefficient (RAFI: ``<speed> r/min <term>``)."""
    if kind in RIDGE_KINDS:
        names = list(model.feature_names_)
    else:
        names = [f"{s:g} r/min {t}" for s in model.speeds_rpm_ for t in model.terms]
    return [
        {"name": n, "prior": float(a), "new": float(b)}
        for n, a, b in zip(names, before.ravel(), after.ravel())
    ]


def _joined_ranges(model, table: pd.DataFrame, train: pd.DataFrame):
    """The prior's rise and speed ranges joined with the new training runs' (the adapted model
    stands on both)."""
    from rafi.family.features import rise_column

    ranges = {}
    for s in model.sensors_:
        x = train[rise_column(s)].to_numpy(dtype=float)
        lo, hi = model.regressor_ranges_[s]
        finite = x[np.isfinite(x)]
        ranges[s] = [float(min(lo, finite.min())), float(max(hi, finite.max()))] if finite.size else [lo, hi]
    return ranges, _joined_speed_range(model.speed_range_rpm_, table)


def _joined_speed_range(prior_range, table: pd.DataFrame) -> list[float] | None:
    """The prior's speed range ``[lo, hi]`` (None: unknown) joined with the new training runs'
    speeds: the range the adapted model stands on (the artefact's ``speed_range_rpm``; tested here
    and covered by the prior are the fitness block's ``speed_range_tested_rpm`` and
    ``speed_range_prior_rpm``)."""
    speeds = [float(s) for s in table["speed_rpm"].astype(float) if np.isfinite(s)]
    ends = [float(v) for v in (prior_range or [])] + speeds
    return [min(ends), max(ends)] if ends else None


def adaptation_factories(
    prior: dict,
    *,
    options: dict,
    machine: str | None,
    reference: dict | None = None,
    log=print,
    origin: str | None = None,
    qualification: dict | None = None,
    speed_tolerance_rpm: float = MACHINE_DEFAULTS["speed_tolerance_rpm"],
) -> dict:
    """Name -> factory of the adaptation candidates of ``prior`` (:data:`CANDIDATES`; ``prior_ridge``
    only for a ridge kind), built from the machine's ``models:`` settings ``options`` and its
    ``reference:`` settings (:class:`AdaptedPrior`, ``reference``); ``origin``, ``qualification``
    and ``speed_tolerance_rpm`` go to each candidate's fitness block."""
    kind = prior_base(prior).get("kind")  # an ensemble prior: its heaviest member's
    names = [n for n in CANDIDATES if CANDIDATES[n] not in RIDGE_METHODS or kind in RIDGE_KINDS]
    member = ensemble_member(prior)
    if member is not None:
        log(
            f"the prior is a CV-weighted ensemble of {member['n_members']} members: adapted through its "
            f"heaviest, {member['name']} ({kind}, weight {member['weight']:.3f})"
        )
    if "prior_ridge" not in names:
        log(
            f"prior_time and prior_ridge not offered: the prior is of kind {kind} "
            "(its filter constants and a ridge towards it need a ridge kind)"
        )
    common = {"alphas": options["prior_ridge_alphas"], "cv": options["cv"], "cv_metric": options["cv_metric"]}
    common["reference"] = reference
    common |= {"origin": origin, "qualification": qualification, "speed_tolerance_rpm": speed_tolerance_rpm}
    out = {
        n: functools.partial(AdaptedPrior, prior=prior, method=CANDIDATES[n], machine=machine, **common)
        for n in names
    }
    if member is not None:  # an ensemble prior: also adapted as a whole (one shared gain)
        for n in ENSEMBLE_CANDIDATES:
            out[n] = functools.partial(
                SharedAdaptedEnsemble, prior=prior, method=ENSEMBLE_CANDIDATES[n], machine=machine, **common
            )
    return out
