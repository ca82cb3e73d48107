"""The replay of a recorded log through the safe compensator (rafi.deploy.replay, ``rafi replay``).

Synthetic logs with known truth (the schedules of tests/test_compensator.py): with the limits
wide open the replayed command is the batch ``predict_detail`` to 1e-9 um after each reference
window; with a tight clamp and rate limit every command respects them and the table says which
limit acted (checked against a recursion written here from the documented rule); a sensor
drop-out is held and named.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from project_copy import copy_project, run_module
from test_compensator import WINDOW, _find_runs, _fit, _in_window, _logs

from rafi.deploy.limits import Limits
from rafi.deploy.replay import (
    COLUMNS,
    SUMMARY_COLUMNS,
    replay_log,
    replay_run_ids,
    replay_runs,
    replay_summary,
    summary_frame,
)
from rafi.method.validate import time_ordered

ROOT = Path(__file__).resolve().parents[1]

#: Nothing limits, nothing counts as a fault but a missing value (held for ever).
OPEN = Limits(
    clamp_um=(-1e9, 1e9),
    rate_um_per_s=1e9,
    temp_valid_c=(-1e3, 1e3),
    stuck_s=1e12,
    stuck_change_k=1e9,
    range_margin_k=1e9,
    speed_margin_rpm=1e12,
    hold_s=1e12,
    safe_um=0.0,
    ramp_um_per_s=1.0,
    interval_s=1e9,
    max_interval_um=None,
)


@pytest.fixture(scope="module", params=["run_start", "log_start"])
def data(request):
    rule = request.param
    table, frame = _find_runs(_logs(), [3000, 6000, 9000], rule)
    return rule, table, time_ordered(frame)


def _artefact(model) -> dict:
    return json.loads(json.dumps(model.to_dict()))


def _replay_every_log(frame, artefact, limits, rule=None):
    """Every log replayed; rows back in the frame's order (the replay sorts by ``log_t_s``)."""
    out = []
    for _, log in frame.groupby("log", sort=False):
        got = replay_log(log, artefact, limits, reference_rule=rule)
        got.index = log.sort_values("log_t_s", kind="stable").index
        out.append(got)
    return pd.concat(out).loc[frame.index]


@pytest.mark.parametrize("kind", ["rafi_linear", "grey_box", "ensemble"])
def test_wide_open_limits_replay_the_batch_prediction(data, kind):
    """Any kind, and the CV-weighted ensemble of every kind (each member its own compensator,
    the fault rules once on the union of the sensors they read)."""
    rule, table, frame = data
    model = _fit(kind, rule, table, frame)
    got = _replay_every_log(frame, _artefact(model), OPEN)
    assert list(got.columns) == list(COLUMNS)
    want = model.predict_detail(frame)["predicted_um"].to_numpy(dtype=float)
    after = ~_in_window(frame, rule)
    status, command = got["status"].to_numpy(), got["command_um"].to_numpy(dtype=float)
    # a fault (a key sensor or the speed missing) is the only rule that can act: the last
    # command is held there, also where the batch value is defined (grey_box filters T8)
    art = _artefact(model)
    missing = frame[list(art["key_sensors"])].isna().any(axis=1) | frame["speed_rpm"].isna()
    fault = after & missing.to_numpy()
    assert (
        fault.sum() == 5 and (status[fault] == "hold").all() and (got["fault"].to_numpy()[fault] != "").all()
    )
    held = np.flatnonzero(fault)
    assert (command[held] == command[held - 1]).all()
    assert np.isfinite(want[after & ~fault]).all()  # the batch has a value wherever no input is missing
    ok = after & ~fault
    assert ok.sum() > 0.9 * len(frame) and np.abs(want[ok]).max() > 5.0
    assert (status[ok] == "ok").all() and (got["fault"].to_numpy()[ok] == "").all()
    np.testing.assert_allclose(command[ok], want[ok], rtol=0, atol=1e-9)
    np.testing.assert_allclose(got["model_um"].to_numpy()[ok], want[ok], rtol=0, atol=1e-9)
    assert (status[~after] == "referencing").all() and (command[~after] == 0.0).all()
    assert not got["clamped"].any() and not got["rate_limited"].iloc[1:].any()
    np.testing.assert_allclose(
        got["residual_um"], got["measured_um"] - got["command_um"], rtol=0, atol=0
    )  # the definition
    np.testing.assert_array_equal(got["measured_um"].to_numpy(), frame["dz_um"].to_numpy())
    summary = summary_frame(replay_summary(got), artefact=art)
    assert (summary["kind"] == kind).all() and (summary["model_id"] == art["model_id"]).all()


