"""Per-machine settings: the sections of :mod:`rafi.contract.method`, ``operations`` and
``presentation`` in the order ``rafi settings`` prints them, and the keys derived from them."""

from __future__ import annotations

from rafi.contract.keys import Section, Setting
from rafi.contract.method import METHOD_SETTINGS
from rafi.contract.operations import OPERATIONS_SETTINGS
from rafi.contract.presentation import PRESENTATION_SETTINGS
from rafi.contract.record import RECORD_SETTINGS

#: Per-machine settings: ``defaults:`` and ``machines.<name>:`` of ``config.yaml``, in the order
#: ``rafi settings`` prints them.
MACHINE_SETTINGS: dict[str, Setting | Section] = {
    **METHOD_SETTINGS,
    **OPERATIONS_SETTINGS,
    **PRESENTATION_SETTINGS,
    **RECORD_SETTINGS,
}

#: ``deploy:`` keys of the limits and fault rules (:class:`rafi.deploy.limits.Limits`).
LIMIT_KEYS: tuple[str, ...] = tuple(k for k, s in MACHINE_SETTINGS["deploy"].keys.items() if s.limit)
#: ``deploy:`` keys the replay depends on: the limits and which runs it replays (not the
#: controller's connection settings).
REPLAY_KEYS: tuple[str, ...] = tuple(k for k, s in MACHINE_SETTINGS["deploy"].keys.items() if s.replay)
#: The promotion gates, in the order they are reported.
GATE_KEYS: tuple[str, ...] = tuple(MACHINE_SETTINGS["qualification"].keys)
