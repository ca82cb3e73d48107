"""Test error of the model family on every real log present: CAIVIAC/FL_THERMAL (one machine per
channel), the turning centre of ``--turning DIR`` and the 78 h spindle of ``--spindle FILE``.

Usage (from the repository root; see benchmarks/README.md)::

    python benchmarks/bench_realdata.py                          # 5 channels x 2 configurations
    python benchmarks/bench_realdata.py --channels ch3 --configs windows
    python benchmarks/bench_realdata.py --data PATH --cores 2 --keep /tmp/rd
    python benchmarks/bench_realdata.py --logs turning-centre --turning DIR --out-dir /tmp/tc
    python benchmarks/bench_realdata.py --logs spindle-78h --spindle FILE --out-dir /tmp/sp

**Every real log present** (``--logs``, default all three): a log whose data is absent is skipped
with a line saying where it was looked for (the data is never shipped; CI needs none); with none
present the bench runs nothing and exits 0. The 78 h spindle (``_realdata_spindle``: one CSV
without a licence, one speed, two chronological splits) runs first, then the turning centre
(``_realdata_turning``: 18 daily tests in two workbooks without a licence, days 1-12 train, 13-18
test); their results go to ``<out-dir>/<out>-spindle-78h`` and ``<out>-turning-centre`` (``.json``
and ``.md``) and ``--out-dir`` must lie outside the repository (refused otherwise: they are derived
from unlicensed rows). FL_THERMAL's go to ``<out-dir>/<out>.json`` and ``.md`` (default
``benchmarks/results/realdata``).

**Per test run** (``_realdata_runs``), for every log: the test MAE and largest error of the
offered model, of every kind of the family, of the family's plain ridge ``temperature_ridge``
(where the machine's models leave it out it is fitted alone in a second project with the same
settings, :func:`add_plain_ridge`, so the offered model stays the one the shipped settings offer)
and of no compensation, and the 90 % interval's coverage and mean width on the test rows.

The data: ``data.xlsx`` of the public repository CAIVIAC/FL_THERMAL (MIT licence), a real 46 h
spindle test, 15 s rows, 16 temperatures ``t1(°C)``..``t16(°C)``, the speed ``spindle(RPM)``,
elapsed seconds ``時間(s)`` and five displacement channels ``ch1(um)``..``ch5(um)``. It is not
shipped with the project: by default it is read from ``../shared/data/fl-thermal/data.xlsx``
beside the project root (``--data``).

**The pipeline, configured, not coded.** For each channel and configuration a temporary project
holds a copy of ``Snakefile``, ``workflow/`` and ``rafi/`` (the code the jobs run), the workbook
under ``raw/fl-thermal-<ch>/`` and a ``config.yaml`` that maps its columns as
``docs/raw-format.md`` tells a user (:func:`machine_config`): the time column in elapsed seconds,
the speed, ``T1``..``T16`` from ``t1``..``t16``, the displacement from the channel, the training
speeds 1250/2500/3750/5000 r/min, and ``reference: log_start`` (a continuous log: every run's
displacement change is taken from the first minute of the log, so the pipeline's prediction is
the displacement from the probe's zero at t = 0, like the published models'). Two configurations:

* ``windows``: roles by time windows, training until the end of the 5000 r/min run
  (``elapsed_s`` 101 265) with the cool-downs (``runs.idle_training: true``), validation after;
* ``automatic``: no windows, ``runs.min_constant_s: 10800`` (the tail's 1-2 h steps form one
  varying run), every other setting at its default.

``snakemake --cores N`` builds the comparison's summary and residuals
(``results/<machine>/comparison/summary.csv`` and ``residuals.parquet``: every model of the
family, one row per validation sample) and nothing else.

**The score** (:func:`score_family`): the test MAE over rows 6751-8891 of the workbook (0-based
data rows, row k at t = 15 k s), i.e. 101 265 s <= t <= 133 365 s: the published chronological
split's test rows after the run it cuts through (the data's README). For every model, mean over
the scored rows of ``|disp - ref - predicted_um|`` where ``disp`` is the workbook's raw value,
``ref`` the median of the channel over the first 60 s of the log (the pipeline's log_start
reference) and ``predicted_um`` the pipeline's prediction of the change from that reference. The
published models predict the raw value (near 0 at t = 0); the two differ by the constant ``ref``
(0.1-0.5 um), the probe's zero. Rows no validation run of the pipeline covers (an excluded
short run) are not scored; the table says how many were.

**The plain ridge reference** (:func:`plain_ridge`), independent of the pipeline: features are the
16 temperature rises (``T - mean of T over the first 300 s``, the machine at rest before the
first run at 465 s) and two first-order low-pass filters of each rise (time constants 900 s and
3600 s, run causally over the whole log from the first row, state starting at the first rise),
48 columns, standardised on the fitting rows; target the raw displacement, with an unpenalised
intercept. The penalty is chosen from :data:`RIDGE_ALPHAS` by blocked CV on the training rows only
(t < 101 265 s): :data:`RIDGE_BLOCKS` contiguous blocks of equal row count, each held out in turn;
the rows within :data:`RIDGE_GAP_S` (3 x the slow time constant) before and after a held-out
block are left out of its fit, so neither the targets' autocorrelation nor the filters' memory
carries the held-out block into the fit. Criterion: the pooled mean squared error over the
held-out blocks. Then a fit on every training row, scored on the test rows by the same MAE.

Published test MAE (seq2seq-v2 with attention, the best of random forest, XGBoost and two
seq2seq models; the repository's ``images/test_ch*``): :data:`PUBLISHED_UM`.

Output: per configuration a table ``channel | published | plain ridge | every model | offered
(kind)``, the automatic/windows ratio of the offered model, per project the runs found and
the input checks' warnings, and per channel and configuration the per-test-run tables; also
``benchmarks/results/realdata.json`` and ``realdata.md`` (``--out-dir``, ``--out``).
Exit status 0; a failed Snakemake run prints its last lines and the next channel runs.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from scipy.signal import lfilter

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / "benchmarks"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from _realdata_runs import per_run, per_run_markdown  # noqa: E402
from _results import OUT_DIR, write_results  # noqa: E402

DATA_REL = Path("shared", "data", "fl-thermal", "data.xlsx")

#: The real logs this bench runs when their data is present.
LOGS = ("fl-thermal", "turning-centre", "spindle-78h")
CHANNELS = ("ch1", "ch2", "ch3", "ch4", "ch5")
CONFIGS = ("windows", "automatic")
#: Published test MAE, um: seq2seq-v2, the best of the repository's four models.
PUBLISHED_UM = {"ch1": 3.561, "ch2": 3.755, "ch3": 3.704, "ch4": 3.461, "ch5": 4.284}

TIME_COL = "時間(s)"
SPEED_COL = "spindle(RPM)"
PERIOD_S = 15.0
TRAINING_SPEEDS_RPM = [1250, 2500, 3750, 5000]
#: End of the 5000 r/min run: training before, validation from here (row 6751).
SPLIT_S = 101_265.0
#: The last test row of the published split (0-based data row; t = 15 s x row).
TEST_LAST_ROW = 8891
#: The pipeline's log_start reference window (reference.window_s).
REFERENCE_WINDOW_S = 60.0
#: The family's plain ridge (temperatures only), scored on every log; where the machine's
#: models leave it out it is fitted alone in a second project (:func:`add_plain_ridge`).
PLAIN_RIDGE = "temperature_ridge"
RIDGE_RESIDUALS = "residuals_temperature_ridge.parquet"

#: The plain ridge: rises from the mean of the first 300 s, filters, penalties, blocked CV.
RIDGE_REST_S = 300.0
RIDGE_TAUS_S = (900.0, 3600.0)
RIDGE_ALPHAS = np.logspace(-4, 5, 46)
RIDGE_BLOCKS = 5
RIDGE_GAP_S = 3 * 3600.0


# ----------------------------------------------------------------------------- the data


def default_data(root: Path = ROOT) -> Path:
    """``../shared/data/fl-thermal/data.xlsx`` beside the project root, else beside the first of
    its parents that has one (a git worktree lies a level deeper); the first candidate if none."""
    candidates = [parent / DATA_REL for parent in root.parents]
    return next((c for c in candidates if c.is_file()), candidates[0])


def read_workbook(path: Path) -> pd.DataFrame:
    """The workbook's one sheet, headers stripped of surrounding spaces (``時間(s) `` has one)."""
    frame = pd.read_excel(path, sheet_name=0)
    return frame.rename(columns=lambda c: str(c).strip())


