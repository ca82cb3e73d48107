"""Champion / challenger: judge tonight's candidate against the champion and record the decision.

:func:`decide` is pure (a :class:`Candidate`, a :class:`Champion`, the runs and the
:class:`DecisionSettings` in, a :class:`Decision` out), so it is unit-tested with fake models. Its
steps are functions of their own: the candidate's gates (:func:`rafi.ops.gates.gate_outcome`), the
comparison with the champion (:func:`compare_with_champion`), provenance (:func:`check_provenance`),
what blocks (:func:`blocking_checks`), the decision (:func:`promotion_decision`), the champion's
drift (:func:`rafi.ops.drift.champion_drift`) and the record (:mod:`rafi.ops.decision_record`).

:func:`run_decide` is rule ``decide``: it reads the candidate and the runs, makes tonight's
candidate (:func:`tonight_candidate`: the fit, or the champion with a speed range retrained),
evaluates both models, and updates the registry (``rafi.ops.registry``).
"""

from __future__ import annotations

import functools
import json
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from rafi.artefact import json_text, jsonable, now_iso, write_text_atomic
from rafi.errors import IncompatibleModels
from rafi.family.confirmation import awaiting_confirmation
from rafi.family.intervals import interval_columns
from rafi.family.prior import parent_of, registry_meta
from rafi.method.validate import qualify as _qualify
from rafi.method.validate import validate_runs
from rafi.ops.adapt import merge_speed_models, retrained_speed_info, speeds_from
from rafi.ops.decision_record import (
    RELATIVE_COLUMNS,
    comparison_table,
    history_record,
    new_since_promotion,
    relative_gate_record,
    summary_record,
)
from rafi.ops.drift import champion_drift, drift_reason, interval_drift_reason
from rafi.ops.gates import gate_outcome, relative_gate, relative_reasons
from rafi.ops.provenance import (
    champion_speeds,
    coverage_reasons,
    data_change_reasons,
    files_of,
    input_warnings,
    prior_warning_reason,
    prior_warnings,
    speed_coverage,
    trained_speeds,
    training_data_changes,
    warning_reason,
    with_prior_speeds,
)
from rafi.ops.registry import DECISION_SCHEMA, Registry, demoted_by_operator, promotion_record
from rafi.ops.status import drift_detected
from rafi.settings import GATE_KEYS


@dataclass(frozen=True, eq=False)
class Candidate:
    """Tonight's candidate, as judged.

    Attributes
    ----------
    model : dict
        Its artefact (``model_id``, ``data``, ``speeds`` or ``train_runs``).
    summary : pandas.DataFrame
        Its validation summary (:func:`rafi.method.validate.validate_runs`).
    verdict : pandas.DataFrame
        ``qualify``'s verdict on ``summary`` (one row per gate and validation run).
    retrained_speeds : list of dict, optional
        The speeds a speed-range adaptation took from tonight's fit
        (:func:`rafi.ops.adapt.retrained_speed_info`).
    adaptation : dict, optional
        How the candidate was made (``mode`` ``full`` or ``speed_range``, see :func:`tonight_candidate`).
    """

    model: dict
    summary: pd.DataFrame
    verdict: pd.DataFrame
    retrained_speeds: list[dict] | None = None
    adaptation: dict | None = None

    @property
    def model_id(self) -> str:
        return self.model["model_id"]


@dataclass(frozen=True, eq=False)
class Champion:
    """The champion in service before tonight (``model_id`` None: the machine has none yet).

    Attributes
    ----------
    model_id : str or None
        Its id (``registry/champion.json``).
    summary : pandas.DataFrame or None
        Its validation summary on tonight's runs.
    model : dict or None
        Its artefact (its training speeds and files).
    verdict : pandas.DataFrame or None
        :func:`rafi.method.validate.qualify` of ``summary`` (stored as ``champion_verdict``, so
        the report reads the champion's gates instead of judging them again).
    residuals : pandas.DataFrame or None
        Its residuals on tonight's validation runs, sample by sample (with ``lower_um`` and
        ``upper_um`` when its artefact has an interval): the interval drift test reads them.
    """

    model_id: str | None = None
    summary: pd.DataFrame | None = None
    model: dict | None = None
    verdict: pd.DataFrame | None = None
    residuals: pd.DataFrame | None = None


