"""The report's section on the model offered to the machine (rafi.report.deployed_section,
deployed_terms, deployed_plot).

The written equation and coefficient table are re-evaluated here from what they say - each
term's definition (the filter recursion, the reference window's median, the speed powers, the
triangular blend) coded independently of ``rafi.family`` - with the coefficients parsed from
the written text, on synthetic whole logs with known schedules (cold starts, cool-downs, a
short gap that carries the filters and a long one that restarts them), under both reference
rules. They must give the fitted model's own prediction to 1e-9 um.
"""

from __future__ import annotations

import re
import warnings

import numpy as np
import pandas as pd
import pytest

from rafi.report.deployed_plot import fig_deployed_residuals
from rafi.report.deployed_section import (
    deployed_panels,
    kind_description,
    section_deployed,
    sensors_left_out_text,
)
from rafi.report.deployed_terms import parse_feature, rafi_tables, ridge_inputs, ridge_tables
from rafi.twin.synthetic_logs import schedule_log
from rafi.twin.synthetic_runs import runs_of_logs, small_family_model

PERIOD = 20.0
WINDOW = 60.0
RESTART = 3600.0
TOL_RPM = 50.0


def _log(pieces, seed, *, segments=()):
    frame, truth = schedule_log(pieces, period_s=PERIOD, seed=seed, speed_noise_rpm=3.0)
    frame["disp_um"] += 7.0
    for k, gap in segments:
        first = int(truth["first_row"].iloc[k])
        frame.loc[first:, "t_s"] += gap
        frame.loc[first:, "time"] += pd.Timedelta(seconds=gap)
        frame.loc[first:, "segment"] += 1
    return frame


@pytest.fixture(scope="module", params=["run_start", "log_start"])
def data(request):
    rule = request.param
    rest = (0, 180)
    logs = {
        f"train{i}.csv": _log([rest, (s, 3 * 3600), (0, 3600)], seed=i)
        for i, s in enumerate((3000, 6000, 9000))
    }
    logs["multi.csv"] = _log(
        [rest, (4500, 3600), (7500, 2400), (0, 1800), (6000, 3600), (0, 1200), (8000, 3600)],
        seed=7,
        segments=[(4, 600.0), (6, 2 * RESTART)],
    )
    table, frame = runs_of_logs(
        logs, training_speeds_rpm=[3000, 6000, 9000], reference_rule=rule, reference_window_s=WINDOW
    )
    return rule, table, frame


def _model(kind: str, rule: str):
    return small_family_model(
        kind,
        reference_rule=rule,
        reference_window_s=WINDOW,
        filter_restart_gap_s=RESTART,
        speed_gain=True,
    )


def _fit(kind, rule, table, frame):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return _model(kind, rule).fit(table, frame)


# ---------------------------------------------------------------- the independent evaluator
def _lowpass(x: np.ndarray, t: np.ndarray, restart: np.ndarray, tau: float) -> np.ndarray:
    """y[k] = y[k-1] + (1 - exp(-(t[k]-t[k-1])/tau)) (x[k] - y[k-1]); y = x at a restart."""
    if tau <= 0:
        return x.copy()
    y = np.empty_like(x)
    for k in range(len(x)):
        if restart[k]:
            y[k] = x[k]
        else:
            y[k] = y[k - 1] + (1.0 - np.exp(-(t[k] - t[k - 1]) / tau)) * (x[k] - y[k - 1])
    return y


