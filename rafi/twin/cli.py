"""Write raw logs from the spindle digital twin (rafi.twin, see docs/twin.md).

Modes:
  shipped   regenerate the shipped data set byte for byte:
              rafi simulate shipped --out raw
  day       write "a new day" of logs for a machine (new file names, never overwrites), e.g.
              rafi simulate day --machine tapping-center-a --out raw --seed 7 \\
                  --ambient-shift 3.0 --sensor-drift T8:0.4 --wear 0.1 \\
                  --speeds 3000,6000 --validation-speeds 4500 --multi
  hostile   write logs that look valid but are wrong (units, sign, channels, ...) beside a
            machine's files, with the outcome each must get (docs/raw-format.md, "Checks"):
              rafi simulate hostile --out /tmp/try/raw/tapping-center-a --shipped raw/tapping-center-a
  plot      plot temperatures and displacement of logs (paper Figure 9 style):
              rafi simulate plot raw/tapping-center-a --out docs/img
  layout    write the logs of a machine that is not the paper's rig (its own sensors and
            files, docs/twin.md "Layouts") and print the config block that reads them:
              rafi simulate layout sensors-6-diameter --out /tmp/try/raw
  foreign   write a random machine nobody tuned on (4-40 own sensors, test days partly outside
            the training range) as a project's data: raw/, config.yaml and truth.json:
              rafi simulate foreign --seed 7 --out /tmp/foreign-7

Run "rafi simulate MODE --help" for the options of each mode.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _speeds(text: str) -> list[int]:
    if text is None or text.strip() == "":
        return []
    try:
        return [int(float(v)) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated speeds in r/min, got {text!r}") from None


def _drift(text: str) -> tuple[str, float]:
    name, sep, value = text.partition(":")
    name = name.strip().upper()
    try:
        if not sep or not name.startswith("T") or not 1 <= int(name[1:]) <= 16:
            raise ValueError
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected SENSOR:KELVIN such as T8:0.4, got {text!r}") from None


def _add_shipped_mode(sub: argparse._SubParsersAction, formatter: type[argparse.HelpFormatter]) -> None:
    """``shipped``: regenerate the shipped data set."""
    mode = sub.add_parser(
        "shipped",
        formatter_class=formatter,
        help="regenerate the shipped raw data set (byte for byte)",
        description="Regenerate the shipped data set: raw/tapping-center-a/*.csv "
        "(12 native logs) and raw/machining-center-b/"
        "thermal_log_2026-10-14.xlsx. Output is deterministic.",
    )
    mode.add_argument("--out", default="raw", help="raw data folder; files go to OUT/<machine>/")
    mode.add_argument(
        "--machine",
        action="append",
        choices=["tapping-center-a", "machining-center-b"],
        help="only this machine (repeatable); default: both",
    )


def _add_day_mode(sub: argparse._SubParsersAction, formatter: type[argparse.HelpFormatter]) -> None:
    """``day``: a new day of logs for a machine, with its room, drift, wear and speeds."""
    mode = sub.add_parser(
        "day",
        formatter_class=formatter,
        help="write a new day of logs for a machine (for retraining tests)",
        description="Simulate a new day of logs for a machine and write them with "
        "new file names (date and seed in the name; existing files are "
        "never overwritten). tapping-center-a: one native CSV per run; "
        "machining-center-b: one continuous xlsx in its own layout.",
    )
    mode.add_argument(
        "--machine",
        default="tapping-center-a",
        choices=["tapping-center-a", "machining-center-b"],
        help="machine id",
    )
    mode.add_argument("--out", default="raw", help="raw data folder; files go to OUT/<machine>/")
    mode.add_argument("--seed", type=int, default=1, help="random seed (noise, defects, room wander)")
    mode.add_argument(
        "--date", default=None, help="day of the logs, YYYY-MM-DD; default 2026-04-01 plus SEED days"
    )
    mode.add_argument(
        "--ambient-shift", type=float, default=0.0, help="room temperature shift against the shipped days, K"
    )
    mode.add_argument(
        "--sensor-drift",
        type=_drift,
        action="append",
        default=[],
        metavar="SENSOR:K",
        help="calibration drift of one sensor, e.g. T8:0.4 (repeatable)",
    )
    mode.add_argument(
        "--wear", type=float, default=0.0, help="relative increase of bearing friction (0.1 = +10 %%)"
    )
    mode.add_argument(
        "--speeds",
        type=_speeds,
        default=None,
        metavar="LIST",
        help="training speeds to run (constant, 4 h each, cold start), comma-separated "
        "r/min; default: the machine's training speeds",
    )
    mode.add_argument(
        "--validation-speeds",
        type=_speeds,
        default=[],
        metavar="LIST",
        help="validation speeds (constant, 3 h each), comma-separated r/min",
    )
    mode.add_argument(
        "--multi", action="store_true", help="also write the 4.5 h multi-condition run (tapping-center-a)"
    )
    mode.add_argument(
        "--hours", type=float, default=None, help="duration of each training run in hours (default 4)"
    )
    mode.add_argument(
        "--sibling",
        type=int,
        default=None,
        metavar="SEED",
        help="another machine of the same series: every physical constant spread by a seeded "
        "build factor (docs/twin.md, re-qualification scenarios)",
    )
    mode.add_argument(
        "--name",
        default=None,
        help="the machine's name in the project: its folder under OUT and the name in the logs' "
        "header (default: --machine; e.g. a sibling of the series)",
    )
    mode.add_argument(
        "--plan",
        default=None,
        metavar="PLAN.csv",
        help="run a test plan (rafi plan, rafi record --plan): its recordings are the training "
        "runs (tapping-center-a: one cold start each); --speeds then defaults to none",
    )
    mode.add_argument("--no-defects", action="store_true", help="write clean logs (no logger defects)")
    mode.add_argument(
        "--stuck-displacement",
        action="store_true",
        help="deliberately broken logs: the displacement freezes after 25 %% of each run",
    )


def _add_noise_floor_mode(sub: argparse._SubParsersAction, formatter: type[argparse.HelpFormatter]) -> None:
    """``noise-floor``: the max residual a perfect model would leave on each shipped run."""
    mode = sub.add_parser(
        "noise-floor",
        formatter_class=formatter,
        help="max residual a perfect model would leave on each shipped run",
        description="Simulate the shipped validation runs again without logger "
        "defects and print, per run, the max |displacement noise| "
        "(log minus the noise-free truth, referenced like dz): the "
        "smallest max residual any model can reach on that run.",
    )
    mode.add_argument(
        "--machine", default="tapping-center-a", choices=["tapping-center-a"], help="machine id"
    )


def _add_hostile_mode(sub: argparse._SubParsersAction, formatter: type[argparse.HelpFormatter]) -> None:
    """``hostile``: the hostile-log corpus beside a machine's files."""
    mode = sub.add_parser(
        "hostile",
        formatter_class=formatter,
        help="write the hostile-log corpus (wrong units, sign, channels, ...) with its ground truth",
        description="Derive logs that look valid but are wrong from the shipped tapping-center-a "
        "logs, write them into OUT (a machine folder) and print, per file, the check that must "
        "catch it and how (quarantined, rejected, warning, flagged, not_read). Never writes "
        "into the shipped folder.",
    )
    mode.add_argument("--out", required=True, help="machine folder to write into, e.g. /tmp/try/raw/m")
    mode.add_argument(
        "--shipped",
        default="raw/tapping-center-a",
        help="the shipped tapping-center-a logs; if they are not there, the twin simulates them again",
    )
    mode.add_argument("--long-bytes", type=int, default=200_000, help="length of the oversized line")


