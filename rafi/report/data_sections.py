"""Sections 2-4 of the report: the data, thermal equilibrium and the key-sensor ranking."""

from __future__ import annotations

import numpy as np
import pandas as pd

from rafi.family.since_change import set_aside_count
from rafi.method.equilibrium import TAU_MAX_SPANS, TAU_MIN_S
from rafi.method.paper import T_EQ_S
from rafi.report.format import (
    DASH,
    NBSP,
    fmt_num,
    fmt_speed,
    isnum,
    plain,
    records,
    short_id,
    speed_key,
    truthy,
)
from rafi.report.inputs import chosen_sensors, collinearity_frame, correlation_wide

#: The paper's key sensors (shown only on the paper's rig, ``report.paper_rig``).
PAPER_KEY_SENSORS = "T6, T8, T9"
#: A collinearity matrix with more sensors than this is a figure (rule report_figures).
MAX_COLLINEARITY_TABLE = 8
#: Two chosen sensors whose rises correlate at least this much (|r|) are called nearly
#: collinear in the report (pairwise |r| 0.9: one explains 81 % of the other's variance).
COLLINEAR_ABS_R = 0.9


def paper_value(frame: pd.DataFrame, i, column: str, values: dict, speed):
    """The paper's value of row ``i``: the table's ``paper_*`` column, else ``values[speed]``."""
    v = frame.loc[i, column] if column in frame else np.nan
    if not isnum(v):
        v = values.get(speed_key(speed), np.nan)
    return v


#: The counts of ``audit.csv`` the cleaning-audit table shows, in its column order.
AUDIT_COUNTS = (
    "rows_in",
    "rows_out",
    "duplicates_dropped",
    "reordered",
    "spikes_replaced",
    "values_interpolated",
    "values_left_missing",
    "gaps_interpolated",
    "segments",
)


def section_data(res: dict, period_s=None, *, max_gap_s=None) -> dict:
    """Section 2: the runs by role, the cleaning audit per file and the quarantined files (every
    run in detail: :mod:`rafi.report.segmentation_section`).

    ``rows_in`` of ``audit.csv`` counts the data rows read from a raw file, ``rows_out`` the
    rows of its clean regular grid (``period_s``, the machine's ``sample_period_s``): gaps
    bridged by interpolation add grid rows, duplicates remove rows, so more rows can come
    out than went in. ``totals_text`` says so with this machine's counts. ``set_aside``: how many
    training runs the compare step set aside before a change (``comparison/since_change.csv``).
    ``missing``: the values cleaning left missing, per file (:func:`missing_values`; ``max_gap_s``
    is ``clean.max_interpolate_gap_s``, the longest gap it bridges).
    """
    runs = res["runs_csv"]
    audit = res["audit"]
    audit_t, quarantined = None, []
    if audit is not None:
        a_rows = []
        for r in audit.itertuples(index=False):
            q = str(r.status) != "ok"
            a_rows.append(
                {
                    "file": r.file,
                    **{k: plain(getattr(r, k, None)) for k in AUDIT_COUNTS},
                    "status": str(r.status),
                    "ok": not q,
                }
            )
            if q:
                quarantined.append(
                    {
                        "file": r.file,
                        "sha256": short_id(r.sha256),
                        "reason": "" if pd.isna(r.reason) else str(r.reason),
                    }
                )
        audit_t = a_rows
        totals = {
            k: int(pd.to_numeric(audit[k], errors="coerce").fillna(0).sum())
            for k in (
                "rows_in",
                "rows_out",
                "duplicates_dropped",
                "spikes_replaced",
                "values_interpolated",
                "gaps_interpolated",
                "values_left_missing",
            )
            if k in audit  # values_left_missing: not in an audit.csv written before it existed
        }
    else:
        totals = {}
    totals_text = None
    if totals:
        grid = f"the regular {fmt_num(period_s, 0, 's')} grid" if isnum(period_s) else "the regular grid"
        totals_text = (
            f"Cleaning read {fmt_num(totals['rows_in'], 0)} rows and wrote {fmt_num(totals['rows_out'], 0)} "
            f"rows on {grid}: {fmt_num(totals['duplicates_dropped'], 0)} duplicate row(s) dropped, "
            f"{fmt_num(totals['gaps_interpolated'], 0)} gap(s) bridged by interpolated grid rows, "
            f"{fmt_num(totals['spikes_replaced'], 0)} spike value(s) replaced, "
            f"{fmt_num(totals['values_interpolated'], 0)} sensor value(s) interpolated"
        )
        if "values_left_missing" in totals:
            totals_text += f", {fmt_num(totals['values_left_missing'], 0)} sensor value(s) left missing"
        totals_text += "."
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
        "totals_text": totals_text,
        "missing": missing_values(audit, runs),
        "max_gap_s": max_gap_s,
        "roles": roles,
        # training runs the compare step set aside before a change (rafi.family.since_change)
        "set_aside": set_aside_count(res.get("comparison_since_change")),
        "n_files": 0 if audit is None else len(audit),
    }


