# Shared helpers of the RAFI workflow: config validation, machine discovery,
# per-machine settings (resolved by rafi.settings), path templates and input functions.
# Every results path comes from rafi.contract (RESULT_FILES and its groups); nothing here
# declares a file name of its own. A fail-mode run stops here, while it plans, on a raw file
# an earlier run quarantined. What a run builds per machine depends on the checkpoint
# input_status (input_status.smk): a machine with no usable raw file is skipped.
#
# Functions only (no rules) - `snakemake --lint` wants rules and functions apart;
# another step's helpers go to workflow/rules/<step>_common.smk (the Snakefile includes
# those first). Every public name below may be used by the other .smk files -
#   constants  RUN (run settings), RAW_DIR, RESULTS_DIR, REPORTS_DIR, LOGS_DIR, MACHINES
#   settings   machine_config(machine) (rafi.settings.machine_settings), model_provenance(machine),
#              nightly_settings(machine), qualification_gates(machine), replay_settings(machine)
#   raw files  LOGS, RAW, raw_files(machine), partner_files(machine), raw_links(machine),
#              machine_raw_paths(wildcards), machine_raw_parts(wildcards),
#              machine_log_names(wildcards), machine_raw_inputs(wildcards),
#              machine_raw_stamps(wildcards)
#   paths      out(name, machine="{machine}", **fields) (a name of rafi.contract.RESULT_FILES),
#              outs(names, machine), registry_dir(machine), report_paths(machine="{machine}"),
#              log_path(step), bench_path(step), skipped_page_path(machine), INPUT_CHECK,
#              FLEET_INDEX
#   code       code_version(script): the params `code` of every rule
#   targets    machine_targets(machine, what), all_pipeline_tables(), all_targets(),
#              nightly_targets() (input functions: they wait for the checkpoint input_status)
#   registry   candidate_model(wildcards), compare_prior(wildcards)
#   messages   say_rejected_input(), say_outcomes(), say_failures() (onsuccess/onerror of the
#              Snakefile)
#   report     workflow/rules/report_common.smk

import logging
import os
import sys
import time
from pathlib import Path
from types import SimpleNamespace

from snakemake.exceptions import WorkflowError
from snakemake.logging import logger as snakemake_logger

# What planning needs is standard library only (no NumPy/pandas to import on every invocation).
import rafi.settings as _settings
from rafi import contract
from rafi.errors import InputSpecError, RafiUserError, RawFormatError, SettingsError
from rafi.family import prior as _prior
from rafi.family.confirmation import taken_back_line, unquoted_ids
from rafi.readers.input_spec import discover_logs, has_braces
from rafi.readers.log_sources import log_name, log_stamp
from rafi.readers.quarantine import (
    is_skipped,
    present_statuses,
    read_input_status,
    rejection_lines,
    still_quarantined,
)
from rafi.ops.code_deps import code_version as _code_version
from rafi.ops.raw_hashes import CACHE_NAME as _RAW_HASH_CACHE, raw_stamps
from rafi.ops.outcome import RunFiles, outcome_lines, read_outcome, skipped_folders
from rafi.ops.run_messages import failure_lines
from rafi.report.probe import sign_key as _probe_sign_key
from rafi.readers.discovery import SKIP_PREFIX
from snakemake.utils import validate

try:
    # a prior's id in checks.confirmed written unquoted, read by YAML as a number: taken back where
    # it can only be that id, else refused naming the fix (before the schema sees it)
    for _taken in unquoted_ids(config):
        print(f"RAFI: {taken_back_line(_taken)}", file=sys.stderr)
    #: Run settings (top level of config.yaml over the contract's defaults).
    RUN = _settings.run_settings(config)
    # the key the schema refuses, in one line (Snakemake's own validation below reports a
    # machine's mistake only as "not valid under any of the given schemas" with a dump of it)
    _settings.validate_config(config)
except SettingsError as exc:
    raise WorkflowError(f"RAFI: {exc}") from None
validate(config, schema="../schemas/config.schema.yaml")

#: When this invocation started planning: the job logs written since then are this run's.
STARTED = time.time()

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
    folder=r"[^/@]+",
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


def nightly_settings(machine):
    """``nightly:`` of ``machine`` (its effective settings)."""
    return machine_config(machine)["nightly"]


def qualification_gates(machine):
    """Promotion gates of ``machine`` (``qualification:`` of its effective settings)."""
    return machine_config(machine)["qualification"]


