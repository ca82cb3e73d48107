"""Sections 5-7 of the report: the models, the fuzzy blending and the validation.

What comes from evaluating the model (the training fit's RMSE, the worked example of the
blending) is read from the tables of rule ``report_tables`` (:mod:`rafi.report.tables`);
the figures are files of rule ``report_figures``.
"""

from __future__ import annotations

import numpy as np
from markupsafe import Markup, escape

from rafi.method.paper import MULTI_CONDITION, RESIDUAL_UM, RMSE_UM
from rafi.report.data_sections import paper_value
from rafi.report.format import (
    NBSP,
    cell,
    equation_text,
    fmt_duration,
    fmt_num,
    fmt_p,
    fmt_sig,
    fmt_speed,
    fmt_speed_range,
    isnum,
    run_label,
    short_id,
    speed_key,
    subscript,
    table,
    term_text,
    truthy,
)
from rafi.report.inputs import noise_floors

#: Where the membership curves of the figure come from (shown in its caption).
MEMBERSHIP_SOURCE = "rafi.method.fuzzy.membership_curves"


def section_models(res: dict, figs, *, paper: bool = False) -> dict:
    """Section 5: the per-speed equations, diagnostics, coefficients and the training fit
    (``paper``: ``report.paper_rig``, the paper's Table 3 RMSE beside each speed)."""
    model = res["model"] or {}
    diag = res["diagnostics"]
    coefs = res["coefficients"]
    terms = list(
        model.get("terms") or (coefs["term"].drop_duplicates().tolist() if coefs is not None else [])
    )
    variables = dict(
        model.get("variables") or {f"x{i + 1}": s for i, s in enumerate(model.get("key_sensors", []))}
    )
    var_text = ", ".join(f"{k[0]}{subscript(k[1:])} = d{v} (K)" for k, v in variables.items())
    speeds = model.get("speeds") or []
    equations = []
    for sp in speeds:
        equations.append(
            {
                "speed": fmt_speed(sp["speed_rpm"]),
                "equation": equation_text(sp["coefficients"], terms, variables),
                "n": sp.get("n"),
                "range": ", ".join(
                    f"d{k} {fmt_num(v[0], 2)}\u2026{fmt_num(v[1], 2, 'K')}"
                    for k, v in (sp.get("regressor_ranges") or {}).items()
                ),
            }
        )
    if not equations and coefs is not None:
        for speed, g in coefs.groupby("speed_rpm"):
            equations.append(
                {
                    "speed": fmt_speed(speed),
                    "n": None,
                    "range": "",
                    "equation": equation_text(g["coef"].tolist(), g["term"].tolist(), variables),
                }
            )
    # the training fit recomputed from model.json on runs.parquet (rule report_tables)
    check = res["training_fit_rmse"]
    rmse_check = (
        {} if check is None else {speed_key(r.speed_rpm): r.rmse_um for r in check.itertuples(index=False)}
    )
    d_rows, mismatches = [], []
    if diag is not None:
        for i in diag.index:
            r = diag.loc[i]
            sp = speed_key(r.speed_rpm)
            ref = paper_value(diag, i, "paper_rmse_um", RMSE_UM, sp)
            chk = rmse_check.get(sp, np.nan)
            if isnum(chk) and isnum(r.rmse_um) and abs(chk - r.rmse_um) > 0.02 * r.rmse_um + 1e-3:
                mismatches.append(
                    f"{fmt_speed(sp)}: table {fmt_num(r.rmse_um, 3)} \u00b5m, "
                    f"recomputed {fmt_num(chk, 3)} \u00b5m"
                )
            d_rows.append(
                [
                    fmt_speed(sp),
                    fmt_num(r.n, 0),
                    fmt_num(r.rmse_um, 3),
                    *([fmt_num(ref, 3)] if paper else []),
                    fmt_num(r.r2, 4),
                    fmt_num(r.r2_adj, 4),
                    fmt_sig(r.max_vif, 2),
                    fmt_num(r.durbin_watson, 2),
                    fmt_p(r.bp_p),
                    fmt_p(r.jb_p),
                    fmt_sig(r.condition_number, 2),
                ]
            )
    diag_t = table(
        [
            "speed",
            "n",
            "RMSE (\u00b5m)",
            *(["paper Table 3 RMSE (\u00b5m)"] if paper else []),
            "R\u00b2",
            "adj. R\u00b2",
            "max VIF",
            "Durbin-Watson",
            "Breusch-Pagan p",
            "Jarque-Bera p",
            "condition number",
        ],
        d_rows,
        cls="num diag",
        widths=[12, 6, 8, 10, 8, 8, 10, 9, 9, 9, 11] if paper else [13, 7, 9, 9, 9, 11, 10, 10, 10, 12],
    )
    coef_t = None
    if coefs is not None and len(coefs):
        c = coefs.copy()
        c["speed_rpm"] = c["speed_rpm"].map(speed_key)
        spd = sorted(c["speed_rpm"].unique())
        rows = []
        for t in terms:
            row = [cell(Markup(f"b\u00b7{term_text(t, variables)}") if t != "1" else "b\u2080 (intercept)")]
            for s in spd:
                g = c[(c["speed_rpm"] == s) & (c["term"] == t)]
                if not len(g):
                    row.append("\u2013")
                    continue
                g = g.iloc[0]
                row.append(
                    cell(
                        Markup(
                            f"{escape(fmt_sig(g.coef, 4))}<br><small>\u00b1"
                            f"{escape(fmt_sig(g.se_hac, 2))}, p {escape(fmt_p(g.p_hac))}"
                            "</small>"
                        )
                    )
                )
            rows.append(row)
        coef_t = table(["term", *[fmt_speed(s) for s in spd]], rows, cls="num coef")
    fig = figs.get("pipeline", "fit_residuals")
    return {
        "equations": equations,
        "variables": var_text,
        "diagnostics": diag_t,
        "coefficients": coef_t,
        "figure": fig,
        "mismatches": mismatches,
        "terms": ", ".join(terms),
        "model_id": short_id(model.get("model_id", ""), 16),
        "created": model.get("created", ""),
        "code_version": model.get("code_version", ""),
        "paper": paper,
    }


