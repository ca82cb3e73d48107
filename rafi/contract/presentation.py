"""Per-machine settings of the report and of the model on the machine: ``report``, ``deploy``."""

from __future__ import annotations

from rafi.contract.keys import (
    FLAG,
    NON_NEGATIVE,
    OPTIONAL_PORT,
    OPTIONAL_TEXT,
    POSITIVE,
    RANGE,
    Section,
    Setting,
)

PRESENTATION_SETTINGS: dict = {
    "report": Section(
        doc="the qualification report (docs/report.md)",
        keys={
            "figure_format": Setting(
                default="png",
                schema={"enum": ["png", "svg"]},
                shown="`png`",
                doc="`png` or `svg`",
            ),
            "coolant_sensors": Setting(
                default=[],
                schema={
                    "type": "array",
                    "items": {"type": "string", "pattern": "^T([1-9]|1[0-6])$"},
                    "uniqueItems": True,
                },
                shown="`[]`",
                doc=(
                    "sensors the report draws and names as coolant (the paper's rig: `[T13]`, the coolant "
                    "inlet)"
                ),
            ),
            "ambient_sensor": Setting(
                default=None,
                schema={"oneOf": [{"type": "null"}, {"type": "string", "pattern": "^T([1-9]|1[0-6])$"}]},
                shown="none",
                doc=(
                    "the sensor in the room air: the test record's ambient temperature (min, max, drift per "
                    "log); none: the record says it was not measured"
                ),
            ),
            "paper_rig": Setting(
                default=False,
                schema=FLAG,
                shown="`false`",
                doc=(
                    "the machine is the paper's rig: the paper's numbers (Tables 1, 3, 4, the "
                    "multi-condition run) are shown beside this machine's; otherwise they are left out"
                ),
            ),
            "document": Section(
                doc="the sign-off block on the first page (the keys below)",
                shown="(block)",
                keys={
                    "number": Setting(
                        default=None,
                        schema=OPTIONAL_TEXT,
                        shown="none",
                        doc=(
                            "the sign-off block on the first page: the document number; left out, a blank "
                            "line to fill in by hand"
                        ),
                    ),
                    "prepared_by": Setting(
                        default=None,
                        schema=OPTIONAL_TEXT,
                        shown="none",
                        doc="who prepared the report; left out, a blank line to sign",
                    ),
                    "approved_by": Setting(
                        default=None,
                        schema=OPTIONAL_TEXT,
                        shown="none",
                        doc="who approved it; left out, a blank line to sign",
                    ),
                    "approved_date": Setting(
                        default=None,
                        schema=OPTIONAL_TEXT,
                        shown="none",
                        doc="the approval date; left out, a blank line",
                    ),
                },
            ),
            "instruments": Section(
                doc="the test conditions of the test record (the keys below); shown when given",
                shown="(block)",
                keys={
                    "machine_serial": Setting(
                        default=None,
                        schema=OPTIONAL_TEXT,
                        shown="none",
                        doc="the machine's serial number (test record); missing ones are listed in a warning",
                    ),
                    "controller": Setting(
                        default=None,
                        schema=OPTIONAL_TEXT,
                        shown="none",
                        doc="the controller (test record)",
                    ),
                    "probe": Setting(
                        default=None,
                        schema=OPTIONAL_TEXT,
                        shown="none",
                        doc="the displacement probe: make, model, resolution (test record)",
                    ),
                    "sensor_positions": Setting(
                        default={},
                        schema={
                            "type": "object",
                            "propertyNames": {"pattern": "^T([1-9]|1[0-6])$"},
                            "additionalProperties": {"type": "string"},
                        },
                        shown="`{}`",
                        doc="sensor -> where it sits (e.g. `T8: rear spindle bearing`)",
                    ),
                    "calibration": Setting(
                        default={},
                        schema={"type": "object", "additionalProperties": {"type": "string"}},
                        shown="`{}`",
                        doc="instrument -> calibration date (ISO 8601)",
                    ),
                },
            ),
        },
    ),
    "deploy": Section(
        doc="the model on the machine (docs/deploy.md)",
        keys={
            "clamp_um": Setting(
                default=[-50.0, 50.0],
                schema=RANGE,
                shown="[-50, 50]",
                doc=(
                    "the command sent to the controller never leaves this range (um) (docs/deploy.md, Limits"
                    " and faults)"
                ),
                limit=True,
                replay=True,
            ),
            "rate_um_per_s": Setting(
                default=0.2,
                schema=POSITIVE,
                shown="0.2",
                doc="nor changes faster than this (um/s)",
                limit=True,
                replay=True,
            ),
            "temp_valid_c": Setting(
                default=[-10.0, 70.0],
                schema=RANGE,
                shown="[-10, 70]",
                doc="a temperature outside this range (degC) is a sensor fault",
                limit=True,
                replay=True,
            ),
            "stuck_s": Setting(
                default=1800,
                schema=POSITIVE,
                shown="1800",
                doc="a sensor whose reading has not changed for this long (s) ...",
                limit=True,
                replay=True,
            ),
            "stuck_change_k": Setting(
                default=0.5,
                schema=POSITIVE,
                shown="0.5",
                doc="... while another sensor the model reads moved by this much (K) is stuck",
                limit=True,
                replay=True,
            ),
            "range_margin_k": Setting(
                default=2.0,
                schema=NON_NEGATIVE,
                shown="2.0",
                doc="outside the trained range: a rise beyond its training range by more than this (K) ...",
                limit=True,
                replay=True,
            ),
            "speed_margin_rpm": Setting(
                default=500,
                schema=NON_NEGATIVE,
                shown="500",
                doc="... or a speed above the trained speeds by more than this (r/min)",
                limit=True,
                replay=True,
            ),
            "hold_s": Setting(
                default=600,
                schema=NON_NEGATIVE,
                shown="600",
                doc="on a fault or outside the trained range the last good value is held this long (s) ...",
                limit=True,
                replay=True,
            ),
            "safe_um": Setting(
                default=0.0,
                schema={"type": "number"},
                shown="0.0",
                doc="... then the command ramps to this value (um) ...",
                limit=True,
                replay=True,
            ),
            "ramp_um_per_s": Setting(
                default=0.02,
                schema=POSITIVE,
                shown="0.02",
                doc="... at this rate (um/s)",
                limit=True,
                replay=True,
            ),
            "interval_s": Setting(
                default=5,
                schema=POSITIVE,
                shown="5",
                doc="the live loop writes every this many seconds",
                limit=True,
                replay=True,
            ),
            "max_interval_um": Setting(
                default=None,
                schema={"oneOf": [{"type": "null"}, {"type": "number", "exclusiveMinimum": 0}]},
                shown="none",
                doc=(
                    "a fault (`interval_wide`, held and ramped like the others) while the model's prediction "
                    "interval is wider than this (um, upper - lower; the artefact's `interval` block); none: "
                    'off (docs/deploy.md "Limits and faults")'
                ),
                limit=True,
                replay=True,
            ),
            "target": Setting(
                default=None,
                schema={"oneOf": [{"type": "null"}, {"type": "object"}]},
                shown="none",
                doc=(
                    "the controller written to by `rafi deploy`; none: replay only. `kind` (`sinumerik`, "
                    "`csv`, `jsonl`) and `axis` (sinumerik: `name`, `number`, `sign`, `limit_um` required, "
                    "no default; `mode`, `ref_position_mm`, `measured_at_mm`, `max_velocity_mm_min`); "
                    "sinumerik: `int_incr_per_mm`, `comp_add_velo_factor`, `ipo_cycle_s`, `node_template`, "
                    "`skip_unchanged`; csv/jsonl: `path`, `fsync_each_line` (docs/deploy-targets.md, "
                    'docs/deploy.md "Live: OPC UA"; checked by `rafi.deploy.live.build_target`)'
                ),
            ),
            "opcua": Setting(
                default=None,
                schema={"oneOf": [{"type": "null"}, {"type": "object"}]},
                shown="none",
                doc=(
                    "the OPC UA connection of `rafi deploy`: `endpoint` (required), `inputs` (`speed_rpm`, "
                    "the machine's sensors: a node id or `{node, scale, offset}`), `node_prefix`, "
                    "`credentials_file`, "
                    "`timeout_s`, `reconnect_min_s`, `reconnect_max_s`; security: `security_policy` (none, "
                    "`Basic256Sha256`, `Aes128_Sha256_RsaOaep`, `Aes256_Sha256_RsaPss`), `security_mode` "
                    "(`SignAndEncrypt`, `Sign`), `certificate`, `private_key`, and whom to trust: "
                    "`server_certificate`, `trust_dir`, `server_fingerprint`; `allow_insecure` (a password "
                    'without encryption) (docs/deploy.md "Live: OPC UA", "Security"; checked by '
                    "`rafi.deploy.opcua_client.opcua_settings`). Never a user or password: those come from "
                    "the environment or a file outside the repository, and are refused here"
                ),
            ),
            "metrics_port": Setting(
                default=None,
                schema=OPTIONAL_PORT,
                shown="none",
                doc=(
                    "`rafi deploy` serves Prometheus metrics on this TCP port (127.0.0.1 unless "
                    "`metrics_address`); none: no metrics (docs/service.md, Metrics)"
                ),
            ),
            "metrics_address": Setting(
                default="127.0.0.1",
                schema={"type": "string", "minLength": 1},
                shown="127.0.0.1",
                doc="the address the metrics are served on (0.0.0.0: every interface)",
            ),
            "champion_check_s": Setting(
                default=60,
                schema=POSITIVE,
                shown="60",
                doc=(
                    "`rafi deploy` looks this often (s) whether `rafi nightly` promoted a new champion, "
                    "and ramps to it (docs/deploy.md, Transitions)"
                ),
            ),
            "cold_band_k": Setting(
                default=0.5,
                schema=POSITIVE,
                shown="0.5",
                doc=(
                    "`rafi deploy` started again keeps the stored session's reference unless the machine "
                    "is cold: every sensor the model reads at most this much (K) above its temperature in "
                    'that reference (docs/deploy.md, "A restart")'
                ),
            ),
            "session_max_age_h": Setting(
                default=24,
                schema=POSITIVE,
                shown="24",
                doc=(
                    "... and unless the stored session is older than this (h): the shop's temperature "
                    "may have moved since, so the reference is captured anew"
                ),
            ),
            "replay_roles": Setting(
                default=["validation_single", "validation_multi", "validation_idle"],
                schema={
                    "type": "array",
                    "items": {
                        "enum": ["training", "validation_single", "validation_multi", "validation_idle"]
                    },
                    "uniqueItems": True,
                },
                shown="`[validation_single, validation_multi, validation_idle]`",
                doc=(
                    "the report replays the runs of these roles through the compensator with the limits in "
                    "force (every validation run: the verdict says where the limits leave more than the "
                    "model alone; a replay costs about a second per run)"
                ),
                replay=True,
            ),
        },
    ),
}
