"""Kind ``grey_box``: ridge on filtered rises + causal first-order filtered speed powers
(the heat input to the unmeasured shaft, bearings and stator), ``docs/models.md``."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

from rafi.family.features import SPEED_SCALE_RPM, lowpass_runs, rise_column
from rafi.family.ridge import FILTER_STATE_TEXT, RidgeBase, cv_scores
from rafi.family.whole_log import filtered_rises, heat_input, lowpass_log, unsort
from rafi.settings import MACHINE_DEFAULTS

MODELS = MACHINE_DEFAULTS["models"]
#: What the artefact records of the filter search: every filter constant at once (since issue 7;
#: the subset search and its limits were retired on 2026-11-29, issue 49). Recorded unchanged so
#: that the artefacts, and so the model ids, of every grey_box stay as they were.
FILTER_SEARCH_RECORD = {"max_taus": 1, "max_speed_taus": 2, "filter_search": "all"}


class GreyBox(RidgeBase):
    """Kind ``grey_box``: ridge on filtered rises + filtered speed-power (heat input) terms.

    ``dz = sum_{tau in T} sum_i b_{i,tau} L_tau(dT_i) + sum_{tau in S} sum_p c_{p,tau} L_tau((n/10^4)^p)
    [+ d (n^2 - n0^2)]`` with ``L_tau`` the causal first-order filter of
    :func:`~rafi.family.features.lowpass_runs`.
    The speed powers (``speed_powers``, default 0, 1, 5/3, 2: spindle running (magnetising
    loss, ~constant; ``n^0`` is 0 at rest), motor/windage, bearing friction,
    rotor losses) stand for the heat input to the *unmeasured* fast parts (shaft, bearings,
    stator); their filters represent the lag with which those parts follow a speed change.

    Initial condition of the filters: on a frame of whole logs (``log``, ``log_t_s``) every
    filter runs over the log and each feature is the filtered absolute input minus its median
    over the run's reference window (:mod:`rafi.family.whole_log`). Per-run frames, as
    before: speed-power filters under ``reference.rule: run_start`` (cold start) start from
    zero (machine at rest) and are referenced like ``dz`` (minus the median over the
    reference window); under ``log_start`` they start settled on the first sample's speed.

    The instantaneous centrifugal term ``n^2 - n0^2`` (krpm^2) is used only if it is
    identifiable: at least ``MIN_IDENTIFYING_RUNS`` training runs show a step from their
    reference speed (:func:`~rafi.family.features.speed_change_evidence`: at least a reference
    window of samples
    within ``speed_tolerance_rpm`` of the reference speed and as many beyond it), e.g. a cold
    start logged from rest. Constant-speed runs referenced while already spinning do not
    identify it (the reference absorbs the draw-in), so it is left out rather than fitted to
    speed jitter. ``ridge_global`` and ``dynamic`` apply the same rule to their speed terms.

    Every rise filter constant and every heat-input filter constant at once; chosen jointly by
    whole-run CV on the training runs only (``cv_metric``, default ``max_abs``): the heat-input
    block in or out, the draw-in lag and ``alpha``.

    Parameters
    ----------
    taus_s : sequence of float or "auto"
        Rise filter constants (``models: grey_box_taus_s``); ``auto``: from the sample period
        and the median training-run length (:mod:`rafi.family.grids`).
    speed_taus_s : sequence of float or "auto"
        Heat-input filter constants (``models: grey_box_speed_taus_s``).
    speed_powers : sequence of float
        The powers ``p`` of ``(n/10^4)^p`` (``models: grey_box_speed_powers``).
    centrifugal_lags_s : sequence of float or "auto"
        First-order lags of the ``n^2`` draw-in term to choose from (``models: grey_box_centrifugal_lags_s``).
    cv_metric : str
        ``rmse`` or ``max_abs`` (``models: grey_box_cv_metric``).
    **others
        ``sensors``, ``alphas``, ``cv``, ``speed_terms``, ``speed_reference``, ``reference``,
        ``machine``, ``speed_tolerance_rpm``, ``filter_restart_gap_s``, ``component_envelope`` as
        :class:`rafi.family.ridge_global.RidgeGlobal`.
    """

    kind = "grey_box"

    def __init__(
        self,
        *,
        taus_s: Sequence[float] = MODELS["grey_box_taus_s"],
        speed_taus_s: Sequence[float] = MODELS["grey_box_speed_taus_s"],
        speed_powers: Sequence[float] = MODELS["grey_box_speed_powers"],
        centrifugal_lags_s: Sequence[float] = MODELS["grey_box_centrifugal_lags_s"],
        cv_metric: str = MODELS["grey_box_cv_metric"],
        sensors: Sequence[str] | None = None,
        alphas: Sequence[float] = MODELS["ridge_alphas"],
        cv: str = MODELS["cv"],
        speed_terms: bool = True,
        speed_reference: str = MODELS["speed_reference"],
        reference: dict = MACHINE_DEFAULTS["reference"],
        machine: str | None = None,
        speed_tolerance_rpm: float = MACHINE_DEFAULTS["speed_tolerance_rpm"],
        filter_restart_gap_s: float = MODELS["filter_restart_gap_s"],
        component_envelope: bool = MODELS["component_envelope"],
    ):
        self.taus_s = taus_s
        self.speed_taus_s = speed_taus_s
        self.speed_powers = speed_powers
        self.centrifugal_lags_s = centrifugal_lags_s
        self.cv_metric = cv_metric
        self.sensors = sensors
        self.alphas = alphas
        self.cv = cv
        self.speed_terms = speed_terms
        self.speed_reference = speed_reference
        self.reference = reference
        self.machine = machine
        self.speed_tolerance_rpm = speed_tolerance_rpm
        self.filter_restart_gap_s = filter_restart_gap_s
        self.component_envelope = component_envelope

    def _inputs_text(self) -> str:
        return (
            "first-order low-pass filtered temperature rises dT (K) of all usable sensors; first-order "
            "low-pass filtered speed powers (n/10000 r/min)^p; displacement is not an input"
        )

    # -- hyperparameters, as used (floats and ints; the grids as resolved by fit)
    def _grid_settings(self) -> dict:
        return {
            "grey_box_taus_s": self.taus_s,
            "grey_box_speed_taus_s": self.speed_taus_s,
            "grey_box_centrifugal_lags_s": self.centrifugal_lags_s,
        }

    def _rise_taus(self) -> list[float]:
        return list(self.grids_["grey_box_taus_s"])

    def _speed_taus(self) -> list[float]:
        return list(self.grids_["grey_box_speed_taus_s"])

    def _powers(self) -> list[float]:
        return [float(p) for p in self.speed_powers]

    def _lags(self) -> list[float]:
        return list(self.grids_["grey_box_centrifugal_lags_s"]) or [0.0]

    @staticmethod
    def _given(value):
        """A grid setting as recorded: ``auto`` or the list as floats."""
        return value if isinstance(value, str) else [float(v) for v in value]

    def _check_params(self) -> None:
        super()._check_params()
        lags = self.centrifugal_lags_s
        if not isinstance(lags, str) and len(lags) and min(float(v) for v in lags) < 0:
            raise ValueError(f"centrifugal_lags_s={self.centrifugal_lags_s!r}: lags must be >= 0")

    def _cold_start(self) -> bool:
        return self.reference["rule"] == "run_start"

    def _features(
        self,
        frame: pd.DataFrame,
        sensors: Sequence[str],
        taus: Sequence[float],
        *,
        speed_taus: Sequence[float],
        instantaneous: bool,
        centrifugal_lags: Sequence[float],
    ):
        """Feature matrix in ``frame`` row order and the feature names: filtered rises, filtered
        speed powers (none if ``speed_taus`` is empty) and, if ``instantaneous``, the ``n^2``
        draw-in column once per lag of ``centrifugal_lags``."""
        lay = self._layout(frame)
        rpm = frame["speed_rpm"].to_numpy(dtype=float)[lay.order]
        parts, names = [filtered_rises(frame, lay, sensors, taus)], []
        for tau in taus:
            names += [f"{rise_column(s)}@{tau:g}s" for s in sensors]
        if speed_taus:
            powers = self._powers()
            parts.append(
                heat_input(
                    rpm,
                    lay,
                    speed_taus,
                    powers,
                    running_rpm=float(self.speed_tolerance_rpm),
                    cold_start=self._cold_start(),
                    window_s=self._window_s(),
                )
            )
            for tau in speed_taus:
                names += [f"L{tau:g}s(n^{p:.4g})" for p in powers]
        if instantaneous:
            n0 = (self._reference_speed(frame)[lay.order] / SPEED_SCALE_RPM) ** 2
            n2 = (rpm / SPEED_SCALE_RPM) ** 2
            if lay.whole_logs:  # L(n^2) over the log, relative to the reference speed's n0^2
                parts.append(lowpass_log(n2, lay.t, lay.restart, centrifugal_lags) - n0[:, None])
            else:
                parts.append(lowpass_runs((n2 - n0)[:, None], lay.t, lay.codes, centrifugal_lags))
            names += ["n2_krpm2" if lag <= 0 else f"L{lag:g}s(n2_krpm2)" for lag in centrifugal_lags]
        return unsort(np.column_stack(parts), lay), names

    def _design(self, frame: pd.DataFrame):
        return self._features(
            frame,
            self.sensors_,
            self.taus_,
            speed_taus=self.speed_taus_,
            instantaneous=self.instantaneous_,
            centrifugal_lags=[self.centrifugal_lag_s_],
        )

    def _filter_sets(self) -> tuple[list, list]:
        """Candidate (rise tau indices, speed tau indices) sets: every rise filter at once, with
        every heat-input filter at once or with none (the ridge penalty sorts out redundant
        constants; CV decides whether the heat-input terms help at all, e.g. they do not for runs
        referenced while already spinning)."""
        n_rise, n_speed = len(self._rise_taus()), len(self._speed_taus())
        return [tuple(range(n_rise))], [(), tuple(range(n_speed))]

    def fit(self, runs_table: pd.DataFrame, runs_frame: pd.DataFrame):
        """Choose the filter constants, the draw-in lag and ``alpha`` by whole-run CV on the
        training runs, then fit on all of them; returns ``self``."""
        table, frame, rows, sensors = self._prepare(runs_table, runs_frame)
        train = frame.loc[rows]
        self.speed_gain_ = False
        self.instantaneous_ = self._use_speed_terms(train)
        self.speed_terms_ = self.instantaneous_  # grey_box's only reference-speed term is n^2 - n0^2
        rise_taus, speed_taus, alphas = self._rise_taus(), self._speed_taus(), self._alphas()
        y = train["dz_um"].to_numpy(dtype=float)
        run_ids = self._cv_units(train)
        lags = self._lags() if self.instantaneous_ else [0.0]
        feats, names, key = self._candidate_features(
            frame,
            sensors,
            rise_taus,
            speed_taus=speed_taus,
            instantaneous=self.instantaneous_,
            centrifugal_lags=lags,
        )
        feats = feats[rows]
        p, q = len(sensors), len(self._powers())
        n_rise = p * len(rise_taus)
        n_speed = q * len(speed_taus)
        inst_cols = (
            [np.arange(n_rise + n_speed + k, n_rise + n_speed + k + 1) for k in range(len(lags))]
            if self.instantaneous_
            else [np.arange(0)]
        )
        folds = self._cv_folds(feats, y, run_ids, table, key)
        cv_table, best = [], (math.inf, None, None, None, 0.0, None)
        rise_sets, speed_sets = self._filter_sets()
        for rs in rise_sets:
            rcols = [np.arange(i * p, (i + 1) * p) for i in rs]
            for ss in speed_sets:
                scols = [n_rise + np.arange(j * q, (j + 1) * q) for j in ss]
                for lag, inst in zip(lags, inst_cols):
                    cols = np.concatenate(rcols + scols + [inst])
                    scores = cv_scores(folds, cols, alphas, self.cv_metric)
                    taus = [rise_taus[i] for i in rs]
                    staus = [speed_taus[j] for j in ss]
                    for a, sc in zip(alphas, scores):
                        cv_table.append(
                            {
                                "taus_s": taus,
                                "speed_taus_s": staus,
                                "centrifugal_lag_s": lag,
                                "alpha": a,
                                "score_um": float(sc),
                            }
                        )
                        if sc < best[0] - 1e-12:
                            best = (float(sc), taus, staus, a, lag, cols)
        _, taus, staus, alpha, lag, cols = best
        self.speed_taus_ = staus
        self.centrifugal_lag_s_ = float(lag)
        design = self._chosen_design(feats, names, cols, frame, key)
        return self._fit_final(
            table, frame, rows, sensors, taus, alpha=alpha, cv_table=cv_table, design=design
        )

    def _chosen(self) -> dict:
        """What CV chose among grid values: every filter constant is in the model (nothing
        chosen, no edge); the draw-in lag only if the term is used."""
        out = {"alpha": self.alpha_}
        if self.instantaneous_:
            out["grey_box_centrifugal_lags_s"] = self.centrifugal_lag_s_
        return out

    # -- artefact
    def _hyper(self) -> dict:
        return {
            **super()._hyper(),
            "speed_gain": False,  # no speed-gain products (a key of every ridge kind's artefact)
            "taus_s": self._given(self.taus_s),
            "max_taus": FILTER_SEARCH_RECORD["max_taus"],
            "speed_taus_s": self._given(self.speed_taus_s),
            "max_speed_taus": FILTER_SEARCH_RECORD["max_speed_taus"],
            "speed_powers": self._powers(),
            "filter_search": FILTER_SEARCH_RECORD["filter_search"],
            "centrifugal_lags_s": self._given(self.centrifugal_lags_s),
        }

    def _selected(self) -> dict:
        return {
            **super()._selected(),
            "speed_taus_s": self.speed_taus_,
            "instantaneous_n2": bool(self.instantaneous_),
            "centrifugal_lag_s": float(self.centrifugal_lag_s_),
        }

    def _filter_text(self) -> dict:
        return {
            "type": "first_order_lowpass",
            "update": "y += (1 - exp(-dt/tau)) * (x - y)",
            "initial_condition": {
                **FILTER_STATE_TEXT,
                "per_run_speed_powers": (
                    "zero before the first sample (cold start from rest), then minus the "
                    "median over the reference window"
                    if self._cold_start()
                    else "settled on the first sample's speed"
                ),
                "draw_in": "L(n^2) - n0^2, n0 the reference speed",
            },
        }

    def _from_selected(self, selected: dict) -> None:
        self.speed_taus_ = [float(t) for t in selected.get("speed_taus_s", [])]
        self.instantaneous_ = bool(selected.get("instantaneous_n2", False))
        self.centrifugal_lag_s_ = float(selected.get("centrifugal_lag_s", 0.0))
        self.speed_terms_ = self.instantaneous_
