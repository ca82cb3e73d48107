"""The output bound one level up: how far beyond the training displacement range may a model's
prediction go? Judged on training runs (and foreign machines' test days), never a real log's tests.

Usage (from the repository root; see benchmarks/README.md)::

    python benchmarks/bench_envelope.py --project /tmp/rd46/keep/ch1-windows ... \\
        --foreign /tmp/foreign46 --out envelope_output

A project is any folder the pipeline has run in up to ``results/<m>/comparison/`` (the real logs'
kept projects of ``bench_realdata.py --keep``, the foreign machines of ``bench_foreign.py --keep``:
``--foreign KEEP`` takes every ``KEEP/seed-NNN/project``).

**What is judged.** A candidate bound holds a prediction inside ``[lo - m span, hi + m span]``,
``[lo, hi]`` the displacement range of the rows the model was fitted on and ``span = hi - lo``;
``free`` holds nothing (the prediction as the pipeline makes it: features already held inside
their envelope, :mod:`rafi.family.envelope`). Candidates ``m`` in :data:`MARGINS`.

**Two judges, per machine and kind:**

* *outer* (every project): the pipeline's own whole-run CV out-of-fold samples (the CV memo's
  ``.oof.parquet``, leave one training run out): the prediction of a held-out training run is
  its measured displacement minus the OOF residual, bounded by the range of the *other* training
  runs (the fold's own training rows);
* *test* (foreign machines only; their test days are generated, not a real log's): the
  validation residuals of the pipeline's final model, bounded by the range of every training run.

**Criterion (fixed before the run, 2026-11-29):** per machine the MAE of the offered kind (the
kind the pipeline offered) over every scored row, as a ratio to ``free``'s.

* **primary**: mean over every machine (real and foreign) of the outer ratio; lower is better;
* **guard**: mean over foreign machines of the test ratio at most 1 + its standard error (a bound
  must not cost where the physics does extrapolate: test days 1.2-1.4 x the top training speed);
* **decision**: the candidate with the lowest primary that passes the guard, if below ``free``'s
  1.00 by more than one standard error of its per-machine ratios; otherwise the widest candidate
  that passes the guard, as a cap that costs nothing measurable.
* shown, not deciding: the same for every kind (a kind that runs away is where a bound works) and
  the worst run's ratio.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import platform
import sys
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / "benchmarks"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from _results import write_results  # noqa: E402

#: Candidate margins (spans beyond the training displacement range); None = free.
MARGINS = (None, 2.0, 1.0, 0.5, 0.25, 0.1, 0.0)


def margin_name(m: float | None) -> str:
    return "free" if m is None else f"m={m:g}"


def bound(pred: np.ndarray, lo: float, hi: float, m: float | None) -> np.ndarray:
    """``pred`` held inside the training range ``[lo, hi]`` widened by ``m`` spans (free: as is)."""
    if m is None:
        return pred
    pad = m * (hi - lo)
    return np.clip(pred, lo - pad, hi + pad)


def machines_of(project: Path) -> list[str]:
    return sorted(p.parent.parent.name for p in (project / "results").glob("*/comparison/summary.csv"))


def offered_kind(project: Path, machine: str) -> str:
    best = json.loads((project / "results" / machine / "comparison" / "best_model.json").read_text())
    return str(best["kind"])


def outer_rows(project: Path, machine: str) -> pd.DataFrame:
    """Every kind's OOF prediction of a held-out training run with its fold's training range."""
    res = project / "results" / machine
    frame = pd.read_parquet(res / "runs.parquet", columns=["run_id", "t_s", "dz_um"])
    table = pd.read_csv(res / "runs.csv")
    training = set(table.loc[table["role"] == "training", "run_id"].astype(str))
    oofs = sorted((res / ".cv_memo").glob("*.oof.parquet"), key=lambda p: p.stat().st_mtime)
    if not oofs:
        return pd.DataFrame()
    oof = pd.read_parquet(oofs[-1])
    oof = oof.loc[oof["unit"].astype(str) == oof["run_id"].astype(str)]
    frame = frame.assign(run_id=frame["run_id"].astype(str))
    rng = frame.loc[frame["run_id"].isin(training)].groupby("run_id")["dz_um"].agg(["min", "max"])
    merged = oof.assign(run_id=oof["run_id"].astype(str)).merge(frame, on=["run_id", "t_s"], how="left")
    merged["predicted_um"] = merged["dz_um"] - merged["residual_um"]
    lo = {r: rng.drop(index=r)["min"].min() for r in rng.index}
    hi = {r: rng.drop(index=r)["max"].max() for r in rng.index}
    merged["lo"] = merged["run_id"].map(lo)
    merged["hi"] = merged["run_id"].map(hi)
    return merged.loc[np.isfinite(merged["predicted_um"]) & merged["lo"].notna()]


def test_rows(project: Path, machine: str) -> pd.DataFrame:
    """Every kind's validation predictions with the range of every training run."""
    res = project / "results" / machine
    frame = pd.read_parquet(res / "runs.parquet", columns=["run_id", "dz_um"])
    table = pd.read_csv(res / "runs.csv")
    training = set(table.loc[table["role"] == "training", "run_id"].astype(str))
    dz = frame.loc[frame["run_id"].astype(str).isin(training), "dz_um"]
    rows = pd.read_parquet(res / "comparison" / "residuals.parquet")
    rows = rows.rename(columns={"measured_um": "dz_um"})
    return rows.assign(lo=float(dz.min()), hi=float(dz.max()))