def test_an_ensemble_is_outside_the_trained_range_where_any_member_is(data):
    """Rule 4 for an ensemble: each member judged by its own ranges and reference, alone. The
    oracle is every member replayed on its own with the same limits: the ensemble is outside on
    exactly the samples where some member is, names the union of their sensors, and the speed
    against the lowest trained top a member names."""
    import re

    rule, table, frame = data
    model = _fit("ensemble", rule, table, frame)
    art = _artefact(model)
    limits = dataclasses.replace(OPEN, range_margin_k=0.3, speed_margin_rpm=-1500.0)
    ens = _replay_every_log(frame, art, limits)
    alone = [_replay_every_log(frame, a, limits) for a in art["members"].values()]

    def named(table):
        causes = table["fault"].fillna("").to_numpy()
        sensors = [set(re.findall(r"(T\d+) rise", c)) for c in causes]
        tops = [[float(v) for v in re.findall(r"above trained (\d+) r/min", c)] for c in causes]
        return sensors, tops

    ok = (ens["status"] != "referencing").to_numpy()
    for m in alone:  # every member's reference windows are the ensemble's
        np.testing.assert_array_equal(m["status"].to_numpy() == "referencing", ~ok)
    either = np.logical_or.reduce([m["outside_range"].to_numpy() for m in alone])
    np.testing.assert_array_equal(ens["outside_range"].to_numpy(), either)
    assert 0.05 < either[ok].mean() < 0.95  # both kinds of sample are there
    sensors, tops = named(ens)
    member_sensors, member_tops = zip(*(named(m) for m in alone))
    for k in np.flatnonzero(ok):
        assert sensors[k] == set().union(*(ms[k] for ms in member_sensors))
        theirs = [v for mt in member_tops for v in mt[k]]
        assert tops[k] == ([min(theirs)] if theirs else [])
    assert any(tops) and any(sensors)


def _expected_commands(t, target, limits):
    """The documented clamp-then-rate rule, from 0 um: ``c_k = c_{k-1} + clip(clip(x_k) - c_{k-1},
    +-rate * min(dt, interval_s))``, with the flags it implies (rate limited: the step was cut;
    clamped: the target was clamped and the step was not cut, i.e. the clamp changed the command)."""
    lo, hi = limits.clamp_um
    c, out, clamped, limited = 0.0, [], [], []
    for k in range(len(t)):
        dt = 0.0 if k == 0 else t[k] - t[k - 1]
        x = min(max(target[k], lo), hi)
        step = limits.rate_um_per_s * min(dt, limits.interval_s)
        limited.append(abs(x - c) > step)
        clamped.append(x != target[k] and not limited[-1])
        c = c + min(max(x - c, -step), step)
        out.append(c)
    return np.array(out), np.array(clamped), np.array(limited)


