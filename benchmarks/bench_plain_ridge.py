"""The real-data benchmark's plain ridge as a yardstick on the validation runs of any project.

Usage (from the repository root; see benchmarks/README.md)::

    python benchmarks/bench_plain_ridge.py --project /tmp/rd/ch5-windows --project /tmp/twins
    python benchmarks/bench_plain_ridge.py --project . --machines machining-center-b

Each ``--project`` is a Snakemake project that has run (``results/<machine>/`` holds
``runs.csv``, ``runs.parquet`` and ``comparison/``): this project after ``snakemake --cores 2``,
a copy of it, the folders ``bench_realdata.py --keep DIR`` leaves, or a user's own project.

**Why.** Issue 25 asks the family to be ahead of a plain ridge on real logs the project has not
seen. ``bench_realdata.py`` measures that on one workbook with its own split; this bench measures
it on any configured machine, on the runs the pipeline itself calls training and validation, so a
user (or a reviewer with a new log) gets the comparison with one command.

**The plain ridge** is ``bench_realdata``'s (:func:`bench_realdata.ridge_fit`,
:func:`~bench_realdata.choose_alpha`, :func:`~bench_realdata.lowpass`, its constants), applied to
the pipeline's cleaned samples (``runs.parquet``) instead of the raw workbook, and independent of
the pipeline's models otherwise:

* **Logs**: the samples of each log (column ``log``) in ``log_t_s`` order, every sample of a log
  whatever its role (the filters run causally from the log's first sample, as a controller's
  would).
* **Features**: every temperature sensor of the machine (its own names, the columns ``s`` of
  ``runs.parquet`` beside their rise ``d<s>``: :func:`rafi.contract.sensors.run_sensors`) usable on
  the training rows (some finite value, not constant); a missing value holds the sensor's last
  value within its log (at the log's start, its first finite value). Per sensor the temperature
  and its low-pass filters (``RIDGE_TAUS_S``, run over the whole log), each as a change from the
  temperature at the sample's reference (the run's or the log's, as the pipeline took it for
  ``dz_um``: the median over the run of ``s - d<s>``), 3 columns per sensor, standardised on the
  fitting rows. On a log with one reference (FL_THERMAL's ``log_start``) these are
  ``bench_realdata``'s rises and their filters.
* **Target**: ``dz_um``, the displacement change from the pipeline's reference, the quantity every
  model of the family predicts (``measured_um`` of ``comparison/residuals.parquet``), with an
  unpenalised intercept. Features and target change from the same reference, so a log of several
  runs each referenced at its own start (``run_start``) is read as the pipeline reads it.
* **Penalty**: blocked CV on the training rows only (``RIDGE_BLOCKS`` contiguous blocks of equal
  row count, rows within ``RIDGE_GAP_S`` of a held-out block left out of its fit). The logs are
  laid end to end on one time axis, each one ``2 x RIDGE_GAP_S`` after the previous one ends, so
  a block's guard never removes rows of another log.

**The score**, read to report and never to choose: on the validation samples of the offered
model (``champion`` of ``comparison/summary.csv``, rows of ``comparison/residuals.parquet``) where
both predictions are finite: the mean |residual| (MAE), the mean over validation runs of the max
|residual| (the selection's criterion) and the worst run's max |residual|, for the plain ridge
and the offered model; ``offered / ridge`` of the MAE. Training rows only choose the penalty.

Output: progress on stderr, the table on stdout, ``benchmarks/results/<out>.json`` and ``.md``
(no date, host or timing in them: the same projects and command give the same files).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / "benchmarks"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from _results import write_results  # noqa: E402
from bench_realdata import (  # noqa: E402
    RIDGE_ALPHAS,
    RIDGE_GAP_S,
    RIDGE_TAUS_S,
    choose_alpha,
    lowpass,
    md_table,
    ridge_fit,
    ridge_predict,
)

from rafi.contract.sensors import run_sensors  # noqa: E402


def in_log_order(frame: pd.DataFrame) -> pd.DataFrame:
    """The samples log by log (logs in the order of their first time stamp, then by name), each
    log in ``log_t_s`` order; index reset."""
    key = pd.DataFrame(
        {
            "first": frame.groupby("log", sort=False)["time"].transform("min").to_numpy(),
            "log": frame["log"].astype(str).to_numpy(),
            "log_t_s": frame["log_t_s"].to_numpy(dtype=float),
        }
    )
    order = key.sort_values(["first", "log", "log_t_s"], kind="stable").index.to_numpy()
    return frame.iloc[order].reset_index(drop=True)


def end_to_end_time(frame: pd.DataFrame, gap_s: float = RIDGE_GAP_S) -> np.ndarray:
    """One time axis over the logs of a frame in :func:`in_log_order`: each log's ``log_t_s``
    shifted to start ``2 x gap_s`` after the previous log ends."""
    t = frame["log_t_s"].to_numpy(dtype=float)
    out = np.empty_like(t)
    offset = 0.0
    for rows in frame.groupby(frame["log"].astype(str), sort=False).indices.values():
        local = t[rows] - t[rows].min()
        out[rows] = offset + local
        offset += local.max() + 2.0 * gap_s
    return out


def ridge_sensors(frame: pd.DataFrame, train: np.ndarray) -> list[str]:
    """The machine's sensors (:func:`rafi.contract.sensors.run_sensors`) with a finite value on the
    training rows and not constant there (unlike the family's
    :func:`rafi.family.features.usable_sensors`, a sensor with missing values is kept:
    :func:`plain_features` holds its last value)."""
    keep = []
    for col in run_sensors(frame):
        values = frame[col].to_numpy(dtype=float)[train]
        finite = values[np.isfinite(values)]
        if finite.size and np.ptp(finite) > 0:
            keep.append(col)
    return keep


def reference_temperatures(frame: pd.DataFrame, sensors: list[str]) -> np.ndarray:
    """Per sample and sensor, the temperature at the sample's reference as the pipeline took it
    (``runs.parquet``'s rise ``d<s>`` is ``s`` minus it, one value a run): the median over the run
    of ``s - d<s>``; a run where that is never finite falls back to the run's first held value
    (:func:`plain_features`' hold)."""
    out = np.empty((len(frame), len(sensors)))
    held = frame[sensors].ffill().bfill().to_numpy(dtype=float)
    for rows in frame.groupby(frame["run_id"].astype(str), sort=False).indices.values():
        part = frame.iloc[rows]
        diff = part[sensors].to_numpy(dtype=float) - part[[f"d{s}" for s in sensors]].to_numpy(dtype=float)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a sensor never finite in the run
            ref = np.nanmedian(diff, axis=0)
        out[rows] = np.where(np.isfinite(ref), ref, held[rows[0]])
    return out


def plain_features(frame: pd.DataFrame, sensors: list[str]) -> np.ndarray:
    """The plain ridge's features of a frame in :func:`in_log_order` (module docstring): per log,
    the held sensors' temperatures and their low-pass filters (run over the log), each less the
    temperature at the sample's reference (:func:`reference_temperatures`), ``3 x len(sensors)``
    columns (rises first, then per filter)."""
    x = np.empty((len(frame), len(sensors) * (1 + len(RIDGE_TAUS_S))))
    ref = reference_temperatures(frame, sensors)
    for rows in frame.groupby(frame["log"].astype(str), sort=False).indices.values():
        part = frame.iloc[rows]
        temps = part[sensors].ffill().bfill().to_numpy(dtype=float)
        t_log = part["log_t_s"].to_numpy(dtype=float)
        x[rows] = np.hstack(
            [temps - ref[rows], *(lowpass(temps, t_log, tau) - ref[rows] for tau in RIDGE_TAUS_S)]
        )
    return x


def roles_of(frame: pd.DataFrame, runs: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Masks of the training and validation samples (``role`` of ``runs.csv``: ``training``;
    ``validation*``)."""
    role = frame["run_id"].astype(str).map(runs.set_index(runs["run_id"].astype(str))["role"].astype(str))
    role = role.fillna("").to_numpy(dtype=str)
    return role == "training", np.char.startswith(role, "validation")


def plain_ridge_predictions(frame: pd.DataFrame, runs: pd.DataFrame) -> tuple[pd.DataFrame, dict]:
    """The plain ridge fitted on a machine's training samples, predicting every sample.

    Returns the frame's ``run_id``, ``t_s`` and ``predicted_um`` (NaN where a feature is not
    finite) and the fit's record (``alpha``, ``cv_rmse_um``, ``at_grid_edge``, ``sensors``,
    ``n_training``)."""
    frame = in_log_order(frame)
    train, _ = roles_of(frame, runs)
    sensors = ridge_sensors(frame, train)
    x = plain_features(frame, sensors)
    y = frame["dz_um"].to_numpy(dtype=float)
    t = end_to_end_time(frame)
    fit_rows = train & np.isfinite(y) & np.isfinite(x).all(axis=1)
    chosen = choose_alpha(x[fit_rows], y[fit_rows], t[fit_rows], RIDGE_ALPHAS)
    model = ridge_fit(x[fit_rows], y[fit_rows], np.array([chosen["alpha"]]))
    pred = ridge_predict(model, x)[:, 0]
    out = pd.DataFrame(
        {"run_id": frame["run_id"].astype(str), "t_s": frame["t_s"].astype(float), "predicted_um": pred}
    )
    return out, {**chosen, "sensors": sensors, "n_training": int(fit_rows.sum())}


def run_scores(run_id: np.ndarray, residual: np.ndarray) -> dict:
    """MAE over the samples, mean over runs of the max |residual| and the worst run's, um."""
    worst = pd.Series(np.abs(residual)).groupby(run_id).max()
    return {
        "mae_um": float(np.mean(np.abs(residual))),
        "mean_max_um": float(worst.mean()),
        "worst_max_um": float(worst.max()),
        "worst_run": str(worst.idxmax()),
    }


def machine_scores(result_dir: Path) -> dict:
    """The plain ridge and the offered model of one machine on its validation samples."""
    runs = pd.read_csv(result_dir / "runs.csv")
    frame = pd.read_parquet(result_dir / "runs.parquet")
    summary = pd.read_csv(result_dir / "comparison" / "summary.csv")
    offered = str(summary.loc[summary["champion"].astype(bool), "model"].iloc[0])
    residuals = pd.read_parquet(result_dir / "comparison" / "residuals.parquet")
    mine = residuals.loc[
        residuals["model"].astype(str) == offered, ["run_id", "t_s", "measured_um", "predicted_um"]
    ]
    ridge, record = plain_ridge_predictions(frame, runs)
    both = mine.assign(run_id=mine["run_id"].astype(str)).merge(
        ridge.rename(columns={"predicted_um": "ridge_um"}),
        on=["run_id", "t_s"],
        how="inner",
        validate="one_to_one",
    )
    ok = np.isfinite(both[["measured_um", "predicted_um", "ridge_um"]].to_numpy(dtype=float)).all(axis=1)
    both = both.loc[ok]
    run_id = both["run_id"].to_numpy(dtype=str)
    measured = both["measured_um"].to_numpy(dtype=float)
    scores = {
        "plain_ridge": run_scores(run_id, measured - both["ridge_um"].to_numpy(dtype=float)),
        "offered": run_scores(run_id, measured - both["predicted_um"].to_numpy(dtype=float)),
    }
    return {
        "offered_kind": offered,
        "n_validation_samples": int(len(both)),
        "n_validation_runs": int(len(np.unique(run_id))),
        "ridge": {k: v for k, v in record.items() if k != "sensors"},
        "n_sensors": len(record["sensors"]),
        "scores": scores,
        "ratio_mae": scores["offered"]["mae_um"] / scores["plain_ridge"]["mae_um"],
    }


def machines_of(project: Path, names: set[str]) -> list[Path]:
    """Result folders of a project's machines that have run (``comparison/summary.csv``), by name."""
    found = sorted(p.parent.parent for p in (project / "results").glob("*/comparison/summary.csv"))
    return [p for p in found if not names or p.name in names]


def markdown(report: dict) -> str:
    """The table: one row per machine."""
    head = [
        "project", "machine", "validation runs", "plain ridge MAE", "offered MAE (kind)", "offered / ridge",
        "plain ridge mean max", "offered mean max", "plain ridge worst", "offered worst", "ridge alpha",
    ]  # fmt: skip
    body = []
    for row in report["machines"]:
        r, o = row["scores"]["plain_ridge"], row["scores"]["offered"]
        edge = " (edge)" if row["ridge"]["at_grid_edge"] else ""
        body.append(
            [
                row["project"],
                row["machine"],
                row["n_validation_runs"],
                f"{r['mae_um']:.2f}",
                f"{o['mae_um']:.2f} ({row['offered_kind']})",
                f"{row['ratio_mae']:.2f}",
                f"{r['mean_max_um']:.2f}",
                f"{o['mean_max_um']:.2f}",
                f"{r['worst_max_um']:.2f} ({r['worst_run']})",
                f"{o['worst_max_um']:.2f} ({o['worst_run']})",
                f"{row['ridge']['alpha']:.3g}{edge}",
            ]
        )
    lines = [
        "# The plain ridge beside the offered model, on each machine's validation runs",
        "",
        f"Command: `{report['command']}`.",
        "um; MAE over the validation samples, mean and worst over validation runs of the max |residual|.",
        "The plain ridge's penalty comes from blocked CV on the training rows; nothing here chose a model.",
        "",
        *md_table(head, body),
    ]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--project", type=Path, action="append", required=True, help="a project that has run")
    parser.add_argument("--machines", default="", help="comma-separated machine names (default: all)")
    parser.add_argument("--out", default="plain_ridge", help="file stem under benchmarks/results/")
    args = parser.parse_args(argv)
    names = {m for m in args.machines.split(",") if m}
    command = "python benchmarks/bench_plain_ridge.py " + " ".join(sys.argv[1:] if argv is None else argv)
    rows = []
    for project in args.project:
        found = machines_of(project, names)
        if not found:
            print(
                f"{project}: no results/<machine>/comparison/summary.csv"
                + (f" of {sorted(names)}" if names else "")
                + "; run `snakemake --cores 2` there first",
                file=sys.stderr,
            )
            return 2
        for result_dir in found:
            print(f"{project.name}/{result_dir.name}: fitting the plain ridge", file=sys.stderr)
            rows.append({"project": project.name, "machine": result_dir.name, **machine_scores(result_dir)})
    report = {"command": command, "machines": rows}
    text = markdown(report)
    print(text, end="")
    write_results(args.out, report, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
