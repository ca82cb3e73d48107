"""``rafi init --preview``: the runs the pipeline will find for a configured machine, before any fit.

:func:`preview` reads the machine's raw files as the clean step does
(:func:`rafi.readers.input_spec.scan_logs`, :func:`rafi.readers.logs.read_log`,
:func:`rafi.method.clean.clean_log` with the machine's settings) and cuts them into runs as the
method step does (:func:`rafi.method.runs.find_runs`), without Snakemake and without writing
anything. It lists every run (log, start, duration, speed, kind, role and why, the reference
rule) and warns where the configuration and the data disagree (:func:`preview_warnings`): a
continuous log referenced by ``run_start``, no run at a training speed, no validation run with
the spindle turning, a window, a window's ``log`` glob or an override that matches nothing.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd

from rafi.errors import RafiUserError, SettingsError


def clean_frames(paths: list[Path], settings: Mapping) -> tuple[dict, list[str]]:
    """``{log name: clean frame}`` of the logs that read and clean, and a line for each that does
    not. The logs are the pipeline's (:func:`rafi.readers.log_sources.expand_logs`): a file, every
    matching sheet of a workbook (``input.sheet`` a pattern), a file joined with its partner
    (``input.join``); a file neither log nor partner, or without its partner, gets a line."""
    from rafi.method.clean import clean_log
    from rafi.readers.input_spec import normalise_input_spec
    from rafi.readers.log_sources import expand_logs, log_name
    from rafi.readers.logs import read_log

    frames, problems = {}, []
    cfg = settings["clean"]
    try:
        logs, problems = expand_logs(list(paths), normalise_input_spec(settings["input"]))
    except RafiUserError as exc:
        return {}, [f"not read: {exc}"]
    for key, src in logs.items():
        name, path = log_name(key, src), Path(src["path"])
        try:
            frame = read_log(path, settings["input"], sheet=src["sheet"], partner=src["partner"], name=name)
            frames[name], _ = clean_log(
                frame,
                file=name,
                sample_period_s=settings["sample_period_s"],
                max_interpolate_gap_s=cfg["max_interpolate_gap_s"],
                spike_threshold=cfg["spike_threshold"],
                open_circuit_values=cfg["open_circuit_values"],
            )
        except RafiUserError as exc:
            problems.append(f"{name}: not read: {exc}")
    return frames, problems


def runs_arguments(settings: Mapping) -> dict:
    """The keyword arguments of :func:`rafi.method.runs.find_runs` from a machine's effective settings
    (:func:`rafi.settings.machine_settings`): what the workflow's runs step passes as params."""
    runs = settings["runs"]
    keys = ("idle_below_rpm", "min_run_s", "min_constant_s", "overrides", "max_leading_rest_s", "windows")
    return {
        "training_speeds_rpm": settings["training_speeds_rpm"],
        "speed_tolerance_rpm": settings["speed_tolerance_rpm"],
        **{key: runs[key] for key in keys},
        "idle_training": runs["idle_training"],
        "allow_training_after_validation": runs["allow_training_after_validation"],
        "reference_rule": settings["reference"]["rule"],
        "reference_window_s": settings["reference"]["window_s"],
    }


def segment(frames: Mapping, settings: Mapping) -> pd.DataFrame:
    """The runs table :func:`rafi.method.runs.find_runs` gives with the machine's settings."""
    from rafi.method.runs import find_runs

    table, _ = find_runs(dict(frames), {}, **runs_arguments(settings))
    return table


def _window_warnings(frames: Mapping, windows: list) -> list[str]:
    """A line for each window whose ``log`` glob matches no file, or that holds no sample."""
    from rafi.method.windows import resolve_windows

    out = []
    for k, spec in enumerate(windows or []):
        glob = str(spec.get("log", "*"))
        names = [n for n in frames if fnmatch.fnmatch(n, glob)]
        if not names:
            out.append(f"runs.windows[{k}].log {glob!r} matches no file (files: {', '.join(sorted(frames))})")
            continue
        hit = False
        for name in names:
            t_s = frames[name]["t_s"].to_numpy(dtype=float)
            times = frames[name]["time"].to_numpy() if "time" in frames[name] else None
            for w in resolve_windows([spec], name, t_s, times):
                hit = hit or bool(((t_s >= w.start_s) & (t_s < w.end_s)).any())
        if not hit:
            out.append(f"runs.windows[{k}] holds no sample of {', '.join(names)}: check its start and end")
    return out


