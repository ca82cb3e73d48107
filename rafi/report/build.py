"""The qualification report: results tables -> context dict -> HTML (jinja2) -> PDF (WeasyPrint).

One template (``rafi/templates/qualification.html.j2``) renders the HTML; the PDF is
rendered from the *same* HTML string, so the two never disagree. Figures are embedded
(base64 PNG or inline SVG, made by :mod:`rafi.report.plots`), so the HTML needs no other file.

Inputs are the tables of ``docs/design.md`` under ``results/<machine>/``; optional
inputs (rendered only when present):

- ``registry/decision.json`` + ``registry/comparison.csv`` - the registry decision (champion
  vs candidate, per validation run, speed-range adaptation, drift); the kind / created / data
  of each model id is read from ``registry/models/<id>.json`` when present (immutable files,
  named by their content hash), else from ``comparison/summary.csv``;
- ``comparison/summary.csv``, ``per_run.csv``, ``cv.csv``, ``residuals.parquet`` - the model
  family comparison (``docs/models.md``);
- quarantined rows of ``audit.csv``.

With ``decision.json`` the verdict judges the model on the machine after this run (the
registry's champion); RAFI as published is always reported beside it as the paper's reference.

Figures can be drawn ahead (:func:`build_figures`, rule ``report_figures``: the method's
figures while ``compare`` runs, the model family's while ``decide`` runs) and passed to
:func:`build_context` (``figures=``, read with :func:`load_figures`); the section code is the
same either way, so the report is identical, and a figure not drawn ahead is drawn here.

All numbers are formatted here (the template only prints strings).
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import platform
import time
from importlib import metadata as _metadata
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from markupsafe import Markup, escape

from rafi.method import fuzzy, paper, validate

#: Paper values (Chang et al. 2023) used when a table lacks its ``paper_*`` column.
PAPER_T_EQ_S = paper.T_EQ_S
PAPER_RMSE_UM = paper.RMSE_UM
PAPER_RESIDUAL_UM = paper.RESIDUAL_UM
PAPER_MULTI = paper.MULTI_CONDITION

#: Files under ``results/<machine>/`` (design.md); ``None``-able ones are optional.
RESULT_FILES = {
    "audit": "audit.csv",
    "runs_csv": "runs.csv",
    "runs_parquet": "runs.parquet",
    "equilibrium": "equilibrium.csv",
    "correlation": "rank/correlation.csv",
    "key_sensors": "rank/key_sensors.csv",
    "key_sensors_json": "rank/key_sensors.json",
    "collinearity": "rank/collinearity.csv",
    "coefficients": "fit/coefficients.csv",
    "diagnostics": "fit/diagnostics.csv",
    "vif": "fit/vif.csv",
    "model": "model.json",
    "validation_summary": "validation/summary.csv",
    "residuals": "validation/residuals.parquet",
}
OPTIONAL_FILES = {
    "decision": "registry/decision.json",
    "registry_comparison": "registry/comparison.csv",
    "comparison": "comparison/summary.csv",
    "comparison_per_run": "comparison/per_run.csv",
    "comparison_cv": "comparison/cv.csv",
    "comparison_residuals": "comparison/residuals.parquet",
}

#: Coolant sensors drawn beside the key sensors (paper Table 2: 13 = coolant inlet, 5 = outlet).
DEFAULT_COOLANT_SENSORS = ["T13"]

SECTION_TITLES = {
    "verdict": "Verdict",
    "data": "Data",
    "equilibrium": "Thermal equilibrium",
    "ranking": "Key-sensor ranking",
    "models": "Models",
    "fuzzy": "Fuzzy blending",
    "validation": "Validation",
    "registry": "Model registry: champion vs candidate",
    "comparison": "Model comparison",
    "choices": "Choices the paper leaves open",
    "provenance": "Software, configuration and provenance",
}

NBSP = "\u00a0"
MINUS = "\u2212"


# =========================================================================== formatting


def _isnum(x) -> bool:
    try:
        return x is not None and not isinstance(x, bool) and math.isfinite(float(x))
    except (TypeError, ValueError):
        return False


def fmt_num(x, digits: int = 2, unit: str = "", *, signed: bool = False) -> str:
    """Fixed-point number with a true minus sign and an optional unit; ``-`` for missing."""
    if not _isnum(x):
        return "\u2013"
    v = float(x)
    if round(v, digits) == 0:
        v = 0.0
    s = f"{v:+,.{digits}f}" if signed else f"{v:,.{digits}f}"
    s = s.replace(",", NBSP).replace("-", MINUS)
    return f"{s}{NBSP}{unit}" if unit else s


def fmt_sig(x, sig: int = 3, unit: str = "") -> str:
    """Significant digits; scientific notation (a x 10^b) outside 1e-3..1e6."""
    if not _isnum(x):
        return "\u2013"
    v = float(x)
    if v == 0:
        s = "0"
    elif 1e-3 <= abs(v) < 1e5:
        digits = max(sig - 1 - int(math.floor(math.log10(abs(v)))), 0)
        s = f"{v:,.{digits}f}".replace(",", NBSP)
    else:
        mant, exp = f"{v:.{sig - 1}e}".split("e")
        s = f"{mant}\u00d710{_superscript(int(exp))}"
    s = s.replace("-", MINUS)
    return f"{s}{NBSP}{unit}" if unit else s


_SUP = str.maketrans("0123456789-", "\u2070\u00b9\u00b2\u00b3\u2074\u2075\u2076\u2077\u2078\u2079\u207b")
_SUB = str.maketrans("0123456789", "\u2080\u2081\u2082\u2083\u2084\u2085\u2086\u2087\u2088\u2089")


def _superscript(n: int) -> str:
    return str(n).translate(_SUP)


def fmt_p(p) -> str:
    """p-value: 3 significant digits, ``< 0.001`` below."""
    if not _isnum(p):
        return "\u2013"
    return "<" + NBSP + "0.001" if float(p) < 1e-3 else f"{float(p):.3f}"


def fmt_speed(rpm) -> str:
    return fmt_num(rpm, 0, "r/min")


def fmt_duration(seconds) -> str:
    """``4.00 h`` for runs, ``45 min`` under an hour."""
    if not _isnum(seconds):
        return "\u2013"
    s = float(seconds)
    return fmt_num(s / 3600.0, 2, "h") if s >= 3600 else fmt_num(s / 60.0, 0, "min")


def fmt_bool(x) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "\u2013"
    return "yes" if _truthy(x) else "no"


def _truthy(x) -> bool:
    if isinstance(x, str):
        return x.strip().lower() in {"true", "1", "yes"}
    return bool(x)


def cell(text, cls: str = "") -> dict:
    return {"text": text, "cls": cls}


def table(headers, rows, *, cls: str = "", widths=None, caption: str = "") -> dict:
    """A table for the template: headers (str), rows of cells (str or ``cell()`` dicts)."""
    norm = [[c if isinstance(c, dict) else cell(c) for c in r] for r in rows]
    return {"headers": list(headers), "rows": norm, "cls": cls, "widths": widths or [], "caption": caption}


def term_text(term: str, variables: dict) -> Markup:
    """``x1*x2^2`` -> ``x₁·x₂²`` (HTML-safe)."""
    if term == "1":
        return Markup("")
    parts = []
    for factor in term.replace(" ", "").split("*"):
        name, _, power = factor.partition("^")
        idx = name[1:]
        s = "x" + idx.translate(_SUB)
        if power:
            s += power.translate(_SUP)
        parts.append(s)
    return Markup("\u00b7".join(str(escape(p)) for p in parts))


def equation_text(coefs, terms, variables: dict) -> Markup:
    """``dz = 0.12 + 1.23·x₁ − ...`` with 4 significant digits per coefficient."""
    pieces = []
    for _k, (b, t) in enumerate(zip(coefs, terms)):
        if not _isnum(b):
            continue
        mag = fmt_sig(abs(float(b)), 4)
        tt = term_text(t, variables)
        body = f"{mag}{NBSP}{tt}" if str(tt) else mag
        sign = MINUS if float(b) < 0 else "+"
        if not pieces:
            pieces.append((MINUS if float(b) < 0 else "") + body)
        else:
            pieces.append(f" {sign} {body}")
    text = "dz = " + "".join(pieces) if pieces else "dz = 0"
    return Markup(f'<span class="eq">{escape(text)}</span>')


# =========================================================================== loading


def result_paths(results_dir: str | os.PathLike) -> dict:
    """Standard paths of every input under ``results/<machine>/`` (optional ones included)."""
    base = Path(results_dir)
    return {k: base / v for k, v in {**RESULT_FILES, **OPTIONAL_FILES}.items()}


def load_results(paths: dict) -> dict:
    """Read every table that exists; missing ones become ``None``.

    Parameters
    ----------
    paths : dict
        name -> path (names of :data:`RESULT_FILES` / :data:`OPTIONAL_FILES`).
    """
    out: dict = {}
    for name, p in paths.items():
        p = Path(p) if p else None
        if p is None or not p.is_file():
            out[name] = None
            continue
        if p.suffix == ".csv":
            out[name] = pd.read_csv(p, keep_default_na=True)
        elif p.suffix == ".parquet":
            out[name] = pd.read_parquet(p)
        elif p.suffix == ".json":
            out[name] = json.loads(p.read_text(encoding="utf-8"))
        else:
            out[name] = p.read_text(encoding="utf-8")
    return out


# =========================================================================== the verdict


def qualify(summary: pd.DataFrame, gates: dict) -> pd.DataFrame:
    """Verdict rows (criterion x validation run) of ``rafi.method.validate.qualify``; a ``run_id``
    column is always present."""
    verdict = validate.qualify(summary, gates)
    return verdict if "run_id" in verdict else verdict.assign(run_id="")


CRITERION_TEXT = {
    "max_residual_um": ("Largest residual after compensation", "\u2264", "\u00b5m", 2),
    "min_improvement_pct": ("Smallest improvement over no compensation", "\u2265", "%", 1),
    "never_worse_than_uncompensated": ("Runs worse than no compensation", "=", "", 0),
}


def aggregate_verdict(verdict: pd.DataFrame) -> list[dict]:
    """One row per criterion: the worst case over the validation runs.

    ``max_residual_um``: the largest residual; ``min_improvement_pct``: the smallest
    improvement; ``never_worse_than_uncompensated``: how many runs are worse (limit 0),
    naming them, or else the run closest to the limit. A NaN measurement fails.
    """
    out = []
    if verdict is None or not len(verdict):
        return out
    v = verdict.copy()
    v["measured"] = pd.to_numeric(v["measured"], errors="coerce")
    v["limit"] = pd.to_numeric(v["limit"], errors="coerce")
    v["passed"] = v["passed"].map(_truthy) & v["measured"].notna()
    for crit in dict.fromkeys(v["criterion"].astype(str)):
        g = v[v["criterion"].astype(str) == crit]
        passed = bool(g["passed"].all())
        label, op, unit, nd = CRITERION_TEXT.get(crit, (crit.replace("_", " "), "vs", "", 2))
        if crit == "never_worse_than_uncompensated":
            bad = g[~g["passed"]]
            ratio = (g["measured"] / g["limit"]).replace([np.inf, -np.inf], np.nan)
            if len(bad):
                note = "worse: " + ", ".join(bad["run_id"].astype(str))
            elif ratio.notna().any():
                i = ratio.idxmax()
                note = f"closest: {g.loc[i, 'run_id']} (after/before = {fmt_num(ratio[i], 2)})"
            else:
                note = ""
            out.append(
                {
                    "criterion": crit,
                    "label": label,
                    "limit": "= 0",
                    "measured": f"{len(bad)} of {len(g)}",
                    "run_id": note,
                    "passed": passed,
                }
            )
            continue
        if crit == "min_improvement_pct":
            i = g["measured"].fillna(-np.inf).idxmin()
        elif crit == "max_residual_um":
            i = g["measured"].fillna(np.inf).idxmax()
        elif not passed:
            i = g[~g["passed"]].index[0]
        else:
            i = g.index[0]
        lim = g.loc[i, "limit"]
        out.append(
            {
                "criterion": crit,
                "label": label,
                "limit": f"{op} {fmt_num(lim, nd, unit)}",
                "measured": fmt_num(g.loc[i, "measured"], nd, unit),
                "run_id": f"run {g.loc[i, 'run_id']}",
                "passed": passed,
            }
        )
    for r in out:
        r["status"] = "PASS" if r["passed"] else "FAIL"
    return out


def verdict_context(verdict: pd.DataFrame, source: str) -> dict:
    rows = aggregate_verdict(verdict)
    passed = bool(rows) and all(r["passed"] for r in rows)
    return {
        "passed": passed,
        "status": "PASS" if passed else "FAIL",
        "rows": rows,
        "source": source,
        "n_checks": 0 if verdict is None else len(verdict),
        "n_failed": 0 if verdict is None else int((~verdict["passed"].map(_truthy)).sum()),
    }


# =========================================================================== helpers


def _short(sha, n: int = 12) -> str:
    return str(sha)[:n] if isinstance(sha, str) and sha else "\u2013"


def _speed_key(x):
    try:
        v = float(x)
        return int(v) if v.is_integer() else v
    except (TypeError, ValueError):
        return x


def _paper(value_col, frame, i, table, speed):
    v = frame.loc[i, value_col] if value_col in frame else np.nan
    if not _isnum(v):
        v = table.get(_speed_key(speed), np.nan)
    return v


def eval_terms(terms, x: np.ndarray) -> np.ndarray:
    """Design matrix of the terms grammar (``1``, ``xi``, ``xi*xj``, ``xi^k``), NumPy only."""
    x = np.asarray(x, dtype=float)
    cols = []
    for t in terms:
        col = np.ones(len(x))
        if t.strip() != "1":
            for factor in t.replace(" ", "").split("*"):
                name, _, power = factor.partition("^")
                col = col * x[:, int(name[1:]) - 1] ** (int(power) if power else 1)
        cols.append(col)
    return np.column_stack(cols)


def membership(speeds, centres) -> np.ndarray:
    """Membership weights of ``rafi.method.fuzzy`` (columns follow sorted ``centres``)."""
    centres = sorted(float(c) for c in centres)
    return fuzzy.triangular_weights(np.asarray(speeds, float), centres)[0]


def _versions() -> list[dict]:
    out = [{"name": "python", "version": platform.python_version()}]
    for pkg in (
        "rafi",
        "numpy",
        "pandas",
        "scipy",
        "statsmodels",
        "snakemake",
        "matplotlib",
        "jinja2",
        "weasyprint",
        "pyarrow",
    ):
        try:
            v = _metadata.version(pkg)
        except _metadata.PackageNotFoundError:
            v = "not installed"
        out.append({"name": pkg, "version": v})
    return out


def _now(now=None) -> str:
    if now is None:
        epoch = os.environ.get("SOURCE_DATE_EPOCH")
        now = (
            _dt.datetime.fromtimestamp(int(epoch), _dt.UTC)
            if epoch
            else _dt.datetime.now(_dt.UTC)
        )
    return now.strftime("%Y-%m-%d %H:%M UTC")


def _collinearity_frame(coll: pd.DataFrame) -> pd.DataFrame:
    first = coll.columns[0]
    if not pd.api.types.is_numeric_dtype(coll[first]):
        coll = coll.set_index(first)
    coll.index = [str(i) for i in coll.index]
    return coll


def _flatten(d, prefix=""):
    items = []
    if isinstance(d, dict):
        for k, v in d.items():
            items += _flatten(v, f"{prefix}{k}.")
    elif isinstance(d, list) and not any(isinstance(v, (dict, list)) for v in d):
        items.append((prefix[:-1], ", ".join(_fmt_any(v) for v in d)))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            items += _flatten(v, f"{prefix}{i}.")
    else:
        items.append((prefix[:-1], _fmt_any(d)))
    return items


def _fmt_any(v) -> str:
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, np.integer)):
        return str(v)
    if _isnum(v):
        return fmt_sig(v, 4)
    if v is None:
        return "\u2013"
    s = str(v)
    return s[:16] + "\u2026" if len(s) == 64 and all(ch in "0123456789abcdef" for ch in s) else s


def split_wide(frame: pd.DataFrame, max_cols: int = 8) -> list[pd.DataFrame]:
    """Split a wide table into chunks of at most ``max_cols`` columns (first column repeated)."""
    if frame.shape[1] <= max_cols:
        return [frame]
    key, rest = frame.columns[0], list(frame.columns[1:])
    step = max_cols - 1
    return [frame[[key, *rest[i : i + step]]] for i in range(0, len(rest), step)]


def generic_table(frame: pd.DataFrame, caption: str = "") -> list[dict]:
    tables = []
    for part in split_wide(frame):
        rows = [
            [_fmt_any(v) if not (isinstance(v, float) and math.isnan(v)) else "\u2013" for v in r]
            for r in part.itertuples(index=False)
        ]
        tables.append(table([str(c).replace("_", " ") for c in part.columns], rows, caption=caption))
    return tables


# =========================================================================== sections


def _section_data(res, machine):
    runs = res["runs_csv"]
    rows = []
    if runs is not None:
        for r in runs.itertuples(index=False):
            speed = (
                fmt_speed(r.speed_rpm)
                if r.kind == "constant"
                else f"{r.kind} {fmt_num(r.speed_min_rpm, 0)}\u2013{fmt_speed(r.speed_max_rpm)}"
            )
            rows.append(
                [
                    cell(run_label(r.run_id)),
                    r.file,
                    r.role,
                    fmt_duration(r.duration_s),
                    speed,
                    _short(getattr(r, "sha256", "")),
                ]
            )
    runs_t = table(
        ["run", "file", "role", "duration", "speed", "sha256 (first 12)"],
        rows,
        cls="runs",
        widths=[18, 26, 16, 9, 17, 14],
    )
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
                        "sha256": _short(r.sha256),
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
    return {
        "runs": runs_t,
        "audit": audit_t,
        "quarantined": quarantined,
        "totals": totals,
        "roles": roles,
        "n_files": 0 if audit is None else len(audit),
    }


def _training_runs(res):
    runs = res["runs_csv"]
    if runs is None:
        return {}
    tr = runs[runs["role"] == "training"]
    return {_speed_key(r.speed_rpm): r.run_id for r in tr.itertuples(index=False)}


def _section_equilibrium(res, key, coolant, figs):
    eq = res["equilibrium"]
    rows = []
    eq_times = {}
    if eq is not None:
        for i in eq.index:
            r = eq.loc[i]
            paper = _paper("paper_t_eq_s", eq, i, PAPER_T_EQ_S, r.speed_rpm)
            eq_times[_speed_key(r.speed_rpm)] = float(r.t_eq_s) if _isnum(r.t_eq_s) else np.nan
            diff = (
                (float(r.t_eq_s) - float(paper)) / float(paper) * 100
                if _isnum(paper) and _isnum(r.t_eq_s)
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
    fig = None
    rf = res["runs_parquet"]
    train = _training_runs(res)
    if rf is not None and train:
        sensors = [s for s in list(key) + list(coolant) if s in rf.columns]
        runs = {}
        for speed, rid in train.items():
            f = rf.loc[rf["run_id"] == rid, ["t_s", *sensors, "dz_um"]]
            if len(f):
                runs[speed] = f
        if runs:
            fig = figs.get(
                "training_runs", "fig_training_runs", runs, temp_sensors=sensors, eq_times=eq_times
            )
    method = None
    if eq is not None and "method" in eq and len(eq):
        method = str(eq["method"].iloc[0])
    return {"table": t, "figure": fig, "method": method, "sensors": [s for s in list(key) + list(coolant)]}


def _section_ranking(res, key_info, figs):
    corr = res["correlation"]
    ks = res["key_sensors"]
    chosen = list(key_info.get("sensors") or (ks["sensor"].tolist() if ks is not None else []))
    threshold = float(key_info.get("threshold", 0.97))
    out = {
        "chosen": chosen,
        "threshold": threshold,
        "scope": key_info.get("scope", ""),
        "fallback_used": _truthy(key_info.get("fallback_used", False)),
        "message": key_info.get("message") or "",
        "figure": None,
        "table": None,
        "key_table": None,
        "collinearity": None,
        "collinearity_figure": None,
    }
    if corr is not None:
        corr = corr.copy()
        corr["scope"] = corr["scope"].astype(str)
        wide = corr.pivot_table(index="scope", columns="sensor", values="abs_r", aggfunc="first")
        sensors = sorted(wide.columns, key=lambda s: (len(s), s))
        scopes = sorted(
            wide.index,
            key=lambda s: (not s.replace(".", "").isdigit(), float(s) if s.replace(".", "").isdigit() else 0),
        )
        wide = wide.loc[scopes, sensors]
        out["figure"] = figs.get(
            "correlation_heatmap", "fig_correlation_heatmap", wide, threshold=threshold, chosen=chosen
        )
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
        m = _collinearity_frame(coll)
        if len(m) <= 8:
            out["collinearity"] = table(
                ["", *m.columns], [[i, *[fmt_num(v, 4) for v in m.loc[i]]] for i in m.index], cls="num narrow"
            )
        else:
            out["collinearity_figure"] = figs.get("collinearity", "fig_matrix", m)
        off = m.to_numpy(float)[~np.eye(len(m), dtype=bool)]
        out["max_offdiag"] = fmt_num(np.nanmax(np.abs(off)), 4) if off.size else None
    return out


def _section_models(res, figs):
    model = res["model"] or {}
    diag = res["diagnostics"]
    coefs = res["coefficients"]
    terms = list(
        model.get("terms") or (coefs["term"].drop_duplicates().tolist() if coefs is not None else [])
    )
    variables = dict(
        model.get("variables") or {f"x{i + 1}": s for i, s in enumerate(model.get("key_sensors", []))}
    )
    var_text = ", ".join(f"{k[0]}{k[1:].translate(_SUB)} = d{v} (K)" for k, v in variables.items())
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
    # recompute the training fit from model.json on runs.parquet (residual plots + RMSE check)
    fits, rmse_check = {}, {}
    rf = res["runs_parquet"]
    if rf is not None and speeds:
        sensors = [f"d{variables[f'x{i + 1}']}" for i in range(len(variables))]
        train = _training_runs(res)
        for sp in speeds:
            speed = _speed_key(sp["speed_rpm"])
            rids = list(sp.get("train_runs") or ([train[speed]] if speed in train else []))
            f = rf.loc[rf["run_id"].isin(rids)]
            if not len(f) or not all(s in f for s in sensors):
                continue
            X = eval_terms(terms, f[sensors].to_numpy(float))
            fitted = X @ np.asarray(sp["coefficients"], float)
            fits[speed] = pd.DataFrame(
                {"t_s": f["t_s"].to_numpy(), "measured_um": f["dz_um"].to_numpy(), "fitted_um": fitted}
            )
            r = f["dz_um"].to_numpy() - fitted
            rmse_check[speed] = float(np.sqrt(np.nanmean(r**2)))
    d_rows, mismatches = [], []
    if diag is not None:
        for i in diag.index:
            r = diag.loc[i]
            sp = _speed_key(r.speed_rpm)
            paper = _paper("paper_rmse_um", diag, i, PAPER_RMSE_UM, sp)
            chk = rmse_check.get(sp, np.nan)
            if _isnum(chk) and _isnum(r.rmse_um) and abs(chk - r.rmse_um) > 0.02 * r.rmse_um + 1e-3:
                mismatches.append(
                    f"{fmt_speed(sp)}: table {fmt_num(r.rmse_um, 3)} \u00b5m, "
                    f"recomputed {fmt_num(chk, 3)} \u00b5m"
                )
            d_rows.append(
                [
                    fmt_speed(sp),
                    fmt_num(r.n, 0),
                    fmt_num(r.rmse_um, 3),
                    fmt_num(paper, 3),
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
            "paper Table 3 RMSE (\u00b5m)",
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
        widths=[12, 6, 8, 10, 8, 8, 10, 9, 9, 9, 11],
    )
    coef_t = None
    if coefs is not None and len(coefs):
        c = coefs.copy()
        c["speed_rpm"] = c["speed_rpm"].map(_speed_key)
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
    fig = None
    if fits:
        fig = figs.get("fit_residuals", "fig_fit_residuals", fits)
    return {
        "equations": equations,
        "variables": var_text,
        "diagnostics": diag_t,
        "coefficients": coef_t,
        "figure": fig,
        "mismatches": mismatches,
        "terms": ", ".join(terms),
        "model_id": _short(model.get("model_id", ""), 16),
        "created": model.get("created", ""),
        "code_version": model.get("code_version", ""),
    }


def _section_fuzzy(res, figs):
    model = res["model"] or {}
    centres = sorted(float(sp["speed_rpm"]) for sp in model.get("speeds") or [])
    if not centres and res["diagnostics"] is not None:
        centres = sorted(res["diagnostics"]["speed_rpm"].astype(float).tolist())
    if len(centres) < 1:
        return None
    lo, hi = centres[0], centres[-1]
    span = max(hi - lo, 1000.0)
    grid = np.linspace(max(0.0, lo - 0.1 * span), hi + 0.1 * span, 801)
    W = fuzzy.membership_curves(centres, grid)
    source = "rafi.method.fuzzy.membership_curves"
    example = None
    if len(centres) >= 2:
        c0, c1 = centres[0], centres[1]
        ex = 4000.0 if (c0, c1) == (3000.0, 6000.0) else c0 + round((c1 - c0) / 3.0, -1)
        w = membership([ex], centres)[0]
        weights = {c: float(w[k]) for k, c in enumerate(centres) if w[k] > 0}
        example = {"speed": fmt_speed(ex), "rows": [], "weights": weights}
        sp_by = {float(sp["speed_rpm"]): sp for sp in model.get("speeds") or []}
        variables = model.get("variables") or {}
        terms = model.get("terms") or []
        # a worked number: the temperature state at the end of the lower neighbour's training run
        x_end = None
        rf = res["runs_parquet"]
        train = _training_runs(res)
        sensors = [f"d{variables[f'x{i + 1}']}" for i in range(len(variables))]
        if rf is not None and _speed_key(c0) in train and sensors and all(s in rf for s in sensors):
            f = rf.loc[rf["run_id"] == train[_speed_key(c0)], sensors]
            if len(f):
                x_end = f.iloc[-1].to_numpy(float)
        blended = 0.0
        for c in (c0, c1):
            d = abs(ex - c)
            wk = weights.get(c, 0.0)
            zk = np.nan
            if x_end is not None and c in sp_by:
                zk = float(
                    (eval_terms(terms, x_end[None, :]) @ np.asarray(sp_by[c]["coefficients"], float))[0]
                )
                blended += wk * zk
            example["rows"].append(
                [fmt_speed(c), fmt_num(d, 0, "r/min"), fmt_num(wk, 3), fmt_num(zk, 2, "\u00b5m")]
            )
        if x_end is not None:
            example["state"] = ", ".join(f"{s} = {fmt_num(v, 2, 'K')}" for s, v in zip(sensors, x_end))
            example["blended"] = fmt_num(blended, 2, "\u00b5m")
        example["table"] = table(
            ["training speed", "distance", "membership weight", "model dz at this state"],
            example["rows"],
            cls="num narrow",
        )
        example["w0"] = fmt_num(weights.get(c0, 0), 3)
        example["w1"] = fmt_num(weights.get(c1, 0), 3)
        example["c0"], example["c1"] = fmt_speed(c0), fmt_speed(c1)
        example["d0"], example["d1"] = fmt_num(abs(ex - c0), 0), fmt_num(abs(ex - c1), 0)
        is_paper = (c0, c1, ex) == (3000.0, 6000.0, 4000.0)
        example["is_paper"] = is_paper
    fig = figs.get(
        "membership",
        "fig_membership",
        grid,
        W,
        centres,
        example_rpm=None
        if example is None
        else float(example["speed"].split(NBSP + "r")[0].replace(NBSP, "")),
        example_weights=None if example is None else example["weights"],
    )
    return {
        "figure": fig,
        "example": example,
        "source": source,
        "outside": (model.get("fuzzy") or {}).get("outside", "edge"),
        "centres": ", ".join(fmt_num(c, 0) for c in centres) + NBSP + "r/min",
    }


def _section_validation(res, key, coolant, figs):
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
    }
    if summ is None:
        return out
    s = summ.copy()
    single = s[s["role"] == "validation_single"] if "role" in s else s
    rows = []
    for i in single.index:
        r = single.loc[i]
        paper = _paper("paper_residual_um", single, i, PAPER_RESIDUAL_UM, r.speed_rpm)
        worse = _truthy(r.get("worse_than_uncompensated", False))
        rows.append(
            [
                cell(run_label(r.run_id)),
                fmt_speed(r.speed_rpm),
                fmt_duration(r.duration_s),
                fmt_num(r.max_abs_before_um, 2),
                fmt_num(r.max_abs_after_um, 2),
                fmt_num(paper, 2),
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
            "paper Table 4 residual (\u00b5m)",
            "improvement (%)",
            "RMSE before (\u00b5m)",
            "RMSE after (\u00b5m)",
        ],
        rows,
        cls="num",
        widths=[17, 11, 8, 11, 11, 12, 10, 10, 10],
    )
    rows = []
    for r in s.itertuples(index=False):
        worse = _truthy(getattr(r, "worse_than_uncompensated", False))
        rows.append(
            [
                cell(run_label(r.run_id)),
                r.role,
                fmt_num(r.n_samples, 0),
                fmt_num(r.n_outside_temp_range, 0),
                fmt_num(r.n_outside_speed_range, 0),
                fmt_num(
                    100 * (r.n_outside_temp_range + 0) / r.n_samples
                    if _isnum(r.n_samples) and r.n_samples
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
    panels = {}
    for r in single.itertuples(index=False):
        f = resid[resid["run_id"] == r.run_id]
        if len(f):
            panels[f"{r.run_id}: {fmt_speed(r.speed_rpm)}"] = f
    if panels:
        out["figure_single"] = figs.get("validation_single", "fig_validation_single", panels)
    idle = s[s["role"] == "validation_idle"] if "role" in s else s.iloc[0:0]
    panels = {}
    for r in idle.itertuples(index=False):
        f = resid[resid["run_id"] == r.run_id]
        if len(f):
            panels[
                f"{r.run_id}: {fmt_num(r.max_abs_before_um, 1)} → "
                f"{fmt_num(r.max_abs_after_um, 1, chr(181) + 'm')}"
            ] = f
    out["figure_idle"] = figs.get("validation_idle", "fig_validation_single", panels) if panels else None
    out["n_idle"] = len(panels)
    rf = res["runs_parquet"]
    others = s[~s["role"].isin(["validation_single", "validation_idle"])] if "role" in s else s.iloc[0:0]
    for r in others.itertuples(index=False):
        f = resid[resid["run_id"] == r.run_id].copy()
        if not len(f):
            continue
        temps = [t for t in list(key) + list(coolant)]
        if rf is not None:
            tf = rf.loc[rf["run_id"] == r.run_id, ["t_s", *[t for t in temps if t in rf]]]
            f = f.merge(tf, on="t_s", how="left")
        fig = figs.get(f"multi_condition/{r.run_id}", "fig_multi_condition", f, temp_sensors=temps)
        paper = PAPER_MULTI if r.role == "validation_multi" else None
        changes = int((f["speed_rpm"].diff().abs() > 100).sum())
        out["multi"].append(
            {
                "run_id": r.run_id,
                "role": r.role,
                "figure": fig,
                "duration": fmt_duration(r.duration_s),
                "speeds": f"{fmt_num(f['speed_rpm'].min(), 0)}\u2013{fmt_speed(f['speed_rpm'].max())}",
                "changes": changes,
                "before": fmt_num(r.max_abs_before_um, 2, "\u00b5m"),
                "after": fmt_num(r.max_abs_after_um, 2, "\u00b5m"),
                "improvement": fmt_num(r.improvement_pct, 1, "%"),
                "outside_t": int(r.n_outside_temp_range),
                "outside_s": int(r.n_outside_speed_range),
                "n": int(r.n_samples),
                "paper": None
                if paper is None
                else {
                    "before": fmt_num(paper["before_um"], 2, "\u00b5m"),
                    "after": fmt_num(paper["after_um"], 2, "\u00b5m"),
                    "improvement": fmt_num(paper["improvement_pct"], 1, "%"),
                },
            }
        )
    return out


def _section_choices(settings: dict, key_info: dict, model: dict, eq_method):
    ref = settings.get("reference") or (model or {}).get("reference") or {}
    eqs = settings.get("equilibrium") or {}
    rank = settings.get("rank") or {}
    fit = settings.get("fit") or {}
    fz = settings.get("fuzzy") or (model or {}).get("fuzzy") or {}
    clean = settings.get("clean") or {}
    runs = settings.get("runs") or {}
    models = settings.get("models") or {}
    rule = ref.get("rule", "run_start")
    scope_text = (
        "the smallest |r| over the training speeds must pass"
        if rank.get("scope", key_info.get("scope")) == "min_per_speed"
        else "all training runs pooled"
    )
    rule_text = {
        "run_start": "the median of the first {w} s of each run",
        "log_start": "the median of the first {w} s of the log/segment the run came from",
    }
    rows = [
        (
            "Regressors and target",
            "Temperature rises dT = T \u2212 T_ref (K) of the key sensors and displacement change "
            "dz = disp \u2212 disp_ref (\u00b5m); the reference state is "
            + rule_text.get(rule, "rule '{r}' over {w} s").format(w=ref.get("window_s", "?"), r=rule)
            + f" (reference.rule = {rule}). Absolute temperatures would make the model depend on the "
            "season.",
        ),
        (
            "Thermal equilibrium",
            f"First time after which the {fmt_num(eqs.get('smooth_window_s'), 0, 's')} rolling median "
            f"of dz stays within \u00b1{fmt_num(100 * float(eqs.get('band_fraction', 0.05)), 0)} % of "
            f"the total rise around the final plateau (median of the last "
            f"{fmt_num(eqs.get('plateau_window_s'), 0, 's')}); uncertainty from a 1.5\u00d7 wider / "
            "narrower band; cross-check with a fitted first-order time constant."
            + (f" Method recorded: {eq_method}." if eq_method else ""),
        ),
        (
            "Correlation scope",
            f"Pearson r of each sensor rise with dz, scope = {rank.get('scope', key_info.get('scope', '?'))}"
            f" ({scope_text}); "
            f"threshold |r| > {rank.get('threshold', key_info.get('threshold', 0.97))}, at most "
            f"{rank.get('max_key_sensors', 3)} key sensors.",
        ),
        (
            "Fewer sensors than needed pass the threshold",
            "Fallback: the best-scoring sensors are taken up to max_key_sensors and marked "
            "'fallback' in rank/key_sensors.csv; the report shows the message."
            + (
                f" This run: {key_info.get('message')}"
                if _truthy(key_info.get("fallback_used"))
                else " This run: not needed."
            ),
        ),
        (
            "Outside the trained speed range",
            f"fuzzy.outside = {fz.get('outside', 'edge')}: the nearest edge model is used with weight "
            "1 (no extrapolation in speed) and the sample is flagged outside_speed_range; samples "
            "whose key-sensor rises leave the fitted range are flagged outside_temp_range and counted "
            "in section Validation.",
        ),
        (
            "Standard errors",
            f"OLS coefficients with Newey-West (HAC) standard errors, {fit.get('hac_maxlags', '?')} "
            "lags, because 5 s samples are strongly autocorrelated; the plain OLS errors are "
            "reported in fit/coefficients.csv but not used for inference.",
        ),
        (
            "Validation",
            "By whole run: a validation run is never used for training (no "
            "sample-wise cross-validation, which would leak through autocorrelation).",
        ),
        (
            "Fuzzy membership",
            "Triangular functions centred on the training speeds (see Fuzzy "
            "blending for the paper's 0.334 / 0.666 wording).",
        ),
        (
            "Cleaning the logs",
            f"Regular grid of {fmt_num(settings.get('sample_period_s'), 0, 's')}; duplicate rows "
            "dropped (first kept); rows at most 3 samples out of order re-sorted, a larger step back "
            "is an error; single-sample spikes (beyond both neighbours by more than "
            f"{clean.get('spike_threshold', '?')} robust sigma of the first differences) replaced by "
            f"interpolation; open-circuit values {clean.get('open_circuit_values', [])} treated as "
            f"missing; gaps and dropouts up to {fmt_num(clean.get('max_interpolate_gap_s'), 0, 's')} "
            "interpolated linearly, a longer gap splits the log into segments (never bridged). Every "
            "action is listed per file in results/<machine>/clean/<file>.audit.csv.",
        ),
        (
            "Runs, roles and the rest before start",
            f"Runs are cut from the speed column: constant for at least "
            f"{fmt_num(runs.get('min_constant_s'), 0, 's')} at a training speed -> training, elsewhere "
            "-> single-speed validation; shorter steps -> one multi-condition run; speed below "
            f"{fmt_num(runs.get('idle_below_rpm'), 0, 'r/min')} -> idle cool-down (validated, never "
            "trained on). A rest at the start of a log shorter than "
            f"{fmt_num(runs.get('max_leading_rest_s'), 0, 's')} belongs to the run, so the reference "
            "state is the cold machine at rest, before the spindle turns (what a controller "
            "compensation is relative to). Roles can be overridden per file (runs.overrides).",
        ),
        (
            "Sensor dropouts",
            f"A sensor's correlation uses the samples it has; a sensor present in fewer than "
            f"{fmt_num(100 * float(rank.get('min_coverage', 0.9)), 0, '%')} of a speed's samples is "
            "not ranked there. Samples with a missing key sensor are left out of the fit and "
            "get no prediction.",
        ),
        (
            "Model family and the champion",
            "Besides RAFI as published, the models in models.enabled "
            f"({', '.join(models.get('enabled', []))}) "
            f"are fitted on the same training runs; their hyperparameters come from whole-run "
            f"cross-validation ({models.get('cv', 'leave_one_run_out')}) on training runs only. The "
            "champion is the best model that passes every gate on every validation run; RAFI as "
            "published is always reported as the paper's reference. A centrifugal (speed-squared) "
            "term is used only when training runs contain a speed step that identifies it.",
        ),
    ]
    return [{"topic": a, "text": b} for a, b in rows]


def run_label(run_id) -> Markup:
    """A run id that may wrap: ``<wbr>`` after ``_`` / ``-`` and before ``#``
    (``thermal_log_2026-10-14#3`` breaks as ``thermal_log_`` / ``2026-10-14`` / ``#3``)."""
    text = str(escape(str(run_id)))
    text = text.replace("_", "_<wbr>").replace("#", "<wbr>#")
    return Markup(text)


def _id_short(model_id, n: int = 12) -> str:
    return str(model_id)[:n] if isinstance(model_id, str) and model_id else "\u2013"


def _num_or_nan(v) -> float:
    return float(v) if _isnum(v) else np.nan


def _model_infos(res: dict, registry_dir: Path | None) -> dict:
    """``model_id -> {kind, created, files, name}`` from every source that names models."""
    infos: dict = {}

    def add(mid, **kw):
        if not isinstance(mid, str) or not mid:
            return
        cur = infos.setdefault(mid, {"kind": None, "created": None, "files": None, "name": None})
        for k, v in kw.items():
            if v is not None and cur.get(k) is None:
                cur[k] = v

    model = res.get("model") or {}
    add(
        model.get("model_id"),
        kind=model.get("kind", "rafi"),
        created=model.get("created"),
        files=sorted((model.get("data") or {}).keys()) or None,
        name="rafi",
    )
    summ = res.get("comparison")
    if summ is not None and "model_id" in summ:
        for r in summ.to_dict("records"):
            add(r.get("model_id"), kind=r.get("kind"), name=r.get("model"))
    dec = res.get("decision")
    if registry_dir is not None and isinstance(dec, dict):
        for mid in {dec.get("candidate_id"), dec.get("champion_id_before"), dec.get("champion_id_after")}:
            if not isinstance(mid, str) or "/" in mid or not mid:
                continue
            path = Path(registry_dir) / "models" / f"{mid}.json"
            if path.is_file():
                try:
                    d = json.loads(path.read_text(encoding="utf-8"))
                except (OSError, ValueError):
                    continue
                add(
                    mid,
                    kind=d.get("kind"),
                    created=d.get("created"),
                    files=sorted((d.get("data") or {}).keys()),
                )
    return infos


def _registry_summary(comp: pd.DataFrame | None, who: str) -> pd.DataFrame | None:
    """Per-run summary (``rafi.method.validate`` columns) of the champion or the candidate from
    ``registry/comparison.csv``."""
    col = f"{who}_max_abs_after_um"
    if comp is None or col not in comp or comp[col].isna().all():
        return None
    out = pd.DataFrame(
        {
            "run_id": comp["run_id"].astype(str),
            "role": comp["role"].astype(str) if "role" in comp else "validation_single",
            "speed_rpm": comp.get("speed_rpm"),
            "max_abs_before_um": pd.to_numeric(comp["max_abs_before_um"], errors="coerce"),
            "max_abs_after_um": pd.to_numeric(comp[col], errors="coerce"),
            "improvement_pct": pd.to_numeric(comp[f"{who}_improvement_pct"], errors="coerce"),
        }
    )
    return out[out["max_abs_after_um"].notna()].reset_index(drop=True)


def _per_run_gates(summary: pd.DataFrame, gates: dict) -> dict:
    """``run_id -> (passed, [failed criteria])`` with the pipeline's own gate rules."""
    if summary is None or not len(summary):
        return {}
    v = qualify(summary, gates)
    out = {}
    for rid, g in v.groupby(v["run_id"].astype(str), sort=False):
        ok = g["passed"].map(_truthy) & pd.to_numeric(g["measured"], errors="coerce").notna()
        out[rid] = (bool(ok.all()), g.loc[~ok, "criterion"].astype(str).tolist())
    for rid in summary["run_id"].astype(str):
        out.setdefault(rid, (True, []))
    return out


GATE_SHORT = {
    "max_residual_um": "residual",
    "min_improvement_pct": "improvement",
    "never_worse_than_uncompensated": "worse than uncomp.",
}


def _gate_cell(result) -> dict:
    if result is None:
        return cell("\u2013")
    ok, failed = result
    if ok:
        return cell("PASS", "pass")
    return cell("FAIL: " + ", ".join(GATE_SHORT.get(c, c) for c in failed), "fail")


DECISION_TEXT = {
    "promoted": (
        "pass",
        "PROMOTED",
        "tonight's candidate passed every gate and is now the model on the machine",
    ),
    "kept": ("neutral", "KEPT", "the model on the machine is unchanged"),
    "rejected": (
        "fail",
        "REJECTED",
        "tonight's candidate failed qualification; it does not go on the machine",
    ),
    "rolled_back": ("warn", "ROLLED BACK", "an operator set the model on the machine by hand"),
}


def _champion_after_summary(res: dict, dec: dict):
    """Validation summary of the model on the machine after this run, and where it came from."""
    after = dec.get("champion_id_after")
    comp = res.get("registry_comparison")
    if not after:
        return None, ""
    if after == dec.get("candidate_id"):
        s = _registry_summary(comp, "candidate")
        if s is not None:
            return s, "registry/comparison.csv (candidate columns)"
    if after == dec.get("champion_id_before"):
        s = _registry_summary(comp, "champion")
        if s is not None:
            return s, "registry/comparison.csv (champion columns)"
    pr = res.get("comparison_per_run")
    if pr is not None and "model_id" in pr:
        g = pr[pr["model_id"].astype(str) == after]
        if len(g):
            return g.reset_index(drop=True), "comparison/per_run.csv"
    model = res.get("model") or {}
    if model.get("model_id") == after and res.get("validation_summary") is not None:
        return res["validation_summary"], "validation/summary.csv"
    return None, ""


def _verdict_all(res: dict, gates: dict, infos: dict) -> dict:
    """The verdict of section 1: the model on the machine (with decision.json) + RAFI."""
    rafi_v = None
    if res["validation_summary"] is not None:
        rafi_v = verdict_context(
            qualify(res["validation_summary"], gates), "from rafi.method.validate.qualify"
        )
        gated = res["validation_summary"]
        if "role" in gated:
            gated = gated[gated["role"].astype(str) != "validation_idle"]
        rafi_v["worst"] = fmt_num(
            pd.to_numeric(gated["max_abs_after_um"], errors="coerce").max(), 2, "\u00b5m"
        )
        rafi_v["min_imp"] = fmt_num(pd.to_numeric(gated["improvement_pct"], errors="coerce").min(), 1, "%")
    else:
        rafi_v = {
            "passed": False,
            "status": "FAIL",
            "source": "no validation summary",
            "rows": [],
            "n_checks": 0,
            "n_failed": 0,
            "worst": "\u2013",
            "min_imp": "\u2013",
        }
    dec = res.get("decision")
    if not isinstance(dec, dict):
        out = dict(rafi_v)
        out.update(judged=None, rafi=None, subject="RAFI as published (model.json)")
        return out
    after = dec.get("champion_id_after")
    info = infos.get(after or "", {})
    decision = str(dec.get("decision", "?"))
    judged = {
        "id": _id_short(after),
        "kind": info.get("kind") or "kind unknown",
        "decision": decision,
        "decision_cls": DECISION_TEXT.get(decision, ("neutral",))[0],
        "none": not after,
        "is_rafi": info.get("kind") == "rafi",
    }
    summ, src = _champion_after_summary(res, dec)
    if summ is not None and len(summ):
        v = qualify(summ, gates)
        out = verdict_context(v, "computed from " + src)
    else:
        out = {
            "passed": False,
            "status": "FAIL",
            "rows": [],
            "n_checks": 0,
            "n_failed": 0,
            "source": (
                "no model on the machine"
                if not after
                else "no validation results for this model in this run's outputs"
            ),
        }
    out.update(judged=judged, rafi=rafi_v, subject=f"model {judged['id']} ({judged['kind']}) on the machine")
    return out


def _section_registry(res: dict, gates: dict, infos: dict):
    dec = res.get("decision")
    if not isinstance(dec, dict):
        return None
    decision = str(dec.get("decision", "?"))
    cls, word, meaning = DECISION_TEXT.get(decision, ("neutral", decision.upper(), ""))
    out = {
        "decision": decision,
        "cls": cls,
        "word": word,
        "meaning": meaning,
        "reasons": [str(r) for r in dec.get("reasons") or []],
        "time": str(dec.get("time") or "\u2013"),
        "schema": dec.get("schema", ""),
    }
    cand_id, champ_id = dec.get("candidate_id"), dec.get("champion_id_before")
    after = dec.get("champion_id_after")
    comp = res.get("registry_comparison")
    cand_s, champ_s = _registry_summary(comp, "candidate"), _registry_summary(comp, "champion")
    cs, ks = dec.get("candidate_summary") or {}, dec.get("champion_summary") or {}

    def info_col(mid, summ_rec, summ, present):
        if not mid:
            return ["none (no champion yet)" if not present else "\u2013"] + ["\u2013"] * 6
        i = infos.get(mid, {})
        files = i.get("files")
        gate = _per_run_gates(summ, gates) if summ is not None else {}
        n_fail = sum(1 for ok, _ in gate.values() if not ok)
        files_text = Markup(", ".join(str(escape(f)) for f in files)) if files else "\u2013"
        return [
            Markup(f"<code>{escape(_id_short(mid))}</code>"),
            i.get("kind") or "\u2013",
            i.get("created") or "\u2013",
            cell(Markup(f"{len(files)} file(s): <small>{files_text}</small>")) if files else "\u2013",
            fmt_num((summ_rec or {}).get("max_residual_um"), 2, "\u00b5m"),
            fmt_num((summ_rec or {}).get("min_improvement_pct"), 1, "%"),
            (
                cell("no validation runs", "")
                if not gate
                else cell("PASS on every run", "pass")
                if n_fail == 0
                else cell(f"FAIL on {n_fail} of {len(gate)} run(s)", "fail")
            ),
        ]

    labels = [
        "model id",
        "kind",
        "created",
        "training data",
        "worst max residual (gated runs)",
        "min improvement (gated runs)",
        "gates",
    ]
    champ_col = info_col(champ_id, ks, champ_s, False)
    cand_col = info_col(cand_id, cs, cand_s, True)
    rows = [[cell(label, "rowhead"), a, b] for label, a, b in zip(labels, champ_col, cand_col)]
    head_champ = "champion before this run" + (" (stays)" if after and after == champ_id else "")
    head_cand = "candidate" + (
        " (now on the machine)" if after and after == cand_id and after != champ_id else ""
    )
    out["side"] = table(["", head_champ, head_cand], rows, cls="side", widths=[22, 39, 39])

    # per validation run
    out["runs"] = None
    if comp is not None and len(comp) and res.get("runs_csv") is not None:
        order = {str(r): k for k, r in enumerate(res["runs_csv"]["run_id"].astype(str))}
        comp = comp.assign(_o=comp["run_id"].astype(str).map(order).fillna(len(order)))
        comp = comp.sort_values("_o", kind="stable").drop(columns="_o")
    if comp is not None and len(comp):
        g_c = _per_run_gates(cand_s, gates) if cand_s is not None else {}
        g_k = _per_run_gates(champ_s, gates) if champ_s is not None else {}
        rows = []
        for r in comp.to_dict("records"):
            rid = str(r["run_id"])
            new = _truthy(r.get("new_since_champion", False))
            rows.append(
                [
                    cell(Markup(f"{run_label(rid)}" + (' <span class="tag">new</span>' if new else ""))),
                    str(r.get("role", "")).replace("validation_", ""),
                    fmt_num(r.get("max_abs_before_um"), 2),
                    fmt_num(r.get("champion_max_abs_after_um"), 2),
                    fmt_num(r.get("champion_improvement_pct"), 1),
                    _gate_cell(g_k.get(rid)) if g_k else "\u2013",
                    fmt_num(r.get("candidate_max_abs_after_um"), 2),
                    fmt_num(r.get("candidate_improvement_pct"), 1),
                    _gate_cell(g_c.get(rid)) if g_c else "\u2013",
                ]
            )
        out["runs"] = table(
            [
                "validation run",
                "role",
                "max |dz| uncomp. (\u00b5m)",
                "champion max |res.| (\u00b5m)",
                "champion impr. (%)",
                "champion gates",
                "candidate max |res.| (\u00b5m)",
                "candidate impr. (%)",
                "candidate gates",
            ],
            rows,
            cls="num runs-cmp",
            widths=[19, 8, 9, 10, 9, 11, 10, 9, 15],
        )

    # speed-range adaptation
    ad = dec.get("adaptation") or {}
    rng = ad.get("retrain_speed_range_rpm")
    rs = dec.get("retrained_speeds") or []
    mode = ad.get("mode", "full")
    if mode == "speed_range":
        lo, hi = (list(rng or []) + [None, None])[:2]
        text = (
            f"Speed-range adaptation: only the speeds in [{fmt_num(lo, 0)}, "
            f"{fmt_speed(hi)}] were retrained from this run's data; every other speed keeps "
            f"the champion's regression (from model {_id_short(ad.get('kept_from'))})."
        )
    elif rng is not None:
        text = (
            f"Speed-range adaptation was requested (retrain_speed_range_rpm = {rng}) but the "
            "full new fit is the candidate."
        )
    else:
        ckind = infos.get(cand_id or "", {}).get("kind")
        text = "Full refit: retrain_speed_range_rpm is not set, so the candidate is the complete new fit"
        if rs:
            text += " (every speed retrained on the runs below)."
        elif cand_id and cand_id == champ_id:
            text += "; it equals the champion (no new training data), nothing was retrained."
        elif ckind and ckind not in ("rafi", "rafi_linear"):
            text += (
                f"; {ckind} is one global model fitted on every training run (no per-speed "
                "regressions to list)."
            )
        else:
            text += "."
    out["adapt_text"] = text
    out["adapt_note"] = ad.get("note") or ""
    out["retrained"] = None
    if rs:
        out["retrained"] = table(
            ["speed", "training runs", "files"],
            [
                [
                    fmt_speed(r.get("speed_rpm")),
                    cell(Markup(", ".join(str(run_label(x)) for x in r.get("train_runs") or [])) or "\u2013"),
                    cell(
                        Markup(
                            "<small>" + ", ".join(str(escape(x)) for x in r.get("files") or []) + "</small>"
                        )
                    ),
                ]
                for r in rs
            ],
            cls="num",
            widths=[16, 34, 50],
        )
    new_files = (dec.get("data") or {}).get("new_since_champion") or []
    out["new_files"] = ", ".join(str(f) for f in new_files)

    # drift
    dr = dec.get("drift") or {}
    status = str(dr.get("status", "\u2013"))
    recal = _truthy(dec.get("recalibration_due", False))
    status_text = {
        "ok": "no drift: the champion's residual on the new validation logs is within the margin",
        "degraded": "DRIFT DETECTED: the champion's residual on the new validation logs grew "
        "beyond the margin",
        "no_new_runs": "no validation log is new since the champion's promotion: nothing to check",
        "no_reference": "the champion's residual at promotion is unknown: drift cannot be judged",
        "no_champion": "no champion yet: nothing to check",
    }.get(status, status)
    if status == "degraded" and not recal:
        status_text += "; resolved by tonight's promotion (no recalibration due)"
    per_run = dr.get("per_run") or {}
    out["drift"] = {
        "status": status,
        "text": status_text,
        "detected": _truthy(dr.get("detected", False)),
        "recal": recal,
        "champion": _id_short(dr.get("champion_id")),
        "promoted_at": dr.get("promoted_at") or "\u2013",
        "margin": fmt_num(dr.get("margin_um"), 2, "\u00b5m"),
        "reference": fmt_num(dr.get("reference_max_residual_um"), 2, "\u00b5m"),
        "now": fmt_num(dr.get("new_max_residual_um"), 2, "\u00b5m"),
        "limit": fmt_num(dr.get("limit_um"), 2, "\u00b5m"),
        "degradation": fmt_num(dr.get("degradation_um"), 2, "\u00b5m", signed=True),
        "new_runs": Markup(", ".join(str(run_label(r)) for r in dr.get("new_runs") or [])),
        "per_run": table(
            ["new validation run", "champion max |residual|"],
            [[cell(run_label(k)), fmt_num(v, 2, "\u00b5m")] for k, v in per_run.items()],
            cls="num narrow",
        )
        if per_run
        else None,
    }
    return out


def _cv_stats(cv: pd.DataFrame | None) -> dict:
    if cv is None or not len(cv) or "model" not in cv:
        return {}
    out = {}
    for name, g in cv.groupby("model"):
        out[str(name)] = {"folds": len(g), "scheme": str(g["scheme"].iloc[0]) if "scheme" in g else ""}
    return out


def _section_comparison(res: dict, gates: dict, champion_after, settings: dict, figs):
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
    champ_rows = s[s["champion"].map(_truthy)] if "champion" in s else s.iloc[0:0]
    fam_champ = champ_rows["model"].iloc[0] if len(champ_rows) else None
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
        passed = _truthy(r.get("passed", False))
        n = r.get("n_samples")
        share = (
            100.0 * float(r["n_outside_temp_range"]) / float(n)
            if _isnum(n) and float(n) > 0 and _isnum(r.get("n_outside_temp_range"))
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
    p = pr.copy()
    p["model"], p["run_id"] = p["model"].astype(str), p["run_id"].astype(str)
    models = list(dict.fromkeys(s["model"]))
    runs = list(dict.fromkeys(p["run_id"]))
    after = p.pivot_table(
        index="run_id", columns="model", values="max_abs_after_um", aggfunc="first"
    ).reindex(index=runs, columns=models)
    imp = p.pivot_table(index="run_id", columns="model", values="improvement_pct", aggfunc="first").reindex(
        index=runs, columns=models
    )
    before = p.groupby("run_id")["max_abs_before_um"].first().reindex(runs)
    role = p.groupby("run_id")["role"].first().reindex(runs).astype(str)
    passed = (
        p.assign(ok=p["passed"].map(_truthy))
        .pivot_table(index="run_id", columns="model", values="ok", aggfunc="first")
        .reindex(index=runs, columns=models)
        .fillna(True)
        .astype(bool)
    )
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
    labels = {
        m: m + (" (champion)" if m == fam_champ else "") + (" (paper)" if m == "rafi" else "") for m in models
    }
    out["figure_bars"] = figs.get(
        "comparison_bars",
        "fig_comparison_bars",
        after,
        before,
        failed=~passed,
        gate_um=_num_or_nan(gates.get("max_residual_um")),
        labels=labels,
    )

    # RAFI as published: where it fails and why
    rafi_name = next((r["model"] for r in s.to_dict("records") if str(r.get("kind")) == "rafi"), None)
    if rafi_name is not None and rafi_name in passed.columns and not passed[rafi_name].all():
        bad = p[(p["model"] == rafi_name) & ~p["passed"].map(_truthy)]
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
        rule = (settings.get("reference") or {}).get("rule") or (
            (res.get("model") or {}).get("reference") or {}
        ).get("rule")
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

    # residual time series: RAFI vs the champion on the multi-condition run(s)
    resid = res.get("comparison_residuals")
    if resid is not None and len(resid) and rafi_name is not None:
        other = on_machine if on_machine and on_machine != rafi_name else fam_champ
        if other is None or other == rafi_name:
            cands = [m for m in models if m != rafi_name]
            other = min(cands, key=lambda m: after[m].max()) if cands else None
        multi = [r for r in runs if role[r] == "validation_multi"]
        if not multi and rafi_name in after:
            multi = [after[rafi_name].idxmax()]
        for rid in multi[:2]:
            sub = resid[resid["run_id"].astype(str) == rid]
            series = {}
            for m in [rafi_name, other]:
                if m is None:
                    continue
                f = sub[sub["model"].astype(str) == m].sort_values("t_s")
                if len(f):
                    series[
                        f"{m}" + (" (paper)" if m == rafi_name else " (champion)" if m == fam_champ else "")
                    ] = f
            if not series:
                continue
            rf = sub[sub["model"].astype(str) == rafi_name].sort_values("t_s")
            # keyed by the model drawn beside RAFI: the only input here that can depend on
            # the registry decision (on_machine)
            fig = figs.get(
                f"comparison_residuals/{rid}/{other}",
                "fig_comparison_residuals",
                series,
                measured=rf[["t_s", "measured_um"]] if len(rf) else None,
                outside=(
                    rf[["t_s"]].assign(outside=rf["outside_temp_range"].map(_truthy))
                    if len(rf) and "outside_temp_range" in rf
                    else None
                ),
                gate_um=_num_or_nan(gates.get("max_residual_um")),
            )
            out["figures_resid"].append(
                {"run_id": rid, "figure": fig, "other": other, "rafi": rafi_name, "role": role[rid]}
            )
    return out


# =========================================================================== figures

#: Figures that can be drawn before the report, by group, with the inputs each group reads.
#: Rule ``report_figures`` draws a group into ``results/<machine>/report/figures-<group>.json``
#: as soon as its inputs exist (``pipeline`` beside ``compare``, ``comparison`` beside
#: ``decide``); the report reuses them and draws only the figures that are missing.
FIGURE_GROUPS = {
    "pipeline": (
        "runs_csv",
        "runs_parquet",
        "equilibrium",
        "correlation",
        "key_sensors",
        "key_sensors_json",
        "collinearity",
        "coefficients",
        "diagnostics",
        "model",
        "validation_summary",
        "residuals",
    ),
    "comparison": ("model", "comparison", "comparison_per_run", "comparison_cv", "comparison_residuals"),
}
FIGURES_SCHEMA = "rafi.report.figures/1"


class Figures:
    """The report's figures by key: taken from ``known`` (drawn ahead by :func:`build_figures`)
    when there, else drawn now with :mod:`rafi.report.plots` and kept in ``drawn``.

    A key names the figure and every input of it that is not fixed by the files of its
    group and the parameters (e.g. the model drawn beside RAFI, which follows the registry
    decision), so a known figure is the figure this report would draw.
    """

    def __init__(self, fmt: str = "png", known: dict | None = None):
        self.fmt = fmt
        self.known = dict(known or {})
        self.drawn: dict = {}
        self.reused: list[str] = []

    def get(self, key: str, name: str, *args, **kwargs) -> dict:
        """Figure ``key``: the known one, else ``rafi.plots.<name>(*args, **kwargs)`` in
        this report's format (matplotlib is imported only when a figure is drawn here)."""
        if key in self.known:
            self.reused.append(key)
            return self.known[key]
        from rafi.report import plots

        fig = self.drawn[key] = getattr(plots, name)(*args, fmt=self.fmt, **kwargs)
        return fig


def _sensors(res: dict, coolant_sensors) -> tuple[dict, list, list]:
    """``(key_sensors.json, key sensors, coolant sensors drawn beside them)``."""
    model = res.get("model") or {}
    key_info = res.get("key_sensors_json") or {}
    key = list(key_info.get("sensors") or model.get("key_sensors") or [])
    coolant = [c for c in (coolant_sensors or DEFAULT_COOLANT_SENSORS) if c not in key]
    return key_info, key, coolant


def figure_params(
    group: str, *, figure_format: str = "png", coolant_sensors=None, gates: dict | None = None
) -> dict:
    """The parameters the figures of ``group`` depend on (stored with them, checked on reuse)."""
    if group == "pipeline":
        return {
            "figure_format": figure_format,
            "coolant_sensors": list(coolant_sensors or DEFAULT_COOLANT_SENSORS),
        }
    return {"figure_format": figure_format, "gates": dict(gates or {})}


def build_figures(
    paths: dict,
    group: str,
    *,
    figure_format: str = "png",
    coolant_sensors: list[str] | None = None,
    gates: dict | None = None,
) -> dict:
    """Draw the figures of one group of :data:`FIGURE_GROUPS` ahead of the report.

    Runs the section code of :func:`build_context` on the group's inputs (every other input
    absent), so each figure is the one the report would draw from the same files.

    Parameters
    ----------
    paths : dict
        Input name -> path; the names of ``FIGURE_GROUPS[group]`` are read.
    group : {"pipeline", "comparison"}
    figure_format, coolant_sensors
        As for :func:`build_context`.
    gates : dict
        ``qualification:`` of the machine (the report's gates; ``comparison`` only).

    Returns
    -------
    dict
        ``{"schema", "group", "params", "figures": {key: figure}}``, JSON-serialisable
        (:func:`load_figures` reads it back).
    """
    if group not in FIGURE_GROUPS:
        raise ValueError(f"unknown figure group {group!r}; expected one of {', '.join(FIGURE_GROUPS)}")
    missing = [k for k in FIGURE_GROUPS[group] if k not in paths]
    if missing:  # an absent input would change the figures silently
        raise ValueError(f"figure group {group!r}: no path for {', '.join(missing)}")
    res = dict.fromkeys({**RESULT_FILES, **OPTIONAL_FILES})
    res.update(load_results({k: paths.get(k) for k in FIGURE_GROUPS[group]}))
    figs = Figures(figure_format)
    if group == "pipeline":
        key_info, key, coolant = _sensors(res, coolant_sensors)
        _section_equilibrium(res, key, coolant, figs)
        _section_ranking(res, key_info, figs)
        _section_models(res, figs)
        _section_fuzzy(res, figs)
        _section_validation(res, key, coolant, figs)
    else:
        # no decision yet: the model beside RAFI is the family's champion, as in the report
        # unless the model on the machine is another one (then the report draws that figure)
        _section_comparison(res, dict(gates or {}), None, {}, figs)
    return {
        "schema": FIGURES_SCHEMA,
        "group": group,
        "params": figure_params(
            group, figure_format=figure_format, coolant_sensors=coolant_sensors, gates=gates
        ),
        "figures": figs.drawn,
    }


def load_figures(
    paths, *, figure_format: str = "png", coolant_sensors: list[str] | None = None, gates: dict | None = None
) -> tuple[dict, list[str]]:
    """Figures drawn ahead (files of :func:`build_figures`) that this report can reuse.

    A file whose schema or parameters differ from this report's is skipped (its figures
    are drawn again). Returns ``(figures by key, notes on skipped files)``.
    """
    known, notes = {}, []
    for path in paths:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
        group = doc.get("group")
        want = (
            figure_params(group, figure_format=figure_format, coolant_sensors=coolant_sensors, gates=gates)
            if group in FIGURE_GROUPS
            else None
        )
        if (
            doc.get("schema") != FIGURES_SCHEMA
            or want is None
            or json.dumps(doc.get("params"), sort_keys=True) != json.dumps(want, sort_keys=True)
        ):
            notes.append(f"{path}: schema/group/parameters differ from this report's; not used")
            continue
        known.update(doc.get("figures") or {})
    return known, notes


# =========================================================================== the context


def build_context(
    paths: dict,
    *,
    machine: str,
    settings: dict | None = None,
    config: dict | None = None,
    figure_format: str = "png",
    coolant_sensors: list[str] | None = None,
    now=None,
    figures: dict | None = None,
) -> dict:
    """Load the results and build the template context.

    Parameters
    ----------
    paths : dict
        Input name -> path (see :func:`result_paths`); missing/absent files are allowed
        for the optional inputs.
    machine : str
    settings : dict
        The machine's effective settings (``defaults`` merged with ``machines.<machine>``);
        ``qualification`` and the choice parameters are read from here.
    config : dict, optional
        The configuration shown verbatim (YAML) in the provenance section.
    figure_format : {"png", "svg"}
    coolant_sensors : list of str
        Drawn beside the key sensors (default ``["T13"]``, the coolant inlet).
    figures : dict, optional
        Figures drawn ahead, by key (:func:`load_figures`); the others are drawn here.
        ``ctx["figures_reused"]`` and ``ctx["figures_drawn"]`` list the keys.
    """
    t0 = time.perf_counter()
    settings = dict(settings or {})
    res = load_results(paths)
    model = res["model"] or {}
    key_info, key, coolant = _sensors(res, coolant_sensors)
    gates = settings.get("qualification") or {}
    figs = Figures(figure_format, figures)

    ctx: dict = {"machine": machine, "generated": _now(now), "sections": []}
    dec_path = paths.get("decision")
    registry_dir = Path(dec_path).parent if dec_path else None
    infos = _model_infos(res, registry_dir)
    ctx["verdict"] = _verdict_all(res, gates, infos)
    ctx["gates"] = gates
    ctx["data"] = _section_data(res, machine)
    ctx["equilibrium"] = _section_equilibrium(res, key, coolant, figs)
    ctx["ranking"] = _section_ranking(res, key_info, figs)
    ctx["models"] = _section_models(res, figs)
    ctx["fuzzy"] = _section_fuzzy(res, figs)
    ctx["validation"] = _section_validation(res, key, coolant, figs)
    ctx["registry"] = _section_registry(res, gates, infos)
    dec = res.get("decision") if isinstance(res.get("decision"), dict) else {}
    ctx["comparison"] = _section_comparison(res, gates, dec.get("champion_id_after"), settings, figs)
    ctx["figures_reused"], ctx["figures_drawn"] = list(figs.reused), list(figs.drawn)
    ctx["verdict"]["quarantined"] = len(ctx["data"]["quarantined"])
    ctx["verdict"]["recalibration_due"] = bool(ctx["registry"] and ctx["registry"]["drift"]["recal"])
    ctx["choices"] = _section_choices(settings, key_info, model, ctx["equilibrium"]["method"])
    ctx["versions"] = _versions()
    ctx["config_yaml"] = yaml.safe_dump(
        config if config is not None else settings, sort_keys=False, allow_unicode=True
    )
    ctx["model_id"] = model.get("model_id", "")
    ctx["champion_id"] = dec.get("champion_id_after") or ""
    ctx["code_version"] = model.get("code_version", "")
    ctx["inputs"] = [{"name": k, "path": str(p), "present": Path(p).is_file()} for k, p in paths.items() if p]

    present = {
        "verdict": True,
        "data": True,
        "equilibrium": True,
        "ranking": True,
        "models": True,
        "fuzzy": ctx["fuzzy"] is not None,
        "validation": True,
        "registry": ctx["registry"] is not None,
        "comparison": ctx["comparison"] is not None,
        "choices": True,
        "provenance": True,
    }
    n = 0
    for sid, title in SECTION_TITLES.items():
        if present[sid]:
            n += 1
            ctx["sections"].append({"id": sid, "number": n, "title": title})
    ctx["section_by_id"] = {s["id"]: s for s in ctx["sections"]}
    ctx["build_seconds"] = time.perf_counter() - t0
    return ctx


# =========================================================================== rendering


def _environment():
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("rafi.report", "templates"),
        autoescape=jinja2.select_autoescape(["html", "j2"], default_for_string=True),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )
    return env


def render_html(ctx: dict) -> str:
    """Render the qualification report HTML (self-contained)."""
    return _environment().get_template("qualification.html.j2").render(**ctx)


def render_pdf(html: str, base_url: str | None = None) -> bytes:
    """Render the same HTML to PDF with WeasyPrint (A4, print CSS in the template)."""
    import gc

    import weasyprint

    # WeasyPrint allocates millions of small objects; the cyclic garbage collector's passes
    # over them were about 15 % of the rendering time. Paused for this one document only.
    enabled = gc.isenabled()
    gc.disable()
    try:
        return weasyprint.HTML(string=html, base_url=base_url or ".").write_pdf()
    finally:
        if enabled:
            gc.enable()


def generate(
    results_dir: str | os.PathLike,
    out_dir: str | os.PathLike,
    *,
    machine: str | None = None,
    settings: dict | None = None,
    config: dict | None = None,
    figure_format: str = "png",
    coolant_sensors: list[str] | None = None,
    paths: dict | None = None,
) -> dict:
    """Build, render and write ``qualification.html`` and ``.pdf`` atomically; return timings."""
    from rafi.artefact import write_bytes_atomic, write_text_atomic

    results_dir = Path(results_dir)
    out_dir = Path(out_dir)
    machine = machine or results_dir.name
    t = {}
    t0 = time.perf_counter()
    ctx = build_context(
        paths or result_paths(results_dir),
        machine=machine,
        settings=settings,
        config=config,
        figure_format=figure_format,
        coolant_sensors=coolant_sensors,
    )
    t["context_s"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    html = render_html(ctx)
    t["html_s"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    pdf = render_pdf(html)
    t["pdf_s"] = time.perf_counter() - t2
    write_text_atomic(out_dir / "qualification.html", html)
    write_bytes_atomic(out_dir / "qualification.pdf", pdf)
    t["total_s"] = time.perf_counter() - t0
    t["verdict"] = ctx["verdict"]["status"]
    t["html_bytes"], t["pdf_bytes"] = len(html.encode()), len(pdf)
    return t
