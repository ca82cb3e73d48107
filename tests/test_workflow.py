"""End to end: the Snakemake pipeline on a trimmed copy of the shipped data.

Copies Snakefile, workflow/ and config.yaml into a temporary directory with a subset
of raw/tapping-center-a (three training speeds, one single-speed validation run, the
multi-condition log), runs `snakemake --cores 2 tables` there and checks:

* every table of docs/design.md exists with its columns;
* a second dry run has nothing to do;
* changing rank.threshold re-runs rank and its downstream (fit, validate) only;
* the raw files are byte-for-byte unchanged.

The report rule is not part of this test (target `tables`): it has its own tests.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import pandas as pd
import pytest
import yaml
from project_copy import run_snakemake

from rafi.settings import deep_merge, machine_settings

ROOT = Path(__file__).resolve().parents[1]
MACHINE = "tapping-center-a"
#: The shipped logs (override with RAFI_E2E_RAW=<folder> to try other data).
RAW = Path(os.environ.get("RAFI_E2E_RAW", ROOT / "raw" / MACHINE))

pytestmark = pytest.mark.slow

#: design.md: file under results/<machine>/ -> required columns (None: not a flat table).
TABLES = {
    "audit.csv": [
        "file",
        "sha256",
        "rows_in",
        "rows_out",
        "duplicates_dropped",
        "reordered",
        "spikes_replaced",
        "values_interpolated",
        "gaps_interpolated",
        "segments",
        "status",
        "reason",
        "open_circuit_removed",
        "values_left_missing",
        "missing_spans",
    ],
    "runs.csv": [
        "run_id",
        "file",
        "segment",
        "start_s",
        "end_s",
        "duration_s",
        "speed_rpm",
        "speed_min_rpm",
        "speed_max_rpm",
        "kind",
        "role",
        "role_source",
        "reference",
        "sha256",
    ],
    "runs.parquet": [
        "run_id",
        "t_s",
        "time",
        "speed_rpm",
        *[f"T{i}" for i in range(1, 17)],
        "disp_um",
        *[f"dT{i}" for i in range(1, 17)],
        "dz_um",
    ],
    "equilibrium.csv": [
        "run_id",
        "speed_rpm",
        "t_eq_s",
        "t_eq_low_s",
        "t_eq_high_s",
        "tau_s",
        "t_eq_tau_s",
        "plateau_um",
        "paper_t_eq_s",
        "method",
    ],
    "rank/correlation.csv": ["scope", "sensor", "r", "abs_r", "rank"],
    "rank/key_sensors.csv": ["sensor", "score_abs_r", "selected_by"],
    "rank/collinearity.csv": None,
    "fit/coefficients.csv": ["speed_rpm", "term", "coef", "se", "se_hac", "t", "p", "p_hac"],
    "fit/diagnostics.csv": [
        "speed_rpm",
        "n",
        "r2",
        "r2_adj",
        "rmse_um",
        "paper_rmse_um",
        "aic",
        "bic",
        "condition_number",
        "durbin_watson",
        "bp_stat",
        "bp_p",
        "jb_stat",
        "jb_p",
        "max_vif",
    ],
    "fit/vif.csv": ["speed_rpm", "term", "vif"],
    "validation/summary.csv": [
        "run_id",
        "role",
        "speed_rpm",
        "duration_s",
        "max_abs_before_um",
        "max_abs_after_um",
        "improvement_pct",
        "rmse_before_um",
        "rmse_after_um",
        "n_samples",
        "n_outside_temp_range",
        "n_outside_speed_range",
        "worse_than_uncompensated",
        "paper_residual_um",
    ],
    "validation/residuals.parquet": [
        "run_id",
        "t_s",
        "speed_rpm",
        "measured_um",
        "predicted_um",
        "residual_um",
        "outside_temp_range",
        "outside_speed_range",
    ],
}
CLEAN_COLUMNS = ["time", "t_s", "speed_rpm", *[f"T{i}" for i in range(1, 17)], "disp_um", "segment"]
AUDIT_ACTION_COLUMNS = ["file", "action", "column", "first_line", "last_line", "n_rows", "detail"]


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def pick_files(config: dict) -> list[Path]:
    """Three training speeds, one single-speed validation log and the multi-condition log."""
    from rafi.readers.native import read_raw_log

    settings = machine_settings(config, MACHINE)
    training = settings["training_speeds_rpm"]
    tol = settings["speed_tolerance_rpm"]
    by_training: dict[float, Path] = {}
    validation: list[tuple[float, Path]] = []
    multi: list[tuple[float, Path]] = []
    for path in sorted(RAW.glob("*.csv")):
        try:
            frame = read_raw_log(path)
        except ValueError:  # a deliberately broken demo file: not for this test
            continue
        speed = frame["speed_rpm"].dropna()
        moving = speed[speed > 100]
        if moving.empty:
            continue
        hours = (frame["time"].iloc[-1] - frame["time"].iloc[0]).total_seconds() / 3600
        if moving.max() - moving.min() > 2 * tol:
            multi.append((-hours, path))
            continue
        rpm = float(moving.median())
        near = [s for s in training if abs(s - rpm) <= tol]
        if near:
            by_training.setdefault(near[0], path)
        elif hours >= 1:
            validation.append((hours, path))
    speeds = sorted(by_training)
    chosen = [by_training[s] for s in (speeds[::2] if len(speeds) >= 5 else speeds)[:3]]
    if len(chosen) < 3 or not validation or not multi:
        pytest.skip(
            f"shipped data in {RAW} lacks 3 training speeds, a validation run or a multi-condition log"
        )
    return chosen + [min(validation)[1], min(multi)[1]]


def snakemake(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    """Run Snakemake in ``cwd`` with the frozen copy of the rafi package found first."""
    return run_snakemake(cwd, *args, cores=2)


def job_counts(output: str) -> dict[str, int]:
    """Rule -> job count from the 'Job stats' table of a (dry) run."""
    counts: dict[str, int] = {}
    if "Job stats:" not in output:
        return counts
    for line in output.split("Job stats:", 1)[1].splitlines()[3:]:
        m = re.match(r"^(\w+)\s+(\d+)\s*$", line)
        if not m:
            break
        if m.group(1) != "total":
            counts[m.group(1)] = int(m.group(2))
    return counts


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    if not RAW.is_dir() or not any(RAW.glob("*.csv")):
        pytest.skip(f"shipped data not present yet ({RAW}): generate it with `rafi simulate`")
    tmp = tmp_path_factory.mktemp("pipeline")
    shutil.copy2(ROOT / "Snakefile", tmp / "Snakefile")
    shutil.copytree(ROOT / "workflow", tmp / "workflow", ignore=shutil.ignore_patterns("__pycache__"))
    # A frozen copy of the package: rafi/*.py are inputs of the rules (rafi_code), so an
    # edit in the working tree during the test must not change what the test measures.
    shutil.copytree(ROOT / "rafi", tmp / "rafi", ignore=shutil.ignore_patterns("__pycache__"))
    config = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))
    files = pick_files(config)
    (tmp / "raw" / MACHINE).mkdir(parents=True)
    for path in files:
        shutil.copy2(path, tmp / "raw" / MACHINE / path.name)
    machine_cfg = (config.get("machines") or {}).get(MACHINE) or {}
    overrides = machine_cfg.get("runs", {}).get("overrides", {})
    kept = {Path(f).stem for f in files}
    if overrides:  # keep only the overrides of the files we copied
        machine_cfg.setdefault("runs", {})["overrides"] = {k: v for k, v in overrides.items() if k in kept}
    config["machines"] = {MACHINE: machine_cfg} if machine_cfg else {}
    (tmp / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")
    return tmp


def test_pipeline_end_to_end(workdir: Path):
    raw_before = {p.name: sha256(p) for p in (workdir / "raw" / MACHINE).iterdir()}

    proc = snakemake(workdir, "tables")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-5000:]

    results = workdir / "results" / MACHINE
    for name, columns in TABLES.items():
        path = results / name
        assert path.is_file(), f"missing {name}"
        frame = pd.read_parquet(path) if name.endswith(".parquet") else pd.read_csv(path)
        assert len(frame) > 0, f"{name} is empty"
        if columns is not None:
            missing = [c for c in columns if c not in frame.columns]
            assert not missing, f"{name} lacks columns {missing}"
    for stem in (p.stem for p in (workdir / "raw" / MACHINE).iterdir()):
        clean = pd.read_parquet(results / "clean" / f"{stem}.parquet")
        assert [c for c in CLEAN_COLUMNS if c not in clean.columns] == []
        actions = pd.read_csv(results / "clean" / f"{stem}.audit.csv")
        assert list(actions.columns) == AUDIT_ACTION_COLUMNS
    assert (results / "rank" / "key_sensors.json").is_file()
    assert (results / "model.json").is_file()
    runs = pd.read_csv(results / "runs.csv")
    assert {"training", "validation_single", "validation_multi"} <= set(runs["role"])
    for rule in ("runs", "rank", "fit", "validate"):
        assert (workdir / "logs" / MACHINE / f"{rule}.log").stat().st_size > 0
    model = json.loads((results / "model.json").read_text(encoding="utf-8"))
    assert model["machine"] == MACHINE and model["speeds"]

    proc = snakemake(workdir, "tables", "-n")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Nothing to be done" in proc.stdout + proc.stderr, proc.stdout[-3000:]

    config_path = workdir / "config.yaml"
    config = yaml.safe_load(config_path.read_text(encoding="utf-8"))
    config["defaults"] = deep_merge(config.get("defaults") or {}, {"rank": {"threshold": 0.5}})
    config_path.write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")
    proc = snakemake(workdir, "tables", "-n")
    assert proc.returncode == 0, proc.stderr[-3000:]
    counts = job_counts(proc.stdout + proc.stderr)
    # runs ... validate are one job per machine (rule method): a rank setting re-runs it, and no
    # clean or input_status job
    assert set(counts) == {"method", "tables"}, counts

    raw_after = {p.name: sha256(p) for p in (workdir / "raw" / MACHINE).iterdir()}
    assert raw_after == raw_before


def test_bad_file_fails_fast_interactively_and_is_quarantined_at_night(workdir: Path, tmp_path: Path):
    """Issue 6: one broken log among good ones. Interactive (on_bad_input: fail): the run
    stops with a message naming the file, line and column. Nightly (quarantine): it
    finishes, lists the file as quarantined with the reason; the raw file is untouched."""
    work = tmp_path / "bad"
    work.mkdir()
    for name in ("Snakefile", "config.yaml"):
        shutil.copy2(workdir / name, work / name)
    for name in ("workflow", "rafi", "raw"):
        shutil.copytree(workdir / name, work / name, ignore=shutil.ignore_patterns("__pycache__"))
    broken = work / "raw" / MACHINE / "zz_broken.csv"
    shutil.copy2(ROOT / "tests" / "data" / "bad" / "text_in_numeric.csv", broken)
    before = sha256(broken)

    failed = snakemake(work, "tables")
    assert failed.returncode != 0
    message = failed.stdout + failed.stderr
    assert "zz_broken.csv, line 13, column 'T3'" in message, message[-3000:]
    assert "'ERR' is not a number" in message

    night = snakemake(work, "tables", "--config", "on_bad_input=quarantine")
    assert night.returncode == 0, night.stdout[-3000:] + night.stderr[-3000:]
    audit = pd.read_csv(work / "results" / MACHINE / "audit.csv").set_index("file")
    assert audit.loc["zz_broken.csv", "status"] == "quarantined"
    assert "line 13" in audit.loc["zz_broken.csv", "reason"]
    assert (audit.drop(index="zz_broken.csv")["status"] == "ok").all()
    runs = pd.read_csv(work / "results" / MACHINE / "runs.csv")
    assert "zz_broken" not in set(runs["run_id"])
    assert sha256(broken) == before

    # Interactive again with nothing new: the quarantined file's outputs are up to date, so no
    # job would fail on it; planning stops the run with the reason instead.
    again = snakemake(work, "tables", "-n")
    assert again.returncode != 0
    assert "zz_broken.csv, line 13, column 'T3'" in again.stdout + again.stderr
    assert "on_bad_input=quarantine" in again.stdout + again.stderr
    # ... and once the file is gone the interactive run goes on, re-running what depended on it
    broken.unlink()
    fixed = snakemake(work, "tables", "-n")
    assert fixed.returncode == 0, fixed.stdout[-3000:] + fixed.stderr[-3000:]


def _project(workdir: Path, dest: Path, files: dict[str, Path]) -> Path:
    """A project in ``dest`` with the workflow of ``workdir`` and ``files`` (name -> source)."""
    dest.mkdir()
    for name in ("Snakefile", "config.yaml"):
        shutil.copy2(workdir / name, dest / name)
    for name in ("workflow", "rafi"):
        shutil.copytree(workdir / name, dest / name, ignore=shutil.ignore_patterns("__pycache__"))
    (dest / "raw" / MACHINE).mkdir(parents=True)
    for name, source in files.items():
        shutil.copy2(source, dest / "raw" / MACHINE / name)
    return dest


def test_any_legal_file_name_works_and_switching_on_bad_input_reruns_nothing(workdir: Path, tmp_path: Path):
    """Braces (Snakemake's wildcard syntax), spaces and unicode in raw file names; then the
    interactive and the nightly mode share every output: switching re-runs no job."""
    shipped = sorted((workdir / "raw" / MACHINE).glob("*.csv"))
    names = ["log_{date}.csv", "with space é.csv", "v}{x.csv", "ünïcode_日本.csv", "100%.csv"]
    work = _project(workdir, tmp_path / "odd", dict(zip(names, shipped)))

    first = snakemake(work, "tables")
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr[-3000:]
    runs = pd.read_csv(work / "results" / MACHINE / "runs.csv")
    assert set(runs["file"]) == set(names)
    assert (work / "results" / MACHINE / "clean" / "log_%7Bdate%7D.parquet").is_file()
    assert (work / "results" / MACHINE / "clean" / "100%25.parquet").is_file()

    for mode in ("quarantine", "fail", "quarantine"):
        dry = snakemake(work, "tables", "-n", "--config", f"on_bad_input={mode}")
        assert dry.returncode == 0, dry.stderr[-3000:]
        assert "Nothing to be done" in dry.stdout + dry.stderr, (mode, job_counts(dry.stdout + dry.stderr))

    # a raw file Snakemake cannot name as an input is followed by its content hash: an edit
    # re-runs its clean job (and what depends on it), not the others
    with open(work / "raw" / MACHINE / "log_{date}.csv", "a", encoding="utf-8") as fh:
        fh.write("\n")
    edited = snakemake(work, "tables", "-n")
    counts = job_counts(edited.stdout + edited.stderr)
    assert counts.get("clean") == 1, counts


def test_a_machine_section_at_the_top_level_stops_planning_with_where_it_belongs(
    workdir: Path, tmp_path: Path
):
    """The first settings bug: `qualification:` at the top level was valid, read by the decide
    job and ignored by the compare job. Now the run does not start, and says why."""
    work = _project(workdir, tmp_path / "top", {})
    config = yaml.safe_load((work / "config.yaml").read_text(encoding="utf-8"))
    config["qualification"] = {"max_residual_um": 5.0}
    (work / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False), encoding="utf-8")
    proc = snakemake(work, "-n")
    assert proc.returncode != 0
    assert "'qualification' is a per-machine setting: put it under 'defaults:'" in proc.stdout + proc.stderr
