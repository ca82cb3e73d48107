"""Prometheus metrics of ``rafi deploy`` and ``rafi record`` (``docs/service.md``).

Each instance owns its own :class:`prometheus_client.CollectorRegistry` (never the process-wide
default), so that two loops in one process, or the tests, do not share counters. Every metric
carries the label ``machine``.

Use (the loop calls one method per cycle or event; the CLI serves the registry)::

    metrics = metrics_from_settings(deploy, machine="m1", log=print)  # None: deploy.metrics_port none
    metrics.model(model_id)
    metrics.connection(link.connected)       # after connect, on a loss, after a reconnect
    metrics.reconnect()                      # each successful reconnect
    metrics.cycle(command, written=True, step_seconds=0.004)
    metrics.close()                          # stops the HTTP server

``rafi deploy`` (prefix ``rafi_deploy``, :class:`LoopMetrics`):

=====================================  =======  ==============================================
metric                                 type     meaning
=====================================  =======  ==============================================
``<p>_command_um``                     gauge    the command of the last cycle (um)
``<p>_model_um``                       gauge    the model's value (um); NaN when it has none
                                                (referencing: 0 um is the reference, no value)
``<p>_interval_lower_um``              gauge    the model's prediction interval, lower end (um)
``<p>_interval_upper_um``              gauge    ... upper end (um); both NaN without an interval
``<p>_interval_half_width_um``         gauge    its half-width (um); NaN without an interval
``<p>_interval_cell{cell}``            gauge    1 for the interval's cell (``settled``,
                                                ``transient``, ``outside``) of the last cycle
``<p>_status{status}``                 gauge    1 for the status of the last cycle, 0 others;
                                                ``outage`` while the controller is unreachable
``<p>_faults_total{cause}``            counter  cycles with a fault of this class
``<p>_limited_total{limit}``           counter  cycles where ``clamp`` / ``rate`` acted
``<p>_outside_envelope_total``         counter  cycles whose model value was held at its
                                                training envelope's edge (not a fault:
                                                ``Command.outside_envelope``)
``<p>_cycles_total``                   counter  cycles run
``<p>_writes_total``                   counter  successful writes to the target
``<p>_reconnects_total``               counter  successful reconnects to the controller
``<p>_connected``                      gauge    1 while the link to the controller is up
``<p>_last_write_age_seconds``         gauge    seconds since the last successful write
                                                (since the start, before the first)
``<p>_step_seconds``                   histo.   wall time of one cycle (read, compute, write)
``<p>_interval_seconds``               gauge    ``deploy.interval_s`` (for alert rules)
``<p>_model_info{model_id}``           info     the model in service
=====================================  =======  ==============================================

Fault classes (``cause``), from the texts of :attr:`rafi.deploy.limits.Command.fault`:
``missing``, ``out_of_range``, ``stuck``, ``speed_missing``, ``outside_range`` (a sensor rise
or the speed beyond the trained range), ``no_value`` (the model has no value),
``interval_wide`` (the prediction interval wider than ``deploy.max_interval_um``), ``other``
(a text this module does not know: counted, never lost).

``rafi record`` (prefix ``rafi_record``, :class:`RecordMetrics`): ``<p>_rows_total``,
``<p>_missing_values_total`` (values recorded as missing: a bad status, no value),
``<p>_gaps_total``, ``<p>_files_total`` (files closed and renamed), ``<p>_reconnects_total``,
``<p>_connected``, ``<p>_last_row_age_seconds``, ``<p>_period_seconds``, ``<p>_file_info{path}``
(the file being written; ``path=""`` between files).

A port already in use, or an address that cannot be bound, is a :class:`~rafi.errors.SettingsError`
(exit 64): the cure is another ``metrics_port``, a restart does not help.
"""

from __future__ import annotations

import errno
import math
import re
import time
from collections.abc import Callable, Iterable, Mapping

from rafi.errors import SettingsError

try:  # the deploy extra; without it only metrics_port none works (metrics_from_settings says so)
    from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, Info
except ImportError:  # pragma: no cover - the test extra installs it
    CollectorRegistry = None

