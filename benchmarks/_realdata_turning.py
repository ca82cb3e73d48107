"""The turning centre of ``bench_realdata.py --turning DIR``: 18 daily tests, six temperatures.

**The data, never shipped.** ``code/Datasets/ACE_X.xlsx`` and ``ACE_Y.xlsx`` of the public
repository srivathsan902/Thermal_Compensation_Webpage, which states no licence: they are read
where the user keeps them (``--turning DIR``, a folder holding both) and nothing derived from
their rows is written into the repository (``bench_realdata.py`` refuses an ``--out-dir`` inside
it). ``ACE_X.xlsx`` holds per sheet the temperatures :data:`TEMPERATURES` under a header row,
``ACE_Y.xlsx`` the same sheets with the one column :data:`DISPLACEMENT`; sheet k (workbook order)
is test day k. Neither holds a time or a speed column and no period is stated: the rows are
taken :data:`PERIOD_S` apart (an assumption) and every day one constant run at the nominal
:data:`NOMINAL_RPM` (no model can read a speed that never changes).

**The pipeline, configured, not coded** (:func:`machine_config`, as ``docs/raw-format.md``
tells a user and as ``rafi init`` proposes it): a sheet pattern (every sheet a log), the two
workbooks joined row by row (``input.join``), the six sensors under their own names, no clock.
The protocol is fixed by issue 46: days 1-:data:`TRAIN_DAYS` train (the pipeline's whole-run CV
chooses inside them), the other days validate and are the test, read once per design; the
reference is each day's own start (``run_start``, the default: the machine cold in the morning).

**The score** (:func:`scored_rows`): per test day and model, the error against the raw
displacement minus the pipeline's reference of that run (the median of ``raw - measured`` over
the run's rows, which is the reference wherever cleaning left a row alone; the largest
difference cleaning made is reported). **The independent plain ridge** (:func:`plain_ridge_days`):
the day's temperature rises from its first row and two low-pass filters of them
(``bench_realdata.RIDGE_TAUS_S``), target the displacement from the day's first row, penalty by
leave-one-day-out CV on the training days only. **Outside the training range**
(:func:`outside_range`): per test day, the rows where a sensor's temperature (and, separately,
its rise from the day's first row) lies outside the range of every training row.
"""

from __future__ import annotations

import glob
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

#: The machine's name (its folder under ``raw/``).
MACHINE = "turning-centre"
#: The two workbooks: temperatures, displacement.
FILES = ("ACE_X.xlsx", "ACE_Y.xlsx")
#: The temperature headers of ``ACE_X.xlsx``, in column order.
TEMPERATURES = ("Ambient", "Ref Temp on Bed", "Spindle Rear", "Coolantwall", "Transfomerbed", "Spindle Front")
#: The displacement header of ``ACE_Y.xlsx``.
DISPLACEMENT = "Dia Disp"
#: Seconds between two rows: ASSUMED, the data states none.
PERIOD_S = 60.0
#: The speed of every day: ASSUMED (no speed column); one constant run per day.
NOMINAL_RPM = 1000
#: Days 1..TRAIN_DAYS train; the rest are the test (issue 46's protocol).
TRAIN_DAYS = 12
#: Days in the workbooks.
DAYS = 18


@dataclass(frozen=True)
class Day:
    """One test day: its sheet's name, temperatures (rows x :data:`TEMPERATURES`), displacement."""

    name: str
    temps: np.ndarray
    disp: np.ndarray

    @property
    def t_s(self) -> np.ndarray:
        return np.arange(len(self.disp)) * PERIOD_S


def present(folder: Path | None) -> bool:
    """True when ``folder`` holds both workbooks of :data:`FILES`."""
    return folder is not None and all((Path(folder) / name).is_file() for name in FILES)


def sensor_names() -> dict[str, str]:
    """Sensor name -> header: the header as a lower-case slug (``Ref Temp on Bed`` -> ``ref_temp_on_bed``)."""
    return {re.sub(r"[^a-z0-9]+", "_", h.lower()).strip("_"): h for h in TEMPERATURES}


def roles(sheets: list[str]) -> dict[str, str]:
    """Sheet -> ``training`` (the first :data:`TRAIN_DAYS`) or ``validation`` (the test days)."""
    return {s: "training" if k < TRAIN_DAYS else "validation" for k, s in enumerate(sheets)}


