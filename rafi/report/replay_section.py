"""Section "The model on the machine: replay of <run>": the offered model run as the controller runs it.

Reads ``deploy/replay_summary.csv`` (rule ``replay``: one row per replayed run), the limits in
force from the machine's settings (``deploy:``, the values rule ``replay`` was given) and the
registry decision (is the replayed model on the machine after this run?). The figures are files
of rule ``report_figures`` (group ``replay``). Nothing is computed here but formatting.
"""

from __future__ import annotations

import pandas as pd
from markupsafe import Markup, escape

from rafi.report.format import fmt_num, run_label, short_id, table

UM = "\u00b5m"

#: Status values in the order the section lists them (``rafi.deploy.limits.STATUSES``).
STATUS_ORDER = ("off", "referencing", "ok", "hold", "ramp")


#: When the replay captures a new reference, by ``reference.rule`` (rafi.deploy.replay).
REFERENCE_TEXT = {
    "run_start": "at the start of each run (reference.rule run_start, as trained)",
    "log_start": "at power-on and at each new log segment (reference.rule log_start, as trained)",
}


def replay_figure_key(run_id) -> str:
    """Key of the figure of one replayed run (group ``replay``)."""
    return f"replay/{run_id}"


def section_title(replay: dict | None, default: str) -> str:
    """The section's title: ``The model on the machine: replay of <run>[, <run>]``."""
    if not replay or not replay["runs"]:
        return default
    return "The model on the machine: replay of " + ", ".join(r["run_id"] for r in replay["runs"])


def _n(value) -> int:
    return int(value) if pd.notna(value) else 0


def _range(v) -> str:
    lo, hi = (float(x) for x in v)
    return f"[{fmt_num(lo, 1)}, {fmt_num(hi, 1)}]"


def _limits_table(deploy: dict, s: pd.DataFrame):
    """Each limit and fault rule in force, and what it did summed over the replayed runs."""
    tot = {c: int(s[c].fillna(0).sum()) for c in s.columns if c.startswith("n_")}
    n = tot.get("n_samples", 0)
    faults = "; ".join(str(f) for f in s["faults"].fillna("") if str(f)) if "faults" in s else ""

    def did(k: int, what: str) -> str:
        return f"{what} on {k} of {n} samples" if k else "did not act"

    sensor = "did not act" if not faults else f"faults: {faults}"
    rows = [
        [
            "clamp",
            f"deploy.clamp_um = {_range(deploy['clamp_um'])} {UM}",
            did(tot.get("n_clamped", 0), "clamped the command"),
        ],
        [
            "rate limit",
            f"deploy.rate_um_per_s = {fmt_num(deploy['rate_um_per_s'], 3)} {UM}/s",
            did(tot.get("n_rate_limited", 0), "limited the change"),
        ],
        [
            "sensor checks: missing, out of range, stuck",
            f"temp_valid_c = {_range(deploy['temp_valid_c'])} \u00b0C; stuck after "
            f"{fmt_num(deploy['stuck_s'], 0)} s while another sensor moved "
            f"{fmt_num(deploy['stuck_change_k'], 2)} K",
            sensor,
        ],
        [
            "trained range",
            f"rise margin {fmt_num(deploy['range_margin_k'], 1)} K; speed margin "
            f"{fmt_num(deploy['speed_margin_rpm'], 0)} r/min above the trained speeds",
            did(tot.get("n_outside_range", 0), "outside"),
        ],
        [
            "fault rule: hold, then ramp",
            f"hold {fmt_num(deploy['hold_s'], 0)} s, then ramp to {fmt_num(deploy['safe_um'], 1)} {UM} at "
            f"{fmt_num(deploy['ramp_um_per_s'], 3)} {UM}/s",
            (
                f"held on {tot.get('n_hold', 0)}, ramped on {tot.get('n_ramp', 0)} of {n} samples"
                if tot.get("n_hold", 0) + tot.get("n_ramp", 0)
                else "did not act"
            ),
        ],
    ]
    return table(
        ["rule", "in force", "what it did in the replay"], rows, cls="kv replay-limits", widths=[24, 44, 32]
    )


def _runs_table(s: pd.DataFrame):
    rows = []
    for r in s.to_dict("records"):
        statuses = ", ".join(f"{st} {_n(r.get(f'n_{st}'))}" for st in STATUS_ORDER if _n(r.get(f"n_{st}")))
        rows.append(
            [
                run_label(r["run_id"]),
                fmt_num(r["n_samples"], 0),
                statuses,
                fmt_num(r["max_abs_measured_um"], 2),
                fmt_num(r["max_abs_residual_model_um"], 2),
                fmt_num(r["max_abs_residual_um"], 2),
                fmt_num(r["max_abs_command_minus_model_um"], 2),
            ]
        )
    return table(
        [
            "run",
            "samples",
            "samples per status",
            f"max |dz| uncomp. ({UM})",
            f"max |residual|, model alone ({UM})",
            f"max |residual|, command with the limits ({UM})",
            f"max |command \u2212 model| ({UM})",
        ],
        rows,
        cls="num replay-runs",
        widths=[20, 9, 23, 12, 12, 12, 12],
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
        The model on the machine after this run (``decision.json`` ``champion_id_after``).
    """
    s = res.get("replay_summary")
    if s is None or not len(s):
        return None
    s = s.assign(run_id=s["run_id"].astype(str))
    model_id = str(s["model_id"].iloc[0]) if "model_id" in s else ""
    kind = str(s["kind"].iloc[0]) if "kind" in s else ""
    if not champion_id:
        on_machine = None
    else:
        on_machine = bool(model_id) and str(champion_id) == model_id
    runs = []
    for r in s.to_dict("records"):
        runs.append(
            {
                "run_id": r["run_id"],
                "log": str(r.get("log", "")),
                "figure": figs.get("replay", replay_figure_key(r["run_id"])),
            }
        )
    deploy = settings["deploy"]
    rule = str(s["reference_rule"].iloc[0]) if "reference_rule" in s else str(settings["reference"]["rule"])
    acted = int(s[["n_clamped", "n_rate_limited", "n_hold", "n_ramp"]].fillna(0).to_numpy().sum())
    return {
        "model": Markup(f"<b>{escape(kind)}</b> <code>{escape(short_id(model_id))}</code>"),
        "on_machine": on_machine,
        "champion": short_id(champion_id) if champion_id else "",
        "runs": runs,
        "roles": ", ".join(str(r) for r in deploy.get("replay_roles") or []),
        "limits": _limits_table(deploy, s),
        "per_run": _runs_table(s),
        "acted": acted,
        "worst_with": fmt_num(pd.to_numeric(s["max_abs_residual_um"]).max(), 2, UM),
        "worst_without": fmt_num(pd.to_numeric(s["max_abs_residual_model_um"]).max(), 2, UM),
        "reference": REFERENCE_TEXT.get(rule, "as the model was trained"),
    }
