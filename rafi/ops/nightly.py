"""Nightly retraining: pick up new logs, retrain, qualify, promote or keep the champion.

Runs the Snakemake pipeline (target rule `nightly`: every table, the champion/challenger
decision and the report of every machine under raw/) under nightly locks, then reads
each machine's registry/decision.json and audit.csv. Bad input is quarantined: a machine none
of whose raw files is usable is skipped (reports/<machine>/skipped.html says why) and the
other machines finish. A night heals what a killed night left: Snakemake's lock in
.snakemake/locks with no live Snakemake process in the project is stale and is cleared (a
line on stdout and in the nightly log). A raw file modified less than nightly_settle_s seconds
ago (config, default 600) waits for the next night; each such file is named. See
docs/operations.md.

Locks: `--machine M` takes results/.nightly.M.lock only, so nights for different
machines run at the same time (a cron line or a Slurm array task per machine) and two for the
same machine refuse each other (exit 75); such a night runs Snakemake without its directory
lock (--nolock: the machines' outputs never overlap) and writes results/nightly.M.log and
results/.nightly.state.M.json. A night for every machine takes results/.nightly.lock and
every machine's lock (sorted order, all or none), keeps Snakemake's lock, and writes
results/nightly.log and results/.nightly.state.json.

Exit codes (most severe first when several apply: 1 > 3 > 2 > 4 > 0):
  0   all good (promoted, kept, or nothing new)
  1   the pipeline failed (Snakemake error; other machines carried on with --keep-going)
  3   recalibration due: the champion drifted on the newest validation logs
  2   tonight's candidate failed qualification (the champion was kept)
  4   some input was rejected: a raw file quarantined, or a machine skipped because none of
      its raw files is usable (the other files and machines carried on)
Returned alone, before any decision:
  64  usage error (unknown machine or model id for --promote; --promote of a model no night
      promoted while a warning of it is not confirmed: one line names each warning and the
      checks.confirmed entries to add, --confirm-warnings promotes over them)
  73  results/ (or the log file) cannot be written: read-only, disk full, quota, permission
      (EX_CANTCREAT; one line names the path and the errno, no traceback)
  74  another I/O error on the project's files (EX_IOERR; one line)
  75  another nightly run holds the lock, or a live Snakemake run works in the project and
      holds Snakemake's lock (EX_TEMPFAIL: try again later; the message names the pid)

Output lines (stdout): `lock ... acquired`, `cleared a stale Snakemake lock (...)`, `waits for
the next night (still being written?): <file> ...`, `snakemake --cores ... -- nightly (log
...)`, `[i/n] done <rule> (...)` / `FAILED <rule>`, `nothing new since ...`, one status line per
machine, `INPUT REJECTED: ...`, the end-of-run lines of the workflow (`RAFI: outcome of this run
...`, one per machine: PASS / FAIL / skipped; rafi.ops.outcome), `N job(s) in T s; exit C`.
Errors (stderr): `another nightly run is in progress ...`, `Snakemake is running in <dir> (pid
N: ...) ...`, `cannot write <path>: <strerror> (<ERRNO>); ...; exiting with 73`.

Examples:
  rafi nightly --cores 2                   # cron / systemd
  rafi nightly --dry-run                   # what would run, no lock, no changes
  rafi nightly --machine tapping-center-a --promote 3f2a9c1b   # roll back the champion
  rafi nightly --machine tapping-center-a --promote 9cb3d9298248 --confirm-warnings
                                           # over unconfirmed warnings (recorded)
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import os
import sys
import time
from pathlib import Path

from rafi.artefact import now_iso
from rafi.cli import add_config_option
from rafi.contract import PROBE_SEPARATOR
from rafi.errors import LockHeld, RegistryError, SettingsError
from rafi.ops import snakemake_api
from rafi.ops.lock import (
    LOCK_NAME,
    clear_stale_snakemake_lock,
    holder_pids,
    machine_lock_path,
    night_locks,
    snakemake_lock_files,
)
from rafi.ops.outcome import RunFiles, outcome_lines, read_outcome
from rafi.ops.project import Paths, config_path, load_config, settling, units, unmatched_folders
from rafi.ops.state import clear_state, fingerprint, log_name, read_state, write_state
from rafi.ops.status import (
    EXIT_CANTCREAT,
    EXIT_IOERR,
    EXIT_LOCKED,
    EXIT_OK,
    EXIT_PIPELINE_FAILED,
    EXIT_QUARANTINED,
    EXIT_USAGE,
    MachineStatus,
    last_activity,
    machine_status,
    most_severe,
    short_id,
)
from rafi.settings import run_settings

#: Test hook: seconds to sleep while holding the lock, before anything else (tests only).
HOLD_ENV = "RAFI_NIGHTLY_TEST_HOLD_S"
#: Test hook: while holding the lock, wait until this file exists (at most 600 s; tests only).
HOLD_UNTIL_ENV = "RAFI_NIGHTLY_TEST_HOLD_UNTIL"


#: errno values that mean "this file cannot be written" (exit code 73, EX_CANTCREAT).
WRITE_ERRNOS = frozenset({errno.EROFS, errno.ENOSPC, errno.EDQUOT, errno.EACCES, errno.EPERM, errno.EFBIG})


def config_overrides(args, config: dict | None = None) -> dict:
    """The ``--config`` values of a night: quarantine bad input, the settle time (run setting
    ``nightly_settle_s``: a raw file modified less than that many seconds ago waits for the next
    night), the machine, the report."""
    over = {"on_bad_input": "quarantine", "settle_s": run_settings(config or {})["nightly_settle_s"]}
    if args.machine:
        over["nightly_machines"] = args.machine
    if getattr(args, "no_report", False):
        over["nightly_report"] = "false"
    if getattr(args, "debug", False):  # rafi --debug nightly: job tracebacks on the terminal too
        over["debug"] = "true"
    return over


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of ``rafi nightly``."""
    parser.add_argument("--cores", type=int, default=2, help="cores for Snakemake (default 2)")
    parser.add_argument(
        "--dry-run", action="store_true", help="only show what would run (no lock, nothing written)"
    )
    parser.add_argument("--machine", help="only this machine (folder under raw/)")
    add_config_option(parser, relative_to="--directory")
    parser.add_argument("--directory", default=".", help="project directory (default .)")
    parser.add_argument(
        "--promote",
        metavar="MODEL_ID",
        help="point the champion of --machine at this registered model "
        "(id or unique prefix; rollback) and exit; a model no night promoted is refused while a "
        "warning of it is not confirmed in checks.confirmed",
    )
    parser.add_argument(
        "--confirm-warnings",
        action="store_true",
        help="with --promote: promote over unconfirmed input or prior fitness warnings (recorded "
        "in history.jsonl with who did it)",
    )
    parser.add_argument(
        "--full-check",
        action="store_true",
        help="always ask Snakemake what is out of date (skip the fast "
        "fingerprint check of config, code, raw/ and results/)",
    )
    parser.add_argument(
        "--no-report", action="store_true", help="leave the report out of tonight's targets (faster; tests)"
    )
    parser.add_argument(
        "--log-file", help="append Snakemake's full output to this file (default results/nightly.log)"
    )


