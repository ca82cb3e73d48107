"""Model registry, champion/challenger decision, speed-range adaptation and drift check.

Layout per machine (``results/<machine>/registry/``, see ``docs/operations.md``)::

    models/<model_id>.json       immutable copy of every model ever judged (byte-for-byte the
                                 model.json content; loadable with rafi.method.model.load_model)
    models/<model_id>.meta.json  immutable provenance: data hashes, config, code version
                                 (rafi version + git commit), source path, save time
    champion.json                pointer to the promoted model (replaced atomically)
    history.jsonl                append-only log, one JSON object per line, of every
                                 promotion / rejection / keep / rollback with reasons, gates,
                                 measured values and the data files seen
    decision.json                tonight's decision (declared Snakemake output)
    comparison.csv               champion vs candidate per validation run (declared output)

Everything here except :func:`run_decide` and the :class:`Registry` file methods is pure
(dicts and frames in, dicts and frames out), so it is unit-tested with fake models.
"""

from __future__ import annotations

import contextlib
import copy
import json
import math
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from rafi import __version__
from rafi.artefact import (
    append_jsonl,
    canonical_json,
    compute_model_id,
    git_commit,
    json_text,
    jsonable,
    now_iso,
    read_jsonl,
    replace_atomic,
    write_once,
)
from rafi.errors import IncompatibleModels, RegistryError
from rafi.method.validate import qualify as _qualify
from rafi.method.validate import validate_runs as _validate_runs
from rafi.settings import DEFAULT_GATES, DEFAULT_NIGHTLY, GATE_KEYS, candidate_model_path

__all__ = [
    "RegistryError",
    "Registry",
    "candidate_model_path",
    "canonical_json",
    "compute_model_id",
    "merge_speed_models",
    "gate_outcome",
    "drift_check",
    "new_validation_runs",
    "decide",
    "comparison_table",
    "run_decide",
    "promote",
    "DEFAULT_NIGHTLY",
    "DEFAULT_GATES",
    "now_iso",
]

HISTORY_SCHEMA = "rafi.registry.history/1"
CHAMPION_SCHEMA = "rafi.registry.champion/1"
DECISION_SCHEMA = "rafi.registry.decision/1"

VALIDATION_ROLES = ("validation_single", "validation_multi", "validation_idle")


def gated_runs(summary: pd.DataFrame) -> pd.DataFrame:
    """Validation runs the residual/improvement gates apply to (idle cool-downs get only
    the never-worse gate, as in ``rafi.method.validate.qualify``)."""
    if "role" not in summary:
        return summary
    return summary[summary["role"].astype(str) != "validation_idle"]


# --------------------------------------------------------------------------- ids


# --------------------------------------------------------------------------- paths


def registry_dir(results_dir: str | os.PathLike, machine: str) -> Path:
    """``<results_dir>/<machine>/registry``."""
    return Path(results_dir) / machine / "registry"


# --------------------------------------------------------------------------- low-level files


