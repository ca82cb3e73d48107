"""State of every machine: model in service, last decision, residual, drift, quarantine.

Reads the files the pipeline and the nights wrote (rafi.ops.fleet; nothing is recomputed, no
lock is taken) and prints one block per machine, machines that need attention first: failed
(data but no decision; the step that stopped the last run and its line, from its job log), never
run or skipped (no usable raw file); then recalibration due;
then a candidate waiting for a confirmation (WAITING FOR CONFIRMATION: it passed every gate,
and the checks.confirmed entries to add are named), a rejected candidate or quarantined files;
then ok. Under a machine's last decision, the raw files that arrived after it (modified since,
or never read by its run) and wait for the next night: "not judged yet". Under a model in
service re-qualified from a prior, what its promotion rested on: its fitness warnings confirmed
(by which checks.confirmed entries), or promoted by hand over them (rafi.ops.promotion_trail).
docs/operations.md, "rafi status".

Exit status (for monitoring; the codes of rafi nightly, most severe first 1 > 3 > 2 > 4 > 0):
  0   every machine ok
  1   some machine failed (data but no decision) or has never been run
  3   some machine's model in service is due for recalibration (drift: its max residual grew
      past the margin, or new samples fall outside its interval more often than its level allows)
  2   some machine's last candidate was not promoted (the champion stays): rejected, or
      waiting for a person to confirm an input warning or its prior's fitness (checks.confirmed)
  4   some input was rejected: quarantined raw files, or a machine skipped
  64  usage error (config unreadable, unknown --machine)
  73  --html PATH cannot be written

Examples:
  rafi status                        # the table, most urgent first
  rafi status --json                 # one JSON document (list of machines) for monitoring
  rafi status --html /srv/www/rafi/index.html
  rafi status --machine tapping-center-a
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rafi.cli import add_config_option
from rafi.errors import SettingsError
from rafi.family.prior_fitness import inherited_text
from rafi.ops.fleet import describe_drift, exit_code, fleet_overview
from rafi.ops.project import Paths, load_config, units
from rafi.ops.promotion_trail import trail_lines
from rafi.ops.status import EXIT_CANTCREAT, EXIT_USAGE, short_id
from rafi.report.requalification_section import largest_change_words
from rafi.settings import run_settings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``rafi status``."""
    parser.add_argument("--directory", default=".", help="project directory (default .)")
    add_config_option(parser, relative_to="--directory")
    parser.add_argument("--machine", action="append", help="only this machine (repeatable)")
    parser.add_argument("--json", action="store_true", help="print one JSON document instead of the table")
    parser.add_argument("--html", metavar="PATH", help="also write the fleet overview page to PATH")


def _num(value, unit: str = "") -> str:
    return "-" if value is None else f"{float(value):.2f}{unit}"


def _speeds(values) -> str:
    return ", ".join(f"{float(v):g}" for v in values or []) or "none"


def _members(champion: dict) -> str:
    """`` of 6 members, heaviest temperature_ridge 0.324`` for a CV-weighted ensemble
    (``members``, :func:`rafi.ops.fleet.ensemble_weights`), else ``""``."""
    members = champion.get("members") or {}
    if not members:
        return ""
    name, weight = next(iter(members.items()))
    return f" of {len(members)} members, heaviest {name} {float(weight):.3f}"