def test_a_tight_clamp_and_rate_limit_are_respected_and_reported(data):
    rule, table, frame = data
    model = _fit("rafi_linear", rule, table, frame)
    tight = dataclasses.replace(OPEN, clamp_um=(-4.0, 4.0), rate_um_per_s=0.002, interval_s=5.0)
    clean = frame[frame["log"] == "train1.csv"]  # no drop-out in this log
    got = replay_log(clean, _artefact(model), tight)
    t = got["log_t_s"].to_numpy(dtype=float)
    command = got["command_um"].to_numpy(dtype=float)
    assert (np.abs(command) <= 4.0).all()
    # the replay writes once per sample: interval_s is the log's sample period, not the 5 s given
    period = float(np.median(np.diff(t)))
    assert period == 20.0
    tight = dataclasses.replace(tight, interval_s=period)
    steps = np.abs(np.diff(command))
    assert (steps <= 0.002 * np.minimum(np.diff(t), period) + 1e-12).all()
    assert (steps > 0.002 * 5.0 + 1e-12).any()  # more than a 5 s interval would allow
    # the model's own value (wide open) is the target in "ok"; 0 um while referencing
    free = replay_log(clean, _artefact(model), OPEN)
    assert set(got["status"]) == {"referencing", "ok"}
    target = np.where(got["status"] == "ok", free["command_um"], 0.0)
    np.testing.assert_allclose(
        got["model_um"][got["status"] == "ok"], target[got["status"] == "ok"], atol=1e-12
    )
    want, clamped, limited = _expected_commands(t, target, tight)
    np.testing.assert_allclose(command, want, rtol=0, atol=1e-9)
    assert clamped.any() and limited.any()  # both limits act on this log
    np.testing.assert_array_equal(got["clamped"].to_numpy(), clamped)
    np.testing.assert_array_equal(got["rate_limited"].to_numpy(), limited)
    s = summary_frame(replay_summary(got))
    assert s["n_clamped"].sum() == clamped.sum() and s["n_rate_limited"].sum() == limited.sum()
    assert (s["n_ok"] + s["n_referencing"] == s["n_samples"]).all() and s["n_samples"].sum() == len(got)
    ok = (got["status"] == "ok").to_numpy()
    for r in s.itertuples(index=False):
        mine = (got["run_id"] == r.run_id).to_numpy()
        measured = got["measured_um"].to_numpy()[mine]
        model = np.where(ok, free["command_um"], 0.0)[mine]  # 0 um while referencing
        assert r.max_abs_residual_model_um == pytest.approx(np.abs(measured - model).max(), abs=1e-9)
        assert r.max_abs_residual_um == pytest.approx(np.abs(measured - command[mine]).max(), abs=1e-12)
        assert r.max_abs_command_minus_model_um == pytest.approx(
            np.abs(command[mine] - model).max(), abs=1e-9
        )
    assert (s["max_abs_residual_um"] > s["max_abs_residual_model_um"]).any()  # the limits cost accuracy here


def test_a_drop_out_is_held_named_and_counted(data):
    rule, table, frame = data
    model = _fit("rafi_linear", rule, table, frame)  # reads T6, T8, T9
    short_hold = dataclasses.replace(OPEN, hold_s=40.0, ramp_um_per_s=0.01, interval_s=20.0)
    got = replay_log(frame[frame["log"] == "multi.csv"], _artefact(model), short_hold)
    faulty = got[got["fault"] != ""]
    assert set(faulty["fault"]) == {"T8 missing", "speed missing"}
    assert (faulty["fault"] == "T8 missing").sum() == 4 and (faulty["fault"] == "speed missing").sum() == 1
    # 4 samples of 20 s: held for 40 s (2 samples), then ramping to 0 um at 0.01 um/s
    t8 = got[got["fault"] == "T8 missing"]
    assert list(t8["status"]) == ["hold", "hold", "ramp", "ramp"]
    before = got["command_um"].loc[t8.index[0] - 1]
    assert (t8["command_um"].iloc[:2] == before).all()
    ramp = t8["command_um"].iloc[2:].to_numpy()
    np.testing.assert_allclose(np.abs(np.diff(np.r_[before, ramp])), 0.2, rtol=0, atol=1e-12)
    s = summary_frame(replay_summary(got))
    assert list(s.columns) == list(SUMMARY_COLUMNS)
    by_run = got.groupby("run_id", sort=False)
    row = s.set_index("run_id").loc[t8["run_id"].iloc[0]]
    assert row["faults"] == "missing: 4 (first: T8 missing); speed_missing: 1 (first: speed missing)"
    assert s["n_samples"].sum() == len(got) == by_run.size().sum()
    statuses = [
        c for c in s.columns if c.startswith("n_") and c[2:] in ("off", "referencing", "ok", "hold", "ramp")
    ]
    assert (s[statuses].sum(axis=1) == s["n_samples"]).all()
    assert s["n_hold"].sum() == (got["status"] == "hold").sum() == 3  # the speed sample held too


def _class_of(cause: str) -> str:
    """The fault class of one cause by the wording docs/deploy.md documents (an oracle written
    here, not rafi.deploy.metrics)."""
    if cause == "speed missing":
        return "speed_missing"
    if cause.endswith(" missing"):
        return "missing"
    if "outside trained range" in cause or "above trained" in cause:
        return "outside_range"
    raise AssertionError(cause)