# --------------------------------------------------------------------------- registry


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
        if model_id != computed:
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
        computed = compute_model_id(content)
        if content.get("model_id") != model_id or computed != model_id:
            raise RegistryError(
                f"{path}: content hashes to {computed}, not {model_id}; the registry file was modified"
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
        replace_atomic(self.champion_path, json_text(pointer))
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


# --------------------------------------------------------------------------- speed-range merge


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


# --------------------------------------------------------------------------- gates


def gate_outcome(summary: pd.DataFrame, verdict: pd.DataFrame, gates: dict) -> tuple[bool, list[str], dict]:
    """Did the candidate pass every gate? Returns ``(passed, reasons, measured)``.

    ``verdict`` is the table of ``qualify``. The never-worse gate is additionally
    checked here run by run from ``summary`` (max|dz - pred| > max|dz| on ANY run
    fails), whatever granularity ``qualify`` reports. No validation run at all fails.
    """
    reasons: list[str] = []
    passed = True
    if summary is None or len(summary) == 0:
        return False, ["no validation runs: the candidate cannot be qualified"], {}
    for rec in verdict.to_dict("records"):
        if not bool(rec.get("passed")):
            passed = False
            run = rec.get("run_id")
            where = (
                f" on run {run}"
                if run is not None and not (isinstance(run, float) and math.isnan(run))
                else ""
            )
            reasons.append(
                f"gate {rec.get('criterion')} failed{where}: measured "
                f"{_fmt(rec.get('measured'))}, limit {_fmt(rec.get('limit'))}"
            )
    worse = []
    if gates.get("never_worse_than_uncompensated", True):
        after = summary["max_abs_after_um"].astype(float)
        before = summary["max_abs_before_um"].astype(float)
        bad = after > before
        if "worse_than_uncompensated" in summary:
            bad = bad | summary["worse_than_uncompensated"].fillna(False).astype(bool)
        worse = summary.loc[bad, "run_id"].astype(str).tolist()
        if worse:
            passed = False
            already = " ".join(reasons)
            for rid in worse:
                if f"never_worse_than_uncompensated failed on run {rid}" not in already:
                    reasons.append(
                        f"gate never_worse_than_uncompensated failed on run {rid}: "
                        "compensated residual larger than uncompensated"
                    )
    gated = gated_runs(summary)
    measured = {
        "max_residual_um": _max(gated["max_abs_after_um"]),
        "min_improvement_pct": _min(gated["improvement_pct"]),
        "worse_than_uncompensated_runs": worse,
        "n_validation_runs": int(len(summary)),
    }
    if passed:
        reasons.append(
            f"passed every gate on {len(summary)} validation run(s): max residual "
            f"{_fmt(measured['max_residual_um'])} um (limit "
            f"{_fmt(gates.get('max_residual_um'))}), min improvement "
            f"{_fmt(measured['min_improvement_pct'])} % (limit "
            f"{_fmt(gates.get('min_improvement_pct'))}), never worse than uncompensated"
        )
    return passed, reasons, measured


def _max(col) -> float | None:
    v = pd.to_numeric(col, errors="coerce").max()
    return None if pd.isna(v) else float(v)


def _min(col) -> float | None:
    v = pd.to_numeric(col, errors="coerce").min()
    return None if pd.isna(v) else float(v)


def _fmt(v) -> str:
    if v is None:
        return "none"
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    return "nan" if math.isnan(f) else f"{f:.3g}"


# --------------------------------------------------------------------------- drift


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


# --------------------------------------------------------------------------- decision


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
        "max_residual_um": _max(gated["max_abs_after_um"]),
        "min_improvement_pct": _min(gated["improvement_pct"]),
        "runs": runs,
    }


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
        float(nightly.get("drift_margin_um", DEFAULT_NIGHTLY["drift_margin_um"])),
    )
    drift["champion_id"] = champion_id
    drift["promoted_at"] = (prom or {}).get("time")
    recal = bool(drift["detected"]) and decision != "promoted"
    if drift["detected"]:
        msg = (
            f"drift: champion {str(champion_id)[:12]} max residual on {len(drift['per_run'])} new "
            f"validation run(s) is {_fmt(drift['new_max_residual_um'])} um vs "
            f"{_fmt(drift['reference_max_residual_um'])} um at promotion (margin "
            f"{_fmt(drift['margin_um'])} um)"
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


# --------------------------------------------------------------------------- I/O driver


def _model_from_dict(d: dict):
    """A predicting model from an artefact dict, of any kind (imported here: the family
    pulls in statsmodels, which the registry itself does not need)."""
    from rafi.family.models import load_any

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

    gates = {k: v for k, v in {**DEFAULT_GATES, **(gates or {})}.items() if k in GATE_KEYS}
    nightly = {**DEFAULT_NIGHTLY, **(nightly or {})}
    validate_runs = validate_runs or _validate_runs
    qualify = qualify or _qualify
    reg = Registry(Path(registry_root), machine)
    runs_table = pd.read_csv(runs_csv)
    runs_frame = pd.read_parquet(runs_parquet)
    history = reg.history()

    fitted = json.loads(Path(candidate_path).read_text(encoding="utf-8"))
    champion_id = reg.champion_id()
    champion_dict = reg.load_model_dict(champion_id) if champion_id else None

    rng = nightly.get("retrain_speed_range_rpm")
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
    replace_atomic(Path(decision_path), json_text(dec.record))
    for r in dec.record["reasons"]:
        log(f"{machine}: {dec.record['decision']}: {r}")
    return dec.record


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
    decision.json so the report shows the manual change.
    """
    reg = Registry(Path(registry_root), machine)
    model_id = reg.resolve(model_id)
    before = reg.champion_id()
    time = now_iso()
    history = reg.history()
    prom = promotion_record(history, model_id) or {}
    rec = {
        "decision": "rolled_back",
        "candidate_id": model_id,
        "champion_id_before": before,
        "champion_id_after": model_id,
        "reasons": [f"{reason}: champion set to {model_id[:12]} by an operator"],
        # keep the drift reference of the model's own promotion
        "candidate_summary": prom.get("candidate_summary"),
        "data_files": prom.get("data_files"),
        "time": time,
    }
    reg.load_model_dict(model_id)
    reg.append_history(rec)
    reg.set_champion(model_id, reason=reason, time=time)
    if decision_path is not None:
        old = {}
        if Path(decision_path).exists():
            with contextlib.suppress(ValueError):
                old = json.loads(Path(decision_path).read_text(encoding="utf-8"))
        new = {
            **old,
            "schema": DECISION_SCHEMA,
            "machine": machine,
            "decision": "rolled_back",
            "champion_id_before": before,
            "champion_id_after": model_id,
            "reasons": rec["reasons"],
            "recalibration_due": False,
            "time": time,
        }
        replace_atomic(Path(decision_path), json_text(new))
    return rec
