"""The model registry of a machine: an immutable model store, the champion pointer, the history.

Layout (``results/<machine>/registry/``, see ``docs/operations.md``)::

    models/<model_id>.json       immutable copy of every model ever judged (byte-for-byte the
                                 model.json content; loadable with rafi.method.model.load_model)
    models/<model_id>.meta.json  immutable provenance: data hashes, config, code version
                                 (rafi version + git commit), source path, save time
    champion.json                pointer to the promoted model (replaced atomically)
    history.jsonl                append-only log, one JSON object per line, of every
                                 promotion / rejection / keep / rollback with reasons, gates,
                                 measured values and the data files seen
    decision.json                tonight's decision (declared Snakemake output, rafi.ops.decide)
    comparison.csv               champion vs candidate per validation run (declared output)

Every write goes through ``rafi.artefact`` (write-once models, atomic pointer replace, fsynced
appends); the decision itself is ``rafi.ops.decide``.
"""

from __future__ import annotations

import contextlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

from rafi import __version__
from rafi.artefact import (
    append_jsonl,
    compute_model_id,
    git_commit,
    json_text,
    model_id_verifies,
    now_iso,
    read_jsonl,
    write_once,
    write_text_atomic,
)
from rafi.contract import REGISTRY_DIR
from rafi.errors import RegistryError

HISTORY_SCHEMA = "rafi.registry.history/1"
CHAMPION_SCHEMA = "rafi.registry.champion/1"
DECISION_SCHEMA = "rafi.registry.decision/1"


def registry_dir(results_dir: str | os.PathLike, machine: str) -> Path:
    """``<results_dir>/<machine>/registry`` (:data:`rafi.contract.REGISTRY_DIR`)."""
    return Path(results_dir) / machine / REGISTRY_DIR


@dataclass
class Registry:
    """The registry folder of one machine (``results/<machine>/registry``)."""

    root: Path
    machine: str = ""

    def __post_init__(self):
        self.root = Path(self.root)
        if not self.machine:
            self.machine = self.root.parent.name

    # paths
    @property
    def models_dir(self) -> Path:
        return self.root / "models"

    @property
    def champion_path(self) -> Path:
        return self.root / "champion.json"

    @property
    def history_path(self) -> Path:
        return self.root / "history.jsonl"

    @property
    def decision_path(self) -> Path:
        return self.root / "decision.json"

    @property
    def comparison_path(self) -> Path:
        return self.root / "comparison.csv"

    def model_path(self, model_id: str) -> Path:
        if not model_id or "/" in model_id or model_id.startswith("."):
            raise RegistryError(f"invalid model id {model_id!r}")
        return self.models_dir / f"{model_id}.json"

    def meta_path(self, model_id: str) -> Path:
        return self.models_dir / f"{model_id}.meta.json"

    # models
    def save_model(
        self, model_dict: dict, *, source: str | None = None, extra: dict | None = None
    ) -> tuple[Path, bool]:
        """Store ``model_dict`` as ``models/<model_id>.json``; never overwrite.

        The id is recomputed from the content and must equal ``model_dict["model_id"]``.
        If the file exists its content hash is verified and it is left untouched
        (returns ``(path, False)``); a file whose content does not hash to its name is
        a :class:`RegistryError`. Returns ``(path, created)``.
        """
        model_id = model_dict.get("model_id")
        computed = compute_model_id(model_dict)
        if not model_id_verifies(model_dict):
            raise RegistryError(
                f"model_id {model_id!r} does not match its content ({computed}); "
                "refusing to register an edited model"
            )
        path = self.model_path(model_id)
        if path.exists():
            self.load_model_dict(model_id)  # verifies the stored file
            return path, False
        created = write_once(path, json_text(model_dict))
        if not created:  # lost a race: verify what the other writer stored
            self.load_model_dict(model_id)
        meta = {
            "model_id": model_id,
            "machine": model_dict.get("machine") or self.machine,
            "registered": now_iso(),
            "source": source,
            "model_created": model_dict.get("created"),
            "data": model_dict.get("data", {}),
            "config": model_dict.get("config", {}),
            "code_version": {
                "model": model_dict.get("code_version"),
                "registry": f"rafi {__version__}",
                "git_commit": git_commit(),
            },
            **(extra or {}),
        }
        write_once(self.meta_path(model_id), json_text(meta))
        return path, created

    def has_model(self, model_id: str) -> bool:
        return self.model_path(model_id).exists()

    def load_model_dict(self, model_id: str) -> dict:
        """Content of ``models/<model_id>.json``, verified against its name."""
        path = self.model_path(model_id)
        if not path.exists():
            raise RegistryError(f"model {model_id} is not in the registry {self.models_dir}")
        content = json.loads(path.read_text(encoding="utf-8"))
        if content.get("model_id") != model_id or not model_id_verifies(content, model_id):
            raise RegistryError(
                f"{path}: content hashes to {compute_model_id(content)}, not {model_id}; the registry "
                "file was modified"
            )
        return content

    def model_ids(self) -> list[str]:
        if not self.models_dir.is_dir():
            return []
        return sorted(
            p.name[:-5]
            for p in self.models_dir.glob("*.json")
            if not p.name.endswith(".meta.json") and not p.name.startswith(".")
        )

    def resolve(self, prefix: str) -> str:
        """Full model id from a unique prefix (as printed in short form)."""
        hits = [m for m in self.model_ids() if m.startswith(prefix)]
        if len(hits) != 1:
            raise RegistryError(
                f"{len(hits)} registered models of {self.machine} match "
                f"{prefix!r}" + (f": {', '.join(h[:12] for h in hits)}" if hits else "")
            )
        return hits[0]

    # champion
    def champion(self) -> dict | None:
        """The champion pointer (dict with ``model_id``), or None."""
        if not self.champion_path.exists():
            return None
        return json.loads(self.champion_path.read_text(encoding="utf-8"))

    def champion_id(self) -> str | None:
        ch = self.champion()
        return ch.get("model_id") if ch else None

    def set_champion(self, model_id: str, *, reason: str, time: str | None = None) -> dict:
        """Point ``champion.json`` at a registered model (atomic replace)."""
        self.load_model_dict(model_id)  # must exist and verify
        pointer = {
            "schema": CHAMPION_SCHEMA,
            "machine": self.machine,
            "model_id": model_id,
            "path": f"models/{model_id}.json",
            "since": time or now_iso(),
            "reason": reason,
        }
        write_text_atomic(self.champion_path, json_text(pointer))
        return pointer

    # history
    def append_history(self, record: dict) -> None:
        rec = {"schema": HISTORY_SCHEMA, "machine": self.machine, "time": now_iso(), **record}
        append_jsonl(self.history_path, rec)

    def history(self) -> list[dict]:
        return read_jsonl(self.history_path)