def preview_warnings(table: pd.DataFrame, frames: Mapping, settings: Mapping) -> list[str]:
    """What in the configuration the runs contradict, one line each naming the key."""
    out = []
    from rafi.method.run_checks import continuous_log_warnings
    from rafi.ops.outcome import one_instruction

    moving = table[(table["kind"] != "idle") & (table["role"] != "excluded")]
    # the pipeline's, runs counted alike, in the end-of-run line's words (one instruction)
    out += [one_instruction(w) for w in continuous_log_warnings(table, settings["reference"]["rule"])]
    trained = table[(table["role"] == "training") & (table["kind"] != "idle")]
    if trained.empty:
        found = sorted({float(x) for x in moving.loc[moving["kind"] == "constant", "speed_rpm"].round()})
        speeds = (
            f"the constant runs found are at {', '.join(f'{x:g}' for x in found)} r/min"
            if found
            else "no constant run was found"
        )
        out.append(
            f"no run at a training speed: training_speeds_rpm is {list(settings['training_speeds_rpm'])}, "
            f"{speeds}"
        )
    validating = table["role"].astype(str).str.startswith("validation")
    if not (validating & (table["kind"] != "idle")).any():
        what = (
            "only cool-downs validate: the pipeline qualifies a model on the spindle at rest"
            if validating.any()
            else "no validation run: the pipeline fits a model but cannot qualify it"
        )
        out.append(
            f"{what}; add a validation log, or split a continuous log in time, e.g. the last 30 %: "
            "runs: {windows: [{role: training, end: 0.7, unit: fraction}, {role: validation, start: 0.7, "
            "unit: fraction}]}"
        )
    out += _window_warnings(frames, settings["runs"]["windows"])
    stems = {Path(n).stem for n in frames}
    for key in settings["runs"]["overrides"] or {}:
        if key not in set(table["run_id"]) and key not in stems:
            out.append(f"runs.overrides[{key!r}] matches no run id or file")
    return out


def _hours(seconds: float) -> str:
    return f"{seconds / 3600:6.2f} h"


def run_lines(table: pd.DataFrame) -> list[str]:
    """One line per run: id, start, duration, speed, kind, role and why."""
    lines = []
    for _, r in table.iterrows():
        lo, hi = r.get("speed_min_rpm"), r.get("speed_max_rpm")
        speed = f"{lo:g}-{hi:g}" if r["kind"] == "varying" and np.isfinite(lo) else f"{r['speed_rpm']:g}"
        why = r.get("role_reason") or r.get("note") or ""
        lines.append(
            f"  {r['run_id']:<28} {_hours(r['start_s'])} +{_hours(r['duration_s'])}  {speed:>11} r/min  "
            f"{r['kind']:<8} {r['role']:<17} {why}"
        )
    return lines


def preview(config_path: str, machine: str) -> list[str]:
    """The lines ``rafi init --preview`` prints for ``machine`` of ``config_path``.

    Raises
    ------
    SettingsError
        The machine is not configured, no raw file matches its pattern, or its settings are
        refused by the segmentation (a bad window: the message names the key).
    """
    from rafi.readers.input_spec import scan_logs
    from rafi.settings import machine_settings, read_machine_config, run_settings, split_unit, unit_name

    config, settings = read_machine_config(config_path, machine)
    folder_name, probe = split_unit(machine)
    probes = list(settings["input"]["probes"])
    if probe is None and len(probes) > 1:  # the runs do not depend on the probe: its first one's
        settings = machine_settings(config, unit_name(folder_name, probes[0]))
    folder = Path(run_settings(config)["raw_dir"]) / folder_name
    paths, refused = scan_logs(folder, settings["input"]) if folder.is_dir() else ([], [])
    if not paths:
        raise SettingsError(
            f"machine {machine!r}: no file in {folder} matches input.pattern {settings['input']['pattern']!r}"
        )
    frames, problems = clean_frames(paths, settings)
    out = [f"rafi init --preview: machine {machine}, {len(paths)} file(s) in {folder}"]
    if probe is None and len(probes) > 1:
        out.append(f"  probes: {', '.join(probes)} (one model each; the runs below are every probe's)")
    out += [f"  {line}" for line in refused + problems]
    if not frames:
        return out + ["no file could be read: nothing to segment"]
    table = segment(frames, settings)
    ref = settings["reference"]
    out.append(f"reference: {ref['rule']} (median of the first {ref['window_s']:g} s)")
    out.append(f"{len(table)} runs; roles: {table['role'].value_counts().to_dict()}")
    out += run_lines(table)
    warnings = preview_warnings(table, frames, settings)
    out += [f"warning: {w}" for w in warnings] or ["no warnings"]
    return out