def replay_settings(machine):
    """The ``deploy:`` settings the replay depends on (``rafi.contract.REPLAY_KEYS``: the limits
    and ``replay_roles``; not the controller's connection settings)."""
    deploy = machine_config(machine)["deploy"]
    return {key: deploy[key] for key in contract.REPLAY_KEYS}


# --------------------------------------------------------------------------- discovery


def _discover():
    """Machine -> {log id: log source} (``rafi.readers.input_spec.discover_logs``: a raw file, a
    sheet of a workbook, a file with its partner), read anew on every invocation, so a new
    folder or file is picked up without editing the config. A link out of ``raw_dir`` is
    refused and a file modified less than ``settle_s`` seconds ago waits for the next run (each
    with a warning line: link_outside_raw, settling)."""
    try:
        found, warnings = discover_logs(
            RAW_DIR,
            lambda m: machine_config(m)["input"],
            configured=config.get("machines") or {},
            settle_s=float(RUN["settle_s"]),
        )
    except (InputSpecError, RawFormatError) as exc:
        raise WorkflowError(f"RAFI: {exc}") from None
    for warning in warnings:
        _log.warning("RAFI: %s", warning)
    SKIPPED_FOLDERS.update(skipped_folders(warnings, SKIP_PREFIX))
    return _by_unit(found)


def _by_unit(found):
    """Folder -> files as unit -> files: a machine with several probes (``input.probes``) is one
    unit per probe, ``<machine>@<probe>``, each reading the machine's files
    (``rafi.settings.machine_units``)."""
    try:
        return {unit: files for m, files in found.items() for unit in _settings.machine_units(config, m)}
    except (InputSpecError, SettingsError) as exc:
        raise WorkflowError(f"RAFI: {exc}") from None


#: Machine -> why, of the machine folders discovery left out (said again at the end of the run).
SKIPPED_FOLDERS = {}
#: Unit -> {log id: log source}.
LOGS = _discover()

#: Machine -> {log id: raw path} (a sheet-log: its workbook; a joined log: its own file).
RAW = {m: {key: src["path"] for key, src in logs.items()} for m, logs in LOGS.items()}

#: What to qualify: the folders of ``raw_dir`` holding at least one matching file, a machine with
#: several probes as one unit per probe (``<machine>@<probe>``).
MACHINES = sorted(RAW)

#: Machine folder -> its probes, of the machines with several probes (``input.probes``).
PROBES = _settings.probes_by_machine(MACHINES)

#: The folder wildcard of the report of a machine with several probes (probes_report): one of them.
MULTI_PROBE_FOLDER = _settings.one_of_pattern(PROBES)

unit_name = _settings.unit_name


def raw_files(machine):
    """Raw log paths of ``machine`` (those matching its ``input.pattern``; a workbook of several
    sheet-logs once), sorted."""
    return sorted(set(RAW.get(machine, {}).values()))


def partner_files(machine):
    """The partner files of ``machine``'s logs (``input.join``) that exist, sorted."""
    found = {src["partner"] for src in LOGS.get(machine, {}).values() if src["partner"]}
    return sorted(p for p in found if Path(p).is_file())


def raw_links(machine):
    """Names of the logs of ``machine`` whose raw file is a symbolic link (inside ``raw_dir``)."""
    logs = LOGS.get(machine, {})
    return sorted(log_name(key, src) for key, src in logs.items() if Path(src["path"]).is_symlink())


def machine_raw_paths(wildcards):
    """Param of the clean step: log id -> raw path of every log of ``{machine}``."""
    return {stem: str(path) for stem, path in sorted(RAW.get(wildcards.machine, {}).items())}


def machine_raw_parts(wildcards):
    """Param of the clean step: log id -> ``{sheet, partner}`` of the logs of ``{machine}`` that
    are not a whole file, and ``{recording: true}`` of the files ``rafi record`` wrote (read as
    native files: ``rafi.readers.recordings``); ``{}`` for a machine of plain files."""
    parts = {}
    for key, src in sorted(LOGS.get(wildcards.machine, {}).items()):
        if src["recording"]:
            parts[key] = {"recording": True}
        elif src["sheet"] is not None or src["partner"] is not None:
            parts[key] = {"sheet": src["sheet"], "partner": src["partner"]}
    return parts


def machine_log_names(wildcards):
    """Log id -> the name each log of ``{machine}`` goes by in the audit (its ``file``)."""
    return {key: log_name(key, src) for key, src in sorted(LOGS.get(wildcards.machine, {}).items())}


