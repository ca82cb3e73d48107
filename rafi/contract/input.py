"""The ``input:`` mapping of a machine: its formats, defaults and JSON schema (docs/raw-format.md)."""

from __future__ import annotations

#: Formats of the raw files (docs/raw-format.md).
FORMATS = ("native", "csv", "xlsx")

#: Defaults of the ``input:`` mapping (``pattern`` defaults by format).
INPUT_DEFAULTS: dict = {
    "format": "native",
    "pattern": None,
    "sheet": 0,
    "delimiter": ",",
    "decimal": ".",
    "encoding": "utf-8",
    "header_row": 1,
    "skip_rows": 0,
    "missing_values": [],
    "footer_rows": 0,
    "sensors": None,
    "columns": {},
    "time": {
        "kind": "timestamp",
        "start": None,
        "format": None,
        "period_s": None,
        "date_column": None,
        "date_from_name": None,
        "timezone": None,
    },
    "speed": {"constant_rpm": None, "constant_rpm_by_file": {}},
    "sample_period_s": None,
    "displacement": {"column": None, "unit": "um", "sign": 1},
    "probes": {},
    "temperature_unit": "C",
    "keep_extra": True,
    "join": None,
}

#: Longest text of ``input.missing_values`` (a logger's marker for a cell without a value: ``---``,
#: ``#N/A``, ``NaN``, ``ERR``).
MISSING_VALUE_MAX_CHARS = 32

#: ``input.header_row`` of a file without a header row (YAML ``none`` or ``null``): the columns
#: are then given by letter or 1-based position.
NO_HEADER = "none"

#: Defaults of ``input.join`` (docs/raw-format.md, "Temperatures and displacement in two files"):
#: the partner of a raw file is the file named with ``replace[0]`` replaced by ``replace[1]``;
#: the canonical ``columns`` come from it, matched ``by`` time or row; ``input`` overrides the
#: machine's layout keys for the partner; a share of rows above ``max_unmatched`` without a
#: partner row (``by: time``) is an error.
JOIN_DEFAULTS: dict = {
    "replace": None,
    "by": "time",
    "columns": ["disp_um"],
    "max_unmatched": 0.02,
    "input": {},
}

#: ``input.join.by``: match the partner's rows by their time (within half a sample period) or
#: by their order (equal numbers of rows).
JOIN_BY = ("time", "row")

#: Keys of the machine's ``input:`` that ``input.join.input`` may override for the partner file.
JOIN_LAYOUT_KEYS = (
    "format",
    "sheet",
    "delimiter",
    "decimal",
    "encoding",
    "header_row",
    "skip_rows",
    "missing_values",
    "footer_rows",
    "columns",
    "time",
    "displacement",
    "temperature_unit",
)

DEFAULT_PATTERN = {"native": "*.csv", "csv": "*.csv", "xlsx": "*.xlsx"}

#: ``input.time.kind``: a column of timestamps, a column of elapsed seconds (or minutes, or hours),
#: a clock written as a number from a fixed origin (Unix seconds or milliseconds, Excel's serial
#: day numbers), or no time column (row k of the file at ``start + k * period_s``).
TIME_KINDS = (
    "timestamp",
    "elapsed_s",
    "elapsed_min",
    "elapsed_h",
    "epoch_s",
    "epoch_ms",
    "excel_days",
    "none",
)

#: Seconds per unit of an elapsed time column (``input.time.kind`` ``elapsed_*``).
ELAPSED_SECONDS = {"elapsed_s": 1.0, "elapsed_min": 60.0, "elapsed_h": 3600.0}

#: A clock written as a number: per ``input.time.kind``, its origin (naive, the logger's own time;
#: Unix time is UTC) and seconds per unit. Such a log has dates; ``time.start`` is not read.
EPOCH_CLOCKS = {
    "epoch_s": ("1970-01-01T00:00:00", 1.0),
    "epoch_ms": ("1970-01-01T00:00:00", 0.001),
    "excel_days": ("1899-12-30T00:00:00", 86400.0),
}

#: ``input.time.date_from_name``: a log's date in its file name (``strftime`` codes: ``%Y``, ``%y``,
#: ``%m``, ``%b``, ``%B``, ``%d``), its rows the time of day. A time of day more than this many
#: seconds before the row above is on the next day (the log ran over midnight); a smaller step
#: back stays a step back (a clock reset).
DATE_FROM_NAME_ROLLOVER_S = 12 * 3600.0

#: ``input.temperature_unit``: degrees Celsius, kelvin or degrees Fahrenheit (converted to deg C).
TEMPERATURE_UNITS = ("C", "K", "F")

#: ``input.time.start`` left out (``None``) with ``elapsed_s`` or ``none``: the log has no clock.
#: Its times are counted from this instant for the arithmetic only (never shown as a date): the
#: frame's ``attrs['metadata']['clock']`` is ``False``, the runs have no clock time and the report
#: shows hours since the log's first sample.
NO_CLOCK_EPOCH = "2000-01-01T00:00:00"

#: Keys meaningful for the native format (everything else is for csv/xlsx).
NATIVE_KEYS = {"format", "pattern", "sample_period_s", "sensors", "missing_values"}

#: The temperature sensors of a machine that names none: the paper's rig, ``T1`` .. ``T16``.
DEFAULT_SENSORS = tuple(f"T{i}" for i in range(1, 17))

#: How many temperature sensors a machine may have.
MAX_SENSORS = 64

