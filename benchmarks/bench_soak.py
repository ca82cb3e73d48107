"""Soak: days of twin data through ``rafi deploy``'s loop to a local OPC UA server, as fast as it goes.

Usage::

    python benchmarks/bench_soak.py                      # 7 simulated days at 5 s: 120 960 cycles
    python benchmarks/bench_soak.py --days 1 --seed 3
    python benchmarks/bench_soak.py --interval-s 30      # 20 160 cycles

What runs is what ``rafi deploy`` runs: :func:`rafi.deploy.live_cli.build` from a ``config.yaml``
and a registry whose champion is a ``ridge_global`` fitted on three twin training runs (T6, T8,
T9; 3000/6000/9000 r/min, cold starts), i.e. :class:`rafi.deploy.live.LiveLoop`,
:class:`rafi.deploy.limits.SafeCompensator`, :class:`rafi.deploy.opcua_client.OpcUaLink` and
the SINUMERIK target, writing SD 43900 of the SINUMERIK-like server of ``tests/opcua_server.py``
(asyncua, 127.0.0.1, in a process of its own, as a controller is another machine: the memory and
the timings are the client's, and tracing does not slow the server's restarts). The loop's own
metrics (``deploy.metrics_port``: a free port) are served and scraped at the end of each day, to
soak them too.

The clock is simulated: the loop's clock is the twin's time, and the loop's ``sleep`` puts the
next sample of the twin (``rafi.twin.simulate.simulate_run``: a 7-day schedule of random speed
steps, rests and a few speeds above the trained ones, the room's daily cycle, no logger defects)
on the server's input nodes. Every ``--restart-every-h`` simulated hours the server stops for a
random 2..10 cycles and starts again (values kept); ``--bad-spans-per-day`` times a day on
average a random sensor (half the time one the model reads) reads BadSensorFailure for a random
1 cycle .. 1 h. The SD value held on the server before the start is ``--held-um`` (the -6.8 um
of issue 24).

Every value the server accepted on SD 43900 (``server.client_writes()``, converted through the
axis sign and MD 10200) is checked:

* clamp: inside ``deploy.clamp_um`` (+- one resolution step);
* rate: ``|step| <= rate_um_per_s * interval_s`` + one resolution step, between consecutive
  writes, across every outage too;
* bumpless: the first write after the start and after each server restart differs from the
  value held on the server by at most ``rate_um_per_s * interval_s`` (+ one resolution step).

Printed: the checks (a failed one exits 1), and side by side for the first and the last
simulated day the wall time per cycle (median, p99, max: read + compute + write over OPC UA,
with tracemalloc on unless ``--no-tracemalloc``), the memory traced by tracemalloc at the end of
the day (current, and the day's peak: everything the loop, the OPC UA client and the metrics
hold; the benchmark's own arrays of 8 bytes per cycle are in it too) and the resident set size.
The cycles per second of the whole run include feeding the server, which the loop does not time.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import sys
import tempfile
import time
import tracemalloc
import urllib.request
import warnings
from collections import Counter, deque
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from opcua_server import SinumerikLikeServer, free_port, input_settings  # noqa: E402

from rafi import SENSORS  # noqa: E402
from rafi.settings import MACHINE_DEFAULTS  # noqa: E402

MACHINE = "soak-m1"
KEY = ["T6", "T8", "T9"]
INCR = 100000  # MD 10200: 0.01 um resolution
SIGN = -1
RES_UM = 1e3 / INCR
USER, PASSWORD = "seawriter", "s3cret-Pw"
DAY_S = 86400.0


def fit_champion() -> dict:
    """A ridge_global on T6, T8, T9 fitted on three 4 h cold-start twin runs (about 2 s)."""
    from rafi.family.ridge_global import RidgeGlobal
    from rafi.twin.schedules import constant_schedule, with_rest
    from rafi.twin.simulate import simulate_run
    from rafi.twin.synthetic_runs import runs_of_logs

    logs = {}
    for i, speed in enumerate((3000, 6000, 9000)):
        run = simulate_run(
            with_rest(constant_schedule(speed, 4 * 3600)), seed=100 + i, start=f"2026-03-0{2 + i}T08:00",
            defects=False, sample_period_s=5,
        )  # fmt: skip
        logs[f"train_{speed}.csv"] = run.log
    table, frame = runs_of_logs(logs, reference_window_s=60)
    model = RidgeGlobal(sensors=KEY, reference={"rule": "run_start", "window_s": 60}, machine=MACHINE)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return json.loads(json.dumps(model.fit(table, frame).to_dict()))


def soak_inputs(days: float, interval_s: float, rng) -> tuple[np.ndarray, np.ndarray]:
    """(speed per cycle, temperatures per cycle) of a twin run of ``days`` at ``interval_s``."""
    from rafi.twin.machines import Ambient
    from rafi.twin.schedules import schedule_from_pairs
    from rafi.twin.simulate import simulate_run

    pairs, total = [(180.0, 0.0)], 180.0
    while total < days * DAY_S + interval_s:
        speed = float(
            rng.choice(
                [0, 0, 3000, 4500, 6000, 7500, 9000, 10500],
                p=[0.15, 0.15, 0.14, 0.12, 0.14, 0.12, 0.14, 0.04],
            )
        )
        duration = float(rng.uniform(1200, 3 * 3600))
        pairs.append((duration, speed))
        total += duration
    run = simulate_run(
        schedule_from_pairs(pairs), seed=int(rng.integers(1 << 30)), start="2026-06-01T06:00",
        ambient=Ambient(base_c=22.0), defects=False, sample_period_s=interval_s,
    )  # fmt: skip
    n = int(round(days * DAY_S / interval_s))
    log = run.log.iloc[:n]
    return log["speed_rpm"].to_numpy(float), log[list(SENSORS)].to_numpy(float)


def bad_spans(n: int, per_day: float, interval_s: float, rng) -> np.ndarray:
    """A (cycles x 16) mask of BadSensorFailure: random spans of 1 cycle .. 1 h on random sensors."""
    mask = np.zeros((n, 16), dtype=bool)
    starts = rng.random(n) < per_day * interval_s / DAY_S
    for c in np.flatnonzero(starts):
        sensor = SENSORS.index(str(rng.choice(KEY))) if rng.random() < 0.5 else int(rng.integers(16))
        mask[c : c + int(rng.integers(1, max(2, 3600 / interval_s))), sensor] = True
    return mask


def write_project(folder: Path, server, champion: dict, interval_s: float) -> argparse.Namespace:
    """config.yaml and results/<machine>/registry with the champion; the args of ``rafi deploy``."""
    registry = folder / "results" / MACHINE / "registry"
    (registry / "models").mkdir(parents=True)
    (registry / "models" / f"{champion['model_id']}.json").write_text(json.dumps(champion))
    (registry / "champion.json").write_text(json.dumps({"model_id": champion["model_id"]}))
    inputs = input_settings()
    deploy = {
        "interval_s": interval_s,
        "target": {
            "kind": "sinumerik",
            "axis": {"name": "Z", "number": server.axis, "sign": SIGN, "limit_um": 60.0},
            "int_incr_per_mm": INCR,
        },
        "opcua": {
            "endpoint": server.endpoint, "inputs": inputs, "timeout_s": 3,
            "reconnect_min_s": 1, "reconnect_max_s": 2, "allow_insecure": True,  # a local test server
        },
        "metrics_port": free_port(),
    }  # fmt: skip
    (folder / "config.yaml").write_text(yaml.safe_dump({"machines": {MACHINE: {"deploy": deploy}}}))
    return argparse.Namespace(
        machine=MACHINE, config=str(folder / "config.yaml"), model=None, follow=None, dry_run=False,
        cycles=None, debug=False,
    )  # fmt: skip


def rss_mb() -> float:
    """The resident set size now (MB; Linux /proc), else the peak (getrusage)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


