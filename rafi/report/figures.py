"""Rule ``report_figures``: every figure of the report as a file, drawn ahead of the report.

Three groups, each drawn as soon as its inputs exist:

``pipeline``
    The method's figures (sections Thermal equilibrium ... Validation), after ``validate``
    and ``report_tables``, beside ``compare``.
``comparison``
    The model family's figures, after ``compare``, beside ``decide``. The residual series of
    RAFI are drawn beside every other model of the family, so the one the registry puts on
    the machine is there whatever ``decide`` decides.
``replay``
    The replay of each run of ``deploy/replay.parquet`` (:mod:`rafi.report.replay_plot`),
    after ``replay``.

A group is written to one folder: ``<key-slug>.<png|svg>`` per figure and ``index.csv``
(``key,file``), read back by :class:`rafi.report.embed.FigureFiles`.
"""

from __future__ import annotations

import itertools
import os
import re
from pathlib import Path

import numpy as np
import pandas as pd

from rafi import contract
from rafi.artefact import write_bytes_atomic, write_csv_atomic
from rafi.family.since_change import set_aside_count
from rafi.method.fuzzy import membership_curves
from rafi.report import plots
from rafi.report.comparison_section import comparison_frames, residual_figure_key, residual_runs
from rafi.report.data_sections import MAX_COLLINEARITY_TABLE
from rafi.report.deployed_plot import fig_deployed_residuals
from rafi.report.deployed_section import deployed_figure_key, deployed_panels
from rafi.report.embed import INDEX
from rafi.report.format import fmt_num, fmt_speed, isnum, speed_key, truthy
from rafi.report.inputs import (
    chosen_sensors,
    collinearity_frame,
    correlation_wide,
    load_results,
    noise_floors,
    sensors,
    training_runs,
)
from rafi.report.intervals import band_label, has_band, replayed_level, residual_band, shared_level
from rafi.report.replay_plot import fig_replay
from rafi.report.replay_section import replay_figure_key
from rafi.report.segmentation_plot import fig_segmentation

#: The inputs each group draws from (names of :data:`rafi.contract.RESULT_FILES`).
FIGURE_GROUPS = contract.FIGURE_GROUPS

UM = "\u00b5m"


def _pipeline(res: dict, coolant_sensors: list, fmt: str):
    """``(key, file bytes)`` of each figure of sections 3-7 that has data."""
    key_info, key, coolant = sensors(res, coolant_sensors)
    rf, eq = res["runs_parquet"], res["equilibrium"]
    train = training_runs(res["runs_csv"])
    if rf is not None and train:
        eq_times = {}
        if eq is not None:
            for r in eq.itertuples(index=False):
                eq_times[speed_key(r.speed_rpm)] = float(r.t_eq_s) if isnum(r.t_eq_s) else np.nan
        drawn = [s for s in key + coolant if s in rf.columns]
        runs = {}
        for speed, rid in train.items():
            f = rf.loc[rf["run_id"] == rid, ["t_s", *drawn, "dz_um"]]
            if len(f):
                runs[speed] = f
        if runs:
            yield (
                "training_runs",
                plots.fig_training_runs(
                    runs, temp_sensors=drawn, eq_times=eq_times, n_key=sum(s in key for s in drawn), fmt=fmt
                ),
            )
    if res["correlation"] is not None:
        yield (
            "correlation_heatmap",
            plots.fig_correlation_heatmap(
                correlation_wide(res["correlation"]),
                threshold=float(key_info["threshold"]),
                chosen=chosen_sensors(key_info, res["key_sensors"]),
                fmt=fmt,
            ),
        )
    coll = res["collinearity"]
    if coll is not None and len(coll) > MAX_COLLINEARITY_TABLE:
        yield "collinearity", plots.fig_matrix(collinearity_frame(coll), fmt=fmt)
    fit = res["training_fit"]
    if fit is not None and len(fit):
        fits = {
            speed_key(s): g[["t_s", "measured_um", "fitted_um"]].reset_index(drop=True)
            for s, g in fit.groupby("speed_rpm", sort=False)
        }
        yield "fit_residuals", plots.fig_fit_residuals(fits, fmt=fmt)
    yield from _membership(res["fuzzy_example"], fmt)
    yield from _validation(res, key + coolant, fmt, n_key=len(key))
    yield from _segmentation(res["runs_csv"], rf, fmt)


