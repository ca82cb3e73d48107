"""Signal primitives shared by the twin and the synthetic generators.

First-order lags (filtered and analytic) and AR(1) noise: where the twin and a synthetic
generator need the same response, they call the same function here.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter


def first_order(u: np.ndarray, period_s: float, tau_s: float, y0: float = 0.0) -> np.ndarray:
    """First-order lag of a 1-D input sampled every ``period_s`` (zero-order hold, exact).

    Parameters
    ----------
    u : numpy.ndarray
        Input samples.
    period_s : float
        Sample period, s.
    tau_s : float
        Time constant, s; ``tau_s <= 0`` passes the input through (a copy).
    y0 : float
        State before the first sample (``u[0]`` starts the lag in steady state).

    Returns
    -------
    numpy.ndarray
        ``y[k] = a y[k-1] + (1 - a) u[k]`` with ``a = exp(-period_s / tau_s)``.
    """
    if tau_s <= 0:
        return np.array(u, dtype=float, copy=True)
    a = np.exp(-period_s / tau_s)
    y, _ = lfilter([1 - a], [1, -a], u, zi=np.array([a * y0]))
    return y


def step_response(t: np.ndarray, amplitude: float, tau_s: float) -> np.ndarray:
    """Analytic first-order step response ``amplitude (1 - exp(-t / tau_s))``."""
    return amplitude * (1 - np.exp(-t / tau_s))


def ar1(x: np.ndarray, a: float, gain: float = 1.0, axis: int = 0) -> np.ndarray:
    """AR(1) filter ``y[k] = a y[k-1] + gain x[k]`` along ``axis``, from a zero state.

    With white input of std ``s`` and ``gain = sqrt(1 - a^2)`` the output is correlated
    noise of std ``s``; with ``gain = 1`` and ``x[0]`` drawn with std ``s`` and the rest
    with ``s sqrt(1 - a^2)``, it is stationary AR(1) noise of std ``s`` from the start.
    """
    return lfilter([gain], [1, -a], x, axis=axis)
