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