__all__ = [
    "FAULT_CLASSES",
    "INTERVAL_CELLS",
    "LoopMetrics",
    "RecordMetrics",
    "fault_causes",
    "fault_classes",
    "fault_groups",
    "fault_groups_text",
    "metrics_from_settings",
]

#: Fault class -> the pattern of its text in ``Command.fault`` (tried in this order).
FAULT_CLASSES = {
    "speed_missing": re.compile(r"^speed missing$"),
    "missing": re.compile(r" missing$"),
    "out_of_range": re.compile(r" out of range\b"),
    "stuck": re.compile(r" stuck$"),
    "outside_range": re.compile(r"outside trained range|above trained"),
    "no_value": re.compile(r"^no model value$"),
    "interval_wide": re.compile(r"^interval_wide\b"),
}
#: The cells of the prediction interval (:data:`rafi.family.interval_rule.CELLS`).
INTERVAL_CELLS = ("settled", "transient", "outside")
#: The status of the deploy metrics while the link to the controller is down (nothing is written).
OUTAGE = "outage"
#: The statuses exposed from the start (others get their series when first seen).
KNOWN_STATUSES = ("off", "referencing", "ok", "hold", "ramp", OUTAGE)
#: Seconds per cycle: a cycle reads, computes and writes over OPC UA (ms), or waits for a
#: reconnect (up to deploy.opcua.timeout_s).
STEP_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0)


def fault_causes(fault: str) -> list[tuple[str, str]]:
    """Every cause in a ``Command.fault`` text (``"; "``-separated) with its class.

    Parameters
    ----------
    fault : str
        ``Command.fault`` (empty: no fault).

    Returns
    -------
    list of (str, str)
        ``(class, cause)`` per cause, in the text's order: a key of :data:`FAULT_CLASSES`, or
        ``other``, and the cause's text (stripped).
    """
    out: list[tuple[str, str]] = []
    for cause in (c.strip() for c in (fault or "").split(";")):
        if cause:
            kind = next((k for k, pattern in FAULT_CLASSES.items() if pattern.search(cause)), "other")
            out.append((kind, cause))
    return out


def fault_classes(fault: str) -> list[str]:
    """The classes of the causes in a ``Command.fault`` text (``"; "``-separated), each once.

    Parameters
    ----------
    fault : str
        ``Command.fault`` (empty: no fault).

    Returns
    -------
    list of str
        Keys of :data:`FAULT_CLASSES`, or ``other``, in the order first met.
    """
    return list(dict.fromkeys(kind for kind, _ in fault_causes(fault)))


def fault_groups(faults: Iterable[str]) -> list[tuple[str, int, str]]:
    """The faults of many samples grouped by class: how many samples, and the first cause.

    Parameters
    ----------
    faults : iterable of str
        ``Command.fault`` of each sample (empty: no fault), in time order.

    Returns
    -------
    list of (str, int, str)
        ``(class, samples, first cause)`` per class (:func:`fault_causes`), in the order first
        met: the number of samples with a cause of the class (a sample with two causes of one
        class, e.g. two sensors missing, counts once) and the text of the first such cause.
    """
    counts: dict[str, int] = {}
    first: dict[str, str] = {}
    for fault in faults:
        seen = set()
        for kind, cause in fault_causes(fault):
            first.setdefault(kind, cause)
            if kind not in seen:
                seen.add(kind)
                counts[kind] = counts.get(kind, 0) + 1
    return [(kind, counts[kind], first[kind]) for kind in counts]


def fault_groups_text(groups) -> str:
    """:func:`fault_groups` as one line: ``"missing: 4 (first: T8 missing); speed_missing: 1 (first:
    speed missing)"``; empty without a fault."""
    return "; ".join(f"{kind}: {n} (first: {cause})" for kind, n, cause in groups)


