"""The live loop: inputs -> :class:`rafi.deploy.limits.SafeCompensator` -> a controller target.

Independent of OPC UA (``rafi.deploy.opcua_client`` supplies a source and a sink; the tests use
fakes). ``rafi deploy`` (:mod:`rafi.deploy.live_cli`) builds it from ``config.yaml``;
``docs/deploy.md`` ("Live: OPC UA") describes it for a controls engineer.

Every ``deploy.interval_s`` seconds one *cycle*:

1. If the link to the controller is down, try to reconnect (the link's bounded back-off); while
   it is down nothing is read, the compensator gets no sample and nothing is written.
2. At the first cycle, and the first after a lost connection, read the value the target holds
   (:meth:`Target.read_current_um`) and start (resume) the command from it: no write differs
   from the value on the controller by more than the rate limit (``docs/deploy.md``,
   Transitions). Every ``deploy.champion_check_s``, look for a new champion and swap it in.
3. Read the new samples from the source (the OPC UA inputs: one sample; a followed log file:
   the lines appended since the last cycle) and step the compensator on each, in order.
4. Write the last command to the target, if ``send`` (never while the status is ``off``), and
   only a command inside ``deploy.clamp_um`` (the limits guarantee it; the loop checks again and
   stops rather than write one outside).

A lost connection (:class:`ConnectionError` from the source or the target) skips the rest of the
cycle. After reconnecting, a followed log's backlog (the lines written during the outage) is
dropped but for its last line, so that the first write after an outage moves at most one
sample's rate limit (``rate_um_per_s * min(dt, interval_s)``, :mod:`rafi.deploy.limits`) away from
the value read back: a backlog stepped sample by sample could move it by the rate limit of every
sample in it. Standard library and NumPy only.
"""

from __future__ import annotations

import math
import os
import re
import time
from collections.abc import Callable, Mapping
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from rafi.contract.sensors import DEFAULT_SENSORS
from rafi.deploy.um_format import signed_um
from rafi.errors import RafiUserError, SettingsError, TargetError

__all__ = ["LiveLoop", "LogFollower", "TARGET_KINDS", "build_target", "check_target_limits"]

#: ``deploy.target.kind`` -> the keys it accepts (``kind`` and ``axis`` besides).
TARGET_KINDS = {
    "sinumerik": (
        "int_incr_per_mm",
        "comp_add_velo_factor",
        "ipo_cycle_s",
        "node_template",
        "skip_unchanged",
    ),
    "csv": ("path", "fsync_each_line"),
    "jsonl": ("path", "fsync_each_line"),
}
#: The keys of a SINUMERIK axis (``deploy.target.axis``).
SINUMERIK_AXIS_KEYS = (
    "name", "number", "sign", "limit_um", "mode", "ref_position_mm", "measured_at_mm", "max_velocity_mm_min",
)  # fmt: skip

_LINE_END = re.compile(rb"[\r\n]")


# --------------------------------------------------------------------------- the target