class Soak:
    """The loop, the server and the simulated clock; :meth:`run` plays every cycle."""

    def __init__(self, args, server, speeds, temps, bad, loop, link):
        self.args, self.server, self.loop, self.link = args, server, loop, link
        self.speeds, self.temps, self.bad = speeds, temps, bad
        self.n = len(speeds)
        self.interval = float(args.interval_s)
        self.clock = 1.0e6
        self.cycle_no = 0
        self.down_until = -1
        self.restarts: list[int] = []  # number of SD writes before each server stop
        self.step_s = np.full(self.n, np.nan)
        self.days: list[dict] = []
        self.statuses: Counter = Counter()
        self.rng = np.random.default_rng(args.seed + 1)
        every = max(1, int(round(args.restart_every_h * 3600 / self.interval)))
        self.stop_at = set(range(every, self.n, every))
        loop.clock = link.clock = lambda: self.clock
        loop.sleep = self.sleep
        self._cycle = loop.cycle
        loop.cycle = self.timed_cycle

    def feed(self, c: int) -> None:
        temps = np.where(self.bad[c], np.nan, self.temps[c])
        self.server.set_inputs(self.speeds[c], temps)

    def timed_cycle(self, now: float) -> None:
        """One cycle of the loop (which drives its own metrics), timed."""
        last = self.loop.last_command
        start = time.perf_counter()
        self._cycle(now)
        self.step_s[self.cycle_no] = time.perf_counter() - start
        if self.loop.last_command is not last:
            self.statuses[self.loop.last_command.status] += 1

    def sleep(self, seconds: float) -> None:
        self.clock += seconds
        self.cycle_no += 1
        c = self.cycle_no
        if c % int(round(DAY_S / self.interval)) == 0:
            self.end_of_day(c)
        if c in self.stop_at:
            self.restarts.append(len(self.server.sd_values()))
            self.server.stop()
            self.down_until = c + int(self.rng.integers(2, 11))
        elif c == self.down_until:
            self.server.start()
        if c < self.n and self.server.up:  # stopped: the inputs wait for the restart
            self.feed(c)

    def end_of_day(self, c: int) -> None:
        """The figures of the day that ends before cycle ``c`` (a last, shorter day too)."""
        ms = self.step_s[len(self.days) * int(round(DAY_S / self.interval)) : c] * 1e3
        ms = ms[np.isfinite(ms)]
        day = {"day": len(self.days) + 1, "cycles": len(ms)}
        day.update(
            median_ms=float(np.median(ms)), p99_ms=float(np.percentile(ms, 99)), max_ms=float(ms.max())
        )
        if tracemalloc.is_tracing():
            current, peak = tracemalloc.get_traced_memory()
            day.update(traced_mb=current / 2**20, traced_peak_mb=peak / 2**20)
            tracemalloc.reset_peak()
        day["rss_mb"] = rss_mb()
        day["writes_metric"] = scraped(self.loop.metrics.port, "rafi_deploy_writes_total")
        self.days.append(day)
        print(
            f"day {day['day']}: {len(ms)} cycles, median {day['median_ms']:.2f} ms, "
            f"{day.get('traced_mb', float('nan')):.1f} MB traced, {time.perf_counter() - T0:.0f} s wall",
            file=sys.stderr, flush=True,
        )  # fmt: skip

    def run(self) -> None:
        self.link.connect()
        self.loop.metrics.connection(True)
        self.feed(0)
        self.loop.run(max_cycles=self.n)
        if len(self.days) * int(round(DAY_S / self.interval)) < self.n:
            self.end_of_day(self.n)


