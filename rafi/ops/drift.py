"""Drift check: has the champion in service degraded on the validation logs it has not seen?"""

from __future__ import annotations

from collections.abc import Iterable

import pandas as pd

from rafi.ops.gates import gated_runs

VALIDATION_ROLES = ("validation_single", "validation_multi", "validation_idle")


def validation_runs(runs_table: pd.DataFrame) -> pd.DataFrame:
    if "role" not in runs_table:
        return runs_table.iloc[0:0]
    return runs_table[runs_table["role"].astype(str).isin(VALIDATION_ROLES)]


def new_validation_runs(runs_table: pd.DataFrame, known_files: dict | None) -> list[str]:
    """Validation runs whose file (by sha256, else by name) was not known at promotion."""
    if known_files is None:
        return []
    val = validation_runs(runs_table)
    hashes = set(known_files.values())
    names = set(known_files)
    new = []
    for rec in val.to_dict("records"):
        sha = rec.get("sha256")
        if isinstance(sha, str) and sha:
            is_new = sha not in hashes
        else:
            is_new = str(rec.get("file")) not in names
        if is_new:
            new.append(str(rec["run_id"]))
    return new


def drift_check(
    champion_summary: pd.DataFrame | None,
    new_run_ids: Iterable[str],
    reference_max_residual_um: float | None,
    margin_um: float,
) -> dict:
    """Has the champion degraded on the newest validation logs?

    ``new_max`` = champion's largest max|residual| over ``new_run_ids``; drift is
    detected when ``new_max > reference + margin`` where ``reference`` is the
    champion's max residual at promotion time (from the history).
    Returns a dict with ``status`` (ok / degraded / no_new_runs / no_reference /
    no_champion), ``detected`` and the numbers.
    """
    new_run_ids = [str(r) for r in new_run_ids]
    out = {
        "status": "ok",
        "detected": False,
        "margin_um": float(margin_um),
        "reference_max_residual_um": reference_max_residual_um,
        "new_runs": new_run_ids,
        "new_max_residual_um": None,
        "limit_um": None,
        "degradation_um": None,
        "per_run": {},
    }
    if champion_summary is None:
        out["status"] = "no_champion"
        return out
    if not new_run_ids:
        out["status"] = "no_new_runs"
        return out
    rows = gated_runs(champion_summary)
    rows = rows[rows["run_id"].astype(str).isin(new_run_ids)]
    if rows.empty:
        out["status"] = "no_new_runs"
        return out
    per_run = {str(r): float(v) for r, v in zip(rows["run_id"], rows["max_abs_after_um"])}
    new_max = max(per_run.values())
    out["per_run"] = per_run
    out["new_max_residual_um"] = new_max
    if reference_max_residual_um is None:
        out["status"] = "no_reference"
        return out
    ref = float(reference_max_residual_um)
    out["limit_um"] = ref + float(margin_um)
    out["degradation_um"] = new_max - ref
    if new_max > ref + float(margin_um):
        out["status"] = "degraded"
        out["detected"] = True
    return out
