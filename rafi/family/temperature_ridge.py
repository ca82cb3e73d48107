"""Kind ``temperature_ridge``: ridge on the temperature rises and their fixed low-pass filters,
with no speed input (the plain ridge of the real-data benchmark, inside the family)."""

from __future__ import annotations

from collections.abc import Sequence

from rafi.family.dynamic import DynamicRidge
from rafi.family.ridge_global import MODELS
from rafi.settings import MACHINE_DEFAULTS


class TemperatureRidge(DynamicRidge):
    """Kind ``temperature_ridge``: ridge on the rises and their low-pass filters; no speed input.

    ``dz = sum_i sum_tau b_(i,tau) L_tau(dT_i)``: every usable sensor's rise ``dT_i`` through
    every first-order low-pass filter ``L_tau`` of ``taus_s`` at once (``tau = 0`` is the rise
    itself; :func:`rafi.family.features.lowpass_runs`), and nothing else: no speed term, no speed
    gain, no heat-input history, no intercept (at the reference state every input is 0). Only
    ``alpha`` is chosen, by whole-run CV on the training runs (``cv``, ``cv_metric``). It is the
    yardstick of ``benchmarks/bench_realdata.py`` (the "plain ridge", 900 s and 3600 s filters) in
    the family's conventions, so the selection can offer it where the training runs find the
    speed-driven terms of the other kinds extrapolating worse than the temperatures alone
    (``docs/models.md``).

    Parameters
    ----------
    taus_s : sequence of float
        The filter time constants, every one used (``models: temperature_ridge_taus_s``).
    sensors, alphas, cv, cv_metric, reference, machine, speed_tolerance_rpm, filter_restart_gap_s,
    component_envelope
        As :class:`rafi.family.ridge_global.RidgeGlobal`.
    """

    kind = "temperature_ridge"

    def __init__(
        self,
        *,
        taus_s: Sequence[float] = MODELS["temperature_ridge_taus_s"],
        sensors: Sequence[str] | None = None,
        alphas: Sequence[float] = MODELS["ridge_alphas"],
        cv: str = MODELS["cv"],
        cv_metric: str = MODELS["cv_metric"],
        reference: dict = MACHINE_DEFAULTS["reference"],
        machine: str | None = None,
        speed_tolerance_rpm: float = MACHINE_DEFAULTS["speed_tolerance_rpm"],
        filter_restart_gap_s: float = MODELS["filter_restart_gap_s"],
        component_envelope: bool = MODELS["component_envelope"],
    ):
        self.taus_s = taus_s
        self.sensors = sensors
        self.alphas = alphas
        self.cv = cv
        self.cv_metric = cv_metric
        self.reference = reference
        self.machine = machine
        self.speed_tolerance_rpm = speed_tolerance_rpm
        self.filter_restart_gap_s = filter_restart_gap_s
        self.component_envelope = component_envelope

    # The parts of DynamicRidge this kind does not have, fixed (not parameters: a temperature
    # ridge with a speed input would be `dynamic`).
    speed_terms = False
    speed_gain = False
    heat_input = False
    speed_reference = "zero"

    def _inputs_text(self) -> str:
        return (
            "temperature rises dT (K) of all usable sensors and their first-order low-pass filters; "
            "no speed input; displacement is not an input"
        )

    def _grid_settings(self) -> dict:
        return {"temperature_ridge_taus_s": self.taus_s}

    def _tau_grid(self) -> tuple[list[float], int]:
        taus = list(self.grids_["temperature_ridge_taus_s"])
        return taus, len(taus)

    @staticmethod
    def _tau_subsets(n: int, max_taus: int) -> list[tuple[int, ...]]:
        """Every filter at once: the one candidate set."""
        return [tuple(range(n))]

    def _chosen(self) -> dict:
        return {"alpha": self.alpha_}

    def _hyper(self) -> dict:
        return {
            "sensors": None if self.sensors is None else list(self.sensors),
            "alphas": self._alphas(),
            "cv": self.cv,
            "cv_metric": self.cv_metric,
            "taus_s": [float(t) for t in self.taus_s],
            "speed_tolerance_rpm": float(self.speed_tolerance_rpm),
            "filter_restart_gap_s": float(self.filter_restart_gap_s),
        }

    @classmethod
    def from_dict(cls, d: dict):
        """A fitted model from its artefact."""
        return super(DynamicRidge, cls).from_dict(d)
