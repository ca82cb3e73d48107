"""Forward-in-time folds of the training runs: the selection's second opinion on drift.

The whole-run CV (:mod:`rafi.family.crossval`) holds out a training run that lies *between*
other training runs; a deployed model predicts what comes *after* all of them. On a continuous
log, forward folds ask that question on the training runs alone (a "rolling origin"): for every
origin with at least :data:`MIN_TRAIN` training runs of the log before it and ``horizon`` after,
the fold trains on the log's runs before the origin and holds out the next ``horizon`` runs; the
log's later training runs are guard runs of the fold (neither fitted nor scored).

Only runs inside **one log** (the runs table's ``file``) have a time order that means drift:
runs of separate files (cold starts, other days) give no forward fold, and a data set without a
log of ``MIN_TRAIN + horizon`` training runs is judged by the whole-run CV alone.

Why at least three runs before an origin: on the real log FL_THERMAL (the forward-folds study,
``docs/decisions.md``, 2026-11-26) one or two training runs train nothing sane (the penalty at
the lower grid edge, predictions of 20-400 um), which would score the kinds on a situation no
deployment is in.
"""

from __future__ import annotations

import re
from collections.abc import Iterator

import numpy as np
import pandas as pd

__all__ = [
    "MIN_TRAIN",
    "PREFIX",
    "scheme_name",
    "configured_scheme",
    "horizon_of",
    "is_forward",
    "fold_unit",
    "unit_run",
    "forward_folds",
    "forward_logs",
]

#: Fewest training runs of a log before a forward fold's origin.
MIN_TRAIN = 3
#: Scheme names of forward folds are ``forward_<horizon>`` (``comparison/cv.csv``).
PREFIX = "forward_"


def scheme_name(horizon: int) -> str:
    """The ``scheme`` of forward folds holding out ``horizon`` runs (``forward_2``)."""
    return f"{PREFIX}{int(horizon)}"


def configured_scheme(options: dict) -> str | None:
    """The forward scheme of a machine's ``models:`` settings (``cv_forward_runs``; 0: none)."""
    horizon = int(options["cv_forward_runs"])
    return scheme_name(horizon) if horizon > 0 else None


def is_forward(scheme) -> bool:
    """True for a forward scheme name (:func:`scheme_name`)."""
    return str(scheme).startswith(PREFIX) and str(scheme)[len(PREFIX) :].isdigit()


#: A forward fold's out-of-fold unit: ``f<fold>:<run>`` (:func:`fold_unit`).
_FOLD_UNIT = re.compile(r"^f\d+:")


def fold_unit(fold: int, unit: str) -> str:
    """The out-of-fold unit of held-out run ``unit`` in forward fold ``fold``: a run is held out by
    several forward folds, and each (fold, run) is one calibration unit."""
    return f"f{int(fold)}:{unit}"


def unit_run(units) -> np.ndarray:
    """The held-out run (or time block) of each out-of-fold unit: the unit without its forward-fold
    prefix (:func:`fold_unit`), so a run's whole-run unit and its forward units share one name."""
    return np.array([_FOLD_UNIT.sub("", str(u), count=1) for u in np.asarray(units).ravel()], dtype=object)


def horizon_of(scheme: str) -> int:
    """The horizon of a forward scheme name (``forward_2`` -> 2)."""
    if not is_forward(scheme):
        raise ValueError(f"{scheme!r} is not a forward scheme ({PREFIX}<runs>)")
    return int(str(scheme)[len(PREFIX) :])


def _training_in_time_order(runs_table: pd.DataFrame) -> pd.DataFrame:
    """The training runs by log and start; none for a table without ``file`` and ``start_s``
    (runs with no log and start have no time order, e.g. a hand-made table)."""
    if not {"file", "start_s"} <= set(runs_table.columns):
        return pd.DataFrame(columns=["run_id", "file", "start_s"])
    t = runs_table.loc[runs_table["role"].astype(str) == "training", ["run_id", "file", "start_s"]]
    t = t.assign(run_id=t["run_id"].astype(str), file=t["file"].astype(str))
    return t.sort_values(["file", "start_s", "run_id"], kind="stable")


def forward_folds(
    runs_table: pd.DataFrame, horizon: int = 2, min_train: int = MIN_TRAIN
) -> Iterator[tuple[list[str], list[str]]]:
    """Forward-in-time folds of the training runs, inside each log.

    Per log (``file``), the training runs in time order (``start_s``, then ``run_id``); for every
    origin ``k >= min_train`` with ``horizon`` runs after it, the fold trains on the log's first
    ``k`` training runs and holds out the next ``horizon``.

    Parameters
    ----------
    runs_table : pandas.DataFrame
        Runs table with ``run_id``, ``role``, ``file`` and ``start_s`` (without the last two:
        no fold).
    horizon : int
        Held-out runs per fold (1: the next run; 2: the next two).
    min_train : int
        Fewest training runs before the origin.

    Yields
    ------
    tuple of (list of str, list of str)
        ``(train_run_ids, test_run_ids)``, logs in name order, origins in time order.
    """
    if int(horizon) < 1:
        raise ValueError(f"horizon must be at least 1 run, got {horizon!r}")
    for _, log in _training_in_time_order(runs_table).groupby("file", sort=True):
        ids = list(log["run_id"])
        for k in range(int(min_train), len(ids) - int(horizon) + 1):
            train, test = ids[:k], ids[k : k + int(horizon)]
            if set(train) & set(test) or not train or not test:
                raise AssertionError(f"bad forward fold: train={train} test={test}")
            yield train, test


def forward_logs(runs_table: pd.DataFrame, horizon: int, min_train: int = MIN_TRAIN) -> dict:
    """Per log: its training runs and how many forward folds it gives at ``horizon``."""
    t = _training_in_time_order(runs_table)
    counts = t.groupby("file", sort=True).size()
    return {
        log: {"training_runs": int(n), "folds": max(0, int(n) - int(min_train) - int(horizon) + 1)}
        for log, n in counts.items()
    }
