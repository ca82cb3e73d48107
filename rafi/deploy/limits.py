"""Limits and fault rules around the streaming compensator: what may reach the controller.

NumPy only, like :mod:`rafi.deploy.compensator`. ``docs/deploy.md`` ("Limits and faults",
"Transitions") describes the rules for a controls engineer; the settings are the ``deploy:``
block (``docs/settings.md``).

Use::

    safe = SafeCompensator(limits=Limits.from_settings(settings["deploy"]))
    safe.step(t, n, temps).status                 # "off": no model loaded, nothing is sent
    safe.load(load_champion("results/m/registry"))  # the qualified model (rafi.deploy.qualified)
    safe.start_from(value_um)                       # the value the controller holds now
    cmd = safe.step(t_s, speed_rpm, temps)          # cmd.command_um: what to write if cmd.send
    safe.resume_from(value_um)                      # after a reconnect: the value read again
    safe.swap(new_champion)                         # a new champion while running: ramp to it

The rules, per sample, in this order
------------------------------------
1. **Off.** Without a loaded model the status is ``off``, the command 0 um and ``send`` is
   False: nothing is written.
2. **Sensor checks** (only the sensors the model reads, and the speed), before the filters:

   * *missing*: NaN;
   * *out of range*: outside ``temp_valid_c`` (an open thermocouple, a unit mix-up); the value
     is replaced by NaN before the filters, so it cannot corrupt their state (a filter holds
     on NaN);
   * *stuck*: the reading has not changed for ``stuck_s`` seconds while another sensor the
     model reads moved by at least ``stuck_change_k`` over the same time (a sensor that sits
     still while the machine around it heats or cools); the value is still fed (there is no
     better one), but the model's value is not trusted;
   * *speed missing*: NaN speed.

3. **The model** (:class:`rafi.deploy.compensator.Compensator`): ``referencing`` while it
   collects its reference window (the target is then ``safe_um``), else its value.
4. **Outside the trained range**: a rise beyond the training range of a sensor (for RAFI, of
   the speed models in use) by more than ``range_margin_k``, or a speed above the highest
   trained speed by more than ``speed_margin_rpm``. Speeds below the trained ones are not
   outside: the machine at rest cooling down is normal service, and every model of the family
   extrapolates to rest by its own rule (``docs/models.md``). An ensemble
   (:mod:`rafi.deploy.ensemble_stream`) is outside where any of its members is, each judged by
   its own ranges and reference; the sensor checks (2) cover every sensor a member reads.
5. **Interval too wide** (``max_interval_um``, off by default): the model's prediction
   interval (the artefact's ``interval`` block, :mod:`rafi.deploy.interval_stream`) is wider
   (``upper - lower``) than ``max_interval_um``; cause ``interval_wide: <width> um wider than
   deploy.max_interval_um <limit> um``. Checked where the model has a value and its reference
   is in force (not while ``referencing``); an artefact without the block never trips it.
6. **Fault rule.** On a fault (2), a model without value, outside the trained range (4) or an
   interval too wide (5), the command *holds* for ``hold_s`` seconds (status ``hold``) the
   last command sent in ``ok`` or ``referencing`` state (at start or after a reconnect: the
   value read from the controller), then *ramps* to ``safe_um`` at ``ramp_um_per_s`` (status
   ``ramp``) and stays there. When the fault clears, the status is ``ok`` again and the command returns to the
   model's value under the rate limit (7). ``fault`` names every cause.
7. **Clamp**, then **rate limit.** The target value is clamped to ``clamp_um``; the command
   then moves towards it by at most ``rate_um_per_s * min(dt, interval_s)`` per sample (``dt``
   the time since the previous sample, ``interval_s`` the loop's interval, one sample per
   write; a replay sets it to the log's sample period; 0 at the first sample): after a long
   gap (a lost connection) it resumes at the rate limit, not in one step. ``rate_limited``
   says the rate limit held the command back from its target, ``clamped`` that the clamp
   changed the command sent (the target was clamped and the rate limit did not act: while the
   rate limit holds the command back, the clamp changes nothing of it).

Bumpless: the command starts from the value the controller holds (:meth:`SafeCompensator.start_from`,
else 0 um: a replay from power-on, compensation off) and, after a lost connection, from the
value read again (:meth:`SafeCompensator.resume_from`: someone may have changed it); a new
model (:meth:`SafeCompensator.swap`) takes over from the command in force. So no command
differs from the one before it (or from the value read) by more than the rate limit.

The session's reference state (the temperatures of every sensor and the speed over the
reference window after power-on or :meth:`SafeCompensator.capture_reference`) is kept, so that
a model swapped in while running compensates from the same reference as the one it replaces
(:meth:`Compensator.set_reference`). Its filters start settled on its first sample: the
machine is taken as thermally settled at the swap (:meth:`SafeCompensator.swap`).

The command is always finite and inside ``clamp_um``.

The interval a :class:`Command` reports (``lower_um``, ``upper_um``, ``half_width_um``,
``interval_cell``) is the *model's*: around ``model_um``, also during ``hold`` and ``ramp``
(where the command is not the model's value, and no interval is claimed for it); the fault
says why the command left the model. NaN / ``""`` without a block, without a model value, and
while off.

``outside_envelope`` says the model's value was held at its training envelope's edge (a feature
or the prediction beyond the training range widened by its margin, :mod:`rafi.family.envelope`;
ridge kinds only, False for ``rafi`` / ``rafi_linear``, while referencing and while off; an
ensemble's: any member's). It is
not a fault: the value is the model's, bounded; "outside the trained range" (rule 4) is the
limit that acts.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from rafi.contract.sensors import DEFAULT_SENSORS
from rafi.deploy.compensator import ENSEMBLE, Compensator
from rafi.errors import SettingsError, TargetError

__all__ = ["STATUSES", "Command", "Limits", "SafeCompensator"]

#: Status of a command (``docs/deploy.md``).
STATUSES = {
    "off": "no qualified model loaded: nothing is sent",
    "referencing": "the model collects its reference window: the command goes to safe_um",
    "ok": "the model's value, clamped and rate limited",
    "hold": "a fault, outside the trained range or the interval too wide: the command in force is held",
    "ramp": "the fault lasted longer than hold_s: the command ramps to safe_um",
}


@dataclass(frozen=True)
class Limits:
    """The limits and fault-rule settings (the ``deploy:`` block; defaults in
    :mod:`rafi.settings`, meanings in the module docstring)."""

    clamp_um: tuple[float, float]
    rate_um_per_s: float
    temp_valid_c: tuple[float, float]
    stuck_s: float
    stuck_change_k: float
    range_margin_k: float
    speed_margin_rpm: float
    hold_s: float
    safe_um: float
    ramp_um_per_s: float
    interval_s: float
    max_interval_um: float | None

    @classmethod
    def from_settings(cls, deploy: dict) -> Limits:
        """Limits from a machine's effective ``deploy`` settings (other keys are ignored).

        Raises
        ------
        SettingsError
            A range whose ends are not increasing, or ``safe_um`` outside ``clamp_um``.
        """
        kw = dict(
            clamp_um=deploy["clamp_um"],
            rate_um_per_s=deploy["rate_um_per_s"],
            temp_valid_c=deploy["temp_valid_c"],
            stuck_s=deploy["stuck_s"],
            stuck_change_k=deploy["stuck_change_k"],
            range_margin_k=deploy["range_margin_k"],
            speed_margin_rpm=deploy["speed_margin_rpm"],
            hold_s=deploy["hold_s"],
            safe_um=deploy["safe_um"],
            ramp_um_per_s=deploy["ramp_um_per_s"],
            interval_s=deploy["interval_s"],
            max_interval_um=deploy["max_interval_um"],
        )
        for key in ("clamp_um", "temp_valid_c"):
            lo, hi = (float(v) for v in kw[key])
            if not lo < hi:
                raise SettingsError(f"deploy.{key} is [{lo:g}, {hi:g}]; the first end must be the lower")
            kw[key] = (lo, hi)
        for key in ("rate_um_per_s", "ramp_um_per_s", "interval_s", "stuck_s", "stuck_change_k"):
            if not float(kw[key]) > 0:
                raise SettingsError(f"deploy.{key} is {kw[key]!r}; it must be above 0")
        wide = kw["max_interval_um"]
        if wide is not None and (isinstance(wide, bool) or not (isinstance(wide, (int, float)) and wide > 0)):
            raise SettingsError(f"deploy.max_interval_um is {wide!r}; expected um above 0, or none (off)")
        if not kw["clamp_um"][0] <= float(kw["safe_um"]) <= kw["clamp_um"][1]:
            clamp = list(kw["clamp_um"])
            raise SettingsError(f"deploy.safe_um ({kw['safe_um']}) is outside deploy.clamp_um {clamp}")
        return cls(**{k: (v if isinstance(v, tuple) or v is None else float(v)) for k, v in kw.items()})


class Command(NamedTuple):
    """What :meth:`SafeCompensator.step` returns for one sample (module docstring; the
    interval fields are the model's interval, NaN / ``""`` without one; ``outside_envelope``
    the compensator's :attr:`rafi.deploy.compensator.Step.outside_envelope`: the model's value
    was held at its training envelope's edge, :mod:`rafi.family.envelope`; informational, not
    a fault: the value is the model's)."""

    t_s: float
    command_um: float
    status: str
    model_um: float
    raw_um: float
    clamped: bool
    rate_limited: bool
    fault: str
    outside_range: bool
    send: bool
    lower_um: float = float("nan")
    upper_um: float = float("nan")
    half_width_um: float = float("nan")
    interval_cell: str = ""
    outside_envelope: bool = False


class _SensorWatch:
    """Missing / out-of-range / stuck checks of the model's sensors, one sample at a time."""

    def __init__(self, names: list[str], limits: Limits):
        self.names = names
        self.limits = limits
        self.since_t = np.full(len(names), np.nan)  # when each reading last changed
        self.value = np.full(len(names), np.nan)  # ... to what
        self.others_at = np.full((len(names), len(names)), np.nan)  # every reading at that time

    def check(self, t: float, temps: np.ndarray) -> tuple[np.ndarray, list[str]]:
        """The readings to feed (out of range -> NaN) and the faults of this sample."""
        lo, hi = self.limits.temp_valid_c
        faults, fed = [], temps.copy()
        for i, (name, v) in enumerate(zip(self.names, temps)):
            if not np.isfinite(v):
                faults.append(f"{name} missing")
            elif not lo <= v <= hi:
                faults.append(f"{name} out of range ({v:.4g} degC)")
                fed[i] = np.nan
        valid = fed  # NaN where missing or out of range
        for i, v in enumerate(valid):
            if not np.isfinite(v):
                continue
            if v != self.value[i] or not np.isfinite(self.since_t[i]):
                self.since_t[i], self.value[i] = t, v
                self.others_at[i] = valid
                continue
            if t - self.since_t[i] >= self.limits.stuck_s:
                with np.errstate(invalid="ignore"):
                    moved = np.abs(valid - self.others_at[i])
                moved[i] = np.nan
                if np.nanmax(moved, initial=0.0) >= self.limits.stuck_change_k:
                    faults.append(f"{self.names[i]} stuck")
        return fed, faults


class SafeCompensator:
    """A compensator with the limits and fault rules of the module docstring.

    The constructor only stores the limits; :meth:`load` loads a model, :meth:`start_from`
    says where the controller is, :meth:`step` takes samples.

    Parameters
    ----------
    limits : Limits
        The limits in force.

    Attributes
    ----------
    sensors_ : tuple of str
        The machine's sensors (set by :meth:`load`): the order of every sample's temperatures.
    compensator_ : Compensator
        Set by :meth:`load` (absent before: the status is ``off``).
    command_um_ : float
        The last command (after :meth:`start_from` / :meth:`resume_from`: the value read).
    held_um_ : float
        What a ``hold`` keeps: the last command sent in ``ok`` or ``referencing`` state, or
        the value read from the controller at start or after a reconnect.
    reference_temperatures_ : ndarray of shape (len(sensors),) or None
        The session's reference state, the machine's sensors (the median over the reference window,
        NaN where a sensor had no valid value); None while the first window is collected.
    reference_speed_rpm_ : float
        The session's reference speed (median over the reference window).
    """

    def __init__(self, *, limits: Limits):
        self.limits = limits

    # ------------------------------------------------------------------ the API
    def load(self, artefact: dict, sensors=DEFAULT_SENSORS) -> SafeCompensator:
        """Load a model artefact of the family (``rafi.model/1``) and start from power-on;
        ``sensors`` are the machine's, the order of the temperatures of every sample.

        The command starts from 0 um (compensation off, as in a replay from power-on) until
        :meth:`start_from` says what the controller holds. Whether the model is *qualified*
        for the machine is the caller's check (:func:`rafi.deploy.qualified.load_champion`);
        the replay of any model uses this too.
        """
        self.sensors_ = tuple(sensors)
        self._artefact = artefact
        self._install(Compensator.from_artefact(artefact, sensors=self.sensors_, input_rule=self._input_rule))
        self._offered = None
        self.session_note_: str | None = None
        self.command_um_ = 0.0
        self.held_um_ = 0.0
        self.reference_temperatures_: np.ndarray | None = None
        self.reference_speed_rpm_ = float("nan")
        self._window_rows: list[tuple[float, float, np.ndarray]] = []
        self._last_t: float | None = None
        self._bad_since: float | None = None
        return self

    def start_from(self, value_um: float | None) -> SafeCompensator:
        """Start from the value the controller holds now (None: not known, ``safe_um``).

        The first command equals it; the following ones move from it under the rate limit.

        Raises
        ------
        TargetError
            A value that is not finite or lies outside ``clamp_um``: moving it into the clamp
            would be a step, so it is left to the operator.
        """
        value = self.limits.safe_um if value_um is None else self._check_read(value_um)
        self.command_um_ = self.held_um_ = value
        self._last_t = None  # the next sample does not move the command
        return self

    def resume_from(self, value_um: float | None) -> SafeCompensator:
        """Resume after a lost connection from the value read again from the controller (None:
        not known, the last command is kept). A ``hold`` then keeps that value. The rate limit
        of the next sample counts at most ``interval_s``. Raises as :meth:`start_from`."""
        if value_um is not None:
            self.command_um_ = self.held_um_ = self._check_read(value_um)
        return self

    def swap(self, artefact: dict) -> SafeCompensator:
        """Load another model while running (a new champion); the command goes on from the
        command in force, under the rate limit, towards the new model's value.

        The new model gets the session's reference state (:attr:`reference_temperatures_`,
        :meth:`Compensator.set_reference`), not the machine's warm state of now; while the
        first reference window is still being collected, it collects its own from the next
        sample. Its filters start settled on its first sample (the machine is taken as
        thermally settled then; a filtered feature is off by the settling of its filter, which
        fades with the filter's time constant). The fault timer and the hold value carry on.
        """
        comp = Compensator.from_artefact(artefact, sensors=self.sensors_, input_rule=self._input_rule)
        self._artefact = artefact
        if self.reference_temperatures_ is not None:
            comp.set_reference(self.reference_temperatures_, self.reference_speed_rpm_)
        self._install(comp)
        self._window_rows = []
        return self

    def capture_reference(self) -> None:
        """Capture a new reference state from the next sample on
        (:meth:`Compensator.capture_reference`); it becomes the session's reference."""
        self.compensator_.capture_reference()
        self._window_rows = []

    # ------------------------------------------------------------------ across a restart
    def session_state(self) -> dict:
        """The session as JSON (:mod:`rafi.deploy.session`): the session's reference (or the
        rows of its window so far), the fault timer and the model's own state; times in the
        sample clock (``clock_s``: the last sample's)."""
        from rafi.deploy.session import compensator_state, json_list, json_number

        ref = self.reference_temperatures_
        return {
            "sensors": list(self.sensors_),
            "clock_s": json_number(self.compensator_.t_prev_s),
            "reference": None
            if ref is None
            else {"temperatures": json_list(ref), "speed_rpm": json_number(self.reference_speed_rpm_)},
            "reference_rows": [[t, json_number(n), json_list(temps)] for t, n, temps in self._window_rows],
            "fault_since_s": json_number(self._bad_since),
            "model": compensator_state(self.compensator_),
        }

    def offer_session(self, state: dict | None, *, why: str = "", decide) -> SafeCompensator:
        """Offer a stored session to the next sample (:mod:`rafi.deploy.session`).

        ``decide(temperatures) -> Decision`` tells, from the first sample's temperatures,
        whether to keep it; kept, it is restored at that sample (:meth:`_resume`), else the
        reference is captured anew. :attr:`session_note_` then says which, and why (``why``:
        the reason there is no ``state``)."""
        self._offered = (state, why, decide)
        self.session_note_ = None
        return self

    def _resume(self, t: float, temperatures) -> None:
        from rafi.deploy.session import json_array, json_float, restore_compensator

        state, why, decide = self._offered
        self._offered = None
        if state is None:
            self.session_note_ = f"reference captured anew: {why}"
            return
        decision = decide(np.asarray(temperatures, dtype=float))
        if not decision.keep:
            self.session_note_ = f"reference captured anew: {decision.reason}"
            return
        clock_s = state.get("clock_s")
        shift = 0.0 if decision.gap_s is None or clock_s is None else (t - decision.gap_s) - float(clock_s)
        comp, ref = self.compensator_, state.get("reference")
        try:
            if state["model"].get("model_id") == comp.model_id:
                restore_compensator(comp, state["model"], shift)
                how = "the model's reference and filters go on"
            elif ref is not None:
                comp.set_reference(json_array(ref["temperatures"]), json_float(ref["speed_rpm"]))
                how = f"model {comp.model_id[:12]} is new since: its filters start settled"
            else:
                self.session_note_ = (
                    "reference captured anew: the stored reference window was another model's"
                )
                return
        except (ValueError, KeyError, TypeError) as exc:
            self._install(
                Compensator.from_artefact(self._artefact, sensors=self.sensors_, input_rule=self._input_rule)
            )
            self.session_note_ = f"reference captured anew: the stored session does not fit the model ({exc})"
            return
        if ref is not None:
            self.reference_temperatures_ = json_array(ref["temperatures"])
            self.reference_speed_rpm_ = json_float(ref["speed_rpm"])
        self._window_rows = [
            (float(t) + shift, json_float(n), json_array(temps))
            for t, n, temps in state.get("reference_rows") or []
        ]
        since = state.get("fault_since_s")
        self._bad_since = None if since is None else float(since) + shift
        self.session_note_ = f"reference kept from {decision.reason}; {how}"

    # ------------------------------------------------------------------ internals
    def _install(self, comp: Compensator) -> None:
        self.compensator_ = comp
        names = [comp.sensors[i] for i in comp.sensor_index]
        self._watch = _SensorWatch(names, self.limits)
        self._faults: list[str] = []

    def _check_read(self, value_um) -> float:
        lo, hi = self.limits.clamp_um
        value = float(value_um)
        if not (np.isfinite(value) and lo <= value <= hi):
            raise TargetError(
                f"the controller holds {value:g} um, outside deploy.clamp_um [{lo:g}, {hi:g}]: moving it "
                "inside would be a step, so nothing is written; set it inside by hand or widen "
                "deploy.clamp_um (docs/deploy.md, Transitions)"
            )
        return value

    def _input_rule(self, t: float, rpm: float, temps: np.ndarray):
        idx = self.compensator_.sensor_index
        fed, faults = self._watch.check(t, temps[idx])
        if not np.isfinite(rpm):
            faults.append("speed missing")
        self._faults = faults
        if not np.array_equal(fed, temps[idx], equal_nan=True):
            temps = temps.copy()
            temps[idx] = fed
        self._fed = temps  # every sensor as the model is fed (out of range -> NaN)
        return rpm, temps, None

    def _note_reference(self, t: float, rpm: float, temperatures, status: str) -> None:
        """Collect the session's reference (every sensor) while the model collects its own."""
        temps = np.array(temperatures, dtype=float)
        lo, hi = self.limits.temp_valid_c
        with np.errstate(invalid="ignore"):
            temps[~((temps >= lo) & (temps <= hi))] = np.nan
        if status == "referencing":
            self._window_rows.append((t, float(rpm), temps))
            return
        rows, self._window_rows = self._window_rows, []
        if not rows:
            return
        stack = np.array([r[2] for r in rows])
        self.reference_temperatures_ = np.array(
            [np.median(c[np.isfinite(c)]) if np.isfinite(c).any() else np.nan for c in stack.T]
        )
        speeds = [r[1] for r in rows]
        if t - rows[0][0] <= self.compensator_.window_s:
            speeds.append(float(rpm))  # the speed's window includes its end (Compensator)
        finite = [s for s in speeds if np.isfinite(s)]
        self.reference_speed_rpm_ = float(np.median(finite)) if finite else float("nan")

    def _outside(self, rpm: float) -> list[str]:
        """Causes of "outside the trained range" for the current sample (rises beyond the
        training range by more than ``range_margin_k``; a speed above the trained speeds by
        more than ``speed_margin_rpm``). An ensemble is outside where any of its members is,
        each judged by its own ranges and reference (its value blends every member's); a
        sensor is named once, the speed against the lowest trained top that it passes."""
        comp = self.compensator_
        members = comp.members.values() if comp.kind == ENSEMBLE else (comp,)
        rises: dict[str, str] = {}
        tops: list[float] = []
        for member in members:
            beyond, top = self._outside_of(member, rpm)
            for name, text in beyond:
                rises.setdefault(name, text)
            if np.isfinite(rpm) and abs(rpm) > top + self.limits.speed_margin_rpm:
                tops.append(top)
        out = list(rises.values())
        if tops:
            out.append(f"speed {abs(rpm):.0f} r/min above trained {min(tops):.0f} r/min")
        return out

    def _outside_of(self, comp: Compensator, rpm: float) -> tuple[list[tuple[str, str]], float]:
        """One model kind's compensator: its key sensors whose rise is beyond their training range
        by more than ``range_margin_k`` (name, cause) and its highest trained speed (inf before
        its reference is in force: nothing is judged then)."""
        lim = self.limits
        if comp.ref_values is None:
            return [], float("inf")
        p = len(comp.sensor_index)
        rises = self._fed[comp.sensor_index] - comp.ref_values[:p]
        if comp.exponents is not None:  # RAFI: the ranges of the speed models in use
            top = float(comp.speeds_rpm.max())
            lo, hi = comp.rise_bounds(rpm)
        else:
            top = comp.speed_range_rpm[1]
            lo, hi = comp.ranges[:, 0], comp.ranges[:, 1]
        with np.errstate(invalid="ignore"):
            beyond = (rises < lo - lim.range_margin_k) | (rises > hi + lim.range_margin_k)
        names = [comp.sensors[comp.sensor_index[i]] for i in np.flatnonzero(beyond)]
        causes = [
            (name, f"{name} rise {r:.3g} K outside trained range") for name, r in zip(names, rises[beyond])
        ]
        return causes, float(top)

    def _interval_wide(self, out) -> list[str]:
        """The cause of rule 5 for the model's step ``out`` (empty: off, no interval, or narrow)."""
        limit = self.limits.max_interval_um
        if limit is None or out.status == "referencing":
            return []
        width = out.upper_um - out.lower_um
        if not width > limit:  # NaN (no interval) is not a fault
            return []
        return [f"interval_wide: {width:.3g} um wider than deploy.max_interval_um {limit:g} um"]

    def _target(self, t: float, dt: float, model_status: str, model_um: float, causes: list) -> tuple:
        """(status, the value the command moves towards) by the rules 3 and 6."""
        lim = self.limits
        if model_status == "referencing" and not causes:
            self._bad_since = None
            return "referencing", lim.safe_um
        if causes or model_status == "no_value":
            if self._bad_since is None:
                self._bad_since = t
            if t - self._bad_since < lim.hold_s:
                return "hold", self.held_um_
            step = lim.ramp_um_per_s * min(dt, lim.interval_s)
            return "ramp", self.command_um_ + float(np.clip(lim.safe_um - self.command_um_, -step, step))
        self._bad_since = None
        return "ok", model_um

    def _limit(self, target: float, dt: float) -> tuple[float, bool, bool]:
        """(command, clamped, rate_limited): rule 7, and which limit changed the command."""
        lim, previous = self.limits, self.command_um_
        clamped_target = float(np.clip(target, *lim.clamp_um))
        max_step = lim.rate_um_per_s * min(dt, lim.interval_s)
        delta = clamped_target - previous
        command = previous + float(np.clip(delta, -max_step, max_step))
        rate_limited = abs(delta) > max_step
        # the command is always inside the clamp: while the rate limit holds it back from the
        # clamped value, the unclamped one would give the same command, so the clamp did not act
        clamped = clamped_target != target and not rate_limited
        return command, bool(clamped), bool(rate_limited)

    # ------------------------------------------------------------------ one sample
    def step(self, t_s: float, speed_rpm: float, temperatures) -> Command:
        """Take one sample (as :meth:`Compensator.step`) and return the command to send."""
        t = float(t_s)
        if not hasattr(self, "compensator_"):
            return Command(t, 0.0, "off", float("nan"), float("nan"), False, False, "", False, False)
        if self._offered is not None:
            self._resume(t, temperatures)
        collecting = self.compensator_.window is not None
        out = self.compensator_.step(t, speed_rpm, temperatures)
        if collecting:
            self._note_reference(t, speed_rpm, temperatures, out.status)
        causes = list(self._faults)
        outside = [] if out.status == "referencing" else self._outside(float(speed_rpm))
        if out.status == "no_value" and not causes:
            causes.append("no model value")
        causes += outside
        causes += self._interval_wide(out)
        dt = 0.0 if self._last_t is None else max(t - self._last_t, 0.0)
        self._last_t = t
        status, target = self._target(t, dt, out.status, out.compensation_um, causes)
        command, clamped, rate_limited = self._limit(target, dt)
        self.command_um_ = command
        if status in ("ok", "referencing"):
            self.held_um_ = command
        model, raw = float(out.compensation_um), float(out.raw_um)
        faults = "; ".join(causes)
        interval = (out.lower_um, out.upper_um, out.half_width_um, out.interval_cell)
        return Command(
            t,
            command,
            status,
            model,
            raw,
            clamped,
            rate_limited,
            faults,
            bool(outside),
            True,
            *interval,
            bool(out.outside_envelope),
        )