def test_faults_are_one_entry_per_class_however_many_values_the_messages_name(data):
    """The trained range with no margin fires on many samples of the multi-speed log, each message
    with its own measured rise or speed; the drop-out adds two classes. Per run, ``faults`` has
    one entry per class: the samples with a cause of the class and its first cause."""
    rule, table, frame = data
    model = _fit("rafi_linear", rule, table, frame)
    edge = dataclasses.replace(OPEN, range_margin_k=0.0, speed_margin_rpm=0.0, hold_s=40.0, interval_s=20.0)
    multi, art = frame[frame["log"] == "multi.csv"], _artefact(model)
    got = replay_log(multi, art, edge)
    s = summary_frame(replay_summary(got)).set_index("run_id")
    many = 0
    for rid, g in got.groupby("run_id", sort=False):
        want: dict = {}
        for fault in g["fault"]:
            causes = [c for c in fault.split("; ") if c]
            for kind in dict.fromkeys(_class_of(c) for c in causes):
                first = next(c for c in causes if _class_of(c) == kind)
                n, example = want.get(kind, (0, first))
                want[kind] = (n + 1, example)
        assert s.loc[rid, "faults"] == "; ".join(f"{k}: {n} (first: {c})" for k, (n, c) in want.items())
        many = max(many, g["fault"][g["fault"] != ""].nunique())
    assert many > 50  # distinct messages in one run: each was an entry of its own before
    assert s["faults"].str.contains("outside_range: ").any() and s["faults"].str.contains("missing: 4 ").any()
    # deterministic: the same replay gives the same bytes
    again = summary_frame(replay_summary(replay_log(multi, art, edge)))
    assert again.to_csv(index=False) == s.reset_index()[list(again.columns)].to_csv(index=False)


def test_replay_runs_feeds_the_run_s_log_from_power_on(data):
    rule, table, frame = data
    model = _fit("grey_box", rule, table, frame)
    art = _artefact(model)
    multi = table[table["file"] == "multi.csv"]["run_id"].astype(str).tolist()
    assert len(multi) >= 3
    whole = replay_log(frame[frame["log"] == "multi.csv"], art, OPEN)
    got = replay_runs(frame, [multi[2], multi[1]], art, OPEN)
    for rid in (multi[2], multi[1]):
        a = got[got["run_id"] == rid].reset_index(drop=True)
        b = whole[whole["run_id"] == rid].reset_index(drop=True)
        pd.testing.assert_frame_equal(a, b)
    assert list(dict.fromkeys(got["run_id"])) == [multi[2], multi[1]]
    # replayed alone (no history: power-on at the run's start) the filters start elsewhere
    alone = replay_log(frame[frame["run_id"] == multi[2]], art, OPEN)
    mine = got[got["run_id"] == multi[2]]
    assert np.nanmax(np.abs(alone["command_um"].to_numpy() - mine["command_um"].to_numpy())) > 0.1
    with pytest.raises(KeyError):
        replay_runs(frame, ["nope"], art, OPEN)
    with pytest.raises(ValueError, match="one log"):
        replay_log(frame, art, OPEN)
    assert WINDOW == 60.0


# --------------------------------------------------------------------------- the report


