"""State of every machine: model in service, last decision, residual, drift, quarantine.

Reads the files the pipeline and the nights wrote (rafi.ops.fleet; nothing is recomputed, no
lock is taken) and prints one block per machine, machines that need attention first: failed
(data but no decision), never run or skipped (no usable raw file); then recalibration due;
then a rejected candidate or quarantined files; then ok. docs/operations.md, "rafi status".

Exit status (for monitoring; the codes of rafi nightly, most severe first 1 > 3 > 2 > 4 > 0):
  0   every machine ok
  1   some machine failed (data but no decision) or has never been run
  3   some machine's model in service is due for recalibration (drift: its max residual grew
      past the margin, or new samples fall outside its interval more often than its level allows)
  2   some machine's last decision rejected the candidate (the champion stays)
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
from rafi.ops.fleet import exit_code, fleet_overview
from rafi.ops.project import Paths, load_config, units
from rafi.ops.status import EXIT_CANTCREAT, EXIT_USAGE, short_id
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


#: What a drift status means, for the status text (``rafi.ops.drift.check_drift``).
DRIFT_WORDS = {
    "ok": "ok",
    "degraded": "degraded",
    "no_new_runs": "no new validation runs since the last check",
    "no_reference": "no reference residual at promotion: not checked",
}


def describe_drift(drift: dict | None, *, has_champion: bool) -> str:
    """The drift line of one machine.

    ``no_champion`` is the status of a decision taken while the machine had no champion (the
    decision that promoted the first one): drift is checked from the next decision on, so it
    reads "not checked yet" under a model in service, and "no model in service" otherwise.
    """
    if not drift:
        return "-"
    status = str(drift["status"])
    if status == "no_champion":
        return "not checked yet (the model was promoted by the last decision)" if has_champion else "-"
    text = DRIFT_WORDS.get(status, status)
    if drift.get("degradation_um") is not None:
        limit = _num(drift.get("limit_um"), " um")
        text += f", +{_num(drift['degradation_um'], ' um')} (limit {limit})"
    return text


def format_rows(rows: list[dict]) -> str:
    """The text ``rafi status`` prints: one block per machine (most urgent first)."""
    if not rows:
        return "no machine\n"
    lines = []
    for r in rows:
        ch = r["champion"]
        model = f"{short_id(ch['id'])} {ch['kind'] or '?'} since {ch['since']}" if ch else "none"
        if ch and ch.get("parent"):
            model += f" (adapted from {short_id(ch['parent'])})"
        last = r["last_decision"]
        decided = f"{last['decision']} at {last['time']}" if last else "none"
        worst = r["worst_residual"]
        resid = (
            f"{_num(worst['max_residual_um'], ' um')}" + (f" ({worst['run']})" if worst.get("run") else "")
            if worst
            else "-"
        )
        drift_text = describe_drift(r["drift"], has_champion=bool(ch))
        lines.append(f"{r['machine']}: {r['state'].upper()}")
        for a in r["attention"]:
            lines.append(f"  ! {a['text']}")
        lines.append(f"  model in service: {model}")
        lines.append(f"  last decision:    {decided}")
        lines.append(f"  worst residual:   {resid}")
        due = "YES" if r["recalibration_due"] else "no"
        lines.append(f"  drift:            {drift_text}; recalibration due: {due}")
        interval = (r["drift"] or {}).get("interval")
        if interval:
            lines.append(f"  interval drift:   {interval['text']}")
        lines.append(f"  quarantined:      {'; '.join(r['quarantined']) or 'none'}")
        lines.append(f"  report:           {r['report_path'] or 'not built'}")
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
    rows = fleet_overview(paths, reports_dir, units(config, args.machine or machines))
    for r in rows:
        r["report_path"] = str(reports_dir / r["report"]) if r["report"] else None
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
