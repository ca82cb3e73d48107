"""Drift checks: has the champion in service degraded on the validation logs it has not seen?

Two checks, both on the validation runs whose files were not known at the champion's promotion
(:func:`new_validation_runs`):

* :func:`drift_check` - its largest max |residual| against the one at promotion plus a margin;
* :func:`interval_drift` - do the new samples fall outside its prediction interval more often
  than the interval's level allows? A one-sided binomial test at a stated false-alarm rate on
  samples thinned to one per ``decorrelation_s`` (:func:`thin_by_run`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import pandas as pd

from rafi.ops.gates import fmt_value, gated_runs
from rafi.ops.status import interval_evidence

VALIDATION_ROLES = ("validation_single", "validation_multi", "validation_idle")


def validation_runs(runs_table: pd.DataFrame) -> pd.DataFrame:
    if "role" not in runs_table:
        return runs_table.iloc[0:0]
    return runs_table[runs_table["role"].astype(str).isin(VALIDATION_ROLES)]


def new_validation_runs(runs_table: pd.DataFrame, known_files: dict | None) -> list[str]:
    """Validation runs whose file (by sha256, else by name) was not known at promotion."""
    if known_files is None:
        return []
    val = validation_runs(runs_table)
    hashes = set(known_files.values())
    names = set(known_files)
    new = []
    for rec in val.to_dict("records"):
        sha = rec.get("sha256")
        if isinstance(sha, str) and sha:
            is_new = sha not in hashes
        else:
            is_new = str(rec.get("file")) not in names
        if is_new:
            new.append(str(rec["run_id"]))
    return new


def drift_check(
    champion_summary: pd.DataFrame | None,
    new_run_ids: Iterable[str],
    reference_max_residual_um: float | None,
    margin_um: float,
) -> dict:
    """Has the champion degraded on the newest validation logs?

    ``new_max`` = champion's largest max|residual| over ``new_run_ids``; drift is
    detected when ``new_max > reference + margin`` where ``reference`` is the
    champion's max residual at promotion time (from the history).
    Returns a dict with ``status`` (ok / degraded / no_new_runs / no_reference /
    no_champion), ``detected`` and the numbers.
    """
    new_run_ids = [str(r) for r in new_run_ids]
    out = {
        "status": "ok",
        "detected": False,
        "margin_um": float(margin_um),
        "reference_max_residual_um": reference_max_residual_um,
        "new_runs": new_run_ids,
        "new_max_residual_um": None,
        "limit_um": None,
        "degradation_um": None,
        "per_run": {},
    }
    if champion_summary is None:
        out["status"] = "no_champion"
        return out
    if not new_run_ids:
        out["status"] = "no_new_runs"
        return out
    rows = gated_runs(champion_summary)
    rows = rows[rows["run_id"].astype(str).isin(new_run_ids)]
    if rows.empty:
        out["status"] = "no_new_runs"
        return out
    per_run = {str(r): float(v) for r, v in zip(rows["run_id"], rows["max_abs_after_um"])}
    new_max = max(per_run.values())
    out["per_run"] = per_run
    out["new_max_residual_um"] = new_max
    if reference_max_residual_um is None:
        out["status"] = "no_reference"
        return out
    ref = float(reference_max_residual_um)
    out["limit_um"] = ref + float(margin_um)
    out["degradation_um"] = new_max - ref
    if new_max > ref + float(margin_um):
        out["status"] = "degraded"
        out["detected"] = True
    return out


#: The columns of a residual frame the interval drift test reads (besides ``run_id`` and ``t_s``).
INTERVAL_COLUMNS = ("measured_um", "lower_um", "upper_um")


def thin_by_run(residuals: pd.DataFrame, decorrelation_s: float) -> pd.DataFrame:
    """One sample per ``decorrelation_s`` of each run: the samples a binomial test may count.

    Only samples with a finite time, measurement and interval count. In each run (in time
    order) the first such sample is kept, then the first one at least ``decorrelation_s``
    after the last kept one, and so on. Why: within a run, whether a sample lies outside the
    interval is strongly correlated with whether its neighbours do (the residual of a thermal
    model is a slow error, not white noise), so k exceedances out of n raw samples are not a
    binomial count; a test on every sample would alarm on a healthy machine whenever one run
    happens to sit near the edge of its interval for a while. ``decorrelation_s`` is the
    spacing at which the exceedances of the calibration residuals are about independent (the
    artefact's ``interval.decorrelation_s``). Runs are separate logs or separate parts of a
    log, so each starts afresh.

    Parameters
    ----------
    residuals : pandas.DataFrame
        ``run_id``, ``t_s`` and :data:`INTERVAL_COLUMNS`.
    decorrelation_s : float
        Minimum spacing (s) of the kept samples; 0 keeps every usable sample.

    Returns
    -------
    pandas.DataFrame
        The kept rows (original columns), in run order then time order.
    """
    cols = ["t_s", *INTERVAL_COLUMNS]
    values = residuals[cols].apply(pd.to_numeric, errors="coerce").to_numpy(dtype=float)
    usable = residuals.loc[np.isfinite(values).all(axis=1)]
    kept = []
    for _, run in usable.groupby(usable["run_id"].astype(str), sort=True):
        run = run.sort_values("t_s", kind="stable")
        t = run["t_s"].to_numpy(dtype=float)
        if decorrelation_s <= 0:
            kept.append(run)
            continue
        picks = [0]
        while True:
            nxt = int(np.searchsorted(t, t[picks[-1]] + decorrelation_s, side="left"))
            if nxt >= len(t):
                break
            picks.append(nxt)
        kept.append(run.iloc[picks])
    return pd.concat(kept) if kept else usable.iloc[0:0]


def _interval_settings(interval: Mapping | None) -> tuple[float, float] | str:
    """``(level, decorrelation_s)`` of an artefact's ``interval`` block, or why there is none."""
    if not isinstance(interval, Mapping):
        return "the champion's artefact has no interval block (a model from before intervals)"
    try:
        level = float(interval["level"])
        spacing = float(interval["decorrelation_s"])
    except (KeyError, TypeError, ValueError):
        return "the champion's interval block has no numeric level and decorrelation_s"
    if not (0.0 < level < 1.0) or not math.isfinite(spacing) or spacing < 0:
        return f"the champion's interval has level {level} and decorrelation_s {spacing}: not usable"
    return level, spacing


def interval_drift(
    residuals: pd.DataFrame | None,
    new_run_ids: Iterable[str],
    interval: Mapping | None,
    false_alarm: float,
) -> dict:
    """Do the new validation samples fall outside the champion's interval too often?

    The samples of ``new_run_ids`` are thinned (:func:`thin_by_run`, one per
    ``interval["decorrelation_s"]``); ``k`` of the ``n`` left lie outside ``[lower_um,
    upper_um]``. Under H0 (the machine is as calibrated) each does so with a probability of at
    most ``1 - level``; the one-sided binomial p-value is P(K >= k) for K ~ Bin(n, 1 - level).
    A p-value below ``false_alarm`` rejects H0: ``recalibration_due``. On an unchanged machine
    this alarms in at most a ``false_alarm`` fraction of the nights (fewer: the binomial is
    discrete); the thinning is what makes the count binomial.

    Parameters
    ----------
    residuals : pandas.DataFrame or None
        The champion's residuals on tonight's validation runs (``validation_runs``' frame:
        ``run_id``, ``t_s``, ``measured_um``, ``lower_um``, ``upper_um``); None: not available.
    new_run_ids : iterable of str
        The validation runs not known at its promotion.
    interval : mapping or None
        The champion artefact's ``interval`` block (``level``, ``decorrelation_s``).
    false_alarm : float
        ``nightly.drift_false_alarm``.

    Returns
    -------
    dict
        ``status`` (``ok``, ``recalibration_due``, ``no_new_runs``, ``no_interval`` - no interval
        columns, block or finite interval on the new runs; ``reason`` says which), ``detected``,
        the evidence ``n``, ``k``, ``expected_k``, ``observed_rate``, ``allowed_rate``, ``level``,
        ``p_value``, ``false_alarm``, ``decorrelation_s``, ``n_samples`` (usable before thinning)
        and ``per_run`` (run -> ``n``, ``k``, ``n_samples``); ``runs`` the new runs.
    """
    runs = sorted({str(r) for r in new_run_ids})
    out = {
        "status": "ok",
        "detected": False,
        "false_alarm": float(false_alarm),
        "runs": runs,
        "level": None,
        "decorrelation_s": None,
        "n_samples": None,
        "n": None,
        "k": None,
        "expected_k": None,
        "observed_rate": None,
        "allowed_rate": None,
        "p_value": None,
        "per_run": {},
        "reason": None,
    }
    if not runs:
        return out | {"status": "no_new_runs"}
    settings = _interval_settings(interval)
    if isinstance(settings, str):
        return out | {"status": "no_interval", "reason": settings}
    level, spacing = settings
    allowed = round(1.0 - level, 12)  # 0.1, not 0.09999999999999998, in decision.json
    out.update(level=level, decorrelation_s=spacing, allowed_rate=allowed)
    missing = [c for c in ("run_id", "t_s", *INTERVAL_COLUMNS) if residuals is None or c not in residuals]
    if missing:
        what = "no residuals of the champion" if residuals is None else f"no column {', '.join(missing)}"
        return out | {"status": "no_interval", "reason": f"{what} on the new validation runs"}
    new = residuals[residuals["run_id"].astype(str).isin(runs)]
    thinned = thin_by_run(new, spacing)
    usable = thin_by_run(new, 0.0)
    if thinned.empty:
        reason = "no new sample has a finite measurement and interval"
        return out | {"status": "no_interval", "reason": reason}
    measured = thinned["measured_um"].to_numpy(dtype=float)
    outside = (measured < thinned["lower_um"].to_numpy(dtype=float)) | (
        measured > thinned["upper_um"].to_numpy(dtype=float)
    )
    ids = thinned["run_id"].astype(str).to_numpy()
    usable_ids = usable["run_id"].astype(str).to_numpy()
    for run in sorted(set(ids)):
        mine = ids == run
        out["per_run"][run] = {
            "n": int(mine.sum()),
            "k": int(outside[mine].sum()),
            "n_samples": int((usable_ids == run).sum()),
        }
    n, k = int(len(outside)), int(outside.sum())
    p_value = binomial_p_value(k, n, allowed)
    out.update(
        n_samples=int(len(usable)),
        n=n,
        k=k,
        expected_k=n * allowed,
        observed_rate=k / n,
        p_value=p_value,
    )
    if p_value < float(false_alarm):
        out.update(status="recalibration_due", detected=True)
    return out


def binomial_p_value(k: int, n: int, rate: float) -> float:
    """One-sided p-value P(K >= k), K ~ Binomial(n, rate): how unlikely ``k`` or more
    exceedances of ``n`` are for a machine that exceeds with probability ``rate``."""
    from scipy.stats import binom  # local: the registry and status code import this module

    return 1.0 if k <= 0 else float(binom.sf(k - 1, n, rate))


def champion_drift(
    champion, promotion: dict | None, runs_table: pd.DataFrame, nightly: Mapping[str, Any]
) -> tuple[dict, list[str]]:
    """The drift checks of the champion in service on the validation runs new since its
    promotion (their files' content was not in its ``data_files``): its max residual against the
    one recorded at its promotion (:func:`drift_check`, ``nightly.drift_margin_um``)
    and, under ``drift["interval"]``, how often the new samples fall outside its interval
    (:func:`interval_drift`, ``nightly.drift_false_alarm``). ``champion`` is a
    :class:`rafi.ops.decide.Champion` (``model_id``, ``summary``, ``model``, ``residuals``).
    Returns ``(drift, new_run_ids)``; no promotion record, no new runs."""
    new_runs = new_validation_runs(runs_table, (promotion or {}).get("data_files")) if promotion else []
    reference = (promotion.get("candidate_summary") or {}).get("max_residual_um") if promotion else None
    drift = drift_check(champion.summary, new_runs, reference, float(nightly["drift_margin_um"]))
    drift["champion_id"] = champion.model_id
    drift["promoted_at"] = (promotion or {}).get("time")
    if champion.model_id is None:
        drift["interval"] = {"status": "no_champion", "detected": False}
    else:
        interval = (champion.model or {}).get("interval")
        drift["interval"] = interval_drift(
            champion.residuals, new_runs, interval, float(nightly["drift_false_alarm"])
        )
    return drift, new_runs


def _drift_outcome(decision: str, waiting: bool) -> str:
    """How a detected drift ends tonight: resolved by the promotion; a candidate from new runs that
    waits for a person's confirmation (:func:`rafi.family.confirmation.awaiting_confirmation`); else
    recalibration due."""
    if decision == "promoted":
        return "; resolved by tonight's promotion"
    if waiting:
        return "; tonight's candidate would replace it and waits for a confirmation (the WAITING line)"
    return "; recalibration due (new training runs needed)"


def drift_reason(drift: dict, champion_id: str | None, decision: str, waiting: bool = False) -> str:
    """The reason line of a detected drift and how it ends tonight (:func:`_drift_outcome`)."""
    line = (
        f"drift: champion {str(champion_id)[:12]} max residual on {len(drift['per_run'])} new "
        f"validation run(s) is {fmt_value(drift['new_max_residual_um'])} um vs "
        f"{fmt_value(drift['reference_max_residual_um'])} um at promotion (margin "
        f"{fmt_value(drift['margin_um'])} um)"
    )
    return line + _drift_outcome(decision, waiting)


def interval_drift_reason(drift: dict, champion_id: str | None, decision: str, waiting: bool = False) -> str:
    """The reason line of a detected interval drift (:func:`interval_drift`) and how it ends tonight."""
    line = f"drift: champion {str(champion_id)[:12]}: {interval_evidence(drift['interval'])}"
    return line + _drift_outcome(decision, waiting)
