"""The registry decision run as rule ``decide`` runs it, on files: a candidate's ``model.json``,
``runs.csv`` and ``runs.parquet`` written to a work folder, the decision written under a registry
folder (``decision.json``, ``comparison.csv``). Tests pass what differs (gates, fakes, confirmed)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from rafi.ops import decide as D


def decide_on_files(
    work: Path,
    registry: Path,
    machine: str,
    model_text: str,
    runs: pd.DataFrame,
    runs_frame: pd.DataFrame,
    **settings,
) -> dict:
    """:func:`rafi.ops.decide.run_decide` of the candidate ``model_text`` (its ``model.json``) on
    ``runs`` (``runs.csv``) and ``runs_frame`` (``runs.parquet``), written to ``work``; ``settings``:
    the rest of its keywords (``gates``, ``nightly``, ``confirmed``, fakes ...)."""
    work.mkdir(parents=True, exist_ok=True)
    (work / "model.json").write_text(model_text, encoding="utf-8")
    runs.to_csv(work / "runs.csv", index=False)
    runs_frame.to_parquet(work / "runs.parquet")
    return D.run_decide(
        machine=machine,
        candidate_path=work / "model.json",
        runs_csv=work / "runs.csv",
        runs_parquet=work / "runs.parquet",
        registry_root=registry,
        decision_path=registry / "decision.json",
        comparison_path=registry / "comparison.csv",
        log=lambda m: None,
        **settings,
    )