def _serve(conn, held_mm: float) -> None:
    """The server process: runs the SinumerikLikeServer, answers ``(method, *args)`` requests."""
    server = SinumerikLikeServer(axis=3, user=USER, password=PASSWORD)
    server.values[server.sd_node()] = (held_mm, server.values[server.sd_node()][1])
    server.start()
    conn.send(server.endpoint)
    try:
        while True:
            method, *call = conn.recv()
            if method == "close":
                break
            if method == "sd_values":
                conn.send([w.value for w in server.client_writes() if w.node == server.sd_node()])
            else:
                getattr(server, method)(*call)
                conn.send(None)
    finally:
        server.close()
        conn.send(None)


class ServerProcess:
    """The SinumerikLikeServer in its own process, so that tracemalloc and the timings see the
    client only (a controller is another machine) and a restart is not slowed by tracing."""

    def __init__(self, held_mm: float):
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._process = ctx.Process(target=_serve, args=(child, held_mm), daemon=True)
        self._process.start()
        self.endpoint = self._conn.recv()
        self.axis = 3
        self.up = True

    def _call(self, method: str, *args):
        self._conn.send((method, *args))
        return self._conn.recv()

    def stop(self) -> None:
        self._call("stop")
        self.up = False

    def start(self) -> None:
        self._call("start")
        self.up = True

    def set_inputs(self, speed_rpm: float, temperatures) -> None:
        self._call("set_inputs", float(speed_rpm), [float(t) for t in temperatures])

    def sd_values(self) -> list[float]:
        return self._call("sd_values")

    def close(self) -> None:
        self._call("close")
        self._process.join(60)


def scraped(port: int, name: str) -> float:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10) as response:
        for line in response.read().decode().splitlines():
            if line.startswith(name + "{"):
                return float(line.rsplit(" ", 1)[1])
    return float("nan")


def check(written_um: list[float], held_um: float, restarts: list[int], deploy: dict, interval_s: float):
    """The clamp, rate and bumpless checks of the module docstring: (lines, all passed)."""
    lo, hi = deploy["clamp_um"]
    step_max = deploy["rate_um_per_s"] * interval_s
    w = np.asarray(written_um)
    steps = np.abs(np.diff(np.concatenate([[held_um], w])))
    outside = int(np.sum((w < lo - RES_UM) | (w > hi + RES_UM)))
    rate_bad = int(np.sum(steps[1:] > step_max + RES_UM))
    first = [(0, held_um)] + [(k, w[k - 1]) for k in restarts if 0 < k < len(w)]
    bumps = [abs(w[k] - held) for k, held in first if k < len(w)]
    bump_bad = sum(b > step_max + RES_UM for b in bumps)
    lines = [
        f"clamp    {'ok  ' if not outside else 'FAIL'} {len(w)} writes in [{min(w):+.3f}, {max(w):+.3f}] um,"
        f" {outside} outside clamp_um [{lo:g}, {hi:g}]",
        f"rate     {'ok  ' if not rate_bad else 'FAIL'} largest step {steps[1:].max():.4f} um,"
        f" {rate_bad} above rate x interval {step_max:.4f} um + {RES_UM:g} um",
        f"bumpless {'ok  ' if not bump_bad else 'FAIL'} start: held {held_um:+.3f} um,"
        f" first write {w[0]:+.3f} um"
        f" (step {bumps[0]:.3f} um); {len(bumps) - 1} server restarts: largest first step"
        f" {max(bumps[1:], default=0.0):.4f} um; {bump_bad} above {step_max:.4f} um",
    ]
    return lines, not (outside or rate_bad or bump_bad)


