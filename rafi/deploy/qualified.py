"""Which model may compensate a machine: only the registry's champion (``docs/deploy.md``).

A model becomes the champion only through the promotion gates (``rafi nightly``,
``docs/operations.md``); compensation stays off until it is loaded. Standard library only.
"""

from __future__ import annotations

import json
from pathlib import Path

from rafi.artefact import model_id_verifies
from rafi.errors import SettingsError, UnqualifiedModel

__all__ = ["check_belongs", "check_machine", "check_qualified", "load_champion", "registry_owners"]


def _shown(path: Path) -> str:
    """``path`` for a message, short enough never to be cut (:func:`rafi.errors.bound_message`):
    relative to the working folder, else to the project (the folder holding ``results_dir``,
    for a registry folder ``<results_dir>/<machine>/registry/...``)."""
    path = Path(path).resolve()
    parts = path.parts
    at = parts.index("registry") if "registry" in parts[3:] else None
    project = path.parents[len(parts) - at + 1] if at is not None else None
    for base in (Path.cwd().resolve(), project):
        try:
            return str(path.relative_to(base)) if base is not None else str(path)
        except ValueError:
            continue
    return str(path)


def _file_in(path: Path) -> str:
    """``<name> in <folder>``: the file name whole (never cut in a message), the folder apart."""
    return f"{path.name} in {_shown(path.parent)}"


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
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
        raise UnqualifiedModel(
            f"the champion's model file {_file_in(path)} cannot be read ({reason}); compensation stays off"
        ) from None
    if not isinstance(artefact, dict) or artefact.get("model_id") != model_id:
        raise UnqualifiedModel(f"the model file {_file_in(path)} is not the champion {model_id[:12]}")
    if not model_id_verifies(artefact, model_id):
        raise UnqualifiedModel(
            f"the champion's model file {_file_in(path)} was modified after promotion (its content does "
            f"not hash to its model_id {model_id[:12]}): refused; compensation stays off"
        )
    return artefact


def check_qualified(artefact: dict, registry_root) -> None:
    """Raise :class:`UnqualifiedModel` unless ``artefact`` is the champion of ``registry_root``
    and its content verifies."""
    champion_id = _champion_id(Path(registry_root))
    model_id = artefact.get("model_id") if isinstance(artefact, dict) else None
    if not model_id or not model_id_verifies(artefact, model_id):
        raise UnqualifiedModel("the model artefact does not verify (its content does not hash to model_id)")
    if model_id == champion_id:
        return
    root = Path(registry_root)
    machine = root.parent.name
    owners = [m for m in registry_owners(model_id, root.parent.parent) if m != machine]
    if owners and not (root / "models" / f"{model_id}.json").is_file():
        raise UnqualifiedModel(
            f"model {model_id[:12]} is machine {' and '.join(owners)}'s model, not this machine's "
            f"({machine}): only {machine}'s champion ({champion_id[:12]}) may compensate {machine}"
        )
    raise UnqualifiedModel(
        f"model {model_id[:12]} is not the champion of {_shown(root)} ({champion_id[:12]}): only the "
        "champion is qualified to compensate this machine; promote it with `rafi nightly` first"
    )


def registry_owners(model_id: str, results_dir) -> list[str]:
    """The machines whose registry (``<results_dir>/<machine>/registry``) holds ``model_id``."""
    return sorted(
        p.parent.parent.parent.name
        for p in Path(results_dir).glob(f"*/registry/models/{model_id}.json")
        if p.is_file()
    )


def check_belongs(artefact: dict, machine: str) -> None:
    """Raise :class:`UnqualifiedModel` when the artefact says it was fitted for another machine
    (its ``machine`` field; an artefact without one is not judged here)."""
    fitted_for = artefact.get("machine") if isinstance(artefact, dict) else None
    if isinstance(fitted_for, str) and fitted_for and fitted_for != machine:
        raise UnqualifiedModel(
            f"model {str(artefact.get('model_id', ''))[:12]} is machine {fitted_for}'s model (so its "
            f"artefact says), not this machine's ({machine}): refused; compensation stays off"
        )


def check_machine(machine: str, config: dict, results_dir, raw_dir=None) -> None:
    """Raise :class:`SettingsError` for a machine that neither ``config.yaml`` (``machines:``),
    the results (a registry) nor the raw folder knows."""
    configured = sorted(str(m) for m in (config.get("machines") or {}))
    known = set(configured) | {p.parent.name for p in Path(results_dir).glob("*/registry") if p.is_dir()}
    if raw_dir is not None and Path(raw_dir).is_dir():
        known |= {p.name for p in Path(raw_dir).iterdir() if p.is_dir() and not p.name.startswith(".")}
    if machine not in known:
        others = sorted(known - set(configured))
        also = f"; results or raw data also have: {', '.join(others)}" if others else ""
        raise SettingsError(
            f"unknown machine {machine}; config.yaml has: {', '.join(configured) or 'no machines'}{also}"
        )