#: At most this many logs get a segmentation timeline (the logs cut into the most runs).
MAX_TIMELINES = 4


def segmentation_logs(runs: pd.DataFrame | None) -> list[str]:
    """Files of ``runs.csv`` cut into two or more runs (at most :data:`MAX_TIMELINES`, the most
    runs first, then in file order): the logs the segmentation timeline shows."""
    if runs is None or not len(runs) or "file" not in runs:
        return []
    counts = runs["file"].astype(str).value_counts(sort=False)
    order = {f: i for i, f in enumerate(dict.fromkeys(runs["file"].astype(str)))}
    multi = sorted((f for f, n in counts.items() if n >= 2), key=lambda f: (-counts[f], order[f]))
    return multi[:MAX_TIMELINES]


def _segmentation(runs: pd.DataFrame | None, rf: pd.DataFrame | None, fmt: str):
    """The timeline of every log cut into several runs, coloured by role (section Segmentation)."""
    files = segmentation_logs(runs)
    if rf is None or not files:
        return
    logs = {}
    for file in files:
        table = runs[runs["file"].astype(str) == file]
        ids = table["run_id"].astype(str)
        f = rf[rf["run_id"].astype(str).isin(set(ids))]
        if "log_t_s" in f:
            clock = f["log_t_s"].to_numpy(dtype=float)
        else:  # results written before runs.parquet had the log's clock
            start = dict(zip(ids, table["start_s"].astype(float)))
            clock = f["t_s"].to_numpy(dtype=float) + f["run_id"].astype(str).map(start).to_numpy(dtype=float)
        order = np.argsort(clock, kind="stable")
        samples = pd.DataFrame(
            {
                "h": clock[order] / 3600.0,
                "speed_rpm": f["speed_rpm"].to_numpy(dtype=float)[order],
                "dz_um": f["dz_um"].to_numpy(dtype=float)[order],
            }
        )
        spans = pd.DataFrame(
            {
                "start_h": table["start_s"].astype(float).to_numpy() / 3600.0,
                "end_h": table["end_s"].astype(float).to_numpy() / 3600.0,
                "role": table["role"].astype(str).to_numpy(),
                "label": ["#" + r.rsplit("#", 1)[-1] if "#" in r else r for r in ids],
            }
        )
        logs[file] = (samples, spans)
    yield "segmentation", fig_segmentation(logs, fmt=fmt)


def _membership(example: dict, fmt: str):
    centres = example["centres_rpm"]
    if not centres:
        return
    lo, hi = centres[0], centres[-1]
    span = max(hi - lo, 1000.0)
    grid = np.linspace(max(0.0, lo - 0.1 * span), hi + 0.1 * span, 801)
    weights = None
    if example["example_rpm"] is not None:
        weights = {n["centre_rpm"]: n["weight"] for n in example["neighbours"] if n["weight"] > 0}
    yield (
        "membership",
        plots.fig_membership(
            grid,
            membership_curves(centres, grid),
            centres,
            example_rpm=example["example_rpm"],
            example_weights=weights,
            fmt=fmt,
        ),
    )


