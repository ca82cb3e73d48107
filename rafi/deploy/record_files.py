"""The raw files of ``rafi record``: native-format logs written so the pipeline never reads half a one.

* :func:`format_value` / :func:`format_time` write a value as the node gave it (an ``Int16`` in
  0.1 degC as ``21.3``, a ``Float`` to single precision, a ``Double`` in full) and a sample time
  as ISO-8601 UTC (``2026-03-01T08:00:05Z``); a missing value is an empty field.
* :class:`RecordingFile` is one file: written under a hidden temporary name
  (``.<name>.csv.part``, which discovery never reads: ``rafi.readers.input_spec.scan_logs``
  skips names starting with a dot, and it does not match ``*.csv``), one ``write`` per row, then
  on :meth:`RecordingFile.close` synced to disk, made read-only and given its final name
  without ever replacing an existing file (a hard link, which fails if the name exists).
* :class:`RecordingFiles` holds the file being written: a new file when the recording changes
  (a plan's ``run``) or the file reaches ``record.max_file_s`` or :data:`ROLL_BYTES`.

Standard library and NumPy only (``rafi/deploy`` never imports pandas at run time).
"""

from __future__ import annotations

import errno
import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from datetime import UTC, datetime
from decimal import Decimal
from pathlib import Path

import numpy as np

from rafi import SENSORS
from rafi.errors import RafiUserError, short_path

__all__ = [
    "COLUMNS",
    "PART_SUFFIX",
    "ROLL_BYTES",
    "RecordingFile",
    "RecordingFiles",
    "format_time",
    "format_value",
    "leftover_parts",
]

#: The columns of a recorded file of a machine with the paper rig's sensors, in order
#: (docs/raw-format.md); a machine with its own sensors records ``time, speed_rpm, <its
#: sensors>, disp_um`` (``columns`` of :class:`RecordingFiles`).
COLUMNS = ("time", "speed_rpm", *SENSORS, "disp_um")
#: The temporary name of a file being written is ``.<final name>`` + this.
PART_SUFFIX = ".part"
#: A file is continued in a new one beyond this size (the reader refuses files over 256 MiB).
ROLL_BYTES = 128 * 1024 * 1024
#: Variant types holding whole numbers.
_INTEGER_TYPES = {"Boolean", "SByte", "Byte", "Int16", "UInt16", "Int32", "UInt32", "Int64", "UInt64"}


def _decimals(x: float) -> int:
    """Decimal places of the shortest form of ``x`` (0.1 -> 1, 1e-05 -> 5, 2.0 -> 0)."""
    exponent = Decimal(repr(float(x))).normalize().as_tuple().exponent
    return max(0, -exponent) if isinstance(exponent, int) else 0


def format_value(raw: float, variant_type: str = "Double", scale: float = 1.0, offset: float = 0.0) -> str:
    """A node's value as a CSV field, to the node's resolution: ``raw * scale + offset``.

    Parameters
    ----------
    raw : float
        The value read (NaN: missing).
    variant_type : str
        The node's variant type (``Int16``, ``Float``, ``Double``, ...).
    scale, offset : float
        The input's scaling.

    Returns
    -------
    str
        ``''`` for a missing or non-finite value; an integer type with as many decimals as
        ``scale`` and ``offset`` have (``Int16`` 213 x 0.1 -> ``21.3``); a ``Float`` as the
        shortest text that reads back as the same single-precision number; anything else as the
        shortest text that reads back as the same double. Never an exponent.
    """
    if raw is None or not math.isfinite(raw):
        return ""
    value = float(raw) * scale + offset
    if not math.isfinite(value):
        return ""
    if variant_type in _INTEGER_TYPES:
        text = f"{value:.{max(_decimals(scale), _decimals(offset))}f}"
    elif variant_type == "Float":
        text = np.format_float_positional(np.float32(value), trim="-")
    else:
        text = np.format_float_positional(value, trim="-")
    return "0" if text in ("-0", "-0.0") or text.strip("-0.") == "" else text


def format_time(epoch_s: float, period_s: float = 1.0) -> str:
    """``epoch_s`` as ISO-8601 UTC: whole seconds (``2026-03-01T08:00:05Z``), or milliseconds
    when the period or the time has a fraction of a second."""
    stamp = datetime.fromtimestamp(round(epoch_s, 3), UTC)
    if float(period_s).is_integer() and float(round(epoch_s, 3)).is_integer():
        return stamp.strftime("%Y-%m-%dT%H:%M:%SZ")
    return stamp.strftime("%Y-%m-%dT%H:%M:%S.") + f"{stamp.microsecond // 1000:03d}Z"


def file_stamp(epoch_s: float) -> str:
    """The start of a recording in its file name: ``20260301T080005Z`` (no ``:``, sortable)."""
    return datetime.fromtimestamp(int(epoch_s), UTC).strftime("%Y%m%dT%H%M%SZ")


