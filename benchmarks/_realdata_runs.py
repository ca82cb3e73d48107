"""Per test run scores of a real log, and their tables (``bench_realdata.py``).

A real log's bench hands over its **scored rows**: one row per model and test sample, columns
``run_id``, ``model``, ``target_um`` (what the probe measured, from the pipeline's reference of
that run), ``predicted_um`` and, where the model has one, its 90 % interval ``lower_um`` /
``upper_um``. :func:`per_run` turns them into one line per test run and model: rows, test MAE,
largest error, the interval's coverage and mean width; the pseudo model ``none`` (no
compensation: the error is the target itself) and the pooled line ``all`` (every test row of the
log) are added. :func:`per_run_markdown` writes the two tables of one log, and below them
:func:`chance_sentence`: how much of issue 46's coverage promise chance decides on so few test
runs. Nothing here reads a file: the tests feed generated rows.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from _coverage import NAMED_LOG_BAND, UNSEEN_LOG_BAND, band_chance, band_text

#: The pseudo model "no compensation" and the pooled line of every test run.
NONE = "none"
ALL = "all"
#: Columns of :func:`per_run`.
COLUMNS = ["run_id", "model", "rows", "mae_um", "max_um", "coverage", "width_um"]
#: Columns of the scored rows.
SCORED = ["run_id", "model", "target_um", "predicted_um", "lower_um", "upper_um"]


def _line(run_id: str, model: str, err: np.ndarray, lo=None, hi=None, target=None) -> dict:
    """One line of :func:`per_run`: MAE and max of ``|err|``; the interval's coverage of
    ``target`` and mean width over the rows where both bounds are finite (NaN without any)."""
    err = np.abs(np.asarray(err, dtype=float))
    line = {"run_id": run_id, "model": model, "rows": int(len(err))}
    line["mae_um"] = float(err.mean()) if len(err) else float("nan")
    line["max_um"] = float(err.max()) if len(err) else float("nan")
    line["coverage"] = line["width_um"] = float("nan")
    if lo is not None:
        ok = np.isfinite(lo) & np.isfinite(hi) & np.isfinite(target)
        if ok.any():
            line["coverage"] = float(np.mean((target[ok] >= lo[ok]) & (target[ok] <= hi[ok])))
            line["width_um"] = float(np.mean(hi[ok] - lo[ok]))
    return line


def per_run(scored: pd.DataFrame) -> pd.DataFrame:
    """Test MAE, max, coverage and mean width per test run and model (:data:`COLUMNS`).

    Parameters
    ----------
    scored : pandas.DataFrame
        The scored rows (:data:`SCORED`; ``lower_um`` / ``upper_um`` may be missing or NaN).

    Returns
    -------
    pandas.DataFrame
        One line per run (in order of appearance, then :data:`ALL`) and model (the models in
        order of appearance, then :data:`NONE`, whose error is the target: no compensation).

    Raises
    ------
    ValueError
        The models do not score the same number of rows of a run (the no-compensation line
        would be ambiguous).
    """
    scored = scored.copy()
    for col in ("lower_um", "upper_um"):
        if col not in scored:
            scored[col] = np.nan
    runs = list(dict.fromkeys(scored["run_id"].astype(str)))
    models = list(dict.fromkeys(scored["model"].astype(str)))
    lines = []
    for run_id in [*runs, ALL]:
        part = scored if run_id == ALL else scored[scored["run_id"].astype(str) == run_id]
        counts = part.groupby(part["model"].astype(str)).size()
        if counts.nunique() > 1:
            raise ValueError(f"run {run_id}: the models score different rows ({counts.to_dict()})")
        for model in models:
            rows = part[part["model"].astype(str) == model]
            target = rows["target_um"].to_numpy(dtype=float)
            lo, hi = (rows[c].to_numpy(dtype=float) for c in ("lower_um", "upper_um"))
            lines.append(
                _line(run_id, model, target - rows["predicted_um"].to_numpy(dtype=float), lo, hi, target)
            )
        first = part[part["model"].astype(str) == models[0]]
        lines.append(_line(run_id, NONE, first["target_um"].to_numpy(dtype=float)))
    return pd.DataFrame(lines, columns=COLUMNS)


def fmt(x) -> str:
    """Two decimals, or a dash."""
    return "-" if x is None or not np.isfinite(x) else f"{x:.2f}"


def pct(x) -> str:
    """A share as a percentage with one decimal, or a dash."""
    return "-" if x is None or not np.isfinite(x) else f"{x:.1%}"


def per_run_markdown(table: pd.DataFrame, offered: str, extra: dict | None = None) -> list[str]:
    """The two tables of one log: ``MAE / max`` per run (the offered model first, then every
    model, ``none`` last) and the 90 % interval's ``coverage / mean width`` per run and model.

    Parameters
    ----------
    table : pandas.DataFrame
        :func:`per_run`'s lines.
    offered : str
        The model the pipeline offered (its column is marked).
    extra : dict, optional
        Model -> ``{run_id: (mae, max)}`` of references outside the pipeline (an independent
        plain ridge), shown after the pipeline's models.
    """
    models = [m for m in dict.fromkeys(table["model"]) if m != NONE]
    models = [offered, *[m for m in models if m != offered]] if offered in models else models
    runs = list(dict.fromkeys(table["run_id"]))
    cell = {(r.run_id, r.model): r for r in table.itertuples()}
    extra = extra or {}
    head = [
        "test run",
        "rows",
        *(f"{m} (offered)" if m == offered else m for m in models),
        *extra,
        "no compensation",
    ]
    lines = [f"| {' | '.join(head)} |", "|" + "---|" * len(head)]
    for run in runs:
        first = cell[(run, NONE)]
        cells = [run, str(first.rows)]
        cells += [f"{fmt(cell[(run, m)].mae_um)} / {fmt(cell[(run, m)].max_um)}" for m in models]
        cells += [" / ".join(fmt(v) for v in extra[name].get(run, (np.nan, np.nan))) for name in extra]
        cells += [f"{fmt(first.mae_um)} / {fmt(first.max_um)}"]
        lines.append(f"| {' | '.join(cells)} |")
    head = ["test run", *(f"{m} (offered)" if m == offered else m for m in models)]
    lines += ["", "90 % interval: coverage / mean width (um)", ""]
    lines += [f"| {' | '.join(head)} |", "|" + "---|" * len(head)]
    for run in runs:
        cells = [run] + [f"{pct(cell[(run, m)].coverage)} / {fmt(cell[(run, m)].width_um)}" for m in models]
        lines.append(f"| {' | '.join(cells)} |")
    chance = chance_sentence(table, offered)
    return lines + ["", chance] if chance else lines


def chance_sentence(table: pd.DataFrame, offered: str) -> str | None:
    """How much of the offered model's coverage promise chance decides on these test runs: the
    spread of its coverage over the runs and the chance that a perfectly calibrated interval
    varying as much covers a share within issue 46's bands (:func:`band_chance`). None with fewer
    than two runs with a coverage."""
    rows = table.loc[(table["model"] == offered) & (table["run_id"] != ALL)]
    cov = rows["coverage"].astype(float).dropna()
    if len(cov) < 2:
        return None
    named, unseen = band_chance(cov, NAMED_LOG_BAND), band_chance(cov, UNSEEN_LOG_BAND)
    named_band, unseen_band = (band_text(b) for b in (NAMED_LOG_BAND, UNSEEN_LOG_BAND))
    return (
        f"The offered model's interval covers {pct(cov.min())} to {pct(cov.max())} of a test run's "
        f"rows (spread {100 * cov.std(ddof=1):.1f} points over {len(cov)} runs): a perfectly "
        f"calibrated interval varying as much from run to run would cover {named_band} of the test "
        f"rows with a chance of {named:.2f} ({unseen_band}: {unseen:.2f})."
    )