def machine_config(sheets: list[str]) -> dict:
    """The machine's ``config.yaml`` entry: the layout (module docstring) and one window per
    sheet giving its day's role (``runs.windows[].log``: the sheet's name, as a glob matching
    only itself)."""
    return {
        "sample_period_s": int(PERIOD_S),
        "training_speeds_rpm": [NOMINAL_RPM],
        "input": {
            "format": "xlsx",
            "pattern": "*X*.xlsx",
            "sheet": "*",
            "header_row": 1,
            "columns": sensor_names(),
            "time": {"kind": "none", "period_s": int(PERIOD_S)},
            "speed": {"constant_rpm": NOMINAL_RPM},
            "displacement": {"column": DISPLACEMENT, "unit": "um"},
            "join": {"replace": ["X", "Y"], "by": "row"},
        },
        "runs": {"windows": [{"role": role, "log": glob.escape(s)} for s, role in roles(sheets).items()]},
    }


def read_days(folder: Path) -> list[Day]:
    """Every sheet of the two workbooks, in workbook order (day 1 first).

    Raises
    ------
    ValueError
        Not :data:`DAYS` sheets, the sheets of the two workbooks differ, a header is missing,
        or a day's two sheets hold different numbers of rows.
    """
    xs = pd.read_excel(Path(folder) / FILES[0], sheet_name=None)
    ys = pd.read_excel(Path(folder) / FILES[1], sheet_name=None)
    if list(xs) != list(ys) or len(xs) != DAYS:
        raise ValueError(f"{FILES}: expected the same {DAYS} sheets in both, got {list(xs)} and {list(ys)}")
    days = []
    for name in xs:
        x, y = (f.rename(columns=lambda c: str(c).strip()).dropna(how="all") for f in (xs[name], ys[name]))
        missing = [h for h in (*TEMPERATURES, DISPLACEMENT) if h not in (*x.columns, *y.columns)]
        if missing or len(x) != len(y):
            raise ValueError(f"sheet {name!r}: missing {missing} or {len(x)} != {len(y)} rows")
        days.append(Day(name, x[list(TEMPERATURES)].to_numpy(float), y[DISPLACEMENT].to_numpy(float)))
    return days


def split(days: list[Day]) -> tuple[list[Day], list[Day]]:
    """``(training days, test days)``."""
    return days[:TRAIN_DAYS], days[TRAIN_DAYS:]


# ----------------------------------------------------------------------------- the score


def scored_rows(residuals: pd.DataFrame, runs: pd.DataFrame, days: list[Day]) -> tuple[pd.DataFrame, float]:
    """The pipeline's validation residuals as scored rows (``_realdata_runs.SCORED``) and the
    largest ``|raw - reference - measured|`` (what cleaning changed), against the raw workbook.

    Each residual row is mapped to its day (``runs.csv``'s ``file``: the sheet-log's name) and
    its row ``(start_s + t_s) / PERIOD_S``; the run's reference is the median of ``raw -
    measured_um`` over its rows (of the first model).
    """
    by_name = {d.name: d for d in days}
    info = runs.assign(run_id=runs["run_id"].astype(str)).set_index("run_id")
    residuals = residuals.assign(run_id=residuals["run_id"].astype(str), model=residuals["model"].astype(str))

    def raw_of(run_id: str, part: pd.DataFrame) -> np.ndarray:
        day = by_name[str(info.loc[run_id, "file"])]
        t = float(info.loc[run_id, "start_s"]) + part["t_s"].to_numpy(dtype=float)
        rows = np.rint(t / PERIOD_S).astype(int)
        if not np.allclose(rows * PERIOD_S, t) or rows.min() < 0 or rows.max() >= len(day.disp):
            raise ValueError(f"{run_id}: residual times off the {PERIOD_S:g} s rows of sheet {day.name!r}")
        return day.disp[rows]

    first = residuals[residuals["model"] == residuals["model"].iloc[0]]
    refs = {
        run_id: float(np.nanmedian(raw_of(run_id, part) - part["measured_um"].to_numpy(dtype=float)))
        for run_id, part in first.groupby("run_id", sort=False)
    }
    parts, worst = [], 0.0
    for (run_id, model), part in residuals.groupby(["run_id", "model"], sort=False):
        measured = part["measured_um"].to_numpy(dtype=float)
        target = raw_of(run_id, part) - refs[run_id]
        worst = max(worst, float(np.nanmax(np.abs(target - measured))))
        frame = {"run_id": run_id, "model": model, "target_um": target}
        frame.update(
            {c: part[c].to_numpy(dtype=float) for c in ("predicted_um", "lower_um", "upper_um") if c in part}
        )
        parts.append(pd.DataFrame(frame))
    return pd.concat(parts, ignore_index=True), worst


