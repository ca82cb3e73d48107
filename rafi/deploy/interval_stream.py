"""The prediction interval of the streaming compensator, one sample at a time (NumPy only).

The rule is :mod:`rafi.family.interval_rule` (the same code the batch outputs use): the interval
of a value ``v`` is ``[v - h, v + h]`` with ``h`` the artefact's ``interval.half_width_um`` of
the sample's cell (``settled``, ``transient``, ``outside``). The change clock
(:class:`~rafi.family.interval_rule.ChangeClock`) is reset at the first sample, at a filter
restart (a gap longer than the model's restart limit) and at the first sample after
:meth:`rafi.deploy.compensator.Compensator.capture_reference` (the start of the reference
window), as the batch code resets it at a layout's restarts and at each reference group's
first row; it advances on every sample, also while the reference is collected or the model
has no value, so the two clocks agree sample by sample.

An artefact without an ``interval`` block (written before issue 26) has no interval: every
bound is NaN and the cell ``""``; nothing fails.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from rafi.family.interval_rule import CELLS, ChangeClock, half_width_um, interval_cell, widening

__all__ = ["NO_INTERVAL", "Bounds", "StreamInterval"]


class Bounds(NamedTuple):
    """The interval of one value: bounds and half-width (um), and its cell."""

    lower_um: float
    upper_um: float
    half_width_um: float
    interval_cell: str


#: No interval (no ``interval`` block, or no value to put it around).
NO_INTERVAL = Bounds(math.nan, math.nan, math.nan, "")


class StreamInterval:
    """The change clock and the half-widths of one artefact's ``interval`` block.

    Parameters
    ----------
    block : dict
        The artefact's ``interval`` block (``transient_s``, ``tolerance_rpm``, ``half_width_um``).
    """

    def __init__(self, block: dict):
        self.block = block
        self.transient_s = float(block["transient_s"])
        self.half_widths = {cell: half_width_um(block, cell) for cell in CELLS}
        self.clock = ChangeClock.create(float(block["tolerance_rpm"]))

    @classmethod
    def from_artefact(cls, d: dict) -> StreamInterval | None:
        """The interval of artefact ``d``; None when it has no ``interval`` block.

        Raises
        ------
        ValueError
            A block that lacks a key or a cell of the rule.
        """
        block = d.get("interval")
        if not block:
            return None
        try:
            return cls(block)
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(
                f"the artefact's interval block is not a rafi.interval/1 block "
                f"(transient_s, tolerance_rpm, half_width_um settled/transient/outside): {exc!r}"
            ) from None

    def update(self, t_s: float, speed_rpm: float, *, reset: bool) -> float:
        """Advance the change clock by one sample; seconds since its last reset."""
        return self.clock.update(t_s, speed_rpm, reset=reset)

    def bounds(self, value_um: float, *, since_change_s: float, outside: bool, excess: float = 0.0) -> Bounds:
        """The interval around ``value_um`` (:data:`NO_INTERVAL` when it is not finite); ``excess``
        widens it beyond the trained range (:func:`rafi.family.interval_rule.widening`)."""
        if not math.isfinite(value_um):
            return NO_INTERVAL
        cell = interval_cell(since_change_s=since_change_s, outside=outside, transient_s=self.transient_s)
        h = self.half_widths[cell] * float(widening(self.block, excess))
        return Bounds(value_um - h, value_um + h, h, cell)
