"""Section 1 of the report: the verdict on the model on the machine and on RAFI as published.

Every verdict is read where a rule stored it; the report judges no gate itself:

- ``registry/decision.json`` ``verdict``: rule decide's verdict on tonight's candidate
  (criterion x validation run, the rows of :func:`rafi.method.validate.qualify`);
- ``registry/decision.json`` ``champion_verdict``: rule decide's verdict on the champion in
  service before this run, on tonight's runs (absent without a champion);
- ``comparison/verdict.csv``: rule compare's verdict on every model of the family (RAFI as
  published included), named by model and model id.

A model's verdict is looked up by its model id (:func:`stored_verdict_of`), RAFI's by the id of
``model.json`` (by the name ``rafi`` when it has none). Where no file stores it (results written
before the file or key existed), the report says so (:data:`NOT_STORED`) instead of a verdict.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from rafi.family.confirmation import awaiting_confirmation
from rafi.report.comparison_section import family_champion
from rafi.report.format import fmt_num, isnum, short_id, truthy
from rafi.report.inputs import noise_floors
from rafi.report.intervals import interval_block, pooled_coverage, worst_run_interval
from rafi.report.probe import probe_words
from rafi.report.trained_range import adapted_speeds, model_speed_counts, range_facts

#: The columns of a verdict (:data:`rafi.method.validate.VERDICT_COLUMNS`).
VERDICT_COLUMNS = ["criterion", "limit", "measured", "passed", "run_id"]

#: Where a verdict was read from, as the report's verdict note says it.
SOURCE_CANDIDATE = "read from registry/decision.json (rule decide's verdict)"
SOURCE_CHAMPION = "read from registry/decision.json (champion_verdict: rule decide's verdict on the champion)"
SOURCE_COMPARISON = "read from comparison/verdict.csv (rule compare's verdict)"
#: What the report says where no result file stores a verdict.
NOT_STORED = "not stored in this results folder; re-run the pipeline"


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


def stored_verdict(dec: dict, run_ids: list | None = None, key: str = "verdict") -> pd.DataFrame | None:
    """Rule decide's verdict on the candidate (or, with ``key="champion_verdict"``, on the
    champion), as stored in ``registry/decision.json``.

    Parameters
    ----------
    dec : dict
        ``registry/decision.json``.
    run_ids : list, optional
        Keep the rows of these runs only (:func:`scored_runs`).
    key : str
        ``verdict`` (the candidate) or ``champion_verdict`` (the champion before this run).

    Returns
    -------
    DataFrame or None
        :data:`VERDICT_COLUMNS`; ``None`` for a decision without that stored verdict.
    """
    rows = dec.get(key)
    if not isinstance(rows, list):
        return None
    verdict = pd.DataFrame(rows, columns=VERDICT_COLUMNS)
    return _of_runs(verdict, run_ids)


def _of_runs(verdict: pd.DataFrame, run_ids: list | None) -> pd.DataFrame:
    """The rows of ``verdict`` on ``run_ids`` (every row when ``None``), renumbered."""
    if run_ids is not None:
        verdict = verdict[verdict["run_id"].astype(str).isin([str(r) for r in run_ids])]
    return verdict.reset_index(drop=True)


def comparison_verdict(res: dict, model_id: str | None, name: str | None = None) -> pd.DataFrame | None:
    """Rule compare's verdict on one model of the family, as stored in ``comparison/verdict.csv``.

    Parameters
    ----------
    res : dict
        Loaded inputs: ``comparison_verdict`` (``comparison/verdict.csv``) and ``comparison``
        (``comparison/summary.csv``: the models compared).
    model_id : str or None
        The model's id: its rows are those with this ``model_id``.
    name : str, optional
        Without ``model_id``: the rows of the model of this name (``rafi``).

    Returns
    -------
    DataFrame or None
        :data:`VERDICT_COLUMNS` in the file's order; empty for a model compared without a gate
        set; ``None`` without the file or for a model the comparison does not hold.
    """
    table = res.get("comparison_verdict")
    if table is None or not (model_id or name):
        return None
    column, value = ("model_id", model_id) if model_id else ("model", name)
    if column not in table:
        return None
    rows = table[table[column].astype(str) == str(value)]
    summary = res.get("comparison")
    compared = summary is not None and column in summary and (summary[column].astype(str) == str(value)).any()
    if not len(rows) and not compared:
        return None
    return rows[VERDICT_COLUMNS].reset_index(drop=True)


def stored_verdict_of(
    res: dict, model_id: str | None, run_ids: list | None = None, name: str | None = None
) -> tuple[pd.DataFrame | None, str]:
    """The stored verdict on a model, and where it was read from.

    Parameters
    ----------
    res : dict
        Loaded inputs: ``decision`` (``registry/decision.json``), ``comparison_verdict`` and
        ``comparison``.
    model_id : str or None
        The model: rule decide's ``verdict`` when it is tonight's candidate, ``champion_verdict``
        when it is the champion before this run, else its rows of ``comparison/verdict.csv``.
    run_ids : list, optional
        Keep the rows of these runs only (:func:`scored_runs`).
    name : str, optional
        The model's name in ``comparison/verdict.csv`` when the report does not know its id.

    Returns
    -------
    (DataFrame or None, str)
        :data:`VERDICT_COLUMNS` and :data:`SOURCE_CANDIDATE`, :data:`SOURCE_CHAMPION` or
        :data:`SOURCE_COMPARISON`; ``(None, NOT_STORED)`` where no file stores it.
    """
    dec = res.get("decision") if isinstance(res.get("decision"), dict) else {}
    if model_id and model_id == dec.get("candidate_id"):
        verdict = stored_verdict(dec, run_ids)
        if verdict is not None:
            return verdict, SOURCE_CANDIDATE
    if model_id and model_id == dec.get("champion_id_before"):
        verdict = stored_verdict(dec, run_ids, "champion_verdict")
        if verdict is not None:
            return verdict, SOURCE_CHAMPION
    verdict = comparison_verdict(res, model_id, name)
    if verdict is not None:
        return _of_runs(verdict, run_ids), SOURCE_COMPARISON
    return None, NOT_STORED


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
    """The verdict box: :func:`aggregate_verdict` rows, PASS only if every criterion passed;
    ``css`` is the box's class, ``stored`` true (a stored verdict)."""
    rows = aggregate_verdict(verdict, noise)
    passed = bool(rows) and all(r["passed"] for r in rows)
    return {
        "passed": passed,
        "status": "PASS" if passed else "FAIL",
        "css": "pass" if passed else "fail",
        "stored": True,
        "rows": rows,
        "source": source,
        "of_candidate": False,
        "n_checks": 0 if verdict is None else len(verdict),
        "n_failed": 0 if verdict is None else int((~verdict["passed"].map(truthy)).sum()),
    }


