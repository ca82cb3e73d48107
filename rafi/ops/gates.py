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
            f"passed every gate on {len(summary)} validation run(s): max residual "
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