def run(args) -> int:
    """Run ``rafi nightly`` with parsed ``args``; returns the exit code."""
    directory = Path(args.directory).resolve()
    args.directory = directory
    try:
        config = load_config(directory, args.config)
        paths = Paths.from_config(directory, config)
    except OSError as exc:
        print(f"rafi nightly: cannot read config: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except SettingsError as exc:
        print(f"rafi nightly: {exc}", file=sys.stderr)
        return EXIT_USAGE
    machines = paths.machines()
    if args.machine and args.machine not in machines:
        print(
            f"rafi nightly: no machine {args.machine!r} under {paths.raw_dir} "
            f"(found: {', '.join(machines) or 'none'})",
            file=sys.stderr,
        )
        return EXIT_USAGE
    if args.machine:
        machines = [args.machine]
    if getattr(args, "confirm_warnings", False) and not args.promote:
        print("rafi nightly: --confirm-warnings goes with --promote", file=sys.stderr)
        return EXIT_USAGE
    args.config_data = config
    overrides = config_overrides(args, config)
    args.reports_dir = directory / str(run_settings(config)["reports_dir"])
    args.settle_s = float(overrides["settle_s"])
    args.settling = settling(paths, config, machines, args.settle_s)
    args.waiting = (
        {m: len(settling(paths, config, [m], args.settle_s)) for m in machines} if args.settling else {}
    )
    args.unmatched = unmatched_folders(paths, config, machines)

    if args.dry_run:
        return _dry_run(args, paths, overrides)

    every = not args.machine  # a night for every machine, or for --machine only
    try:
        with night_locks(paths.results_dir, machines, every_machine=every):
            held = _locks_text(paths, machines, every)
            print(f"rafi nightly: {held} acquired (pid {os.getpid()}, {now_iso()})", flush=True)
            _test_hold()
            if args.promote:
                return _promote(args, paths, machines)
            return _night(args, paths, machines, overrides, every)
    except LockHeld as exc:
        print(
            f"rafi nightly: another nightly run is in progress ({exc.holder}; lock "
            f"{exc.path}); exiting with {EXIT_LOCKED} (try again later)",
            file=sys.stderr,
        )
        return EXIT_LOCKED
    except OSError as exc:  # results/ read-only or full, or another I/O error: one line, no traceback
        return _os_error(exc, paths.results_dir)


def _locks_text(paths: Paths, machines: list[str], every: bool) -> str:
    """``lock <path>`` (one machine) or ``locks <fleet lock> + N machine locks in <dir>``."""
    if not every:
        return "lock " + ", ".join(str(machine_lock_path(paths.results_dir, m)) for m in machines)
    return (
        f"lock {paths.results_dir / LOCK_NAME} and {len(machines)} machine lock(s) "
        f"{machine_lock_path(paths.results_dir, '<machine>')}"
    )


def _test_hold() -> None:
    """The test hooks (:data:`HOLD_ENV`, :data:`HOLD_UNTIL_ENV`): hold the locks a while."""
    hold = os.environ.get(HOLD_ENV)
    if hold:
        time.sleep(float(hold))
    until = os.environ.get(HOLD_UNTIL_ENV)
    if until:
        deadline = time.monotonic() + 600
        while not os.path.exists(until) and time.monotonic() < deadline:
            time.sleep(0.05)


def _os_error(exc: OSError, results_dir: Path) -> int:
    """Say in one line which file could not be written or read and why; the exit code."""
    code = EXIT_CANTCREAT if exc.errno in WRITE_ERRNOS else EXIT_IOERR
    name = errno.errorcode.get(exc.errno or 0, "unknown errno")
    what = exc.filename or results_dir
    reason = os.strerror(exc.errno) if exc.errno else str(exc)
    hint = {
        errno.EROFS: "the file system is mounted read-only",
        errno.ENOSPC: "the disk is full: free some space",
        errno.EDQUOT: "the disk quota is used up",
        errno.EACCES: "this user may not write there",
        errno.EPERM: "this user may not write there (or the file is immutable: lsattr)",
    }.get(exc.errno, "")
    print(
        f"rafi nightly: cannot {'write' if code == EXIT_CANTCREAT else 'use'} {what}: {reason} "
        f"({name}){'; ' + hint if hint else ''}; results_dir is {results_dir}. The night stopped "
        f"(the champion in service stays); exiting with {code}",
        file=sys.stderr,
    )
    return code


def check_writable(folder: Path) -> None:
    """Create, write (64 KiB), fsync and remove a file in ``folder`` (created if missing).

    Raises
    ------
    OSError
        What writing there gives (``EROFS`` read-only, ``ENOSPC`` full, ``EACCES`` ...), with the
        probe's path as ``filename``.
    """
    folder.mkdir(parents=True, exist_ok=True)
    probe = folder / f".nightly.write-probe.{os.getpid()}"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            os.write(fd, b"\0" * 65536)
            os.fsync(fd)
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror, str(folder)) from None
        finally:
            os.close(fd)
    finally:
        try:
            os.unlink(probe)
        except FileNotFoundError:
            pass


