"""Model kinds scored on forward-in-time folds of the training runs, beside whole-run CV.

Usage (from the repository root; see benchmarks/README.md)::

    python benchmarks/bench_forward_folds.py --project /tmp/oc/ng/ch3-windows \\
        --kinds dynamic,grey_box,ridge_global \\
        --variant 'slow_grey_box:kind="grey_box",grey_box_slow_rises=true,grey_box_heat_input="always"'

Each ``--project`` is a Snakemake project that has run, as for ``bench_selection_rules.py``
(whose :func:`machine_inputs` and :func:`extra_scheme` this bench imports): the folders
``bench_realdata.py --keep DIR`` leaves, or a copy of this project after ``snakemake --cores 2``.

**Why.** The selection's whole-run CV holds out a training run that lies *between* other
training runs; a deployment lies *after* all of them. Forward folds ask the deployment's
question on the training runs alone:

* ``whole_run``: leave one training run out (the selection's own scheme);
* ``F1`` (:func:`rafi.family.forward_folds.forward_folds`, ``horizon=1``): train on the training
  runs of a log before a point in time, hold out the next run;
* ``F2`` (``horizon=2``): the same, holding out the next two runs (drift over a horizon).

Forward folds start only where at least ``min_train`` (3) training runs lie before the point
in time (one or two runs train nothing sane) and need a full horizon. They run inside **one
continuous log** (the ``file`` of the runs table): runs of separate files (cold starts) have no
meaningful time order, so a log with fewer than ``min_train + horizon`` training runs gives no
forward fold and its runs are neither trained on nor held out by ``F1``/``F2``; a data set whose
logs are all like that (``tapping-center-a``) is scored by ``whole_run`` only, and the report says
so. Each fold fits a fresh model (:func:`rafi.family.crossval.cross_validate`: the runs after the
held-out ones are guard runs, never fitted); a model's own hyperparameter CV runs on the fold's
training runs. The fold score is the mean over the held-out runs of their max |residual| (the
selection's criterion); a scheme's score is the mean over its folds; the pick of a scheme is the
lowest score (ties within 1e-3 um to the simpler kind, :data:`rafi.family.selection.SIMPLICITY`).

**Candidates.** The machine's enabled kinds (``--kinds`` to choose some), plus ``--variant``:
``NAME:key=json,key=json`` with ``kind`` among the keys (the kind the variant builds) and every
other key a ``models:`` option of the machine, its value JSON (strings quoted), e.g.
``slow_grey_box:kind="grey_box",grey_box_slow_rises=true,grey_box_heat_input="always"``. Commas
inside JSON brackets or strings do not split (``dynamic_powers=[1,2]``).

**Data read.** ``config.yaml``, ``runs.csv``, ``runs.parquet``, ``key_sensors.json`` and
``comparison/cv.csv`` (training CV rows, to check the whole-run figures of unchanged kinds); of the
runs frame only each log's rows up to the end of its last training run are kept
(:func:`training_part`: the filters are causal, so nothing after that changes a training-run
figure). Validation and test rows are never used.

Output: progress on stderr, the tables on stdout, ``benchmarks/results/<out>.json`` and ``.md``
(no date, host or timing in them: the same projects and command give the same files).
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
for path in (ROOT, ROOT / "benchmarks"):
    if str(path) not in sys.path:
        sys.path.insert(0, str(path))

from _results import write_results  # noqa: E402
from bench_selection_rules import extra_scheme, machine_inputs  # noqa: E402

from rafi.contract import RESULT_FILES  # noqa: E402
from rafi.family import crossval  # noqa: E402
from rafi.family.forward_folds import MIN_TRAIN, forward_folds, forward_logs, is_forward  # noqa: E402
from rafi.family.selection import SIMPLICITY  # noqa: E402
from rafi.family.whole_log import has_whole_logs  # noqa: E402

#: Scheme label -> (name registered in crossval.SCHEMES, forward horizon or None).
SCHEMES = {"whole_run": ("leave_one_run_out", None), "F1": ("forward_1", 1), "F2": ("forward_2", 2)}
TIE_UM = 1e-3


# ----------------------------------------------------------------------------- folds


def training_part(runs_table: pd.DataFrame, frame: pd.DataFrame) -> pd.DataFrame:
    """The rows of ``frame`` a training-run figure can depend on: per log holding a training run,
    its rows up to the end of its last training run (whole-log frames: the filters run through the
    log causally); per-run frames: the training runs' rows."""
    train_ids = set(crossval.training_runs(runs_table, frame)[0]["run_id"].astype(str))
    in_train = frame["run_id"].astype(str).isin(train_ids).to_numpy()
    if not has_whole_logs(frame):
        return frame.loc[in_train]
    log = frame["log"].astype(str)
    end = frame.loc[in_train, "log_t_s"].groupby(log[in_train]).max()
    limit = log.map(end).to_numpy(dtype=float)  # NaN for a log without a training run
    return frame.loc[frame["log_t_s"].to_numpy(dtype=float) <= limit]