def empty_verdict(source: str, stored: bool = True) -> dict:
    """The verdict box without a verdict: FAIL with ``source`` saying why (no model, no
    results), or, with ``stored=False``, NOT STORED (no result file stores the verdict:
    :data:`NOT_STORED`; the report computes none)."""
    return {
        "passed": False,
        "status": "FAIL" if stored else "NOT STORED",
        "css": "fail" if stored else "unknown",
        "stored": stored,
        "rows": [],
        "source": source,
        "of_candidate": False,
        "n_checks": 0,
        "n_failed": 0,
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


def per_run_gates(verdict: pd.DataFrame | None, run_ids=()) -> dict:
    """``run_id -> (passed, [failed criteria])`` from stored verdict rows; a run of ``run_ids``
    without a row (no gate set) passes. A NaN measurement fails."""
    out = {}
    if verdict is not None and len(verdict):
        for rid, g in verdict.groupby(verdict["run_id"].astype(str), sort=False):
            ok = g["passed"].map(truthy) & pd.to_numeric(g["measured"], errors="coerce").notna()
            out[rid] = (bool(ok.all()), g.loc[~ok, "criterion"].astype(str).tolist())
    for rid in run_ids:
        out.setdefault(str(rid), (True, []))
    return out


def registry_gates(res: dict) -> dict:
    """The gates per validation run of the candidate and of the champion before this run, as the
    registry section shows them: each model's stored verdict (:func:`stored_verdict_of`:
    ``verdict``, ``champion_verdict`` of ``registry/decision.json``) on the runs
    ``registry/comparison.csv`` scores it on.

    Parameters
    ----------
    res : dict
        Loaded inputs: ``decision``, ``registry_comparison`` and the comparison's verdict.

    Returns
    -------
    dict
        ``candidate`` and ``champion``: ``run_id -> (passed, [failed criteria])``, empty for a
        model without results, ``None`` for a model whose verdict no file stores.
    """
    dec = res.get("decision") if isinstance(res.get("decision"), dict) else {}
    comp = res.get("registry_comparison")
    ids = {"candidate": dec.get("candidate_id"), "champion": dec.get("champion_id_before")}
    out = {}
    for who, model_id in ids.items():
        runs = scored_runs(comp, who)
        if not runs:
            out[who] = {}
            continue
        verdict, _ = stored_verdict_of(res, model_id, runs)
        out[who] = None if verdict is None else per_run_gates(verdict, runs)
    return out


def judged_verdict(res: dict, dec: dict) -> tuple[pd.DataFrame | None, str]:
    """The stored verdict on the model on the machine after this run, and where it was read from.

    The model is ``champion_id_after`` of ``dec``; its verdict is read (:func:`stored_verdict_of`)
    on the runs ``registry/comparison.csv`` scores it on when it is tonight's candidate or the
    champion before this run. ``(None, NOT_STORED)`` where no file stores it.
    """
    after = dec.get("champion_id_after")
    comp = res.get("registry_comparison")
    runs = None
    if after and after == dec.get("candidate_id"):
        runs = scored_runs(comp, "candidate")
    elif after and after == dec.get("champion_id_before"):
        runs = scored_runs(comp, "champion")
    return stored_verdict_of({**res, "decision": dec}, after, runs)


def rafi_verdict(res: dict) -> tuple[pd.DataFrame | None, str]:
    """The stored verdict on RAFI as published (``model.json``), and where it was read from: rule
    decide's when ``model.json`` was tonight's candidate, else rule compare's
    (``comparison/verdict.csv``, by the id of ``model.json``, else by the name ``rafi``);
    ``(None, NOT_STORED)`` where no file stores it."""
    model_id = (res.get("model") or {}).get("model_id")
    return stored_verdict_of(res, model_id, name=None if model_id else "rafi")


def offered_range_facts(res: dict, tolerance_rpm=None) -> dict | None:
    """The samples outside the trained ranges of the model offered to the machine, and its trained
    speeds (:func:`rafi.report.trained_range.range_facts`).

    The offered model is the comparison's champion (``comparison/summary.csv``), its rows those of
    ``comparison/per_run.csv`` and its artefact ``comparison/best_model.json`` (when it carries the
    champion's id; else its trained speeds are unknown). Without a comparison, RAFI as published:
    ``validation/summary.csv`` and ``model.json``. With ``tolerance_rpm`` (the machine's
    ``speed_tolerance_rpm``) a sample is outside the trained speeds only beyond it, recounted from
    the residual samples (:func:`rafi.report.trained_range.model_speed_counts`).

    Returns
    -------
    dict or None
        :func:`~rafi.report.trained_range.range_facts` with ``model`` (its name, ``RAFI as
        published`` for ``model.json``) and ``offered`` (it is the comparison's offered model);
        ``None`` without counts.
    """
    summ, per_run = res.get("comparison"), res.get("comparison_per_run")
    champ = family_champion(summ) if summ is not None and len(summ) else None
    counts = model_speed_counts(res, tolerance_rpm) if tolerance_rpm is not None else {}
    if champ is not None and per_run is not None and "model" in per_run:
        row = summ[summ["model"].astype(str) == champ].iloc[0]
        best = res.get("best_model")
        same = isinstance(best, dict) and str(best.get("model_id", "")) == str(row.get("model_id", ""))
        rows = per_run[per_run["model"].astype(str) == champ]
        facts = range_facts(rows, best if same else None, counts.get(champ))
        if facts is not None:
            return {
                **facts,
                "model": champ,
                "offered": True,
                "adapted": adapted_speeds(best if same else None),
            }
    facts = range_facts(res.get("validation_summary"), res.get("model"), counts.get("rafi"))
    return None if facts is None else {**facts, "model": "RAFI as published", "offered": False}


def residual_statement(res: dict, settings: dict) -> dict | None:
    """What a residual of this report can and cannot show, with this machine's numbers.

    Parameters
    ----------
    res : dict
        Loaded inputs: the noise floors (:func:`rafi.report.inputs.noise_floors`) and the offered
        model's samples outside its trained ranges (:func:`offered_range_facts`: the comparison's
        ``summary.csv``, ``per_run.csv`` and ``best_model.json``; without them
        ``validation/summary.csv`` and ``model.json``).
    settings : dict
        The machine's settings (``report.instruments.probe``; ``speed_tolerance_rpm``: a sample
        is outside the trained speeds only beyond it).

    Returns
    -------
    dict or None
        ``noise_lo``, ``noise_hi`` (the range of the validation runs' noise floors, um),
        ``n_runs``, ``probe`` and ``measured``; and the offered model's
        (:func:`offered_range_facts`, the same computation as the validation section's and the
        comparison's for RAFI as published): ``model``, ``offered``, ``speeds`` (its trained
        speeds, ``""`` unknown), ``adapted`` (a model adapted from a prior:
        :func:`rafi.report.trained_range.adapted_speeds`, the speeds its training runs here tested
        and those the prior alone covers, said instead of the range; else None), ``n_samples``,
        ``n_temp`` / ``temp_pct`` (validation samples
        outside its trained temperature range) and ``n_speed`` (more than
        ``speed_tolerance_rpm`` outside its trained speeds; ``None`` unknown), each ``None``
        without counts; ``None`` without a noise floor.
    """
    noise = noise_floors(res)
    if not noise:
        return None
    vals = np.asarray(list(noise.values()), float)
    tolerance = settings.get("speed_tolerance_rpm")
    facts = offered_range_facts(res, tolerance) or {}
    return {
        "noise_lo": fmt_num(vals.min(), 2),
        "noise_hi": fmt_num(vals.max(), 2, "\u00b5m"),
        "n_runs": len(vals),
        "probe": (settings["report"].get("instruments") or {}).get("probe") or "",
        "measured": probe_words(settings),
        "model": facts.get("model"),
        "offered": bool(facts.get("offered")),
        "speeds": facts.get("speeds") or "",
        # a model adapted from a prior: its speeds tested here and those of the prior alone
        "adapted": facts.get("adapted"),
        "n_samples": facts.get("n_samples"),
        "n_temp": facts.get("n_temp"),
        "temp_pct": facts.get("temp_pct"),
        "n_speed": facts.get("n_speed"),
        "speed_tolerance_rpm": tolerance if isnum(tolerance) else None,
    }


def rafi_context(res: dict, noise: dict) -> dict:
    """The RAFI line of the verdict: its stored verdict (:func:`rafi_verdict`; NOT STORED where
    no file stores it) with the worst residual, its run's noise floor and the smallest
    improvement of ``validation/summary.csv``, and the interval at that run (its pooled coverage
    from RAFI's row of ``comparison/summary.csv``)."""
    gated = res.get("validation_summary")
    if gated is None:
        return {
            **empty_verdict("no validation summary"),
            "worst": "\u2013",
            "worst_noise": "",
            "min_imp": "\u2013",
        }
    verdict, source = rafi_verdict(res)
    rafi_v = verdict_context(verdict, source, noise) if verdict is not None else empty_verdict(source, False)
    after = pd.to_numeric(gated["max_abs_after_um"], errors="coerce")
    rafi_v["worst"] = fmt_num(after.max(), 2, "\u00b5m")
    worst_run = str(gated.loc[after.idxmax(), "run_id"]) if after.notna().any() else ""
    rafi_v["worst_noise"] = fmt_num(noise[worst_run], 2, "\u00b5m") if worst_run in noise else ""
    rafi_v["min_imp"] = fmt_num(pd.to_numeric(gated["improvement_pct"], errors="coerce").min(), 1, "%")
    model = res.get("model") or {}
    level = (interval_block(model) or {}).get("level")
    pooled = pooled_coverage(res.get("comparison"), model.get("model_id"), "rafi")
    rafi_v["interval"] = worst_run_interval(gated, level, worst_run, pooled) if worst_run else None
    return rafi_v


def _worst_run(verdict: pd.DataFrame | None):
    """The run of the largest measured max residual in a stored verdict (``None`` without one)."""
    if verdict is None or not len(verdict):
        return None
    g = verdict[verdict["criterion"].astype(str) == "max_residual_um"]
    measured = pd.to_numeric(g["measured"], errors="coerce")
    return str(g.loc[measured.idxmax(), "run_id"]) if measured.notna().any() else None


def artefact_of(res: dict, model_id, registry_dir: Path | None = None) -> dict | None:
    """The artefact of ``model_id``: ``comparison/best_model.json`` or ``model.json`` when they
    carry that id, else ``registry/models/<id>.json`` (``None`` where no file holds it)."""
    if not isinstance(model_id, str) or not model_id:
        return None
    for doc in (res.get("best_model"), res.get("model")):
        if isinstance(doc, dict) and str(doc.get("model_id", "")) == model_id:
            return doc
    if registry_dir is None or "/" in model_id:
        return None
    path = Path(registry_dir) / "models" / f"{model_id}.json"
    try:
        return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None
    except (OSError, ValueError):
        return None


def judged_interval(res: dict, model_id, verdict, registry_dir: Path | None = None) -> dict | None:
    """The interval at the worst run of the model on the machine
    (:func:`rafi.report.intervals.worst_run_interval`): its rows of ``comparison/per_run.csv``
    (by ``model_id``), the level of its artefact (:func:`artefact_of`), the worst run of its
    stored verdict (else of those rows), its coverage over every validation sample of
    ``comparison/summary.csv`` (:func:`rafi.report.intervals.pooled_coverage`); ``None`` where a
    result is missing."""
    per_run = res.get("comparison_per_run")
    if per_run is None or "model_id" not in per_run or not model_id:
        return None
    rows = per_run[per_run["model_id"].astype(str) == str(model_id)]
    level = (interval_block(artefact_of(res, model_id, registry_dir)) or {}).get("level")
    worst = _worst_run(verdict)
    if worst is not None and worst not in set(rows["run_id"].astype(str)):
        return None  # the verdict's worst run is not among the comparison's runs: say nothing
    pooled = pooled_coverage(res.get("comparison"), model_id)
    return worst_run_interval(rows.reset_index(drop=True), level, worst, pooled)


def candidate_box(res: dict, dec: dict, noise: dict, waiting: str | None) -> tuple[dict, pd.DataFrame | None]:
    """The verdict box where no model is on the machine after this run: the stored verdict on
    tonight's candidate (rule decide's, on the runs ``registry/comparison.csv`` scores it on).

    Nothing is on the machine, so the box is never PASS: WAITING when the candidate passed every
    gate and waits for a confirmation (``waiting``,
    :func:`rafi.family.confirmation.awaiting_confirmation`), else FAIL. Its rows are the
    candidate's criteria, ``n_checks`` / ``n_failed`` count the candidate's checks and
    ``of_candidate`` is true, so the box states what decision.json holds (not "no validation
    results" beside nine stored checks).

    Parameters
    ----------
    res : dict
        Loaded inputs (``registry_comparison`` and the comparison's verdict).
    dec : dict
        ``registry/decision.json``.
    noise : dict
        Run id -> noise floor (:func:`rafi.report.inputs.noise_floors`).
    waiting : str or None
        What the candidate waits for.

    Returns
    -------
    (dict, DataFrame or None)
        The box (:func:`verdict_context` or, without a stored verdict on a candidate,
        :func:`empty_verdict` "no model on the machine") and the candidate's verdict rows.
    """
    cand = dec.get("candidate_id")
    verdict = None
    if cand:
        verdict, src = stored_verdict_of(
            {**res, "decision": dec}, cand, scored_runs(res.get("registry_comparison"), "candidate")
        )
    if verdict is None or not len(verdict):
        out = empty_verdict("no model on the machine")
        verdict = None
    else:
        out = verdict_context(verdict, src, noise)
        out.update(passed=False, status="FAIL", css="fail", of_candidate=True)
    if waiting:
        out.update(status="WAITING", css="unknown")
    return out, verdict


def verdict_all(res: dict, infos: dict, registry_dir: Path | None = None) -> dict:
    """The verdict of section 1: the model on the machine (with decision.json) + RAFI, over
    every validation run (idle cool-downs included), each max residual beside its run's noise
    floor (:func:`judged_verdict`, :func:`rafi_verdict`: the stored verdicts; NOT STORED where
    no result file stores one); ``interval``: the prediction interval at the worst run of the
    judged model (:func:`judged_interval`; RAFI's: :func:`rafi_context`), ``None`` without
    interval results. ``judged`` has ``waiting``
    (:func:`rafi.family.confirmation.awaiting_confirmation`: what a candidate that passed every
    gate waits for, an input warning or its prior's fitness to be confirmed; None otherwise) and
    ``candidate``; such a candidate makes the status WAITING, with or without a model on the
    machine (the end-of-run line's word): with one, the box's rows stay that model's stored checks
    (``passed``: whether it meets them); without one, the box shows the candidate's stored checks
    (:func:`candidate_box`; ``candidate_kind``).
    ``registry_dir``: where ``registry/models/<id>.json`` are looked up."""
    noise = noise_floors(res)
    rafi_v = rafi_context(res, noise)
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
    # the candidate waiting for a confirmation (an input warning, its prior's fitness): without a
    # model on the machine neither PASS nor FAIL (the words of the end-of-run line and rafi status)
    judged["waiting"] = awaiting_confirmation(dec)
    judged["candidate"] = short_id(dec.get("candidate_id") or "")
    verdict, src = judged_verdict(res, dec)
    if not after:
        out, verdict = candidate_box(res, dec, noise, judged["waiting"])
        cand = dec.get("candidate_id")
        judged["candidate_kind"] = (infos.get(cand or "") or {}).get("kind") or "kind unknown"
        out["interval"] = judged_interval(res, cand, verdict, registry_dir) if verdict is not None else None
    elif verdict is None:
        out = empty_verdict(src, stored=False)
    else:
        out = verdict_context(verdict, src, noise)
    if after and judged["waiting"]:
        # the model on the machine stays, tonight's candidate waits for a confirmation: WAITING,
        # the words of the end-of-run line (its rows stay the model on the machine's own checks)
        out.update(status="WAITING", css="unknown")
    if after:
        out["interval"] = judged_interval(res, after, verdict, registry_dir)
    out.update(judged=judged, rafi=rafi_v, subject=f"model {judged['id']} ({judged['kind']}) on the machine")
    return out


def placement(dec, model_id, champion_after) -> dict:
    """Where this run's registry decision left ``model_id`` (the model a section documents or
    replays), for sections 2 and 3.

    Parameters
    ----------
    dec : dict or None
        ``registry/decision.json`` (``None``: results without a decision).
    model_id : str
        The model of the section.
    champion_after : str or None
        The model on the machine after this run (``champion_id_after``).

    Returns
    -------
    dict
        ``on_machine``: True when ``model_id`` is on the machine, False when it is not, ``None``
        only without a decision and a model on the machine (no registry decision in this run);
        ``no_model``: a decision that left no model on the machine (rejected, no champion yet);
        ``decision`` (the decision's word, ``""`` without one) and ``waiting``: what the model
        waits for when it is the candidate that passed every gate and waits for a confirmation
        (:func:`rafi.family.confirmation.awaiting_confirmation`), with or without a model on the
        machine; else None.
    """
    decided = isinstance(dec, dict) and bool(dec)
    if not champion_after and not decided:
        return {"on_machine": None, "no_model": False, "decision": "", "waiting": None}
    is_candidate = decided and bool(model_id) and str(dec.get("candidate_id") or "") == str(model_id)
    on_machine = bool(champion_after) and str(champion_after) == str(model_id)
    return {
        "on_machine": on_machine,
        "no_model": not champion_after,
        "decision": str(dec.get("decision") or "") if decided else "",
        "waiting": awaiting_confirmation(dec) if is_candidate and not on_machine else None,
    }
