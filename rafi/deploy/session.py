"""The session of ``rafi deploy`` across a restart: its reference state, kept on disk.

A model compensates the change from a *reference state*, captured after power-on
(:mod:`rafi.deploy.compensator`). A process started again on a warm machine would capture the
warm state as its reference and zero a compensation that is due. So the live loop keeps the
session - the reference (every sensor and the speed), the model's own reference and filter
states, the reference window still being collected, the fault timer - in
``results/<unit>/deploy/session.json`` (written atomically, every :data:`SAVE_EVERY_S` seconds,
when the reference is set and when the loop stops), and the next start re-uses it unless
(:func:`decide`, ``docs/deploy.md`` "A restart"):

* there is none, it cannot be read, or it is of another machine or sensor layout;
* it is older than ``deploy.session_max_age_h`` (the shop's temperature may have moved), or
  the clock reads earlier than the time it was saved (a PC clock reset: its age is unknown);
* the machine is *cold*: every sensor the model reads, on the first sample with a value, is at
  most ``deploy.cold_band_k`` above its temperature in the stored reference (colder counts as
  cold too). A sample without any of those values keeps the session (nothing says it is cold;
  within the age limit the stored reference is the machine's last cold state).

Then the reference is captured anew, as at a first start. Kept, it is restored with the
sample clock shifted so that the time between the stored last sample and the first new one is
the real time that passed (wall clock; a followed log's own time stamps where both sessions
followed a log): the filters advance over the gap (or restart settled, as always, after a gap
longer than the artefact's ``filter_restart_gap_s``), a reference window still being
collected closes when its time is up, a fault's hold and ramp go on. Where the champion
changed meanwhile, the new model gets the stored reference (as in a swap while running,
:meth:`rafi.deploy.limits.SafeCompensator.swap`); its filters start settled.

NumPy and the standard library only (the controller PC's footprint).
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from rafi.deploy.compensator import ENSEMBLE

__all__ = [
    "SAVE_EVERY_S",
    "json_array",
    "json_float",
    "json_list",
    "json_number",
    "SCHEMA",
    "Decision",
    "SessionFile",
    "SessionKeeper",
    "compensator_state",
    "decide",
    "restore_compensator",
    "session_path",
]

SCHEMA = "rafi.deploy-session/1"
#: The loop writes the session at most this often (s), besides when its reference is set and
#: when it stops: a crash or a power cut loses at most this much of the filters' history.
SAVE_EVERY_S = 10.0


def session_path(results_dir, unit: str) -> Path:
    """``results/<unit>/deploy/session.json``: beside the unit's replay, where the service may
    write (``docs/systemd/rafi-deploy@.service``, ``ReadWritePaths``)."""
    return Path(results_dir) / unit / "deploy" / "session.json"


# --------------------------------------------------------------------------- JSON of arrays


def json_list(values) -> list | None:
    """An array as JSON (NaN -> null); None stays None."""
    if values is None:
        return None
    array = np.asarray(values, dtype=float)
    return (
        [None if not math.isfinite(v) else float(v) for v in array.ravel()]
        if array.ndim <= 1
        else [json_list(row) for row in array]
    )


def json_array(values) -> np.ndarray | None:
    """JSON (null -> NaN) as a float array; None stays None."""
    if values is None:
        return None
    return np.array(_nan(values), dtype=float)


def _nan(values):
    if isinstance(values, list):
        return [_nan(v) for v in values]
    return math.nan if values is None else float(values)


def json_float(value) -> float:
    return math.nan if value is None else float(value)


def json_number(value) -> float | None:
    return None if value is None or not math.isfinite(float(value)) else float(value)


# --------------------------------------------------------------------------- the model's state


def compensator_state(comp) -> dict:
    """The run-time state of a :class:`~rafi.deploy.compensator.Compensator` as JSON: its
    reference (or the window being collected), its filters and the interval's change clock;
    every time in the compensator's sample clock. An ensemble
    (:class:`~rafi.deploy.ensemble_stream.EnsembleCompensator`) has, instead of a reference and
    filters, ``members``: each member's state by name (its own reference, window and filters)."""
    clock = getattr(comp.interval, "clock", None)
    out = {"model_id": comp.model_id, "t_prev_s": json_number(comp.t_prev_s)}
    if comp.kind == ENSEMBLE:
        out["members"] = {name: compensator_state(m) for name, m in comp.members.items()}
    else:
        window = comp.window
        out.update(
            ref_values=json_list(comp.ref_values),
            ref_speed_rpm=json_number(comp.ref_speed_rpm),
            window=None
            if window is None
            else {
                "t0_s": json_number(window.t0_s),
                "values": [json_list(v) for v in window.values],
                "speeds": [json_number(v) for v in window.speeds],
            },
            banks={
                name: {"state": json_list(bank.state), "seen": [bool(s) for s in bank.seen]}
                for name, bank in comp.banks.items()
            },
        )
    out.update(
        change_clock=None
        if clock is None
        else {"t_reset_s": json_number(clock.t_reset_s), "anchor_rpm": json_number(clock.anchor_rpm)},
        since_change_s=json_number(comp._since_change_s),
        reset_clock=bool(comp._reset_clock),
    )
    return out


