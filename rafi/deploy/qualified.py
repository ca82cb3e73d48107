"""Which model may compensate a machine: only the registry's champion (``docs/deploy.md``).

A model becomes the champion only through the promotion gates (``rafi nightly``,
``docs/operations.md``); compensation stays off until it is loaded. Standard library only.
"""

from __future__ import annotations

import json
from pathlib import Path

from rafi.artefact import model_id_verifies
from rafi.errors import UnqualifiedModel

__all__ = ["check_qualified", "load_champion"]


def _champion_id(registry_root: Path) -> str:
    pointer = Path(registry_root) / "champion.json"
    try:
        model_id = json.loads(pointer.read_text(encoding="utf-8")).get("model_id")
    except FileNotFoundError:
        raise UnqualifiedModel(
            f"{pointer}: the registry has no champion, so no model is qualified for this machine "
            "(a model becomes the champion through `rafi nightly`'s gates); compensation stays off"
        ) from None
    except (OSError, ValueError, AttributeError) as exc:
        raise UnqualifiedModel(f"{pointer}: unreadable champion pointer ({exc}); compensation off") from None
    if not isinstance(model_id, str) or not model_id:
        raise UnqualifiedModel(f"{pointer}: no model_id in the champion pointer; compensation stays off")
    return model_id


def load_champion(registry_root) -> dict:
    """The champion's model artefact of the registry ``registry_root``, verified.

    Parameters
    ----------
    registry_root : path
        ``results/<machine>/registry``.

    Returns
    -------
    dict
        The artefact (``rafi.model/1``), its content hashing to its ``model_id``.

    Raises
    ------
    UnqualifiedModel
        No champion, or its file is missing, unreadable or was modified.
    """
    root = Path(registry_root)
    model_id = _champion_id(root)
    path = root / "models" / f"{model_id}.json"
    try:
        artefact = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise UnqualifiedModel(f"{path}: the champion's artefact cannot be read ({exc})") from None
    if not isinstance(artefact, dict) or artefact.get("model_id") != model_id:
        raise UnqualifiedModel(f"{path}: the file is not the champion {model_id}")
    if not model_id_verifies(artefact, model_id):
        raise UnqualifiedModel(f"{path}: its content does not hash to {model_id} (modified after promotion)")
    return artefact


def check_qualified(artefact: dict, registry_root) -> None:
    """Raise :class:`UnqualifiedModel` unless ``artefact`` is the champion of ``registry_root``
    and its content verifies."""
    champion_id = _champion_id(Path(registry_root))
    model_id = artefact.get("model_id") if isinstance(artefact, dict) else None
    if not model_id or not model_id_verifies(artefact, model_id):
        raise UnqualifiedModel("the model artefact does not verify (its content does not hash to model_id)")
    if model_id != champion_id:
        raise UnqualifiedModel(
            f"model {model_id[:12]} is not the champion of {registry_root} ({champion_id[:12]}): only the "
            "champion is qualified to compensate this machine; promote it with `rafi nightly` first"
        )
