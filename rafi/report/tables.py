"""What the report shows from evaluating the RAFI model, as tables (rule ``report_tables``).

The report job evaluates no model: the training fit of each per-speed regression and the
worked example of the fuzzy blending are computed here, with the model's own code
(:meth:`rafi.method.model.RafiModel.predict`, :func:`rafi.method.fuzzy.triangular_weights`),
and written to ``results/<machine>/report/``:

``training_fit.parquet``
    ``speed_rpm, run_id, t_s, measured_um, fitted_um``: each training speed's regression on
    its own training runs (the figure of section Models).
``training_fit.csv``
    ``speed_rpm, rmse_um``: the RMSE of that fit, checked by the report against
    ``fit/diagnostics.csv``.
``fuzzy_example.json``
    The training speeds (``centres_rpm``) and the worked example of section Fuzzy blending:
    ``example_rpm``, per neighbouring training speed ``centre_rpm, distance_rpm, weight,
    model_dz_um``, the temperature ``state`` it is evaluated at and the ``blended_dz_um``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rafi.method.fuzzy import triangular_weights
from rafi.method.model import RafiModel
from rafi.report.format import speed_key
from rafi.report.inputs import training_runs

FUZZY_EXAMPLE_SCHEMA = "rafi.report.fuzzy_example/1"


def _model(doc: dict | None) -> RafiModel | None:
    """The RAFI model of ``model.json`` (``None`` without per-speed regressions)."""
    if not doc or not doc.get("speeds"):
        return None
    return RafiModel.from_dict(doc)


def training_fit(doc: dict | None, runs: pd.DataFrame | None, frames: pd.DataFrame | None) -> pd.DataFrame:
    """Each training speed's regression evaluated on its own training runs.

    Parameters
    ----------
    doc : dict
        ``model.json``.
    runs : DataFrame
        ``runs.csv`` (the training run of a speed whose model lists no ``train_runs``).
    frames : DataFrame
        ``runs.parquet``.

    Returns
    -------
    DataFrame
        ``speed_rpm, run_id, t_s, measured_um, fitted_um``; a speed whose runs or key
        sensors are missing is left out.
    """
    columns = ["speed_rpm", "run_id", "t_s", "measured_um", "fitted_um"]
    model = _model(doc)
    if model is None or frames is None:
        return pd.DataFrame(columns=columns)
    train = training_runs(runs)
    parts = []
    for speed, rids in zip(model.speeds_rpm_, model.train_runs_):
        rids = list(rids) or ([train[speed_key(speed)]] if speed_key(speed) in train else [])
        f = frames.loc[frames["run_id"].isin(rids)]
        if not len(f) or not all(c in f for c in model.input_columns):
            continue
        # the regression of this speed alone: at its own speed its membership weight is 1
        fitted = model.predict(f[model.input_columns].assign(speed_rpm=float(speed)))
        parts.append(
            pd.DataFrame(
                {
                    "speed_rpm": float(speed),
                    "run_id": f["run_id"].astype(str).to_numpy(),
                    "t_s": f["t_s"].to_numpy(),
                    "measured_um": f["dz_um"].to_numpy(float),
                    "fitted_um": fitted,
                }
            )
        )
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=columns)


def training_rmse(fit: pd.DataFrame) -> pd.DataFrame:
    """``speed_rpm, rmse_um`` of :func:`training_fit` (NaN residuals ignored)."""
    rows = []
    for speed, g in fit.groupby("speed_rpm", sort=True):
        r = g["measured_um"].to_numpy(float) - g["fitted_um"].to_numpy(float)
        rows.append({"speed_rpm": speed, "rmse_um": float(np.sqrt(np.nanmean(r**2)))})
    return pd.DataFrame(rows, columns=["speed_rpm", "rmse_um"])


def example_speed(c0: float, c1: float) -> float:
    """The speed of the worked example between the two lowest training speeds: the paper's
    4000 r/min between 3000 and 6000, else a third of the way up (rounded to 10 r/min)."""
    return 4000.0 if (c0, c1) == (3000.0, 6000.0) else c0 + round((c1 - c0) / 3.0, -1)


def fuzzy_example(
    doc: dict | None,
    diagnostics: pd.DataFrame | None,
    runs: pd.DataFrame | None,
    frames: pd.DataFrame | None,
) -> dict:
    """The training speeds and the worked example of the fuzzy blending.

    The example speed lies between the two lowest training speeds ``c0 < c1``; the
    temperature state is the end of the ``c0`` training run (``runs.csv``).

    Parameters
    ----------
    doc : dict
        ``model.json`` (its speeds; else those of ``diagnostics``).
    diagnostics : DataFrame
        ``fit/diagnostics.csv``.
    runs, frames : DataFrame
        ``runs.csv`` and ``runs.parquet``.

    Returns
    -------
    dict
        ``schema, centres_rpm, example_rpm`` (``None`` with fewer than two speeds),
        ``neighbours`` (list of ``centre_rpm, distance_rpm, weight, model_dz_um``),
        ``state`` (``{dT<sensor>: K}`` or ``None``) and ``blended_dz_um``.
    """
    doc = doc or {}
    centres = sorted(float(sp["speed_rpm"]) for sp in doc.get("speeds") or [])
    if not centres and diagnostics is not None:
        centres = sorted(diagnostics["speed_rpm"].astype(float).tolist())
    out = {
        "schema": FUZZY_EXAMPLE_SCHEMA,
        "centres_rpm": centres,
        "example_rpm": None,
        "neighbours": [],
        "state": None,
        "blended_dz_um": None,
    }
    if len(centres) < 2:
        return out
    c0, c1 = centres[0], centres[1]
    ex = example_speed(c0, c1)
    weights = triangular_weights([ex], centres)[0][0]
    by_centre = dict(zip(centres, weights))
    model = _model(doc)
    state = None
    train = training_runs(runs)
    if model is not None and frames is not None and speed_key(c0) in train:
        cols = model.input_columns
        if all(c in frames for c in cols):
            f = frames.loc[frames["run_id"] == train[speed_key(c0)], cols]
            if len(f):
                state = f.iloc[[-1]].reset_index(drop=True)
    trained = set() if model is None else {float(s) for s in model.speeds_rpm_}
    for c in (c0, c1):
        dz = np.nan
        if state is not None and c in trained:
            dz = float(model.predict(state.assign(speed_rpm=c))[0])
        out["neighbours"].append(
            {"centre_rpm": c, "distance_rpm": abs(ex - c), "weight": float(by_centre[c]), "model_dz_um": dz}
        )
    out["example_rpm"] = ex
    if state is not None:
        out["state"] = {c: float(state.loc[0, c]) for c in state.columns}
        out["blended_dz_um"] = float(model.predict(state.assign(speed_rpm=ex))[0])
    return out


def write_report_tables(
    model_path, runs_csv, runs_parquet, diagnostics_path, *, fit_path, rmse_path, example_path
) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    """Compute the three tables from the pipeline's files and write them atomically.

    Parameters
    ----------
    model_path, runs_csv, runs_parquet, diagnostics_path : path-like
        ``model.json``, ``runs.csv``, ``runs.parquet`` and ``fit/diagnostics.csv``.
    fit_path, rmse_path, example_path : path-like
        Where ``training_fit.parquet``, ``training_fit.csv`` and ``fuzzy_example.json`` go.

    Returns
    -------
    fit, rmse : DataFrame
    example : dict
    """
    import json
    from pathlib import Path

    from rafi.artefact import jsonable, write_csv_atomic, write_parquet_atomic, write_text_atomic

    runs = pd.read_csv(runs_csv)
    frames = pd.read_parquet(runs_parquet)
    doc = json.loads(Path(model_path).read_text(encoding="utf-8"))
    fit = training_fit(doc, runs, frames)
    rmse = training_rmse(fit)
    example = fuzzy_example(doc, pd.read_csv(diagnostics_path), runs, frames)
    Path(fit_path).parent.mkdir(parents=True, exist_ok=True)
    write_parquet_atomic(fit, fit_path)
    write_csv_atomic(rmse, rmse_path)
    write_text_atomic(example_path, json.dumps(jsonable(example), indent=2) + "\n")
    return fit, rmse, example
