"""Run the qualified model live beside the controller (docs/deploy.md, "Live: OPC UA").

Every deploy.interval_s seconds: read the spindle speed and the temperatures (from the
OPC UA nodes of deploy.opcua.inputs, or from a log file as a logger appends to it, --follow),
compute the compensation with the limits and fault rules in force, and write it to the target
of deploy.target (a SINUMERIK over OPC UA, or a CSV / JSON-lines file). Only the registry's
champion (--model champion, the default, or --model PATH if it is the champion) is loaded;
anything else is refused before connecting. After connecting, a preflight checks every node
before anything is written; the command starts from the value the controller holds and moves
from it at the rate limit (docs/deploy.md, Transitions).

Exit status: 0 done (--cycles reached, or stopped by Ctrl-C / SIGTERM in any phase: the
target is closed and the last value stays on the controller); 64 a settings mistake (an unknown
machine, a wrong node, a node of the wrong type or not writable, missing credentials, a login
the server refuses); 65 the model (no qualified model, another machine's model) or the
controller's value (outside deploy.clamp_um) or a target that refuses the limits; 69 the
controller cannot be reached at start (a connection lost later is retried, not an exit). With
--wait-for-controller (the systemd unit passes it, docs/service.md) a controller that cannot be
reached at start is waited for instead: tried every second, one line a minute, never exit 69.
"""

from __future__ import annotations

import json
import signal
import sys
import time
import traceback
from pathlib import Path

from rafi.cli import add_config_option
from rafi.deploy.opcua_reconnect import add_wait_option, prefixed
from rafi.errors import EX_USAGE, RafiUserError, SettingsError

EX_UNAVAILABLE = 69