def machine_raw_inputs(wildcards):
    """Input function (clean step): the raw files of ``{machine}`` and the partner files of its
    logs, except those whose path holds braces, which Snakemake would read as wildcards
    (``machine_raw_stamps`` follows them)."""
    machine = wildcards.machine
    return [p for p in raw_files(machine) + partner_files(machine) if not has_braces(p)]


_RAW_STAMPS = {}


def machine_raw_stamps(wildcards):
    """Param of the clean step: log id -> content stamp (``sha256:<hex>``, or
    ``unreadable:<errno>``) of every log of ``{machine}``: its raw file's content hash, combined
    with its sheet's name and its partner's hash for a log that is not a whole file
    (``rafi.readers.log_sources.log_stamp``). Snakemake compares modification times only; with
    the hash as a param, its ``params`` trigger re-runs the machine's clean job when a file's
    content changed even with its size and mtime kept (``cp -p``, ``rsync -t``). Computed once
    per invocation for every raw and partner file, through the stat-keyed cache
    ``results/.raw_hashes.json`` (``rafi.ops.raw_hashes``: an unchanged file is not read
    again; a dry run does not write the cache)."""
    if not _RAW_STAMPS:
        paths = [p for m in MACHINES for p in raw_files(m)]
        paths += [src["partner"] for m in MACHINES for src in LOGS[m].values() if src["partner"]]
        cache = Path(RESULTS_DIR) / _RAW_HASH_CACHE
        _RAW_STAMPS.update(raw_stamps(paths, cache, write=not workflow.output_settings.dryrun))
    return {
        key: log_stamp(
            _RAW_STAMPS[src["path"]],
            src["sheet"],
            _RAW_STAMPS[src["partner"]] if src["partner"] else None,
        )
        for key, src in sorted(LOGS.get(wildcards.machine, {}).items())
    }


# --------------------------------------------------------------------------- paths


def out(name, machine="{machine}", **fields):
    """Path of result ``name`` (a key of ``rafi.contract.RESULT_FILES``) under ``results_dir``.

    With the default arguments the ``{machine}`` (and ``{stem}``, ``{group}``, ``{step}``)
    wildcards are kept, so ``out("model")`` can be used directly in ``input:``/``output:``; pass
    a machine name to get a concrete path, e.g. ``out("model", "tapping-center-a")``.
    """
    return f"{RESULTS_DIR}/{machine}/{contract.result_file(name, **fields)}"


def outs(names, machine):
    """Concrete paths of the results ``names`` of ``machine``, in that order."""
    return [out(name, machine) for name in names]


def registry_dir(machine="{machine}"):
    """The registry folder ``results/<machine>/registry`` (``rafi.contract.REGISTRY_DIR``)."""
    return f"{RESULTS_DIR}/{machine}/{contract.REGISTRY_DIR}"


def report_paths(machine="{machine}"):
    """Paths of the qualification report of ``machine``: dict ``html``/``pdf``."""
    return {ext: f"{REPORTS_DIR}/{machine}/qualification.{ext}" for ext in ("html", "pdf")}


def log_path(step, machine="{machine}"):
    """Log file of a step: ``logs/{machine}/<step>.log``."""
    return f"{LOGS_DIR}/{machine}/{step}.log"


def bench_path(step, machine="{machine}"):
    """Benchmark TSV of a step: ``results/{machine}/benchmarks/<step>.tsv``."""
    return out("benchmark", machine, step=step)


def skipped_page_path(machine="{machine}"):
    """``reports/<machine>/skipped.html``: the page of a skipped machine (rule skipped_report)."""
    return f"{REPORTS_DIR}/{machine}/skipped.html"


#: Run-level summary of rejected input, ``results/input_check.json`` (written by input_check).
INPUT_CHECK = f"{RESULTS_DIR}/{contract.RUN_FILES['input_check']}"
#: The fleet overview page (rule fleet_index, fleet.smk).
FLEET_INDEX = f"{REPORTS_DIR}/index.html"


# --------------------------------------------------------------------------- code
#
# Snakemake's own `code` rerun trigger covers a rule's script file, not the rafi modules the
# script imports. Listing those modules as inputs (as this workflow once did) made every failure
# block list 25 source files twice; instead each rule carries `code=code_version(script)` as a
# param: the digest of the script, its glue and every rafi module (and report template) it
# runs, so editing rafi/method/rank.py re-runs the rules that run rank.py and their downstream,
# through Snakemake's own params trigger.

