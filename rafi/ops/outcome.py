"""What a workflow run says at its end: one line per machine (and probe) - PASS, FAIL or skipped.

The Snakefile's ``onsuccess`` and ``onerror`` (``say_outcomes`` in ``workflow/rules/common.smk``)
and ``rafi nightly`` print, after every run that ran jobs (``docs/operations.md``, "End-of-run
lines")::

    RAFI: outcome of this run, one line per machine (docs/operations.md#end-of-run-lines):
      fl-thermal: FAIL - model offered: grey_box 0a1b2c3d4e5f, not promoted: max residual
        above 12 um on 5 of 5 run(s) (worst 178.73 um, run x#2); report reports/fl-thermal/...
        warning (runs): log x.csv holds 6 runs of one continuous recording ...
      lathe-c: skipped - no file matches input.pattern '*.csv'; the folder holds ...
      tapping-center-a: PASS - model offered: dynamic 92289bc7cc53, promoted; report ...
      mill-d: not judged in this run (no decision built; the last is of 2026-11-20T02:00:00Z)

(each entry is one line; wrapped here). PASS: the model offered passed every qualification gate
(``decision.json`` ``gates_passed``); whether it was promoted is said after it. WAITING: it
passed every gate and waits for a person to confirm an input warning or its prior's fitness
warnings (each warning and the ``checks.confirmed`` entries to add are named). FAIL: it failed
a gate (each failed gate in words), or a step of the machine failed in this run. skipped: the
machine folder has no usable raw file (discovery found no file, or every file was quarantined).
A machine whose decision was not built in this run (``tables`` target, a night for another
machine) is "not judged in this run".

Several probes per machine are coming: :func:`outcome_lines` takes ``(machine, probe)`` rows
(``probe`` None today) and prints the probe beside the machine. The pure functions build lines
from dicts (``decision.json``, ``input_status.json``); :func:`read_outcome` is the I/O edge.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path

from rafi.contract import REGISTRY_DIR, result_file
from rafi.family.confirmation import awaiting_confirmation, confirmation_entry
from rafi.ops.run_messages import MARKER, log_warnings, step_failed

#: The docs section on these lines.
DOCS = "docs/operations.md#end-of-run-lines"
#: The statuses of a line, in the order they are listed.
STATUSES = ("FAIL", "skipped", "WAITING", "PASS", "not judged")

#: A gate (``rafi.method.validate.qualify``'s criterion) in words: (what is measured, the unit,
#: the comparison a failure makes, ``True`` if the worst measurement is the largest).
GATE_WORDS = {
    "max_residual_um": ("max residual", "um", "above", True),
    "min_improvement_pct": ("improvement", "%", "below", False),
    "never_worse_than_uncompensated": ("compensated residual", "um", "above the uncompensated", True),
    "min_coverage": ("interval coverage", "", "below", False),
}


@dataclass(frozen=True)
class Outcome:
    """What one line says about one machine (and probe)."""

    machine: str
    status: str  # one of STATUSES
    text: str  # what follows the status
    probe: str | None = None
    report: str | None = None  # the report in words (report_words)
    warnings: tuple[str, ...] = field(default=())


def _num(value) -> str:
    """A measurement for a line: two decimals, ``?`` where there is none (None, NaN, text)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return "?"
    return "?" if v != v else f"{v:.2f}"


def _limit(value, unit: str) -> str:
    try:
        text = f"{float(value):g}"
    except (TypeError, ValueError):
        return "?"
    return f"{text} {unit}".rstrip()


