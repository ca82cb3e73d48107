# The qualification report: results/<machine>/ tables -> reports/<machine>/qualification.{html,pdf}.
#
# One jinja2 template renders the HTML; WeasyPrint renders the PDF from the same HTML
# string (rafi.report), so the two never disagree. Uses helpers of common.smk:
# out(), machine_config(), report_paths(), log_path(), bench_path(), rafi_code(), RAFI_DIR.
#
# Optional inputs (the report shows their section only when the file exists):
#   results/<machine>/registry/decision.json   - "Model registry: champion vs candidate"
#   results/<machine>/comparison/summary.csv   - "Model comparison"
# A rule that *produces* one of them should register it so the report waits for it:
#   REPORT_EXTRA_INPUTS["decision"] = "registry/decision.json"   (path under results/<machine>/)
# Otherwise it is used if it already exists when the DAG is built.

import os

REPORT_OPTIONAL = {"decision": "registry/decision.json", "comparison": "comparison/summary.csv"}

if "REPORT_EXTRA_INPUTS" not in globals():
    REPORT_EXTRA_INPUTS = {}


def report_inputs(wildcards):
    """Named inputs of rule report: the design.md tables, optional files, code and template."""
    machine = wildcards.machine
    names = ["audit", "runs_csv", "runs_parquet", "equilibrium", "correlation", "key_sensors",
             "key_sensors_json", "collinearity", "coefficients", "diagnostics", "vif", "model",
             "validation_summary", "residuals"]
    inputs = {name: out(name, machine) for name in names}
    for name, rel in REPORT_OPTIONAL.items():
        path = f"{RESULTS_DIR}/{machine}/{rel}"
        if name in REPORT_EXTRA_INPUTS or os.path.isfile(path):
            inputs[name] = f"{RESULTS_DIR}/{machine}/{REPORT_EXTRA_INPUTS.get(name, rel)}"
    inputs["code"] = rafi_code("report", "plots")
    inputs["template"] = str(RAFI_DIR / "templates" / "qualification.html.j2")
    return inputs


def report_settings(machine):
    """Report-only settings (optional `report:` block in config.yaml; defaults here)."""
    rep = dict(config.get("report") or {})
    mrep = ((config.get("machines") or {}).get(machine) or {}).get("report") or {}
    rep.update(mrep)
    return {"figure_format": rep.get("figure_format", "png"),
            "coolant_sensors": list(rep.get("coolant_sensors", ["T13"]))}


rule report:
    """Qualification report of one machine: verdict, data, equilibrium, ranking, models,
    fuzzy blending, validation, open choices, provenance (HTML + PDF, figures embedded)."""
    input:
        unpack(report_inputs),
    output:
        html=report_paths()["html"],
        pdf=report_paths()["pdf"],
    params:
        settings=lambda w: machine_config(w.machine),
        report=lambda w: report_settings(w.machine),
        paths={"raw_dir": str(config["raw_dir"]), "results_dir": RESULTS_DIR,
               "reports_dir": REPORTS_DIR},
    log:
        log_path("report"),
    benchmark:
        bench_path("report")
    conda:
        "../envs/rafi.yaml"
    script:
        "../scripts/report.py"