def describe_prior(prior: dict | None, trail: dict | None = None, machine: str | None = None) -> list[str]:
    """The lines naming the prior of a model in service re-qualified from one
    (:func:`rafi.ops.fleet.prior_summary`): its id and machine, where it comes from, its own
    qualification; how far the adaptation moved it; the speeds tested here and those only it
    covers; its fitness warnings and what the promotion did with them (``trail``,
    :func:`rafi.ops.promotion_trail.trail_lines`: confirmed, and by which ``checks.confirmed``
    entries, or promoted by hand over them; ``machine`` takes the entries to add)."""
    if not prior:
        return []
    origin = f", {prior['origin']}" if prior.get("origin") else ""
    own = []
    if prior.get("promoted"):
        own.append(f"promoted {prior['promoted']}")
    if prior.get("max_residual_um") is not None:
        runs = f" on {prior['n_runs']} validation run(s)" if prior.get("n_runs") else ""
        own.append(f"worst {_num(prior['max_residual_um'], ' um')}{runs}")
    first = f"{short_id(prior['id'])} of {prior.get('machine') or '?'}{origin}"
    first += f" ({'; '.join(own)})" if own else " (its own qualification not recorded)"
    member = prior.get("member") or {}
    if member.get("name"):  # a CV-weighted ensemble prior: the member re-fitted
        first += (
            f"; an ensemble, adapted through its heaviest member {member['name']} "
            f"(weight {float(member.get('weight') or 0):.3f})"
        )
    moved = [str(prior.get("method") or "?")]
    if prior.get("gain") is not None:
        moved.append(f"gain {float(prior['gain']):.3g}")
    if prior.get("time_factor") is not None:
        moved.append(f"time factor {float(prior['time_factor']):g}")
    if prior.get("alpha") is not None:
        moved.append(f"ridge penalty {float(prior['alpha']):g}")
    big = largest_change_words(prior.get("largest_coefficient_change"))
    if big:  # the report's words: a factor of its prior value, never a relative change
        moved.append(f"the coefficient that moved most relative to its prior value: {big}")
    lines = [f"  prior:            {first}", f"  adaptation:       {', '.join(moved)}"]
    if prior.get("speeds_tested_rpm") is not None:
        lines.append(
            f"  speeds:           tested here {_speeds(prior['speeds_tested_rpm'])} r/min; the prior's "
            f"alone {_speeds(prior.get('speeds_prior_only_rpm'))}"
            + inherited_text(prior.get("speeds_inherited"), lambda v: _speeds(v) + " r/min")
        )
    if prior.get("warnings"):
        said = trail_lines(trail, prior["warnings"], machine)["prior"]
        lines.append(f"  prior warnings:   {', '.join(prior['warnings'])}: {said}")
    return lines


#: At most this many names of raw files not judged yet on a line of ``rafi status``.
UNJUDGED_SHOWN = 5


def unjudged_text(unjudged: dict) -> str:
    """The raw files the last decision has not judged (:func:`rafi.ops.fleet.unjudged_files`), in
    words: how many, since when, their first :data:`UNJUDGED_SHOWN` names."""
    files = list(unjudged["files"])
    shown = ", ".join(files[:UNJUDGED_SHOWN])
    if len(files) > UNJUDGED_SHOWN:
        shown += f", ... ({len(files) - UNJUDGED_SHOWN} more)"
    return (
        f"{unjudged['count']} raw file(s) arrived after the last decision ({unjudged['since']}): "
        f"{shown}; the next night judges them"
    )


def _headline(state: str) -> str:
    return "WAITING FOR CONFIRMATION" if state == "waiting" else state.upper()


def machine_lines(group: dict) -> list[str]:
    """The line of a machine with several probes (:func:`rafi.report.fleet_page.machine_groups`,
    as the page's machine row): its state (the most urgent of its probes'), the probes whose model
    in service with the controller's limits leaves more than the largest-residual gate, and its
    own page (``report_path`` of its first row's ``machine_report``)."""
    n = len(group["probes"])
    lines = [
        f"{group['machine']}: {_headline(group['state'])} ({n} probes, each qualified on its own: the most "
        "urgent state of its probes; their blocks follow)"
    ]
    for a in group["above_gate"]:
        lines.append(f"  replay:           @{a['probe']}: {a['text']}")
    page = next((u["row"].get("machine_report_path") for u in group["units"]), None)
    lines.append(f"  report:           {page + ' (every probe on one page)' if page else 'not built'}")
    return lines