# ----------------------------------------------------------------------------- candidates


def split_top_level(text: str) -> list[str]:
    """``text`` split at the commas outside JSON brackets and strings."""
    parts, depth, quoted, start = [], 0, False, 0
    for i, ch in enumerate(text):
        if quoted:
            quoted = not (ch == '"' and text[i - 1] != "\\")
        elif ch == '"':
            quoted = True
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return [p.strip() for p in parts if p.strip()]


def parse_variant(text: str) -> tuple[str, str, dict]:
    """``NAME:kind="KIND",key=json,...`` -> ``(name, kind, {option: value})`` (module docstring)."""
    name, sep, body = text.partition(":")
    if not sep or not name.strip():
        raise SystemExit(f'--variant {text!r}: expected NAME:kind="KIND",key=json,...')
    settings = {}
    for item in split_top_level(body):
        key, eq, value = item.partition("=")
        try:
            settings[key.strip()] = json.loads(value)
        except json.JSONDecodeError:
            raise SystemExit(
                f'--variant {name}: {key.strip()}={value} is not JSON (quote strings: {key.strip()}="...")'
            ) from None
        if not eq:
            raise SystemExit(f"--variant {name}: {item!r} is not key=json")
    kind = settings.pop("kind", None)
    if not isinstance(kind, str):
        raise SystemExit(f'--variant {name}: needs kind="KIND" (the kind the variant builds)')
    return name.strip(), kind, settings


def candidates(factories: dict, kinds: list[str], variants: list[tuple[str, str, dict]]) -> dict:
    """Name -> ``{"kind", "overrides", "factory"}``: the kinds asked for (all enabled ones when
    ``kinds`` is empty) and the variants, built from the machine's settings
    (``factories`` from :func:`machine_inputs`)."""
    base = next(iter(factories.values()))
    options = base.keywords["options"]
    settings = {k: v for k, v in base.keywords.items() if k != "options"}

    def build(kind: str, overrides: dict):
        return functools.partial(base.func, kind, **settings, options={**options, **overrides})

    out = {}
    for kind in kinds or list(factories):
        out[kind] = {"kind": kind, "overrides": {}, "factory": factories.get(kind) or build(kind, {})}
    for name, kind, overrides in variants:
        unknown = sorted(set(overrides) - set(options))
        if unknown:
            raise SystemExit(f"--variant {name}: {', '.join(unknown)} not a models: option of the machine")
        if name in out:
            raise SystemExit(f"--variant {name}: the name is taken by a kind or another variant")
        out[name] = {"kind": kind, "overrides": overrides, "factory": build(kind, overrides)}
    return out


# ----------------------------------------------------------------------------- scoring


def fold_figures(cv: pd.DataFrame) -> list[dict]:
    """Per fold of ``cross_validate`` rows: training-run count, held-out runs, their max
    |residual| and the fold score (their mean)."""
    folds = []
    for _, g in cv.groupby("fold", sort=True):
        mx = {str(r): float(v) for r, v in zip(g["test_runs"], g["max_abs_after_um"])}
        folds.append(
            {
                "n_train_runs": int(g["n_train_runs"].iloc[0]),
                "test_runs": list(mx),
                "max_abs_um": mx,
                "score_um": float(np.mean(list(mx.values()))),
            }
        )
    return folds


