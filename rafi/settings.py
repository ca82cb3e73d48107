"""Settings (standard library only)."""

from __future__ import annotations

import os

#: Defaults of ``nightly:`` (config.yaml, top level or per machine).
DEFAULT_NIGHTLY = {
    "candidate": "fit",  # fit | family: which file is tonight's candidate
    "retrain_speed_range_rpm": None,  # [lo, hi]: only these speeds come from the new fit
    "drift_margin_um": 2.0,  # champion max residual may grow this much on new logs
}


#: Defaults of ``qualification:`` (the promotion gates).
DEFAULT_GATES = {
    "max_residual_um": 12.0,
    "min_improvement_pct": 30.0,
    "never_worse_than_uncompensated": True,
}


GATE_KEYS = ("max_residual_um", "min_improvement_pct", "never_worse_than_uncompensated")


def candidate_model_path(
    machine: str, results_dir: str | os.PathLike = "results", source: str = "fit"
) -> str:
    """Path of tonight's candidate model of ``machine``.

    ``source`` is ``nightly.candidate`` from the config:

    * ``fit`` (default): ``<results>/<machine>/model.json``, written by rule ``fit``;
    * ``family``: ``<results>/<machine>/comparison/best_model.json``, the best model of the
      model family (``rafi.family.models``), which must be a ``rafi.model/1`` artefact.

    The decision is made at DAG-build time from the config (not from which files happen
    to exist), so the rule graph is the same on a fresh checkout and after a run.
    """
    if source == "fit":
        return f"{results_dir}/{machine}/model.json"
    if source == "family":
        return f"{results_dir}/{machine}/comparison/best_model.json"
    raise ValueError(f"nightly.candidate is {source!r}; expected 'fit' or 'family'")
