"""Giving fitted models their prediction interval: the family in ``rule compare``
(:func:`calibrate_family`) and RAFI's ``model.json`` in ``rule method`` (:func:`rafi_interval`).

Both calibrate on the model's own out-of-fold residuals of the whole-run cross-validation
(:func:`rafi.family.crossval.cross_validate` with ``oof=``; time blocks for a single-run log), with
:func:`rafi.family.intervals.calibrate` and the settings ``models: interval_level``,
``interval_transient_s`` and ``interval_min_runs``. The forward folds' held-out runs
(``models: cv_forward_runs``, :mod:`rafi.family.forward_folds`) score the selection but do not
calibrate (:func:`calibration_units`; ``docs/decisions.md``, 2026-11-26).
"""

from __future__ import annotations

import pandas as pd

from rafi.family.crossval import cross_validate, cv_data, scheme_of
from rafi.family.forward_folds import unit_run
from rafi.family.intervals import OOF_COLUMNS, calibrate, set_interval

__all__ = [
    "interval_options",
    "stacked_oof",
    "whole_run_units",
    "calibration_units",
    "calibrate_family",
    "borrow_interval",
    "rafi_interval",
]


def interval_options(options: dict) -> dict:
    """The keyword arguments of :func:`rafi.family.intervals.calibrate` from ``models:``."""
    return {
        "level": float(options["interval_level"]),
        "transient_s": float(options["interval_transient_s"]),
        "min_runs": int(options["interval_min_runs"]),
    }


def stacked_oof(parts: list) -> pd.DataFrame:
    """Every kind's OOF samples in one frame (the empty frame of :data:`OOF_COLUMNS` without any)."""
    parts = [p for p in parts if len(p)]
    if not parts:
        return pd.DataFrame({c: pd.Series(dtype=float) for c in OOF_COLUMNS})
    return pd.concat(parts, ignore_index=True)[OOF_COLUMNS]


def whole_run_units(oof: pd.DataFrame) -> pd.DataFrame:
    """The OOF samples of the whole-run (or time-block) units: those of the forward folds
    (``f<fold>:<run>``, :func:`rafi.family.forward_folds.fold_unit`) left out."""
    if not len(oof):
        return oof
    units = oof["unit"].astype(str).to_numpy()
    return oof.loc[unit_run(units) == units]


def calibration_units(oof: pd.DataFrame, whole: str) -> tuple[pd.DataFrame, str]:
    """The OOF samples the intervals calibrate on and the scheme the calibration records: the
    whole-run (time-block) units alone (:func:`whole_run_units`, scheme ``whole``). The forward
    units are fitted on fewer runs than the whole-run folds: judged one level up with refits on
    the training runs, the whole-run units alone came closer to the nominal level
    (``docs/decisions.md``, 2026-11-26).
    """
    return whole_run_units(oof), whole


def _describe(name: str, block: dict | None) -> str:
    if block is None:
        return f"{name}: no prediction interval (no cross-validation fold)"
    h = block["half_width_um"]
    cal = block["calibration"]
    fallback = f", fell back: {', '.join(cal['fallback'])}" if cal["fallback"] else ""
    return (
        f"{name}: {block['level']:.0%} interval +-{h['settled']:.2f} / {h['transient']:.2f} / "
        f"{h['outside']:.2f} um (settled / transient / outside) from {cal['n_runs']} held-out "
        f"{cal['units']}, level {cal['corrected_level']:.3f}{fallback}; decorrelation "
        f"{block['decorrelation_s']:g} s"
    )


def calibrate_family(
    models: dict,
    oof: pd.DataFrame,
    *,
    options: dict,
    scheme: str,
    tolerance_rpm: float,
    keep: set | frozenset = frozenset(),
    log=print,
) -> dict:
    """Calibrate and attach every model's interval (:func:`rafi.family.intervals.set_interval`).

    Parameters
    ----------
    models : dict
        Name -> fitted model (changed in place: its artefact then carries the block).
    oof : pandas.DataFrame
        The OOF samples of every model (:data:`rafi.family.intervals.OOF_COLUMNS`; ``model`` = name).
    options : dict
        The machine's ``models:`` settings.
    scheme : str
        The CV scheme the OOF samples come from.
    tolerance_rpm : float
        The machine's ``speed_tolerance_rpm`` (the change clock's; the OOF samples' clock).
    keep : set
        Names whose model keeps the interval it has (RAFI's ``model.json``).

    Returns
    -------
    dict
        Name -> the block (``None``: no interval).
    """
    out = {}
    names = oof["model"].astype(str).to_numpy() if len(oof) else []
    for name, model in models.items():
        if name in keep:
            out[name] = None
            continue
        mine = oof.loc[names == str(name)] if len(oof) else oof
        block = calibrate(
            mine, tolerance_rpm=float(tolerance_rpm), scheme=scheme, **interval_options(options)
        )
        set_interval(model, block)
        out[name] = block
        log(_describe(name, block))
    return out


def borrow_interval(models: dict, blocks: dict, borrower: str, lender: str, log=print) -> dict | None:
    """Give ``borrower`` the interval of ``lender`` (both fitted here, on the same runs), its
    calibration saying so (``calibration.borrowed_from``); nothing without both or a lender's block.

    The moved members of an ensemble prior (``prior_shared_ridge``) would calibrate on their own
    whole-run CV of a few hours' runs, which holds out a run the others cannot predict (the one
    top-speed heat-up of a ``rafi plan`` programme): an interval tens of um wide on a model right to
    a few tenths. The shared gain, fitted on the same prior and runs and predicting alike, lends
    its own (``docs/decisions.md``, 2026-11-30).

    Parameters
    ----------
    models : dict
        Name -> fitted model (``borrower`` changed in place).
    blocks : dict
        Name -> its calibrated block (:func:`calibrate_family`'s return; changed in place).
    borrower, lender : str
        The names.

    Returns
    -------
    dict or None
        The borrowed block (None: nothing borrowed).
    """
    lent = blocks.get(lender)
    if borrower not in models or lent is None:
        return None
    block = {**lent, "calibration": {**lent["calibration"], "borrowed_from": lender}}
    set_interval(models[borrower], block)
    blocks[borrower] = block
    log(f"interval of {borrower}: {lender}'s (the same prior and runs), not its own CV's")
    return block


def rafi_interval(
    model,
    factory,
    runs_table: pd.DataFrame,
    runs_frame: pd.DataFrame,
    *,
    options: dict,
    speed_tolerance_rpm: float,
    log=print,
) -> dict | None:
    """Calibrate RAFI's interval for the pipeline's ``model.json`` and attach it to ``model`` (a
    :class:`~rafi.method.model.RafiModel`): RAFI's own whole-run CV on the training runs, each
    fold fitting ``factory()`` (a :class:`~rafi.family.published.PublishedRafi` with the
    machine's settings), under ``models: cv`` (time-blocked folds when the training runs give no
    whole-run fold, :func:`rafi.family.crossval.cv_data`). Returns the block (``None``: no fold,
    no interval)."""
    table, frame = cv_data(runs_table, runs_frame, options, log=log)
    oof: list = []
    cross_validate(factory, table, frame, options["cv"], name="rafi", oof=oof)
    samples, scheme = calibration_units(stacked_oof(oof), scheme_of(table, options["cv"]))
    block = calibrate(
        samples, tolerance_rpm=float(speed_tolerance_rpm), scheme=scheme, **interval_options(options)
    )
    set_interval(model, block)
    log(_describe("rafi (model.json)", block))
    return block
