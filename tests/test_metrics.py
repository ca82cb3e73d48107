"""Prometheus metrics of rafi deploy / rafi record (rafi.deploy.metrics): served over real HTTP
on a free port, read back with urllib and parsed with prometheus_client's own parser.

The fault classes are checked against the texts the real SafeCompensator produces (not against
copies of them), so that a changed fault text fails here instead of landing in ``other``.
The age of the last write uses an injected clock: nothing depends on wall time.
"""

from __future__ import annotations

import math
import socket
import urllib.error
import urllib.request

import numpy as np
import pytest

pytest.importorskip("prometheus_client")

from prometheus_client.parser import text_string_to_metric_families  # noqa: E402
from test_live import DEPLOY, WINDOW, artefact, temps16  # noqa: E402

from rafi.artefact import compute_model_id  # noqa: E402
from rafi.deploy.limits import Command, Limits, SafeCompensator  # noqa: E402
from rafi.deploy.metrics import (  # noqa: E402
    FAULT_CLASSES,
    INTERVAL_CELLS,
    LoopMetrics,
    RecordMetrics,
    fault_classes,
    fault_groups,
    fault_groups_text,
    metrics_from_settings,
)
from rafi.errors import SettingsError  # noqa: E402
from rafi.settings import MACHINE_DEFAULTS  # noqa: E402

NAN = math.nan
#: An artefact's interval block (issue 26): 5 um wide when settled, 7 um in a transient.
INTERVAL = {
    "schema": "rafi.interval/1",
    "level": 0.9,
    "transient_s": 30.0,
    "tolerance_rpm": 50.0,
    "half_width_um": {"settled": 2.5, "transient": 3.5, "outside": 6.0},
}


def scrape(port: int) -> dict:
    """``{(sample name, frozenset(labels)): value}`` of GET /metrics on 127.0.0.1:port."""
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10) as response:
        assert response.status == 200
        text = response.read().decode("utf-8")
    return {
        (s.name, frozenset(s.labels.items())): s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
    }


def value(samples: dict, name: str, **labels) -> float:
    return samples[(name, frozenset(labels.items()))]


def command(status="ok", cmd=1.0, model=1.0, fault="", clamped=False, rate=False, envelope=False) -> Command:
    c = Command(0.0, cmd, status, model, model, clamped, rate, fault, False, status != "off")
    return c._replace(outside_envelope=envelope)


class Clock:
    def __init__(self, t: float = 1000.0):
        self.t = t

    def __call__(self) -> float:
        return self.t


@pytest.fixture
def served():
    """Metrics instances started by the test; every server is stopped afterwards."""
    started = []

    def start(cls=LoopMetrics, **kw):
        m = cls(**kw)
        m.serve(0)
        started.append(m)
        return m

    yield start
    for m in started:
        m.close()


# ------------------------------------------------------------------------ fault classes


def _faults_of_the_safe_compensator() -> dict[str, str]:
    """One ``Command.fault`` text per class, as the real SafeCompensator writes it."""
    model = artefact()
    model["regressor_ranges"] = {s: [-1.0, 5.0] for s in model["key_sensors"]}
    model["model_id"] = compute_model_id(model)
    limits = Limits.from_settings(dict(DEPLOY, range_margin_k=1.0))
    out = {}

    def run(rows, model=model, limits=limits):
        safe = SafeCompensator(limits=limits).load(model)
        t, cmd = 0.0, None
        window = [
            (6000.0, [30.0 + 0.01 * k, 31.0 + 0.01 * k, 32.0 + 0.01 * k]) for k in range(int(WINDOW / 5) + 1)
        ]
        for speed, key in window + rows:  # every reading moves a little: none stuck
            cmd = safe.step(t, speed, temps16(key))
            t += 5.0
        return cmd.fault

    out["missing"] = run([(6000.0, [30.0, NAN, 32.0])])
    out["out_of_range"] = run([(6000.0, [200.0, 31.0, 32.0])])
    out["speed_missing"] = run([(NAN, [30.0, 31.0, 32.0])])
    out["outside_range"] = run([(6000.0, [40.0, 31.0, 32.0])])  # a rise of 10 K, trained up to 5 K
    out["outside_range (speed)"] = run([(12000.0, [30.0, 31.0, 32.0])])
    rising = [(6000.0, [30.0 + 0.2 * k, 31.0 + 0.2 * k, 32.0]) for k in range(1, 16)]  # T9 sits still
    out["stuck"] = run(rising)
    sure = {**model, "interval": INTERVAL}
    sure["model_id"] = compute_model_id(sure)
    narrow = Limits.from_settings(dict(DEPLOY, range_margin_k=1.0, max_interval_um=4.0))
    out["interval_wide"] = run([(6000.0, [30.0, 31.0, 32.0])], model=sure, limits=narrow)  # 5 um wide
    return out


