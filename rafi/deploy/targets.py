"""Controller targets: where the compensation goes, behind one writer interface.

A *target* takes one sample at a time - the sample time, the compensation per axis in
micrometres and the compensator's status - and delivers it to a controller or a file::

    with SinumerikTarget(axes, sink=DrySink()) as target:
        target.write(12.5, {"Z": -12.3}, "ok")

Every target is a :class:`Target`: ``open()``, ``write(time_s, values_um, status)``,
``close()``, and a context manager that closes on leaving the block, an exception included.
A sample is checked whole before any part of it is written (all axes present, finite, inside
the target's limits); a refused sample raises :class:`rafi.errors.TargetError` and writes
nothing. The targets here:

* :class:`CsvFileTarget`, :class:`JsonLinesTarget` - the generic target for any controller
  that can read a file (or a PLC gateway that follows one): one line per sample, appended with
  one ``write`` per line, so a crash leaves complete lines only; fsync on close.
* :class:`rafi.deploy.target_sinumerik.SinumerikTarget` - SINUMERIK 840D sl setting data
  SD 43900 (and optionally SD 43910/43920) through a pluggable sink (the OPC UA client of a
  later step, or :class:`~rafi.deploy.target_sinumerik.DrySink`). Re-exported here.

What each target writes and every setting: ``docs/deploy-targets.md``. NumPy-free: the
standard library only.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
from pathlib import Path

from rafi.deploy.target_base import Target, check_axes
from rafi.deploy.target_sinumerik import DrySink, SinumerikAxis, SinumerikTarget, WrittenValue
from rafi.errors import TargetError

__all__ = [
    "Target",
    "check_axes",
    "CsvFileTarget",
    "JsonLinesTarget",
    "SinumerikAxis",
    "SinumerikTarget",
    "DrySink",
    "WrittenValue",
]


class _LineFileTarget(Target):
    """A file of one line per sample, appended; the base of the CSV and JSON-lines targets.

    Each line is written with a single ``os.write`` on an ``O_APPEND`` descriptor, so a crash
    (or a kill) leaves complete lines only. A torn last line left by a power loss (a file not
    ending in a newline) is cut off when the file is opened again; :attr:`torn_bytes_dropped`
    says how many bytes were dropped. ``fsync`` on close, and after every line when
    ``fsync_each_line`` is true (slower; survives a power loss with at most one line lost).
    """

    def __init__(self, path, axes, *, fsync_each_line: bool = False):
        super().__init__(axes)
        self.path = Path(path)
        self.fsync_each_line = bool(fsync_each_line)
        self.torn_bytes_dropped = 0
        self._fd: int | None = None

    def header(self) -> str | None:
        """The first line of a new file (without newline), or None for no header."""
        return None

    def format_line(self, time_s: float, values_um: dict[str, float], status: str) -> str:
        raise NotImplementedError

    def _open(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            size = os.fstat(fd).st_size
            if size:
                self._drop_torn_tail(fd, size)
            header = self.header()
            if header is not None:
                if os.fstat(fd).st_size == 0:
                    os.write(fd, (header + "\n").encode("utf-8"))
                else:
                    found = self._first_line(fd)
                    if found != header:
                        raise TargetError(
                            f"{self.path} exists with another header {found!r}; expected {header!r} "
                            "(other axes?): write to a new file",
                            target=self.name,
                        )
        except BaseException:
            os.close(fd)
            raise
        self._fd = fd

    def _drop_torn_tail(self, fd: int, size: int) -> None:
        with open(self.path, "rb") as fh:
            fh.seek(max(size - 65536, 0))
            tail = fh.read()
        if tail.endswith(b"\n"):
            return
        cut = tail.rfind(b"\n")
        if cut < 0 and size > len(tail):
            raise TargetError(
                f"{self.path} ends in a line of over 64 KiB: not a target file", target=self.name
            )
        keep = size - len(tail) + cut + 1
        os.ftruncate(fd, keep)
        self.torn_bytes_dropped = size - keep

    def _first_line(self, fd: int) -> str:
        with open(self.path, "rb") as fh:
            return fh.readline(65536).decode("utf-8", "replace").rstrip("\r\n")

    def parse_value(self, line: str, header: str, axis: str) -> float | None:
        """The value of ``axis`` in a data ``line`` (None if it has none)."""
        raise NotImplementedError

    def read_current_um(self) -> dict[str, float | None]:
        """Per axis, the value of the file's last complete line: what a controller following
        the file applies now. None for a new or empty file, or a line without the axis (the
        live loop then starts from ``deploy.safe_um``)."""
        out: dict[str, float | None] = {axis: None for axis in self.axes}
        try:
            with open(self.path, "rb") as fh:
                header = fh.readline(65536).decode("utf-8", "replace").rstrip("\r\n")
                size = os.fstat(fh.fileno()).st_size
                fh.seek(max(size - 65536, 0))
                tail = fh.read().decode("utf-8", "replace")
        except OSError:
            return out
        lines = [line for line in tail.split("\n")[:-1] if line.strip()]  # complete lines only
        if not lines or (self.header() is not None and lines[-1] == header):
            return out
        for axis in self.axes:
            try:
                value = self.parse_value(lines[-1], header, axis)
            except (ValueError, KeyError, IndexError, TypeError):
                value = None
            out[axis] = value if value is not None and math.isfinite(value) else None
        return out

    def _write(self, time_s, values_um, status) -> None:
        line = self.format_line(time_s, values_um, status)
        data = (line + "\n").encode("utf-8")
        if os.write(self._fd, data) != len(data):  # pragma: no cover - a full disk
            raise OSError(f"short write to {self.path}")
        if self.fsync_each_line:
            os.fsync(self._fd)

    def _close(self) -> None:
        fd, self._fd = self._fd, None
        if fd is not None:
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            with contextlib.suppress(OSError):
                dfd = os.open(self.path.parent, os.O_RDONLY)
                try:
                    os.fsync(dfd)
                finally:
                    os.close(dfd)


class CsvFileTarget(_LineFileTarget):
    """The generic target as CSV: a header ``time_s,<axis>_um,...,status``, one row per sample.

    Numbers are written with Python's shortest round-trip repr (``float(text)`` gives the
    value back exactly); the status is quoted by the CSV rules when it needs to be.
    Appending to an existing file requires the same header (the same axes in the same order).
    """

    name = "csv"

    def header(self) -> str:
        return ",".join(["time_s", *(f"{a}_um" for a in self.axes), "status"])

    def parse_value(self, line: str, header: str, axis: str) -> float | None:
        names = next(csv.reader([header]))
        return float(next(csv.reader([line]))[names.index(f"{axis}_um")])

    def format_line(self, time_s, values_um, status) -> str:
        buf = io.StringIO()
        csv.writer(buf, lineterminator="").writerow(
            [repr(time_s), *(repr(values_um[a]) for a in self.axes), status]
        )
        return buf.getvalue()


class JsonLinesTarget(_LineFileTarget):
    """The generic target as JSON lines: ``{"time_s": t, "values_um": {axis: v}, "status": s}``.

    Keys in that order, axes in the configured order; no header (each line stands alone).
    """

    name = "jsonl"

    def parse_value(self, line: str, header: str, axis: str) -> float | None:
        return float(json.loads(line)["values_um"][axis])

    def format_line(self, time_s, values_um, status) -> str:
        record = {"time_s": time_s, "values_um": {a: values_um[a] for a in self.axes}, "status": status}
        return json.dumps(record, separators=(",", ":"), allow_nan=False, ensure_ascii=False)
