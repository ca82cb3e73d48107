"""The key-sensor |r| heatmap readable from 4 to 40 sensors (foreign-5: 39 sensors ran together).

The figure is read back from matplotlib's own layout after it is drawn
(:func:`rafi.report.plot_layout.text_overlaps`: every tick label, value and label as a box,
turned with the text): no two texts overlap or run off the figure, every sensor's name is a tick
label, and every value written stands in its own cell and says the |r| of that cell. Sensor
names are those of the shipped machines (``T1`` .. ``T16``) and of the foreign twins
(``rearbearing_6``, ``frontbearing_12``).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rafi.report import plots
from rafi.report.plot_layout import text_overlaps

PLACES = ("head", "housing", "frontbearing", "rearbearing", "motorbase", "column", "coolant", "tank")


def correlation(n_sensors: int, scopes=("3000", "5750", "8500", "11250", "pooled"), *, short=False, seed=0):
    """A wide |r| table as rule rank writes it (rows: scopes, columns: sensors), |r| from 0.4
    to 1; names ``T<k>`` (``short``) or ``<place>_<k>`` as the foreign twins name them."""
    rng = np.random.default_rng(seed)
    names = (
        [f"T{k}" for k in range(1, n_sensors + 1)]
        if short
        else [f"{PLACES[k % len(PLACES)]}_{k // len(PLACES) + 1}" for k in range(n_sensors)]
    )
    vals = rng.uniform(0.4, 1.0, (len(scopes), n_sensors))
    vals[0, 0] = 1.0
    return pd.DataFrame(vals, index=list(scopes), columns=names)


def _draw(kept_figures, abs_r, chosen):
    plots.fig_correlation_heatmap(abs_r, threshold=0.97, chosen=chosen)
    return kept_figures[-1]


def _sensor_axis(ax, names):
    """The axis whose tick labels are the sensors'."""
    for axis in (ax.xaxis, ax.yaxis):
        if [t.get_text() for t in axis.get_ticklabels()] == list(names):
            return axis
    raise AssertionError("no axis has the sensors as its tick labels")


@pytest.mark.parametrize("n", [4, 8, 12, 16, 24, 32, 39, 40])
@pytest.mark.parametrize("short", [False, True])
def test_no_text_of_the_heatmap_overlaps_or_runs_off(kept_figures, n, short):
    abs_r = correlation(n, short=short, seed=n)
    fig = _draw(kept_figures, abs_r, chosen=list(abs_r.columns[:3]))
    found = text_overlaps(fig)
    assert not found, f"{len(found)} text defect(s) with {n} sensors: {found[:5]}"


@pytest.mark.parametrize("n", [4, 16, 39, 40])
def test_every_sensor_is_named_and_the_chosen_ones_in_bold(kept_figures, n):
    abs_r = correlation(n, seed=n)
    chosen = list(abs_r.columns[1::5])
    ax = _draw(kept_figures, abs_r, chosen).axes[0]
    axis = _sensor_axis(ax, abs_r.columns)
    bold = [t.get_text() for t in axis.get_ticklabels() if t.get_fontweight() in ("bold", 700)]
    assert bold == chosen


@pytest.mark.parametrize("n", [4, 16, 39, 40])
def test_a_value_written_stands_in_its_cell_and_says_its_r(kept_figures, n):
    abs_r = correlation(n, seed=n)
    ax = _draw(kept_figures, abs_r, []).axes[0]
    sensors_on_x = _sensor_axis(ax, abs_r.columns) is ax.xaxis
    cells = abs_r.to_numpy(float) if sensors_on_x else abs_r.to_numpy(float).T
    values = [t for t in ax.texts if t.get_visible()]
    for text in values:
        x, y = text.get_position()
        j, i = int(round(x)), int(round(y))
        assert (x, y) == (j, i)
        v = cells[i, j]
        assert text.get_text() == (f"{v:.3f}"[1:] if v < 1 else "1.00")
        assert (text.get_fontweight() in ("bold", 700)) == (v >= 0.97)
    # values are written where they fit: the shipped machines' 16 sensors and the foreign
    # twins' 39 each have all of them
    assert len(values) == cells.size


def test_the_foreign_twin_s_39_sensors_at_the_audit(kept_figures):
    """foreign-5: 39 sensors, 4 training speeds and pooled; the names ran into a black band."""
    abs_r = correlation(39, seed=5)
    fig = _draw(kept_figures, abs_r, chosen=["housing_2", "housing_4"])
    assert not text_overlaps(fig)
    width_in, height_in = fig.get_size_inches()
    assert width_in == plots.PAGE_WIDTH_IN and height_in <= 9.0  # one page of the report
