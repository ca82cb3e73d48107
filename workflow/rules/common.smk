# Shared helpers of the RAFI workflow: config validation, machine discovery,
# per-machine settings (resolved by rafi.settings), path templates and input functions.
# A fail-mode run stops here, while it plans, on a raw file an earlier run quarantined.
# What a run builds per machine depends on the checkpoint input_status (input_status.smk): a
# machine with no usable raw file is skipped (machine_targets).
#
# Functions only (no rules) - `snakemake --lint` wants rules and functions apart;
# another step's helpers go to workflow/rules/<step>_common.smk (the Snakefile includes
# those first). Every public name below may be used by the other .smk files -
#   constants  RUN (run settings), RAW_DIR, RESULTS_DIR, REPORTS_DIR, LOGS_DIR, RAFI_DIR,
#              MACHINES, OUTPUTS
#   settings   machine_config(machine) (rafi.settings.machine_settings), model_provenance(machine)
#   raw files  raw_files(machine), raw_links(machine), raw_path(wildcards), raw_file(wildcards),
#              raw_stamp(wildcards)
#   paths      out(name, machine="{machine}"), pipeline_tables(machine),
#              report_paths(machine="{machine}"), log_path(step), bench_path(step)
#   quarantine input_status_path(machine), skipped_page_path(machine), INPUT_CHECK,
#              machine_skipped(machine), rejected_input_message(), say_rejected_input()
#   targets    machine_targets(machine, what), all_pipeline_tables(), all_targets(),
#              nightly_targets() (input functions: they wait for the checkpoint input_status)
#   inputs     clean_dir(machine), clean_cache_dir(machine), machine_raw_paths(wildcards),
#              machine_raw_inputs(wildcards), machine_raw_stamps(wildcards), rafi_code(script),
#              script_helpers()
#   compare    comparison_path(name, machine), comparison_outputs(machine)
#   registry   nightly_settings(machine), qualification_gates(machine),
#              registry_path(name, machine), candidate_model(wildcards)
#   deploy     deploy_path(name, machine), DEPLOY_FILES, replay_settings(machine)
#   report     workflow/rules/report_common.smk

import importlib.util
import logging
import os
from pathlib import Path
from types import SimpleNamespace

from snakemake.exceptions import WorkflowError
from snakemake.logging import logger as snakemake_logger

# What planning needs is standard library only (no NumPy/pandas to import on every invocation).
import rafi.settings as _settings
from rafi.errors import InputSpecError, RawFormatError, SettingsError
from rafi.readers.input_spec import discover_machines, has_braces
from rafi.readers.quarantine import (
    is_skipped,
    present_statuses,
    read_input_status,
    rejection_lines,
    still_quarantined,
)
from rafi.ops.code_deps import code_files
from rafi.ops.raw_hashes import CACHE_NAME as _RAW_HASH_CACHE, raw_stamps
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
    on every invocation, so a new folder or file is picked up without editing the config. A
    link out of ``raw_dir`` is refused and a file modified less than ``settle_s`` seconds ago
    waits for the next run (each with a warning line: link_outside_raw, settling)."""
    try:
        found, warnings = discover_machines(
            RAW_DIR,
            lambda m: machine_config(m)["input"],
            configured=config.get("machines") or {},
            settle_s=float(RUN["settle_s"]),
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


def raw_links(machine):
    """Names of the raw files of ``machine`` that are symbolic links (inside ``raw_dir``)."""
    return sorted(Path(p).name for p in raw_files(machine) if Path(p).is_symlink())


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
    would read as wildcards; such a file is followed by ``raw_stamp`` (a param) alone."""
    path = raw_path(wildcards)
    return [] if has_braces(path) else path


_RAW_STAMPS = {}


def raw_stamp(wildcards):
    """Param of the clean step: the raw file's content hash (``sha256:<hex>``, or
    ``unreadable:<errno>``), so that a file whose content changed re-runs its clean job even
    if its size and mtime were kept (``cp -p``, ``rsync -t``); Snakemake itself compares
    mtimes only. Computed once per invocation for every raw file, through the cache
    ``results/.raw_hashes.json`` (``rafi.ops.raw_hashes``: an unchanged file is not read
    again; a dry run does not write the cache)."""
    if not _RAW_STAMPS:
        paths = [p for m in MACHINES for p in raw_files(m)]
        cache = Path(RESULTS_DIR) / _RAW_HASH_CACHE
        _RAW_STAMPS.update(raw_stamps(paths, cache, write=not workflow.output_settings.dryrun))
    path = str(raw_path(wildcards))
    if path not in _RAW_STAMPS:  # not discovered at startup (cannot happen): hash it alone
        _RAW_STAMPS.update(raw_stamps([path], Path(RESULTS_DIR) / _RAW_HASH_CACHE, write=False))
    return _RAW_STAMPS[path]


