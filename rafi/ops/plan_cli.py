"""``rafi plan``: the shortest test programme that re-qualifies a machine from a prior.

The programme (:func:`rafi.ops.plan.plan_programme`, ``docs/operations.md``, "Re-qualification
in hours" and "A programme shaped by the prior") is built from:

* the **prior**: the model the re-qualification starts from, resolved as rule compare resolves
  it (``models.prior``, :func:`rafi.family.prior.prior_chain`; ``--prior`` overrides it here) and
  refused as the night refuses it: a model of a machine that is neither this one nor declared in
  ``models.prior_siblings`` stops the command with the night's one line
  (:func:`rafi.family.prior.check_origin`, :class:`rafi.errors.PriorForeign`, exit status 64),
  read by :func:`rafi.ops.plan.prior_view`: the speeds it was trained at, its interval's half
  widths, its slowest time constant (a CV-weighted ensemble read whole: its members' speeds and
  ranges, its own interval, the time constants of the member the adaptation re-fits);
* the **speeds**: the machine's ``training_speeds_rpm`` inside ``--speed-range`` (the range the
  machine is used in: paper item 10), those the prior never trained at first;
* the machine's **resolved settings**: the shortest run (``runs.min_run_s``,
  ``runs.min_constant_s``), the rest before the first heat-up (under
  ``runs.max_leading_rest_s``), the speed tolerance;
* the **budget**: ``--hours`` of recorded machine time (default 4).

It prints the programme, one step a line with the reason it is there, and writes it as a test
plan CSV (``docs/record.md``, "The test plan") that ``rafi record --plan`` follows on the machine
and ``rafi simulate day --plan`` follows on the twin. The file is checked by reading it back with
the recorder's own reader.
"""

from __future__ import annotations

import math
from pathlib import Path

from rafi.cli import add_config_option
from rafi.errors import SettingsError, short_path
from rafi.family.confirmation import confirmation_entry

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


def run(args) -> int:
    from rafi.artefact import write_text_atomic
    from rafi.deploy.record_plan import read_plan
    from rafi.family.prior import check_origin, prior_chain, source_unit
    from rafi.ops.plan import (
        covering_budget_h,
        plan_csv,
        plan_limits,
        plan_programme,
        plan_text,
        prior_speeds_left,
        prior_view,
    )
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
    if prior is not None:  # a prior the night would refuse is refused here, before hours are recorded
        source = source_unit(results, setting, args.machine)[1]
        check_origin(prior, args.machine, settings["models"]["prior_siblings"] or (), source)
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
    tolerance = float(settings["speed_tolerance_rpm"])
    programme = dict(
        speeds_rpm=speeds,
        speed_range=tuple(args.speed_range) if args.speed_range else None,
        prior=prior_view(prior, tolerance_rpm=tolerance),
        name=f"requal_{args.machine}"[:80],
        **limits,
    )
    table = plan_programme(budget_h=float(args.hours), **programme)
    out = Path(args.out or f"plan_{args.machine}.csv")
    write_text_atomic(out, plan_csv(table))
    plan = read_plan(out)  # the recorder's own reader accepts what was written
    print(plan_header(args.machine, prior, plan.total_s, out))
    print(plan_text(table))
    left = prior_speeds_left(table, prior, tolerance_rpm=tolerance)
    if left:
        budget = covering_budget_h(prior, tolerance_rpm=tolerance, **programme)
        print(speeds_left_text(left, prior, budget, args.speed_range is not None, tolerance_rpm=tolerance))
    return 0


def speeds_left_text(
    left: list[float], prior: dict, budget_h: float | None, ranged: bool, *, tolerance_rpm: float = 0.0
) -> str:
    """The line under the table when the programme leaves speeds of the prior untested: which (and
    those the prior itself had only from its own prior, :func:`rafi.family.prior_fitness.inherited_speeds`),
    what the night will do about them, and the budget that tests them all (or why none does)."""
    from rafi.family.prior_fitness import inherited_speeds, inherited_text

    pid = str(prior.get("model_id", ""))[:12]
    older = inherited_text(inherited_speeds(prior, left, tolerance_rpm=tolerance_rpm))
    speeds = ", ".join(f"{s:g}" for s in left)
    if budget_h is not None:
        cover = f"--hours {budget_h:g} tests them all"
    else:
        where = "inside --speed-range" if ranged else "of this machine's training_speeds_rpm"
        cover = f"no programme {where} tests them all"
    return (
        f"  left to the prior alone: {speeds} r/min (trained by the prior, untested here{older}); the "
        f"night's fitness warning prior_speeds blocks the promotion until confirmed (checks.confirmed: "
        f"{confirmation_entry(pid, 'prior_speeds')}); {cover}"
    )


def plan_header(machine: str, prior: dict | None, total_s: float, out: Path) -> str:
    """The lines above the table: the prior, the length, the file and what to do with it."""
    from rafi.family.prior import ENSEMBLE_KIND

    if prior:
        who = f"prior {str(prior.get('model_id', ''))[:12]} ({prior.get('kind', '?')}"
        if prior.get("kind") == ENSEMBLE_KIND:  # read whole: its members' speeds, its own interval
            who += f" of {len(prior.get('weights') or {})} members"
        who += f", champion of {prior.get('machine')})" if prior.get("machine") else ")"
    else:
        who = "no prior (the programme of a first qualification in the same budget)"
    return (
        f"rafi plan: {machine}: {who}; {total_s / 3600:.2f} h -> {short_path(out)}\n"
        f"  record it: rafi record --machine {machine} --plan {short_path(out)}"
    )
