"""Training on the runs since a change: the runs recorded before it are set aside.

The whole-run CV names the training runs no model explains (:mod:`rafi.family.unexplained`). When,
in the order the training runs were recorded, one change between two consecutive runs separates
those runs from the others (the named ones all before it, or all from it on), the machine was set
up otherwise from that change on (a fixture, the probe re-clamped, a heat source moved) and its
current state is that of the runs since. A compensation fitted across the change predicts the
state before it, so with ``models.since_change`` the runs before the change are set aside (role
``excluded``, the reason naming the change) and the family is fitted, cross-validated and chosen
on the runs from it on, the validation runs as before (``docs/models.md``, Training runs since a
change; ``docs/decisions.md``, 2026-11-30).

The separation allows exceptions (an unnamed run on the named side, a named run on the other), at
most :data:`MAX_EXCEPTION_SHARE` of the named runs; the change chosen is the one with the fewest,
the earliest of equals; at least :data:`MIN_RUNS_SINCE` runs must lie from it on, and the runs
since must cover every speed of the runs set aside (:func:`speeds_covered`: otherwise the runs may
disagree by speed, not by a change). Where the warning names no run nothing changes.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np
import pandas as pd

from rafi.family.unexplained import held_out_figures, unexplained_runs
from rafi.settings import truthy

__all__ = [
    "MAX_EXCEPTION_SHARE",
    "MIN_RUNS_SINCE",
    "CHANGE_COLUMNS",
    "Change",
    "change_of",
    "find_change",
    "recorded_order",
    "change_table",
    "change_text",
    "set_aside_before",
    "set_aside_count",
    "speeds_covered",
]

#: At most this share of the named runs may lie on the wrong side of the change.
MAX_EXCEPTION_SHARE = 0.5

#: The fewest training runs from the change on (three whole-run folds).
MIN_RUNS_SINCE = 3

#: The columns of ``comparison/since_change.csv`` (:func:`change_table`).
CHANGE_COLUMNS = (
    "run_id",
    "order",
    "none_max_um",
    "best_max_um",
    "best_model",
    "unexplained",
    "set_aside",
    "change_run",
    "named_side",
    "exceptions",
)


@dataclass(frozen=True)
class Change:
    """A change between two consecutive training runs (:func:`find_change`).

    Attributes
    ----------
    first_run : str
        The first training run from the change on.
    set_aside : tuple of str
        The training runs before it, in recorded order.
    named : tuple of str
        The runs no model explains (:func:`rafi.family.unexplained.unexplained_runs`).
    named_side : str
        ``"since"`` when the named runs lie from the change on, ``"before"`` when before it.
    exceptions : int
        Unnamed runs on the named side plus named runs on the other.
    """

    first_run: str
    set_aside: tuple[str, ...]
    named: tuple[str, ...]
    named_side: str
    exceptions: int

    @property
    def reason(self) -> str:
        """One line for ``role_reason`` and the log."""
        side = "from it on" if self.named_side == "since" else "before it"
        return (
            f"set aside: recorded before a change found at {self.first_run} (the training runs no model "
            f"explains, {len(self.named)}, lie {side}, with {self.exceptions} exception"
            f"{'' if self.exceptions == 1 else 's'}); the model is trained on the runs since"
        )


def natural_order(text: str) -> tuple:
    """A sort key that compares the numbers in ``text`` as numbers (``day2`` before ``day10``)."""
    return tuple((0, int(t), "") if t.isdigit() else (1, 0, t) for t in re.split(r"(\d+)", text) if t)


def recorded_order(runs_table: pd.DataFrame) -> list[str]:
    """The training runs' ids in the order they were recorded: by ``start_time`` (ISO text) where
    the logs have a clock, then by log name in natural order (``Sheet2`` before ``Sheet10``: logs
    without a clock are ordered by their names), then by start in the log (``start_s``)."""
    table = runs_table.loc[runs_table["role"].astype(str) == "training"]
    n = len(table)
    clock = ["" if pd.isna(c) else str(c) for c in table["start_time"]] if "start_time" in table else [""] * n
    logs = table["file"].astype(str).tolist() if "file" in table else [""] * n
    starts = (
        pd.to_numeric(table["start_s"], errors="coerce").fillna(0.0).tolist()
        if "start_s" in table
        else [0.0] * n
    )
    keys = sorted((c, natural_order(f), s, i) for i, (c, f, s) in enumerate(zip(clock, logs, starts)))
    runs = table["run_id"].astype(str).tolist()
    return [runs[k[-1]] for k in keys]


def find_change(order: list[str], named: set[str], *, min_since: int = MIN_RUNS_SINCE) -> Change | None:
    """The change that separates the ``named`` runs from the others in ``order``, or ``None``.

    Parameters
    ----------
    order : list of str
        The training runs in recorded order (:func:`recorded_order`).
    named : set of str
        The runs no model explains.
    min_since : int
        The fewest runs from the change on.

    Returns
    -------
    Change or None
        The change with the fewest exceptions (the earliest of equals; at each position the named
        runs after it first), if those are at most :data:`MAX_EXCEPTION_SHARE` of the named runs;
        ``None`` without named runs or without such a change.
    """
    named = set(named) & set(order)
    if not named:
        return None
    flags = [r in named for r in order]
    best: tuple[int, int, str] | None = None
    for cut in range(1, len(order) - min_since + 1):
        before, since = flags[:cut], flags[cut:]
        named_since = sum(before) + sum(not f for f in since)
        named_before = sum(not f for f in before) + sum(since)
        for exceptions, side in ((named_since, "since"), (named_before, "before")):
            if best is None or exceptions < best[0]:
                best = (exceptions, cut, side)
    if best is None or best[0] > MAX_EXCEPTION_SHARE * len(named):
        return None
    exceptions, cut, side = best
    return Change(
        first_run=order[cut],
        set_aside=tuple(order[:cut]),
        named=tuple(r for r in order if r in named),
        named_side=side,
        exceptions=int(exceptions),
    )


def speeds_covered(change: Change, runs_table: pd.DataFrame, *, tolerance_rpm: float) -> bool:
    """Whether every speed of the runs ``change`` sets aside has a training run since the change
    within ``tolerance_rpm`` (``speed_rpm`` of ``runs_table``). Where it has not, the runs that
    disagree may differ by their speed rather than by a change (a programme recorded in order of
    speed: the top speed held out is an extrapolation), so no change is taken."""
    training = runs_table.loc[runs_table["role"].astype(str) == "training"]
    speed = pd.to_numeric(training["speed_rpm"], errors="coerce")
    aside = training["run_id"].astype(str).isin(set(change.set_aside)).to_numpy()
    since = speed[~aside].to_numpy(dtype=float)
    since = since[np.isfinite(since)]
    before = speed[aside].to_numpy(dtype=float)
    return all(np.abs(since - s).min(initial=np.inf) <= tolerance_rpm for s in before[np.isfinite(before)])


def change_of(cv: pd.DataFrame | None, runs_table: pd.DataFrame, *, tolerance_rpm: float) -> Change | None:
    """:func:`find_change` on the runs of ``runs_table`` that the whole-run CV rows ``cv`` name
    (:func:`rafi.family.unexplained.unexplained_runs`), kept only where the runs since cover the
    speeds of the runs set aside (:func:`speeds_covered`, ``tolerance_rpm``: the machine's
    ``speed_tolerance_rpm``)."""
    named = set(unexplained_runs(cv)["run"].astype(str))
    change = find_change(recorded_order(runs_table), named) if named else None
    if change is None or not speeds_covered(change, runs_table, tolerance_rpm=tolerance_rpm):
        return None
    return change


def set_aside_before(runs_table: pd.DataFrame, change: Change) -> pd.DataFrame:
    """``runs_table`` with the runs of ``change.set_aside`` in role ``excluded``, their
    ``role_reason`` the change's (a copy; the raw logs and ``runs.csv`` are not touched)."""
    out = runs_table.copy()
    aside = out["run_id"].astype(str).isin(set(change.set_aside))
    out.loc[aside, "role"] = "excluded"
    if "role_reason" in out.columns:
        out["role_reason"] = out["role_reason"].astype(object)
        out.loc[aside, "role_reason"] = change.reason
    return out