def _log_line(log_file: Path, text: str) -> None:
    """Append ``<time> rafi nightly: <text>`` to the nightly log."""
    with open(log_file, "a", encoding="utf-8") as fh:
        fh.write(f"{now_iso()} rafi nightly: {text}\n")


def _snakemake_lock(paths: Paths, log_file: Path) -> int | None:
    """Clear a stale Snakemake lock in the project (said on stdout and in the log); exit code
    75 if a Snakemake run works in the project now, else None. Other nights holding their
    nightly locks here (and their jobs) are not such a run."""
    removed, live = clear_stale_snakemake_lock(paths.directory, coordinated=holder_pids(paths.results_dir))
    if live:
        procs = "; ".join(f"pid {pid}: {cmd}" for pid, cmd in live)
        text = (
            f"Snakemake is running in {paths.directory} ({procs}) and holds its lock "
            f"{paths.directory / '.snakemake' / 'locks'}; exiting with {EXIT_LOCKED} (the next night "
            "runs when it has finished)"
        )
        _log_line(log_file, text)
        print(f"rafi nightly: {text}", file=sys.stderr)
        return EXIT_LOCKED
    if removed:
        text = (
            f"cleared a stale Snakemake lock ({', '.join(p.name for p in removed)} in "
            f"{removed[0].parent}): no Snakemake process works in {paths.directory}; it was left by "
            "a run that was killed"
        )
        _log_line(log_file, text)
        print(f"rafi nightly: {text}", flush=True)
    return None


