"""Replay of a recorded log through the safe compensator, as a controller would run it.

Offline (pandas is used here; the compensator itself stays NumPy only). A log of ``rule runs``'
frame (``results/<machine>/runs.parquet``: ``log``, ``log_t_s``, ``run_id``, ``segment``,
``speed_rpm``, the sensors, ``dz_um``) is fed one sample at a time, in ``log_t_s`` order, through
a :class:`rafi.deploy.limits.SafeCompensator` with the machine's limits in force, powered on at
the log's first sample. The controller is told where a reference is captured exactly as
``tests/test_compensator.py`` tells the bare compensator: ``capture_reference()`` at the first
sample of every run (``reference.rule: run_start``) or of every log segment (``log_start``);
the capture at power-on is the first one.

Functions
---------
:func:`replay_log`
    One log -> one row per sample: what the model said, what was commanded, and why.
:func:`replay_runs`
    The runs asked for: each run's log replayed from its first sample up to the run's end, the
    run's own samples kept.
:func:`replay_summary` / :func:`summary_frame`
    Per run: samples per status, what each limit did, the worst residuals with and without
    the limits (``docs/deploy.md``, section Replay).
"""

from __future__ import annotations

import dataclasses
from collections import Counter

import numpy as np
import pandas as pd

from rafi.contract.sensors import run_sensors
from rafi.deploy.limits import STATUSES, SafeCompensator
from rafi.deploy.metrics import fault_groups, fault_groups_text

__all__ = [
    "COLUMNS",
    "SUMMARY_COLUMNS",
    "replay_log",
    "replay_run_ids",
    "replay_runs",
    "replay_summary",
    "summary_frame",
]

#: Columns of the replay table, in order (``docs/deploy.md``, section Replay).
COLUMNS = (
    "log",
    "run_id",
    "log_t_s",
    "t_s",
    "speed_rpm",
    "measured_um",
    "model_um",
    "lower_um",
    "upper_um",
    "interval_cell",
    "command_um",
    "status",
    "clamped",
    "rate_limited",
    "fault",
    "outside_range",
    "outside_envelope",
    "residual_um",
)

#: The status values a replay counts (``rafi.deploy.limits.STATUSES``, in this order).
REPLAY_STATUSES = tuple(STATUSES)

#: Columns of the summary table (one row per replayed run).
SUMMARY_COLUMNS = (
    "model_id",
    "kind",
    "reference_rule",
    "run_id",
    "log",
    "n_samples",
    *(f"n_{s}" for s in REPLAY_STATUSES),
    "n_clamped",
    "n_rate_limited",
    "n_fault",
    "n_outside_range",
    "n_outside_envelope",
    "faults",
    "max_abs_command_minus_model_um",
    "max_abs_measured_um",
    "max_abs_residual_model_um",
    "max_abs_residual_um",
    "coverage",
    "interval_width_um",
)

_NEEDED = ("log", "log_t_s", "run_id", "t_s", "speed_rpm", "dz_um")


def _reference_rule(artefact: dict, reference_rule: str | None) -> str:
    rule = reference_rule or (artefact.get("reference") or {}).get("rule") or "run_start"
    if rule not in ("run_start", "log_start"):
        raise ValueError(f"reference rule {rule!r}; expected 'run_start' or 'log_start'")
    return rule


def _starts(log: pd.DataFrame, rule: str) -> np.ndarray:
    """True where the controller is told to capture a new reference (the first sample is the
    power-on capture, not a call)."""
    if rule == "run_start":
        key = log["run_id"].astype(str)
    elif "segment" in log:
        key = log["segment"]
    else:  # one segment: the power-on capture only
        return np.zeros(len(log), dtype=bool)
    starts = key.ne(key.shift()).to_numpy(copy=True)
    starts[:1] = False
    return starts


