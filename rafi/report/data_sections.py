"""Sections 2-4 of the report: the data, thermal equilibrium and the key-sensor ranking."""

from __future__ import annotations

import numpy as np
import pandas as pd

from rafi.method.paper import T_EQ_S
from rafi.report.format import (
    cell,
    fmt_num,
    fmt_speed,
    isnum,
    short_id,
    speed_key,
    table,
    truthy,
)
from rafi.report.inputs import chosen_sensors, collinearity_frame, correlation_wide

#: A collinearity matrix with more sensors than this is a figure (rule report_figures).
MAX_COLLINEARITY_TABLE = 8


def paper_value(frame: pd.DataFrame, i, column: str, values: dict, speed):
    """The paper's value of row ``i``: the table's ``paper_*`` column, else ``values[speed]``."""
    v = frame.loc[i, column] if column in frame else np.nan
    if not isnum(v):
        v = values.get(speed_key(speed), np.nan)
    return v


def section_data(res: dict) -> dict:
    """Section 2: the runs by role, the cleaning audit per file and the quarantined files (every
    run in detail: :mod:`rafi.report.segmentation_section`)."""
    runs = res["runs_csv"]
    audit = res["audit"]
    audit_t, quarantined = None, []
    if audit is not None:
        a_rows = []
        for r in audit.itertuples(index=False):
            q = str(r.status) != "ok"
            a_rows.append(
                [
                    r.file,
                    fmt_num(r.rows_in, 0),
                    fmt_num(r.rows_out, 0),
                    fmt_num(r.duplicates_dropped, 0),
                    fmt_num(r.reordered, 0),
                    fmt_num(r.spikes_replaced, 0),
                    fmt_num(r.values_interpolated, 0),
                    fmt_num(r.gaps_interpolated, 0),
                    fmt_num(r.segments, 0),
                    cell(str(r.status), "fail" if q else "pass"),
                ]
            )
            if q:
                quarantined.append(
                    {
                        "file": r.file,
                        "sha256": short_id(r.sha256),
                        "reason": "" if pd.isna(r.reason) else str(r.reason),
                    }
                )
        audit_t = table(
            [
                "file",
                "rows in",
                "rows out",
                "dupli\u00adcates",
                "re\u00adordered",
                "spikes",
                "values interp.",
                "gaps interp.",
                "seg\u00adments",
                "status",
            ],
            a_rows,
            cls="audit num",
            widths=[27, 7, 7, 8, 9, 7, 8, 7, 8, 12],
        )
        totals = {
            k: int(pd.to_numeric(audit[k], errors="coerce").fillna(0).sum())
            for k in (
                "rows_in",
                "rows_out",
                "duplicates_dropped",
                "spikes_replaced",
                "values_interpolated",
                "gaps_interpolated",
            )
        }
    else:
        totals = {}
    roles = runs["role"].value_counts().to_dict() if runs is not None else {}
    status = res.get("input_status") if isinstance(res.get("input_status"), dict) else {}
    listed = {q["file"] for q in quarantined}
    for rec in status.get("rejected") or []:
        if rec.get("file") not in listed:  # rejected at machine level (e.g. duplicate content)
            quarantined.append(
                {
                    "file": rec.get("file", ""),
                    "sha256": short_id(rec.get("sha256") or ""),
                    "reason": str(rec.get("reason") or rec.get("check") or ""),
                }
            )
    return {
        "audit": audit_t,
        "quarantined": quarantined,
        "warnings": input_warnings(status),
        "totals": totals,
        "roles": roles,
        "n_files": 0 if audit is None else len(audit),
    }


def input_warnings(status: dict) -> list[dict]:
    """The input warnings of ``input_status.json`` for the report, unconfirmed ones first.

    Each: ``file``, ``check`` (check id, docs/raw-format.md "Checks"), ``column``, ``message``,
    ``confirmed`` (a person confirmed it in ``checks.confirmed``; an unconfirmed warning blocks
    promotion at night).
    """
    rows = [
        {
            "file": str(w.get("file", "")),
            "check": str(w.get("check", "")),
            "column": "" if w.get("column") in (None, "") else str(w.get("column")),
            "message": str(w.get("message", "")),
            "confirmed": bool(w.get("confirmed")),
        }
        for w in (status or {}).get("warnings") or []
    ]
    return sorted(rows, key=lambda w: (w["confirmed"], w["file"], w["check"]))