class Written:
    """Evaluates what the section writes, from the definitions it states, on a whole-log frame."""

    def __init__(self, frame: pd.DataFrame, rule: str):
        f = frame.sort_values(["log", "log_t_s"], kind="stable")
        self.index = f.index
        self.f = f
        self.t = f["log_t_s"].to_numpy(float)
        new_log = f["log"].ne(f["log"].shift()).to_numpy()
        gap = np.r_[0.0, np.diff(self.t)]
        self.restart = new_log | (gap > RESTART)
        key = f["run_id"].astype(str) if rule == "run_start" else f["log"] + "/" + f["segment"].astype(str)
        self.groups = key.to_numpy()
        self.window = {}
        for g in pd.unique(self.groups):
            rows = np.flatnonzero(self.groups == g)
            t0 = self.t[rows[0]]
            self.window[g] = rows[: max(1, int(np.sum(self.t[rows] < t0 + WINDOW - 1e-9)))]
        self.n = f["speed_rpm"].to_numpy(float)

    def referenced(self, x: np.ndarray) -> np.ndarray:
        """``x`` minus its median over the row's reference window."""
        ref = {g: np.nanmedian(x[rows]) for g, rows in self.window.items()}
        return x - np.array([ref[g] for g in self.groups])

    def n0(self, speed_rule: str) -> np.ndarray:
        """Reference speed: median speed of the run's first window (``t - t0 <= window``) or 0."""
        if speed_rule != "run_start":
            return np.zeros(len(self.n))
        out = np.empty(len(self.n))
        runs = self.f["run_id"].astype(str).to_numpy()
        ts = self.f["t_s"].to_numpy(float)
        for r in pd.unique(runs):
            rows = np.flatnonzero(runs == r)
            out[rows] = np.median(self.n[rows[ts[rows] <= ts[rows].min() + WINDOW]])
        return out

    def feature(self, name: str, art: dict) -> np.ndarray:
        p = parse_feature(name, art["hyperparameters"].get("speed_powers") or ())
        n_krpm = self.n / 1000.0
        n0 = self.n0(art["speed_reference"]["rule"]) / 1000.0
        if p["type"] in ("rise", "rise_speed"):
            x = self.f[p["sensor"]].to_numpy(float)
            v = self.referenced(_lowpass(x, self.t, self.restart, p["tau_s"]))
            return v * n_krpm if p["type"] == "rise_speed" else v
        if p["type"] == "power":
            q = p["power"]
            x = (np.abs(self.n) > TOL_RPM).astype(float) if q == 0 else (np.abs(self.n) / 1e4) ** q
            return self.referenced(_lowpass(x, self.t, self.restart, p["tau_s"]))
        if p["type"] == "draw_in":
            return _lowpass(n_krpm**2, self.t, self.restart, p["tau_s"]) - n0**2
        if p["type"] == "speed":
            return n_krpm - n0
        return n_krpm**2 - n0**2  # speed2 (grey_box: the unlagged draw-in, the same formula)

    def ridge(self, terms, art: dict) -> pd.Series:
        total = np.zeros(len(self.t))
        for name, text in terms:
            total += float(text) * self.feature(name, art)
        return pd.Series(total, index=self.index)

    def rafi(self, flat, art: dict) -> pd.Series:
        var = art["variables"]
        x = {k: self.referenced(self.f[s].to_numpy(float)) for k, s in var.items()}
        speeds = sorted({s for (s, _), _ in flat})
        poly = {}
        for s in speeds:
            val = np.zeros(len(self.t))
            for (sp, term), text in flat:
                if sp != s:
                    continue
                v = np.ones(len(self.t))
                if term != "1":
                    for factor in term.split("*"):
                        name, _, pw = factor.partition("^")
                        v = v * x[name] ** (int(pw) if pw else 1)
                val += float(text) * v
            poly[s] = val
        out = np.empty(len(self.t))
        for k, n in enumerate(self.n):  # triangular blend of the two neighbours; edge model outside
            if n <= speeds[0]:
                out[k] = poly[speeds[0]][k]
            elif n >= speeds[-1]:
                out[k] = poly[speeds[-1]][k]
            else:
                j = int(np.searchsorted(speeds, n, side="right")) - 1
                w = (n - speeds[j]) / (speeds[j + 1] - speeds[j])
                out[k] = (1 - w) * poly[speeds[j]][k] + w * poly[speeds[j + 1]][k]
        return pd.Series(out, index=self.index)


def _written_in(blocks) -> set:
    """Every coefficient text that stands in a table cell of the blocks (as the section's
    template sets them: each block rendered through ``deployed.html.j2``)."""
    from rafi.report.render import _environment

    env = _environment()
    src = (
        '{% from "macros.html.j2" import exact %}{% for b in blocks %}'
        "{% for r in b.rows %}{% for c in r.get('coefs', [r.get('coef')]) %}{{ exact(c) }}{% endfor %}"
        "{% endfor %}{% endfor %}"
    )
    html = env.from_string(src).render(blocks=blocks)
    return set(re.findall(r"<code[^>]*>([^<]+)</code>", html))


