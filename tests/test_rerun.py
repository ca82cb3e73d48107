"""Interactive runs and `rafi nightly` share every output (issue 11: the re-run thrash).

`on_bad_input` used to be a param of the clean rule: `snakemake --cores 2` followed by
`rafi nightly` with nothing new re-ran all 35 jobs, and the next `snakemake` re-ran them back.
Here, on a trimmed copy of the shipped data with the real Snakefile:

1. `snakemake --cores 2` builds everything;
2. `rafi nightly` with nothing new runs no job (no output is rewritten);
3. a new log arrives and `rafi nightly` processes it; then `snakemake -n` has nothing to do.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from project_copy import copy_project, copy_settled, run_module

ROOT = Path(__file__).resolve().parents[1]
MACHINE = "tapping-center-a"
KEEP = ("train_03000rpm", "train_09000rpm", "train_15000rpm", "valid_04500rpm", "multi_condition")

pytestmark = pytest.mark.slow


def _outputs(proj: Path) -> dict[str, int]:
    """Every file a job writes, with its mtime (nightly's own lock/state/log files aside)."""
    found = {}
    for folder in ("results", "reports"):
        for path in (proj / folder).rglob("*"):
            rel = str(path.relative_to(proj))
            if (
                path.is_file()
                and "/benchmarks/" not in rel
                and not path.name.startswith((".nightly", "nightly"))
            ):
                found[rel] = path.stat().st_mtime_ns
    return found


#: What `snakemake --report` must show (workflow/report/*.rst): file of each report() output.
REPORTED = (
    f"reports/{MACHINE}/qualification.html",
    f"reports/{MACHINE}/qualification.pdf",
    f"results/{MACHINE}/comparison/summary.csv",
    f"results/{MACHINE}/validation/summary.csv",
    f"results/{MACHINE}/registry/decision.json",
    f"results/{MACHINE}/audit.csv",
    "reports/index.html",
)


def _check_snakemake_report(proj: Path) -> None:
    """`snakemake --report` of a finished run lists the qualification reports and the key
    tables with their captions, and changes no output (issue 15)."""
    before = _outputs(proj)
    done = run_module(proj, "snakemake", "--report", "report.html")
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    assert "ERROR" not in done.stderr, done.stderr[-3000:]  # docutils errors in a caption
    html = (proj / "report.html").read_text(encoding="utf-8")
    missing = [f for f in REPORTED if f'"{f}": {{"name"' not in html]
    assert not missing, f"not in the report's results: {missing}"
    assert f"Registry decision of machine <strong>{MACHINE}</strong>" in html
    assert _outputs(proj) == before


@pytest.fixture
def project(tmp_path: Path) -> Path:
    proj = copy_project(tmp_path / "proj")
    (proj / "raw" / MACHINE).mkdir(parents=True)
    for stem in KEEP:
        copy_settled(ROOT / "raw" / MACHINE / f"{stem}.csv", proj / "raw" / MACHINE / f"{stem}.csv")
    return proj


def test_snakemake_then_nightly_then_snakemake_rerun_nothing(project: Path):
    first = run_module(project, "snakemake", "--cores", "2")
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr[-3000:]
    built = _outputs(project)
    assert f"reports/{MACHINE}/qualification.html" in built
    _check_snakemake_report(project)

    night = run_module(project, "rafi.cli", "nightly", "--directory", str(project), "--cores", "2")
    assert night.returncode in (0, 4), night.stdout[-3000:] + night.stderr[-3000:]
    assert _outputs(project) == built, "rafi nightly with nothing new rewrote outputs"

    again = run_module(project, "snakemake", "--cores", "2", "-n")
    assert again.returncode == 0, again.stderr[-3000:]
    assert "Nothing to be done" in again.stdout + again.stderr, again.stdout[-3000:]

    # the other way round: a night processes a new log, then an interactive run has nothing to do
    copy_settled(
        ROOT / "raw" / MACHINE / "valid_13500rpm.csv", project / "raw" / MACHINE / "valid_13500rpm.csv"
    )
    night = run_module(project, "rafi.cli", "nightly", "--directory", str(project), "--cores", "2")
    assert night.returncode in (0, 4), night.stdout[-3000:] + night.stderr[-3000:]
    assert f"results/{MACHINE}/clean/valid_13500rpm.parquet" in _outputs(project)
    after_night = run_module(project, "snakemake", "--cores", "2", "-n")
    assert after_night.returncode == 0, after_night.stderr[-3000:]
    assert "Nothing to be done" in after_night.stdout + after_night.stderr, after_night.stdout[-3000:]
