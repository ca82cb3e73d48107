"""Cutting clean logs into runs, giving each a role and a reference state.

:func:`find_runs` works on each file and each ``segment`` of it separately (a run
never spans a gap). Within a segment:

0. The speed is smoothed by a centred rolling median of ``SPEED_SMOOTH_S``
   (60 s, at least 3 samples) for the cutting only (steps stay sharp; speed
   noise and single ramp samples go); run statistics use the logged speed.
1. **Idle** samples: ``speed_rpm < idle_below_rpm`` (or unknown speed).
2. **Pieces** of the non-idle stretches: a piece continues while the speed stays
   within ``speed_tolerance_rpm`` of the speed at its first sample; adjacent
   pieces whose medians differ by at most the tolerance are merged again (speed
   noise does not fragment a constant stretch).
3. A non-idle piece lasting at least ``min_constant_s`` is **constant**;
   consecutive shorter non-idle pieces form a varying stretch.
4. **Ramp samples**: a varying stretch of at most ``RAMP_MAX_SAMPLES`` samples
   next to a constant piece (the spindle ramping up or down between two log
   samples) is absorbed into that constant run (the following one when the
   stretch precedes a constant piece, else the preceding one).
5. Varying stretches separated only by an idle piece shorter than
   ``min_constant_s`` (a stop inside a multi-condition schedule) are merged,
   idle piece included, into one **varying** run. So one cold-start log with
   several short speed steps is ONE varying run.
6. **Rest before start**: an idle piece at the very start of a segment that is shorter
   than ``max_leading_rest_s`` (default 300 s) and followed by a non-idle run is absorbed
   into that run as its rest before start (a cold-start log: the logger is started with
   the machine at rest, then the spindle). A one-run file stays one run (``run_id`` = the
   stem), ``t_s`` of the run starts at the log (segment) start, and the reference window
   falls on the rest: the reference state is the cold machine at rest, which is also what
   a compensation on the controller is relative to. The kind (constant / varying) and the
   speed statistics (``speed_rpm``, ``speed_min_rpm``, ``speed_max_rpm``) ignore the rest;
   ``duration_s`` counts every sample of the run, rest included; ``note`` states the rest.
   A longer leading idle piece stays an idle run of its own.
7. Every other idle piece is an **idle** run.

Roles: ``excluded`` when shorter than ``min_run_s`` (reason in ``note``);
constant within ``speed_tolerance_rpm`` of a training speed -> ``training``;
other constant -> ``validation_single``; varying -> ``validation_multi``; idle ->
``validation_idle``. ``overrides`` (keyed by run_id, else file stem) set the role
with ``role_source = 'config'``.

Durations count samples: ``duration_s = n_samples * period``; ``start_s`` and
``end_s`` are the ``t_s`` (seconds since the first sample of the file) of the
first and last sample of the run.

Reference state: ``dT_i = T_i - T_i,ref`` and ``dz_um = disp_um - disp_ref`` with
the reference = median (NaN ignored) over the first ``reference_window_s`` of the
run (``run_start``) or of the segment the run came from (``log_start``); at
least one sample is always used. A sensor without a valid value in the window
gets NaN rises for that run (stated in ``note``); NaN values left by cleaning stay
NaN in the rises, and later steps drop them.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from rafi import SENSORS
from rafi.method.windows import (
    VALIDATION_BY_KIND,
    check_windows,
    cut_points,
    leak_check,
    resolve_windows,
    window_of,
)
from rafi.settings import MACHINE_DEFAULTS

#: Roles a run can have (``docs/design.md``).
ROLES = ("training", "validation_single", "validation_multi", "validation_idle", "excluded")

#: Columns of ``runs.csv``, in order.
RUNS_TABLE_COLUMNS = (
    "run_id",
    "file",
    "segment",
    "start_s",
    "end_s",
    "duration_s",
    "speed_rpm",
    "speed_min_rpm",
    "speed_max_rpm",
    "kind",
    "role",
    "role_source",
    "reference",
    "sha256",
    "note",
    "role_reason",
    "start_time",
    "end_time",
)

#: Columns of ``runs.parquet``, in order.
RUNS_FRAME_COLUMNS = (
    "run_id",
    "t_s",
    "time",
    "speed_rpm",
    *SENSORS,
    "disp_um",
    *(f"d{s}" for s in SENSORS),
    "dz_um",
    "log",
    "log_t_s",
    "segment",
)

#: Width (s) of the centred rolling median applied to the speed before cutting it into
#: pieces (at least 3 samples): removes speed noise and isolated ramp samples, keeps steps sharp.
SPEED_SMOOTH_S = 60.0

#: A varying stretch of at most this many samples next to a constant run is a ramp.
RAMP_MAX_SAMPLES = 3

#: File-name suffixes removed from the keys of ``clean_frames`` to get the stem.
LOG_SUFFIXES = (".csv", ".xlsx", ".xls", ".txt", ".parquet", ".tsv")

REFERENCE_RULES = ("run_start", "log_start")


def _stem(key: str) -> str:
    p = Path(str(key))
    return p.stem if p.suffix.lower() in LOG_SUFFIXES else p.name


def _period(t_s: np.ndarray, seg: np.ndarray) -> float:
    if len(t_s) < 2:
        return 1.0
    d = np.diff(t_s)[seg[1:] == seg[:-1]]
    d = d[d > 0]
    return float(np.median(d)) if len(d) else 1.0


def _pieces(speed: np.ndarray, idle: np.ndarray, tol: float) -> list[list]:
    """Pieces ``[start, end_exclusive, is_idle]`` of one segment."""
    n = len(speed)
    pieces: list[list] = []
    change = np.flatnonzero(np.diff(idle.astype(np.int8))) + 1
    bounds = np.concatenate(([0], change, [n]))
    for a, b in zip(bounds[:-1], bounds[1:]):
        if idle[a]:
            pieces.append([a, b, True])
            continue
        i = a
        while i < b:
            anchor = speed[i]
            j, w = i + 1, 64
            end = b
            while j < b:
                stop = min(b, j + w)
                out = np.abs(speed[j:stop] - anchor) > tol
                if out.any():
                    end = j + int(np.argmax(out))
                    break
                j, w = stop, w * 2
            pieces.append([i, end, False])
            i = end
    # merge adjacent non-idle pieces whose medians agree (speed noise around one set point)
    merged: list[list] = []
    for p in pieces:
        if merged and not p[2] and not merged[-1][2] and merged[-1][1] == p[0]:
            q = merged[-1]
            if abs(np.median(speed[q[0] : q[1]]) - np.median(speed[p[0] : p[1]])) <= tol:
                q[1] = p[1]
                continue
        merged.append(list(p))
    return merged


def _segment_runs(
    speed: np.ndarray,
    period: float,
    *,
    tol: float,
    idle_below: float,
    min_constant_s: float,
    max_leading_rest_s: float = 0.0,
) -> list[tuple[int, int, str, int]]:
    """Runs ``(start, end_exclusive, kind, rest_samples)`` of one segment, in time order.

    ``rest_samples`` > 0 for a run that absorbed the segment's leading rest (its first
    ``rest_samples`` samples are the rest, idle).
    """
    win = max(3, 2 * int(round(SPEED_SMOOTH_S / 2 / period)) + 1)
    smooth = pd.Series(speed).rolling(win, center=True, min_periods=1).median().to_numpy()
    idle = ~(smooth >= idle_below)  # NaN speed counts as idle
    pieces = _pieces(smooth, idle, tol)
    min_const_n = min_constant_s / period
    groups: list[list] = []  # [start, end_exclusive, kind]
    for a, b, is_idle in pieces:
        kind = "idle" if is_idle else ("constant" if (b - a) >= min_const_n - 1e-9 else "varying")
        if kind == "varying" and groups and groups[-1][2] == "varying" and groups[-1][1] == a:
            groups[-1][1] = b  # consecutive short pieces: one stretch
        else:
            groups.append([a, b, kind])
    # ramps: a tiny varying stretch next to a constant run is absorbed by it
    kept: list[list] = []
    for k, g in enumerate(groups):
        if g[2] == "varying" and g[1] - g[0] <= RAMP_MAX_SAMPLES:
            nxt = groups[k + 1] if k + 1 < len(groups) else None
            if nxt is not None and nxt[2] == "constant" and nxt[0] == g[1]:
                nxt[0] = g[0]
                continue
            if kept and kept[-1][2] == "constant" and kept[-1][1] == g[0]:
                kept[-1][1] = g[1]
                continue
        kept.append(g)
    # a short idle stretch between two varying stretches is a stop inside the schedule
    out: list[list] = []
    for g in kept:
        if out and g[2] == "varying" and out[-1][2] == "varying":
            out[-1][1] = g[1]
            continue
        if (
            len(out) >= 2
            and g[2] == "varying"
            and out[-1][2] == "idle"
            and out[-2][2] == "varying"
            and (out[-1][1] - out[-1][0]) < min_const_n
        ):
            out.pop()
            out[-1][1] = g[1]
            continue
        out.append(g)
    rest = [0] * len(out)
    # a short rest at the segment start belongs to the following run (cold start from rest)
    if (
        len(out) >= 2
        and out[0][2] == "idle"
        and out[1][2] != "idle"
        and out[0][0] == 0
        and (out[0][1] - out[0][0]) * period < float(max_leading_rest_s) - 1e-9
    ):
        n_rest = out[0][1] - out[0][0]
        out[1][0] = out[0][0]
        out.pop(0)
        rest = [n_rest] + [0] * (len(out) - 1)
    return [(int(a), int(b), kind, int(r)) for (a, b, kind), r in zip(out, rest)]


def find_runs(
    clean_frames: dict,
    sha256: dict,
    *,
    training_speeds_rpm,
    speed_tolerance_rpm: float,
    idle_below_rpm: float,
    min_run_s: float,
    min_constant_s: float,
    overrides,
    reference_rule: str,
    reference_window_s: float,
    max_leading_rest_s: float = MACHINE_DEFAULTS["runs"]["max_leading_rest_s"],
    windows=MACHINE_DEFAULTS["runs"]["windows"],
    idle_training: bool = MACHINE_DEFAULTS["runs"]["idle_training"],
    allow_training_after_validation: bool = MACHINE_DEFAULTS["runs"]["allow_training_after_validation"],
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Find the runs of a machine's clean logs, classify them and compute the rises.

    Parameters
    ----------
    clean_frames : dict of str -> pandas.DataFrame
        File stem (a file name such as ``x.csv`` is accepted too; the stem is then
        the name without its suffix) -> clean frame of :func:`rafi.method.clean.clean_log`
        (``time``, ``t_s``, ``speed_rpm``, ``T1``..``T16``, ``disp_um``,
        ``segment``). Files are processed in sorted key order.
    sha256 : dict of str -> str
        Same keys -> SHA-256 of the raw file (missing keys give an empty text).
    training_speeds_rpm : sequence of float
        Speeds the model is trained at.
    speed_tolerance_rpm : float
        Tolerance both for "constant" speed and for matching a training speed.
    idle_below_rpm : float
        Speeds below this are idle.
    min_run_s : float
        Runs shorter than this are ``excluded``.
    min_constant_s : float
        A constant-speed piece shorter than this is part of a varying run.
    overrides : dict of str -> str or None
        Run id or file stem -> role (one of ``ROLES``); run id wins over stem.
    reference_rule : {'run_start', 'log_start'}
        Where the reference state is taken.
    reference_window_s : float
        Length of the reference window, seconds.
    max_leading_rest_s : float
        An idle stretch at the start of a segment shorter than this (s) is the rest before
        the start of the following run and is absorbed into it (``0``: never).
    windows : sequence of mapping
        ``runs: windows:``, roles by time (:mod:`rafi.method.windows`); runs are cut where a
        window starts or ends. A run in a window gets the window's role (``role_source =
        'window'``); run-id overrides still win.
    idle_training : bool
        Idle runs (cool-downs) that would be validation (automatic role) or lie in a training
        window are ``training`` runs (the family's models learn the cool-down; RAFI as
        published ignores idle training runs).
    allow_training_after_validation : bool
        Accept configured training data after validation data of the same log (the leak guard,
        :func:`rafi.method.windows.leak_check`, otherwise refuses it).

    Returns
    -------
    runs_table : pandas.DataFrame
        One row per run, columns ``RUNS_TABLE_COLUMNS`` (``docs/design.md`` plus
        ``note``). ``run_id`` is the stem when the file gives one run, else
        ``f"{stem}#{k}"`` with ``k = 1, 2, ...`` in time order.
    runs_frame : pandas.DataFrame
        All runs stacked (RangeIndex), columns ``RUNS_FRAME_COLUMNS``; ``t_s`` is
        seconds since the start of the run (for a run with an absorbed rest: since the
        start of the rest, i.e. of the log segment).

    Raises
    ------
    ValueError
        On an unknown ``reference_rule`` or an override with an unknown role.
    rafi.errors.SettingsError
        A bad or overlapping window, or configured training data after validation data of the
        same log (unless ``allow_training_after_validation``).
    """
    if reference_rule not in REFERENCE_RULES:
        raise ValueError(
            f"reference_rule is {reference_rule!r}; expected one of {', '.join(REFERENCE_RULES)}"
        )
    overrides = dict(overrides or {})
    for key, role in overrides.items():
        if role not in ROLES:
            raise ValueError(f"override {key!r}: role {role!r} is not one of {', '.join(ROLES)}")
    train = np.asarray(sorted(float(s) for s in (training_speeds_rpm or [])), dtype=float)
    tol = float(speed_tolerance_rpm)
    window = float(reference_window_s)
    windows = check_windows(windows)

    rows: list[dict] = []
    parts: dict[str, list] = {c: [] for c in RUNS_FRAME_COLUMNS}
    for key in sorted(clean_frames):
        fr = clean_frames[key]
        stem = _stem(key)
        n_rows = len(fr)
        if n_rows == 0:
            continue
        t_s = (
            fr["t_s"].to_numpy(dtype=float)
            if "t_s" in fr
            else (pd.to_datetime(fr["time"]) - pd.to_datetime(fr["time"]).iloc[0])
            .dt.total_seconds()
            .to_numpy()
        )
        seg = fr["segment"].to_numpy(dtype="int64") if "segment" in fr else np.zeros(n_rows, "int64")
        speed = fr["speed_rpm"].to_numpy(dtype=float, na_value=np.nan)
        temps = np.column_stack(
            [
                fr[s].to_numpy(dtype=float, na_value=np.nan) if s in fr else np.full(n_rows, np.nan)
                for s in SENSORS
            ]
        )
        disp = fr["disp_um"].to_numpy(dtype=float, na_value=np.nan)
        times = (
            fr["time"].to_numpy(dtype="datetime64[ns]")
            if "time" in fr
            else np.full(n_rows, np.datetime64("NaT"), dtype="datetime64[ns]")
        )
        period = _period(t_s, seg)

        found = []  # (segment, seg_first_row, a, b, kind)
        change = np.flatnonzero(seg[1:] != seg[:-1]) + 1
        for s0, s1 in zip(np.concatenate(([0], change)), np.concatenate((change, [n_rows]))):
            for a, b, kind, rest in _segment_runs(
                speed[s0:s1],
                period,
                tol=tol,
                idle_below=float(idle_below_rpm),
                min_constant_s=float(min_constant_s),
                max_leading_rest_s=float(max_leading_rest_s),
            ):
                found.append((int(seg[s0]), int(s0), int(s1), int(s0 + a), int(s0 + b), kind, int(rest)))
        log_windows = resolve_windows(windows, str(key), t_s, times)
        found = _cut_at(found, cut_points(log_windows, t_s))

        first_row = len(rows)
        for k, (segment, s0, s1, a, b, kind, rest) in enumerate(found, start=1):
            run_id = stem if len(found) == 1 else f"{stem}#{k}"
            sp = speed[a:b]
            sp_on = speed[a + rest : b]  # speed statistics ignore the rest
            med = float(np.nanmedian(sp_on)) if np.isfinite(sp_on).any() else float("nan")
            duration = (b - a) * period
            notes = []
            if rest:
                notes.append(
                    f"rest before start: {rest * period:g} s at rest absorbed (reference "
                    "state = cold machine at rest)"
                )
            auto, reason = _auto_role(
                kind, med, duration, train, tol, float(min_run_s), float(idle_below_rpm)
            )
            if auto == "validation_idle" and idle_training:
                auto, reason = "training", reason + "; idle cool-down used for training (runs.idle_training)"
            role, source = auto, "auto"
            win = window_of(log_windows, float(t_s[a]))
            if win is not None:
                what = f"constant at {med:.0f} r/min" if kind == "constant" else kind
                role, source, reason = _window_role(
                    win, what, kind, duration, float(min_run_s), idle_training
                )
            for okey in (run_id, stem, str(key)):
                if okey in overrides:
                    reason = f"run-id override {okey!r} in runs.overrides (otherwise: {role}, {reason})"
                    role, source = overrides[okey], "config"
                    break

            # reference state
            if reference_rule == "run_start":
                r0, r_end = a, b
                ref_text = f"median of the first {window:g} s of the run (run_start)"
            else:
                r0, r_end = s0, s1
                ref_text = f"median of the first {window:g} s of segment {segment} of the log (log_start)"
            r1 = r0 + max(1, int(np.searchsorted(t_s[r0:r_end], t_s[r0] + window - 1e-9, side="left")))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN window -> NaN
                ref_T = np.nanmedian(temps[r0:r1], axis=0)
                ref_z = float(np.nanmedian(disp[r0:r1]))
            no_ref = [SENSORS[i] for i in range(16) if np.isnan(ref_T[i])]
            if np.isnan(ref_z):
                no_ref.append("disp_um")
            if no_ref:
                notes.append(f"no valid reference value for {', '.join(no_ref)}: rises are NaN")

            rows.append(
                {
                    "run_id": run_id,
                    "file": str(key),
                    "segment": segment,
                    "start_s": float(t_s[a]),
                    "end_s": float(t_s[b - 1]),
                    "duration_s": float(duration),
                    "speed_rpm": med,
                    "speed_min_rpm": float(np.nanmin(sp_on)) if np.isfinite(sp_on).any() else float("nan"),
                    "speed_max_rpm": float(np.nanmax(sp_on)) if np.isfinite(sp_on).any() else float("nan"),
                    "kind": kind,
                    "role": role,
                    "role_source": source,
                    "reference": ref_text,
                    "sha256": str(sha256.get(key, sha256.get(stem, ""))),
                    "note": "; ".join(notes),
                    "role_reason": reason,
                    "start_time": _iso(times[a]),
                    "end_time": _iso(times[b - 1]),
                }
            )
            n = b - a
            parts["run_id"].append((run_id, n))
            parts["t_s"].append(t_s[a:b] - t_s[a])
            parts["time"].append(times[a:b])
            parts["speed_rpm"].append(sp)
            for i, s in enumerate(SENSORS):
                parts[s].append(temps[a:b, i])
                parts[f"d{s}"].append(temps[a:b, i] - ref_T[i])
            parts["disp_um"].append(disp[a:b])
            parts["dz_um"].append(disp[a:b] - ref_z)
            parts["log"].append((str(key), n))
            parts["log_t_s"].append(t_s[a:b])
            parts["segment"].append(seg[a:b])
        rows[first_row:] = _guard_log(rows[first_row:], allow_training_after_validation)

    table = pd.DataFrame(rows, columns=list(RUNS_TABLE_COLUMNS))
    table = table.astype(
        {
            "segment": "int64",
            "start_s": "float64",
            "end_s": "float64",
            "duration_s": "float64",
            "speed_rpm": "float64",
            "speed_min_rpm": "float64",
            "speed_max_rpm": "float64",
        }
    )
    ids = parts.pop("run_id")
    logs = parts.pop("log")
    data = {
        "run_id": pd.Categorical.from_codes(
            np.repeat(np.arange(len(ids)), [n for _, n in ids]), categories=[r for r, _ in ids]
        ).astype("str")
        if ids
        else pd.array([], dtype="str")
    }
    data["log"] = (
        np.repeat(np.array([k for k, _ in logs], dtype=object), [n for _, n in logs])
        if logs
        else np.array([], dtype=object)
    )
    for c in RUNS_FRAME_COLUMNS[1:]:
        if c == "log":
            continue
        if parts[c]:
            data[c] = np.concatenate(parts[c])
        else:
            data[c] = np.array(
                [], dtype="datetime64[ns]" if c == "time" else (object if c == "run_id" else float)
            )
    frame = pd.DataFrame(data, columns=list(RUNS_FRAME_COLUMNS))
    frame["segment"] = frame["segment"].astype("int64")
    return table, frame


