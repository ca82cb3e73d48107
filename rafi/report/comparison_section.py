"""Section 9 of the report: the model family compared with RAFI as published.

Reads ``comparison/summary.csv``, ``per_run.csv`` and ``cv.csv``; the figures are files of
rule ``report_figures`` (group ``comparison``), which draws them from the frames of
:func:`comparison_frames` - the same tables the section lists.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from markupsafe import Markup, escape

from rafi.report.format import cell, fmt_num, isnum, run_label, table, truthy


def family_champion(summary: pd.DataFrame):
    """Name of the family's champion in ``comparison/summary.csv`` (``None`` if no model is)."""
    rows = summary[summary["champion"].map(truthy)] if "champion" in summary else summary.iloc[0:0]
    return str(rows["model"].iloc[0]) if len(rows) else None


def comparison_frames(summary: pd.DataFrame, per_run: pd.DataFrame) -> dict:
    """The comparison as frames by validation run (rows, in file order) and model (columns).

    Parameters
    ----------
    summary, per_run : DataFrame
        ``comparison/summary.csv`` and ``comparison/per_run.csv``.

    Returns
    -------
    dict
        ``per_run`` (model and run id as text), ``models``, ``runs``, ``after`` (max
        |residual|, um), ``imp`` (improvement, %), ``passed`` (bool), ``before`` and
        ``role`` (by run), ``champion`` (:func:`family_champion`) and ``rafi`` (the model
        of kind ``rafi``, or ``None``).
    """
    s = summary.assign(model=summary["model"].astype(str))
    p = per_run.copy()
    p["model"], p["run_id"] = p["model"].astype(str), p["run_id"].astype(str)
    models = list(dict.fromkeys(s["model"]))
    runs = list(dict.fromkeys(p["run_id"]))
    after = p.pivot_table(
        index="run_id", columns="model", values="max_abs_after_um", aggfunc="first"
    ).reindex(index=runs, columns=models)
    imp = p.pivot_table(index="run_id", columns="model", values="improvement_pct", aggfunc="first").reindex(
        index=runs, columns=models
    )
    passed = (
        p.assign(ok=p["passed"].map(truthy))
        .pivot_table(index="run_id", columns="model", values="ok", aggfunc="first")
        .reindex(index=runs, columns=models)
        .fillna(True)
        .astype(bool)
    )
    return {
        "per_run": p,
        "models": models,
        "runs": runs,
        "after": after,
        "imp": imp,
        "passed": passed,
        "before": p.groupby("run_id")["max_abs_before_um"].first().reindex(runs),
        "role": p.groupby("run_id")["role"].first().reindex(runs).astype(str),
        "champion": family_champion(s),
        "rafi": next((r["model"] for r in s.to_dict("records") if str(r.get("kind")) == "rafi"), None),
    }


def residual_runs(frames: dict) -> list:
    """Runs whose residual series are drawn: the multi-condition runs (at most two), else
    the run where RAFI as published is worst."""
    runs, role, after, rafi = frames["runs"], frames["role"], frames["after"], frames["rafi"]
    multi = [r for r in runs if role[r] == "validation_multi"]
    if not multi and rafi in after:
        multi = [after[rafi].idxmax()]
    return multi[:2]


def model_beside_rafi(frames: dict, on_machine):
    """The model drawn beside RAFI: the one on the machine, else the family's champion, else
    the model with the smallest worst residual (``None`` if RAFI is the only model)."""
    rafi, after = frames["rafi"], frames["after"]
    other = on_machine if on_machine and on_machine != rafi else frames["champion"]
    if other is None or other == rafi:
        cands = [m for m in frames["models"] if m != rafi]
        other = min(cands, key=lambda m: after[m].max()) if cands else None
    return other


def residual_figure_key(run_id, other) -> str:
    """Key of the figure of RAFI's and ``other``'s residuals on one run."""
    return f"comparison_residuals/{run_id}/{other}"