class _Metrics:
    """What both kinds share: the registry, the link's state, the HTTP server."""

    section = "deploy"

    def __init__(self, prefix: str, machine: str, registry, clock: Callable[[], float]):
        self.prefix, self.machine = prefix, str(machine)
        self.registry = registry if registry is not None else CollectorRegistry()
        self.clock = clock
        self.server = self.thread = None
        self.port: int | None = None
        self._started = clock()
        self._reconnects = self._counter("reconnects", "successful reconnects to the controller")
        self._connected = self._gauge("connected", "1 while the link to the controller is up")

    def _labels(self, metric, **labels):
        return metric.labels(machine=self.machine, **labels)

    def _gauge(self, name: str, doc: str, *labels: str):
        metric = Gauge(f"{self.prefix}_{name}", doc, ("machine", *labels), registry=self.registry)
        return metric if labels else self._labels(metric)

    def _counter(self, name: str, doc: str, *labels: str):
        metric = Counter(f"{self.prefix}_{name}", doc, ("machine", *labels), registry=self.registry)
        return metric if labels else self._labels(metric)

    def _age(self, name: str, doc: str, since: Callable[[], float]) -> None:
        """A gauge computed when scraped: seconds since ``since()``."""
        self._gauge(name, doc).set_function(lambda: max(self.clock() - since(), 0.0))

    def reconnect(self) -> None:
        """Count one successful reconnect (and the link is up)."""
        self._reconnects.inc()
        self.connection(True)

    def connection(self, up: bool) -> None:
        """Whether the link to the controller is up now."""
        self._connected.set(1.0 if up else 0.0)

    # ------------------------------------------------------------------ serving
    def serve(self, port: int, address: str = "127.0.0.1") -> int:
        """Serve ``/metrics`` over HTTP on ``address``:``port`` in a daemon thread.

        Parameters
        ----------
        port : int
            TCP port; 0 picks a free one (the tests).
        address : str
            The address to listen on (``0.0.0.0``: every interface).

        Returns
        -------
        int
            The port bound (:attr:`port`; :attr:`server` and :attr:`thread` are set too).

        Raises
        ------
        SettingsError
            The port is in use, or the address cannot be bound (one line naming the setting).
        """
        from prometheus_client import start_http_server

        try:
            self.server, self.thread = start_http_server(int(port), addr=str(address), registry=self.registry)
        except OSError as exc:
            where = f"{self.section}.metrics_port {port} on {address}"
            if exc.errno == errno.EADDRINUSE:
                why = "the port is in use (another rafi service or program listens there); choose another"
            elif exc.errno == errno.EACCES:
                why = "permission denied (ports below 1024 need privileges); choose a port above 1024"
            else:
                why = f"cannot listen there ({exc.strerror or exc}); check {self.section}.metrics_address"
            raise SettingsError(f"{where}: {why}") from None
        self.port = int(self.server.server_port)
        return self.port

    def close(self) -> None:
        """Stop the HTTP server, if serving (the metrics stay readable in :attr:`registry`)."""
        server, self.server = self.server, None
        if server is not None:
            server.shutdown()
            server.server_close()
            self.thread.join(10.0)