def test_the_report_shows_the_replay_with_the_limits_in_force(tmp_path):
    """The report's fixture replayed with a tight clamp: the section names the run, says what
    each limit did with the summary's numbers, and embeds the figure of rule report_figures."""
    from test_report import FIXTURE, _settings, _upstream

    from rafi.artefact import write_csv_atomic, write_parquet_atomic
    from rafi.report.context import build_context
    from rafi.report.inputs import result_paths
    from rafi.report.render import render_html

    results = tmp_path / "tapping-center-a"
    shutil.copytree(FIXTURE, results)
    frame, table = pd.read_parquet(results / "runs.parquet"), pd.read_csv(results / "runs.csv")
    files = dict(zip(table["run_id"], table["file"]))
    frame["log"], frame["log_t_s"] = frame["run_id"].map(files), frame["t_s"]  # one run per log
    artefact = json.loads((results / "comparison" / "best_model.json").read_text())
    _, settings = _settings()
    settings["deploy"] = {**settings["deploy"], "clamp_um": [-6.0, 6.0]}
    limits = Limits.from_settings(settings["deploy"])
    # by default every validation run is replayed (issue 46: a run beyond the trained speeds too)
    ids = replay_run_ids(table, settings["deploy"]["replay_roles"])
    validation = table.loc[table["role"].str.startswith("validation"), "run_id"].tolist()
    assert ids == validation and "multi-1" in ids
    ids = ["multi-1"]
    replayed = replay_runs(frame, ids, artefact, limits)
    summary = summary_frame(replay_summary(replayed), artefact=artefact)
    (results / "deploy").mkdir()
    write_parquet_atomic(replayed, results / "deploy" / "replay.parquet")
    write_csv_atomic(summary, results / "deploy" / "replay_summary.csv")
    dirs = _upstream(results, settings)
    ctx = build_context(result_paths(results), dirs, machine="tapping-center-a", settings=settings)
    html = render_html(ctx)
    row = summary.iloc[0]
    assert row["n_clamped"] > 0 and (np.abs(replayed["command_um"]) <= 6.0).all()
    assert ctx["section_by_id"]["replay"]["title"] == "The model on the machine: replay of multi-1"
    assert "The model on the machine: replay of multi-1" in html
    assert f"clamped the command on {row['n_clamped']} of {row['n_samples']} samples" in html
    assert "[\u22126.0, 6.0]" in html  # the clamp in force, from the settings
    assert "replay/replay/multi-1" in ctx["figures_used"] and 'id="fig-replay-1"' in html
    # the champion of the fixture's registry is the replayed model
    assert "the model on the machine</b> after this run" in html
    # without the replay's table the section is absent
    (results / "deploy" / "replay_summary.csv").unlink()
    ctx = build_context(result_paths(results), dirs, machine="tapping-center-a", settings=settings)
    assert "replay" not in ctx["section_by_id"] and ctx["replay"] is None


# --------------------------------------------------------------------------- rule and command

MACHINE = "tapping-center-a"
KEEP = ("train_03000rpm", "train_09000rpm", "train_15000rpm", "multi_condition")


@pytest.mark.slow
def test_rule_replay_and_rafi_replay_on_a_trimmed_project(tmp_path):
    """The real Snakefile builds deploy/replay.* (byte-identical on a forced rerun); ``rafi replay``
    on the same results writes the same samples, prints what each limit did, and refuses an
    unknown run or a machine without results in one line."""
    proj = copy_project(tmp_path / "proj")
    raw = proj / "raw" / MACHINE
    raw.mkdir(parents=True)
    for stem in KEEP:
        shutil.copy2(ROOT / "raw" / MACHINE / f"{stem}.csv", raw / f"{stem}.csv")
    target = f"results/{MACHINE}/deploy/replay_summary.csv"
    done = run_module(proj, "snakemake", "--cores", "2", target)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    deploy = proj / "results" / MACHINE / "deploy"
    table, summary = pd.read_parquet(deploy / "replay.parquet"), pd.read_csv(deploy / "replay_summary.csv")
    assert list(table.columns) == list(COLUMNS) and list(summary.columns) == list(SUMMARY_COLUMNS)
    assert (
        list(summary["run_id"]) == ["multi_condition"] and summary["n_samples"].iloc[0] == len(table) > 1000
    )
    best = json.loads((proj / "results" / MACHINE / "comparison" / "best_model.json").read_text())
    assert summary["model_id"].iloc[0] == best["model_id"]
    first = {p.name: p.read_bytes() for p in deploy.iterdir()}
    done = run_module(proj, "snakemake", "--cores", "2", "--forcerun", "replay", target)
    assert done.returncode == 0 and "replay" in done.stderr, done.stderr[-3000:]
    assert {p.name: p.read_bytes() for p in deploy.iterdir()} == first

    done = run_module(proj, "rafi.cli", "replay", "--machine", MACHINE, "--out", "cli")
    assert done.returncode == 0, done.stderr
    assert (
        f"multi_condition: {len(table)} samples" in done.stdout
        and "clamp [-50, 50] um acted on" in done.stdout
    )
    cli = pd.read_csv(proj / "cli" / "multi_condition.csv", keep_default_na=False, na_values=[""])
    assert (proj / "cli" / "multi_condition.png").stat().st_size > 10_000
    for col in ("log_t_s", "measured_um", "model_um", "command_um", "residual_um"):
        np.testing.assert_allclose(cli[col], table[col], rtol=1e-12, atol=1e-12)
    assert list(cli["status"]) == list(table["status"])
    pd.testing.assert_frame_equal(pd.read_csv(proj / "cli" / "summary.csv"), summary)

    done = run_module(proj, "rafi.cli", "replay", "--machine", MACHINE, "--run", "nope")
    assert done.returncode == 64 and "unknown run id(s) nope; runs.csv has: multi_condition" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1
    done = run_module(proj, "rafi.cli", "replay", "--machine", "machining-center-b")
    assert done.returncode == 64 and "run `snakemake --cores 2 tables` first" in done.stderr
    done = run_module(proj, "rafi.cli", "replay", "--machine", "nosuch")
    assert done.returncode == 64 and done.stderr.startswith(
        "rafi replay: unknown machine nosuch; config.yaml has:"
    )