def machine_raw_paths(wildcards):
    """Param of the clean step: log id -> raw path of every raw file of ``{machine}``."""
    return {stem: str(path) for stem, path in sorted(RAW.get(wildcards.machine, {}).items())}


def machine_raw_inputs(wildcards):
    """Input function (clean step): the raw files of ``{machine}`` except those whose path holds
    braces, which Snakemake would read as wildcards (``machine_raw_stamps`` follows them)."""
    return [p for p in raw_files(wildcards.machine) if not has_braces(p)]


def machine_raw_stamps(wildcards):
    """Param of the clean step: log id -> content hash (``raw_stamp``) of every raw file of
    ``{machine}``: a file whose content changed re-runs the machine's clean job even if its
    size and mtime were kept."""
    return {
        stem: raw_stamp(SimpleNamespace(machine=wildcards.machine, stem=stem))
        for stem in sorted(RAW.get(wildcards.machine, {}))
    }


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


def report_paths(machine="{machine}"):
    """Paths of the qualification report of ``machine``: dict ``html``/``pdf``."""
    return {ext: f"{REPORTS_DIR}/{machine}/qualification.{ext}" for ext in ("html", "pdf")}


def log_path(step, machine="{machine}"):
    """Log file of a step: ``logs/{machine}/<step>.log`` (step may contain ``{stem}``)."""
    return f"{LOGS_DIR}/{machine}/{step}.log"


def bench_path(step, machine="{machine}"):
    """Benchmark TSV of a step: ``results/{machine}/benchmarks/<step>.tsv``."""
    return f"{RESULTS_DIR}/{machine}/benchmarks/{step}.tsv"


def clean_dir(machine="{machine}"):
    """The clean step's output folder ``results/<machine>/clean/``: per raw file (log id
    ``<stem>``) ``<stem>.parquet``, ``<stem>.audit.csv`` and ``<stem>.summary.csv`` (the
    ``clean_*`` templates of ``OUTPUTS``), all written by one job per machine."""
    return f"{RESULTS_DIR}/{machine}/clean"


def clean_cache_dir(machine="{machine}"):
    """``results/<machine>/.clean_cache/``: the clean step's content-addressed cache
    (``rafi.ops.clean_cache``), where an unchanged raw file's outputs come back from."""
    return f"{RESULTS_DIR}/{machine}/.clean_cache"


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


# --------------------------------------------------------------------------- deploy (replay)


def deploy_path(name, machine="{machine}"):
    """``results/<machine>/deploy/<name>`` (the outputs of the replay: ``replay.parquet``, ``replay_summary.csv``)."""
    return f"{RESULTS_DIR}/{machine}/deploy/{name}"


DEPLOY_FILES = ("replay.parquet", "replay_summary.csv")

#: The ``deploy:`` settings a replay depends on (the fields of rafi.deploy.limits.Limits and
#: which runs it replays; not the controller's connection settings).
REPLAY_SETTINGS = (
    "clamp_um",
    "rate_um_per_s",
    "temp_valid_c",
    "stuck_s",
    "stuck_change_k",
    "range_margin_k",
    "speed_margin_rpm",
    "hold_s",
    "safe_um",
    "ramp_um_per_s",
    "interval_s",
    "replay_roles",
)


def replay_settings(machine):
    """The limits in force and ``replay_roles`` of ``machine`` (``deploy:`` of its settings)."""
    deploy = machine_config(machine)["deploy"]
    return {key: deploy[key] for key in REPLAY_SETTINGS}


def _nightly_machines():
    only = RUN["nightly_machines"]
    if not only:
        return MACHINES
    only = [only] if isinstance(only, str) else list(only)
    return [m for m in MACHINES if m in only]


def _report_wanted():
    return str(RUN["nightly_report"]).lower() not in ("0", "false", "no")


# --------------------------------------------------------------------------- machine-level quarantine
#
# The checkpoint input_status (input_status.smk) writes results/<machine>/input_status.json
# after the clean jobs: `usable` (at least one raw file is ok) or `skipped` (every file was
# quarantined). The final targets are input functions that read it (machine_targets), so a
# skipped machine builds only audit.csv and reports/<machine>/skipped.html, and the run carries
# on with the others. Until the checkpoint has run, checkpoints.input_status.get() raises and
# Snakemake builds the checkpoint first; one function per machine, so that one machine's
# checkpoint does not hold back another's jobs.


