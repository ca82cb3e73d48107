"""The prediction interval of one compensation, sample by sample (NumPy only).

This is the part of the interval that both the batch code (:mod:`rafi.family.intervals`, which
calibrates it on whole-run CV residuals) and the streaming compensator
(:mod:`rafi.deploy.compensator`) evaluate, so that the two agree to rounding.

An interval is ``[predicted - h, predicted + h]`` with a half-width ``h`` that depends only on
the sample's *cell* (a Mondrian split-conformal interval):

* ``outside`` - the sample is outside the trained temperature or speed range (the flags of
  ``predict_detail``);
* ``transient`` - less than ``transient_s`` since the change clock was reset;
* ``settled`` - the rest.

Beyond the trained range the half-width also grows with the distance: ``h x (1 + c x excess)``,
``excess`` the sample's key sensor rises and speed beyond their training ranges in training spans
(``range_excess`` of ``predict_detail``, :func:`rafi.family.envelope.range_excess`; 0 inside the
ranges and for the kinds without it) and ``c`` the block's ``excess_slope`` (:data:`EXCESS_SLOPE`
from 2026-11-29; a block without it: 0, the interval as before). Since 2026-11-30 a ridge kind's
``excess`` also holds its **component excess** (:func:`rafi.family.envelope.component_excess`:
how far its prediction reaches beyond the combinations of features it was trained on, in
training displacement spans), so a direction of the temperatures the training never showed
widens the interval though every sensor is inside its own range; a block calibrated so says
:data:`COMPONENT_EXCESS` and one calibrated before is evaluated as it was
(:func:`reads_components`). The calibration divides each residual by the same factor (a
normalised conformal score), so the level holds.

The change clock (:class:`ChangeClock`) is reset at the first sample, at a filter restart (a
gap longer than the restart limit), at the start of a reference window, and when the speed
moves more than ``tolerance_rpm`` away from the speed at the last reset (its *anchor*). A NaN
speed neither resets nor moves the anchor; the first finite speed after a reset with a NaN
anchor becomes the anchor without a reset.

The artefact's ``interval`` block (:data:`INTERVAL_SCHEMA`) holds what is needed here:
``level``, ``transient_s``, ``tolerance_rpm`` and ``half_width_um`` (cell -> um).
"""

from __future__ import annotations

import math

import numpy as np

INTERVAL_SCHEMA = "rafi.interval/1"
CELLS = ("settled", "transient", "outside")
#: How fast the half-width grows beyond the trained range, per training span of excess. Judged one
#: level up (2026-11-29, leave one training run out on 6 real logs and 22 foreign machines; the
#: decision log): 10 gave the held-out runs' coverage closest to the level (mean |coverage - 90 %|
#: 0.104 against 0.124 without, 0.110-0.121 at 3, 20 and 30) and 92 % coverage of their rows
#: outside the range against 82 %.
EXCESS_SLOPE = 10.0


#: The ``interval`` block's key saying that the excess it widens with holds the component excess
#: (calibrated since 2026-11-30, issue 46; the decision log).
COMPONENT_EXCESS = "component_excess"


def reads_components(block) -> bool:
    """Whether a model's range excess holds its component excess: yes for a model not calibrated
    yet (``block`` None: a fold's model, or one being calibrated, whose out-of-fold excess the
    calibration reads) and for one calibrated with it; no for a block calibrated before
    (2026-11-30), which is evaluated as it was calibrated."""
    return not isinstance(block, dict) or bool(block.get(COMPONENT_EXCESS, False))


def widening(interval: dict, excess) -> np.ndarray:
    """The factor ``1 + excess_slope x excess`` of an ``interval`` block (1 without the slope)."""
    slope = float(interval.get("excess_slope", 0.0))
    e = np.nan_to_num(np.asarray(excess, dtype=float))
    return 1.0 + slope * np.maximum(e, 0.0)


def interval_cell(*, since_change_s: float, outside: bool, transient_s: float) -> str:
    """The cell of one sample (see the module docstring)."""
    if outside:
        return "outside"
    if since_change_s < transient_s:
        return "transient"
    return "settled"


def half_width_um(interval: dict, cell: str) -> float:
    """The half-width (um) of ``cell`` in an artefact's ``interval`` block."""
    return float(interval["half_width_um"][cell])


