"""Per-machine settings of ``rafi record`` (recording a qualification test): ``record``."""

from __future__ import annotations

from rafi.contract.keys import OPTIONAL_PORT, POSITIVE, Section, Setting

#: A node id, or ``{node, scale, offset}`` (value = raw * scale + offset).
_NODE_OR_SCALED: dict = {
    "oneOf": [
        {"type": "null"},
        {"type": "string", "minLength": 1},
        {
            "type": "object",
            "additionalProperties": False,
            "required": ["node"],
            "properties": {
                "node": {"type": "string", "minLength": 1},
                "scale": {"type": "number", "not": {"const": 0}},
                "offset": {"type": "number"},
            },
        },
    ]
}

RECORD_SETTINGS: dict = {
    "record": Section(
        doc="`rafi record`: recording a qualification test into raw/<machine>/ (docs/record.md)",
        keys={
            "displacement": Setting(
                default=None,
                schema=_NODE_OR_SCALED,
                shown="none",
                doc=(
                    "the OPC UA node of the displacement probe, in um after scaling: a node id or "
                    "`{node, scale, offset}` (um = raw * scale + offset; a probe in mm: scale 1000); the "
                    "speed and temperatures come from `deploy.opcua.inputs`. None: recording from OPC UA is"
                    " refused (`--follow` reads `disp_um` from the DAQ's file)"
                ),
            ),
            "speed_command": Setting(
                default=None,
                schema={"oneOf": [{"type": "null"}, {"type": "string", "minLength": 1}]},
                shown="none (no writes)",
                doc=(
                    "the node `rafi record --plan` writes each step's speed to (r/min, a Double or Float "
                    "the NC program reads); none: nothing is ever written and `--plan` is refused"
                ),
            ),
            "max_file_s": Setting(
                default=86400,
                schema=POSITIVE,
                shown="86400 (1 day)",
                doc=(
                    "a recording longer than this (s) is closed and continued in a new file, so that no "
                    "file waits for days before the pipeline may read it"
                ),
            ),
            "metrics_port": Setting(
                default=None,
                schema=OPTIONAL_PORT,
                shown="none",
                doc=(
                    "`rafi record` serves Prometheus metrics on this TCP port; none: no metrics "
                    "(docs/service.md, Metrics)"
                ),
            ),
            "metrics_address": Setting(
                default="127.0.0.1",
                schema={"type": "string", "minLength": 1},
                shown="127.0.0.1",
                doc="the address the recording's metrics are served on (0.0.0.0: every interface)",
            ),
        },
    ),
}
