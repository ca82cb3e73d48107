"""``rafi record``: record a qualification test into ``raw/<machine>/`` (docs/record.md).

Every sample period (the machine's ``sample_period_s``) one *tick*:

1. With a test plan (:mod:`rafi.deploy.record_plan`), the step in force: at a new step its
   speed is written to the speed-command node (``record.speed_command``), and again after every
   reconnect (a restarted server may have lost it); the step's ``run`` names the recording
   (:class:`rafi.deploy.record_files.RecordingFiles`: a new run closes the file).
2. If the OPC UA link is down, try to reconnect (the link's bounded, doubling back-off); while
   it is down no row is written: the outage is a *gap* in the file (one line when it starts,
   one when it ends, with the number of samples lost).
3. Read the sample (:class:`OpcUaSource`: the speed, temperature and displacement nodes, one
   request, stamped with the tick's time; :class:`DaqFollower`: the complete lines a DAQ
   appended to its CSV file since the last tick) and write it. A bad status or a missing value
   is an empty field.

A tick whose time has passed by a whole period (a slow server, a busy computer) is skipped, not
caught up in a burst: a gap of that many samples; so a row's time is never more than one period
before the moment its values were read. One progress line per minute. The loop ends at the end of the
plan, after ``duration_s``, or by Ctrl-C / SIGTERM (:class:`KeyboardInterrupt`); in every case
the file is closed and renamed, and with a plan the speed command is set to 0. Standard
library and NumPy only; the clock, the wall clock and the sleep are injected for the tests.
"""

from __future__ import annotations

import csv
import math
import re
import signal
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path

from rafi.deploy.record_files import COLUMNS, RecordingFiles, format_time, format_value
from rafi.errors import RafiUserError, RawFormatError, short_path

__all__ = ["DaqFollower", "OpcUaSource", "Recorder", "counted"]

#: Status names that mean a configured node does not exist: refused before recording.
_NO_SUCH_NODE = ("BadNodeIdUnknown", "BadNodeIdInvalid")
_LINE_END = re.compile(rb"\r\n|\r|\n")
#: Seconds between two progress lines.
PROGRESS_S = 60.0


def counted(n: int, word: str) -> str:
    """``1 row``, ``2 rows``, ``0 gaps``."""
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


# --------------------------------------------------------------------------- sources


class OpcUaSource:
    """The sample of a tick from OPC UA nodes (:meth:`rafi.deploy.opcua_client.OpcUaLink.read_nodes`).

    Parameters
    ----------
    link : OpcUaLink
        The session.
    channels : mapping
        Column (``speed_rpm``, a sensor, ``disp_um``) -> ``(node id, scale, offset)``; a column
        without a node is written empty.
    where : mapping
        Column -> the setting that names its node (for the messages).
    columns : sequence of str
        The file's columns (``time``, ``speed_rpm``, the machine's sensors, ``disp_um``).
    """

    def __init__(
        self, link, channels: Mapping[str, tuple[str, float, float]], where: Mapping[str, str],
        columns: Sequence[str] = COLUMNS,
    ):  # fmt: skip
        self.link = link
        self.file_columns = tuple(columns)
        self.columns = [c for c in self.file_columns[1:] if c in channels]
        self.channels = dict(channels)
        self.where = dict(where)
        self.period_s = 1.0

    def check(self) -> None:
        """Read every node once; RafiUserError (64) naming the setting of a node the server lacks."""
        values = self.link.read_nodes([self.channels[c][0] for c in self.columns])
        for column, (_, vtype, status) in zip(self.columns, values):
            if status in _NO_SUCH_NODE:
                raise RafiUserError(
                    f"{self.where.get(column, column)}: the server has no node {self.channels[column][0]} "
                    f"({status}); check the node id (docs/record.md)"
                )
            if vtype not in ("String", "ByteString", "LocalizedText", "QualifiedName", "NodeId"):
                continue
            raise RafiUserError(
                f"{self.where.get(column, column)}: node {self.channels[column][0]} holds a {vtype}, "
                "not a number; check the node id"
            )

    def read(self, wall_s: float) -> list[list[str]]:
        """One row stamped ``wall_s``; ConnectionError when the link is lost."""
        values = self.link.read_nodes([self.channels[c][0] for c in self.columns])
        by_column = {}
        for column, (value, vtype, _status) in zip(self.columns, values):
            _, scale, offset = self.channels[column]
            by_column[column] = format_value(value, vtype, scale, offset)
        return [[format_time(wall_s, self.period_s), *(by_column.get(c, "") for c in self.file_columns[1:])]]


