"""How ``rafi nightly`` drives Snakemake: its Python API, progress from its structured log records.

Snakemake (the range pinned in pyproject.toml) runs in this process through ``snakemake.api``
(``SnakemakeApi`` -> ``workflow`` -> ``dag`` -> ``execute_workflow``). Progress is read from
the log records Snakemake emits for its logger plugins: each carries ``event`` (a
``snakemake_interface_logger_plugins.common.LogEvent``) and that event's fields, as documented
by snakemake-interface-logger-plugins - ``job_info`` (``jobid``, ``rule_name``, ``wildcards``),
``job_finished`` (``job_id``), ``job_error`` (``jobid``, ``rule_name``), ``progress``
(``done``, ``total``), ``run_info`` (``stats``). :class:`ProgressHandler` is a plain
``logging.Handler`` on Snakemake's logger that reads those fields; a logger *plugin* would get
the same records but must be its own installed ``snakemake_logger_plugin_*`` package. No
printed text is parsed and nothing in Snakemake is patched.

The API's default scheduling settings set no job rate limit (the command line's default is
``--max-jobs-per-timespan 100/1s``), so the scheduler starts no wake-up timer that would keep
the process alive for a second after the last job.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

TARGET = "nightly"


@dataclass
class Outcome:
    """What a Snakemake run did.

    Attributes
    ----------
    ok : bool
        Snakemake finished without error.
    planned : dict
        ``{rule: n_jobs}`` of the jobs Snakemake scheduled (target rule left out).
    ran : list of (str, str)
        ``(rule, "k=v, ...")`` of every finished job, target rule left out.
    failed : list of str
        Rules of failed jobs.
    error : str or None
        The exception Snakemake raised, if any (planning errors have no failed job).
    target_scheduled : bool
        The target rule's own job was scheduled.
    """

    ok: bool = True
    planned: dict = field(default_factory=dict)
    ran: list = field(default_factory=list)
    failed: list = field(default_factory=list)
    error: str | None = None
    target_scheduled: bool = False

    @property
    def nothing_to_do(self) -> bool:
        """Snakemake found nothing out of date (no job at all, not even the target's)."""
        return self.ok and not self.planned and not self.ran and not self.target_scheduled


class ProgressHandler(logging.Handler):
    """One line per finished or failed job, from Snakemake's structured log records.

    Parameters
    ----------
    out : text stream or None
        Where the progress lines go (None: collect only).
    target : str
        The target rule; its job is not counted.
    prefix : str
        Start of every printed line.
    """

    def __init__(self, out: TextIO | None = sys.stdout, target: str = TARGET, prefix: str = "rafi nightly: "):
        super().__init__()
        from snakemake_interface_logger_plugins.common import LogEvent

        self._events = LogEvent
        self.out = out
        self.target = target
        self.prefix = prefix
        self.outcome = Outcome()
        self.jobs: dict[int, tuple[str, str]] = {}
        self._failed_ids: set = set()
        self.total: int | None = None

    def _print(self, text: str) -> None:
        if self.out is not None:
            print(self.prefix + text, file=self.out, flush=True)

    def _count(self, total) -> None:
        if total is not None:  # Snakemake counts the target's job too
            self.total = max(int(total) - 1, 0)

    def emit(self, record: logging.LogRecord) -> None:
        ev = self._events
        event = getattr(record, "event", None)
        if event is None:
            return
        if event == ev.RUN_INFO:
            stats = getattr(record, "stats", None) or {}
            if self.total is None:
                self._count(stats.get("total"))
        elif event == ev.JOB_INFO:
            rule = str(getattr(record, "rule_name", "?"))
            wildcards = getattr(record, "wildcards", None) or {}
            wc = ", ".join(f"{k}={v}" for k, v in dict(wildcards).items())
            self.jobs[int(record.jobid)] = (rule, wc)
            if rule == self.target:
                self.outcome.target_scheduled = True
            else:
                self.outcome.planned[rule] = self.outcome.planned.get(rule, 0) + 1
        elif event == ev.JOB_FINISHED:
            rule, wc = self.jobs.get(int(record.job_id), ("?", ""))
            if rule != self.target:
                self.outcome.ran.append((rule, wc))
                total = "?" if self.total is None else str(self.total)
                self._print(f"[{len(self.outcome.ran)}/{total}] done {rule}" + (f" ({wc})" if wc else ""))
        elif event == ev.PROGRESS:
            self._count(getattr(record, "total", None))
        elif event == ev.JOB_ERROR:
            jobid = getattr(record, "jobid", None)
            if jobid is not None and jobid in self._failed_ids:
                return  # some versions report a failed job twice
            self._failed_ids.add(jobid)
            rule = str(getattr(record, "rule_name", "?"))
            self.outcome.failed.append(rule)
            self._print(f"FAILED {rule} (see the Snakemake log)")


@contextlib.contextmanager
def output_to(log: TextIO) -> Iterator[tuple[TextIO, TextIO]]:
    """Send this process's stdout and stderr (file descriptors 1 and 2, so the jobs' output
    too) to ``log``; yield streams on the original stdout and stderr for the progress lines.
    """
    for stream in (sys.stdout, sys.stderr, log):
        stream.flush()
    saved = [os.dup(1), os.dup(2)]
    console_out = os.fdopen(os.dup(saved[0]), "w", buffering=1, encoding="utf-8")
    console_err = os.fdopen(os.dup(saved[1]), "w", buffering=1, encoding="utf-8")
    try:
        os.dup2(log.fileno(), 1)
        os.dup2(log.fileno(), 2)
        yield console_out, console_err
    finally:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError):
                stream.flush()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved:
            os.close(fd)
        console_out.close()
        console_err.close()


