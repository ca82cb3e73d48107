"""The segmentation timeline of the qualification report (section Segmentation).

Called by rule ``report_figures`` (:mod:`rafi.report.figures`, group ``pipeline``), never by
the report job; returns the bytes of a PNG or SVG file (:func:`rafi.report.plot_layout.render`).
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np

from rafi.report.plot_layout import (
    BOTTOM_IN,
    C_MEAS,
    PAGE_WIDTH_IN,
    ROW_GAP_IN,
    STYLE,
    TOP_LEGEND_IN,
    adjust,
    envelope,
    legend_top,
    plot_series,
    render,
    y_room_in,
)

#: Colour of each run role on the segmentation timeline.
ROLE_COLOURS = {
    "training": "#2e7d32",
    "validation_single": "#1f77b4",
    "validation_multi": "#7b1fa2",
    "validation_idle": "#80cbc4",
    "excluded": "#bdbdbd",
}


def fig_segmentation(logs: dict, *, fmt: str = "png") -> bytes:
    """Timeline of each log on its own clock, the background coloured by the role of each run:
    dz (left axis) and the spindle speed (right axis, grey).

    ``logs``: ``label -> (samples, spans)``; ``samples`` has ``h`` (hours on the log's clock),
    ``speed_rpm`` and ``dz_um``; ``spans`` has ``start_h``, ``end_h``, ``role`` and ``label``
    (the run's number within the log, written at the top of its band where it fits).
    """
    with plt.rc_context(STYLE):
        names = list(logs)
        fig, axes = plt.subplots(
            len(names), 1, figsize=(PAGE_WIDTH_IN, 1.9 * len(names) + 0.5), squeeze=False
        )
        axes = axes[:, 0]
        seen, twins = {}, []
        for ax, name in zip(axes, names):
            samples, spans = logs[name]
            span_h = max(float(spans["end_h"].max() - spans["start_h"].min()), 1e-9) if len(spans) else 1.0
            for s in spans.itertuples(index=False):
                colour = ROLE_COLOURS.get(str(s.role), "#eeeeee")
                seen.setdefault(str(s.role), ax.axvspan(s.start_h, s.end_h, color=colour, alpha=0.35, lw=0))
                if s.end_h - s.start_h < 0.03 * span_h:  # too narrow for its number
                    continue
                ax.text(
                    (s.start_h + s.end_h) / 2,
                    0.98,
                    str(s.label),
                    transform=ax.get_xaxis_transform(),
                    ha="center",
                    va="top",
                    fontsize=5.5,
                )
            plot_series(ax, samples["h"], samples["dz_um"], color=C_MEAS)
            ax.set_ylabel("dz (µm)", color=C_MEAS)
            ax.set_title(name, loc="left")
            ax.set_xlabel("time since the start of the log (h)")
            ax.margins(x=0)
            tw = ax.twinx()
            tw.spines["right"].set_visible(True)
            tw.grid(False)
            hs, sp = envelope(samples["h"], samples["speed_rpm"])
            tw.plot(hs, sp, color="#555555", lw=0.7)
            top = float(np.nanmax(sp)) if len(sp) and np.isfinite(sp).any() else 1.0
            tw.set_ylim(min(0.0, float(np.nanmin(sp))) if len(sp) else 0.0, 1.2 * top + 1.0)
            tw.set_ylabel("speed (r/min)", color="#555555")
            twins.append(tw)
        room = max(y_room_in(a) for a in axes)
        adjust(
            fig,
            left=room,
            right=max(y_room_in(t) for t in twins),
            top=TOP_LEGEND_IN,
            bottom=BOTTOM_IN,
            nrows=len(names),
            hgap=ROW_GAP_IN,
        )
        order = [r for r in ROLE_COLOURS if r in seen] + [r for r in seen if r not in ROLE_COLOURS]
        legend_top(fig, [seen[r] for r in order], [r.replace("_", " ") for r in order], len(order))
        return render(fig, fmt)
