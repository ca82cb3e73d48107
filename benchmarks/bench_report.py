"""Time the qualification report for one machine's results directory (target < 15 s).

    python benchmarks/bench_report.py results/tapping-center-a      # real pipeline output
    python benchmarks/bench_report.py --synthetic                    # full-size synthetic (5 s grid)

Prints wall and CPU seconds per stage (context incl. figures, HTML, PDF) and sizes.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
TARGET_S = 15.0


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
        settings = dict(cfg["defaults"])
        settings.update((cfg.get("machines") or {}).get(machine) or {})
        c0, w0 = time.process_time(), time.perf_counter()
        from rafi.report.build.build import build as report  # import cost is part of a report job

        imports = (time.perf_counter() - w0, time.process_time() - c0)
        print(f"results: {results}")
        print(f"imports          {imports[0]:6.2f} s wall {imports[1]:6.2f} s cpu")
        for i in range(a.repeat):
            t = report.generate(
                results,
                Path(tmp) / "out",
                machine=machine,
                settings=settings,
                config=cfg,
                figure_format=a.format,
            )
            print(
                f"run {i + 1}: context+figures {t['context_s']:6.2f} s | html {t['html_s']:5.2f} s | "
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