def pick(scores: dict, kinds: dict) -> str | None:
    """The candidate with the lowest finite score (ties within :data:`TIE_UM` to the simpler kind,
    then the name)."""
    finite = {n: s for n, s in scores.items() if s is not None and np.isfinite(s)}
    if not finite:
        return None
    return min(
        finite, key=lambda n: (round(finite[n] / TIE_UM), SIMPLICITY.get(kinds[n], len(SIMPLICITY)), n)
    )


def score_candidates(
    table: pd.DataFrame, frame: pd.DataFrame, cands: dict, *, min_train: int = MIN_TRAIN, log=print
) -> dict:
    """Every candidate on every scheme of :data:`SCHEMES` (module docstring).

    Returns
    -------
    dict
        ``{"forward_logs": {scheme: forward_logs()}, "scores": {scheme: {name: score_um}},
        "folds": {scheme: {name: fold_figures()}}, "errors": {...}, "picks": {scheme: name}}``;
        a forward scheme without folds is absent from ``scores`` and ``picks``.
    """
    frame = training_part(table, frame)
    out = {"forward_logs": {}, "scores": {}, "folds": {}, "errors": {}, "picks": {}}
    registered = {
        name: functools.partial(forward_folds, horizon=h, min_train=min_train)
        for name, h in SCHEMES.values()
        if h
    }
    with (
        extra_scheme("forward_1", registered["forward_1"]),
        extra_scheme("forward_2", registered["forward_2"]),
    ):
        for label, (scheme, horizon) in SCHEMES.items():
            if horizon:
                out["forward_logs"][label] = forward_logs(table, horizon, min_train)
                if not crossval.has_folds(table, scheme):
                    log(f"  {label}: no log with {min_train + horizon} training runs; not scored")
                    continue
            scores, folds = {}, {}
            for name, c in cands.items():
                t0 = time.perf_counter()
                try:
                    cv = crossval.cross_validate(c["factory"], table, frame, scheme, name=name)
                except Exception as exc:  # one candidate failing must not lose the others
                    out["errors"].setdefault(label, {})[name] = f"{type(exc).__name__}: {exc}"[:300]
                    scores[name] = None
                    log(f"  {label:9s} {name:16s} failed: {out['errors'][label][name]}")
                    continue
                folds[name] = fold_figures(cv)
                scores[name] = float(np.mean([f["score_um"] for f in folds[name]]))
                log(f"  {label:9s} {name:16s} {scores[name]:8.2f} um  ({time.perf_counter() - t0:.0f} s)")
            out["scores"][label], out["folds"][label] = scores, folds
            out["picks"][label] = pick(scores, {n: c["kind"] for n, c in cands.items()})
    return out


def check_against_pipeline(result: dict, cands: dict, cv_csv: pd.DataFrame) -> dict:
    """Per unchanged kind: does its whole-run figure of every run equal ``comparison/cv.csv``'s
    (the pipeline's own CV; a difference means other code or settings than the project's)?"""
    cv_csv = cv_csv.loc[~cv_csv["scheme"].map(is_forward).to_numpy(dtype=bool)]  # whole-run rows only
    rows = cv_csv.set_index([cv_csv["model"].astype(str), cv_csv["test_runs"].astype(str)])[
        "max_abs_after_um"
    ]
    check = {}
    for name, folds in result["folds"].get("whole_run", {}).items():
        if cands[name]["overrides"] or name not in set(cv_csv["model"].astype(str)):
            continue
        mine = {r: v for f in folds for r, v in f["max_abs_um"].items()}
        check[name] = all(
            np.isclose(v, rows.get((name, r), np.nan), rtol=1e-6, atol=1e-6) for r, v in mine.items()
        )
    return check


# ----------------------------------------------------------------------------- report


