"""The streaming compensator: one model artefact of the family, evaluated one sample at a time.

NumPy only at run time (no pandas, statsmodels or Snakemake: ``tests/test_compensator.py``
imports this module in a fresh interpreter and checks ``sys.modules``), so it runs on a
controller PC. ``docs/deploy.md`` describes it for a controls engineer.

Use::

    comp = Compensator.from_artefact(json.load(open("best_model.json")))
    for t_s, speed_rpm, temps in samples:          # temps: the machine's sensors (degC), NaN = missing
        out = comp.step(t_s, speed_rpm, temps)     # out.compensation_um, out.status

What it does per sample
-----------------------
1. **Filters from power-on.** Every first-order filter of the model (``dynamic``'s and
   ``grey_box``'s rise filters, the heat-input filters of ``grey_box`` and of ``dynamic`` with
   ``heat_input``, ``grey_box``'s draw-in lag) runs over
   the *absolute* inputs from the first sample on, with the discretisation of
   :func:`rafi.family.whole_log.lowpass_log`: ``y = e y + (1 - e) x``, ``e = exp(-dt/tau)``,
   settled on the first finite value, a NaN input holds the state, and the filters restart
   (settled) after a gap longer than the artefact's ``filter_restart_gap_s``.
2. **Reference capture.** The compensation is relative to a reference state (no intercept:
   0 at the reference). After power-on, and again after :meth:`Compensator.capture_reference`
   (e.g. at the start of a job, with the machine at rest), the compensator collects the first
   ``reference.window_s`` seconds of samples and takes, as the batch code does, the median
   (NaN ignored) of the temperatures (the zero of the rises) and of every filter output (the
   zero of every filtered feature) over the samples with ``t < t0 + window_s``, and the median
   speed over ``t - t0 <= window_s`` (``speed_reference.rule: run_start``; ``zero``: 0 r/min).
   While it collects, the status is ``referencing`` and the compensation is 0 um (the value at
   the reference state). :meth:`Compensator.set_reference` gives a reference instead (see there).
3. **Evaluation.** The features and the model's own formula: the fuzzy blend of per-speed
   polynomials for ``rafi`` / ``rafi_linear`` (:func:`rafi.method.fuzzy.triangular_weights`),
   ``features . coefficients`` for the ridge kinds, the features and the prediction held inside
   the artefact's training envelope (:mod:`rafi.family.envelope`; ``Step.outside_envelope`` says
   where); the
   out-of-range flags of the batch ``predict_detail``.

Equality with the batch prediction, and the exact differences
-------------------------------------------------------------
On a recorded log of whole-log runs (``rule runs``' frame, with ``log`` / ``log_t_s``), fed in
``log_t_s`` order from the log's first sample, with :meth:`capture_reference` called at the
first sample of every run (``reference.rule: run_start``) or of every log segment
(``log_start``), the compensation equals ``predict_detail(frame)["predicted_um"]`` of the
fitted model to 1e-9 um on every sample after the run's reference window where the batch value
is finite; where the batch value is NaN the status is ``no_value``. The differences, all due
to what a device cannot know when a sample arrives:

* **Inside the reference window** the batch code references every sample to the median of the
  whole window, later samples included; the device knows the reference only when the window is
  complete. It returns 0 um with status ``referencing`` there (the batch value there is the
  noise of the window about its median, a few tenths of a um at most).
* **Where a run starts** is known to the batch code from the whole log (``rafi.method.runs``
  cuts it after the fact); the device is told by the caller (:meth:`capture_reference`), e.g.
  by the controller at the start of a job. A new log segment (the logger's gap rule,
  ``clean: max_interpolate_gap_s``) is likewise the caller's decision.
* **Per-run frames** (frames without ``log`` / ``log_t_s``, e.g. the synthetic test runs) are
  filtered by the batch code per run, settled on the run's first *rise*
  (:func:`rafi.family.features.lowpass_runs`); the device filters absolute inputs from
  power-on, i.e. the whole-log rule, which is what the pipeline uses on every real log. The two
  agree for a log that starts settled and holds one run (to the noise of its first sample).
* **Rounding**: the batch filter is vectorised (:func:`rafi.family.whole_log._decay_sum`), the
  device runs the recursion, and the final dot product is summed in another order; the
  difference is ~1e-12 um.

The prediction interval
-----------------------
With an ``interval`` block in the artefact (issue 26), every step also carries the interval of
the model's value, ``[value - h, value + h]`` (``Step.lower_um``, ``upper_um``,
``half_width_um``, ``interval_cell``) by the rule of :mod:`rafi.family.interval_rule`
(:mod:`rafi.deploy.interval_stream`). The change clock is reset at the first sample, at a
filter restart (``dt > restart_gap_s``) and at the first sample after :meth:`capture_reference`;
the batch code resets it at the layout's restarts and at each reference group's first row, so
on the log fed as above the interval equals the batch one to 1e-9 um wherever the compensation
does. Without the block, or without a value, the bounds are NaN and the cell ``""``.

The ensemble
------------
An artefact of kind ``ensemble`` (:mod:`rafi.family.ensemble`) gives an
:class:`~rafi.deploy.ensemble_stream.EnsembleCompensator`: one compensator of this module per
member (its own filters, reference window, envelope and output cap), blended with the weights
over the members that have a value, the flags any member's, the ensemble's own interval; the
hooks below run once, around the blend. It equals the batch prediction as above.

Limits and fault rules (not yet)
--------------------------------
Clamp, rate limit, sensor faults and the trained range are issue 14's next step. The hooks:
``input_rule(t_s, speed_rpm, temperatures) -> (speed_rpm, temperatures, status or None)`` runs
before the filters (a fault rule replaces or flags a sample there; a returned status replaces
``ok``), ``output_rule(t_s, raw_um, status, outside_speed_range, outside_temp_range) ->
(compensation_um, status)`` after the model (clamp, rate limit, hold). Without them the
compensation is the model's raw value; the flags ``outside_speed_range`` / ``outside_temp_range``
of every step are informational (as in the batch ``predict_detail``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from rafi.artefact import model_id_verifies
from rafi.contract.sensors import DEFAULT_SENSORS
from rafi.deploy.interval_stream import NO_INTERVAL, StreamInterval
from rafi.deploy.step import ENSEMBLE, KINDS, MEMBER_KINDS, STATUSES, Step
from rafi.deploy.streaming import LowpassBank, ReferenceWindow
from rafi.family.envelope import (
    bound_components,
    bound_features,
    bound_output,
    component_bounds,
    component_excess,
    component_reach,
    component_scores,
    envelope_bounds,
    key_range_excess,
    key_range_inputs,
    output_bounds,
)
from rafi.family.interval_rule import reads_components
from rafi.method.fuzzy import prepare_centres, triangular_weights

if TYPE_CHECKING:
    from rafi.deploy.ensemble_stream import EnsembleCompensator

__all__ = ["ENSEMBLE", "KINDS", "MEMBER_KINDS", "STATUSES", "Compensator", "Step", "parse_exponents"]

SCHEMA = "rafi.model/1"
SPEED_SCALE_RPM = 1000.0  # rafi.family.features.SPEED_SCALE_RPM
SPEED_POWER_SCALE_RPM = 10000.0  # rafi.family.features.SPEED_POWER_SCALE_RPM


def parse_exponents(terms: Sequence[str], n_vars: int) -> np.ndarray:
    """Exponent matrix of RAFI's terms (the grammar of :func:`rafi.method.model.parse_term`)."""
    out = np.zeros((len(terms), n_vars), dtype=int)
    for j, term in enumerate(terms):
        text = str(term).replace(" ", "")
        if text == "1":
            continue
        for factor in text.split("*"):
            name, _, power = factor.partition("^")
            if not name.startswith("x") or not name[1:].isdigit() or not 1 <= int(name[1:]) <= n_vars:
                raise ValueError(f"term {term!r}: factor {factor!r} is not 'xi' or 'xi^k' (i <= {n_vars})")
            out[j, int(name[1:]) - 1] += int(power) if power else 1
    return out


