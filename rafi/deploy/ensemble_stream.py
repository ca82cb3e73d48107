"""The CV-weighted ensemble on the machine: one streaming compensator per member, blended.

NumPy only, like :mod:`rafi.deploy.compensator` (whose :meth:`Compensator.from_artefact` gives
an :class:`EnsembleCompensator` for an artefact of kind ``ensemble``, :mod:`rafi.family.ensemble`).
It has the public surface of a :class:`~rafi.deploy.compensator.Compensator`, so
:class:`rafi.deploy.limits.SafeCompensator`, the replay, the live loop, a swap and the stored
session (:mod:`rafi.deploy.session`) hold it as they hold any kind.

Per sample
----------
1. The ``input_rule`` (the fault rules of :mod:`rafi.deploy.limits`) runs once, on every
   sensor the ensemble reads (the union of its members' key sensors); its output feeds every
   member.
2. Every member is a compensator of its own artefact (its own filters, reference window,
   training envelope and output cap), stepped with the same sample and told the same
   :meth:`~EnsembleCompensator.capture_reference` / :meth:`~EnsembleCompensator.set_reference`.
3. While any member collects its reference window the status is ``referencing`` and the value
   0 um (the members of a qualification share the reference settings, so they finish together).
   Then every member's raw value is held inside the ensemble's output bound (its artefact's
   ``envelope``: the training displacement range widened by two spans, which RAFI's kinds do not
   apply themselves; a value so held counts as ``outside_envelope``), and the value is the
   weighted mean of those over the members that have
   one (:func:`blend_row`, the rule of :func:`rafi.family.ensemble.blend`), ``no_value`` where
   none has; ``outside_speed_range`` / ``outside_temp_range`` / ``outside_envelope`` are any
   member's, ``range_excess`` the largest member's.
4. The prediction interval is the ensemble artefact's own ``interval`` block (calibrated on the
   blended residuals) with its own change clock: reset at the first sample, at a gap longer than
   the ensemble's ``filter_restart_gap_s`` (the shortest member's) and at a reference capture,
   as the batch code resets it (:func:`rafi.family.intervals.clock_settings` of the ensemble's
   artefact); the cell is ``outside`` where any member is outside its range, the widening that
   of the largest member's excess. The members' own interval blocks are not evaluated.
5. The ``output_rule`` (clamp, rate limit, hold) runs once, on the blended value.

So on a log fed as :mod:`rafi.deploy.compensator` says, the value and the interval equal the
batch ``predict_detail`` of :class:`rafi.family.ensemble.WeightedEnsemble` and its batch interval
to 1e-9 um after the reference windows (``tests/test_compensator.py``,
``tests/test_interval_stream.py``).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from rafi.contract.sensors import DEFAULT_SENSORS
from rafi.deploy.interval_stream import NO_INTERVAL, StreamInterval
from rafi.deploy.step import ENSEMBLE, MEMBER_KINDS, Step
from rafi.family.envelope import output_bounds

__all__ = ["EnsembleCompensator", "blend_row", "ensemble_weights"]


def blend_row(values, weights) -> float:
    """The weighted mean of the finite ``values`` (NaN when none is finite).

    The rule of :func:`rafi.family.ensemble.blend` for one row, ``sum_k w_k v_k / sum_k w_k``
    over the finite ``v_k``, in plain floats (a handful of members: a NumPy call per operation
    would cost more than the sums).
    """
    num = total = 0.0
    for v, w in zip(values, weights):
        if math.isfinite(v):
            num += w * v
            total += w
    return num / total if total > 0 else float("nan")


def ensemble_weights(d: dict) -> dict[str, float]:
    """The member -> weight of an ensemble artefact, renormalised to sum to 1 (as
    :meth:`rafi.family.ensemble.WeightedEnsemble.from_fitted` does), in the artefact's order.

    Raises
    ------
    ValueError
        No ``weights`` / ``members``, a weight naming no member, a member of a kind the ensemble
        cannot hold, or weights that are not finite, non-negative and of positive sum.
    """
    weights, members = d.get("weights"), d.get("members")
    if not isinstance(weights, dict) or not isinstance(members, dict) or not weights:
        raise ValueError(
            "an ensemble artefact needs 'weights' and 'members' (name -> weight, name -> artefact)"
        )
    unknown = [n for n in weights if n not in members]
    if unknown:
        raise ValueError(f"ensemble weights name {', '.join(unknown)}, which is not among its members")
    for name in weights:
        kind = (members[name] or {}).get("kind") if isinstance(members[name], dict) else None
        if kind not in MEMBER_KINDS:
            raise ValueError(
                f"ensemble member {name!r} is of kind {kind!r}; a member is one of {', '.join(MEMBER_KINDS)}"
            )
    try:
        values = {str(n): float(w) for n, w in weights.items()}
    except (TypeError, ValueError):
        raise ValueError(f"ensemble weights {weights} are not numbers") from None
    total = float(sum(values.values()))
    if not all(np.isfinite(w) and w >= 0 for w in values.values()) or not total > 0:
        raise ValueError(f"ensemble weights {values} are not finite, non-negative with a positive sum")
    return {n: w / total for n, w in values.items()}


class EnsembleCompensator:
    """An ensemble artefact evaluated one sample at a time (module docstring).

    Create it with :meth:`from_artefact` (or :meth:`Compensator.from_artefact`).

    Parameters
    ----------
    model_id : str
        The ensemble artefact's.
    sensors : tuple of str
        The machine's sensors (the order of every sample's temperatures).
    members : dict
        Member name -> its :class:`~rafi.deploy.compensator.Compensator` (no hooks, no interval).
    weights : list of float
        The members' weights, in the order of ``members`` (summing to 1).
    window_s : float
        The ensemble's ``reference.window_s``.
    restart_gap_s : float
        The ensemble's ``filter_restart_gap_s`` (the interval's change clock restarts beyond it).
    input_rule, output_rule : callable or None
        The hooks of :mod:`rafi.deploy.compensator`, run once for the ensemble.
    interval : StreamInterval or None
        The ensemble artefact's own interval.
    output_bounds : tuple of float or None
        ``(low, high)`` every member's raw value is held in (:func:`rafi.family.envelope.output_bounds`
        of the artefact's ``envelope``); None: no bound.

    Attributes
    ----------
    kind : str
        ``ensemble``.
    sensor_index : ndarray of int
        Positions in ``sensors`` of every sensor a member reads (their union, in member order).
    t_prev_s : float or None
        The last sample's time.
    """

    kind = ENSEMBLE

    def __init__(
        self,
        *,
        model_id: str,
        sensors: tuple,
        members: dict,
        weights: list,
        window_s: float,
        restart_gap_s: float,
        input_rule: Callable | None = None,
        output_rule: Callable | None = None,
        interval: StreamInterval | None = None,
        output_bounds: tuple | None = None,
    ):
        self.model_id = model_id
        self.sensors = sensors
        self.members = members
        self.weights = weights
        self.window_s = window_s
        self.restart_gap_s = restart_gap_s
        self.input_rule = input_rule
        self.output_rule = output_rule
        self.interval = interval
        self.output_bounds = output_bounds
        read = dict.fromkeys(int(i) for m in members.values() for i in m.sensor_index)
        self.sensor_index = np.array(list(read), dtype=int)
        self._since_change_s = float("nan")
        self._reset_clock = False
        self.t_prev_s: float | None = None

    @classmethod
    def from_artefact(
        cls,
        d: dict,
        *,
        sensors=DEFAULT_SENSORS,
        input_rule: Callable | None = None,
        output_rule: Callable | None = None,
        member: Callable,
    ) -> EnsembleCompensator:
        """The ensemble of artefact ``d`` (kind ``ensemble``, already checked by
        :meth:`Compensator.from_artefact`: schema and ``model_id``); every member is checked as
        an artefact of its own (schema, kind, ``model_id``, features). ``member(artefact,
        sensors=...)`` builds one member's compensator (:meth:`Compensator.from_artefact`, which
        passes itself: this module does not import it).

        Raises
        ------
        ValueError
            A malformed ensemble (:func:`ensemble_weights`), a member that is not an artefact the
            compensator evaluates, or sensors a member reads that ``sensors`` lacks.
        """
        weights = ensemble_weights(d)
        sensors = tuple(sensors)
        read = dict.fromkeys(
            [*d.get("key_sensors", []), *(s for n in weights for s in d["members"][n].get("key_sensors", []))]
        )
        missing = [s for s in read if s not in sensors]
        if missing:
            raise ValueError(
                f"the model reads {', '.join(missing)}, which the machine's sensors "
                f"({', '.join(sensors)}) do not include"
            )
        members = {}
        for name in weights:
            try:
                comp = member(d["members"][name], sensors=sensors)
            except ValueError as exc:
                raise ValueError(f"ensemble member {name!r}: {exc}") from None
            comp.interval = None  # the ensemble's own interval is the one in force
            members[name] = comp
        hyper = d.get("hyperparameters") or {}
        return cls(
            model_id=str(d.get("model_id", "")),
            sensors=sensors,
            members=members,
            weights=list(weights.values()),
            window_s=float((d.get("reference") or {}).get("window_s", 0.0)),
            restart_gap_s=float(hyper.get("filter_restart_gap_s", float("inf"))),
            input_rule=input_rule,
            output_rule=output_rule,
            interval=StreamInterval.from_artefact(d),
            output_bounds=output_bounds(d.get("envelope")),
        )

    # ------------------------------------------------------------------ reference
    @property
    def window(self):
        """A member's reference window still being collected (None: every member's reference
        is in force)."""
        return next((m.window for m in self.members.values() if m.window is not None), None)

    @property
    def ref_values(self) -> np.ndarray | None:
        """Every member's reference values, concatenated in member order (None while any member
        collects its window). Each member's own (``members[name].ref_values``) goes with its own
        ``sensor_index``; this one only says whether every reference is in force."""
        refs = [m.ref_values for m in self.members.values()]
        return None if any(r is None for r in refs) else np.concatenate(refs)

    def capture_reference(self) -> None:
        """Every member captures a new reference from the next sample on (the filters run on);
        the interval's change clock restarts there."""
        for m in self.members.values():
            m.capture_reference()
        self._reset_clock = True

    def set_reference(self, temperatures, speed_rpm: float) -> None:
        """Every member uses the given reference state
        (:meth:`rafi.deploy.compensator.Compensator.set_reference`)."""
        for m in self.members.values():
            m.set_reference(temperatures, speed_rpm)

    # ------------------------------------------------------------------ one sample
    def step(self, t_s: float, speed_rpm: float, temperatures) -> Step:
        """Take one sample and return the blended compensation (um) with its status (as
        :meth:`rafi.deploy.compensator.Compensator.step`)."""
        t = float(t_s)
        rpm = float(speed_rpm)
        temps = np.asarray(temperatures, dtype=float)
        forced = None
        if self.input_rule is not None:
            rpm, temps, forced = self.input_rule(t, rpm, temps)
        dt = 0.0 if self.t_prev_s is None else t - self.t_prev_s
        restart = self.t_prev_s is None or dt > self.restart_gap_s
        self.t_prev_s = t
        if self.interval is not None:
            self._since_change_s = self.interval.update(t, rpm, reset=restart or self._reset_clock)
        self._reset_clock = False
        steps = [m.step(t, rpm, temps) for m in self.members.values()]
        if any(s.status == "referencing" for s in steps):
            return self._finish(t, 0.0, "referencing", (False, False, False), 0.0)
        values = [s.raw_um for s in steps]
        held = False
        if self.output_bounds is not None:
            lo, hi = self.output_bounds
            held = any(v < lo or v > hi for v in values)  # NaN is neither
            values = [min(max(v, lo), hi) if math.isfinite(v) else v for v in values]
        raw = blend_row(values, self.weights)
        status = "ok" if np.isfinite(raw) else "no_value"
        if forced is not None:
            status = forced
        flags = (
            any(s.outside_speed_range for s in steps),
            any(s.outside_temp_range for s in steps),
            held or any(s.outside_envelope for s in steps),
        )
        excess = max(0.0 if math.isnan(s.range_excess) else s.range_excess for s in steps)
        return self._finish(t, raw, status, flags, excess)

    def _finish(self, t: float, raw: float, status: str, flags: tuple, excess: float) -> Step:
        """The step's value, interval and hooks; ``flags``: outside the speed range, the
        temperature range, the envelope."""
        out_speed, out_temp, beyond = flags
        value = raw if status != "no_value" else float("nan")
        bounds = NO_INTERVAL
        if self.interval is not None:
            bounds = self.interval.bounds(
                float(value),
                since_change_s=self._since_change_s,
                outside=bool(out_speed or out_temp),
                excess=excess,
            )
        if self.output_rule is not None:
            value, status = self.output_rule(t, raw, status, out_speed, out_temp)
        return Step(
            t,
            float(value),
            status,
            float(raw),
            bool(out_speed),
            bool(out_temp),
            *bounds,
            bool(beyond),
            excess,
        )

    # ------------------------------------------------------------------ introspection
    @property
    def state_nbytes(self) -> int:
        """Bytes of the run-time state: every member's (filters, reference, window in progress)."""
        return int(sum(m.state_nbytes for m in self.members.values()))