def restore_compensator(comp, state: dict, shift_s: float) -> None:
    """Give ``comp`` (a fresh compensator of the same model) the stored ``state``, every time
    moved by ``shift_s`` (the new sample clock = the stored one + ``shift_s``); an ensemble's
    members each get their own.

    Raises
    ------
    ValueError
        The state does not fit the model (another model, other members, another number of
        features).
    """
    if state.get("model_id") != comp.model_id:
        raise ValueError(f"the stored state is of model {state.get('model_id')}, not {comp.model_id}")
    if comp.kind == ENSEMBLE:
        members = state.get("members") or {}
        if list(members) != list(comp.members):
            raise ValueError(
                f"the stored members {list(members)} are not the ensemble's {list(comp.members)}"
            )
        for name, member in comp.members.items():
            restore_compensator(member, members[name], shift_s)
    else:
        _restore_single(comp, state, shift_s)
    t_prev = json_float(state.get("t_prev_s"))
    comp.t_prev_s = None if math.isnan(t_prev) else t_prev + shift_s
    clock = state.get("change_clock")
    if clock is not None and comp.interval is not None:
        comp.interval.clock.t_reset_s = json_float(clock["t_reset_s"]) + shift_s
        comp.interval.clock.anchor_rpm = json_float(clock["anchor_rpm"])
    comp._since_change_s = json_float(state.get("since_change_s"))
    comp._reset_clock = bool(state.get("reset_clock"))


def _restore_single(comp, state: dict, shift_s: float) -> None:
    """The reference, window and filters of one model kind's compensator."""
    from rafi.deploy.streaming import ReferenceWindow

    banks = state.get("banks") or {}
    if set(banks) != set(comp.banks):
        raise ValueError(f"the stored filters {sorted(banks)} are not the model's {sorted(comp.banks)}")
    restored = {}
    for name, bank in comp.banks.items():
        values = json_array(banks[name]["state"]).reshape(bank.state.shape)
        seen = np.array(banks[name]["seen"], dtype=bool).reshape(bank.seen.shape)
        restored[name] = (values, seen)
    for name, (values, seen) in restored.items():
        comp.banks[name].state, comp.banks[name].seen = values, seen
    comp.ref_values = json_array(state.get("ref_values"))
    comp.ref_speed_rpm = json_float(state.get("ref_speed_rpm"))
    window = state.get("window")
    comp.window = (
        None
        if window is None
        else ReferenceWindow(
            window_s=comp.window_s,
            t0_s=None if window["t0_s"] is None else float(window["t0_s"]) + shift_s,
            values=[json_array(v) for v in window["values"]],
            speeds=[json_float(v) for v in window["speeds"]],
        )
    )


def _window_started(model: dict) -> bool:
    """Whether a stored model state (an ensemble's: any member's) has samples in a reference
    window being collected."""
    if (model.get("window") or {}).get("values"):
        return True
    return any(_window_started(m or {}) for m in (model.get("members") or {}).values())


# --------------------------------------------------------------------------- keep or anew