def replay_log(
    frame: pd.DataFrame, artefact: dict, limits, *, reference_rule: str | None = None
) -> pd.DataFrame:
    """Feed one recorded log through a safe compensator, one sample at a time.

    Parameters
    ----------
    frame : DataFrame
        The samples of ONE log (``runs.parquet`` rows with one value of ``log``), in any order:
        they are fed in ``log_t_s`` order (stable), from the first.
    artefact : dict
        A ``rafi.model/1`` artefact of the family (``best_model.json``, a champion).
    limits : rafi.deploy.limits.Limits
        The limits and fault rules in force (``Limits.from_settings``). Its ``interval_s`` is
        replaced by the log's sample period (the median time between samples): a controller
        replaying this log writes once per sample.
    reference_rule : {"run_start", "log_start"}, optional
        When to call ``capture_reference()``: at each run's first sample, or each segment's.
        Default: the artefact's ``reference.rule`` (the rule it was trained with).

    Returns
    -------
    DataFrame
        One row per sample in feeding order, the columns of :data:`COLUMNS`:
        ``measured_um`` is the frame's ``dz_um``, ``model_um`` the compensator's value (NaN
        where it has none), ``lower_um`` / ``upper_um`` / ``interval_cell`` the model's prediction
        interval (around ``model_um``; NaN / ``""`` without the artefact's ``interval`` block or
        a model value), ``command_um`` what would be written, ``residual_um`` =
        ``measured_um - command_um``; ``status``, ``clamped``, ``rate_limited``, ``fault``,
        ``outside_range`` and ``outside_envelope`` (the model's value held at its training
        envelope's edge, :mod:`rafi.family.envelope`) as the safe compensator's command says.

    Raises
    ------
    ValueError
        No rows, more than one log, or a column missing.
    """
    missing = [c for c in _NEEDED if c not in frame.columns] + (
        [] if run_sensors(frame) else ["<sensor> beside its rise d<sensor>"]
    )
    if missing:
        raise ValueError(f"the frame has no column(s) {', '.join(missing)} (runs.parquet of rule runs)")
    logs = frame["log"].astype(str).unique()
    if len(logs) != 1:
        raise ValueError(f"replay_log takes the samples of one log; got {len(logs)} logs")
    rule = _reference_rule(artefact, reference_rule)
    log = frame.sort_values("log_t_s", kind="stable")
    starts = _starts(log, rule)
    sensors = run_sensors(log)
    temps = log[list(sensors)].to_numpy(dtype=float)
    t = log["log_t_s"].to_numpy(dtype=float)
    rpm = log["speed_rpm"].to_numpy(dtype=float)
    steps = np.diff(t)
    steps = steps[steps > 0]
    if len(steps):
        limits = dataclasses.replace(limits, interval_s=float(np.median(steps)))
    safe = SafeCompensator(limits=limits).load(artefact, sensors)
    rows = []
    for k in range(len(log)):
        if starts[k]:
            safe.capture_reference()
        c = safe.step(float(t[k]), float(rpm[k]), temps[k])
        rows.append(
            (
                float(c.model_um),
                float(c.lower_um),
                float(c.upper_um),
                str(c.interval_cell),
                float(c.command_um),
                str(c.status),
                bool(c.clamped),
                bool(c.rate_limited),
                str(c.fault or ""),
                bool(c.outside_range),
                bool(c.outside_envelope),
            )
        )
    got = pd.DataFrame(rows, columns=list(COLUMNS[COLUMNS.index("model_um") : COLUMNS.index("residual_um")]))
    out = pd.DataFrame(
        {
            "log": log["log"].astype(str).to_numpy(),
            "run_id": log["run_id"].astype(str).to_numpy(),
            "log_t_s": t,
            "t_s": log["t_s"].to_numpy(dtype=float),
            "speed_rpm": rpm,
            "measured_um": log["dz_um"].to_numpy(dtype=float),
        }
    )
    out = pd.concat([out, got], axis=1)
    out["residual_um"] = out["measured_um"] - out["command_um"]
    return out[list(COLUMNS)]


def replay_runs(
    frame: pd.DataFrame,
    run_ids,
    artefact: dict,
    limits,
    *,
    reference_rule: str | None = None,
) -> pd.DataFrame:
    """Replay each run of ``run_ids`` as the controller would have met it.

    The run's whole log is fed from its first sample (power-on) up to the run's last sample,
    so the filters carry what came before; the rows of the run itself are returned. A replay is
    causal, so each log is fed once, up to the end of the last run wanted from it.

    Parameters
    ----------
    frame : DataFrame
        ``runs.parquet`` (every log).
    run_ids : iterable of str
        Runs to replay, in the order wanted.
    artefact, limits, reference_rule
        As :func:`replay_log`.

    Returns
    -------
    DataFrame
        The runs' rows of :func:`replay_log`, run after run (index 0..n-1).

    Raises
    ------
    KeyError
        A run id not in ``frame``.
    """
    ids = frame["run_id"].astype(str)
    wanted = [str(r) for r in run_ids]
    for rid in wanted:
        if not (ids == rid).any():
            raise KeyError(rid)
    # a replay is causal: each log once, up to the end of the last run wanted from it
    logs = frame["log"].astype(str)
    ends: dict = {}
    for rid in wanted:
        mine = frame[ids == rid]
        name = str(mine["log"].iloc[0])
        ends[name] = max(ends.get(name, -np.inf), float(mine["log_t_s"].max()))
    tables = {
        name: replay_log(
            frame[(logs == name) & (frame["log_t_s"] <= end)], artefact, limits, reference_rule=reference_rule
        )
        for name, end in ends.items()
    }
    parts = []
    for rid in wanted:
        mine = frame[ids == rid]
        table = tables[str(mine["log"].iloc[0])]
        parts.append(table[table["run_id"] == rid])
    if not parts:
        return pd.DataFrame({c: [] for c in COLUMNS})
    return pd.concat(parts, ignore_index=True)


def _max_abs(values) -> float:
    v = np.abs(np.asarray(values, dtype=float))
    v = v[np.isfinite(v)]
    return float(v.max()) if len(v) else float("nan")


def _count(g: pd.DataFrame, column: str) -> int:
    """Samples where the flag ``column`` is set (0 in a table written before the column)."""
    return int(g[column].astype(bool).sum()) if column in g else 0