def test_every_fault_text_of_the_safe_compensator_has_its_class():
    texts = _faults_of_the_safe_compensator()
    for kind, text in texts.items():
        assert text, kind
        assert fault_classes(text) == [kind.split(" ")[0]], (kind, text)
    assert fault_classes("no model value") == ["no_value"]
    assert set(FAULT_CLASSES) == {k.split(" ")[0] for k in texts} | {"no_value"}


def test_several_causes_count_once_per_class_and_unknown_texts_are_other():
    assert fault_classes("") == []
    assert fault_classes("T6 missing; T8 missing; speed missing") == ["missing", "speed_missing"]
    assert fault_classes("T6 stuck; a cause nobody wrote yet") == ["stuck", "other"]


def test_fault_groups_count_samples_per_class_with_the_first_cause():
    """A sample counts once per class (two sensors missing: one sample), the example is the first
    cause of the class met, classes in the order first met; the text is one entry per class."""
    faults = [
        "",
        "T6 out of range (71.2 degC)",
        "T6 missing; T8 missing",
        "T8 missing; speed missing",
        "T6 out of range (73.9 degC); a cause nobody wrote yet",
    ]
    groups = fault_groups(faults)
    assert groups == [
        ("out_of_range", 2, "T6 out of range (71.2 degC)"),
        ("missing", 2, "T6 missing"),
        ("speed_missing", 1, "speed missing"),
        ("other", 1, "a cause nobody wrote yet"),
    ]
    assert fault_groups_text(groups) == (
        "out_of_range: 2 (first: T6 out of range (71.2 degC)); missing: 2 (first: T6 missing); "
        "speed_missing: 1 (first: speed missing); other: 1 (first: a cause nobody wrote yet)"
    )
    assert fault_groups(["", ""]) == [] and fault_groups_text([]) == ""


# ------------------------------------------------------------------------ deploy over HTTP