#: A sensor name: a letter, then letters, digits or ``_`` (it names a column, its rise ``d<name>``,
#: an OPC UA input and a model term).
SENSOR_NAME_RE = "^[A-Za-z][A-Za-z0-9_]{0,31}$"

#: Column names of the clean and runs tables that a sensor may not take.
RESERVED_NAMES = ("time", "speed_rpm", "disp_um", "t_s", "dz_um", "log", "log_t_s", "segment", "run_id")

#: Keys of ``input.columns`` that are not sensors.
NON_SENSOR_COLUMNS = ("time", "speed_rpm", "disp_um")

CANONICAL_RE = SENSOR_NAME_RE

#: A displacement probe's name (``input.probes``): X, Y, Z, ch1, ... It names the probe's results
#: (``results/<machine>@<probe>/``), its model, its registry and its report section.
PROBE_NAME_RE = "^[A-Za-z][A-Za-z0-9_]{0,15}$"

#: Between a machine's name and a probe's in the name of the probe's results: ``fl-thermal@ch1``.
PROBE_SEPARATOR = "@"

#: The keys of one probe of ``input.probes`` (``unit`` and ``sign`` default to ``displacement``'s).
PROBE_KEYS = ("column", "unit", "sign", "description")

#: JSON schema (draft 7) of one ``input:`` mapping; the workflow's config schema embeds it.
#: It carries no ``default`` keywords on purpose: a validator that fills defaults in would
#: add csv/xlsx keys to native mappings. Defaults live in :data:`INPUT_DEFAULTS`.
INPUT_SCHEMA: dict = {
    "type": "object",
    "additionalProperties": False,
    "properties": {
        "format": {"enum": list(FORMATS)},
        "pattern": {
            "oneOf": [
                {"type": "string", "minLength": 1},
                {"type": "array", "items": {"type": "string", "minLength": 1}, "minItems": 1},
            ]
        },
        "sheet": {"type": ["string", "integer"], "minLength": 1, "minimum": 0},
        "delimiter": {
            "anyOf": [{"type": "string", "minLength": 1, "maxLength": 1}, {"enum": ["tab", "\\t"]}]
        },
        "decimal": {"enum": [".", ","]},
        "encoding": {"type": "string", "minLength": 1},
        "header_row": {"anyOf": [{"type": "integer", "minimum": 1}, {"enum": [NO_HEADER, None]}]},
        "skip_rows": {"type": "integer", "minimum": 0},
        "missing_values": {
            "type": "array",
            "items": {"type": "string", "minLength": 1, "maxLength": MISSING_VALUE_MAX_CHARS},
            "uniqueItems": True,
        },
        "footer_rows": {"type": "integer", "minimum": 0},
        "sensors": {
            "type": ["array", "null"],
            "items": {"type": "string", "pattern": SENSOR_NAME_RE},
            "minItems": 1,
            "maxItems": MAX_SENSORS,
            "uniqueItems": True,
        },
        "columns": {
            "type": "object",
            "propertyNames": {"pattern": CANONICAL_RE},
            "additionalProperties": {
                "anyOf": [{"type": "string", "minLength": 1}, {"type": "integer", "minimum": 1}]
            },
        },
        "time": {
            "type": "object",
            "additionalProperties": False,
            "properties": {
                "kind": {"enum": list(TIME_KINDS)},
                "start": {"type": ["string", "null"], "minLength": 1},
                "format": {"type": ["string", "null"]},
                "period_s": {"type": "number", "exclusiveMinimum": 0},
                "date_column": {"type": ["string", "null"], "minLength": 1},
                "date_from_name": {"type": ["string", "null"], "minLength": 1},
                "timezone": {"type": ["string", "null"], "minLength": 1},
            },
        },
        "speed": {
            "type": "object",
            "additionalProperties": False,
            "properties": {
                "constant_rpm": {"type": "number", "minimum": 0},
                "constant_rpm_by_file": {
                    "type": "object",
                    "propertyNames": {"minLength": 1},
                    "additionalProperties": {"type": "number", "minimum": 0},
                },
            },
        },
        "sample_period_s": {"type": "number", "exclusiveMinimum": 0},
        "displacement": {
            "type": "object",
            "additionalProperties": False,
            "properties": {
                "column": {"type": "string", "minLength": 1},
                "unit": {"enum": ["um", "mm"]},
                "sign": {"enum": [1, -1]},
            },
        },
        "probes": {
            "type": "object",
            "propertyNames": {"pattern": PROBE_NAME_RE},
            "maxProperties": 16,
            "additionalProperties": {
                "type": "object",
                "additionalProperties": False,
                "required": ["column"],
                "properties": {
                    "column": {"type": "string", "minLength": 1},
                    "unit": {"enum": ["um", "mm"]},
                    "sign": {"enum": [1, -1]},
                    "description": {"type": "string", "minLength": 1},
                },
            },
        },
        "temperature_unit": {"enum": list(TEMPERATURE_UNITS)},
        "keep_extra": {"type": "boolean"},
        "join": {
            "type": ["object", "null"],
            "additionalProperties": False,
            "required": ["replace"],
            "properties": {
                "replace": {
                    "type": "array",
                    "items": {"type": "string"},
                    "minItems": 2,
                    "maxItems": 2,
                },
                "by": {"enum": list(JOIN_BY)},
                "columns": {
                    "type": "array",
                    "items": {"type": "string", "minLength": 1},
                    "minItems": 1,
                },
                "max_unmatched": {"type": "number", "minimum": 0, "maximum": 1},
                "input": {"type": "object", "propertyNames": {"enum": list(JOIN_LAYOUT_KEYS)}},
            },
        },
    },
}