def failed_gate_words(verdict: Iterable[dict]) -> list[str]:
    """The failed gates of a verdict (rows of ``decision.json`` ``verdict``: ``criterion``,
    ``run_id``, ``measured``, ``limit``, ``passed``) in words, one item per gate, in the verdict's
    order: ``"max residual above 12 um on 2 of 3 runs (worst 178.73 um, run x#2)"``.

    A missing measurement (NaN, None) counts as failed and as the worst; the never-worse gate,
    whose limit is each run's own uncompensated residual, names the worst run's pair of values.
    """
    rows = list(verdict)
    by_gate: dict[str, list[dict]] = {}
    for row in rows:
        by_gate.setdefault(str(row.get("criterion")), []).append(row)
    words = []
    for gate, gate_rows in by_gate.items():
        failed = [r for r in gate_rows if not r.get("passed")]
        if not failed:
            continue
        what, unit, verb, larger_is_worse = GATE_WORDS.get(gate, (gate, "", "outside its limit", True))

        def badness(r, larger=larger_is_worse):
            try:
                v = float(r.get("measured"))
            except (TypeError, ValueError):
                return float("inf")
            return float("inf") if v != v else (v if larger else -v)

        worst = max(failed, key=badness)
        runs = f"on {len(failed)} of {len(gate_rows)} run(s)"
        if gate == "never_worse_than_uncompensated":
            words.append(
                f"{what} {verb} {runs} (worst: {_num(worst.get('measured'))} um vs "
                f"{_num(worst.get('limit'))} um uncompensated, run {worst.get('run_id')})"
            )
        else:
            words.append(
                f"{what} {verb} {_limit(worst.get('limit'), unit)} {runs} (worst "
                f"{_num(worst.get('measured'))} {unit}".rstrip()
                + f", run {worst.get('run_id')})"
            )
    return words


def model_words(kind: str | None, model_id: str | None) -> str:
    """The model offered, for a line: ``"dynamic 92289bc7cc53"`` (kind and short id)."""
    short = str(model_id)[:12] if model_id else "none"
    return f"{kind} {short}" if kind else short


def decision_outcome(
    machine: str,
    decision: dict,
    *,
    kind: str | None = None,
    probe: str | None = None,
    report: str | None = None,  # report_words
    warnings: Iterable[str] = (),
) -> Outcome:
    """The outcome of a machine judged in this run, from its ``decision.json`` (``kind``: the
    candidate's model kind, from the registry).

    PASS if every gate passed (``gates_passed``), with the decision (``promoted``, ``kept``, or
    ``not promoted (blocked by ...)``); WAITING when it passed every gate and only warnings a
    person confirms hold it back - unconfirmed input warnings, the prior's fitness warnings
    (:func:`awaiting_confirmation`: each warning and the ``checks.confirmed`` entries to add);
    FAIL with each failed gate in words (:func:`failed_gate_words`; the decision's first reason
    where the verdict names none, e.g. no validation run).
    """
    offered = f"model offered: {model_words(kind, decision.get('candidate_id'))}"
    state = decision.get("decision")
    waiting = awaiting_confirmation(decision)
    if waiting:  # passed every gate, goes on once a person confirms: neither PASS nor FAIL
        return Outcome(
            machine,
            "WAITING",
            f"{offered}, passed every gate, not promoted: {waiting}",
            probe,
            report,
            tuple(warnings),
        )
    if decision.get("gates_passed"):
        if state == "promoted" or state == "kept":
            text = f"{offered}, {state}"
        else:
            blocked = ", ".join(decision.get("blocked_by") or []) or "see decision.json"
            text = f"{offered}, not promoted (blocked by {blocked})"
        status = "PASS"
    else:
        why = failed_gate_words(decision.get("verdict") or []) or list((decision.get("reasons") or [])[:1])
        text = f"{offered}, {'kept' if state == 'kept' else 'not promoted'}: " + "; ".join(
            why or ["see decision.json"]
        )
        status = "FAIL"
    return Outcome(machine, status, text, probe, report, tuple(warnings))


# --------------------------------------------------------------------------- the warnings, true to the state
#
# The runs step writes its warnings before anything is decided (rafi.method.run_checks); the
# end-of-run lines repeat them from the logs in place, under a decision that may have moved on.
# Two of its clauses are said here as the decision in place has it (the runs step's text is left
# as it is: changing it would re-run the runs step, and all that follows, on every project).
# tests/test_outcome.py checks these texts against run_checks' own output.

