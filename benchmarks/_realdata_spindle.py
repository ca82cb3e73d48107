"""The 78 h spindle log of ``bench_realdata.py --spindle FILE``: one speed, sixteen temperatures.

**The data, never shipped.** ``data/thermal expansion error original.csv`` of the public
repository ruoheng-du/thermal-expansion-error-prediction, which states no licence: it is read
where the user keeps it (``--spindle FILE``) and nothing derived from its rows is written into
the repository (``bench_realdata.py`` refuses an ``--out-dir`` inside it). One header row, the
displacement :data:`DISPLACEMENT` (um) and the temperatures :data:`TEMPERATURES` (degC); 4682
rows one minute apart (the repository's report: a high-speed electric spindle at Shanghai Jiao
Tong University, T14 the worktable, T15 the room). No time column (rows :data:`PERIOD_S` apart, as
the report states) and no speed column: the speed is not stated, so the whole log is one constant
run at the nominal :data:`NOMINAL_RPM` (an assumption no model can notice: the speed never
changes). This is, by its sensors, length and no-compensation error, the "spindle, 16 sensors,
one speed, 78 h" log of issue 46's table.

**Two splits, fixed before any row was scored** (:data:`SPLITS`, the share of rows that train):
``publisher``, the first 90 % (the repository's own chronological split,
``lstm_keras/main.py``); ``heat-up``, the first third (the heat-up, 26 h), the plateau after it
the test, as the room warms by 1-2 K: issue 46 does not state its split, and no compensation
errs by 15.23 um on this one's test rows against the 15.2 of its table.

**The pipeline, configured, not coded** (:func:`machine_config`): what ``rafi init --machine
spindle-78h FILE --period-s 60`` proposes, with its CHECK lines answered (the constant speed,
the training speed) and what ``rafi init --preview`` warns of (a continuous log:
``reference: log_start``), the roles by a time window at the split. One training run: the
pipeline's CV holds out blocks of time (``docs/models.md``).

**The score** (:func:`scored_rows`): per test run and model, the error against the raw
displacement minus the pipeline's reference of the log (the median of ``raw - measured`` over
the scored rows of the first model: the reference wherever cleaning left a row alone; the largest
difference cleaning made is reported). **The independent plain ridge** (:func:`plain_ridge_split`):
``bench_realdata``'s (the rises from the first 300 s and their two low-pass filters, the penalty
by blocked CV on the training rows only), scored on the test rows. **Outside the training range**
(:func:`outside_range`): the test rows where some sensor lies beyond every training row.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

#: The machine's name (its folder under ``raw/``).
MACHINE = "spindle-78h"
#: The file's name in its repository (``data/``).
FILE = "thermal expansion error original.csv"
#: The displacement header (um).
DISPLACEMENT = "delta L"
#: The temperature headers (degC), in column order.
TEMPERATURES = tuple(f"T{i}" for i in range(16))
#: Seconds between two rows, as the repository's report states.
PERIOD_S = 60.0
#: The speed of the whole log: ASSUMED (no speed column, none stated).
NOMINAL_RPM = 6000
#: Split name -> the share of the rows (from the first) that train; the rest is the test.
SPLITS = {"publisher": 0.9, "heat-up": 1 / 3}


def present(path: Path | None) -> bool:
    """True when ``path`` is a file."""
    return path is not None and Path(path).is_file()


def read_log(path: Path) -> pd.DataFrame:
    """The log's displacement and temperatures, one row a minute.

    Raises
    ------
    ValueError
        A header of :data:`DISPLACEMENT` / :data:`TEMPERATURES` is missing, or a value is not a
        number (naming the column and the file's line).
    """
    frame = pd.read_csv(path, encoding="utf-8-sig")
    frame.columns = [str(c).strip() for c in frame.columns]
    wanted = [DISPLACEMENT, *TEMPERATURES]
    missing = [c for c in wanted if c not in frame.columns]
    if missing:
        raise ValueError(f"{path}: no column {missing}; expected the headers {wanted}")
    frame = frame[wanted]
    numbers = frame.apply(pd.to_numeric, errors="coerce")
    bad = numbers.isna() & frame.notna()
    if bad.to_numpy().any():
        row, col = np.argwhere(bad.to_numpy())[0]
        raise ValueError(
            f"{path}, line {row + 2}, column {wanted[col]!r}: {frame.iat[row, col]!r} is not a number"
        )
    return numbers


def split_row(n_rows: int, split: str) -> int:
    """The first test row of ``split`` (:data:`SPLITS`) in a log of ``n_rows`` rows."""
    return int(n_rows * SPLITS[split])


def machine_config(n_rows: int, split: str) -> dict:
    """The machine's ``config.yaml`` entry (module docstring): training until the first test
    row's time, validation from it."""
    end = int(split_row(n_rows, split) * PERIOD_S)
    return {
        "sample_period_s": int(PERIOD_S),
        "training_speeds_rpm": [NOMINAL_RPM],
        "reference": {"rule": "log_start", "window_s": int(PERIOD_S)},
        "runs": {
            "windows": [
                {"role": "training", "end": end, "unit": "elapsed_s"},
                {"role": "validation", "start": end, "unit": "elapsed_s"},
            ]
        },
        "input": {
            "format": "csv",
            "pattern": "*.csv",
            "header_row": 1,
            "columns": {name.lower(): name for name in TEMPERATURES},
            "time": {"kind": "none", "period_s": int(PERIOD_S)},
            "speed": {"constant_rpm": NOMINAL_RPM},
            "displacement": {"column": DISPLACEMENT, "unit": "um"},
            "temperature_unit": "C",
        },
    }


# ----------------------------------------------------------------------------- the score


def log_rows(residuals: pd.DataFrame, runs: pd.DataFrame) -> np.ndarray:
    """The 0-based row of the log of every residual row: its run's ``start_s`` plus its ``t_s``.

    Raises
    ------
    ValueError
        A time off the :data:`PERIOD_S` rows.
    """
    start = residuals["run_id"].astype(str).map(runs.set_index(runs["run_id"].astype(str))["start_s"])
    t_log = start.to_numpy(dtype=float) + residuals["t_s"].to_numpy(dtype=float)
    rows = np.rint(t_log / PERIOD_S)
    if not np.allclose(rows * PERIOD_S, t_log, atol=1e-6):
        raise ValueError(f"residual times are not on the {PERIOD_S:g} s rows of the log")
    return rows.astype(int)


def scored_rows(residuals: pd.DataFrame, runs: pd.DataFrame, disp: np.ndarray) -> tuple[pd.DataFrame, float]:
    """The validation residuals as scored rows (``_realdata_runs.SCORED``) against the raw
    displacement ``disp``, and the largest ``|raw - reference - measured|`` (what cleaning
    changed). The reference is the median of ``raw - measured_um`` over the first model's rows."""
    disp = np.asarray(disp, dtype=float)
    residuals = residuals.assign(run_id=residuals["run_id"].astype(str), model=residuals["model"].astype(str))
    first = residuals[residuals["model"] == residuals["model"].iloc[0]]
    ref = float(np.nanmedian(disp[log_rows(first, runs)] - first["measured_um"].to_numpy(dtype=float)))
    parts, worst = [], 0.0
    for model, part in residuals.groupby("model", sort=False):
        target = disp[log_rows(part, runs)] - ref
        worst = max(worst, float(np.nanmax(np.abs(target - part["measured_um"].to_numpy(dtype=float)))))
        frame = {"run_id": part["run_id"].to_numpy(), "model": model, "target_um": target}
        frame.update(
            {c: part[c].to_numpy(dtype=float) for c in ("predicted_um", "lower_um", "upper_um") if c in part}
        )
        parts.append(pd.DataFrame(frame))
    return pd.concat(parts, ignore_index=True), worst


def plain_ridge_split(frame: pd.DataFrame, split: str) -> dict:
    """The independent plain ridge (``bench_realdata.plain_ridge``'s features, penalty and fit)
    on the rows before the split, scored on the rest: ``alpha``, ``cv_rmse_um``,
    ``at_grid_edge``, ``test_mae_um``, ``test_max_um``."""
    from bench_realdata import plain_ridge

    t_s = np.arange(len(frame)) * PERIOD_S
    train = np.arange(len(frame)) < split_row(len(frame), split)
    disp = frame[DISPLACEMENT].to_numpy(dtype=float)
    return plain_ridge(frame[list(TEMPERATURES)].to_numpy(dtype=float), disp, t_s, train, ~train)


def outside_range(frame: pd.DataFrame, split: str) -> dict:
    """The test rows (``rows``), those where some sensor lies outside the range of every training
    row (``outside``) and those sensors (``sensors``)."""
    temps = frame[list(TEMPERATURES)].to_numpy(dtype=float)
    k = split_row(len(frame), split)
    lo, hi = temps[:k].min(axis=0), temps[:k].max(axis=0)
    beyond = (temps[k:] < lo) | (temps[k:] > hi)
    return {
        "rows": int(len(temps) - k),
        "outside": int(beyond.any(axis=1).sum()),
        "sensors": [name for name, hit in zip(TEMPERATURES, beyond.any(axis=0)) if hit],
    }


# ----------------------------------------------------------------------------- the run


def run(path: Path, split: str, cores: int, keep: Path | None, models: dict | None = None) -> dict:
    """Build, run and score the log's project for one split (module docstring); the temporary
    project goes unless ``keep`` (then ``keep/spindle-78h-<split>``). Returns the report's record."""
    import bench_realdata as rd

    frame = read_log(path)
    entry = machine_config(len(frame), split)
    if models is not None:
        entry["models"] = models
    title = f"78 h spindle (ruoheng-du/thermal-expansion-error-prediction), split '{split}'"
    disp = frame[DISPLACEMENT].to_numpy(dtype=float)
    out = {"split": split, "train_share": SPLITS[split], "first_test_row": split_row(len(frame), split)}
    record, _ = rd.scored_project(
        keep,
        f"{MACHINE}-{split}",
        MACHINE,
        {"log.csv": Path(path)},
        entry,
        cores,
        title,
        lambda residuals, runs: scored_rows(residuals, runs, disp),
    )
    out.update(record)
    if out["ok"]:
        out["plain_ridge"] = plain_ridge_split(frame, split)
        out["outside"] = outside_range(frame, split)
    return out


def markdown(report: dict) -> str:
    """The log's report (every split run) as markdown."""
    from _realdata_runs import fmt, per_run_markdown

    lines = [
        f"# Real-data benchmark, 78 h spindle ({report['date']})",
        "",
        f"Command: `{report['command']}`; host {report['host']}, {report['cpus']} CPUs.",
        "Data: ruoheng-du/thermal-expansion-error-prediction `data/thermal expansion error original.csv`",
        "(no licence: local judging only, never committed). Rows 60 s apart (the data's report);",
        f"ASSUMED: one constant run at a nominal {NOMINAL_RPM} r/min (no speed column). Reference: the",
        "log's first minute (log_start).",
    ]
    for r in report["spindle"]:
        lines += ["", f"## Split '{r['split']}': the first {r['train_share']:.0%} of the rows train"]
        lines += [f"(test from row {r['first_test_row']})", ""]
        if not r.get("ok"):
            lines += ["snakemake FAILED; its last lines:", "", "```", r["tail"], "```"]
            continue
        ridge = r["plain_ridge"]
        test_run = r["test_runs"][0] if len(r["test_runs"]) == 1 else "all"
        extra = {"plain ridge (independent)": {test_run: (ridge["test_mae_um"], ridge["test_max_um"])}}
        out = r["outside"]
        edge = ", AT THE GRID EDGE" if ridge["at_grid_edge"] else ""
        lines += [
            f"Offered: `{r['champion']}` ({r['selection']}).",
            f"Plain ridge (independent): alpha {ridge['alpha']:.3g} by blocked CV on the training rows "
            f"(CV RMSE {fmt(ridge['cv_rmse_um'])} um{edge}).",
            f"The family's plain ridge: {r['plain_ridge_run']}. Largest change cleaning made to a scored "
            f"displacement: {fmt(r['max_clean_diff_um'])} um. Test rows outside the training temperature "
            f"range: {out['outside']} of {out['rows']} ({', '.join(out['sensors']) or '-'}).",
            "",
            *per_run_markdown(pd.DataFrame(r["per_run"]), r["champion"], extra),
            "",
            *(f"- {k}: {v}" for k, v in r["selected"].items()),
            *(f"- warning {w}" for w in r["warnings"]),
        ]
    return "\n".join(lines) + "\n"
