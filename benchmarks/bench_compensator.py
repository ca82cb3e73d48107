"""Time per step and memory of the streaming compensator (rafi.deploy), per model kind.

Usage::

    python benchmarks/bench_compensator.py                 # every kind, fitted on synthetic logs
    python benchmarks/bench_compensator.py --steps 20000
    python benchmarks/bench_compensator.py --artefact results/tapping-center-a/comparison/best_model.json

Without ``--artefact`` every kind is fitted with its default hyperparameters (``auto`` grids,
``grey_box`` with every filter constant) on three synthetic 4 h logs at 5 s sampling
(``rafi.twin.synthetic_logs.schedule_log``, cold start at rest, 3000/6000/9000 r/min,
reference ``run_start`` over 60 s), and the ensemble of those five (equal weights,
``rafi.family.ensemble``: one compensator per member, blended). Each compensator then runs a
multi-speed log, sample by sample (``--steps`` samples, the log repeated), after a warm-up of
200 samples.

Prints one row per model: the features, median / 99th percentile / max time per
``Compensator.step`` (us; target < 1000 us) and per ``SafeCompensator.step`` (the same model
inside the limits and fault rules with the default ``deploy`` settings: what runs on the
machine), the run-time state of the compensator
(``state_nbytes``: filter states and reference) and the memory the running compensator holds
as traced by ``tracemalloc`` (every Python object created by ``from_artefact`` and kept after
the steps, the artefact dict itself excluded), bare and with the limits. Single-threaded
BLAS, as on a controller PC.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import tracemalloc
import warnings
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rafi import SENSORS  # noqa: E402
from rafi.deploy.compensator import Compensator  # noqa: E402
from rafi.deploy.limits import Limits, SafeCompensator  # noqa: E402
from rafi.settings import MACHINE_DEFAULTS  # noqa: E402

WINDOW = 60.0
PERIOD = 5.0


def _fitted_artefacts() -> dict:
    """Every kind, default hyperparameters, fitted on synthetic cold-start logs."""
    from rafi.family.dynamic import DynamicRidge
    from rafi.family.grey_box import GreyBox
    from rafi.family.published import PublishedRafi
    from rafi.family.rafi_linear import RafiLinear
    from rafi.family.ridge_global import RidgeGlobal
    from rafi.twin.synthetic_logs import schedule_log
    from rafi.twin.synthetic_runs import runs_of_logs

    logs = {
        f"train{i}.csv": schedule_log(
            [(0, 180), (s, 4 * 3600), (0, 3600)], period_s=PERIOD, seed=i, speed_noise_rpm=3.0
        )[0]
        for i, s in enumerate((3000, 6000, 9000))
    }
    table, frame = runs_of_logs(logs, reference_window_s=WINDOW)
    ref = {"rule": "run_start", "window_s": WINDOW}
    models = {
        "rafi": PublishedRafi(key_sensors=["T6", "T8", "T9"], reference=ref),
        "rafi_linear": RafiLinear(key_sensors=["T6", "T8", "T9"], reference=ref),
        "ridge_global": RidgeGlobal(reference=ref),
        "dynamic": DynamicRidge(reference=ref),
        "grey_box": GreyBox(reference=ref),
    }
    from rafi.family.ensemble import WeightedEnsemble

    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for kind, m in models.items():
            t0 = time.perf_counter()
            out[kind] = json.loads(json.dumps(m.fit(table, frame).to_dict()))
            print(f"fitted {kind} in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    ensemble = WeightedEnsemble.from_fitted(models, dict.fromkeys(models, 1.0))
    out["ensemble"] = json.loads(json.dumps(ensemble.to_dict()))
    return out


def n_features(artefact: dict) -> int:
    """The features (ridge kinds) or terms (RAFI) of a model; an ensemble's: its members' together."""
    if artefact.get("kind") == "ensemble":
        return sum(n_features(m) for m in artefact["members"].values())
    return len(artefact.get("features", artefact.get("terms", [])))


def _inputs(steps: int):
    """``steps`` samples of a multi-speed log (repeated as needed): t, speed, T1..T16."""
    from rafi.twin.synthetic_logs import schedule_log

    frame, _ = schedule_log(
        [(0, 180), (4500, 2700), (12000, 2700), (0, 1800), (7500, 2700)], period_s=PERIOD, seed=9
    )
    n = len(frame)
    idx = np.arange(steps) % n
    t = idx * PERIOD + (np.arange(steps) // n) * n * PERIOD
    return t.astype(float), frame["speed_rpm"].to_numpy(float)[idx], frame[list(SENSORS)].to_numpy(float)[idx]


def _time_steps(make, t, rpm, temps, steps: int) -> tuple[object, np.ndarray, int]:
    """Build a compensator with ``make()``, warm it up, time ``steps`` steps (ns) and trace the
    memory it holds after them (bytes)."""
    tracemalloc.start()
    before = tracemalloc.take_snapshot()
    comp = make()
    for k in range(200):  # warm-up: the reference window and the first filter steps
        comp.step(t[k], rpm[k], temps[k])
    times = np.empty(steps)
    tracemalloc.stop()  # tracing slows every allocation: time the steps without it
    clock = time.perf_counter_ns
    for k in range(steps):
        a = clock()
        comp.step(t[200 + k], rpm[200 + k], temps[200 + k])
        times[k] = clock() - a
    tracemalloc.start()
    comp.step(t[-1] + PERIOD, rpm[-1], temps[-1])
    after = tracemalloc.take_snapshot()
    tracemalloc.stop()
    held = sum(s.size_diff for s in after.compare_to(before, "filename") if s.size_diff > 0)
    return comp, times, held


def bench(name: str, artefact: dict, steps: int) -> dict:
    """Time per step and memory of one compensator over ``steps`` samples, bare and inside the
    limits and fault rules (``SafeCompensator`` with the default ``deploy`` settings)."""
    t, rpm, temps = _inputs(steps + 200)
    comp, times, held = _time_steps(lambda: Compensator.from_artefact(artefact), t, rpm, temps, steps)
    limits = Limits.from_settings({**MACHINE_DEFAULTS["deploy"], "interval_s": PERIOD})
    _, safe_times, safe_held = _time_steps(
        lambda: SafeCompensator(limits=limits).load(artefact), t, rpm, temps, steps
    )
    us, safe_us = times / 1000.0, safe_times / 1000.0
    return {
        "model": name,
        "kind": comp.kind,
        "features": n_features(artefact),
        "median_us": float(np.median(us)),
        "p99_us": float(np.percentile(us, 99)),
        "max_us": float(us.max()),
        "safe_median_us": float(np.median(safe_us)),
        "safe_p99_us": float(np.percentile(safe_us, 99)),
        "state_bytes": comp.state_nbytes,
        "held_kib": held / 1024.0,
        "safe_held_kib": safe_held / 1024.0,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=5000, help="timed steps per model")
    ap.add_argument("--artefact", action="append", default=[], help="a model.json (repeatable)")
    args = ap.parse_args(argv)
    if args.artefact:
        artefacts = {Path(p).as_posix(): json.loads(Path(p).read_text()) for p in args.artefact}
    else:
        artefacts = _fitted_artefacts()
    rows = [bench(name, d, args.steps) for name, d in artefacts.items()]
    print(f"\nCompensator.step, {args.steps} steps per model, {os.cpu_count()} CPUs, single-threaded BLAS\n")
    print(
        "| model | kind | features | median us/step | p99 us | max us | with limits: median us | p99 us "
        "| state bytes | held KiB | with limits: held KiB |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r['model']} | {r['kind']} | {r['features']} | {r['median_us']:.1f} | {r['p99_us']:.1f} "
            f"| {r['max_us']:.0f} | {r['safe_median_us']:.1f} | {r['safe_p99_us']:.1f} | {r['state_bytes']} "
            f"| {r['held_kib']:.1f} | {r['safe_held_kib']:.1f} |"
        )
    worst = max(r["safe_p99_us"] for r in rows)
    print(f"\nworst p99: {worst:.1f} us per step (target < 1000 us)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
