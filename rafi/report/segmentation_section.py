"""Section Segmentation of the report: how the logs were cut into runs and why each run has its role.

Reads ``runs.csv`` (``rafi.method.runs``: span on the log's clock, speed, kind, role,
``role_source``, ``role_reason``, ``note``, and ``start_time`` / ``end_time`` where the log
has a clock) and the machine's ``runs:`` settings; the timeline figure is a file of rule
``report_figures`` (group ``pipeline``, key ``segmentation``). Every sentence about the data
is computed from ``runs.csv``.
"""

from __future__ import annotations

import pandas as pd

from rafi.report.format import fmt_run_speed, isnum, plain

#: Where a role came from (``role_source`` of runs.csv), for people.
SOURCE_TEXT = {
    "auto": "automatic",
    "config": "run-id override",
    "window": "time window",
    "leak_guard": "leak guard",
}


def _text(value) -> str:
    return "" if value is None or (isinstance(value, float) and pd.isna(value)) else str(value)


def _hours(seconds):
    """Seconds on the log's clock as hours (``None`` for a missing value)."""
    return float(seconds) / 3600.0 if isnum(seconds) else None


def training_after_validation(runs: pd.DataFrame) -> list[str]:
    """Training runs that start after the first validation run of the same log starts
    (``start_s`` on the log's clock): data recorded after validation data that trained the
    model."""
    if runs is None or not len(runs) or not {"file", "start_s", "role"} <= set(runs.columns):
        return []
    out = []
    for _, g in runs.groupby(runs["file"].astype(str), sort=False):
        roles = g["role"].astype(str)
        val = g.loc[roles.str.startswith("validation"), "start_s"].astype(float)
        if not len(val):
            continue
        late = g[(roles == "training") & (g["start_s"].astype(float) > val.min())]
        out += late["run_id"].astype(str).tolist()
    return out


def _row(r: dict) -> dict:
    """One run of ``runs.csv`` as the segmentation table shows it."""
    source = _text(r.get("role_source"))
    return {
        "run_id": r["run_id"],
        "start_h": _hours(r.get("start_s")),
        "end_h": _hours(r.get("end_s")),
        "start_time": _text(r.get("start_time")),
        "end_time": _text(r.get("end_time")),
        "duration_s": plain(r.get("duration_s")),
        "speed_rpm": plain(r.get("speed_rpm")),
        "speed": fmt_run_speed(r),
        "kind": _text(r.get("kind")),
        "role": str(r.get("role", "")),
        "source": SOURCE_TEXT.get(source, source),
        "why": [p for p in (_text(r.get("role_reason")), _text(r.get("note"))) if p],
    }


def section_segmentation(res: dict, settings: dict, figs) -> dict | None:
    """Section Segmentation: every run of every log with its span, speed, kind, role and why.

    Parameters
    ----------
    res : dict
        Loaded inputs (``runs_csv``).
    settings : dict
        The machine's settings (``runs.allow_training_after_validation``, ``runs.windows``).
    figs : rafi.report.embed.FigureFiles
        The figure files of rule ``report_figures``.

    Returns
    -------
    dict or None
        ``table`` (one dict per run: ``run_id``, ``start_h`` / ``end_h`` on the log's clock,
        ``start_time`` / ``end_time``, ``duration_s``, ``speed_rpm``, ``speed`` (as every section
        prints a run's speed: :func:`rafi.report.format.fmt_run_speed`, a varying run's range),
        ``kind``, ``role``, ``source``, ``why``), ``figure``,
        ``n_runs``, ``n_logs``, ``by_role`` / ``by_source`` (counts), ``allow_late`` (the
        setting), ``late`` (training runs after validation data of their log), ``windows``
        (number of configured windows); ``None`` without ``runs.csv``.
    """
    runs = res.get("runs_csv")
    if runs is None or not len(runs):
        return None
    rows = [_row(r) for r in runs.to_dict("records")]
    runs_settings = settings.get("runs", {}) if isinstance(settings, dict) else {}
    late = training_after_validation(runs)
    source = runs["role_source"].astype(str) if "role_source" in runs else pd.Series(dtype=str)
    return {
        "table": rows,
        "figure": figs.get("pipeline", "segmentation"),
        "n_runs": len(runs),
        "n_logs": int(runs["file"].astype(str).nunique()) if "file" in runs else 0,
        "by_role": runs["role"].astype(str).value_counts(sort=False).to_dict(),
        "by_source": {SOURCE_TEXT.get(k, k): v for k, v in source.value_counts(sort=False).items()},
        "allow_late": bool(runs_settings.get("allow_training_after_validation", False)),
        "late": late,
        "windows": len(runs_settings.get("windows") or []),
    }
