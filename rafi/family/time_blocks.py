"""Time-blocked folds for training data with too few whole runs (``docs/models.md``, "Time-blocked
folds").

Whole-run cross-validation (:mod:`rafi.family.crossval`) needs runs: a machine whose training
part is one long run (a single-speed log without a speed column, a training window holding one
run) has no whole-run fold. Its training samples are then cut, in time order, into ``K``
contiguous **blocks** separated by **guard gaps** of ``gap_s``::

    block 1 | gap 1 | block 2 | gap 2 | ... | gap K-1 | block K

Each block is held out in turn; the fold's model learns from every other block and every gap
**except the two gaps beside the held-out block**, so no training sample lies within ``gap_s``
of a held-out sample (strictly more than ``gap_s`` apart, on the log's clock). A gap is never
held out (it is never scored) and trains in every fold it does not border.

Why the gap suffices: the family's features are first-order filters of the inputs, computed over
the whole log (as the controller computes them from power-on); a training sample ``gap_s`` after
the held-out block carries ``exp(-gap_s / tau)`` of the held-out block's inputs in a filter of
time constant ``tau``. In time-blocked folds no filter constant exceeds ``gap_s /``
:data:`GAP_PER_TAU` (the models cut their grids there, :func:`max_filter_s`), so that share is
below ``exp(-3)`` = 5 %; the default gap of 3 h admits filters up to 1 h.

Blocks are cut on the **training clock**: the time of a training sample counted along the
training samples in time order, adding each step within a run and nothing between runs, so a
distance on it is never longer than the same distance on the log's clock. The scheme is chosen
by the data's structure alone (:func:`block_count`): no validation figure enters.

The fold structure travels with the data: :func:`time_block_units` returns a *unit table* (one
row per block or gap of a training run, the run's own row otherwise) with the columns
:data:`UNIT`, :data:`SEQ` and :data:`GAP`, and the runs frame with a :data:`UNIT` column. A
model's ``fit`` receives them like a runs table and frame: the features still use ``run_id``
(reference windows, filters over whole logs), the folds use the units.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import pandas as pd

__all__ = [
    "SCHEME",
    "GAP_PER_TAU",
    "UNIT",
    "SEQ",
    "GAP",
    "is_blocked",
    "unit_column",
    "training_clock",
    "block_count",
    "block_sequence",
    "time_block_units",
    "time_block_folds",
    "max_filter_s",
    "blocks_text",
    "hours",
]

#: The ``scheme`` of time-blocked folds in ``comparison/cv.csv``.
SCHEME = "time_blocks"
#: The guard gap is at least this many times the largest filter time constant (``exp(-3)`` = 5 %).
GAP_PER_TAU = 3.0
#: Column naming a sample's (or a unit-table row's) CV unit: ``<run>@block<k>`` / ``<run>@gap<k>``.
UNIT = "cv_unit"
#: Column of the unit table: position on the training timeline (0, 2, ... blocks; 1, 3, ... gaps;
#: -1 for a run that is not cut).
SEQ = "cv_seq"
#: Column of the unit table: the guard gap (s).
GAP = "cv_gap_s"


def is_blocked(table: pd.DataFrame) -> bool:
    """True if ``table`` is a unit table of :func:`time_block_units`."""
    return {UNIT, SEQ, GAP} <= set(table.columns)


def unit_column(*frames: pd.DataFrame) -> str:
    """:data:`UNIT` if every one of ``frames`` has it, else ``run_id``: the column a fold splits on."""
    return UNIT if frames and all(UNIT in f.columns for f in frames) else "run_id"


def _time_order(frame: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Positions sorting ``frame`` in time (by log then ``log_t_s``; per-run frames: by run then
    ``t_s``), the time and the run of every sorted row."""
    runs = frame["run_id"].astype(str).to_numpy()
    if {"log", "log_t_s"} <= set(frame.columns):
        group, t = pd.factorize(frame["log"].astype(str))[0], frame["log_t_s"].to_numpy(dtype=float)
    else:
        group = pd.factorize(frame["run_id"].astype(str))[0]
        t = (
            frame["t_s"].to_numpy(dtype=float)
            if "t_s" in frame.columns
            else np.arange(len(frame), dtype=float)
        )
    order = np.lexsort((t, group))
    return order, t[order], runs[order]


