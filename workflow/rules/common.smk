# Shared helpers of the RAFI workflow: config validation, machine discovery,
# per-machine settings (resolved by rafi.settings), path templates and input functions.
# A fail-mode run stops here, while it plans, on a raw file an earlier run quarantined.
#
# Functions only (no rules) - `snakemake --lint` wants rules and functions apart;
# another step's helpers go to workflow/rules/<step>_common.smk (the Snakefile includes
# those first). Every public name below may be used by the other .smk files -
#   constants  RUN (run settings), RAW_DIR, RESULTS_DIR, REPORTS_DIR, LOGS_DIR, RAFI_DIR,
#              MACHINES, OUTPUTS
#   settings   machine_config(machine) (rafi.settings.machine_settings), model_provenance(machine)
#   raw files  raw_files(machine), raw_path(wildcards), raw_file(wildcards), raw_stamp(wildcards)
#   paths      out(name, machine="{machine}"), pipeline_tables(machine),
#              all_pipeline_tables(), report_paths(machine="{machine}"),
#              log_path(step), bench_path(step)
#   inputs     clean_files(kind), rafi_code(script), script_helpers()
#   compare    comparison_path(name, machine), comparison_outputs(machine)
#   registry   nightly_settings(machine), qualification_gates(machine),
#              registry_path(name, machine), candidate_model(wildcards), nightly_targets()
#   report     workflow/rules/report_common.smk

import importlib.util
import logging
import os
from pathlib import Path

from snakemake.exceptions import WorkflowError

# What planning needs is standard library only (no NumPy/pandas to import on every invocation).
import rafi.settings as _settings
from rafi.errors import InputSpecError, RawFormatError, SettingsError
from rafi.readers.input_spec import discover_machines, has_braces
from rafi.readers.quarantine import still_quarantined
from rafi.ops.code_deps import code_files
from snakemake.utils import validate

try:
    #: Run settings (top level of config.yaml over rafi.settings.RUN_DEFAULTS).
    RUN = _settings.run_settings(config)
except SettingsError as exc:
    raise WorkflowError(f"RAFI: {exc}") from None
validate(config, schema="../schemas/config.schema.yaml")