def _coverage(g: pd.DataFrame) -> dict:
    """``coverage`` and ``interval_width_um`` of one run's replay rows (:func:`replay_summary`)."""
    lower, upper = g["lower_um"].to_numpy(dtype=float), g["upper_um"].to_numpy(dtype=float)
    measured = g["measured_um"].to_numpy(dtype=float)
    use = (g["status"].astype(str).to_numpy() != "referencing") & np.isfinite(measured)
    use &= np.isfinite(lower) & np.isfinite(upper)
    if not use.any():
        return {"coverage": float("nan"), "interval_width_um": float("nan")}
    inside = (measured[use] >= lower[use]) & (measured[use] <= upper[use])
    return {"coverage": float(inside.mean()), "interval_width_um": float(np.median((upper - lower)[use]))}


def replay_summary(table: pd.DataFrame) -> dict:
    """What the limits did on each replayed run, from the replay table alone.

    Parameters
    ----------
    table : DataFrame
        Rows of :func:`replay_log` / :func:`replay_runs`.

    Returns
    -------
    dict
        ``run_id -> dict`` (runs in table order) with the keys of :data:`SUMMARY_COLUMNS`:
        ``n_samples``; ``n_<status>`` per status of :data:`REPLAY_STATUSES` (a status not
        listed there is counted too, as ``n_<status>``); ``n_clamped``, ``n_rate_limited``,
        ``n_fault`` (samples with a fault), ``n_outside_range``, ``n_outside_envelope`` (samples
        whose model value was held at the training envelope's edge; 0 for a table without the
        column, written before it); ``faults`` (per fault class of
        :func:`rafi.deploy.metrics.fault_classes`, in order of first appearance: the samples with
        a cause of the class and the first such cause, ``"missing: 4 (first: T8 missing); ..."``,
        :func:`rafi.deploy.metrics.fault_groups_text`: one entry per class, however many
        measured values the causes name);
        ``max_abs_command_minus_model_um`` (where the model has a value), ``max_abs_measured_um``
        (uncompensated), ``max_abs_residual_model_um`` (measured - model: without the limits,
        where the model has a value) and ``max_abs_residual_um`` (measured - command: with them);
        ``coverage`` (the fraction of the samples after the reference window, with a finite
        measurement and a model interval, whose measurement lies inside the model's interval)
        and ``interval_width_um`` (the median ``upper_um - lower_um`` over those samples), NaN
        without such samples (an artefact without an ``interval`` block).
    """
    out: dict = {}
    for rid, g in table.groupby(table["run_id"].astype(str), sort=False):
        status = Counter(g["status"].astype(str))
        model = g["model_um"].to_numpy(dtype=float)
        command = g["command_um"].to_numpy(dtype=float)
        measured = g["measured_um"].to_numpy(dtype=float)
        row = {"run_id": rid, "log": str(g["log"].iloc[0]), "n_samples": len(g)}
        for s in (*REPLAY_STATUSES, *sorted(set(status) - set(REPLAY_STATUSES))):
            row[f"n_{s}"] = int(status.get(s, 0))
        row.update(
            n_clamped=int(g["clamped"].astype(bool).sum()),
            n_rate_limited=int(g["rate_limited"].astype(bool).sum()),
            n_fault=int((g["fault"].astype(str) != "").sum()),
            n_outside_range=int(g["outside_range"].astype(bool).sum()),
            n_outside_envelope=_count(g, "outside_envelope"),
            faults=fault_groups_text(fault_groups(g["fault"].astype(str))),
            max_abs_command_minus_model_um=_max_abs(command - model),
            max_abs_measured_um=_max_abs(measured),
            max_abs_residual_model_um=_max_abs(measured - model),
            max_abs_residual_um=_max_abs(measured - command),
            **_coverage(g),
        )
        out[rid] = row
    return out


def summary_frame(summary: dict, *, artefact: dict | None = None) -> pd.DataFrame:
    """:func:`replay_summary` as a table (``replay_summary.csv``): one row per run, the columns of
    :data:`SUMMARY_COLUMNS` (and ``n_<status>`` of any other status after ``n_ramp``);
    ``model_id``, ``kind`` and ``reference_rule`` (when the replay captured a reference: the
    artefact's ``reference.rule``, as :func:`replay_log` uses it) from ``artefact`` (empty
    without it)."""
    art = artefact or {}
    model = {
        "model_id": str(art.get("model_id", "")),
        "kind": str(art.get("kind", "")),
        "reference_rule": _reference_rule(art, None) if art else "",
    }
    rows = [{**model, **r} for r in summary.values()]
    extra = sorted({k for r in rows for k in r} - set(SUMMARY_COLUMNS))
    cols = list(SUMMARY_COLUMNS)
    at = cols.index("n_clamped")
    cols[at:at] = extra
    return pd.DataFrame(rows, columns=cols)


def replay_run_ids(table: pd.DataFrame, roles) -> list[str]:
    """Run ids of ``runs.csv`` whose role is one of ``roles`` (``deploy.replay_roles``), in the
    table's order."""
    wanted = {str(r) for r in roles}
    return [str(r.run_id) for r in table.itertuples(index=False) if str(r.role) in wanted]
