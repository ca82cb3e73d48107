"""All figures of the qualification report (the only module that imports matplotlib).

Every ``fig_*`` function takes plain tables/arrays, draws one figure with labelled
axes and units, and returns an *embeddable* figure: a dict ``{"kind": "png", "src":
"data:image/png;base64,..."}`` or ``{"kind": "svg", "svg": "<svg ...>"}`` so the
HTML report needs no external files and WeasyPrint renders the same bytes.
Backend is Agg (no display); figures are closed after encoding.
"""

from __future__ import annotations

import base64
import io
import re

import matplotlib

matplotlib.use("Agg", force=True)

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

#: Figure width that fills the A4 content box (180 mm) at 100 % image width.
PAGE_WIDTH_IN = 7.0

STYLE = {
    "font.family": "DejaVu Sans",
    "font.size": 7.5,
    "axes.titlesize": 8,
    "axes.labelsize": 7.5,
    "legend.fontsize": 6.5,
    "xtick.labelsize": 6.5,
    "ytick.labelsize": 6.5,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "grid.linewidth": 0.5,
    "lines.linewidth": 1.0,
    "axes.spines.top": False,
    "axes.spines.right": False,
    "svg.hashsalt": "rafi-report",
    "svg.fonttype": "path",
}

#: Colours: measured / before = grey-blue, model / after = orange, residual = red.
C_MEAS, C_PRED, C_RES, C_SPEED = "#4a6fa5", "#e07b00", "#c0392b", "#2e7d32"


def encode(fig, fmt: str = "png", dpi: int = 140) -> dict:
    """Encode a figure for inline embedding and close it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    fmt : {"png", "svg"}
    dpi : int
        Resolution of PNG output (ignored for SVG).
    """
    buf = io.BytesIO()
    try:
        if fmt == "svg":
            fig.savefig(buf, format="svg", metadata={"Date": None})
            text = buf.getvalue().decode("utf-8")
            text = text[text.index("<svg"):]
            text = re.sub(r'<svg([^>]*?) width="[^"]*" height="[^"]*"', r'<svg\1', text, count=1)
            return {"kind": "svg", "svg": text}
        fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None})
        data = base64.b64encode(buf.getvalue()).decode("ascii")
        return {"kind": "png", "src": f"data:image/png;base64,{data}"}
    finally:
        plt.close(fig)


def _hours(t_s):
    return np.asarray(t_s, dtype=float) / 3600.0


def _grid(n: int, ncols: int = 3, row_h: float = 2.1, extra_rows: int = 1):
    ncols = max(1, min(ncols, n))
    nrows = max(1, int(np.ceil(n / ncols)))
    return nrows, ncols, (PAGE_WIDTH_IN, row_h * nrows * extra_rows)


def _speed_label(speed) -> str:
    return f"{float(speed):,.0f} r/min".replace(",", "\u00a0")


# --------------------------------------------------------------------------- section 3

def fig_training_runs(runs: dict, *, temp_sensors: list[str], eq_times: dict | None = None,
                      fmt: str = "png") -> dict:
    """Temperatures and displacement against time, one panel per training speed (paper Fig. 9).

    Parameters
    ----------
    runs : dict
        ``speed_rpm -> DataFrame`` with ``t_s``, the sensors in ``temp_sensors`` (deg C) and
        ``dz_um``.
    temp_sensors : list of str
        Sensors to draw (key sensors first, then coolant sensors, drawn dashed).
    eq_times : dict, optional
        ``speed_rpm -> t_eq_s`` marked with a vertical line.
    """
    with plt.rc_context(STYLE):
        speeds = sorted(runs)
        nrows, ncols, size = _grid(len(speeds), 2, 2.0)
        fig, axes = plt.subplots(nrows, ncols, figsize=size, squeeze=False, constrained_layout=True)
        colours = plt.get_cmap("tab10")
        handles = {}
        for ax, speed in zip(axes.flat, speeds):
            f = runs[speed]
            h = _hours(f["t_s"])
            for i, s in enumerate(temp_sensors):
                if s in f:
                    (ln,) = ax.plot(h, f[s], color=colours(i), ls="-" if i < 3 else "--", lw=0.9)
                    handles.setdefault(f"{s} (°C)", ln)
            ax.set_title(_speed_label(speed))
            ax.set_xlabel("time (h)")
            ax.set_ylabel("temperature (°C)")
            ax2 = ax.twinx()
            ax2.grid(False)
            ax2.spines["right"].set_visible(True)
            (ln,) = ax2.plot(h, f["dz_um"], color="black", lw=1.2)
            handles.setdefault("dz (µm, right axis)", ln)
            ax2.set_ylabel("displacement dz (µm)")
            if eq_times and np.isfinite(eq_times.get(speed, np.nan)):
                ln = ax.axvline(eq_times[speed] / 3600.0, color="grey", ls=":", lw=1.0)
                handles.setdefault("equilibrium t_eq", ln)
        for ax in list(axes.flat)[len(speeds):]:
            ax.set_visible(False)
        fig.legend(list(handles.values()), list(handles.keys()), loc="outside upper center",
                   ncol=min(len(handles), 6), frameon=False)
        return encode(fig, fmt)