@pytest.mark.parametrize("kind", ["ridge_global", "dynamic", "grey_box", "temperature_ridge"])
def test_the_written_ridge_table_is_the_model(data, kind):
    rule, table, frame = data
    model = _fit(kind, rule, table, frame)
    art = model.to_dict()
    blocks, terms = ridge_tables(art)
    assert [n for n, _ in terms] == art["features"]  # every term, in the artefact's order
    assert {c for _, c in terms} <= _written_in(blocks)  # each one stands in the table as written
    if kind == "grey_box":
        types = {parse_feature(n)["type"] for n, _ in terms}
        assert {"rise", "power", "draw_in"} <= types
    if kind == "ridge_global":
        assert any(parse_feature(n)["type"] == "rise_speed" for n, _ in terms)
    if kind == "temperature_ridge":  # the rises and their filters only, and the report says why
        assert {parse_feature(n)["type"] for n, _ in terms} == {"rise"}
        assert dict(ridge_inputs(art))["spindle speed"] == (
            "not read by the model (temperature_ridge has no speed input)"
        )
    mine = Written(frame, rule).ridge(terms, art).loc[frame.index]
    theirs = pd.Series(model.predict(frame), index=frame.index)
    ok = np.isfinite(theirs.to_numpy())
    assert ok.mean() > 0.95
    assert np.isfinite(mine.to_numpy()[ok]).all()
    assert np.max(np.abs(mine.to_numpy()[ok] - theirs.to_numpy()[ok])) < 1e-9


@pytest.mark.parametrize("kind", ["rafi", "rafi_linear"])
def test_the_written_rafi_table_is_the_model(data, kind):
    rule, table, frame = data
    model = _fit(kind, rule, table, frame)
    art = model.to_dict()
    blocks, flat = rafi_tables(art)
    assert {c for _, c in flat} <= _written_in(blocks)
    assert len(flat) == len(art["terms"]) * len(art["speeds"])
    mine = Written(frame, rule).rafi(flat, art).loc[frame.index]
    theirs = model.predict(frame)
    ok = np.isfinite(theirs)
    assert ok.mean() > 0.95
    assert np.max(np.abs(mine.to_numpy()[ok] - theirs[ok])) < 1e-9


def test_a_coefficient_off_by_one_ulp_is_caught(data):
    """The comparison is sharp enough to see a written coefficient that differs in the last digit."""
    rule, table, frame = data
    model = _fit("grey_box", rule, table, frame)
    art = model.to_dict()
    _, terms = ridge_tables(art)
    big = max(range(len(terms)), key=lambda i: abs(float(terms[i][1])))
    bent = list(terms)
    bent[big] = (terms[big][0], repr(float(terms[big][1]) * (1 + 1e-6)))
    w = Written(frame, rule)
    theirs = model.predict(frame)
    ok = np.isfinite(theirs)
    diff = np.abs(w.ridge(bent, art).loc[frame.index].to_numpy()[ok] - theirs[ok])
    assert diff.max() > 1e-9


def test_every_feature_name_of_every_kind_is_understood():
    assert parse_feature("dT6@0s") == {"type": "rise", "sensor": "T6", "tau_s": 0.0}
    assert parse_feature("dT16@120s*n_krpm") == {"type": "rise_speed", "sensor": "T16", "tau_s": 120.0}
    assert parse_feature("L60s(n^1.667)") == {"type": "power", "tau_s": 60.0, "power": 1.667}
    # the name rounds the exponent; the power used is the artefact's own (5/3, not 1.667)
    assert parse_feature("L60s(n^1.667)", [0.0, 1.0, 5 / 3, 2.0])["power"] == 5 / 3
    assert parse_feature("L10s(n2_krpm2)") == {"type": "draw_in", "tau_s": 10.0}
    assert parse_feature("n_krpm") == {"type": "speed"}
    with pytest.raises(ValueError):
        parse_feature("dT6@0s^2")


