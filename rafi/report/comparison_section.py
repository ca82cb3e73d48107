"""Section 9 of the report: the model family compared with RAFI as published.

Reads ``comparison/summary.csv``, ``per_run.csv`` and ``cv.csv``; the figures are files of
rule ``report_figures`` (group ``comparison``), which draws them from the frames of
:func:`comparison_frames` - the same tables the section lists.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from markupsafe import Markup, escape

from rafi.family.selection import SELECTION_RULE
from rafi.report.format import cell, fmt_num, isnum, run_label, table, truthy
from rafi.report.inputs import collinearity_frame, noise_floors


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


#: A run with at least this share of samples outside RAFI's trained temperature range counts
#: as extrapolated in the explanation of its failures.
EXTRAPOLATED_PCT = 10.0


def _key_sensor_r(res: dict) -> float:
    """Largest |r| between two of RAFI's key sensors on the training runs (rank/collinearity.csv)."""
    coll, info = res.get("collinearity"), res.get("key_sensors_json") or {}
    key = [str(k) for k in info.get("sensors") or []]
    if coll is None or len(key) < 2:
        return np.nan
    m = collinearity_frame(coll.copy())
    key = [k for k in key if k in m.index and k in m.columns]
    vals = [abs(float(m.loc[a, b])) for i, a in enumerate(key) for b in key[i + 1 :]]
    return max(vals) if vals else np.nan


def rafi_failure(bad: pd.DataFrame, res: dict, settings: dict) -> dict:
    """Why RAFI as published fails on the runs ``bad`` (its rows of ``comparison/per_run.csv``),
    from the data: per run the residual and the shares of samples outside the temperature rises
    and speeds it was trained on; the trained speeds (model.json); the key sensors' collinearity
    (rank/collinearity.csv); the reference rule of the machine."""
    um = "\u00b5m"
    parts, t_share, s_share = [], [], []
    for r in bad.to_dict("records"):
        n = float(r.get("n_samples") or 0)
        ts = 100.0 * float(r.get("n_outside_temp_range") or 0) / n if n else np.nan
        ss = 100.0 * float(r.get("n_outside_speed_range") or 0) / n if n else np.nan
        t_share.append(ts)
        s_share.append(ss)
        parts.append(
            Markup(
                f"{run_label(r['run_id'])} ({escape(fmt_num(r['max_abs_after_um'], 2, um))}, "
                f"noise floor {escape(fmt_num(r.get('noise_floor_um'), 2, um))}; "
                f"{escape(fmt_num(ts, 0, '%'))} of {escape(fmt_num(n, 0))} samples outside the trained "
                f"temperature range, {escape(fmt_num(ss, 0, '%'))} outside the trained speeds)"
            )
        )
    t_share, s_share = np.asarray(t_share, float), np.asarray(s_share, float)
    n_ext = int(np.sum(t_share >= EXTRAPOLATED_PCT))
    speeds = [float(x["speed_rpm"]) for x in (res.get("model") or {}).get("speeds") or [] if "speed_rpm" in x]
    trained = (
        f" (trained speeds {fmt_num(min(speeds), 0)}\u2013{fmt_num(max(speeds), 0)} r/min)" if speeds else ""
    )
    if n_ext:
        why = (
            f"On {n_ext} of the {len(bad)} failing run(s) at least {EXTRAPOLATED_PCT:g} % of the samples lie "
            f"outside the temperature rises RAFI's per-speed regressions were fitted on (up to "
            f"{fmt_num(np.nanmax(t_share), 0, '%')}), where its squared and product terms extrapolate"
        )
    else:
        why = (
            f"The failing run(s) lie inside the trained temperature range (at most "
            f"{fmt_num(np.nanmax(t_share) if len(t_share) else np.nan, 0, '%')} of the samples outside): "
            "the failure is not extrapolation in temperature"
        )
    if len(s_share) and np.nanmax(s_share) > 0:
        worst_speed = fmt_num(np.nanmax(s_share), 0, "%")
        why += f"; up to {worst_speed} of the samples are outside its trained speeds{trained}"
    why += "."
    r_max = _key_sensor_r(res)
    if isnum(r_max):
        why += f" Its key sensors correlate up to |r| = {fmt_num(r_max, 3)} on the training runs."
    if settings["reference"]["rule"] == "log_start":
        why += (
            " On this machine the runs are cut out of a continuous log and do not start cold "
            "(reference.rule = log_start): each starts from the state the log reached."
        )
    return {
        "runs": Markup("; ".join(str(x) for x in parts)),
        "why": why,
        "n": len(bad),
        "max_share": fmt_num(np.nanmax(t_share) if len(t_share) else np.nan, 0, "%"),
    }