@dataclass(frozen=True)
class DecisionSettings:
    """The machine's settings a decision follows.

    Attributes
    ----------
    gates : mapping
        ``qualification:`` (the absolute gates).
    nightly : mapping
        ``nightly:`` (``champion_margin_um``: the relative gate's margin, a number or
        ``"noise"``; ``drift_margin_um``; ``drift_false_alarm``).
    speed_tolerance_rpm : float
        Coverage of the champion's training speeds: within this many r/min.
    confirmed : tuple of mapping
        ``checks.confirmed``: the warnings a person has looked at (here: a prior's fitness
        warnings, :func:`rafi.ops.provenance.prior_warnings`).
    """

    gates: Mapping[str, Any]
    nightly: Mapping[str, Any]
    speed_tolerance_rpm: float = 50.0
    confirmed: tuple = ()

    @property
    def champion_margin(self):
        """``nightly.champion_margin_um`` (``"noise"`` when not set)."""
        return self.nightly.get("champion_margin_um", "noise")


@dataclass
class Decision:
    """Result of :func:`decide`: the decision record, the comparison table and the history line."""

    record: dict
    comparison: pd.DataFrame
    history: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class ChampionComparison:
    """The candidate against the champion run by run (:func:`compare_with_champion`).

    Attributes
    ----------
    table : pandas.DataFrame
        :func:`rafi.ops.gates.relative_gate` (empty without a champion).
    reasons : list of str
        Its reason lines (none without a champion).
    margin : float or str
        ``nightly.champion_margin_um``.
    """

    table: pd.DataFrame
    reasons: list[str]
    margin: Any

    @property
    def worse(self) -> pd.DataFrame:
        """The runs where the candidate is worse than the champion by more than the margin."""
        return self.table[self.table["candidate_worse"].astype(bool)] if len(self.table) else self.table


@dataclass(frozen=True)
class Provenance:
    """What the candidate and the champion were trained on, and tonight's input (:func:`check_provenance`).

    Attributes
    ----------
    tonight : dict
        ``file -> sha256`` of the files tonight's runs come from.
    candidate_training : dict
        :func:`rafi.ops.provenance.trained_speeds` of the candidate.
    coverage : dict
        :func:`rafi.ops.provenance.speed_coverage` of the champion's speeds.
    champion_data : dict
        The champion's training files (``file -> sha256``; empty without a champion).
    changes : dict
        :func:`rafi.ops.provenance.training_data_changes` of those files.
    warnings : dict
        :func:`rafi.ops.provenance.input_warnings` of tonight's input status.
    prior : dict
        :func:`rafi.ops.provenance.prior_warnings` of the candidate (an adapted prior's fitness).
    """

    tonight: dict
    candidate_training: dict
    coverage: dict
    champion_data: dict
    changes: dict
    warnings: dict
    prior: dict = field(default_factory=lambda: {"blocking": [], "confirmed": []})


@dataclass(frozen=True)
class Blocking:
    """The checks that stop a candidate passing every gate from being promoted (:func:`blocking_checks`).

    Attributes
    ----------
    names : list of str
        ``blocked_by`` of ``decision.json``: ``relative_gate``, ``coverage``, ``input_warnings``,
        ``prior_fitness``.
    reasons : list of str
        The reason lines of the coverage, the input warnings and the prior's fitness warnings
        (the relative gate has its own).
    """

    names: list[str]
    reasons: list[str]


def compare_with_champion(champion: Champion, candidate_summary: pd.DataFrame, margin) -> ChampionComparison:
    """The relative gate (issue 13 item 4): the candidate against the champion in service, on every
    validation run both are scored on (:func:`rafi.ops.gates.relative_gate`); nothing to compare
    without a champion."""
    if champion.model_id is None:
        return ChampionComparison(pd.DataFrame(columns=["run_id", *RELATIVE_COLUMNS]), [], margin)
    table = relative_gate(champion.summary, candidate_summary, margin)
    return ChampionComparison(table, relative_reasons(table, champion.model_id, margin), margin)


