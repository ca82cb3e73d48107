"""Section "The model on the machine: replay of <run>": the offered model run as the controller runs it.

Reads ``deploy/replay_summary.csv`` (rule ``replay``: one row per replayed run), the limits in
force from the machine's settings (``deploy:``, the values rule ``replay`` was given) and the
registry decision (is the replayed model on the machine after this run?). The figures are files
of rule ``report_figures`` (group ``replay``). Computed here besides formatting: the faults of
the replay table ``deploy/replay.parquet`` (same rule) by class over all replayed runs
(:func:`rafi.deploy.metrics.fault_groups`), as the figure classifies them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from markupsafe import Markup, escape

from rafi.deploy.metrics import fault_classes, fault_groups, fault_groups_text
from rafi.report.envelope_text import MEANING, held_runs
from rafi.report.format import fmt_num, isnum, records, short_id
from rafi.report.intervals import band_label, coverage_fields, has_coverage, replayed_level
from rafi.report.verdict import placement

UM = "\u00b5m"

#: Status values in the order the section lists them (``rafi.deploy.limits.STATUSES``).
STATUS_ORDER = ("off", "referencing", "ok", "hold", "ramp")

#: Fault classes with a row of their own in the limits table (not listed under the sensor checks).
OWN_ROW = ("outside_range", "interval_wide")


#: When the replay captures a new reference, by ``reference.rule`` (rafi.deploy.replay).
REFERENCE_TEXT = {
    "run_start": "at the start of each run (reference.rule run_start, as trained)",
    "log_start": "at power-on and at each new log segment (reference.rule log_start, as trained)",
}


def replay_figure_key(run_id) -> str:
    """Key of the figure of one replayed run (group ``replay``)."""
    return f"replay/{run_id}"


#: Up to this many replayed runs the section's title names them; beyond, it counts them.
TITLE_RUNS = 3


def section_title(replay: dict | None, default: str) -> str:
    """The section's title: ``The model on the machine: replay of <run>[, <run>]`` for up to
    :data:`TITLE_RUNS` runs, ``... replay of <n> runs`` beyond (every validation run is replayed:
    the table and the figures name them)."""
    if not replay or not replay["runs"]:
        return default
    runs = [r["run_id"] for r in replay["runs"]]
    if len(runs) > TITLE_RUNS:
        return f"The model on the machine: replay of {len(runs)} runs"
    return "The model on the machine: replay of " + ", ".join(runs)


def _n(value) -> int:
    return int(value) if pd.notna(value) else 0


def _acted_on(table: pd.DataFrame | None, kind: str) -> dict | None:
    """Samples of the replay table whose ``fault`` names a cause of class ``kind``
    (:func:`rafi.deploy.metrics.fault_classes`), alone or beside other causes, by status:
    ``hold``, ``ramp`` and ``n`` (all); ``None`` without a table with ``fault`` and ``status``.
    The figure's own shading (:mod:`rafi.report.replay_plot`) marks only the samples where the
    wide interval is the sole cause; this count is every sample the rule acted on."""
    if table is None or not {"fault", "status"} <= set(table.columns):
        return None
    mine = np.array([kind in fault_classes(str(f)) for f in table["fault"].fillna("")], dtype=bool)
    status = table["status"].astype(str).to_numpy()[mine]
    return {"n": int(mine.sum()), **{st: int((status == st).sum()) for st in ("hold", "ramp")}}


def _sensor_faults(s: pd.DataFrame, table: pd.DataFrame | None) -> str:
    """The faults for the sensor checks' row: the replay table's faults over every replayed run
    grouped by class (:func:`rafi.deploy.metrics.fault_groups`, the classes with a row of their
    own left out); without the table, ``replay_summary.csv``'s ``faults`` of the runs."""
    if table is None or "fault" not in table:
        return "; ".join(str(f) for f in s["faults"].fillna("") if str(f)) if "faults" in s else ""
    groups = fault_groups(table["fault"].fillna("").astype(str))
    return fault_groups_text([g for g in groups if g[0] not in OWN_ROW])


def _limits(deploy: dict, s: pd.DataFrame, table: pd.DataFrame | None) -> dict:
    """The limits and fault rules in force and what they did summed over the replayed runs:
    ``deploy`` (the settings), ``totals`` (the ``n_*`` counts of ``replay_summary.csv``
    summed), ``n`` (samples), ``faults`` (the sensor faults, :func:`_sensor_faults`) and
    ``interval_wide`` (the samples the wide-interval rule held / ramped, :func:`_acted_on`;
    ``None`` without the replay table)."""
    tot = {c: int(s[c].fillna(0).sum()) for c in s.columns if c.startswith("n_")}
    if table is not None and "run_id" in table:
        table = table[table["run_id"].astype(str).isin(set(s["run_id"]))]
    return {
        "deploy": deploy,
        "totals": tot,
        "n": tot.get("n_samples", 0),
        "faults": _sensor_faults(s, table),
        "interval_wide": _acted_on(table, "interval_wide"),
    }