def _sensor_words(sensors: Sequence[str]) -> str:
    """``T1..T16`` for the paper rig's sensors, else the names (the first six, then ``...``)."""
    if tuple(sensors) == COLUMNS[2:-1]:
        return f"{sensors[0]}..{sensors[-1]}"
    return ", ".join(sensors[:6]) + (", ..." if len(sensors) > 6 else "")


def _clean_number(text: str) -> str:
    text = text.strip().strip('"').strip()
    try:
        value = float(text)
    except ValueError:
        return ""
    return text if math.isfinite(value) else ""


class DaqFollower:
    """Follow a DAQ's native-format CSV file as it is written (``--follow``).

    ``tail -f`` style: only complete lines are read; ``#`` lines are skipped; the first other
    line is the header, which must name ``time`` and ``speed_rpm`` (the machine's sensors and
    ``disp_um`` where present; other columns are not recorded). A field that is not a number is
    recorded as missing; a line whose time is unreadable or not later than the one before is
    skipped (counted, logged once per 100). A file that is replaced or shortened is followed
    from its start (logged).

    Parameters
    ----------
    path : path
        The DAQ's file (it may not exist yet).
    from_start : bool
        Record the lines already in the file too (default: only those appended from now on).
    log : callable
        ``log(line)``.
    columns : sequence of str
        The recorded file's columns (``time``, ``speed_rpm``, the machine's sensors, ``disp_um``).
    """

    def __init__(
        self, path, *, from_start: bool = False, log: Callable[[str], None] = print,
        columns: Sequence[str] = COLUMNS,
    ):  # fmt: skip
        self.path = Path(path)
        self.columns = tuple(columns)
        self.from_start = from_start
        self.log = log
        self.skipped = 0
        self._ident = None
        self._pos = 0
        self._skip_to = 0
        self._buffer = b""
        self._index: dict[str, int] | None = None
        self._last_time: datetime | None = None
        self._waiting_logged = False

    def _new_lines(self) -> list[tuple[int, bytes]]:
        try:
            st = self.path.stat()
        except FileNotFoundError:
            if not self._waiting_logged:
                self._waiting_logged = True
                self.log(f"rafi record: waiting for {short_path(self.path)} to appear")
            return []
        ident = (st.st_dev, st.st_ino)
        if ident != self._ident or st.st_size < self._pos:
            if self._ident is not None:
                self.log(
                    f"rafi record: {short_path(self.path)} was replaced or shortened; following it from "
                    "its start"
                )
            first = self._ident is None
            self._ident, self._pos, self._buffer, self._index = ident, 0, b"", None
            self._skip_to = st.st_size if (first and not self.from_start) else 0
        if st.st_size <= self._pos:
            return []
        with open(self.path, "rb") as fh:
            fh.seek(self._pos)
            data = fh.read(st.st_size - self._pos)
        start = self._pos - len(self._buffer)
        self._pos += len(data)
        data = self._buffer + data
        out, at = [], 0
        for match in _LINE_END.finditer(data):
            out.append((start + at, data[at : match.start()]))
            at = match.end()
        self._buffer = data[at:]
        return out

    def _header(self, line: str) -> None:
        names = [f.strip().strip('"') for f in next(csv.reader([line]))]
        missing = [c for c in ("time", "speed_rpm") if c not in names]
        if missing:
            raise RawFormatError(
                self.path,
                f"the header has no column {missing[0]!r}; a followed DAQ file is in the native format "
                f"(time, speed_rpm, {_sensor_words(self.columns[2:-1])}, disp_um; docs/raw-format.md)",
                column=missing[0],
            )
        self._index = {name: i for i, name in enumerate(names) if name in self.columns}

    def _skip(self, why: str) -> None:
        self.skipped += 1
        if self.skipped % 100 == 1:
            self.log(
                f"rafi record: {short_path(self.path)}: a line was skipped ({why}; {self.skipped} so far)"
            )

    def read(self, wall_s: float | None = None) -> list[list[str]]:
        """The rows of the lines completed since the last call (the DAQ's own times)."""
        rows = []
        for offset, raw in self._new_lines():
            line = raw.decode("utf-8", errors="replace").lstrip("\ufeff")
            if not line.strip() or line.lstrip().startswith("#"):
                continue
            if self._index is None:
                self._header(line)
                continue
            if offset < self._skip_to:
                continue  # written before the recording started
            fields = next(csv.reader([line]))
            text = fields[self._index["time"]].strip().strip('"') if self._index["time"] < len(fields) else ""
            try:
                stamp = datetime.fromisoformat(text)
            except ValueError:
                self._skip(f"time {text[:40]!r} is not ISO-8601")
                continue
            stamp = stamp.astimezone(UTC) if stamp.tzinfo else stamp.replace(tzinfo=UTC)
            if self._last_time is not None and stamp <= self._last_time:
                self._skip("its time is not later than the line before")
                continue
            self._last_time = stamp
            row = [text]
            for column in self.columns[1:]:
                i = self._index.get(column)
                row.append(_clean_number(fields[i]) if i is not None and i < len(fields) else "")
            rows.append(row)
        return rows