def check_provenance(
    candidate_model: dict,
    champion: Champion,
    promotion: dict | None,
    runs_table: pd.DataFrame,
    input_status: dict | None,
    speed_tolerance_rpm: float,
    *,
    confirmed=(),
) -> Provenance:
    """What the candidate was trained on against what the champion was, and tonight's input.

    The champion's training speeds come from its artefact, else its ``promotion`` record
    (:func:`rafi.ops.provenance.champion_speeds`), its training files from its artefact's
    ``data``, else the promotion's ``data_files``. ``input_status`` (``input_status.json``)
    says why a training file is missing and carries the input warnings; ``confirmed``
    (``checks.confirmed``) confirms a prior's fitness warnings and names the entries that confirm
    each confirmed warning (``confirmed_by``).
    """
    tonight = files_of(runs_table)
    status = input_status or {}
    candidate_training = trained_speeds(candidate_model, runs_table)
    has_champion = champion.model_id is not None
    champion_training = champion_speeds(champion.model, promotion, runs_table) if has_champion else None
    candidate_training = with_prior_speeds(
        candidate_model, candidate_training, champion.model_id, champion_training
    )
    champion_data = {}
    if has_champion:
        champion_data = (champion.model or {}).get("data") or (promotion or {}).get("data_files") or {}
    return Provenance(
        tonight=tonight,
        candidate_training=candidate_training,
        coverage=speed_coverage(champion_training, candidate_training, speed_tolerance_rpm),
        champion_data=champion_data,
        changes=training_data_changes(champion_data, tonight, status.get("rejected"), status.get("usable")),
        warnings=input_warnings(status, tonight, confirmed),
        prior=prior_warnings(candidate_model, confirmed),
    )


def blocking_checks(
    comparison: ChampionComparison, provenance: Provenance, champion_id: str | None
) -> Blocking:
    """Which checks block a promotion: the relative gate (worse than the champion on a run), the
    coverage of the champion's training speeds, an unconfirmed input warning on tonight's data, an
    unconfirmed fitness warning of the prior the candidate was adapted from."""
    hits = (
        ("relative_gate", len(comparison.worse) > 0),
        ("coverage", provenance.coverage["blocking"]),
        ("input_warnings", bool(provenance.warnings["blocking"])),
        ("prior_fitness", bool(provenance.prior["blocking"])),
    )
    reasons = coverage_reasons(provenance.coverage, champion_id) + [
        warning_reason(w) for w in provenance.warnings["blocking"]
    ]
    reasons += [prior_warning_reason(w) for w in provenance.prior["blocking"]]
    return Blocking(names=[name for name, hit in hits if hit], reasons=reasons)


def promotion_decision(
    candidate_id: str,
    champion_id: str | None,
    history: list[dict],
    gates: tuple[bool, list[str]],
    comparison: ChampionComparison,
    blocking: Blocking,
) -> tuple[str, list[str]]:
    """The decision and its reasons, in this order of precedence.

    * the candidate is the champion -> ``kept`` (nothing to promote; the gate lines are left out);
    * an operator rolled the candidate back after its last promotion -> ``kept`` (not
      re-promoted until new data change it);
    * ``gates`` (``(passed, reasons)`` of :func:`rafi.ops.gates.gate_outcome`) passed and nothing
      blocks -> ``promoted``;
    * otherwise ``rejected``: the champion, if any, stays.
    """
    passed, reasons = gates
    if champion_id is not None and candidate_id == champion_id:
        return "kept", [
            f"candidate {candidate_id[:12]} is the champion already (no new training data changed the model)"
        ]
    if champion_id is not None and (rollback := demoted_by_operator(history, candidate_id)):
        return "kept", [
            f"candidate {candidate_id[:12]} was rolled back by an operator at "
            f"{rollback.get('time')}; not re-promoted until new data change it",
            *reasons,
        ]
    if passed and not blocking.names:
        return "promoted", reasons + comparison.reasons
    stays = (
        f"champion {champion_id[:12]} stays"
        if champion_id
        else "no champion yet: the machine has no qualified model"
    )
    return "rejected", reasons + comparison.reasons + blocking.reasons + [stays]


