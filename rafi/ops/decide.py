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
from rafi.ops.gates import col_max, col_min, fmt_value, gate_outcome, gated_runs
from rafi.ops.registry import DECISION_SCHEMA, Registry, demoted_by_operator, promotion_record
from rafi.settings import GATE_KEYS


def comparison_table(
    runs_table: pd.DataFrame,
    champion_summary: pd.DataFrame | None,
    candidate_summary: pd.DataFrame | None,
    new_run_ids=(),
) -> pd.DataFrame:
    """Per validation run: champion vs candidate max residual and improvement."""
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
    time: str | None = None,
) -> Decision:
    """Champion / challenger decision (pure).

    * candidate identical to the champion -> ``kept`` (nothing to promote);
    * candidate was demoted by an operator rollback after its last promotion -> ``kept``
      (a rolled-back model is not re-promoted until the data change);
    * candidate passes every gate -> ``promoted``;
    * otherwise -> ``rejected`` (champion, if any, stays).

    The drift check always runs on the champion in service before tonight.
    """
    time = time or now_iso()
    cand_id = candidate_dict["model_id"]
    passed, reasons, measured = gate_outcome(candidate_summary, candidate_verdict, gates)
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
    elif passed:
        decision = "promoted"
    else:
        decision = "rejected"
        if champion_id:
            reasons = reasons + [f"champion {champion_id[:12]} stays"]
        else:
            reasons = reasons + ["no champion yet: the machine has no qualified model"]
    champion_after = cand_id if decision == "promoted" else champion_id

    # drift of the champion in service
    prom = promotion_record(history, champion_id)
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

    data_files = {}
    if {"file", "sha256"} <= set(runs_table.columns):
        data_files = dict(zip(runs_table["file"].astype(str), runs_table["sha256"].astype(str)))
    new_files = sorted(
        {f for f, h in data_files.items() if known is not None and h not in set(known.values())}
    )
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
        "measured": measured,
        "verdict": jsonable(candidate_verdict.to_dict("records")) if candidate_verdict is not None else [],
        "candidate_summary": _summary_record(candidate_summary),
        "champion_summary": _summary_record(champion_summary),
        "retrained_speeds": retrained_speeds or [],
        "adaptation": adaptation or {"retrain_speed_range_rpm": None, "mode": "full"},
        "data": {
            "files": data_files,
            "new_since_champion": new_files,
            "candidate_data": candidate_dict.get("data", {}),
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
            "measured",
            "candidate_summary",
            "champion_summary",
            "retrained_speeds",
            "adaptation",
            "recalibration_due",
            "drift",
        )
    }
    hist["data_files"] = data_files
    hist["time"] = time
    comp = comparison_table(runs_table, champion_summary, candidate_summary, new_runs)
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
) -> dict:
    """Judge tonight's candidate, update the registry, write decision.json + comparison.csv.

    ``candidate_summary_path``: ``validation/summary.csv`` of the fitted model; reused when
    the candidate is that model (no speed-range merge), so it is not evaluated twice.

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
