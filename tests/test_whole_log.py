"""Whole-log dynamics (issue 12): filters over whole logs, no target leak, grids from the data."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rafi import SENSORS as _SENSORS
from rafi.family.crossval import cross_validate
from rafi.family.dynamic import DynamicRidge
from rafi.family.features import lowpass_runs
from rafi.family.grey_box import GreyBox
from rafi.family.grids import edge_flags, resolve
from rafi.family.ridge_global import RidgeGlobal
from rafi.family.whole_log import filtered_rises, layout, lowpass_log
from rafi.twin.synthetic_runs import runs_of_logs

SENSORS = list(_SENSORS)
PERIOD = 30.0
WINDOW = 60.0
SHORT_GAP = 600.0  # carried through (< filter_restart_gap_s)
LONG_GAP = 3 * 3600.0  # restarts the filters
RESTART = 3600.0
# (duration s, speed r/min) per piece; None = a gap
SCHEDULE = [
    (120, 0),
    (4 * 3600, 3000),
    (2 * 3600, 0),
    (3 * 3600, 6000),
    (3600, 0),
    (SHORT_GAP, None),
    (2 * 3600, 9000),
    (3600, 0),
    (LONG_GAP, None),
    (2 * 3600, 4500),
    (3600, 0),
    (2 * 3600, 3000),
]
SENSOR_TAUS = np.linspace(400.0, 3000.0, 16)


def _continuous_log(seed: int = 0) -> pd.DataFrame:
    """A clean frame (``rafi.method.clean`` layout) of one log with cool-downs, a short and a
    long gap; temperatures are first-order responses to the heat input over the whole log
    (continuous through the gaps), the displacement a lagged sum of them."""
    rng = np.random.default_rng(seed)
    t_all = np.arange(0.0, sum(d for d, _ in SCHEDULE), PERIOD)
    speed = np.zeros(len(t_all))
    logged = np.ones(len(t_all), dtype=bool)
    segment = np.zeros(len(t_all), dtype=int)
    start, seg = 0.0, 0
    for dur, n in SCHEDULE:
        inside = (t_all >= start) & (t_all < start + dur)
        if n is None:
            logged[inside] = False
            seg += 1
        else:
            speed[inside] = n
            segment[inside] = seg
        start += dur
    heat = (speed / 9000.0) ** 1.3
    codes = np.zeros(len(t_all), dtype=int)
    temps = np.column_stack(
        [20.0 + 3.0 * lowpass_runs(heat, t_all, codes, [tau])[:, 0] for tau in SENSOR_TAUS]
    )
    temps += rng.normal(0.0, 0.01, temps.shape)
    lag = lowpass_runs(temps - 20.0, t_all, codes, [1500.0])
    disp = 5.0 + lag @ np.linspace(1.0, -0.3, 16) + rng.normal(0.0, 0.05, len(t_all))
    f = pd.DataFrame(
        {
            "time": pd.Timestamp("2026-01-01") + pd.to_timedelta(t_all, unit="s"),
            "t_s": t_all,
            "speed_rpm": speed + rng.normal(0.0, 2.0, len(t_all)) * (speed > 0),
        }
    )
    for i, s in enumerate(SENSORS):
        f[s] = temps[:, i]
    f["disp_um"] = disp
    f["segment"] = segment
    return f.loc[logged].reset_index(drop=True)


def _runs(rule: str):
    clean = _continuous_log()
    table, frame = runs_of_logs(
        {"log.csv": clean}, reference_rule=rule, reference_window_s=WINDOW, min_constant_s=3600
    )
    return clean, table, frame


def _oracle(clean: pd.DataFrame, frame: pd.DataFrame, rule: str, tau: float) -> np.ndarray:
    """One filter over the joined log (restarted only after the long gap), referenced to each
    run's reference window; rows of ``frame``."""
    t = clean["t_s"].to_numpy()
    piece = np.r_[0, np.cumsum(np.diff(t) > RESTART)]
    filt = lowpass_runs(clean[SENSORS].to_numpy(), t, piece, [tau])
    at = pd.Series(np.arange(len(t)), index=t)
    pos = at.loc[frame["log_t_s"].to_numpy()].to_numpy()  # clean row of each runs-frame row
    out = np.empty((len(frame), 16))
    key = frame["run_id"] if rule == "run_start" else frame["segment"]
    for _, rows in frame.groupby(key, sort=False).indices.items():
        p = np.sort(pos[rows])
        window = p[t[p] < t[p[0]] + WINDOW - 1e-9]
        out[rows] = filt[pos[rows]] - np.median(filt[window], axis=0)
    return out