def _features(day: Day, taus: tuple) -> np.ndarray:
    from bench_realdata import lowpass

    rises = day.temps - day.temps[0]
    return np.hstack([rises, *(lowpass(rises, day.t_s, tau) for tau in taus)])


def plain_ridge_days(days: list[Day]) -> dict:
    """The independent plain ridge (module docstring): ``alpha``, ``cv_rmse_um``,
    ``at_grid_edge`` and ``test`` (sheet -> ``(MAE, max)`` in um, the target the displacement
    from the day's first row)."""
    from bench_realdata import RIDGE_ALPHAS, RIDGE_TAUS_S, ridge_fit, ridge_predict

    train, test = split(days)
    xs = [_features(d, RIDGE_TAUS_S) for d in days]
    ys = [d.disp - d.disp[0] for d in days]
    n = len(train)
    sq, count = np.zeros(len(RIDGE_ALPHAS)), 0
    for held in range(n):
        fit = [k for k in range(n) if k != held]
        model = ridge_fit(np.vstack([xs[k] for k in fit]), np.concatenate([ys[k] for k in fit]), RIDGE_ALPHAS)
        sq += np.sum((ridge_predict(model, xs[held]) - ys[held][:, None]) ** 2, axis=0)
        count += len(ys[held])
    best = int(np.argmin(sq))
    alpha = np.array([RIDGE_ALPHAS[best]])
    model = ridge_fit(np.vstack(xs[:n]), np.concatenate(ys[:n]), alpha)
    scores = {}
    for k, day in enumerate(test, start=n):
        err = np.abs(ys[k] - ridge_predict(model, xs[k])[:, 0])
        scores[day.name] = (float(err.mean()), float(err.max()))
    every = np.concatenate([ys[k] - ridge_predict(model, xs[k])[:, 0] for k in range(n, len(days))])
    scores["all"] = (float(np.mean(np.abs(every))), float(np.max(np.abs(every))))
    return {
        "alpha": float(alpha[0]),
        "cv_rmse_um": float(np.sqrt(sq[best] / count)),
        "at_grid_edge": best in (0, len(RIDGE_ALPHAS) - 1),
        "test": scores,
    }


def outside_range(days: list[Day]) -> list[dict]:
    """Per test day: its rows, the rows where some sensor's temperature lies outside the range of
    every training row (``outside``, with the sensors: ``sensors``) and the same for the rises
    from the day's first row (``outside_rise``)."""
    train, test = split(days)
    temps = np.vstack([d.temps for d in train])
    rises = np.vstack([d.temps - d.temps[0] for d in train])
    lo, hi = temps.min(axis=0), temps.max(axis=0)
    rlo, rhi = rises.min(axis=0), rises.max(axis=0)
    out = []
    for day in test:
        beyond = (day.temps < lo) | (day.temps > hi)
        rise = day.temps - day.temps[0]
        out.append(
            {
                "day": day.name,
                "rows": int(len(day.disp)),
                "outside": int(beyond.any(axis=1).sum()),
                "sensors": [h for h, hit in zip(TEMPERATURES, beyond.any(axis=0)) if hit],
                "outside_rise": int(((rise < rlo) | (rise > rhi)).any(axis=1).sum()),
            }
        )
    return out


def outside_markdown(rows: list[dict]) -> list[str]:
    """The table of :func:`outside_range`, and the totals."""
    lines = ["| test day | rows | outside (temperature) | sensors | outside (rise from the day's start) |"]
    lines.append("|---|---|---|---|---|")
    for r in rows:
        share = r["outside"] / r["rows"]
        rise = r["outside_rise"] / r["rows"]
        sensors = ", ".join(r["sensors"]) or "-"
        lines.append(
            f"| {r['day']} | {r['rows']} | {r['outside']} ({share:.0%}) | {sensors} | "
            f"{r['outside_rise']} ({rise:.0%}) |"
        )
    total = sum(r["rows"] for r in rows)
    out = sum(r["outside"] for r in rows)
    days = sum(r["outside"] > 0 for r in rows)
    lines.append(f"| all | {total} | {out} ({out / max(total, 1):.0%}); {days} of {len(rows)} days | | |")
    return lines