#: The training-speeds warning's clause on a prior (``training_speed_problems`` with a prior).
PRIOR_SPEEDS_CLAUSE = (
    "; in a re-qualification from a prior (models.prior) these speeds are left to the prior, and "
    "the promotion waits for the prior_speeds confirmation (docs/models.md)"
)
#: What the continuous-log warning (``continuous_log_warnings``) said to do, two instructions.
CONTINUOUS_LOG_ADVICE = (
    "For runs inside one continuous log set `reference: {rule: log_start}` ({docs}); a recording "
    "of `rafi plan`'s programme is read per run by design, leave it (docs/record.md)"
)
#: ... said as one instruction: a `rafi plan` recording is left as it is.
CONTINUOUS_LOG_ONE = (
    "If the log is a recording of `rafi plan`'s programme, leave it: such a recording is read per "
    "run by design (docs/record.md); set `reference: {rule: log_start}` only for runs cut out of "
    "one continuous log of production ({docs})"
)


def _prior_speeds_state(decision: dict) -> tuple[str, str | None]:
    """``("blocking" | "confirmed" | "none", the prior's id)`` of the fitness warning
    ``prior_speeds`` in ``decision`` (``prior_fitness``)."""
    fitness = decision.get("prior_fitness") if isinstance(decision.get("prior_fitness"), dict) else {}
    for state in ("blocking", "confirmed"):
        for w in fitness.get(state) or []:
            if isinstance(w, dict) and w.get("check") == "prior_speeds":
                return state, str(w.get("prior") or "")[:12]
    return "none", None


def one_instruction(warning: str) -> str:
    """The continuous-log warning's two instructions (:data:`CONTINUOUS_LOG_ADVICE`) said as one
    (:data:`CONTINUOUS_LOG_ONE`): a recording of ``rafi plan``'s programme is left as it is,
    ``log_start`` is for runs cut out of a continuous log of production; any other line as it is."""
    head, _, tail = CONTINUOUS_LOG_ADVICE.partition("{docs}")
    start = warning.find(head)
    end = warning.find(tail, start + len(head)) if start >= 0 else -1
    if end < 0:
        return warning
    one = CONTINUOUS_LOG_ONE.replace("{docs}", warning[start + len(head) : end])
    return warning[:start] + one + warning[end + len(tail) :]


def warning_in_state(warning: str, decision: dict | None) -> str:
    """A job's warning line as the decision in place has it.

    * The training-speeds warning's clause "the promotion waits for the prior_speeds
      confirmation" (:data:`PRIOR_SPEEDS_CLAUSE`) stays while the decision's ``prior_speeds``
      warning blocks; once confirmed it names the confirmation instead; under a decision without
      that warning (no prior tonight, or a prior that left no speed to itself) the clause goes.
      Without a decision (a step failed before it) the line is as the runs step wrote it.
    * The continuous-log warning's two instructions are one (:func:`one_instruction`).

    Parameters
    ----------
    warning : str
        ``(<step>): <message>`` (:func:`rafi.ops.run_messages.log_warnings`).
    decision : dict or None
        ``decision.json`` in place.

    Returns
    -------
    str
    """
    warning = one_instruction(warning)
    if PRIOR_SPEEDS_CLAUSE not in warning or not isinstance(decision, dict):
        return warning
    state, prior = _prior_speeds_state(decision)
    if state == "blocking":
        return warning
    if state == "confirmed":
        entry = confirmation_entry(prior, "prior_speeds")
        said = (
            "; in this re-qualification from a prior these speeds are left to the prior, its "
            f"prior_speeds warning confirmed in checks.confirmed ({entry}; docs/models.md)"
        )
        return warning.replace(PRIOR_SPEEDS_CLAUSE, said)
    return warning.replace(PRIOR_SPEEDS_CLAUSE, "")


