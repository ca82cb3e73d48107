"""The promotion gates: did tonight's candidate pass every one (``qualification:`` in the config)?"""

from __future__ import annotations

import math

import pandas as pd


def gated_runs(summary: pd.DataFrame) -> pd.DataFrame:
    """Validation runs the residual/improvement gates apply to: every one, idle cool-downs
    included, as in ``rafi.method.validate.qualify`` (issue 12: before, idle runs were held
    only to the never-worse gate and left out of the worst case)."""
    return summary


#: The gate judged run by run against the run's own uncompensated residual.
NEVER_WORSE = "never_worse_than_uncompensated"


def _run_key(run_id) -> str | None:
    """A verdict row's run as text, None for a row that names no run (NaN or missing)."""
    if run_id is None or (isinstance(run_id, float) and math.isnan(run_id)):
        return None
    return str(run_id)


def _exceeds(measured, limit) -> bool:
    """``measured > limit`` for two numbers; False if either is missing or not a number."""
    try:
        return float(measured) > float(limit)
    except (TypeError, ValueError):
        return False


def failed_gates(verdict: pd.DataFrame) -> list[dict]:
    """The failed rows of ``qualify``'s verdict, in its order: ``{"gate", "run", "measured", "limit"}``
    (``run`` None for a row that names no run)."""
    return [
        {
            "gate": rec.get("criterion"),
            "run": _run_key(rec.get("run_id")),
            "measured": rec.get("measured"),
            "limit": rec.get("limit"),
        }
        for rec in verdict.to_dict("records")
        if not bool(rec.get("passed"))
    ]


def failed_gate_reason(failure: dict) -> str:
    """The reason line of one failed verdict row (:func:`failed_gates`)."""
    where = f" on run {failure['run']}" if failure["run"] is not None else ""
    return (
        f"gate {failure['gate']} failed{where}: measured "
        f"{fmt_value(failure['measured'])}, limit {fmt_value(failure['limit'])}"
    )


def worse_than_uncompensated(summary: pd.DataFrame, verdict: pd.DataFrame, gates: dict) -> tuple[list, list]:
    """The runs where compensation made things worse, as judged by ``qualify``.

    A run whose never-worse verdict row failed with a measurement above its limit (``after >
    before``; a NaN measurement fails the gate but is not "worse"). A run of ``summary`` the
    verdict did not judge on that gate (a ``qualify`` that left it out) is judged here from
    ``summary`` (``max_abs_after_um > max_abs_before_um`` or its ``worse_than_uncompensated``
    flag), so the gate holds whatever granularity ``qualify`` reports.

    Returns
    -------
    tuple of list
        ``(worse, unjudged)``: every worse run in ``summary`` order (``run_id`` as text), and
        those of them the verdict did not judge (they need a reason line of their own).
    """
    if not gates[NEVER_WORSE]:
        return [], []
    judged = {
        _run_key(rec.get("run_id")): not bool(rec.get("passed"))
        and _exceeds(rec.get("measured"), rec.get("limit"))
        for rec in verdict.to_dict("records")
        if rec.get("criterion") == NEVER_WORSE
    }
    after = summary["max_abs_after_um"].astype(float)
    before = summary["max_abs_before_um"].astype(float)
    flagged = after > before
    if "worse_than_uncompensated" in summary:
        flagged = flagged | summary["worse_than_uncompensated"].fillna(False).astype(bool)
    worse, unjudged = [], []
    for run, flag in zip(summary["run_id"].astype(str), flagged):
        if run in judged:
            if judged[run]:
                worse.append(run)
        elif flag:
            worse.append(run)
            unjudged.append(run)
    return worse, unjudged


#: The reason of a candidate without a validation run, and what to do.
NO_VALIDATION = (
    "no validation runs: the candidate cannot be qualified; give the machine a validation log, or split "
    "a continuous log in time (runs.windows, docs/raw-format.md#worked-example-a-continuous-log-with-a-"
    "chronological-split)"
)


def gate_outcome(summary: pd.DataFrame, verdict: pd.DataFrame, gates: dict) -> tuple[bool, list[str], dict]:
    """Did the candidate pass every gate? Returns ``(passed, reasons, measured)``.

    ``verdict`` is the table of ``qualify`` (one row per gate and validation run): each failed
    row is a reason line. The never-worse gate is held on every run of ``summary``
    (:func:`worse_than_uncompensated`); a run the verdict did not judge on it gets its own line,
    so no (gate, run) is reported twice. No validation run at all fails.
    """
    if summary is None or len(summary) == 0:
        return False, [NO_VALIDATION], {}
    failures = failed_gates(verdict)
    worse, unjudged = worse_than_uncompensated(summary, verdict, gates)
    reasons = [failed_gate_reason(f) for f in failures]
    reasons += [
        f"gate {NEVER_WORSE} failed on run {run}: compensated residual larger than uncompensated"
        for run in unjudged
    ]
    passed = not failures and not worse
    gated = gated_runs(summary)
    measured = {
        "max_residual_um": col_max(gated["max_abs_after_um"]),
        "min_improvement_pct": col_min(gated["improvement_pct"]),
        "worse_than_uncompensated_runs": worse,
        "n_validation_runs": int(len(summary)),
    }
    if passed:
        reasons.append(
            f"passed every absolute gate on {len(summary)} validation run(s): max residual "
            f"{fmt_value(measured['max_residual_um'])} um (limit "
            f"{fmt_value(gates.get('max_residual_um'))}), min improvement "
            f"{fmt_value(measured['min_improvement_pct'])} % (limit "
            f"{fmt_value(gates.get('min_improvement_pct'))}), never worse than uncompensated"
        )
    return passed, reasons, measured


