"""Speed-range adaptation (paper, item 10): retrain only the per-speed models in a speed range."""

from __future__ import annotations

import copy
from collections.abc import Iterable

import pandas as pd

from rafi.artefact import canonical_json, compute_model_id
from rafi.errors import IncompatibleModels


def _in_range(speed, lo, hi) -> bool:
    return (lo is None or float(speed) >= float(lo)) and (hi is None or float(speed) <= float(hi))


def merge_speed_models(candidate_dict: dict, champion_dict: dict, lo, hi) -> dict:
    """Speed-range adaptation (paper item 10): retrain only the speeds in ``[lo, hi]``.

    Returns a new model dict whose per-speed models inside ``[lo, hi]`` (inclusive)
    come from ``candidate_dict`` and all others from ``champion_dict`` (a speed only
    the candidate has is taken from it). ``data`` is the union of both (the merged
    model depends on both data sets); everything else (sensors, terms, config, code
    version) is the candidate's. ``model_id`` is recomputed, ``created`` kept from
    the candidate. ``lo``/``hi`` may be None (open end).

    Raises
    ------
    IncompatibleModels
        If key sensors, terms or reference state differ: the coefficients would then
        refer to different regressors.
    """
    for key in ("kind", "key_sensors", "terms", "reference"):
        if candidate_dict.get(key) != champion_dict.get(key):
            raise IncompatibleModels(
                f"{key} differ (candidate {candidate_dict.get(key)!r}, champion "
                f"{champion_dict.get(key)!r}); per-speed models cannot be mixed"
            )
    if not candidate_dict.get("speeds") or not champion_dict.get("speeds"):
        raise IncompatibleModels(
            "a model has no per-speed models ('speeds'); only kind 'rafi' "
            "models can be adapted speed by speed"
        )
    cand = {float(s["speed_rpm"]): s for s in candidate_dict.get("speeds", [])}
    champ = {float(s["speed_rpm"]): s for s in champion_dict.get("speeds", [])}
    speeds = []
    for sp in sorted(set(cand) | set(champ)):
        if sp in cand and (_in_range(sp, lo, hi) or sp not in champ):
            speeds.append(copy.deepcopy(cand[sp]))
        else:
            speeds.append(copy.deepcopy(champ[sp]))
    merged = copy.deepcopy(candidate_dict)
    merged["speeds"] = speeds
    merged["data"] = {**(champion_dict.get("data") or {}), **(candidate_dict.get("data") or {})}
    merged.pop("model_id", None)
    merged["model_id"] = compute_model_id(merged)
    return merged


def speeds_from(merged: dict, candidate: dict) -> list[float]:
    """Speeds of ``merged`` whose per-speed model is the candidate's (retrained tonight)."""
    cand = {float(s["speed_rpm"]): canonical_json(s) for s in candidate.get("speeds", [])}
    return [
        s["speed_rpm"]
        for s in merged.get("speeds", [])
        if cand.get(float(s["speed_rpm"])) == canonical_json(s)
    ]


def retrained_speed_info(model_dict: dict, speeds: Iterable[float], runs_table: pd.DataFrame) -> list[dict]:
    """``[{speed_rpm, train_runs, files}]`` for the given speeds of ``model_dict``."""
    wanted = {float(s) for s in speeds}
    file_of = {}
    if {"run_id", "file"} <= set(runs_table.columns):
        file_of = dict(zip(runs_table["run_id"].astype(str), runs_table["file"].astype(str)))
    out = []
    for sp in model_dict.get("speeds", []):
        if float(sp["speed_rpm"]) in wanted:
            runs = [str(r) for r in sp.get("train_runs", [])]
            out.append(
                {
                    "speed_rpm": sp["speed_rpm"],
                    "train_runs": runs,
                    "files": sorted({file_of[r] for r in runs if r in file_of}),
                }
            )
    return out
