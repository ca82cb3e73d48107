"""The residual figure of the model offered to the machine: one panel per validation run.

Called by rule ``report_figures`` (:mod:`rafi.report.figures`, group ``comparison``), never by
the report job. Each panel has two axes sharing time: the measured displacement change dz
(uncompensated) above, the residual after compensation below with the run's noise floor as a
band (the expected max |noise| of the run: a residual inside it is at the noise) and, where the
results hold one, the prediction interval on the residual's scale as a second band around zero
(:func:`rafi.report.intervals.residual_band`: a residual outside it is a sample outside the
interval).
"""

from __future__ import annotations

import re

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.backends.backend_agg import RendererAgg
from matplotlib.font_manager import FontProperties

from rafi.report.plot_layout import (
    BOTTOM_IN,
    C_MEAS,
    C_RES,
    EDGE_IN,
    PAGE_WIDTH_IN,
    STYLE,
    TOP_LEGEND_IN,
    adjust,
    hours,
    legend_top,
    plot_band,
    plot_series,
    render,
    split_shared,
    y_room_in,
)

#: Panels per row.
NCOLS = 2
#: Height of one panel (the two axes of one run), inches.
PANEL_H_IN = 2.05
#: Gap between the two axes of one panel, inches.
INNER_GAP_IN = 0.08
#: Room of a panel's title line, inches (the gap between rows holds the x labels and the title).
TITLE_LINE_IN = 0.16


_RENDERER: list = []


def _text_width_in(text: str, size_pt: float) -> float:
    """Width (inches) of ``text`` set in the figures' font at ``size_pt`` (Agg's text layout at
    72 dpi, the one the figures are drawn with)."""
    if not _RENDERER:
        _RENDERER.append(RendererAgg(1, 1, 72))
    prop = FontProperties(family=STYLE["font.family"], size=size_pt)
    return _RENDERER[0].get_text_width_height_descent(text, prop, ismath=False)[0] / 72.0


def _pieces(word: str, width_in: float, size: float) -> list[str]:
    """``word`` cut after ``_``, ``-``, ``#`` or ``/`` (else anywhere) into pieces no wider than
    ``width_in``: a run id longer than a panel is wide."""
    if _text_width_in(word, size) <= width_in:
        return [word]
    parts = re.findall(r"[^_#/-]*[_#/-]?", word)
    out = [""]
    for part in (p for p in parts if p):
        for piece in [part] if _text_width_in(part, size) <= width_in else list(part):
            if out[-1] and _text_width_in(out[-1] + piece, size) > width_in:
                out.append(piece)
            else:
                out[-1] += piece
    return out


def _wrap(title: str, width_in: float) -> str:
    """``title`` wrapped at spaces (a word wider than a line is cut, :func:`_pieces`) onto lines no
    wider than ``width_in`` at the axes title size, so a panel title never runs into the next panel."""
    size = float(STYLE["axes.titlesize"])
    lines: list[str] = []
    for word in title.split(" "):
        for k, piece in enumerate(_pieces(word, width_in, size)):
            if k == 0 and lines and _text_width_in(lines[-1] + " " + piece, size) <= width_in:
                lines[-1] += " " + piece
            else:
                lines.append(piece)
    return "\n".join(lines)


def fig_deployed_residuals(panels: list[dict], *, fmt: str = "png") -> bytes:
    """Measured dz and residual against time, one panel per run, noise floor as a band.

    Parameters
    ----------
    panels : list of dict
        Per run: ``title`` (str), ``frame`` (``t_s``, ``measured_um``, ``residual_um``),
        ``noise_floor`` (um; NaN: no band) and, optionally, ``band`` (``(lower, upper)`` on the
        residual's scale, um, or ``None``) with its legend entry ``band_label``.
    fmt : {"png", "svg"}

    Returns
    -------
    bytes
        The figure file.
    """
    with plt.rc_context(STYLE):
        return render(build_figure(panels), fmt)


def build_figure(panels: list[dict]):
    """The figure of :func:`fig_deployed_residuals` (call inside ``plt.rc_context(STYLE)``)."""
    n = len(panels)
    ncols = max(1, min(NCOLS, n))
    nrows = max(1, int(np.ceil(n / ncols)))
    panel_w = PAGE_WIDTH_IN / ncols - 0.75  # the panel's axes width, less the y labels
    titles = [_wrap(p["title"], panel_w) for p in panels]
    lines = max((t.count("\n") + 1 for t in titles), default=1)
    row_gap = 0.42 + lines * TITLE_LINE_IN
    top = TOP_LEGEND_IN + (lines - 1) * TITLE_LINE_IN
    height = top + BOTTOM_IN + nrows * PANEL_H_IN + (nrows - 1) * row_gap
    fig = plt.figure(figsize=(PAGE_WIDTH_IN, height))
    outer = fig.add_gridspec(nrows, ncols)
    pairs = []
    for k, p in enumerate(panels):
        sub = outer[k // ncols, k % ncols].subgridspec(2, 1, height_ratios=[1, 1.5])
        ax_m = fig.add_subplot(sub[0])
        ax_r = fig.add_subplot(sub[1], sharex=ax_m)
        f = p["frame"]
        h = hours(f["t_s"])
        plot_series(ax_m, h, f["measured_um"], color=C_MEAS, lw=0.9, label="measured dz (uncompensated)")
        ax_m.axhline(0, color="black", lw=0.4)
        ax_m.set_ylabel("dz (µm)")
        ax_m.tick_params(labelbottom=False)
        ax_m.set_title(titles[k], loc="left")
        nf = p.get("noise_floor")
        if nf is not None and np.isfinite(nf):
            ax_r.axhspan(-nf, nf, color="#b0bec5", alpha=0.45, lw=0, label="± noise floor of the run")
        if p.get("band") is not None:
            plot_band(ax_r, h, *p["band"], label=p.get("band_label") or "prediction interval")
        plot_series(ax_r, h, f["residual_um"], color=C_RES, lw=0.9, label="residual after compensation")
        ax_r.axhline(0, color="black", lw=0.4)
        ax_r.set_ylabel("residual (µm)")
        ax_r.set_xlabel("time since run start (h)")
        pairs.append((ax_m, ax_r))
    room = max((y_room_in(a) for pair in pairs for a in pair), default=0.5)
    adjust(
        fig,
        left=room,
        right=EDGE_IN,
        top=top,
        bottom=BOTTOM_IN,
        ncols=ncols,
        nrows=nrows,
        wgap=room + 0.12,
        hgap=row_gap,
    )
    split_shared(fig, outer, nrows, ncols, INNER_GAP_IN)
    if pairs:
        handles, labels = [], []
        for ax in pairs[0]:
            hh, ll = ax.get_legend_handles_labels()
            handles += hh
            labels += ll
        for _, ax_r in pairs[1:]:  # a band only some runs have
            for hh, ll in zip(*ax_r.get_legend_handles_labels()):
                if ll not in labels:
                    handles.append(hh)
                    labels.append(ll)
        legend_top(fig, handles, labels, min(len(labels), 4))
    return fig
