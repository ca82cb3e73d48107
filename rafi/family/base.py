"""What every model of the family shares: the estimator conventions and the artefact helpers.

Conventions (those of scikit-learn): ``__init__`` takes keyword arguments only and stores
them as given; a default, where there is one, is read from
:data:`rafi.settings.MACHINE_DEFAULTS`, the defaults of ``rafi/contract/`` (the one place a
setting's default is written).
``fit(runs_table, runs_frame)`` checks the hyperparameters, uses **only** the runs whose
``role`` is ``training`` and is the only method that sets a fitted attribute (name ending in
``_``). ``from_dict`` builds a fitted model from its artefact explicitly: the constructor
with the recorded hyperparameters, then every fitted attribute from the artefact.

Every fitted model of the family has ``grid_edges_``: plain-text flags for hyperparameters
CV chose at an edge of their grid (:func:`rafi.family.grids.edge_flags`; empty for the kinds
without a grid), also recorded in the ridge kinds' artefact as ``selected.grid_edges``.
``fit`` receives the whole runs frame: a model filtering its inputs evaluates them over whole
logs (:mod:`rafi.family.whole_log`) but learns from the ``training`` runs' displacement only.

Artefact (``docs/design.md``): ``schema: rafi.model/1``, a ``kind``, ``model_id`` = SHA-256
of the canonical JSON without ``model_id``/``created`` (:func:`rafi.artefact.compute_model_id`).
"""

from __future__ import annotations

import inspect
from collections.abc import Iterable

import numpy as np
import pandas as pd

from rafi import __version__
from rafi.artefact import compute_model_id, model_id_verifies, now_iso

SCHEMA = "rafi.model/1"
#: ``code_version`` of the family's artefacts: the package version only (no git commit), so
#: the artefact, and with it ``model_id``, depends on the code release and the data alone.
CODE_VERSION = f"rafi {__version__}"


class FamilyModel:
    """Base class of the family's models (``kind`` is set by each subclass)."""

    kind = "family"

    @classmethod
    def _param_names(cls) -> list[str]:
        """The hyperparameters: the keyword arguments of ``__init__``."""
        sig = inspect.signature(cls.__init__)
        return [p.name for p in sig.parameters.values() if p.kind is inspect.Parameter.KEYWORD_ONLY]

    def get_params(self) -> dict:
        """The hyperparameters as given to the constructor."""
        return {name: getattr(self, name) for name in self._param_names()}

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"

    def can_fit(self, runs_table: pd.DataFrame) -> bool:
        """Whether the training runs of ``runs_table`` hold anything this kind learns from."""
        return True

    def predict_detail(self, frame: pd.DataFrame) -> pd.DataFrame:
        """``predicted_um``, ``outside_speed_range``, ``outside_temp_range`` per row of ``frame``."""
        raise NotImplementedError

    def predict(self, frame: pd.DataFrame) -> np.ndarray:
        """Predicted displacement change (um) per row of ``frame``."""
        return self.predict_detail(frame)["predicted_um"].to_numpy()


def finish_artefact(body: dict) -> dict:
    """``body`` with ``schema``, ``created`` (UTC, now) and ``model_id``."""
    out = dict(body)
    out["schema"] = SCHEMA
    out["created"] = now_iso()
    out["model_id"] = compute_model_id(out)
    return out


def check_artefact(d: dict, kind: str) -> None:
    """Raise ``ValueError`` unless ``d`` is an unedited ``rafi.model/1`` artefact of ``kind``."""
    if d.get("schema") != SCHEMA:
        raise ValueError(f"not a {SCHEMA} artefact: schema={d.get('schema')!r}")
    if d.get("kind") != kind:
        raise ValueError(f"artefact kind {d.get('kind')!r}, expected {kind!r}")
    if "model_id" in d and not model_id_verifies(d):
        raise ValueError("model_id does not match the artefact content (edited or corrupted)")


def floats(a) -> list:
    """NumPy array -> nested list of Python floats (exact JSON round trip)."""
    return np.asarray(a, dtype=float).tolist()


def data_hashes(runs_table: pd.DataFrame, run_ids: Iterable[str]) -> dict:
    """``file -> sha256`` of the runs ``run_ids`` (empty where the table has no such columns)."""
    if not {"file", "sha256"} <= set(runs_table.columns):
        return {}
    sub = runs_table[runs_table["run_id"].astype(str).isin(set(map(str, run_ids)))]
    return {str(f): str(h) for f, h in zip(sub["file"], sub["sha256"]) if isinstance(f, str)}