def _say_settling(args, prefix: str = "rafi nightly: ") -> None:
    for path, age in args.settling:
        print(
            f"{prefix}waits for the next night (still being written?): {path} was modified "
            f"{age:.0f} s ago (nightly_settle_s {args.settle_s:g})"
        )


def _dry_run(args, paths: Paths, overrides: dict) -> int:
    _say_settling(args, "rafi nightly (dry run): ")
    stale = snakemake_lock_files(paths.directory)
    if stale:
        print(
            f"rafi nightly (dry run): Snakemake's lock is set ({', '.join(p.name for p in stale)}); "
            "a night clears it if no Snakemake process works here"
        )
    with open(os.devnull, "w", encoding="utf-8") as sink, snakemake_api.output_to(sink):
        outcome = snakemake_api.run(
            args.directory,
            config_path(args.directory, args.config),
            overrides,
            cores=args.cores,
            dry_run=True,
        )
    if not outcome.ok:
        print(f"rafi nightly (dry run): the pipeline cannot be planned: {outcome.error}", file=sys.stderr)
        return EXIT_PIPELINE_FAILED
    jobs = dict(outcome.planned)
    if not jobs and outcome.target_scheduled:
        jobs[snakemake_api.TARGET] = 1  # only the target itself is out of date
    if not jobs:
        print("rafi nightly (dry run): nothing to do")
    else:
        print("rafi nightly (dry run): would run " + ", ".join(f"{r} x{n}" for r, n in sorted(jobs.items())))
    return EXIT_OK


def _promote(args, paths: Paths, machines: list[str]) -> int:
    """``--promote``: :func:`rafi.ops.promotion_trail.promote_by_hand` with the machine's
    ``checks.confirmed``; a refusal (an unknown id, an unconfirmed warning) is one line, exit 64."""
    from rafi.ops.promotion_trail import promote_by_hand
    from rafi.settings import machine_settings

    if not args.machine:
        if len(machines) != 1:
            print("rafi nightly: --promote needs --machine", file=sys.stderr)
            return EXIT_USAGE
        args.machine = machines[0]
    reg = paths.registry(args.machine)
    try:
        settings = machine_settings(getattr(args, "config_data", None) or {}, args.machine)
        confirmed = settings["checks"]["confirmed"]
        rec = promote_by_hand(
            reg,
            args.machine,
            args.promote,
            confirmed=confirmed or (),
            confirm_warnings=bool(getattr(args, "confirm_warnings", False)),
        )
    except (RegistryError, SettingsError) as exc:
        print(f"rafi nightly: {exc}", file=sys.stderr)
        return EXIT_USAGE
    over = (rec.get("by_hand") or {}).get("overridden")
    print(
        f"rafi nightly: {args.machine}: champion {short_id(rec['champion_id_before'])} -> "
        f"{short_id(rec['champion_id_after'])}"
        + (f" over unconfirmed warnings ({over['warnings']})" if over else "")
        + f" (recorded in {reg / 'history.jsonl'})"
    )
    return EXIT_OK