# ----------------------------------------------------------------------------- the run


def pipeline_outside(residuals: pd.DataFrame, model: str) -> dict:
    """Per test run, the share of ``model``'s residual rows the pipeline flags
    ``outside_temp_range`` (its own envelope test; NaN without the column)."""
    part = residuals[residuals["model"].astype(str) == model]
    if "outside_temp_range" not in part:
        return {}
    return {
        str(k): float(v)
        for k, v in part.groupby(part["run_id"].astype(str))["outside_temp_range"].mean().items()
    }


def run(folder: Path, cores: int, keep: Path | None, models: dict | None = None) -> dict:
    """Build, run and score the turning centre's project (module docstring); the temporary
    project goes unless ``keep`` (then ``keep/turning-centre``). Returns the report's record."""
    import bench_realdata as rd

    days = read_days(folder)
    entry = machine_config([d.name for d in days])
    if models is not None:
        entry["models"] = models
    title = "turning centre (srivathsan902/Thermal_Compensation_Webpage), days 1-12 train, 13-18 test"
    out = {"period_s_assumed": PERIOD_S, "rpm_assumed": NOMINAL_RPM}
    record, residuals = rd.scored_project(
        keep,
        MACHINE,
        MACHINE,
        {name: Path(folder) / name for name in FILES},
        entry,
        cores,
        title,
        lambda residuals, runs: scored_rows(residuals, runs, days),
    )
    out.update(record)
    if not out["ok"]:
        return out
    out["pipeline_outside"] = pipeline_outside(residuals, out["champion"])
    out["plain_ridge"] = plain_ridge_days(days)
    out["outside"] = outside_range(days)
    return out


def markdown(report: dict) -> str:
    """The turning centre's report as markdown."""
    from _realdata_runs import fmt, per_run_markdown

    r = report["turning"]
    lines = [
        f"# Real-data benchmark, turning centre ({report['date']})",
        "",
        f"Command: `{report['command']}`; host {report['host']}, {report['cpus']} CPUs.",
        "Data: srivathsan902/Thermal_Compensation_Webpage `code/Datasets/ACE_X.xlsx` + `ACE_Y.xlsx`",
        "(no licence: local judging only, never committed). Days 1-12 train (whole-run CV inside them),",
        "13-18 test.",
        f"ASSUMED: rows {PERIOD_S:g} s apart (no time column, no stated period); one constant run per day",
        f"at a nominal {NOMINAL_RPM} r/min (no speed column). Reference: each day's own start (run_start).",
    ]
    if not r.get("ok"):
        return (
            "\n".join([*lines, "", "snakemake FAILED; its last lines:", "", "```", r["tail"], "```"]) + "\n"
        )
    table = pd.DataFrame(r["per_run"])
    ridge = r["plain_ridge"]
    extra = {"plain ridge (independent)": ridge["test"]}
    lines += [
        "",
        f"Offered: `{r['champion']}` ({r['selection']}).",
        f"Plain ridge (independent): alpha {ridge['alpha']:.3g} by leave-one-day-out CV on days 1-12 "
        f"(CV RMSE {fmt(ridge['cv_rmse_um'])} um{', AT THE GRID EDGE' if ridge['at_grid_edge'] else ''}).",
        f"The family's plain ridge: {r['plain_ridge_run']}. Largest change cleaning made to a scored "
        f"displacement: {fmt(r['max_clean_diff_um'])} um.",
        "",
        "## Test MAE / max, um, per test day (the pipeline's reference of the day)",
        "",
        *per_run_markdown(table, r["champion"], extra),
        "",
        "## Test rows outside the training temperature range (days 1-12, every sensor)",
        "",
        *outside_markdown(r["outside"]),
        "",
        "The pipeline's own envelope flag (`outside_temp_range`, offered model's rows): "
        + ", ".join(f"{k} {v:.0%}" for k, v in r["pipeline_outside"].items()),
        "",
        "## Selection, warnings",
        "",
        *(f"- {k}: {v}" for k, v in r["selected"].items()),
        *(f"- warning {w}" for w in r["warnings"]),
    ]
    return "\n".join(lines) + "\n"
