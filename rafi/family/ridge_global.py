"""Kind ``ridge_global``: one ridge regression on every usable temperature rise + speed terms."""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np
import pandas as pd

from rafi.family.features import SPEED_SCALE_RPM, rise_column
from rafi.family.ridge import RidgeBase, cv_scores
from rafi.family.whole_log import filtered_rises, unsort
from rafi.settings import MACHINE_DEFAULTS

MODELS = MACHINE_DEFAULTS["models"]
SPEED_GAINS = (True, False, "cv")


class RidgeGlobal(RidgeBase):
    """Kind ``ridge_global``: one ridge model on all usable rises + speed terms.

    ``dz = sum_i (b_i + g_i n) dT_i + c1 (n - n0) + c2 (n^2 - n0^2)`` with ``n`` in krpm and
    ``n0`` the speed of the reference state. The speed-dependent gains ``g_i n`` (RAFI's
    per-speed coefficients, as one smooth linear law) are used if ``speed_gain`` is true, not
    used if false, and kept or dropped by CV if ``"cv"``. No intercept (at the reference state
    every input is 0, so the compensation is 0). Inputs are scaled by their RMS over the
    training runs; ``alpha`` (and ``speed_gain: cv``) are chosen by whole-run CV (``cv``) on
    the training runs only. The speed terms are used only where the training runs identify
    them (:meth:`RidgeBase._use_speed_terms`).

    Parameters
    ----------
    sensors : sequence of str or None
        The sensors whose rises are inputs; None: every usable one (:func:`usable_sensors`).
    alphas : sequence of float
        Ridge penalties to choose from (``models: ridge_alphas``).
    cv : str
        Whole-run CV scheme (``models: cv``).
    cv_metric : str
        ``rmse`` or ``max_abs`` (``models: cv_metric``).
    speed_terms : bool
        Allow the terms ``n - n0``, ``n^2 - n0^2``.
    speed_gain : bool or "cv"
        The products ``dT_i * n`` (``models: speed_gain``).
    speed_reference : str
        ``auto``, ``run_start`` or ``zero``: the speed ``n0`` (``models: speed_reference``).
    reference : dict
        The ``reference:`` settings (``rule``, ``window_s``).
    machine : str or None
        Machine name recorded in the artefact.
    speed_tolerance_rpm : float
        A sample this far from the reference speed shows a speed step.
    filter_restart_gap_s : float
        Whole-log frames: a gap longer than this (s) restarts the filters
        (``models: filter_restart_gap_s``; :mod:`rafi.family.whole_log`).
    component_envelope : bool
        Also hold the features' principal components inside their training envelope (``models:
        component_envelope``; :mod:`rafi.family.envelope`).
    """

    kind = "ridge_global"

    def __init__(
        self,
        *,
        sensors: Sequence[str] | None = None,
        alphas: Sequence[float] = MODELS["ridge_alphas"],
        cv: str = MODELS["cv"],
        cv_metric: str = MODELS["cv_metric"],
        speed_terms: bool = True,
        speed_gain: bool | str = MODELS["speed_gain"],
        speed_reference: str = MODELS["speed_reference"],
        reference: dict = MACHINE_DEFAULTS["reference"],
        machine: str | None = None,
        speed_tolerance_rpm: float = MACHINE_DEFAULTS["speed_tolerance_rpm"],
        filter_restart_gap_s: float = MODELS["filter_restart_gap_s"],
        component_envelope: bool = MODELS["component_envelope"],
    ):
        self.sensors = sensors
        self.alphas = alphas
        self.cv = cv
        self.cv_metric = cv_metric
        self.speed_terms = speed_terms
        self.speed_gain = speed_gain
        self.speed_reference = speed_reference
        self.reference = reference
        self.machine = machine
        self.speed_tolerance_rpm = speed_tolerance_rpm
        self.filter_restart_gap_s = filter_restart_gap_s
        self.component_envelope = component_envelope

    def _inputs_text(self) -> str:
        return "temperature rises dT (K) of all usable sensors; speed (krpm) relative to the reference state"

    def _tau_grid(self) -> tuple[list[float], int]:
        """Filter constants to choose from and the most chosen at once (rises as they are)."""
        return [0.0], 1

    def _check_params(self) -> None:
        super()._check_params()
        if self.speed_gain not in SPEED_GAINS:
            raise ValueError(f"speed_gain={self.speed_gain!r}: use true, false or cv")

    def _features(
        self, frame: pd.DataFrame, sensors: Sequence[str], taus: Sequence[float], *, speed_gain, speed_terms
    ):
        """Feature matrix in ``frame`` row order and the feature names."""
        lay = self._layout(frame)
        rpm = frame["speed_rpm"].to_numpy(dtype=float)[lay.order]
        filtered = filtered_rises(frame, lay, sensors, taus)
        n = rpm / SPEED_SCALE_RPM
        p = len(sensors)
        parts, names = [], []
        for i, tau in enumerate(taus):  # one block per tau: rises (and rises x speed)
            block = filtered[:, i * p : (i + 1) * p]
            parts.append(block)
            names += [f"{rise_column(s)}@{tau:g}s" for s in sensors]
            if speed_gain is True:
                parts.append(block * n[:, None])
                names += [f"{rise_column(s)}@{tau:g}s*n_krpm" for s in sensors]
        if speed_terms:
            n0 = self._reference_speed(frame)[lay.order] / SPEED_SCALE_RPM
            parts.append(np.column_stack([n - n0, n**2 - n0**2]))
            names += ["n_krpm", "n2_krpm2"]
        return unsort(np.column_stack(parts), lay), names

    @staticmethod
    def _tau_subsets(n: int, max_taus: int) -> list[tuple[int, ...]]:
        """The filter sets the CV chooses among, as positions in the grid of ``n``: every subset
        with at most ``max_taus`` members, smallest first."""
        return [s for k in range(1, max(1, max_taus) + 1) for s in itertools.combinations(range(n), k)]

    def _gain_candidates(self) -> list[bool]:
        """The speed-gain settings the CV chooses among (``speed_gain``)."""
        return [False, True] if self.speed_gain == "cv" else [bool(self.speed_gain)]

    def _design(self, frame: pd.DataFrame):
        return self._features(
            frame, self.sensors_, self.taus_, speed_gain=self.speed_gain_, speed_terms=self.speed_terms_
        )

    def fit(self, runs_table: pd.DataFrame, runs_frame: pd.DataFrame):
        """Choose the filter constants, ``alpha`` (and the speed gain) by whole-run CV on the
        training runs, then fit on all of them; returns ``self``."""
        table, frame, rows, sensors = self._prepare(runs_table, runs_frame)
        train = frame.loc[rows]
        self.speed_terms_ = self._use_speed_terms(train)
        taus_grid, max_taus = self._tau_grid()
        gains = self._gain_candidates()
        alphas = self._alphas()
        y = train["dz_um"].to_numpy(dtype=float)
        run_ids = self._cv_units(train)
        # the superset of the columns, once (over whole logs), then the training rows; each
        # candidate is a subset of the columns
        all_feats, all_names, key = self._candidate_features(
            frame, sensors, taus_grid, speed_gain=max(gains), speed_terms=self.speed_terms_
        )
        all_feats = all_feats[rows]
        p = len(sensors)
        width = p * (2 if max(gains) else 1)
        speed = np.arange(len(taus_grid) * width, all_feats.shape[1])
        folds = self._cv_folds(all_feats, y, run_ids, table, key)
        cv_table, best = [], (math.inf, None, None, None, None)
        for gain in gains:
            for subset in self._tau_subsets(len(taus_grid), max_taus):
                cols = [np.arange(i * width, i * width + (width if gain else p)) for i in subset]
                cols = np.concatenate(cols + [speed])
                scores = cv_scores(folds, cols, alphas, self.cv_metric)
                taus = [taus_grid[i] for i in subset]
                for a, sc in zip(alphas, scores):
                    cv_table.append({"taus_s": taus, "speed_gain": gain, "alpha": a, "score_um": float(sc)})
                    if sc < best[0] - 1e-12:
                        best = (float(sc), taus, a, gain, cols)
        _, taus, alpha, gain, cols = best
        self.speed_gain_ = bool(gain)
        design = self._chosen_design(all_feats, all_names, cols, frame, key)
        return self._fit_final(
            table, frame, rows, sensors, taus, alpha=alpha, cv_table=cv_table, design=design
        )

    def _hyper(self) -> dict:
        return {**super()._hyper(), "speed_gain": self.speed_gain}