@dataclass(frozen=True)
class Decision:
    """Whether a start keeps the stored session (:func:`decide`) and the reason, as the log
    line says it; ``gap_s``: the time between the stored last sample and now (None: both
    sessions stamp samples with a followed log's own clock, which needs no shift)."""

    keep: bool
    reason: str
    gap_s: float | None = None


def _age(seconds: float) -> str:
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 2 * 3600:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def decide(
    state: dict | None,
    *,
    unit: str,
    sensors,
    now_s: float,
    clock: str = "session",
    temperatures=None,
    read_sensors=(),
    cold_band_k: float,
    max_age_h: float,
) -> Decision:
    """Keep the stored session, or capture the reference anew (module docstring).

    Parameters
    ----------
    state : dict or None
        The stored session (:meth:`SessionFile.load`), None: none.
    unit, sensors
        This start's unit (``machine`` or ``machine@probe``) and the machine's sensors.
    now_s : float
        The wall clock (s since the epoch).
    clock : str
        How this session stamps its samples: ``log`` (a followed log's own time stamps) or
        ``session`` (the loop's clock, which starts anew with the process).
    temperatures : array_like or None
        The first sample's temperatures (of ``sensors``); None: not known yet (only the
        checks that need none are made).
    read_sensors : sequence of str
        The sensors the model reads (the cold rule looks at these).
    cold_band_k, max_age_h : float
        ``deploy.cold_band_k``, ``deploy.session_max_age_h``.
    """
    if state is None:
        return Decision(False, "no stored session")
    if state.get("unit") != unit or list(state.get("sensors") or []) != list(sensors):
        return Decision(False, f"the stored session is of {state.get('unit')!r} with other sensors")
    if state.get("reference") is None and not _window_started(state.get("model") or {}):
        return Decision(False, "the stored session had not started its reference")
    age = now_s - float(state["last_sample_at_s"])
    if age < 0:
        return Decision(False, f"the clock reads {_age(-age)} before the stored session was saved")
    if age > max_age_h * 3600.0:
        return Decision(
            False, f"the stored session is {_age(age)} old (deploy.session_max_age_h: {max_age_h:g})"
        )
    saved = f"the session of {_age(age)} ago"
    gap = None if clock == "log" and state.get("clock") == "log" else age
    reference = (state.get("reference") or {}).get("temperatures")
    if temperatures is None or reference is None:
        return Decision(True, saved, gap)
    ref = json_array(reference)
    temps = np.asarray(temperatures, dtype=float)
    rises = {
        name: float(temps[i] - ref[i])
        for i, name in enumerate(sensors)
        if name in read_sensors and math.isfinite(temps[i]) and math.isfinite(ref[i])
    }
    if not rises:
        return Decision(True, f"{saved} (no temperature to tell a cold machine: kept)", gap)
    name, rise = max(rises.items(), key=lambda item: item[1])
    if rise <= cold_band_k:
        return Decision(
            False,
            f"the machine is cold: every sensor the model reads is within deploy.cold_band_k "
            f"{cold_band_k:g} K of {saved}'s reference",
        )
    return Decision(True, f"{saved}; the machine is warm: {name} is {rise:+.1f} K from its reference", gap)


# --------------------------------------------------------------------------- the file


class SessionFile:
    """The stored session of one unit (``results/<unit>/deploy/session.json``).

    Parameters
    ----------
    path : path
        The file.
    write : bool
        False (a dry run): :meth:`save` writes nothing.
    """

    def __init__(self, path, *, write: bool = True):
        self.path = Path(path)
        self.write = write

    def load(self) -> tuple[dict | None, str]:
        """The stored session, or None and why (no file, a file that cannot be read: the
        start then captures its reference anew; a broken file never stops the loop)."""
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            return None, "no stored session"
        except OSError as exc:
            return None, f"{self.path} cannot be read ({exc.strerror or exc})"
        try:
            state = json.loads(text)
        except ValueError as exc:
            return None, f"{self.path} is not JSON ({exc})"
        if not isinstance(state, dict) or state.get("schema") != SCHEMA:
            return None, f"{self.path} is not a {SCHEMA} file"
        if not isinstance(state.get("last_sample_at_s"), (int, float)):
            return None, f"{self.path} has no last_sample_at_s"
        return state, ""

    def save(self, state: dict) -> None:
        """Write ``state`` atomically (a temporary file in the folder, flushed to disk, then
        renamed over the old one: a power cut leaves the old file or the new, never half)."""
        if not self.write:
            return
        self.path.parent.mkdir(parents=True, exist_ok=True)
        text = json.dumps(state, indent=1, allow_nan=False)
        fd, tmp = tempfile.mkstemp(prefix=".session-", suffix=".tmp", dir=self.path.parent)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(text)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        try:
            folder = os.open(self.path.parent, os.O_RDONLY)
        except OSError:
            return
        try:
            os.fsync(folder)
        finally:
            os.close(folder)


