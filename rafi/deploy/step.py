"""What every streaming compensator returns and which artefact kinds it evaluates: the
:class:`Step` of one sample and the kinds (:mod:`rafi.deploy.compensator` runs a single kind,
:mod:`rafi.deploy.ensemble_stream` an ensemble of them). NumPy only."""

from __future__ import annotations

from typing import NamedTuple

from rafi.contract import MODEL_KINDS

__all__ = ["ENSEMBLE", "KINDS", "MEMBER_KINDS", "STATUSES", "Step"]

#: The kind of the CV-weighted ensemble's artefact (``rafi.family.ensemble.ENSEMBLE``).
ENSEMBLE = "ensemble"
#: The single model kinds the compensator evaluates, each on its own or as an ensemble's member.
MEMBER_KINDS = MODEL_KINDS
#: Every artefact kind the compensator evaluates (:mod:`rafi.deploy.ensemble_stream` runs an ensemble).
KINDS = (*MEMBER_KINDS, ENSEMBLE)
#: Status values of a step (``docs/deploy.md``).
STATUSES = {
    "referencing": "collecting the reference window; compensation 0 um (the reference state)",
    "ok": "the model's value",
    "no_value": "the model has no value (a needed input is missing); compensation NaN",
}


class Step(NamedTuple):
    """The result of one :meth:`rafi.deploy.compensator.Compensator.step`.

    ``lower_um`` / ``upper_um`` / ``half_width_um`` / ``interval_cell``: the prediction interval
    of the model's value (:mod:`rafi.deploy.interval_stream`; around 0 um while referencing);
    NaN / ``""`` when the artefact has no ``interval`` block or the model has no value.
    ``range_excess``: how far the sample lies beyond the trained range
    (:func:`rafi.family.envelope.key_range_excess`; the ridge kinds', 0 for ``rafi`` /
    ``rafi_linear`` and while referencing), the factor that widens the interval.
    """

    t_s: float
    compensation_um: float
    status: str
    raw_um: float
    outside_speed_range: bool
    outside_temp_range: bool
    lower_um: float = float("nan")
    upper_um: float = float("nan")
    half_width_um: float = float("nan")
    interval_cell: str = ""
    outside_envelope: bool = False
    range_excess: float = 0.0
