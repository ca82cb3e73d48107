"""Per-machine settings of the input and the paper's method: ``input`` ... ``fuzzy`` (docs/settings.md)."""

from __future__ import annotations

from rafi.contract.input import INPUT_SCHEMA
from rafi.contract.keys import FLAG, NON_NEGATIVE, POSITIVE, Section, Setting

METHOD_SETTINGS: dict = {
    "input": Setting(
        default={},
        schema=INPUT_SCHEMA,
        shown="native format",
        doc=(
            "how the raw files are found and read: `docs/raw-format.md` (`format`, `pattern`, `sheet`, "
            "`delimiter`, `decimal`, `encoding`, `header_row`, `skip_rows`, `sensors`, `columns`, `time`, "
            "`speed`, `sample_period_s`, `displacement`, `probes`, `join`, `temperature_unit`, "
            "`keep_extra`). The machine's sensors: `sensors` (1 to 64 names), else the sensor keys of "
            "`columns`, else T1..T16; several displacement probes: `probes` (name -> column, unit, sign, "
            "description), each qualified as `<machine>@<probe>`. A log without a time "
            "column: `time: {kind: none, period_s: ...}` (row k at `time.start + k * period_s`); without a "
            "speed column: `speed.constant_rpm` and/or `speed.constant_rpm_by_file` (glob on the file name "
            '-> r/min); raw-format.md, "Logs without a time or speed column"'
        ),
    ),
    "sample_period_s": Setting(
        default=5,
        schema=POSITIVE,
        shown="5",
        doc=(
            "the logger's sample period (s); with `input.time.kind: none` it must equal `input.time.period_s`"
        ),
    ),
    "training_speeds_rpm": Setting(
        default=[3000, 6000, 9000, 12000, 15000, 18000],
        schema={
            "type": "array",
            "items": {"type": "number", "exclusiveMinimum": 0},
            "minItems": 1,
            "uniqueItems": True,
        },
        shown="3000 ... 18000 (6 speeds)",
        doc="speeds with a regression each",
    ),
    "speed_tolerance_rpm": Setting(
        default=50,
        schema=NON_NEGATIVE,
        shown="50",
        doc="\\|speed - training speed\\| within this -> that training speed",
    ),
    "checks": Section(
        doc='plausibility checks of the raw files (docs/raw-format.md, "Checks")',
        keys={
            "probe_sign": Setting(
                default="auto",
                schema={"type": "string", "enum": ["auto", "positive", "negative"]},
                shown="`auto`",
                doc=(
                    "expected sign of the displacement while the machine warms up: `positive` (the spindle "
                    "grows towards the table), `negative`, or `auto` (the sign of most of the machine's "
                    "other files; positive when there are none); [raw-format.md](raw-format.md#checks)"
                ),
            ),
            "confirmed": Setting(
                default=[],
                schema={
                    "type": "array",
                    "items": {
                        "type": "object",
                        "properties": {
                            "file": {"type": "string", "minLength": 1},
                            "check": {"type": "string", "minLength": 1},
                        },
                        "required": ["file", "check"],
                        "additionalProperties": False,
                    },
                },
                shown="none",
                doc=(
                    "warnings a person has looked at: a list of `{file: <name or glob>, check: <check id>}`;"
                    " a confirmed warning no longer blocks promotion and the report says who confirmed what"
                ),
            ),
        },
    ),
    "clean": Section(
        doc="how the raw logs are cleaned onto the sample grid",
        keys={
            "max_interpolate_gap_s": Setting(
                default=60,
                schema=NON_NEGATIVE,
                shown="60",
                doc="gaps up to this are interpolated; longer ones split the log into segments",
            ),
            "spike_threshold": Setting(
                default=8,
                schema=POSITIVE,
                shown="8",
                doc=(
                    "robust z-score (MAD of first differences) beyond which a sample, or a burst "
                    "of at most 3, is a spike"
                ),
            ),
            "open_circuit_values": Setting(
                default=[-999.0, 999.9, 850.0],
                schema={"type": "array", "items": {"type": "number"}},
                shown="-999.0, 999.9, 850.0",
                doc="values a logger writes for a broken sensor",
            ),
        },
    ),
    "runs": Section(
        doc='how the clean logs are cut into runs and given roles (docs/raw-format.md, "Segmentation")',
        keys={
            "idle_below_rpm": Setting(
                default=100,
                schema=NON_NEGATIVE,
                shown="100",
                doc="below this the spindle stands",
            ),
            "min_run_s": Setting(
                default=1800,
                schema=NON_NEGATIVE,
                shown="1800",
                doc="shorter runs are excluded (reported, not used)",
            ),
            "min_constant_s": Setting(
                default=3600,
                schema=NON_NEGATIVE,
                shown="3600",
                doc="a constant-speed stretch shorter than this is part of a varying run",
            ),
            "max_leading_rest_s": Setting(
                default=300,
                schema=NON_NEGATIVE,
                shown="300",
                doc="an idle stretch shorter than this at a log/segment start is the run's rest before start",
            ),
            "overrides": Setting(
                default={},
                schema={
                    "type": "object",
                    "additionalProperties": {
                        "type": "string",
                        "enum": [
                            "training",
                            "validation_single",
                            "validation_multi",
                            "validation_idle",
                            "excluded",
                        ],
                    },
                },
                shown="none",
                doc=(
                    "file stem or run id (`<stem>#3`, see the run ids in `runs.csv` or the report's "
                    "segmentation section) -> role (`training`, `validation_single`, `validation_multi`, "
                    "`validation_idle`, `excluded`); wins over windows and the automatic role"
                ),
            ),
            "windows": Setting(
                default=[],
                schema={
                    "type": "array",
                    "items": {
                        "type": "object",
                        "properties": {
                            "role": {"type": "string", "enum": ["training", "validation", "excluded"]},
                            "start": {"type": ["number", "string"]},
                            "end": {"type": ["number", "string"]},
                            "unit": {"type": "string", "enum": ["elapsed_s", "fraction", "time"]},
                            "log": {"type": "string", "description": "glob on the file name"},
                        },
                        "required": ["role"],
                        "additionalProperties": False,
                    },
                },
                shown="none",
                doc=(
                    "roles by time: a list of `{role: training/validation/excluded, start, end, unit: "
                    "elapsed_s/fraction/time, log: <glob>}`; runs are cut at the boundaries "
                    "([raw-format.md](raw-format.md#segmentation-runs-and-roles))"
                ),
            ),
            "idle_training": Setting(
                default="schedule",
                schema={"enum": [False, "schedule", True]},
                shown="schedule",
                doc=(
                    "which idle cool-downs are training runs for the family's models (RAFI as published "
                    "ignores them): `schedule` those of the training schedule (an automatic cool-down "
                    "followed by a training run of its log before any validation data, and every idle "
                    "run in a training window); `true` also every other automatic cool-down before "
                    "validation data; `false` none (idle runs in a training window are excluded) "
                    "([raw-format.md](raw-format.md#segmentation-runs-and-roles))"
                ),
            ),
            "allow_training_after_validation": Setting(
                default=False,
                schema=FLAG,
                shown="`false`",
                doc=(
                    "accept configured training data that lies after, or overlaps, validation data of the "
                    "same log; the leak guard refuses it otherwise, and the report says when it was allowed"
                ),
            ),
        },
    ),
    "reference": Section(
        doc="the reference state the rises are measured from",
        keys={
            "rule": Setting(
                default="run_start",
                schema={"type": "string", "enum": ["run_start", "log_start"]},
                shown="`run_start`",
                doc=(
                    "reference state: `run_start` (median of the run's first `window_s`) or `log_start` (of "
                    "the log/segment the run came from)"
                ),
            ),
            "window_s": Setting(
                default=60,
                schema=POSITIVE,
                shown="60",
                doc="length of the reference window (s)",
            ),
        },
    ),
    "equilibrium": Section(
        doc="time to thermal equilibrium (paper Table 1)",
        keys={
            "band_fraction": Setting(
                default=0.05,
                schema={"type": "number", "exclusiveMinimum": 0, "exclusiveMaximum": 1},
                shown="0.05",
                doc="within 5 % of the total rise of the final plateau",
            ),
            "plateau_window_s": Setting(
                default=900,
                schema=POSITIVE,
                shown="900",
                doc="final plateau = median of the last 15 min",
            ),
            "smooth_window_s": Setting(
                default=300,
                schema=POSITIVE,
                shown="300",
                doc="rolling median before the band test",
            ),
        },
    ),
    "rank": Section(
        doc="the key-sensor ranking",
        keys={
            "threshold": Setting(
                default=0.97,
                schema={"type": "number", "minimum": 0, "maximum": 1},
                shown="0.97",
                doc="\\|r\\| a key sensor must reach",
            ),
            "max_key_sensors": Setting(
                default=3,
                schema={"type": "integer", "minimum": 1, "maximum": 16},
                shown="3",
                doc="at most this many key sensors",
            ),
            "scope": Setting(
                default="min_per_speed",
                schema={"type": "string", "enum": ["min_per_speed", "pooled"]},
                shown="`min_per_speed`",
                doc="`min_per_speed` (the smallest \\|r\\| over the training speeds must pass) or `pooled`",
            ),
            "min_coverage": Setting(
                default=0.9,
                schema={"type": "number", "exclusiveMinimum": 0, "maximum": 1},
                shown="0.9",
                doc="a sensor must be present in 90 % of the samples",
            ),
        },
    ),
    "fit": Section(
        doc="the per-speed OLS regressions",
        keys={
            "terms": Setting(
                default=[
                    "1",
                    "x1",
                    "x2",
                    "x3",
                    "x1*x2",
                    "x1*x3",
                    "x2*x3",
                    "x1^2",
                    "x2^2",
                    "x3^2",
                    "x1*x2*x3",
                ],
                schema={
                    "type": "array",
                    "items": {
                        "type": "string",
                        "pattern": "^(1|x[0-9]+(\\^[0-9]+)?(\\*x[0-9]+(\\^[0-9]+)?)*)$",
                    },
                    "minItems": 1,
                    "uniqueItems": True,
                },
                shown="the paper's 11 terms",
                doc="regression terms (`1`, `x1`, `x1*x2`, `x1^2`, ...)",
            ),
            "hac_maxlags": Setting(
                default=60,
                schema={"type": "integer", "minimum": 0},
                shown="60",
                doc="Newey-West lags (samples) of the HAC standard errors",
            ),
        },
    ),
    "fuzzy": Section(
        doc="the triangular blending between speeds",
        keys={
            "outside": Setting(
                default="edge",
                schema={"type": "string", "enum": ["edge"]},
                shown="`edge`",
                doc="outside the trained speeds: the edge model, samples flagged",
            ),
        },
    ),
}