def _runs(s: pd.DataFrame) -> list[dict]:
    """One dict per replayed run: ``replay_summary.csv``'s row, ``statuses`` (``[status,
    samples]`` of every status that occurred, in :data:`STATUS_ORDER`) and the replay's
    ``coverage_pct`` and ``interval_width_um`` (:func:`rafi.report.intervals.coverage_fields`:
    ``None`` for a run without them - an older table, a model without an interval)."""
    rows = records(s)
    for r in rows:
        r["statuses"] = [[st, _n(r.get(f"n_{st}"))] for st in STATUS_ORDER if _n(r.get(f"n_{st}"))]
        r.update(coverage_fields(r))
    return rows


#: What each limit did to the command, by the ``n_*`` column of ``replay_summary.csv``, as the
#: verdict says it: the first with "its output", the others with "it" ("held its output on 79,
#: ramped it on 21 of 149 samples"; "clamped its output on 181 of 960 samples").
ACTIONS = (
    ("n_hold", "held"),
    ("n_ramp", "ramped"),
    ("n_clamped", "clamped"),
    ("n_rate_limited", "rate-limited"),
)
#: Without a noise floor, a difference smaller than this (um) does not show at two decimals.
SHOWN_UM = 0.005


def _actions(row: dict) -> list[list]:
    """``[words, samples]`` of each limit that acted on a replayed run (:data:`ACTIONS`)."""
    acted = [(verb, _n(row.get(col))) for col, verb in ACTIONS if _n(row.get(col))]
    return [[f"{verb} {'its output' if k == 0 else 'it'}", n] for k, (verb, n) in enumerate(acted)]


def replay_gaps(summary: pd.DataFrame | None, noise: dict | None = None, gate_um=None) -> dict | None:
    """Where the compensator with the controller's limits leaves materially more than the model
    alone, per replayed run, for the verdict: the gates judge the model alone (offline), the
    replay says what the machine would keep.

    A run differs materially when its max |residual| with the limits (``max_abs_residual_um``)
    exceeds the model's alone (``max_abs_residual_model_um``) by more than the run's noise floor
    (the expected max |noise| of its dz: a smaller difference cannot be told from the probe's
    noise), or, without a noise floor, by more than shows at two decimals (:data:`SHOWN_UM`).

    Parameters
    ----------
    summary : DataFrame or None
        ``deploy/replay_summary.csv``.
    noise : dict, optional
        Run id -> noise floor (um, :func:`rafi.report.inputs.noise_floors`).
    gate_um : float, optional
        ``qualification.max_residual_um``: a run whose residual with the limits is above it is
        flagged ``above_gate`` (said, not judged: the gates stay those of the model alone).

    Returns
    -------
    dict or None
        ``model_id`` (the replayed model), ``id`` (its short id), ``gate_um`` and ``runs``: one
        dict per such run, largest residual with the limits first: ``run_id``, ``with_um``,
        ``offline_um``, ``n_samples``, ``actions`` (``[words, samples]`` of each limit that acted,
        :data:`ACTIONS`), ``faults`` (the run's ``faults`` of the summary, the fault rule's causes)
        and ``above_gate``; ``None`` without a summary or without such a run.
    """
    need = {"run_id", "max_abs_residual_um", "max_abs_residual_model_um"}
    if summary is None or not len(summary) or not need <= set(summary.columns):
        return None
    noise = noise or {}
    gate = float(gate_um) if isnum(gate_um) else None
    runs = []
    for r in summary.to_dict("records"):
        with_um, alone = r["max_abs_residual_um"], r["max_abs_residual_model_um"]
        if not isnum(with_um):
            continue
        floor = noise.get(str(r["run_id"]))
        margin = float(floor) if isnum(floor) else SHOWN_UM
        if isnum(alone) and float(with_um) - float(alone) <= margin:
            continue
        runs.append(
            {
                "run_id": str(r["run_id"]),
                "with_um": float(with_um),
                "offline_um": float(alone) if isnum(alone) else None,
                "n_samples": _n(r.get("n_samples")),
                "actions": _actions(r),
                "faults": str(r.get("faults") or "") if pd.notna(r.get("faults")) else "",
                "above_gate": gate is not None and float(with_um) > gate,
            }
        )
    if not runs:
        return None
    runs.sort(key=lambda g: -g["with_um"])
    model_id = str(summary["model_id"].iloc[0]) if "model_id" in summary else ""
    return {"model_id": model_id, "id": short_id(model_id), "gate_um": gate, "runs": runs}


def _read_csv(path) -> pd.DataFrame | None:
    """A result table, or None where it is not there or cannot be read."""
    if not path or not Path(path).is_file():
        return None
    try:
        return pd.read_csv(path)
    except (OSError, ValueError):
        return None


