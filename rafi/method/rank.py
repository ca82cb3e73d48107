"""Key temperature sensors: Pearson correlation of each sensor's rise with the displacement.

The paper keeps the sensors whose temperature-displacement Pearson ``|r|`` exceeds
0.97 (fewer than 4; result T6, T8, T9) but does not say whether ``r`` is computed
per speed or over all runs. We compute both, on the rises ``dT_i`` and ``dz_um``
relative to each run's reference state, over the *training* runs only:

* one scope per training speed (``scope`` = the speed as text, e.g. ``"3000"``),
  pooling all training runs at that speed;
* ``"pooled"``: all training runs together.

Selection score:

* ``scope="min_per_speed"`` (default): a sensor's score is its minimum ``|r|``
  over the training speeds, i.e. it must pass the threshold at *every* speed,
  since every per-speed regression uses the same key sensors;
* ``scope="pooled"``: the pooled ``|r|``.

Sensors with ``score > threshold`` are kept, best first, at most
``max_key_sensors``. If fewer pass, the set is filled up to ``max_key_sensors``
with the next best sensors by score, marked ``selected_by="fallback"``, and
``info["fallback_used"]`` is True with a message saying so. ``r`` is computed on the
samples where both the rise and ``dz`` are present: a logger dropout left after
cleaning (too long to interpolate) only removes those samples. A sensor present in
fewer than ``min_coverage`` (90 %) of a scope's samples, or with zero variance, gets
``r = NaN`` there and is never selected (with ``min_per_speed`` a NaN at any speed
makes its score NaN). Ties are broken by sensor number.

Pearson ranking ignores that the chosen sensors correlate with each other;
``collinearity`` (sensor x sensor ``r`` of the chosen rises) makes that visible.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from rafi.contract.sensors import run_sensors
from rafi.errors import SettingsError
from rafi.settings import MACHINE_DEFAULTS

__all__ = [
    "RankResult",
    "rank_sensors",
    "speed_training_runs",
    "training_speed_groups",
    "SPEED_GROUP_TOLERANCE_RPM",
]

SPEED_GROUP_TOLERANCE_RPM = 50.0
"""Training runs whose ``speed_rpm`` differ by at most this are one training speed."""

SCOPES = ("min_per_speed", "pooled")


@dataclass
class RankResult:
    """Output of :func:`rank_sensors`.

    Attributes
    ----------
    correlation : pandas.DataFrame
        Long table ``scope``, ``sensor``, ``r``, ``abs_r``, ``rank`` (1 = best within
        the scope; missing for NaN ``r``).
    key_sensors : pandas.DataFrame
        ``sensor``, ``score_abs_r``, ``selected_by`` (``threshold`` / ``fallback``).
    info : dict
        JSON-serialisable ``{sensors, threshold, scope, max_key_sensors,
        fallback_used, message}``.
    collinearity : pandas.DataFrame
        Pearson ``r`` between the chosen sensors' rises, training runs pooled;
        index and columns are the sensor names.
    """

    correlation: pd.DataFrame
    key_sensors: pd.DataFrame
    info: dict
    collinearity: pd.DataFrame


def _speed_label(v: float) -> int | float:
    v = float(v)
    r = round(v)
    return int(r) if abs(v - r) < 1e-9 else v


def speed_training_runs(runs_table: pd.DataFrame) -> pd.DataFrame:
    """The training runs RAFI as published learns from: ``role == "training"`` and, where the
    table has a ``kind``, constant speed (idle cool-downs and varying stretches that a time
    window or ``runs.idle_training`` made training runs are for the family's models only)."""
    train = runs_table.loc[runs_table["role"].astype(str) == "training"]
    if "kind" in train.columns:
        train = train.loc[~train["kind"].astype(str).isin(["idle", "varying"])]
    return train


def training_speed_groups(
    runs_table: pd.DataFrame, *, tolerance_rpm: float = SPEED_GROUP_TOLERANCE_RPM
) -> dict:
    """Group the training runs by training speed.

    Runs of :func:`speed_training_runs` are sorted by ``speed_rpm``; a run joins the
    current group if its speed is within ``tolerance_rpm`` of the group's first
    run. The group's label is its median speed rounded to an integer r/min (the
    runs step normally already reports the nominal speed).

    Returns
    -------
    dict
        ``{speed_label (int): [run_id, ...]}``, increasing speed.

    Raises
    ------
    ValueError
        If ``runs_table`` lacks a column.
    rafi.errors.SettingsError
        If there are no training runs (the workflow's runs step says so earlier, with the speeds
        the logs hold: :func:`rafi.method.run_checks.training_speed_problems`).
    """
    for col in ("run_id", "role", "speed_rpm"):
        if col not in runs_table.columns:
            raise ValueError(f"runs_table lacks column {col!r}")
    train = speed_training_runs(runs_table)[["run_id", "speed_rpm"]]
    train = train.dropna(subset=["speed_rpm"])
    if train.empty:
        raise SettingsError(
            "training_speeds_rpm: the runs table has no constant-speed run with role 'training' "
            "(and a speed): set training_speeds_rpm to the speeds the machine was trained at, or "
            "give training windows (runs.windows)"
        )
    train = train.sort_values(["speed_rpm", "run_id"], kind="stable")
    groups: list[tuple[list[float], list[str]]] = []
    for run_id, speed in zip(train["run_id"].astype(str), train["speed_rpm"].astype(float)):
        if groups and speed - groups[-1][0][0] <= tolerance_rpm:
            groups[-1][0].append(speed)
            groups[-1][1].append(run_id)
        else:
            groups.append(([speed], [run_id]))
    return {int(round(float(np.median(s)))): ids for s, ids in groups}


def trained_speeds(runs_table: pd.DataFrame) -> list[float] | None:
    """The speeds of the constant training runs as RAFI groups them
    (:func:`training_speed_groups`), increasing; None where there is none."""
    try:
        return [float(v) for v in training_speed_groups(runs_table)]
    except SettingsError:
        return None


def _sensor_columns(runs_frame: pd.DataFrame) -> list[str]:
    return list(run_sensors(runs_frame))


def _pearson(
    dt: np.ndarray, dz: np.ndarray, min_coverage: float = MACHINE_DEFAULTS["rank"]["min_coverage"]
) -> np.ndarray:
    """Pearson r of each column of ``dt`` [n, m] with ``dz`` [n] over the rows where
    both are finite; NaN if a column is finite in fewer than ``min_coverage`` of the
    rows or has (near) zero variance there."""
    n, m = dt.shape
    out = np.full(m, np.nan)
    if n < 3:
        return out
    for j in range(m):
        ok = np.isfinite(dt[:, j]) & np.isfinite(dz)
        if ok.sum() < max(3, min_coverage * n):
            continue
        col, z = dt[ok, j], dz[ok]
        zc = z - z.mean()
        sz = np.sqrt(np.sum(zc * zc))
        if not np.isfinite(sz) or sz == 0:
            continue
        n = int(ok.sum())
        xc = col - col.mean()
        sx = np.sqrt(np.sum(xc * xc))
        if sx <= 1e-12 * max(1.0, float(np.max(np.abs(col)))) * np.sqrt(n):
            continue
        out[j] = float(np.clip(np.sum(xc * zc) / (sx * sz), -1.0, 1.0))
    return out


def _scope_table(scope: str, sensors: list[str], r: np.ndarray) -> pd.DataFrame:
    tab = pd.DataFrame({"scope": scope, "sensor": sensors, "r": r, "abs_r": np.abs(r)})
    tab["rank"] = tab["abs_r"].rank(ascending=False, method="min").astype("Int64")
    return tab


def rank_sensors(
    runs_table: pd.DataFrame,
    runs_frame: pd.DataFrame,
    *,
    threshold: float = MACHINE_DEFAULTS["rank"]["threshold"],
    max_key_sensors: int = MACHINE_DEFAULTS["rank"]["max_key_sensors"],
    scope: str = MACHINE_DEFAULTS["rank"]["scope"],
    min_coverage: float = MACHINE_DEFAULTS["rank"]["min_coverage"],
) -> RankResult:
    """Rank the temperature sensors by correlation with the displacement; pick key sensors.

    Parameters
    ----------
    runs_table : pandas.DataFrame
        One row per run (``run_id``, ``role``, ``speed_rpm``, ...); only
        ``role == "training"`` runs are used.
    runs_frame : pandas.DataFrame
        Stacked samples with ``run_id``, the rises ``dT1``..``dT16`` and ``dz_um``.
    threshold : float, default 0.97
        Keep sensors with score ``> threshold`` (paper: 0.97).
    max_key_sensors : int, default 3
        At most this many (paper: "fewer than 4"); fewer passing sensors are
        topped up by the next best (``selected_by="fallback"``).
    scope : {"min_per_speed", "pooled"}
        Selection score, see the module docstring.
    min_coverage : float, default 0.9
        Smallest share of a scope's samples in which a sensor must be present to
        get a correlation there.

    Returns
    -------
    RankResult

    Raises
    ------
    ValueError
        Bad arguments, no training runs, or no sensor with a finite score.
    """
    max_key_sensors = _checked_arguments(threshold, max_key_sensors, scope)
    if "dz_um" not in runs_frame.columns or "run_id" not in runs_frame.columns:
        raise ValueError("runs_frame needs columns 'run_id' and 'dz_um'")
    sensors = _sensor_columns(runs_frame)
    if not sensors:
        raise ValueError("runs_frame has no rise columns dT1..dT16")

    correlation, per_speed, pooled, r_pooled = scope_correlations(
        runs_frame, training_speed_groups(runs_table), sensors, min_coverage
    )
    score, where, score_name = selection_score(scope, per_speed, r_pooled)
    passing, chosen, fallback = choose_sensors(score, threshold, max_key_sensors)
    names = [sensors[j] for j in chosen + fallback]
    message = selection_message(
        sensors,
        score,
        passing,
        chosen,
        fallback,
        threshold=threshold,
        max_key_sensors=max_key_sensors,
        where=where,
        score_name=score_name,
    )
    key_sensors = pd.DataFrame(
        {
            "sensor": names,
            "score_abs_r": [float(score[j]) for j in chosen + fallback],
            "selected_by": ["threshold"] * len(chosen) + ["fallback"] * len(fallback),
        }
    )
    info = {
        "sensors": names,
        "threshold": float(threshold),
        "scope": scope,
        "max_key_sensors": max_key_sensors,
        "fallback_used": bool(fallback),
        "message": message,
    }
    return RankResult(
        correlation=correlation, key_sensors=key_sensors, info=info, collinearity=collinearity(pooled, names)
    )


def _checked_arguments(threshold: float, max_key_sensors, scope: str) -> int:
    """``max_key_sensors`` as an int; ValueError on a bad scope, threshold or count."""
    if scope not in SCOPES:
        raise ValueError(f"scope={scope!r}; expected one of {SCOPES}")
    if not 0 <= threshold <= 1:
        raise ValueError(f"threshold={threshold}; expected a |r| between 0 and 1")
    if int(max_key_sensors) != max_key_sensors or max_key_sensors < 1:
        raise ValueError(f"max_key_sensors={max_key_sensors}; expected an integer >= 1")
    return int(max_key_sensors)


def scope_correlations(
    runs_frame: pd.DataFrame, groups: dict, sensors: list[str], min_coverage: float
) -> tuple[pd.DataFrame, list[np.ndarray], pd.DataFrame, np.ndarray]:
    """Pearson r of each sensor's rise with ``dz_um`` per training speed and pooled.

    Parameters
    ----------
    runs_frame : pandas.DataFrame
        Stacked samples (``run_id``, ``dT<i>`` of ``sensors``, ``dz_um``).
    groups : dict
        Training speed -> run ids (:func:`training_speed_groups`).
    sensors : list of str
        Sensor names whose rises are correlated.
    min_coverage : float
        See :func:`rank_sensors`.

    Returns
    -------
    correlation : pandas.DataFrame
        The long table (one scope per speed, then ``pooled``).
    per_speed_abs : list of numpy.ndarray
        ``|r|`` per sensor at each speed, in the order of ``groups``.
    pooled : pandas.DataFrame
        The pooled training samples with a displacement.
    r_pooled : numpy.ndarray
        Pooled r per sensor.
    """
    dcols = [f"d{s}" for s in sensors]
    run_ids = runs_frame["run_id"].astype(str)

    def pearson_of(samples: pd.DataFrame) -> np.ndarray:
        return _pearson(
            samples[dcols].to_numpy(dtype=float, na_value=np.nan),
            samples["dz_um"].to_numpy(dtype=float),
            min_coverage,
        )

    tables, per_speed_abs, train_ids = [], [], []
    for speed, ids in groups.items():
        train_ids.extend(ids)
        r = pearson_of(runs_frame.loc[run_ids.isin(ids) & runs_frame["dz_um"].notna()])
        tables.append(_scope_table(str(speed), sensors, r))
        per_speed_abs.append(np.abs(r))
    pooled = runs_frame.loc[run_ids.isin(train_ids) & runs_frame["dz_um"].notna()]
    r_pooled = pearson_of(pooled)
    tables.append(_scope_table("pooled", sensors, r_pooled))
    return pd.concat(tables, ignore_index=True), per_speed_abs, pooled, r_pooled


def selection_score(
    scope: str, per_speed_abs: list[np.ndarray], r_pooled: np.ndarray
) -> tuple[np.ndarray, str, str]:
    """Each sensor's selection score, where it was measured and its name (for the message).

    ``min_per_speed``: the smallest ``|r|`` over the training speeds (NaN at any speed: NaN);
    ``pooled``: the pooled ``|r|``.
    """
    if scope == "min_per_speed":
        stack = np.vstack(per_speed_abs)
        score = np.where(np.isnan(stack).any(axis=0), np.nan, stack.min(axis=0))
        return score, "at every training speed", "min |r|"
    return np.abs(r_pooled), "over the pooled training runs", "pooled |r|"


def choose_sensors(score: np.ndarray, threshold: float, max_key_sensors: int) -> tuple[list, list, list]:
    """Indices of the sensors passing ``threshold``, of those chosen (best first, at most
    ``max_key_sensors``) and of the next best added as fallback up to ``max_key_sensors``.

    Sensors with a NaN score are never chosen; ties go to the lower index.

    Raises
    ------
    ValueError
        No sensor has a finite score.
    """
    finite = np.flatnonzero(np.isfinite(score))
    if finite.size == 0:
        raise ValueError(
            "no sensor has a finite correlation with dz_um in the training runs "
            "(all rises missing or constant?)"
        )
    order = finite[np.lexsort((finite, -score[finite]))]  # best first; ties by sensor number
    passing = [j for j in order if score[j] > threshold]
    chosen = passing[:max_key_sensors]
    fallback = [j for j in order if j not in chosen][: max_key_sensors - len(chosen)]
    return passing, chosen, fallback


def selection_message(
    sensors, score, passing, chosen, fallback, *, threshold, max_key_sensors, where, score_name
) -> str:
    """The choice of key sensors in words (``key_sensors.json`` ``message``)."""

    def fmt(js):
        return ", ".join(f"{sensors[j]} ({score_name} {score[j]:.3f})" for j in js)

    n_pass = len(passing)
    if n_pass == 0:
        head = f"no sensor reaches |r| > {threshold:g} {where}"
    elif n_pass == 1:
        head = f"1 sensor reaches |r| > {threshold:g} {where}"
    else:
        head = f"{n_pass} sensors reach |r| > {threshold:g} {where}"
    if fallback:
        added = ", ".join(sensors[j] for j in fallback)
        message = (
            f"{'' if n_pass == 0 else 'only '}{head}; {added} added as the next best "
            f"({'; '.join(f'{score_name} {score[j]:.3f}' for j in fallback)})"
        )
        if len(chosen) + len(fallback) < max_key_sensors:
            message += (
                f"; only {len(chosen) + len(fallback)} sensor(s) have a finite correlation, "
                f"fewer than max_key_sensors={max_key_sensors}"
            )
        return message
    if n_pass > max_key_sensors:
        return f"{head}; the best {max_key_sensors} kept: {fmt(chosen)}"
    return f"{head}: {fmt(chosen)}"


def collinearity(pooled: pd.DataFrame, names: list[str]) -> pd.DataFrame:
    """Pearson r between the rises of the sensors ``names`` over the samples ``pooled``; index
    (named ``sensor``) and columns are the sensor names."""
    coll = pooled[[f"d{s}" for s in names]].astype(float).corr(method="pearson")
    coll.index = pd.Index(names, name="sensor")
    coll.columns = pd.Index(names)
    return coll
