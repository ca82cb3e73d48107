"""Sample-by-sample building blocks of the streaming compensator (NumPy only).

* :class:`LowpassBank` - the family's causal first-order filter
  (:func:`rafi.family.whole_log.lowpass_log`) one sample at a time, for several columns and
  time constants at once: ``y = exp(-dt/tau) y + (1 - exp(-dt/tau)) x`` (``tau <= 0`` passes
  the input through); a NaN input holds
  the state (and the time it was NaN is not decayed, as in the batch code: ``dt`` is the
  distance to the previous *sample*); after :meth:`LowpassBank.restart` each column starts
  settled on its first finite value (NaN until then).
* :class:`ReferenceWindow` - collects the samples of a reference window and gives their
  median, with the window rules of :func:`rafi.method.runs.find_runs` (temperatures and
  filter values: ``t < t0 + window_s``, at least one sample, NaN ignored) and of
  :func:`rafi.family.features.reference_speed` (speed: ``t - t0 <= window_s``, plain median).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence

import numpy as np

#: Slack of the reference window's end, as in :func:`rafi.method.runs.find_runs`.
WINDOW_EPS_S = 1e-9


class LowpassBank:
    """First-order low-pass filters of ``n_columns`` inputs for every ``tau`` (all ``> 0``).

    Parameters
    ----------
    taus_s : ndarray, shape (n_taus, 1)
        Time constants (s); ``tau <= 0`` passes the input through.
    n_columns : int
        Number of inputs filtered with every time constant.

    Notes
    -----
    The output of :meth:`update` is tau-major (``len(taus_s) * n_columns`` values), the column
    order of :func:`rafi.family.whole_log.lowpass_log`.
    """

    def __init__(self, *, taus_s: np.ndarray, n_columns: int, state: np.ndarray, seen: np.ndarray):
        self.taus_s = taus_s
        self.n_columns = n_columns
        self.state = state
        self.seen = seen
        # constants of the filter constants, and the decay / gain of the last step length (a
        # log samples at a fixed period: computed once, not per sample; the same operations)
        self._through = self.taus_s[:, 0] <= 0
        self._step: tuple[tuple, np.ndarray, np.ndarray] | None = None

    @classmethod
    def create(cls, taus_s: Sequence[float], n_columns: int) -> LowpassBank:
        """A bank with no sample seen yet (every column restarts on its first finite value)."""
        taus = np.asarray([float(t) for t in taus_s], dtype=float).reshape(-1, 1)
        return cls(
            taus_s=taus,
            n_columns=int(n_columns),
            state=np.zeros((len(taus), int(n_columns))),
            seen=np.zeros(int(n_columns), dtype=bool),
        )

    def restart(self) -> None:
        """Forget the state: each column starts settled on its next finite value."""
        self.seen[:] = False

    def settle(self, values: np.ndarray) -> None:
        """Set every filter settled on ``values`` (the machine at rest at those values)."""
        x = np.asarray(values, dtype=float)
        self.state[:] = x[None, :]
        self.seen[:] = np.isfinite(x)

    def update(self, values: np.ndarray, dt_s: float) -> np.ndarray:
        """Advance by ``dt_s`` (clipped at 0) with the inputs ``values``; the filtered values."""
        x = np.asarray(values, dtype=float)
        finite = np.isfinite(x)
        decay, gain = self._coefficients(float(dt_s))
        new = decay * self.state + gain * x[None, :]
        self.state = np.where(finite[None, :], new, self.state)
        first = finite & ~self.seen
        if first.any():
            self.state[:, first] = x[first][None, :]
        self.seen |= finite
        out = np.where(self.seen[None, :], self.state, np.nan)
        through = self._through
        if through.any():  # tau = 0: the input itself, NaN included (lowpass_log's pass-through)
            out[through] = x[None, :]
        return out.ravel()

    def _coefficients(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """``(exp(-dt/tau), -expm1(-dt/tau))`` per filter (n_taus, 1) for a step of ``dt_s``,
        kept for the next step of the same length."""
        key = (dt_s, math.copysign(1.0, dt_s))  # -0.0 is its own step (the sign of a zero gain)
        if self._step is not None and self._step[0] == key:
            return self._step[1], self._step[2]
        with np.errstate(divide="ignore", invalid="ignore"):  # tau = 0: overwritten in update
            inc = max(dt_s, 0.0) / np.where(self.taus_s > 0, self.taus_s, 0.0)  # (n_taus, 1)
        decay, gain = np.exp(-inc), -np.expm1(-inc)
        self._step = (key, decay, gain)
        return decay, gain

    @property
    def nbytes(self) -> int:
        """Bytes held by the filter state."""
        return int(self.state.nbytes + self.seen.nbytes + self.taus_s.nbytes)


class ReferenceWindow:
    """The samples of one reference window and their medians.

    Parameters
    ----------
    window_s : float
        Length of the window (s), ``reference.window_s`` of the artefact.
    t0_s : float or None
        Time of the window's first sample (None: the next sample starts it).
    values : list of ndarray
        The temperature-like rows (medians NaN-ignoring, ``t < t0 + window_s``).
    speeds : list of float
        The speeds with ``t - t0 <= window_s`` (median over them, NaN propagates).
    """

    def __init__(self, *, window_s: float, t0_s: float | None, values: list, speeds: list):
        self.window_s = window_s
        self.t0_s = t0_s
        self.values = values
        self.speeds = speeds

    @classmethod
    def create(cls, window_s: float) -> ReferenceWindow:
        """An empty window that starts with the next sample."""
        return cls(window_s=float(window_s), t0_s=None, values=[], speeds=[])

    def closes_at(self, t_s: float) -> bool:
        """True if a sample at ``t_s`` lies after the window (the window is complete).

        The first sample always belongs to the window (at least one sample, as in the batch code).
        """
        return self.t0_s is not None and t_s >= self.t0_s + self.window_s - WINDOW_EPS_S

    def add(self, t_s: float, values: np.ndarray) -> None:
        """Add a sample of the window (its temperature-like ``values``)."""
        if self.t0_s is None:
            self.t0_s = float(t_s)
        self.values.append(np.array(values, dtype=float))

    def add_speed(self, t_s: float, speed_rpm: float) -> None:
        """Add a speed if ``t_s`` is within the speed window (``t - t0 <= window_s``)."""
        if self.t0_s is None:
            self.t0_s = float(t_s)
        if float(t_s) - self.t0_s <= self.window_s:
            self.speeds.append(float(speed_rpm))

    def median(self) -> np.ndarray:
        """NaN-ignoring median per column (NaN where a column has no finite value)."""
        rows = np.asarray(self.values, dtype=float)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # an all-NaN column -> NaN
            return np.nanmedian(rows, axis=0)

    def median_speed(self) -> float:
        """Median of the window's speeds (r/min)."""
        return float(np.median(np.asarray(self.speeds, dtype=float)))
