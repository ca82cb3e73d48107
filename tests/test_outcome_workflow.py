"""Issue 45, loud outcomes, with the real Snakefile on a trimmed copy of the shipped data.

* A full run ends with one line per machine: PASS (the model offered and the report's path) for
  the shipped machine, FAIL with the failed gate for a copy held to a gate no model can pass, and
  skipped for a folder of workbooks with no configuration (what it holds, the docs section).
* A ``runs.windows`` entry whose ``log`` glob matches no log stops the machine with one line
  naming the key, the glob and the machine's logs, repeated as the last line of the run.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import yaml
from project_copy import copy_project, run_snakemake

ROOT = Path(__file__).resolve().parents[1]
MACHINE = "tapping-center-a"
STRICT = "tapping-center-strict"
KEEP = ("train_03000rpm", "train_09000rpm", "train_15000rpm", "valid_04500rpm", "multi_condition")
#: A residual limit no model reaches on the twin's logs (their noise floor is about 0.6 um).
STRICT_LIMIT_UM = 0.01

pytestmark = pytest.mark.slow


def _project(tmp_path: Path, machines: dict[str, dict], stems=KEEP) -> Path:
    """A project copy with ``stems`` of the shipped machine under each of ``machines`` (name ->
    its ``machines:`` entry), the shipped machine's settings merged in."""
    proj = copy_project(tmp_path / "proj")
    config = yaml.safe_load((proj / "config.yaml").read_text(encoding="utf-8"))
    shipped = (config.get("machines") or {}).get(MACHINE) or {}
    config["machines"] = {name: {**shipped, **extra} for name, extra in machines.items()}
    (proj / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")
    for name in machines:
        raw = proj / "raw" / name
        raw.mkdir(parents=True)
        for stem in stems:
            shutil.copy2(ROOT / "raw" / MACHINE / f"{stem}.csv", raw / f"{stem}.csv")
    return proj


def _end_lines(stderr: str) -> list[str]:
    """The end-of-run lines: from their heading to the next blank line."""
    lines = stderr.splitlines()
    start = max(i for i, line in enumerate(lines) if line.startswith("RAFI: outcome of this run"))
    block = []
    for line in lines[start + 1 :]:
        if not line.startswith("  "):
            break
        block.append(line)
    return block


def test_a_run_ends_with_pass_fail_and_skipped_per_machine(tmp_path: Path):
    proj = _project(tmp_path, {MACHINE: {}, STRICT: {"qualification": {"max_residual_um": STRICT_LIMIT_UM}}})
    foreign = proj / "raw" / "fl-thermal"
    foreign.mkdir()
    for name in ("probe_1.xlsx", "probe_2.xlsx", "notes.txt"):
        (foreign / name).write_bytes(b"not read")

    done = run_snakemake(proj, cores=2, timeout=1200)
    assert done.returncode == 0, done.stderr[-3000:]
    lines = _end_lines(done.stderr)
    by_machine = {
        line.strip().split(":", 1)[0]: line.strip() for line in lines if not line.startswith("    ")
    }
    assert list(by_machine) == [STRICT, "fl-thermal", MACHINE]  # FAIL, skipped, PASS

    for name, status in ((MACHINE, "PASS"), (STRICT, "FAIL")):
        decision = json.loads((proj / "results" / name / "registry" / "decision.json").read_text())
        model = json.loads(
            (proj / "results" / name / "registry" / "models" / f"{decision['candidate_id']}.json").read_text()
        )
        report = Path("reports") / name / "qualification.html"
        assert (proj / report).is_file()
        line = by_machine[name]
        assert line.startswith(
            f"{name}: {status} - model offered: {model['kind']} {decision['candidate_id'][:12]}"
        )
        assert line.endswith(f"; report {report}")
        assert decision["gates_passed"] is (status == "PASS")
    assert ", promoted; report" in by_machine[MACHINE]

    decision = json.loads((proj / "results" / STRICT / "registry" / "decision.json").read_text())
    n_runs = decision["measured"]["n_validation_runs"]
    worst = decision["measured"]["max_residual_um"]
    assert (
        f"max residual above {STRICT_LIMIT_UM:g} um on {n_runs} of {n_runs} run(s) (worst {worst:.2f} um"
        in (by_machine[STRICT])
    )

    skipped = by_machine["fl-thermal"]
    assert skipped.startswith("fl-thermal: skipped - no file matches input.pattern '*.csv'")
    assert "3 file(s): notes.txt, probe_1.xlsx, probe_2.xlsx (.xlsx 2, .txt 1)" in skipped
    assert skipped.endswith("docs/raw-format.md#bringing-your-own-layout")


def test_a_window_glob_matching_no_log_stops_the_machine_naming_the_key(tmp_path: Path):
    windows = [{"role": "training", "log": "train_*"}, {"role": "validation", "log": "test_*"}]
    stems = ("train_03000rpm", "valid_04500rpm")
    proj = _project(tmp_path, {MACHINE: {"runs": {"windows": windows}}}, stems=stems)

    done = run_snakemake(proj, "tables", cores=2, timeout=900)
    assert done.returncode == 1, done.stderr[-3000:]
    message = (
        f"runs.windows[1].log: 'test_*' matches no log of machine {MACHINE} "
        "(logs: train_03000rpm.csv, valid_04500rpm.csv)"
    )
    last = done.stderr.strip().splitlines()[-1]
    assert last == f"RAFI runs (machine={MACHINE}) failed: {message}"
    assert _end_lines(done.stderr) == [
        f"  {MACHINE}: FAIL - step runs failed (its message is below); no model offered"
    ]
    assert not (proj / "results" / MACHINE / "runs.csv").exists()