def replay_gaps_of(replay_summary, per_run=None, validation_summary=None, gate_um=None) -> dict | None:
    """:func:`replay_gaps` of a unit's files, as its report's verdict computes them: for the pages
    that summarise several units (the machine's page of its probes, ``rafi status``, the fleet
    page), which must say what each unit's verdict says.

    Parameters
    ----------
    replay_summary : path
        ``deploy/replay_summary.csv`` (missing: None is returned).
    per_run, validation_summary : path, optional
        ``comparison/per_run.csv`` and ``validation/summary.csv``: the runs' noise floors
        (:func:`rafi.report.inputs.noise_floors`).
    gate_um : float, optional
        ``qualification.max_residual_um`` (the limit of the largest-residual gate).
    """
    from rafi.report.inputs import noise_floors

    summary = _read_csv(replay_summary)
    tables = {"comparison_per_run": _read_csv(per_run), "validation_summary": _read_csv(validation_summary)}
    return replay_gaps(summary, noise_floors(tables), gate_um)


def above_gate_words(gaps: dict | None, *, plain: bool = False) -> str | None:
    """Where the compensator with the controller's limits leaves more than the largest-residual
    gate allows, in the words of the report's verdict (the runs of :func:`replay_gaps` flagged
    ``above_gate``); None where no run is. The replay says it, it does not gate.

    ``"with the controller's limits (the replay) the compensator would leave 21.12 µm on data#9
    (model alone 3.80 µm), above the 12.00 µm limit of the largest-residual gate; the gates judge
    the model alone"``; ``plain``: ASCII numbers (``21.12 um``), as ``rafi status`` prints them.
    """
    runs = [r for r in (gaps or {}).get("runs") or [] if r.get("above_gate")]
    if not runs:
        return None

    def um(value) -> str:
        return f"{float(value):.2f} um" if plain else fmt_num(value, 2, UM)

    left = [
        f"{um(r['with_um'])} on {r['run_id']}"
        + (f" (model alone {um(r['offline_um'])})" if r.get("offline_um") is not None else "")
        for r in runs
    ]
    leaves = ", ".join(left[:-1]) + " and " + left[-1] if len(left) > 1 else left[0]
    return (
        f"with the controller's limits (the replay) the compensator would leave {leaves}, above the "
        f"{um(gaps['gate_um'])} limit of the largest-residual gate; the gates judge the model alone"
    )


def section_replay(res: dict, settings: dict, figs, champion_id) -> dict | None:
    """The section's context, or ``None`` without a replay (no ``replay_summary.csv`` or no run).

    Parameters
    ----------
    res : dict
        Loaded inputs (:func:`rafi.report.inputs.load_results`); ``replay_summary`` is read.
    settings : dict
        The machine's settings; ``deploy`` holds the limits in force.
    figs : rafi.report.embed.FigureFiles
        The figure files (group ``replay``).
    champion_id : str or None
        The model on the machine after this run (``decision.json`` ``champion_id_after``); where
        the replayed model stands after the decision (``res["decision"]``):
        :func:`rafi.report.verdict.placement`.
    """
    s = res.get("replay_summary")
    if s is None or not len(s):
        return None
    s = s.assign(run_id=s["run_id"].astype(str))
    model_id = str(s["model_id"].iloc[0]) if "model_id" in s else ""
    kind = str(s["kind"].iloc[0]) if "kind" in s else ""
    placed = placement(res.get("decision"), model_id, champion_id)
    runs = []
    for r in s.to_dict("records"):
        runs.append(
            {
                "run_id": r["run_id"],
                "log": str(r.get("log", "")),
                "figure": figs.get("replay", replay_figure_key(r["run_id"])),
                # the figure draws the model's interval (replay_plot): the summary has its coverage
                "band": isnum(r.get("coverage")),
                # a hold / ramp by the interval alone has its own shading (replay_plot)
                "interval_wide": "interval_wide" in str(r.get("faults", "")),
            }
        )
    deploy = settings["deploy"]
    rule = str(s["reference_rule"].iloc[0]) if "reference_rule" in s else str(settings["reference"]["rule"])
    acted = int(s[["n_clamped", "n_rate_limited", "n_hold", "n_ramp"]].fillna(0).to_numpy().sum())
    return {
        "model": Markup(f"<b>{escape(kind)}</b> <code>{escape(short_id(model_id))}</code>"),
        **placed,
        "champion": short_id(champion_id) if champion_id else "",
        "runs": runs,
        "roles": ", ".join(str(r) for r in deploy.get("replay_roles") or []),
        "limits": _limits(deploy, s, res.get("replay")),
        "per_run": _runs(s),
        # the per-run table's interval columns: left out when no run has a coverage
        "coverage": has_coverage(s),
        "interval_label": band_label(replayed_level(s, res.get("model"), res.get("best_model"))),
        "acted": acted,
        "worst_with": fmt_num(pd.to_numeric(s["max_abs_residual_um"]).max(), 2, UM),
        "worst_without": fmt_num(pd.to_numeric(s["max_abs_residual_model_um"]).max(), 2, UM),
        "reference": REFERENCE_TEXT.get(rule, "as the model was trained"),
        # the runs with samples held at the model's training envelope's edge (none: not said)
        "envelope": held_runs(s),
        "envelope_meaning": MEANING,
    }
