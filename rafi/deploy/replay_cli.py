"""Replay recorded runs through the compensator with the machine's limits in force.

Reads the results of an earlier pipeline run (results/<machine>/runs.parquet and runs.csv) and
feeds each run's log, from its first sample up to the run's end, through the safe compensator
exactly as a controller would (power-on at the log's first sample, a new reference at each run
start or log segment, as the model was trained). Writes, per replayed run, <file>.csv (one row
per sample: the model's value, the command, the status and what each limit did) and <file>.png,
where <file> is the run id made a file name (thermal_log_2026-10-14#11 ->
thermal_log_2026-10-14_11.csv), and summary.csv; prints what each limit did. docs/deploy.md, section Replay.

  rafi replay --machine tapping-center-a                     # the runs of deploy.replay_roles
  rafi replay --machine machining-center-b --run 'thermal_log_2026-10-14#11' --model champion
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

from rafi.cli import add_config_option
from rafi.errors import ReplayError

MODEL_CHOICES = ("candidate", "champion")


def add_arguments(parser) -> None:
    """``rafi replay``'s arguments."""
    parser.add_argument("--machine", required=True, help="a machine with results under results_dir")
    parser.add_argument(
        "--model",
        default="candidate",
        help="candidate (this run's offered model, nightly.candidate: comparison/best_model.json by "
        "default), champion (the registry's, verified) or the path of a model JSON (default: candidate)",
    )
    parser.add_argument(
        "--run",
        action="append",
        dest="runs",
        metavar="RUN_ID",
        help="a run id of runs.csv (repeatable; default: the runs whose role is in deploy.replay_roles)",
    )
    parser.add_argument("--out", help="output folder (default: <results_dir>/<machine>/deploy/replay)")
    add_config_option(parser)


def _load_model(spec: str, machine: str, results_dir: Path, settings: dict) -> tuple[dict, str]:
    """The artefact asked for by ``--model`` and where it came from."""
    from rafi.contract import REGISTRY_DIR
    from rafi.deploy.qualified import load_champion
    from rafi.settings import candidate_model_path

    if spec == "champion":
        root = results_dir / machine / REGISTRY_DIR
        return load_champion(root), str(root)
    if spec == "candidate":
        rel = candidate_model_path(machine, ".", settings["nightly"]["candidate"])
        path = results_dir / Path(rel).relative_to(".")
    else:
        path = Path(spec)
    try:
        artefact = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        hint = " (run `snakemake --cores 2 all` first)" if spec == "candidate" else ""
        raise ReplayError(f"no model file {path}{hint}") from None
    except (OSError, ValueError) as exc:
        raise ReplayError(f"{path}: not a readable model JSON ({exc})") from None
    if not isinstance(artefact, dict):
        raise ReplayError(f"{path}: not a model artefact (a JSON object)")
    return artefact, str(path)


def _read_results(results_dir: Path, machine: str):
    import pandas as pd

    base = results_dir / machine
    paths = [base / "runs.parquet", base / "runs.csv"]
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        raise ReplayError(
            f"no pipeline results for machine {machine!r}: {', '.join(missing)} missing "
            "(run `snakemake --cores 2 tables` first)"
        )
    return pd.read_parquet(paths[0]), pd.read_csv(paths[1])


def _pick_runs(asked, table, roles) -> list[str]:
    from rafi.deploy.replay import replay_run_ids

    known = [str(r) for r in table["run_id"]]
    if asked:
        unknown = [r for r in asked if r not in known]
        if unknown:
            raise ReplayError(f"unknown run id(s) {', '.join(unknown)}; runs.csv has: {', '.join(known)}")
        return list(dict.fromkeys(asked))
    ids = replay_run_ids(table, roles)
    if not ids:
        have = sorted({str(r) for r in table["role"]})
        raise ReplayError(
            f"no run of role {', '.join(roles) or '(none)'} (deploy.replay_roles) in runs.csv "
            f"(roles there: {', '.join(have)}); pass --run RUN_ID"
        )
    return ids


def file_stem(run_id: str) -> str:
    """A file name for a run id (``thermal_log_2026-10-14#11`` -> ``thermal_log_2026-10-14_11``)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", str(run_id)).strip("_") or "run"


def _interval_text(row: dict) -> str:
    """The model's interval on a run (coverage and median width), empty without one."""
    coverage, width = row.get("coverage"), row.get("interval_width_um")
    if coverage is None or width is None or not (math.isfinite(coverage) and math.isfinite(width)):
        return ""
    return f"; the model's interval (median width {width:.2f} um) held the measurement on {coverage:.0%}"