def run(
    directory: Path,
    config_file: Path,
    overrides: dict,
    *,
    cores: int,
    dry_run: bool = False,
    target: str = TARGET,
    out: TextIO | None = sys.stdout,
    lock: bool = True,
) -> Outcome:
    """Build ``target`` of the project in ``directory`` with Snakemake (``--rerun-incomplete
    --keep-going``), or only plan it (``dry_run``).

    Parameters
    ----------
    directory : Path
        Project folder (Snakemake's working directory; its ``Snakefile`` if there is one).
    config_file : Path
        The config file (``--configfile``).
    overrides : dict
        ``--config`` values.
    cores : int
        ``--cores``.
    dry_run : bool
        Plan only: nothing is run or written; ``Outcome.planned`` lists the jobs.
    target : str
        Target rule.
    out : text stream or None
        Where the progress lines go.
    lock : bool
        Take Snakemake's directory lock (False: ``--nolock``; only for a night for some
        machines, which holds their nightly locks, see ``rafi.ops.nightly``).

    Returns
    -------
    Outcome
        Never raises for a Snakemake error: ``ok`` is False and ``error`` says why (the full
        report goes to Snakemake's log, i.e. stderr).
    """
    from snakemake.api import SnakemakeApi
    from snakemake.logging import logger
    from snakemake.settings.types import (
        ConfigSettings,
        DAGSettings,
        ExecutionSettings,
        OutputSettings,
        ResourceSettings,
    )

    directory = Path(directory).resolve()
    snakefile = directory / "Snakefile"
    handler = ProgressHandler(None if dry_run else out, target=target)
    try:
        with SnakemakeApi(OutputSettings(dryrun=dry_run, nocolor=True)) as api:
            # added after SnakemakeApi(): newer versions reset the logger's handlers there
            logger.addHandler(handler)
            try:
                workflow = api.workflow(
                    resource_settings=ResourceSettings(cores=cores),
                    config_settings=ConfigSettings(
                        config=dict(overrides),
                        configfiles=[Path(config_file).resolve()],
                        config_args=[f"{k}={v}" for k, v in overrides.items()] or None,
                    ),
                    snakefile=snakefile if snakefile.exists() else None,
                    workdir=directory,
                )
                dag = workflow.dag(DAGSettings(targets={target}, force_incomplete=not dry_run))
                dag.execute_workflow(
                    executor="dryrun" if dry_run else "local",
                    execution_settings=ExecutionSettings(keep_going=True, lock=lock),
                )
            except Exception as exc:  # Snakemake's errors have no common base class
                api.print_exception(exc)
                handler.outcome.ok = False
                handler.outcome.error = f"{type(exc).__name__}: {exc}"
    finally:
        logger.removeHandler(handler)
    return handler.outcome
