"""Kind ``dynamic``: ridge on first-order low-pass filtered rises (a lag model) + speed terms
+ the heat-input history (filtered speed powers)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pandas as pd

from rafi.family.ridge_global import MODELS, RidgeGlobal
from rafi.family.whole_log import heat_input, unsort
from rafi.settings import MACHINE_DEFAULTS


class DynamicRidge(RidgeGlobal):
    """Kind ``dynamic``: ridge on low-pass filtered rises (lag model) + speed terms.

    Features: ``L_tau(dT_i)`` (and ``L_tau(dT_i) * n`` with ``speed_gain``; ``cv`` offers it only
    without the heat input) for every usable
    sensor ``i`` and every ``tau`` of the chosen set, where ``L_tau`` is the causal
    first-order filter of :func:`rafi.family.features.lowpass_runs` (``tau = 0`` is the
    unfiltered rise), plus the speed terms of :class:`RidgeGlobal`, plus (``heat_input``) the
    heat-input history ``L_s((n/10^4)^p)`` for every ``s`` of ``speed_taus_s`` and ``p`` of
    ``speed_powers`` at once (:func:`rafi.family.whole_log.heat_input`, the features of
    ``grey_box``): what the unmeasured shaft, bearings and stator follow, which the housing
    temperatures show only late. The set of time constants
    (every subset of ``taus_s`` with at most ``max_taus`` members), ``alpha`` (and
    ``speed_gain: cv``) are chosen jointly by whole-run CV on the training runs. The
    measured displacement is never an input.

    Parameters
    ----------
    taus_s : sequence of float or "auto"
        Filter time constants to choose from (``models: dynamic_taus_s``); ``auto``: derived
        from the sample period and the median training-run length (:mod:`rafi.family.grids`).
    max_taus : int
        At most this many chosen at once (``models: dynamic_max_taus``).
    heat_input : bool
        Add the heat-input history (``models: dynamic_heat_input``).
    speed_taus_s : sequence of float or "auto"
        Its filter time constants, every one at once (``models: grey_box_speed_taus_s``).
    speed_powers : sequence of float
        Its powers ``p`` (``models: grey_box_speed_powers``).
    **others
        As :class:`RidgeGlobal`.
    """

    kind = "dynamic"

    def __init__(
        self,
        *,
        taus_s: Sequence[float] = MODELS["dynamic_taus_s"],
        max_taus: int = MODELS["dynamic_max_taus"],
        heat_input: bool = MODELS["dynamic_heat_input"],
        speed_taus_s: Sequence[float] = MODELS["grey_box_speed_taus_s"],
        speed_powers: Sequence[float] = MODELS["grey_box_speed_powers"],
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
        super().__init__(
            sensors=sensors,
            alphas=alphas,
            cv=cv,
            cv_metric=cv_metric,
            speed_terms=speed_terms,
            speed_gain=speed_gain,
            speed_reference=speed_reference,
            reference=reference,
            machine=machine,
            speed_tolerance_rpm=speed_tolerance_rpm,
            filter_restart_gap_s=filter_restart_gap_s,
            component_envelope=component_envelope,
        )
        self.taus_s = taus_s
        self.max_taus = max_taus
        self.heat_input = heat_input
        self.speed_taus_s = speed_taus_s
        self.speed_powers = speed_powers

    def _inputs_text(self) -> str:
        heat = "first-order low-pass filtered speed powers (n/10000 r/min)^p; " if self._heat_taus() else ""
        return (
            "first-order low-pass filtered temperature rises dT (K) of all usable sensors; "
            f"speed (krpm) relative to the reference state; {heat}displacement is not an input"
        )

    def _grid_settings(self) -> dict:
        grids = {"dynamic_taus_s": self.taus_s}
        if self.heat_input:
            grids["grey_box_speed_taus_s"] = self.speed_taus_s
        return grids

    def _gain_candidates(self) -> list[bool]:
        """As :class:`RidgeGlobal`, but ``speed_gain: cv`` with the heat input is no gain: the
        filtered speed powers carry the speed dependence smoothly, while ``L_tau(dT_i) * n`` would
        step the prediction at every speed change by an amount proportional to the thermal state,
        which no heat flow does (``docs/decisions.md``, 2026-11-26). ``true`` / ``false`` are kept."""
        if self._heat_taus() and self.speed_gain == "cv":
            return [False]
        return super()._gain_candidates()

    def _heat_taus(self) -> list[float]:
        """The heat-input filter constants in use (none without ``heat_input``)."""
        fitted = getattr(self, "speed_taus_", None)
        if fitted is not None:
            return list(fitted)
        return list(self.grids_.get("grey_box_speed_taus_s", [])) if self.heat_input else []

    def _features(
        self, frame: pd.DataFrame, sensors: Sequence[str], taus: Sequence[float], *, speed_gain, speed_terms
    ):
        """:meth:`RidgeGlobal._features` and, last, the heat-input block (in every candidate)."""
        feats, names = super()._features(frame, sensors, taus, speed_gain=speed_gain, speed_terms=speed_terms)
        heat_taus = self._heat_taus()
        if not heat_taus:
            return feats, names
        lay = self._layout(frame)
        rpm = frame["speed_rpm"].to_numpy(dtype=float)[lay.order]
        powers = [float(p) for p in self.speed_powers]
        heat = heat_input(
            rpm,
            lay,
            heat_taus,
            powers,
            running_rpm=float(self.speed_tolerance_rpm),
            cold_start=self.reference["rule"] == "run_start",
            window_s=self._window_s(),
        )
        for tau in heat_taus:
            names = names + [f"L{tau:g}s(n^{p:.4g})" for p in powers]
        return np.column_stack([feats, unsort(heat, lay)]), names

    def fit(self, runs_table: pd.DataFrame, runs_frame: pd.DataFrame):
        """As :meth:`RidgeGlobal.fit`, the heat-input block (if any) in every candidate."""
        self.speed_taus_ = None  # from the grids resolved by this fit
        super().fit(runs_table, runs_frame)
        self.speed_taus_ = self._heat_taus()
        return self

    def _tau_grid(self) -> tuple[list[float], int]:
        return list(self.grids_["dynamic_taus_s"]), int(self.max_taus)

    def _chosen(self) -> dict:
        return {"alpha": self.alpha_, "dynamic_taus_s": self.taus_}

    def _hyper(self) -> dict:
        taus = self.taus_s if isinstance(self.taus_s, str) else [float(t) for t in self.taus_s]
        hyper = {**super()._hyper(), "taus_s": taus, "max_taus": int(self.max_taus)}
        if self.heat_input:  # absent when off: the artefacts of dynamic without it are unchanged
            speed = self.speed_taus_s
            hyper["heat_input"] = True
            hyper["speed_taus_s"] = speed if isinstance(speed, str) else [float(t) for t in speed]
            hyper["speed_powers"] = [float(p) for p in self.speed_powers]
        return hyper

    def _selected(self) -> dict:
        out = super()._selected()
        if self.speed_taus_:
            out["speed_taus_s"] = [float(t) for t in self.speed_taus_]
        return out

    @classmethod
    def from_dict(cls, d: dict):
        """A fitted model from its artefact; one without ``heat_input`` (written before it
        existed, or with it off) has none."""
        m = super().from_dict(d)
        m.heat_input = bool(d.get("hyperparameters", {}).get("heat_input", False))
        return m

    def _from_selected(self, selected: dict) -> None:
        self.speed_taus_ = [float(t) for t in selected.get("speed_taus_s", [])]