def _comparison_tables(models: dict, table, frame, champion: str):
    """summary/per_run/cv/residuals shaped like rule compare's, for fitted ``models``."""
    val = table[table["role"].astype(str).str.startswith("validation")]
    summ, per_run, resid, cv = [], [], [], []
    for name, m in models.items():
        art = m.to_dict()
        pred = pd.Series(m.predict(frame), index=frame.index)
        for k, r in enumerate(val.itertuples(index=False)):
            rows = frame["run_id"] == r.run_id
            f = frame.loc[rows, ["run_id", "t_s", "dz_um"]].rename(columns={"dz_um": "measured_um"})
            f["residual_um"] = f["measured_um"] - pred[rows]
            f["model"] = name
            resid.append(f)
            per_run.append(
                {
                    "model": name,
                    "run_id": r.run_id,
                    "role": r.role,
                    "speed_rpm": r.speed_rpm,
                    "max_abs_before_um": f["measured_um"].abs().max(),
                    "max_abs_after_um": f["residual_um"].abs().max(),
                    "rmse_after_um": float(np.sqrt(np.nanmean(f["residual_um"] ** 2))),
                    "passed": True,
                    "noise_floor_um": 0.5 + 0.01 * k,
                    "model_id": art["model_id"],
                }
            )
            cv.append({"model": name, "scheme": "leave_one_run_out", "fold": k, "test_runs": r.run_id})
        summ.append(
            {
                "model": name,
                "kind": art["kind"],
                "champion": name == champion,
                "model_id": art["model_id"],
                "passed": True,
                "max_abs_after_um": 1.0,
                "noise_floor_um": 0.5,
                "cv_mean_max_abs_um": 1.0 if name == champion else 2.0,
                "cv_max_abs_um": 1.5,
                "selection_rank": 1 if name == champion else 2,
            }
        )
    return (
        pd.DataFrame(summ),
        pd.DataFrame(per_run),
        pd.DataFrame(cv),
        pd.concat(resid, ignore_index=True),
    )


class _Figs:
    def __init__(self, n):
        self.n = n

    def get(self, group, key):
        k = int(key.rsplit("/", 1)[-1])
        return {"kind": "png", "src": key} if group == "comparison" and k <= self.n else None


def test_the_section_documents_the_champion_and_every_validation_run(data):
    rule, table, frame = data
    models = {k: _fit(k, rule, table, frame) for k in ("rafi", "grey_box")}
    summ, per_run, cv, resid = _comparison_tables(models, table, frame, "grey_box")
    art = models["grey_box"].to_dict()
    res = {
        "comparison": summ,
        "comparison_per_run": per_run,
        "comparison_cv": cv,
        "best_model": art,
        "model": models["rafi"].to_dict(),
    }
    panels = deployed_panels(summ, per_run, resid)
    val_runs = list(per_run.loc[per_run["model"] == "grey_box", "run_id"])
    assert [p["run_id"] for g in panels for p in g] == val_runs  # every validation run, in order
    assert all(len(g) <= 6 for g in panels)
    d = section_deployed(res, _Figs(len(panels)), champion_after=art["model_id"])
    assert d["kind"] == "grey_box" and d["model_id"] == art["model_id"] and d["on_machine"] is True
    assert len(d["figures"]) == len(panels)
    assert d["n_terms"] == len(art["features"])
    assert [r["run_id"] for r in d["validation"]] == val_runs and d["n_runs"] == len(val_runs)
    assert [r["model"] for r in d["cv"]["beaten"] if r["rafi"]] == ["rafi"]  # "(RAFI as published)"
    assert d["description"].startswith("Ridge on filtered rises")
    # an artefact that is not the champion's is never documented as if it were
    other = dict(res, best_model=models["rafi"].to_dict())
    assert section_deployed(other, _Figs(0)) is None
    assert section_deployed(dict(res, comparison=None), _Figs(0)) is None
    # the registry kept another model: said, not hidden
    assert section_deployed(res, _Figs(0), champion_after="f" * 64)["on_machine"] is False


def test_the_section_says_where_the_offered_model_gave_no_compensation(data):
    rule, table, frame = data
    models = {k: _fit(k, rule, table, frame) for k in ("rafi", "grey_box")}
    summ, per_run, cv, _ = _comparison_tables(models, table, frame, "grey_box")
    res = {"comparison": summ, "comparison_per_run": per_run, "comparison_cv": cv}
    res["best_model"] = models["grey_box"].to_dict()
    assert section_deployed(res, _Figs(0))["unpredicted"] == []  # nothing missing: nothing said
    per_run = per_run.assign(n_samples=100, n_unpredicted=0, unpredicted_inputs="")
    mine = per_run.index[per_run["model"] == "grey_box"]
    per_run.loc[mine[0], ["n_unpredicted", "unpredicted_inputs"]] = [7, "T11"]
    per_run.loc[mine[-1], ["n_unpredicted", "unpredicted_inputs"]] = [3, float("nan")]  # as read from csv
    per_run.loc[per_run.index[per_run["model"] == "rafi"][0], "n_unpredicted"] = 5  # another model's
    d = section_deployed({**res, "comparison_per_run": per_run}, _Figs(0))
    first, last = per_run.loc[mine[0], "run_id"], per_run.loc[mine[-1], "run_id"]
    assert d["unpredicted"] == [
        {"run_id": first, "n": 7, "n_scored": 100, "inputs": "T11"},
        {"run_id": last, "n": 3, "n_scored": 100, "inputs": ""},
    ]


