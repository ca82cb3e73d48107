# Helpers of the qualification report (path and input functions only): what report_tables,
# report_figures and report read. Uses common.smk (out, comparison_path, registry_path, deploy_path,
# machine_config, rafi_code, script_helpers, RAFI_DIR, RESULTS_DIR); the Snakefile includes
# this file after common.smk and before the rules.
#   report_inputs(wildcards), report_settings(machine), REPORT_MODEL_TABLES,
#   report_table_path(name, machine), REPORT_FIGURE_GROUPS, report_figures_path(group, machine),
#   report_figure_inputs(wildcards), report_figure_settings(wildcards), REPORT_MODEL_TABLE_INPUTS


#: Tables of design.md the report reads (runs.parquet: only the test record's spans, ambient
#: temperatures and drifts; what it shows from evaluating the model comes from rule
#: report_tables, the figures from report_figures).
REPORT_TABLES = (
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
    "runs_parquet",
)

#: Outputs of report_tables under ``results/<machine>/report/`` - what the report shows from
#: evaluating the model (rafi.report.tables).
REPORT_MODEL_TABLES = {
    "training_fit": "training_fit.parquet",
    "training_fit_rmse": "training_fit.csv",
    "fuzzy_example": "fuzzy_example.json",
}


#: Figure groups of rule report_figures - the inputs each draws from, the names of
#: rafi.report.figures.FIGURE_GROUPS (rafi.report.figures.draw_group checks that it gets
#: every one; the report package is not imported here, it would load pandas).
REPORT_FIGURE_GROUPS = {
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
    "comparison": ("comparison", "comparison_per_run", "comparison_residuals"),
    "replay": ("replay", "replay_summary"),
}

_COMPARISON_INPUTS = {
    "comparison": "summary.csv",
    "comparison_per_run": "per_run.csv",
    "comparison_cv": "cv.csv",
    "comparison_residuals": "residuals.parquet",
    "best_model": "best_model.json",
}


def report_table_path(name, machine="{machine}"):
    """Path of an output of rule report_tables (a key of ``REPORT_MODEL_TABLES``)."""
    return f"{RESULTS_DIR}/{machine}/report/{REPORT_MODEL_TABLES[name]}"


def report_figures_path(group="{group}", machine="{machine}"):
    """Folder of one figure group: ``results/<machine>/report/figures/<group>/`` (one PNG or
    SVG file per figure and ``index.csv``)."""
    return f"{RESULTS_DIR}/{machine}/report/figures/{group}"


_REPLAY_INPUTS = {"replay": "replay.parquet", "replay_summary": "replay_summary.csv"}


def _report_input(name, machine):
    if name in _REPLAY_INPUTS:
        return deploy_path(_REPLAY_INPUTS[name], machine)
    if name in _COMPARISON_INPUTS:
        return comparison_path(_COMPARISON_INPUTS[name], machine)
    if name in REPORT_MODEL_TABLES:
        return report_table_path(name, machine)
    return out(name, machine)


#: What the report's tables from the model (rafi.report.tables) read: the first step of rule
#: report_figures, whose figures then draw from them.
REPORT_MODEL_TABLE_INPUTS = ("model", "runs_csv", "runs_parquet", "diagnostics")


def report_figure_inputs(wildcards):
    """Named inputs of report_figures (one job per machine: the report's tables from the model,
    then every figure group) - the tables they read, and the code. The tables the job writes
    itself (``REPORT_MODEL_TABLES``) are not inputs."""
    machine = wildcards.machine
    names = [*REPORT_MODEL_TABLE_INPUTS, *(n for group in REPORT_FIGURE_GROUPS.values() for n in group)]
    inputs = {name: _report_input(name, machine) for name in names if name not in REPORT_MODEL_TABLES}
    inputs["code"] = rafi_code("report_figures")
    inputs["glue"] = script_helpers()
    return inputs


def report_figure_settings(wildcards):
    """Figure group -> the settings its figures depend on (``_group_figure_settings``)."""
    return {group: _group_figure_settings(wildcards.machine, group) for group in REPORT_FIGURE_GROUPS}


def _group_figure_settings(machine, group):
    """The settings the figures of a group depend on: ``report.figure_format`` (every group),
    ``report.coolant_sensors`` (pipeline), ``qualification`` (comparison: the gate lines) and
    ``deploy.clamp_um`` (replay: the clamp lines)."""
    wildcards = SimpleNamespace(machine=machine, group=group)
    shown = report_settings(wildcards.machine)
    pipeline = wildcards.group == "pipeline"
    settings = {
        "report": {
            "figure_format": shown["figure_format"],
            "coolant_sensors": list(shown["coolant_sensors"]) if pipeline else [],
        },
        "qualification": (
            dict(machine_config(wildcards.machine)["qualification"])
            if wildcards.group == "comparison"
            else {}
        ),
    }
    if wildcards.group == "replay":
        settings["deploy"] = {"clamp_um": list(machine_config(wildcards.machine)["deploy"]["clamp_um"])}
    return settings


def report_inputs(wildcards):
    """Named inputs of the report: the design.md tables, the tables of report_tables, the
    model comparison, the registry decision, the replay summary, the figure folders, the code
    and the template."""
    machine = wildcards.machine
    inputs = {name: out(name, machine) for name in REPORT_TABLES}
    inputs["training_fit_rmse"] = report_table_path("training_fit_rmse", machine)
    inputs["fuzzy_example"] = report_table_path("fuzzy_example", machine)
    for name in ("comparison", "comparison_per_run", "comparison_cv", "best_model", "replay_summary"):
        inputs[name] = _report_input(name, machine)
    inputs["input_status"] = input_status_path(machine)
    inputs["decision"] = registry_path("decision.json", machine)
    inputs["registry_comparison"] = registry_path("comparison.csv", machine)
    inputs["figures"] = [report_figures_path(g, machine) for g in REPORT_FIGURE_GROUPS]
    inputs["code"] = rafi_code("report")
    inputs["glue"] = script_helpers()
    inputs["template"] = str(RAFI_DIR / "report" / "templates" / "qualification.html.j2")
    return inputs


def report_settings(machine):
    """``report:`` of ``machine`` (its effective settings)."""
    return machine_config(machine)["report"]
