"""The figure of a replay (``rafi replay``, the report's section on the model on the machine).

One run of a replay table (:func:`rafi.deploy.replay.replay_log`): the measured displacement,
the model's value with its prediction interval (a band, where the table has ``lower_um`` and
``upper_um``) and the command against time, with shading where a limit or a fault rule acted
(clamp, rate limit, hold / ramp; a hold / ramp caused by the interval alone, fault class
``interval_wide``, in a colour of its own), and the status of every sample as a strip below. Called by
rule ``report_figures`` (group ``replay``) and by ``rafi replay``; the report job embeds the file.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.patches import Patch

from rafi.deploy.metrics import fault_classes
from rafi.report.intervals import band_label, has_band
from rafi.report.plot_layout import (
    C_MEAS,
    C_PRED,
    PAGE_WIDTH_IN,
    STYLE,
    envelope,
    hours,
    plot_band,
    plot_series,
    render,
)

#: Colour of each status in the strip (``rafi.deploy.limits.STATUSES``).
STATUS_COLOURS = {
    "off": "#9e9e9e",
    "referencing": "#90caf9",
    "ok": "#a5d6a7",
    "hold": "#ffcc80",
    "ramp": "#ef9a9a",
}

#: Bands drawn behind the curves where a rule acted: (column test, label, colour).
_BANDS = (
    ("clamped", "clamp acted", "#ce93d8"),
    ("rate_limited", "rate limit acted", "#80deea"),
    ("fault_rule", "fault rule (hold / ramp)", "#ffab91"),
    ("interval_wide", "interval too wide (hold / ramp)", "#a1887f"),
)


def _held_by_interval(f: pd.DataFrame, held: np.ndarray) -> np.ndarray:
    """True where the command was held or ramped because of the prediction interval alone: the
    sample's ``fault`` names fault class ``interval_wide`` and no other
    (:func:`rafi.deploy.metrics.fault_classes`). A sample with a further cause (a sensor, the
    trained range) counts as the other fault rules; a table without ``fault`` has none."""
    if "fault" not in f:
        return np.zeros(len(f), dtype=bool)
    alone = np.array([fault_classes(str(x)) == ["interval_wide"] for x in f["fault"].fillna("")], dtype=bool)
    return held & alone


def _band(ax, h, flag, colour, label):
    if not np.any(flag):
        return None
    xe, ye = envelope(h, np.asarray(flag, float))
    return ax.fill_between(
        xe,
        0,
        1,
        where=ye > 0.5,
        step="post",
        color=colour,
        alpha=0.45,
        lw=0,
        transform=ax.get_xaxis_transform(),
        label=label,
    )


def fig_replay(
    table: pd.DataFrame,
    *,
    clamp_um: tuple | None = None,
    level: float | None = None,
    title: str = "",
    fmt: str = "png",
) -> bytes:
    """Measured dz, model and command of one replayed run against time, with the status strip.

    Parameters
    ----------
    table : DataFrame
        The run's rows of the replay table: ``t_s``, ``measured_um``, ``model_um``,
        ``command_um``, ``status``, ``clamped``, ``rate_limited`` (time order); ``fault`` (the
        causes, :attr:`rafi.deploy.limits.Command.fault`) tells a hold / ramp by the interval
        alone from the other fault rules (without it, every hold / ramp is a fault rule); with
        ``lower_um`` and ``upper_um`` (:data:`rafi.deploy.replay.COLUMNS`: the model's
        interval, around ``model_um``) the interval is a band around the model's curve. A table
        without them, or without a finite bound (an artefact without an ``interval`` block), is
        drawn without a band.
    clamp_um : (float, float), optional
        The clamp range, drawn as dashed lines where it falls inside the data's range
        (otherwise named in the legend only).
    level : float, optional
        The interval's level (the replayed artefact's ``interval.level``): the band's legend
        entry (``90 % interval``; ``prediction interval`` without it).
    title : str
        Axes title.
    fmt : {"png", "svg"}

    Returns
    -------
    bytes
        The file (:func:`rafi.report.plot_layout.render`).
    """
    f = table.sort_values("t_s", kind="stable")
    h = hours(f["t_s"])
    status = f["status"].astype(str).to_numpy()
    with plt.rc_context(STYLE):
        fig, (ax, strip) = plt.subplots(
            2,
            1,
            figsize=(PAGE_WIDTH_IN, 3.1),
            sharex=True,
            gridspec_kw={"height_ratios": [7, 1], "hspace": 0.08},
            constrained_layout=True,
        )
        held = np.isin(status, ("hold", "ramp"))
        by_interval = _held_by_interval(f, held)
        flags = {
            "clamped": f["clamped"].astype(bool).to_numpy(),
            "rate_limited": f["rate_limited"].astype(bool).to_numpy(),
            "fault_rule": held & ~by_interval,
            "interval_wide": by_interval,
        }
        for key, label, colour in _BANDS:
            _band(ax, h, flags[key], colour, label)
        if has_band(f):
            lower, upper = (pd.to_numeric(f[c], errors="coerce") for c in ("lower_um", "upper_um"))
            plot_band(ax, h, lower, upper, label=band_label(level))
        plot_series(ax, h, f["measured_um"], color=C_MEAS, lw=0.9, label="measured dz")
        plot_series(ax, h, f["command_um"], color="black", lw=1.1, label="command (what is written)")
        plot_series(ax, h, f["model_um"], color=C_PRED, lw=1.0, ls="--", label="model value")
        ax.axhline(0, color="black", lw=0.4)
        values = np.concatenate(
            [f[c].to_numpy(dtype=float) for c in ("measured_um", "model_um", "command_um")]
        )
        values = values[np.isfinite(values)]
        if clamp_um is not None:
            lo, hi = (float(v) for v in clamp_um)
            top = float(np.abs(values).max()) if len(values) else 0.0
            shown = [v for v in (lo, hi) if abs(v) <= 1.3 * top]
            for k, v in enumerate(shown):
                ax.axhline(v, color="#7b1fa2", ls=":", lw=0.9, label="clamp" if k == 0 else None)
            if len(shown) < 2:
                ax.plot([], [], color="none", label=f"clamp [{lo:g}, {hi:g}] \u00b5m (off the axis)")
        if title:
            ax.set_title(title)
        ax.set_ylabel("displacement (\u00b5m)")
        present = [s for s in STATUS_COLOURS if (status == s).any()]
        present += sorted(set(status) - set(STATUS_COLOURS))
        colours = {s: STATUS_COLOURS.get(s, "#616161") for s in present}
        for s in present:
            xe, ye = envelope(h, (status == s).astype(float))
            strip.fill_between(xe, 0, 1, where=ye > 0.5, step="post", color=colours[s], lw=0)
        strip.set_yticks([])
        strip.set_ylim(0, 1)
        strip.grid(False)
        strip.set_ylabel("status", rotation=0, ha="right", va="center")
        strip.set_xlabel("time since run start (h)")
        if len(h):
            strip.set_xlim(float(h.min()), float(h.max()))
        handles, labels = ax.get_legend_handles_labels()
        handles += [Patch(color=colours[s], label=f"status {s}") for s in present]
        labels += [f"status {s}" for s in present]
        fig.legend(handles, labels, ncol=4, loc="outside upper center", frameon=False)
        return render(fig, fmt)