def test_rows(t_s: np.ndarray) -> np.ndarray:
    """Mask of the test rows: ``SPLIT_S <= t <= 15 s x TEST_LAST_ROW`` (rows 6751-8891)."""
    t_s = np.asarray(t_s, dtype=float)
    return (t_s >= SPLIT_S) & (t_s <= TEST_LAST_ROW * PERIOD_S)


def training_rows(t_s: np.ndarray) -> np.ndarray:
    """Mask of the training rows of the windows protocol: ``t < SPLIT_S`` (rows 0-6750)."""
    return np.asarray(t_s, dtype=float) < SPLIT_S


# ----------------------------------------------------------------------------- the plain ridge


def lowpass(x: np.ndarray, t_s: np.ndarray, tau_s: float) -> np.ndarray:
    """First-order low-pass of every column of ``x`` (rows at a constant step of ``t_s``), causal,
    state starting at the first row: ``y[k] = y[k-1] + a (x[k] - y[k-1])``, ``a = 1 - exp(-dt/tau)``."""
    x = np.asarray(x, dtype=float)
    step = float(np.median(np.diff(t_s)))
    a = 1.0 - np.exp(-step / tau_s)
    zi = (1.0 - a) * x[:1]
    y, _ = lfilter([a], [1.0, a - 1.0], x, axis=0, zi=zi)
    return y