def _add_plot_mode(sub: argparse._SubParsersAction, formatter: type[argparse.HelpFormatter]) -> None:
    """``plot``: temperatures and displacement of logs against time."""
    mode = sub.add_parser(
        "plot",
        formatter_class=formatter,
        help="plot temperatures and displacement of logs against time",
        description="Plot key sensors, coolant sensors and the displacement of each "
        "native log (Figure 9 style) and an overview of all runs; "
        "images are written as OUT/twin-<file stem>.png and "
        "OUT/twin-overview.png.",
    )
    mode.add_argument("folder", help="folder with native logs, e.g. raw/tapping-center-a")
    mode.add_argument("--out", default="docs/img", help="image folder")
    mode.add_argument("--pattern", default="train_*.csv", help="glob of the files to plot")
    mode.add_argument("--sensors", default="T6,T8,T9,T16,T5,T11,T13", help="comma-separated sensors to draw")


def _add_layout_mode(sub: argparse._SubParsersAction, formatter: type[argparse.HelpFormatter]) -> None:
    """``layout``: a machine with its own sensors and files, and the config that reads it."""
    from rafi.twin.layouts import layout_names

    mode = sub.add_parser(
        "layout",
        formatter_class=formatter,
        help="write the logs of a machine in a real-world layout and its config block",
        description="Write the logs of a machine that is not the paper's rig (rafi.twin.layouts: its "
        "own sensors, 4 to 40 of them, its own file format) into OUT/<machine>/ and print "
        "the config block that reads them (machines: <machine>: ...).",
    )
    mode.add_argument("layout", choices=list(layout_names()), help="the layout")
    mode.add_argument("--out", default="raw", help="raw data folder; files go to OUT/<machine>/")
    mode.add_argument("--machine", help="the machine's folder name (default: the layout's name)")
    mode.add_argument("--seed", type=int, default=1, help="seed of the twin's runs")


