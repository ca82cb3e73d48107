"""Training runs no model explains: held out by the whole-run CV, every model fitted on the other
training runs is worse there than no compensation.

The whole-run CV (``comparison/cv.csv``) holds out each training run in turn and fits every model
on the others. Where *every* model's max |residual| on a held-out run is above that run's own max
|displacement change| (``max_abs_before_um``: no compensation), the run does not behave like the
training runs it was predicted from: the machine was set up otherwise, a probe or a fixture moved,
a heat source no sensor sees was on, the season changed what the sensors do not measure. A model
fitted on runs that disagree may not hold on the next one, however it was chosen; the compare
step's log and the report name those runs with both figures, so the engineer looks at them before
signing. On the turning centre of issue 46 four of its twelve training days are such runs (its
second week reverses the daily drift of the first at the same temperature rises,
``docs/decisions.md``, 2026-11-29); on 40 foreign machines (production and varied plans) and
the shipped twins none.

It states what the CV measured and decides nothing: no model is left out and no gate changes.
Only the whole-run folds count (a forward fold predicts from fewer runs by design).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rafi.family.forward_folds import is_forward
from rafi.family.time_blocks import SCHEME as TIME_BLOCKS

#: The columns of :func:`unexplained_runs`.
COLUMNS = ("run", "none_max_um", "best_max_um", "best_model", "models")


#: The columns of ``comparison/cv.csv`` the rule reads.
NEEDED = ("model", "scheme", "test_runs", "max_abs_before_um", "max_abs_after_um")


def _whole_run_rows(cv: pd.DataFrame | None) -> pd.DataFrame | None:
    """The whole-run rows of ``cv`` (a copy; forward folds left out), ``None`` without the table
    or its columns (:data:`NEEDED`)."""
    if cv is None or not len(cv) or not set(NEEDED) <= set(cv.columns):
        return None
    return cv.loc[~cv["scheme"].map(is_forward)].copy()


def held_out_figures(cv: pd.DataFrame | None) -> pd.DataFrame:
    """Every held-out training run of the whole-run CV with the best model's figure there.

    Parameters
    ----------
    cv : pandas.DataFrame or None
        ``comparison/cv.csv`` (as :func:`unexplained_runs`).

    Returns
    -------
    pandas.DataFrame
        One row per held-out run in the CV's order (:data:`COLUMNS`): ``run``, ``none_max_um``
        (no compensation's max |displacement change|), ``best_max_um`` (the lowest max |residual|
        of any model fitted on the other runs), ``best_model`` (the first of equals) and
        ``models`` (how many were scored). Runs no model has a finite score on are left out.
    """
    empty = pd.DataFrame(columns=list(COLUMNS))
    rows = _whole_run_rows(cv)
    if rows is None:
        return empty
    rows["after"] = pd.to_numeric(rows["max_abs_after_um"], errors="coerce")
    rows["before"] = pd.to_numeric(rows["max_abs_before_um"], errors="coerce")
    rows = rows.loc[np.isfinite(rows["after"]) & np.isfinite(rows["before"])]
    out = []
    for run, g in rows.groupby(rows["test_runs"].astype(str), sort=False):
        best = g.loc[g["after"].idxmin()]
        out.append(
            {
                "run": run,
                "none_max_um": float(g["before"].iloc[0]),
                "best_max_um": float(best["after"]),
                "best_model": str(best["model"]),
                "models": int(g["model"].nunique()),
            }
        )
    return pd.DataFrame(out, columns=list(COLUMNS)) if out else empty


def unexplained_runs(cv: pd.DataFrame | None) -> pd.DataFrame:
    """The held-out training runs on which every model is worse than no compensation.

    Parameters
    ----------
    cv : pandas.DataFrame or None
        ``comparison/cv.csv``: ``model``, ``scheme``, ``test_runs`` (the held-out run or runs of
        the row), ``max_abs_before_um`` (no compensation) and ``max_abs_after_um`` (the model).
        Forward-fold rows are left out; a model without a finite score on a run (it predicted
        nothing there) does not count for that run.

    Returns
    -------
    pandas.DataFrame
        The rows of :func:`held_out_figures` whose ``best_max_um`` is above ``none_max_um``, in
        the CV's order (:data:`COLUMNS`); empty (with those columns) without the table or
        without such a run.
    """
    table = held_out_figures(cv)
    return table.loc[table["best_max_um"] > table["none_max_um"]].reset_index(drop=True)


def unexplained_text(cv: pd.DataFrame | None) -> str | None:
    """One sentence for the log and the report: how many of the training runs held out by the
    whole-run CV of ``cv`` (time blocks, for a single run's log) no model explains
    (:func:`unexplained_runs`), each with the best model's max |residual| and no compensation's
    (um); ``None`` when there is none."""
    table = unexplained_runs(cv)
    if not len(table):
        return None
    rows = _whole_run_rows(cv)
    held_out = rows["test_runs"].astype(str).nunique()
    units = "time blocks of the training data" if (rows["scheme"] == TIME_BLOCKS).all() else "training runs"
    each = "; ".join(
        f"{r.run} {r.best_model} {r.best_max_um:.2f} against {r.none_max_um:.2f} um"
        for r in table.itertuples()
    )
    return (
        f"On {len(table)} of {held_out} {units} held out by the cross-validation every model fitted on "
        "the others was worse than no compensation (the best model's max |residual| "
        f"against the run's own max |displacement change|: {each}): those runs do not behave "
        "like the others (a changed setup, a moved probe or fixture, a heat source no sensor sees?), "
        "and a model fitted on runs that disagree may not hold on the next."
    )