def scores(rows: pd.DataFrame) -> dict:
    """Per kind and margin: MAE over the rows and the worst run's MAE (a row a model cannot
    predict is left out, as the CV does)."""
    out: dict = {}
    for kind, g in rows.groupby(rows["model"].astype(str)):
        g = g.loc[np.isfinite(g["predicted_um"]) & np.isfinite(g["dz_um"])]
        if g.empty:
            continue
        per = {}
        for m in MARGINS:
            p = bound(g["predicted_um"].to_numpy(float), g["lo"].to_numpy(float), g["hi"].to_numpy(float), m)
            err = np.abs(g["dz_um"].to_numpy(float) - p)
            by_run = pd.Series(err).groupby(g["run_id"].astype(str).to_numpy()).mean()
            per[margin_name(m)] = {"mae": float(err.mean()), "worst_run": float(by_run.max())}
        out[kind] = per
    return out


def judge_project(project: Path, foreign: bool) -> list[dict]:
    out = []
    for machine in machines_of(project):
        outer = outer_rows(project, machine)
        entry = {
            "project": str(project),
            "machine": machine,
            "foreign": foreign,
            "offered": offered_kind(project, machine),
            "outer": scores(outer) if not outer.empty else {},
            "test": scores(test_rows(project, machine)) if foreign else {},
        }
        out.append(entry)
    return out


def ratios(entries: list[dict], judge: str, kind: str | None = None) -> pd.DataFrame:
    """Per machine (rows) and margin (columns): the kind's MAE over free's (the offered kind when
    ``kind`` is None)."""
    rows = {}
    for e in entries:
        k = e["offered"] if kind is None else kind
        s = e[judge].get(k)
        if not s or not s["free"]["mae"] > 0:
            continue
        rows[e["machine"]] = {n: v["mae"] / s["free"]["mae"] for n, v in s.items()}
    return pd.DataFrame.from_dict(rows, orient="index")


def mean_se(col: pd.Series) -> tuple[float, float]:
    v = col.to_numpy(float)
    return float(v.mean()), float(v.std(ddof=1) / np.sqrt(len(v))) if len(v) > 1 else float("inf")


