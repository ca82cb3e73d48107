"""Record a qualification test into raw/<machine>/ (docs/record.md).

Every sample period (the machine's sample_period_s) read the spindle speed, the temperatures
T1..T16 and the displacement probe - from the OPC UA nodes of deploy.opcua.inputs and
record.displacement, or from a DAQ's CSV file as it is written (--follow) - and write them as a
native-format raw log (docs/raw-format.md) under raw/<machine>/. A file is written under a
hidden temporary name and renamed to <run>_<start>.csv when it is closed (end of the plan,
Ctrl-C / SIGTERM, or record.max_file_s), so the pipeline never reads half a file; an existing
file is never replaced. A bad status or a missing value is an empty field; a lost connection
is a gap (no rows), reconnected with a bounded back-off.

With --plan PLAN.csv (speed_rpm,duration_s[,run]) the speed of each step is written to
record.speed_command and the recording ends with the plan (then 0 r/min is commanded);
without it nothing is ever written to the controller: it records while the operator runs the
NC program, until Ctrl-C or --duration.

Exit status: 0 done (the plan or --duration ended, or stopped by Ctrl-C / SIGTERM: the file is
closed and renamed); 64 a settings, plan or credentials mistake, a node the server does not
have, or a login or write the server refuses; 65 a followed DAQ file that is not in the native
format; 69 the OPC UA server cannot be reached at start (a connection lost later is a gap);
with --wait-for-controller (the systemd unit passes it, docs/service.md) it is waited for instead.
"""

from __future__ import annotations

import math
import re
import signal
import sys
from collections.abc import Mapping
from pathlib import Path

from rafi.cli import add_config_option
from rafi.deploy.opcua_reconnect import add_wait_option, prefixed
from rafi.errors import SettingsError, short_path

EX_UNAVAILABLE = 69
_DURATION = re.compile(r"^\s*([0-9]+(?:\.[0-9]*)?)\s*(s|min|h|d)?\s*$")
_UNITS = {None: 1.0, "s": 1.0, "min": 60.0, "h": 3600.0, "d": 86400.0}
#: The longest notes (the reader refuses a metadata value over 4096 characters).
NOTES_MAX_CHARS = 4000


def parse_duration(text: str) -> float:
    """``'4h'``, ``'90min'``, ``'300s'``, ``'300'`` -> seconds; SettingsError otherwise."""
    match = _DURATION.match(text or "")
    value = float(match.group(1)) * _UNITS[match.group(2)] if match else math.nan
    if not (math.isfinite(value) and value > 0):
        raise SettingsError(f"--duration {text!r}: expected a time above 0 such as 4h, 90min or 300s")
    return value


def add_arguments(parser) -> None:
    parser.add_argument("--machine", required=True, help="the machine (named under machines: in the config)")
    add_config_option(parser)
    parser.add_argument(
        "--follow", metavar="DAQFILE", help="read the samples from this native CSV file as a DAQ writes it"
    )
    parser.add_argument(
        "--from-start", action="store_true", help="with --follow: record the lines already in the file too"
    )
    parser.add_argument(
        "--plan",
        metavar="PLAN.csv",
        help="follow this test plan (speed_rpm,duration_s[,run]) by writing record.speed_command",
    )
    parser.add_argument("--notes", default="", help="the run's notes, written into every file's header")
    parser.add_argument(
        "--name", default="rec", help="the recording's name without a plan's run column (default: rec)"
    )
    parser.add_argument(
        "--duration", help="stop after this long (4h, 90min, 300s); default: until Ctrl-C (or the plan's end)"
    )
    add_wait_option(parser)