# --------------------------------------------------------------------------- section 4

def fig_correlation_heatmap(abs_r: pd.DataFrame, *, threshold: float, chosen: list[str],
                            fmt: str = "png") -> dict:
    """Heatmap of |r| (rows = scopes: speeds and pooled, columns = sensors)."""
    with plt.rc_context({**STYLE, "axes.grid": False}):
        nrow, ncol = abs_r.shape
        fig, ax = plt.subplots(figsize=(PAGE_WIDTH_IN, 0.75 + 0.3 * nrow), constrained_layout=True)
        vals = abs_r.to_numpy(dtype=float)
        lo = float(np.nanmin(vals)) if np.isfinite(vals).any() else 0.0
        im = ax.imshow(vals, aspect="auto", cmap="viridis", vmin=min(lo, threshold - 0.05), vmax=1.0)
        ax.set_xticks(range(ncol), abs_r.columns)
        ax.set_yticks(range(nrow), abs_r.index)
        ax.set_xlabel("sensor (chosen key sensors in bold)")
        ax.set_ylabel("scope (training speed, r/min)")
        for lab in ax.get_xticklabels():
            if lab.get_text() in chosen:
                lab.set_fontweight("bold")
        for i in range(nrow):
            for j in range(ncol):
                v = vals[i, j]
                if np.isfinite(v):
                    ax.text(j, i, f"{v:.3f}"[1:] if v < 1 else "1.00", ha="center", va="center",
                            fontsize=5.5, color="white" if v < threshold else "black",
                            fontweight="bold" if v >= threshold else "normal")
        cb = fig.colorbar(im, ax=ax, pad=0.01, fraction=0.03)
        cb.set_label("|r| (-)")
        cb.ax.axhline(threshold, color="red", lw=1)
        return encode(fig, fmt)


def fig_matrix(matrix: pd.DataFrame, *, label: str = "Pearson r (-)", fmt: str = "png") -> dict:
    """A square correlation matrix (used when it is too wide for a table)."""
    with plt.rc_context({**STYLE, "axes.grid": False}):
        n = len(matrix)
        side = min(PAGE_WIDTH_IN, 1.2 + 0.35 * n)
        fig, ax = plt.subplots(figsize=(side, side * 0.85), constrained_layout=True)
        im = ax.imshow(matrix.to_numpy(float), cmap="RdBu_r", vmin=-1, vmax=1)
        ax.set_xticks(range(n), matrix.columns, rotation=90)
        ax.set_yticks(range(n), matrix.index)
        fig.colorbar(im, ax=ax, label=label)
        return encode(fig, fmt)


# --------------------------------------------------------------------------- section 5

def fig_fit_residuals(fits: dict, *, fmt: str = "png") -> dict:
    """Measured and fitted dz (top) and residual (bottom) per training speed.

    ``fits``: ``speed_rpm -> DataFrame`` with ``t_s``, ``measured_um``, ``fitted_um``.
    """
    with plt.rc_context(STYLE):
        speeds = sorted(fits)
        ncols = min(3, len(speeds))
        nblocks = int(np.ceil(len(speeds) / ncols))
        fig = plt.figure(figsize=(PAGE_WIDTH_IN, 2.6 * nblocks), constrained_layout=True)
        gs = fig.add_gridspec(2 * nblocks, ncols, height_ratios=[2, 1] * nblocks)
        for k, speed in enumerate(speeds):
            r, c = divmod(k, ncols)
            f = fits[speed]
            h = _hours(f["t_s"])
            ax = fig.add_subplot(gs[2 * r, c])
            ax.plot(h, f["measured_um"], ".", ms=1.5, color=C_MEAS, label="measured")
            ax.plot(h, f["fitted_um"], color=C_PRED, lw=1.0, label="model")
            ax.set_title(_speed_label(speed))
            ax.set_ylabel("dz (µm)")
            ax.tick_params(labelbottom=False)
            if k == 0:
                ax.legend(loc="lower right", frameon=False)
            axr = fig.add_subplot(gs[2 * r + 1, c], sharex=ax)
            res = np.asarray(f["measured_um"], float) - np.asarray(f["fitted_um"], float)
            axr.plot(h, res, color=C_RES, lw=0.7)
            axr.axhline(0, color="black", lw=0.5)
            axr.set_ylabel("residual (µm)")
            axr.set_xlabel("time (h)")
        return encode(fig, fmt)