def test_the_loop_metrics_read_over_http(served):
    clock = Clock()
    m = served(machine="m1", interval_s=5.0, clock=clock)
    before = scrape(m.port)
    assert value(before, "rafi_deploy_writes_total", machine="m1") == 0
    assert value(before, "rafi_deploy_outside_envelope_total", machine="m1") == 0
    assert math.isnan(value(before, "rafi_deploy_model_um", machine="m1"))
    assert {value(before, "rafi_deploy_status", machine="m1", status=s) for s in ("off", "ok", "ramp")} == {0}

    m.model("a1b2c3")
    m.connection(True)
    m.cycle(command("referencing", cmd=0.0, model=NAN), written=True, step_seconds=0.004)
    clock.t += 5.0
    m.cycle(command("ok", cmd=1.25, model=3.0, rate=True, envelope=True), written=True, step_seconds=0.006)
    clock.t += 5.0
    m.connection(False)
    m.cycle(None, written=False, step_seconds=2.0)  # the controller unreachable
    clock.t += 5.0
    m.reconnect()
    m.cycle(
        command("hold", cmd=1.25, model=NAN, fault="T8 missing; speed missing"),
        written=True,
        step_seconds=0.01,
    )
    clock.t += 5.0
    m.cycle(
        command("ramp", cmd=1.0, model=NAN, fault="T8 missing", clamped=True),
        written=False,
        step_seconds=0.003,
    )
    clock.t += 7.0  # scraped 12 s after the last successful write

    s = scrape(m.port)
    assert value(s, "rafi_deploy_command_um", machine="m1") == 1.0
    assert math.isnan(value(s, "rafi_deploy_model_um", machine="m1"))
    status = {
        k: value(s, "rafi_deploy_status", machine="m1", status=k)
        for k in ("off", "referencing", "ok", "hold", "ramp")
    }
    assert status == {"off": 0, "referencing": 0, "ok": 0, "hold": 0, "ramp": 1}
    faults = {
        k: value(s, "rafi_deploy_faults_total", machine="m1", cause=k) for k in (*FAULT_CLASSES, "other")
    }
    assert faults == {"missing": 2, "speed_missing": 1, "out_of_range": 0, "stuck": 0, "outside_range": 0,
                      "no_value": 0, "interval_wide": 0, "other": 0}  # fmt: skip
    assert value(s, "rafi_deploy_limited_total", machine="m1", limit="rate") == 1
    assert value(s, "rafi_deploy_limited_total", machine="m1", limit="clamp") == 1
    assert value(s, "rafi_deploy_cycles_total", machine="m1") == 5
    assert value(s, "rafi_deploy_outside_envelope_total", machine="m1") == 1
    assert value(s, "rafi_deploy_writes_total", machine="m1") == 3
    assert value(s, "rafi_deploy_reconnects_total", machine="m1") == 1
    assert value(s, "rafi_deploy_connected", machine="m1") == 1
    assert value(s, "rafi_deploy_last_write_age_seconds", machine="m1") == pytest.approx(12.0)
    assert value(s, "rafi_deploy_interval_seconds", machine="m1") == 5.0
    assert value(s, "rafi_deploy_step_seconds_count", machine="m1") == 5
    assert value(s, "rafi_deploy_step_seconds_sum", machine="m1") == pytest.approx(2.023)
    assert value(s, "rafi_deploy_step_seconds_bucket", machine="m1", le="0.005") == 2
    assert value(s, "rafi_deploy_step_seconds_bucket", machine="m1", le="1.0") == 4
    assert value(s, "rafi_deploy_model_info", machine="m1", model_id="a1b2c3") == 1

    m.model("d4e5f6")  # a new champion replaces the old one's series
    s = scrape(m.port)
    assert [k for k in s if k[0] == "rafi_deploy_model_info"] == [
        ("rafi_deploy_model_info", frozenset({"machine": "m1", "model_id": "d4e5f6"}.items()))
    ]


def test_the_interval_and_its_fault_read_over_http(served):
    """The model's interval of the last cycle (gauges, one cell at 1) and the interval_wide class."""
    m = served(machine="m1")
    s = scrape(m.port)
    for name in ("lower_um", "upper_um", "half_width_um"):
        assert math.isnan(value(s, f"rafi_deploy_interval_{name}", machine="m1"))
    assert {value(s, "rafi_deploy_interval_cell", machine="m1", cell=c) for c in INTERVAL_CELLS} == {0}
    wide = "interval_wide: 7 um wider than deploy.max_interval_um 6 um"
    c = command("hold", cmd=1.0, model=2.0, fault=wide)._replace(
        lower_um=-1.5, upper_um=5.5, half_width_um=3.5, interval_cell="transient"
    )
    m.cycle(c, written=True, step_seconds=0.001)
    s = scrape(m.port)
    got = {
        n: value(s, f"rafi_deploy_interval_{n}", machine="m1")
        for n in ("lower_um", "upper_um", "half_width_um")
    }
    assert got == {"lower_um": -1.5, "upper_um": 5.5, "half_width_um": 3.5}
    cells = {k: value(s, "rafi_deploy_interval_cell", machine="m1", cell=k) for k in INTERVAL_CELLS}
    assert cells == {"settled": 0, "transient": 1, "outside": 0}
    assert value(s, "rafi_deploy_faults_total", machine="m1", cause="interval_wide") == 1
    m.cycle(command("ok", cmd=2.0, model=2.0), written=True, step_seconds=0.001)  # no interval: NaN, no cell
    s = scrape(m.port)
    assert math.isnan(value(s, "rafi_deploy_interval_upper_um", machine="m1"))
    assert {value(s, "rafi_deploy_interval_cell", machine="m1", cell=c) for c in INTERVAL_CELLS} == {0}
    assert value(s, "rafi_deploy_faults_total", machine="m1", cause="interval_wide") == 1