def unit_lines(r: dict) -> list[str]:
    """The block of one qualification unit: its state and attention lines, then the page's columns
    (model in service, last decision, worst residual, drift, interval drift, quarantined files,
    report), a line each; ``-`` where the page shows ``-``."""
    lines = []
    ch = r["champion"]
    named = f" ({ch['candidate']})" if ch and ch.get("candidate") else ""
    model = (
        f"{short_id(ch['id'])} {ch['kind'] or '?'}{named}{_members(ch)} since {ch['since']}" if ch else "none"
    )
    if ch and ch.get("parent"):
        model += f" (adapted from {short_id(ch['parent'])} of {ch.get('parent_machine') or '?'})"
    last = r["last_decision"]
    decided = f"{last['decision']} at {last['time']}" if last else "none"
    if last and r.get("waiting"):
        decided += " (not promoted until the confirmation above)"
    worst = r["worst_residual"]
    resid = (
        f"{_num(worst['max_residual_um'], ' um')}" + (f" ({worst['run']})" if worst.get("run") else "")
        if worst
        else "-"
    )
    lines.append(f"{r['machine']}: {_headline(r['state'])}")
    for a in r["attention"]:
        lines.append(f"  ! {a['text']}")
    lines.append(f"  model in service: {model}")
    trail = (ch or {}).get("trail")
    lines += describe_prior((ch or {}).get("prior"), trail, r.get("folder") or r["machine"])
    checks = ((ch or {}).get("prior") or {}).get("warnings") or []
    inputs = trail_lines(trail, checks, r.get("folder") or r["machine"])["inputs"]
    if ch and inputs:
        lines.append(f"  input warnings:   {inputs}")
    lines.append(f"  last decision:    {decided}")
    if r.get("unjudged"):
        lines.append(f"  not judged yet:   {unjudged_text(r['unjudged'])}")
    lines.append(f"  worst residual:   {resid}")
    if r.get("replay_above_gate"):
        lines.append(f"  replay:           {r['replay_above_gate']}")
    due = "YES" if r["recalibration_due"] else "no"
    drift = describe_drift(r["drift"], has_champion=bool(ch))
    lines.append(f"  drift:            {drift}; recalibration due: {due}")
    interval = (r["drift"] or {}).get("interval")
    lines.append(f"  interval drift:   {interval['text'] if interval else '-'}")
    lines.append(f"  quarantined:      {'; '.join(r['quarantined']) or 'none'}")
    lines.append(f"  report:           {r['report_path'] or 'not built'}")
    return lines


def format_rows(rows: list[dict]) -> str:
    """The text ``rafi status`` prints: the page's table as text. One block per unit, most urgent
    first; a machine with several probes (units ``<machine>@<probe>``) is one machine, its line
    (:func:`machine_lines`) at the place of its most urgent probe with its probes' blocks under
    it (:func:`rafi.report.fleet_page.machine_groups`, the page's grouping)."""
    from rafi.report.fleet_page import machine_groups

    if not rows:
        return "no machine\n"
    lines = []
    for group in machine_groups(rows):
        if group["probes"]:
            lines += machine_lines(group)
        for unit in group["units"]:
            lines += unit_lines(unit["row"])
    return "\n".join(lines) + "\n"


def run(args) -> int:
    """Run ``rafi status`` with parsed ``args``; returns the exit status."""
    from rafi.report.fleet_page import write_fleet_page

    directory = Path(args.directory).resolve()
    try:
        config = load_config(directory, args.config)
        paths = Paths.from_config(directory, config)
        reports_dir = directory / str(run_settings(config)["reports_dir"])
    except (OSError, SettingsError) as exc:
        print(f"rafi status: cannot read config: {exc}", file=sys.stderr)
        return EXIT_USAGE
    machines = paths.machines()
    unknown = [m for m in args.machine or [] if m not in machines]
    if unknown:
        print(
            f"rafi status: no machine {', '.join(map(repr, unknown))} under {paths.raw_dir} "
            f"(found: {', '.join(machines) or 'none'})",
            file=sys.stderr,
        )
        return EXIT_USAGE
    rows = fleet_overview(paths, reports_dir, units(config, args.machine or machines), config=config)
    for r in rows:
        r["report_path"] = str(reports_dir / r["report"]) if r["report"] else None
        r["machine_report_path"] = str(reports_dir / r["machine_report"]) if r.get("machine_report") else None
    if args.html:
        try:
            out = write_fleet_page(paths, reports_dir, args.html, rows=rows)
        except OSError as exc:
            print(f"rafi status: cannot write {args.html}: {exc}", file=sys.stderr)
            return EXIT_CANTCREAT
        print(f"rafi status: wrote {out}", file=sys.stderr)
    if args.json:
        print(json.dumps({"machines": rows, "exit_code": exit_code(rows)}, indent=2, sort_keys=True))
    else:
        sys.stdout.write(format_rows(rows))
    return exit_code(rows)