def build_target(block: Mapping | None, *, sink=None, project_dir="."):
    """The controller target of ``deploy.target``, checked.

    Parameters
    ----------
    block : mapping
        ``deploy.target``: ``kind`` (``sinumerik``, ``csv`` or ``jsonl``), ``axis`` and the
        kind's settings (``docs/deploy.md``, ``docs/deploy-targets.md``).
    sink : object, optional
        The SINUMERIK target's sink (an :class:`~rafi.deploy.opcua_client.OpcUaLink`, or a
        :class:`~rafi.deploy.target_sinumerik.DrySink` for a dry run).
    project_dir : path
        A relative ``path`` of a file target is relative to this folder.

    Returns
    -------
    (Target, str)
        The target (not opened) and the axis name the compensation is written to.

    Raises
    ------
    SettingsError, TargetError
        A missing or unknown setting, a bad value (the target's own checks).
    """
    from rafi.deploy.target_sinumerik import SinumerikAxis, SinumerikTarget
    from rafi.deploy.targets import CsvFileTarget, JsonLinesTarget

    if block is None:
        raise SettingsError(
            "deploy.target is not set: name the controller (kind: sinumerik, csv or jsonl; docs/deploy.md)"
        )
    if not isinstance(block, Mapping):
        raise SettingsError(f"deploy.target is {type(block).__name__}; expected a mapping")
    kind = block.get("kind")
    if kind not in TARGET_KINDS:
        raise SettingsError(f"deploy.target.kind is {kind!r}; expected one of {sorted(TARGET_KINDS)}")
    unknown = sorted(str(k) for k in block if k not in ("kind", "axis", *TARGET_KINDS[kind]))
    if unknown:
        raise SettingsError(
            f"deploy.target.{unknown[0]} is not a setting of kind {kind}; known: "
            f"{['kind', 'axis', *TARGET_KINDS[kind]]}"
        )
    options = {k: block[k] for k in TARGET_KINDS[kind] if k in block}
    axis = block.get("axis")
    if kind == "sinumerik":
        if not isinstance(axis, Mapping):
            raise SettingsError(
                "deploy.target.axis must be a mapping: name, number (machine axis), sign (+1/-1) and "
                "limit_um are required, with no default (docs/deploy-targets.md)"
            )
        extra = sorted(str(k) for k in axis if k not in SINUMERIK_AXIS_KEYS)
        if extra:
            raise SettingsError(
                f"deploy.target.axis.{extra[0]} is not a setting; known: {list(SINUMERIK_AXIS_KEYS)}"
            )
        for key in ("name", "number", "sign", "limit_um"):
            if key not in axis:
                raise SettingsError(
                    f"deploy.target.axis.{key} is missing; it has no default (sign: check on the "
                    "machine which direction cancels the growth, docs/deploy-targets.md)"
                )
        if sink is None:
            raise SettingsError("the sinumerik target needs an OPC UA link (deploy.opcua) or --dry-run")
        target = SinumerikTarget([SinumerikAxis(**dict(axis))], sink, **options)
        return target, str(axis["name"])
    if not isinstance(axis, str):
        raise SettingsError(f"deploy.target.axis is {axis!r}; for kind {kind} it is the axis name (e.g. Z)")
    path = options.pop("path", None)
    if not isinstance(path, str) or not path:
        raise SettingsError(f"deploy.target.path is {path!r}; kind {kind} writes to a file")
    path = Path(project_dir) / os.path.expanduser(path)
    cls = CsvFileTarget if kind == "csv" else JsonLinesTarget
    return cls(path, [axis], **options), axis


def check_target_limits(target, axis: str, limits) -> None:
    """Refuse a set-up where the target would refuse a command the limits allow.

    Every command lies in ``limits.clamp_um``; a SINUMERIK axis refuses values beyond its
    ``limit_um`` (and, in slope mode, slopes beyond MD 32760). Checked before anything is
    written, so that the loop never meets a refusal mid-run.
    """
    if not hasattr(target, "setting_value"):
        return
    for value in (*limits.clamp_um, limits.safe_um):
        try:
            target.setting_value(axis, float(value))
        except TargetError as exc:
            raise TargetError(
                f"deploy.clamp_um {list(limits.clamp_um)} allows {value:g} um, which the target refuses "
                f"({exc}); narrow deploy.clamp_um or widen the axis' limit_um",
                target=target.name,
                axis=axis,
            ) from None


# --------------------------------------------------------------------------- the log follower


def _number(text: str) -> float:
    text = text.strip().strip('"').strip()
    if not text:
        return math.nan
    try:
        value = float(text)
    except ValueError:
        return math.nan
    return value if math.isfinite(value) else math.nan


def _epoch_s(text: str) -> float:
    stamp = datetime.fromisoformat(text.strip().strip('"').strip())
    if stamp.tzinfo is None:
        stamp = stamp.replace(tzinfo=UTC)  # one clock within a file: any fixed origin serves
    return stamp.timestamp()


