"""The state of every machine of a project, read from its files (``rafi status``, reports/index.html).

One dict per machine (:func:`machine_overview`), built only from what the pipeline and the
nights wrote; nothing is computed anew:

* the model in service: ``registry/champion.json`` (id, since, reason) and the ``kind`` of its
  stored model (``registry/models/<id>.json``);
* the last decision and its date: ``registry/decision.json`` (the last line of
  ``registry/history.jsonl`` when decision.json is missing);
* the worst validation residual of the model in service: ``max_residual_um`` of the summary
  ``decide`` made of that model on tonight's validation runs (``decision.json``:
  ``candidate_summary`` when the champion is tonight's candidate, else ``champion_summary``),
  the number the gates and the drift check use, on every validation run. Not
  ``comparison/per_run.csv`` or ``validation/summary.csv``: those score tonight's candidates,
  which are not in service unless promoted. After a rollback there is none until the next
  night scores the model;
* drift and recalibration due: ``decision.json`` ``drift`` (the max-residual check, and under
  ``interval`` the interval test with its evidence) and ``recalibration_due``, when that decision
  checked the model in service (its ``champion_id_before``); after a promotion or a rollback the
  check was of the model replaced, so the row says ``not_checked`` until the next decision;
* the prior of a model in service re-qualified from one: its ``adaptation`` block (the prior's
  id and machine, where it comes from, its own qualification and the fitness figures:
  :func:`prior_summary`);
* what the model in service rests on: the line of ``history.jsonl`` that put it in service (its
  warnings confirmed, and by which ``checks.confirmed`` entries, or promoted by hand over them:
  :func:`rafi.ops.promotion_trail.promotion_trail`);
* where the model in service with the controller's limits leaves more than the largest-residual
  gate (``deploy/replay_summary.csv`` of the run that offered it, its noise floors and the gate
  of ``decision.json``: :func:`replay_above_gate`, the words of the unit's own verdict). The
  replay does not gate: the state stays what the gates and the checks make it;
* quarantined files and whether the machine was skipped: ``audit.csv`` and
  ``input_status.json`` (:func:`rafi.ops.status.machine_status`);
* its page: ``reports/<m>/qualification.html``, or ``reports/<m>/skipped.html`` for a skipped
  machine;
* the raw files its last decision has not judged (:func:`rafi.ops.project.unjudged_files`,
  given the config): modified after that decision's time, or not cleaned in their present content.

Attention order (:data:`RANK`, most urgent first; within a rank by machine name):

0. ``failed`` (the machine has data but no decision, or its decision is older than its
   ``audit.csv``: the last run stopped before the decision; the step that failed and its one
   line, read from the job log the run left, :func:`machine_failure`), ``not_run`` (nothing in results/
   yet) and ``skipped`` (no usable raw file);
1. ``recalibration_due``;
2. ``waiting`` (the last candidate passed every gate and waits for a person to confirm an input
   warning or its prior's fitness warnings: :func:`rafi.family.confirmation.awaiting_confirmation`;
   the champion stays until then), ``rejected`` (the last decision rejected the candidate for any
   other reason; the champion stays) and ``quarantined`` (some raw file was set aside);
3. ``ok``.

Exit status of ``rafi status`` (:func:`exit_code`): the codes of ``rafi nightly`` with its
severity 1 > 3 > 2 > 4 > 0: 1 some machine failed or was never run, 3 recalibration due,
2 the last decision of some machine did not promote its candidate (rejected, or waiting for a
confirmation: the night that decided it exited 2 too), 4 input rejected (quarantined files or a
skipped machine), 0 every machine ok.
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path

from rafi.family.confirmation import awaiting_confirmation
from rafi.family.prior import prior_promoted
from rafi.ops.project import Paths, units, unjudged_files
from rafi.ops.promotion_trail import promotion_trail
from rafi.ops.status import (
    EXIT_OK,
    EXIT_PIPELINE_FAILED,
    EXIT_QUARANTINED,
    EXIT_RECALIBRATION_DUE,
    EXIT_REJECTED,
    drift_detected,
    interval_evidence,
    machine_status,
    most_severe,
    parse_time,
    short_id,
)

#: Attention rank of each state (lower: more urgent).
RANK = {
    "failed": 0,
    "not_run": 0,
    "skipped": 0,
    "recalibration_due": 1,
    "waiting": 2,
    "rejected": 2,
    "quarantined": 2,
    "ok": 3,
}

#: Exit code of each state (``rafi nightly``'s codes).
STATE_CODE = {
    "failed": EXIT_PIPELINE_FAILED,
    "not_run": EXIT_PIPELINE_FAILED,
    "skipped": EXIT_QUARANTINED,
    "recalibration_due": EXIT_RECALIBRATION_DUE,
    "waiting": EXIT_REJECTED,  # not promoted, as rafi nightly exits that night
    "rejected": EXIT_REJECTED,
    "quarantined": EXIT_QUARANTINED,
    "ok": EXIT_OK,
}

#: Decisions written by rule ``decide`` (their summaries score the models they name).
_DECIDED = ("promoted", "kept", "rejected")


def _read_json(path: Path) -> dict | None:
    with contextlib.suppress(OSError, ValueError):
        data = json.loads(path.read_text(encoding="utf-8"))
        return data if isinstance(data, dict) else None
    return None


def _history(path: Path) -> list[dict]:
    """The complete JSON lines of ``history.jsonl`` (a line torn by a crash is skipped)."""
    lines = []
    with contextlib.suppress(OSError):
        with open(path, encoding="utf-8", errors="replace") as fh:
            for line in fh:
                with contextlib.suppress(ValueError):
                    rec = json.loads(line)
                    if isinstance(rec, dict):
                        lines.append(rec)
    return lines


def _last_history(path: Path) -> dict | None:
    """The last complete JSON line of ``history.jsonl`` (a line torn by a crash is skipped)."""
    lines = _history(path)
    return lines[-1] if lines else None


def _num(value) -> float | None:
    try:
        out = float(value)
    except (TypeError, ValueError):
        return None
    return out if out == out else None  # NaN -> None


def champion_residual(decision: dict | None, champion_id: str | None) -> dict | None:
    """The worst validation residual of the model in service, from ``decision.json``.

    Parameters
    ----------
    decision : dict or None
        ``registry/decision.json``.
    champion_id : str or None
        The model in service (``champion.json``).

    Returns
    -------
    dict or None
        ``{"max_residual_um", "run", "n_runs", "source"}``: ``source`` names the summary used
        (``candidate_summary`` or ``champion_summary``); ``run`` the validation run with that
        residual (None if no run matches it). None when no summary of that model is in the
        decision (no champion, a rollback, a decision of another model).
    """
    if not decision or not champion_id or decision.get("decision") not in _DECIDED:
        return None
    if decision.get("candidate_id") == champion_id:
        source = "candidate_summary"
    elif decision.get("champion_id_before") == champion_id:
        source = "champion_summary"
    else:
        return None
    summary = decision.get(source) or {}
    worst = _num(summary.get("max_residual_um"))
    if worst is None:
        return None
    run = None
    for run_id, rec in sorted((summary.get("runs") or {}).items()):
        value = _num((rec or {}).get("max_abs_after_um"))
        if value is not None and abs(value - worst) <= 1e-9 * max(1.0, abs(worst)):
            run = run_id
            break
    return {"max_residual_um": worst, "run": run, "n_runs": summary.get("n_runs"), "source": source}


#: The evidence of the interval drift test a row repeats (``decision.json`` ``drift.interval``).
INTERVAL_KEYS = (
    "status",
    "detected",
    "n",
    "k",
    "expected_k",
    "observed_rate",
    "allowed_rate",
    "level",
    "p_value",
    "false_alarm",
    "decorrelation_s",
    "runs",
    "reason",
)


#: The drift keys a row repeats (``decision.json`` ``drift``).
DRIFT_KEYS = ("status", "degradation_um", "new_max_residual_um", "reference_max_residual_um", "limit_um")


#: What a drift status means, in words (``rafi.ops.drift.check_drift``; ``not_checked``: :func:`_drift`).
DRIFT_WORDS = {
    "ok": "ok",
    "degraded": "degraded",
    "no_new_runs": "no new validation runs since the last check",
    "no_reference": "no reference residual at promotion: not checked",
}


def describe_drift(drift: dict | None, *, has_champion: bool) -> str:
    """The max-residual drift check of a row in words (``rafi status`` and the fleet page).

    ``no_champion`` is the status of a decision taken while the machine had no champion (the
    decision that promoted the first one): drift is checked from the next decision on, so it
    reads "not checked yet" under a model in service, and "-" otherwise (no model in service).
    ``not_checked`` (:func:`_drift`): the last decision checked another model (the one the model
    in service replaced), or the model was rolled back to after it, so none of its figures is
    shown.

    Parameters
    ----------
    drift : dict or None
        A row's ``drift`` (:func:`_drift`).
    has_champion : bool
        The machine has a model in service.

    Returns
    -------
    str
        E.g. ``"degraded, +3.10 um (limit 2.00 um)"``; ``"-"`` when there is nothing to say.
    """
    if not drift:
        return "-"
    status = str(drift["status"])
    if status == "not_checked":
        if drift.get("rolled_back"):
            return "not checked yet (the model was rolled back to after the last check)"
        if drift.get("checked_model"):
            replaced = short_id(drift["checked_model"])
            return f"not checked yet (the last check was of {replaced}, the model replaced)"
        return "not checked yet (the model was promoted by the last decision)"
    if status == "no_champion":
        return "not checked yet (the model was promoted by the last decision)" if has_champion else "-"
    text = DRIFT_WORDS.get(status, status.replace("_", " "))
    degradation = _num(drift.get("degradation_um"))
    if degradation is not None:
        limit = _num(drift.get("limit_um"))
        text += f", {degradation:+.2f} um (limit {'-' if limit is None else f'{limit:.2f} um'})"
    return text


def _drift(decision: dict | None, champion_id: str | None = None) -> dict | None:
    """Both drift checks of ``decision.json``: the max-residual one (its keys at the top) and the
    interval test (``interval``: :data:`INTERVAL_KEYS` and ``text``, its evidence in words; None
    in a decision from before the test).

    The checks are of the decision's ``champion_id_before``; when that is not ``champion_id``
    (the model in service was promoted by that decision, or rolled back to after it) they are
    not this model's: ``status`` ``not_checked``, ``checked_model`` the model they were of, no
    figures and no interval. A rollback (``rafi.ops.registry``) keeps the drift block of the
    decision before it, whose checked model it does not record: ``not_checked`` with
    ``rolled_back`` True and ``checked_model`` None."""
    drift = (decision or {}).get("drift")
    if not isinstance(drift, dict):
        return None
    checked = (decision or {}).get("champion_id_before")
    rolled_back = (decision or {}).get("decision") == "rolled_back"
    if champion_id and (checked != champion_id or rolled_back):
        return {k: None for k in DRIFT_KEYS} | {
            "status": "not_checked",
            "checked_model": None if rolled_back else checked,
            "rolled_back": rolled_back,
            "new_runs": [],
            "interval": None,
        }
    keys = DRIFT_KEYS
    out = {k: drift.get(k) for k in keys} | {"new_runs": list(drift.get("new_runs") or [])}
    interval = drift.get("interval")
    out["interval"] = (
        {k: interval.get(k) for k in INTERVAL_KEYS} | {"text": interval_evidence(interval)}
        if isinstance(interval, dict)
        else None
    )
    return out


def prior_summary(artefact: dict | None, results_dir: str | os.PathLike | None = None) -> dict | None:
    """The prior of a model re-qualified from one, from its ``adaptation`` block: ``id``,
    ``machine``, ``origin`` (``this machine`` / ``declared sibling``; None: not recorded),
    ``promoted`` (when it was made champion: read from its machine's registry under
    ``results_dir``, :func:`rafi.family.prior.prior_promoted`; an artefact of an earlier
    version may carry it in its fitness block), ``max_residual_um`` / ``n_runs`` (its own
    qualification), ``method``,
    ``gain``, ``time_factor``, ``alpha`` (a ridge's penalty), ``largest_coefficient_change``,
    ``prediction_change``, ``speeds_tested_rpm``, ``speeds_prior_only_rpm``, ``speeds_inherited``
    (:func:`rafi.family.prior_fitness.inherited_speeds`) and ``warnings``
    (the fitness block, :mod:`rafi.family.prior_fitness`; the figures are None for a model
    without one). None for a model that is not an adapted prior."""
    block = (artefact or {}).get("adaptation")
    if not isinstance(block, dict) or not block.get("parent"):
        return None
    fit = block.get("fitness") if isinstance(block.get("fitness"), dict) else {}
    own = fit.get("prior") or {}
    keys = (
        "largest_coefficient_change",
        "prediction_change",
        "speeds_tested_rpm",
        "speeds_prior_only_rpm",
        "speeds_inherited",
    )
    machine = block.get("parent_machine") or own.get("machine")
    promoted = prior_promoted(results_dir, machine, block.get("parent")) if results_dir is not None else None
    return {
        "id": block.get("parent"),
        "machine": machine,
        "origin": fit.get("origin"),
        "promoted": promoted or own.get("promoted"),
        "max_residual_um": own.get("max_residual_um"),
        "n_runs": own.get("n_runs"),
        "method": block.get("method"),
        "gain": block.get("gain"),
        "time_factor": block.get("time_factor"),
        "alpha": block.get("alpha"),
        **{k: fit.get(k) for k in keys},
        "warnings": [str(w.get("check")) for w in fit.get("warnings") or []],
        "member": block.get("member") if isinstance(block.get("member"), dict) else None,
    }


def ensemble_weights(artefact: dict | None) -> dict | None:
    """A CV-weighted ensemble's members and weights (``kind: ensemble``,
    :mod:`rafi.family.ensemble`), heaviest first; None for any other model."""
    if (artefact or {}).get("kind") != "ensemble" or not isinstance(artefact.get("weights"), dict):
        return None
    weights = {str(k): float(v) for k, v in artefact["weights"].items()}
    return dict(sorted(weights.items(), key=lambda kv: -kv[1]))


def replay_above_gate(machine_dir: Path, decision: dict | None, champion_id: str | None) -> str | None:
    """Where the model in service, with the controller's limits, leaves more than the
    largest-residual gate of ``decision.json`` allows: the sentence of its report's verdict
    (:func:`rafi.report.replay_section.above_gate_words`, plain numbers), from the unit's
    ``deploy/replay_summary.csv``, ``comparison/per_run.csv`` and ``validation/summary.csv``. None
    where it does not, where the replay is of another model (tonight's candidate, not promoted)
    or there is no replay."""
    from rafi.contract import result_file
    from rafi.report.replay_section import above_gate_words, replay_gaps_of

    gate = ((decision or {}).get("gates") or {}).get("max_residual_um")
    if not champion_id or gate is None:
        return None
    gaps = replay_gaps_of(
        machine_dir / result_file("replay_summary"),
        machine_dir / result_file("comparison_per_run"),
        machine_dir / result_file("validation_summary"),
        gate,
    )
    if not gaps or gaps["model_id"] != champion_id:
        return None
    return above_gate_words(gaps, plain=True)


def _page(reports_dir: Path, machine: str, skipped: bool) -> str | None:
    """The machine's page relative to ``reports_dir`` (None if it is not there)."""
    name = "skipped.html" if skipped else "qualification.html"
    return f"{machine}/{name}" if (reports_dir / machine / name).is_file() else None


def unit_fields(reports_dir: Path, machine: str) -> dict:
    """``folder`` and ``probe`` of a qualification unit (:func:`rafi.settings.split_unit`; ``probe``
    None for a machine with one probe) and ``machine_report``: a probe's machine's own page
    relative to ``reports_dir`` (rule probes_report; None where it is not built, and for a machine
    with one probe)."""
    from rafi.settings import split_unit

    folder, probe = split_unit(machine)
    page = _page(Path(reports_dir), folder, False) if probe is not None else None
    return {"folder": folder, "probe": probe, "machine_report": page}


def _older(a: Path, b: Path) -> bool:
    """``a`` was modified before ``b`` (False if either is missing)."""
    try:
        return a.stat().st_mtime_ns < b.stat().st_mtime_ns
    except OSError:
        return False


def rejected_text(decision: dict, *, has_champion: bool) -> str:
    """What ``rafi status`` says of a last decision ``rejected``: a candidate that passed every gate
    and waits for its input warnings or its prior's fitness warnings to be confirmed is named with
    each warning and the ``checks.confirmed`` entries to add
    (:func:`rafi.family.confirmation.awaiting_confirmation`, the words of the end-of-run line); any
    other is rejected. Then whether a model stays in service."""
    waiting = awaiting_confirmation(decision)
    if waiting:  # passed every gate: goes on the machine once confirmed
        stays = "the champion stays until then" if has_champion else "no model in service until then"
        who = short_id(str(decision.get("candidate_id") or ""))
        return f"the last candidate {who} passed every gate and {waiting}; {stays}"
    stays = "the champion stays" if has_champion else "no model in service"
    return f"the last candidate was rejected; {stays}"


def failure_words(
    failed: tuple[str, str, str | None] | None, directory: str | os.PathLike | None = None
) -> str | None:
    """A failed step of a machine (:func:`rafi.ops.outcome.failed_step`: step, log, failure line)
    in words: ``step compare failed: <its one line> (logs/m/compare.log)``, or with a traceback
    ``step compare failed (details in logs/m/compare.log)``; the log relative to ``directory``
    where it is under it. None without one."""
    from rafi.ops.run_messages import MARKER

    if not failed:
        return None
    step, log, line = failed
    with contextlib.suppress(ValueError, TypeError):
        log = str(Path(log).relative_to(directory)) if directory is not None else log
    if line is None:
        return f"step {step} failed (details in {log})"
    return f"step {step} failed: {line.split(MARKER, 1)[-1]} ({log})"


def machine_failure(paths: Paths, machine: str, since: float = 0.0) -> tuple[str, str, str | None] | None:
    """The step of ``machine`` that stopped its last run, from the job logs that run left
    (``logs/<machine>/<step>.log``, written at or after ``since``): ``(step, log, failure line or
    None)`` of the newest log that ended in a failure (:func:`rafi.ops.run_messages.step_failed`:
    a refusal's one line, e.g. a prior of an undeclared machine, ``PriorForeign``; None after a
    traceback), or None. A step that failed on an earlier run and was not run since is older than
    the step that failed last."""
    from rafi.ops.run_messages import step_failed

    found = []
    for log in sorted((Path(paths.directory) / "logs" / machine).glob("*.log")):
        stamp = _mtime(log)
        if stamp < since:
            continue
        failed, line = step_failed(log)
        if failed:
            found.append((stamp, log.stem, str(log), line))
    if not found:
        return None
    return max(found, key=lambda f: f[0])[1:]


def _mtime(path: Path) -> float:
    try:
        return path.stat().st_mtime
    except OSError:
        return 0.0


def _stopped(paths: Paths, machine: str, decision: dict | None) -> str:
    """The attention line of a machine whose last run stopped before the decision: no
    ``decision.json``, or one older than ``audit.csv``; the step that stopped it and its line
    (:func:`machine_failure`, a log written after that decision), where a job log says."""
    if decision is None:
        text = "no decision.json: the last run stopped before the decision"
        since = 0.0
    else:
        text = "decision.json is older than audit.csv: the last run stopped before the decision"
        since = _mtime(paths.registry(machine) / "decision.json")
    failure = failure_words(machine_failure(paths, machine, since), paths.directory)
    return f"{text}: {failure}" if failure else text


def _unjudged(paths: Paths, config: dict | None, machine: str, last: dict | None) -> dict | None:
    """The raw files the last decision has not judged (:func:`rafi.ops.project.unjudged_files`):
    ``count``, ``files`` and ``since`` (its time); None without the config, a decision with a
    readable time, or such a file."""
    since = parse_time((last or {}).get("time"))
    if config is None or since is None:
        return None
    files = unjudged_files(paths, config, machine, since)
    return {"count": len(files), "files": files, "since": last["time"]} if files else None


def rejected_attention(decision: dict, *, has_champion: bool) -> tuple[str, str]:
    """The state and attention line of a last decision ``rejected``: ``waiting`` when the candidate
    passed every gate and waits for a confirmation alone
    (:func:`rafi.family.confirmation.awaiting_confirmation`), else ``rejected``; the line is
    :func:`rejected_text`."""
    waits = awaiting_confirmation(decision) is not None
    return ("waiting" if waits else "rejected"), rejected_text(decision, has_champion=has_champion)


def adapted_name(artefact: dict) -> str | None:
    """The name the report's comparison gives a model adapted from a prior (``prior_shared_ridge``,
    ``prior_gain``, ...: :func:`rafi.report.ensemble_section.adapted_from`), else None."""
    from rafi.report.ensemble_section import adapted_from  # local: the report's pandas

    return (adapted_from(artefact) or {}).get("candidate") or None


def machine_overview(
    paths: Paths, reports_dir: str | os.PathLike, machine: str, config: dict | None = None
) -> dict:
    """The state of one machine (see the module docstring for the sources and states).

    Parameters
    ----------
    paths : Paths
        The project.
    reports_dir : path
        The project's ``reports_dir`` (absolute, or relative to the current directory).
    machine : str
        Folder name under raw/ (or a probe's unit, ``<machine>@<probe>``).
    config : dict, optional
        The project's config: with it, ``unjudged`` counts the raw files the last decision has
        not judged (:func:`rafi.ops.project.unjudged_files`); without it, ``unjudged`` is None.

    Returns
    -------
    dict
        ``machine``, ``state``, ``rank``, ``attention`` (every state that applies, most urgent
        first, with a short text each), ``replay_above_gate`` (:func:`replay_above_gate`: said,
        not a state), ``champion`` (``id``, ``kind``, ``members``: an ensemble's
        weights, heaviest first, :func:`ensemble_weights`, else None; ``parent``: the prior it was
        re-qualified from or ``None``, ``parent_machine``, ``prior`` (:func:`prior_summary`),
        ``trail`` (what it rests on: its warnings confirmed and by which ``checks.confirmed``
        entries, or promoted by hand over them, :func:`rafi.ops.promotion_trail.promotion_trail`),
        ``since``, ``reason``; or None), ``last_decision`` (``decision``, ``time``,
        ``candidate_id``, ``reasons``, ``source``; or None), ``worst_residual``
        (:func:`champion_residual`), ``drift``, ``recalibration_due``, ``quarantined`` (list of
        ``file (reason)``), ``skipped``, ``report`` (path relative to ``reports_dir``, or None),
        ``unjudged`` (:func:`_unjudged`), ``waiting`` (the last candidate waits for a
        confirmation), ``exit_code``; ``folder`` and ``probe`` (the machine and its probe of a
        unit ``<machine>@<probe>``, ``probe`` None for a machine with one probe) and
        ``machine_report`` (a probe's: its machine's page, ``<machine>/qualification.html``
        relative to ``reports_dir``, or None).
    """
    reports_dir = Path(reports_dir)
    reg = paths.registry(machine)
    champion = _read_json(reg / "champion.json")
    champion_id = (champion or {}).get("model_id")
    kind = candidate = parent = prior = members = None
    if champion_id and "/" not in champion_id and not champion_id.startswith("."):
        artefact = _read_json(reg / "models" / f"{champion_id}.json") or {}
        kind = artefact.get("kind") or None
        candidate = adapted_name(artefact)
        parent = (artefact.get("adaptation") or {}).get("parent") or None
        prior = prior_summary(artefact, paths.results_dir)
        members = ensemble_weights(artefact)
    decision = _read_json(reg / "decision.json")
    trail = promotion_trail(_history(reg / "history.jsonl"), champion_id, decision) if champion_id else None
    last = None
    if decision:
        last = {k: decision.get(k) for k in ("decision", "time", "candidate_id")} | {
            "reasons": list(decision.get("reasons") or []),
            "source": "decision.json",
        }
    else:
        rec = _last_history(reg / "history.jsonl")
        if rec:
            last = {k: rec.get(k) for k in ("decision", "time", "candidate_id")} | {
                "reasons": list(rec.get("reasons") or []),
                "source": "history.jsonl",
            }
    status = machine_status(paths, machine, None)
    machine_dir = paths.results_dir / machine
    audit = machine_dir / "audit.csv"
    attention: list[tuple[str, str]] = []
    if status.skipped:
        attention.append(("skipped", "no usable raw file: nothing retrained or judged"))
    elif not machine_dir.is_dir() or not (audit.exists() or (machine_dir / "input_status.json").exists()):
        attention.append(("not_run", "no results yet: the pipeline has not run for this machine"))
    elif decision is None or (decision.get("decision") in _DECIDED and _older(reg / "decision.json", audit)):
        attention.append(("failed", _stopped(paths, machine, decision)))
    drift = _drift(decision, champion_id)
    if drift is not None:
        drift["text"] = describe_drift(drift, has_champion=bool(champion_id))
    # the decision's verdict on the model it checked: not the model in service after a promotion
    recal = bool((decision or {}).get("recalibration_due")) and (drift or {}).get("status") != "not_checked"
    if recal:
        interval = (drift or {}).get("interval") or {}
        if interval.get("detected"):
            attention.append(
                (
                    "recalibration_due",
                    f"new data fall outside the interval too often ({interval['text']}): recalibration due",
                )
            )
        # the max-residual check found it, or a decision that does not say which check did
        if (drift or {}).get("status") == "degraded" or not drift_detected((decision or {}).get("drift")):
            deg = _num((drift or {}).get("degradation_um"))
            by = f" by {deg:.2f} um" if deg is not None else ""
            attention.append(("recalibration_due", f"the model in service drifted{by}: recalibration due"))
    if (decision or {}).get("decision") == "rejected":
        attention.append(rejected_attention(decision, has_champion=bool(champion_id)))
    if status.quarantined and not status.skipped:
        attention.append(("quarantined", f"{len(status.quarantined)} raw file(s) quarantined"))
    attention.sort(key=lambda a: RANK[a[0]])
    state = attention[0][0] if attention else "ok"
    return {
        "machine": machine,
        "state": state,
        # the last candidate passed every gate and waits for a confirmation (state waiting unless
        # a more urgent one leads)
        "waiting": any(s == "waiting" for s, _ in attention),
        "rank": RANK[state],
        "attention": [{"state": s, "text": t} for s, t in attention],
        "champion": (
            {
                "id": champion_id,
                "kind": kind,
                # an adapted model's row in the report's comparison (prior_shared_ridge, ...)
                "candidate": candidate,
                "members": members,
                "parent": parent,
                "parent_machine": (prior or {}).get("machine"),
                "prior": prior,
                "trail": trail,
                "since": champion.get("since"),
                "reason": champion.get("reason"),
            }
            if champion_id
            else None
        ),
        "last_decision": last,
        "worst_residual": champion_residual(decision, champion_id),
        "replay_above_gate": replay_above_gate(machine_dir, decision, champion_id),
        "drift": drift,
        "recalibration_due": recal,
        "quarantined": list(status.quarantined),
        "skipped": status.skipped,
        "report": _page(reports_dir, machine, status.skipped),
        **unit_fields(reports_dir, machine),
        "unjudged": _unjudged(paths, config, machine, last),
        "exit_code": most_severe(STATE_CODE[s] for s, _ in attention),
    }


def fleet_overview(
    paths: Paths,
    reports_dir: str | os.PathLike,
    machines: list[str] | None = None,
    *,
    config: dict | None = None,
) -> list[dict]:
    """:func:`machine_overview` of every machine (``machines``, default every folder of raw/: with
    ``config`` each of its probes, :func:`rafi.ops.project.units`), most urgent first
    (:data:`RANK`), then by machine name; ``config`` (the project's) counts the raw files each
    last decision has not judged."""
    if machines is None:
        names = paths.machines() if config is None else units(config, paths.machines())
    else:
        names = list(machines)
    rows = [machine_overview(paths, reports_dir, m, config) for m in names]
    return sorted(rows, key=lambda r: (r["rank"], r["machine"]))


def exit_code(rows: list[dict]) -> int:
    """The exit status of ``rafi status``: the most severe code of any machine (0: all ok)."""
    return most_severe(r["exit_code"] for r in rows)
