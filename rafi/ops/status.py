"""What a night reports per machine, and the exit codes of ``rafi nightly``.

The codes and their order are in ``rafi nightly --help`` and ``docs/operations.md``. Rejected
input - a quarantined raw file, or a machine *skipped* because none of its raw files is usable
(``on_bad_input: quarantine``) - gives :data:`EXIT_QUARANTINED`, never a pipeline failure.
"""

from __future__ import annotations

import calendar
import contextlib
import csv
import json
import time
from collections.abc import Iterable
from dataclasses import dataclass

from rafi.family.confirmation import awaiting_confirmation
from rafi.ops.project import Paths

EXIT_OK = 0
EXIT_PIPELINE_FAILED = 1
EXIT_REJECTED = 2
EXIT_RECALIBRATION_DUE = 3
EXIT_QUARANTINED = 4  # some input was rejected: a raw file quarantined or a machine skipped
EXIT_USAGE = 64
EXIT_CANTCREAT = 73  # EX_CANTCREAT (sysexits.h): results/ cannot be written (read-only, full)
EXIT_IOERR = 74  # EX_IOERR: another error reading or writing the project's files
EXIT_LOCKED = 75  # EX_TEMPFAIL (sysexits.h): another night, or a Snakemake run, works here

#: Severity order used when several codes apply (first wins).
SEVERITY = (EXIT_PIPELINE_FAILED, EXIT_RECALIBRATION_DUE, EXIT_REJECTED, EXIT_QUARANTINED, EXIT_OK)


def most_severe(codes: Iterable[int]) -> int:
    """The most severe of ``codes`` by :data:`SEVERITY` (0 for none)."""
    codes = set(codes)
    for code in SEVERITY:
        if code in codes:
            return code
    return EXIT_OK


def short_id(model_id) -> str:
    """The first 12 characters of a model id, or ``none``."""
    return str(model_id)[:12] if model_id else "none"


def _num(v) -> str:
    return "?" if v is None else f"{float(v):.2f}"


def parse_time(text) -> float | None:
    """Seconds since the epoch of a ``YYYY-MM-DDTHH:MM:SSZ`` time (None if not one)."""
    if not text:
        return None
    try:
        return calendar.timegm(time.strptime(str(text), "%Y-%m-%dT%H:%M:%SZ"))
    except ValueError:
        return None


def drift_detected(drift: dict | None) -> bool:
    """Either drift check of ``decision.json``'s ``drift`` found drift: the max residual grew past
    its margin (``detected``) or the new samples fell outside the interval too often
    (``interval.detected``)."""
    drift = drift or {}
    return bool(drift.get("detected")) or bool((drift.get("interval") or {}).get("detected"))


def interval_evidence(interval: dict | None) -> str:
    """The interval drift test's result in words (``decision.json`` ``drift.interval``, see
    :func:`rafi.ops.drift.interval_drift`): what was counted, against what, and the p-value.

    ``"9 of 40 new samples (one per 600 s, 3 run(s)) outside the 90 % interval, 4.0 expected;
    p = 0.00021 < 0.01"``; for the other statuses, why nothing was tested.
    """
    d = interval or {}
    status = d.get("status")
    if status in ("ok", "recalibration_due") and d.get("n"):
        level = 100.0 * float(d["level"])
        verdict = "<" if d.get("detected") else ">="
        return (
            f"{d['k']} of {d['n']} new samples (one per {float(d['decorrelation_s']):g} s, "
            f"{len(d.get('per_run') or {})} run(s)) outside the {level:g} % interval, "
            f"{float(d['expected_k']):.1f} expected; p = {float(d['p_value']):.2g} {verdict} "
            f"{float(d['false_alarm']):g}"
        )
    if status == "no_interval":
        return f"interval not tested: {d.get('reason') or 'no interval'}"
    if status == "no_new_runs":
        return "interval not tested: no new validation runs"
    if status == "no_champion":
        return "interval not tested: no model in service"
    return "interval not tested"