def _night(args, paths: Paths, machines: list[str], overrides: dict, every: bool = True) -> int:
    started = time.time()
    night_start = float(int(started))
    scope = None if every else machines  # whose fast-path state and log
    check_writable(paths.results_dir)
    log_file = Path(args.log_file) if args.log_file else paths.results_dir / log_name(scope)
    log_file.parent.mkdir(parents=True, exist_ok=True)
    code = _snakemake_lock(paths, log_file)
    if code is not None:
        return code
    _say_settling(args)
    # a night that left a settling file out must not let the next one take the fast path
    remember = not args.settling
    fp = None if args.full_check else fingerprint(args.config, paths, overrides, scope)
    if fp is not None and read_state(paths, scope).get("fingerprint") == fp:
        # nothing changed since the last successful night: no need to ask Snakemake
        return _nothing_new(paths, machines, started, args.waiting)
    # One Snakemake run, no separate dry run (it would build the job graph twice): Snakemake
    # itself schedules no job when no new data arrived.
    cfg = config_path(paths.directory, args.config)
    print(
        f"rafi nightly: snakemake --cores {args.cores} --rerun-incomplete --keep-going "
        f"{'' if every else '--nolock '}--configfile {cfg} "
        f"--config {' '.join(f'{k}={v}' for k, v in overrides.items())} -- {snakemake_api.TARGET} "
        f"(log {log_file})",
        flush=True,
    )
    with open(log_file, "a", encoding="utf-8") as log_fh:
        log_fh.write(f"\n===== rafi nightly {now_iso()} pid {os.getpid()}\n")
        with snakemake_api.output_to(log_fh) as (console, console_err):
            # A night for some machines runs without Snakemake's directory lock: its own nightly
            # locks keep every other night off these machines' outputs, and Snakemake's file
            # lock cannot be shared (a run that ends removes .snakemake/locks whole, so a run
            # still planning fails to write its lock; docs/operations.md, "Parallel nights").
            outcome = snakemake_api.run(
                paths.directory, cfg, overrides, cores=args.cores, out=console, lock=every
            )
            if not outcome.ok and not outcome.failed:  # it failed before any job: say why
                print(f"rafi nightly: the pipeline cannot be planned: {outcome.error}", file=console_err)
    if outcome.ok and remember:
        write_state(paths, fingerprint(args.config, paths, overrides, scope), scope)
    else:
        clear_state(paths, scope)
    if not every or not outcome.ok:  # else rule fleet_index has written it
        _refresh_fleet_page(paths, getattr(args, "reports_dir", paths.directory / "reports"), args)
    if outcome.nothing_to_do:
        return _nothing_new(paths, machines, started, args.waiting)
    if not outcome.ok and "LockException" in str(outcome.error):
        # a Snakemake run started here between the check above and ours
        print(
            f"rafi nightly: Snakemake's lock in {paths.directory} was taken by another run; exiting "
            f"with {EXIT_LOCKED} (try again later)",
            file=sys.stderr,
        )
        return EXIT_LOCKED
    if not outcome.ok:
        try:  # a disk that filled up during the night is the cause, not the pipeline
            check_writable(paths.results_dir)
        except OSError as exc:
            return _os_error(exc, paths.results_dir)
    qualified = units(load_config(args.directory, args.config, say=False), machines)
    statuses = [machine_status(paths, m, night_start) for m in qualified]
    failures = _failures(paths, qualified, night_start) if not outcome.ok else {}
    code = _report(statuses, pipeline_failed=not outcome.ok, waiting=args.waiting, failures=failures)
    _say_outcomes(args, paths, qualified, night_start)
    failed = ""
    if outcome.failed:
        failed = f" done, {len(outcome.failed)} failed ({', '.join(sorted(set(outcome.failed)))})"
    print(
        f"rafi nightly: {len(outcome.ran)} job(s){failed} in {time.time() - started:.1f} s; "
        f"exit {code} (log {log_file})"
    )
    return code


def _failures(paths: Paths, machines: list[str], since: float) -> dict[str, str]:
    """Machine -> its step that failed tonight in words (:func:`rafi.ops.fleet.failure_words`:
    the step and the one line its job log ended with, e.g. a refused prior)."""
    from rafi.ops.fleet import failure_words, machine_failure

    found = {}
    for m in machines:
        words = failure_words(machine_failure(paths, m, since), paths.directory)
        if words:
            found[m] = words
    return found