def training_clock(t_s: np.ndarray, runs: np.ndarray) -> tuple[np.ndarray, float]:
    """The training clock of samples in time order and the sample period.

    Parameters
    ----------
    t_s : ndarray
        Time of each training sample (s), in time order.
    runs : ndarray
        Run of each sample.

    Returns
    -------
    clock : ndarray
        Seconds from the first sample, adding each step within a run and 0 between runs (so
        ``clock[j] - clock[i] <= t_s[j] - t_s[i]`` for two samples of one log).
    period_s : float
        Median positive step within a run (1 s without one).
    """
    if not len(t_s):
        return np.zeros(0), 1.0
    step = np.r_[0.0, np.diff(np.asarray(t_s, dtype=float))]
    same_run = np.r_[False, runs[1:] == runs[:-1]]
    step = np.where(same_run, np.clip(step, 0.0, None), 0.0)
    positive = step[step > 0]
    return np.cumsum(step), float(np.median(positive)) if len(positive) else 1.0


def block_count(span_s: float, period_s: float, n_blocks: int, gap_s: float) -> tuple[int, float] | None:
    """How many blocks the training time holds, and their length: the data's structure alone.

    ``K`` from ``n_blocks`` down to 2, the first whose blocks, ``(span_s - (K - 1) gap_s) / K``,
    are at least ``max(gap_s, period_s)`` long (a held-out block spans at least the guard gap,
    three time constants of the slowest filter). ``None`` when not even two blocks fit.
    """
    for k in range(int(n_blocks), 1, -1):
        block = (float(span_s) - (k - 1) * float(gap_s)) / k
        if block >= max(float(gap_s), float(period_s)) - 1e-9:
            return k, block
    return None


def block_sequence(clock: np.ndarray, n_blocks: int, block_s: float, gap_s: float) -> np.ndarray:
    """Position of every sample on the timeline: ``2 k`` in block ``k``, ``2 k + 1`` in the gap
    after it (``clock`` from the first sample: block ``k`` is ``[k (b + g), k (b + g) + b)``)."""
    pitch = float(block_s) + float(gap_s)
    k = np.minimum(np.floor(clock / pitch), n_blocks - 1)
    inside = clock - k * pitch < float(block_s)
    return np.where(inside, 2 * k, 2 * k + 1).astype("int64")


