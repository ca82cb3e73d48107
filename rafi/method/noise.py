"""The noise floor of a validation run, estimated from its own displacement (no truth needed).

A perfect model leaves the measurement noise as its residual, so ``max |residual|`` of a run
cannot be expected below the largest noise sample of that run. Both numbers are estimated
from the run's ``dz`` alone:

* **White-noise sigma** from the high-frequency part: the second differences
  ``d2[k] = dz[k+1] - 2 dz[k] + dz[k-1]`` remove the slow thermal drift (constant and
  linear parts exactly, the curvature of a drift sampled every few seconds is negligible),
  and of white noise of std ``sigma`` they have std ``sigma * sqrt(6)``. A robust scale
  (``1.4826 * MAD``) ignores the few samples where the displacement really jumps (a
  speed change, the draw-in of the tool holder). Where the MAD is 0 (a coarsely quantised
  signal), the mean absolute deviation (scaled by ``sqrt(pi / 2)``) is used instead.
* **Expected max |noise|** over the run's ``n`` samples for independent Gaussian noise:
  ``E[max_k |e_k|] = sigma * integral_0^inf (1 - erf(x / sqrt 2)^n) dx`` (numerically).

What this does not see: slowly correlated noise (drift of the sensor over minutes) survives
differencing only in part, so it counts as model error here. The floor is a lower bound
for what a model can reach on the run, not an estimate of the model error.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["MIN_DIFFERENCES", "white_noise_sigma", "expected_max_abs_noise", "noise_floor"]

#: Fewer finite second differences than this give no estimate (NaN).
MIN_DIFFERENCES = 10

_MAD_TO_SIGMA = 1.482602218505602  # 1 / Phi^-1(3/4)


def white_noise_sigma(values) -> float:
    """Robust standard deviation of the white noise in a time-ordered series.

    Parameters
    ----------
    values : array-like of float
        One run's displacement (``dz``), in time order, on a regular grid; NaN allowed (a
        second difference touching a NaN is dropped).

    Returns
    -------
    float
        ``1.4826 * MAD(d2) / sqrt(6)`` with ``d2`` the second differences (see the module
        docstring); NaN with fewer than :data:`MIN_DIFFERENCES` finite second differences.
    """
    x = np.asarray(values, dtype=float)
    if x.size < 3:
        return float("nan")
    d2 = x[2:] - 2.0 * x[1:-1] + x[:-2]
    d2 = d2[np.isfinite(d2)]
    if d2.size < MIN_DIFFERENCES:
        return float("nan")
    dev = np.abs(d2 - np.median(d2))
    scale = _MAD_TO_SIGMA * float(np.median(dev))
    if scale == 0.0:
        scale = math.sqrt(math.pi / 2.0) * float(np.mean(dev))
    return scale / math.sqrt(6.0)


def expected_max_abs_noise(sigma: float, n: int, *, points: int = 4001) -> float:
    """Expected largest ``|e_k|`` of ``n`` independent N(0, sigma^2) samples.

    Parameters
    ----------
    sigma : float
        Noise standard deviation (NaN gives NaN, 0 gives 0).
    n : int
        Number of samples (0 gives NaN).
    points : int
        Grid points of the numerical integral over ``[0, 12]`` (in units of sigma).

    Returns
    -------
    float
        ``sigma * integral_0^12 (1 - erf(x / sqrt 2)^n) dx`` (the tail beyond 12 sigma is
        below 1e-30 for any n below 1e12). ``n = 1`` gives ``sigma * sqrt(2 / pi)``.
    """
    if not np.isfinite(sigma) or n < 1:
        return float("nan")
    if sigma == 0.0:
        return 0.0
    from scipy.special import erfc  # here, not at the top: importing SciPy costs every job ~0.3 s

    x = np.linspace(0.0, 12.0, int(points))
    # erf(z)^n = exp(n * log1p(-erfc(z))), accurate where erf is close to 1
    with np.errstate(divide="ignore"):
        cdf = np.exp(float(n) * np.log1p(-erfc(x / math.sqrt(2.0))))
    return float(sigma) * float(np.trapezoid(1.0 - cdf, x))


def noise_floor(values) -> tuple[float, float]:
    """``(sigma, expected max |noise|)`` of one run's displacement, in its units.

    ``sigma`` from :func:`white_noise_sigma`; the expected max over the run's finite samples
    from :func:`expected_max_abs_noise`: the max residual a perfect model would typically
    leave on this run.
    """
    x = np.asarray(values, dtype=float)
    sigma = white_noise_sigma(x)
    return sigma, expected_max_abs_noise(sigma, int(np.isfinite(x).sum()))
