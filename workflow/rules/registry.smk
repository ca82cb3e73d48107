# Model registry and champion/challenger decision (rafi.registry, docs/operations.md).
#
#   results/<machine>/model.json (or the model family's best model, nightly.candidate)
#     + runs.csv/runs.parquet + validation/summary.csv [+ registry/champion.json]
#     -> decide -> registry/decision.json, registry/comparison.csv
#
# Side effects of `decide` (deliberately NOT declared outputs): registry/models/<id>.json
# (+ .meta.json), registry/champion.json and registry/history.jsonl. Snakemake deletes a
# job's declared outputs before it re-runs the job, and would delete them on a failed job;
# the registry must survive every run: the model files are write-once, history.jsonl is
# append-only and champion.json is only ever replaced atomically by a promotion or an
# operator's rollback (`rafi nightly --promote`). The script writes the declared outputs
# last, after champion.json, so they are never older than the champion pointer they
# depend on and `snakemake -n` after a run has nothing to do.
#
# Uses from common.smk: MACHINES, machine_config(), out(), log_path(), bench_path(),
# rafi_code(), script_helpers(), report_paths(), RESULTS_DIR.

import rafi.registry as _registry


# The report waits for the decision and shows its section (see report.smk).
if "REPORT_EXTRA_INPUTS" not in globals():
    REPORT_EXTRA_INPUTS = {}
REPORT_EXTRA_INPUTS["decision"] = "registry/decision.json"


def nightly_settings(machine):
    """``nightly:`` of ``machine``: built-in defaults < top-level ``nightly`` < machine's."""
    merged = dict(_registry.DEFAULT_NIGHTLY)
    merged.update(config.get("nightly") or {})
    merged.update(machine_config(machine).get("nightly") or {})
    return merged


def qualification_gates(machine):
    """Promotion gates of ``machine`` (``qualification:``, per machine over top level)."""
    merged = dict(_registry.DEFAULT_GATES)
    merged.update(config.get("qualification") or {})
    merged.update(machine_config(machine).get("qualification") or {})
    return {k: merged[k] for k in _registry.GATE_KEYS if k in merged}


def registry_path(name, machine="{machine}"):
    """``results/<machine>/registry/<name>``."""
    return f"{RESULTS_DIR}/{machine}/registry/{name}"


def candidate_model(wildcards):
    """Input function: tonight's candidate (rafi.registry.candidate_model_path)."""
    return _registry.candidate_model_path(
        wildcards.machine, RESULTS_DIR, nightly_settings(wildcards.machine)["candidate"])


def champion_input(wildcards):
    """Input function: the champion pointer if the machine has one, else nothing.

    Listing it makes a rollback (champion.json newer than decision.json) re-run
    `decide`. Note: on the night the first champion is created, the recorded input set
    changes from [] to [champion.json]; `rafi nightly` clears that job's recorded
    metadata afterwards (`--cleanup-metadata`), so the next dry run is empty.
    """
    path = Path(registry_path("champion.json", wildcards.machine))
    return [str(path)] if path.exists() else []


def _nightly_machines():
    only = config.get("nightly_machines")
    if not only:
        return MACHINES
    only = [only] if isinstance(only, str) else list(only)
    return [m for m in MACHINES if m in only]


def nightly_targets():
    """Every output a night produces: tables, decision, report (if report.smk is there)."""
    targets = []
    for m in _nightly_machines():
        targets += list(pipeline_tables(m).values())
        targets += [registry_path("decision.json", m), registry_path("comparison.csv", m)]
        if globals().get("HAVE_REPORT") and str(config.get("nightly_report", True)).lower() not in (
                "0", "false", "no"):
            targets += list(report_paths(m).values())
    return targets


rule decide:
    """Judge tonight's candidate against the champion; promote only if every gate passes."""
    input:
        model=candidate_model,
        table=out("runs_csv"),
        frame=out("runs_parquet"),
        summary=out("validation_summary"),
        champion=champion_input,
        code=rafi_code("registry"),
        glue=script_helpers(),
    output:
        decision=registry_path("decision.json"),
        comparison=registry_path("comparison.csv"),
    params:
        machine=lambda w: w.machine,
        gates=lambda w: qualification_gates(w.machine),
        nightly=lambda w: nightly_settings(w.machine),
        registry=lambda w: registry_path("", w.machine).rstrip("/"),
    log:
        log_path("decide"),
    benchmark:
        bench_path("decide")
    conda:
        "../envs/rafi.yaml"
    script:
        "../scripts/registry_decide.py"


# `rafi nightly` builds this target (restricted by `--config nightly_machines=M`; the
# report is left out with `--config nightly_report=false`, i.e. `rafi nightly --no-report`).
rule nightly:
    input:
        nightly_targets(),