@pytest.fixture(scope="module")
def beyond_training():
    """Trained at 3000 and 6000 r/min; validated at 4500 r/min (inside what was trained) and for
    hours at 9000 r/min (hotter than ever: tests/test_envelope.py's ``hotter_than_ever``)."""
    from rafi.twin.synthetic_logs import schedule_log
    from rafi.twin.synthetic_runs import runs_of_logs

    rest = (0, 180)
    logs = {
        f"train{i}.csv": schedule_log([rest, (speed, 2 * 3600), (0, 3600)], period_s=20, seed=i)[0]
        for i, speed in enumerate((3000, 6000))
    }
    logs["inside.csv"] = schedule_log([rest, (4500, 3600)], period_s=20, seed=7)[0]
    logs["hot.csv"] = schedule_log([rest, (9000, 5 * 3600)], period_s=20, seed=9)[0]
    table, frame = runs_of_logs(logs, training_speeds_rpm=[3000, 6000], reference_window_s=60)
    roles = table.set_index("run_id")["role"]
    assert roles["inside"].startswith("validation") and roles["hot"].startswith("validation")
    return table, time_ordered(frame)


@pytest.mark.parametrize("runaway", [False, True])
def test_samples_held_at_the_envelope_edge_are_the_same_in_validation_and_replay(beyond_training, runaway):
    """A ridge whose inputs leave the training envelope (9000 r/min, trained to 6000) or whose fit
    ran away (its coefficients x 40, as in tests/test_envelope.py) is held at the envelope's edge
    on the same samples in the batch validation and in the replay after the reference window; a
    run inside the envelope has none."""
    import warnings

    from rafi.method.validate import validate_runs
    from rafi.twin.synthetic_runs import small_family_model

    table, frame = beyond_training
    model = small_family_model(
        "dynamic",
        reference_rule="run_start",
        reference_window_s=60,
        filter_restart_gap_s=3600,
        alphas=(1e-8,),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit(table, frame)
    if runaway:
        model.coef_ = model.coef_ * 40.0
    summary, residuals = validate_runs(model, table, frame)
    runs = ["inside", "hot"]
    replayed = replay_runs(frame, runs, _artefact(model), OPEN)
    counts = summary_frame(replay_summary(replayed)).set_index("run_id")["n_outside_envelope"]
    batch = summary.set_index("run_id")["n_outside_envelope"]
    for rid in runs:
        rep = replayed[replayed["run_id"] == rid]
        res = residuals[residuals["run_id"] == rid]
        np.testing.assert_array_equal(rep["t_s"].to_numpy(), res["t_s"].to_numpy())
        after = rep["status"].to_numpy() != "referencing"
        assert not rep["outside_envelope"].to_numpy()[~after].any()  # 0 um at the reference
        np.testing.assert_array_equal(
            rep["outside_envelope"].to_numpy()[after], res["outside_envelope"].to_numpy()[after]
        )
        assert counts[rid] == int(res["outside_envelope"].to_numpy()[after].sum())
        assert batch[rid] == int(res["outside_envelope"].sum())  # every sample is measured here
    assert counts["hot"] > 0.3 * (replayed["run_id"] == "hot").sum()  # most of the hot run is held
    if not runaway:
        assert counts["inside"] == 0 and batch["inside"] == 0