def stamp(now_s: float) -> str:
    """The wall clock as ISO 8601 (UTC, seconds), for the file's reader."""
    return datetime.fromtimestamp(now_s, tz=UTC).isoformat(timespec="seconds")


# --------------------------------------------------------------------------- the loop's side


class SessionKeeper:
    """What the live loop does with the stored session: offer it at start, save it as it runs.

    Parameters
    ----------
    file : SessionFile
        The unit's stored session.
    unit : str
        ``machine`` or ``machine@probe``.
    clock : str
        ``log`` (``--follow``: samples stamped with the log's time) or ``session``.
    cold_band_k, max_age_h : float
        ``deploy.cold_band_k``, ``deploy.session_max_age_h``.
    wall : callable
        The wall clock (``time.time``; a test injects one).
    """

    def __init__(
        self, file: SessionFile, *, unit: str, clock: str, cold_band_k: float, max_age_h: float, wall
    ):
        self.file = file
        self.unit = unit
        self.clock = clock
        self.cold_band_k = float(cold_band_k)
        self.max_age_h = float(max_age_h)
        self.wall = wall
        self._saved_at = -math.inf
        self._sample_t: float | None = None  # the last sample seen, in the sample clock ...
        self._sample_wall = math.nan  # ... and the wall clock when it was stepped
        self._had_reference = False

    def offer(self, safe) -> None:
        """Offer the stored session to ``safe`` (a loaded
        :class:`~rafi.deploy.limits.SafeCompensator`, before its first sample)."""
        state, why = self.file.load()
        now = self.wall()
        checked = decide(
            state, unit=self.unit, sensors=safe.sensors_, now_s=now, clock=self.clock,
            cold_band_k=self.cold_band_k, max_age_h=self.max_age_h,
        )  # fmt: skip
        if state is not None and not checked.keep:
            state, why = None, checked.reason
        comp = safe.compensator_
        read = [comp.sensors[i] for i in comp.sensor_index]

        def rule(temperatures):
            return decide(
                state, unit=self.unit, sensors=safe.sensors_, now_s=now, clock=self.clock,
                temperatures=temperatures, read_sensors=read,
                cold_band_k=self.cold_band_k, max_age_h=self.max_age_h,
            )  # fmt: skip

        safe.offer_session(state, why=why, decide=rule)

    def save(self, safe, *, force: bool = False) -> None:
        """Save the session if :data:`SAVE_EVERY_S` passed, the reference was just set, or
        ``force`` (the loop stops); nothing before the first sample. Called after every
        sample: the wall clock of the last sample is what a restart measures its gap from."""
        if not hasattr(safe, "compensator_") or safe.compensator_.t_prev_s is None:
            return
        now = self.wall()
        if safe.compensator_.t_prev_s != self._sample_t:
            self._sample_t, self._sample_wall = safe.compensator_.t_prev_s, now
        has_reference = safe.reference_temperatures_ is not None
        due = force or now - self._saved_at >= SAVE_EVERY_S or has_reference != self._had_reference
        if not due:
            return
        state = {
            "schema": SCHEMA,
            "unit": self.unit,
            "last_sample_at": stamp(self._sample_wall),
            "last_sample_at_s": self._sample_wall,
        }
        state.update(clock=self.clock, **safe.session_state())
        self.file.save(state)
        self._saved_at, self._had_reference = now, has_reference
