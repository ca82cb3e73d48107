"""The report's test fixture and what the upstream rules write before the report.

``tests/data/report_fixture/tapping-center-a`` is a results folder of the pipeline (written
before intervals existed). :func:`copy_fixture` copies it; :func:`write_upstream_tables` writes
what rule ``report_tables`` writes; :func:`empty_figure_dirs` gives every figure group an empty
folder (rule ``report_figures`` drew nothing), for tests that read the text and tables only.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from rafi.report import tables
from rafi.report.inputs import FIGURE_DIRS, figure_dirs, result_paths

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "tests" / "data" / "report_fixture" / "tapping-center-a"


def copy_fixture(tmp: Path, machine: str = "tapping-center-a") -> Path:
    """A copy of the fixture as ``tmp/results/<machine>``."""
    results = Path(tmp) / "results" / machine
    shutil.copytree(FIXTURE, results)
    return results


def write_upstream_tables(results: Path) -> dict:
    """Rule report_tables' tables of a results folder; returns its :func:`result_paths`."""
    paths = result_paths(results)
    tables.write_report_tables(
        paths["model"],
        paths["runs_csv"],
        paths["runs_parquet"],
        paths["diagnostics"],
        fit_path=paths["training_fit"],
        rmse_path=paths["training_fit_rmse"],
        example_path=paths["fuzzy_example"],
    )
    return paths


def empty_figure_dirs(results: Path) -> dict:
    """Every figure group's folder with an empty index; returns ``{group: folder}``."""
    for rel in FIGURE_DIRS.values():
        (results / rel).mkdir(parents=True, exist_ok=True)
        (results / rel / "index.csv").write_text("key,file\n", encoding="utf-8")
    return figure_dirs(results)
