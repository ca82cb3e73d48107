"""What rule ``decide`` writes besides the decision itself: the parts of ``decision.json`` and
``history.jsonl`` built from tables, and ``registry/comparison.csv``.

Pure functions on frames and dicts (:mod:`rafi.ops.decide` calls them); no I/O.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rafi.ops.gates import col_max, col_min, gated_runs

#: The relative gate's columns of ``registry/comparison.csv`` (:func:`rafi.ops.gates.relative_gate`).
RELATIVE_COLUMNS = [
    "noise_floor_um",
    "margin_um",
    "both_scored",
    "candidate_minus_champion_um",
    "candidate_worse",
]

#: The fields of ``decision.json`` a ``history.jsonl`` line repeats. ``input_warnings`` and
#: ``prior_fitness`` (each confirmed warning with the ``checks.confirmed`` entries that confirm it)
#: keep what a promotion rested on after the next decision replaces ``decision.json``; a line
#: written before them has neither (readers take a missing key for "not recorded").
HISTORY_FIELDS = (
    "candidate_id",
    "champion_id_before",
    "champion_id_after",
    "decision",
    "reasons",
    "gates",
    "gates_passed",
    "blocked_by",
    "measured",
    "candidate_summary",
    "champion_summary",
    "retrained_speeds",
    "adaptation",
    "training",
    "recalibration_due",
    "drift",
    "input_warnings",
    "prior_fitness",
)

#: What ``relative_gate.worse_runs`` of ``decision.json`` says about each run.
WORSE_RUN_FIELDS = (
    "champion_max_abs_after_um",
    "candidate_max_abs_after_um",
    "noise_floor_um",
    "margin_um",
    "candidate_minus_champion_um",
)


def comparison_table(
    runs_table: pd.DataFrame,
    champion_summary: pd.DataFrame | None,
    candidate_summary: pd.DataFrame | None,
    new_run_ids=(),
    relative: pd.DataFrame | None = None,
) -> pd.DataFrame:
    """Per validation run: champion vs candidate max residual and improvement, and the relative
    gate (``relative``, :func:`rafi.ops.gates.relative_gate`): the run's noise floor, the margin,
    whether both models are scored on it, the difference and whether the candidate is worse."""
    cols = [
        "run_id",
        "file",
        "role",
        "speed_rpm",
        "new_since_champion",
        "max_abs_before_um",
        "champion_max_abs_after_um",
        "champion_improvement_pct",
        "candidate_max_abs_after_um",
        "candidate_improvement_pct",
        *RELATIVE_COLUMNS,
    ]
    frames = []
    base = None
    for name, summ in (("champion", champion_summary), ("candidate", candidate_summary)):
        if summ is None or len(summ) == 0:
            continue
        part = (
            summ[["run_id", "max_abs_after_um", "improvement_pct"]]
            .astype({"run_id": str})
            .rename(
                columns={
                    "max_abs_after_um": f"{name}_max_abs_after_um",
                    "improvement_pct": f"{name}_improvement_pct",
                }
            )
        )
        frames.append(part)
        if base is None:
            base = summ[
                [c for c in ("run_id", "role", "speed_rpm", "max_abs_before_um") if c in summ]
            ].astype({"run_id": str})
    if base is None:
        return pd.DataFrame(columns=cols)
    out = base.copy()
    for part in frames:
        out = out.merge(part, on="run_id", how="outer")
    out["run_id"] = out["run_id"].astype(str)
    if {"run_id", "file"} <= set(runs_table.columns):
        files = runs_table[["run_id", "file"]].astype(str).drop_duplicates("run_id")
        out = out.merge(files, on="run_id", how="left")
    new = {str(r) for r in new_run_ids}
    out["new_since_champion"] = out["run_id"].astype(str).isin(new)
    if relative is not None and len(relative):
        out = out.merge(
            relative[["run_id", *RELATIVE_COLUMNS]].astype({"run_id": str}), on="run_id", how="left"
        )
    else:
        floors = [s for s in (candidate_summary, champion_summary) if s is not None and "noise_floor_um" in s]
        if floors:
            f = floors[0][["run_id", "noise_floor_um"]].astype({"run_id": str}).drop_duplicates("run_id")
            out = out.merge(f, on="run_id", how="left")
    for c in ("both_scored", "candidate_worse"):
        out[c] = out[c].fillna(False).astype(bool) if c in out else False
    for c in cols:
        if c not in out:
            out[c] = np.nan
    return out[cols].sort_values("run_id", kind="stable").reset_index(drop=True)


def summary_record(summary: pd.DataFrame | None) -> dict | None:
    """A validation summary as ``decision.json`` states it: ``n_runs``, the worst case over the
    gated runs (``max_residual_um``, ``min_improvement_pct``) and each run's numbers (None
    without a summary)."""
    if summary is None:
        return None
    if len(summary) == 0:
        return {"n_runs": 0, "max_residual_um": None, "min_improvement_pct": None, "runs": {}}
    runs = {}
    for rec in summary.to_dict("records"):
        runs[str(rec["run_id"])] = {
            "max_abs_before_um": rec.get("max_abs_before_um"),
            "max_abs_after_um": rec.get("max_abs_after_um"),
            "improvement_pct": rec.get("improvement_pct"),
            "worse_than_uncompensated": bool(
                float(rec["max_abs_after_um"]) > float(rec["max_abs_before_um"])
            ),
        }
    gated = gated_runs(summary)
    return {
        "n_runs": int(len(summary)),
        "max_residual_um": col_max(gated["max_abs_after_um"]),
        "min_improvement_pct": col_min(gated["improvement_pct"]),
        "runs": runs,
    }


def relative_gate_record(relative: pd.DataFrame, champion_id: str | None, margin) -> dict:
    """``relative_gate`` of ``decision.json`` from the per-run table of
    :func:`rafi.ops.gates.relative_gate`: applied (a champion and a run both are scored on),
    the margin, how many runs both are scored on, passed, and every run where the candidate
    is worse."""
    shared = relative[relative["both_scored"].astype(bool)] if len(relative) else relative
    worse = relative[relative["candidate_worse"].astype(bool)] if len(relative) else relative
    return {
        "applied": champion_id is not None and len(shared) > 0,
        "champion_margin_um": margin,
        "n_runs_both_scored": int(len(shared)),
        "passed": len(worse) == 0,
        "worse_runs": [
            {"run_id": str(r["run_id"]), **{k: r[k] for k in WORSE_RUN_FIELDS}}
            for r in worse.to_dict("records")
        ],
    }


def new_since_promotion(tonight: dict[str, str], known: dict[str, str] | None) -> list[str]:
    """Tonight's files (``file -> sha256``) whose content the champion's promotion did not see
    (``known``: its ``data_files``; none without a promotion record)."""
    if known is None:
        return []
    seen = set(known.values())
    return sorted({file for file, sha in tonight.items() if sha not in seen})


def history_record(record: dict, tonight: dict[str, str], time: str) -> dict:
    """The ``history.jsonl`` line of a decision: :data:`HISTORY_FIELDS` of ``record``, the files
    seen tonight (``data_files``: the next nights' drift check and new-file list), the
    champion's vanished and changed training files, and the time."""
    line = {k: record[k] for k in HISTORY_FIELDS}
    if record.get("candidate_parent"):  # a re-qualified prior: the model it was adapted from
        line["candidate_parent"] = record["candidate_parent"]
        line["candidate_parent_machine"] = record.get("candidate_parent_machine")
    line["data_files"] = tonight
    line["vanished"] = record["data"]["vanished"]
    line["changed"] = record["data"]["changed"]
    line["time"] = time
    return line