def decide(
    *,
    machine: str,
    candidate: Candidate,
    champion: Champion,
    runs_table: pd.DataFrame,
    settings: DecisionSettings,
    history: list[dict],
    input_status: dict | None = None,
    time: str | None = None,
) -> Decision:
    """Champion / challenger decision (pure).

    1. the candidate's absolute gates (:func:`rafi.ops.gates.gate_outcome`);
    2. the comparison with the champion, run by run (:func:`compare_with_champion`);
    3. provenance: coverage of the champion's training speeds, its vanished or changed training
       files, tonight's input warnings (:func:`check_provenance`); what blocks
       (:func:`blocking_checks`);
    4. the decision (:func:`promotion_decision`): ``kept`` (the candidate is the champion, or an
       operator rolled it back), ``promoted`` (every gate passed, nothing blocks) or ``rejected``;
    5. the drift of the champion in service (:func:`rafi.ops.drift.champion_drift`), whatever the
       decision;
    6. the record (``decision.json``), the comparison table and the history line.

    Vanished or changed training files of the champion are reported (``data.vanished``,
    ``data.changed`` and reasons), not blocking. ``history`` is ``history.jsonl`` so far;
    ``input_status`` is ``input_status.json``; ``time`` defaults to now.
    """
    time = time or now_iso()
    promotion = promotion_record(history, champion.model_id)
    promoted_on = (promotion or {}).get("data_files")  # the files the champion's promotion saw
    passed, gate_reasons, measured = gate_outcome(candidate.summary, candidate.verdict, settings.gates)
    comparison = compare_with_champion(champion, candidate.summary, settings.champion_margin)
    provenance = check_provenance(
        candidate.model,
        champion,
        promotion,
        runs_table,
        input_status,
        settings.speed_tolerance_rpm,
        confirmed=settings.confirmed,
    )
    blocking = blocking_checks(comparison, provenance, champion.model_id)
    decision, reasons = promotion_decision(
        candidate.model_id, champion.model_id, history, (passed, gate_reasons), comparison, blocking
    )
    reasons += data_change_reasons(provenance.changes, champion.model_id)
    drift, new_runs = champion_drift(champion, promotion, runs_table, settings.nightly)
    waiting = awaiting_confirmation(
        {
            "decision": decision,
            "gates_passed": bool(passed),
            "blocked_by": blocking.names,
            "input_warnings": provenance.warnings,
            "prior_fitness": provenance.prior,
        }
    )
    if drift["detected"]:
        reasons.append(drift_reason(drift, champion.model_id, decision, waiting=bool(waiting)))
    if drift["interval"]["detected"]:
        reasons.append(interval_drift_reason(drift, champion.model_id, decision, waiting=bool(waiting)))
    record = {
        "schema": DECISION_SCHEMA,
        "machine": machine,
        "candidate_id": candidate.model_id,
        **(
            {
                "candidate_parent": parent_of(candidate.model),
                "candidate_parent_machine": (candidate.model.get("adaptation") or {}).get("parent_machine"),
            }
            if parent_of(candidate.model)
            else {}
        ),
        "champion_id_before": champion.model_id,
        "champion_id_after": candidate.model_id if decision == "promoted" else champion.model_id,
        "decision": decision,
        "reasons": reasons,
        "gates": dict(settings.gates),
        "gates_passed": bool(passed),
        "blocked_by": blocking.names,
        "measured": measured,
        "verdict": jsonable(candidate.verdict.to_dict("records")) if candidate.verdict is not None else [],
        **(
            {"champion_verdict": jsonable(champion.verdict.to_dict("records"))}
            if champion.verdict is not None
            else {}
        ),
        "candidate_summary": summary_record(candidate.summary),
        "champion_summary": summary_record(champion.summary),
        "relative_gate": relative_gate_record(comparison.table, champion.model_id, comparison.margin),
        "coverage": provenance.coverage,
        "input_warnings": provenance.warnings,
        "prior_fitness": provenance.prior,
        "retrained_speeds": candidate.retrained_speeds or [],
        "adaptation": candidate.adaptation or {"retrain_speed_range_rpm": None, "mode": "full"},
        "training": provenance.candidate_training,
        "data": {
            "files": provenance.tonight,
            "new_since_champion": new_since_promotion(provenance.tonight, promoted_on),
            "candidate_data": candidate.model.get("data", {}),
            "champion_data": provenance.champion_data,
            **provenance.changes,
        },
        "recalibration_due": drift_detected(drift) and decision != "promoted",
        "drift": drift,
        "time": time,
    }
    table = comparison_table(runs_table, champion.summary, candidate.summary, new_runs, comparison.table)
    return Decision(
        record=jsonable(record),
        comparison=table,
        history=jsonable(history_record(record, provenance.tonight, time)),
    )


