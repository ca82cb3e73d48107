"""The ``rafi`` console command: one sub-command per tool.

Each sub-command lives in the module that does the work and exposes
``add_arguments(parser)`` and ``run(args) -> int``; this file only wires them up.

A user error (:class:`rafi.errors.RafiUserError`: a bad raw file, a bad ``config.yaml``) that
reaches this level prints one line, ``rafi <command>: <message>``, and exits with its status:
64 (``EX_USAGE``) for a configuration or usage mistake, 65 (``EX_DATAERR``) for bad data.
``rafi --debug <command>`` prints the traceback as well (and sets ``args.debug``, which a
command passes on, e.g. as the run setting ``debug``). Other exit statuses are the command's
own (``rafi nightly``: docs/operations.md).
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import sys
import traceback

#: sub-command -> (module, one-line help)
COMMANDS = {
    "simulate": ("rafi.twin.cli", "write raw logs from the spindle digital twin"),
    "init": ("rafi.ops.init_cli", "read a new machine's logs, say what they hold, propose its config block"),
    "nightly": ("rafi.ops.nightly", "retrain, qualify and promote models (for cron / systemd)"),
    "settings": ("rafi.settings", "print the effective settings of a machine (every default filled in)"),
    "diff": ("rafi.ops.result_diff", "compare two result trees number by number (timings, ids aside)"),
    "status": ("rafi.ops.fleet_cli", "every machine: model in service, decision, drift; urgent first"),
    "deploy": ("rafi.deploy.live_cli", "run the qualified model live: inputs in, compensation out"),
    "record": ("rafi.deploy.record_cli", "record a qualification test: speed, temperatures, probe -> raw/"),
    "plan": ("rafi.ops.plan_cli", "the shortest test programme that re-qualifies a machine from a prior"),
    "certificate": (
        "rafi.deploy.certificate_cli",
        "create the OPC UA client certificate and key of rafi deploy",
    ),
    "replay": (
        "rafi.deploy.replay_cli",
        "replay recorded runs through the compensator with the limits in force",
    ),
}


#: The option naming the pipeline config, the same on every command; ``--config-file`` (the
#: spelling of ``rafi nightly`` and ``rafi status`` before issue 45) is kept as a hidden alias.
CONFIG_OPTION = "--config"
#: Exit status when the reader of the output closed the pipe early (128 + SIGPIPE, as a shell
#: reports a command killed by it).
EXIT_BROKEN_PIPE = 141
CONFIG_ALIAS = "--config-file"


def add_config_option(parser: argparse.ArgumentParser, relative_to: str | None = None) -> None:
    """Add ``--config PATH`` (default ``config.yaml``; ``args.config``) to a command's ``parser``,
    with the hidden alias ``--config-file``. ``relative_to``: the option the path is relative
    to, named in the help (e.g. ``--directory``)."""
    where = f", relative to {relative_to}" if relative_to else ""
    text = f"pipeline config (default config.yaml{where})"
    parser.add_argument(CONFIG_OPTION, dest="config", default="config.yaml", help=text)
    parser.add_argument(CONFIG_ALIAS, dest="config", default=argparse.SUPPRESS, help=argparse.SUPPRESS)


_ROLE = re.compile(r":[a-z]+:`~?(?:[\w.]*\.)?([^`]+)`")


def plain_text(docstring: str) -> str:
    """A docstring as a user reads it in ``--help``: no reStructuredText roles or literals
    (``:func:`rafi.x.f``` -> ``f``, double backquotes dropped)."""
    return _ROLE.sub(r"\1", docstring).replace("``", "")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rafi",
        description="RAFI thermal-displacement compensation for CNC spindles: the tools beside "
        "the pipeline (run the pipeline itself with `snakemake --cores 2`).",
    )
    from rafi import __version__

    parser.add_argument("--version", action="version", version=f"rafi {__version__}")
    parser.add_argument(
        "--debug",
        action="store_true",
        help="a user error (bad file, bad config) prints its traceback too, not one line only",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, help_text) in COMMANDS.items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name != module_name:
                raise
            continue
        p = sub.add_parser(
            name,
            help=help_text,
            description=plain_text(
                getattr(module, "CLI_DESCRIPTION", None) or module.__doc__ or help_text
            ).strip(),
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    from rafi.errors import RafiUserError

    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except RafiUserError as exc:
        if args.debug:
            traceback.print_exc()
        print(f"rafi {args.command}: {exc}", file=sys.stderr)
        return exc.exit_status
    except BrokenPipeError:
        # the reader of our output went away (`rafi plan ... | head`): no traceback; the
        # Python documentation's recipe (signal's "Note on SIGPIPE"), so that the flush at exit
        # does not raise again
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_BROKEN_PIPE


if __name__ == "__main__":
    sys.exit(main())