def promotion_record(history: list[dict], model_id: str | None) -> dict | None:
    """Latest record that made ``model_id`` champion (promotion or rollback)."""
    if not model_id:
        return None
    for rec in reversed(history):
        if rec.get("champion_id_after") == model_id and rec.get("decision") in ("promoted", "rolled_back"):
            return rec
    return None


def demoted_by_operator(history: list[dict], model_id: str) -> dict | None:
    """The rollback record that demoted ``model_id``, if it came after its last promotion."""
    for rec in reversed(history):
        if (
            rec.get("decision") == "rolled_back"
            and rec.get("champion_id_before") == model_id
            and rec.get("champion_id_after") != model_id
        ):
            return rec
        if rec.get("decision") == "promoted" and rec.get("champion_id_after") == model_id:
            return None
    return None


def promote(
    registry_root: str | os.PathLike,
    machine: str,
    model_id: str,
    *,
    reason: str = "operator rollback",
    decision_path: str | os.PathLike | None = None,
) -> dict:
    """Point the champion at an already registered model (rollback / manual promotion).

    Appends a ``rolled_back`` history record (so the nightly decision does not re-promote
    the demoted model from the same data) and, if ``decision_path`` is given, rewrites
    decision.json so the report shows the manual change (:func:`record_manual_promotion`).
    """
    reg = Registry(Path(registry_root), machine)
    model_id = reg.resolve(model_id)
    prom = promotion_record(reg.history(), model_id) or {}
    reg.load_model_dict(model_id)
    decision = {}
    if decision_path is not None and Path(decision_path).exists():
        with contextlib.suppress(ValueError):
            decision = json.loads(Path(decision_path).read_text(encoding="utf-8"))
    return record_manual_promotion(
        reg, model_id, reason=reason, reference=prom, decision=decision, decision_path=decision_path
    )


def record_manual_promotion(
    reg: Registry,
    model_id: str,
    *,
    reason: str,
    reference: dict,
    said: str | None = None,
    by_hand: dict | None = None,
    decision: dict | None = None,
    decision_path: str | os.PathLike | None = None,
) -> dict:
    """Write a promotion by an operator of the resolved ``model_id``: the ``rolled_back`` line of
    ``history.jsonl``, ``champion.json`` and, with ``decision_path``, ``decision.json`` (``decision``,
    the file as it was, with the manual change over it). The one writer of :func:`promote` and
    ``rafi nightly --promote`` (:func:`rafi.ops.promotion_trail.promote_by_hand`).

    Parameters
    ----------
    reg : Registry
        The machine's registry.
    model_id : str
        The model put in service (full id, registered).
    reason : str
        ``champion.json``'s reason.
    reference : dict
        The record whose drift reference (``candidate_summary``), files (``data_files``) and
        training speeds (``training``) the line keeps: the model's own promotion, else what
        judged it.
    said : str, optional
        The line's reason sentence (default: ``<reason>: champion set to <id> by an operator``).
    by_hand : dict, optional
        The ``by_hand`` block of the line (and, with the model id, of ``decision.json``).
    decision, decision_path
        ``decision.json`` as it was and where it is; without ``decision_path`` it is not written.

    Returns
    -------
    dict
        The ``history.jsonl`` line.
    """
    before = reg.champion_id()
    time = now_iso()
    rec = {
        "decision": "rolled_back",
        "candidate_id": model_id,
        "champion_id_before": before,
        "champion_id_after": model_id,
        "reasons": [said or f"{reason}: champion set to {model_id[:12]} by an operator"],
        # keep the drift reference of the model's own promotion
        "candidate_summary": reference.get("candidate_summary"),
        "data_files": reference.get("data_files"),
        # and the speeds it was trained on (coverage check of the next candidates)
        "training": reference.get("training"),
        **({"by_hand": by_hand} if by_hand is not None else {}),
        "time": time,
    }
    reg.append_history(rec)
    reg.set_champion(model_id, reason=reason, time=time)
    if decision_path is not None:
        new = {
            **(decision or {}),
            "schema": DECISION_SCHEMA,
            "machine": reg.machine,
            "decision": "rolled_back",
            "champion_id_before": before,
            "champion_id_after": model_id,
            "reasons": rec["reasons"],
            "recalibration_due": False,
            **({"by_hand": {"model_id": model_id, **by_hand}} if by_hand is not None else {}),
            "time": time,
        }
        write_text_atomic(Path(decision_path), json_text(new))
    return rec