@pytest.mark.parametrize("rule", ["run_start", "log_start"])
def test_features_over_a_whole_log_equal_one_filter_over_the_joined_runs(rule):
    """Known truth: the runs frame's features equal one filter over the joined log, to rounding."""
    clean, table, frame = _runs(rule)
    assert {"log", "log_t_s", "segment"} <= set(frame.columns)
    assert len(table) >= 8 and frame["segment"].nunique() == 3
    shuffled = frame.sample(frac=1.0, random_state=1)
    lay = layout(shuffled, rule=rule, window_s=WINDOW, restart_gap_s=RESTART)
    for tau in (600.0, 2400.0):
        got = np.empty((len(shuffled), 16))
        got[lay.order] = filtered_rises(shuffled, lay, SENSORS, [tau])
        want = _oracle(clean, shuffled, rule, tau)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    # tau = 0 is the rise itself, exactly
    zero = np.empty((len(shuffled), 16))
    zero[lay.order] = filtered_rises(shuffled, lay, SENSORS, [0.0])
    assert np.array_equal(zero, shuffled[[f"d{s}" for s in SENSORS]].to_numpy())


def test_filter_state_is_carried_through_cool_downs_and_short_gaps_only():
    clean, table, frame = _runs("run_start")
    lay = layout(frame, rule="run_start", window_s=WINDOW, restart_gap_s=RESTART)
    t = lay.t
    restarts = t[lay.restart]
    assert len(restarts) == 2 and restarts[0] == 0.0  # the log start and after the long gap
    f = lowpass_log(frame[SENSORS].to_numpy()[lay.order], t, lay.restart, [2400.0])
    after_long = np.flatnonzero(lay.restart)[1]
    x = frame[SENSORS].to_numpy()[lay.order]
    assert np.array_equal(f[after_long], x[after_long])  # settled on the first sample
    after_short = np.flatnonzero(np.diff(t) > 2 * PERIOD)[0] + 1
    assert np.abs(f[after_short] - x[after_short]).max() > 0.05  # carried: still lagging
    # a run that starts at the end of a cool-down is 0 at its reference window, not settled after it
    feats = filtered_rises(frame, lay, SENSORS, [2400.0])
    runs = frame["run_id"].to_numpy()[lay.order]
    warm = table.loc[table["speed_rpm"] > 5000, "run_id"].iloc[0]
    rows = np.flatnonzero(runs == warm)
    assert np.abs(np.median(feats[rows[:2]], axis=0)).max() < 1e-12
    assert np.abs(feats[rows[-1]]).max() > 0.1


def test_a_cold_single_run_log_gives_the_per_run_features():
    """A log that starts settled and holds one run: whole-log and per-run filters agree."""
    clean, table, frame = _runs("run_start")
    first = frame.loc[frame["run_id"] == table["run_id"].iloc[0]]
    whole = layout(first, rule="run_start", window_s=WINDOW, restart_gap_s=RESTART)
    per_run = layout(
        first.drop(columns=["log", "log_t_s"]), rule="run_start", window_s=WINDOW, restart_gap_s=0
    )
    a = filtered_rises(first, whole, SENSORS[:3], [600.0])
    b = filtered_rises(first, per_run, SENSORS[:3], [600.0])
    # per run: settled on dT[0]; whole log: settled on T[0], minus the window median -> same up to the noise
    assert np.abs(a - b).max() < 0.05


def _leak_models():
    ref = {"rule": "run_start", "window_s": WINDOW}
    return [
        lambda: RidgeGlobal(alphas=[1e-4, 1e-2], reference=ref),
        lambda: DynamicRidge(taus_s=[0, 600, 2400], max_taus=2, alphas=[1e-4, 1e-2], reference=ref),
        lambda: GreyBox(taus_s=[0, 600], speed_taus_s=[300, 1200], alphas=[1e-4, 1e-2], reference=ref),
    ]


@pytest.mark.parametrize("k", range(3))
def test_no_target_leaks_from_runs_that_are_not_training(k):
    """Every non-training run's dz replaced by NaN or garbage: bit-identical fits and CV."""
    _, table, frame = _runs("run_start")
    train = set(table.loc[table["role"] == "training", "run_id"])
    assert 3 <= len(train) < len(table)
    other = ~frame["run_id"].isin(train)
    factory = _leak_models()[k]
    a = factory().fit(table, frame)
    cv_a = cross_validate(factory, table, frame)
    for garbage in (np.nan, 1e6):
        poisoned = frame.copy()
        poisoned.loc[other, "dz_um"] = garbage
        poisoned.loc[other, "disp_um"] = garbage
        b = factory().fit(table, poisoned)
        assert np.array_equal(a.coef_, b.coef_) and a.alpha_ == b.alpha_ and a.taus_ == b.taus_
        pd.testing.assert_frame_equal(cv_a, cross_validate(factory, table, poisoned))


