"""Sections 5-7 of the report: the models, the fuzzy blending and the validation.

What comes from evaluating the model (the training fit's RMSE, the worked example of the
blending) is read from the tables of rule ``report_tables`` (:mod:`rafi.report.tables`);
the figures are files of rule ``report_figures``. The functions return data; the sentences
and tables are in ``templates/sections/models.html.j2``, ``fuzzy.html.j2`` and
``validation.html.j2``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rafi.method.paper import MULTI_CONDITION, RESIDUAL_UM, RMSE_UM
from rafi.report.data_sections import paper_value
from rafi.report.envelope_text import MEANING, held_runs
from rafi.report.format import fmt_speed_range, isnum, records, run_speeds, short_id, speed_key, truthy
from rafi.report.inputs import noise_floors
from rafi.report.intervals import band_label, coverage_fields, has_band, has_coverage, interval_block
from rafi.report.trained_range import range_facts

#: Where the membership curves of the figure come from (shown in its caption).
MEMBERSHIP_SOURCE = "rafi.method.fuzzy.membership_curves"

#: A training fit's RMSE recomputed from model.json may differ from fit/diagnostics.csv by
#: this share (plus :data:`RMSE_CHECK_UM`) before the report flags it.
RMSE_CHECK_REL = 0.02
RMSE_CHECK_UM = 1e-3


def equations(model: dict, coefs: pd.DataFrame | None, terms: list) -> list[dict]:
    """One equation per training speed: ``speed_rpm``, ``coefficients``, ``terms``, ``n`` and
    ``ranges`` (key sensor -> ``[lo, hi]`` of the rises it was fitted on) from ``model.json``;
    from ``fit/coefficients.csv`` (no ``n``, no ranges) when the model lists no speed."""
    out = [
        {
            "speed_rpm": sp["speed_rpm"],
            "coefficients": list(sp["coefficients"]),
            "terms": terms,
            "n": sp.get("n"),
            "ranges": dict(sp.get("regressor_ranges") or {}),
        }
        for sp in model.get("speeds") or []
    ]
    if not out and coefs is not None:
        for speed, g in coefs.groupby("speed_rpm"):
            out.append(
                {
                    "speed_rpm": speed,
                    "coefficients": g["coef"].tolist(),
                    "terms": g["term"].tolist(),
                    "n": None,
                    "ranges": {},
                }
            )
    return out


def diagnostics_rows(diag: pd.DataFrame | None, rmse_check: pd.DataFrame | None) -> tuple[list, list]:
    """The rows of ``fit/diagnostics.csv`` (with the paper's Table 3 RMSE beside each speed)
    and the speeds whose RMSE recomputed by rule ``report_tables`` (``report/training_fit.csv``)
    differs from the table.

    Returns
    -------
    tuple
        ``(rows, mismatches)``: per speed ``speed_rpm``, ``n``, ``rmse_um``, ``paper_rmse_um``,
        ``r2``, ``r2_adj``, ``max_vif``, ``durbin_watson``, ``bp_p``, ``jb_p``,
        ``condition_number``; per mismatch ``speed_rpm``, ``table_um``, ``recomputed_um``.
    """
    if diag is None:
        return [], []
    check = (
        {}
        if rmse_check is None
        else {speed_key(r.speed_rpm): r.rmse_um for r in rmse_check.itertuples(index=False)}
    )
    rows, mismatches = [], []
    columns = ("n", "rmse_um", "r2", "r2_adj", "max_vif", "durbin_watson", "bp_p", "jb_p", "condition_number")
    for i in diag.index:
        r = diag.loc[i]
        sp = speed_key(r.speed_rpm)
        chk = check.get(sp, np.nan)
        if (
            isnum(chk)
            and isnum(r.rmse_um)
            and abs(chk - r.rmse_um) > RMSE_CHECK_REL * r.rmse_um + RMSE_CHECK_UM
        ):
            mismatches.append({"speed_rpm": sp, "table_um": r.rmse_um, "recomputed_um": chk})
        row = {"speed_rpm": sp, **{c: r.get(c) for c in columns}}
        row["paper_rmse_um"] = paper_value(diag, i, "paper_rmse_um", RMSE_UM, sp)
        rows.append(row)
    return rows, mismatches


def coefficient_rows(coefs: pd.DataFrame | None, terms: list) -> tuple[list, list | None]:
    """``fit/coefficients.csv`` as one row per term: ``term`` and ``by_speed`` (speed ->
    ``coef``, ``se_hac``, ``p_hac``; ``None`` where the speed has no such term).

    Returns
    -------
    tuple
        ``(speeds, rows)``; ``rows`` is ``None`` without coefficients.
    """
    if coefs is None or not len(coefs):
        return [], None
    c = coefs.assign(speed_rpm=coefs["speed_rpm"].map(speed_key))
    speeds = [speed_key(s) for s in sorted(c["speed_rpm"].unique())]
    rows = []
    for t in terms:
        by_speed = {}
        for s in speeds:
            g = c[(c["speed_rpm"] == s) & (c["term"] == t)]
            by_speed[s] = records(g[["coef", "se_hac", "p_hac"]])[0] if len(g) else None
        rows.append({"term": t, "by_speed": by_speed})
    return speeds, rows


def section_models(res: dict, figs, *, paper: bool = False) -> dict:
    """Section 5: the per-speed equations, diagnostics, coefficients and the training fit.

    Parameters
    ----------
    res : dict
        Loaded inputs: ``model``, ``diagnostics``, ``coefficients``, ``training_fit_rmse``.
    figs : rafi.report.embed.FigureFiles
    paper : bool
        ``report.paper_rig``: the paper's Table 3 RMSE beside each speed.

    Returns
    -------
    dict
        ``terms``, ``variables`` (``x1`` -> sensor), ``equations`` (:func:`equations`),
        ``diagnostics`` and ``mismatches`` (:func:`diagnostics_rows`), ``coef_speeds`` and
        ``coefficients`` (:func:`coefficient_rows`), ``figure``, ``model_id``, ``created``,
        ``code_version``, ``paper``.
    """
    model = res["model"] or {}
    coefs = res["coefficients"]
    terms = list(
        model.get("terms") or (coefs["term"].drop_duplicates().tolist() if coefs is not None else [])
    )
    variables = dict(
        model.get("variables") or {f"x{i + 1}": s for i, s in enumerate(model.get("key_sensors", []))}
    )
    diag_rows, mismatches = diagnostics_rows(res["diagnostics"], res["training_fit_rmse"])
    coef_speeds, coef_rows = coefficient_rows(coefs, terms)
    return {
        "terms": terms,
        "variables": variables,
        "equations": equations(model, coefs, terms),
        "diagnostics": diag_rows,
        "mismatches": mismatches,
        "coef_speeds": coef_speeds,
        "coefficients": coef_rows,
        "figure": figs.get("pipeline", "fit_residuals"),
        "model_id": short_id(model.get("model_id", ""), 16),
        "created": model.get("created", ""),
        "code_version": model.get("code_version", ""),
        "paper": paper,
    }


def section_fuzzy(res: dict, figs, *, paper: bool = False) -> dict | None:
    """Section 6: the membership functions and the worked example (``report/fuzzy_example.json``);
    ``paper`` (``report.paper_rig``): the paper's worked example and its wording are discussed.

    Returns
    -------
    dict or None
        ``figure``, ``example`` (``speed_rpm``, ``neighbours``: ``centre_rpm``,
        ``distance_rpm``, ``weight``, ``model_dz_um``; ``state``: sensor -> rise, K, or
        ``None``; ``blended_dz_um``), ``source``, ``outside``, ``centres`` (r/min), ``paper``;
        ``None`` without training speeds.
    """
    model = res["model"] or {}
    ex = res["fuzzy_example"]
    if len(ex["centres_rpm"]) < 1:
        return None
    example = None
    if ex["example_rpm"] is not None:
        example = {
            "speed_rpm": ex["example_rpm"],
            "neighbours": list(ex["neighbours"]),
            "state": ex["state"],
            "blended_dz_um": ex.get("blended_dz_um"),
        }
    return {
        "figure": figs.get("pipeline", "membership"),
        "example": example,
        "source": MEMBERSHIP_SOURCE,
        "outside": (model.get("fuzzy") or {}).get("outside", "edge"),
        "centres": list(ex["centres_rpm"]),
        "paper": paper,
    }


def idle_rows(idle: pd.DataFrame, noise: dict) -> list[dict] | None:
    """The idle cool-down runs of ``validation/summary.csv``: max |dz| before, max |residual|
    after beside the run's noise floor, improvement, RMSE, ``worse`` (than uncompensated);
    ``None`` without idle runs."""
    if not len(idle):
        return None
    return [
        {
            "run_id": str(r["run_id"]),
            "duration_s": r.get("duration_s"),
            "max_abs_before_um": r.get("max_abs_before_um"),
            "max_abs_after_um": r.get("max_abs_after_um"),
            "noise_floor_um": noise.get(str(r["run_id"])),
            "improvement_pct": r.get("improvement_pct"),
            "worse": truthy(r.get("worse_than_uncompensated", False)),
            "rmse_before_um": r.get("rmse_before_um"),
            "rmse_after_um": r.get("rmse_after_um"),
            **coverage_fields(r),
        }
        for r in idle.to_dict("records")
    ]


def single_rows(single: pd.DataFrame, noise: dict) -> list[dict]:
    """The single-speed validation runs: speed, duration, max |dz| before, max |residual| after,
    noise floor, the paper's Table 4 residual at that speed, improvement, ``worse``, RMSE."""
    rows = []
    for i in single.index:
        r = single.loc[i]
        rows.append(
            {
                "run_id": str(r.run_id),
                "speed_rpm": r.speed_rpm,
                "duration_s": r.duration_s,
                "max_abs_before_um": r.max_abs_before_um,
                "max_abs_after_um": r.max_abs_after_um,
                "noise_floor_um": noise.get(str(r.run_id)),
                "paper_residual_um": paper_value(single, i, "paper_residual_um", RESIDUAL_UM, r.speed_rpm),
                "improvement_pct": r.improvement_pct,
                "worse": truthy(r.get("worse_than_uncompensated", False)),
                "rmse_before_um": r.rmse_before_um,
                "rmse_after_um": r.rmse_after_um,
                **coverage_fields(r),
            }
        )
    return rows


def range_rows(summary: pd.DataFrame) -> list[dict]:
    """Every validation run's samples outside the trained temperature and speed ranges, the
    share outside the temperature range (%), ``n_outside_envelope`` (samples held at the
    training envelope's edge; 0 in a summary written before the column) and ``worse`` (than
    uncompensated)."""
    rows = []
    for r in summary.itertuples(index=False):
        n = r.n_samples
        rows.append(
            {
                "run_id": str(r.run_id),
                "role": r.role,
                "n_samples": n,
                "n_outside_temp_range": r.n_outside_temp_range,
                "n_outside_speed_range": r.n_outside_speed_range,
                "outside_temp_pct": 100 * (r.n_outside_temp_range + 0) / n if isnum(n) and n else np.nan,
                "n_outside_envelope": getattr(r, "n_outside_envelope", 0),
                "worse": truthy(getattr(r, "worse_than_uncompensated", False)),
            }
        )
    return rows


#: A step of the speed (r/min) between two samples that counts as a change of speed.
SPEED_STEP_RPM = 100.0


def speed_changes(speed: pd.Series, step_rpm: float = SPEED_STEP_RPM) -> tuple[int, bool]:
    """How often a run's speed changes, without the spindle's start from a rest before it.

    Parameters
    ----------
    speed : pandas.Series
        The run's speed (r/min), in time order.
    step_rpm : float
        A step between two samples larger than this is a change.

    Returns
    -------
    (int, bool)
        The changes after the first sample that turns (a stop and a restart later count), and
        whether the run starts at rest (its leading samples below ``step_rpm`` before a change).
    """
    values = pd.to_numeric(speed, errors="coerce").to_numpy(dtype=float)
    turning = np.flatnonzero(np.abs(values) > step_rpm)
    if not len(turning):
        return 0, False
    start = int(turning[0])
    steps = np.abs(np.diff(values[start:])) > step_rpm
    return int(steps.sum()), start > 0


def other_runs(
    summary: pd.DataFrame,
    resid: pd.DataFrame,
    noise: dict,
    figs,
    paper: bool,
    *,
    runs: pd.DataFrame | None = None,
    model: dict | None = None,
) -> list[dict]:
    """The validation runs that are neither single-speed nor idle (multi-condition, ...), each
    with its figure, duration, ``speed`` (:func:`rafi.report.format.fmt_run_speed` of its row of
    ``runs``, ``runs.csv``: a varying run's range without its rest before start, as every section
    prints it; the range of its samples only without that row), speed changes and whether it
    starts from rest (:func:`speed_changes` of ``validation/residuals.parquet``), max |dz| before
    and |residual| after, noise floor, improvement, the samples outside the trained ranges with
    ``trained_speeds`` (the speeds of
    ``model``, ``model.json``: :func:`rafi.report.trained_range.range_facts`, as the verdict and
    the comparison count them; ``""`` unknown) and, on the paper's rig, the paper's
    multi-condition run (``paper``)."""
    speeds = run_speeds(runs)
    others = (
        summary[~summary["role"].isin(["validation_single", "validation_idle"])]
        if "role" in summary
        else summary.iloc[0:0]
    )
    out = []
    for r in others.to_dict("records"):
        f = resid[resid["run_id"] == r["run_id"]]
        if not len(f):
            continue
        facts = range_facts(pd.DataFrame([r]), model) or {}
        r = pd.Series(r)
        out.append(
            {
                "run_id": r.run_id,
                "role": r.role,
                "figure": figs.get("pipeline", f"multi_condition/{r.run_id}"),
                "duration_s": r.duration_s,
                "speed": speeds.get(str(r.run_id))
                or fmt_speed_range(f["speed_rpm"].min(), f["speed_rpm"].max()),
                **dict(zip(("changes", "from_rest"), speed_changes(f["speed_rpm"]), strict=True)),
                "max_abs_before_um": r.max_abs_before_um,
                "max_abs_after_um": r.max_abs_after_um,
                "noise_floor_um": noise.get(str(r.run_id)),
                "improvement_pct": r.improvement_pct,
                "n_outside_temp_range": facts.get("n_temp"),
                "n_outside_speed_range": facts.get("n_speed"),
                "n_samples": facts.get("n_samples"),
                "trained_speeds": facts.get("speeds", ""),
                "paper": dict(MULTI_CONDITION) if paper and r.role == "validation_multi" else None,
                **coverage_fields(r),
            }
        )
    return out


def section_validation(res: dict, figs, *, paper: bool = False) -> dict:
    """Section 7: single-speed, multi-condition and idle validation runs, out-of-range samples.

    Parameters
    ----------
    res : dict
        Loaded inputs: ``validation_summary``, ``residuals`` and the noise floors.
    figs : rafi.report.embed.FigureFiles
    paper : bool
        ``report.paper_rig``: the paper's Table 4 and multi-condition run beside them.

    Returns
    -------
    dict
        ``single`` (:func:`single_rows`), ``ranges`` (:func:`range_rows`), ``idle``
        (:func:`idle_rows`) and ``n_idle``, ``multi`` (:func:`other_runs`), ``figure_single``,
        ``figure_idle``, ``paper``; the tables are ``None`` without ``validation/summary.csv``.
        ``coverage``: the summary has the interval's ``coverage`` (each row then has
        ``coverage_pct`` and ``interval_width_um``, :func:`rafi.report.intervals.coverage_fields`);
        ``band``: ``validation/residuals.parquet`` has the interval (the figures draw it);
        ``interval``: ``label`` (``90 % interval``) and ``level_pct`` of ``model.json``'s
        interval block (``None`` without one).
        ``envelope``: the runs with samples held at the training envelope's edge
        (:func:`rafi.report.envelope_text.held_runs`; empty when none were) and
        ``envelope_meaning`` (:data:`rafi.report.envelope_text.MEANING`).
    """
    summ = res["validation_summary"]
    resid = res["residuals"]
    out = {
        "single": None,
        "ranges": None,
        "figure_single": None,
        "multi": [],
        "figure_idle": None,
        "n_idle": 0,
        "idle": None,
        "paper": paper,
        "coverage": has_coverage(summ),
        "band": has_band(resid),
        "interval": None,
        "envelope": held_runs(summ),
        "envelope_meaning": MEANING,
    }
    block = interval_block(res.get("model"))
    if block is not None:
        out["interval"] = {"label": band_label(block["level"]), "level_pct": 100.0 * float(block["level"])}
    if summ is None:
        return out
    noise = noise_floors(res)
    single = summ[summ["role"] == "validation_single"] if "role" in summ else summ
    idle = summ[summ["role"] == "validation_idle"] if "role" in summ else summ.iloc[0:0]
    out["single"] = single_rows(single, noise)
    out["idle"], out["n_idle"] = idle_rows(idle, noise), len(idle)
    out["ranges"] = range_rows(summ)
    if resid is None:
        return out
    out["figure_single"] = figs.get("pipeline", "validation_single")
    out["figure_idle"] = figs.get("pipeline", "validation_idle")
    out["n_idle"] = sum(bool((resid["run_id"] == rid).any()) for rid in idle["run_id"])
    out["multi"] = other_runs(
        summ, resid, noise, figs, paper, runs=res.get("runs_csv"), model=res.get("model")
    )
    return out
