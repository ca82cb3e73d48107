"""Kind ``rafi_linear``: RAFI's key sensors and fuzzy blend, linear terms only."""

from __future__ import annotations

from collections.abc import Sequence

from rafi.family.published import PublishedRafi
from rafi.settings import MACHINE_DEFAULTS

#: The terms that define the kind: one linear law per training speed.
LINEAR_TERMS = ["1", "x1", "x2", "x3"]


class RafiLinear(PublishedRafi):
    """Kind ``rafi_linear``: terms ``1, x1, x2, x3`` per training speed, RAFI's fuzzy blend.

    The artefact is RAFI's layout with ``kind: rafi_linear`` (and its own ``model_id``).
    Parameters as :class:`rafi.family.published.PublishedRafi`; ``terms`` defaults to
    :data:`LINEAR_TERMS`.
    """

    kind = "rafi_linear"

    def __init__(
        self,
        *,
        key_sensors: Sequence[str],
        terms: Sequence[str] = LINEAR_TERMS,
        reference: dict = MACHINE_DEFAULTS["reference"],
        machine: str | None = None,
        hac_maxlags: int = MACHINE_DEFAULTS["fit"]["hac_maxlags"],
        speed_tolerance_rpm: float = MACHINE_DEFAULTS["speed_tolerance_rpm"],
    ):
        self.key_sensors = key_sensors
        self.terms = terms
        self.reference = reference
        self.machine = machine
        self.hac_maxlags = hac_maxlags
        self.speed_tolerance_rpm = speed_tolerance_rpm