def selection_context(summary: pd.DataFrame, champion) -> dict:
    """How the champion was chosen, from ``comparison/summary.csv``: the rule
    (:data:`rafi.family.compare.SELECTION_RULE`), its CV score and rank, and its gates on the
    validation runs (touched once, after the choice)."""
    out = {
        "rule": SELECTION_RULE,
        "champion": champion,
        "basis": "none",
        "score": "\u2013",
        "n": len(summary),
    }
    if champion is None:
        return out
    r = summary[summary["model"].astype(str) == champion].iloc[0]
    score = r.get("cv_mean_max_abs_um")
    out["basis"] = "cv" if isnum(score) else "default"
    out["score"] = fmt_num(score, 2, "\u00b5m")
    out["worst_fold"] = fmt_num(r.get("cv_max_abs_um"), 2, "\u00b5m")
    out["passed"] = truthy(r.get("passed", False))
    out["validation_worst"] = fmt_num(r.get("max_abs_after_um"), 2, "\u00b5m")
    out["noise"] = fmt_num(r.get("noise_floor_um"), 2, "\u00b5m")
    out["better_on_validation"] = [
        str(m)
        for m, after in zip(
            summary["model"].astype(str), pd.to_numeric(summary["max_abs_after_um"], errors="coerce")
        )
        if m != champion
        and isnum(after)
        and isnum(r.get("max_abs_after_um"))
        and after < float(r["max_abs_after_um"])
    ]
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
        "selection": None,
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
        rank = r.get("selection_rank")
        rows.append(
            [
                cell(Markup(f"<b>{escape(name)}</b> " + " ".join(tags))),
                str(r.get("kind", "")),
                cell(fmt_num(r.get("cv_mean_max_abs_um"), 2), "champ" if name == fam_champ else ""),
                fmt_num(r.get("cv_max_abs_um"), 2),
                fmt_num(rank, 0) if isnum(rank) else "\u2013",
                cell(fmt_num(r.get("max_abs_after_um"), 2), "" if passed else "fail"),
                fmt_num(r.get("noise_floor_um"), 2),
                cell(fmt_num(r.get("improvement_pct"), 1), "" if passed else "fail"),
                f"{fmt_num(r.get('n_outside_temp_range'), 0)} ({fmt_num(share, 0, '%')})",
                fmt_num(r.get("n_outside_speed_range"), 0),
                cell("PASS" if passed else "FAIL", "pass" if passed else "fail"),
            ]
        )
    out["summary"] = table(
        [
            "model",
            "kind",
            "CV mean max |res.| (\u00b5m): the choice",
            "CV worst run (\u00b5m)",
            "rank",
            "validation worst max |res.| (\u00b5m)",
            "noise floor of that run (\u00b5m)",
            "min impr. (%)",
            "samples outside trained temp.",
            "outside trained speed",
            "gates",
        ],
        rows,
        cls="num models",
        widths=[19, 9, 9, 8, 5, 9, 8, 7, 10, 8, 8],
    )
    if all(str(r.get("kind", "")) == str(r["model"]) for r in s.to_dict("records")):
        # every model is named after its kind: the kind column only repeats the name
        summary = out["summary"]
        summary["headers"].pop(1)
        for row in summary["rows"]:
            row.pop(1)
        summary["widths"] = [28, *summary["widths"][2:]]
    out["selection"] = selection_context(s, fam_champ)
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
            "run, hyperparameters re-chosen inside the fold: nested). The CV columns come "
            "from the training runs only and choose the champion; the validation columns "
            "come after the choice and do not change it."
        )
    if pr is None or not len(pr):
        return out
    fr = comparison_frames(summ, pr)
    p, models, runs = fr["per_run"], fr["models"], fr["runs"]
    noise = noise_floors(res)
    after, imp, before, role, passed = fr["after"], fr["imp"], fr["before"], fr["role"], fr["passed"]
    rows = []
    for rid in runs:
        row = [
            cell(
                Markup(f"{run_label(rid)}<br><small>{escape(role[rid].replace('validation_', ''))}</small>")
            ),
            fmt_num(before[rid], 2),
            fmt_num(noise.get(rid), 2),
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
    heads = ["validation run", "max |dz| uncomp. (\u00b5m)", "noise floor (\u00b5m)"]
    for m in models:
        heads.append(m + (" \u2605" if m == fam_champ else ""))
    w_run, w_before = 22, 9
    w_m = (100 - w_run - 2 * w_before) / max(len(models), 1)
    out["per_run"] = table(
        heads, rows, cls="num per-run", widths=[w_run, w_before, w_before] + [round(w_m, 1)] * len(models)
    )
    out["figure_bars"] = figs.get("comparison", "comparison_bars")

    # RAFI as published: where it fails and why (computed from this machine's tables)
    rafi_name = fr["rafi"]
    if rafi_name is not None and rafi_name in passed.columns and not passed[rafi_name].all():
        bad = p[(p["model"] == rafi_name) & ~p["passed"].map(truthy)]
        out["rafi_fail"] = rafi_failure(bad, res, settings)
        champ_txt = ""
        if fam_champ and fam_champ != rafi_name:
            ok = bool(passed[fam_champ].all()) if fam_champ in passed.columns else False
            verb = "passes every gate" if ok else "also fails a gate"
            champ_txt = f" The champion ({fam_champ}) {verb} on the same runs"
            champ_txt += (
                " and is the model on the machine."
                if on_machine == fam_champ
                else "; whether it goes on the machine is the registry's decision (section Model registry)."
            )
        out["rafi_fail"]["why"] += champ_txt

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