def section_fuzzy(res: dict, figs, *, paper: bool = False) -> dict | None:
    """Section 6: the membership functions and the worked example (``report/fuzzy_example.json``);
    ``paper`` (``report.paper_rig``): the paper's worked example and its wording are discussed.

    Returns ``None`` without training speeds.
    """
    model = res["model"] or {}
    ex = res["fuzzy_example"]
    centres = ex["centres_rpm"]
    if len(centres) < 1:
        return None
    example = None
    if ex["example_rpm"] is not None:
        speed = ex["example_rpm"]
        (n0, n1) = ex["neighbours"]
        rows = [
            [
                fmt_speed(n["centre_rpm"]),
                fmt_num(n["distance_rpm"], 0, "r/min"),
                fmt_num(n["weight"], 3),
                fmt_num(n["model_dz_um"], 2, "\u00b5m"),
            ]
            for n in ex["neighbours"]
        ]
        example = {
            "speed": fmt_speed(speed),
            "rows": rows,
            "table": table(
                ["training speed", "distance", "membership weight", "model dz at this state"],
                rows,
                cls="num narrow",
            ),
            "w0": fmt_num(n0["weight"], 3),
            "w1": fmt_num(n1["weight"], 3),
            "c0": fmt_speed(n0["centre_rpm"]),
            "c1": fmt_speed(n1["centre_rpm"]),
            "d0": fmt_num(n0["distance_rpm"], 0),
            "d1": fmt_num(n1["distance_rpm"], 0),
        }
        if ex["state"] is not None:
            example["state"] = ", ".join(f"{s} = {fmt_num(v, 2, 'K')}" for s, v in ex["state"].items())
            example["blended"] = fmt_num(ex["blended_dz_um"], 2, "\u00b5m")
    return {
        "figure": figs.get("pipeline", "membership"),
        "example": example,
        "source": MEMBERSHIP_SOURCE,
        "outside": (model.get("fuzzy") or {}).get("outside", "edge"),
        "centres": ", ".join(fmt_num(c, 0) for c in centres) + NBSP + "r/min",
        "paper": paper,
    }


def idle_table(idle, noise: dict):
    """The idle cool-down runs of ``validation/summary.csv``: max |dz| before, max |residual|
    after beside the run's noise floor, improvement, RMSE (``None`` without idle runs)."""
    if not len(idle):
        return None
    rows = []
    for r in idle.to_dict("records"):
        worse = truthy(r.get("worse_than_uncompensated", False))
        rows.append(
            [
                cell(run_label(r["run_id"])),
                fmt_duration(r.get("duration_s")),
                fmt_num(r.get("max_abs_before_um"), 2),
                fmt_num(r.get("max_abs_after_um"), 2),
                fmt_num(noise.get(str(r["run_id"])), 2),
                cell(fmt_num(r.get("improvement_pct"), 1), "fail" if worse else ""),
                fmt_num(r.get("rmse_before_um"), 2),
                fmt_num(r.get("rmse_after_um"), 2),
            ]
        )
    return table(
        [
            "run",
            "duration",
            "max |dz| before (\u00b5m)",
            "max |residual| after (\u00b5m)",
            "noise floor (\u00b5m)",
            "improvement (%)",
            "RMSE before (\u00b5m)",
            "RMSE after (\u00b5m)",
        ],
        rows,
        cls="num",
        widths=[24, 9, 11, 11, 10, 11, 12, 12],
    )