def _model_from_dict(d: dict):
    """A predicting model from an artefact dict, of any kind (imported here: the family
    pulls in statsmodels, which the registry itself does not need)."""
    from rafi.family.compare import load_any

    return load_any(d)


def _summary_only(result):
    return result[0] if isinstance(result, tuple) else result


def _residuals_only(result) -> pd.DataFrame | None:
    """The residual frame of ``validate_runs``' result (None from one that returns a summary only)."""
    return result[1] if isinstance(result, tuple) and len(result) > 1 else None


def tonight_candidate(
    fitted: dict, champion_id: str | None, champion_model: dict | None, retrain_range
) -> tuple[dict, dict]:
    """The model tonight offers, and how it was made.

    With ``nightly.retrain_speed_range_rpm`` (``retrain_range``, ``[low, high]``, either end
    None for open) and a champion, the candidate is the champion with the speeds in the range
    taken from tonight's ``fitted`` model (:func:`rafi.ops.adapt.merge_speed_models`); if the
    two cannot be merged, or there is no champion, it is ``fitted`` itself.

    Returns
    -------
    tuple
        ``(candidate, adaptation)``: ``adaptation`` has ``retrain_speed_range_rpm``, ``mode``
        (``full`` / ``speed_range``), ``fitted_id``, ``kept_from`` (speed range), a ``note``
        when the range was asked for but not applied, and ``retrained_speeds_rpm`` (none when
        the candidate is the champion).
    """
    candidate = fitted
    adaptation = {"retrain_speed_range_rpm": retrain_range, "mode": "full", "fitted_id": fitted["model_id"]}
    if retrain_range is not None and champion_model is not None:
        low, high = (list(retrain_range) + [None, None])[:2]
        try:
            candidate = merge_speed_models(fitted, champion_model, low, high)
            adaptation.update(mode="speed_range", kept_from=champion_id)
        except IncompatibleModels as exc:
            adaptation.update(
                mode="full",
                note=f"speed-range adaptation impossible: {exc}; the full new fit is the candidate",
            )
    elif retrain_range is not None:
        adaptation["note"] = "no champion yet: the full new fit is the candidate"
    adaptation["retrained_speeds_rpm"] = (
        [] if candidate["model_id"] == champion_id else speeds_from(candidate, fitted)
    )
    return candidate, adaptation


def _read_parquet(path: str | os.PathLike | None) -> pd.DataFrame | None:
    """A parquet file's frame, None without a path or file."""
    if path is None or not Path(path).exists():
        return None
    return pd.read_parquet(path)


def _read_json(path: str | os.PathLike | None) -> dict | None:
    """A JSON file's content, None without a path or file."""
    if path is None or not Path(path).exists():
        return None
    return json.loads(Path(path).read_text(encoding="utf-8"))