def test_cross_validation_fits_see_whole_logs_but_learn_from_their_training_runs():
    _, table, frame = _runs("run_start")
    seen = []

    class Spy(RidgeGlobal):
        def fit(self, runs_table, runs_frame):
            seen.append((set(runs_table.loc[runs_table["role"] == "training", "run_id"]), len(runs_frame)))
            return super().fit(runs_table, runs_frame)

    cv = cross_validate(lambda: Spy(alphas=[1e-3]), table, frame)
    train = set(table.loc[table["role"] == "training", "run_id"])
    assert len(seen) == len(train) == len(cv)
    for (fitted_on, n_rows), held in zip(seen, cv["test_runs"]):
        assert fitted_on == train - {held} and n_rows == len(frame)


def test_auto_grids_scale_with_the_data_and_lists_are_kept():
    assert resolve("dynamic_taus_s", "auto", 5.0, 14400.0) == [0, 20, 60, 180, 540, 1600, 4900, 15000]
    assert resolve("grey_box_taus_s", "auto", 5.0, 14400.0) == [0, 120, 600]
    assert resolve("grey_box_speed_taus_s", "auto", 5.0, 14400.0) == [60, 180, 540, 1600]
    assert resolve("grey_box_centrifugal_lags_s", "auto", 15.0, 14400.0) == [0, 15, 30, 60]
    # a 1 h run at 60 s: every value from a few samples up to about the run
    assert resolve("dynamic_taus_s", "auto", 60.0, 3600.0) == [0, 240, 720, 2200]
    assert resolve("dynamic_taus_s", [0, 300], 5.0, 14400.0) == [0.0, 300.0]
    with pytest.raises(ValueError, match="auto"):
        resolve("dynamic_taus_s", "automatic", 5.0, 14400.0)


def test_edge_flags_name_every_choice_at_a_grid_edge():
    grids = {
        "alpha": [1e-4, 1e-2, 1.0],
        "dynamic_taus_s": [0, 60, 600, 4800],
        "grey_box_centrifugal_lags_s": [0, 5, 20],
    }
    flags = edge_flags("dynamic", {"alpha": 1.0, "dynamic_taus_s": [0, 4800]}, grids)
    assert len(flags) == 2 and "alpha 1 is the largest" in flags[0] and "4800 s is the largest" in flags[1]
    assert edge_flags("dynamic", {"alpha": 1e-2, "dynamic_taus_s": [0, 600]}, grids) == []
    assert "smallest non-zero" in edge_flags("dynamic", {"dynamic_taus_s": [60]}, grids)[0]
    assert edge_flags("g", {"grey_box_centrifugal_lags_s": 0.0}, grids) == []  # no lag: a natural bound
    assert "largest" in edge_flags("g", {"grey_box_centrifugal_lags_s": 20.0}, grids)[0]


def test_a_lag_longer_than_the_grid_is_flagged_and_recorded(tmp_path):
    """dz lags the sensors by 1500 s; a grid that stops at 300 s ends at its edge: flagged."""
    _, table, frame = _runs("run_start")
    ref = {"rule": "run_start", "window_s": WINDOW}
    # the rises' grid alone: the heat input's speed filters would take up part of the lag
    m = DynamicRidge(
        taus_s=[0, 60, 300], max_taus=1, alphas=[1e-4, 1e-2], reference=ref, heat_input=False
    ).fit(table, frame)
    assert m.taus_ == [300.0]
    assert any("300 s is the largest" in f for f in m.grid_edges_)
    d = m.to_dict()
    assert d["selected"]["grid_edges"] == m.grid_edges_
    assert DynamicRidge.from_dict(d).grid_edges_ == m.grid_edges_
    auto = DynamicRidge(alphas=[1e-4, 1e-2], reference=ref).fit(table, frame)
    assert auto.to_dict()["hyperparameters"]["taus_s"] == "auto"
    assert auto.grids_["dynamic_taus_s"][-1] >= 3600.0  # up to about the run length


def test_a_choice_at_a_grid_edge_is_said_where_people_read_what_cv_chose():
    from rafi.family.compare import describe_selection

    _, table, frame = _runs("run_start")
    ref = {"rule": "run_start", "window_s": WINDOW}
    # the rises' grid alone: the heat input's speed filters would take up part of the lag
    m = DynamicRidge(
        taus_s=[0, 60, 300], max_taus=1, alphas=[1e-4, 1e-2], reference=ref, heat_input=False
    ).fit(table, frame)
    text = describe_selection(m)
    assert "AT A GRID EDGE" in text and "300 s is the largest" in text
    m.grid_edges_ = []  # the same fitted model with nothing at an edge: nothing said
    assert "GRID EDGE" not in describe_selection(m)


