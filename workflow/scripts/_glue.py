"""Shared glue of the workflow scripts: logging into the rule's log file, API calls.

Each script does::

    from _glue import step
    with step(snakemake) as log:
        ...            # read inputs, call the rafi function, write outputs atomically

Inside the block stdout, stderr and the ``logging`` module go to ``snakemake.log[0]``,
so ``print`` lines are progress lines of the log. An exception is written to the log
with its traceback and, as one line, to the terminal, then re-raised (the job fails).
"""

from __future__ import annotations

import contextlib
import logging
import sys
import time
from pathlib import Path

import pandas as pd


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
        wildcards = ", ".join(f"{k}={v}" for k, v in smk.wildcards.items())
        print(f"[{smk.rule}] {wildcards}", flush=True)
        try:
            yield log
        except BaseException as exc:
            log.exception("rule %s failed", smk.rule)
            print(
                f"RAFI {smk.rule} ({wildcards}) failed: {exc}\n  (details: {log_file})",
                file=terminal,
                flush=True,
            )
            raise
        print(f"[{smk.rule}] done in {time.perf_counter() - started:.1f} s", flush=True)


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