def _validate_runs(model, runs_table: pd.DataFrame, runs_frame: pd.DataFrame):
    """``validate_runs`` with the model's prediction interval (``coverage``: the gate ``min_coverage``)."""
    return validate_runs(model, runs_table, runs_frame, bounds=functools.partial(interval_columns, model))


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
    candidate_residuals_path: str | os.PathLike | None = None,
    model_from_dict: Callable[[dict], Any] = _model_from_dict,
    validate_runs: Callable | None = None,
    qualify: Callable | None = None,
    input_status_path: str | os.PathLike | None = None,
    speed_tolerance_rpm: float = 50.0,
    displacement_sign: int | None = None,
    confirmed=(),
) -> dict:
    """Judge tonight's candidate, update the registry, write decision.json + comparison.csv.

    ``candidate_summary_path``: ``validation/summary.csv`` of the fitted model; reused when
    the candidate is that model (no speed-range merge), so it is not evaluated twice;
    ``candidate_residuals_path`` (``validation/residuals.parquet``) is then its residuals (the
    interval drift test reads them when the candidate is the champion).
    ``input_status_path``: the machine's ``input_status.json`` (its ``warnings`` block
    promotion until confirmed; its ``rejected`` files explain a vanished training file).
    ``speed_tolerance_rpm``: the machine's speed tolerance (coverage of the champion's speeds).
    ``displacement_sign``: the machine's ``input.displacement.sign``, kept in the model's meta.
    ``confirmed``: ``checks.confirmed`` (confirms a prior's fitness warnings).

    Order of writes (each atomic): models/<id>.json (write-once) -> history.jsonl (append)
    -> champion.json (replace, only on promotion) -> comparison.csv -> decision.json. The
    declared outputs come last so they are newer than champion.json (no spurious re-run),
    and a crash leaves at worst a history line whose pointer update is repeated next night.
    """
    from rafi.artefact import write_csv_atomic  # local: keeps the pure part importable without pyarrow

    settings = DecisionSettings(
        gates={k: gates[k] for k in GATE_KEYS},  # the machine's resolved settings: every key present
        nightly=nightly,
        speed_tolerance_rpm=speed_tolerance_rpm,
        confirmed=tuple(confirmed or ()),
    )
    validate_runs = validate_runs or _validate_runs
    qualify = qualify or _qualify
    reg = Registry(Path(registry_root), machine)
    runs_table = pd.read_csv(runs_csv)
    runs_frame = pd.read_parquet(runs_parquet)

    def evaluate(model: dict) -> tuple[pd.DataFrame, pd.DataFrame | None]:
        result = validate_runs(model_from_dict(model), runs_table, runs_frame)
        return _summary_only(result), _residuals_only(result)

    fitted = json.loads(Path(candidate_path).read_text(encoding="utf-8"))
    champion_id = reg.champion_id()
    champion_model = reg.load_model_dict(champion_id) if champion_id else None
    candidate, adaptation = tonight_candidate(
        fitted, champion_id, champion_model, nightly["retrain_speed_range_rpm"]
    )
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
        candidate_summary = pd.read_csv(candidate_summary_path)
        candidate_residuals = _read_parquet(candidate_residuals_path)
    else:
        candidate_summary, candidate_residuals = evaluate(candidate)
    champion_summary, champion_residuals = None, None
    if champion_id is not None and champion_id == candidate["model_id"]:
        champion_summary, champion_residuals = candidate_summary, candidate_residuals
    elif champion_model is not None:
        champion_summary, champion_residuals = evaluate(champion_model)
    dec = decide(
        machine=machine,
        candidate=Candidate(
            model=candidate,
            summary=candidate_summary,
            verdict=qualify(candidate_summary, settings.gates),
            retrained_speeds=retrained_speed_info(candidate, adaptation["retrained_speeds_rpm"], runs_table),
            adaptation=adaptation,
        ),
        champion=Champion(
            model_id=champion_id,
            summary=champion_summary,
            model=champion_model,
            verdict=None if champion_summary is None else qualify(champion_summary, settings.gates),
            residuals=champion_residuals,
        ),
        runs_table=runs_table,
        settings=settings,
        history=reg.history(),
        input_status=_read_json(input_status_path),
    )

    meta = registry_meta(candidate, displacement_sign)  # the parent, the probe sign (rafi.family.prior)
    reg.save_model(candidate, source=str(candidate_path), extra={"adaptation": adaptation, **meta})
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