def _iso(value) -> str:
    return "" if pd.isna(value) else pd.Timestamp(value).isoformat()


def _cut_at(found: list, cuts: np.ndarray) -> list:
    """``found`` runs split at the sample indices ``cuts`` (window boundaries)."""
    out = []
    for segment, s0, s1, a, b, kind, rest in found:
        inner = [int(c) for c in cuts if a < c < b]
        for x, y in zip([a, *inner], [*inner, b]):
            out.append((segment, s0, s1, x, y, kind, min(rest, y - x) if x == a else 0))
    return out


def _auto_role(kind, speed, duration, train, tol, min_run_s, idle_below) -> tuple[str, str]:
    """The automatic role of a run and why, in words."""
    if duration < min_run_s - 1e-9:
        return "excluded", f"shorter than runs.min_run_s ({duration:g} s < {min_run_s:g} s)"
    if kind == "constant":
        if len(train) and np.min(np.abs(train - speed)) <= tol + 1e-9:
            return "training", f"constant at {speed:.0f} r/min, a training speed"
        return "validation_single", f"constant at {speed:.0f} r/min, not a training speed"
    if kind == "varying":
        return "validation_multi", "varying speed (steps shorter than runs.min_constant_s)"
    return "validation_idle", f"idle (spindle below {idle_below:g} r/min): a cool-down"


def _window_role(win, what, kind, duration, min_run_s, idle_training) -> tuple[str, str, str]:
    """Role, source and reason of a run of ``kind`` (``what``: the kind for people) inside the
    window ``win``."""
    if win.role == "excluded":
        return "excluded", "window", f"in the {win.text}"
    if duration < min_run_s - 1e-9:
        return "excluded", "window", f"in the {win.text} but shorter than runs.min_run_s ({duration:g} s)"
    if win.role == "validation":
        return VALIDATION_BY_KIND[kind], "window", f"in the {win.text} ({what})"
    if kind == "idle" and not idle_training:
        return "excluded", "window", f"idle, in the {win.text}, and runs.idle_training is false"
    return "training", "window", f"in the {win.text} ({what})"


def _guard_log(rows: list[dict], allow: bool) -> list[dict]:
    """The runs of one log after the leak guard (:func:`rafi.method.windows.leak_check`)."""
    if not rows:
        return rows
    return leak_check(pd.DataFrame(rows), allow=allow).to_dict("records")
