"""Fit and predict time of every model of the family (docs/models.md).

Usage (after the pipeline has produced results/<machine>/runs.* and rank/key_sensors.json)::

    python benchmarks/bench_models.py                       # every machine under results/
    python benchmarks/bench_models.py --machine tapping-center-a --repeat 3
    python benchmarks/bench_models.py --synthetic           # no pipeline outputs needed
    python benchmarks/bench_models.py --twin-preview --compare   # twin physics, no pipeline
    python benchmarks/bench_models.py --family --kinds rafi     # rule compare's run_family, cold / CV memo

``--twin-preview`` simulates clean runs with the digital twin's physics (``rafi.twin.physics``:
integrate / sensor_truth / displacement_truth; no logger defects, so no clean/runs step is
needed): 6 cold-start 4 h training runs at 3000..18000 r/min, 3 h validation runs at
4500, 8000, 10500, 13500, 16500 r/min and a 4.5 h multi-condition run (45 min steps
6000, 12000, 4500, 16500, 9000, 13500), rises referenced to the median of the first 60 s.
``--compare`` also prints the comparison (rule compare's tables) per validation run.

Prints one line per (machine, model): best-of-``repeat`` fit time (with the model's own
whole-run CV for the hyperparameters), predict time for all samples, the chosen
hyperparameters, and the row count. RAFI's refits skip the statsmodels diagnostics (HAC
errors, VIF), as in the compare rule. BLAS runs single-threaded, as in the compare rule.
Settings: each machine's effective settings (``rafi.settings.machine_settings`` on
``config.yaml``); the synthetic and twin data use the defaults. Timings are measured here and
logged by the compare job; they are never written into the comparison tables.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # as in workflow/scripts/compare.py: small matrices, one thread

import pandas as pd  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rafi.family.compare import make_model, run_family  # noqa: E402
from rafi.settings import MACHINE_DEFAULTS, machine_settings  # noqa: E402
from rafi.twin.synthetic_runs import make_synthetic_runs  # noqa: E402


def _load(machine_dir: Path):
    table = pd.read_csv(machine_dir / "runs.csv")
    frame = pd.read_parquet(machine_dir / "runs.parquet")
    key = json.loads((machine_dir / "rank" / "key_sensors.json").read_text())["sensors"]
    return table, frame, key


def _settings(machine: str) -> dict:
    """The machine's effective settings (every key present)."""
    import yaml

    return machine_settings(yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8")), machine)


def twin_preview(seed: int = 0, dt: float = 5.0):
    """(runs_table, runs_frame) of clean twin runs, key sensors T6, T8, T9 (the paper's)."""
    import numpy as np

    from rafi.twin import physics
    from rafi.twin.machines import tapping_center_a

    p = tapping_center_a()
    rng = np.random.default_rng(seed)

    def run(rid, role, sched, speed):
        sp = np.concatenate([np.full(int(d / dt), s, float) for d, s in sched])
        n = len(sp)
        t = np.arange(n) * dt
        amb = 22 + 0.3 * np.sin(2 * np.pi * t / (6 * 3600) + rng.uniform(0, 6))
        nodes, _ = physics.integrate(p, sp, amb, dt)
        temps = physics.sensor_truth(p, nodes, amb, dt) + rng.normal(0, p.temp_noise_c, (n, 16))
        z = physics.displacement_truth(p, nodes, sp, dt, nodes[0]) + rng.normal(0, p.disp_noise_um, n)
        ref = t <= 60
        f = pd.DataFrame({"run_id": rid, "t_s": t, "speed_rpm": sp})
        for i in range(16):
            f[f"dT{i + 1}"] = temps[:, i] - np.median(temps[ref, i])
        f["dz_um"] = z - np.median(z[ref])
        return {"run_id": rid, "role": role, "speed_rpm": float(speed)}, f

    rows, frames = [], []
    for s in (3000, 6000, 9000, 12000, 15000, 18000):
        r, f = run(f"train-{s}", "training", [(4 * 3600, s)], s)
        rows.append(r), frames.append(f)
    for s in (4500, 8000, 10500, 13500, 16500):
        r, f = run(f"val-{s}", "validation_single", [(3 * 3600, s)], s)
        rows.append(r), frames.append(f)
    steps = [(2700, s) for s in (6000, 12000, 4500, 16500, 9000, 13500)]
    r, f = run("val-multi", "validation_multi", steps, 9000)
    rows.append(r), frames.append(f)
    return pd.DataFrame(rows), pd.concat(frames, ignore_index=True)


def show_comparison(name, table, frame, key, settings):
    res = run_family(
        table,
        frame,
        key_sensors=key,
        terms=settings["fit"]["terms"],
        reference=settings["reference"],
        machine=name,
        options=settings["models"],
        gates=settings["qualification"],
        log=lambda m: None,
    )
    pr = res["per_run"]
    for col in ("max_abs_before_um", "max_abs_after_um", "improvement_pct"):
        print(f"\n{col}")
        print(pr.pivot(index="run_id", columns="model", values=col).round(2).to_string())
    print(
        "\n"
        + res["summary"][["model", "max_abs_after_um", "improvement_pct", "passed", "champion"]]
        .round(2)
        .to_string(index=False)
    )


def bench(name, table, frame, key, settings, repeat, kinds):
    n_train = int(frame["run_id"].isin(table.loc[table["role"] == "training", "run_id"]).sum())
    for kind in kinds:
        best_fit, best_pred, model = float("inf"), float("inf"), None
        for _ in range(repeat):
            t0 = time.perf_counter()
            model = make_model(
                kind,
                key_sensors=key,
                terms=settings["fit"]["terms"],
                reference=settings["reference"],
                machine=name,
                options=settings["models"],
            ).fit(table, frame)
            best_fit = min(best_fit, time.perf_counter() - t0)
            t0 = time.perf_counter()
            model.predict(frame)
            best_pred = min(best_pred, time.perf_counter() - t0)
        hp = f"alpha={model.alpha_:g} taus_s={model.taus_}" if hasattr(model, "alpha_") else ""
        print(
            f"{name:20s} {kind:13s} fit {best_fit:7.2f} s  predict {best_pred:6.2f} s "
            f"({len(frame)} rows, {n_train} training)  {hp}",
            flush=True,
        )


def bench_family(name, table, frame, key, settings, repeat):
    """Rule compare's work (:func:`run_family`: every fit, the nested whole-run CV, validation)
    cold and with the CV rows read from the memo (:mod:`rafi.family.cv_memo`), best of ``repeat``:
    wall and CPU seconds."""
    import tempfile

    def once(memo_dir):
        w0, c0 = time.perf_counter(), time.process_time()
        res = run_family(
            table,
            frame,
            key_sensors=key,
            terms=settings["fit"]["terms"],
            reference=settings["reference"],
            machine=name,
            options=settings["models"],
            gates=settings["qualification"],
            hac_maxlags=settings["fit"]["hac_maxlags"],
            speed_tolerance_rpm=settings["speed_tolerance_rpm"],
            cv_memo_dir=memo_dir,
            code_version="sha256:bench" if memo_dir else None,
            log=lambda m: None,
        )
        return time.perf_counter() - w0, time.process_time() - c0, res["cv_memo"]

    with tempfile.TemporaryDirectory() as memo_dir:
        once(memo_dir)  # fills the memo
        for label, folder in (("cold", None), ("CV from the memo", memo_dir)):
            wall, cpu, memo = min(once(folder) for _ in range(repeat))
            print(f"{name:20s} run_family {label:17s} {wall:6.2f} s wall {cpu:6.2f} s CPU (memo: {memo})")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--results", default=str(ROOT / "results"))
    p.add_argument("--machine", action="append")
    p.add_argument("--repeat", type=int, default=1)
    p.add_argument("--synthetic", action="store_true")
    p.add_argument("--twin-preview", action="store_true")
    p.add_argument("--compare", action="store_true", help="also print the per-run comparison")
    p.add_argument("--kinds", nargs="+", help="default: the machine's models: enabled")
    p.add_argument(
        "--family", action="store_true", help="also time run_family cold and with the CV from the memo"
    )
    a = p.parse_args(argv)
    warnings.simplefilter("ignore")
    if a.synthetic or a.twin_preview:
        if a.synthetic:
            table, frame, key = (*make_synthetic_runs(sample_s=5.0, n_sensors=16), ["T1", "T2", "T3"])
        else:
            table, frame, key = (*twin_preview(), ["T6", "T8", "T9"])
        name = "synthetic" if a.synthetic else "twin-preview"
        settings = MACHINE_DEFAULTS
        bench(name, table, frame, key, settings, a.repeat, a.kinds or settings["models"]["enabled"])
        if a.compare:
            show_comparison(name, table, frame, key, settings)
        return 0
    machines = a.machine or sorted(
        p.name for p in Path(a.results).iterdir() if (p / "runs.parquet").is_file()
    )
    for m in machines:
        table, frame, key = _load(Path(a.results) / m)
        settings = _settings(m)
        bench(m, table, frame, key, settings, a.repeat, a.kinds or settings["models"]["enabled"])
        if a.family:
            bench_family(m, table, frame, key, settings, a.repeat)
        if a.compare:
            show_comparison(m, table, frame, key, settings)
    return 0


if __name__ == "__main__":
    sys.exit(main())