def _design(x: np.ndarray, exponents: np.ndarray) -> np.ndarray:
    """:func:`rafi.method.model.design_matrix` of one row (same operations, same rounding)."""
    out = np.ones((1, exponents.shape[0]))
    for j, row in enumerate(exponents):
        for i, p in enumerate(row):
            if p:
                out[:, j] *= x[:, i] ** p
    return out


def _check(d: dict) -> str:
    if not isinstance(d, dict):
        raise ValueError(f"a model artefact is a JSON object, got {type(d).__name__}")
    if d.get("schema") != SCHEMA:
        raise ValueError(f"not a {SCHEMA} artefact: schema={d.get('schema')!r}")
    kind = d.get("kind")
    if kind not in KINDS:
        raise ValueError(f"artefact kind {kind!r}: the compensator evaluates {', '.join(KINDS)}")
    if "model_id" in d and not model_id_verifies(d):
        raise ValueError("model_id does not match the artefact content (edited or corrupted)")
    return kind


class Compensator:
    """A model artefact evaluated one sample at a time (module docstring).

    Create it with :meth:`from_artefact`; the constructor only stores its arguments (every one
    of them is set by :meth:`from_artefact`).

    Parameters
    ----------
    kind, model_id : str
        From the artefact.
    sensors : tuple of str
        The machine's sensors: the order of the ``temperatures`` of :meth:`step` and
        :meth:`set_reference` (``T1..T16`` for the paper's rig).
    sensor_index : ndarray of int
        Positions in ``sensors`` of the sensors the model reads (its key sensors / sensors).
    window_s : float
        ``reference.window_s``.
    speed_rule : str
        ``run_start`` (the median speed of the reference window) or ``zero``.
    restart_gap_s : float
        A gap longer than this restarts the filters.
    rise_taus, speed_taus : ndarray
        Rise filter constants (0: the rise itself) and heat-input filter constants.
    speed_powers : ndarray
        The powers of ``(n / 10^4 r/min)^p`` (p = 0: running above ``running_rpm``).
    running_rpm : float
        The speed above which the spindle counts as running (``speed_tolerance_rpm``).
    draw_in_lag_s : float or None
        Lag of ``grey_box``'s ``n^2`` term, None without it.
    speed_terms, speed_gain : bool
        ``ridge_global`` / ``dynamic``: the terms ``n - n0``, ``n^2 - n0^2``; the products ``dT n``.
    coef : ndarray
        Ridge coefficients, or RAFI's ``(k, n_terms)`` per-speed coefficients.
    exponents : ndarray or None
        RAFI's term exponents.
    speeds_rpm : ndarray or None
        RAFI's training speeds (the fuzzy centres).
    ranges : ndarray
        Rise ranges: ridge ``(p, 2)``; RAFI ``(k, p, 2)``, tolerance already applied.
    speed_range_rpm : tuple of float
        Ridge: the training speed range; RAFI: ``(speed_tolerance_rpm, nan)``.
    banks : dict
        The filter banks (``rise``, ``power``, ``draw``; each optional).
    window : ReferenceWindow or None
        The reference window being captured (from the first sample on: an empty one).
    input_rule, output_rule : callable or None
        The hooks of the module docstring.
    interval : StreamInterval or None
        The artefact's prediction interval (None: no ``interval`` block, no interval).
    """

    def __init__(
        self,
        *,
        kind: str,
        model_id: str,
        sensors: tuple,
        sensor_index: np.ndarray,
        window_s: float,
        speed_rule: str,
        restart_gap_s: float,
        rise_taus: np.ndarray,
        speed_taus: np.ndarray,
        speed_powers: np.ndarray,
        running_rpm: float,
        draw_in_lag_s: float | None,
        speed_terms: bool,
        speed_gain: bool,
        coef: np.ndarray,
        exponents: np.ndarray | None,
        speeds_rpm: np.ndarray | None,
        ranges: np.ndarray,
        speed_range_rpm: tuple,
        banks: dict,
        window: ReferenceWindow | None,
        input_rule: Callable | None = None,
        output_rule: Callable | None = None,
        interval: StreamInterval | None = None,
        envelope: tuple | None = None,
        output_bounds: tuple | None = None,
        components: tuple | None = None,
        reach: tuple | None = None,
    ):
        self.kind = kind
        self.model_id = model_id
        self.sensors = sensors
        self.sensor_index = sensor_index
        self.window_s = window_s
        self.speed_rule = speed_rule
        self.restart_gap_s = restart_gap_s
        self.rise_taus = rise_taus
        self.speed_taus = speed_taus
        self.speed_powers = speed_powers
        self.running_rpm = running_rpm
        self.draw_in_lag_s = draw_in_lag_s
        self.speed_terms = speed_terms
        self.speed_gain = speed_gain
        self.coef = coef
        self.exponents = exponents
        self.speeds_rpm = speeds_rpm
        self.ranges = ranges
        self.speed_range_rpm = speed_range_rpm
        self.banks = banks
        self.input_rule = input_rule
        self.output_rule = output_rule
        self.window = window  # the reference window being captured (None: a reference in force)
        self.interval = interval
        self.envelope = envelope
        self.output_bounds = output_bounds
        self.components = components
        self.reach = reach  # rafi.family.envelope.component_reach: the component excess's constants
        self._outside_envelope = False
        self._excess = 0.0  # the last row's range_excess (a ridge kind's; the interval widens with it)
        self._since_change_s = float("nan")
        self._reset_clock = False  # the next sample starts a reference window: reset the clock
        # run-time state: the last sample's time, the reference in force
        self.t_prev_s: float | None = None
        self.ref_values: np.ndarray | None = None
        self.ref_speed_rpm: float = float("nan")
        # constants of the artefact computed on first use, not per sample (the same operations):
        # the fuzzy weights of the last speed seen (a log holds a speed for many samples) and a
        # ridge kind's range_excess inputs (rafi.family.envelope.key_range_excess)
        self._speed_memo: tuple | None = None
        self._centres: tuple | None = None  # rafi.method.fuzzy.prepare_centres of speeds_rpm
        self._excess_inputs: tuple[np.ndarray, np.ndarray] | None = None

    # ------------------------------------------------------------------ creation
    @classmethod
    def from_artefact(
        cls,
        d: dict,
        *,
        sensors=DEFAULT_SENSORS,
        input_rule: Callable | None = None,
        output_rule: Callable | None = None,
    ) -> Compensator | EnsembleCompensator:
        """A compensator for the fitted model ``d`` (a ``rafi.model/1`` artefact of a kind in
        :data:`KINDS`; an edited artefact is refused), capturing its reference from the first
        sample on. ``sensors``: the machine's sensors, the order in which the temperatures
        arrive (its ``input.sensors``). An ensemble's artefact gives an
        :class:`~rafi.deploy.ensemble_stream.EnsembleCompensator` (the same public surface: one
        compensator per member, blended).

        Raises
        ------
        ValueError
            Not such an artefact, its features are not what this module computes, or it reads
            a sensor that is not one of ``sensors``.
        """
        kind = _check(d)
        if kind == ENSEMBLE:
            from rafi.deploy.ensemble_stream import EnsembleCompensator

            return EnsembleCompensator.from_artefact(
                d, sensors=sensors, input_rule=input_rule, output_rule=output_rule, member=cls.from_artefact
            )
        sensors = tuple(sensors)
        missing = [s for s in d.get("key_sensors", []) if s not in sensors]
        if missing:
            raise ValueError(
                f"the model reads {', '.join(missing)}, which the machine's sensors "
                f"({', '.join(sensors)}) do not include"
            )
        ref = d.get("reference") or {}
        window_s = float(ref.get("window_s", 0.0))
        common = dict(kind=kind, model_id=str(d.get("model_id", "")), window_s=window_s, sensors=sensors)
        hooks = dict(input_rule=input_rule, output_rule=output_rule, window=ReferenceWindow.create(window_s))
        hooks["interval"] = StreamInterval.from_artefact(d)
        if kind in ("rafi", "rafi_linear"):
            return cls(**common, **cls._rafi_parts(d, sensors), **hooks)
        return cls(**common, **cls._ridge_parts(d, sensors), **hooks)

    @staticmethod
    def _rafi_parts(d: dict, machine_sensors: tuple) -> dict:
        sensors = list(d["key_sensors"])
        speeds = sorted(d["speeds"], key=lambda sp: float(sp["speed_rpm"]))
        fuzzy = d.get("fuzzy") or {}
        tol_k = float(fuzzy.get("temp_tolerance_k", 0.1))
        ranges = np.array([[sp["regressor_ranges"][s] for s in sensors] for sp in speeds], dtype=float)
        ranges[:, :, 0] -= tol_k
        ranges[:, :, 1] += tol_k
        return dict(
            sensor_index=np.array([machine_sensors.index(s) for s in sensors]),
            speed_rule="zero",
            restart_gap_s=float("inf"),
            rise_taus=np.zeros(1),
            speed_taus=np.zeros(0),
            speed_powers=np.zeros(0),
            running_rpm=0.0,
            draw_in_lag_s=None,
            speed_terms=False,
            speed_gain=False,
            coef=np.array([sp["coefficients"] for sp in speeds], dtype=float),
            exponents=parse_exponents(d["terms"], len(sensors)),
            speeds_rpm=np.array([float(sp["speed_rpm"]) for sp in speeds]),
            ranges=ranges,
            speed_range_rpm=(float(fuzzy.get("speed_tolerance_rpm", 50.0)), float("nan")),
            banks={},
        )

    @staticmethod
    def _ridge_parts(d: dict, machine_sensors: tuple) -> dict:
        kind, sel, hyper = d["kind"], d["selected"], d.get("hyperparameters", {})
        sensors = list(d["key_sensors"])
        p = len(sensors)
        rise_taus = np.array([float(t) for t in sel["taus_s"]])
        grey = kind == "grey_box"
        speed_gain = bool(sel.get("speed_gain", False)) and not grey
        speed_terms = bool(sel.get("speed_terms", False)) and not grey
        # heat-input filters: grey_box's, and dynamic's with heat_input (after its speed terms)
        speed_taus = np.array([float(t) for t in sel.get("speed_taus_s", [])])
        powers = (
            np.array([float(v) for v in hyper.get("speed_powers", [])]) if len(speed_taus) else np.zeros(0)
        )
        lag = float(sel.get("centrifugal_lag_s", 0.0)) if grey and sel.get("instantaneous_n2") else None
        names = []
        for tau in rise_taus:
            names += [f"d{s}@{tau:g}s" for s in sensors]
            if speed_gain:
                names += [f"d{s}@{tau:g}s*n_krpm" for s in sensors]
        if speed_terms:
            names += ["n_krpm", "n2_krpm2"]
        for tau in speed_taus:
            names += [f"L{tau:g}s(n^{q:.4g})" for q in powers]
        if lag is not None:
            names += ["n2_krpm2" if lag <= 0 else f"L{lag:g}s(n2_krpm2)"]
        if names != list(d["features"]):
            raise ValueError(
                f"{kind} artefact: features {d['features']} are not the {names} this compensator computes"
            )
        banks = {}
        if (rise_taus > 0).any():
            banks["rise"] = LowpassBank.create(rise_taus[rise_taus > 0], p)
        if len(speed_taus):
            banks["power"] = LowpassBank.create(speed_taus, len(powers))
        if lag is not None:
            banks["draw"] = LowpassBank.create([lag], 1)
        rng = d["regressor_ranges"]
        speed_rule = (d.get("speed_reference") or {}).get("rule", "zero")
        return dict(
            sensor_index=np.array([machine_sensors.index(s) for s in sensors]),
            speed_rule=speed_rule,
            restart_gap_s=float(hyper.get("filter_restart_gap_s", float("inf"))),
            rise_taus=rise_taus,
            speed_taus=speed_taus,
            speed_powers=powers,
            running_rpm=float(hyper.get("speed_tolerance_rpm", 50.0)),
            draw_in_lag_s=lag,
            speed_terms=speed_terms,
            speed_gain=speed_gain,
            coef=np.asarray(d["coefficients"], dtype=float),
            exponents=None,
            speeds_rpm=None,
            ranges=np.array([rng[s] for s in sensors], dtype=float).reshape(p, 2),
            speed_range_rpm=tuple(float(v) for v in d["speed_range_rpm"]),
            banks=banks,
            envelope=envelope_bounds(d.get("envelope"), len(names)),
            components=component_bounds(d.get("envelope"), len(names), d["coefficients"]),
            reach=component_reach(d.get("envelope"), len(names), d["coefficients"])
            if reads_components(d.get("interval"))
            else None,
            output_bounds=output_bounds(d.get("envelope")),
        )

    # ------------------------------------------------------------------ reference
    def capture_reference(self) -> None:
        """Capture a new reference state from the next sample on (the filters run on)."""
        self.window = ReferenceWindow.create(self.window_s)
        self.ref_values = None
        self._reset_clock = True

    def set_reference(self, temperatures, speed_rpm: float) -> None:
        """Use a given reference state: temperatures of :attr:`sensors` (degC) and speed (r/min).

        The machine is taken as *settled* there: the reference of every filtered feature is
        its settled value (the filtered temperature is the temperature, a heat-input filter
        the speed power itself). The filters themselves are not touched.
        """
        temps = np.asarray(temperatures, dtype=float)[self.sensor_index]
        self.window = None
        self.ref_speed_rpm = float(speed_rpm) if self.speed_rule == "run_start" else 0.0
        parts = [temps]
        if "rise" in self.banks:
            parts.append(np.tile(temps, int((self.rise_taus > 0).sum())))
        if "power" in self.banks:
            parts.append(np.tile(self._powers(float(speed_rpm)), len(self.speed_taus)))
        self.ref_values = np.concatenate(parts)

    # ------------------------------------------------------------------ one sample
    def _powers(self, rpm: float) -> np.ndarray:
        """``grey_box``'s speed powers of one speed (the batch code's operations)."""
        r = np.abs(rpm) / SPEED_POWER_SCALE_RPM
        return np.array(
            [float(np.abs(rpm) > self.running_rpm) if q == 0 else r**q for q in self.speed_powers],
            dtype=float,
        )

    def _filter(self, temps: np.ndarray, rpm: float, dt: float) -> tuple[np.ndarray, float]:
        """Advance every filter; the referenced part (temperatures, filtered temperatures,
        filtered speed powers) and the filtered ``n^2`` (NaN without the draw-in term)."""
        parts = [temps]
        if "rise" in self.banks:
            parts.append(self.banks["rise"].update(temps, dt))
        if "power" in self.banks:
            parts.append(self.banks["power"].update(self._powers(rpm), dt))
        draw = float("nan")
        if "draw" in self.banks:
            draw = float(self.banks["draw"].update(np.array([(rpm / SPEED_SCALE_RPM) ** 2]), dt)[0])
        return np.concatenate(parts), draw

    def step(self, t_s: float, speed_rpm: float, temperatures) -> Step:
        """Take one sample and return the compensation (um) with its status.

        Parameters
        ----------
        t_s : float
            Time (s), increasing (any origin).
        speed_rpm : float
            Spindle speed (r/min); NaN if unknown.
        temperatures : array_like, shape (len(sensors),)
            The machine's sensors (degC), NaN where a sensor has no value.
        """
        t = float(t_s)
        rpm = float(speed_rpm)
        temps_all = np.asarray(temperatures, dtype=float)
        forced = None
        if self.input_rule is not None:
            rpm, temps_all, forced = self.input_rule(t, rpm, temps_all)
        temps = temps_all[self.sensor_index]
        dt = 0.0 if self.t_prev_s is None else t - self.t_prev_s
        restart = self.t_prev_s is None or dt > self.restart_gap_s
        if restart:
            for bank in self.banks.values():
                bank.restart()
        self.t_prev_s = t
        if self.interval is not None:
            self._since_change_s = self.interval.update(t, rpm, reset=restart or self._reset_clock)
        self._reset_clock = False
        values, draw = self._filter(temps, rpm, dt)
        if self.window is not None:
            if not self.window.closes_at(t):
                self.window.add(t, values)
                self.window.add_speed(t, rpm)
                return self._finish(t, 0.0, "referencing", False, False)
            self.window.add_speed(t, rpm)  # t - t0 == window_s still counts for the speed
            self.ref_values = self.window.median()
            self.ref_speed_rpm = self.window.median_speed() if self.speed_rule == "run_start" else 0.0
            self.window = None
        feats = values - self.ref_values
        rises = feats[: len(temps)]
        if self.exponents is not None:
            raw, out_speed, out_temp = self._rafi(rises, rpm)
        else:
            raw, out_speed, out_temp = self._ridge(feats, rises, rpm, draw)
        status = "ok" if np.isfinite(raw) else "no_value"
        if forced is not None:
            status = forced
        return self._finish(t, raw, status, out_speed, out_temp)

    def _finish(self, t: float, raw: float, status: str, out_speed: bool, out_temp: bool) -> Step:
        value = raw if status != "no_value" else float("nan")
        bounds = NO_INTERVAL
        if self.interval is not None:
            outside = bool(out_speed or out_temp)
            bounds = self.interval.bounds(
                float(value), since_change_s=self._since_change_s, outside=outside, excess=self._excess
            )
        excess, self._excess = self._excess, 0.0
        if self.output_rule is not None:
            value, status = self.output_rule(t, raw, status, out_speed, out_temp)
        beyond, self._outside_envelope = self._outside_envelope, False
        return Step(
            t,
            float(value),
            status,
            float(raw),
            bool(out_speed),
            bool(out_temp),
            *bounds,
            beyond,
            float(excess),
        )

    def _rafi(self, rises: np.ndarray, rpm: float) -> tuple[float, bool, bool]:
        """:meth:`rafi.method.model.RafiModel._evaluate` and its flags for one row."""
        x = rises[None, :]
        per_speed = _design(x, self.exponents) @ self.coef.T
        speed = np.array([rpm])
        weights, outside = self.speed_weights(rpm)
        active = weights > 0
        contrib = np.where(active, weights * np.where(active, per_speed, 0.0), 0.0)
        pred = contrib.sum(axis=1)
        bad = ~np.isfinite(speed) | np.any(active & ~np.isfinite(per_speed), axis=1)
        pred[bad] = np.nan
        with np.errstate(invalid="ignore"):
            out_model = np.any(
                (x[:, None, :] < self.ranges[None, :, :, 0]) | (x[:, None, :] > self.ranges[None, :, :, 1]),
                axis=2,
            )
        out_temp = bool(np.any(out_model & active))
        return float(pred[0]), bool(outside[0]), out_temp

    def _ridge(
        self, feats: np.ndarray, rises: np.ndarray, rpm: float, draw: float
    ) -> tuple[float, bool, bool]:
        """``features . coefficients`` of a ridge kind and its flags for one row."""
        p = len(rises)
        n = rpm / SPEED_SCALE_RPM
        filt = feats[p:]
        parts, k = [], 0
        for tau in self.rise_taus:
            if tau > 0:
                block = filt[k * p : (k + 1) * p]
                k += 1
            else:
                block = rises
            parts.append(block)
            if self.speed_gain:
                parts.append(block * n)
        if self.speed_terms:
            n0 = self.ref_speed_rpm / SPEED_SCALE_RPM
            parts.append(np.array([n - n0, n**2 - n0**2]))
        if len(self.speed_taus):
            parts.append(filt[k * p :])
        if self.draw_in_lag_s is not None:
            parts.append(np.array([draw - (self.ref_speed_rpm / SPEED_SCALE_RPM) ** 2]))
        # rafi.family.envelope: the components, the box, the output, as the batch code
        design = np.concatenate(parts)
        # one set of component scores for the bound and the interval's excess (same components)
        scores = component_scores(design[None, :], self.components or self.reach)
        combined, beyond_components = bound_components(
            design, self.components, None if scores is None else scores[0]
        )
        bounded, beyond = bound_features(combined, self.envelope)
        pred, beyond_output = bound_output(bounded @ self.coef, self.output_bounds)
        self._outside_envelope = bool(beyond or beyond_output or beyond_components)
        pred = float(pred)
        lo, hi = self.ranges[:, 0], self.ranges[:, 1]
        out_temp = bool(((rises < lo) | (rises > hi)).any())
        out_speed = bool(rpm < self.speed_range_rpm[0] or rpm > self.speed_range_rpm[1])
        if self._excess_inputs is None:  # key_range_excess's ranges and spans, once
            self._excess_inputs = key_range_inputs(self.ranges, self.speed_range_rpm)
        excess = key_range_excess(
            rises[None, :], [rpm], self.ranges, self.speed_range_rpm, inputs=self._excess_inputs
        )
        self._excess = float(excess[0] + component_excess(design[None, :], self.reach, scores)[0])
        return pred, out_speed, out_temp

    def speed_weights(self, rpm: float) -> tuple[np.ndarray, np.ndarray]:
        """RAFI's fuzzy weights ``(1, k)`` and outside flag ``(1,)`` of one speed
        (:func:`rafi.method.fuzzy.triangular_weights` with the artefact's speed tolerance),
        read-only; those of the last speed asked are kept, so a held speed costs nothing."""
        key = (rpm, math.copysign(1.0, rpm))  # NaN never matches: computed again
        if self._speed_memo is None or self._speed_memo[0] != key:
            if self._centres is None:
                self._centres = prepare_centres(self.speeds_rpm)
            tol = self.speed_range_rpm[0]
            weights, outside = triangular_weights(
                np.array([rpm]), self.speeds_rpm, tolerance_rpm=tol, prepared=self._centres
            )
            weights.setflags(write=False)
            outside.setflags(write=False)
            self._speed_memo = (key, weights, outside, None)
        return self._speed_memo[1], self._speed_memo[2]

    def rise_bounds(self, rpm: float) -> tuple[np.ndarray, np.ndarray]:
        """RAFI's trained range ``(low, high)`` of each key sensor's rise at one speed: over the
        speed models in use there (every one where none is), tolerance applied; kept with
        :meth:`speed_weights`."""
        weights, _ = self.speed_weights(rpm)
        memo = self._speed_memo
        if memo[3] is None:
            active = weights[0] > 0
            ranges = self.ranges[active] if active.any() else self.ranges
            self._speed_memo = (*memo[:3], (ranges[:, :, 0].min(axis=0), ranges[:, :, 1].max(axis=0)))
        return self._speed_memo[3]

    # ------------------------------------------------------------------ introspection
    @property
    def state_nbytes(self) -> int:
        """Bytes of the run-time state (filter states, reference, window in progress)."""
        n = sum(b.nbytes for b in self.banks.values())
        if self.ref_values is not None:
            n += self.ref_values.nbytes
        if self.window is not None:
            n += sum(v.nbytes for v in self.window.values) + 8 * len(self.window.speeds)
        return int(n)
