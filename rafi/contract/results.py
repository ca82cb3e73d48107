"""The results layout: every file under ``results/<machine>/``, by name, and the groups of them."""

from __future__ import annotations

#: Every file (or folder) under ``results/<machine>/``, by name; ``{stem}`` is a raw file's log
#: id, ``{group}`` a figure group, ``{step}`` a rule's name.
RESULT_FILES: dict[str, str] = {
    # clean (one job per machine): per raw file
    "clean_dir": "clean",
    "clean_parquet": "clean/{stem}.parquet",
    "clean_audit": "clean/{stem}.audit.csv",
    "clean_summary": "clean/{stem}.summary.csv",
    # input_status (checkpoint)
    "input_status": "input_status.json",
    "audit": "audit.csv",
    # method: runs -> equilibrium -> rank -> fit -> validate
    "runs_csv": "runs.csv",
    "runs_parquet": "runs.parquet",
    "equilibrium": "equilibrium.csv",
    "correlation": "rank/correlation.csv",
    "key_sensors": "rank/key_sensors.csv",
    "key_sensors_json": "rank/key_sensors.json",
    "collinearity": "rank/collinearity.csv",
    "coefficients": "fit/coefficients.csv",
    "diagnostics": "fit/diagnostics.csv",
    "vif": "fit/vif.csv",
    "model": "model.json",
    "validation_summary": "validation/summary.csv",
    "residuals": "validation/residuals.parquet",
    # compare (the model family)
    "comparison": "comparison/summary.csv",
    "comparison_per_run": "comparison/per_run.csv",
    "comparison_residuals": "comparison/residuals.parquet",
    "best_model": "comparison/best_model.json",
    "comparison_cv": "comparison/cv.csv",
    "comparison_verdict": "comparison/verdict.csv",
    "comparison_since_change": "comparison/since_change.csv",
    # decide (the registry's declared outputs; its own files are side effects, see REGISTRY_DIR)
    "decision": "registry/decision.json",
    "registry_comparison": "registry/comparison.csv",
    # replay
    "replay": "deploy/replay.parquet",
    "replay_summary": "deploy/replay_summary.csv",
    # report_figures: what the report shows from evaluating the model, and the figures
    "training_fit": "report/training_fit.parquet",
    "training_fit_rmse": "report/training_fit.csv",
    "fuzzy_example": "report/fuzzy_example.json",
    "figures": "report/figures/{group}",
    # per-rule benchmark TSVs
    "benchmark": "benchmarks/{step}.tsv",
}

#: Memos under ``results/<machine>/``: not outputs (no rule declares them), looked up by content and
#: safe to delete (``docs/decisions.md``: why they are no layer of change detection).
RESULT_FILES["cv_memo"] = ".cv_memo"  # rule compare: the CV rows by content (rafi.family.cv_memo)

#: Files of a run under ``results/`` itself (not of one machine).
RUN_FILES: dict[str, str] = {
    "input_check": "input_check.json",  # rule input_check: was input rejected anywhere?
    "raw_hashes": ".raw_hashes.json",  # the raw files' content hashes, cached on their stat
    "template_cache": ".template_cache",  # the report's compiled templates (jinja2's bytecode cache)
}

#: The model registry of a machine, ``results/<machine>/registry/`` (``docs/operations.md``):
#: ``models/<id>.json``, ``champion.json``, ``history.jsonl`` besides the declared outputs.
REGISTRY_DIR = "registry"

#: The tables of ``docs/design.md`` every full run produces per machine (``rule tables``).
PIPELINE_TABLES = (
    "audit",
    "runs_csv",
    "runs_parquet",
    "equilibrium",
    "correlation",
    "key_sensors",
    "key_sensors_json",
    "collinearity",
    "coefficients",
    "diagnostics",
    "vif",
    "model",
    "validation_summary",
    "residuals",
)
#: Outputs of rule compare.
COMPARISON_FILES = (
    "comparison",
    "comparison_per_run",
    "comparison_residuals",
    "best_model",
    "comparison_cv",
    "comparison_verdict",
    "comparison_since_change",
)
#: Declared outputs of rule decide.
DECISION_FILES = ("decision", "registry_comparison")
#: Outputs of rule replay.
REPLAY_FILES = ("replay", "replay_summary")
#: What rule report_figures writes before it draws: the report's tables from evaluating the model.
REPORT_MODEL_TABLES = ("training_fit", "training_fit_rmse", "fuzzy_example")
#: What the report's model tables (:mod:`rafi.report.tables`) read.
REPORT_MODEL_TABLE_INPUTS = ("model", "runs_csv", "runs_parquet", "diagnostics")

#: Figure groups of rule report_figures and the inputs each draws from.
FIGURE_GROUPS: dict[str, tuple[str, ...]] = {
    "pipeline": (
        "runs_csv",
        "runs_parquet",
        "equilibrium",
        "correlation",
        "key_sensors",
        "key_sensors_json",
        "collinearity",
        "model",
        "validation_summary",
        "residuals",
        "training_fit",
        "fuzzy_example",
    ),
    # model.json and best_model.json: the level of the interval bands (their "interval" blocks)
    "comparison": (
        "comparison",
        "comparison_per_run",
        "comparison_residuals",
        "model",
        "best_model",
        "comparison_since_change",
    ),
    # model.json and best_model.json: the level of the replayed model's interval (the candidate)
    "replay": ("replay", "replay_summary", "model", "best_model"),
}

#: What the report needs: these tables must exist ...
REPORT_REQUIRED = (
    "audit",
    "runs_csv",
    "equilibrium",
    "correlation",
    "key_sensors",
    "key_sensors_json",
    "collinearity",
    "coefficients",
    "diagnostics",
    "model",
    "validation_summary",
    "residuals",
    "training_fit_rmse",
    "fuzzy_example",
)
#: ... these are read when present (a section is left out without its file).
REPORT_OPTIONAL = (
    "input_status",
    "decision",
    "registry_comparison",
    "comparison",
    "comparison_per_run",
    "comparison_cv",
    "comparison_verdict",
    "comparison_since_change",
    "best_model",
    "replay_summary",
    "replay",
    "comparison_residuals",
    "runs_parquet",
)


def result_file(name: str, **fields: str) -> str:
    """Path of result ``name`` relative to ``results/<machine>/``, its ``{...}`` fields filled.

    A field not given stays a ``{field}`` wildcard (Snakemake's form), e.g.
    ``result_file("clean_parquet")`` is ``"clean/{stem}.parquet"``.
    """
    path = RESULT_FILES[name]
    for key, value in fields.items():
        path = path.replace("{" + key + "}", str(value))
    return path