# --------------------------------------------------------------------------- shared features


def test_a_logs_filtered_values_do_not_depend_on_the_logs_before_it():
    """Known truth: a log filtered alone. After another log the values are the same to the last
    bit, also where a block of the vectorised sum ends on a tie (5 s steps, tau 15 s: 1800 rows
    sum to exactly 600), which the block count decides by rounding."""
    rng = np.random.default_rng(1)
    for _ in range(5):
        n_before, n_log = int(rng.integers(300, 3000)), 2500
        t_before = np.cumsum(rng.uniform(0.5, 2.0, n_before))
        t_log = np.arange(n_log) * 5.0
        x = rng.normal(size=(n_before + n_log, 3)).cumsum(axis=0)
        restart = np.zeros(n_before + n_log, dtype=bool)
        restart[[0, n_before]] = True
        both = lowpass_log(x, np.r_[t_before, t_log], restart, [15.0, 7.5, 600.0])
        alone = lowpass_log(x[n_before:], t_log, restart[n_before:], [15.0, 7.5, 600.0])
        assert np.array_equal(both[n_before:], alone)


def _several_logs():
    """Two logs with several training runs each; a dropout of T8 in one training run, so the
    usable sensors differ between CV folds."""
    logs = {"a.csv": _continuous_log(0), "b.csv": _continuous_log(1)}
    table, frame = runs_of_logs(
        logs, reference_rule="run_start", reference_window_s=WINDOW, min_constant_s=3600
    )
    train = table.loc[table["role"] == "training", "run_id"].tolist()
    rows = np.flatnonzero(frame["run_id"] == train[1])[50:60]
    frame.loc[rows, ["T8", "dT8"]] = np.nan
    return table, frame, train


@pytest.mark.parametrize("k", range(3))
def test_shared_features_change_no_fit_and_no_fold(k, monkeypatch):
    """Known truth: every fit computing its own features (no memo). With the features shared by
    the fits of a scope, the fitted artefact and every CV fold are bit-identical."""
    import contextlib

    from rafi.family import crossval
    from rafi.family.feature_memo import sharing_features
    from rafi.family.whole_log import rows_of_logs

    table, frame, train = _several_logs()
    assert frame["log"].nunique() == 2 and len(train) >= 4
    factory = _leak_models()[k]
    universe = frame.loc[rows_of_logs(frame, train)]
    alone = factory().fit(table, frame).to_dict()
    with sharing_features(universe) as memo:
        shared = factory().fit(table, frame).to_dict()
        shared_cv = cross_validate(factory, table, frame)
    assert memo._features and memo._grams  # the fits did share
    for d in (alone, shared):
        d.pop("created")
    assert shared == alone
    monkeypatch.setattr(crossval, "sharing_features", lambda frame: contextlib.nullcontext())
    pd.testing.assert_frame_equal(shared_cv, cross_validate(factory, table, frame), check_exact=True)


def test_only_whole_logs_of_the_universe_are_served():
    from rafi.family.feature_memo import FeatureMemo

    table, frame, train = _several_logs()
    memo = FeatureMemo(frame)
    log_b = frame.loc[frame["log"] == "b.csv"]
    assert np.array_equal(memo.positions(log_b), np.flatnonzero(frame["log"] == "b.csv"))
    assert memo.positions(frame.iloc[::-1]) is not None  # any row order
    assert memo.positions(log_b.iloc[:-1]) is None  # part of a log
    assert memo.positions(log_b.drop(columns=["log_t_s"])) is None  # per-run frame
    changed = log_b.copy()
    changed["speed_rpm"] += 1.0
    assert memo.positions(changed) is None  # other values under the same labels
    assert memo.positions(log_b.reset_index(drop=True)) is None  # labels not of the universe rows


def test_the_cv_memo_key_sees_the_inputs_of_every_run_of_a_training_log():
    """A filter runs through the other runs of a log: their temperatures are part of what the CV
    reads, so they are part of its memo key (rafi.family.cv_memo)."""
    from rafi.family.cv_memo import training_content

    table, frame, train = _several_logs()
    key = training_content(table, frame)
    other = table.loc[table["role"] != "training", "run_id"].iloc[0]
    training_logs = set(frame.loc[frame["run_id"].isin(train), "log"])
    assert frame.loc[frame["run_id"] == other, "log"].iloc[0] in training_logs
    changed = frame.copy()
    changed.loc[changed["run_id"] == other, "T3"] += 0.01
    assert training_content(table, changed) != key
