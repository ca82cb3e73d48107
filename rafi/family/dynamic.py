"""Kind ``dynamic``: ridge on first-order low-pass filtered rises (a lag model) + speed terms."""

from __future__ import annotations

from collections.abc import Sequence

from rafi.family.ridge_global import MODELS, RidgeGlobal
from rafi.settings import MACHINE_DEFAULTS


class DynamicRidge(RidgeGlobal):
    """Kind ``dynamic``: ridge on low-pass filtered rises (lag model) + speed terms.

    Features: ``L_tau(dT_i)`` (and ``L_tau(dT_i) * n`` with ``speed_gain``) for every usable
    sensor ``i`` and every ``tau`` of the chosen set, where ``L_tau`` is the causal
    first-order filter of :func:`rafi.family.features.lowpass_runs` (``tau = 0`` is the
    unfiltered rise), plus the speed terms of :class:`RidgeGlobal`. The set of time constants
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
    **others
        As :class:`RidgeGlobal`.
    """

    kind = "dynamic"

    def __init__(
        self,
        *,
        taus_s: Sequence[float] = MODELS["dynamic_taus_s"],
        max_taus: int = MODELS["dynamic_max_taus"],
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
        )
        self.taus_s = taus_s
        self.max_taus = max_taus

    def _inputs_text(self) -> str:
        return (
            "first-order low-pass filtered temperature rises dT (K) of all usable sensors; "
            "speed (krpm) relative to the reference state; displacement is not an input"
        )

    def _grid_settings(self) -> dict:
        return {"dynamic_taus_s": self.taus_s}

    def _tau_grid(self) -> tuple[list[float], int]:
        return list(self.grids_["dynamic_taus_s"]), int(self.max_taus)

    def _chosen(self) -> dict:
        return {"alpha": self.alpha_, "dynamic_taus_s": self.taus_}

    def _hyper(self) -> dict:
        taus = self.taus_s if isinstance(self.taus_s, str) else [float(t) for t in self.taus_s]
        return {**super()._hyper(), "taus_s": taus, "max_taus": int(self.max_taus)}
