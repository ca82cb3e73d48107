"""Run settings: the top level of ``config.yaml`` (docs/settings.md)."""

from __future__ import annotations

from rafi.contract.keys import NON_NEGATIVE, Setting

#: Run settings: top level of ``config.yaml`` (``--config key=value`` on the command line).
RUN_SETTINGS: dict[str, Setting] = {
    "raw_dir": Setting(
        default="raw",
        schema={"type": "string", "minLength": 1},
        shown="`raw`",
        doc="folder of the machine folders",
    ),
    "results_dir": Setting(
        default="results",
        schema={"type": "string", "minLength": 1},
        shown="`results`",
        doc="tables, models, registry",
    ),
    "reports_dir": Setting(
        default="reports",
        schema={"type": "string", "minLength": 1},
        shown="`reports`",
        doc="qualification reports",
    ),
    "on_bad_input": Setting(
        default="fail",
        schema={"type": "string", "enum": ["fail", "quarantine"]},
        shown="`fail`",
        doc=(
            "a raw file that cannot be read or fails its checks: `fail` stops the run with the message "
            "(file, line, column); `quarantine` lists it as quarantined and carries on (`rafi nightly`). No "
            "job's params depend on it: both modes share every output, so switching re-runs nothing. In "
            "`fail` mode a file an earlier `quarantine` run set aside stops the run while it is planned."
        ),
    ),
    "nightly_machines": Setting(
        default=None,
        schema={
            "oneOf": [{"type": "null"}, {"type": "string"}, {"type": "array", "items": {"type": "string"}}]
        },
        shown="none (all)",
        doc="set by `rafi nightly --machine`",
    ),
    "nightly_report": Setting(
        default=True,
        schema={"type": ["boolean", "string"]},
        shown="`true`",
        doc="set by `rafi nightly --no-report`",
    ),
    "settle_s": Setting(
        default=0,
        schema=NON_NEGATIVE,
        shown="0",
        doc=(
            "a raw file modified less than this many seconds ago is still being written: it is left out of "
            "this run (listed as waiting) and read by the next one"
        ),
    ),
    "nightly_settle_s": Setting(
        default=600,
        schema=NON_NEGATIVE,
        shown="600",
        doc="the `settle_s` of `rafi nightly` (a logger may still be writing at night)",
    ),
    "debug": Setting(
        default=False,
        schema={"type": ["boolean", "string"]},
        shown="`false`",
        doc="a user error (bad file, bad config) prints its traceback too; `rafi --debug ...` sets it",
    ),
}
