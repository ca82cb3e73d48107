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
    "columns": {},
    "time": {"kind": "timestamp", "start": None, "format": None, "period_s": None},
    "speed": {"constant_rpm": None, "constant_rpm_by_file": {}},
    "sample_period_s": None,
    "displacement": {"column": None, "unit": "um", "sign": 1},
    "temperature_unit": "C",
    "keep_extra": True,
}

DEFAULT_PATTERN = {"native": "*.csv", "csv": "*.csv", "xlsx": "*.xlsx"}

#: ``input.time.kind``: a column of timestamps, a column of elapsed seconds, or no time column
#: (row k of the file at ``start + k * period_s``).
TIME_KINDS = ("timestamp", "elapsed_s", "none")

#: ``input.time.start`` left out (``None``) with ``elapsed_s`` or ``none``: the log has no clock.
#: Its times are counted from this instant for the arithmetic only (never shown as a date): the
#: frame's ``attrs['metadata']['clock']`` is ``False``, the runs have no clock time and the report
#: shows hours since the log's first sample.
NO_CLOCK_EPOCH = "2000-01-01T00:00:00"

#: Keys meaningful for the native format (everything else is for csv/xlsx).
NATIVE_KEYS = {"format", "pattern", "sample_period_s"}

CANONICAL_RE = "^(time|speed_rpm|T([1-9]|1[0-6])|disp_um)$"

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
        "header_row": {"type": "integer", "minimum": 1},
        "skip_rows": {"type": "integer", "minimum": 0},
        "columns": {
            "type": "object",
            "propertyNames": {"pattern": CANONICAL_RE},
            "additionalProperties": {"type": "string", "minLength": 1},
        },
        "time": {
            "type": "object",
            "additionalProperties": False,
            "properties": {
                "kind": {"enum": list(TIME_KINDS)},
                "start": {"type": ["string", "null"], "minLength": 1},
                "format": {"type": ["string", "null"]},
                "period_s": {"type": "number", "exclusiveMinimum": 0},
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
        "temperature_unit": {"enum": ["C", "K"]},
        "keep_extra": {"type": "boolean"},
    },
}