def _envelope_text(row: dict) -> str:
    """The samples whose model value was held at the training envelope's edge, empty without."""
    n = row.get("n_outside_envelope")
    return f"; model held at its training envelope's edge on {n}" if n else ""


def summary_lines(summary, limits) -> list[str]:
    """What ``rafi replay`` prints per run: counts per status and what each limit did."""
    from rafi.deploy.replay import REPLAY_STATUSES

    lines = []
    for r in summary.to_dict("records"):
        statuses = ", ".join(f"{s} {r[f'n_{s}']}" for s in REPLAY_STATUSES if r.get(f"n_{s}"))
        lo, hi = limits.clamp_um
        lines.append(
            f"{r['run_id']}: {r['n_samples']} samples ({statuses}); "
            f"clamp [{lo:g}, {hi:g}] um acted on {r['n_clamped']}, "
            f"rate limit {limits.rate_um_per_s:g} um/s on {r['n_rate_limited']}, "
            f"fault rule (hold/ramp) on {r['n_hold'] + r['n_ramp']}"
            + (f" [{r['faults']}]" if r["faults"] else "")
            + _envelope_text(r)
            + f"; max |command - model| {r['max_abs_command_minus_model_um']:.2f} um; max |residual| "
            f"{r['max_abs_residual_um']:.2f} um with the limits, {r['max_abs_residual_model_um']:.2f} um "
            f"without (uncompensated {r['max_abs_measured_um']:.2f} um)" + _interval_text(r)
        )
    return lines


def run(args) -> int:
    """``rafi replay``: replay, write the tables and plots, print the summary."""
    import yaml

    from rafi.artefact import write_bytes_atomic, write_csv_atomic
    from rafi.deploy.limits import Limits
    from rafi.deploy.qualified import check_machine
    from rafi.deploy.replay import replay_runs, replay_summary, summary_frame
    from rafi.ops.project import Paths
    from rafi.report.replay_plot import fig_replay
    from rafi.settings import machine_settings

    try:
        with open(args.config, encoding="utf-8") as fh:
            config = yaml.safe_load(fh) or {}
    except OSError as exc:
        raise ReplayError(f"cannot read the config {args.config}: {exc.strerror or exc}") from None
    except yaml.YAMLError as exc:
        raise ReplayError(f"{args.config}: not valid YAML ({exc})") from None
    paths = Paths.from_config(Path("."), config)
    results_dir = paths.results_dir
    check_machine(args.machine, config, results_dir, paths.raw_dir)
    settings = machine_settings(config, args.machine)
    limits = Limits.from_settings(settings["deploy"])
    frame, table = _read_results(results_dir, args.machine)
    ids = _pick_runs(args.runs, table, list(settings["deploy"]["replay_roles"]))
    artefact, source = _load_model(args.model, args.machine, results_dir, settings)
    try:
        replayed = replay_runs(frame, ids, artefact, limits)
    except ValueError as exc:  # not an artefact of the family, edited, a column missing
        raise ReplayError(f"{source}: {exc}") from None
    summary = summary_frame(replay_summary(replayed), artefact=artefact)
    out = Path(args.out) if args.out else results_dir / args.machine / "deploy" / "replay"
    out.mkdir(parents=True, exist_ok=True)
    fmt = str(settings["report"]["figure_format"])
    level = (artefact.get("interval") or {}).get("level")  # the band's legend; none without a block
    for rid in ids:
        rows = replayed[replayed["run_id"] == rid]
        stem = file_stem(rid)
        write_csv_atomic(rows, out / f"{stem}.csv", index=False)
        write_bytes_atomic(
            out / f"{stem}.{fmt}",
            fig_replay(rows, clamp_um=limits.clamp_um, level=level, title=f"Replay of {rid}", fmt=fmt),
        )
    write_csv_atomic(summary, out / "summary.csv", index=False)
    model = f"{artefact.get('kind', '?')} {str(artefact.get('model_id', ''))[:12]}"
    print(f"rafi replay: {args.machine}, model {model} ({source})")
    for line in summary_lines(summary, limits):
        print("  " + line)
    example = ids[0]
    print(
        f"wrote {len(ids)} run(s) to {out}: per run <file>.csv and <file>.{fmt}, where <file> is the run id "
        f"made a file name (e.g. {example} -> {file_stem(example)}.csv), and summary.csv"
    )
    return 0