# --------------------------------------------------------------------------- section 6

def fig_membership(speed_grid, weights, centres, *, example_rpm: float | None = None,
                   example_weights: dict | None = None, fmt: str = "png") -> dict:
    """Triangular membership functions of the training speeds."""
    with plt.rc_context(STYLE):
        fig, ax = plt.subplots(figsize=(PAGE_WIDTH_IN, 2.3), constrained_layout=True)
        cmap = plt.get_cmap("tab10")
        x = np.asarray(speed_grid, float)
        for k, c in enumerate(centres):
            ax.plot(x, weights[:, k], color=cmap(k % 10), label=_speed_label(c))
        if example_rpm is not None:
            ax.axvline(example_rpm, color="black", ls="--", lw=0.8)
            for c, w in (example_weights or {}).items():
                ax.plot([example_rpm], [w], "o", color="black", ms=3)
                ax.annotate(f"{w:.3f} on {_speed_label(c)}", (example_rpm, w), xytext=(6, 2),
                            textcoords="offset points", fontsize=6.5)
        ax.set_xlabel("spindle speed (r/min)")
        ax.set_ylabel("membership weight (-)")
        ax.set_ylim(-0.03, 1.08)
        ax.legend(ncol=min(len(centres), 6), loc="upper center", bbox_to_anchor=(0.5, 1.22),
                  frameon=False)
        return encode(fig, fmt)


# --------------------------------------------------------------------------- section 7

def fig_validation_single(runs: dict, *, fmt: str = "png") -> dict:
    """Before (measured dz) and after (residual) compensation per validation run (paper Fig. 12).

    ``runs``: ``label -> DataFrame`` with ``t_s``, ``measured_um``, ``residual_um``.
    """
    with plt.rc_context(STYLE):
        labels = list(runs)
        nrows, ncols, size = _grid(len(labels), 3, 2.0)
        fig, axes = plt.subplots(nrows, ncols, figsize=size, squeeze=False, constrained_layout=True)
        for ax, lab in zip(axes.flat, labels):
            f = runs[lab]
            h = _hours(f["t_s"])
            ax.plot(h, f["measured_um"], color=C_MEAS, label="before (measured dz)")
            ax.plot(h, f["residual_um"], color=C_RES, label="after (residual)")
            ax.axhline(0, color="black", lw=0.5)
            ax.set_title(lab)
            ax.set_xlabel("time (h)")
            ax.set_ylabel("displacement (µm)")
        for ax in list(axes.flat)[len(labels):]:
            ax.set_visible(False)
        if labels:
            h, lab = axes.flat[0].get_legend_handles_labels()
            fig.legend(h, lab, loc="outside upper center", ncol=2, frameon=False)
        return encode(fig, fmt)


def fig_multi_condition(f: pd.DataFrame, *, temp_sensors: list[str], title: str = "",
                        fmt: str = "png") -> dict:
    """Multi-condition run (paper Figs 13-14): speed, temperatures, measured vs predicted, residual.

    ``f`` has ``t_s``, ``speed_rpm``, ``measured_um``, ``predicted_um``, ``residual_um`` and the
    temperature columns (deg C) in ``temp_sensors`` when available.
    """
    with plt.rc_context(STYLE):
        temps = [s for s in temp_sensors if s in f]
        n = 3 if temps else 2
        fig, axes = plt.subplots(n, 1, figsize=(PAGE_WIDTH_IN, 1.45 * n + 0.9), sharex=True,
                                 constrained_layout=True,
                                 gridspec_kw={"height_ratios": [1, 1.3, 1.6] if n == 3 else [1, 1.6]})
        h = _hours(f["t_s"])
        ax = axes[0]
        ax.step(h, f["speed_rpm"], where="post", color=C_SPEED)
        ax.set_ylabel("speed (r/min)")
        if title:
            ax.set_title(title)
        if temps:
            ax = axes[1]
            cmap = plt.get_cmap("tab10")
            for i, s in enumerate(temps):
                ax.plot(h, f[s], color=cmap(i), ls="-" if i < 3 else "--", label=s)
            ax.set_ylabel("temperature (°C)")
            ax.legend(ncol=len(temps), loc="upper left", frameon=False)
        ax = axes[-1]
        ax.plot(h, f["measured_um"], color=C_MEAS, label="measured dz (before)")
        ax.plot(h, f["predicted_um"], color=C_PRED, label="predicted")
        ax.plot(h, f["residual_um"], color=C_RES, label="residual (after)")
        ax.axhline(0, color="black", lw=0.5)
        ax.set_ylabel("displacement (µm)")
        ax.set_xlabel("time (h)")
        ax.legend(ncol=3, loc="upper left", frameon=False)
        return encode(fig, fmt)