# --------------------------------------------------------------------------- the loop


@contextmanager
def _signals_deferred():
    """While the files are closed, Ctrl-C / SIGTERM do not interrupt (a second Ctrl-C must not
    leave a file under its temporary name); no-op outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    saved = {s: signal.signal(s, signal.SIG_IGN) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in saved.items():
            signal.signal(s, handler)


class Recorder:
    """The record loop (module docstring).

    Parameters
    ----------
    source : OpcUaSource or DaqFollower
        ``read(wall_s) -> rows``; an OPC UA source raises ConnectionError when the link is lost.
    files : RecordingFiles
        Where the rows go.
    period_s : float
        The sample period.
    name : str
        The recording's name without a plan (``--name``).
    plan : Plan, optional
        The test plan; needs ``command``.
    command : callable, optional
        ``command(speed_rpm)`` writes the speed command (ConnectionError when the link is lost).
    link : OpcUaLink, optional
        ``connected`` and ``try_reconnect()``; None when nothing can be lost.
    duration_s : float, optional
        Stop after this long (without a plan; None: until Ctrl-C).
    clock, wall, sleep, log : callable
        Seconds (``time.monotonic``), seconds since the epoch (``time.time``), the wait
        (``time.sleep``) and ``log(line)``; a test injects them.
    """

    def __init__(
        self, source, files: RecordingFiles, *, period_s: float, name: str = "rec", plan=None,
        command: Callable[[float], None] | None = None, link=None, duration_s: float | None = None,
        clock: Callable[[], float] = time.monotonic, wall: Callable[[], float] = time.time,
        sleep: Callable[[float], None] = time.sleep, log: Callable[[str], None] = print,
        metrics=None, notify=None,
    ):  # fmt: skip
        if plan is not None and command is None:
            raise RafiUserError("a test plan needs record.speed_command (the node its speeds are written to)")
        self.source, self.files, self.period_s = source, files, float(period_s)
        self.name, self.plan, self.command, self.link = name, plan, command, link
        self.duration_s = duration_s
        self.clock, self.wall, self.sleep, self.log = clock, wall, sleep, log
        self.metrics, self.notify = metrics, notify
        self.ticks = 0
        self.gaps = 0
        self.lost_samples = 0
        self.missing = 0
        self.skipped_ticks = 0
        self.commands: list[float] = []
        self._commanded: int | None = None
        self._last_commanded: int | None = None
        self._gap_since: float | None = None
        self._gap_ticks = 0
        self._next_progress = 0.0
        if hasattr(source, "period_s"):
            source.period_s = self.period_s

    # -- one tick ------------------------------------------------------------------------
    def _step(self, elapsed: float):
        if self.plan is None:
            return None, self.name
        index = self.plan.step_at(elapsed)
        return index, self.plan.steps[index].run

    def _gap(self, wall_s: float, why: str, samples: int = 1) -> None:
        if self._gap_since is None:
            self._gap_since, self._gap_ticks = wall_s, 0
            self.gaps += 1
            if self.metrics is not None:
                self.metrics.gap()
            self.log(
                f"rafi record: gap from {format_time(wall_s, self.period_s)}: {why}; no rows until it is over"
            )
        self._gap_ticks += samples
        self.lost_samples += samples

    def _gap_over(self, wall_s: float) -> None:
        if self._gap_since is not None:
            self.log(
                f"rafi record: recording again from {format_time(wall_s, self.period_s)}: a gap of "
                f"{self._gap_ticks} samples ({wall_s - self._gap_since:.0f} s) in the file"
            )
            self._gap_since = None

    def tick(self, k: int, wall_s: float) -> None:
        """Tick ``k`` (``k`` periods after the start), stamped ``wall_s`` (module docstring), told
        to the metrics and systemd's watchdog when they are given."""
        rows, closed, reconnects = self.files.rows, len(self.files.closed), self._reconnects()
        try:
            self._tick(k, wall_s)
        finally:
            self._observe(rows, closed, reconnects)

    def _reconnects(self) -> int:
        return int(getattr(self.link, "reconnects", 0) or 0)

    def _observe(self, rows_before: int, closed_before: int, reconnects_before: int) -> None:
        if self.metrics is not None:
            for _ in range(self.files.rows - rows_before):
                self.metrics.row()
            for _ in range(len(self.files.closed) - closed_before):
                self.metrics.file_closed()
            for _ in range(self._reconnects() - reconnects_before):
                self.metrics.reconnect()
            current = self.files.current
            self.metrics.file(None if current is None else current.path)
            self.metrics.connection(self.link is None or bool(self.link.connected))
        if self.notify is not None:
            self.notify.watchdog()

    def _tick(self, k: int, wall_s: float) -> None:
        index, run = self._step(k * self.period_s)
        self.files.switch(run)
        if self.link is not None and not self.link.connected:
            if not self.link.try_reconnect():
                self._gap(wall_s, "the OPC UA connection is lost; reconnecting")
                return
        try:
            if index is not None and index != self._commanded:
                speed = self.plan.steps[index].speed_rpm
                self.command(speed)
                self.commands.append(speed)
                again = " again, after the reconnect" if index == self._last_commanded else ""
                self._commanded = self._last_commanded = index
                self.log(
                    f"rafi record: step {index + 1}/{len(self.plan.steps)}: speed command {speed:g} r/min"
                    f"{again} for {self.plan.steps[index].duration_s:g} s"
                    + ("" if run else " (not recorded)")
                )
            rows = self.source.read(wall_s)
        except ConnectionError as exc:
            self._commanded = None  # written again once the link is back
            self._gap(wall_s, str(exc))
            return
        self._gap_over(wall_s)
        if run is not None:
            missing = sum(1 for row in rows for field in row[1:] if field == "")
            self.missing += missing
            if self.metrics is not None and missing:
                self.metrics.missing(missing)
        self.files.write(rows, wall_s)

    # -- the run -------------------------------------------------------------------------
    def _progress(self, now: float, wall_s: float) -> None:
        if now < self._next_progress:
            return
        self._next_progress = now + PROGRESS_S
        current = self.files.current
        where = f"{current.stem}.csv (being written)" if current is not None else "no file open"
        step = ""
        if self.plan is not None and self._commanded is not None:
            step = f", step {self._commanded + 1}/{len(self.plan.steps)}"
        self.log(
            f"rafi record: {format_time(wall_s, 1.0 if self.period_s >= 1 else self.period_s)} {where}: "
            f"{counted(self.files.rows, 'row')}, {counted(self.gaps, 'gap')}, "
            f"{counted(self.missing, 'missing value')}{step}"
        )

    def _end_s(self) -> float | None:
        if self.plan is not None:
            return self.plan.total_s
        return self.duration_s

    def run(self) -> list[Path]:
        """Record until the plan ends, ``duration_s`` passes or Ctrl-C / SIGTERM; the files closed.

        The first tick waits for the next whole second when the period is whole seconds, so
        that the times read ``08:00:05``. The files are closed (and, with a plan, the speed
        command set to 0) however the loop ends; a KeyboardInterrupt is raised again after.
        """
        w = self.wall()
        if self.period_s.is_integer() and not float(w).is_integer():
            self.sleep(math.ceil(w) - w)
            w = math.ceil(w)
        t0, w0 = self.clock(), w
        self._next_progress = t0
        end_s = self._end_s()
        k = 0
        try:
            while end_s is None or k * self.period_s < end_s:
                late = self.clock() - (t0 + k * self.period_s)
                if late >= self.period_s:  # a tick whose time has passed: skip to now, no burst
                    skip = int(late // self.period_s)
                    why = f"{skip} samples late (a slow server or a busy computer)"
                    self._gap(w0 + k * self.period_s, why, skip)
                    self.skipped_ticks += skip
                    k += skip
                    continue
                self.tick(k, w0 + k * self.period_s)
                self.ticks += 1
                self._progress(self.clock(), w0 + k * self.period_s)
                k += 1
                wait = t0 + k * self.period_s - self.clock()
                if wait > 0 and (end_s is None or k * self.period_s < end_s):
                    self.sleep(wait)
        finally:
            with _signals_deferred():
                self.finish()
        return list(self.files.closed)

    def finish(self) -> None:
        """Close the file; with a plan, command 0 r/min (the spindle stands still). Called once by
        :meth:`run` however it ends."""
        try:
            if self.plan is not None and self.command is not None:
                if self.link is None or self.link.connected:
                    try:
                        self.command(0.0)
                        self.commands.append(0.0)
                        self.log("rafi record: speed command 0 r/min written (the plan ended or was stopped)")
                    except (ConnectionError, RafiUserError) as exc:
                        self.log(f"rafi record: the speed command 0 r/min could not be written: {exc}")
                else:
                    self.log("rafi record: the OPC UA connection is down: speed command 0 r/min not written")
        finally:
            self.files.close()