def section_validation(res: dict, figs, *, paper: bool = False) -> dict:
    """Section 7: single-speed, multi-condition and idle validation runs, out-of-range samples
    (``paper``: ``report.paper_rig``, the paper's Table 4 and multi-condition run beside them)."""
    summ = res["validation_summary"]
    resid = res["residuals"]
    out = {
        "single": None,
        "ranges": None,
        "figure_single": None,
        "multi": [],
        "notes": [],
        "figure_idle": None,
        "n_idle": 0,
        "idle": None,
        "paper": paper,
    }
    if summ is None:
        return out
    s = summ.copy()
    noise = noise_floors(res)
    single = s[s["role"] == "validation_single"] if "role" in s else s
    rows = []
    for i in single.index:
        r = single.loc[i]
        ref = paper_value(single, i, "paper_residual_um", RESIDUAL_UM, r.speed_rpm)
        worse = truthy(r.get("worse_than_uncompensated", False))
        rows.append(
            [
                cell(run_label(r.run_id)),
                fmt_speed(r.speed_rpm),
                fmt_duration(r.duration_s),
                fmt_num(r.max_abs_before_um, 2),
                fmt_num(r.max_abs_after_um, 2),
                fmt_num(noise.get(str(r.run_id)), 2),
                *([fmt_num(ref, 2)] if paper else []),
                cell(fmt_num(r.improvement_pct, 1), "fail" if worse else ""),
                fmt_num(r.rmse_before_um, 2),
                fmt_num(r.rmse_after_um, 2),
            ]
        )
    out["single"] = table(
        [
            "run",
            "speed",
            "duration",
            "max |dz| before (\u00b5m)",
            "max |residual| after (\u00b5m)",
            "noise floor (\u00b5m)",
            *(["paper Table 4 residual (\u00b5m)"] if paper else []),
            "improvement (%)",
            "RMSE before (\u00b5m)",
            "RMSE after (\u00b5m)",
        ],
        rows,
        cls="num",
        widths=[14, 10, 7, 10, 10, 8, 10, 9, 11, 11] if paper else [16, 11, 8, 11, 11, 9, 10, 12, 12],
    )
    idle_runs = s[s["role"] == "validation_idle"] if "role" in s else s.iloc[0:0]
    out["idle"], out["n_idle"] = idle_table(idle_runs, noise), len(idle_runs)
    rows = []
    for r in s.itertuples(index=False):
        worse = truthy(getattr(r, "worse_than_uncompensated", False))
        rows.append(
            [
                cell(run_label(r.run_id)),
                r.role,
                fmt_num(r.n_samples, 0),
                fmt_num(r.n_outside_temp_range, 0),
                fmt_num(r.n_outside_speed_range, 0),
                fmt_num(
                    100 * (r.n_outside_temp_range + 0) / r.n_samples
                    if isnum(r.n_samples) and r.n_samples
                    else np.nan,
                    1,
                    "%",
                ),
                cell("yes" if worse else "no", "fail" if worse else "pass"),
            ]
        )
    out["ranges"] = table(
        [
            "run",
            "role",
            "samples",
            "outside trained temperature range",
            "outside trained speed range",
            "share outside temp. range",
            "worse than uncompensated",
        ],
        rows,
        cls="num",
        widths=[20, 17, 9, 15, 14, 12, 13],
    )
    if resid is None:
        return out
    out["figure_single"] = figs.get("pipeline", "validation_single")
    idle = s[s["role"] == "validation_idle"] if "role" in s else s.iloc[0:0]
    out["figure_idle"] = figs.get("pipeline", "validation_idle")
    out["n_idle"] = sum(bool((resid["run_id"] == rid).any()) for rid in idle["run_id"])
    others = s[~s["role"].isin(["validation_single", "validation_idle"])] if "role" in s else s.iloc[0:0]
    for r in others.itertuples(index=False):
        f = resid[resid["run_id"] == r.run_id]
        if not len(f):
            continue
        fig = figs.get("pipeline", f"multi_condition/{r.run_id}")
        ref = MULTI_CONDITION if paper and r.role == "validation_multi" else None
        changes = int((f["speed_rpm"].diff().abs() > 100).sum())
        out["multi"].append(
            {
                "run_id": r.run_id,
                "role": r.role,
                "figure": fig,
                "duration": fmt_duration(r.duration_s),
                "speeds": fmt_speed_range(f["speed_rpm"].min(), f["speed_rpm"].max()),
                "changes": changes,
                "before": fmt_num(r.max_abs_before_um, 2, "\u00b5m"),
                "after": fmt_num(r.max_abs_after_um, 2, "\u00b5m"),
                "noise": fmt_num(noise.get(str(r.run_id)), 2, "\u00b5m"),
                "improvement": fmt_num(r.improvement_pct, 1, "%"),
                "outside_t": int(r.n_outside_temp_range),
                "outside_s": int(r.n_outside_speed_range),
                "n": int(r.n_samples),
                "paper": None
                if ref is None
                else {
                    "before": fmt_num(ref["before_um"], 2, "\u00b5m"),
                    "after": fmt_num(ref["after_um"], 2, "\u00b5m"),
                    "improvement": fmt_num(ref["improvement_pct"], 1, "%"),
                },
            }
        )
    return out