def skipped_outcome(machine: str, why: str, *, probe: str | None = None) -> Outcome:
    """A machine skipped for want of a usable raw file; ``why`` says why (and where to read on)."""
    return Outcome(machine, "skipped", why, probe)


def failed_step_outcome(
    machine: str,
    step: str,
    log: str,
    line: str | None = None,
    *,
    said_below: bool = False,
    probe: str | None = None,
    warnings: Iterable[str] = (),
) -> Outcome:
    """A machine a step of which failed in this run. ``line``: the failure line its log ended
    with (bad input; None after a traceback: the ``log`` has the details); ``said_below``: the
    failure lines are printed after these lines (the Snakefile's ``say_failures``), so the
    message is not repeated here."""
    if line is None:
        why = f" (details in {log})"
    elif said_below:
        why = " (its message is below)"
    else:
        why = ": " + line.split(MARKER, 1)[-1]
    return Outcome(
        machine, "FAIL", f"step {step} failed{why}; no model offered", probe, None, tuple(warnings)
    )


def not_judged_outcome(
    machine: str, last_time: str | None = None, *, probe: str | None = None, warnings: Iterable[str] = ()
) -> Outcome:
    """A machine whose decision was not built in this run (``last_time``: that of the one in place)."""
    last = f"; the last is of {last_time}" if last_time else "; none yet"
    return Outcome(
        machine, "not judged", f"in this run (no decision built{last})", probe, None, tuple(warnings)
    )


def report_words(path: str, exists: bool, fresh: bool) -> str:
    """The report of a judged machine, for its line: ``"report <path>"`` when this run wrote it,
    else that it was not (re)built in this run (``rafi nightly --no-report``, a target without it)."""
    if fresh:
        return f"report {path}"
    if exists:
        return f"report not rebuilt in this run ({path} is of an earlier one)"
    return "no report built in this run"


def outcome_line(outcome: Outcome) -> str:
    """The line of one outcome (its warnings on lines of their own below it, indented)."""
    who = outcome.machine if outcome.probe is None else f"{outcome.machine} [{outcome.probe}]"
    sep = " " if outcome.status == "not judged" else " - "
    report = f"; {outcome.report}" if outcome.report else ""
    lines = [f"{who}: {outcome.status}{sep}{outcome.text}{report}"]
    lines += [f"  warning {w}" for w in outcome.warnings]
    return "\n".join(lines)


def outcome_lines(
    rows: Iterable[tuple[str, str | None]], outcome_of: Callable[[str, str | None], Outcome]
) -> list[str]:
    """The end-of-run lines: a heading, then one line per ``(machine, probe)`` row (FAIL first,
    then skipped, PASS and not judged; machines in name order within each); ``[]`` without rows.

    ``outcome_of(machine, probe)`` gives each row's :class:`Outcome` (:func:`read_outcome`)."""
    outcomes = [outcome_of(machine, probe) for machine, probe in rows]
    if not outcomes:
        return []
    order = {s: i for i, s in enumerate(STATUSES)}
    outcomes.sort(key=lambda o: (order.get(o.status, len(order)), o.machine, o.probe or ""))
    lines = [f"RAFI: outcome of this run, one line per machine ({DOCS}):"]
    return lines + ["  " + line.replace("\n", "\n  ") for line in map(outcome_line, outcomes)]


# --------------------------------------------------------------------------- reading a run's files


@dataclass(frozen=True)
class RunFiles:
    """Where a run's files are, and when it started (``time.time()``): a file modified since
    then was written by this run."""

    results_dir: str
    reports_dir: str
    logs_dir: str
    since: float
    failures_said_below: bool = False


def _fresh(path: Path, since: float) -> bool:
    try:
        return path.stat().st_mtime >= since
    except OSError:
        return False


def _newer(path: Path, than: Path) -> bool:
    """``path`` exists and was written no earlier than ``than`` (or ``than`` does not exist)."""
    try:
        mine = path.stat().st_mtime
    except OSError:
        return False
    try:
        return mine >= than.stat().st_mtime
    except OSError:
        return True