class LoopMetrics(_Metrics):
    """The metrics of the live loop (module docstring).

    Parameters
    ----------
    prefix : str
        Metric name prefix.
    machine : str
        The machine (label ``machine`` of every metric).
    registry : prometheus_client.CollectorRegistry, optional
        Default: a new one of this instance's own.
    interval_s : float, optional
        ``deploy.interval_s`` (exposed for alert rules; NaN if not given).
    clock : callable
        Seconds, for the age of the last write (default ``time.monotonic``; a test injects one).
    """

    def __init__(
        self, prefix: str = "rafi_deploy", *, machine: str, registry=None, interval_s: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):  # fmt: skip
        super().__init__(prefix, machine, registry, clock)
        self._last_write: float | None = None
        self._command = self._gauge("command_um", "the command of the last cycle (um)")
        self._model = self._gauge("model_um", "the model's value of the last cycle (um); NaN without one")
        self._model.set(math.nan)
        self._command.set(math.nan)
        self._interval = {
            "lower_um": self._gauge("interval_lower_um", "the model's prediction interval, lower end (um)"),
            "upper_um": self._gauge("interval_upper_um", "the model's prediction interval, upper end (um)"),
            "half_width_um": self._gauge(
                "interval_half_width_um", "the prediction interval's half-width (um)"
            ),
        }
        for gauge in self._interval.values():
            gauge.set(math.nan)
        self._cell = self._gauge(
            "interval_cell", "1 for the prediction interval's cell, 0 for the others", "cell"
        )
        for cell in INTERVAL_CELLS:
            self._labels(self._cell, cell=cell).set(0.0)
        self._status = self._gauge("status", "1 for the status of the last cycle, 0 for the others", "status")
        for status in KNOWN_STATUSES:
            self._labels(self._status, status=status).set(0.0)
        self._status_now: str | None = None
        self._faults = self._counter("faults", "cycles with a fault of this class", "cause")
        for cause in (*FAULT_CLASSES, "other"):
            self._labels(self._faults, cause=cause)
        self._limited = self._counter("limited", "cycles where this limit acted (clamp, rate)", "limit")
        for limit in ("clamp", "rate"):
            self._labels(self._limited, limit=limit)
        self._envelope = self._counter(
            "outside_envelope", "cycles whose model value was held at its training envelope's edge"
        )
        self._cycles = self._counter("cycles", "cycles run")
        self._writes = self._counter("writes", "successful writes to the target")
        self._age(
            "last_write_age_seconds",
            "seconds since the last successful write (since the start, before the first)",
            lambda: self._started if self._last_write is None else self._last_write,
        )
        self._steps = self._labels(
            Histogram(
                f"{prefix}_step_seconds", "wall time of one cycle (read, compute, write)", ("machine",),
                buckets=STEP_BUCKETS, registry=self.registry,
            )
        )  # fmt: skip
        self._gauge("interval_seconds", "deploy.interval_s").set(
            math.nan if interval_s is None else interval_s
        )
        self._info = Info(f"{prefix}_model", "the model in service", ("machine",), registry=self.registry)

    def connection(self, up: bool) -> None:
        """Whether the link to the controller is up now; down: the status is ``outage`` (until a
        cycle after the reconnect gives a command's status)."""
        super().connection(up)
        if not up:
            self.status(OUTAGE)

    def model(self, model_id: str) -> None:
        """The model now in service (a new champion replaces the previous one)."""
        self._labels(self._info).info({"model_id": str(model_id)})

    def status(self, status: str) -> None:
        """Set the status gauge: 1 for ``status``, 0 for every other."""
        if status == self._status_now:
            return
        if self._status_now is not None:
            self._labels(self._status, status=self._status_now).set(0.0)
        self._labels(self._status, status=status).set(1.0)
        self._status_now = status

    def fault(self, causes: str) -> list[str]:
        """Count the fault classes of one cycle's ``Command.fault``; returns them."""
        classes = fault_classes(causes)
        for cause in classes:
            self._labels(self._faults, cause=cause).inc()
        return classes

    def interval(self, command) -> None:
        """Set the interval gauges from a command's model interval (NaN and no cell: none)."""
        for name, gauge in self._interval.items():
            v = float(getattr(command, name, math.nan))
            gauge.set(v if math.isfinite(v) else math.nan)
        cell = str(getattr(command, "interval_cell", "") or "")
        for known in INTERVAL_CELLS:
            self._labels(self._cell, cell=known).set(1.0 if known == cell else 0.0)

    def cycle(self, command=None, *, written: bool, step_seconds: float) -> None:
        """Record one cycle.

        Parameters
        ----------
        command : rafi.deploy.limits.Command, optional
            The last command of the cycle (None: no sample, e.g. the controller unreachable).
        written : bool
            The command reached the target.
        step_seconds : float
            Wall time the cycle took.
        """
        self._cycles.inc()
        self._steps.observe(max(float(step_seconds), 0.0))
        if command is not None:
            self._command.set(float(command.command_um))
            model = float(command.model_um)
            valued = math.isfinite(model) and command.status != "referencing"  # 0 um: the reference
            self._model.set(model if valued else math.nan)
            self.status(command.status)
            self.fault(command.fault)
            self.interval(command)
            for limit, acted in (("clamp", command.clamped), ("rate", command.rate_limited)):
                if acted:
                    self._labels(self._limited, limit=limit).inc()
            if getattr(command, "outside_envelope", False):
                self._envelope.inc()
        if written:
            self._writes.inc()
            self._last_write = self.clock()


