"""Section 1 of the report: the verdict on the model on the machine and on RAFI as published.

The verdict is read where a rule stored it: ``registry/decision.json`` holds rule decide's
verdict on tonight's candidate (``verdict``: criterion x validation run, the rows of
:func:`rafi.method.validate.qualify`), which is the verdict on the model on the machine when
the candidate was promoted and the verdict on RAFI as published when the candidate is
``model.json``. No result file stores the per-criterion verdict of any other model (the
champion kept in service, RAFI as published beside a family model, a model without a
decision): only for those :func:`recomputed_verdict` applies the pipeline's own gate rules to
the model's stored per-run results (``registry/comparison.csv``, ``comparison/per_run.csv``,
``validation/summary.csv``), and the report says so.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from rafi.report.format import fmt_num, short_id, truthy
from rafi.report.inputs import noise_floors

#: The columns of a verdict (:data:`rafi.method.validate.VERDICT_COLUMNS`).
VERDICT_COLUMNS = ["criterion", "limit", "measured", "passed", "run_id"]


def recomputed_verdict(summary: pd.DataFrame, gates: dict) -> pd.DataFrame:
    """Verdict rows (criterion x validation run) of ``rafi.method.validate.qualify`` on a model's
    stored per-run results, for a model whose verdict no result file stores (module docstring);
    a ``run_id`` column is always present."""
    from rafi.method.validate import qualify

    verdict = qualify(summary, gates)
    return verdict if "run_id" in verdict else verdict.assign(run_id="")


def scored_runs(comp: pd.DataFrame | None, who: str) -> list | None:
    """The runs of ``registry/comparison.csv`` on which ``who`` (``candidate``, ``champion``) has
    a finite max |residual| (the runs the report's registry tables score it on); ``None``
    without the table."""
    col = f"{who}_max_abs_after_um"
    if comp is None or "run_id" not in comp:
        return None
    if col not in comp:
        return []
    after = pd.to_numeric(comp[col], errors="coerce")
    return comp.loc[after.notna(), "run_id"].astype(str).tolist()


def stored_verdict(dec: dict, run_ids: list | None = None) -> pd.DataFrame | None:
    """Rule decide's verdict on the candidate, as stored in ``registry/decision.json``.

    Parameters
    ----------
    dec : dict
        ``registry/decision.json``.
    run_ids : list, optional
        Keep the rows of these runs only (:func:`scored_runs`).

    Returns
    -------
    DataFrame or None
        :data:`VERDICT_COLUMNS`; ``None`` for a decision without a stored verdict.
    """
    rows = dec.get("verdict")
    if not isinstance(rows, list):
        return None
    verdict = pd.DataFrame(rows, columns=VERDICT_COLUMNS)
    if run_ids is not None:
        verdict = verdict[verdict["run_id"].astype(str).isin([str(r) for r in run_ids])]
    return verdict.reset_index(drop=True)


CRITERION_TEXT = {
    "max_residual_um": ("Largest residual after compensation", "\u2264", "\u00b5m", 2),
    "min_improvement_pct": ("Smallest improvement over no compensation", "\u2265", "%", 1),
    "never_worse_than_uncompensated": ("Runs worse than no compensation", "=", "", 0),
}


def aggregate_verdict(verdict: pd.DataFrame, noise: dict | None = None) -> list[dict]:
    """One row per criterion: the worst case over every validation run (idle cool-downs
    included: :func:`rafi.method.validate.qualify` holds them to every gate).

    ``max_residual_um``: the largest residual, with ``noise`` = the noise floor of that run
    (``noise``: run id -> expected max |noise|, :func:`rafi.report.inputs.noise_floors`);
    ``min_improvement_pct``: the smallest improvement; ``never_worse_than_uncompensated``:
    how many runs are worse (limit 0), naming them, or else the run closest to the limit.
    A NaN measurement fails.
    """
    noise = noise or {}
    out = []
    if verdict is None or not len(verdict):
        return out
    v = verdict.copy()
    v["measured"] = pd.to_numeric(v["measured"], errors="coerce")
    v["limit"] = pd.to_numeric(v["limit"], errors="coerce")
    v["passed"] = v["passed"].map(truthy) & v["measured"].notna()
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
                    "noise": "",
                    "n_runs": int(g["run_id"].nunique()),
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
        floor = noise.get(str(g.loc[i, "run_id"])) if crit == "max_residual_um" else None
        out.append(
            {
                "criterion": crit,
                "label": label,
                "limit": f"{op} {fmt_num(lim, nd, unit)}",
                "measured": fmt_num(g.loc[i, "measured"], nd, unit),
                "run_id": f"run {g.loc[i, 'run_id']}",
                "passed": passed,
                "noise": fmt_num(floor, 2, unit) if floor is not None else "",
                "n_runs": int(g["run_id"].nunique()),
            }
        )
    for r in out:
        r["status"] = "PASS" if r["passed"] else "FAIL"
    return out


def verdict_context(verdict: pd.DataFrame, source: str, noise: dict | None = None) -> dict:
    """The verdict box: :func:`aggregate_verdict` rows, PASS only if every criterion passed."""
    rows = aggregate_verdict(verdict, noise)
    passed = bool(rows) and all(r["passed"] for r in rows)
    return {
        "passed": passed,
        "status": "PASS" if passed else "FAIL",
        "rows": rows,
        "source": source,
        "n_checks": 0 if verdict is None else len(verdict),
        "n_failed": 0 if verdict is None else int((~verdict["passed"].map(truthy)).sum()),
    }


def model_infos(res: dict, registry_dir: Path | None) -> dict:
    """``model_id -> {kind, created, files, name}`` from every source that names models."""
    infos: dict = {}

    def add(mid, **kw):
        """Fill the fields of ``mid`` not known yet."""
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


def registry_summary(comp: pd.DataFrame | None, who: str) -> pd.DataFrame | None:
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


def per_run_gates(verdict: pd.DataFrame | None, run_ids=()) -> dict:
    """``run_id -> (passed, [failed criteria])`` from verdict rows (stored or recomputed); a run
    of ``run_ids`` without a row (no gate set) passes. A NaN measurement fails."""
    out = {}
    if verdict is not None and len(verdict):
        for rid, g in verdict.groupby(verdict["run_id"].astype(str), sort=False):
            ok = g["passed"].map(truthy) & pd.to_numeric(g["measured"], errors="coerce").notna()
            out[rid] = (bool(ok.all()), g.loc[~ok, "criterion"].astype(str).tolist())
    for rid in run_ids:
        out.setdefault(str(rid), (True, []))
    return out


def registry_gates(dec: dict, comp: pd.DataFrame | None, gates: dict) -> dict:
    """The gates per validation run of the candidate and of the champion before this run, as the
    registry section shows them.

    Parameters
    ----------
    dec : dict
        ``registry/decision.json``: the candidate's verdict is its ``verdict``.
    comp : DataFrame or None
        ``registry/comparison.csv``: the runs each model is scored on; the champion's results
        (no file stores the champion's verdict: recomputed, :func:`recomputed_verdict`).
    gates : dict
        The machine's ``qualification`` settings (for the champion's recomputed verdict).

    Returns
    -------
    dict
        ``candidate`` and ``champion``: ``run_id -> (passed, [failed criteria])``, empty for a
        model without results.
    """
    out = {}
    for who in ("candidate", "champion"):
        summary = registry_summary(comp, who)
        stored = stored_verdict(dec, scored_runs(comp, who)) if who == "candidate" else None
        if stored is not None and summary is not None:
            out[who] = per_run_gates(stored, summary["run_id"])
        elif summary is not None:
            out[who] = per_run_gates(recomputed_verdict(summary, gates), summary["run_id"])
        else:
            out[who] = {}
    return out


def champion_after_summary(res: dict, dec: dict):
    """Validation summary of the model on the machine after this run, and where it came from."""
    after = dec.get("champion_id_after")
    comp = res.get("registry_comparison")
    if not after:
        return None, ""
    if after == dec.get("candidate_id"):
        s = registry_summary(comp, "candidate")
        if s is not None:
            return s, "registry/comparison.csv (candidate columns)"
    if after == dec.get("champion_id_before"):
        s = registry_summary(comp, "champion")
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


def judged_verdict(res: dict, dec: dict, gates: dict) -> tuple[pd.DataFrame | None, str]:
    """The verdict on the model on the machine after this run, and where it comes from.

    The stored verdict of ``registry/decision.json`` when the model is tonight's candidate
    (on the runs ``registry/comparison.csv`` scores it on); else :func:`recomputed_verdict` on
    the model's results (:func:`champion_after_summary`). ``(None, "")`` without results.
    """
    if dec.get("champion_id_after") and dec.get("champion_id_after") == dec.get("candidate_id"):
        comp = res.get("registry_comparison")
        stored = stored_verdict(dec, scored_runs(comp, "candidate"))
        if stored is not None and len(stored):
            return stored, "read from registry/decision.json (rule decide's verdict)"
    summ, src = champion_after_summary(res, dec)
    if summ is not None and len(summ):
        return recomputed_verdict(summ, gates), "computed from " + src
    return None, ""


def rafi_verdict(res: dict, gates: dict) -> tuple[pd.DataFrame, str]:
    """The verdict on RAFI as published (``model.json``, ``validation/summary.csv`` present):
    rule decide's stored verdict when ``model.json`` was tonight's candidate, else
    :func:`recomputed_verdict` on ``validation/summary.csv``."""
    dec = res.get("decision")
    model_id = (res.get("model") or {}).get("model_id")
    if isinstance(dec, dict) and model_id and dec.get("candidate_id") == model_id:
        stored = stored_verdict(dec)
        if stored is not None and len(stored):
            return stored, "read from registry/decision.json (rule decide's verdict)"
    return recomputed_verdict(res["validation_summary"], gates), "from rafi.method.validate.qualify"


def residual_statement(res: dict, settings: dict) -> dict | None:
    """What a residual of this report can and cannot show, with this machine's numbers.

    Parameters
    ----------
    res : dict
        Loaded inputs: the noise floors (:func:`rafi.report.inputs.noise_floors`), ``runs_csv``
        (the speeds of the training runs) and ``validation_summary`` (RAFI's samples outside
        its trained temperature range).
    settings : dict
        The machine's settings (``report.instruments.probe``).

    Returns
    -------
    dict or None
        ``noise_lo``, ``noise_hi`` (the range of the validation runs' noise floors, um),
        ``n_runs``, ``speeds`` (the training runs' speed range; ``""`` without runs.csv),
        ``outside`` / ``n_samples`` (validation samples outside RAFI's trained temperature
        range; ``None`` without the summary) and ``probe``; ``None`` without a noise floor.
    """
    noise = noise_floors(res)
    if not noise:
        return None
    vals = np.asarray(list(noise.values()), float)
    out = {
        "noise_lo": fmt_num(vals.min(), 2),
        "noise_hi": fmt_num(vals.max(), 2, "\u00b5m"),
        "n_runs": len(vals),
        "speeds": "",
        "outside": None,
        "n_samples": None,
        "probe": (settings["report"].get("instruments") or {}).get("probe") or "",
    }
    runs = res.get("runs_csv")
    if runs is not None and "role" in runs:
        tr = runs[runs["role"].astype(str) == "training"]
        # a constant-speed run at its nominal speed, a varying one over its whole range
        nominal = pd.to_numeric(tr["speed_rpm"], errors="coerce")
        varying = tr["kind"].astype(str).eq("varying") if "kind" in tr else nominal.isna()
        lo = nominal.where(~varying, pd.to_numeric(tr.get("speed_min_rpm", nominal), errors="coerce")).min()
        hi = nominal.where(~varying, pd.to_numeric(tr.get("speed_max_rpm", nominal), errors="coerce")).max()
        if pd.notna(lo) and pd.notna(hi):
            out["speeds"] = f"{fmt_num(lo, 0)}\u2013{fmt_num(hi, 0, 'r/min')}"
    summ = res.get("validation_summary")
    if summ is not None and {"n_outside_temp_range", "n_samples"} <= set(summ.columns):
        out["outside"] = int(pd.to_numeric(summ["n_outside_temp_range"], errors="coerce").fillna(0).sum())
        out["n_samples"] = int(pd.to_numeric(summ["n_samples"], errors="coerce").fillna(0).sum())
    return out


def verdict_all(res: dict, gates: dict, infos: dict) -> dict:
    """The verdict of section 1: the model on the machine (with decision.json) + RAFI, over
    every validation run (idle cool-downs included), each max residual beside its run's noise
    floor (:func:`judged_verdict`, :func:`rafi_verdict`: the stored verdict where one is)."""
    rafi_v = None
    noise = noise_floors(res)
    if res["validation_summary"] is not None:
        rafi_v = verdict_context(*rafi_verdict(res, gates), noise)
        gated = res["validation_summary"]
        after = pd.to_numeric(gated["max_abs_after_um"], errors="coerce")
        rafi_v["worst"] = fmt_num(after.max(), 2, "\u00b5m")
        worst_run = str(gated.loc[after.idxmax(), "run_id"]) if after.notna().any() else ""
        rafi_v["worst_noise"] = fmt_num(noise[worst_run], 2, "\u00b5m") if worst_run in noise else ""
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
            "worst_noise": "",
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
        "id": short_id(after),
        "kind": info.get("kind") or "kind unknown",
        "decision": decision,
        "none": not after,
        "is_rafi": info.get("kind") == "rafi",
    }
    verdict, src = judged_verdict(res, dec, gates)
    if verdict is not None:
        out = verdict_context(verdict, src, noise)
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