def test_the_age_before_the_first_write_counts_from_the_start(served):
    clock = Clock(50.0)
    m = served(machine="m1", clock=clock)
    clock.t += 42.0
    assert value(scrape(m.port), "rafi_deploy_last_write_age_seconds", machine="m1") == pytest.approx(42.0)


def test_two_instances_in_one_process_do_not_collide(served):
    a = served(machine="m1")
    b = served(machine="m2")
    same = served(machine="m1")  # the same names again: its own registry, no duplicate error
    assert len({a.port, b.port, same.port}) == 3
    for _ in range(3):
        a.cycle(command(), written=True, step_seconds=0.001)
    b.cycle(command(fault="T6 stuck", status="hold"), written=False, step_seconds=0.001)
    sa, sb, ss = scrape(a.port), scrape(b.port), scrape(same.port)
    assert value(sa, "rafi_deploy_writes_total", machine="m1") == 3
    assert value(sb, "rafi_deploy_writes_total", machine="m2") == 0
    assert value(ss, "rafi_deploy_writes_total", machine="m1") == 0
    assert value(sb, "rafi_deploy_faults_total", machine="m2", cause="stuck") == 1
    assert value(sa, "rafi_deploy_faults_total", machine="m1", cause="stuck") == 0
    assert not any(dict(k[1]).get("machine") == "m2" for k in sa)


def test_close_stops_the_server(served):
    m = served(machine="m1")
    port = m.port
    scrape(port)
    m.close()
    assert not m.thread.is_alive()
    with pytest.raises(urllib.error.URLError):
        scrape(port)


# ------------------------------------------------------------------------ record


def test_the_record_metrics_read_over_http(served):
    clock = Clock()
    m = served(RecordMetrics, machine="m1", period_s=5.0, clock=clock)
    m.connection(True)
    m.file("raw/m1/run.csv.part")
    for missing in (0, 2, 0):
        m.row(missing)
        clock.t += 5.0
    m.gap()
    m.reconnect()
    s = scrape(m.port)
    assert value(s, "rafi_record_rows_total", machine="m1") == 3
    assert value(s, "rafi_record_missing_values_total", machine="m1") == 2
    assert value(s, "rafi_record_gaps_total", machine="m1") == 1
    assert value(s, "rafi_record_reconnects_total", machine="m1") == 1
    assert value(s, "rafi_record_connected", machine="m1") == 1
    assert value(s, "rafi_record_last_row_age_seconds", machine="m1") == pytest.approx(5.0)
    assert value(s, "rafi_record_period_seconds", machine="m1") == 5.0
    assert value(s, "rafi_record_file_info", machine="m1", path="raw/m1/run.csv.part") == 1
    m.file_closed()
    s = scrape(m.port)
    assert value(s, "rafi_record_files_total", machine="m1") == 1
    assert value(s, "rafi_record_file_info", machine="m1", path="") == 1


# ------------------------------------------------------------------------ settings and errors


def test_metrics_are_off_by_default_and_served_when_a_port_is_set():
    from opcua_server import free_port

    lines = []
    assert metrics_from_settings(MACHINE_DEFAULTS["deploy"], machine="m1", log=lines.append) is None
    assert lines == []
    port = free_port()
    m = metrics_from_settings(dict(DEPLOY, metrics_port=port), machine="m1", log=lines.append)
    try:
        assert m.port == port and lines == [
            f"rafi deploy: Prometheus metrics on http://127.0.0.1:{port}/metrics"
        ]
        assert value(scrape(port), "rafi_deploy_interval_seconds", machine="m1") == DEPLOY["interval_s"]
    finally:
        m.close()
    r = metrics_from_settings({"metrics_port": port}, machine="m1", log=lines.append, kind="record")
    try:
        assert isinstance(r, RecordMetrics) and (
            "rafi_record_rows_total",
            frozenset({("machine", "m1")}),
        ) in scrape(port)
    finally:
        r.close()