def _validation(res: dict, temps: list, fmt: str, n_key: int = 3):
    """The validation figures of RAFI as published, with the interval of ``model.json`` as a band
    where ``validation/residuals.parquet`` holds it."""
    s, resid, rf = res["validation_summary"], res["residuals"], res["runs_parquet"]
    if s is None or resid is None:
        return
    level = shared_level(res.get("model"))
    single = s[s["role"] == "validation_single"] if "role" in s else s
    panels = {}
    for r in single.itertuples(index=False):
        f = resid[resid["run_id"] == r.run_id]
        if len(f):
            panels[f"{r.run_id}: {fmt_speed(r.speed_rpm)}"] = f
    if panels:
        yield "validation_single", plots.fig_validation_single(panels, level=level, fmt=fmt)
    idle = s[s["role"] == "validation_idle"] if "role" in s else s.iloc[0:0]
    panels = {}
    for r in idle.itertuples(index=False):
        f = resid[resid["run_id"] == r.run_id]
        if len(f):
            label = f"{r.run_id}: {fmt_num(r.max_abs_before_um, 1)} → {fmt_num(r.max_abs_after_um, 1, UM)}"
            panels[label] = f
    if panels:
        yield "validation_idle", plots.fig_validation_single(panels, level=level, fmt=fmt)
    others = s[~s["role"].isin(["validation_single", "validation_idle"])] if "role" in s else s.iloc[0:0]
    for r in others.itertuples(index=False):
        f = resid[resid["run_id"] == r.run_id].copy()
        if not len(f):
            continue
        if rf is not None:
            tf = rf.loc[rf["run_id"] == r.run_id, ["t_s", *[t for t in temps if t in rf]]]
            f = f.merge(tf, on="t_s", how="left")
        drawn = [t for t in temps if t in f]  # key sensors first, then the coolant sensors
        n = sum(t in temps[:n_key] for t in drawn)
        fig = plots.fig_multi_condition(f, temp_sensors=drawn, n_key=n, level=level, fmt=fmt)
        yield f"multi_condition/{r.run_id}", fig


def _comparison(res: dict, gates: dict, fmt: str):
    """``(key, file bytes)`` of the bars and of RAFI's residuals beside every other model."""
    summary, per_run = res["comparison"], res["comparison_per_run"]
    if summary is None or not len(summary) or per_run is None or not len(per_run):
        return
    fr = comparison_frames(summary, per_run)
    champion, rafi, models = fr["champion"], fr["rafi"], fr["models"]
    gate_um = float(gates["max_residual_um"]) if isnum(gates["max_residual_um"]) else np.nan
    labels = {
        m: m + (" (champion)" if m == champion else "") + (" (paper)" if m == "rafi" else "") for m in models
    }
    yield (
        "comparison_bars",
        plots.fig_comparison_bars(
            fr["after"],
            fr["before"],
            failed=~fr["passed"],
            gate_um=gate_um,
            labels=labels,
            offered=champion,
            fmt=fmt,
        ),
    )
    if set_aside_count(res.get("comparison_since_change")):
        yield "since_change", plots.fig_since_change(res["comparison_since_change"], fmt=fmt)
    resid = res["comparison_residuals"]
    if resid is None or not len(resid) or rafi is None:
        return
    level = shared_level(res.get("model"), res.get("best_model"))
    palette = plots.model_colours(models)  # the bar chart's: a model in one colour on every figure
    for rid in residual_runs(fr):
        sub = resid[resid["run_id"].astype(str) == rid]
        rf = sub[sub["model"].astype(str) == rafi].sort_values("t_s")
        for other in [m for m in models if m != rafi] or [None]:
            series, colours = {}, {}
            for m in (rafi, other):
                if m is None:
                    continue
                f = sub[sub["model"].astype(str) == m].sort_values("t_s")
                if len(f):
                    tag = " (paper)" if m == rafi else " (champion)" if m == champion else ""
                    series[f"{m}{tag}"] = f
                    colours[f"{m}{tag}"] = palette.get(m)
            if not series:
                continue
            yield (
                residual_figure_key(rid, other),
                plots.fig_comparison_residuals(
                    series,
                    measured=rf[["t_s", "measured_um"]] if len(rf) else None,
                    outside=(
                        rf[["t_s"]].assign(outside=rf["outside_temp_range"].map(truthy))
                        if len(rf) and "outside_temp_range" in rf
                        else None
                    ),
                    gate_um=gate_um,
                    level=level,
                    colours=colours,
                    fmt=fmt,
                ),
            )


