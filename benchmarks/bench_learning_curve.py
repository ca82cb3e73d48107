"""Learning curve on a real log: the project's own choice against hours of training data.

Usage (from the repository root; see benchmarks/README.md)::

    python benchmarks/bench_learning_curve.py                       # 5 channels x 6 cuts
    python benchmarks/bench_learning_curve.py --channels ch3 --cuts 8h,28h
    python benchmarks/bench_learning_curve.py --cores 2 --keep /tmp/lc   # keep the projects

The data and the pipeline are those of ``benchmarks/bench_realdata.py`` (CAIVIAC/FL_THERMAL, one
machine per displacement channel, the real Snakefile, configured, not coded), with its
``windows`` protocol: training until the end of the 5000 r/min run at 101 265 s with the
cool-downs (``runs.idle_training: true``), validation on everything after, test MAE over the
workbook rows 6751-8891. What changes here is only how much of the training part trains.

**The cut** (:data:`CUTS`, :func:`curve_runs`): the training runs are taken in time order up to a
cut time ``c`` on the log's clock (``elapsed_s``), all set by ``runs.windows`` in the config:

* ``{role: training, end: c}``: every run that starts before ``c`` trains (the window cuts a run
  at ``c``, so nothing after ``c`` trains);
* ``{role: excluded, start: c, end: 101265}``: the rest of the training part is not used at all
  (neither trains nor validates), so the validation runs, and with them the scored test rows, are
  the same at every cut;
* ``{role: validation, start: 101265}``: as in ``bench_realdata``.

The cuts: the first 2 h of the 1250 r/min run, the whole run (4 h), the run and its cool-down
(8 h), then each further speed with its cool-down (16 h, 24 h), and the whole training part
(28 h: up to the end of the 5000 r/min run, which is ``bench_realdata``'s ``windows``). At every
cut the pipeline chooses its model by its own rule on the training runs it has (whole-run CV;
time-blocked folds or the default model when there are too few runs: the table says which).

**The score** per channel and cut, of the offered model (the champion) and read only to report:
test MAE over rows 6751-8891 (:func:`bench_realdata.score_family`), the largest |residual| over the
test rows (raw displacement minus reference minus prediction), the worst validation run's max
|residual| (the pipeline's cleaned ``measured_um``, as the gates judge it, over every validation
run after 101 265 s) and the coverage of the 90 % interval on the test rows. Beside them: the
published test MAE (seq2seq-v2) and the plain ridge reference of ``bench_realdata`` (trained on
the whole training part; it has no curve: its blocked CV needs more than 2 x 3 h of data).

Output: markdown on stdout and in ``benchmarks/results/learning_curve.md``, everything in
``learning_curve.json``; progress on stderr. Exit status 0; a failed Snakemake run is reported and
the next project runs.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_realdata as rd  # noqa: E402
from _results import write_results  # noqa: E402

from rafi.family.forward_folds import is_forward  # noqa: E402

#: The cuts: name -> (cut time on the log's clock, s; what trains). Runs per the data's README:
#: 1250 r/min 465-14 850 s, then a 4 h rest, 2500 from 29 265 s, 3750 from 58 065 s, 5000 from
#: 86 865 s to 101 250 s; a cut at a run's start keeps the cool-down before it.
CUTS = {
    "2h": (7_665.0, "the first 2 h of the 1250 r/min run"),
    "4h": (14_865.0, "the 1250 r/min run"),
    "8h": (29_265.0, "1250 r/min + cool-down"),
    "16h": (58_065.0, "+ 2500 r/min + cool-down"),
    "24h": (86_865.0, "+ 3750 r/min + cool-down"),
    "28h": (rd.SPLIT_S, "+ 5000 r/min (the whole training part)"),
}

#: compare.log lines that say how the champion was chosen (or that it could not be).
SELECTION_MARKERS = ("too few training runs", "offered by the default rule", "chosen by")


# ----------------------------------------------------------------------------- the cut


def curve_runs(cut_s: float) -> dict:
    """The ``runs`` settings of one cut: training before ``cut_s``, the rest of the training part
    (``cut_s`` to :data:`bench_realdata.SPLIT_S`) excluded, validation after, cool-downs train."""
    cut = int(cut_s)
    if not 0 < cut <= rd.SPLIT_S:
        raise ValueError(f"cut {cut_s} s outside the training part (0, {rd.SPLIT_S:.0f}] s")
    windows = [{"role": "training", "end": cut, "unit": "elapsed_s"}]
    if cut < rd.SPLIT_S:
        windows.append({"role": "excluded", "start": cut, "end": int(rd.SPLIT_S), "unit": "elapsed_s"})
    windows.append({"role": "validation", "start": int(rd.SPLIT_S), "unit": "elapsed_s"})
    return {"idle_training": True, "windows": windows}


def curve_config(channel: str, cut_s: float) -> dict:
    """A machine's ``config.yaml`` entry: ``bench_realdata``'s ``windows`` configuration with the
    roles of :func:`curve_runs`."""
    return {**rd.machine_config(channel, "windows"), "runs": curve_runs(cut_s)}


def parse_cuts(text: str) -> dict[str, tuple[float, str]]:
    """``--cuts``: names of :data:`CUTS` or cut times in seconds, comma-separated."""
    out = {}
    for name in (c.strip() for c in text.split(",") if c.strip()):
        if name in CUTS:
            out[name] = CUTS[name]
            continue
        try:
            seconds = float(name)
        except ValueError:
            raise ValueError(f"unknown cut {name!r}; expected some of {', '.join(CUTS)} or seconds") from None
        out[f"{seconds / 3600:.1f}h"] = (seconds, f"training until {seconds:.0f} s")
    return out


# ----------------------------------------------------------------------------- the score


def training_facts(runs: pd.DataFrame, cut_s: float) -> dict:
    """What trained: hours and ids of the training runs, the last training sample's time (must
    not pass ``cut_s``) and the validation span."""
    train = runs.loc[runs["role"].astype(str) == "training"]
    val = runs.loc[runs["role"].astype(str).str.startswith("validation")]
    last = float(train["end_s"].max()) if len(train) else float("nan")
    if last >= cut_s:
        raise ValueError(f"a training sample at {last:.0f} s, at or after the cut {cut_s:.0f} s")
    return {
        "training_h": float(train["duration_s"].sum()) / 3600.0,
        "training_runs": [
            f"{'idle' if str(r.kind) == 'idle' else round(float(r.speed_rpm))}" for r in train.itertuples()
        ],
        "last_training_s": last,
        "validation_from_s": float(val["start_s"].min()) if len(val) else float("nan"),
    }


def offered_extremes(
    residuals: pd.DataFrame, runs: pd.DataFrame, model: str, disp: np.ndarray, t_s: np.ndarray
) -> dict:
    """The offered model's largest |residual| over the test rows (raw ``disp`` minus the
    reference) and its worst validation run (max |measured_um - predicted_um|, the gates' view)."""
    part = residuals.loc[residuals["model"].astype(str) == model]
    rows = rd.log_rows(part, runs)
    keep = rd.test_rows(t_s)[rows]
    pred = part["predicted_um"].to_numpy(dtype=float)
    ref = rd.reference_um(disp, t_s)
    test_max = float(np.max(np.abs(disp[rows[keep]] - ref - pred[keep]))) if keep.any() else float("nan")
    per_run = (part["measured_um"] - part["predicted_um"]).abs().groupby(part["run_id"].astype(str)).max()
    return {
        "test_max_abs_um": test_max,
        "worst_run": str(per_run.idxmax()),
        "worst_run_max_abs_um": float(per_run.max()),
    }


def selection_lines(proj: Path, machine: str) -> list[str]:
    """The compare log's lines on how the champion was chosen (:data:`SELECTION_MARKERS`)."""
    log = proj / "logs" / machine / "compare.log"
    lines = log.read_text(encoding="utf-8").splitlines() if log.is_file() else []
    return [ln.strip() for ln in selected_lines(lines) if ln != "-"]


def selected_lines(lines: list[str]) -> list[str]:
    """The lines of ``lines`` with one of :data:`SELECTION_MARKERS` (a dash if none)."""
    return [ln for ln in lines if any(m in ln for m in SELECTION_MARKERS)] or ["-"]


def cv_facts(proj: Path, machine: str, champion: str) -> dict:
    """The folds' schemes, the champion's whole-run fold count and CV mean max |residual| (NaN: no
    fold)."""
    cv = pd.read_csv(proj / "results" / machine / "comparison" / "cv.csv")
    whole = ~cv["scheme"].map(is_forward).to_numpy(dtype=bool)  # the forward folds' rows apart
    mine = cv.loc[whole & (cv["model"].astype(str) == champion).to_numpy()]
    return {
        "cv_scheme": ",".join(sorted(set(cv["scheme"].astype(str)))) if len(cv) else "no fold",
        "cv_folds": int(mine["fold"].nunique()) if len(mine) else 0,
        "cv_mean_max_abs_um": float(mine["max_abs_after_um"].mean()) if len(mine) else float("nan"),
    }


def curve_scorer(cut_s: float):
    """The ``score`` of :func:`bench_realdata.run_one` for one cut: its :func:`project_scores`
    plus :func:`training_facts`, :func:`offered_extremes`, :func:`cv_facts` and the selection
    lines."""

    def score(proj: Path, machine: str, frame: pd.DataFrame, channel: str) -> dict:
        row = rd.project_scores(proj, machine, frame, channel)
        res = proj / "results" / machine
        runs = pd.read_csv(res / "runs.csv")
        residuals = pd.read_parquet(res / "comparison" / "residuals.parquet")
        disp = frame[f"{channel}(um)"].to_numpy(dtype=float)
        t_s = frame[rd.TIME_COL].to_numpy(dtype=float)
        row.update(training_facts(runs, cut_s))
        row.update(offered_extremes(residuals, runs, row["champion"], disp, t_s))
        row.update(cv_facts(proj, machine, row["champion"]))
        row["selection_log"] = selection_lines(proj, machine)
        return row

    return score


def failure_cause(proj: Path) -> str:
    """The last line of every log file of the rules Snakemake reports as failed (the exception),
    from ``bench-snakemake.log`` of a project :func:`bench_realdata.run_snakemake` ran."""
    out = (proj / "bench-snakemake.log").read_text(encoding="utf-8") if proj.is_dir() else ""
    causes = []
    for line in out.splitlines():
        if not line.strip().startswith("log: "):
            continue
        for name in line.strip()[5:].split(" (")[0].split(", "):
            path = proj / name.strip()
            text = path.read_text(encoding="utf-8").strip() if path.is_file() else ""
            if text and "Error" in text.splitlines()[-1]:
                causes.append(f"{name.strip()}: {text.splitlines()[-1]}")
    return "; ".join(dict.fromkeys(causes)) or "see the Snakemake output"


# ----------------------------------------------------------------------------- the tables


def pct(x: float | None) -> str:
    """A fraction as a percentage, or a dash."""
    return "-" if x is None or not np.isfinite(x) else f"{x:.0%}"


def summary_table(rows: list[dict], channels: list[str], ridge: dict) -> list[str]:
    """Test MAE of the offered model (kind) per cut and channel, with the references below."""
    cuts = list(dict.fromkeys(r["cut"] for r in rows))
    by = {(r["cut"], r["channel"]): r for r in rows}
    body = []
    for cut in cuts:
        done = [by[(cut, ch)] for ch in channels if by.get((cut, ch), {}).get("ok")]
        hours = rd.fmt(done[0]["training_h"]) if done else "-"
        cells = [cut, hours, next(r["what"] for r in rows if r["cut"] == cut)]
        for ch in channels:
            r = by.get((cut, ch))
            cells.append(
                f"{rd.fmt(r['mae'][r['champion']])} ({r['champion']})" if r and r.get("ok") else "FAILED"
            )
        body.append(cells)
    body.append(
        ["plain ridge", "28.1", "t < 101 265 s", *(rd.fmt(ridge[ch]["test_mae_um"]) for ch in channels)]
    )
    body.append(
        [
            "published",
            "-",
            "seq2seq-v2, first 60 % of rows",
            *(rd.fmt(rd.PUBLISHED_UM[ch]) for ch in channels),
        ]
    )
    return rd.md_table(["cut", "training h", "what trains", *channels], body)


def run_label(row: dict, run_id: str) -> str:
    """A run by its span and speed (run ids differ between cuts: a cut inside a run adds one)."""
    run = next((x for x in row["runs"] if x["run_id"] == run_id), None)
    if run is None:
        return run_id
    return f"{run['span_h']} h, {'idle' if run['kind'] == 'idle' else run['speed_rpm']}"


def gates(lines: list[str]) -> str:
    """``pass`` / ``FAIL`` from the compare log's champion line, else a dash."""
    said = " ".join(lines)
    return "pass" if "passes the gates" in said else "FAIL" if "FAILS the gates" in said else "-"


def channel_table(rows: list[dict], channel: str) -> list[str]:
    """One channel's curve: training, CV, offered model, its test and validation figures."""
    head = ["cut", "training h", "training runs", "CV", "offered", "test MAE", "test max abs"]
    head += ["worst validation run max abs", "90 % coverage (test)", "gates"]
    body = []
    for r in (r for r in rows if r["channel"] == channel):
        if not r.get("ok"):
            body.append([r["cut"], "-", "-", "-", f"FAILED ({r['cause']})", *["-"] * 5])
            continue
        champ = r["champion"]
        cv = f"{r['cv_scheme']} ({r['cv_folds']})" if r["cv_folds"] else "no fold: default"
        body.append(
            [
                r["cut"],
                rd.fmt(r["training_h"]),
                " ".join(r["training_runs"]),
                cv,
                champ,
                rd.fmt(r["mae"][champ]),
                rd.fmt(r["test_max_abs_um"]),
                f"{rd.fmt(r['worst_run_max_abs_um'])} ({run_label(r, r['worst_run'])})",
                pct(r["coverage"].get(champ)),
                gates(r["selection_log"]),
            ]
        )
    return rd.md_table(head, body)


def markdown(report: dict) -> str:
    """The whole report as markdown."""
    rows, channels = report["runs"], report["channels"]
    lines = [
        f"# Learning curve on real data, FL_THERMAL ({report['date']})",
        "",
        f"Command: `{report['command']}`; host {report['host']}, {report['cpus']} CPUs.",
        "Real data (CAIVIAC/FL_THERMAL, one machine per channel). Training runs taken in time order",
        "up to the cut, the rest of the training part excluded; validation after 101 265 s at every",
        "cut. Test MAE, um, of the offered model over rows 6751-8891 (101 265 s <= t <= 133 365 s).",
        "",
        *summary_table(rows, channels, report["ridge"]),
    ]
    for ch in channels:
        lines += ["", f"## {ch}", "", *channel_table(rows, ch)]
    lines += ["", "## how the model was chosen", ""]
    for r in rows:
        said = "; ".join(selected_lines(r["selection_log"])) if r.get("ok") else f"FAILED: {r['cause']}"
        lines.append(f"- {r['channel']} {r['cut']}: {said}")
    return "\n".join(lines) + "\n"


def progress(row: dict) -> str:
    """One line per channel and cut (stderr)."""
    head = f"{row['channel']} {row['cut']:>4s} {row['wall_s']:7.1f} s"
    if not row.get("ok"):
        return f"{head}  snakemake FAILED: {row['cause']}"
    champ = row["champion"]
    return (
        f"{head}  {row['training_h']:.1f} h training ({' '.join(row['training_runs'])}), "
        f"CV {row['cv_scheme']}, offered {champ}: test MAE {row['mae'][champ]:.2f} um, "
        f"max {row['test_max_abs_um']:.2f} um, coverage {pct(row['coverage'].get(champ))}"
    )


def run_curve(
    data: Path, frame: pd.DataFrame, channels: list[str], cuts: dict, cores: int, keep: Path | None
) -> list[dict]:
    """Every cut and channel through :func:`bench_realdata.run_one`; the projects live under
    ``keep``, else under a temporary folder removed at the end (a failed project is read for
    :func:`failure_cause` first)."""
    root = keep if keep is not None else Path(tempfile.mkdtemp(prefix="rafi-curve-"))
    rows = []
    try:
        for name, (cut_s, what) in cuts.items():
            for ch in channels:
                config = f"cut-{name}"
                entry, score = curve_config(ch, cut_s), curve_scorer(cut_s)
                row = rd.run_one(data, frame, ch, config, cores, root, entry=entry, score=score)
                row.update(cut=name, cut_s=cut_s, what=what)
                if not row["ok"]:
                    row["cause"] = failure_cause(root / f"{ch}-{config}")
                rows.append(row)
                print(progress(row), file=sys.stderr, flush=True)
                if keep is None:
                    shutil.rmtree(root / f"{ch}-{config}", ignore_errors=True)
    finally:
        if keep is None:
            shutil.rmtree(root, ignore_errors=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--data", type=Path, default=None, help="FL_THERMAL data.xlsx (default: ../shared/data/fl-thermal/)"
    )
    parser.add_argument("--channels", default=",".join(rd.CHANNELS), help="comma-separated, e.g. ch3,ch5")
    parser.add_argument("--cuts", default=",".join(CUTS), help=f"names ({', '.join(CUTS)}) or seconds")
    parser.add_argument("--cores", "--jobs", type=int, default=2, help="passed to snakemake --cores")
    parser.add_argument("--keep", type=Path, default=None, help="keep the projects under this folder")
    args = parser.parse_args(argv)
    channels = [c.strip() for c in args.channels.split(",") if c.strip()]
    for c in channels:
        if c not in rd.CHANNELS:
            parser.error(f"unknown channel {c!r}; expected some of {', '.join(rd.CHANNELS)}")
    try:
        cuts = parse_cuts(args.cuts)
    except ValueError as exc:
        parser.error(str(exc))
    args.data = args.data or rd.default_data()
    if not args.data.is_file():
        parser.error(f"no workbook at {args.data} (--data PATH: FL_THERMAL's data/data.xlsx)")
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
    frame = rd.read_workbook(args.data)
    t_s = frame[rd.TIME_COL].to_numpy(dtype=float)
    temps = frame[[f"t{i}(°C)" for i in range(1, 17)]].to_numpy(dtype=float)
    ridge = {ch: rd.plain_ridge(temps, frame[f"{ch}(um)"].to_numpy(dtype=float), t_s) for ch in channels}
    t0 = time.perf_counter()
    rows = run_curve(args.data, frame, channels, cuts, args.cores, args.keep)
    report = {
        "date": dt.date.today().isoformat(),
        "command": " ".join(
            ["python benchmarks/bench_learning_curve.py", *(sys.argv[1:] if argv is None else argv)]
        ),
        "host": platform.node(),
        "cpus": os.cpu_count(),
        "wall_s": round(time.perf_counter() - t0, 1),
        "data": str(args.data),
        "channels": channels,
        "cuts": {name: {"cut_s": c, "what": w} for name, (c, w) in cuts.items()},
        "ridge": ridge,
        "runs": rows,
    }
    text = markdown(report)
    print(text)
    write_results("learning_curve", report, text, ensure_ascii=False)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
