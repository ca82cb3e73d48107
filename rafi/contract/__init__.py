"""The one contract: every results path, figure group and setting (type, default, meaning).

Standard library only: Snakemake imports this while it plans every run. Everything that names a
file under ``results/<machine>/`` or a settings key derives from here:

- :data:`RESULT_FILES` and the groups after it: ``workflow/rules/common.smk`` (``out()``),
  ``report_common.smk``, :mod:`rafi.report.inputs`, the registry (:data:`REGISTRY_DIR`);
- :data:`RUN_SETTINGS` and :data:`MACHINE_SETTINGS`: the defaults (:mod:`rafi.settings`), the
  config schema (``workflow/schemas/config.schema.yaml``, written by :func:`schema_yaml`) and the
  tables of ``docs/settings.md`` (:func:`settings_tables`); ``python -m rafi.contract`` rewrites
  both, and a test fails when either is stale;
- :data:`RETIRED_SETTINGS`: keys removed, each with what replaced it (:func:`retired_setting`);
- :data:`LIMIT_KEYS` (the ``deploy:`` keys of :class:`rafi.deploy.limits.Limits`) and
  :data:`REPLAY_KEYS` (what the replay rule depends on).
"""

from __future__ import annotations

from rafi.contract.generate import (
    TABLES_BEGIN,
    TABLES_END,
    config_schema,
    defaults,
    schema_yaml,
    settings_tables,
    with_settings_tables,
    write_generated,
)
from rafi.contract.input import (
    CANONICAL_RE,
    DEFAULT_PATTERN,
    DEFAULT_SENSORS,
    ELAPSED_SECONDS,
    EPOCH_CLOCKS,
    FORMATS,
    INPUT_DEFAULTS,
    INPUT_SCHEMA,
    JOIN_BY,
    JOIN_DEFAULTS,
    JOIN_LAYOUT_KEYS,
    MAX_SENSORS,
    NATIVE_KEYS,
    NO_CLOCK_EPOCH,
    NO_HEADER,
    NON_SENSOR_COLUMNS,
    PROBE_KEYS,
    PROBE_NAME_RE,
    PROBE_SEPARATOR,
    RESERVED_NAMES,
    SENSOR_NAME_RE,
    TEMPERATURE_UNITS,
    TIME_KINDS,
)
from rafi.contract.keys import Section, Setting
from rafi.contract.machine import GATE_KEYS, LIMIT_KEYS, MACHINE_SETTINGS, REPLAY_KEYS
from rafi.contract.operations import MODEL_KINDS
from rafi.contract.results import (
    COMPARISON_FILES,
    DECISION_FILES,
    FIGURE_GROUPS,
    PIPELINE_TABLES,
    REGISTRY_DIR,
    REPLAY_FILES,
    REPORT_MODEL_TABLE_INPUTS,
    REPORT_MODEL_TABLES,
    REPORT_OPTIONAL,
    REPORT_REQUIRED,
    RESULT_FILES,
    RUN_FILES,
    result_file,
)
from rafi.contract.retired import RETIRED_SETTINGS, retired_setting
from rafi.contract.run import RUN_SETTINGS

__all__ = [
    "MODEL_KINDS",
    "CANONICAL_RE",
    "COMPARISON_FILES",
    "DECISION_FILES",
    "DEFAULT_PATTERN",
    "DEFAULT_SENSORS",
    "MAX_SENSORS",
    "NON_SENSOR_COLUMNS",
    "PROBE_KEYS",
    "PROBE_NAME_RE",
    "PROBE_SEPARATOR",
    "RESERVED_NAMES",
    "SENSOR_NAME_RE",
    "FIGURE_GROUPS",
    "FORMATS",
    "GATE_KEYS",
    "INPUT_DEFAULTS",
    "INPUT_SCHEMA",
    "JOIN_BY",
    "JOIN_DEFAULTS",
    "JOIN_LAYOUT_KEYS",
    "NO_HEADER",
    "LIMIT_KEYS",
    "MACHINE_SETTINGS",
    "NATIVE_KEYS",
    "PIPELINE_TABLES",
    "REGISTRY_DIR",
    "REPLAY_FILES",
    "REPLAY_KEYS",
    "REPORT_MODEL_TABLES",
    "REPORT_MODEL_TABLE_INPUTS",
    "REPORT_OPTIONAL",
    "REPORT_REQUIRED",
    "RESULT_FILES",
    "RETIRED_SETTINGS",
    "RUN_FILES",
    "RUN_SETTINGS",
    "TABLES_BEGIN",
    "TABLES_END",
    "TIME_KINDS",
    "ELAPSED_SECONDS",
    "EPOCH_CLOCKS",
    "TEMPERATURE_UNITS",
    "NO_CLOCK_EPOCH",
    "Section",
    "Setting",
    "config_schema",
    "defaults",
    "result_file",
    "retired_setting",
    "schema_yaml",
    "settings_tables",
    "with_settings_tables",
    "write_generated",
]
