"""Features of whole logs computed once and shared by every fit of one model kind.

The nested whole-run cross-validation fits a ridge kind once per outer fold, and each fit
evaluates its filtered features over the whole logs holding its training runs, then predicts
the held-out run's log; the final fit does the same on every training log. A log's features
depend on that log alone, to the last bit (:func:`rafi.family.whole_log.lowpass_log` restarts
its block sums at each log, reference windows and speed references are per run or per log
segment), so they are computed once on the *universe* - every log holding a training run - and
each fit takes its rows from there (:meth:`FeatureMemo.universe_features`). The per-run Gram matrices of
the CV are shared the same way (:meth:`FeatureMemo.run_gram`).

The memo is active only inside :func:`sharing_features` (``rule compare``: one scope per model
kind, around its fit and its cross-validation); without it every fit computes its own features
as before. A frame that is not made of whole logs of the universe with the same values (a
per-run frame, another frame, part of a log) is always computed on its own.
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Callable, Hashable

import numpy as np
import pandas as pd

from rafi.family.whole_log import has_whole_logs

__all__ = ["FeatureMemo", "sharing_features", "active_memo"]

#: Columns :meth:`FeatureMemo.positions` compares between a frame and the universe.
CHECKED = ("log_t_s", "speed_rpm", "dz_um")

_ACTIVE: contextvars.ContextVar = contextvars.ContextVar("rafi_feature_memo", default=None)


class FeatureMemo:
    """Features (and per-run Gram matrices) of the logs of ``universe``, each computed once.

    Parameters
    ----------
    universe : pandas.DataFrame
        A runs frame of whole logs (``log``, ``log_t_s``) with a unique index: in ``rule
        compare`` the logs holding a training run (:func:`rafi.family.whole_log.rows_of_logs`).
    """

    def __init__(self, universe: pd.DataFrame):
        self.universe = universe
        self.usable = has_whole_logs(universe) and universe.index.is_unique
        self._log_rows = universe["log"].astype(str).value_counts() if self.usable else None
        self._features: dict = {}
        self._grams: dict = {}
        self._solutions: dict = {}

    def positions(self, frame: pd.DataFrame) -> np.ndarray | None:
        """Positions in the universe of the rows of ``frame``, or ``None`` unless ``frame`` is
        made of whole logs of the universe: rows of the universe by index label, every row of
        each of its logs, with the same :data:`CHECKED` values (the frames of a scope are rows
        of one runs frame; the check guards against another frame with the same labels)."""
        if not self.usable or not has_whole_logs(frame) or not frame.index.is_unique:
            return None
        pos = self.universe.index.get_indexer(frame.index)
        if len(pos) and pos.min() < 0:
            return None
        counts = frame["log"].astype(str).value_counts()
        if not counts.equals(self._log_rows.reindex(counts.index)):
            return None
        for column in CHECKED:
            if (column in frame.columns) != (column in self.universe.columns):
                return None
            if column in frame.columns and not np.array_equal(
                frame[column].to_numpy(dtype=float),
                self.universe[column].to_numpy(dtype=float)[pos],
                equal_nan=True,
            ):
                return None
        return pos

    def universe_features(self, key: Hashable, compute: Callable):
        """``compute(universe)`` (a feature matrix in universe row order and its names), computed
        once per ``key``; ``key`` must name everything ``compute`` depends on besides the frame.
        A fit takes the rows of its frame from it (:meth:`positions`)."""
        if key not in self._features:
            self._features[key] = compute(self.universe)
        return self._features[key]

    def stored(self, key: Hashable):
        """What :meth:`universe_features` stored for ``key`` on the universe (matrix, names), or ``None``."""
        return self._features.get(key)

    def run_gram(self, key: Hashable, run_id: str, compute: Callable):
        """``compute()`` (a run's ``X'X``, ``X'y`` and sample count), once per ``key`` and run."""
        if (key, run_id) not in self._grams:
            self._grams[(key, run_id)] = compute()
        return self._grams[(key, run_id)]

    def solution(self, key: Hashable, compute: Callable):
        """``compute()`` (a CV fold's ridge coefficients, or one speed's OLS coefficients of RAFI's
        kinds), once per ``key`` (for the ridge kinds the memo key of the features, the fold's
        training runs, the candidate's columns and the penalties; for RAFI a digest of the speed's
        samples and design, :func:`rafi.method.fit.fit_speed`)."""
        if key not in self._solutions:
            self._solutions[key] = compute()
        return self._solutions[key]


def active_memo() -> FeatureMemo | None:
    """The memo of the current :func:`sharing_features` scope, or ``None``."""
    return _ACTIVE.get()


@contextlib.contextmanager
def sharing_features(universe: pd.DataFrame):
    """Share the features of the logs of ``universe`` among the fits inside the block (an
    enclosing scope is kept: its memo already serves them)."""
    if _ACTIVE.get() is not None:
        yield _ACTIVE.get()
        return
    token = _ACTIVE.set(FeatureMemo(universe))
    try:
        yield _ACTIVE.get()
    finally:
        _ACTIVE.reset(token)
