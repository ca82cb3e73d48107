"""Champion / challenger: judge tonight's candidate against the champion and record the decision.

:func:`decide` is pure (dicts and frames in, a :class:`Decision` out), so it is unit-tested with
fake models; :func:`run_decide` is rule ``decide``: it reads the candidate and the runs,
evaluates both models, and updates the registry (``rafi.ops.registry``).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from rafi.artefact import json_text, jsonable, now_iso, write_text_atomic
from rafi.errors import IncompatibleModels
from rafi.method.validate import qualify as _qualify
from rafi.method.validate import validate_runs as _validate_runs
from rafi.ops.adapt import merge_speed_models, retrained_speed_info, speeds_from
from rafi.ops.drift import drift_check, new_validation_runs
from rafi.ops.gates import (
    col_max,
    col_min,
    fmt_value,
    gate_outcome,
    gated_runs,
    relative_gate,
    relative_reasons,
)
from rafi.ops.provenance import (
    champion_speeds,
    coverage_reasons,
    data_change_reasons,
    files_of,
    input_warnings,
    speed_coverage,
    trained_speeds,
    training_data_changes,
    warning_reason,
)
from rafi.ops.registry import DECISION_SCHEMA, Registry, demoted_by_operator, promotion_record
from rafi.settings import GATE_KEYS

RELATIVE_COLUMNS = [
    "noise_floor_um",
    "margin_um",
    "both_scored",
    "candidate_minus_champion_um",
    "candidate_worse",
]


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


def _summary_record(summary: pd.DataFrame | None) -> dict | None:
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


@dataclass
class Decision:
    """Result of :func:`decide`: the decision record, the comparison table and the history line."""

    record: dict
    comparison: pd.DataFrame
    history: dict = field(default_factory=dict)


def decide(
    *,
    machine: str,
    candidate_dict: dict,
    candidate_summary: pd.DataFrame,
    candidate_verdict: pd.DataFrame,
    champion_id: str | None,
    champion_summary: pd.DataFrame | None,
    runs_table: pd.DataFrame,
    gates: dict,
    nightly: dict,
    history: list[dict],
    retrained_speeds: list[dict] | None = None,
    adaptation: dict | None = None,
    champion_dict: dict | None = None,
    speed_tolerance_rpm: float = 50.0,
    input_status: dict | None = None,
    time: str | None = None,
) -> Decision:
    """Champion / challenger decision (pure).

    * candidate identical to the champion -> ``kept`` (nothing to promote);
    * candidate was demoted by an operator rollback after its last promotion -> ``kept``
      (a rolled-back model is not re-promoted until the data change);
    * candidate passes every absolute gate (``gates``) and, with a champion, the relative
      gate (not worse than the champion on any validation run both are scored on by more than
      ``nightly.champion_margin_um``) and the coverage check (its training covers every speed
      the champion's did, within ``speed_tolerance_rpm``), and no unconfirmed input warning of
      ``input_status`` is on a file tonight's data uses -> ``promoted``;
    * otherwise -> ``rejected`` (champion, if any, stays).

    ``champion_dict`` is the champion's artefact (its training speeds and files); the
    champion's training files gone from or changed in tonight's data are reported in
    ``data.vanished`` / ``data.changed`` (reasons too), without blocking. The drift check
    always runs on the champion in service before tonight.
    """
    time = time or now_iso()
    cand_id = candidate_dict["model_id"]
    passed, reasons, measured = gate_outcome(candidate_summary, candidate_verdict, gates)
    prom = promotion_record(history, champion_id)
    tonight = files_of(runs_table)
    status = input_status or {}

    # relative to the champion in service (issue 13 item 4)
    margin = nightly.get("champion_margin_um", "noise")
    rel = pd.DataFrame(columns=["run_id", *RELATIVE_COLUMNS])
    rel_lines: list[str] = []
    if champion_id is not None:
        rel = relative_gate(champion_summary, candidate_summary, margin)
        rel_lines = relative_reasons(rel, champion_id, margin)
    worse = rel[rel["candidate_worse"].astype(bool)] if len(rel) else rel
    cand_training = trained_speeds(candidate_dict, runs_table)
    champ_training = champion_speeds(champion_dict, prom, runs_table) if champion_id is not None else None
    cov = speed_coverage(champ_training, cand_training, speed_tolerance_rpm)
    champ_data = (champion_dict or {}).get("data") or (prom or {}).get("data_files") or {}
    changes = training_data_changes(
        champ_data if champion_id is not None else {}, tonight, status.get("rejected"), status.get("usable")
    )
    warns = input_warnings(status, tonight)
    blocked_by = [
        name
        for name, hit in (
            ("relative_gate", len(worse) > 0),
            ("coverage", cov["blocking"]),
            ("input_warnings", bool(warns["blocking"])),
        )
        if hit
    ]
    blockers = coverage_reasons(cov, champion_id) + [warning_reason(w) for w in warns["blocking"]]

    if champion_id is not None and cand_id == champion_id:
        decision, reasons = (
            "kept",
            [f"candidate {cand_id[:12]} is the champion already (no new training data changed the model)"],
        )
    elif champion_id is not None and (rb := demoted_by_operator(history, cand_id)):
        decision = "kept"
        reasons = [
            f"candidate {cand_id[:12]} was rolled back by an operator at "
            f"{rb.get('time')}; not re-promoted until new data change it"
        ] + reasons
    elif passed and not blocked_by:
        decision = "promoted"
        reasons = reasons + rel_lines
    else:
        decision = "rejected"
        reasons = reasons + rel_lines + blockers
        if champion_id:
            reasons = reasons + [f"champion {champion_id[:12]} stays"]
        else:
            reasons = reasons + ["no champion yet: the machine has no qualified model"]
    reasons += data_change_reasons(changes, champion_id)
    champion_after = cand_id if decision == "promoted" else champion_id

    # drift of the champion in service
    known = (prom or {}).get("data_files")
    new_runs = new_validation_runs(runs_table, known) if prom else []
    ref = None
    if prom:
        ref = (prom.get("candidate_summary") or {}).get("max_residual_um")
    drift = drift_check(
        champion_summary,
        new_runs,
        ref,
        float(nightly["drift_margin_um"]),
    )
    drift["champion_id"] = champion_id
    drift["promoted_at"] = (prom or {}).get("time")
    recal = bool(drift["detected"]) and decision != "promoted"
    if drift["detected"]:
        msg = (
            f"drift: champion {str(champion_id)[:12]} max residual on {len(drift['per_run'])} new "
            f"validation run(s) is {fmt_value(drift['new_max_residual_um'])} um vs "
            f"{fmt_value(drift['reference_max_residual_um'])} um at promotion (margin "
            f"{fmt_value(drift['margin_um'])} um)"
        )
        msg += (
            "; resolved by tonight's promotion"
            if decision == "promoted"
            else "; recalibration due (new training runs needed)"
        )
        reasons.append(msg)

    new_files = sorted({f for f, h in tonight.items() if known is not None and h not in set(known.values())})
    shared = rel[rel["both_scored"].astype(bool)] if len(rel) else rel
    relative = {
        "applied": champion_id is not None and len(shared) > 0,
        "champion_margin_um": margin,
        "n_runs_both_scored": int(len(shared)),
        "passed": len(worse) == 0,
        "worse_runs": [
            {
                "run_id": str(r["run_id"]),
                "champion_max_abs_after_um": r["champion_max_abs_after_um"],
                "candidate_max_abs_after_um": r["candidate_max_abs_after_um"],
                "noise_floor_um": r["noise_floor_um"],
                "margin_um": r["margin_um"],
                "candidate_minus_champion_um": r["candidate_minus_champion_um"],
            }
            for r in worse.to_dict("records")
        ],
    }
    record = {
        "schema": DECISION_SCHEMA,
        "machine": machine,
        "candidate_id": cand_id,
        "champion_id_before": champion_id,
        "champion_id_after": champion_after,
        "decision": decision,
        "reasons": reasons,
        "gates": dict(gates),
        "gates_passed": bool(passed),
        "blocked_by": blocked_by,
        "measured": measured,
        "verdict": jsonable(candidate_verdict.to_dict("records")) if candidate_verdict is not None else [],
        "candidate_summary": _summary_record(candidate_summary),
        "champion_summary": _summary_record(champion_summary),
        "relative_gate": relative,
        "coverage": cov,
        "input_warnings": warns,
        "retrained_speeds": retrained_speeds or [],
        "adaptation": adaptation or {"retrain_speed_range_rpm": None, "mode": "full"},
        "training": cand_training,
        "data": {
            "files": tonight,
            "new_since_champion": new_files,
            "candidate_data": candidate_dict.get("data", {}),
            "champion_data": champ_data if champion_id is not None else {},
            **changes,
        },
        "recalibration_due": recal,
        "drift": drift,
        "time": time,
    }
    hist = {
        k: record[k]
        for k in (
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
        )
    }
    hist["data_files"] = tonight
    hist["vanished"] = changes["vanished"]
    hist["changed"] = changes["changed"]
    hist["time"] = time
    comp = comparison_table(runs_table, champion_summary, candidate_summary, new_runs, rel)
    return Decision(record=jsonable(record), comparison=comp, history=jsonable(hist))


def _model_from_dict(d: dict):
    """A predicting model from an artefact dict, of any kind (imported here: the family
    pulls in statsmodels, which the registry itself does not need)."""
    from rafi.family.compare import load_any

    return load_any(d)


def _summary_only(result):
    return result[0] if isinstance(result, tuple) else result


def run_decide(
    *,
    machine: str,
    candidate_path: str | os.PathLike,
    runs_csv: str | os.PathLike,
    runs_parquet: str | os.PathLike,
    registry_root: str | os.PathLike,
    decision_path: str | os.PathLike,
    comparison_path: str | os.PathLike,
    gates: dict,
    nightly: dict,
    log: Callable[[str], None] = print,
    candidate_summary_path: str | os.PathLike | None = None,
    model_from_dict: Callable[[dict], Any] = _model_from_dict,
    validate_runs: Callable | None = None,
    qualify: Callable | None = None,
    input_status_path: str | os.PathLike | None = None,
    speed_tolerance_rpm: float = 50.0,
) -> dict:
    """Judge tonight's candidate, update the registry, write decision.json + comparison.csv.

    ``candidate_summary_path``: ``validation/summary.csv`` of the fitted model; reused when
    the candidate is that model (no speed-range merge), so it is not evaluated twice.
    ``input_status_path``: the machine's ``input_status.json`` (its ``warnings`` block
    promotion until confirmed; its ``rejected`` files explain a vanished training file).
    ``speed_tolerance_rpm``: the machine's speed tolerance (coverage of the champion's speeds).

    Order of writes (each atomic): models/<id>.json (write-once) -> history.jsonl (append)
    -> champion.json (replace, only on promotion) -> comparison.csv -> decision.json. The
    declared outputs come last so they are newer than champion.json (no spurious re-run),
    and a crash leaves at worst a history line whose pointer update is repeated next night.
    """
    from rafi.artefact import write_csv_atomic  # local: keeps the pure part importable without pyarrow

    gates = {k: gates[k] for k in GATE_KEYS}  # the machine's resolved settings: every key present
    validate_runs = validate_runs or _validate_runs
    qualify = qualify or _qualify
    reg = Registry(Path(registry_root), machine)
    runs_table = pd.read_csv(runs_csv)
    runs_frame = pd.read_parquet(runs_parquet)
    history = reg.history()
    input_status = None
    if input_status_path is not None and Path(input_status_path).exists():
        input_status = json.loads(Path(input_status_path).read_text(encoding="utf-8"))

    fitted = json.loads(Path(candidate_path).read_text(encoding="utf-8"))
    champion_id = reg.champion_id()
    champion_dict = reg.load_model_dict(champion_id) if champion_id else None

    rng = nightly["retrain_speed_range_rpm"]
    candidate = fitted
    adaptation = {"retrain_speed_range_rpm": rng, "mode": "full", "fitted_id": fitted["model_id"]}
    if rng is not None and champion_dict is not None:
        lo, hi = (list(rng) + [None, None])[:2]
        try:
            candidate = merge_speed_models(fitted, champion_dict, lo, hi)
            adaptation.update(mode="speed_range", kept_from=champion_id)
        except IncompatibleModels as exc:
            adaptation.update(
                mode="full",
                note=f"speed-range adaptation impossible: {exc}; the full new fit is the candidate",
            )
    elif rng is not None:
        adaptation["note"] = "no champion yet: the full new fit is the candidate"
    retrained = [] if candidate["model_id"] == champion_id else speeds_from(candidate, fitted)
    adaptation["retrained_speeds_rpm"] = retrained
    log(
        f"{machine}: candidate {candidate['model_id'][:12]} ({adaptation['mode']}), "
        f"champion {str(champion_id)[:12] if champion_id else 'none'}"
    )

    if (
        candidate_summary_path is not None
        and candidate["model_id"] == fitted["model_id"]
        and Path(candidate_summary_path).exists()
    ):
        # the fitted model itself: rule validate already evaluated it on these runs
        cand_summary = pd.read_csv(candidate_summary_path)
    else:
        cand_summary = _summary_only(validate_runs(model_from_dict(candidate), runs_table, runs_frame))
    verdict = qualify(cand_summary, gates)
    champ_summary = None
    if champion_id is not None and champion_id == candidate["model_id"]:
        champ_summary = cand_summary
    elif champion_dict is not None:
        champ_summary = _summary_only(validate_runs(model_from_dict(champion_dict), runs_table, runs_frame))
    dec = decide(
        machine=machine,
        candidate_dict=candidate,
        candidate_summary=cand_summary,
        candidate_verdict=verdict,
        champion_id=champion_id,
        champion_summary=champ_summary,
        runs_table=runs_table,
        gates=gates,
        nightly=nightly,
        history=history,
        retrained_speeds=retrained_speed_info(candidate, retrained, runs_table),
        adaptation=adaptation,
        champion_dict=champion_dict,
        speed_tolerance_rpm=speed_tolerance_rpm,
        input_status=input_status,
    )

    reg.save_model(candidate, source=str(candidate_path), extra={"adaptation": adaptation})
    reg.append_history(dec.history)
    if dec.record["decision"] == "promoted":
        reg.set_champion(
            candidate["model_id"], reason="promoted by nightly decision", time=dec.record["time"]
        )
    write_csv_atomic(dec.comparison, comparison_path)
    write_text_atomic(Path(decision_path), json_text(dec.record))
    for r in dec.record["reasons"]:
        log(f"{machine}: {dec.record['decision']}: {r}")
    return dec.record