def missing_values(audit: pd.DataFrame | None, runs: pd.DataFrame | None) -> list[dict]:
    """The files whose cleaning left sensor values missing, in ``audit.csv`` order.

    Each: ``file``, ``runs`` (the run ids of that file in ``runs.csv``, joined), ``n`` (values
    left missing) and ``spans`` (``missing_spans`` of ``audit.csv``: per span the sensor, the
    source lines, how many values and whether they were open-circuit markers removed or absent
    from the file; :func:`rafi.method.audit.missing_spans`). A sample that needs such a value is
    not fitted or scored, and a model gives it no compensation: these are the samples the
    deployed model's "no compensation on ..." counts within a validation run. ``[]`` for an
    ``audit.csv`` written before these columns existed.
    """
    if audit is None or not {"values_left_missing", "missing_spans"} <= set(audit.columns):
        return []
    run_ids: dict[str, list[str]] = {}
    if runs is not None and {"run_id", "file"} <= set(runs.columns):
        for rid, file in zip(runs["run_id"].astype(str), runs["file"].astype(str)):
            run_ids.setdefault(file, []).append(rid)
    out = []
    for r in audit.itertuples(index=False):
        n = pd.to_numeric(r.values_left_missing, errors="coerce")
        if str(r.status) != "ok" or not isnum(n) or n <= 0:
            continue
        spans = "" if pd.isna(r.missing_spans) else str(r.missing_spans)
        out.append(
            {
                "file": str(r.file),
                "runs": ", ".join(run_ids.get(str(r.file), [])),
                "n": int(n),
                "spans": [part for part in spans.split("; ") if part],
            }
        )
    return out


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


#: The bounds of the first-order fit (:data:`rafi.method.equilibrium.TAU_MIN_S`,
#: :data:`~rafi.method.equilibrium.TAU_MAX_SPANS`) apply to the fitted span (spindle start to the
#: run's last sample). ``equilibrium.csv`` does not record the span: the report takes it from
#: ``runs.csv`` (``end_s - start_s``), less at most ``runs.max_leading_rest_s`` before the
#: spindle start.
#: A tau within this fraction of a bound is reported as at the bound.
BOUND_TOL = 0.05
#: The detected t_eq and the tau cross-check disagree when one exceeds the other by more
#: than this factor.
DISAGREE_FACTOR = 2.0

#: How ``equilibrium.csv`` says why a run has no t_eq: the last ``; ``-part of its ``method``
#: (:func:`rafi.method.equilibrium.equilibrium_table` appends it) starts with one of these.
NO_T_EQ_REASONS = ("never settled", "not computed")
#: What the table shows for a time of the band detection that does not exist because dz never
#: stayed inside that band before the run's end.
NOT_SETTLED = "not settled"