class ChangeClock:
    """Seconds since the last reset of the change clock, one sample at a time.

    Parameters
    ----------
    tolerance_rpm : float
        A speed further than this from the anchor resets the clock.
    t_reset_s, anchor_rpm : float
        State (NaN: no sample seen yet / no finite speed since the reset).
    """

    def __init__(self, *, tolerance_rpm: float, t_reset_s: float, anchor_rpm: float):
        self.tolerance_rpm = tolerance_rpm
        self.t_reset_s = t_reset_s
        self.anchor_rpm = anchor_rpm

    @classmethod
    def create(cls, tolerance_rpm: float) -> ChangeClock:
        """A clock that has seen no sample (the first sample resets it)."""
        return cls(tolerance_rpm=float(tolerance_rpm), t_reset_s=math.nan, anchor_rpm=math.nan)

    def update(self, t_s: float, speed_rpm: float, *, reset: bool = False) -> float:
        """Take one sample; ``reset`` marks a restart or a reference window's start.

        Returns the seconds since the last reset (0 at a reset).
        """
        t, rpm = float(t_s), float(speed_rpm)
        moved = math.isfinite(rpm) and math.isfinite(self.anchor_rpm)
        moved = moved and abs(rpm - self.anchor_rpm) > self.tolerance_rpm
        if reset or moved or math.isnan(self.t_reset_s):
            self.t_reset_s = t
            self.anchor_rpm = rpm
        elif math.isnan(self.anchor_rpm) and math.isfinite(rpm):
            self.anchor_rpm = rpm
        return t - self.t_reset_s


def since_change(
    t_s: np.ndarray, speed_rpm: np.ndarray, reset: np.ndarray, *, tolerance_rpm: float
) -> np.ndarray:
    """:class:`ChangeClock` over a sorted series (one log): seconds since the last reset.

    Parameters
    ----------
    t_s, speed_rpm : ndarray
        Time (s, increasing) and speed (r/min) of the samples in order.
    reset : ndarray of bool
        Samples where the clock is reset (restarts, reference windows' starts).
    """
    clock = ChangeClock.create(tolerance_rpm)
    out = np.empty(len(t_s), dtype=float)
    for i, (t, rpm, r) in enumerate(zip(np.asarray(t_s, float), np.asarray(speed_rpm, float), reset)):
        out[i] = clock.update(t, rpm, reset=bool(r))
    return out


def change_resets(restart: np.ndarray, ref_group: np.ndarray) -> np.ndarray:
    """Where the change clock is reset in a batch layout (sorted rows): the filter restarts
    (:attr:`rafi.family.whole_log.Layout.restart`) and the first row of every reference group
    (:attr:`~rafi.family.whole_log.Layout.ref_group`, the start of its reference window)."""
    out = np.asarray(restart, dtype=bool).copy()
    groups = np.asarray(ref_group)
    if len(groups):
        out[np.unique(groups, return_index=True)[1]] = True
    return out


def batch_bounds(
    interval: dict,
    *,
    predicted_um: np.ndarray,
    t_s: np.ndarray,
    speed_rpm: np.ndarray,
    reset: np.ndarray,
    outside: np.ndarray,
    excess: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """The interval of every sample of a sorted series (the batch side of the streaming rule).

    Parameters
    ----------
    interval : dict
        An artefact's ``interval`` block.
    predicted_um, t_s, speed_rpm : ndarray
        The prediction (um, NaN: no value), time (s) and speed (r/min) of the samples, sorted
        as a :class:`rafi.family.whole_log.Layout` sorts them (logs one after the other).
    reset : ndarray of bool
        :func:`change_resets` of the layout (a log's first row is a restart).
    outside : ndarray of bool
        ``outside_temp_range | outside_speed_range`` of ``predict_detail``.
    excess : ndarray, optional
        ``range_excess`` of ``predict_detail`` (None: 0 everywhere).

    Returns
    -------
    dict
        ``lower_um``, ``upper_um``, ``half_width_um`` (NaN where the prediction is NaN) and
        ``interval_cell`` (``""`` there), in the input order.
    """
    since = since_change(t_s, speed_rpm, reset, tolerance_rpm=float(interval["tolerance_rpm"]))
    transient_s = float(interval["transient_s"])
    cells = np.array(
        [
            interval_cell(since_change_s=s, outside=bool(o), transient_s=transient_s)
            for s, o in zip(since, np.asarray(outside, dtype=bool))
        ],
        dtype=object,
    )
    pred = np.asarray(predicted_um, dtype=float)
    h = np.array([half_width_um(interval, c) for c in cells], dtype=float).reshape(len(cells))
    if excess is not None:
        h = h * widening(interval, excess)
    h[~np.isfinite(pred)] = np.nan
    cells[~np.isfinite(pred)] = ""
    return {"lower_um": pred - h, "upper_um": pred + h, "half_width_um": h, "interval_cell": cells}