class LogFollower:
    """Follow a native-format CSV log (``docs/raw-format.md``) as a logger appends to it.

    ``tail -f`` style: only complete lines are read (a line still being written waits for its
    line end); a file that shrinks or is replaced is read again from its start (logged).
    No pandas: the csv module on each line.

    Parameters
    ----------
    path : path
        The log file (it may not exist yet).
    from_start : bool
        Read the lines already in the file too (default: only lines appended from now on;
        the header is read in any case).
    log : callable, optional
        ``log(message)`` for skipped lines and a replaced file.
    sensors : sequence of str
        The machine's sensors (``input.sensors``): the temperature columns read, in order.
    """

    def __init__(
        self, path, *, from_start: bool = False, log: Callable | None = None, sensors=DEFAULT_SENSORS
    ):
        self.path = Path(path)
        self.sensors = tuple(sensors)
        self.from_start = from_start
        self.log = log or (lambda message: None)
        self._pos = 0
        self._ident = None
        self._buffer = b""
        self._columns: dict[str, int] | None = None
        self._last_t = -math.inf
        self.skipped = 0

    def _restart(self, ident, size: int, first: bool) -> None:
        self._ident, self._buffer, self._columns = ident, b"", None
        self._pos = 0
        self._skip_to = size if (first and not self.from_start) else 0

    def _lines(self) -> list[bytes]:
        try:
            st = self.path.stat()
        except FileNotFoundError:
            return []
        ident = (st.st_dev, st.st_ino)
        if self._ident is None:
            self._restart(ident, st.st_size, first=True)
        elif ident != self._ident or st.st_size < self._pos:
            self.log(f"{self.path}: the file was replaced or shortened; following it from its start")
            self._restart(ident, st.st_size, first=False)
        if st.st_size <= self._pos:
            return []
        with open(self.path, "rb") as fh:
            fh.seek(self._pos)
            data = fh.read(st.st_size - self._pos)
        self._pos += len(data)
        data = self._buffer + data
        ends = [m.end() for m in _LINE_END.finditer(data)]
        cut = ends[-1] if ends else 0
        self._buffer = data[cut:]
        start, out = self._pos - len(data), []
        for raw in _LINE_END.split(data[:cut]):
            offset, start = start, start + len(raw) + 1
            out.append((offset, raw))
        return out

    def read(self, now: float | None = None) -> list[tuple[float, float, np.ndarray]]:
        """The samples ``(t_s, speed_rpm, temperatures)`` (of :attr:`sensors`) of the lines completed
        since the
        last call (none if the file did not grow). ``now`` is not used (the log's own clock)."""
        import csv

        samples = []
        for offset, raw in self._lines():
            line = raw.decode("utf-8", errors="replace").lstrip("\ufeff")
            if not line.strip() or line.startswith("#"):
                continue
            fields = next(csv.reader([line]))
            if self._columns is None:
                names = [f.strip() for f in fields]
                missing = [c for c in ("time", "speed_rpm") if c not in names]
                if missing:
                    raise RafiUserError(
                        f"{self.path}: the header has no column {missing[0]!r} (docs/raw-format.md)"
                    )
                self._columns = {name: i for i, name in enumerate(names)}
                continue
            if offset < getattr(self, "_skip_to", 0):
                continue  # written before the loop started
            col = self._columns
            try:
                t_s = _epoch_s(fields[col["time"]])
            except (ValueError, IndexError):
                self.skipped += 1
                self.log(f"{self.path}: a line without a readable time was skipped")
                continue
            if not t_s > self._last_t:
                self.skipped += 1
                continue  # a repeated or older sample: the compensator's clock only advances
            self._last_t = t_s
            values = [
                _number(fields[i]) if i is not None and i < len(fields) else math.nan
                for i in (col.get(name) for name in ("speed_rpm", *self.sensors))
            ]
            samples.append((t_s, values[0], np.array(values[1:], dtype=float)))
        return samples

    def after_outage(self, samples: list) -> list:
        """Of the samples read after a lost connection, the last one only (module docstring)."""
        return samples[-1:]


class LinkSource:
    """The live inputs of a link (an :class:`~rafi.deploy.opcua_client.OpcUaLink`): one sample
    per cycle, stamped with the loop's clock."""

    def __init__(self, link, sensors=DEFAULT_SENSORS):
        self.link = link
        self.sensors = tuple(sensors)

    def read(self, now: float) -> list[tuple[float, float, np.ndarray]]:
        return [self.link.read_sample(now, self.sensors)]

    def after_outage(self, samples: list) -> list:
        return samples


# --------------------------------------------------------------------------- the loop