_SCRIPTS_DIR = Path(str(workflow.current_basedir)).parent / "scripts"


def code_version(script):
    """Param ``code`` of a rule: the digest of ``workflow/scripts/<script>.py`` and what it runs."""
    return _code_version(_SCRIPTS_DIR / f"{script}.py")


# --------------------------------------------------------------------------- registry
#
# Side effects of `decide` (deliberately NOT declared outputs): registry/models/<id>.json
# (+ .meta.json), registry/champion.json and registry/history.jsonl. Snakemake deletes a
# job's declared outputs before it re-runs the job; the registry must survive every run.
# champion.json is not an input of `decide` either: a rollback (`rafi nightly --promote`)
# rewrites decision.json itself, and listing a file that appears on the first promotion
# would change decide's input set and make the next dry run want to re-run it.


def candidate_model(wildcards):
    """Input function: tonight's candidate (``rafi.settings.candidate_model_path``)."""
    return _settings.candidate_model_path(
        wildcards.machine, RESULTS_DIR, nightly_settings(wildcards.machine)["candidate"]
    )


def compare_prior(wildcards):
    """Param ``prior`` of the compare job, from ``models.prior`` by
    ``rafi.family.prior.prior_param``. It is the registry's prior chain from its first model
    that learnt from none of the machine's raw files (ids, the registry path, the machine and its
    declared siblings). The registry files are read, not inputs: a
    champion trained on these logs changes nothing here, so promoting one re-runs nothing."""
    machine = wildcards.machine
    current = [s.split(":", 1)[1] for s in machine_raw_stamps(wildcards).values() if s.startswith("sha256:")]
    try:
        return _prior.prior_param(
            RESULTS_DIR,
            machine,
            machine_config(machine)["models"]["prior"],
            current,
            siblings=machine_config(machine)["models"]["prior_siblings"],
        )
    except RafiUserError as exc:
        raise WorkflowError(f"RAFI: {exc}") from None


def _nightly_machines():
    only = RUN["nightly_machines"]
    if not only:
        return MACHINES
    only = [only] if isinstance(only, str) else list(only)
    return [m for m in MACHINES if m in only or _settings.split_unit(m)[0] in only]


