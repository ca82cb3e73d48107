"""``rafi plan``: the shortest test programme that re-qualifies a machine from a prior.

The programme (:func:`rafi.ops.plan.plan_programme`, ``docs/operations.md``, "Re-qualification
in hours") is built from:

* the **prior**: the model the re-qualification starts from, resolved as rule compare resolves
  it (``models.prior``, :func:`rafi.family.prior.prior_chain`; ``--prior`` overrides it here);
* the **speeds**: the machine's ``training_speeds_rpm`` inside ``--speed-range`` (the range the
  machine is used in: paper item 10, retrain only what is used);
* **where the prior is least sure**: a speed outside the prior's trained speed range falls in the
  interval's ``outside`` cell, one inside it in ``settled`` (after ``transient_s`` of
  ``transient``): the prior's half widths of those cells weigh the time each speed gets;
* the **budget**: ``--hours`` of recorded machine time (default 4).

It prints the programme as a table and writes it as a test plan CSV (``docs/record.md``, "The
test plan") that ``rafi record --plan`` follows on the machine and ``rafi simulate day --plan``
follows on the twin. The file is checked by reading it back with the recorder's own reader.
"""

from __future__ import annotations

import math
from pathlib import Path

from rafi.cli import add_config_option
from rafi.errors import SettingsError, short_path

#: Default budget of recorded machine time, h.
DEFAULT_HOURS = 4.0


def add_arguments(parser) -> None:
    parser.add_argument("--machine", required=True, help="the machine (named under machines: in the config)")
    add_config_option(parser)
    parser.add_argument(
        "--hours",
        type=float,
        default=DEFAULT_HOURS,
        help=f"recorded machine time, h (default {DEFAULT_HOURS:g})",
    )
    parser.add_argument(
        "--speed-range",
        nargs=2,
        type=float,
        metavar=("LO", "HI"),
        help="the speeds the machine is used at, r/min (default: every training speed)",
    )
    parser.add_argument(
        "--prior",
        default=None,
        help="auto, champion, none or a sibling machine's name (default: the machine's models.prior)",
    )
    parser.add_argument("--out", default=None, help="the plan CSV to write (default: plan_<machine>.csv)")


def prior_setting(text: str | None, configured):
    """``--prior`` as a ``models.prior`` value (``None``: the configured one)."""
    if text is None:
        return configured
    return text if text in ("auto", "champion", "none") else {"machine": text}


def speed_uncertainty(prior: dict | None, speeds) -> dict | None:
    """``speed -> half width (um)`` of the prior's interval cell each speed falls in, or ``None``
    (no prior, or a prior without an interval): ``outside`` beyond the prior's trained speed
    range, ``settled`` inside it."""
    block = (prior or {}).get("interval") or {}
    half = block.get("half_width_um") or {}
    if not half:
        return None
    lo, hi = trained_speed_range(prior)
    return {
        float(s): float(half["outside"] if lo is None or not lo <= float(s) <= hi else half["settled"])
        for s in speeds
    }


def trained_speed_range(prior: dict | None) -> tuple[float | None, float | None]:
    """The prior's trained speed range, r/min (``(None, None)`` when the artefact does not say)."""
    if not prior:
        return None, None
    if prior.get("speed_range_rpm"):
        lo, hi = prior["speed_range_rpm"]
        return float(lo), float(hi)
    speeds = [float(s["speed_rpm"]) for s in prior.get("speeds") or [] if "speed_rpm" in s]
    return (min(speeds), max(speeds)) if speeds else (None, None)


def run(args) -> int:
    from rafi.artefact import write_text_atomic
    from rafi.deploy.record_plan import read_plan
    from rafi.family.prior import prior_chain
    from rafi.ops.plan import PLAN_TABLE_COLUMNS, plan_csv, plan_limits, plan_programme
    from rafi.settings import read_machine_config, run_settings

    if not math.isfinite(args.hours) or args.hours <= 0:
        raise SettingsError(f"--hours {args.hours:g}: expected the recorded machine time in hours, above 0")
    config_path = Path(args.config)
    config, settings = read_machine_config(config_path, args.machine)
    project = config_path.resolve().parent
    results = project / run_settings(config)["results_dir"]
    setting = prior_setting(args.prior, settings["models"]["prior"])
    chain = prior_chain(results, args.machine, setting)
    prior = chain[0] if chain else None
    speeds = [float(s) for s in settings["training_speeds_rpm"] or []]
    if not speeds:
        raise SettingsError(
            f"machine {args.machine!r} has no training_speeds_rpm in {short_path(config_path)}: "
            "the plan chooses among them"
        )
    limits = plan_limits(settings)
    limits["transient_s"] = float(
        ((prior or {}).get("interval") or {}).get("transient_s") or limits["transient_s"]
    )
    table = plan_programme(
        speeds_rpm=speeds,
        budget_h=float(args.hours),
        speed_range=tuple(args.speed_range) if args.speed_range else None,
        uncertainty=speed_uncertainty(prior, speeds),
        name=f"requal_{args.machine}"[:80],
        **limits,
    )
    out = Path(args.out or f"plan_{args.machine}.csv")
    write_text_atomic(out, plan_csv(table))
    plan = read_plan(out)  # the recorder's own reader accepts what was written
    print(plan_header(args.machine, prior, plan.total_s, out))
    print(table[list(PLAN_TABLE_COLUMNS)].to_string(index=False))
    return 0


def plan_header(machine: str, prior: dict | None, total_s: float, out: Path) -> str:
    """The lines above the table: the prior, the length, the file and what to do with it."""
    if prior:
        who = f"prior {str(prior.get('model_id', ''))[:12]} ({prior.get('kind', '?')}"
        who += f", champion of {prior.get('machine')})" if prior.get("machine") else ")"
    else:
        who = "no prior (the programme of a first qualification in the same budget)"
    return (
        f"rafi plan: {machine}: {who}; {total_s / 3600:.2f} h -> {short_path(out)}\n"
        f"  record it: rafi record --machine {machine} --plan {short_path(out)}"
    )