def tau_bounds(span_s, max_rest_s: float = 0.0) -> tuple[float, float]:
    """``(lower, upper)`` bound of the fitted tau of a run spanning ``span_s`` seconds; the
    upper bound is the smallest the fit can have had (span less ``max_rest_s``)."""
    if not isnum(span_s):
        return TAU_MIN_S, np.nan
    return TAU_MIN_S, TAU_MAX_SPANS * max(float(span_s) - float(max_rest_s), 0.0)


def tau_at_bound(tau_s, span_s, max_rest_s: float = 0.0) -> str | None:
    """``"upper"`` / ``"lower"`` when ``tau_s`` sits at a bound of the fit (within
    :data:`BOUND_TOL`), else ``None``."""
    if not isnum(tau_s):
        return None
    lo, hi = tau_bounds(span_s, max_rest_s)
    if float(tau_s) <= lo * (1 + BOUND_TOL):
        return "lower"
    if isnum(hi) and hi > 0 and float(tau_s) >= hi * (1 - BOUND_TOL):
        return "upper"
    return None


def disagreement(t_eq_s, t_eq_tau_s) -> float:
    """``max / min`` of the detected t_eq and the tau cross-check (NaN when either is missing)."""
    if not (isnum(t_eq_s) and isnum(t_eq_tau_s)) or min(float(t_eq_s), float(t_eq_tau_s)) <= 0:
        return np.nan
    a, b = float(t_eq_s), float(t_eq_tau_s)
    return max(a, b) / min(a, b)


def disagreement_text(apart: list[str]) -> list[str]:
    """One sentence on the runs whose t_eq and tau cross-check differ by more than
    :data:`DISAGREE_FACTOR` (``[]`` without any)."""
    if not apart:
        return []
    runs = apart[0] if len(apart) == 1 else ", ".join(apart[:-1]) + " and " + apart[-1]
    one = len(apart) == 1
    return [
        f"The detected equilibrium time and the \u03c4 cross-check differ by more than a factor of "
        f"{DISAGREE_FACTOR:g} at {runs}: dz does not rise like a single first-order system on "
        f"{'this run' if one else 'these runs'}, the two estimates do not confirm each other and "
        f"t_eq is uncertain beyond the range in the table."
    ]


def no_t_eq_reason(t_eq_s, method) -> str | None:
    """Why a run of ``equilibrium.csv`` has no t_eq, in its own words (``None`` when it has one).

    Parameters
    ----------
    t_eq_s : float
        The run's detected equilibrium time (NaN: none).
    method : str
        The run's ``method``: the detection described, then ``"; never settled inside the band
        before the end of the run"`` or ``"; not computed: <n> valid samples"`` where there is no
        t_eq (:data:`NO_T_EQ_REASONS`).

    Returns
    -------
    str or None
        That last part, e.g. ``"never settled inside the band before the end of the run"``;
        ``"no time in equilibrium.csv"`` where the table gives none.
    """
    if isnum(t_eq_s):
        return None
    last = str(method or "").rsplit("; ", 1)[-1].strip()
    return last if last.startswith(NO_T_EQ_REASONS) else "no time in equilibrium.csv"


def beyond_run(t_eq_tau_s, span_s) -> bool:
    """Whether the t_eq from the fitted tau lies beyond the run's last sample: longer than the run's
    span (``runs.csv``: ``end_s - start_s``, which the time from the spindle start cannot exceed),
    a time the first-order fit extrapolates and the run never showed."""
    return bool(isnum(t_eq_tau_s) and isnum(span_s) and float(t_eq_tau_s) > float(span_s))