@pytest.mark.parametrize("port", [0, 70000, "9100", True, 91.5])
def test_a_port_that_is_not_a_port_is_a_settings_error(port):
    with pytest.raises(
        SettingsError, match=r"^deploy\.metrics_port is .*expected a TCP port 1\.\.65535 or none$"
    ):
        metrics_from_settings({"metrics_port": port}, machine="m1")


def test_a_port_in_use_is_one_line_and_exit_64():
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        with pytest.raises(SettingsError) as info:
            metrics_from_settings({"metrics_port": port, "metrics_address": "127.0.0.1"}, machine="m1")
        with pytest.raises(SettingsError, match=r"^record\.metrics_port .*the port is in use"):
            metrics_from_settings({"metrics_port": port}, machine="m1", kind="record")
    message = str(info.value)
    assert info.value.exit_status == 64 and "\n" not in message
    assert message == (
        f"deploy.metrics_port {port} on 127.0.0.1: the port is in use (another rafi service or program "
        "listens there); choose another"
    )


def test_an_address_that_cannot_be_bound_names_the_address_setting():
    with pytest.raises(
        SettingsError,
        match=r"deploy\.metrics_port 19999 on 192\.0\.2\.1: cannot listen there .*metrics_address",
    ):
        LoopMetrics(machine="m1").serve(19999, "192.0.2.1")  # TEST-NET-1: not an address of this host


def test_the_safe_compensators_statuses_are_all_exposed(served):
    from rafi.deploy.limits import STATUSES

    m = served(machine="m1")
    s = scrape(m.port)
    assert {dict(k[1])["status"] for k in s if k[0] == "rafi_deploy_status"} >= set(STATUSES)
    m.status("a_new_status")  # a status added later gets its own series
    s = scrape(m.port)
    assert value(s, "rafi_deploy_status", machine="m1", status="a_new_status") == 1
    assert np.isclose(sum(v for k, v in s.items() if k[0] == "rafi_deploy_status"), 1.0)


def test_without_prometheus_client_only_no_port_works(monkeypatch):
    from rafi.deploy import metrics as module

    monkeypatch.setattr(module, "CollectorRegistry", None)  # as if the deploy extra were not installed
    assert metrics_from_settings({"metrics_port": None}, machine="m1") is None
    with pytest.raises(
        SettingsError, match=r"^deploy\.metrics_port is set but prometheus_client is not installed"
    ):
        metrics_from_settings({"metrics_port": 9464}, machine="m1")


def test_an_outage_is_a_status_and_referencing_has_no_model_value(served):
    m = served(machine="m1")
    # while referencing the compensator's 0 um is the reference, not a model value
    m.cycle(command("referencing", cmd=0.0, model=0.0), written=True, step_seconds=0.004)
    assert math.isnan(value(scrape(m.port), "rafi_deploy_model_um", machine="m1"))
    m.cycle(command("ok", cmd=1.0, model=1.5), written=True, step_seconds=0.004)
    m.connection(False)  # the loop: the link is down after this cycle
    m.cycle(None, written=False, step_seconds=3.0)
    s = scrape(m.port)
    statuses = {dict(k[1])["status"]: v for k, v in s.items() if k[0] == "rafi_deploy_status"}
    assert statuses["outage"] == 1 and sum(statuses.values()) == 1
    assert value(s, "rafi_deploy_connected", machine="m1") == 0
    m.reconnect()
    m.cycle(command("ok", cmd=1.2, model=1.6), written=True, step_seconds=0.004)
    s = scrape(m.port)
    assert value(s, "rafi_deploy_status", machine="m1", status="ok") == 1
    assert value(s, "rafi_deploy_status", machine="m1", status="outage") == 0
    assert value(s, "rafi_deploy_model_um", machine="m1") == 1.6