@dataclass
class MachineStatus:
    """A machine's decision.json and quarantined inputs after a night.

    ``skipped``: every raw file of the machine was quarantined, so the night built only its
    audit and skipped page; ``decision`` is then an earlier night's (never tonight's).
    """

    machine: str
    decision: dict | None
    quarantined: list[str]
    tonight: bool
    skipped: bool = False

    def codes(self) -> set[int]:
        """Exit codes this machine contributes (recalibration, rejection tonight, rejected input)."""
        codes = set()
        d = self.decision or {}
        if d.get("recalibration_due"):
            codes.add(EXIT_RECALIBRATION_DUE)
        if self.tonight and not self.skipped and d.get("decision") == "rejected":
            codes.add(EXIT_REJECTED)
        if self.quarantined or self.skipped:
            codes.add(EXIT_QUARANTINED)
        return codes

    def line(self) -> str:
        """The one status line printed for this machine."""
        d = self.decision
        if self.skipped:
            champion = (d or {}).get("champion_id_after")
            text = f"{self.machine}: SKIPPED - no usable raw file, nothing retrained or judged; "
            text += f"champion {short_id(champion)} stays" if champion else "no model in service"
            if d:
                text += f" (last decision {d.get('decision')} at {d.get('time')})"
            return text + f"; quarantined: {', '.join(self.quarantined) or 'every file'}"
        if not d:
            return f"{self.machine}: no decision yet"
        waiting = awaiting_confirmation(d)  # passed every gate, held for a person's confirmation
        text = (
            f"{self.machine}: {'WAITING' if waiting else d.get('decision')}"
            f"{' tonight' if self.tonight else ' (' + str(d.get('time')) + ')'}; champion "
            f"{short_id(d.get('champion_id_after'))}"
        )
        if d.get("decision") in ("promoted", "rejected"):
            text += f", candidate {short_id(d.get('candidate_id'))}"
            if d.get("candidate_parent"):
                of = d.get("candidate_parent_machine") or "?"
                text += f" (adapted from {short_id(d.get('candidate_parent'))} of {of})"
        sp = [str(s.get("speed_rpm")) for s in d.get("retrained_speeds") or []]
        if sp and d.get("decision") == "promoted":
            text += f", retrained speeds {', '.join(sp)} r/min"
        if d.get("recalibration_due"):
            dr = d.get("drift") or {}
            interval = dr.get("interval") or {}
            causes = []
            if dr.get("detected") or not interval.get("detected"):
                causes.append(
                    f"max residual {_num(dr.get('new_max_residual_um'))} um on new logs vs "
                    f"{_num(dr.get('reference_max_residual_um'))} um at promotion"
                )
            if interval.get("detected"):
                causes.append(interval_evidence(interval))
            text += "; RECALIBRATION DUE: " + "; ".join(causes)
        if waiting:
            text += f"; {waiting}"
        if self.quarantined:
            text += f"; quarantined: {', '.join(self.quarantined)}"
        return text


def machine_status(paths: Paths, machine: str, night_start: float | None) -> MachineStatus:
    """Read ``machine``'s decision.json, audit.csv and input_status.json (a machine whose audit
    lists files but no usable one is ``skipped``: the workflow built no decision for it tonight).
    Files rejected for the machine in input_status.json count as quarantined.

    Parameters
    ----------
    paths : Paths
        The project.
    machine : str
        Folder name under raw/.
    night_start : float or None
        Start of tonight (epoch seconds); a decision at or after it is tonight's. None: no
        decision is tonight's (a night without a Snakemake run).
    """
    decision = None
    dpath = paths.registry(machine) / "decision.json"
    if dpath.exists():
        with contextlib.suppress(ValueError, OSError):
            decision = json.loads(dpath.read_text(encoding="utf-8"))
    quarantined = []
    usable = 0
    audit = paths.results_dir / machine / "audit.csv"
    if audit.exists():
        with open(audit, newline="", encoding="utf-8") as fh:
            for row in csv.DictReader(fh):
                status = (row.get("status") or "").strip()
                if status == "ok":
                    usable += 1
                elif status == "quarantined":
                    quarantined.append(f"{row.get('file')} ({row.get('reason') or 'no reason'})")
    # files rejected for the machine as a whole (input_status.json: duplicate content, a probe
    # sign against the configured one): clean read them, so audit.csv calls them ok
    rejected = {}
    with contextlib.suppress(ValueError, OSError):
        status_doc = json.loads(
            (paths.results_dir / machine / "input_status.json").read_text(encoding="utf-8")
        )
        rejected = {str(r.get("file")): r for r in status_doc.get("rejected") or []}
    listed = {q.split(" (", 1)[0] for q in quarantined}
    for name, rec in sorted(rejected.items()):
        if name not in listed:
            quarantined.append(f"{name} ({rec.get('reason') or rec.get('check') or 'rejected'})")
            usable -= 1
    tonight = False
    if decision and night_start is not None:
        t = parse_time(decision.get("time"))
        tonight = t is not None and t >= night_start - 1
    skipped = bool(quarantined) and not usable
    return MachineStatus(machine, decision, quarantined, tonight, skipped)


def last_activity(statuses: list[MachineStatus]) -> str:
    """Time of the latest decision of any machine, or ``the first run``."""
    times = [s.decision.get("time") for s in statuses if s.decision and s.decision.get("time")]
    return max(times) if times else "the first run"