def test_the_section_names_the_sensors_a_ridge_model_leaves_out_and_why(data):
    rule, table, frame = data
    frame = frame.copy()
    train = frame["run_id"].isin(table.loc[table["role"] == "training", "run_id"]).to_numpy()
    rows = np.flatnonzero(train)
    frame.loc[frame.index[rows[: len(rows) // 10]], "dT3"] = np.nan  # 10 % of the training rows
    frame["dT5"] = 0.0  # a sensor stuck at its reference value
    frame.loc[frame.index[rows[:3]], "dT6"] = np.nan  # a short dropout: T6 stays, its rows go
    art = _fit("temperature_ridge", rule, table, frame).to_dict()
    assert {"T3", "T5"}.isdisjoint(art["key_sensors"]) and "T6" in art["key_sensors"]
    text = sensors_left_out_text(art, table, frame)
    share = 100 * (len(rows) // 10) / len(rows)
    assert text == f"T3: missing on {share:.1f} % of the rows; T5: constant"
    # every sensor read (the shipped twins) or the samples not at hand: nothing to say
    assert sensors_left_out_text(_fit("ridge_global", rule, table, data[2]).to_dict(), table, data[2]) == ""
    assert sensors_left_out_text(art, table, None) == ""
    # an adapted prior reads the prior's sensors, chosen on the prior's data: not these rows'
    assert sensors_left_out_text({**art, "adaptation": {"method": "gain"}}, table, frame) == ""


def test_kind_descriptions_come_from_the_family():
    assert kind_description("grey_box").startswith("Ridge on filtered rises")
    assert kind_description("temperature_ridge").endswith("no speed input.")
    assert "fuzzy" in kind_description("rafi")
    assert kind_description("unknown") == ""


@pytest.mark.parametrize("n_panels", [1, 5, 6, 7])
def test_residual_figure_titles_never_overlap_and_stay_on_the_figure(n_panels):
    """From matplotlib's own layout: every panel title, tick label, axis label and the legend lies
    inside the figure, and no title overlaps another title, an axes or another panel's labels."""
    import matplotlib.pyplot as plt

    from rafi.report import deployed_plot
    from rafi.report.plot_layout import STYLE

    rng = np.random.default_rng(0)
    t = np.arange(0, 3 * 3600, 15.0)
    panels = []
    for k in range(n_panels):
        f = pd.DataFrame(
            {"t_s": t, "measured_um": 10 * (1 - np.exp(-t / 2000)), "residual_um": rng.normal(0, 0.3, len(t))}
        )
        title = f"thermal_log_2026-10-14#{10 + k} (idle): 14.7 \u2192 1.08 \u00b5m"
        if k == 6:  # a run id wider than a panel, without a space to break at
            title = (
                "plant3_line2_machining-center-with-a-very-long-name_2026-10-14_continuous_log#17 (idle): 3.8"
            )
        panels.append({"title": title, "frame": f, "noise_floor": 0.7 if k else np.nan})
    with plt.rc_context(STYLE):
        fig = deployed_plot.build_figure(panels)
        fig.canvas.draw()
        r = fig.canvas.get_renderer()
        page = fig.bbox
        titles = [ax._left_title.get_window_extent(r) for ax in fig.axes if ax.get_title(loc="left")]
        assert len(titles) == n_panels
        boxes = titles + [ax.get_tightbbox(r) for ax in fig.axes] + [fig.legends[0].get_window_extent(r)]
        for b in boxes:
            assert (
                b.x0 >= page.x0 - 0.5
                and b.x1 <= page.x1 + 0.5
                and b.y0 >= page.y0 - 0.5
                and b.y1 <= page.y1 + 0.5
            )
        for i, a in enumerate(titles):
            for b in titles[i + 1 :]:
                assert not a.overlaps(b)
            for ax in fig.axes:  # no title over an axes (its own panel's axes lie below it)
                assert not a.overlaps(ax.bbox)
            assert not a.overlaps(fig.legends[0].get_window_extent(r))
        plt.close(fig)
    assert "\n" in deployed_plot._wrap(panels[0]["title"], 2.0)
    assert "\n" not in deployed_plot._wrap("valid_04500rpm (single): 15.1 \u2192 0.79 \u00b5m", 3.0)
    assert fig_deployed_residuals(panels, fmt="png")[:8] == b"\x89PNG\r\n\x1a\n"