def band_times(row: dict, reason: str | None) -> dict:
    """The band detection's times of one run as the table shows them: ``t_eq`` and ``range``
    (``low - high``), each a time, :data:`NOT_SETTLED` where dz never stayed inside that band
    before the run's end, or an en dash where nothing was computed (``reason`` ``not computed``)."""
    computed = not (reason or "").startswith("not computed")

    def one(v) -> str:
        if isnum(v):
            return fmt_num(v, 0, "s")
        return NOT_SETTLED if computed else DASH

    lo, hi = row.get("t_eq_low_s"), row.get("t_eq_high_s")
    if not isnum(lo) and not isnum(hi):
        rng = NOT_SETTLED if computed else DASH
    else:
        rng = f"{one(lo)} \u2013 {one(hi)}"
    return {"t_eq": one(row.get("t_eq_s")), "range": rng}


def _speeds_text(speeds: list[str]) -> str:
    """``a``, ``a and b``, ``a, b and c``."""
    return speeds[0] if len(speeds) == 1 else ", ".join(speeds[:-1]) + " and " + speeds[-1]


def gap_text(gaps: list[tuple[str, str]]) -> list[str]:
    """One sentence per reason of the runs without a t_eq (``(speed, reason)``; ``[]`` without)."""
    by: dict = {}
    for speed, reason in gaps:
        by.setdefault(reason, []).append(speed)
    return [f"No t_eq at {_speeds_text(runs)}: {reason} (equilibrium.csv)." for reason, runs in by.items()]


def beyond_text(beyond: list[str]) -> list[str]:
    """One sentence on the runs whose t_eq from the fitted tau is longer than the run
    (``"<speed> (<t_eq_tau> against a run of <span>)"``; ``[]`` without)."""
    if not beyond:
        return []
    one = len(beyond) == 1
    return [
        f"The t_eq from the fitted \u03c4 is longer than the run at {_speeds_text(beyond)}: an "
        f"extrapolation of the first-order fit beyond the run's last sample, not a time "
        f"{'the run' if one else 'these runs'} showed."
    ]


def _run_spans(runs: pd.DataFrame | None) -> dict:
    """``run_id -> span (s)`` of runs.csv: ``end_s - start_s``, else ``duration_s``."""
    if runs is None or not len(runs) or "run_id" not in runs:
        return {}
    if {"start_s", "end_s"} <= set(runs.columns):
        span = runs["end_s"].astype(float) - runs["start_s"].astype(float)
    elif "duration_s" in runs:
        span = runs["duration_s"].astype(float)
    else:
        return {}
    return dict(zip(runs["run_id"].astype(str), span))


def equilibrium_description(eqs: dict | None) -> str:
    """The equilibrium method in words, with the machine's ``equilibrium`` settings."""
    if not eqs:
        return (
            "Equilibrium time: first time after which the smoothed dz stays inside a band around "
            "the final plateau; the \u03c4 columns are the first-order cross-check."
        )
    return (
        f"Equilibrium time t_eq: the first time after which the {fmt_num(eqs['smooth_window_s'], 0, 's')} "
        f"rolling median of dz stays within \u00b1{fmt_num(100 * float(eqs['band_fraction']), 0, '%')} of "
        f"the total rise around the final plateau (median of the last "
        f"{fmt_num(eqs['plateau_window_s'], 0, 's')}), counted from the spindle start (the first "
        "sample at half the run's median speed or more). The uncertainty range repeats the "
        "detection with a 1.5\u00d7 wider and narrower band. Cross-check: a first-order rise "
        f"dz = c + A (1 \u2212 e^(\u2212t/\u03c4)) fitted from the spindle start, with "
        f"t_eq = \u03c4 ln(1/{float(eqs['band_fraction']):g})."
    )