def decide(entries: list[dict]) -> dict:
    outer = ratios(entries, "outer")
    test = ratios([e for e in entries if e["foreign"]], "test")
    rows = []
    for m in MARGINS:
        n = margin_name(m)
        p, p_se = mean_se(outer[n])
        g, g_se = mean_se(test[n]) if not test.empty else (float("nan"), float("nan"))
        rows.append(
            {
                "margin": n,
                "primary": p,
                "primary_se": p_se,
                "guard": g,
                "guard_se": g_se,
                "passes_guard": bool(test.empty or g <= 1.0 + g_se),
                "outer_worst": float(outer[n].max()),
                "test_worst": float(test[n].max()) if not test.empty else float("nan"),
            }
        )
    t = pd.DataFrame(rows)
    ok = t.loc[t["passes_guard"] & (t["margin"] != "free")]
    best = ok.sort_values(["primary", "margin"]).iloc[0] if not ok.empty else None
    if best is not None and best["primary"] < 1.0 - best["primary_se"]:
        choice, why = best["margin"], "lowest primary, below free by more than one SE"
    elif not ok.empty:
        choice, why = (
            ok.iloc[0]["margin"],
            "no candidate beats free beyond one SE: the widest cap that passes the guard",
        )
    else:
        choice, why = "free", "no candidate passes the guard"
    return {"table": t.to_dict(orient="records"), "choice": choice, "why": why, "machines": len(outer)}


def markdown(report: dict) -> str:
    d = report["decision"]
    lines = [
        f"# The output bound one level up ({report['date']})",
        "",
        f"Command: `{report['command']}`; host {report['host']}.",
        f"Machines: {d['machines']} ({report['foreign']} foreign, "
        f"{report['real']} real logs' training runs).",
        "",
        "| margin | primary (outer, offered) | SE | guard (foreign test, offered) | SE | passes "
        "| worst outer | worst test |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in d["table"]:
        lines.append(
            f"| {r['margin']} | {r['primary']:.4f} | {r['primary_se']:.4f} | {r['guard']:.4f} | "
            f"{r['guard_se']:.4f} | {r['passes_guard']} | {r['outer_worst']:.3f} | {r['test_worst']:.3f} |"
        )
    lines += [
        "",
        f"**Decision**: {d['choice']} ({d['why']}).",
        "",
        "## Every kind (mean ratio, outer / test)",
        "",
    ]
    kinds = sorted({k for e in report["entries"] for k in e["outer"]})
    lines.append("| kind | " + " | ".join(margin_name(m) for m in MARGINS) + " |")
    lines.append("|---|" + "---|" * len(MARGINS))
    for k in kinds:
        o = ratios(report["entries"], "outer", k)
        t = ratios([e for e in report["entries"] if e["foreign"]], "test", k)
        cells = []
        for m in MARGINS:
            n = margin_name(m)
            a = f"{o[n].mean():.3f}" if n in o else "-"
            b = f"{t[n].mean():.3f}" if n in t else "-"
            cells.append(f"{a} / {b}")
        lines.append(f"| {k} | " + " | ".join(cells) + " |")
    lines += ["", "## Per machine (offered kind: outer MAE free -> m=1 -> m=0.1; worst run)", ""]
    for e in report["entries"]:
        s = e["outer"].get(e["offered"], {})
        if s:
            free, tight = s["free"], s["m=0.1"]
            lines.append(
                f"- {e['machine']} ({e['offered']}): {free['mae']:.3f} -> {s['m=1']['mae']:.3f} -> "
                f"{tight['mae']:.3f} um; worst run {free['worst_run']:.3f} -> {tight['worst_run']:.3f}"
            )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--project", action="append", default=[], type=Path, help="a project the pipeline ran in")
    ap.add_argument(
        "--foreign", action="append", default=[], type=Path, help="a bench_foreign.py --keep folder"
    )
    ap.add_argument("--out", default="envelope_output")
    ap.add_argument("--out-dir", type=Path, default=None, help="default benchmarks/results")
    args = ap.parse_args(argv)
    entries = []
    for p in args.project:
        entries += judge_project(p, foreign=False)
    for keep in args.foreign:
        for p in sorted(keep.glob("seed-*/project")):
            if (p / "results").is_dir():
                entries += judge_project(p, foreign=True)
    report = {
        "date": dt.date.today().isoformat(),
        "command": "python benchmarks/bench_envelope.py "
        + " ".join(argv if argv is not None else sys.argv[1:]),
        "host": f"{platform.node()}, {platform.python_version()}",
        "foreign": sum(e["foreign"] for e in entries),
        "real": sum(not e["foreign"] for e in entries),
        "entries": entries,
    }
    report["decision"] = decide(entries)
    text = markdown(report)
    kwargs = {"out_dir": args.out_dir} if args.out_dir else {}
    write_results(args.out, report, text, **kwargs)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