def section_equilibrium(res: dict, figs) -> dict:
    """Section 3: time to thermal equilibrium per training speed, beside the paper's Table 1."""
    eq = res["equilibrium"]
    rows = []
    if eq is not None:
        for i in eq.index:
            r = eq.loc[i]
            paper = paper_value(eq, i, "paper_t_eq_s", T_EQ_S, r.speed_rpm)
            diff = (
                (float(r.t_eq_s) - float(paper)) / float(paper) * 100
                if isnum(paper) and isnum(r.t_eq_s)
                else np.nan
            )
            rows.append(
                [
                    fmt_speed(r.speed_rpm),
                    fmt_num(r.t_eq_s, 0, "s"),
                    f"{fmt_num(r.t_eq_low_s, 0)}\u2013{fmt_num(r.t_eq_high_s, 0, 's')}",
                    fmt_num(r.t_eq_tau_s, 0, "s"),
                    fmt_num(r.tau_s, 0, "s"),
                    fmt_num(r.plateau_um, 2, "\u00b5m"),
                    fmt_num(paper, 0, "s"),
                    fmt_num(diff, 0, "%", signed=True),
                ]
            )
    t = table(
        [
            "speed",
            "t_eq",
            "uncertainty range",
            "t_eq from fitted \u03c4",
            "\u03c4 (first order)",
            "plateau dz",
            "paper Table 1",
            "vs paper",
        ],
        rows,
        cls="num",
        widths=[13, 11, 18, 13, 11, 11, 12, 11],
    )
    fig = figs.get("pipeline", "training_runs")
    method = None
    if eq is not None and "method" in eq and len(eq):
        method = str(eq["method"].iloc[0])
    return {"table": t, "figure": fig, "method": method}


def section_ranking(res: dict, key_info: dict, figs) -> dict:
    """Section 4: the correlation ranking, the chosen key sensors and their collinearity."""
    corr = res["correlation"]
    ks = res["key_sensors"]
    chosen = chosen_sensors(key_info, ks)
    threshold = float(key_info["threshold"])
    out = {
        "chosen": chosen,
        "threshold": threshold,
        "scope": key_info.get("scope", ""),
        "fallback_used": truthy(key_info.get("fallback_used", False)),
        "message": key_info.get("message") or "",
        "figure": None,
        "table": None,
        "key_table": None,
        "collinearity": None,
        "collinearity_figure": None,
    }
    if corr is not None:
        wide = correlation_wide(corr)
        sensors = list(wide.columns)
        out["figure"] = figs.get("pipeline", "correlation_heatmap")
        # ranking table: the best sensors by the selection score (min |r| over speeds and pooled)
        per_speed = wide.drop(index="pooled", errors="ignore")
        score = per_speed.min(axis=0) if len(per_speed) else wide.min(axis=0)
        pooled = wide.loc["pooled"] if "pooled" in wide.index else pd.Series(np.nan, index=sensors)
        order = score.sort_values(ascending=False).index
        rows = []
        for k, s in enumerate(order, start=1):
            sel = s in chosen
            rows.append(
                [
                    str(k),
                    cell(s, "pass" if sel else ""),
                    fmt_num(score[s], 4),
                    fmt_num(per_speed[s].max() if len(per_speed) else np.nan, 4),
                    fmt_num(pooled.get(s, np.nan), 4),
                    cell("yes" if score[s] > threshold else "no", "pass" if score[s] > threshold else ""),
                    "chosen" if sel else "",
                ]
            )
        out["table"] = table(
            [
                "rank",
                "sensor",
                "min |r| over speeds",
                "max |r| over speeds",
                "|r| pooled",
                f"> {threshold:g}",
                "key sensor",
            ],
            rows,
            cls="num",
            widths=[8, 10, 18, 18, 14, 10, 12],
        )
    if ks is not None:
        out["key_table"] = table(
            ["sensor", "score |r|", "selected by"],
            [[r.sensor, fmt_num(r.score_abs_r, 4), r.selected_by] for r in ks.itertuples(index=False)],
            cls="num narrow",
        )
    coll = res["collinearity"]
    if coll is not None and len(coll):
        m = collinearity_frame(coll)
        if len(m) <= MAX_COLLINEARITY_TABLE:
            out["collinearity"] = table(
                ["", *m.columns], [[i, *[fmt_num(v, 4) for v in m.loc[i]]] for i in m.index], cls="num narrow"
            )
        else:
            out["collinearity_figure"] = figs.get("pipeline", "collinearity")
        off = m.to_numpy(float)[~np.eye(len(m), dtype=bool)]
        out["max_offdiag"] = fmt_num(np.nanmax(np.abs(off)), 4) if off.size else None
    return out