def _add_foreign_mode(sub: argparse._SubParsersAction, formatter: type[argparse.HelpFormatter]) -> None:
    """``foreign``: a random machine, its config and the truth of its test days."""
    from rafi.twin.foreign import PLANS

    mode = sub.add_parser(
        "foreign",
        formatter_class=formatter,
        help="write a random foreign machine (own sensors, test days partly outside the training range)",
        description="Write the foreign machine of a seed (rafi.twin.foreign: the twin's network with "
        "every constant drawn anew, 4 to 40 sensors of its own, one cold start a day at 60 s, training "
        "days then test days) into OUT: raw/<machine>/*.csv, config.yaml (that machine only) and "
        "truth.json (per test day the fraction of rows outside the training envelope). Into a project "
        "that has a config.yaml: the machine is added under its machines: (the others and the "
        "comments kept), the logs go to its raw_dir and the truth to truth-<machine>.json. With "
        "Snakefile and workflow/ beside them (or snakemake -s <Snakefile> -d OUT) OUT is a project.",
    )
    mode.add_argument("--seed", type=int, required=True, help="the machine's seed (its name: foreign-SEED)")
    mode.add_argument("--out", required=True, help="the project folder to write into")
    mode.add_argument(
        "--setup-drift",
        action="store_true",
        help="the displacement also wanders by what no sensor sees (probe stand, foundation): a slow "
        "walk of 0.5-3 um, drawn per machine",
    )
    mode.add_argument(
        "--realism",
        default="none",
        metavar="EFFECTS",
        help="add what real machines do and the linear twin does not, drawn per machine on a stream of "
        "its own (same machine, days and noise): 'all' or a comma-separated subset of hidden_source (an "
        "unobserved heat source - hydraulics, a neighbouring machine - cycling into the column, head or "
        "motor base, at another level on test days), convection (still-air heat loss ~ dT^1.2-1.33), "
        "fixed_chiller (the oil cooler holds a fixed set point instead of tracking the room), "
        "sensor_mount (1-3 sensors reseated from one test day on: other lag, other share of room air), "
        "warm_start (a test day, 60 %%, starts after only 1-10 h at rest, still warm from the day before); "
        "truth.json says what was drawn and each day's contribution; 'none' gives the plain machine",
    )
    mode.add_argument(
        "--setup-change",
        action="store_true",
        help="from a training day in the second half on, the displacement's largest node gain reaches the "
        "probe only by a factor of -1 to 0 (a fixture or the probe re-clamped: a change no sensor sees, "
        "so the training runs disagree); truth.json says from which day",
    )
    mode.add_argument(
        "--plan",
        choices=PLANS,
        default="varied",
        help="how its days are planned: varied (a qualification: a run at each training speed, speed "
        "steps, test days leaving the range) or production (4-8 sensors, the same job every day in a "
        "shop that warms while it runs, over a season that carries the test days out of the range)",
    )