def _deployed(res: dict, fmt: str):
    """``(key, file bytes)`` of the residual figures of the model offered to the machine: every
    validation run (idle cool-downs included), :func:`rafi.report.deployed_section.deployed_panels`."""
    groups = deployed_panels(
        res["comparison"], res["comparison_per_run"], res["comparison_residuals"], noise_floors(res)
    )
    label = band_label(shared_level(res.get("best_model"), res.get("model")))
    for k, group in enumerate(groups, start=1):
        panels = []
        for p in group:
            role = p["role"].replace("validation_", "")
            title = f"{p['run_id']} ({role}): {fmt_num(p['before'], 1)} \u2192 {fmt_num(p['after'], 2, UM)}"
            band = residual_band(p["frame"]) if has_band(p["frame"]) else None
            panels.append(
                {
                    "title": title,
                    "frame": p["frame"],
                    "noise_floor": p["noise_floor"],
                    "band": band,
                    "band_label": label,
                }
            )
        yield deployed_figure_key(k), fig_deployed_residuals(panels, fmt=fmt)


def _replay(res: dict, deploy: dict, fmt: str):
    """``(key, file bytes)`` of each run of the replay summary that has samples."""
    summary, table = res["replay_summary"], res["replay"]
    if summary is None or not len(summary) or table is None or not len(table):
        return
    clamp = tuple(deploy["clamp_um"]) if deploy.get("clamp_um") else None
    level = replayed_level(summary, res.get("model"), res.get("best_model"))
    for rid in summary["run_id"].astype(str):
        rows = table[table["run_id"].astype(str) == rid]
        if len(rows):
            figure = fig_replay(rows, clamp_um=clamp, level=level, title=f"Replay of {rid}", fmt=fmt)
            yield replay_figure_key(rid), figure


def _file_name(n: int, key: str, fmt: str) -> str:
    slug = re.sub(r"[^A-Za-z0-9._-]+", "_", key)
    return f"{n:02d}-{slug}.{fmt}"


def draw_group(
    paths: dict,
    group: str,
    out_dir: str | os.PathLike,
    *,
    figure_format: str,
    coolant_sensors: list,
    gates: dict,
    deploy: dict | None = None,
) -> list[str]:
    """Draw the figures of one group into ``out_dir`` (files + ``index.csv``).

    Parameters
    ----------
    paths : dict
        Input name -> path; every name of ``FIGURE_GROUPS[group]`` is needed.
    group : {"pipeline", "comparison", "replay"}
    out_dir : path
        The group's folder (created).
    figure_format : {"png", "svg"}
        ``report.figure_format`` of the machine.
    coolant_sensors : list of str
        ``report.coolant_sensors`` of the machine (drawn beside the key sensors; pipeline).
    gates : dict
        ``qualification`` of the machine (the gate lines; comparison).
    deploy : dict, optional
        ``deploy`` of the machine; ``clamp_um`` is drawn (replay).

    Returns
    -------
    list of str
        The keys of the figures drawn.
    """
    if group not in FIGURE_GROUPS:
        raise ValueError(f"unknown figure group {group!r}; expected one of {', '.join(FIGURE_GROUPS)}")
    if figure_format not in ("png", "svg"):
        raise ValueError(f"figure format {figure_format!r}; expected png or svg")
    missing = [k for k in FIGURE_GROUPS[group] if k not in paths]
    if missing:  # an absent input would change the figures silently
        raise ValueError(f"figure group {group!r}: no path for {', '.join(missing)}")
    res = load_results({k: paths[k] for k in FIGURE_GROUPS[group]})
    if group == "pipeline":
        drawn = _pipeline(res, list(coolant_sensors), figure_format)
    elif group == "replay":
        drawn = _replay(res, dict(deploy or {}), figure_format)
    else:
        drawn = itertools.chain(_comparison(res, dict(gates), figure_format), _deployed(res, figure_format))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for n, (key, data) in enumerate(drawn):
        name = _file_name(n, key, figure_format)
        write_bytes_atomic(out_dir / name, data)
        rows.append({"key": key, "file": name})
    write_csv_atomic(pd.DataFrame(rows, columns=["key", "file"]), out_dir / INDEX)
    return [r["key"] for r in rows]
