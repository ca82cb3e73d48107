"""All figures of the qualification report, one function per figure.

Every ``fig_*`` function takes plain tables/arrays, draws one figure with labelled axes and
units, and returns the bytes of a PNG or SVG file (:func:`rafi.report.plot_layout.render`).
They are called by rule ``report_figures`` (:mod:`rafi.report.figures`), never by the report
job, which embeds the files.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.colors import to_hex

from rafi.report.intervals import band_label, has_band, residual_band
from rafi.report.plot_layout import (
    BOTTOM_IN,
    C_MEAS,
    C_PRED,
    C_RES,
    C_SPEED,
    EDGE_IN,
    PAGE_WIDTH_IN,
    ROW_GAP_IN,
    SHARED_GAP_IN,
    STYLE,
    TOP_LEGEND_IN,
    TOP_TITLE_IN,
    adjust,
    envelope,
    fit_titles,
    hours,
    legend_top,
    panel_grid,
    plot_band,
    plot_series,
    render,
    speed_label,
    split_shared,
    text_colour,
    y_room_in,
)
from rafi.settings import truthy

# --------------------------------------------------------------------------- section 3


def fig_training_runs(
    runs: dict,
    *,
    temp_sensors: list[str],
    eq_times: dict | None = None,
    n_key: int = 3,
    fmt: str = "png",
) -> bytes:
    """Temperatures and displacement against time, one panel per training speed (paper Fig. 9).

    Parameters
    ----------
    runs : dict
        ``speed_rpm -> DataFrame`` with ``t_s``, the sensors in ``temp_sensors`` (deg C) and
        ``dz_um``.
    temp_sensors : list of str
        Sensors to draw: the ``n_key`` key sensors first (solid), then the coolant sensors
        (``report.coolant_sensors``; dashed, "coolant" in the legend).
    eq_times : dict, optional
        ``speed_rpm -> t_eq_s`` marked with a vertical line.
    """
    with plt.rc_context(STYLE):
        speeds = sorted(runs)
        nrows, ncols, size = panel_grid(len(speeds), 2, 2.0)
        fig, axes = plt.subplots(nrows, ncols, figsize=size, squeeze=False)
        colours = plt.get_cmap("tab10")
        handles = {}
        twins = []
        for ax, speed in zip(axes.flat, speeds):
            f = runs[speed]
            h = hours(f["t_s"])
            for i, s in enumerate(temp_sensors):
                if s in f:
                    (ln,) = plot_series(ax, h, f[s], color=colours(i), ls="-" if i < n_key else "--", lw=0.9)
                    handles.setdefault(f"{s} (°C{')' if i < n_key else ', coolant)'}", ln)
            ax.set_title(speed_label(speed))
            ax.set_xlabel("time (h)")
            ax.set_ylabel("temperature (°C)")
            ax2 = ax.twinx()
            twins.append(ax2)
            ax2.grid(False)
            ax2.spines["right"].set_visible(True)
            (ln,) = plot_series(ax2, h, f["dz_um"], color="black", lw=1.2)
            handles.setdefault("dz (µm, right axis)", ln)
            ax2.set_ylabel("displacement dz (µm)")
            if eq_times and np.isfinite(eq_times.get(speed, np.nan)):
                ln = ax.axvline(eq_times[speed] / 3600.0, color="grey", ls=":", lw=1.0)
                handles.setdefault("equilibrium t_eq", ln)
        for ax in list(axes.flat)[len(speeds) :]:
            ax.set_visible(False)
        used = list(axes.flat)[: len(speeds)]
        left = right = 0.0
        for _ in range(2):  # the panels' final size changes their ticks: measure again once
            left = max(left, *(y_room_in(ax) for ax in used))
            right = max(right, *(y_room_in(ax2, ax2.yaxis) for ax2 in twins))
            adjust(
                fig,
                left=left,
                right=right,
                top=TOP_LEGEND_IN,
                bottom=BOTTOM_IN,
                ncols=ncols,
                nrows=nrows,
                wgap=left + right + 0.05,
                hgap=ROW_GAP_IN,
            )
        legend_top(fig, list(handles.values()), list(handles.keys()), min(len(handles), 6))
        return render(fig, fmt)


# --------------------------------------------------------------------------- section 4


#: The |r| heatmap: height of a row (in) with the scopes as rows and with the sensors as rows,
#: the type of its values (pt), the room a value or a tick label keeps from the next one (pt) and
#: the tallest the figure grows (in: a page of the report with its caption).
HEATMAP_SCOPE_ROW_IN = 0.3
HEATMAP_SENSOR_ROW_IN = 0.14
HEATMAP_VALUE_PT = 5.5
HEATMAP_CLEAR_PT = 1.5
HEATMAP_MAX_HEIGHT_IN = 9.0


def fig_correlation_heatmap(
    abs_r: pd.DataFrame, *, threshold: float, chosen: list[str], fmt: str = "png"
) -> bytes:
    """Heatmap of |r|: a cell per scope (training speed, pooled) and sensor, its value in it.

    The sensors are the columns while a column holds a cell's value, else the rows (a row per
    sensor, the figure as tall as they need, at most :data:`HEATMAP_MAX_HEIGHT_IN`): from 4 to 40
    sensors every value is written. Sensor names side by side that would run together stand
    upright; a value is written only where every cell holds one (:func:`_heatmap`).

    Parameters
    ----------
    abs_r : DataFrame
        |r| with a row per scope and a column per sensor.
    threshold : float
        The key-sensor threshold: bold values at or above it, a red line on the colour bar.
    chosen : list of str
        The chosen key sensors, named in bold.
    """
    with plt.rc_context({**STYLE, "axes.grid": False}):
        fig, written = _heatmap(abs_r, threshold=threshold, chosen=chosen, sensors_as_rows=False)
        if not written:
            plt.close(fig)
            fig, _ = _heatmap(abs_r.T, threshold=threshold, chosen=chosen, sensors_as_rows=True)
        return render(fig, fmt)


def _heatmap(table: pd.DataFrame, *, threshold: float, chosen: list[str], sensors_as_rows: bool):
    """The |r| heatmap of ``table`` (its rows drawn as rows) and whether its values are written.

    Drawn twice: once to measure the laid-out cells and tick labels (matplotlib's own extents),
    then with the x tick labels upright where side by side they would be closer than
    :data:`HEATMAP_CLEAR_PT`, the figure taller by what they need, and the values written where
    the widest of them (bold ``.999``) fits every cell with that room on each side.
    """
    nrow, ncol = table.shape
    if sensors_as_rows:
        row_in = min(HEATMAP_SENSOR_ROW_IN, (HEATMAP_MAX_HEIGHT_IN - 0.9) / max(nrow, 1))
        # a row holds its tick label: smaller type where the rows are thinner than the default
        ytick_pt = min(STYLE["ytick.labelsize"], 72.0 * row_in / 1.4)
    else:
        row_in, ytick_pt = HEATMAP_SCOPE_ROW_IN, STYLE["ytick.labelsize"]
    height = 0.75 + row_in * nrow + (0.15 if sensors_as_rows else 0.0)
    fig, ax = plt.subplots(figsize=(PAGE_WIDTH_IN, height), constrained_layout=True)
    vals = table.to_numpy(dtype=float)
    lo = float(np.nanmin(vals)) if np.isfinite(vals).any() else 0.0
    im = ax.imshow(vals, aspect="auto", cmap="viridis", vmin=min(lo, threshold - 0.05), vmax=1.0)
    ax.set_xticks(range(ncol), table.columns)
    ax.set_yticks(range(nrow), table.index)
    ax.tick_params(axis="y", labelsize=ytick_pt)
    sensors = "sensor (chosen key sensors in bold)"
    scopes = "scope (training speed, r/min)"
    ax.set_xlabel(scopes if sensors_as_rows else sensors)
    ax.set_ylabel(sensors if sensors_as_rows else scopes)
    for lab in ax.get_yticklabels() if sensors_as_rows else ax.get_xticklabels():
        if lab.get_text() in chosen:
            lab.set_fontweight("bold")
    cb = fig.colorbar(im, ax=ax, pad=0.01, fraction=0.03)
    cb.set_label("|r| (-)")
    cb.ax.axhline(threshold, color="red", lw=1)

    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    pt = 72.0 / fig.dpi
    widths = [lab.get_window_extent(renderer).width * pt for lab in ax.get_xticklabels()]
    if widths and max(widths) + HEATMAP_CLEAR_PT > ax.bbox.width * pt / ncol:
        before = max(lab.get_window_extent(renderer).height for lab in ax.get_xticklabels()) / fig.dpi
        ax.tick_params(axis="x", labelrotation=90)
        fig.canvas.draw()
        after = max(lab.get_window_extent(renderer).height for lab in ax.get_xticklabels()) / fig.dpi
        fig.set_size_inches(PAGE_WIDTH_IN, min(height + after - before, HEATMAP_MAX_HEIGHT_IN))
        fig.canvas.draw()

    cell_w, cell_h = ax.bbox.width * pt / ncol, ax.bbox.height * pt / nrow
    probe = ax.text(0, 0, ".999", fontsize=HEATMAP_VALUE_PT, fontweight="bold")
    box = probe.get_window_extent(renderer)
    probe.remove()
    written = box.width * pt + 2 * HEATMAP_CLEAR_PT <= cell_w and box.height * pt + HEATMAP_CLEAR_PT <= cell_h
    if written:
        for i in range(nrow):
            for j in range(ncol):
                v = vals[i, j]
                if np.isfinite(v):
                    ax.text(
                        j,
                        i,
                        f"{v:.3f}"[1:] if v < 1 else "1.00",
                        ha="center",
                        va="center",
                        fontsize=HEATMAP_VALUE_PT,
                        color=text_colour(im.cmap(im.norm(v))),
                        fontweight="bold" if v >= threshold else "normal",
                    )
    return fig, written


def fig_matrix(matrix: pd.DataFrame, *, label: str = "Pearson r (-)", fmt: str = "png") -> bytes:
    """A square correlation matrix (used when it is too wide for a table)."""
    with plt.rc_context({**STYLE, "axes.grid": False}):
        n = len(matrix)
        side = min(PAGE_WIDTH_IN, 1.2 + 0.35 * n)
        fig, ax = plt.subplots(figsize=(side, side * 0.85), constrained_layout=True)
        im = ax.imshow(matrix.to_numpy(float), cmap="RdBu_r", vmin=-1, vmax=1)
        ax.set_xticks(range(n), matrix.columns, rotation=90)
        ax.set_yticks(range(n), matrix.index)
        fig.colorbar(im, ax=ax, label=label)
        return render(fig, fmt)


# --------------------------------------------------------------------------- section 5


def fig_fit_residuals(fits: dict, *, fmt: str = "png") -> bytes:
    """Measured and fitted dz (top) and residual (bottom) per training speed.

    ``fits``: ``speed_rpm -> DataFrame`` with ``t_s``, ``measured_um``, ``fitted_um``.
    """
    with plt.rc_context(STYLE):
        speeds = sorted(fits)
        ncols = min(3, len(speeds))
        nblocks = int(np.ceil(len(speeds) / ncols))
        fig = plt.figure(figsize=(PAGE_WIDTH_IN, 2.6 * nblocks))
        outer = fig.add_gridspec(nblocks, ncols)
        left_axes = []
        for k, speed in enumerate(speeds):
            r, c = divmod(k, ncols)
            f = fits[speed]
            h = hours(f["t_s"])
            inner = outer[r, c].subgridspec(2, 1, height_ratios=[2, 1], hspace=0.0)
            ax = fig.add_subplot(inner[0])
            plot_series(ax, h, f["measured_um"], ".", ms=1.5, color=C_MEAS, label="measured")
            plot_series(ax, h, f["fitted_um"], color=C_PRED, lw=1.0, label="model")
            ax.set_title(speed_label(speed))
            ax.set_ylabel("dz (µm)")
            ax.tick_params(labelbottom=False)
            axr = fig.add_subplot(inner[1], sharex=ax)
            left_axes += [ax, axr]
            res = np.asarray(f["measured_um"], float) - np.asarray(f["fitted_um"], float)
            plot_series(axr, h, res, color=C_RES, lw=0.7)
            axr.axhline(0, color="black", lw=0.5)
            axr.set_ylabel("residual (µm)")
            axr.set_xlabel("time (h)")
        room = max((y_room_in(a) for a in left_axes), default=0.5)
        adjust(
            fig,
            left=room,
            right=EDGE_IN,
            top=TOP_LEGEND_IN,
            bottom=BOTTOM_IN,
            ncols=ncols,
            nrows=nblocks,
            wgap=room + 0.05,
            hgap=ROW_GAP_IN,
        )
        split_shared(fig, outer, nblocks, ncols, SHARED_GAP_IN)
        legend_top(fig, *left_axes[0].get_legend_handles_labels(), 2)  # outside the axes
        return render(fig, fmt)


# --------------------------------------------------------------------------- section 6


def fig_membership(
    speed_grid,
    weights,
    centres,
    *,
    example_rpm: float | None = None,
    example_weights: dict | None = None,
    fmt: str = "png",
) -> bytes:
    """Triangular membership functions of the training speeds."""
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(figsize=(PAGE_WIDTH_IN, 2.3), constrained_layout=True)
        cmap = plt.get_cmap("tab10")
        x = np.asarray(speed_grid, float)
        for k, c in enumerate(centres):
            ax.plot(x, weights[:, k], color=cmap(k % 10), label=speed_label(c))
        if example_rpm is not None:
            ax.axvline(example_rpm, color="black", ls="--", lw=0.8)
            for c, w in (example_weights or {}).items():
                ax.plot([example_rpm], [w], "o", color="black", ms=3)
                ax.annotate(
                    f"{w:.3f} on {speed_label(c)}",
                    (example_rpm, w),
                    xytext=(6, 2),
                    textcoords="offset points",
                    fontsize=6.5,
                )
        ax.set_xlabel("spindle speed (r/min)")
        ax.set_ylabel("membership weight (-)")
        ax.set_ylim(-0.03, 1.08)
        ax.legend(ncol=min(len(centres), 6), loc="upper center", bbox_to_anchor=(0.5, 1.22), frameon=False)
        return render(fig, fmt)


# --------------------------------------------------------------------------- section 7


def fig_validation_single(runs: dict, *, level: float | None = None, fmt: str = "png") -> bytes:
    """Before (measured dz) and after (residual) compensation per validation run (paper Fig. 12).

    ``runs``: ``label -> DataFrame`` with ``t_s``, ``measured_um``, ``residual_um``; with
    ``lower_um``, ``upper_um`` and ``predicted_um`` the prediction interval on the residual's
    scale is a band around zero (:func:`rafi.report.intervals.residual_band`), named by its
    ``level`` in the legend.
    """
    with plt.rc_context(STYLE):
        labels = list(runs)
        nrows, ncols, size_in = panel_grid(len(labels), 3, 2.0)
        fig, axes = plt.subplots(nrows, ncols, figsize=size_in, squeeze=False)
        for ax, lab in zip(axes.flat, labels):
            f = runs[lab]
            h = hours(f["t_s"])
            if has_band(f):
                plot_band(ax, h, *residual_band(f), label=band_label(level))
            plot_series(ax, h, f["measured_um"], color=C_MEAS, label="before (measured dz)")
            plot_series(ax, h, f["residual_um"], color=C_RES, label="after (residual)")
            ax.axhline(0, color="black", lw=0.5)
            ax.set_xlabel("time (h)")
            ax.set_ylabel("displacement (µm)")
        for ax in list(axes.flat)[len(labels) :]:
            ax.set_visible(False)
        used = list(axes.flat)[: len(labels)]
        room = max((y_room_in(ax) for ax in used), default=0.5)
        # titles as wide as their panel at most (long run ids: two lines, then a smaller font)
        panel_w = (PAGE_WIDTH_IN - room - EDGE_IN - (ncols - 1) * (room + 0.05)) / ncols
        titles, size, lines = fit_titles(fig, labels, panel_w)
        extra = (lines - 1) * 1.25 * size / 72.0
        fig.set_size_inches(PAGE_WIDTH_IN, size_in[1] + nrows * extra)
        for ax, title in zip(axes.flat, titles):
            ax.set_title(title, fontsize=size)
        adjust(
            fig,
            left=room,
            right=EDGE_IN,
            top=(TOP_LEGEND_IN if labels else TOP_TITLE_IN) + extra,
            bottom=BOTTOM_IN,
            ncols=ncols,
            nrows=nrows,
            wgap=room + 0.05,
            hgap=ROW_GAP_IN + extra,
        )
        if labels:
            legend = {}  # a band only some runs have
            for ax in used:
                for hh, ll in zip(*ax.get_legend_handles_labels()):
                    legend.setdefault(ll, hh)
            legend_top(fig, list(legend.values()), list(legend), len(legend))
        return render(fig, fmt)


def fig_multi_condition(
    f: pd.DataFrame,
    *,
    temp_sensors: list[str],
    title: str = "",
    n_key: int = 3,
    level: float | None = None,
    fmt: str = "png",
) -> bytes:
    """Multi-condition run (paper Figs 13-14): speed, temperatures, measured vs predicted, residual.

    ``f`` has ``t_s``, ``speed_rpm``, ``measured_um``, ``predicted_um``, ``residual_um`` and the
    temperature columns (deg C) in ``temp_sensors`` when available; with ``lower_um`` and
    ``upper_um`` the prediction interval is a band around the prediction, named by its ``level``.
    """
    with plt.rc_context(STYLE):
        temps = [s for s in temp_sensors if s in f]
        n = 3 if temps else 2
        fig, axes = plt.subplots(
            n,
            1,
            figsize=(PAGE_WIDTH_IN, 1.45 * n + 0.9),
            sharex=True,
            gridspec_kw={"height_ratios": [1, 1.3, 1.6] if n == 3 else [1, 1.6]},
        )
        h = hours(f["t_s"])
        ax = axes[0]
        hs, sp = envelope(h, f["speed_rpm"])
        ax.step(hs, sp, where="post", color=C_SPEED)
        ax.set_ylabel("speed (r/min)")
        if title:
            ax.set_title(title)
        if temps:
            ax = axes[1]
            cmap = plt.get_cmap("tab10")
            for i, s in enumerate(temps):
                lab = s if i < n_key else f"{s} (coolant)"
                # colours apart from measured (blue), predicted (orange), residual (red): one legend
                plot_series(ax, h, f[s], color=cmap((i + 4) % 10), ls="-" if i < n_key else "--", label=lab)
            ax.set_ylabel("temperature (°C)")
        ax = axes[-1]
        if has_band(f):
            plot_band(ax, h, f["lower_um"], f["upper_um"], label=band_label(level))
        plot_series(ax, h, f["measured_um"], color=C_MEAS, label="measured dz (before)")
        plot_series(ax, h, f["predicted_um"], color=C_PRED, label="predicted")
        plot_series(ax, h, f["residual_um"], color=C_RES, label="residual (after)")
        ax.axhline(0, color="black", lw=0.5)
        ax.set_ylabel("displacement (µm)")
        ax.set_xlabel("time (h)")
        handles = [h for a in axes for h in a.get_legend_handles_labels()[0]]
        labels = [lab for a in axes for lab in a.get_legend_handles_labels()[1]]
        adjust(
            fig,
            left=max(y_room_in(a) for a in axes),
            right=EDGE_IN,
            top=TOP_LEGEND_IN if title else TOP_LEGEND_IN - TOP_TITLE_IN + 0.03,
            bottom=BOTTOM_IN,
            nrows=n,
            hgap=SHARED_GAP_IN,
        )
        legend_top(fig, handles, labels, len(handles))  # outside the axes, over no curve
        return render(fig, fmt)


# --------------------------------------------------------------------------- model comparison

#: One colour per model the comparison can score, the same in every figure: its kinds
#: (rafi.family.compare.KINDS), the CV-weighted ensemble and a prior's adaptation candidates
#: (rafi.family.adapted), no two alike.
MODEL_COLOURS = {
    "rafi": "#c0392b",
    "rafi_linear": "#e07b00",
    "ridge_global": "#1f77b4",
    "dynamic": "#2e7d32",
    "grey_box": "#bcbd22",
    "temperature_ridge": "#6a3d9a",
    "ensemble": "#17becf",
    "prior": "#8c564b",
    "prior_gain": "#c49c94",
    "prior_time": "#e377c2",
    "prior_ridge": "#f7b6d2",
    "prior_shared_gain": "#7f7f7f",
    "prior_shared_ridge": "#6b6ecf",
}
#: The colours a model without one of its own takes, in turn (tab20b, then tab20).
SPARE_COLOURS = tuple(to_hex(c) for name in ("tab20b", "tab20") for c in plt.get_cmap(name).colors)
#: Width (pt) of the black outline of the offered model's bars.
OFFERED_EDGE_PT = 1.4


def model_colours(models) -> dict:
    """The colour of each model of a figure: its own (:data:`MODEL_COLOURS`), else the first of
    :data:`SPARE_COLOURS` no other model of the figure has.

    Parameters
    ----------
    models : iterable of str
        The figure's models.

    Returns
    -------
    dict
        model -> colour (hex); distinct while the figure has at most as many models without a
        colour of their own as there are spare colours (40), then the spares repeat.
    """
    models = list(models)
    out = {m: MODEL_COLOURS[m] for m in models if m in MODEL_COLOURS}
    spare = [c for c in SPARE_COLOURS if c not in set(out.values())] or list(SPARE_COLOURS)
    for k, m in enumerate(m for m in models if m not in out):
        out[m] = spare[k % len(spare)]
    return out


def fig_comparison_bars(
    after: pd.DataFrame,
    before: pd.Series,
    *,
    failed: pd.DataFrame | None = None,
    gate_um: float | None = None,
    labels: dict | None = None,
    offered: str | None = None,
    fmt: str = "png",
) -> bytes:
    """Grouped bars: max |residual| per validation run (groups) and model (bars).

    Parameters
    ----------
    after : DataFrame
        index = run ids (plot order), columns = models, values = max |residual| (um).
    before : Series
        index = run ids: uncompensated max |dz| (um), drawn as a black tick over each group.
    failed : DataFrame of bool, optional
        Same shape as ``after``: True where that model fails a gate on that run (hatched bar).
    gate_um : float, optional
        The ``max_residual_um`` gate (dashed red line).
    labels : dict, optional
        model -> legend label (e.g. marking the champion).
    offered : str, optional
        The model offered to the machine: its bars (and its legend entry) outlined in black
        (:data:`OFFERED_EDGE_PT`). Each model has its colour (:func:`model_colours`).
    """
    with plt.rc_context(STYLE):
        runs, models = list(after.index), list(after.columns)
        colours = model_colours(models)
        n, m = len(runs), max(len(models), 1)
        fig, ax = plt.subplots(figsize=(PAGE_WIDTH_IN, 2.9), constrained_layout=True)
        x = np.arange(n, dtype=float)
        width = 0.8 / m
        b = before.reindex(runs).to_numpy(float)
        # a run-away model (e.g. 200 um) must not flatten the others: clip the axis just above
        # the uncompensated values and write the clipped bars' values on top
        allv = after.to_numpy(float)
        ref = np.nanmax(np.concatenate([b[np.isfinite(b)], [gate_um or 0.0, 1e-9]]))
        top = 1.25 * ref
        clip = np.isfinite(allv).any() and np.nanmax(allv) > top
        for k, name in enumerate(models):
            pos = x - 0.4 + width * (k + 0.5)
            vals = after[name].to_numpy(float)
            if clip:
                for xi, v in zip(pos, vals):
                    if np.isfinite(v) and v > top:
                        ax.text(
                            xi,
                            0.97 * top,
                            f"{v:.0f} \u2191",
                            rotation=90,
                            ha="center",
                            va="top",
                            fontsize=6,
                            color="white",
                            fontweight="bold",
                        )
                vals = np.minimum(vals, top)
            bad = failed[name].to_numpy(bool) if failed is not None and name in failed else np.zeros(n, bool)
            outline = (
                {"edgecolor": "black", "linewidth": OFFERED_EDGE_PT} if name == offered else {"linewidth": 0}
            )
            ax.bar(
                pos,
                np.nan_to_num(vals),
                width * 0.92,
                color=colours[name],
                label=(labels or {}).get(name, name),
                **outline,
            )
            if bad.any():
                ax.bar(
                    pos[bad],
                    np.nan_to_num(vals[bad]),
                    width * 0.92,
                    facecolor="none",
                    edgecolor="black",
                    hatch="////",
                    lw=0.6,
                )
        ax.hlines(b, x - 0.45, x + 0.45, color="black", lw=1.6, label="uncompensated max |dz|")
        if gate_um is not None and np.isfinite(gate_um):
            ax.axhline(gate_um, color=C_RES, ls="--", lw=0.9, label=f"gate: max residual {gate_um:g} µm")
        if failed is not None and failed.to_numpy(bool).any():
            ax.bar(
                [np.nan],
                [0],
                color="white",
                edgecolor="black",
                hatch="////",
                lw=0.6,
                label="fails a gate on this run",
            )
        ax.set_xticks(x, runs, rotation=20 if n > 4 else 0, ha="right" if n > 4 else "center")
        ax.set_xlim(-0.6, n - 0.4)
        if clip:
            ax.set_ylim(0, top)
        ax.set_xlabel(
            "validation run" + (" (bars above the axis clipped, value written on top, µm)" if clip else "")
        )
        ax.set_ylabel("max |residual| after compensation (µm)")
        h, lab = ax.get_legend_handles_labels()
        fig.legend(h, lab, ncol=min(m + 2, 4), loc="outside upper center", frameon=False)
        return render(fig, fmt)


def fig_since_change(table: pd.DataFrame, *, fmt: str = "png") -> bytes:
    """The training runs in recorded order, as the whole-run CV that found a change saw them.

    Parameters
    ----------
    table : DataFrame
        ``comparison/since_change.csv`` (:func:`rafi.family.since_change.change_table`): per run
        ``order``, ``none_max_um`` (no compensation, black), ``best_max_um`` (the best model
        fitted on the other runs), ``unexplained`` (ringed red: no model beats no compensation),
        ``set_aside`` (shaded) and ``change_run`` (dashed line before it).
    """
    with plt.rc_context(STYLE):
        t = table.sort_values("order")
        x = t["order"].to_numpy(float)
        none = pd.to_numeric(t["none_max_um"], errors="coerce").to_numpy(float)
        best = pd.to_numeric(t["best_max_um"], errors="coerce").to_numpy(float)
        named = t["unexplained"].map(truthy).to_numpy(bool)
        aside = t["set_aside"].map(truthy).to_numpy(bool)
        fig, ax = plt.subplots(figsize=(PAGE_WIDTH_IN, 2.6), constrained_layout=True)
        if aside.any():
            ax.axvspan(x[aside].min() - 0.5, x[aside].max() + 0.5, color="0.88", lw=0, label="set aside")
            change = f"change ({t['change_run'].iloc[0]})"
            ax.axvline(x[aside].max() + 0.5, color="black", ls="--", lw=0.9, label=change)
        ax.plot(x, none, "s", color="black", ms=3.5, label="no compensation: max |dz|")
        ax.plot(x, best, "o", color=C_PRED, ms=4, label="best model held out: max |residual|")
        if named.any():
            ax.plot(
                x[named], best[named], "o", mfc="none", mec=C_RES, ms=8, mew=1.2, label="no model explains it"
            )
        ax.set_xlim(x.min() - 0.6, x.max() + 0.6)
        ax.set_ylim(bottom=0)
        ax.set_xlabel("training run, in recorded order")
        ax.set_ylabel("max |value| (µm)")
        h, lab = ax.get_legend_handles_labels()
        fig.legend(h, lab, ncol=3, loc="outside upper center", frameon=False)
        return render(fig, fmt)


def fig_comparison_residuals(
    series: dict,
    *,
    measured=None,
    outside=None,
    gate_um=None,
    title: str = "",
    level: float | None = None,
    colours: dict | None = None,
    fmt: str = "png",
) -> bytes:
    """Residual against time of several models on one run (RAFI vs the champion).

    ``series``: label -> DataFrame with ``t_s`` and ``residual_um`` (first = RAFI, drawn red);
    ``colours``: label -> colour, each model in its colour of the comparison's bar chart
    (:func:`model_colours`); a label without one takes red first, then blue, green, orange;
    a frame with ``lower_um``, ``upper_um`` and ``predicted_um`` gets its model's interval on
    the residual's scale as a band around zero in its colour, named by the ``level``.
    ``measured``: DataFrame ``t_s``, ``measured_um`` (uncompensated dz, thin grey).
    ``outside``: DataFrame ``t_s``, ``outside`` (bool): shaded where RAFI was evaluated
    outside its trained temperature range.
    """
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(figsize=(PAGE_WIDTH_IN, 2.5), constrained_layout=True)
        if measured is not None and len(measured):
            plot_series(
                ax,
                hours(measured["t_s"]),
                measured["measured_um"],
                color="#9aa0a6",
                lw=0.8,
                label="uncompensated dz",
            )
        for k, (lab, f) in enumerate(series.items()):
            colour = (colours or {}).get(lab) or (
                C_RES if k == 0 else ("#1f77b4", "#2e7d32", "#e07b00")[(k - 1) % 3]
            )
            if has_band(f):
                lo, hi = residual_band(f)
                name = f"{band_label(level)} {lab}"
                hatch = ("////", "\\\\\\\\", "||||")[k % 3]
                plot_band(ax, hours(f["t_s"]), lo, hi, color=colour, alpha=0.45, hatch=hatch, label=name)
            plot_series(ax, hours(f["t_s"]), f["residual_um"], color=colour, lw=1.0, label=f"residual {lab}")
        if outside is not None and len(outside) and bool(np.any(outside["outside"])):
            h = hours(outside["t_s"])
            xe, ye = envelope(h, np.asarray(outside["outside"], float))
            ax.fill_between(
                xe,
                0,
                1,
                where=ye > 0.5,
                step="post",
                color="#f2b8b5",
                alpha=0.35,
                lw=0,
                transform=ax.get_xaxis_transform(),
                label="RAFI outside trained temperature range",
            )
        if gate_um is not None and np.isfinite(gate_um):
            ax.axhline(gate_um, color=C_RES, ls="--", lw=0.7)
            ax.axhline(-gate_um, color=C_RES, ls="--", lw=0.7, label=f"±{gate_um:g} µm gate")
        ax.axhline(0, color="black", lw=0.5)
        ylabel = "displacement (µm)"
        if measured is not None and len(measured):
            ref = max(float(np.nanmax(np.abs(measured["measured_um"]))), gate_um or 0.0)
            peak = max(float(np.nanmax(np.abs(f["residual_um"]))) for f in series.values())
            if np.isfinite(ref) and peak > 1.5 * ref:
                ax.set_ylim(-1.5 * ref, 1.5 * ref)
                ylabel = f"displacement (µm; clipped at ±{1.5 * ref:.0f})"
        if title:
            ax.set_title(title)
        ax.set_xlabel("time since run start (h)")
        ax.set_ylabel(ylabel)
        h, lab = ax.get_legend_handles_labels()
        fig.legend(h, lab, ncol=3, loc="outside upper center", frameon=False)
        return render(fig, fmt)