def leftover_parts(folder) -> list[Path]:
    """Temporary files of recordings that were never closed (a crash, a power cut)."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.glob(f".*{PART_SUFFIX}") if p.is_file())


def _metadata_lines(metadata: Mapping[str, object]) -> str:
    out = []
    for key, value in metadata.items():
        for part in str(value).replace("\r", "").split("\n") or [""]:
            out.append(f"# {key}: {part}\n")
    return "".join(out)


class RecordingFile:
    """One raw file being recorded (module docstring).

    Parameters
    ----------
    folder : path
        ``raw/<machine>/`` (created if missing).
    stem : str
        The final name without ``.csv``; ``_2``, ``_3`` ... is added if a file of that name exists.
    metadata : mapping
        The ``# key: value`` lines (``machine``, ``sample_period_s``, ``notes``, ...); ``run_id``
        is set to the stem.
    columns : sequence of str
        The header (``time``, ``speed_rpm``, the machine's sensors, ``disp_um``).
    """

    def __init__(self, folder, stem: str, metadata: Mapping[str, object], columns: Sequence[str] = COLUMNS):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.rows = 0
        self.size = 0
        self.final: Path | None = None
        self._partial = False
        for n in range(1, 1000):
            self.stem = stem if n == 1 else f"{stem}_{n}"
            self.path = self.folder / f".{self.stem}.csv{PART_SUFFIX}"
            if (self.folder / f"{self.stem}.csv").exists():
                continue
            try:
                self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            except FileExistsError:
                continue
            break
        else:
            raise RafiUserError(f"{short_path(self.folder)}: 999 files named {stem}_N.csv exist already")
        self.columns = tuple(columns)
        self._write(_metadata_lines({**metadata, "run_id": self.stem}) + ",".join(self.columns) + "\n")
        self.size, self.header_size = self._written, self._written

    def _write(self, text: str) -> None:
        data = text.encode("utf-8")
        done = 0
        self._written = self.size
        try:
            while done < len(data):
                done += os.write(self._fd, data[done:])
        except BaseException:
            self._partial = True  # cut back to the last whole row on close
            raise
        self._written = self.size + len(data)

    def write_row(self, fields: Sequence[str]) -> None:
        """Append one row (``len(columns)`` fields, ``''`` for a missing value) in one write."""
        self._write(",".join(fields) + "\n")
        self.size = self._written
        self.rows += 1

    @property
    def closed(self) -> bool:
        return self._fd is None

    def close(self) -> Path | None:
        """Sync, make read-only and give the file its final name; the final path (None: no row was
        recorded, and the temporary file is removed). Closing twice does nothing."""
        if self._fd is None:
            return self.final
        fd, self._fd = self._fd, None
        try:
            if self._partial:
                os.ftruncate(fd, self.size)
            os.fsync(fd)
            if self.rows:
                os.fchmod(fd, 0o444)  # a raw file is never changed once closed
        finally:
            os.close(fd)
        if not self.rows:
            self.path.unlink(missing_ok=True)
            return None
        self.final = self._publish()
        return self.final

    def _publish(self) -> Path:
        for n in range(1, 1000):
            final = self.folder / (f"{self.stem}.csv" if n == 1 else f"{self.stem}_{n}.csv")
            try:
                os.link(self.path, final)  # fails if the name exists: never replaces a file
            except FileExistsError:
                continue
            except OSError as exc:
                if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EXDEV, errno.EMLINK):
                    raise
                if final.exists():  # a file system without hard links: check, then rename
                    continue
                os.rename(self.path, final)
            else:
                self.path.unlink()
            _sync_folder(self.folder)
            return final
        raise RafiUserError(f"{short_path(self.folder)}: 999 files named {self.stem}_N.csv exist already")


def _sync_folder(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


class RecordingFiles:
    """The files of one ``rafi record`` session: the one being written and those closed.

    Parameters
    ----------
    folder : path
        ``raw/<machine>/``.
    metadata : mapping
        The header of every file.
    max_file_s : float
        ``record.max_file_s``: a file that has recorded this long is closed and continued.
    log : callable
        One line per file closed.
    clock : callable
        Seconds (the recorder's clock).
    columns : sequence of str
        The header of every file (default :data:`COLUMNS`).
    """

    def __init__(
        self, folder, metadata: Mapping[str, object], *, max_file_s: float = 86400.0,
        log: Callable[[str], None] = print, clock: Callable[[], float] = time.monotonic,
        columns: Sequence[str] = COLUMNS,
    ):  # fmt: skip
        self.folder = Path(folder)
        self.metadata = dict(metadata)
        self.columns = tuple(columns)
        self.max_file_s = float(max_file_s)
        self.log, self.clock = log, clock
        self.current: RecordingFile | None = None
        self.run: str | None = None
        self.closed: list[Path] = []
        self.rows = 0
        self._opened_at = 0.0

    def switch(self, run: str | None) -> None:
        """The recording now in force (None: none); a change closes the current file."""
        if run != self.run:
            self.close()
            self.run = run

    def write(self, rows: Sequence[Sequence[str]], wall_s: float) -> None:
        """Write ``rows`` to the current recording's file (opened at the first row, named
        ``<run>_<start>.csv`` with ``wall_s`` the start); a file too long or too large is
        closed first and the rows go to a new one. Nothing while no recording is in force."""
        if self.run is None:
            return
        for fields in rows:
            if self.current is not None and (
                self.clock() - self._opened_at >= self.max_file_s or self.current.size >= ROLL_BYTES
            ):
                self.close()
            if self.current is None:
                self.current = RecordingFile(
                    self.folder, f"{self.run}_{file_stamp(wall_s)}", self.metadata, self.columns
                )
                self._opened_at = self.clock()
            self.current.write_row(fields)
            self.rows += 1

    def close(self) -> Path | None:
        """Close the current file (final name, one line); the path or None."""
        current, self.current = self.current, None
        if current is None:
            return None
        final = current.close()
        if final is None:
            self.log(f"rafi record: nothing recorded in {current.stem}: no file written")
        else:
            self.closed.append(final)
            self.log(f"rafi record: closed {short_path(final)} ({current.rows} rows)")
        return final