def change_table(change: Change | None, cv: pd.DataFrame | None, runs_table: pd.DataFrame) -> pd.DataFrame:
    """``comparison/since_change.csv``: with a ``change``, every training run of ``runs_table`` in
    recorded order (:data:`CHANGE_COLUMNS`) with its figures in the whole-run CV ``cv`` that found
    the change (:func:`rafi.family.unexplained.held_out_figures`; NaN where it was not held out),
    whether no model explains it and whether it was set aside; empty with those columns without
    a change."""
    if change is None:
        return pd.DataFrame(columns=list(CHANGE_COLUMNS))
    figures = held_out_figures(cv).set_index("run")
    named, aside = set(change.named), set(change.set_aside)
    rows = []
    for k, run in enumerate(recorded_order(runs_table), start=1):
        has = run in figures.index
        rows.append(
            {
                "run_id": run,
                "order": k,
                "none_max_um": float(figures.loc[run, "none_max_um"]) if has else np.nan,
                "best_max_um": float(figures.loc[run, "best_max_um"]) if has else np.nan,
                "best_model": str(figures.loc[run, "best_model"]) if has else "",
                "unexplained": run in named,
                "set_aside": run in aside,
                "change_run": change.first_run,
                "named_side": change.named_side,
                "exceptions": change.exceptions,
            }
        )
    return pd.DataFrame(rows, columns=list(CHANGE_COLUMNS))


def change_text(table: pd.DataFrame | None) -> str | None:
    """One sentence for the log and the report from ``comparison/since_change.csv`` (``table``,
    :func:`change_table`); ``None`` when nothing was set aside."""
    if table is None or not len(table):
        return None
    aside = table.loc[table["set_aside"].map(truthy)]
    if not len(aside):
        return None
    first = table.iloc[0]
    side = "from it on" if str(first["named_side"]) == "since" else "before it"
    ids = [str(r) for r in aside["run_id"]]
    runs = ids[0] if len(ids) == 1 else f"{ids[0]} to {ids[-1]}"
    named, exceptions = int(table["unexplained"].map(truthy).sum()), int(first["exceptions"])
    return (
        f"{len(aside)} training runs recorded before a change found at {first['change_run']} were set "
        f"aside ({runs}): the {named} training runs no model explains lie {side}, "
        f"with {exceptions} exception{'' if exceptions == 1 else 's'}, so "
        "the machine's current state is that of the runs since, and the models were fitted, "
        "cross-validated and chosen on those (models.since_change)"
    )


def set_aside_count(table: pd.DataFrame | None) -> int:
    """How many training runs ``comparison/since_change.csv`` (``table``) says were set aside."""
    return 0 if table is None or not len(table) else int(table["set_aside"].map(truthy).sum())
