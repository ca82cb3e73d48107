"""Whether ``rafi nightly`` promoted a new champion while ``rafi deploy`` runs.

Every ``deploy.champion_check_s`` seconds the live loop asks :meth:`ChampionWatch.poll`; when
the registry's champion pointer names another model, the new champion is loaded and verified
(:func:`rafi.deploy.qualified.load_champion`) and handed to the loop, which swaps it in
(:meth:`rafi.deploy.limits.SafeCompensator.swap`: it ramps from the command in force to the new
model under the rate limit). A champion that cannot be loaded (a half-written registry, an
edited file) is logged once and the model in service stays. Standard library only.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from rafi.errors import UnqualifiedModel

__all__ = ["ChampionWatch"]


class ChampionWatch:
    """Polls a registry's champion pointer.

    Parameters
    ----------
    registry_root : path
        ``results/<machine>/registry``.
    model_id : str
        The model in service.
    check_s : float
        ``deploy.champion_check_s``: seconds between two looks.
    log : callable
        ``log(line)`` for a new champion, and once for one that cannot be loaded.
    """

    def __init__(self, registry_root, model_id: str, *, check_s: float, log: Callable[[str], None] = print):
        self.registry_root = Path(registry_root)
        self.model_id = model_id
        self.check_s = float(check_s)
        self.log = log
        self._next_s: float | None = None
        self._refused: str | None = None

    def poll(self, now: float) -> dict | None:
        """The new champion's artefact if one was promoted since the last look (and it is time
        to look: every ``check_s`` from the first call), else None."""
        if self._next_s is None:
            self._next_s = now + self.check_s
            return None
        if now < self._next_s:
            return None
        self._next_s = now + self.check_s
        from rafi.deploy.qualified import check_belongs, load_champion

        try:
            pointer = json.loads((self.registry_root / "champion.json").read_text(encoding="utf-8"))
            champion_id = pointer.get("model_id")
        except (OSError, ValueError, AttributeError):
            return None  # being replaced (atomically) or unreadable: look again next time
        if not isinstance(champion_id, str) or champion_id in (self.model_id, self._refused):
            return None
        try:
            artefact = load_champion(self.registry_root)
            check_belongs(artefact, self.registry_root.parent.name)
        except UnqualifiedModel as exc:
            self._refused = champion_id
            self.log(f"new champion {champion_id[:12]} not loaded, model {self.model_id[:12]} stays: {exc}")
            return None
        self.model_id = artefact["model_id"]
        return artefact