def add_arguments(parser) -> None:
    parser.add_argument(
        "--machine", required=True, help="the machine (its settings and results/<machine>/registry)"
    )
    add_config_option(parser)
    parser.add_argument(
        "--model",
        default="champion",
        help="champion (the registry's, the default) or the path of a model artefact (JSON), which "
        "must be the registry's champion",
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
    add_wait_option(parser)


def _load_model(args, config: dict, project: Path) -> tuple[dict, Path]:
    """The qualified model of ``args.machine`` and its registry (nothing else is accepted)."""
    from rafi.deploy.qualified import check_belongs, check_machine, check_qualified, load_champion
    from rafi.ops.registry import registry_dir
    from rafi.settings import run_settings

    run = run_settings(config)
    results_dir = project / run["results_dir"]
    check_machine(args.machine, config, results_dir, project / run["raw_dir"])
    root = registry_dir(results_dir, args.machine)
    if not args.model or args.model == "champion":
        artefact = load_champion(root)
    else:
        try:
            artefact = json.loads(Path(args.model).read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise RafiUserError(f"--model {args.model}: cannot read the artefact ({exc})") from None
        check_qualified(artefact, root)
    check_belongs(artefact, args.machine)
    return artefact, root


class _DryTarget:
    """Stands in for a file target in a dry run: same checks, writes nothing."""

    def __init__(self, target):
        from rafi.deploy.target_base import Target

        class Dry(Target):
            name = target.name

            def read_current_um(self):
                return target.read_current_um()

            def _open(self):
                pass

            def _write(self, time_s, values_um, status):
                pass

            def _close(self):
                pass

        self.target = Dry(target.axes)


def _link(args, deploy: dict, safe, kind, *, project: Path, log, environ):
    """The OPC UA link of ``rafi deploy`` (None without OPC UA) and the user, checked."""
    needs_link = not args.follow or (kind == "sinumerik" and not args.dry_run)
    if not needs_link:
        return None, None
    from rafi.deploy.opcua_client import OpcUaLink, load_credentials, opcua_settings, require_credentials

    opcua = opcua_settings(deploy.get("opcua"), need_inputs=not args.follow, project_dir=project)
    if not args.follow:
        comp = safe.compensator_
        needed = [comp.sensors[i] for i in comp.sensor_index]
        missing = [s for s in needed if s not in opcua["inputs"]]
        if missing:
            raise SettingsError(f"deploy.opcua.inputs has no node for {missing}: the model reads {needed}")
    if args.dry_run:  # reads only: no login, so that credentials meant for writing are not needed
        user, password = None, None
    else:
        user, password = load_credentials(opcua, project_dir=project, environ=environ)
    if kind == "sinumerik" and not args.dry_run:
        require_credentials(user, opcua)
    return OpcUaLink(opcua, user=user, password=password, log=prefixed(log, "rafi deploy")), user


def build(args, *, log=print, environ=None):
    """The loop of ``rafi deploy`` and the link to close afterwards (None without OPC UA).

    Everything is checked (the machine, settings, the model's qualification and machine, the
    credentials, the target against the limits) before anything connects; nothing is written
    here. ``loop.preflight_spec`` holds what :func:`rafi.deploy.preflight.preflight` checks
    after connecting (None without a link).
    """
    import yaml

    from rafi.deploy.champion_watch import ChampionWatch
    from rafi.deploy.limits import Limits, SafeCompensator
    from rafi.deploy.live import LinkSource, LiveLoop, LogFollower, build_target, check_target_limits
    from rafi.deploy.metrics import metrics_from_settings
    from rafi.deploy.sd_notify import SdNotify
    from rafi.deploy.target_sinumerik import DrySink
    from rafi.settings import machine_settings

    config_path = Path(args.config)
    try:
        config = yaml.safe_load(config_path.read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise SettingsError(f"{config_path}: cannot read the config ({exc})") from None
    project = config_path.resolve().parent
    artefact, registry = _load_model(args, config, project)
    settings = machine_settings(config, args.machine)
    deploy, sensors = settings["deploy"], settings["input"]["sensors"]
    limits = Limits.from_settings(deploy)
    safe = SafeCompensator(limits=limits).load(artefact, sensors)

    target_block = deploy.get("target")
    kind = (target_block or {}).get("kind") if isinstance(target_block, dict) else None
    link, user = _link(args, deploy, safe, kind, project=project, log=log, environ=environ)
    sink = DrySink() if args.dry_run else link
    target, axis = build_target(target_block, sink=sink, project_dir=project)
    check_target_limits(target, axis, limits)
    if args.dry_run and kind in ("csv", "jsonl"):
        target = _DryTarget(target).target
    source = LogFollower(args.follow, log=log, sensors=sensors) if args.follow else LinkSource(link, sensors)
    watch = ChampionWatch(registry, artefact["model_id"], check_s=deploy["champion_check_s"], log=log)
    metrics = metrics_from_settings(deploy, machine=args.machine, log=log)
    if metrics is not None:
        metrics.model(artefact["model_id"])
    loop = LiveLoop(
        source, safe, target, axis=axis, interval_s=limits.interval_s,
        link=link if (link is not None and (not args.follow or sink is link)) else None,
        log=log, champion=watch, metrics=metrics, notify=SdNotify(log=log),
        session=_session(args, config, project, deploy),
    )  # fmt: skip
    loop.model_id = artefact["model_id"]
    loop.preflight_spec = None
    if link is not None:
        outputs = target.output_nodes() if kind == "sinumerik" else []
        inputs = {} if args.follow else {name: spec[0] for name, spec in link.inputs.items()}
        loop.preflight_spec = dict(inputs=inputs, outputs=outputs, write=not args.dry_run, user=user)
    return loop, link


def _session(args, config: dict, project: Path, deploy: dict):
    """The session kept across a restart (``results/<unit>/deploy/session.json``; a dry run
    reads it and writes nothing)."""
    from rafi.deploy.session import SessionFile, SessionKeeper, session_path
    from rafi.settings import run_settings

    path = session_path(project / run_settings(config)["results_dir"], args.machine)
    return SessionKeeper(
        SessionFile(path, write=not args.dry_run),
        unit=args.machine,
        clock="log" if args.follow else "session",
        cold_band_k=deploy["cold_band_k"],
        max_age_h=deploy["session_max_age_h"],
        wall=time.time,
    )


def _plural(n: int, word: str) -> str:
    return f"{n} {word}" if n == 1 else f"{n} {word}s"


def _summary(loop, args, seconds: float) -> str:
    writes = (
        f"would write {_plural(loop.writes, 'value')} (dry run: nothing written)"
        if args.dry_run
        else _plural(loop.writes, "write")
    )
    return (
        f"rafi deploy: {_plural(loop.cycles, 'cycle')}, {writes}, {_plural(loop.outage_cycles, 'cycle')} "
        f"without the controller, {seconds:.0f} s"
    )


def _connect_and_check(loop, link, args, state: _State) -> int | None:
    """Connect (or, with ``--wait-for-controller``, wait for the controller), run the preflight
    and, in a dry run, copy the controller's values into the dry sink; an exit status to return,
    or None to go on. Waiting, a connection lost during the preflight is waited for again."""
    from rafi.deploy.opcua_reconnect import wait_for_controller
    from rafi.deploy.preflight import preflight

    wait = getattr(args, "wait_for_controller", False)

    def waiting() -> None:
        state.phase = "waiting for the controller"
        if loop.metrics is not None:
            loop.metrics.connection(False)

    while True:
        state.phase = "connecting"
        try:
            if wait:
                wait_for_controller(link, log=_print_line, notify=loop.notify, on_wait=waiting)
            else:
                link.connect()
            state.phase = "checking the nodes (preflight)"
            problems = preflight(link, **loop.preflight_spec)
            if problems:
                for line in problems:
                    print(f"rafi deploy: preflight: {line}", file=sys.stderr)
                print(f"rafi deploy: {_plural(len(problems), 'problem')}: nothing written", file=sys.stderr)
                return EX_USAGE
            if args.dry_run and hasattr(loop.target, "sink"):
                for node in loop.preflight_spec["outputs"]:
                    loop.target.sink.start[node] = link.read_value(node)
        except ConnectionError as exc:
            if not wait:
                print(f"rafi deploy: {exc}", file=sys.stderr)
                return EX_UNAVAILABLE
            _print_line(f"{exc}; waiting for the controller again")
            continue
        return None


def _print_line(message: str) -> None:
    print(f"rafi deploy: {message}", flush=True)


class _State:
    """Where ``rafi deploy`` is, for the one line of a stop (Ctrl-C / SIGTERM)."""

    def __init__(self):
        self.phase = "starting"
        self.signal = "Ctrl-C"
        self.loop = None
        self.target_opened = False

    def stop_on_sigterm(self, signum, frame):
        """SIGTERM (systemd's stop) stops as Ctrl-C does."""
        self.signal = "SIGTERM"
        raise KeyboardInterrupt


def _stopped_line(state: _State) -> str:
    phase = state.phase
    if phase == "running" and state.loop is not None:  # where the loop was when it was stopped
        phase = getattr(state.loop, "stopped_in", None) or state.loop.phase
    if state.target_opened:
        what = "the target is closed, the last value stays on the controller"
    else:
        what = "nothing was written; the controller keeps its value"
    return f"rafi deploy: stopped while {phase} ({state.signal}); {what}"


def _service_ready(loop) -> None:
    """Tell systemd (``Type=notify``) and the metrics that the loop runs (``docs/service.md``)."""
    if loop.metrics is not None:
        loop.metrics.connection(loop.link is None or bool(loop.link.connected))
    warning = loop.notify.interval_warning(loop.interval_s)
    if warning:
        print(f"rafi deploy: {warning}", file=sys.stderr)
    loop.notify.ready(f"model {loop.model_id[:12]} -> {loop.target.name} axis {loop.axis}")


def _service_stopping(loop) -> None:
    if loop is None:
        return
    loop.notify.stopping()
    if loop.metrics is not None:
        loop.metrics.close()


def run(args) -> int:
    if args.cycles is not None and args.cycles < 1:
        raise SettingsError(f"--cycles {args.cycles}: expected 1 or more")
    state = _State()
    previous = signal.signal(signal.SIGTERM, state.stop_on_sigterm)
    link = None
    started = time.monotonic()
    try:
        state.loop, link = loop, link = build(args)
        if link is not None:
            status = _connect_and_check(loop, link, args, state)
            if status is not None:
                return status
        print(
            f"rafi deploy: {args.machine}: model {loop.model_id[:12]}"
            f" -> {loop.target.name} axis {loop.axis} every {loop.interval_s:g} s"
            f"{' (dry run)' if args.dry_run else ''}; Ctrl-C stops",
            flush=True,
        )
        _service_ready(loop)
        state.phase, state.target_opened = "running", True
        started = time.monotonic()
        loop.run(max_cycles=args.cycles)
        print(_summary(loop, args, time.monotonic() - started))
        return 0
    except KeyboardInterrupt:
        if getattr(args, "debug", False):
            traceback.print_exc()
        print(_stopped_line(state), flush=True)
        if state.target_opened:
            print(_summary(state.loop, args, time.monotonic() - started))
        return 0
    finally:
        signal.signal(signal.SIGTERM, previous)
        _service_stopping(state.loop)
        if link is not None:
            try:
                link.close()
            except KeyboardInterrupt:  # a second Ctrl-C while closing: the session is left to die
                pass
