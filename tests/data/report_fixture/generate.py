"""Generate a small, realistic ``results/<machine>/`` tree for the report tests.

The tables follow ``docs/design.md`` exactly; the numbers come from a toy
first-order thermal model (not the project's digital twin), fitted with plain
NumPy least squares, so the report has consistent inputs without the pipeline.

    python tests/data/report_fixture/generate.py            # committed fixture (120 s grid)
    python tests/data/report_fixture/generate.py OUT --sample-period-s 5   # full-size (benchmark)
    python tests/data/report_fixture/generate.py --verdict   # comparison/verdict.csv only

``comparison/`` and ``registry/`` come from the real producers (``rafi.family.compare.run_family``
and two nights of ``rafi.ops.decide.run_decide``), ``validation/`` from ``rafi.method.validate``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import numpy as np
import pandas as pd

MACHINE = "tapping-center-a"
SENSORS = [f"T{i}" for i in range(1, 17)]
TRAIN = [3000, 6000, 9000, 12000, 15000, 18000]
PAPER_T_EQ = {3000: 10160, 6000: 9675, 9000: 6895, 12000: 6615, 15000: 5385, 18000: 5560}
PAPER_RMSE = {3000: 0.639, 6000: 0.418, 9000: 0.277, 12000: 0.283, 15000: 0.780, 18000: 0.421}
PAPER_RES = {4500: 10.0287, 8000: 5.6419, 10500: 5.3598, 13500: 3.4792, 16500: 9.2334}
TERMS = ["1", "x1", "x2", "x3", "x1*x2", "x1*x3", "x2*x3", "x1^2", "x2^2", "x3^2", "x1*x2*x3"]
KEY = ["T6", "T8", "T9"]
# rise of each sensor at 18000 r/min (K) and its lag factor relative to the displacement
GAIN = np.array([1.5, 1.4, 1.6, 2.0, 1.2, 9.0, 2.2, 7.5, 8.0, 5.0, 0.8, 1.1, 0.9, 3.0, 1.0, 8.5])
LAG = np.array([1.6, 1.7, 1.5, 1.4, 1.3, 1.0, 1.5, 1.05, 0.95, 1.2, 2.0, 1.8, 1.9, 1.3, 1.8, 1.1])


def amp(n):  # plateau displacement (um) at speed n
    return 6.0 + 22.0 * (np.asarray(n, float) / 18000.0) ** 0.8


def tau_of(n):  # time constant (s): t_eq(5 %) = 3 tau ~ paper Table 1
    return np.interp(n, TRAIN, [PAPER_T_EQ[s] / 3.0 for s in TRAIN])


def simulate(speed, dt, rng, drift=0.0):
    """First-order response to a (possibly varying) speed profile."""
    n = len(speed)
    temps = np.zeros((n, 16))
    z = np.zeros(n)
    ts = np.zeros(16)
    zs = 0.0
    for i in range(n):
        s = speed[i]
        frac = (s / 18000.0) ** 0.9
        tau = tau_of(max(s, 3000))
        ts += (GAIN * frac - ts) * dt / (tau * LAG)
        zs += (amp(s) * (s > 0) - zs) * dt / tau
        temps[i] = ts
        z[i] = zs + drift * i * dt / 3600.0
    z += 1.5e-9 * speed ** 2  # centrifugal growth (BT30): a jump at speed changes
    temps = 22.0 + temps + rng.normal(0, 0.03, temps.shape)
    z = z + rng.normal(0, 0.25, n)
    return temps, z


def terms_matrix(x):
    x1, x2, x3 = x[:, 0], x[:, 1], x[:, 2]
    return np.column_stack([np.ones(len(x)), x1, x2, x3, x1 * x2, x1 * x3, x2 * x3,
                            x1 ** 2, x2 ** 2, x3 ** 2, x1 * x2 * x3])


def tri_weights(speed, centres):
    c = np.asarray(centres, float)
    s = np.clip(np.asarray(speed, float), c[0], c[-1])
    w = np.zeros((len(s), len(c)))
    k = np.clip(np.searchsorted(c, s, side="right") - 1, 0, len(c) - 2)
    frac = (s - c[k]) / (c[k + 1] - c[k])
    w[np.arange(len(s)), k] = 1 - frac
    w[np.arange(len(s)), k + 1] += frac
    return w, (np.asarray(speed) < c[0]) | (np.asarray(speed) > c[-1])


def generate(out: Path, sample_period_s: float = 120.0, seed: int = 7,
             family: bool = True) -> None:
    rng = np.random.default_rng(seed)
    dt = sample_period_s
    base = out / MACHINE
    (base / "rank").mkdir(parents=True, exist_ok=True)
    (base / "fit").mkdir(exist_ok=True)
    (base / "validation").mkdir(exist_ok=True)
    t0 = pd.Timestamp("2026-03-02T07:30:00")
    runs, frames = [], []

    def add_run(run_id, file, role, speed, drift=0.0, seg=0):
        nonlocal t0
        temps, z = simulate(speed, dt, rng, drift)
        n = len(speed)
        t_s = np.arange(n) * dt
        ref = t_s <= 60.0
        ref_T = np.median(temps[ref], axis=0)
        ref_z = np.median(z[ref])
        f = pd.DataFrame({"run_id": run_id, "t_s": t_s,
                          "time": t0 + pd.to_timedelta(t_s, unit="s"), "speed_rpm": speed})
        for i, s in enumerate(SENSORS):
            f[s] = temps[:, i].round(2)
        f["disp_um"] = (z + 3.1).round(3)
        for i, s in enumerate(SENSORS):
            f["d" + s] = (f[s] - ref_T[i]).round(2)
        f["dz_um"] = (f["disp_um"] - (ref_z + 3.1)).round(3)
        frames.append(f)
        sha = hashlib.sha256(file.encode()).hexdigest()
        const = np.ptp(speed) < 100
        runs.append(dict(run_id=run_id, file=file, segment=seg, start_s=0.0, end_s=float(t_s[-1]),
                         duration_s=float(t_s[-1] + dt), speed_rpm=float(np.median(speed)),
                         speed_min_rpm=float(speed.min()), speed_max_rpm=float(speed.max()),
                         kind="constant" if const else "varying", role=role, role_source="auto",
                         reference="median of the first 60 s of the run (run_start)", sha256=sha))
        t0 = t0 + pd.Timedelta(days=1)

    for s in TRAIN:
        add_run(f"train-{s}", f"2026-03-{TRAIN.index(s) + 2:02d}_train_{s}rpm.csv", "training",
                np.full(int(4 * 3600 / dt), float(s)))
    for j, (s, hours) in enumerate(zip(PAPER_RES, [4, 3, 2.5, 3, 2])):
        add_run(f"val-{s}", f"2026-03-{j + 10:02d}_val_{s}rpm.csv", "validation_single",
                np.full(int(hours * 3600 / dt), float(s)), drift=1.2 + 0.3 * j)
    steps = [(3000, 0.5), (9000, 0.75), (15000, 0.75), (6000, 0.5), (12000, 0.75), (18000, 0.5),
             (4500, 0.75)]
    multi = np.concatenate([np.full(int(h * 3600 / dt), float(s)) for s, h in steps])
    add_run("multi-1", "2026-03-16_multi_condition.csv", "validation_multi", multi, drift=1.5)
    add_run("short-1", "2026-03-17_warmup.csv", "excluded", np.full(int(0.4 * 3600 / dt), 6000.0))
    runs_table = pd.DataFrame(runs)
    runs_frame = pd.concat(frames, ignore_index=True)

    # ---- audit
    audit = []
    for r in runs:
        n_in = int(r["duration_s"] / dt) + 3
        audit.append(dict(file=r["file"], sha256=r["sha256"], rows_in=n_in, rows_out=n_in - 3,
                          duplicates_dropped=2, reordered=0, spikes_replaced=int(rng.integers(0, 4)),
                          values_interpolated=int(rng.integers(0, 30)), gaps_interpolated=1,
                          segments=1, status="ok", reason=""))
    audit.append(dict(file="2026-03-18_broken_logger.csv",
                      sha256=hashlib.sha256(b"broken").hexdigest(), rows_in=1840, rows_out=0,
                      duplicates_dropped=0, reordered=0, spikes_replaced=0, values_interpolated=0,
                      gaps_interpolated=0, segments=0, status="quarantined",
                      reason="line 812, column T7: '23,41' is not a number (decimal comma? use a point)"))
    pd.DataFrame(audit).to_csv(base / "audit.csv", index=False)
    runs_table.to_csv(base / "runs.csv", index=False)
    runs_frame.to_parquet(base / "runs.parquet", compression="zstd")

    # ---- equilibrium
    from rafi.method.equilibrium import equilibrium_time
    eq = []
    for s in TRAIN:
        f = runs_frame[runs_frame.run_id == f"train-{s}"]
        r = equilibrium_time(f.t_s.to_numpy(), f.dz_um.to_numpy())
        eq.append(dict(run_id=f"train-{s}", speed_rpm=s, t_eq_s=r.t_eq_s, t_eq_low_s=r.t_eq_low_s,
                       t_eq_high_s=r.t_eq_high_s, tau_s=r.tau_s, t_eq_tau_s=r.t_eq_tau_s,
                       plateau_um=r.plateau_um, paper_t_eq_s=PAPER_T_EQ[s],
                       method="band 5 % of rise around final 900 s plateau, 300 s median"))
    pd.DataFrame(eq).to_csv(base / "equilibrium.csv", index=False)

    # ---- rank
    train = runs_frame[runs_frame.run_id.str.startswith("train-")]
    rows = []
    for scope, g in [(str(s), train[train.run_id == f"train-{s}"]) for s in TRAIN] + [("pooled", train)]:
        rs = [float(np.corrcoef(g["d" + s], g.dz_um)[0, 1]) for s in SENSORS]
        order = np.argsort(-np.abs(rs))
        rank = np.empty(16, int)
        rank[order] = np.arange(1, 17)
        rows += [dict(scope=scope, sensor=s, r=r, abs_r=abs(r), rank=int(k))
                 for s, r, k in zip(SENSORS, rs, rank)]
    corr = pd.DataFrame(rows)
    corr.to_csv(base / "rank" / "correlation.csv", index=False)
    per = corr[corr.scope != "pooled"].groupby("sensor").abs_r.min()
    pd.DataFrame({"sensor": KEY, "score_abs_r": [per[k] for k in KEY],
                  "selected_by": "threshold"}).to_csv(base / "rank" / "key_sensors.csv", index=False)
    (base / "rank" / "key_sensors.json").write_text(json.dumps(
        {"sensors": KEY, "threshold": 0.97, "scope": "min_per_speed", "fallback_used": False,
         "message": ""}, indent=2))
    cm = np.corrcoef(train[["d" + k for k in KEY]].to_numpy().T)
    coll = pd.DataFrame(cm, columns=KEY)
    coll.insert(0, "sensor", KEY)
    coll.to_csv(base / "rank" / "collinearity.csv", index=False)

    # ---- fit
    coef_rows, diag_rows, vif_rows, speeds = [], [], [], []
    for s in TRAIN:
        f = runs_frame[runs_frame.run_id == f"train-{s}"]
        x = f[["d" + k for k in KEY]].to_numpy()
        X = terms_matrix(x)
        y = f.dz_um.to_numpy()
        b, *_ = np.linalg.lstsq(X, y, rcond=None)
        res = y - X @ b
        n, p = X.shape
        sse = float(res @ res)
        rmse = float(np.sqrt(sse / n))
        r2 = 1 - sse / float(((y - y.mean()) ** 2).sum())
        sigma2 = sse / (n - p)
        cov = sigma2 * np.linalg.pinv(X.T @ X)
        se = np.sqrt(np.abs(np.diag(cov)))
        tval = b / se
        for term, bi, si, ti in zip(TERMS, b, se, tval):
            coef_rows.append(dict(speed_rpm=s, term=term, coef=bi, se=si, se_hac=si * 4.1, t=ti,
                                  p=float(min(1.0, 2 * np.exp(-0.5 * ti * ti))),
                                  p_hac=float(min(1.0, 2 * np.exp(-0.5 * (ti / 4.1) ** 2)))))
        vifs = []
        for j in range(1, p):
            others = np.delete(X, j, axis=1)
            bj, *_ = np.linalg.lstsq(others, X[:, j], rcond=None)
            rj = X[:, j] - others @ bj
            r2j = 1 - (rj @ rj) / (((X[:, j] - X[:, j].mean()) ** 2).sum())
            vifs.append(1 / max(1 - r2j, 1e-12))
            vif_rows.append(dict(speed_rpm=s, term=TERMS[j], vif=vifs[-1]))
        dw = float(np.sum(np.diff(res) ** 2) / sse)
        diag_rows.append(dict(speed_rpm=s, n=n, r2=r2, r2_adj=1 - (1 - r2) * (n - 1) / (n - p),
                              rmse_um=rmse, paper_rmse_um=PAPER_RMSE[s],
                              aic=n * np.log(sse / n) + 2 * p, bic=n * np.log(sse / n) + p * np.log(n),
                              condition_number=float(np.linalg.cond(X)), durbin_watson=dw,
                              bp_stat=float(rng.uniform(5, 40)), bp_p=float(rng.uniform(0, 0.3)),
                              jb_stat=float(rng.uniform(0.5, 12)), jb_p=float(rng.uniform(0.002, 0.8)),
                              max_vif=max(vifs)))
        speeds.append(dict(speed_rpm=s, coefficients=[float(v) for v in b],
                           regressor_ranges={k: [float(x[:, i].min()), float(x[:, i].max())]
                                             for i, k in enumerate(KEY)},
                           train_runs=[f"train-{s}"], rmse_um=rmse, n=n))
    pd.DataFrame(coef_rows).to_csv(base / "fit" / "coefficients.csv", index=False)
    pd.DataFrame(diag_rows).to_csv(base / "fit" / "diagnostics.csv", index=False)
    pd.DataFrame(vif_rows).to_csv(base / "fit" / "vif.csv", index=False)
    model = {"schema": "rafi.model/1", "kind": "rafi", "machine": MACHINE, "key_sensors": KEY,
             "variables": {f"x{i + 1}": k for i, k in enumerate(KEY)}, "terms": TERMS,
             "inputs": "temperature rises dT (K) of the key sensors",
             "target": "displacement change dz (um) from the reference state",
             "reference": {"rule": "run_start", "window_s": 60}, "speeds": speeds,
             "fuzzy": {"membership": "triangular", "outside": "edge"},
             "data": {r["file"]: r["sha256"] for r in runs if r["role"] == "training"},
             "code_version": "rafi 0.1.0 (fixture)", "config": {},
             "created": "2026-03-20T12:00:00Z"}
    # the real artefact (canonical content, valid model_id) so every producer accepts it
    from rafi.method.model import RafiModel
    rafi_model = RafiModel.from_dict(model, verify_id=False)
    model = rafi_model.to_dict()
    model["variables"] = {f"x{i + 1}": k for i, k in enumerate(KEY)}
    (base / "model.json").write_text(json.dumps(model, indent=2, sort_keys=True))

    # ---- validate (the pipeline's own rafi.method.validate.validate_runs)
    from rafi.method.validate import validate_runs
    summary, residuals = validate_runs(rafi_model, runs_table, runs_frame)
    summary.to_csv(base / "validation" / "summary.csv", index=False)
    residuals.to_parquet(base / "validation" / "residuals.parquet", compression="zstd")

    if family:
        _family_and_registry(base, runs_table, runs_frame, rafi_model, model)


#: Model-family options for the fixture: the config defaults with a smaller grid (fast).
def _family_options() -> dict:
    from rafi.settings import MACHINE_DEFAULTS
    return {**MACHINE_DEFAULTS["models"],
            "enabled": ["rafi", "rafi_linear", "ridge_global", "dynamic"],
            "ridge_alphas": [1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 0.1, 1.0, 10.0],
            "dynamic_taus_s": [0, 1200, 4800], "dynamic_max_taus": 1}


GATES = {"max_residual_um": 12.0, "min_improvement_pct": 30.0,
         "never_worse_than_uncompensated": True}


def _family_and_registry(base: Path, runs_table, runs_frame, rafi_model, model: dict) -> None:
    """comparison/* from rafi.family.compare.run_family and registry/* from two nights of
    rafi.ops.decide.run_decide (the real producers of rules compare and decide).

    Night 1 (the multi-condition log not recorded yet): RAFI as published is the candidate
    and is promoted. Night 2 (all logs): the family's champion is the candidate; the
    multi-condition run is new since the champion's promotion, so the drift check runs.
    """
    import shutil
    import tempfile

    from rafi.family.compare import run_family
    from rafi.ops.decide import run_decide

    comp = base / "comparison"
    comp.mkdir(exist_ok=True)
    res = run_family(runs_table, runs_frame, key_sensors=KEY, terms=TERMS,
                     reference=model["reference"], machine=MACHINE, options=_family_options(),
                     gates=GATES, rafi_model=rafi_model, log=lambda m: None)
    res["summary"].to_csv(comp / "summary.csv", index=False)
    res["per_run"].to_csv(comp / "per_run.csv", index=False)
    res["verdict"].to_csv(comp / "verdict.csv", index=False)
    res["cv"].to_csv(comp / "cv.csv", index=False)
    res["residuals"].to_parquet(comp / "residuals.parquet", compression="zstd")
    (comp / "best_model.json").write_text(json.dumps(res["best_artefact"], indent=2, sort_keys=True))

    reg = base / "registry"
    if reg.exists():
        shutil.rmtree(reg)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        night1 = tmp / "runs_night1.csv"
        runs_table[runs_table["role"] != "validation_multi"].to_csv(night1, index=False)
        runs_csv = tmp / "runs.csv"
        runs_table.to_csv(runs_csv, index=False)
        frame = tmp / "runs.parquet"
        runs_frame.to_parquet(frame)
        for table, cand in ((night1, base / "model.json"), (runs_csv, comp / "best_model.json")):
            run_decide(machine=MACHINE, candidate_path=cand, runs_csv=table, runs_parquet=frame,
                       registry_root=tmp / "registry", decision_path=tmp / "registry" / "decision.json",
                       comparison_path=tmp / "registry" / "comparison.csv", gates=GATES,
                       nightly={"candidate": "family", "retrain_speed_range_rpm": None,
                                "drift_margin_um": 2.0, "drift_false_alarm": 0.01}, log=lambda m: None)
        shutil.copytree(tmp / "registry", reg)
    for p in reg.rglob("*"):
        if p.is_file():
            p.chmod(0o644)


def write_verdict(out: Path) -> None:
    """comparison/verdict.csv of the committed comparison, the rest of the fixture kept.

    Rule compare stores, per model, :func:`rafi.family.compare.named_verdict` of
    :func:`rafi.method.validate.qualify` of the model's validation summary (``run_family``'s
    ``verdict``); ``comparison/per_run.csv`` is that summary, so the same two functions on it
    (read back, in the model order of ``summary.csv``) give the file ``run_family`` wrote
    beside it (``tests/test_comparison_verdict.py`` checks the equality on run_family's own
    output). For a fixture made before verdict.csv existed, whose other files a full
    ``--refresh`` would change.
    """
    from rafi.family.compare import named_verdict, stacked_verdicts
    from rafi.method.validate import qualify

    comp = out / MACHINE / "comparison"
    summary = pd.read_csv(comp / "summary.csv")
    per_run = pd.read_csv(comp / "per_run.csv")
    parts = [
        named_verdict(qualify(per_run[per_run["model"] == name].reset_index(drop=True), GATES), name, mid)
        for name, mid in zip(summary["model"], summary["model_id"])
    ]
    stacked_verdicts(parts).to_csv(comp / "verdict.csv", index=False)


def refresh(out: Path) -> None:
    """Re-run the real producers (validation, comparison, registry) on the committed data and
    model (runs.csv, runs.parquet, model.json unchanged): after a change of the producers."""
    from rafi.method.model import RafiModel
    from rafi.method.validate import validate_runs
    base = out / MACHINE
    runs_table = pd.read_csv(base / "runs.csv")
    runs_frame = pd.read_parquet(base / "runs.parquet")
    model = json.loads((base / "model.json").read_text())
    rafi_model = RafiModel.from_dict(model)
    summary, residuals = validate_runs(rafi_model, runs_table, runs_frame)
    summary.to_csv(base / "validation" / "summary.csv", index=False)
    residuals.to_parquet(base / "validation" / "residuals.parquet", compression="zstd")
    _family_and_registry(base, runs_table, runs_frame, rafi_model, model)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?", default=str(Path(__file__).resolve().parent))
    ap.add_argument("--sample-period-s", type=float, default=120.0)
    ap.add_argument("--no-family", action="store_true",
                    help="skip comparison/ and registry/ (model family + registry decision)")
    ap.add_argument("--refresh", action="store_true",
                    help="keep the data and model.json; re-run validation, comparison and registry")
    ap.add_argument("--verdict", action="store_true",
                    help="keep everything else; write comparison/verdict.csv of the committed comparison")
    a = ap.parse_args(argv)
    if a.verdict:
        write_verdict(Path(a.out))
        return
    if a.refresh:
        refresh(Path(a.out))
        return
    generate(Path(a.out), a.sample_period_s, family=not a.no_family)


if __name__ == "__main__":
    main()