def _node(spec, prefix: str, where: str) -> tuple[str, float, float]:
    """``record.displacement``: a node id or ``{node, scale, offset}`` -> ``(node id, scale, offset)``."""
    node, scale, offset = spec, 1.0, 0.0
    if isinstance(spec, Mapping):
        node, scale, offset = spec.get("node"), spec.get("scale", 1.0), spec.get("offset", 0.0)
    if not isinstance(node, str) or not node.strip():
        raise SettingsError(f"{where} is {spec!r}; expected a node id or {{node, scale, offset}}")
    for key, value in (("scale", scale), ("offset", offset)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise SettingsError(f"{where}.{key} is {value!r}; expected a finite number")
    if scale == 0:
        raise SettingsError(f"{where}.scale is 0")
    node = node.strip()
    full = node.startswith(("ns=", "nsu=", "i=", "s=", "g=", "b="))
    return (node if full else prefix + node), float(scale), float(offset)


def _check_args(args) -> None:
    from rafi.contract import PROBE_SEPARATOR
    from rafi.deploy.record_plan import RUN_NAME
    from rafi.readers.discovery import safe_name_problem

    problem = safe_name_problem(args.machine)
    if problem or args.machine.startswith(".") or re.search(r"[/\\{}]", args.machine):
        raise SettingsError(
            f"--machine {args.machine!r} cannot name a folder of raw_dir ({problem or 'its form'})"
        )
    if PROBE_SEPARATOR in args.machine:
        raise SettingsError(
            f"--machine {args.machine!r} names a probe of a machine (<machine>@<probe>); a recording "
            "belongs to the machine, whose folder its probes read: give the machine"
        )
    if not RUN_NAME.match(args.name):
        raise SettingsError(
            f"--name {args.name!r}: use letters, digits, '.', '_' and '-' (at most 80, starting with a "
            "letter or digit)"
        )
    if len(args.notes) > NOTES_MAX_CHARS or any(
        len(line) > NOTES_MAX_CHARS for line in args.notes.splitlines()
    ):
        raise SettingsError(f"--notes holds {len(args.notes)} characters; at most {NOTES_MAX_CHARS}")
    if args.duration:
        parse_duration(args.duration)
    if args.plan and args.duration:
        raise SettingsError("--duration and --plan: the plan says how long the recording lasts; give one")
    if args.from_start and not args.follow:
        raise SettingsError("--from-start goes with --follow")


def _channels(opcua: dict, record: dict, log, sensors) -> tuple[dict, dict]:
    """The OPC UA node of each column (``speed_rpm``, the machine's ``sensors``, ``disp_um``) and
    the setting that names it; an input that is not a column of the file is refused."""
    stray = [name for name in opcua["inputs"] if name != "speed_rpm" and name not in sensors]
    if stray:
        raise SettingsError(
            f"deploy.opcua.inputs.{stray[0]}: not a sensor of this machine (its sensors, "
            f"input.sensors: {_names(sensors)}); rafi record writes a column per sensor of the machine: "
            "name each input after its sensor"
        )
    if record.get("displacement") is None:
        raise SettingsError(
            "record.displacement is not set: name the OPC UA node of the displacement probe "
            "(or record a DAQ's file with --follow; docs/record.md)"
        )
    channels = dict(opcua["inputs"])
    where = {name: f"deploy.opcua.inputs.{name}" for name in channels}
    channels["disp_um"] = _node(record["displacement"], opcua["node_prefix"], "record.displacement")
    where["disp_um"] = "record.displacement"
    unset = [s for s in sensors if s not in channels]
    if unset:
        log(f"rafi record: deploy.opcua.inputs has no node for {', '.join(unset)}: recorded as missing")
    return channels, where


def _names(names) -> str:
    return ", ".join(names[:6]) + (f", ... ({len(names)} in all)" if len(names) > 6 else "")


def recorded_columns(machine: str, spec: dict) -> tuple[str, ...]:
    """The columns of ``machine``'s recordings: ``time, speed_rpm, <its sensors>, disp_um``.

    A recording is a native log (docs/raw-format.md) the pipeline reads beside the machine's own
    logs whatever their format (:mod:`rafi.readers.recordings`). Refused, in one line, before
    anything connects: a machine with several probes (``input.probes``), whose units would each
    need their probe in a native file that has one displacement column.
    """
    from rafi.contract.sensors import canonical_columns

    if spec["probes"]:
        raise SettingsError(
            f"machines.{machine}.input.probes: the machine has several probes "
            f"({_names(list(spec['probes']))}); rafi record writes one displacement column (disp_um), "
            "not one per probe: record with the machine's own logger (docs/record.md)"
        )
    return canonical_columns(spec["sensors"])


def build(args, *, log=print, environ=None):
    """The recorder of ``rafi record`` and the OPC UA link to connect and close (None without one).

    Everything is checked (settings, plan, credentials) before anything connects; nothing is
    written here and no file is created.
    """

    from rafi import __version__
    from rafi.deploy.metrics import metrics_from_settings
    from rafi.deploy.record import DaqFollower, OpcUaSource, Recorder
    from rafi.deploy.record_files import RecordingFiles, leftover_parts
    from rafi.deploy.record_plan import read_plan
    from rafi.deploy.sd_notify import SdNotify
    from rafi.readers.recordings import RECORDED_BY
    from rafi.settings import read_machine_config, run_settings

    _check_args(args)
    config_path = Path(args.config)
    config, settings = read_machine_config(config_path, args.machine)
    columns = recorded_columns(args.machine, settings["input"])
    project = config_path.resolve().parent
    record, period = settings["record"], float(settings["sample_period_s"])
    folder = project / run_settings(config)["raw_dir"] / args.machine
    plan = read_plan(args.plan, default_run=args.name) if args.plan else None
    short = [s for s in (plan.steps if plan else ()) if s.duration_s < period]
    if short:
        raise SettingsError(
            f"plan {short_path(args.plan)}, line {short[0].line}, column 'duration_s': "
            f"{short[0].duration_s:g} s is shorter than the sample period {period:g} s "
            "(sample_period_s): the step might never be commanded"
        )
    if plan is not None and record["speed_command"] is None:
        raise SettingsError(
            "--plan needs record.speed_command: the node the plan's speeds are written to (docs/record.md)"
        )
    link = source = None
    if not args.follow or plan is not None:
        from rafi.deploy.opcua_client import OpcUaLink, load_credentials, opcua_settings

        opcua = opcua_settings(
            settings["deploy"].get("opcua"), need_inputs=not args.follow, project_dir=project
        )
        user, password = load_credentials(opcua, project_dir=project, environ=environ)
        link = OpcUaLink(opcua, user=user, password=password, log=prefixed(log, "rafi record"))
        if not args.follow:
            source = OpcUaSource(link, *_channels(opcua, record, log, columns[2:-1]), columns=columns)
    if args.follow:
        source = DaqFollower(args.follow, from_start=args.from_start, log=log, columns=columns)
    for part in leftover_parts(folder):
        log(
            f"rafi record: {short_path(part)} is a recording that was never closed (a crash or power "
            "cut): check its last line and rename it to <name>.csv, or delete it"
        )
    metadata = {
        "machine": args.machine,
        "sample_period_s": f"{period:g}",
        **({"notes": args.notes} if args.notes.strip() else {}),
        "recorded_by": f"{RECORDED_BY} {__version__}",  # how the pipeline knows a recording
        "source": f"OPC UA {link.endpoint}" if not args.follow else f"DAQ file {args.follow}",
    }
    if plan is not None:
        metadata["plan"] = f"{Path(args.plan).name} ({len(plan.steps)} steps, {plan.total_s:g} s)"
    files = RecordingFiles(folder, metadata, max_file_s=float(record["max_file_s"]), log=log, columns=columns)
    command = None
    if plan is not None:
        node = link.node_id(record["speed_command"])

        def command(speed_rpm: float) -> None:
            link.write_value(node, float(speed_rpm), "Double")

    metrics = metrics_from_settings(record, machine=args.machine, log=log, kind="record", interval_s=period)
    recorder = Recorder(
        source, files, period_s=period, name=args.name, plan=plan, command=command, link=link,
        duration_s=parse_duration(args.duration) if args.duration else None, log=log,
        metrics=metrics, notify=SdNotify(log=log),
    )  # fmt: skip
    files.clock = recorder.clock
    recorder.speed_command_node = record["speed_command"]
    return recorder, link


def preflight(recorder, link) -> None:
    """After connecting: every node read once (a node the server lacks: 64), and the speed-command
    node is a Double or Float."""
    from rafi.deploy.record import OpcUaSource

    if isinstance(recorder.source, OpcUaSource):
        recorder.source.check()
    if recorder.plan is not None:
        node = link.node_id(recorder.speed_command_node)
        ((_, vtype, status),) = link.read_nodes([node])
        if status in ("BadNodeIdUnknown", "BadNodeIdInvalid"):
            raise SettingsError(f"record.speed_command: the server has no node {node} ({status})")
        if vtype not in ("Double", "Float"):
            raise SettingsError(
                f"record.speed_command: node {node} is of type {vtype or 'unknown'}; rafi record writes "
                "the speed as a Double or Float (a PLC REAL)"
            )


def _stop_on_sigterm(signum, frame):
    raise KeyboardInterrupt


def _connect(args, recorder, link) -> int | None:
    """Connect (or, with ``--wait-for-controller``, wait for the server; a connection lost during
    the preflight is then waited for again) and run the preflight; an exit status, or None."""
    from rafi.deploy.opcua_reconnect import wait_for_controller

    def say(message: str) -> None:
        print(f"rafi record: {message}", flush=True)

    def waiting() -> None:
        if recorder.metrics is not None:
            recorder.metrics.connection(False)

    wait = getattr(args, "wait_for_controller", False)
    while True:
        try:
            if wait:
                wait_for_controller(link, log=say, notify=recorder.notify, on_wait=waiting)
            else:
                link.connect()
            preflight(recorder, link)
            return None
        except ConnectionError as exc:
            if not wait:
                print(f"rafi record: {exc}", file=sys.stderr)
                return EX_UNAVAILABLE
            say(f"{exc}; waiting for the server again")


def _record(args, recorder, link) -> int:
    from rafi.deploy.record import counted

    if link is not None:
        status = _connect(args, recorder, link)
        if status is not None:
            return status
    source = f"OPC UA {link.endpoint}" if args.follow is None else short_path(args.follow)
    print(
        f"rafi record: {args.machine}: {source} every {recorder.period_s:g} s -> "
        f"{short_path(recorder.files.folder)}"
        f"{f' following {short_path(args.plan)}' if args.plan else ''}; Ctrl-C stops",
        flush=True,
    )
    recorder.notify.ready(f"recording {args.machine} every {recorder.period_s:g} s")
    stopped = False
    try:
        recorder.run()
    except KeyboardInterrupt:
        stopped = True
    closed = ", ".join(p.name for p in recorder.files.closed) or "none"
    print(
        f"rafi record: {'stopped; ' if stopped else ''}{counted(recorder.files.rows, 'row')}, "
        f"{counted(recorder.gaps, 'gap')}, {counted(recorder.missing, 'missing value')}; files: {closed}",
        flush=True,
    )
    return 0


def run(args) -> int:
    recorder, link = build(args)
    previous = signal.signal(signal.SIGTERM, _stop_on_sigterm)
    try:
        return _record(args, recorder, link)
    except KeyboardInterrupt:  # before the recording started (connecting, checking the nodes)
        print("rafi record: stopped before recording; no file was written", flush=True)
        return 0
    finally:
        signal.signal(signal.SIGTERM, previous)
        recorder.notify.stopping()
        if recorder.metrics is not None:
            recorder.metrics.close()
        if link is not None:
            link.close()