def markdown(report: dict) -> str:
    """One table per data set (rows: schemes; columns: candidates; the pick in bold), then the
    per-fold figures."""
    lines = [
        "# Forward-in-time folds of the training runs",
        "",
        f"Command: `{report['command']}`.",
        "Training runs only; um. Score: mean over folds of the mean over the held-out runs of their max",
        f"|residual|. F1/F2: the next one/two runs after >= {report['min_train']} training runs of a log.",
    ]
    for ds in report["data_sets"]:
        names = list(ds["candidates"])
        lines += ["", f"## {ds['machine']}", "", f"| scheme | folds | {' | '.join(names)} | pick |"]
        lines.append("|" + "---|" * (len(names) + 3))
        for label in SCHEMES:
            if label not in ds["scores"]:
                lines.append(f"| {label} | 0 | " + " | ".join("-" for _ in names) + " | no forward fold |")
                continue
            cells = []
            for n in names:
                s = ds["scores"][label].get(n)
                text = "error" if s is None else f"{s:.2f}"
                cells.append(f"**{text}**" if n == ds["picks"][label] else text)
            nfold = len(next(iter(ds["folds"][label].values()), []))
            lines.append(f"| {label} | {nfold} | {' | '.join(cells)} | {ds['picks'][label] or '-'} |")
        for note in ds["notes"]:
            lines.append(f"\n{note}")
        lines += ["", "| scheme | candidate | held-out run: max |residual| per fold |", "|---|---|---|"]
        for label, per in ds["folds"].items():
            for n, folds in per.items():
                cells = "; ".join(
                    "/".join(f"{r} {f['max_abs_um'][r]:.2f}" for r in f["test_runs"]) for f in folds
                )
                lines.append(f"| {label} | {n} | {cells} |")
    return "\n".join(lines) + "\n"


def data_set(project: Path, machine: str, kinds: list[str], variants: list, min_train: int, log) -> dict:
    """One machine of one project: every candidate on every scheme, the picks and the notes."""
    inputs = machine_inputs(project, machine)
    cands = candidates(inputs["factories"], kinds, variants)
    result = score_candidates(inputs["table"], inputs["frame"], cands, min_train=min_train, log=log)
    check = check_against_pipeline(result, cands, inputs["cv"])
    notes = []
    for label, logs in result["forward_logs"].items():
        without = sorted(lg for lg, v in logs.items() if not v["folds"])
        if without and label not in result["scores"]:
            notes.append(
                f"{label}: no log holds {min_train + SCHEMES[label][1]} training runs "
                f"({len(without)} logs, separate files have no time order): whole-run only."
            )
        elif without:
            notes.append(
                f"{label}: logs without forward folds (too few training runs): {', '.join(without)}."
            )
    differ = sorted(n for n, ok in check.items() if not ok)
    if differ:
        notes.append(
            f"whole_run differs from comparison/cv.csv for {', '.join(differ)} (other code or settings)."
        )
        log(f"  {machine}: {notes[-1]}")
    return {
        "machine": machine,
        "project": str(project),
        "candidates": {n: {"kind": c["kind"], "overrides": c["overrides"]} for n, c in cands.items()},
        "cv_csv_check": check,
        "notes": notes,
        **result,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--project", type=Path, action="append", required=True, help="a project that has run; repeat"
    )
    parser.add_argument("--machines", default="", help="comma-separated machine names (default: all)")
    parser.add_argument(
        "--kinds", default="", help="comma-separated kinds (default: the machine's enabled kinds)"
    )
    parser.add_argument(
        "--variant", action="append", default=[], help='NAME:kind="KIND",option=json,... (repeat)'
    )
    parser.add_argument(
        "--min-train", type=int, default=MIN_TRAIN, help="fewest training runs before an origin"
    )
    parser.add_argument("--out", default="forward_folds", help="file stem under benchmarks/results/")
    args = parser.parse_args(argv)
    wanted = {m.strip() for m in args.machines.split(",") if m.strip()}
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    variants = [parse_variant(v) for v in args.variant]
    err = functools.partial(print, file=sys.stderr, flush=True)
    sets = []
    for project in args.project:
        for res in sorted((project / "results").iterdir()):
            if not (res / RESULT_FILES["comparison_cv"]).is_file() or (wanted and res.name not in wanted):
                continue
            err(f"{res.name} ({project})")
            sets.append(data_set(project, res.name, kinds, variants, args.min_train, err))
    report = {
        "command": " ".join(
            ["python benchmarks/bench_forward_folds.py", *(sys.argv[1:] if argv is None else argv)]
        ),
        "min_train": args.min_train,
        "data_sets": sets,
    }
    text = markdown(report)
    print(text)
    write_results(args.out, report, text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