def _run_foreign(args: argparse.Namespace) -> int:
    """``rafi simulate foreign``: write the machine, print its config block and test days."""
    import yaml

    from rafi.errors import SettingsError
    from rafi.twin.foreign import parse_realism, write_foreign

    try:
        effects = parse_realism(args.realism)
    except ValueError as exc:
        print(f"rafi simulate foreign: --realism: {exc}", file=sys.stderr)
        return 2
    try:
        machine, paths = write_foreign(
            args.seed,
            args.out,
            setup_drift=args.setup_drift,
            realism=effects,
            plan=args.plan,
            setup_change=args.setup_change,
        )
    except SettingsError as exc:
        print(f"rafi simulate foreign: {exc}", file=sys.stderr)
        return 2
    for path in paths:
        print(path, file=sys.stderr)
    for run in machine.truth["test_runs"]:
        print(
            f"{run['stem']} ({run['kind']}): {100 * run['outside_any']:.0f} % of {run['rows']} rows outside "
            f"the training envelope (temperature {100 * run['outside_temperature']:.0f} %, rise "
            f"{100 * run['outside_rise']:.0f} %, speed {100 * run['outside_speed']:.0f} %)",
            file=sys.stderr,
        )
    print(yaml.safe_dump({"machines": {machine.name: machine.config}}, sort_keys=False))
    return 0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The modes of ``rafi simulate`` and their options, added to ``parser``."""
    sub = parser.add_subparsers(dest="mode", metavar="MODE")
    formatter = argparse.ArgumentDefaultsHelpFormatter
    _add_shipped_mode(sub, formatter)
    _add_day_mode(sub, formatter)
    _add_noise_floor_mode(sub, formatter)
    _add_hostile_mode(sub, formatter)
    _add_plot_mode(sub, formatter)
    _add_layout_mode(sub, formatter)
    _add_foreign_mode(sub, formatter)


def run(args: argparse.Namespace) -> int:
    """Carry out the ``rafi simulate`` mode of ``args`` and return the exit status."""
    mode = _MODES.get(getattr(args, "mode", None))
    if mode is None:
        print(
            "rafi simulate: choose a mode: shipped, day, hostile, noise-floor, plot, layout or foreign "
            "(see rafi simulate --help)",
            file=sys.stderr,
        )
        return 2
    return mode(args)


def _run_shipped(args: argparse.Namespace) -> int:
    """rafi simulate shipped."""
    from rafi.twin.writers import write_shipped

    machines = args.machine or ["tapping-center-a", "machining-center-b"]
    for path in write_shipped(args.out, machines=machines):
        print(path)
    return 0


def _run_day(args: argparse.Namespace) -> int:
    """rafi simulate day."""
    from rafi.deploy.record_plan import read_plan
    from rafi.twin.day import write_day

    try:
        plan = read_plan(args.plan) if args.plan else None
        paths = write_day(
            args.out,
            machine=args.machine,
            seed=args.seed,
            date=args.date,
            ambient_shift=args.ambient_shift,
            sensor_drift=dict(args.sensor_drift),
            wear=args.wear,
            speeds=args.speeds,
            validation_speeds=args.validation_speeds,
            multi=args.multi,
            hours=args.hours,
            defects=not args.no_defects,
            stuck_displacement=args.stuck_displacement,
            plan=plan,
            sibling=args.sibling,
            name=args.name,
        )
    except (FileExistsError, ValueError) as exc:
        print(f"rafi simulate day: {exc}", file=sys.stderr)
        return 1
    for path in paths:
        print(path)
    return 0


def _run_noise_floor(args: argparse.Namespace) -> int:
    """rafi simulate noise-floor."""
    from rafi.twin.calibration import noise_floor

    table = noise_floor(args.machine)
    print(table.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    return 0


def _run_hostile(args: argparse.Namespace) -> int:
    """rafi simulate hostile."""
    from rafi.twin.hostile_files import write_hostile_corpus

    out, shipped = Path(args.out).resolve(), Path(args.shipped).resolve()
    if out == shipped:
        print("rafi simulate hostile: --out must not be the shipped folder", file=sys.stderr)
        return 2
    cases = write_hostile_corpus(shipped, out, out.parent.parent / "outside-raw", long_bytes=args.long_bytes)
    for case in cases:
        print(f"{out / case.file}\t{case.check}\t{case.outcome}\t{case.what}")
    return 0


def _run_plot(args: argparse.Namespace) -> int:
    """rafi simulate plot."""
    from rafi.twin.plots import plot_runs

    folder = Path(args.folder)
    files = sorted(folder.glob(args.pattern))
    if not files:
        print(f"rafi simulate plot: no files match {args.pattern!r} in {folder}", file=sys.stderr)
        return 1
    sensors = [s.strip() for s in args.sensors.split(",") if s.strip()]
    for path in plot_runs(files, args.out, sensors=sensors):
        print(path)
    return 0


def _run_layout(args: argparse.Namespace) -> int:
    """rafi simulate layout."""
    import yaml

    from rafi.twin.layouts import LAYOUTS, layout_config, write_layout

    machine = args.machine or LAYOUTS[args.layout].name
    for path in write_layout(args.layout, args.out, seed=args.seed, machine=machine):
        print(path, file=sys.stderr)
    print(
        yaml.safe_dump(
            {"machines": {machine: layout_config(args.layout)}}, sort_keys=False, allow_unicode=True
        )
    )
    return 0


#: ``rafi simulate <mode>`` -> the function that carries it out.
_MODES = {
    "shipped": _run_shipped,
    "day": _run_day,
    "noise-floor": _run_noise_floor,
    "hostile": _run_hostile,
    "plot": _run_plot,
    "layout": _run_layout,
    "foreign": _run_foreign,
}