# --------------------------------------------------------------------------- machine-level quarantine
#
# The checkpoint input_status (input_status.smk) writes results/<machine>/input_status.json
# after the clean jobs: `usable` (at least one raw file is ok) or `skipped` (every file was
# quarantined). The final targets are input functions that read it (machine_targets), so a
# skipped machine builds only audit.csv and reports/<machine>/skipped.html, and the run carries
# on with the others. Until the checkpoint has run, checkpoints.input_status.get() raises and
# Snakemake builds the checkpoint first; one function per machine, so that one machine's
# checkpoint does not hold back another's jobs.


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
    the replay it shows) only unless ``--config nightly_report=false``. A skipped machine gets
    ``audit.csv`` (and, except for ``tables``, its ``skipped.html`` page) instead. Every kind
    includes ``input_status.json``.
    """
    if what not in TARGET_KINDS:
        raise ValueError(f"machine_targets: what must be one of {TARGET_KINDS}, not {what!r}")

    def _targets(wildcards):
        targets = [out("input_status", machine)]
        if machine_skipped(machine):
            targets.append(out("audit", machine))
            return targets if what == "tables" else targets + [skipped_page_path(machine)]
        targets += outs(contract.PIPELINE_TABLES, machine)
        if what == "tables":
            return targets
        targets += outs(contract.COMPARISON_FILES + contract.DECISION_FILES, machine)
        if what == "all":
            targets += outs(contract.REPLAY_FILES, machine)
        if what == "all" or _settings.truthy(RUN["nightly_report"]):
            targets += list(report_paths(machine).values())
        return targets

    return _targets


def all_pipeline_tables():
    """Input functions (one per machine): the tables of every machine (``rule tables``)."""
    return [machine_targets(m, "tables") for m in MACHINES]


def probes_report_targets(folder):
    """Input function: the report of machine ``folder`` with several probes (rule probes_report),
    once every probe has a report (none while one of them is skipped)."""

    def _targets(wildcards):
        if any(machine_skipped(unit_name(folder, p)) for p in PROBES[folder]):
            return []
        return list(report_paths(folder).values())

    return _targets


def all_targets():
    """Input functions (one per machine), ``INPUT_CHECK`` and the fleet overview: everything
    (``rule all``); a machine with several probes also gets its report of every probe."""
    probes = [probes_report_targets(f) for f in sorted(PROBES)]
    return [machine_targets(m, "all") for m in MACHINES] + probes + [INPUT_CHECK, FLEET_INDEX]


def nightly_targets():
    """Every output a night produces: tables, comparison, decision and (unless
    ``--config nightly_report=false``) the report, for the machines of the night (a skipped
    machine: its audit and skipped page); ``INPUT_CHECK`` and the fleet overview when the night
    covers every machine (a night for some machines, ``rafi nightly --machine M``, rewrites the
    page itself); the report of a machine with several probes whose every probe is in the night."""
    machines = _nightly_machines()
    targets = [machine_targets(m, "nightly") for m in machines]
    if machines == MACHINES:
        return targets + [INPUT_CHECK, FLEET_INDEX]
    night = _settings.probes_by_machine(machines)
    whole = [f for f in sorted(PROBES) if night.get(f) == PROBES[f]]
    with_report = _settings.truthy(RUN["nightly_report"])
    return targets + [probes_report_targets(f) for f in whole if with_report]


# --------------------------------------------------------------------------- messages at the end


def rejected_input_message():
    """What the run says at its end if input was rejected, else ``""`` (read from the
    ``input_status.json`` of every machine there is one for)."""
    lines = rejection_lines(present_statuses(out("input_status", m) for m in MACHINES))
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


def outcome_rows():
    """The ``(machine, probe)`` rows of the end-of-run lines: every machine of the run (those of
    ``nightly_machines`` when it is set) and every machine folder discovery skipped; one row per
    machine (probe None) until a machine has several probes."""
    machines = set(_nightly_machines())
    if not RUN["nightly_machines"]:
        machines |= set(SKIPPED_FOLDERS)
    return [(m, None) for m in sorted(machines)]


def say_outcomes(failed=False):
    """onsuccess/onerror (``failed``) of the Snakefile: one line per machine
    (``rafi.ops.outcome``): PASS / FAIL / skipped / not judged in this run, the model offered,
    why it failed, the report, and the warnings of its job logs. After a failure, say_failures
    prints the failed jobs' lines below them (unless ``debug``)."""
    below = failed and not _settings.truthy(RUN["debug"])
    files = RunFiles(RESULTS_DIR, REPORTS_DIR, LOGS_DIR, STARTED, failures_said_below=below)
    lines = outcome_lines(outcome_rows(), lambda m, p: read_outcome(m, p, files, SKIPPED_FOLDERS))
    if lines:
        print("\n" + "\n".join(lines), file=sys.stderr, flush=True)


def say_failures():
    """onerror of the Snakefile: repeat the one-line message of every job of this run that failed
    on bad input (``RAFI <step> (<wildcards>) failed: ...``, the last line of its log) as the last
    thing the user reads, below Snakemake's failure blocks; in an interactive run
    (``on_bad_input: fail``) then end it (exit status 1) without Snakemake's closing lines, which
    would bury it. A run with ``debug`` set, or whose failures are not bad input (a bug: its
    traceback matters more), ends as Snakemake ends it, and so does ``rafi nightly`` (quarantine
    mode, Snakemake in its own process: it reports the failure itself)."""
    lines = failure_lines(LOGS_DIR, since=STARTED)
    if not lines or _settings.truthy(RUN["debug"]):
        return
    print("\n" + "\n".join(lines), file=sys.stderr, flush=True)
    if RUN["on_bad_input"] == "fail":
        raise SystemExit(1)


# --------------------------------------------------------------------------- bad input


def _refuse_quarantined():
    """``on_bad_input: fail``: stop now if an earlier (quarantine) run set aside a raw file that
    is still there unchanged; its outputs are up to date, so no job would fail on it."""
    if RUN["on_bad_input"] != "fail":
        return
    pairs = [(path, out("clean_summary", m, stem=key)) for m in MACHINES for key, path in RAW[m].items()]
    reasons = still_quarantined(pairs)
    if reasons:
        listed = "\n  ".join(reasons)
        raise WorkflowError(
            f"RAFI: {len(reasons)} raw file(s) cannot be used:\n  {listed}\nFix or remove them, or "
            "run with --config on_bad_input=quarantine to carry on without them."
        )


_refuse_quarantined()