class RecordMetrics(_Metrics):
    """The metrics of ``rafi record`` (module docstring); parameters as :class:`LoopMetrics`
    (``period_s``: the machine's sample period)."""

    section = "record"

    def __init__(
        self, prefix: str = "rafi_record", *, machine: str, registry=None, period_s: float | None = None,
        clock: Callable[[], float] = time.monotonic,
    ):  # fmt: skip
        super().__init__(prefix, machine, registry, clock)
        self._last_row: float | None = None
        self._rows = self._counter("rows", "rows written")
        self._missing = self._counter("missing_values", "values recorded as missing (bad status, no value)")
        self._gaps = self._counter("gaps", "gaps recorded (a lost connection, a late sample)")
        self._files = self._counter("files", "files closed and renamed to their final name")
        self._age(
            "last_row_age_seconds",
            "seconds since the last row written (since the start, before the first)",
            lambda: self._started if self._last_row is None else self._last_row,
        )
        self._gauge("period_seconds", "the sample period").set(math.nan if period_s is None else period_s)
        self._file = Info(f"{prefix}_file", "the file being written", ("machine",), registry=self.registry)
        self.file(None)

    def row(self, missing: int = 0) -> None:
        """One row written, ``missing`` of its values recorded as missing."""
        self._rows.inc()
        if missing:
            self._missing.inc(missing)
        self._last_row = self.clock()

    def missing(self, values: int) -> None:
        """``values`` values recorded as missing (a bad status, no value)."""
        self._missing.inc(values)

    def gap(self) -> None:
        """One gap recorded."""
        self._gaps.inc()

    def file(self, path) -> None:
        """The file now being written (None: between files)."""
        self._labels(self._file).info({"path": "" if path is None else str(path)})

    def file_closed(self) -> None:
        """The current file was closed and renamed."""
        self._files.inc()
        self.file(None)


def metrics_from_settings(
    settings: Mapping, *, machine: str, log: Callable[[str], None] = print, kind: str = "deploy",
    interval_s: float | None = None,
):  # fmt: skip
    """The metrics a CLI serves, from its settings block; None when ``metrics_port`` is none.

    Parameters
    ----------
    settings : mapping
        The effective settings block holding ``metrics_port`` and ``metrics_address``
        (``deploy``; ``rafi record`` passes its own block, or ``deploy`` if it has none).
    machine : str
        The machine.
    log : callable
        ``log(line)``: one line naming the URL served.
    kind : str
        ``deploy`` (:class:`LoopMetrics`) or ``record`` (:class:`RecordMetrics`).
    interval_s : float, optional
        The interval (deploy) or sample period (record) to expose; default
        ``settings["interval_s"]`` if present.

    Returns
    -------
    LoopMetrics, RecordMetrics or None
        Serving already (call ``close()`` at the end).

    Raises
    ------
    SettingsError
        A port that is not an integer in 1..65535, or one that cannot be bound (exit 64).
    """
    port = settings.get("metrics_port")
    if port is None:
        return None
    section = kind if kind == "record" else "deploy"
    if CollectorRegistry is None:
        raise SettingsError(
            f"{section}.metrics_port is set but prometheus_client is not installed "
            "(pip install -e '.[deploy]'), or set it to none"
        )
    if isinstance(port, bool) or not isinstance(port, int) or not 1 <= port <= 65535:
        raise SettingsError(f"{section}.metrics_port is {port!r}; expected a TCP port 1..65535 or none")
    address = str(settings.get("metrics_address") or "127.0.0.1")
    seconds = interval_s if interval_s is not None else settings.get("interval_s")
    if kind == "record":
        metrics = RecordMetrics(machine=machine, period_s=seconds)
    elif kind == "deploy":
        metrics = LoopMetrics(machine=machine, interval_s=seconds)
    else:
        raise ValueError(f"kind {kind!r}: expected deploy or record")
    metrics.section = section
    bound = metrics.serve(port, address)
    host = f"[{address}]" if ":" in address else address
    log(f"rafi {kind}: Prometheus metrics on http://{host}:{bound}/metrics")
    return metrics