class LiveLoop:
    """Source -> SafeCompensator -> target, every ``interval_s`` (module docstring).

    Parameters
    ----------
    source : object
        ``read(now) -> [(t_s, speed_rpm, temperatures[16]), ...]`` (:class:`LogFollower`,
        :class:`LinkSource`), raising ConnectionError when the link is lost, and
        ``after_outage(samples) -> samples``.
    safe : rafi.deploy.limits.SafeCompensator
        Loaded with the qualified model.
    target : rafi.deploy.targets.Target
        Opened by :meth:`run` if not open, closed when it ends.
    axis : str
        The target's axis the command goes to.
    interval_s : float
        ``deploy.interval_s``.
    link : object, optional
        The connection to the controller: ``connected`` and ``try_reconnect() -> bool``
        (:class:`~rafi.deploy.opcua_client.OpcUaLink`); None when nothing can be lost.
    clock, sleep : callable
        Seconds (default ``time.monotonic``) and the wait (``time.sleep``); a test injects both.
    log : callable
        ``log(line)``: one progress line per write, one per minute while nothing is written.
    champion : object, optional
        ``poll(now) -> artefact or None`` (:class:`~rafi.deploy.champion_watch.ChampionWatch`):
        a new champion to swap in (:meth:`~rafi.deploy.limits.SafeCompensator.swap`).
    metrics : rafi.deploy.metrics.LoopMetrics, optional
        Told every cycle, reconnect and new champion (Prometheus, ``docs/service.md``).
    notify : rafi.deploy.sd_notify.SdNotify, optional
        systemd's watchdog, kicked after every cycle.
    session : rafi.deploy.session.SessionKeeper, optional
        The session kept across a restart: offered to the compensator at start, saved as the
        loop runs and when it ends (``docs/deploy.md``, "A restart").

    Attributes
    ----------
    phase : str
        ``starting``, ``referencing``, ``running`` or ``reconnecting`` (for the stop message).
    stopped_in : str or None
        The phase when an exception (Ctrl-C) ended :meth:`run`, before the target was closed.
    """

    def __init__(
        self, source, safe, target, *, axis: str, interval_s: float, link=None,
        clock: Callable[[], float] = time.monotonic, sleep: Callable[[float], None] = time.sleep,
        log: Callable[[str], None] = print, champion=None, metrics=None, notify=None, session=None,
    ):  # fmt: skip
        if not (isinstance(interval_s, (int, float)) and math.isfinite(interval_s) and interval_s > 0):
            raise SettingsError(f"deploy.interval_s is {interval_s!r}; expected seconds above 0")
        self.source, self.safe, self.target, self.axis = source, safe, target, axis
        self.interval_s = float(interval_s)
        self.link, self.clock, self.sleep, self.log = link, clock, sleep, log
        self.champion, self.metrics, self.notify = champion, metrics, notify
        self.session = session
        self.cycles = 0
        self.writes = 0
        self.outage_cycles = 0
        self.last_command = None
        self._was_down = False
        self._read_back: str | None = "start"  # read the controller's value before stepping
        self._quiet_since: float | None = None
        self.stopped_in: str | None = None

    @property
    def phase(self) -> str:
        """What the loop is doing: ``starting``, ``referencing``, ``running`` or ``reconnecting``."""
        if self.link is not None and not self.link.connected:
            return "reconnecting"
        if self.last_command is None:
            return "starting"
        return "referencing" if self.last_command.status == "referencing" else "running"

    def _start_from_controller(self) -> None:
        """Read the value the target holds and start (or resume) the command from it."""
        value = self.target.read_current_um()[self.axis]
        shown = "not known" if value is None else f"{signed_um(value)} um"
        if self._read_back == "start":
            self.safe.start_from(value)
            start = f"{signed_um(self.safe.command_um_)} um" + (" (deploy.safe_um)" if value is None else "")
            self.log(f"{self.target.name} axis {self.axis} holds {shown}: the command starts from {start}")
            if self.session is not None:
                self.session.offer(self.safe)
        else:
            before = self.safe.command_um_
            self.safe.resume_from(value)
            if value is not None and value != before:
                self.log(
                    f"{self.target.name} axis {self.axis} holds {shown} after the outage (last command "
                    f"{signed_um(before)} um): the command goes on from it"
                )
        self._read_back = None

    def _swap_champion(self, now: float) -> None:
        artefact = self.champion.poll(now) if self.champion is not None else None
        if artefact is None:
            return
        old = getattr(self, "model_id", "") or self.safe.compensator_.model_id
        self.safe.swap(artefact)
        self.model_id = artefact["model_id"]
        if self.metrics is not None:
            self.metrics.model(self.model_id)
        self.log(
            f"new champion {self.model_id[:12]} replaces {old[:12]}: the command goes from "
            f"{self.safe.command_um_:+.3f} um to its value at the rate limit"
        )

    def _session_news(self) -> None:
        """Log how the session started (kept or anew), once; save it when due."""
        note = getattr(self.safe, "session_note_", None)
        if note:
            self.safe.session_note_ = None
            self.log(note)
        self._save_session()

    def _save_session(self, *, force: bool = False) -> None:
        if self.session is None:
            return
        try:
            self.session.save(self.safe, force=force)
        except OSError as exc:  # a full disk must not stop the compensation: said once per cause
            message = f"the session cannot be saved ({exc}): a restart will capture its reference anew"
            if message != getattr(self, "_save_problem", None):
                self._save_problem = message
                self.log(message)

    def _quiet(self, now: float, why: str) -> None:
        if self._quiet_since is None:
            self._quiet_since = now
        elif now - self._quiet_since >= 60.0:
            self._quiet_since = now
            self.log(f"nothing written for 60 s: {why}")

    def cycle(self, now: float) -> None:
        """One cycle at clock time ``now`` (module docstring), reported to the metrics and the
        watchdog when they are given."""
        started, writes, last = time.perf_counter(), self.writes, self.last_command
        try:
            self._cycle(now)
        finally:
            if self.metrics is not None:
                fresh = self.last_command if self.last_command is not last else None
                self.metrics.cycle(
                    fresh, written=self.writes > writes, step_seconds=time.perf_counter() - started
                )
                self.metrics.connection(self.link is None or bool(self.link.connected))
            if self.notify is not None:
                self.notify.watchdog()

    def _cycle(self, now: float) -> None:
        if self.link is not None and not self.link.connected:
            if not self.link.try_reconnect():
                self.outage_cycles += 1
                self._was_down = True
                self._quiet(now, "the controller is unreachable")
                return
            if self.metrics is not None:
                self.metrics.reconnect()
        try:
            if self._read_back is not None:
                self._start_from_controller()
            self._swap_champion(now)
            samples = self.source.read(now)
            if self._was_down:
                samples, self._was_down = self.source.after_outage(samples), False
            command = None
            for t_s, speed_rpm, temperatures in samples:
                command = self.safe.step(t_s, speed_rpm, temperatures)
                self._session_news()
            if command is None:
                self._quiet(now, "no new sample")
                return
            self.last_command = command
            if not command.send:
                self._quiet(now, f"status {command.status}")
                return
            lo, hi = self.safe.limits.clamp_um
            value = command.command_um
            if not (math.isfinite(value) and lo <= value <= hi):  # the limits never do this
                raise RafiUserError(f"command {value!r} um is outside deploy.clamp_um [{lo}, {hi}]: stopped")
            status = f"{command.status}: {command.fault}" if command.fault else command.status
            self.target.write(command.t_s, {self.axis: value}, status)
        except ConnectionError:
            if self.link is None:
                raise
            self._was_down = True
            self._read_back = self._read_back or "resume"  # someone may change it meanwhile
            self.outage_cycles += 1
            return
        self.writes += 1
        self._quiet_since = None
        flags = "".join(
            f" [{name}]"
            for name, on in (
                ("clamped", command.clamped),
                ("rate limited", command.rate_limited),
                ("held at the envelope's edge", getattr(command, "outside_envelope", False)),
            )
            if on
        )
        finite = math.isfinite(command.model_um)
        model = f"model {signed_um(command.model_um)} um" if finite else "model: no value"
        lower, upper = getattr(command, "lower_um", math.nan), getattr(command, "upper_um", math.nan)
        if math.isfinite(lower) and math.isfinite(upper):  # the model's interval (docs/deploy.md)
            model += f" in [{lower:+.3f}, {upper:+.3f}] {command.interval_cell}"
        stamp = datetime.now().isoformat(timespec="seconds")
        self.log(
            f"{stamp} {command.status:<11} {signed_um(value, width=9)} um "
            f"({model}){flags}{'  ' + command.fault if command.fault else ''}"
        )

    def run(self, max_cycles: int | None = None) -> int:
        """Run cycles every ``interval_s`` until ``max_cycles`` (None: until interrupted).

        The target is opened first if it is not open, and closed when the loop ends, by an
        exception (Ctrl-C included) too. Returns the number of writes.
        """
        if not self.target.is_open:
            self.target.open()
        try:
            next_t = self.clock()
            while max_cycles is None or self.cycles < max_cycles:
                self.cycle(self.clock())
                self.cycles += 1
                if max_cycles is not None and self.cycles >= max_cycles:
                    break
                next_t += self.interval_s
                wait = next_t - self.clock()
                if wait < 0:  # late (a slow server): start again from now, no burst of cycles
                    next_t, wait = self.clock(), 0.0
                self.sleep(wait)
        except BaseException:
            self.stopped_in = self.phase  # before the target (and with it the link) is closed
            raise
        finally:
            self._save_session(force=True)
            self.target.close()
        return self.writes