def col_max(col) -> float | None:
    """Largest number of a column (None if it has none)."""
    v = pd.to_numeric(col, errors="coerce").max()
    return None if pd.isna(v) else float(v)


def col_min(col) -> float | None:
    """Smallest number of a column (None if it has none)."""
    v = pd.to_numeric(col, errors="coerce").min()
    return None if pd.isna(v) else float(v)


def fmt_value(v) -> str:
    """A measured value or limit as printed in reasons (3 significant digits)."""
    if v is None:
        return "none"
    try:
        f = float(v)
    except (TypeError, ValueError):
        return str(v)
    return "nan" if math.isnan(f) else f"{f:.3g}"


def run_margin_um(margin, noise_floor_um) -> float | None:
    """The margin of one validation run: the number itself, or with ``"noise"`` the run's
    noise floor (None if the run has none: a margin of 0 is applied then)."""
    if isinstance(margin, str) and margin.strip().lower() == "noise":
        f = pd.to_numeric(pd.Series([noise_floor_um]), errors="coerce").iloc[0]
        return None if pd.isna(f) else float(f)
    return float(margin)


def relative_gate(
    champion_summary: pd.DataFrame | None, candidate_summary: pd.DataFrame | None, margin
) -> pd.DataFrame:
    """The candidate against the champion in service, run by run (issue 13 item 4).

    On every validation run both models can be scored on (same ``run_id``, a finite
    ``max_abs_after_um`` for both) the candidate is *worse* if its max |residual| exceeds the
    champion's by more than the margin: ``nightly.champion_margin_um``, a number (um) or
    ``"noise"``: the run's ``noise_floor_um`` (the candidate's row, else the champion's; 0 if
    neither has one).

    Returns
    -------
    pandas.DataFrame
        One row per run of either summary: ``run_id``, ``champion_max_abs_after_um``,
        ``candidate_max_abs_after_um``, ``noise_floor_um``, ``margin_um``, ``both_scored``,
        ``candidate_minus_champion_um`` and ``candidate_worse`` (False where not both scored).
    """
    cols = [
        "run_id",
        "champion_max_abs_after_um",
        "candidate_max_abs_after_um",
        "noise_floor_um",
        "margin_um",
        "both_scored",
        "candidate_minus_champion_um",
        "candidate_worse",
    ]

    def part(summ, name):
        if summ is None or len(summ) == 0 or "run_id" not in summ:
            return pd.DataFrame(columns=["run_id", f"{name}_after", f"{name}_floor"])
        floor = summ["noise_floor_um"] if "noise_floor_um" in summ else pd.Series(float("nan"), summ.index)
        return pd.DataFrame(
            {
                "run_id": summ["run_id"].astype(str),
                f"{name}_after": pd.to_numeric(summ["max_abs_after_um"], errors="coerce"),
                f"{name}_floor": pd.to_numeric(floor, errors="coerce"),
            }
        ).drop_duplicates("run_id")

    both = part(champion_summary, "champion").merge(
        part(candidate_summary, "candidate"), on="run_id", how="outer"
    )
    if both.empty:
        return pd.DataFrame(columns=cols)
    champ = both["champion_after"].astype(float)
    cand = both["candidate_after"].astype(float)
    floor = both["candidate_floor"].astype(float).fillna(both["champion_floor"].astype(float))
    scored = champ.map(math.isfinite) & cand.map(math.isfinite)
    margins = [run_margin_um(margin, f) for f in floor]
    out = pd.DataFrame(
        {
            "run_id": both["run_id"],
            "champion_max_abs_after_um": champ,
            "candidate_max_abs_after_um": cand,
            "noise_floor_um": floor,
            "margin_um": [float("nan") if m is None else m for m in margins],
            "both_scored": scored.astype(bool),
            "candidate_minus_champion_um": (cand - champ).where(scored),
        }
    )
    limit = out["margin_um"].fillna(0.0)
    out["candidate_worse"] = scored & (out["candidate_minus_champion_um"] > limit)
    return out[cols].sort_values("run_id", kind="stable").reset_index(drop=True)


def relative_reasons(rel: pd.DataFrame, champion_id: str, margin) -> list[str]:
    """Reason lines of :func:`relative_gate`: one per run where the candidate is worse (both
    residuals and the margin), or one line saying it is not worse anywhere."""
    shared = rel[rel["both_scored"]] if len(rel) else rel
    what = "the run's noise floor" if isinstance(margin, str) else f"{fmt_value(margin)} um"
    if shared.empty:
        return [
            f"relative gate not applied: no validation run both the candidate and champion "
            f"{champion_id[:12]} can be scored on"
        ]
    worse = shared[shared["candidate_worse"]]
    if worse.empty:
        return [
            f"not worse than champion {champion_id[:12]} on any of the {len(shared)} validation run(s) both "
            f"can be scored on (margin: {what})"
        ]
    out = []
    for r in worse.to_dict("records"):
        m = r["margin_um"]
        m_text = f"{fmt_value(m)} um" if not pd.isna(m) else "0 um (the run has no noise floor)"
        out.append(
            f"relative gate failed on run {r['run_id']}: candidate max residual "
            f"{fmt_value(r['candidate_max_abs_after_um'])} um vs champion {champion_id[:12]} "
            f"{fmt_value(r['champion_max_abs_after_um'])} um, worse by "
            f"{fmt_value(r['candidate_minus_champion_um'])} um, more than the margin {m_text}"
        )
    return out