def time_block_units(
    runs_table: pd.DataFrame, runs_frame: pd.DataFrame, *, n_blocks: int, gap_s: float
) -> tuple[pd.DataFrame, pd.DataFrame] | None:
    """The unit table and frame of time-blocked folds, or ``None`` when two blocks do not fit.

    Parameters
    ----------
    runs_table, runs_frame : pandas.DataFrame
        Rule ``runs``' table and frame (the training runs are ``role == "training"``).
    n_blocks : int
        Blocks wanted (``models.cv_time_blocks``); fewer when the training time is short
        (:func:`block_count`).
    gap_s : float
        The guard gap (``models.cv_time_block_gap_s``).

    Returns
    -------
    (unit_table, unit_frame) or None
        ``unit_table``: the non-training runs' rows as they are (:data:`UNIT` = the run id,
        :data:`SEQ` = -1) and per training run one row per block or gap it holds samples of
        (the run's row with its :data:`UNIT`, :data:`SEQ`), every row with :data:`GAP`;
        ``unit_frame``: ``runs_frame`` with the :data:`UNIT` of every sample.
    """
    train_ids = set(runs_table.loc[runs_table["role"].astype(str) == "training", "run_id"].astype(str))
    is_train = runs_frame["run_id"].astype(str).isin(train_ids).to_numpy()
    train = runs_frame.loc[is_train]
    order, t, runs = _time_order(train)
    clock, period = training_clock(t, runs)
    span = float(clock[-1]) + period if len(clock) else 0.0
    plan = block_count(span, period, n_blocks, gap_s)
    if plan is None:
        return None
    k, block_s = plan
    seq_sorted = block_sequence(clock, k, block_s, gap_s)
    seq = np.empty(len(train), dtype="int64")
    seq[order] = seq_sorted
    names = np.where(seq % 2 == 0, "@block", "@gap")
    unit_of_train = train["run_id"].astype(str).to_numpy() + names + (seq // 2 + 1).astype(str)
    units = runs_frame["run_id"].astype(str).to_numpy().astype(object)
    units[is_train] = unit_of_train
    frame = runs_frame.assign(**{UNIT: units})
    rows = []
    pairs = pd.DataFrame({"run_id": train["run_id"].astype(str).to_numpy(), UNIT: unit_of_train, SEQ: seq})
    first = pairs.drop_duplicates(UNIT).sort_values([SEQ, "run_id"], kind="stable")
    by_run = {str(r["run_id"]): r for r in runs_table.to_dict("records")}
    for rec in runs_table.to_dict("records"):
        if str(rec["run_id"]) not in train_ids:
            rows.append({**rec, UNIT: str(rec["run_id"]), SEQ: -1})
    for rid, unit, s in zip(first["run_id"], first[UNIT], first[SEQ]):
        rows.append({**by_run[rid], UNIT: unit, SEQ: int(s)})
    table = pd.DataFrame(rows, columns=[*runs_table.columns, UNIT, SEQ]).assign(**{GAP: float(gap_s)})
    table[SEQ] = table[SEQ].astype("int64")
    return table.reset_index(drop=True), frame


def time_block_folds(table: pd.DataFrame) -> Iterator[tuple[list[str], list[str]]]:
    """Folds ``(train_units, test_units)`` of a unit table: one per block among its training rows.

    The test units are the block's; the training units are every other training unit except
    the gaps beside the block (:data:`SEQ` one less or one more). Units whose role is not
    ``training`` (a block held out by an outer fold, its gaps) are never on either side.
    """
    t = table.loc[table["role"].astype(str) == "training", [UNIT, SEQ]]
    units, seq = t[UNIT].astype(str).to_numpy(), t[SEQ].to_numpy(dtype="int64")
    for s in sorted(set(seq[(seq >= 0) & (seq % 2 == 0)].tolist())):
        test = [u for u, q in zip(units, seq) if q == s]
        train = [u for u, q in zip(units, seq) if q != s and abs(q - s) != 1]
        if not train or not test:
            continue
        if set(train) & set(test):
            raise AssertionError(f"units in both train and test: {sorted(set(train) & set(test))}")
        yield train, test


def max_filter_s(table: pd.DataFrame) -> float | None:
    """The longest filter time constant a model may use under the folds of ``table``:
    ``gap / GAP_PER_TAU`` for a unit table, ``None`` (no limit) otherwise."""
    if not is_blocked(table) or not len(table):
        return None
    return float(table[GAP].iloc[0]) / GAP_PER_TAU


def blocks_text(table: pd.DataFrame) -> dict | None:
    """The folds of a unit table for the artefact and people (``None`` otherwise): ``scheme``,
    ``blocks`` (K), ``gap_s`` and ``max_filter_s``."""
    if not is_blocked(table):
        return None
    seq = table[SEQ].to_numpy(dtype="int64")
    blocks = int(seq[seq >= 0].max() // 2 + 1) if (seq >= 0).any() else 0
    gap = float(table[GAP].iloc[0])
    return {"scheme": SCHEME, "blocks": blocks, "gap_s": gap, "max_filter_s": gap / GAP_PER_TAU}


def hours(seconds: float) -> str:
    """``seconds`` in hours for people, e.g. ``3 h`` or ``9.5 h``."""
    h = float(seconds) / 3600.0
    return f"{h:.3g} h" if not math.isclose(h, round(h)) else f"{round(h):d} h"