def section_equilibrium(res: dict, figs, settings: dict | None = None, *, paper: bool = False) -> dict:
    """Section 3: time to thermal equilibrium per training speed.

    Parameters
    ----------
    res : dict
        Loaded inputs (``equilibrium``, ``runs_csv``).
    figs : rafi.report.embed.FigureFiles
    settings : dict, optional
        The machine's settings (``runs.max_leading_rest_s`` for the fit's bound).
    paper : bool
        ``report.paper_rig``: the paper's Table 1 beside each time.

    Returns
    -------
    dict
        ``table`` (one dict per run: equilibrium.csv's times, ``t_eq`` / ``range`` as shown
        (:func:`band_times`), ``no_t_eq`` (why there is no t_eq, :func:`no_t_eq_reason`, or
        ``None``), ``bound`` (tau at a bound of the fit: ``"upper"``/``"lower"``/``None``),
        ``apart`` (the two estimates disagree), ``t_eq_flagged`` (``apart`` or no t_eq),
        ``beyond`` (the t_eq from tau is longer than the run: :func:`beyond_run`),
        ``tau_flagged``; with ``paper`` also ``paper_t_eq_s``,
        ``vs_paper_pct``), ``paper``, ``figure``, ``method`` and ``flags`` (sentences: the runs
        without a t_eq and why, tau at a bound, the two estimates disagreeing by more than
        :data:`DISAGREE_FACTOR`, a t_eq from tau beyond the run's end).
    """
    eq = res["equilibrium"]
    spans = _run_spans(res.get("runs_csv"))
    max_rest = float(((settings or {}).get("runs") or {}).get("max_leading_rest_s") or 0.0)
    rows, flags, apart, gaps, beyond = [], [], [], [], []
    if eq is not None:
        for i in eq.index:
            r = eq.loc[i]
            speed = fmt_speed(r.speed_rpm)
            span = spans.get(str(r.get("run_id", "")), np.nan)
            bound = tau_at_bound(r.tau_s, span, max_rest)
            if bound:
                lo, hi = tau_bounds(span, max_rest)
                limit = (
                    fmt_num(lo, 0, "s")
                    if bound == "lower"
                    else f"{TAU_MAX_SPANS:g} \u00d7 the fitted span, \u2265{NBSP}{fmt_num(hi, 0, 's')}"
                )
                flags.append(
                    f"{speed}: the first-order fit ended at its {bound} bound (\u03c4 = "
                    f"{fmt_num(r.tau_s, 0, 's')}, bound {limit}); the run does not identify a time "
                    "constant and the \u03c4 cross-check is void."
                )
            reason = no_t_eq_reason(r.t_eq_s, r.get("method"))
            if reason:
                gaps.append((speed, reason))
            past = not bound and beyond_run(r.t_eq_tau_s, span)
            if past:
                tau_t = fmt_num(r.t_eq_tau_s, 0, "s")
                beyond.append(f"{speed} ({tau_t} against a run of {fmt_num(span, 0, 's')})")
            ratio = np.nan if bound else disagreement(r.t_eq_s, r.t_eq_tau_s)
            far = bool(isnum(ratio) and ratio > DISAGREE_FACTOR)
            if far:
                apart.append(
                    f"{speed} ({fmt_num(r.t_eq_s, 0, 's')} against {fmt_num(r.t_eq_tau_s, 0, 's')}, "
                    f"factor {fmt_num(ratio, 2)})"
                )
            row = {
                k: plain(r.get(k))
                for k in (
                    "speed_rpm",
                    "t_eq_s",
                    "t_eq_low_s",
                    "t_eq_high_s",
                    "t_eq_tau_s",
                    "tau_s",
                    "plateau_um",
                )
            }
            row.update(band_times(row, reason))
            row.update(
                {
                    "bound": bound,
                    "apart": far,
                    "no_t_eq": reason,
                    "beyond": past,
                    "t_eq_flagged": far or bool(reason),
                    "tau_flagged": bool(bound) or far or past,
                }
            )
            if paper:
                ref = paper_value(eq, i, "paper_t_eq_s", T_EQ_S, r.speed_rpm)
                diff = (
                    (float(r.t_eq_s) - float(ref)) / float(ref) * 100
                    if isnum(ref) and isnum(r.t_eq_s)
                    else np.nan
                )
                row.update({"paper_t_eq_s": plain(ref), "vs_paper_pct": plain(diff)})
            rows.append(row)
    fig = figs.get("pipeline", "training_runs")
    method = None
    if eq is not None and "method" in eq and len(eq):
        method = str(eq["method"].iloc[0])
    return {
        "table": rows,
        "paper": paper,
        "figure": fig,
        "method": method,
        "description": equilibrium_description((settings or {}).get("equilibrium")),
        "flags": gap_text(gaps) + flags + disagreement_text(apart) + beyond_text(beyond),
        "factor": f"{DISAGREE_FACTOR:g}",
    }


