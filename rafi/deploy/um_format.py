"""How ``rafi deploy`` prints a value in micrometres: signed, three decimals, never ``-0.000``.

A command held at a value that is a tiny negative number (``-1e-12`` after a ramp, or the
``-0.0`` an axis sign makes of zero) would print as ``-0.000 um``, which reads as a compensation
where there is none. :func:`signed_um` prints every value that rounds to zero as ``+0.000``.
Standard library only.
"""

from __future__ import annotations

import math

__all__ = ["signed_um"]


def signed_um(value: float, *, width: int = 0, digits: int = 3) -> str:
    """``value`` as ``+1.234`` / ``-0.500``, and ``+0.000`` for anything that rounds to zero.

    Parameters
    ----------
    value : float
        Micrometres (NaN and infinities are printed as Python prints them, signed).
    width : int
        The minimum width, right-aligned (as in ``f"{value:+9.3f}"``).
    digits : int
        Decimals.

    Returns
    -------
    str
        The number without its unit.
    """
    value = float(value)
    if math.isfinite(value) and round(value, digits) == 0:
        value = 0.0  # -0.0 and -0.0004 alike: +0.000
    return f"{value:+{width}.{digits}f}"
