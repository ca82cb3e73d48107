"""Every model of the comparison's bar chart in its own colour, the offered model picked out.

The bars are read back from the figure matplotlib drew (``render`` kept from closing it): each
model's bars are the patches of its legend entry's label, their face colour its colour. The
families drawn are every kind the comparison scores (:data:`rafi.family.compare.KINDS`), the
CV-weighted ensemble and the adaptation candidates of a prior (:mod:`rafi.family.adapted`), in
the orders and subsets a machine's ``comparison/summary.csv`` may hold, and names no kind has.
"""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest
from matplotlib.colors import to_hex

from rafi.family.adapted import CANDIDATES, ENSEMBLE_CANDIDATES
from rafi.family.compare import KINDS
from rafi.family.ensemble import ENSEMBLE
from rafi.report import plots

#: Every name a comparison of this code can hold, in the order of a re-qualification's summary.
FAMILY = [*KINDS, *CANDIDATES, *ENSEMBLE_CANDIDATES, ENSEMBLE]


def _draw(kept_figures, models: list, offered=None, seed: int = 0):
    """The bar chart of ``models`` on three runs (random residuals, one failing model); returns
    ``{model: [its bar patches]}``."""
    rng = np.random.default_rng(seed)
    runs = ["run_a", "run_b", "run_c"]
    after = pd.DataFrame(rng.uniform(0.5, 20.0, (len(runs), len(models))), index=runs, columns=models)
    failed = pd.DataFrame(False, index=runs, columns=models)
    failed.iloc[0, 0] = True
    before = pd.Series(25.0, index=runs)
    kwargs = {"offered": offered} if offered is not None else {}
    plots.fig_comparison_bars(after, before, failed=failed, gate_um=12.0, **kwargs)
    (ax,) = kept_figures[-1].axes
    bars = {}
    for container in ax.containers:
        if container.get_label() in models:
            bars[container.get_label()] = list(container.patches)
    assert sorted(bars) == sorted(models)
    return bars


def _colour(patches) -> str:
    (colour,) = {to_hex(p.get_facecolor()) for p in patches}
    return colour


def test_every_kind_of_the_family_has_its_own_colour(kept_figures):
    bars = _draw(kept_figures, FAMILY)
    colours = [_colour(p) for p in bars.values()]
    assert len(set(colours)) == len(FAMILY), dict(zip(bars, colours))


@pytest.mark.parametrize("seed", range(6))
def test_any_subset_in_any_order_has_distinct_colours_and_each_kind_keeps_its_own(kept_figures, seed):
    rng = np.random.default_rng(seed)
    everyone = {m: _colour(p) for m, p in _draw(kept_figures, FAMILY).items()}
    subset = [str(m) for m in rng.permutation(FAMILY)[: rng.integers(3, len(FAMILY) + 1)]]
    colours = {m: _colour(p) for m, p in _draw(kept_figures, subset, seed=seed).items()}
    assert len(set(colours.values())) == len(subset), colours
    assert colours == {m: everyone[m] for m in subset}


def test_names_no_kind_has_take_colours_no_other_model_of_the_figure_has(kept_figures):
    for extra in itertools.combinations(["custom", "ridge_global_v2", "prior_x", "late"], 2):
        models = [*FAMILY, *extra]
        colours = [_colour(p) for p in _draw(kept_figures, models).values()]
        assert len(set(colours)) == len(models), dict(zip(models, colours))


def test_the_fl_family_offers_the_ensemble_beside_ridge_global_in_two_colours(kept_figures):
    """The audit's case: fl-thermal, foreign-5, tapping-center-a drew both in #1f77b4."""
    models = ["rafi", "rafi_linear", "ridge_global", "dynamic", "grey_box", "temperature_ridge", "ensemble"]
    bars = _draw(kept_figures, models, offered="ensemble")
    assert _colour(bars["ensemble"]) != _colour(bars["ridge_global"])


@pytest.mark.parametrize("offered", ["ensemble", "prior_shared_ridge", "dynamic"])
def test_the_offered_model_is_outlined_and_no_other(kept_figures, offered):
    bars = _draw(kept_figures, FAMILY, offered=offered)
    for model, patches in bars.items():
        widths = {round(p.get_linewidth(), 2) for p in patches}
        edges = {to_hex(p.get_edgecolor(), keep_alpha=True) for p in patches}
        if model == offered:
            assert widths == {plots.OFFERED_EDGE_PT} and edges == {"#000000ff"}, (model, widths, edges)
        else:
            assert widths == {0.0} or edges == {"#00000000"}, (model, widths, edges)


def test_the_legend_names_the_offered_model_with_its_outline(kept_figures):
    _draw(kept_figures, FAMILY, offered="prior_shared_ridge")
    legend = kept_figures[-1].legends[0]
    handles = dict(zip([t.get_text() for t in legend.get_texts()], legend.legend_handles))
    assert handles["prior_shared_ridge"].get_linewidth() == plots.OFFERED_EDGE_PT
    assert (
        handles["ridge_global"].get_linewidth() in (0.0, None)
        or to_hex(handles["ridge_global"].get_edgecolor(), keep_alpha=True) == "#00000000"
    )


def test_the_residual_figures_draw_each_model_in_its_bar_colour(tmp_path, monkeypatch):
    """The residual-against-time figures of the comparison drew the second model blue whatever its
    colour in the bar chart: the ensemble was ridge_global's blue there. Each model's residual line
    now has its colour of the bars (:func:`plots.model_colours`), RAFI its red."""
    from report_fixture import copy_fixture, write_upstream_tables

    from rafi.report import figures
    from rafi.report.inputs import load_results

    res = load_results(write_upstream_tables(copy_fixture(tmp_path)))
    drawn = []
    monkeypatch.setattr(
        plots,
        "fig_comparison_residuals",
        lambda series, **kw: drawn.append((list(series), kw["colours"])) or b"",
    )
    list(figures._comparison(res, {"max_residual_um": 12.0}, "png"))
    assert drawn
    models = [str(m) for m in res["comparison"]["model"]]
    palette = plots.model_colours(models)
    for labels, colours in drawn:
        assert set(colours) == set(labels)
        for label in labels:
            assert colours[label] == palette[label.split(" ")[0]]
    assert {colours[lab] for _, colours in drawn for lab in colours} >= {plots.MODEL_COLOURS["rafi"]}