def table(days: list[dict]) -> list[str]:
    """The first and the last simulated day side by side."""
    cols = [days[0], days[-1]] if len(days) > 1 else [days[0]]
    head = " | ".join(f"day {d['day']}" for d in cols)
    rows = [
        ("cycles", "cycles", "{:.0f}"),
        ("step median (ms)", "median_ms", "{:.2f}"),
        ("step p99 (ms)", "p99_ms", "{:.2f}"),
        ("step max (ms)", "max_ms", "{:.1f}"),
        ("tracemalloc current (MB)", "traced_mb", "{:.2f}"),
        ("tracemalloc peak of the day (MB)", "traced_peak_mb", "{:.2f}"),
        ("RSS (MB)", "rss_mb", "{:.0f}"),
        ("writes (metric)", "writes_metric", "{:.0f}"),
    ]
    out = [f"| | {head} |", "|---|" + "---|" * len(cols)]
    for label, key, fmt in rows:
        out.append(f"| {label} | " + " | ".join(fmt.format(d.get(key, float("nan"))) for d in cols) + " |")
    return out


def main(argv=None) -> int:
    global T0
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--days", type=float, default=7.0)
    parser.add_argument(
        "--interval-s", type=float, default=float(MACHINE_DEFAULTS["deploy"]["interval_s"]),
        help="deploy.interval_s (default: its default, 5 s)",
    )  # fmt: skip
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--restart-every-h", type=float, default=6.0)
    parser.add_argument("--bad-spans-per-day", type=float, default=4.0)
    parser.add_argument("--held-um", type=float, default=-6.8, help="SD 43900 before the start (um)")
    parser.add_argument("--no-tracemalloc", action="store_true", help="time the cycles without tracing")
    args = parser.parse_args(argv)
    from rafi.deploy import live_cli

    T0 = time.perf_counter()
    rng = np.random.default_rng(args.seed)
    champion = fit_champion()
    speeds, temps = soak_inputs(args.days, args.interval_s, rng)
    bad = bad_spans(len(speeds), args.bad_spans_per_day, args.interval_s, rng)
    print(f"inputs ready: {len(speeds)} cycles, {time.perf_counter() - T0:.1f} s", file=sys.stderr)
    deploy = dict(MACHINE_DEFAULTS["deploy"], interval_s=args.interval_s)
    server = ServerProcess(SIGN * args.held_um / 1000.0)
    if not args.no_tracemalloc:
        tracemalloc.start()
    folder = tempfile.mkdtemp(prefix="rafi-soak-")
    try:
        ns = write_project(Path(folder), server, champion, args.interval_s)
        log = deque(maxlen=100)  # the loop's lines (one per write): the last ones only, not a growing list
        loop, link = live_cli.build(
            ns, log=log.append, environ={"RAFI_OPCUA_USER": USER, "RAFI_OPCUA_PASSWORD": PASSWORD}
        )
        soak = Soak(args, server, speeds, temps, bad, loop, link)
        try:
            soak.run()
        finally:
            link.close()
            loop.metrics.close()
        written = [SIGN * v * 1000.0 for v in server.sd_values()]
    finally:
        server.close()
        shutil.rmtree(folder, ignore_errors=True)
    tracemalloc.stop()
    wall = time.perf_counter() - T0
    lines, ok = check(written, args.held_um, soak.restarts, deploy, args.interval_s)
    print(
        f"soak: {args.days:g} simulated day(s) at {args.interval_s:g} s = {soak.n} cycles, seed {args.seed}; "
        f"{len(soak.restarts)} server restarts ({loop.outage_cycles} cycles without the controller, "
        f"{link.reconnects} reconnects); {int(bad.any(axis=1).sum())} cycles with a bad sensor; "
        f"{loop.writes} writes; {wall:.0f} s wall ({soak.n / wall:.0f} cycles/s)"
    )
    print("statuses: " + ", ".join(f"{k} {v}" for k, v in soak.statuses.most_common()))
    print(*lines, sep="\n")
    print(*table(soak.days), sep="\n")
    return 0 if ok else 1


T0 = time.perf_counter()

if __name__ == "__main__":
    sys.exit(main())