def _cv_stats(cv: pd.DataFrame | None) -> dict:
    if cv is None or not len(cv) or "model" not in cv:
        return {}
    out = {}
    for name, g in cv.groupby("model"):
        out[str(name)] = {"folds": len(g), "scheme": str(g["scheme"].iloc[0]) if "scheme" in g else ""}
    return out


def section_comparison(res: dict, champion_after, settings: dict, figs) -> dict | None:
    """Section 9: the family's summary, per-run table, figures and why RAFI fails where it does.

    Parameters
    ----------
    res : dict
        Loaded inputs (``comparison``, ``comparison_per_run``, ``comparison_cv``).
    champion_after : str or None
        Model id on the machine after this run (``registry/decision.json``).
    settings : dict
        The machine's settings (``reference.rule`` explains RAFI's failures).
    figs : rafi.report.embed.FigureFiles
        The figure files of rule ``report_figures``.

    Returns
    -------
    dict or None
        ``None`` without ``comparison/summary.csv``.
    """
    summ = res.get("comparison")
    if summ is None or not len(summ):
        return None
    pr = res.get("comparison_per_run")
    out = {
        "summary": None,
        "per_run": None,
        "figure_bars": None,
        "figures_resid": [],
        "rafi_fail": None,
        "champion": None,
        "on_machine": None,
        "cv": None,
        "selected": [],
        "notes": [],
    }
    s = summ.copy()
    s["model"] = s["model"].astype(str)
    fam_champ = family_champion(s)
    out["champion"] = fam_champ
    on_machine = None
    if champion_after and "model_id" in s:
        hit = s[s["model_id"].astype(str) == str(champion_after)]
        on_machine = hit["model"].iloc[0] if len(hit) else None
    out["on_machine"] = on_machine
    cvs = _cv_stats(res.get("comparison_cv"))
    rows = []
    for r in s.to_dict("records"):
        name = r["model"]
        passed = truthy(r.get("passed", False))
        n = r.get("n_samples")
        share = (
            100.0 * float(r["n_outside_temp_range"]) / float(n)
            if isnum(n) and float(n) > 0 and isnum(r.get("n_outside_temp_range"))
            else np.nan
        )
        tags = []
        if name == fam_champ:
            tags.append('<span class="tag champ">champion</span>')
        if on_machine == name:
            tags.append('<span class="tag">on the machine</span>')
        if str(r.get("kind")) == "rafi":
            tags.append('<span class="tag ref">paper reference</span>')
        rows.append(
            [
                cell(Markup(f"<b>{escape(name)}</b> " + " ".join(tags))),
                str(r.get("kind", "")),
                cell(fmt_num(r.get("max_abs_after_um"), 2), "" if passed else "fail"),
                cell(fmt_num(r.get("improvement_pct"), 1), "" if passed else "fail"),
                fmt_num(r.get("rmse_after_um"), 2),
                f"{fmt_num(r.get('n_outside_temp_range'), 0)} ({fmt_num(share, 0, '%')})",
                fmt_num(r.get("n_outside_speed_range"), 0),
                fmt_num(r.get("cv_rmse_um"), 2),
                fmt_num(r.get("cv_max_abs_um"), 2),
                cell("PASS" if passed else "FAIL", "pass" if passed else "fail"),
            ]
        )
    out["summary"] = table(
        [
            "model",
            "kind",
            "worst max |res.| (\u00b5m)",
            "min impr. (%)",
            "worst RMSE (\u00b5m)",
            "samples outside trained temp.",
            "outside trained speed",
            "CV RMSE (\u00b5m)",
            "CV max |res.| (\u00b5m)",
            "gates",
        ],
        rows,
        cls="num models",
        widths=[22, 11, 9, 8, 8, 11, 8, 8, 8, 7],
    )
    if "selected" in s:
        out["selected"] = [
            (str(r["model"]), str(r["selected"]))
            for r in s.to_dict("records")
            if isinstance(r.get("selected"), str) and r["selected"]
        ]
    if cvs:
        k = next(iter(cvs.values()))
        out["cv"] = (
            f"Cross-validation: {k['scheme'].replace('_', '-')} over the training runs "
            f"({k['folds']} folds per model; each model refitted without the held-out "
            "run, hyperparameters re-chosen inside the fold). The validation runs never "
            "enter model selection."
        )
    if pr is None or not len(pr):
        return out
    fr = comparison_frames(summ, pr)
    p, models, runs = fr["per_run"], fr["models"], fr["runs"]
    after, imp, before, role, passed = fr["after"], fr["imp"], fr["before"], fr["role"], fr["passed"]
    rows = []
    for rid in runs:
        row = [
            cell(
                Markup(f"{run_label(rid)}<br><small>{escape(role[rid].replace('validation_', ''))}</small>")
            ),
            fmt_num(before[rid], 2),
        ]
        for m in models:
            ok = bool(passed.loc[rid, m])
            row.append(
                cell(
                    Markup(
                        f"{escape(fmt_num(after.loc[rid, m], 2))}<br><small>"
                        f"{escape(fmt_num(imp.loc[rid, m], 1, '%'))}</small>"
                    ),
                    "" if ok else "fail",
                )
            )
        rows.append(row)
    heads = ["validation run", "max |dz| uncomp. (\u00b5m)"]
    for m in models:
        heads.append(m + (" \u2605" if m == fam_champ else ""))
    w_run, w_before = 24, 11
    w_m = (100 - w_run - w_before) / max(len(models), 1)
    out["per_run"] = table(
        heads, rows, cls="num per-run", widths=[w_run, w_before] + [round(w_m, 1)] * len(models)
    )
    out["figure_bars"] = figs.get("comparison", "comparison_bars")

    # RAFI as published: where it fails and why
    rafi_name = fr["rafi"]
    if rafi_name is not None and rafi_name in passed.columns and not passed[rafi_name].all():
        bad = p[(p["model"] == rafi_name) & ~p["passed"].map(truthy)]
        parts, shares = [], []
        for r in bad.to_dict("records"):
            n = float(r.get("n_samples") or 0)
            sh = 100.0 * float(r.get("n_outside_temp_range") or 0) / n if n else np.nan
            shares.append(sh)
            parts.append(
                Markup(
                    f"{run_label(r['run_id'])} ({escape(fmt_num(r['max_abs_after_um'], 2, chr(181) + 'm'))}, "
                    f"{escape(fmt_num(r['improvement_pct'], 1, '%'))}; "
                    f"{escape(fmt_num(r.get('n_outside_temp_range'), 0))} of "
                    f"{escape(fmt_num(n, 0))} samples = {escape(fmt_num(sh, 0, '%'))} "
                    "outside the trained temperature range)"
                )
            )
        rule = settings["reference"]["rule"]
        why = (
            "Its per-speed quadratic-plus-interaction regressions on three nearly collinear "
            "key sensors are only valid inside the temperature rises they were fitted on; "
            "outside that range the squared and product terms extrapolate and the "
            "prediction runs away from the measurement."
        )
        if rule == "log_start":
            why += (
                " On this machine the runs are cut out of a continuous log and do not start "
                "cold (reference.rule = log_start), so the rises start outside the cold-start "
                "training range."
            )
        champ_txt = ""
        if fam_champ and fam_champ != rafi_name:
            champ_txt = f" The family's champion ({fam_champ}) passes every gate on the same runs"
            champ_txt += (
                " and is the model on the machine."
                if on_machine == fam_champ
                else "; whether it goes on the machine is the registry's decision (section Model registry)."
            )
        out["rafi_fail"] = {
            "runs": Markup("; ".join(str(x) for x in parts)),
            "why": why + champ_txt,
            "n": len(bad),
            "max_share": fmt_num(np.nanmax(shares) if shares else np.nan, 0, "%"),
        }

    # residual time series: RAFI vs the model beside it on the multi-condition run(s)
    if rafi_name is not None:
        other = model_beside_rafi(fr, on_machine)
        for rid in residual_runs(fr):
            fig = figs.get("comparison", residual_figure_key(rid, other))
            if fig is None:
                continue
            out["figures_resid"].append(
                {"run_id": rid, "figure": fig, "other": other, "rafi": rafi_name, "role": role[rid]}
            )
    return out
