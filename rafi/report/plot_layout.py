"""Style, file output and fixed layouts of the report's figures (matplotlib, Agg backend).

Used by :mod:`rafi.report.plots` only: :func:`render` turns a figure into the bytes of a
PNG or SVG file (rule ``report_figures`` writes them), :func:`envelope` thins long series,
and the layout helpers place multi-panel figures with margins in inches.
"""

from __future__ import annotations

import io

import matplotlib

matplotlib.use("Agg", force=True)

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.font_manager import FontProperties  # noqa: E402
from PIL import Image  # noqa: E402

from rafi.report.fonts import matplotlib_families  # noqa: E402

#: Figure width that fills the A4 content box (180 mm) at 100 % image width.
PAGE_WIDTH_IN = 7.0

#: The figures' style; ``font.family`` is DejaVu Sans, then the installed CJK fonts (a log's
#: Chinese, Japanese or Korean headers in a label are drawn, not boxes: rafi.report.fonts).
STYLE = {
    "font.family": matplotlib_families(),
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


def render(fig, fmt: str = "png", dpi: int = 140) -> bytes:
    """The bytes of a figure file (PNG or SVG), and close the figure.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    fmt : {"png", "svg"}
    dpi : int
        Resolution of PNG output (ignored for SVG).

    Returns
    -------
    bytes
        A complete PNG or SVG document (SVG without a date, so the same figure gives the
        same bytes).
    """
    if fmt not in ("png", "svg"):
        raise ValueError(f"figure format {fmt!r}; expected png or svg")
    buf = io.BytesIO()
    try:
        if fmt == "svg":
            fig.savefig(buf, format="svg", metadata={"Date": None})
            return buf.getvalue()
        fig.set_dpi(dpi)
        fig.canvas.draw()
        rgba = np.asarray(fig.canvas.buffer_rgba())
        # the figure is opaque (white face): drop the alpha channel, so WeasyPrint embeds
        # the image as is instead of splitting it into colour + soft mask (two re-encodes)
        Image.fromarray(np.ascontiguousarray(rgba[..., :3])).save(buf, format="PNG", compress_level=6)
        return buf.getvalue()
    finally:
        plt.close(fig)


def hours(t_s):
    """Seconds -> hours (array)."""
    return np.asarray(t_s, dtype=float) / 3600.0


#: Longest series drawn as is; longer ones are reduced to a min/max envelope (same look,
#: every extreme kept, far fewer vertices for matplotlib and the PDF).
MAX_POINTS = 1600


def envelope(x, y, max_points: int = MAX_POINTS):
    """Min/max envelope of ``y`` over ``x`` for plotting: at most ``max_points`` points.

    The samples are cut into ``max_points / 2`` consecutive buckets; each bucket keeps its
    minimum and its maximum (in time order), so peaks - the numbers the report is about -
    survive the reduction. NaN buckets stay NaN (a gap in the line). Short series are
    returned unchanged.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    n = len(y)
    if n <= max_points or max_points < 4:
        return x, y
    b = int(np.ceil(n / (max_points // 2)))
    nb = int(np.ceil(n / b))
    pad = nb * b - n
    yy = np.concatenate([y, np.full(pad, np.nan)]).reshape(nb, b)
    finite = np.isfinite(yy)
    lo = np.where(finite, yy, np.inf).argmin(axis=1)
    hi = np.where(finite, yy, -np.inf).argmax(axis=1)
    first, second = np.minimum(lo, hi), np.maximum(lo, hi)
    idx = (np.arange(nb) * b)[:, None] + np.column_stack([first, second])
    idx = np.minimum(idx.ravel(), n - 1)
    return x[idx], y[idx]


def plot_series(ax, x, y, *args, **kwargs):
    """``ax.plot`` of a possibly long series through :func:`envelope`."""
    xe, ye = envelope(x, y)
    return ax.plot(xe, ye, *args, **kwargs)


#: The colour of the prediction interval's band.
C_BAND = "#f0a35e"


def plot_band(ax, x, lower, upper, *, label: str, color: str = C_BAND, alpha: float = 0.3, hatch=None):
    """``ax.fill_between`` of a band ``[lower, upper]`` over ``x`` (a PolyCollection).

    A long series is cut into the buckets of :func:`envelope`; each bucket is drawn from its
    smallest lower to its largest upper bound (step-wise), so the band drawn holds every
    sample's band. Samples with a NaN bound leave a gap. With ``hatch`` the band is hatched in
    ``color`` instead of filled (several bands on one axes, beside other shading).
    """
    x, lo, hi = (np.asarray(v, dtype=float) for v in (x, lower, upper))
    where = np.isfinite(lo) & np.isfinite(hi)
    step = None
    if len(x) > MAX_POINTS:
        b = int(np.ceil(len(x) / (MAX_POINTS // 2)))
        starts = np.arange(0, len(x), b)
        lo = np.where(where, lo, np.inf)
        hi = np.where(where, hi, -np.inf)
        lo, hi = np.minimum.reduceat(lo, starts), np.maximum.reduceat(hi, starts)
        where = np.isfinite(lo) & np.isfinite(hi)
        x = np.append(x[starts], x[-1])
        lo, hi, where = np.append(lo, lo[-1]), np.append(hi, hi[-1]), np.append(where, where[-1])
        step = "post"
    lo, hi = np.where(where, lo, np.nan), np.where(where, hi, np.nan)
    if hatch:
        kw = {"facecolor": "none", "edgecolor": color, "hatch": hatch, "alpha": alpha, "lw": 0}
    else:
        kw = {"color": color, "alpha": alpha, "lw": 0}
    return ax.fill_between(x, lo, hi, where=where, step=step, label=label, **kw)


# --------------------------------------------------------------------------- fixed layout
# constrained_layout measures every artist's tight bbox at save time (about 40 % of the
# figure time of the report); the multi-panel figures below use explicit margins in inches
# instead, sized from their actual tick labels, so nothing is cut off with other data.

#: Gaps (inches) of the fixed layouts, as constrained_layout placed them for the report.
TOP_TITLE_IN = 0.22  # axes title above the top row
TOP_LEGEND_IN = 0.48  # figure legend + axes title above the top row
BOTTOM_IN = 0.40  # x tick labels + x label below the bottom row
ROW_GAP_IN = 0.61  # x tick labels + x label + next row's title
SHARED_GAP_IN = 0.13  # between panels sharing x (tick labels hidden)
EDGE_IN = 0.05  # outer edge where nothing sticks out


def _tick_label_width_in(fig, axis) -> float:
    """Widest major tick label of ``axis`` in inches (without drawing the figure)."""
    lo, hi = sorted(axis.get_view_interval())
    eps = 1e-9 * max(abs(hi - lo), 1e-300)
    locs = [v for v in axis.get_majorticklocs() if lo - eps <= v <= hi + eps]
    labels = axis.get_major_formatter().format_ticks(locs) if locs else []
    size = matplotlib.rcParams["ytick.labelsize"]
    prop = FontProperties(size=size)
    renderer = fig.canvas.get_renderer()
    w = 0.0
    for text in labels:
        if text:
            w = max(
                w,
                renderer.get_text_width_height_descent(text, prop, ismath="TeX" if "$" in text else False)[0],
            )
    return w / fig.dpi


def y_room_in(ax, axis=None) -> float:
    """Inches beside ``ax`` taken by y tick labels + y label (+ a small pad)."""
    axis = axis or ax.yaxis
    fig = ax.figure
    tick = axis.get_major_ticks()[0] if axis.get_major_ticks() else None
    size = (tick.tick1line.get_markersize() if tick else 3.5) / 72.0
    pad = (tick.get_pad() if tick else 3.5) / 72.0
    room = size + pad + _tick_label_width_in(fig, axis)
    if axis.get_label_text():
        fs = FontProperties(size=matplotlib.rcParams["axes.labelsize"]).get_size_in_points()
        room += axis.labelpad / 72.0 + 1.1 * fs / 72.0
    return room + 0.03


def adjust(fig, *, left, right, top, bottom, ncols=1, nrows=1, wgap=0.0, hgap=0.0):
    """``fig.subplots_adjust`` with margins and gaps in inches."""
    W, H = fig.get_size_inches()
    aw = (W - left - right - (ncols - 1) * wgap) / ncols
    ah = (H - top - bottom - (nrows - 1) * hgap) / nrows
    fig.subplots_adjust(
        left=left / W,
        right=1 - right / W,
        bottom=bottom / H,
        top=1 - top / H,
        wspace=wgap / aw if ncols > 1 else 0.2,
        hspace=hgap / ah if nrows > 1 else 0.2,
    )


def split_shared(fig, outer, nrows, ncols, gap_in):
    """Set the gap (inches) inside the 2-row sub-grids of ``outer`` (panels sharing x)."""
    H = fig.get_size_inches()[1]
    pos = outer.get_grid_positions(fig)
    cell_h = pos[1][0] - pos[0][0]  # top - bottom of one outer cell (figure fraction)
    gap = gap_in / H
    for sub in {
        id(a.get_subplotspec().get_gridspec()): a.get_subplotspec().get_gridspec() for a in fig.axes
    }.values():
        if sub is not outer:
            sub._hspace = 2 * gap / max(cell_h - gap, 1e-6)
    for ax in fig.axes:
        ax._set_position(ax.get_subplotspec().get_position(fig))


def legend_top(fig, handles, labels, ncol):
    """Figure legend centred above the axes (the ``loc="outside upper center"`` look)."""
    return fig.legend(
        handles,
        labels,
        loc="upper center",
        bbox_to_anchor=(0.5, 1.0),
        ncol=ncol,
        frameon=False,
        borderaxespad=0.3,
        columnspacing=1.2,  # (default 2.0) room for a band's entry in one row
    )


def panel_grid(n: int, ncols: int = 3, row_h: float = 2.1, extra_rows: int = 1):
    """``(nrows, ncols, figsize)`` of a page-wide grid of ``n`` panels, ``row_h`` inches per row."""
    ncols = max(1, min(ncols, n))
    nrows = max(1, int(np.ceil(n / ncols)))
    return nrows, ncols, (PAGE_WIDTH_IN, row_h * nrows * extra_rows)


def speed_label(speed) -> str:
    """``3000`` -> ``3 000 r/min`` (no-break space)."""
    return f"{float(speed):,.0f} r/min".replace(",", "\u00a0")


# --------------------------------------------------------------------------- text on figures


def text_colour(rgba) -> str:
    """Black or white, whichever reads better on a cell of colour ``rgba`` (WCAG relative
    luminance of the sRGB colour: black above 0.179)."""
    lin = [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in rgba[:3]]
    return "black" if 0.2126 * lin[0] + 0.7152 * lin[1] + 0.0722 * lin[2] > 0.179 else "white"


def fit_titles(fig, titles: list[str], width_in: float) -> tuple[list[str], float, int]:
    """Panel titles that fit ``width_in``: a title too wide is broken after its ``": "`` and,
    if a line is still too wide, all titles get a smaller font (down to 5.5 pt).
    Returns ``(titles, font size, lines)``."""
    renderer = fig.canvas.get_renderer()
    size = float(plt.rcParams["axes.titlesize"])

    def wide(text: str, pt: float) -> float:
        prop = FontProperties(family=plt.rcParams["font.family"], size=pt)
        return max(renderer.get_text_width_height_descent(t, prop, ismath=False)[0] for t in text.split("\n"))

    out = [t.replace(": ", ":\n", 1) if wide(t, size) / fig.dpi > width_in else t for t in titles]
    while size > 5.5 and any(wide(t, size) / fig.dpi > width_in for t in out):
        size -= 0.5
    return out, size, max((t.count("\n") + 1 for t in out), default=1)


# --------------------------------------------------------------------------- text layout check

#: Clearance of :func:`text_overlaps` in points: two texts closer than this (or overlapping)
#: read as one - the panel titles of the old idle-run figure ran together 0.3 pt apart; a word
#: space at the figures' 6.5-8 pt is 2-2.5 pt, a legend's row gap 3 pt, and no two texts of the
#: report's figures are closer than 2.5 pt.
TEXT_CLEAR_PT = 1.0
#: A text crossing the figure's edge by more than this (points) is cut off: 0.5 pt is below a
#: glyph's stroke at those sizes, above rounding.
TEXT_EDGE_PT = 0.5


def _drawn_texts(fig) -> list:
    """The visible, non-empty text artists of a drawn figure, with a name for each."""
    from matplotlib.text import Text

    found = []

    def add(text, name):
        if isinstance(text, Text) and text.get_visible() and text.get_text().strip():
            found.append((name, text))

    for i, t in enumerate(fig.texts):
        add(t, f"figure text {i}")
    legends = list(fig.legends)
    for k, ax in enumerate(fig.axes):
        if not ax.get_visible():
            continue
        where = f"axes {k}"
        for t in (ax.title, ax._left_title, ax._right_title):
            add(t, f"{where} title")
        for axis, xy in ((ax.xaxis, "x"), (ax.yaxis, "y")):
            if not (ax.axison and axis.get_visible()):  # ax.axis("off") draws no axis
                continue
            add(axis.label, f"{where} {xy} label")
            add(axis.get_offset_text(), f"{where} {xy} offset")
            for tick in axis._update_ticks():  # the ticks drawn: inside the view interval
                add(tick.label1, f"{where} {xy} tick")
                add(tick.label2, f"{where} {xy} tick")
        for t in ax.texts:
            add(t, f"{where} text")
        if ax.get_legend() is not None:
            legends.append(ax.get_legend())
    for j, leg in enumerate(legends):
        if leg.get_visible():
            for t in leg.get_texts():
                add(t, f"legend {j}")
            add(leg.get_title(), f"legend {j} title")
    return found


def _text_corners(text, renderer) -> np.ndarray:
    """The 4 corners (display pixels) of a text's box, turned with the text.

    ``get_window_extent`` of a turned text (tick labels at 30 degrees) is the upright box
    around it, far larger than the text; the turned box has the same centre and the size of
    the text laid out upright.
    """
    bb = text.get_window_extent(renderer)
    angle = text.get_rotation() % 180.0
    centre = np.array([(bb.x0 + bb.x1) / 2.0, (bb.y0 + bb.y1) / 2.0])
    if angle == 0.0:
        w, h = bb.width, bb.height
    else:
        text.set_rotation(0.0)
        try:
            upright = text.get_window_extent(renderer)
        finally:
            text.set_rotation(angle)
        w, h = upright.width, upright.height
    t = np.deg2rad(angle)
    rot = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    half = np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) / 2.0
    return centre + half @ rot.T


def _penetration(a: np.ndarray, b: np.ndarray) -> float:
    """How far two convex quadrilaterals overlap: the smallest overlap of their projections on
    the normals of their edges (separating axis theorem; <= 0 when they are apart). For two
    upright boxes it is the smaller of the width and the height of their intersection."""
    depth = np.inf
    for poly in (a, b):
        for k in range(2):
            edge = poly[k + 1] - poly[k]
            normal = np.array([-edge[1], edge[0]]) / max(np.hypot(*edge), 1e-12)
            pa, pb = a @ normal, b @ normal
            depth = min(depth, min(pa.max(), pb.max()) - max(pa.min(), pb.min()))
    return float(depth)


def text_overlaps(fig, clear_pt: float = TEXT_CLEAR_PT, edge_pt: float = TEXT_EDGE_PT) -> list[dict]:
    """Text of a figure that overlaps other text or runs off the figure, measured by matplotlib.

    The figure is drawn once; every visible text (titles, axis labels, drawn tick labels,
    offset texts, annotations, legend entries) is taken with its box from matplotlib's own
    layout (the lines' extent from the font's metrics), turned with the text.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    clear_pt : float
        Two boxes *overlap* when they are less than ``clear_pt`` points apart
        (:func:`_penetration` > ``-clear_pt``; overlapping boxes have a positive depth).
    edge_pt : float
        A box is *outside* when a corner lies beyond an edge of the figure by more than
        ``edge_pt`` points.

    Returns
    -------
    list of dict
        ``{"kind": "overlap", "texts": (a, b), "by_pt": depth}`` (negative: a gap narrower
        than ``clear_pt``) or ``{"kind": "outside",
        "texts": (a,), "by_pt": (beyond left, bottom, right, top)}``, a text named
        ``"<where>: <text>"``; empty when the figure's text is clear.
    """
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    scale = 72.0 / fig.dpi  # display pixels -> points
    W, H = fig.bbox.width, fig.bbox.height
    boxes = []
    for name, text in _drawn_texts(fig):
        corners = _text_corners(text, renderer)
        if np.ptp(corners[:, 0]) > 0 and np.ptp(corners[:, 1]) > 0:
            boxes.append((f"{name}: {text.get_text()}", corners))
    found = []
    for label, c in boxes:
        x, y = c[:, 0], c[:, 1]
        beyond = tuple(round(float(v) * scale, 2) for v in (-x.min(), -y.min(), x.max() - W, y.max() - H))
        if max(beyond) > edge_pt:
            found.append({"kind": "outside", "texts": (label,), "by_pt": beyond})
    for i, (la, a) in enumerate(boxes):
        lo_a, hi_a = a.min(axis=0), a.max(axis=0)
        for lb, b in boxes[i + 1 :]:
            if (np.minimum(hi_a, b.max(axis=0)) - np.maximum(lo_a, b.min(axis=0)) <= -clear_pt / scale).any():
                continue  # the upright boxes are clear of each other: so are the texts
            depth = _penetration(a, b) * scale
            if depth > -clear_pt:
                found.append({"kind": "overlap", "texts": (la, lb), "by_pt": round(depth, 2)})
    return found
