"""Whole-run cross-validation of the model family.

5 s samples are strongly autocorrelated, so a sample-wise split leaks: a test sample's
neighbours, 5 s away, sit in the training set. Every split here is by **whole run**:

* ``leave_one_run_out``: one fold per training run;
* ``leave_one_speed_out``: one fold per training speed (all runs at that speed held out);
  for RAFI this is exactly the situation of a validation speed between two training speeds
  (or beyond the edge, for the lowest / highest speed).

Training data with no whole-run fold (one long training run) gets **time-blocked folds**
instead (:mod:`rafi.family.time_blocks`): :func:`split_runs` and :func:`cross_validate` then work
on the blocks of a unit table, with a guard gap around each held-out block.

**Forward folds** (:mod:`rafi.family.forward_folds`, scheme ``forward_<h>``) train on a log's
training runs before a point in time and hold out the next ``h``; the later ones are guard runs.

Only runs with ``role == "training"`` are ever split; validation runs never enter model
selection. Every splitter asserts that no run is in both the train and the test set.

A fold's model sees the **inputs** of whole logs (a filter runs through the other runs of a
log, held-out ones included) but the **displacement** of its training runs only: the held-out
runs get the role :data:`HELD_OUT` in the table ``fit`` receives, and ``fit`` learns from
``role == "training"`` rows alone.

The comparison on the validation runs and the champion choice are in
:mod:`rafi.family.compare`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator

import numpy as np
import pandas as pd

from rafi.family.feature_memo import sharing_features
from rafi.family.forward_folds import fold_unit, forward_folds, horizon_of, is_forward
from rafi.family.time_blocks import SCHEME as TIME_BLOCKS
from rafi.family.time_blocks import hours, is_blocked, time_block_folds, time_block_units, unit_column
from rafi.family.whole_log import rows_of_logs
from rafi.method.validate import input_sensors, inputs_without_value

__all__ = [
    "SCHEMES",
    "training_runs",
    "leave_one_run_out",
    "leave_one_speed_out",
    "split_runs",
    "assert_disjoint",
    "subset_runs",
    "cross_validate",
    "CV_COLUMNS",
    "HELD_OUT",
    "GUARD",
    "hold_out",
    "training_mask",
    "has_folds",
    "cv_schemes",
    "scheme_of",
    "cv_data",
]

SPEED_GROUP_TOLERANCE_RPM = 50.0

#: Role of a training run held out of a CV fold (in the table that fold's ``fit`` receives).
HELD_OUT = "held_out"
#: Role of a guard gap beside a held-out time block (:mod:`rafi.family.time_blocks`): neither
#: trained on nor scored in that fold.
GUARD = "guard"

CV_COLUMNS = [
    "model",
    "scheme",
    "fold",
    "test_runs",
    "test_speed_rpm",
    "n_train_runs",
    "n_samples",
    "max_abs_before_um",
    "max_abs_after_um",
    "improvement_pct",
    "rmse_um",
    "n_unpredicted",
    "unpredicted_inputs",
]

# --------------------------------------------------------------------------- subsets


def training_runs(runs_table: pd.DataFrame, runs_frame: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The ``role == "training"`` rows of ``runs_table`` and their samples in ``runs_frame``.

    This is the only door through which a model's ``fit`` sees data. For a unit table of
    time-blocked folds (:func:`rafi.family.time_blocks.time_block_units`) the rows are those of
    its training units (a run's held-out block and guard gaps are not among them); a run id
    then appears once per training unit of the run.
    """
    for col in ("run_id", "role", "speed_rpm"):
        if col not in runs_table.columns:
            raise ValueError(f"runs_table lacks column {col!r}")
    table = runs_table.loc[runs_table["role"].astype(str) == "training"]
    return table, runs_frame.loc[training_mask(runs_frame, table)]


def training_mask(frame: pd.DataFrame, table: pd.DataFrame) -> np.ndarray:
    """Rows of ``frame`` that belong to the rows of ``table``: by run, or by CV unit where both
    have one (time-blocked folds)."""
    col = unit_column(frame, table)
    return frame[col].astype(str).isin(set(table[col].astype(str))).to_numpy()


