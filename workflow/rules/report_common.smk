# Helpers of the qualification report (path and input functions only): what report_figures and
# report read. Every name is a result of rafi.contract (REPORT_REQUIRED, REPORT_OPTIONAL,
# REPORT_MODEL_TABLES, FIGURE_GROUPS); paths through out() of common.smk, which the Snakefile
# includes first.
#   report_figure_inputs(wildcards), report_figure_settings(wildcards), report_inputs(wildcards),
#   report_settings(machine)


def report_figure_inputs(wildcards):
    """Named inputs of report_figures (one job per machine: the report's tables from the model,
    then every figure group): the tables they read. The tables the job writes itself
    (``rafi.contract.REPORT_MODEL_TABLES``) are not inputs."""
    names = [
        *contract.REPORT_MODEL_TABLE_INPUTS,
        *(n for group in contract.FIGURE_GROUPS.values() for n in group),
    ]
    return {
        name: out(name, wildcards.machine)
        for name in dict.fromkeys(names)
        if name not in contract.REPORT_MODEL_TABLES
    }


def report_figure_settings(wildcards):
    """Figure group -> the settings its figures depend on (``_group_figure_settings``)."""
    return {group: _group_figure_settings(wildcards.machine, group) for group in contract.FIGURE_GROUPS}


def _group_figure_settings(machine, group):
    """The settings the figures of a group depend on: ``report.figure_format`` (every group),
    ``report.coolant_sensors`` (pipeline), ``qualification`` (comparison: the gate lines) and
    ``deploy.clamp_um`` (replay: the clamp lines)."""
    shown = report_settings(machine)
    settings = {
        "report": {
            "figure_format": shown["figure_format"],
            "coolant_sensors": list(shown["coolant_sensors"]) if group == "pipeline" else [],
        },
        "qualification": dict(qualification_gates(machine)) if group == "comparison" else {},
    }
    if group == "replay":
        settings["deploy"] = {"clamp_um": list(machine_config(machine)["deploy"]["clamp_um"])}
    return settings


def report_inputs(wildcards):
    """Named inputs of the report: the tables it shows (``rafi.contract.REPORT_REQUIRED`` and
    ``REPORT_OPTIONAL``, every one built by a full run) and the figure folders."""
    machine = wildcards.machine
    names = (*contract.REPORT_REQUIRED, *contract.REPORT_OPTIONAL)
    inputs = {name: out(name, machine) for name in names}
    inputs["figures"] = [out("figures", machine, group=g) for g in contract.FIGURE_GROUPS]
    return inputs


def probes_report_inputs(wildcards):
    """Named inputs of the report of a machine with several probes (``probes_report``), every
    probe's comparison summary, per-run table, registry decision, cleaning audit, replay summary,
    validation summary and RAFI as published (``summary_<probe>``, ..., ``audit_<probe>``: the
    files' probe sign, ``replay_<probe>``: the offered model with the controller's limits,
    ``validation_<probe>``, ``model_<probe>``: with the decision and the audit, what the revision
    of the probe's report hashes) and, as ``reports``, every probe's report (HTML) in the order of
    ``input.probes``."""
    folder = wildcards.folder
    inputs = {}
    for probe in PROBES[folder]:
        unit = unit_name(folder, probe)
        inputs[f"summary_{probe}"] = out("comparison", unit)
        inputs[f"per_run_{probe}"] = out("comparison_per_run", unit)
        inputs[f"decision_{probe}"] = out("decision", unit)
        inputs[f"audit_{probe}"] = out("audit", unit)
        inputs[f"replay_{probe}"] = out("replay_summary", unit)
        inputs[f"validation_{probe}"] = out("validation_summary", unit)
        inputs[f"model_{probe}"] = out("model", unit)
    inputs["reports"] = [report_paths(unit_name(folder, p))["html"] for p in PROBES[folder]]
    return inputs


def report_settings(machine):
    """``report:`` of ``machine`` (its effective settings)."""
    return machine_config(machine)["report"]
