"""Whole-run cross-validation, model comparison and champion choice.

5 s samples are strongly autocorrelated, so a sample-wise split leaks: a test sample's
neighbours, 5 s away, sit in the training set. Every split here is by **whole run**:

* ``leave_one_run_out``: one fold per training run;
* ``leave_one_speed_out``: one fold per training speed (all runs at that speed held out);
  for RAFI this is exactly the situation of a validation speed between two training speeds
  (or beyond the edge, for the lowest / highest speed).

Only runs with ``role == "training"`` are ever split; validation runs never enter model
selection. Every splitter asserts that no run is in both the train and the test set.

:func:`compare_models` validates several fitted models on the validation runs with
:func:`rafi.method.validate.validate_runs` (the pipeline's own definitions of residual and
improvement) and the acceptance gates of :func:`rafi.method.validate.qualify`;
:func:`choose_champion` picks the passer with the lowest worst-case residual.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import pandas as pd

__all__ = [
    "SCHEMES",
    "training_runs",
    "leave_one_run_out",
    "leave_one_speed_out",
    "split_runs",
    "assert_disjoint",
    "subset_runs",
    "cross_validate",
    "compare_models",
    "choose_champion",
    "CV_COLUMNS",
    "COMPARISON_COLUMNS",
]

SPEED_GROUP_TOLERANCE_RPM = 50.0

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
]

COMPARISON_COLUMNS = [
    "model",
    "kind",
    "scope",
    "run_id",
    "role",
    "speed_rpm",
    "n_samples",
    "max_abs_before_um",
    "max_abs_after_um",
    "improvement_pct",
    "rmse_before_um",
    "rmse_after_um",
    "n_outside_temp_range",
    "n_outside_speed_range",
    "worse_than_uncompensated",
    "passed",
    "verdict",
    "champion",
    "model_id",
]


# --------------------------------------------------------------------------- subsets


def training_runs(runs_table: pd.DataFrame, runs_frame: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The ``role == "training"`` rows of ``runs_table`` and their samples in ``runs_frame``.

    This is the only door through which a model's ``fit`` sees data.
    """
    for col in ("run_id", "role", "speed_rpm"):
        if col not in runs_table.columns:
            raise ValueError(f"runs_table lacks column {col!r}")
    table = runs_table.loc[runs_table["role"].astype(str) == "training"]
    ids = set(table["run_id"].astype(str))
    frame = runs_frame.loc[runs_frame["run_id"].astype(str).isin(ids)]
    return table, frame


