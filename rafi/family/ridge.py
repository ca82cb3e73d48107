"""What the ridge kinds (``ridge_global``, ``dynamic``, ``grey_box``) share: the ridge solve for
every penalty at once, whole-run CV from per-run Gram matrices, the final fit, the evaluation
and the artefact (``docs/models.md``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from rafi.family.base import CODE_VERSION, FamilyModel, check_artefact, data_hashes, finish_artefact, floats
from rafi.family.crossval import split_runs, training_mask, training_runs
from rafi.family.envelope import (
    bound_components,
    bound_features,
    bound_output,
    component_bounds,
    component_excess,
    component_reach,
    component_scores,
    envelope_bounds,
    fit_envelope,
    key_range_excess,
    output_bounds,
)
from rafi.family.feature_memo import active_memo
from rafi.family.features import (
    MIN_IDENTIFYING_RUNS,
    complete_rows,
    reference_speed,
    rise_column,
    speed_change_evidence,
    usable_sensors,
)
from rafi.family.grids import data_scales, edge_flags, resolve
from rafi.family.interval_rule import reads_components
from rafi.family.time_blocks import blocks_text, max_filter_s, unit_column
from rafi.family.whole_log import has_whole_logs, layout, rows_of_logs

CV_METRICS = ("rmse", "max_abs")

#: How the filters start and what a filtered feature is relative to (the artefact's ``filter``).
FILTER_STATE_TEXT = {
    "whole_logs": (
        "frames with log/log_t_s: causal over each log in log_t_s order, state carried through "
        "cool-downs and gaps up to filter_restart_gap_s, restarted settled on the first finite "
        "sample at a log start or after a longer gap; the absolute input is filtered and the "
        "feature is the filtered value minus its median over the run's reference window"
    ),
    "per_run": "frames without log columns: per run, settled on the run's first sample",
}


def fit_rows_of(runs_table: pd.DataFrame, runs_frame: pd.DataFrame):
    """``(table, frame, rows)`` as the ridge kinds fit: the training runs, the rows features are
    computed on (the whole logs holding a training run; per-run frames: the training rows with a
    finite ``dz_um``) and the mask of the training rows with a finite ``dz_um``."""
    table, train = training_runs(runs_table, runs_frame)
    if has_whole_logs(runs_frame):
        frame = runs_frame.loc[rows_of_logs(runs_frame, table["run_id"])]
        rows = training_mask(frame, table) & np.isfinite(frame["dz_um"].to_numpy(dtype=float))
    else:  # per run, as before: only the training rows with a finite dz
        frame = train[np.isfinite(train["dz_um"].to_numpy(dtype=float))]
        rows = np.ones(len(frame), dtype=bool)
    return table, frame, rows


def ridge_gram(g: np.ndarray, c: np.ndarray, n: int, alphas: Sequence[float]) -> np.ndarray:
    """Coefficients (p x n_alphas) of ``min |y - Xb|^2/n + alpha |b|^2`` from ``X'X``, ``X'y``.

    ``X`` is already scaled; ``(X'X + n alpha I) b = X'y`` is solved through the
    eigendecomposition of ``X'X`` for all alphas at once.
    """
    w, v = np.linalg.eigh(g)
    w = np.clip(w, 0.0, None)
    vc = v.T @ c
    return v @ (vc[:, None] / (w[:, None] + n * np.asarray(alphas, dtype=float)[None, :]))


def rms_scale(x: np.ndarray) -> np.ndarray:
    """RMS of every column of ``x`` (1 where it is ~0): the inputs' scale, about zero."""
    s = np.sqrt(np.mean(x**2, axis=0))
    return np.where(s > 1e-12, s, 1.0)


def run_gram(feats: np.ndarray, y: np.ndarray, rows: np.ndarray) -> tuple:
    """``X'X``, ``X'y`` and the sample count of the rows ``rows`` of ``feats`` / ``y`` (one run)."""
    return feats[rows].T @ feats[rows], feats[rows].T @ y[rows], len(rows)


def cv_folds(
    feats: np.ndarray,
    y: np.ndarray,
    run_ids: np.ndarray,
    table: pd.DataFrame,
    scheme: str,
    *,
    shared_key=None,
) -> list:
    """Per whole-run fold of ``scheme``, once per fit: the training runs' ``X'X``, ``X'y`` and
    sample count (sums of per-run parts), the test runs' rows of ``X`` and ``y`` (for
    ``max_abs``) and their ``X'X``, ``X'y``, ``y'y`` (for ``rmse``).

    ``shared_key``: the feature memo's key of ``feats`` when they came from the active memo
    (:class:`rafi.family.feature_memo.FeatureMemo`); each run's Gram matrices are then computed
    once for every fit of the scope (a run's rows and features are the same in each)."""
    rows = {r: np.flatnonzero(run_ids == r) for r in np.unique(run_ids)}
    memo = active_memo() if shared_key is not None else None
    if memo is None:
        gram = {r: run_gram(feats, y, i) for r, i in rows.items()}
    else:
        gram = {r: memo.run_gram(shared_key, r, lambda i=i: run_gram(feats, y, i)) for r, i in rows.items()}
    folds = []
    for train_ids, test_ids in split_runs(table, scheme):
        train_runs = tuple(r for r in train_ids if r in gram)
        train = [gram[r] for r in train_runs]
        te = [rows[r] for r in test_ids if r in rows]
        if not train or not te:
            continue
        test = [gram[r] for r in test_ids if r in gram]
        te = np.concatenate(te)
        folds.append(
            {
                "g": sum(t[0] for t in train),
                "c": sum(t[1] for t in train),
                "n": sum(t[2] for t in train),
                "x_test": feats[te],
                "y_test": y[te],
                "g_test": sum(t[0] for t in test),
                "c_test": sum(t[1] for t in test),
                "yy_test": float(y[te] @ y[te]),
                # which sums g, c, n are: the same runs give the same sums in every fit sharing
                # the run Grams (a pair of runs held out in the outer and the inner CV, either way)
                "solution_key": (shared_key, train_runs) if memo is not None else None,
            }
        )
    return folds


def fold_solution(fold: dict, cols: np.ndarray, alphas: Sequence[float]) -> np.ndarray | None:
    """Ridge coefficients (columns ``cols``, one column per alpha) fitted on a fold's training
    runs, or ``None`` when the fold has no training sample. Computed once per training-run set
    and candidate in the active feature memo's scope (:func:`cv_folds`)."""
    if fold["n"] == 0:
        return None
    memo = active_memo() if fold.get("solution_key") is not None else None
    if memo is None:
        return _fold_solution(fold, cols, alphas)
    key = (*fold["solution_key"], np.asarray(cols).tobytes(), tuple(alphas))
    return memo.solution(key, lambda: _fold_solution(fold, cols, alphas))


def _fold_solution(fold: dict, cols: np.ndarray, alphas: Sequence[float]) -> np.ndarray:
    """:func:`fold_solution` computed: ridge on the columns scaled to unit RMS."""
    ix = np.ix_(cols, cols)
    g, c, n = fold["g"][ix], fold["c"][cols], fold["n"]
    sc = np.sqrt(np.diag(g) / n)
    sc = np.where(sc > 1e-12, sc, 1.0)
    return ridge_gram(g / np.outer(sc, sc), c / sc, n, alphas) / sc[:, None]


def cv_scores(folds: list, cols: np.ndarray, alphas: Sequence[float], metric: str) -> np.ndarray:
    """CV score per alpha (lower is better) of the feature columns ``cols``, whole-run folds:
    ``rmse`` over every held-out sample, or ``max_abs``, the mean over folds of the held-out
    runs' max |residual|."""
    sq = np.zeros(len(alphas))
    fold_max, count = [], 0
    ix = np.ix_(cols, cols)
    for fold in folds:
        b = fold_solution(fold, cols, alphas)
        if b is None:
            continue
        if metric == "rmse":
            # |y - Xb|^2 = y'y - 2 b'X'y + b'X'Xb from the test fold's Gram matrix: no pass
            # over the test samples per candidate
            sq += (
                fold["yy_test"]
                - 2.0 * (fold["c_test"][cols] @ b)
                + np.einsum("ia,ij,ja->a", b, fold["g_test"][ix], b)
            )
            count += len(fold["y_test"])
        else:
            res = fold["y_test"][:, None] - fold["x_test"][:, cols] @ b
            fold_max.append(np.max(np.abs(res), axis=0))
    if metric == "rmse":
        return np.sqrt(np.clip(sq, 0.0, None) / count) if count else np.zeros(len(alphas))
    return np.mean(fold_max, axis=0) if fold_max else np.zeros(len(alphas))


class RidgeBase(FamilyModel):
    """Base of the ridge kinds. A subclass defines ``__init__`` (its hyperparameters, among them
    ``sensors``, ``alphas``, ``cv``, ``cv_metric``, ``speed_terms``, ``speed_reference``,
    ``reference``, ``machine``, ``speed_tolerance_rpm``, ``filter_restart_gap_s``), ``fit``,
    ``_design`` (the feature matrix of the fitted model), ``_grid_settings`` and ``_inputs_text``.

    Features are computed over whole logs where the frame has ``log`` / ``log_t_s``
    (:mod:`rafi.family.whole_log`): ``fit`` evaluates them on every log that holds a training
    run (the inputs of every run of those logs, never another run's displacement) and then
    keeps the training rows with a finite ``dz_um``."""

    kind = "ridge_base"

    # -- hyperparameters
    def _check_params(self) -> None:
        if self.cv_metric not in CV_METRICS:
            raise ValueError(f"cv_metric {self.cv_metric!r}: use rmse or max_abs")

    def _alphas(self) -> list[float]:
        return [float(a) for a in self.alphas]

    def _window_s(self) -> float:
        return float(self.reference["window_s"])

    def _layout(self, frame: pd.DataFrame):
        """How ``frame`` is filtered (:func:`rafi.family.whole_log.layout`)."""
        return layout(
            frame,
            rule=str(self.reference["rule"]),
            window_s=self._window_s(),
            restart_gap_s=float(self.filter_restart_gap_s),
        )

    def _grid_settings(self) -> dict:
        """Setting name -> value (a list or ``auto``) of the filter grids of this kind."""
        return {}

    def _resolve_grids(self, frame: pd.DataFrame, max_filter_s: float | None = None) -> None:
        """Set ``data_scales_`` (sample period, median run length of the training rows ``frame``)
        and ``grids_`` (every grid as used: ``alpha`` and the kind's filter grids; under
        time-blocked folds a filter time constant above ``max_filter_s`` is left out,
        :mod:`rafi.family.time_blocks`)."""
        period, run_s = data_scales(frame)
        self.data_scales_ = {"sample_period_s": period, "run_length_s": run_s}
        self.grids_ = {"alpha": self._alphas()}
        for name, value in self._grid_settings().items():
            grid = resolve(name, value, period, run_s)
            if max_filter_s is not None and name.endswith("taus_s"):
                grid = [v for v in grid if v <= max_filter_s * (1 + 1e-9)]
            self.grids_[name] = grid

    def _speed_rule(self) -> str:
        """``auto``: the run's start window under ``reference.rule: run_start``, else 0 r/min."""
        if self.speed_reference != "auto":
            return self.speed_reference
        return "run_start" if self.reference["rule"] == "run_start" else "zero"

    def _reference_speed(self, frame: pd.DataFrame) -> np.ndarray:
        """Speed of each row's reference state (r/min), in ``frame`` row order."""
        return reference_speed(frame, self._speed_rule(), self._window_s())

    def _identifying_runs(self, frame: pd.DataFrame) -> list[str]:
        """Training runs with a step from their reference speed (:func:`speed_change_evidence`);
        a speed term relative to the reference speed is used only if at least
        ``MIN_IDENTIFYING_RUNS`` of them identify it."""
        return speed_change_evidence(
            frame, self._reference_speed(frame), float(self.speed_tolerance_rpm), self._window_s()
        )

    def _use_speed_terms(self, frame: pd.DataFrame) -> bool:
        """Set ``identifying_runs_``; True if ``speed_terms`` and the training runs identify them."""
        self.identifying_runs_ = self._identifying_runs(frame) if self.speed_terms else []
        return bool(self.speed_terms) and len(self.identifying_runs_) >= MIN_IDENTIFYING_RUNS

    # -- fit
    def _prepare(self, runs_table: pd.DataFrame, runs_frame: pd.DataFrame):
        """``(table, frame, rows, sensors)``: the training runs, the rows features are computed
        on (whole logs holding a training run; per run: the training rows), the mask of the
        training rows with a finite ``dz_um`` and a finite rise of every sensor in ``frame`` and
        the sensors (:func:`usable_sensors`: a sensor missing on a few rows stays, those rows
        go). Sets ``grids_``."""
        self._check_params()
        table, frame, rows = fit_rows_of(runs_table, runs_frame)
        self.time_blocks_ = blocks_text(runs_table)
        fit_rows = frame.loc[rows]
        sensors = list(self.sensors) if self.sensors is not None else usable_sensors(fit_rows)
        if not sensors:
            raise ValueError("no usable temperature sensor in the training runs")
        rows = rows & complete_rows(frame, sensors)  # a sensor's dropout: those rows, not the sensor
        fit_rows = frame.loc[rows]
        self._resolve_grids(fit_rows, max_filter_s(table))
        return table, frame, rows, sensors

    def _cv_folds(self, feats: np.ndarray, y: np.ndarray, run_ids: np.ndarray, table: pd.DataFrame, key=None):
        """:func:`cv_folds` of the hyperparameter CV: ``cv``'s whole-run (or time-block) folds.
        The kinds choose their own hyperparameters there; the forward folds score the selection
        only (``docs/decisions.md``, 2026-11-26)."""
        return cv_folds(feats, y, run_ids, table, self.cv, shared_key=key)

    @staticmethod
    def _cv_units(train: pd.DataFrame) -> np.ndarray:
        """The CV unit of every training row: its run, or its time block or gap under
        time-blocked folds (:mod:`rafi.family.time_blocks`)."""
        return train[unit_column(train)].astype(str).to_numpy()

    def _candidate_features(self, frame: pd.DataFrame, sensors, taus, **options):
        """``self._features(frame, sensors, taus, **options)`` (the columns of every candidate of
        the CV) and the feature memo's key, or ``None`` where the features were computed here.

        Inside :func:`rafi.family.feature_memo.sharing_features` the features of a frame made of
        whole logs of the memo's universe are taken from the universe's, computed once for every
        fit of the scope (the CV folds, the final fit)."""
        memo = active_memo()
        pos = memo.positions(frame) if memo is not None else None
        if pos is None:
            feats, names = self._features(frame, sensors, taus, **options)
            return feats, names, None
        key = (
            type(self).__name__,
            repr(self.get_params()),
            tuple(sensors),
            tuple(float(t) for t in taus),
            repr(sorted(options.items())),
        )
        universe, names = memo.universe_features(key, lambda f: self._features(f, sensors, taus, **options))
        return universe[pos], names, key

    def _chosen_design(self, feats, names, columns, frame, key):
        """The chosen candidate's design ``(features of the training rows, names)`` as columns of
        the candidates' features ``feats`` (whole logs: each filter, each column, is evaluated on
        its own, so the columns equal :meth:`_design`'s to the last bit), or ``None`` (per-run
        frames: :meth:`_design` computes it). Remembers the memo's ``key`` and the columns, so a
        prediction of whole logs of the memo's universe takes them from there too."""
        self._shared_design = (key, np.asarray(columns)) if key is not None else None
        if not has_whole_logs(frame):
            return None
        # C order, as _design returns them: the matrix products of the fit sum in the same order
        return np.ascontiguousarray(feats[:, columns]), [names[c] for c in columns]

    def _fit_final(self, table, frame, rows, sensors, taus, *, alpha, cv_table, design=None):
        """Fit the chosen model on every training run (the selection attributes of the subclass,
        e.g. ``speed_gain_``, are set before); ``rows`` marks the training rows of ``frame``;
        ``design``: the chosen features of those rows and their names (else :meth:`_design`)."""
        self.sensors_ = list(sensors)
        self.taus_ = [float(t) for t in taus]
        self.alpha_ = float(alpha)
        if design is None:
            feats, names = self._design(frame)
            feats = feats[rows]
        else:
            feats, names = design
        frame = frame.loc[rows]
        y = frame["dz_um"].to_numpy(dtype=float)
        sc = rms_scale(feats)
        b = ridge_gram((feats / sc).T @ (feats / sc), (feats / sc).T @ y, len(y), [alpha])[:, 0]
        self.feature_names_ = names
        self.scale_ = sc
        self.coef_ = b / sc
        self.train_runs_ = sorted(set(map(str, table["run_id"])))  # a run once, also over its time blocks
        x = frame[[rise_column(s) for s in sensors]].to_numpy(dtype=float)
        self.regressor_ranges_ = {
            s: [float(x[:, i].min()), float(x[:, i].max())] for i, s in enumerate(sensors)
        }
        self.speed_range_rpm_ = [float(table["speed_rpm"].min()), float(table["speed_rpm"].max())]
        self.envelope_ = fit_envelope(feats, y, components=bool(getattr(self, "component_envelope", False)))
        self.rmse_um_ = float(np.sqrt(np.mean((y - feats @ self.coef_) ** 2)))
        self.n_ = int(len(y))
        self.cv_table_ = cv_table
        self.data_ = data_hashes(table, self.train_runs_)
        self.grid_edges_ = edge_flags(self.kind, self._chosen(), self.grids_)
        return self

    def _chosen(self) -> dict:
        """Hyperparameter -> the value CV chose, for :func:`rafi.family.grids.edge_flags`."""
        return {"alpha": self.alpha_}

    # -- evaluation (NumPy only)
    def _design_of(self, frame: pd.DataFrame) -> np.ndarray:
        """:meth:`_design`'s features of ``frame``, from the active feature memo where the fit's
        candidates came from it and ``frame`` is whole logs of its universe."""
        shared = getattr(self, "_shared_design", None)
        memo = active_memo() if shared is not None else None
        if memo is not None:
            pos = memo.positions(frame)
            stored = memo.stored(shared[0]) if pos is not None else None
            if stored is not None:
                return np.ascontiguousarray(stored[0][pos][:, shared[1]])
        return self._design(frame)[0]

    def predict_detail(self, frame: pd.DataFrame) -> pd.DataFrame:
        """``predicted_um`` and the out-of-range flags per row of ``frame`` (same index).

        The prediction is from the features bounded to the training envelope and is itself held
        inside the training displacement range widened by its margin (:mod:`rafi.family.envelope`);
        ``unbounded_um`` is the free extrapolation and ``outside_envelope`` marks the rows where a
        feature or the prediction was bounded; ``range_excess`` is how far the row's key sensor
        rises and speed lie beyond their training ranges, in training spans
        (:func:`rafi.family.envelope.range_excess`; the interval widens with it)."""
        feats = self._design_of(frame)
        envelope = getattr(self, "envelope_", None)
        bounds = component_bounds(envelope, feats.shape[1], self.coef_)
        scores = component_scores(feats, bounds)  # the interval's excess below reads them too
        combined, beyond_components = bound_components(feats, bounds, scores)
        bounded, beyond = bound_features(combined, envelope_bounds(envelope, feats.shape[1]))
        beyond = beyond | beyond_components
        pred, beyond_output = bound_output(bounded @ self.coef_, output_bounds(envelope))
        beyond = beyond | beyond_output
        x = frame[[rise_column(s) for s in self.sensors_]].to_numpy(dtype=float)
        lo = np.array([self.regressor_ranges_[s][0] for s in self.sensors_])
        hi = np.array([self.regressor_ranges_[s][1] for s in self.sensors_])
        n = frame["speed_rpm"].to_numpy(dtype=float)
        excess = key_range_excess(x, n, np.column_stack([lo, hi]), self.speed_range_rpm_)
        if reads_components(getattr(self, "interval_", None)):
            reach = component_reach(envelope, feats.shape[1], self.coef_)
            excess = excess + component_excess(feats, reach, scores)
        return pd.DataFrame(
            {
                "predicted_um": pred,
                "outside_speed_range": (n < self.speed_range_rpm_[0]) | (n > self.speed_range_rpm_[1]),
                "outside_temp_range": ((x < lo) | (x > hi)).any(axis=1),
                "outside_envelope": beyond,
                "unbounded_um": feats @ self.coef_,
                "range_excess": excess,
            },
            index=frame.index,
        )

    # -- artefact
    def _hyper(self) -> dict:
        """The hyperparameters as recorded in the artefact (``hyperparameters``)."""
        return {
            "sensors": None if self.sensors is None else list(self.sensors),
            "alphas": self._alphas(),
            "cv": self.cv,
            "cv_metric": self.cv_metric,
            "speed_terms": bool(self.speed_terms),
            "speed_reference": self.speed_reference,
            "speed_tolerance_rpm": float(self.speed_tolerance_rpm),
            "filter_restart_gap_s": float(self.filter_restart_gap_s),
        }

    def _selected(self) -> dict:
        """What CV chose, as recorded in the artefact (``selected``; ``cv_folds`` only when the
        hyperparameters were chosen on time-blocked folds)."""
        out = {
            "alpha": self.alpha_,
            "taus_s": self.taus_,
            "speed_gain": self.speed_gain_,
            "speed_terms": bool(self.speed_terms_),
            "identifying_runs": list(self.identifying_runs_),
            "grids": {k: [float(v) for v in g] for k, g in self.grids_.items()},
            "data_scales": dict(self.data_scales_),
            "grid_edges": list(self.grid_edges_),
        }
        if getattr(self, "time_blocks_", None):
            out["cv_folds"] = dict(self.time_blocks_)
        return out

    def _filter_text(self) -> dict:
        return {
            "type": "first_order_lowpass",
            "update": "y += (1 - exp(-dt/tau)) * (x - y)",
            "initial_condition": FILTER_STATE_TEXT,
        }

    def to_dict(self) -> dict:
        """The ``rafi.model/1`` artefact of the fitted model."""
        body = {
            "kind": self.kind,
            "machine": self.machine,
            "key_sensors": self.sensors_,
            "inputs": self._inputs_text(),
            "target": "displacement change dz (um) from the reference state",
            "reference": dict(self.reference),
            "speed_reference": {"rule": self._speed_rule(), "window_s": self._window_s()},
            "hyperparameters": self._hyper()
            | {"component_envelope": bool(getattr(self, "component_envelope", False))},
            "selected": self._selected(),
            "cv": self.cv_table_,
            "features": self.feature_names_,
            "coefficients": floats(self.coef_),
            "scale": floats(self.scale_),
            "filter": self._filter_text(),
            "regressor_ranges": self.regressor_ranges_,
            "speed_range_rpm": self.speed_range_rpm_,
            "train_runs": self.train_runs_,
            "rmse_um": self.rmse_um_,
            "n": self.n_,
            "data": self.data_,
            "code_version": CODE_VERSION,
        }
        if getattr(self, "envelope_", None) is not None:  # the training envelope (rafi.family.envelope)
            body["envelope"] = self.envelope_
        if getattr(self, "interval_", None) is not None:  # the prediction interval (rafi.family.intervals)
            body["interval"] = dict(self.interval_)
        if getattr(self, "adaptation_", None) is not None:  # an adapted prior (rafi.family.adapted)
            body["adaptation"] = dict(self.adaptation_)
        return finish_artefact(body)

    @classmethod
    def from_dict(cls, d: dict):
        """A fitted model from its artefact (refused if edited)."""
        check_artefact(d, cls.kind)
        names = cls._param_names()
        params = {k: v for k, v in d.get("hyperparameters", {}).items() if k in names}
        m = cls(reference=d["reference"], machine=d["machine"], **params)
        selected = d["selected"]
        m.sensors_ = list(d["key_sensors"])
        m.taus_ = [float(t) for t in selected["taus_s"]]
        m.alpha_ = float(selected["alpha"])
        m.speed_gain_ = bool(selected.get("speed_gain", False))
        m.speed_terms_ = bool(selected.get("speed_terms", m.speed_terms))
        m.identifying_runs_ = list(selected.get("identifying_runs", []))
        m.feature_names_ = list(d["features"])
        m.coef_ = np.asarray(d["coefficients"], dtype=float)
        m.scale_ = np.asarray(d["scale"], dtype=float)
        m.regressor_ranges_ = d["regressor_ranges"]
        m.speed_range_rpm_ = d["speed_range_rpm"]
        m.train_runs_ = d["train_runs"]
        m.rmse_um_ = d.get("rmse_um")
        m.n_ = d.get("n")
        m.cv_table_ = d.get("cv", [])
        m.data_ = d.get("data", {})
        m.grids_ = {k: [float(v) for v in g] for k, g in selected.get("grids", {}).items()}
        m.data_scales_ = dict(selected.get("data_scales", {}))
        m.grid_edges_ = list(selected.get("grid_edges", []))
        m.time_blocks_ = selected.get("cv_folds")
        m.envelope_ = d["envelope"] if isinstance(d.get("envelope"), dict) else None
        m.interval_ = d["interval"] if isinstance(d.get("interval"), dict) else None
        m.adaptation_ = d["adaptation"] if isinstance(d.get("adaptation"), dict) else None
        m._from_selected(selected)
        return m

    def _from_selected(self, selected: dict) -> None:
        """Fitted attributes of a subclass from the artefact's ``selected`` (none here)."""
