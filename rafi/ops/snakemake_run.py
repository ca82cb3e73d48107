"""``python -m rafi.ops.snakemake_run ARGS``: ``python -m snakemake ARGS`` without the idle second at exit.

``rafi nightly`` runs Snakemake through this. Snakemake's job scheduler (9.x, default
``--max-jobs-per-timespan 100/1s``) starts a one-second ``threading.Timer`` after each job
selection, to wake itself up once the rate limit allows more jobs. Those timers are not
daemon threads, so the interpreter waits for the last one before it exits: about one idle
second after the last job of every run (a night ends with the instant target job
``nightly``, so the whole second is added to the night). Here the timers are daemon threads:
they wake the scheduler exactly as before while it runs and no longer hold the process once
Snakemake is done. Everything else is ``python -m snakemake``.
"""

from __future__ import annotations

import runpy
import sys
import threading


class _DaemonTimer(threading.Timer):
    """A ``threading.Timer`` that does not keep the interpreter alive."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.daemon = True


def main() -> None:
    threading.Timer = _DaemonTimer
    sys.argv[0] = "snakemake"
    runpy.run_module("snakemake", run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    main()