def subset_runs(
    runs_table: pd.DataFrame, runs_frame: pd.DataFrame, run_ids
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Rows of ``runs_table`` / ``runs_frame`` belonging to ``run_ids`` (whole runs only)."""
    ids = set(map(str, run_ids))
    return (
        runs_table.loc[runs_table["run_id"].astype(str).isin(ids)],
        runs_frame.loc[runs_frame["run_id"].astype(str).isin(ids)],
    )


def hold_out(runs_table: pd.DataFrame, run_ids, role: str = HELD_OUT) -> pd.DataFrame:
    """A copy of ``runs_table`` whose runs (or CV units) ``run_ids`` have the role ``role``."""
    out = runs_table.copy()
    ids = set(map(str, run_ids))
    out.loc[out[unit_column(out)].astype(str).isin(ids), "role"] = role
    return out


# --------------------------------------------------------------------------- splitters


def assert_disjoint(train_ids, test_ids) -> None:
    """Raise ``AssertionError`` if a run is in both sets or a set is empty."""
    train, test = set(map(str, train_ids)), set(map(str, test_ids))
    if train & test:
        raise AssertionError(f"runs in both train and test: {sorted(train & test)}")
    if not train or not test:
        raise AssertionError(f"empty fold: train={sorted(train)} test={sorted(test)}")


def _train_ids(runs_table: pd.DataFrame) -> pd.DataFrame:
    t = runs_table.loc[runs_table["role"].astype(str) == "training", ["run_id", "speed_rpm"]].copy()
    t["run_id"] = t["run_id"].astype(str)
    return t.sort_values(["speed_rpm", "run_id"], kind="stable")


def leave_one_run_out(runs_table: pd.DataFrame) -> Iterator[tuple[list[str], list[str]]]:
    """One fold per training run: ``(train_run_ids, [held_out_run_id])``."""
    ids = list(_train_ids(runs_table)["run_id"])
    for rid in ids:
        train = [r for r in ids if r != rid]
        if not train:
            continue
        assert_disjoint(train, [rid])
        yield train, [rid]


def leave_one_speed_out(
    runs_table: pd.DataFrame, *, tolerance_rpm: float = SPEED_GROUP_TOLERANCE_RPM
) -> Iterator[tuple[list[str], list[str]]]:
    """One fold per training speed (runs within ``tolerance_rpm`` share a speed)."""
    t = _train_ids(runs_table)
    groups: list[list[str]] = []
    first = None
    for rid, speed in zip(t["run_id"], t["speed_rpm"].astype(float)):
        if groups and speed - first <= tolerance_rpm:
            groups[-1].append(rid)
        else:
            groups.append([rid])
            first = speed
    all_ids = list(t["run_id"])
    for test in groups:
        train = [r for r in all_ids if r not in test]
        if not train:
            continue
        assert_disjoint(train, test)
        yield train, list(test)


SCHEMES: dict[str, Callable] = {
    "leave_one_run_out": leave_one_run_out,
    "leave_one_speed_out": leave_one_speed_out,
}


def split_runs(runs_table: pd.DataFrame, scheme: str = "leave_one_run_out"):
    """Folds ``(train_run_ids, test_run_ids)`` of the training runs under ``scheme``; on a unit
    table (:func:`rafi.family.time_blocks.time_block_units`) the time-blocked folds of its units,
    whatever ``scheme`` (the data's structure chose them), and no forward fold (time blocks are
    the folds of one run). ``forward_<h>``: :func:`rafi.family.forward_folds.forward_folds`."""
    fn = SCHEMES.get(scheme)
    if fn is None and is_forward(scheme):
        fn = functools.partial(forward_folds, horizon=horizon_of(scheme))
    if fn is None:
        raise ValueError(f"unknown CV scheme {scheme!r}; known: {sorted(SCHEMES)} and forward_<runs>")
    if is_blocked(runs_table):
        return iter(()) if is_forward(scheme) else time_block_folds(runs_table)
    return fn(runs_table)


def has_folds(runs_table: pd.DataFrame, scheme: str) -> bool:
    """True if ``scheme`` gives at least one fold on the training runs of ``runs_table``."""
    return next(iter(split_runs(runs_table, scheme)), None) is not None


def cv_schemes(runs_table: pd.DataFrame, scheme: str, forward: str | None = None) -> list[str]:
    """The CV schemes to run on ``runs_table``: ``scheme``, then ``forward`` (a forward scheme,
    :mod:`rafi.family.forward_folds`) when it gives a fold there."""
    return [scheme] + ([forward] if forward and has_folds(runs_table, forward) else [])


def scheme_of(runs_table: pd.DataFrame, scheme: str) -> str:
    """The scheme the folds of ``runs_table`` follow: :data:`rafi.family.time_blocks.SCHEME` on a
    unit table, else ``scheme``."""
    return TIME_BLOCKS if is_blocked(runs_table) else scheme


# --------------------------------------------------------------------------- cross-validation


def _metrics(measured: np.ndarray, predicted: np.ndarray, run_rows: pd.DataFrame, sensors) -> dict:
    """The CV figures of one held-out run (its rows ``run_rows``) over the samples the model
    predicted, and the measured samples it gave no value on, with the inputs it reads
    (``sensors``, :func:`rafi.method.validate.input_sensors`) that had none there."""
    ok = np.isfinite(measured) & np.isfinite(predicted)
    unpredicted = np.isfinite(measured) & ~np.isfinite(predicted)
    blind = {
        "n_unpredicted": int(unpredicted.sum()),
        "unpredicted_inputs": inputs_without_value(run_rows, unpredicted, sensors),
    }
    if not ok.any():
        return {
            "n_samples": 0,
            "max_abs_before_um": np.nan,
            "max_abs_after_um": np.nan,
            "improvement_pct": np.nan,
            "rmse_um": np.nan,
            **blind,
        }
    m, r = measured[ok], measured[ok] - predicted[ok]
    before, after = float(np.max(np.abs(m))), float(np.max(np.abs(r)))
    return {
        "n_samples": int(ok.sum()),
        "max_abs_before_um": before,
        "max_abs_after_um": after,
        "improvement_pct": 100.0 * (before - after) / before if before > 0 else np.nan,
        "rmse_um": float(np.sqrt(np.mean(r**2))),
        **blind,
    }


def cross_validate(
    model_factory: Callable[[], object],
    runs_table: pd.DataFrame,
    runs_frame: pd.DataFrame,
    scheme: str = "leave_one_run_out",
    *,
    name: str = "",
    oof: list | None = None,
) -> pd.DataFrame:
    """Whole-run CV of the model that ``model_factory()`` builds, on the training runs only.

    Each fold fits a fresh model on the fold's training runs: ``fit`` gets the whole
    ``runs_frame`` and the table with the held-out runs' role set to :data:`HELD_OUT`, so it
    learns from the displacement of the fold's training runs only (a model with
    hyperparameters runs its own inner CV on those runs only = nested CV) while a filter may
    run through the inputs of whole logs. The fold's model then predicts the logs holding the
    held-out runs once (:func:`rafi.family.whole_log.rows_of_logs`; per-run frames: the
    held-out runs' rows) and each held-out run is scored on its own samples. Metrics per
    held-out run are those of ``docs/design.md`` (``max |dz - predicted|``, improvement, RMSE),
    over the samples the model predicted; ``n_unpredicted`` counts the measured samples it gave
    no value on (an input it reads missing there) and ``unpredicted_inputs`` names those inputs,
    as in ``validation/summary.csv``.

    With ``oof`` (a list), the held-out samples themselves are appended to it as one frame
    (:func:`rafi.family.intervals.oof_samples`, :data:`rafi.family.intervals.OOF_COLUMNS`): the
    out-of-fold residuals the prediction interval is calibrated on. Under forward folds a run is
    held out by several folds, so its OOF unit is ``f<fold>:<run>`` (one unit per fold and run).

    A fold with nothing the model learns from (``model.can_fit(fold_table)`` false: RAFI as
    published learns from constant-speed runs only, and a fold may hold only a cool-down) is
    scored as no compensation (a prediction of 0 on its held-out runs, so every kind is judged on
    the same runs) and gives no out-of-fold samples.

    Returns
    -------
    pandas.DataFrame
        One row per (fold, held-out run), columns :data:`CV_COLUMNS`.
    """
    rows = []
    train_table, _ = training_runs(runs_table, runs_frame)
    col = unit_column(runs_table, runs_frame)
    units = train_table[col].astype(str)
    speeds = dict(zip(units, train_table["speed_rpm"].astype(float)))
    run_of_unit = dict(zip(units, train_table["run_id"].astype(str)))
    scheme_name = scheme_of(runs_table, scheme)
    # what any fold's fit and prediction can see: the logs holding a training run (the fits
    # share their features, rafi.family.feature_memo)
    frame = runs_frame.loc[rows_of_logs(runs_frame, train_table["run_id"])]
    held_out, artefact = [], None
    with sharing_features(frame):
        for k, (train_ids, test_ids) in enumerate(split_runs(runs_table, scheme)):
            assert_disjoint(train_ids, test_ids)
            fold_table = hold_out(runs_table, test_ids)
            # time-blocked folds: the training units beside the held-out block (its guard gaps)
            guards = set(units) - set(map(str, train_ids)) - set(map(str, test_ids))
            if guards:
                fold_table = hold_out(fold_table, guards, GUARD)
            fitted_on = set(map(str, training_runs(fold_table, frame)[0][col]))
            assert fitted_on == set(map(str, train_ids)), "a fold fits on exactly its training runs"
            model = model_factory()
            fits = model.can_fit(fold_table) if hasattr(model, "can_fit") else True
            needed_mask = rows_of_logs(frame, {run_of_unit[str(u)] for u in test_ids})
            needed = frame.loc[needed_mask]
            if not fits:  # nothing this kind learns from in the fold: it compensates nothing there
                predicted = np.zeros(len(needed))
            elif oof is None:
                predicted = np.asarray(model.fit(fold_table, frame).predict(needed), dtype=float)
            else:  # the same prediction with its out-of-range flags (the interval's cell)
                detail = model.fit(fold_table, frame).predict_detail(needed)
                predicted = detail["predicted_um"].to_numpy(dtype=float)
            sensors = input_sensors(model) if fits else None
            unit_of = needed[col].astype(str).to_numpy()
            dz = needed["dz_um"].to_numpy(dtype=float)
            if oof is not None and fits:
                artefact = artefact or model.to_dict()
                part = _held_out(detail, dz, unit_of, np.flatnonzero(needed_mask), test_ids)
                if is_forward(scheme):
                    part["unit"] = [fold_unit(k, u) for u in part["unit"]]
                held_out.append(part)
            for rid in test_ids:
                mine = unit_of == str(rid)
                rows.append(
                    {
                        "model": name,
                        "scheme": scheme_name,
                        "fold": k,
                        "test_runs": rid,
                        "test_speed_rpm": speeds.get(rid, np.nan),
                        "n_train_runs": len(train_ids),
                        **_metrics(dz[mine], predicted[mine], needed.loc[mine], sensors),
                    }
                )
    if oof is not None:
        from rafi.family.intervals import oof_samples

        oof.append(oof_samples(held_out, frame, artefact or {}, name))
    return pd.DataFrame(rows, columns=CV_COLUMNS)


def _held_out(detail: pd.DataFrame, dz: np.ndarray, unit_of: np.ndarray, positions: np.ndarray, test_ids):
    """The held-out samples of one fold for :func:`rafi.family.intervals.oof_samples`."""
    mine = np.isin(unit_of, list(map(str, test_ids)))
    outside = detail["outside_temp_range"].to_numpy(dtype=bool) | detail["outside_speed_range"].to_numpy(
        dtype=bool
    )
    return pd.DataFrame(
        {
            "pos": positions[mine],
            "unit": unit_of[mine],
            "residual_um": (dz - detail["predicted_um"].to_numpy(dtype=float))[mine],
            "outside": outside[mine],
            "excess": _excess(detail)[mine],
        }
    )


def _excess(detail: pd.DataFrame) -> np.ndarray:
    """``range_excess`` of ``predict_detail`` (0 for a kind without it: the RAFI kinds)."""
    if "range_excess" not in detail.columns:
        return np.zeros(len(detail))
    return np.nan_to_num(detail["range_excess"].to_numpy(dtype=float))


def cv_data(runs_table: pd.DataFrame, runs_frame: pd.DataFrame, options: dict, *, log=print):
    """The table and frame the models are fitted and cross-validated on: the runs as they are
    when ``options["cv"]`` gives a whole-run fold, else the time-blocked units of the training
    runs (:func:`rafi.family.time_blocks.time_block_units`, ``options["cv_time_blocks"]`` blocks,
    ``options["cv_time_block_gap_s"]`` guard gaps) when two blocks fit; the data's structure alone
    decides. Without either there is no fold (:func:`default_champion`)."""
    if has_folds(runs_table, options["cv"]) or not len(training_runs(runs_table, runs_frame)[1]):
        return runs_table, runs_frame
    units = time_block_units(
        runs_table,
        runs_frame,
        n_blocks=int(options["cv_time_blocks"]),
        gap_s=float(options["cv_time_block_gap_s"]),
    )
    if units is None:
        log("too few training runs for whole-run folds and too little training time for two time blocks")
        return runs_table, runs_frame
    table = units[0]
    blocks = int(table.loc[table["cv_seq"] >= 0, "cv_seq"].max()) // 2 + 1
    log(
        f"too few training runs for whole-run folds: {blocks} time blocks with "
        f"{hours(float(options['cv_time_block_gap_s']))} guard gaps"
    )
    return units
