"""The files the qualification report reads, and the small lookups every part of it shares.

Inputs are the tables of ``docs/design.md`` under ``results/<machine>/``, the tables rule
``report_tables`` writes for the report (``report/*``: what the report shows that comes from
evaluating the model) and the figure files of rule ``report_figures``
(``report/figures/<group>/``). Optional inputs (sections rendered only when present):

- ``input_status.json`` - files rejected at machine level and the input warnings;
- ``registry/decision.json`` + ``registry/comparison.csv`` - the registry decision;
- ``comparison/summary.csv``, ``per_run.csv``, ``cv.csv``, ``best_model.json`` - the model family
  comparison and the artefact of the model it offers;
- ``deploy/replay_summary.csv`` - the replay of the model on the machine (rule ``replay``);
- ``runs.parquet`` - every logged sample: the test record (log spans, sample period, ambient
  temperature, thermal drift per run; :mod:`rafi.report.test_record`) and the figures.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pandas as pd

from rafi import contract
from rafi.method.rank import speed_training_runs
from rafi.report.format import speed_key

#: Files under ``results/<machine>/`` the report needs (names of :data:`rafi.contract.RESULT_FILES`).
RESULT_FILES = {name: contract.RESULT_FILES[name] for name in contract.REPORT_REQUIRED}

#: Optional inputs: a section is left out when its file is absent.
OPTIONAL_FILES = {name: contract.RESULT_FILES[name] for name in contract.REPORT_OPTIONAL}

#: Inputs of rule report_figures besides those above (read by the figure job only).
FIGURE_INPUT_FILES = {
    name: contract.RESULT_FILES[name]
    for group in contract.FIGURE_GROUPS.values()
    for name in group
    if name not in RESULT_FILES and name not in OPTIONAL_FILES
}

#: Figure folder of each group (rule report_figures), under ``results/<machine>/``.
FIGURE_DIRS = {group: contract.result_file("figures", group=group) for group in contract.FIGURE_GROUPS}


def result_paths(results_dir: str | os.PathLike) -> dict:
    """Standard path of every input under ``results/<machine>/`` (optional and figure inputs included)."""
    base = Path(results_dir)
    names = {**RESULT_FILES, **OPTIONAL_FILES, **FIGURE_INPUT_FILES}
    return {k: base / v for k, v in names.items()}


def figure_dirs(results_dir: str | os.PathLike) -> dict:
    """Figure folder of each group under ``results/<machine>/``: ``{group: path}``."""
    return {group: Path(results_dir) / rel for group, rel in FIGURE_DIRS.items()}


def load_results(paths: dict) -> dict:
    """Read every table that exists; missing ones become ``None``.

    Parameters
    ----------
    paths : dict
        name -> path (names of :data:`RESULT_FILES`, :data:`OPTIONAL_FILES`,
        :data:`FIGURE_INPUT_FILES`).

    Returns
    -------
    dict
        name -> DataFrame (CSV, Parquet), parsed JSON, or ``None``.
    """
    out: dict = {}
    for name, p in paths.items():
        p = Path(p) if p else None
        if p is None or not p.is_file():
            out[name] = None
            continue
        if p.suffix == ".csv":
            out[name] = pd.read_csv(p, keep_default_na=True)
        elif p.suffix == ".parquet":
            out[name] = pd.read_parquet(p)
        elif p.suffix == ".json":
            out[name] = json.loads(p.read_text(encoding="utf-8"))
        else:
            out[name] = p.read_text(encoding="utf-8")
    return out


def training_runs(runs: pd.DataFrame | None) -> dict:
    """``speed -> run id`` of the training runs in ``runs.csv`` (the last one per speed)."""
    if runs is None:
        return {}
    tr = speed_training_runs(runs)
    return {speed_key(r.speed_rpm): r.run_id for r in tr.itertuples(index=False)}


def sensors(res: dict, coolant_sensors) -> tuple[dict, list, list]:
    """``(key_sensors.json, key sensors, coolant sensors drawn beside them)``.

    Parameters
    ----------
    res : dict
        Loaded inputs (:func:`load_results`); ``key_sensors_json`` and ``model`` are read.
    coolant_sensors : list of str
        ``report.coolant_sensors`` of the machine's settings.
    """
    model = res.get("model") or {}
    key_info = res.get("key_sensors_json") or {}
    key = list(key_info.get("sensors") or model.get("key_sensors") or [])
    coolant = [c for c in coolant_sensors if c not in key]
    return key_info, key, coolant


def correlation_wide(corr: pd.DataFrame) -> pd.DataFrame:
    """``rank/correlation.csv`` as |r| by scope (rows: speeds in order, then pooled) and sensor."""
    corr = corr.copy()
    corr["scope"] = corr["scope"].astype(str)
    wide = corr.pivot_table(index="scope", columns="sensor", values="abs_r", aggfunc="first")
    names = sorted(wide.columns, key=lambda s: (len(s), s))
    scopes = sorted(
        wide.index,
        key=lambda s: (not s.replace(".", "").isdigit(), float(s) if s.replace(".", "").isdigit() else 0),
    )
    return wide.loc[scopes, names]


def collinearity_frame(coll: pd.DataFrame) -> pd.DataFrame:
    """``rank/collinearity.csv`` as a square frame indexed by sensor name."""
    first = coll.columns[0]
    if not pd.api.types.is_numeric_dtype(coll[first]):
        coll = coll.set_index(first)
    coll.index = [str(i) for i in coll.index]
    return coll


def chosen_sensors(key_info: dict, key_sensors: pd.DataFrame | None) -> list:
    """The key sensors: ``key_sensors.json`` ``sensors``, else ``rank/key_sensors.csv``."""
    return list(
        key_info.get("sensors") or (key_sensors["sensor"].tolist() if key_sensors is not None else [])
    )


def noise_floors(res: dict) -> dict:
    """``run_id -> noise floor (um)`` of every validation run: the expected max |noise| estimated
    from the run's own measured dz (:func:`rafi.method.validate.run_noise_floor`), a property of
    the run, the same for every model. Every place of the report that states a run's noise floor
    reads it here (or through :func:`model_noise_floors`), so a run has one figure on every page.
    From ``validation/summary.csv``, else ``comparison/per_run.csv`` (they agree; results written
    before the floor was the run's own counted only the samples each model compensated, and
    then ``validation/summary.csv`` is the one shown). Results written before the noise floor
    existed give an empty dict."""
    out: dict = {}
    for name in ("comparison_per_run", "validation_summary"):
        t = res.get(name)
        if t is None or "noise_floor_um" not in t or "run_id" not in t:
            continue
        for rid, v in zip(t["run_id"].astype(str), pd.to_numeric(t["noise_floor_um"], errors="coerce")):
            if pd.notna(v):
                out[rid] = float(v)
    return out


def model_noise_floors(res: dict) -> dict:
    """``model -> noise floor (um)`` of the validation run where the model leaves its largest
    max |residual| (``comparison/per_run.csv``), read from :func:`noise_floors`: the floor
    beside a model's worst residual. Without ``per_run.csv`` (or that run's floor), the
    ``noise_floor_um`` of the model's row of ``comparison/summary.csv`` (the same run's)."""
    out: dict = {}
    summary = res.get("comparison")
    if summary is not None and {"model", "noise_floor_um"} <= set(summary.columns):
        floors = pd.to_numeric(summary["noise_floor_um"], errors="coerce")
        for name, v in zip(summary["model"].astype(str), floors):
            if pd.notna(v):
                out[name] = float(v)
    per_run = res.get("comparison_per_run")
    if per_run is None or not {"model", "run_id", "max_abs_after_um"} <= set(per_run.columns):
        return out
    noise = noise_floors(res)
    after = per_run.assign(
        model=per_run["model"].astype(str),
        run_id=per_run["run_id"].astype(str),
        after=pd.to_numeric(per_run["max_abs_after_um"], errors="coerce"),
    ).dropna(subset=["after"])
    for name, rows in after.groupby("model", sort=False):
        worst = str(rows.loc[rows["after"].idxmax(), "run_id"])
        if worst in noise:
            out[name] = noise[worst]
    return out
