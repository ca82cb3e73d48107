"""Run the qualified model live beside the controller (docs/deploy.md, "Live: OPC UA").

Every deploy.interval_s seconds: read the spindle speed and the temperatures (from the
OPC UA nodes of deploy.opcua.inputs, or from a log file as a logger appends to it, --follow),
compute the compensation with the limits and fault rules in force, and write it to the target
of deploy.target (a SINUMERIK over OPC UA, or a CSV / JSON-lines file). Only the registry's
champion (or --model, if it is the champion) is loaded; anything else is refused before
connecting.

Exit status: 0 done (--cycles reached, or stopped by Ctrl-C / SIGTERM: the target is closed
and the last value stays on the controller); 64 a settings or credentials mistake, or a login
the server refuses; 65 no qualified model, or a target that refuses the limits; 69 the
controller cannot be reached at start (a connection lost later is retried, not an exit).
"""

from __future__ import annotations

import json
import signal
import sys
import time
from pathlib import Path

from rafi.errors import RafiUserError, SettingsError

EX_UNAVAILABLE = 69


def add_arguments(parser) -> None:
    parser.add_argument(
        "--machine", required=True, help="the machine (its settings and results/<machine>/registry)"
    )
    parser.add_argument("--config", default="config.yaml", help="config file (default: config.yaml)")
    parser.add_argument(
        "--model",
        help="a model artefact (JSON); it must be the registry's champion (default: load the champion)",
    )
    parser.add_argument(
        "--follow", metavar="LOGFILE", help="read the inputs from this native CSV log as it is written"
    )
    parser.add_argument(
        "--dry-run",
        action="store_true",
        help="compute and print, write nothing to the controller or the target file",
    )
    parser.add_argument("--cycles", type=int, help="stop after this many cycles (default: run until Ctrl-C)")


def _load_model(args, results_dir: Path) -> dict:
    from rafi.deploy.qualified import check_qualified, load_champion
    from rafi.ops.registry import registry_dir

    root = registry_dir(results_dir, args.machine)
    if not args.model:
        return load_champion(root)
    try:
        artefact = json.loads(Path(args.model).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise RafiUserError(f"--model {args.model}: cannot read the artefact ({exc})") from None
    check_qualified(artefact, root)
    return artefact


class _DryTarget:
    """Stands in for a file target in a dry run: same checks, writes nothing."""

    def __init__(self, target):
        from rafi.deploy.target_base import Target

        class Dry(Target):
            name = target.name

            def _open(self):
                pass

            def _write(self, time_s, values_um, status):
                pass

            def _close(self):
                pass

        self.target = Dry(target.axes)


def build(args, *, log=print, environ=None):
    """The loop of ``rafi deploy`` and the link to close afterwards (None without OPC UA).

    Everything is checked (settings, the model's qualification, the target against the limits)
    before anything connects; nothing is written here.
    """
    import yaml

    from rafi.deploy.limits import Limits, SafeCompensator
    from rafi.deploy.live import LinkSource, LiveLoop, LogFollower, build_target, check_target_limits
    from rafi.deploy.target_sinumerik import DrySink
    from rafi.settings import machine_settings, run_settings

    config_path = Path(args.config)
    try:
        config = yaml.safe_load(config_path.read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise SettingsError(f"{config_path}: cannot read the config ({exc})") from None
    project = config_path.resolve().parent
    deploy = machine_settings(config, args.machine)["deploy"]
    limits = Limits.from_settings(deploy)
    artefact = _load_model(args, project / run_settings(config)["results_dir"])
    safe = SafeCompensator(limits=limits).load(artefact)

    target_block = deploy.get("target")
    kind = (target_block or {}).get("kind") if isinstance(target_block, dict) else None
    needs_link = not args.follow or (kind == "sinumerik" and not args.dry_run)
    link = None
    if needs_link:
        from rafi.deploy.opcua_client import OpcUaLink, load_credentials, opcua_settings

        opcua = opcua_settings(deploy.get("opcua"), need_inputs=not args.follow)
        if not args.follow:
            from rafi import SENSORS

            needed = [SENSORS[i] for i in safe.compensator_.sensor_index]
            missing = [s for s in needed if s not in opcua["inputs"]]
            if missing:
                raise SettingsError(
                    f"deploy.opcua.inputs has no node for {missing}: the model reads {needed}"
                )
        user, password = load_credentials(opcua, project_dir=project, environ=environ)
        link = OpcUaLink(opcua, user=user, password=password, log=log)
    sink = DrySink() if args.dry_run else link
    target, axis = build_target(target_block, sink=sink, project_dir=project)
    check_target_limits(target, axis, limits)
    if args.dry_run and kind in ("csv", "jsonl"):
        target = _DryTarget(target).target
    if args.follow:
        source = LogFollower(args.follow, log=log)
    else:
        source = LinkSource(link)
    loop = LiveLoop(
        source, safe, target, axis=axis, interval_s=limits.interval_s,
        link=link if (link is not None and (not args.follow or sink is link)) else None,
        log=log,
    )  # fmt: skip
    loop.model_id = artefact["model_id"]
    return loop, link


def _stop_on_sigterm(signum, frame):
    raise KeyboardInterrupt


def run(args) -> int:
    if args.cycles is not None and args.cycles < 1:
        raise SettingsError(f"--cycles {args.cycles}: expected 1 or more")
    loop, link = build(args)
    previous = signal.signal(signal.SIGTERM, _stop_on_sigterm)
    try:
        if link is not None:
            try:
                link.connect()
            except ConnectionError as exc:
                print(f"rafi deploy: {exc}", file=sys.stderr)
                return EX_UNAVAILABLE
        print(
            f"rafi deploy: {args.machine}: model {loop.model_id[:12]}"
            f" -> {loop.target.name} axis {loop.axis} every {loop.interval_s:g} s"
            f"{' (dry run)' if args.dry_run else ''}; Ctrl-C stops",
            flush=True,
        )
        started = time.monotonic()
        try:
            loop.run(max_cycles=args.cycles)
        except KeyboardInterrupt:
            print("rafi deploy: stopped; the target is closed, the last value stays on the controller")
        print(
            f"rafi deploy: {loop.cycles} cycles, {loop.writes} writes, {loop.outage_cycles} cycles without "
            f"the controller, {time.monotonic() - started:.0f} s"
        )
        return 0
    finally:
        signal.signal(signal.SIGTERM, previous)
        if link is not None:
            link.close()