# Every job does linear algebra on small matrices: one BLAS thread per process is fastest,
# and Snakemake's --cores stays the only parallelism (multi-threaded BLAS in several jobs at
# once oversubscribes the cores badly). Jobs inherit this environment; it must be set here
# because a script's own setting comes after Snakemake has loaded NumPy.
os.environ.update(
    {var: os.environ.get(var, "1") for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
)

_log = logging.getLogger("rafi.workflow")

RAW_DIR = Path(RUN["raw_dir"])
RESULTS_DIR = str(RUN["results_dir"]).rstrip("/")
REPORTS_DIR = str(RUN["reports_dir"]).rstrip("/")
LOGS_DIR = "logs"


wildcard_constraints:
    machine=r"[^/]+",
    stem=r"[^/]+",


# --------------------------------------------------------------------------- settings

_MACHINE_SETTINGS = {}


def machine_config(machine):
    """Effective settings of ``machine`` (``rafi.settings.machine_settings``: every key present).

    Computed once per machine and invocation; callers must not modify the dict they get.
    """
    if machine not in _MACHINE_SETTINGS:
        _MACHINE_SETTINGS[machine] = _settings.machine_settings(config, machine)
    return _MACHINE_SETTINGS[machine]


def model_provenance(machine):
    """The settings ``model.json`` records for ``machine`` (``rafi.settings.model_provenance``)."""
    return _settings.model_provenance(machine_config(machine))


# --------------------------------------------------------------------------- discovery


def _discover():
    """Machine -> {log id: raw path} (``rafi.readers.input_spec.discover_machines``), read anew
    on every invocation, so a new folder or file is picked up without editing the config."""
    try:
        found, warnings = discover_machines(
            RAW_DIR, lambda m: machine_config(m)["input"], configured=config.get("machines") or {}
        )
    except (InputSpecError, RawFormatError) as exc:
        raise WorkflowError(f"RAFI: {exc}") from None
    for warning in warnings:
        _log.warning("RAFI: %s", warning)
    return found


RAW = _discover()

#: Machines to process: the folders of ``raw_dir`` holding at least one matching file.
MACHINES = sorted(RAW)


def raw_files(machine):
    """Raw log paths of ``machine`` (those matching its ``input.pattern``), sorted."""
    return sorted(RAW.get(machine, {}).values())


def raw_path(wildcards):
    """The raw file of ``{machine}``/``{stem}`` (``{stem}`` is its log id)."""
    try:
        return RAW[wildcards.machine][wildcards.stem]
    except KeyError:
        raise WorkflowError(
            f"RAFI: no raw file {wildcards.stem}.* for machine {wildcards.machine!r} under {RAW_DIR}"
        ) from None


def raw_file(wildcards):
    """Input function (clean step): the raw file, unless its path holds braces, which Snakemake
    would read as wildcards; such a file is followed by ``raw_stamp`` (a param) instead."""
    path = raw_path(wildcards)
    return [] if has_braces(path) else path


def raw_stamp(wildcards):
    """Size and modification time of a raw file that cannot be an input (see ``raw_file``), so
    that editing it re-runs its clean job; ``None`` for every other file."""
    path = raw_path(wildcards)
    if not has_braces(path):
        return None
    stat = os.stat(path)
    return [stat.st_size, stat.st_mtime_ns]


# --------------------------------------------------------------------------- paths


#: Output templates (relative to ``results_dir``) - the tables of docs/design.md plus the
#: per-file intermediates of the clean step (``clean/<stem>.summary.csv``: one audit row).
OUTPUTS = {
    "clean_parquet": "clean/{stem}.parquet",
    "clean_audit": "clean/{stem}.audit.csv",
    "clean_summary": "clean/{stem}.summary.csv",
    "audit": "audit.csv",
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
}


#: Per-machine tables every full run must produce (``rule all``).
TABLES = [name for name in OUTPUTS if not name.startswith("clean_")]


def out(name, machine="{machine}", stem="{stem}"):
    """Path of output ``name`` (a key of ``OUTPUTS``) under ``results_dir``.

    With the default arguments the ``{machine}`` (and ``{stem}``) wildcards are kept,
    so ``out("model")`` can be used directly in ``input:``/``output:``; pass a machine
    name to get a concrete path, e.g. ``out("model", "tapping-center-a")``.
    """
    return f"{RESULTS_DIR}/{machine}/{OUTPUTS[name]}".replace("{stem}", stem)


def pipeline_tables(machine):
    """Dict name -> concrete path of every per-machine table of design.md for ``machine``."""
    return {name: out(name, machine) for name in TABLES}


def all_pipeline_tables():
    """Flat list of ``pipeline_tables`` of every discovered machine (for ``rule all``)."""
    return [path for m in MACHINES for path in pipeline_tables(m).values()]


def report_paths(machine="{machine}"):
    """Paths of the qualification report of ``machine``: dict ``html``/``pdf``."""
    return {ext: f"{REPORTS_DIR}/{machine}/qualification.{ext}" for ext in ("html", "pdf")}


def log_path(step, machine="{machine}"):
    """Log file of a step: ``logs/{machine}/<step>.log`` (step may contain ``{stem}``)."""
    return f"{LOGS_DIR}/{machine}/{step}.log"


def bench_path(step, machine="{machine}"):
    """Benchmark TSV of a step: ``results/{machine}/benchmarks/<step>.tsv``."""
    return f"{RESULTS_DIR}/{machine}/benchmarks/{step}.tsv"


def clean_files(kind="clean_parquet"):
    """Input function: the per-file clean outputs of ``{machine}`` (one per raw file).

    ``kind`` is ``clean_parquet``, ``clean_audit`` or ``clean_summary``.
    """

    def _inputs(wildcards):
        return [out(kind, wildcards.machine, stem) for stem in sorted(RAW.get(wildcards.machine, {}))]

    return _inputs


# --------------------------------------------------------------------------- code dependencies
#
# Snakemake's own `code` rerun trigger only covers the script file of a rule, not the rafi
# modules the script imports. rafi_code(script) lists them (rafi.ops.code_deps, from the
# script's own imports) for use as `input:`: editing rafi/method/rank.py makes the rank
# outputs older than an input and re-runs rank and everything downstream, nothing upstream.


def _rafi_package_dir():
    spec = importlib.util.find_spec("rafi")
    if spec is not None and spec.origin:
        return Path(spec.origin).parent
    return Path(workflow.basedir) / "rafi"


RAFI_DIR = _rafi_package_dir()


def rafi_code(script):
    """Paths of the ``rafi`` source files ``workflow/scripts/<script>.py`` runs (``input:``)."""
    return code_files(_SCRIPTS_DIR / f"{script}.py", RAFI_DIR)


_SCRIPTS_DIR = Path(str(workflow.current_basedir)).parent / "scripts"


def script_helpers():
    """The shared script glue module (``workflow/scripts/_glue.py``), an input of every rule."""
    return str(_SCRIPTS_DIR / "_glue.py")


# --------------------------------------------------------------------------- model comparison


def comparison_path(name, machine="{machine}"):
    """Path of a comparison output: ``results/<machine>/comparison/<name>``."""
    return f"{RESULTS_DIR}/{machine}/comparison/{name}"


COMPARISON_FILES = ("summary.csv", "per_run.csv", "residuals.parquet", "best_model.json", "cv.csv")


def comparison_outputs(machine):
    """Concrete comparison outputs of ``machine`` (for ``rule all``)."""
    return [comparison_path(name, machine) for name in COMPARISON_FILES]


# --------------------------------------------------------------------------- registry
#
# Side effects of `decide` (deliberately NOT declared outputs): registry/models/<id>.json
# (+ .meta.json), registry/champion.json and registry/history.jsonl. Snakemake deletes a
# job's declared outputs before it re-runs the job; the registry must survive every run.
# champion.json is not an input of `decide` either: a rollback (`rafi nightly --promote`)
# rewrites decision.json itself, and listing a file that appears on the first promotion
# would change decide's input set and make the next dry run want to re-run it.


def nightly_settings(machine):
    """``nightly:`` of ``machine`` (its effective settings)."""
    return machine_config(machine)["nightly"]


def qualification_gates(machine):
    """Promotion gates of ``machine`` (``qualification:`` of its effective settings)."""
    return machine_config(machine)["qualification"]


def registry_path(name, machine="{machine}"):
    """``results/<machine>/registry/<name>``."""
    return f"{RESULTS_DIR}/{machine}/registry/{name}"


def candidate_model(wildcards):
    """Input function: tonight's candidate (``rafi.settings.candidate_model_path``)."""
    return _settings.candidate_model_path(
        wildcards.machine, RESULTS_DIR, nightly_settings(wildcards.machine)["candidate"]
    )


def _nightly_machines():
    only = RUN["nightly_machines"]
    if not only:
        return MACHINES
    only = [only] if isinstance(only, str) else list(only)
    return [m for m in MACHINES if m in only]


def _report_wanted():
    return str(RUN["nightly_report"]).lower() not in ("0", "false", "no")


def nightly_targets():
    """Every output a night produces: tables, comparison, decision and (unless
    ``--config nightly_report=false``) the report, for the machines of the night."""
    targets = []
    for m in _nightly_machines():
        targets += list(pipeline_tables(m).values()) + comparison_outputs(m)
        targets += [registry_path("decision.json", m), registry_path("comparison.csv", m)]
        if _report_wanted():
            targets += list(report_paths(m).values())
    return targets


# --------------------------------------------------------------------------- bad input


def _refuse_quarantined():
    """``on_bad_input: fail``: stop now if an earlier (quarantine) run set aside a raw file that
    is still there unchanged; its outputs are up to date, so no job would fail on it."""
    if RUN["on_bad_input"] != "fail":
        return
    pairs = [(path, out("clean_summary", m, key)) for m in MACHINES for key, path in RAW[m].items()]
    reasons = still_quarantined(pairs)
    if reasons:
        listed = "\n  ".join(reasons)
        raise WorkflowError(
            f"RAFI: {len(reasons)} raw file(s) cannot be used:\n  {listed}\nFix or remove them, or "
            "run with --config on_bad_input=quarantine to carry on without them."
        )


_refuse_quarantined()