def input_status_path(machine="{machine}"):
    """``results/<machine>/input_status.json`` (output of the checkpoint input_status)."""
    return f"{RESULTS_DIR}/{machine}/input_status.json"


def skipped_page_path(machine="{machine}"):
    """``reports/<machine>/skipped.html``: the page of a skipped machine (rule skipped_report)."""
    return f"{REPORTS_DIR}/{machine}/skipped.html"


#: Run-level summary of rejected input, ``results/input_check.json`` (written by input_check).
INPUT_CHECK = f"{RESULTS_DIR}/input_check.json"
#: The fleet overview page (rule fleet_index, fleet.smk).
FLEET_INDEX = f"{REPORTS_DIR}/index.html"


def machine_skipped(machine):
    """True if ``machine`` has no usable raw file (after the checkpoint input_status: raises
    Snakemake's IncompleteCheckpointException until it has run)."""
    return is_skipped(read_input_status(checkpoints.input_status.get(machine=machine).output.status))


#: What machine_targets() builds for a machine, by purpose.
TARGET_KINDS = ("tables", "all", "nightly")


def machine_targets(machine, what):
    """Input function: the final outputs of ``machine`` for ``what`` (a ``TARGET_KINDS``).

    ``tables``: the tables of docs/design.md; ``all``: plus the comparison, the registry
    decision, the replay (``deploy/``) and the report; ``nightly``: as ``all``, the report (and
    the replay it shows) only unless ``--config nightly_report=false``. A skipped machine gets ``audit.csv`` (and, except for ``tables``,
    its ``skipped.html`` page) instead. Every kind includes ``input_status.json``.
    """
    if what not in TARGET_KINDS:
        raise ValueError(f"machine_targets: what must be one of {TARGET_KINDS}, not {what!r}")

    def _targets(wildcards):
        targets = [input_status_path(machine)]
        if machine_skipped(machine):
            targets.append(out("audit", machine))
            return targets if what == "tables" else targets + [skipped_page_path(machine)]
        targets += list(pipeline_tables(machine).values())
        if what == "tables":
            return targets
        targets += comparison_outputs(machine)
        targets += [registry_path("decision.json", machine), registry_path("comparison.csv", machine)]
        if what == "all":
            targets += [deploy_path(name, machine) for name in DEPLOY_FILES]
        if what == "all" or _report_wanted():
            targets += list(report_paths(machine).values())
        return targets

    return _targets


def all_pipeline_tables():
    """Input functions (one per machine): the tables of every machine (``rule tables``)."""
    return [machine_targets(m, "tables") for m in MACHINES]


def all_targets():
    """Input functions (one per machine), ``INPUT_CHECK`` and the fleet overview: everything
    (``rule all``)."""
    return [machine_targets(m, "all") for m in MACHINES] + [INPUT_CHECK, FLEET_INDEX]


def nightly_targets():
    """Every output a night produces: tables, comparison, decision and (unless
    ``--config nightly_report=false``) the report, for the machines of the night (a skipped
    machine: its audit and skipped page); ``INPUT_CHECK`` and the fleet overview when the night
    covers every machine (a night for some machines, ``rafi nightly --machine M``, rewrites the
    page itself)."""
    machines = _nightly_machines()
    targets = [machine_targets(m, "nightly") for m in machines]
    return targets + ([INPUT_CHECK, FLEET_INDEX] if machines == MACHINES else [])


def rejected_input_message():
    """What the run says at its end if input was rejected, else ``""`` (read from the
    ``input_status.json`` of every machine there is one for)."""
    lines = rejection_lines(present_statuses(input_status_path(m) for m in MACHINES))
    if not lines:
        return ""
    listed = "\n  ".join(lines)
    return (
        f"RAFI: INPUT WAS REJECTED - the run carried on without it:\n  {listed}\n"
        f"Summary: {INPUT_CHECK}; per machine: {RESULTS_DIR}/<machine>/audit.csv and "
        f"input_status.json; a skipped machine's page: {REPORTS_DIR}/<machine>/skipped.html. "
        "rafi nightly exits with 4 for this."
    )


def say_rejected_input():
    """onsuccess/onerror of the Snakefile: log ``rejected_input_message()``, if any."""
    message = rejected_input_message()
    if message:
        snakemake_logger.warning(message)


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