def _say_outcomes(args, paths: Paths, machines: list[str], since: float) -> None:
    """The end-of-run lines of the workflow (:mod:`rafi.ops.outcome`), on the terminal: one per
    machine, PASS / FAIL / skipped, the model offered, why it failed, the report."""
    files = RunFiles(
        str(paths.results_dir),
        str(getattr(args, "reports_dir", paths.directory / "reports")),
        str(paths.directory / "logs"),
        since,
        failures_said_below=False,
    )
    skipped = getattr(args, "unmatched", {})
    for line in outcome_lines([(m, None) for m in machines], lambda m, p: read_outcome(m, p, files, skipped)):
        print(line)


def _refresh_fleet_page(paths: Paths, reports_dir: Path, args=None) -> None:
    """Rewrite ``reports/index.html`` after a night for some machines (one line if it cannot
    be written; the night's exit code is not changed). With the project's config (``args``), a
    machine with several probes is listed with its probes' units, as rule fleet_index lists it."""
    from rafi.errors import RafiUserError
    from rafi.ops.fleet import fleet_overview
    from rafi.report.fleet_page import write_fleet_page

    config = None
    if args is not None:
        with contextlib.suppress(OSError, RafiUserError):
            config = load_config(args.directory, args.config, say=False)
    try:
        rows = lambda: fleet_overview(paths, reports_dir, config=config)  # noqa: E731 - read under the lock
        out = write_fleet_page(paths, reports_dir, rows=rows)
    except (OSError, ValueError) as exc:
        print(f"rafi nightly: the fleet overview was not updated: {exc}", file=sys.stderr)
        return
    print(f"rafi nightly: fleet overview {out} updated", flush=True)


def _nothing_new(paths: Paths, machines: list[str], started: float, waiting: dict | None = None) -> int:
    statuses = [machine_status(paths, m, None) for m in machines]
    champs = (
        ", ".join(f"{s.machine} {short_id((s.decision or {}).get('champion_id_after'))}" for s in statuses)
        or "none"
    )
    print(
        f"rafi nightly: nothing new since {last_activity(statuses)}: champion {champs} "
        f"stays ({time.time() - started:.1f} s)"
    )
    return _report(statuses, waiting=waiting)


def _report(
    statuses: list[MachineStatus],
    pipeline_failed: bool = False,
    waiting: dict | None = None,
    failures: dict | None = None,
) -> int:
    """The status line of every machine (with the raw files that wait for the next night, from
    ``waiting``: machine -> count; a machine whose step failed tonight, ``failures``: machine ->
    the step and its line, :func:`_failures`, says so first), then the input summary; returns the
    exit code."""
    codes = {EXIT_PIPELINE_FAILED} if pipeline_failed else set()
    for s in statuses:
        n = (waiting or {}).get(s.machine.split(PROBE_SEPARATOR)[0], 0)  # a probe's machine folder
        wait = (
            f"; {n} new raw file(s) not judged tonight: they wait for the next night (nightly_settle_s)"
            if n
            else ""
        )
        line = s.line()
        failure = (failures or {}).get(s.machine)
        if failure:  # the step and the line that stopped it, before the decision of an earlier night
            last = s.line().split(": ", 1)[1] if s.decision else "none"
            line = f"{s.machine}: FAILED tonight, {failure}; last decision: {last}"
        print("rafi nightly: " + line + wait)
        codes |= s.codes()
    skipped = [s.machine for s in statuses if s.skipped]
    n_files = sum(len(s.quarantined) for s in statuses)
    if skipped or n_files:
        print(
            f"rafi nightly: INPUT REJECTED: {n_files} raw file(s) quarantined"
            + (f", machine(s) skipped: {', '.join(skipped)}" if skipped else "")
            + f" (exit code {EXIT_QUARANTINED} unless a more severe one applies)"
        )
    if pipeline_failed:
        print("rafi nightly: the pipeline FAILED for some job (details in the log)")
    return most_severe(codes)


def main(argv=None) -> int:  # pragma: no cover - `python -m rafi.ops.nightly`
    """``python -m rafi.ops.nightly``: the same as ``rafi nightly``."""
    parser = argparse.ArgumentParser(
        prog="rafi nightly", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
