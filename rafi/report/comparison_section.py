"""Section 9 of the report: the model family compared with RAFI as published.

Reads ``comparison/summary.csv``, ``per_run.csv`` and ``cv.csv``; the figures are files of
rule ``report_figures`` (group ``comparison``), which draws them from the frames of
:func:`comparison_frames` - the same tables the section lists.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rafi.family.forward_folds import MIN_TRAIN, horizon_of, is_forward
from rafi.family.selection import rule_of_candidates, selection_rule
from rafi.family.since_change import change_text
from rafi.family.time_blocks import SCHEME as TIME_BLOCKS
from rafi.family.unexplained import unexplained_text
from rafi.report.ensemble_section import ensemble_context
from rafi.report.envelope_text import MEANING, held_by_model
from rafi.report.format import isnum, truthy
from rafi.report.inputs import collinearity_frame, model_noise_floors, noise_floors
from rafi.report.intervals import band_label, coverage_fields, has_band, has_coverage, shared_level
from rafi.report.plain_ridge import PLAIN_RIDGE, section_plain_ridge
from rafi.report.trained_range import (
    model_speed_counts,
    outside_counts,
    stored_speed_counts,
    trained_speed_span,
    trained_speeds_text,
)


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
        ``role`` (by run), ``champion`` (:func:`family_champion`), ``rafi`` (the model
        of kind ``rafi``, or ``None``) and ``coverage`` / ``width`` (the interval's coverage,
        fraction, and median width, um; ``None`` without a ``coverage`` column).
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
    interval = {"coverage": None, "width": None}
    if has_coverage(p) and "interval_width_um" in p:
        for key, col in (("coverage", "coverage"), ("width", "interval_width_um")):
            wide = p.pivot_table(index="run_id", columns="model", values=col, aggfunc="first")
            interval[key] = wide.reindex(index=runs, columns=models)
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
        **interval,
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


def selection_score(row):
    """The score that chose the champion for one model (a ``summary.csv`` row): its
    ``selection_score_um``, or ``cv_mean_max_abs_um`` in a ``summary.csv`` written before the
    forward folds (no ``selection_score_um`` column: the whole-run mean was the score)."""
    return row.get("selection_score_um") if "selection_score_um" in row else row.get("cv_mean_max_abs_um")


def forward_mask(cv: pd.DataFrame) -> np.ndarray:
    """True for the rows of ``comparison/cv.csv`` that are forward folds (all false in a table
    without ``scheme``)."""
    if "scheme" not in cv:
        return np.zeros(len(cv), dtype=bool)
    return cv["scheme"].map(is_forward).to_numpy(dtype=bool)


def cv_schemes(cv: pd.DataFrame | None) -> tuple[str, str]:
    """``(whole-run scheme, forward scheme)`` of ``comparison/cv.csv``, each ``""`` when it has no
    such rows: the whole-run scheme (``leave_one_run_out``, ``leave_one_speed_out`` or
    ``time_blocks``) and the forward one (``forward_2``, :mod:`rafi.family.forward_folds`)."""
    if cv is None or not len(cv) or "scheme" not in cv:
        return "", ""
    scheme = cv["scheme"].astype(str)
    forward = forward_mask(cv)
    whole, ahead = scheme[~forward], scheme[forward]
    return (str(whole.iloc[0]) if len(whole) else "", str(ahead.iloc[0]) if len(ahead) else "")


def _fold_count(rows: pd.DataFrame) -> int:
    """Folds among ``cv.csv`` rows (one row per fold and held-out run; a fold under
    leave_one_speed_out or a forward fold holds out several runs)."""
    return int(rows["fold"].nunique()) if "fold" in rows else len(rows)


def _cv_stats(cv: pd.DataFrame | None) -> dict:
    """``model -> {folds, held_out, scheme, forward_folds, forward_held_out, forward_scheme}`` of
    ``comparison/cv.csv`` (empty without the table): ``folds`` and ``held_out`` (runs) count the
    whole-run folds only; the forward folds are counted apart (0 without them)."""
    if cv is None or not len(cv) or "model" not in cv:
        return {}
    out = {}
    for name, g in cv.groupby("model"):
        whole_scheme, forward_scheme = cv_schemes(g)
        forward = forward_mask(g)
        out[str(name)] = {
            "folds": _fold_count(g[~forward]),
            "held_out": int((~forward).sum()),
            "scheme": whole_scheme,
            "forward_folds": _fold_count(g[forward]),
            "forward_held_out": int(forward.sum()),
            "forward_scheme": forward_scheme,
            "horizon": horizon_of(forward_scheme) if forward_scheme else 0,
        }
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


def _share_pct(count, n) -> float:
    """``count`` of ``n`` samples in percent (NaN without samples)."""
    n = float(n or 0)
    return 100.0 * float(count or 0) / n if n else np.nan


def _finite_max(values) -> float | None:
    """The largest finite value (``None`` without one)."""
    arr = np.asarray(values, float)
    return float(np.nanmax(arr)) if np.isfinite(arr).any() else None


def rafi_failure(bad: pd.DataFrame, res: dict, settings: dict) -> dict:
    """Why RAFI as published fails on the runs ``bad``, from the data.

    Parameters
    ----------
    bad : DataFrame
        RAFI's failing rows of ``comparison/per_run.csv``.
    res : dict
        Loaded inputs: ``model`` (the trained speeds), ``collinearity`` and ``key_sensors_json``.
    settings : dict
        The machine's settings (``reference.rule``).

    Returns
    -------
    dict
        ``runs`` (per run: ``run_id``, ``max_abs_after_um``, ``noise_floor_um``, ``n_samples``,
        ``outside_temp_pct``, ``outside_speed_pct``), ``n``, ``n_extrapolated`` (runs with at
        least :data:`EXTRAPOLATED_PCT` % of the samples outside the trained temperature range),
        ``extrapolated_pct``, ``max_temp_pct``, ``max_speed_pct`` (``None`` unless some sample
        is outside the trained speeds), ``trained_speeds`` (:func:`_trained_speeds` of
        ``model.json``: ``trained speeds 3 000–18 000 r/min``, ``trained speed 3 000 r/min`` or
        ``None``),
        ``key_sensor_r`` (largest |r| between two key sensors, ``None`` unknown) and
        ``log_start`` (``reference.rule`` is ``log_start``).
    """
    runs = []
    noise = noise_floors(res)
    for r in bad.to_dict("records"):
        # the shares as the verdict's statement and the validation section count them
        c = outside_counts(pd.DataFrame([r])) or {}
        runs.append(
            {
                "run_id": str(r["run_id"]),
                "max_abs_after_um": r["max_abs_after_um"],
                "noise_floor_um": noise.get(str(r["run_id"])),
                "n_samples": float(r.get("n_samples") or 0),
                "outside_temp_pct": np.nan if c.get("temp_pct") is None else c["temp_pct"],
                "outside_speed_pct": np.nan if c.get("speed_pct") is None else c["speed_pct"],
            }
        )
    t_share = np.asarray([r["outside_temp_pct"] for r in runs], float)
    max_speed = _finite_max([r["outside_speed_pct"] for r in runs])
    r_max = _key_sensor_r(res)
    return {
        "runs": runs,
        "n": len(bad),
        "n_extrapolated": int(np.sum(t_share >= EXTRAPOLATED_PCT)),
        "extrapolated_pct": EXTRAPOLATED_PCT,
        "max_temp_pct": _finite_max(t_share),
        "max_speed_pct": max_speed if max_speed is not None and max_speed > 0 else None,
        "trained_speeds": _trained_speeds(res.get("model")),
        "key_sensor_r": r_max if isnum(r_max) else None,
        "log_start": settings["reference"]["rule"] == "log_start",
    }


def _trained_speeds(artefact) -> str | None:
    """RAFI's trained speeds as the failure explanation words them (``trained speeds 1 250–5 000
    r/min``, one speed once: ``trained speed 3 000 r/min``), from
    :func:`rafi.report.trained_range.trained_speeds_text` as the verdict and the validation section
    read them; ``None`` where its artefact records none."""
    text = trained_speeds_text(artefact)
    if not text:
        return None
    span = trained_speed_span(artefact)
    return f"trained speed {text}" if span[0] == span[1] else f"trained speeds {text}"


def selection_context(
    summary: pd.DataFrame, champion, scheme: str = "", forward: str = "", noise: dict | None = None
) -> dict:
    """How the champion was chosen, from ``comparison/summary.csv``.

    Parameters
    ----------
    summary : DataFrame
        ``comparison/summary.csv``.
    champion : str or None
        The champion's name.
    scheme, forward : str
        The whole-run and the forward scheme of ``comparison/cv.csv`` (:func:`cv_schemes`).
    noise : dict, optional
        Model -> the noise floor beside its worst residual
        (:func:`rafi.report.inputs.model_noise_floors`); without it the summary's.

    Returns
    -------
    dict
        ``rule`` (:func:`rafi.family.selection.selection_rule` of the folds' ``scheme`` and
        ``forward``; with an ensemble prior's adaptations among the models,
        :func:`rafi.family.selection.rule_of_candidates` after it), ``time_blocks`` (the folds were
        time blocks), ``horizon`` (runs a forward
        fold holds out; 0 without forward folds), ``min_train`` (fewest training runs before a
        forward fold's origin), ``champion``, ``n`` (models), ``basis``
        (``cv``, ``default`` without a CV score, ``none`` without a champion) and, with a
        champion: ``score`` (the selection score that chose it, um: :func:`selection_score`),
        ``whole_score`` (its whole-run CV mean max |residual|), ``forward_score`` (the same over
        the forward folds' held-out runs; ``None`` when they did not score it), ``worst_fold``
        (its worst whole-run held-out run), ``passed`` (its gates on the validation runs, touched
        once after the choice), ``validation_worst``, ``noise`` (the noise floor of that run) and
        ``better_on_validation`` (candidates with a lower worst residual on the validation runs).
    """
    rule, extra = selection_rule(scheme, forward), rule_of_candidates(summary["model"])
    out = {
        "rule": f"{rule} {extra}" if extra else rule,
        "time_blocks": str(scheme) == TIME_BLOCKS,
        "horizon": horizon_of(forward) if is_forward(forward) else 0,
        "min_train": MIN_TRAIN,
        "champion": champion,
        "basis": "none",
        "score": None,
        "whole_score": None,
        "forward_score": None,
        "n": len(summary),
    }
    if champion is None:
        return out
    r = summary[summary["model"].astype(str) == champion].iloc[0]
    score = selection_score(r)
    ahead = r.get("cv_forward_mean_max_abs_um")
    out["basis"] = "cv" if isnum(score) else "default"
    out["score"] = score
    out["whole_score"] = r.get("cv_mean_max_abs_um")
    out["forward_score"] = ahead if out["horizon"] and isnum(ahead) else None
    out["worst_fold"] = r.get("cv_max_abs_um")
    out["passed"] = truthy(r.get("passed", False))
    out["validation_worst"] = r.get("max_abs_after_um")
    out["noise"] = r.get("noise_floor_um") if noise is None else noise.get(str(champion))
    offerable = summary["candidate"].map(truthy) if "candidate" in summary else pd.Series(True, summary.index)
    out["better_on_validation"] = [
        str(m)
        for m, after, can in zip(
            summary["model"].astype(str),
            pd.to_numeric(summary["max_abs_after_um"], errors="coerce"),
            offerable,
        )
        if m != champion
        and can  # the plain ridge scored as the reference only is the passage's (rafi.report.plain_ridge)
        and isnum(after)
        and isnum(r.get("max_abs_after_um"))
        and after < float(r["max_abs_after_um"])
    ]
    return out


def model_rows(
    summary: pd.DataFrame, champion, on_machine, speed_counts: dict | None = None, noise: dict | None = None
) -> list[dict]:
    """One row per model of ``comparison/summary.csv``: its CV numbers (``selection_score_um``,
    the score that chose, :func:`selection_score`; ``cv_mean_max_abs_um`` of the whole-run folds;
    ``cv_forward_mean_max_abs_um`` of the forward folds, ``None`` in an older ``summary.csv``),
    its validation numbers, the share of samples outside its trained temperature range, its gates
    and ``is_champion``, ``on_machine``, ``is_rafi`` (the paper's reference), ``is_plain_ridge``
    (the floor, :mod:`rafi.family.plain_ridge`) and ``candidate`` (the rule may offer it; true in a
    ``summary.csv`` without the column). ``speed_counts``: model -> its samples more than the
    machine's ``speed_tolerance_rpm`` outside its trained speeds, per run
    (:func:`rafi.report.trained_range.model_speed_counts`), their total in place of the summary's
    ``n_outside_speed_range``, the verdict's count for the offered model. ``noise``: model -> the
    noise floor of its worst run (:func:`rafi.report.inputs.model_noise_floors`; without it the
    summary's)."""
    rows = []
    for r in summary.to_dict("records"):
        name = str(r["model"])
        counted = (speed_counts or {}).get(name)
        if counted is not None:
            r = {**r, "n_outside_speed_range": int(counted.sum())}
        n = r.get("n_samples")
        outside = r.get("n_outside_temp_range")
        rows.append(
            {
                "model": name,
                "kind": str(r.get("kind", "")),
                "selection_score_um": selection_score(r),
                "cv_mean_max_abs_um": r.get("cv_mean_max_abs_um"),
                "cv_forward_mean_max_abs_um": r.get("cv_forward_mean_max_abs_um"),
                "cv_max_abs_um": r.get("cv_max_abs_um"),
                "selection_rank": r.get("selection_rank"),
                "max_abs_after_um": r.get("max_abs_after_um"),
                "noise_floor_um": r.get("noise_floor_um") if noise is None else noise.get(name),
                "improvement_pct": r.get("improvement_pct"),
                "n_outside_temp_range": outside,
                "outside_temp_pct": _share_pct(outside, n) if isnum(n) and isnum(outside) else np.nan,
                "n_outside_speed_range": r.get("n_outside_speed_range"),
                "passed": truthy(r.get("passed", False)),
                "is_champion": name == champion,
                "on_machine": name == on_machine,
                "is_rafi": str(r.get("kind")) == "rafi",
                "is_plain_ridge": name == PLAIN_RIDGE,
                "candidate": truthy(r.get("candidate", True)),
                **coverage_fields(r),
            }
        )
    return rows


def per_run_rows(frames: dict, noise: dict) -> list[dict]:
    """One row per validation run of :func:`comparison_frames`: ``run_id``, ``role``, max |dz|,
    noise floor and per model ``after:<model>`` (max |residual|), ``imp:<model>``
    (improvement), ``passed:<model>`` (its gates on the run) and, with the interval,
    ``cov:<model>`` (coverage, %) and ``width:<model>`` (median width, um)."""
    rows = []
    for rid in frames["runs"]:
        row = {
            "run_id": rid,
            "role": frames["role"][rid].replace("validation_", ""),
            "max_abs_before_um": frames["before"][rid],
            "noise_floor_um": noise.get(rid),
        }
        for m in frames["models"]:
            row[f"after:{m}"] = frames["after"].loc[rid, m]
            row[f"imp:{m}"] = frames["imp"].loc[rid, m]
            row[f"passed:{m}"] = bool(frames["passed"].loc[rid, m])
            if frames.get("coverage") is not None:
                cov, width = frames["coverage"].loc[rid, m], frames["width"].loc[rid, m]
                f = coverage_fields({"coverage": cov, "interval_width_um": width})
                row[f"cov:{m}"], row[f"width:{m}"] = f["coverage_pct"], f["interval_width_um"]
        rows.append(row)
    return rows


#: The per-model fields of a row of :func:`per_run_rows`, ``<field>:<model>``.
RUN_CELL_FIELDS = ("after", "imp", "passed", "cov", "width")


def per_model_rows(per_run: list[dict], models: list) -> list[dict]:
    """The rows of :func:`per_run_rows` turned: the table with a row per model and a column per
    validation run, for a family with more models than validation runs (fewer, wider columns).

    Parameters
    ----------
    per_run : list of dict
        :func:`per_run_rows`.
    models : list
        The models, in the order of ``comparison/summary.csv``.

    Returns
    -------
    list of dict
        First the runs' own numbers, ``what`` ``"before"`` (max |dz| without compensation) and
        ``"noise"`` (noise floor), each with ``value:<run id>``; then per model ``what``
        ``"model"``, ``model`` and ``<field>:<run id>`` for the fields of
        :data:`RUN_CELL_FIELDS` the rows hold (``after:<run id>`` its max |residual| on the run).
    """
    rows = [
        {"what": "before", **{f"value:{r['run_id']}": r["max_abs_before_um"] for r in per_run}},
        {"what": "noise", **{f"value:{r['run_id']}": r["noise_floor_um"] for r in per_run}},
    ]
    for m in models:
        row = {"what": "model", "model": m}
        for r in per_run:
            for field in RUN_CELL_FIELDS:
                if f"{field}:{m}" in r:
                    row[f"{field}:{r['run_id']}"] = r[f"{field}:{m}"]
        rows.append(row)
    return rows


def champion_beside_rafi(frames: dict, champion, on_machine) -> dict | None:
    """The family's champion on the runs where RAFI as published fails: its name, whether it
    passes every gate on them and whether it is on the machine (``None`` when RAFI is the
    champion or there is none)."""
    if not champion or champion == frames["rafi"]:
        return None
    passed = frames["passed"]
    return {
        "name": champion,
        "passes": bool(passed[champion].all()) if champion in passed.columns else False,
        "on_machine": on_machine == champion,
    }


def unpredicted_models(
    summary: pd.DataFrame, count: str = "n_unpredicted", inputs: str = "unpredicted_inputs"
) -> list[dict]:
    """The models of ``summary.csv`` that gave no value on some measured samples: ``model``, ``n``
    (column ``count``) and ``inputs`` (column ``inputs``, may be ``""``). The defaults read the
    validation runs' columns; ``cv_unpredicted`` / ``cv_unpredicted_inputs`` the held-out
    training runs' of the cross-validation."""
    if count not in summary.columns:
        return []
    rows = summary[summary[count].fillna(0) > 0]
    return [
        {
            "model": str(r["model"]),
            "n": int(r[count]),
            "inputs": "" if pd.isna(r.get(inputs)) else str(r.get(inputs)),
        }
        for r in rows.to_dict("records")
    ]


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
        ``None`` without ``comparison/summary.csv``; else ``champion``, ``on_machine``,
        ``models`` (:func:`model_rows`), ``kind_column`` (some model is not named after its
        kind), ``selection`` (:func:`selection_context`), ``selected`` (``(model, what CV
        chose)``), ``forward`` (some model has a forward CV score), ``cv`` (the first model's
        :func:`_cv_stats`: whole-run ``scheme`` and ``folds``, ``forward_scheme``,
        ``forward_folds``, ``horizon``), ``unpredicted`` and ``cv_unpredicted`` (:func:`unpredicted_models`),
        ``unexplained`` (:func:`rafi.family.unexplained.unexplained_text`: the held-out training
        runs no model explains, ``None`` when there is none), ``set_aside``
        (:func:`rafi.family.since_change.change_text` of ``comparison_since_change``: the training
        runs set aside before a change, ``None`` when none were), ``figure_since_change`` (the
        figure of the training runs in recorded order, when runs were set aside),
        ``run_models`` and ``per_run`` (:func:`per_run_rows`), ``per_model`` (:func:`per_model_rows`,
        the same table with a row per model, where the models outnumber the validation runs;
        else ``None``), ``figure_bars``, ``rafi_fail``
        (:func:`rafi_failure` with ``champion``: :func:`champion_beside_rafi`) and
        ``figures_resid``, ``plain_ridge`` (:func:`rafi.report.plain_ridge.section_plain_ridge`);
        the interval:
        ``coverage`` (summary.csv has it), ``run_coverage`` (per_run.csv has it), ``band``
        (residuals.parquet has it) and ``interval_label`` (``90 % interval``);
        ``envelope`` (per model, the validation runs with samples held at its training
        envelope's edge, from ``comparison/residuals.parquet``:
        :func:`rafi.report.envelope_text.held_by_model`; empty when none were) and
        ``envelope_meaning``; ``ensemble``: :func:`rafi.report.ensemble_section.ensemble_context`
        of the offered artefact (``best_model``, when its id is in the summary; ``None`` unless it
        is the CV-weighted ensemble), which also gives ``selection`` its ``rule`` and ``ensemble``;
        ``speed_tolerance_rpm``, ``speed_recounted`` (the models' samples outside their trained
        speeds are recounted from ``residuals.parquet``: :func:`rafi.report.trained_range.model_speed_counts`)
        and ``speed_stored`` (where ``per_run.csv``'s own counts differ from the recount:
        :func:`rafi.report.trained_range.stored_speed_counts`).
    """
    summ = res.get("comparison")
    if summ is None or not len(summ):
        return None
    s = summ.assign(model=summ["model"].astype(str))
    fam_champ = family_champion(s)
    on_machine = None
    if champion_after and "model_id" in s:
        hit = s[s["model_id"].astype(str) == str(champion_after)]
        on_machine = hit["model"].iloc[0] if len(hit) else None
    cv_rows = res.get("comparison_cv")
    cvs = _cv_stats(cv_rows)
    tolerance = settings.get("speed_tolerance_rpm")
    model_noise = model_noise_floors(res)
    recounted = model_speed_counts(res, tolerance)
    rows = model_rows(s, fam_champ, on_machine, recounted, model_noise)
    best, ids = res.get("best_model"), set(s["model_id"].astype(str)) if "model_id" in s else set()
    offered = best if isinstance(best, dict) and str(best.get("model_id", "")) in ids else None
    ensemble = ensemble_context(offered, s, *cv_schemes(cv_rows))
    out = {
        "champion": fam_champ,
        "on_machine": on_machine,
        "models": rows,
        "kind_column": any(str(r.get("kind", "")) != str(r["model"]) for r in s.to_dict("records")),
        "selection": selection_context(s, fam_champ, *cv_schemes(cv_rows), noise=model_noise),
        "plain_ridge": section_plain_ridge(s, cv_schemes(cv_rows)[0]),
        # the CV-weighted ensemble offered under models: offer: ensemble (rafi.report.ensemble_section)
        "ensemble": ensemble,
        # the forward CV's column: only when some model was scored on forward folds
        "forward": any(isnum(r["cv_forward_mean_max_abs_um"]) for r in rows),
        "selected": [
            (str(r["model"]), str(r["selected"]))
            for r in s.to_dict("records")
            if "selected" in s and isinstance(r.get("selected"), str) and r["selected"]
        ],
        "cv": next(iter(cvs.values())) if cvs else None,
        "unpredicted": unpredicted_models(s),
        # held-out training runs on which every model is worse than no compensation (rafi.family.unexplained)
        "unexplained": unexplained_text(cv_rows),
        # training runs recorded before a change, set aside (models.since_change)
        "set_aside": change_text(res.get("comparison_since_change")),
        "cv_unpredicted": unpredicted_models(s, "cv_unpredicted", "cv_unpredicted_inputs"),
        "run_models": [],
        "per_run": None,
        "per_model": None,
        "figure_bars": None,
        "rafi_fail": None,
        "figures_resid": [],
        # the prediction interval (issue 26): coverage beside every residual, bands in the figures
        "coverage": has_coverage(s),
        "run_coverage": False,
        "band": has_band(res.get("comparison_residuals")),
        "interval_label": band_label(shared_level(res.get("model"), res.get("best_model"))),
        "envelope": held_by_model(res.get("comparison_residuals")),
        "envelope_meaning": MEANING,
        # a sample outside the trained speeds: beyond them by more than this (rafi.report.trained_range)
        "speed_tolerance_rpm": tolerance if isnum(tolerance) else None,
        # the table's outside-speed counts are the recount, not per_run.csv's (the footer says so)
        "speed_recounted": bool(recounted),
        "speed_stored": stored_speed_counts(s, recounted),
    }
    if ensemble is not None:  # offered by models: offer, not by the lowest score: the rule says so
        out["selection"]["ensemble"] = ensemble
        if ensemble["selection_rule"]:  # an ensemble adapted from a prior: the re-qualification's rule stands
            out["selection"]["rule"] = ensemble["selection_rule"]
    pr = res.get("comparison_per_run")
    if pr is None or not len(pr):
        return out
    fr = comparison_frames(summ, pr)
    out["run_models"] = fr["models"]
    out["per_run"] = per_run_rows(fr, noise_floors(res))
    if len(fr["models"]) > len(fr["runs"]):
        out["per_model"] = per_model_rows(out["per_run"], fr["models"])
    out["run_coverage"] = fr["coverage"] is not None
    out["figure_bars"] = figs.get("comparison", "comparison_bars")
    out["figure_since_change"] = figs.get("comparison", "since_change")
    rafi_name, passed = fr["rafi"], fr["passed"]
    if rafi_name is not None and rafi_name in passed.columns and not passed[rafi_name].all():
        p = fr["per_run"]
        out["rafi_fail"] = rafi_failure(
            p[(p["model"] == rafi_name) & ~p["passed"].map(truthy)], res, settings
        )
        out["rafi_fail"]["champion"] = champion_beside_rafi(fr, fam_champ, on_machine)
    if rafi_name is not None:  # residual time series: RAFI vs the model beside it
        other = model_beside_rafi(fr, on_machine)
        for rid in residual_runs(fr):
            fig = figs.get("comparison", residual_figure_key(rid, other))
            if fig is not None:
                out["figures_resid"].append(
                    {"run_id": rid, "figure": fig, "other": other, "rafi": rafi_name, "role": fr["role"][rid]}
                )
    return out