def section_ranking(res: dict, key_info: dict, figs, *, paper: bool = False) -> dict:
    """Section 4: the correlation ranking, the chosen key sensors and their collinearity
    (``paper``: ``report.paper_rig``, the paper's key sensors beside them).

    Parameters
    ----------
    res : dict
        Loaded inputs (``correlation``, ``key_sensors``, ``collinearity``).
    key_info : dict
        ``rank/key_sensors.json``.
    figs : rafi.report.embed.FigureFiles
    paper : bool

    Returns
    -------
    dict
        ``table`` (one dict per sensor, best first: ``rank``, ``sensor``, ``min_abs_r``,
        ``max_abs_r``, ``pooled_abs_r``, ``passes``, ``chosen``), ``key_table``
        (``key_sensors.csv``'s rows), ``collinearity`` (``sensor`` and ``r``: column sensor ->
        r, for the sensors ``collinearity_sensors``) or ``collinearity_figure``, and the
        chosen set in words.
    """
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
        "collinearity_sensors": [],
        "collinearity_figure": None,
        "paper": PAPER_KEY_SENSORS if paper else None,
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
        out["table"] = [
            {
                "rank": k,
                "sensor": s,
                "min_abs_r": plain(score[s]),
                "max_abs_r": plain(per_speed[s].max() if len(per_speed) else np.nan),
                "pooled_abs_r": plain(pooled.get(s, np.nan)),
                "passes": bool(score[s] > threshold),
                "chosen": s in chosen,
            }
            for k, s in enumerate(order, start=1)
        ]
    if ks is not None:
        out["key_table"] = records(
            ks, {"sensor": "sensor", "score_abs_r": "score_abs_r", "selected_by": "selected_by"}
        )
    coll = res["collinearity"]
    if coll is not None and len(coll):
        m = collinearity_frame(coll)
        if len(m) <= MAX_COLLINEARITY_TABLE:
            out["collinearity"] = [
                {"sensor": i, "r": {c: plain(v) for c, v in m.loc[i].items()}} for i in m.index
            ]
            out["collinearity_sensors"] = list(m.columns)
        else:
            out["collinearity_figure"] = figs.get("pipeline", "collinearity")
        out.update(collinearity_text(m, chosen))
    return out


def collinearity_text(m: pd.DataFrame, chosen: list) -> dict:
    """The largest |r| between two chosen sensors and what it means, against
    :data:`COLLINEAR_ABS_R`: ``max_offdiag`` (formatted), ``pair`` and ``collinear`` (bool);
    empty without two sensors."""
    names = [s for s in chosen if s in m.index and s in m.columns] or list(m.index)
    best, pair = np.nan, None
    for k, a in enumerate(names):
        for b in names[k + 1 :]:
            v = abs(float(m.loc[a, b])) if isnum(m.loc[a, b]) else np.nan
            if isnum(v) and not (isnum(best) and v <= best):
                best, pair = v, (a, b)
    if pair is None:
        return {}
    return {
        "max_offdiag": fmt_num(best, 4),
        "pair": f"{pair[0]}\u2013{pair[1]}",
        "collinear": bool(best >= COLLINEAR_ABS_R),
        "collinear_limit": f"{COLLINEAR_ABS_R:g}",
    }