def subset_runs(
    runs_table: pd.DataFrame, runs_frame: pd.DataFrame, run_ids
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Rows of ``runs_table`` / ``runs_frame`` belonging to ``run_ids`` (whole runs only)."""
    ids = set(map(str, run_ids))
    return (
        runs_table.loc[runs_table["run_id"].astype(str).isin(ids)],
        runs_frame.loc[runs_frame["run_id"].astype(str).isin(ids)],
    )


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
    """Folds ``(train_run_ids, test_run_ids)`` of the training runs under ``scheme``."""
    try:
        fn = SCHEMES[scheme]
    except KeyError:
        raise ValueError(f"unknown CV scheme {scheme!r}; known: {sorted(SCHEMES)}") from None
    return fn(runs_table)


# --------------------------------------------------------------------------- cross-validation


def _metrics(measured: np.ndarray, predicted: np.ndarray) -> dict:
    ok = np.isfinite(measured) & np.isfinite(predicted)
    if not ok.any():
        return {
            "n_samples": 0,
            "max_abs_before_um": np.nan,
            "max_abs_after_um": np.nan,
            "improvement_pct": np.nan,
            "rmse_um": np.nan,
        }
    m, r = measured[ok], measured[ok] - predicted[ok]
    before, after = float(np.max(np.abs(m))), float(np.max(np.abs(r)))
    return {
        "n_samples": int(ok.sum()),
        "max_abs_before_um": before,
        "max_abs_after_um": after,
        "improvement_pct": 100.0 * (before - after) / before if before > 0 else np.nan,
        "rmse_um": float(np.sqrt(np.mean(r**2))),
    }


def cross_validate(
    model_factory: Callable[[], object],
    runs_table: pd.DataFrame,
    runs_frame: pd.DataFrame,
    scheme: str = "leave_one_run_out",
    *,
    name: str = "",
) -> pd.DataFrame:
    """Whole-run CV of the model that ``model_factory()`` builds, on the training runs only.

    Each fold fits a fresh model on the fold's training runs (the held-out runs are
    removed from both ``runs_table`` and ``runs_frame`` before ``fit`` sees them; a model
    with hyperparameters runs its own inner CV on those training runs only) and predicts
    every held-out run as a whole. Metrics per held-out run are those of
    ``docs/design.md`` (``max |dz - predicted|``, improvement, RMSE).

    Returns
    -------
    pandas.DataFrame
        One row per (fold, held-out run), columns :data:`CV_COLUMNS`.
    """
    rows = []
    train_table, _ = training_runs(runs_table, runs_frame)
    speeds = dict(zip(train_table["run_id"].astype(str), train_table["speed_rpm"].astype(float)))
    for k, (train_ids, test_ids) in enumerate(split_runs(runs_table, scheme)):
        assert_disjoint(train_ids, test_ids)
        t_table, t_frame = subset_runs(runs_table, runs_frame, train_ids)
        assert not set(map(str, pd.unique(t_frame["run_id"]))) & set(map(str, test_ids))
        model = model_factory().fit(t_table, t_frame)
        for rid in test_ids:
            _, run = subset_runs(runs_table, runs_frame, [rid])
            if "t_s" in run.columns:
                run = run.sort_values("t_s", kind="stable")
            pred = np.asarray(model.predict(run), dtype=float)
            met = _metrics(run["dz_um"].to_numpy(dtype=float), pred)
            rows.append(
                {
                    "model": name,
                    "scheme": scheme,
                    "fold": k,
                    "test_runs": rid,
                    "test_speed_rpm": speeds.get(rid, np.nan),
                    "n_train_runs": len(train_ids),
                    **met,
                }
            )
    return pd.DataFrame(rows, columns=CV_COLUMNS)


# --------------------------------------------------------------------------- comparison


def _model_kind(model) -> str:
    return str(getattr(model, "kind", None) or model.to_dict().get("kind", type(model).__name__))


def compare_models(
    models: dict,
    runs_table: pd.DataFrame,
    runs_frame: pd.DataFrame,
    gates: dict,
    *,
    return_residuals: bool = False,
):
    """Validate every fitted model on the validation runs and qualify it against ``gates``.

    Parameters
    ----------
    models : dict[str, fitted model]
        Name -> anything with ``predict_detail`` (family models or a ``RafiModel``).
    gates : dict
        The config ``qualification:`` section (see :func:`rafi.method.validate.qualify`).

    Returns
    -------
    summary : pandas.DataFrame
        Columns :data:`COMPARISON_COLUMNS`: one ``scope == "run"`` row per model and
        validation run, and one ``scope == "model"`` row per model with the worst case
        (``max_abs_after_um`` = worst max residual, ``improvement_pct`` = minimum over the
        runs, ``rmse_after_um`` = worst, counts summed, ``passed`` = every gate of every
        run passed, ``verdict`` pass/fail, ``champion`` from :func:`choose_champion`).
    residuals : pandas.DataFrame (only with ``return_residuals=True``)
        :func:`rafi.method.validate.validate_runs` residuals with a ``model`` column.
    """
    from rafi.method.validate import qualify, validate_runs

    parts, res_parts = [], []
    for name, model in models.items():
        summary, residuals = validate_runs(model, runs_table, runs_frame)
        verdict = qualify(summary, gates)
        passed_run = verdict.groupby(verdict["run_id"].astype(str))["passed"].all()
        s = summary.copy()
        s["passed"] = s["run_id"].astype(str).map(passed_run).fillna(False).astype(bool)
        s["model"], s["kind"], s["scope"] = name, _model_kind(model), "run"
        try:
            s["model_id"] = model.to_dict().get("model_id", "")
        except Exception:  # noqa: BLE001 - an unfitted or foreign object: id unknown
            s["model_id"] = ""
        s["verdict"] = np.where(s["passed"], "pass", "fail")
        parts.append(s)
        if return_residuals:
            res_parts.append(residuals.assign(model=name))
        overall = bool(len(verdict) and verdict["passed"].all())
        parts.append(
            pd.DataFrame(
                [
                    {
                        "model": name,
                        "kind": s["kind"].iloc[0] if len(s) else _model_kind(model),
                        "scope": "model",
                        "run_id": "all",
                        "role": "all",
                        "speed_rpm": np.nan,
                        "n_samples": int(s["n_samples"].sum()),
                        "max_abs_before_um": float(s["max_abs_before_um"].max()) if len(s) else np.nan,
                        "max_abs_after_um": float(s["max_abs_after_um"].max()) if len(s) else np.nan,
                        "improvement_pct": float(s["improvement_pct"].min()) if len(s) else np.nan,
                        "rmse_before_um": float(s["rmse_before_um"].max()) if len(s) else np.nan,
                        "rmse_after_um": float(s["rmse_after_um"].max()) if len(s) else np.nan,
                        "n_outside_temp_range": int(s["n_outside_temp_range"].sum()),
                        "n_outside_speed_range": int(s["n_outside_speed_range"].sum()),
                        "worse_than_uncompensated": bool(s["worse_than_uncompensated"].any()),
                        "passed": overall,
                        "verdict": "pass" if overall else "fail",
                        "model_id": s["model_id"].iloc[0] if len(s) else "",
                    }
                ]
            )
        )
    out = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=COMPARISON_COLUMNS)
    out["champion"] = False
    champ = choose_champion(out)
    if champ is not None:
        out.loc[out["model"] == champ, "champion"] = True
    out = out[COMPARISON_COLUMNS]
    if return_residuals:
        res = pd.concat(res_parts, ignore_index=True) if res_parts else pd.DataFrame()
        return out, res
    return out


def choose_champion(summary: pd.DataFrame, *, require_pass: bool = True) -> str | None:
    """The model that passes every gate with the lowest worst-case max residual.

    Ties are broken by the higher minimum improvement, then the simpler kind
    (rafi_linear, ridge_global, dynamic, grey_box), then by name. Returns ``None`` if
    no model passes (``require_pass=False``: the lowest worst case regardless of gates).
    """
    m = summary.loc[summary["scope"] == "model"]
    if require_pass:
        m = m.loc[m["passed"].astype(bool)]
    m = m.dropna(subset=["max_abs_after_um"])
    if m.empty:
        return None
    order = {"rafi_linear": 0, "ridge_global": 1, "dynamic": 2, "grey_box": 3}  # simpler first on exact ties
    kinds = m["kind"] if "kind" in m.columns else m["model"]
    m = m.assign(
        _res=m["max_abs_after_um"].astype(float).round(9),
        _imp=-m["improvement_pct"].astype(float).fillna(-np.inf),
        _cx=kinds.map(order).fillna(4),
    )
    m = m.sort_values(["_res", "_imp", "_cx", "model"], kind="stable")
    return str(m["model"].iloc[0])
