"""Shared pieces of the plausibility checks: how a finding is worded, warnings, robust statistics.

A check that is *certain* raises :class:`rafi.errors.RawFormatError` through
:meth:`Where.error`; one that is only *suspicious* returns a :class:`CheckWarning`. Both messages
start with the check id (``"temperature_unit: ..."``, docs/raw-format.md, "Checks"), name the
column (with the file's own header for mapped files), give the evidence in numbers and say the
likely cause.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from rafi.errors import RawFormatError

#: Seconds at the start of a log whose median is a sensor's *start level*.
START_WINDOW_S = 600.0
#: Fewest samples a start level is taken from (a log sampled slowly gets a longer window).
START_MIN_SAMPLES = 5


@dataclass(frozen=True)
class CheckWarning:
    """A suspicious finding: the file is used, the warning is recorded and shown.

    Attributes
    ----------
    check : str
        Stable check id (``speed_range``, ``constant_channel``, ...).
    column : str
        Canonical column concerned (``""`` for the whole file).
    message : str
        One line: what was found (numbers), what was expected, the likely cause.
    first_line, last_line : int or None
        Source lines (rows for a spreadsheet) the finding covers, when it has a span.
    """

    check: str
    column: str
    message: str
    first_line: int | None = None
    last_line: int | None = None

    @property
    def detail(self) -> str:
        """``"<check id>: <message>"`` (the ``detail`` of the audit row)."""
        return f"{self.check}: {self.message}"


def whole_log_warning(check: str, column: str, message: str, sig) -> CheckWarning:
    """A :class:`CheckWarning` about the whole log: it spans the first to the last line of ``sig``
    (a :class:`Signals`)."""
    return CheckWarning(check, column, message, int(sig.lines[0]), int(sig.lines[-1]))


class Where:
    """Words a finding for one frame: sheet/row for spreadsheets, file headers for mapped files."""

    def __init__(self, frame: pd.DataFrame, path):
        meta = frame.attrs.get("metadata") or {}
        self.path = path if path is not None else frame.attrs.get("source", "<log>")
        self.sheet = meta.get("sheet") if isinstance(meta, dict) else None
        cols = meta.get("columns") if isinstance(meta, dict) else None
        self.columns = cols if isinstance(cols, dict) else {}

    def label(self, canon: str) -> str:
        """``canon``, with the file's own header when a mapping renamed it."""
        theirs = self.columns.get(canon)
        return f"{canon} (header {theirs!r})" if theirs and theirs != canon else canon

    def prefix(self, canon: str) -> str:
        """``"<label>: "`` for a renamed column, else ``""``."""
        label = self.label(canon)
        return f"{label}: " if label != canon else ""

    def error(
        self, message: str, *, line=None, column: str | None = None, check: str | None = None
    ) -> RawFormatError:
        """The :class:`RawFormatError` of a certain finding at ``line`` / ``column``."""
        return RawFormatError(
            self.path,
            message,
            line=None if line is None else int(line),
            column=column,
            sheet=self.sheet,
            check=check,
        )

    def check_error(self, check: str, message: str, *, line=None, column: str | None = None):
        """An error of check ``check``: the message starts with the check id, which is also the
        error's ``check`` attribute (the clean step appends ``[<check id>]`` to the quarantine
        reason)."""
        return self.error(f"{check}: {message}", line=line, column=column, check=check)


@dataclass
class Signals:
    """The numeric channels of a frame as float arrays, open-circuit readings as NaN.

    Attributes
    ----------
    t : numpy.ndarray
        Seconds since the first row (file order).
    values : dict of str to numpy.ndarray
        ``speed_rpm``, the sensors, ``disp_um``.
    lines : numpy.ndarray
        Source line (row) of every sample.
    period_s : float
        The sample period used for durations.
    """

    t: np.ndarray
    values: dict[str, np.ndarray]
    lines: np.ndarray
    period_s: float

    @property
    def sensors(self) -> tuple[str, ...]:
        """The temperature sensors: every channel but the speed and the displacement, in order."""
        return tuple(name for name in self.values if name not in ("speed_rpm", "disp_um"))

    @property
    def n(self) -> int:
        """Number of rows."""
        return int(self.lines.size)

    def start_mask(self) -> np.ndarray:
        """Rows of the first :data:`START_WINDOW_S` seconds (at least :data:`START_MIN_SAMPLES`)."""
        return self._edge_mask(self.t - np.nanmin(self.t), slice(0, START_MIN_SAMPLES))

    def end_mask(self) -> np.ndarray:
        """Rows of the last :data:`START_WINDOW_S` seconds (at least :data:`START_MIN_SAMPLES`)."""
        return self._edge_mask(np.nanmax(self.t) - self.t, slice(max(0, self.n - START_MIN_SAMPLES), None))

    def _edge_mask(self, seconds_from_edge: np.ndarray, fallback: slice) -> np.ndarray:
        mask = seconds_from_edge <= START_WINDOW_S
        if mask.sum() < START_MIN_SAMPLES:
            mask = np.zeros(self.n, bool)
            mask[fallback] = True
        return mask


def present(values: np.ndarray) -> np.ndarray:
    """The non-NaN values."""
    return values[~np.isnan(values)]


def robust_range(values: np.ndarray, lo: float = 2.0, hi: float = 98.0) -> float:
    """Spread between two percentiles of the non-NaN values (0 without values): a few glitch
    samples do not widen it, unlike max - min."""
    v = present(values)
    if v.size == 0:
        return 0.0
    q = np.percentile(v, [lo, hi])
    return float(q[1] - q[0])


def start_level(values: np.ndarray, mask: np.ndarray) -> float:
    """Median of the non-NaN values in ``mask`` (the start of the log), NaN without any."""
    v = present(values[mask])
    if v.size == 0:
        v = present(values)[:START_MIN_SAMPLES]
    return float(np.median(v)) if v.size else float("nan")


def is_flat(values: np.ndarray, tolerance: float = 0.01) -> bool:
    """True if 98 % of the non-NaN values lie within ``tolerance`` of each other (1st-99th
    percentile): a channel that does not move."""
    v = present(values)
    return v.size > 0 and robust_range(v, 1.0, 99.0) <= tolerance


def fmt(x: float) -> str:
    """A number for a message: 4 significant digits, whole numbers from 1000 on (no exponent)."""
    if np.isfinite(x) and 1000 <= abs(x) < 1e12:
        return f"{x:.0f}"
    return f"{x:.4g}"
