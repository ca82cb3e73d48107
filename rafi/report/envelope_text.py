"""The samples a model gave at its training envelope's edge, as the report's sections say them.

A ridge kind predicts from its features bounded to the training envelope and holds its prediction
inside the training displacement range widened by a margin (:mod:`rafi.family.envelope`); its
``predict_detail`` and the streaming compensator flag those samples (``outside_envelope``), and
validation and replay count them per run (``n_outside_envelope``). The validation, comparison and
replay sections list the runs where some were, with :data:`MEANING`, and say nothing when none
were (a kind without an envelope never has any).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

__all__ = ["MEANING", "held_by_model", "held_runs"]

#: What a sample held at the envelope's edge means (one sentence, after the counts).
MEANING = (
    "On such a sample an input the model reads, or its prediction, lay beyond the range of the "
    "training runs widened by the envelope's margin, and the model gave its value at the envelope's "
    "edge instead of extrapolating (docs/models.md, The training envelope)."
)


def _count(value) -> int:
    number = pd.to_numeric(value, errors="coerce")
    return int(number) if pd.notna(number) else 0


def held_runs(
    summary: pd.DataFrame | None, count: str = "n_outside_envelope", n: str = "n_samples"
) -> list[dict]:
    """The runs of a per-run table with samples held at the envelope's edge, in table order.

    Parameters
    ----------
    summary : DataFrame or None
        ``validation/summary.csv`` or ``replay_summary.csv`` (``run_id``, ``count``, ``n``).
    count, n : str
        The columns of the held samples and of all samples.

    Returns
    -------
    list of dict
        ``run_id``, ``n`` (held) and ``n_samples`` per run with ``n > 0``; empty without such a
        run, without the table or without its ``count`` column (a table written before it).
    """
    if summary is None or count not in summary.columns or not len(summary):
        return []
    rows = []
    for r in summary.to_dict("records"):
        k = _count(r.get(count))
        if k > 0:
            rows.append({"run_id": str(r["run_id"]), "n": k, "n_samples": _count(r.get(n))})
    return rows


def held_by_model(residuals: pd.DataFrame | None) -> list[dict]:
    """Per model of ``comparison/residuals.parquet``, the validation runs with samples held at its
    envelope's edge, counted as :func:`rafi.method.validate.validate_runs` counts them (samples
    with a measurement and a prediction).

    Returns
    -------
    list of dict
        ``model`` and ``runs`` (:func:`held_runs`' rows) per model with a held sample, in the
        table's order; empty without such a model or without the ``outside_envelope`` column.
    """
    need = {"model", "run_id", "measured_um", "predicted_um", "outside_envelope"}
    if residuals is None or not need <= set(residuals.columns) or not len(residuals):
        return []
    r = residuals
    ok = np.isfinite(pd.to_numeric(r["measured_um"], errors="coerce").to_numpy(dtype=float))
    ok &= np.isfinite(pd.to_numeric(r["predicted_um"], errors="coerce").to_numpy(dtype=float))
    table = pd.DataFrame(
        {
            "model": r["model"].astype(str).to_numpy(),
            "run_id": r["run_id"].astype(str).to_numpy(),
            "held": r["outside_envelope"].fillna(False).astype(bool).to_numpy() & ok,
            "ok": ok,
        }
    )
    out = []
    for model, g in table.groupby("model", sort=False):
        per_run = g.groupby("run_id", sort=False).agg(
            n_outside_envelope=("held", "sum"), n_samples=("ok", "sum")
        )
        runs = held_runs(per_run.reset_index())
        if runs:
            out.append({"model": str(model), "runs": runs})
    return out