def _json(path: Path) -> dict | None:
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def machine_warnings(logs_dir: str | os.PathLike, machine: str) -> list[str]:
    """The warning lines of every job log of ``machine`` (``logs/<machine>/*.log``, path order)."""
    folder = Path(logs_dir) / machine
    return [w for log in sorted(folder.glob("*.log")) for w in log_warnings(log)]


def failed_step(
    logs_dir: str | os.PathLike, machine: str, since: float
) -> tuple[str, str, str | None] | None:
    """The step of ``machine`` whose log this run wrote and that failed: ``(step, log, failure
    line or None)`` - the first (in path order) that ended with a failure line, else the first
    that ended without its done line - or None."""
    found = []
    for log in sorted((Path(logs_dir) / machine).glob("*.log")):
        if _fresh(log, since):
            failed, line = step_failed(log)
            if failed:
                found.append((line is None, log.stem, str(log), line))
    if not found:
        return None
    return min(found)[1:]


def read_outcome(
    machine: str, probe: str | None, files: RunFiles, skipped_folders: dict[str, str] | None = None
) -> Outcome:
    """The :class:`Outcome` of ``machine`` (and ``probe``; today every probe reads the machine's
    files) after a run, from what the run wrote.

    In order: a folder discovery skipped (``skipped_folders``: machine -> why); a machine whose
    ``input_status.json`` says skipped (every raw file quarantined); a step of the machine that
    failed in this run (its log, :func:`failed_step`); a ``decision.json`` written in this run
    (:func:`decision_outcome`, the model's kind from the registry, the report's path if this run
    wrote it); else not judged in this run.
    """
    if skipped_folders and machine in skipped_folders:
        return skipped_outcome(machine, skipped_folders[machine], probe=probe)
    results = Path(files.results_dir) / machine
    decision_path = results / result_file("decision")
    decision = _json(decision_path)
    # the runs step's warnings as the decision in place has them (a confirmed prior_speeds), where
    # that decision judged the runs in place (written after the runs step's log)
    judged = decision if _newer(decision_path, Path(files.logs_dir) / machine / "runs.log") else None
    warnings = [warning_in_state(w, judged) for w in machine_warnings(files.logs_dir, machine)]
    status = _json(results / result_file("input_status"))
    if status and status.get("status") == "skipped":
        rejected = status.get("rejected") or []
        listed = "; ".join(f"{r.get('file')}: {r.get('reason')}" for r in rejected)
        return skipped_outcome(
            machine, f"no usable raw file ({len(rejected)} rejected): {listed}", probe=probe
        )
    failed = failed_step(files.logs_dir, machine, files.since)
    if failed is not None:
        step, log, line = failed
        return failed_step_outcome(
            machine, step, log, line, said_below=files.failures_said_below, probe=probe, warnings=warnings
        )
    if decision is None or not _fresh(decision_path, files.since):
        return not_judged_outcome(machine, (decision or {}).get("time"), probe=probe, warnings=warnings)
    from rafi.ops.registry import Registry  # NumPy: not while the workflow plans

    registry = Registry(results / REGISTRY_DIR, machine)
    model = _json(registry.model_path(str(decision.get("candidate_id")))) or {}
    html = Path(files.reports_dir) / machine / "qualification.html"
    report = report_words(str(html), html.is_file(), _fresh(html, files.since))
    return decision_outcome(
        machine, decision, kind=model.get("kind"), probe=probe, report=report, warnings=warnings
    )


def skipped_folders(warnings: Iterable[str], prefix: str) -> dict[str, str]:
    """Machine -> why, of the discovery warnings about machine folders left out (lines
    ``<prefix><folder>: <why>``, ``prefix`` being ``rafi.readers.discovery.SKIP_PREFIX``)."""
    found = {}
    for line in warnings:
        if not line.startswith(prefix) or ": " not in line[len(prefix) :]:
            continue
        folder, why = line[len(prefix) :].split(": ", 1)
        found[Path(folder).name] = why
    return found