def ridge_features(temps: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """The 48 features: the rises from the mean over the first ``RIDGE_REST_S`` and their
    low-pass filters with the time constants ``RIDGE_TAUS_S`` (rises first, then per filter)."""
    temps = np.asarray(temps, dtype=float)
    rest = np.asarray(t_s) < RIDGE_REST_S
    rises = temps - temps[rest].mean(axis=0)
    return np.hstack([rises, *(lowpass(rises, t_s, tau) for tau in RIDGE_TAUS_S)])


def ridge_fit(x: np.ndarray, y: np.ndarray, alphas: np.ndarray) -> tuple:
    """Ridge on standardised ``x`` with an unpenalised intercept for every penalty in ``alphas``.

    Returns ``(mean, scale, intercept, coefs)``; ``coefs`` has one column per penalty, in the
    standardised units (predict with :func:`ridge_predict`)."""
    mean, scale = x.mean(axis=0), x.std(axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    xs = (x - mean) / scale
    intercept = float(y.mean())
    u, s, vt = np.linalg.svd(xs, full_matrices=False)
    uty = u.T @ (y - intercept)
    shrink = s[:, None] / (s[:, None] ** 2 + np.asarray(alphas)[None, :])
    return mean, scale, intercept, vt.T @ (shrink * uty[:, None])


def ridge_predict(fit: tuple, x: np.ndarray) -> np.ndarray:
    """Predictions of :func:`ridge_fit`'s model, one column per penalty."""
    mean, scale, intercept, coefs = fit
    return intercept + ((x - mean) / scale) @ coefs


def blocked_folds(t_s: np.ndarray, n_blocks: int, gap_s: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(fit rows, held-out rows)`` index pairs: ``n_blocks`` contiguous blocks of equal row
    count, the rows within ``gap_s`` of a held-out block left out of its fit."""
    t_s = np.asarray(t_s, dtype=float)
    folds = []
    for block in np.array_split(np.arange(len(t_s)), n_blocks):
        lo, hi = t_s[block[0]] - gap_s, t_s[block[-1]] + gap_s
        fit = np.flatnonzero((t_s < lo) | (t_s > hi))
        folds.append((fit, block))
    return folds


def choose_alpha(x: np.ndarray, y: np.ndarray, t_s: np.ndarray, alphas: np.ndarray = RIDGE_ALPHAS) -> dict:
    """The penalty with the lowest pooled held-out mean squared error over :func:`blocked_folds`
    (``RIDGE_BLOCKS``, ``RIDGE_GAP_S``) of the rows given (the training rows only)."""
    sq = np.zeros(len(alphas))
    n = 0
    for fit_rows, held in blocked_folds(t_s, RIDGE_BLOCKS, RIDGE_GAP_S):
        model = ridge_fit(x[fit_rows], y[fit_rows], alphas)
        sq += np.sum((ridge_predict(model, x[held]) - y[held, None]) ** 2, axis=0)
        n += len(held)
    best = int(np.argmin(sq))
    return {
        "alpha": float(alphas[best]),
        "cv_rmse_um": float(np.sqrt(sq[best] / n)),
        "at_grid_edge": best in (0, len(alphas) - 1),
    }


def plain_ridge(
    temps: np.ndarray,
    disp: np.ndarray,
    t_s: np.ndarray,
    train: np.ndarray | None = None,
    test: np.ndarray | None = None,
) -> dict:
    """The plain ridge reference (module docstring): penalty by blocked CV on the training rows,
    fitted on all of them, scored on the test rows (``train`` / ``test``: boolean masks of the
    rows; default FL_THERMAL's published split). Returns ``test_mae_um``, ``test_max_um``,
    ``alpha``, ``cv_rmse_um``, ``at_grid_edge``, ``train_mae_um``."""
    t_s = np.asarray(t_s, dtype=float)
    disp = np.asarray(disp, dtype=float)
    x = ridge_features(temps, t_s)
    train = training_rows(t_s) if train is None else np.asarray(train, dtype=bool)
    test = test_rows(t_s) if test is None else np.asarray(test, dtype=bool)
    chosen = choose_alpha(x[train], disp[train], t_s[train])
    model = ridge_fit(x[train], disp[train], np.array([chosen["alpha"]]))
    pred = ridge_predict(model, x)[:, 0]
    return {
        **chosen,
        "test_mae_um": float(np.mean(np.abs(disp[test] - pred[test]))),
        "test_max_um": float(np.max(np.abs(disp[test] - pred[test]))),
        "train_mae_um": float(np.mean(np.abs(disp[train] - pred[train]))),
    }


# ----------------------------------------------------------------------------- the projects


def machine_name(channel: str) -> str:
    """The machine (raw folder) of one channel."""
    return f"fl-thermal-{channel}"


def machine_config(channel: str, config: str) -> dict:
    """A machine's ``config.yaml`` entry: the column mapping (docs/raw-format.md) plus the roles
    of ``config`` (``windows`` or ``automatic``)."""
    columns = {"time": TIME_COL, "speed_rpm": SPEED_COL, "disp_um": f"{channel}(um)"}
    columns.update({f"T{i}": f"t{i}(°C)" for i in range(1, 17)})
    entry = {
        "sample_period_s": int(PERIOD_S),
        "training_speeds_rpm": list(TRAINING_SPEEDS_RPM),
        "reference": {"rule": "log_start", "window_s": int(REFERENCE_WINDOW_S)},
        "input": {
            "format": "xlsx",
            "pattern": "*.xlsx",
            "sheet": 0,
            "header_row": 1,
            "columns": columns,
            "time": {"kind": "elapsed_s", "start": "2024-01-01T00:00:00"},
            "sample_period_s": int(PERIOD_S),
            "temperature_unit": "C",
        },
    }
    if config == "windows":
        entry["runs"] = {
            "idle_training": True,
            "windows": [
                {"role": "training", "end": int(SPLIT_S), "unit": "elapsed_s"},
                {"role": "validation", "start": int(SPLIT_S), "unit": "elapsed_s"},
            ],
        }
    elif config == "automatic":
        entry["runs"] = {"min_constant_s": 10800}
    else:
        raise ValueError(f"unknown configuration {config!r}; expected one of {CONFIGS}")
    return entry


def write_project(proj: Path, data: Path, channel: str, config: str, entry: dict | None = None) -> str:
    """A runnable project in ``proj`` for one channel and configuration; returns the machine.
    ``entry``: the machine's settings instead of :func:`machine_config` (``config`` then only
    labels the project)."""
    machine = machine_name(channel)
    write_project_files(
        proj,
        machine,
        {"data.xlsx": data},
        machine_config(channel, config) if entry is None else entry,
        f"FL_THERMAL {channel}, roles '{config}'",
    )
    return machine


def write_project_files(proj: Path, machine: str, files: dict, entry: dict, title: str) -> None:
    """A runnable project in ``proj``: the code the jobs run (``Snakefile``, ``workflow/``,
    ``rafi/``), ``files`` (name -> source) copied into ``raw/<machine>/`` and a ``config.yaml``
    with ``entry`` as the machine's settings."""
    proj.mkdir(parents=True, exist_ok=True)
    shutil.copy2(ROOT / "Snakefile", proj / "Snakefile")
    for name in ("workflow", "rafi"):
        shutil.copytree(ROOT / name, proj / name, ignore=shutil.ignore_patterns("__pycache__"))
    raw = proj / "raw" / machine
    raw.mkdir(parents=True)
    for name, src in files.items():
        shutil.copy2(src, raw / name)
    settings = {
        "raw_dir": "raw",
        "results_dir": "results",
        "reports_dir": "reports",
        "on_bad_input": "fail",
        "defaults": {},
        "machines": {machine: entry},
    }
    text = f"# bench_realdata.py: {title}\n"
    text += yaml.safe_dump(settings, allow_unicode=True, sort_keys=False)
    (proj / "config.yaml").write_text(text, encoding="utf-8")


def enabled_kinds(entry: dict) -> list[str]:
    """The kinds a machine's settings fit (``models.enabled``, else the default)."""
    from rafi.settings import MACHINE_DEFAULTS

    return list((entry.get("models") or {}).get("enabled") or MACHINE_DEFAULTS["models"]["enabled"])


def ridge_entry(entry: dict) -> dict:
    """``entry`` fitting the plain ridge ``temperature_ridge`` alone (its other settings kept)."""
    return {**entry, "models": {**(entry.get("models") or {}), "enabled": [PLAIN_RIDGE]}}


def add_plain_ridge(proj: Path, machine: str, files: dict, entry: dict, cores: int, title: str) -> str:
    """When ``entry`` does not fit ``temperature_ridge``: a second project (``proj`` + ``-ridge``)
    fitting it alone, its validation residuals copied beside the first project's as
    ``comparison/`` :data:`RIDGE_RESIDUALS` (read by :func:`read_residuals`). Returns what
    happened, one line."""
    if PLAIN_RIDGE in enabled_kinds(entry):
        return f"{PLAIN_RIDGE} fitted with the family"
    other = proj.with_name(proj.name + "-ridge")
    shutil.rmtree(other, ignore_errors=True)
    try:
        write_project_files(other, machine, files, ridge_entry(entry), f"{title}, {PLAIN_RIDGE} alone")
        ok, wall, output = run_snakemake(other, machine, cores)
        if not ok:
            return f"{PLAIN_RIDGE} alone FAILED: " + " / ".join(output.splitlines()[-5:])
        shutil.copy2(
            other / "results" / machine / "comparison" / "residuals.parquet",
            proj / "results" / machine / "comparison" / RIDGE_RESIDUALS,
        )
        return f"{PLAIN_RIDGE} alone in a second project, {wall:.0f} s"
    finally:
        shutil.rmtree(other, ignore_errors=True)


def read_residuals(proj: Path, machine: str) -> pd.DataFrame:
    """The project's validation residuals, with :func:`add_plain_ridge`'s rows if any."""
    folder = proj / "results" / machine / "comparison"
    residuals = pd.read_parquet(folder / "residuals.parquet")
    extra = folder / RIDGE_RESIDUALS
    if extra.is_file() and PLAIN_RIDGE not in set(residuals["model"].astype(str)):
        more = pd.read_parquet(extra)
        residuals = pd.concat([residuals, more[more["model"].astype(str) == PLAIN_RIDGE]], ignore_index=True)
    return residuals


def targets(machine: str) -> list[str]:
    """The smallest target set with every model's validation residuals and the champion."""
    return [f"results/{machine}/comparison/summary.csv", f"results/{machine}/comparison/residuals.parquet"]


def run_snakemake(proj: Path, machine: str, cores: int) -> tuple[bool, float, str]:
    """``snakemake --cores N <targets>`` in ``proj`` (its own ``rafi/`` first on the path);
    returns ``(ok, wall seconds, output)``."""
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join(filter(None, [str(proj), os.environ.get("PYTHONPATH")])),
    }
    cmd = [sys.executable, "-m", "snakemake", "--cores", str(cores), *targets(machine)]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, cwd=proj, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    (proj / "bench-snakemake.log").write_text(done.stdout + done.stderr, encoding="utf-8")
    return done.returncode == 0, wall, done.stdout + done.stderr


def scored_project(
    keep: Path | None, name: str, machine: str, files: dict, entry: dict, cores: int, title: str, score
) -> tuple[dict, pd.DataFrame | None]:
    """Build and run one real log's project, fit the plain ridge beside it (:func:`add_plain_ridge`)
    and score its validation residuals: ``(record, residuals)``. The project is ``keep/name``
    (kept) or a temporary folder (removed). ``score(residuals, runs) -> (scored rows, largest
    change cleaning made)`` maps the residuals onto the raw log (``_realdata_runs.SCORED``). The
    record: ``ok``, ``wall_s``, on failure ``tail`` (and no residuals), else
    :func:`project_facts`, ``plain_ridge_run``, ``per_run``, ``test_runs``, ``max_clean_diff_um``.
    """
    if keep is not None:
        proj = keep / name
        shutil.rmtree(proj, ignore_errors=True)
    else:
        proj = Path(tempfile.mkdtemp(prefix=f"rafi-realdata-{name}-"))
    try:
        write_project_files(proj, machine, files, entry, title)
        ok, wall, output = run_snakemake(proj, machine, cores)
        out = {"ok": ok, "wall_s": round(wall, 1)}
        if not ok:
            out["tail"] = "\n".join(output.splitlines()[-25:])
            return out, None
        out["plain_ridge_run"] = add_plain_ridge(proj, machine, files, entry, cores, title)
        residuals = read_residuals(proj, machine)
        scored, worst = score(residuals, pd.read_csv(proj / "results" / machine / "runs.csv"))
        out.update(project_facts(proj, machine))
        out["per_run"] = per_run(scored).to_dict("records")
        out["test_runs"] = list(dict.fromkeys(scored["run_id"].astype(str)))
        out["max_clean_diff_um"] = worst
        return out, residuals
    finally:
        if keep is None:
            shutil.rmtree(proj, ignore_errors=True)


# ----------------------------------------------------------------------------- the score


def reference_um(disp: np.ndarray, t_s: np.ndarray) -> float:
    """The pipeline's log_start reference: the median over the first ``REFERENCE_WINDOW_S``."""
    return float(np.nanmedian(np.asarray(disp, dtype=float)[np.asarray(t_s) < REFERENCE_WINDOW_S]))


def log_rows(residuals: pd.DataFrame, runs: pd.DataFrame) -> np.ndarray:
    """The 0-based workbook row of every residual row: the run's ``start_s`` plus the row's
    ``t_s`` (seconds since the run's start), over the 15 s step."""
    start = residuals["run_id"].astype(str).map(runs.set_index(runs["run_id"].astype(str))["start_s"])
    t_log = start.to_numpy(dtype=float) + residuals["t_s"].to_numpy(dtype=float)
    rows = np.rint(t_log / PERIOD_S)
    if not np.allclose(rows * PERIOD_S, t_log, atol=1e-6):
        raise ValueError("residual times are not on the 15 s grid of the workbook")
    return rows.astype(int)


def score_family(residuals: pd.DataFrame, runs: pd.DataFrame, disp: np.ndarray, t_s: np.ndarray) -> dict:
    """Test MAE per model over the test rows its validation residuals cover.

    Returns ``{"mae": {model: um}, "rows": {model: scored test rows}, "n_test": test rows,
    "reference_um": ref, "max_clean_diff_um": max |measured_um - (disp - ref)| over the scored
    rows, "coverage": {model: fraction}, "width_um": {model: um}}`` (what cleaning changed in the
    measured values; the score uses the raw ``disp``). ``coverage`` is the fraction of the scored
    rows whose ``disp - ref`` lies in the model's prediction interval ``[lower_um, upper_um]``
    (residuals without those columns, or a model without an interval: NaN), ``width_um`` the
    median of ``upper_um - lower_um`` over them: read to report, never to choose."""
    disp = np.asarray(disp, dtype=float)
    ref = reference_um(disp, t_s)
    test = test_rows(t_s)
    out = {"mae": {}, "rows": {}, "n_test": int(test.sum()), "reference_um": ref, "max_clean_diff_um": 0.0}
    out.update(coverage={}, width_um={})
    for model, part in residuals.groupby(residuals["model"].astype(str), sort=False):
        rows = log_rows(part, runs)
        keep = test[rows]
        rows = rows[keep]
        if len(np.unique(rows)) != len(rows):
            raise ValueError(f"{model}: a test row is in two validation runs")
        pred = part["predicted_um"].to_numpy(dtype=float)[keep]
        measured = part["measured_um"].to_numpy(dtype=float)[keep]
        out["mae"][model] = float(np.mean(np.abs(disp[rows] - ref - pred))) if len(rows) else float("nan")
        out["rows"][model] = int(len(rows))
        out["coverage"][model], out["width_um"][model] = interval_score(part, keep, disp[rows] - ref)
        diff = np.abs(measured - (disp[rows] - ref))
        if len(diff):
            out["max_clean_diff_um"] = max(out["max_clean_diff_um"], float(np.nanmax(diff)))
    return out


def interval_score(part: pd.DataFrame, keep: np.ndarray, target: np.ndarray) -> tuple[float, float]:
    """Coverage (fraction) and median width (um) of one model's interval over its scored rows."""
    if not {"lower_um", "upper_um"} <= set(part.columns):
        return float("nan"), float("nan")
    lo, hi = (part[c].to_numpy(dtype=float)[keep] for c in ("lower_um", "upper_um"))
    ok = np.isfinite(lo) & np.isfinite(hi) & np.isfinite(target)
    if not ok.any():
        return float("nan"), float("nan")
    inside = (target[ok] >= lo[ok]) & (target[ok] <= hi[ok])
    return float(inside.mean()), float(np.median(hi[ok] - lo[ok]))


def project_facts(proj: Path, machine: str) -> dict:
    """What the pipeline found: runs (id, span in h, speed, kind, role), the champion, the
    selection basis and the input checks' warnings."""
    res = proj / "results" / machine
    runs = pd.read_csv(res / "runs.csv")
    summary = pd.read_csv(res / "comparison" / "summary.csv")
    champion = str(summary.loc[summary["champion"].astype(bool), "model"].iloc[0])
    status = json.loads((res / "input_status.json").read_text(encoding="utf-8"))
    log = proj / "logs" / machine / "compare.log"
    basis = next(
        (line.strip() for line in log.read_text(encoding="utf-8").splitlines() if "chosen by" in line), ""
    )
    keys = json.loads((res / "rank" / "key_sensors.json").read_text(encoding="utf-8"))
    audit = pd.read_csv(res / "audit.csv").iloc[0]
    cleaning = ("spikes_replaced", "values_interpolated", "gaps_interpolated", "duplicates_dropped")
    return {
        "key_sensors": keys["sensors"],
        "key_sensor_fallback": bool(keys.get("fallback_used")),
        "cleaning": {c: int(audit[c]) for c in cleaning},
        "runs": [
            {
                "run_id": str(r.run_id),
                "span_h": f"{r.start_s / 3600:.2f}-{r.end_s / 3600:.2f}",
                "speed_rpm": None if pd.isna(r.speed_rpm) else round(float(r.speed_rpm)),
                "kind": str(r.kind),
                "role": str(r.role),
                "role_source": str(r.role_source),
            }
            for r in runs.itertuples()
        ],
        "champion": champion,
        "selection": basis,
        "selected": dict(zip(summary["model"].astype(str), summary["selected"].astype(str))),
        "warnings": [f"{w.get('check')}: {w.get('message')}" for w in status.get("warnings", [])]
        + compare_warnings(log),
    }


def compare_warnings(log: Path) -> list[str]:
    """The compare step's warning lines in its log ``log`` (training runs no model explains, runs
    set aside before a change: ``rafi.ops.run_messages.warning_line``), their text only."""
    marker = " warning: "
    lines = log.read_text(encoding="utf-8").splitlines() if log.is_file() else []
    return [
        f"compare: {line.split(marker, 1)[1]}"
        for line in lines
        if line.startswith("RAFI compare") and marker in line
    ]


def scored_rows(
    residuals: pd.DataFrame, runs: pd.DataFrame, disp: np.ndarray, t_s: np.ndarray
) -> pd.DataFrame:
    """The residuals on the test rows as ``_realdata_runs``'s scored rows: the target the raw
    ``disp`` minus the log_start reference (as :func:`score_family` scores)."""
    disp = np.asarray(disp, dtype=float)
    ref, test = reference_um(disp, t_s), test_rows(t_s)
    parts = []
    for model, part in residuals.groupby(residuals["model"].astype(str), sort=False):
        rows = log_rows(part, runs)
        keep = test[rows]
        frame = {"run_id": part["run_id"].astype(str).to_numpy()[keep], "model": model}
        frame["target_um"] = disp[rows[keep]] - ref
        for col in ("predicted_um", "lower_um", "upper_um"):
            if col in part:
                frame[col] = part[col].to_numpy(dtype=float)[keep]
        parts.append(pd.DataFrame(frame))
    return pd.concat(parts, ignore_index=True)


def project_scores(proj: Path, machine: str, frame: pd.DataFrame, channel: str) -> dict:
    """:func:`score_family` of a project's residuals (with the plain ridge's of
    :func:`add_plain_ridge`), its :func:`project_facts` and ``per_run``: the lines of
    ``_realdata_runs.per_run`` over the test rows."""
    res = proj / "results" / machine
    residuals = read_residuals(proj, machine)
    runs = pd.read_csv(res / "runs.csv")
    t_s = frame[TIME_COL].to_numpy(dtype=float)
    disp = frame[f"{channel}(um)"].to_numpy(dtype=float)
    row = score_family(residuals, runs, disp, t_s)
    row.update(project_facts(proj, machine))
    row["per_run"] = per_run(scored_rows(residuals, runs, disp, t_s)).to_dict("records")
    return row


def run_one(
    data: Path,
    frame: pd.DataFrame,
    channel: str,
    config: str,
    cores: int,
    keep: Path | None,
    entry: dict | None = None,
    score=project_scores,
    plain: bool = False,
) -> dict:
    """Build, run and score one project; the temporary folder goes unless ``keep``.

    ``entry``: the machine's settings instead of :func:`machine_config` (``config`` then only
    labels the project); ``score(proj, machine, frame, channel) -> dict``: what is added to the
    row of a successful run (default :func:`project_scores`); ``plain``: also fit the plain
    ridge ``temperature_ridge`` where the settings leave it out (:func:`add_plain_ridge`)."""
    if keep is not None:
        proj = keep / f"{channel}-{config}"
        shutil.rmtree(proj, ignore_errors=True)
    else:
        proj = Path(tempfile.mkdtemp(prefix=f"rafi-realdata-{channel}-{config}-"))
    try:
        machine = write_project(proj, data, channel, config, entry)
        ok, wall, output = run_snakemake(proj, machine, cores)
        row = {"channel": channel, "config": config, "wall_s": round(wall, 1), "ok": ok}
        if not ok:
            row["tail"] = "\n".join(output.splitlines()[-25:])
            return row
        if plain:
            used = machine_config(channel, config) if entry is None else entry
            row["plain_ridge_run"] = add_plain_ridge(
                proj, machine, {"data.xlsx": data}, used, cores, f"FL_THERMAL {channel}, roles '{config}'"
            )
        row.update(score(proj, machine, frame, channel))
        return row
    finally:
        if keep is None:
            shutil.rmtree(proj, ignore_errors=True)


# ----------------------------------------------------------------------------- the tables


def fmt(x: float | None) -> str:
    """Two decimals, or a dash."""
    return "-" if x is None or not np.isfinite(x) else f"{x:.2f}"


def config_table(config: str, rows: list[dict], ridge: dict) -> list[str]:
    """Markdown table of one configuration: published, plain ridge, every model, offered."""
    done = [r for r in rows if r["config"] == config and r.get("ok")]
    models = list(dict.fromkeys(m for r in done for m in r["mae"]))
    head = ["channel", "published seq2seq-v2", "plain ridge", *models, "offered (kind)", "scored rows"]
    head += ["offered 90 % coverage", "offered median width"]
    lines = [f"| {' | '.join(head)} |", "|" + "---|" * len(head)]
    for r in sorted(done, key=lambda r: r["channel"]):
        ch = r["channel"]
        offered = r["champion"]
        cells = [ch, fmt(PUBLISHED_UM[ch]), fmt(ridge[ch]["test_mae_um"])]
        cells += [fmt(r["mae"].get(m)) for m in models]
        cells += [f"{fmt(r['mae'].get(offered))} ({offered})", f"{r['rows'].get(offered, 0)}/{r['n_test']}"]
        cover = r.get("coverage", {}).get(offered)
        cells += ["-" if cover is None or not np.isfinite(cover) else f"{cover:.1%}"]
        cells += [fmt(r.get("width_um", {}).get(offered))]
        lines.append(f"| {' | '.join(cells)} |")
    return lines


def ratio_table(rows: list[dict]) -> list[str]:
    """Offered model, automatic over windows, per channel measured in both."""
    by = {(r["channel"], r["config"]): r for r in rows if r.get("ok")}
    lines = ["| channel | windows | automatic | automatic / windows |", "|---|---|---|---|"]
    for ch in CHANNELS:
        w, a = by.get((ch, "windows")), by.get((ch, "automatic"))
        if not (w and a):
            continue
        mw, ma = w["mae"][w["champion"]], a["mae"][a["champion"]]
        lines.append(f"| {ch} | {fmt(mw)} ({w['champion']}) | {fmt(ma)} ({a['champion']}) | {ma / mw:.2f} |")
    return lines


def md_table(head: list[str], body: list[list]) -> list[str]:
    """A markdown table."""
    return [f"| {' | '.join(head)} |", "|" + "---|" * len(head)] + [
        f"| {' | '.join(str(c) for c in cells)} |" for cells in body
    ]


def markdown(report: dict) -> str:
    """The whole report as markdown."""
    rows, ridge = report["runs"], report["ridge"]
    lines = [
        f"# Real-data benchmark, FL_THERMAL ({report['date']})",
        "",
        f"Command: `{report['command']}`; host {report['host']}, {report['cpus']} CPUs.",
        "Test MAE, um, over rows 6751-8891 (101 265 s <= t <= 133 365 s).",
    ]
    for config in report["configs"]:
        lines += ["", f"## {config}", "", *config_table(config, rows, ridge)]
    lines += ["", "## offered model, automatic vs windows", "", *ratio_table(rows)]
    body = [
        [ch, fmt(r["test_mae_um"]), f"{r['alpha']:.3g}", fmt(r["cv_rmse_um"]), r["at_grid_edge"]]
        for ch, r in ridge.items()
    ]
    lines += ["", "## plain ridge", ""]
    lines += md_table(["channel", "test MAE", "alpha", "CV RMSE", "at grid edge"], body)
    body = [
        [r["channel"], r["config"], r["wall_s"], r.get("champion", "FAILED"), r.get("selection", "")]
        for r in rows
    ]
    lines += ["", "## runs", "", *md_table(["channel", "config", "wall s", "offered", "selection"], body)]
    for r in rows:
        if r.get("ok") and r.get("per_run"):
            lines += ["", f"## {r['channel']} {r['config']}: test MAE / max, um, per validation run", ""]
            lines += per_run_markdown(pd.DataFrame(r["per_run"]), r["champion"])
    return "\n".join(lines) + "\n"


def describe(row: dict) -> str:
    """What the pipeline found in one project: runs and roles, key sensors, cleaning, warnings."""
    keys = ", ".join(row["key_sensors"]) + (
        " (fallback: none reaches r > 0.97)" if row["key_sensor_fallback"] else ""
    )
    lines = [
        f"{row['channel']} {row['config']}: {row['selection']}",
        f"   key sensors {keys}; cleaning {row['cleaning']}",
    ]
    for run in row["runs"]:
        speed = "-" if run["speed_rpm"] is None else run["speed_rpm"]
        lines.append(
            f"   {run['run_id']:8s} {run['span_h']:>12s} h {speed!s:>5} r/min {run['kind']:8s} "
            f"{run['role']} ({run['role_source']})"
        )
    lines += [f"   warning {w}" for w in row["warnings"]]
    return "\n".join(lines)


def progress(row: dict) -> str:
    """One line per channel and configuration."""
    head = f"{row['channel']} {row['config']:9s} {row['wall_s']:7.1f} s"
    if not row.get("ok"):
        return f"{head}  snakemake FAILED; its last lines:\n{row['tail']}"
    offered = row["champion"]
    return (
        f"{head}  offered {offered}: test MAE {row['mae'][offered]:.2f} um "
        f"({row['rows'][offered]}/{row['n_test']} rows), interval coverage "
        f"{row['coverage'].get(offered, float('nan')):.1%} width {fmt(row['width_um'].get(offered))} um; "
        + ", ".join(f"{m} {v:.2f}" for m, v in row["mae"].items())
    )


def log_plan(
    logs: list[str], fl_data: Path, turning: Path | None, spindle: Path | None = None
) -> tuple[list[str], list[str]]:
    """``(logs to run, a line per log skipped)``: a real log runs when its data is present
    (FL_THERMAL's workbook; the turning centre's two workbooks in ``turning``; the 78 h spindle's
    CSV file ``spindle``), else it is skipped with a line saying where it was looked for."""
    import _realdata_spindle as spindle_log
    import _realdata_turning as turning_centre

    run, skipped = [], []
    for log in logs:
        if log == "fl-thermal":
            present, where = fl_data.is_file(), f"no workbook at {fl_data} (--data)"
        elif log == "spindle-78h":
            present = spindle_log.present(spindle)
            where = f"no file {spindle} (--spindle FILE)" if spindle else "no --spindle FILE"
        else:
            present = turning_centre.present(turning)
            names = " and ".join(turning_centre.FILES)
            where = (
                f"no {names} in {turning} (--turning DIR)" if turning else f"no --turning DIR with {names}"
            )
        (run if present else skipped).append(log if present else f"{log}: skipped, {where}")
    return run, skipped


def inside_repository(path: Path, root: Path = ROOT) -> bool:
    """True when ``path`` lies in the repository ``root`` (the turning centre's and the 78 h
    spindle's results may not: they are derived from rows without a licence)."""
    return Path(path).resolve().is_relative_to(Path(root).resolve())


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--data", type=Path, default=None, help="FL_THERMAL data.xlsx (default: ../shared/data/fl-thermal/)"
    )
    parser.add_argument(
        "--turning",
        type=Path,
        default=None,
        help="a folder holding the turning centre's ACE_X.xlsx and ACE_Y.xlsx",
    )
    parser.add_argument(
        "--spindle",
        type=Path,
        default=None,
        help="the 78 h spindle's CSV ('thermal expansion error original.csv')",
    )
    parser.add_argument("--logs", default=",".join(LOGS), help="the real logs to run, of " + ",".join(LOGS))
    parser.add_argument("--channels", default=",".join(CHANNELS), help="comma-separated, e.g. ch3,ch5")
    parser.add_argument("--configs", default=",".join(CONFIGS), help="windows,automatic")
    parser.add_argument("--cores", "--jobs", type=int, default=2, help="passed to snakemake --cores")
    parser.add_argument("--keep", type=Path, default=None, help="keep the projects under this folder")
    parser.add_argument(
        "--models",
        type=json.loads,
        default=None,
        help='JSON: the machines\' models: settings, e.g. \'{"enabled": ["dynamic", "grey_box"]}\'',
    )
    parser.add_argument(
        "--out",
        default="realdata",
        help="file stem (the other logs': <stem>-turning-centre, <stem>-spindle-78h)",
    )
    parser.add_argument(
        "--out-dir",
        type=Path,
        default=None,
        help="results folder (default benchmarks/results; for the unlicensed logs: outside the repository)",
    )
    args = parser.parse_args(argv)
    args.channels = [c.strip() for c in args.channels.split(",") if c.strip()]
    args.configs = [c.strip() for c in args.configs.split(",") if c.strip()]
    args.logs = [c.strip() for c in args.logs.split(",") if c.strip()]
    for values, known, what in (
        (args.channels, CHANNELS, "channel"),
        (args.configs, CONFIGS, "configuration"),
    ):
        for c in values:
            if c not in known:
                parser.error(f"unknown {what} {c!r}; expected some of {', '.join(known)}")
    for c in args.logs:
        if c not in LOGS:
            parser.error(f"unknown log {c!r}; expected some of {', '.join(LOGS)}")
    args.data = args.data or default_data()
    args.out_dir = args.out_dir or OUT_DIR
    args.plan, args.skipped = log_plan(args.logs, args.data, args.turning, args.spindle)
    unlicensed = [log for log in ("turning-centre", "spindle-78h") if log in args.plan]
    if unlicensed and inside_repository(args.out_dir):
        parser.error(
            f"--out-dir {args.out_dir} lies in the repository: the results of {' and '.join(unlicensed)} "
            "are derived from data without a licence and are never written there; give a folder outside it"
        )
    return args


def run_fl_thermal(args: argparse.Namespace, command: str) -> None:
    """FL_THERMAL's channels and configurations (module docstring); writes ``<out>.json/.md``."""
    frame = read_workbook(args.data)
    t_s = frame[TIME_COL].to_numpy(dtype=float)
    temps = frame[[f"t{i}(°C)" for i in range(1, 17)]].to_numpy(dtype=float)
    ridge = {}
    for ch in args.channels:
        ridge[ch] = plain_ridge(temps, frame[f"{ch}(um)"].to_numpy(dtype=float), t_s)
        print(
            f"{ch} plain ridge: test MAE {ridge[ch]['test_mae_um']:.2f} um (alpha {ridge[ch]['alpha']:.3g})",
            flush=True,
        )
    rows = []
    for config in args.configs:
        for ch in args.channels:
            entry = None if args.models is None else {**machine_config(ch, config), "models": args.models}
            row = run_one(args.data, frame, ch, config, args.cores, args.keep, entry, plain=True)
            rows.append(row)
            print(progress(row), flush=True)
    report = {
        **host_facts(command),
        "data": str(args.data),
        "configs": args.configs,
        "ridge": ridge,
        "runs": rows,
    }
    text = markdown(report)
    print("\n" + text)
    for r in rows:
        if r.get("ok"):
            print(describe(r))
    write_results(args.out, report, text, ensure_ascii=False, out_dir=args.out_dir)


def run_turning_centre(args: argparse.Namespace, command: str) -> None:
    """The turning centre (``_realdata_turning``); writes ``<out>-turning-centre.json/.md``."""
    import _realdata_turning as turning_centre

    result = turning_centre.run(args.turning, args.cores, args.keep, args.models)
    report = {**host_facts(command), "data": str(args.turning), "turning": result}
    text = turning_centre.markdown(report)
    print("\n" + text, flush=True)
    write_results(f"{args.out}-turning-centre", report, text, ensure_ascii=False, out_dir=args.out_dir)


def run_spindle(args: argparse.Namespace, command: str) -> None:
    """The 78 h spindle (``_realdata_spindle``), both splits; writes ``<out>-spindle-78h.json/.md``."""
    import _realdata_spindle as spindle_log

    results = []
    for split in spindle_log.SPLITS:
        results.append(spindle_log.run(args.spindle, split, args.cores, args.keep, args.models))
        print(f"spindle-78h split {split}: done ({results[-1].get('wall_s')} s)", flush=True)
    report = {**host_facts(command), "data": str(args.spindle), "spindle": results}
    text = spindle_log.markdown(report)
    print("\n" + text, flush=True)
    write_results(f"{args.out}-spindle-78h", report, text, ensure_ascii=False, out_dir=args.out_dir)


def host_facts(command: str) -> dict:
    """Date, command, host and CPUs of a report."""
    return {
        "date": dt.date.today().isoformat(),
        "command": command,
        "host": platform.node(),
        "cpus": os.cpu_count(),
    }


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    command = " ".join(["python benchmarks/bench_realdata.py", *(sys.argv[1:] if argv is None else argv)])
    for line in args.skipped:
        print(line, flush=True)
    if not args.plan:
        print("no real log present: nothing run", flush=True)
        return 0
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
    if "spindle-78h" in args.plan:  # the smaller ones first
        run_spindle(args, command)
    if "turning-centre" in args.plan:
        run_turning_centre(args, command)
    if "fl-thermal" in args.plan:
        run_fl_thermal(args, command)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
