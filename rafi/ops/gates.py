"""The promotion gates: did tonight's candidate pass every one (``qualification:`` in the config)?"""

from __future__ import annotations

import math

import pandas as pd


def gated_runs(summary: pd.DataFrame) -> pd.DataFrame:
    """Validation runs the residual/improvement gates apply to: every one, idle cool-downs
    included, as in ``rafi.method.validate.qualify`` (issue 12: before, idle runs were held
    only to the never-worse gate and left out of the worst case)."""
    return summary


def gate_outcome(summary: pd.DataFrame, verdict: pd.DataFrame, gates: dict) -> tuple[bool, list[str], dict]:
    """Did the candidate pass every gate? Returns ``(passed, reasons, measured)``.

    ``verdict`` is the table of ``qualify``. The never-worse gate is additionally
    checked here run by run from ``summary`` (max|dz - pred| > max|dz| on ANY run
    fails), whatever granularity ``qualify`` reports. No validation run at all fails.
    """
    reasons: list[str] = []
    passed = True
    if summary is None or len(summary) == 0:
        return False, ["no validation runs: the candidate cannot be qualified"], {}
    for rec in verdict.to_dict("records"):
        if not bool(rec.get("passed")):
            passed = False
            run = rec.get("run_id")
            where = (
                f" on run {run}"
                if run is not None and not (isinstance(run, float) and math.isnan(run))
                else ""
            )
            reasons.append(
                f"gate {rec.get('criterion')} failed{where}: measured "
                f"{fmt_value(rec.get('measured'))}, limit {fmt_value(rec.get('limit'))}"
            )
    worse = []
    if gates["never_worse_than_uncompensated"]:
        after = summary["max_abs_after_um"].astype(float)
        before = summary["max_abs_before_um"].astype(float)
        bad = after > before
        if "worse_than_uncompensated" in summary:
            bad = bad | summary["worse_than_uncompensated"].fillna(False).astype(bool)
        worse = summary.loc[bad, "run_id"].astype(str).tolist()
        if worse:
            passed = False
            already = " ".join(reasons)
            for rid in worse:
                if f"never_worse_than_uncompensated failed on run {rid}" not in already:
                    reasons.append(
                        f"gate never_worse_than_uncompensated failed on run {rid}: "
                        "compensated residual larger than uncompensated"
                    )
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
