"""Time the qualification report for one machine's results directory (target < 15 s).

    python benchmarks/bench_report.py results/tapping-center-a      # real pipeline output
    python benchmarks/bench_report.py --synthetic                    # full-size synthetic (5 s grid)

Prints wall and CPU seconds of the upstream steps (rules report_tables and report_figures, run
here on the synthetic fixture; a pipeline's results directory has their outputs) and of the
report job per stage (context, HTML, PDF), and sizes.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 15.0


def upstream(results: Path, settings: dict) -> None:
    """Rules report_tables and report_figures on ``results`` (what the report job reads), timed."""
    from rafi.artefact import jsonable
    from rafi.report import figures, tables
    from rafi.report.inputs import figure_dirs, result_paths

    w0 = time.perf_counter()
    paths = result_paths(results)
    runs, frames = pd.read_csv(paths["runs_csv"]), pd.read_parquet(paths["runs_parquet"])
    doc = json.loads(Path(paths["model"]).read_text(encoding="utf-8"))
    fit = tables.training_fit(doc, runs, frames)
    Path(paths["training_fit"]).parent.mkdir(parents=True, exist_ok=True)
    fit.to_parquet(paths["training_fit"])
    tables.training_rmse(fit).to_csv(paths["training_fit_rmse"], index=False)
    example = tables.fuzzy_example(doc, pd.read_csv(paths["diagnostics"]), runs, frames)
    Path(paths["fuzzy_example"]).write_text(json.dumps(jsonable(example)), encoding="utf-8")
    w1 = time.perf_counter()
    for group, folder in figure_dirs(results).items():
        figures.draw_group(
            paths,
            group,
            folder,
            figure_format=settings["report"]["figure_format"],
            coolant_sensors=settings["report"]["coolant_sensors"],
            gates=settings["qualification"],
        )
    w2 = time.perf_counter()
    print(f"report_tables    {w1 - w0:6.2f} s wall | report_figures (both groups) {w2 - w1:6.2f} s wall")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results_dir", nargs="?", help="results/<machine> directory")
    ap.add_argument(
        "--synthetic",
        action="store_true",
        help="generate a full-size fixture (5 s samples) in a temp dir first",
    )
    ap.add_argument("--format", default="png", choices=["png", "svg"])
    ap.add_argument("--repeat", type=int, default=1)
    a = ap.parse_args(argv)
    cfg = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))
    with tempfile.TemporaryDirectory() as tmp:
        if a.synthetic or not a.results_dir:
            sys.path.insert(0, str(ROOT / "tests" / "data" / "report_fixture"))
            import generate  # noqa: E402

            generate.generate(Path(tmp) / "results", sample_period_s=5.0)
            results = Path(tmp) / "results" / generate.MACHINE
        else:
            results = Path(a.results_dir)
        machine = results.name
        from rafi.settings import machine_settings

        settings = machine_settings(cfg, machine)
        settings["report"]["figure_format"] = a.format
        print(f"results: {results}")
        if a.synthetic or not a.results_dir:
            upstream(results, settings)  # a pipeline's results directory has them already
        c0, w0 = time.process_time(), time.perf_counter()
        from rafi.report import render  # import cost is part of a report job

        imports = (time.perf_counter() - w0, time.process_time() - c0)
        print(f"imports          {imports[0]:6.2f} s wall {imports[1]:6.2f} s cpu")
        for i in range(a.repeat):
            t = render.generate(results, Path(tmp) / "out", machine=machine, settings=settings, config=cfg)
            print(
                f"run {i + 1}: context {t['context_s']:6.2f} s | html {t['html_s']:5.2f} s | "
                f"pdf {t['pdf_s']:6.2f} s | total {t['total_s']:6.2f} s wall | "
                f"html {t['html_bytes'] / 1e6:.2f} MB, pdf {t['pdf_bytes'] / 1e6:.2f} MB, "
                f"verdict {t['verdict']}"
            )
        cpu = time.process_time() - c0
        wall = time.perf_counter() - w0
        print(
            f"total incl. imports: {wall:.2f} s wall, {cpu:.2f} s cpu "
            f"(target < {TARGET_S:.0f} s) -> {'OK' if wall < TARGET_S else 'SLOW'}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
