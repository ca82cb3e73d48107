"""Section Segmentation of the report: how the logs were cut into runs and why each run has its role.

Reads ``runs.csv`` (``rafi.method.runs``: span on the log's clock, speed, kind, role,
``role_source``, ``role_reason``, ``note``, and ``start_time`` / ``end_time`` where the log
has a clock) and the machine's ``runs:`` settings; the timeline figure is a file of rule
``report_figures`` (group ``pipeline``, key ``segmentation``). Every sentence about the data
is computed from ``runs.csv``.
"""

from __future__ import annotations

import pandas as pd
from markupsafe import Markup, escape

from rafi.report.format import (
    cell,
    fmt_duration,
    fmt_num,
    fmt_speed,
    fmt_speed_range,
    isnum,
    run_label,
    table,
)

#: Where a role came from (``role_source`` of runs.csv), for people.
SOURCE_TEXT = {
    "auto": "automatic",
    "config": "run-id override",
    "window": "time window",
    "leak_guard": "leak guard",
}


def _text(value) -> str:
    return "" if value is None or (isinstance(value, float) and pd.isna(value)) else str(value)


def _hours(seconds) -> str:
    return fmt_num(float(seconds) / 3600.0, 2, "h") if isnum(seconds) else "\u2013"


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


def _span(r) -> Markup:
    text = escape(f"{_hours(r.get('start_s'))} \u2013 {_hours(r.get('end_s'))}")
    start, end = _text(r.get("start_time")), _text(r.get("end_time"))
    if start and end:
        text += Markup("<br><small>") + escape(f"{start} \u2013 {end}") + Markup("</small>")
    return Markup(text)


def _speed(r) -> str:
    lo, hi = r.get("speed_min_rpm"), r.get("speed_max_rpm")
    if str(r.get("kind")) != "varying" or not (isnum(lo) and isnum(hi)) or float(hi) - float(lo) < 1.0:
        return fmt_speed(r.get("speed_rpm"))
    return fmt_speed_range(lo, hi)


def _why(r) -> Markup:
    parts = [escape(p) for p in (_text(r.get("role_reason")), _text(r.get("note"))) if p]
    return Markup("; ".join(str(p) for p in parts)) if parts else Markup("\u2013")


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
        ``table``, ``figure``, ``n_runs``, ``n_logs``, ``by_role`` / ``by_source`` (counts),
        ``allow_late`` (the setting), ``late`` (training runs after validation data of their
        log), ``windows`` (number of configured windows); ``None`` without ``runs.csv``.
    """
    runs = res.get("runs_csv")
    if runs is None or not len(runs):
        return None
    rows = []
    for r in runs.to_dict("records"):
        source = _text(r.get("role_source"))
        rows.append(
            [
                cell(run_label(r["run_id"])),
                cell(_span(r)),
                fmt_duration(r.get("duration_s")),
                _speed(r),
                _text(r.get("kind")),
                cell(
                    Markup(
                        f"{escape(str(r.get('role', '')))}<br><small>"
                        f"{escape(SOURCE_TEXT.get(source, source))}</small>"
                    )
                ),
                cell(_why(r)),
            ]
        )
    runs_settings = settings.get("runs", {}) if isinstance(settings, dict) else {}
    late = training_after_validation(runs)
    source = runs["role_source"].astype(str) if "role_source" in runs else pd.Series(dtype=str)
    return {
        "table": table(
            ["run", "span on the log's clock", "duration", "speed", "kind", "role (source)", "why"],
            rows,
            cls="segmentation",
            widths=[17, 17, 8, 13, 8, 13, 24],
        ),
        "figure": figs.get("pipeline", "segmentation"),
        "n_runs": len(runs),
        "n_logs": int(runs["file"].astype(str).nunique()) if "file" in runs else 0,
        "by_role": runs["role"].astype(str).value_counts(sort=False).to_dict(),
        "by_source": {SOURCE_TEXT.get(k, k): v for k, v in source.value_counts(sort=False).items()},
        "allow_late": bool(runs_settings.get("allow_training_after_validation", False)),
        "late": late,
        "windows": len(runs_settings.get("windows") or []),
    }
