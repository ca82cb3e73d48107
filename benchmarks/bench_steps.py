"""Time of single method steps on synthetic data of a known size (in-process, no Snakemake).

Usage::

    python benchmarks/bench_steps.py             # every case, 5 repeats, the median
    python benchmarks/bench_steps.py --repeat 9

Cases (what the tests once asserted with timers; a test must not time):

* ``twin_4h_run``: ``rafi.twin.simulate.simulate_run`` of a 4 h run at 9000 r/min (2880
  samples); target < 1 s.
* ``clean_3000``: ``rafi.method.clean.clean_log`` (the tests' settings) of a 3000-row log with
  every defect kind injected; target < 0.2 s.
* ``clean_30000``: the same on 30 000 rows with two long gaps; target < 1 s.
* ``find_runs_37000``: ``rafi.method.runs.find_runs`` of a ~37 000-sample continuous log
  (three times the test suite's continuous schedule); target < 0.5 s.

Prints a Markdown table (median and min of ``--repeat`` timed calls after one warm-up call).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def cases() -> dict:
    """name -> (callable, target seconds)."""
    from rafi.method.clean import clean_log
    from rafi.method.runs import find_runs
    from rafi.twin.schedules import constant_schedule
    from rafi.twin.simulate import simulate_run
    from rafi.twin.synthetic_logs import (
        CLEAN_KWARGS,
        CONTINUOUS_SCHEDULE,
        FIND_RUNS_KWARGS,
        canonical_log,
        inject_defects,
        schedule_log,
    )

    small, _ = canonical_log(3000, seed=3)
    small, _ = inject_defects(small, duplicates=3, swaps=3, spikes=5, dropouts=5, gaps=3, seed=1)
    big, _ = canonical_log(30000, extras=False, seed=1)
    big, _ = inject_defects(
        big, duplicates=20, swaps=20, spikes=40, dropouts=40, gaps=20, long_gaps=2, seed=3
    )
    clean_kw = CLEAN_KWARGS
    cont, _ = schedule_log(CONTINUOUS_SCHEDULE * 3, speed_noise_rpm=20)
    kw = FIND_RUNS_KWARGS
    return {
        "twin_4h_run": (lambda: simulate_run(constant_schedule(9000, 4 * 3600), seed=1), 1.0),
        "clean_3000": (lambda: clean_log(small, **clean_kw), 0.2),
        "clean_30000": (lambda: clean_log(big, **clean_kw), 1.0),
        "find_runs_37000": (lambda: find_runs({"log": cont}, {"log": "sha"}, **kw), 0.5),
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5, help="timed calls per case (after one warm-up)")
    args = ap.parse_args(argv)
    print("| case | median s | min s | target s |\n|---|---|---|---|")
    for name, (call, target) in cases().items():
        call()
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            call()
            times.append(time.perf_counter() - t0)
        print(f"| {name} | {statistics.median(times):.3f} | {min(times):.3f} | {target:g} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
