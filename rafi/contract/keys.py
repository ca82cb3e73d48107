"""How the contract declares a setting: :class:`Setting` (a key) and :class:`Section` (a mapping)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Setting:
    """One settings key: its default, its JSON schema (no ``default`` keyword), and what it means.

    ``shown`` is how ``docs/settings.md`` writes the default where the value itself reads badly
    (``None`` for a key the table leaves out); ``limit`` marks a ``deploy:`` key of
    :class:`rafi.deploy.limits.Limits`, ``replay`` one the replay rule depends on.
    """

    default: Any
    schema: dict
    doc: str
    shown: str | None = None
    limit: bool = False
    replay: bool = False


@dataclass(frozen=True)
class Section:
    """A mapping of settings (``clean:``, ``deploy:``, ...): every key known, none other allowed."""

    doc: str
    keys: dict
    shown: str | None = None
    schema_extra: dict = field(default_factory=dict)


# --------------------------------------------------------------------------- schemas several keys share
# (the generator copies a schema into the config schema, so sharing one dict is safe)

#: A number of at least 0.
NON_NEGATIVE: dict = {"type": "number", "minimum": 0}
#: A number above 0.
POSITIVE: dict = {"type": "number", "exclusiveMinimum": 0}
#: True or false.
FLAG: dict = {"type": "boolean"}
#: A text, or nothing (a line left blank in the report).
OPTIONAL_TEXT: dict = {"type": ["null", "string"]}
#: A TCP port to serve on, or nothing (not served).
OPTIONAL_PORT: dict = {"oneOf": [{"type": "null"}, {"type": "integer", "minimum": 1, "maximum": 65535}]}
#: ``[low, high]``.
RANGE: dict = {"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": 2}


def auto_or_numbers(*, positive: bool = False) -> dict:
    """``auto`` or a non-empty list of distinct numbers >= 0 (> 0 with ``positive``): a grid that
    the model kind chooses itself unless the machine's settings give one."""
    bound = {"exclusiveMinimum": 0} if positive else {"minimum": 0}
    return {
        "oneOf": [
            {"const": "auto"},
            {"type": "array", "items": {"type": "number", **bound}, "minItems": 1, "uniqueItems": True},
        ]
    }
