"""Shared glue of the workflow scripts: logging into the rule's log file, API calls.

Each script does::

    from _glue import step
    with step(snakemake) as log:
        ...            # read inputs, call the rafi function, write outputs atomically

Inside the block stdout, stderr and the ``logging`` module go to ``snakemake.log[0]``,
so ``print`` lines are progress lines of the log. A failure ends the log with one line,
``RAFI <rule> (<wildcards>) failed: <message>``, which the Snakefile's ``onerror`` repeats as the
last thing the user reads (``say_failures`` in common.smk). A user error (a bad file or a bad
configuration: :class:`rafi.errors.RafiUserError`) ends the script with exit status 1 and no
traceback anywhere (its message names the file, line and column); with run setting
``debug: true`` it is re-raised like any other exception, whose traceback goes to the log and
whose one line also goes to the terminal. Either way the job fails, and Snakemake adds its own
block (``Error in rule ...``) with the log.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pandas as pd


def debug_wanted(config) -> bool:
    """Run setting ``debug`` (``--config debug=true``): user errors keep their traceback."""
    from rafi.settings import run_settings, truthy

    try:
        return truthy(run_settings(config)["debug"])
    except Exception:  # an unusable config was refused while planning; be quiet here
        return False


def wildcards_text(smk) -> str:
    """The job's wildcards as its log lines name them (``machine=m, probe=p``)."""
    return ", ".join(f"{k}={v}" for k, v in smk.wildcards.items())


def warn(smk, step_name: str, message: str) -> None:
    """Print ``message`` as a warning line of the job's log
    (:func:`rafi.ops.run_messages.warning_line`): the end-of-run lines and ``rafi nightly``
    repeat it under the machine's line."""
    from rafi.ops.run_messages import warning_line

    print(warning_line(step_name, wildcards_text(smk), message), flush=True)


@contextlib.contextmanager
def step(smk):
    """Run a script body with all output redirected to the rule's log file."""
    log_file = Path(smk.log[0])
    log_file.parent.mkdir(parents=True, exist_ok=True)
    terminal = sys.__stderr__
    started = time.perf_counter()
    with (
        open(log_file, "w", encoding="utf-8", buffering=1) as fh,
        contextlib.redirect_stdout(fh),
        contextlib.redirect_stderr(fh),
    ):
        logging.basicConfig(
            stream=fh,
            level=logging.INFO,
            force=True,
            format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        )
        log = logging.getLogger(f"rafi.workflow.{smk.rule}")
        wildcards = wildcards_text(smk)
        print(f"[{smk.rule}] {wildcards}", flush=True)
        try:
            yield log
        except BaseException as exc:
            from rafi.errors import RafiUserError, bound_message
            from rafi.ops.run_messages import failure_line

            line = failure_line(smk.rule, wildcards, bound_message(exc, 2000))
            if isinstance(exc, RafiUserError) and not debug_wanted(smk.config):
                # bad input: its message says it all (file, line, column); no traceback
                print(line, flush=True)
                raise SystemExit(1) from None
            log.exception("rule %s failed", smk.rule)
            print(f"{line}\n  (details: {log_file})", file=terminal, flush=True)
            raise
        print(f"[{smk.rule}] done in {time.perf_counter() - started:.1f} s", flush=True)


def part(smk, name: str) -> SimpleNamespace:
    """One step of a rule that runs several steps in one process (rules method and
    report_figures), for :func:`step`: the step's own log (the rule's log named ``name``) and
    name, so its log file and its error line read as those of a rule of its own."""
    return SimpleNamespace(
        log=[getattr(smk.log, name)], rule=name, wildcards=smk.wildcards, config=smk.config
    )


def read_runs(smk) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Read ``runs.csv`` and ``runs.parquet`` (inputs ``table`` and ``frame``)."""
    table = pd.read_csv(smk.input.table)
    frame = pd.read_parquet(smk.input.frame)
    print(f"read {smk.input.table}: {len(table)} runs; {smk.input.frame}: {len(frame)} rows", flush=True)
    return table, frame


def as_table(obj) -> pd.DataFrame:
    """A DataFrame with any named index moved into columns (CSV tables carry no index)."""
    frame = obj if isinstance(obj, pd.DataFrame) else pd.DataFrame(obj)
    if any(name is not None for name in frame.index.names):
        frame = frame.reset_index()
    return frame
