"""The one contract: every results path, figure group and setting (type, default, meaning).

Standard library only: Snakemake imports this while it plans every run. Everything that names a
file under ``results/<machine>/`` or a settings key derives from here:

- :data:`RESULT_FILES` and the groups after it: ``workflow/rules/common.smk`` (``out()``),
  ``report_common.smk``, :mod:`rafi.report.inputs`, the registry (:data:`REGISTRY_DIR`);
- :data:`RUN_SETTINGS` and :data:`MACHINE_SETTINGS`: the defaults (:mod:`rafi.settings`), the
  config schema (``workflow/schemas/config.schema.yaml``, written by :func:`schema_yaml`) and the
  tables of ``docs/settings.md`` (:func:`settings_tables`); ``python -m rafi.contract`` rewrites
  both, and a test fails when either is stale;
- :data:`LIMIT_KEYS` (the ``deploy:`` keys of :class:`rafi.deploy.limits.Limits`) and
  :data:`REPLAY_KEYS` (what the replay rule depends on).
"""

from __future__ import annotations

import copy
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

# --------------------------------------------------------------------------- results layout

#: Every file (or folder) under ``results/<machine>/``, by name; ``{stem}`` is a raw file's log
#: id, ``{group}`` a figure group, ``{step}`` a rule's name.
RESULT_FILES: dict[str, str] = {
    # clean (one job per machine): per raw file
    "clean_dir": "clean",
    "clean_parquet": "clean/{stem}.parquet",
    "clean_audit": "clean/{stem}.audit.csv",
    "clean_summary": "clean/{stem}.summary.csv",
    # input_status (checkpoint)
    "input_status": "input_status.json",
    "audit": "audit.csv",
    # method: runs -> equilibrium -> rank -> fit -> validate
    "runs_csv": "runs.csv",
    "runs_parquet": "runs.parquet",
    "equilibrium": "equilibrium.csv",
    "correlation": "rank/correlation.csv",
    "key_sensors": "rank/key_sensors.csv",
    "key_sensors_json": "rank/key_sensors.json",
    "collinearity": "rank/collinearity.csv",
    "coefficients": "fit/coefficients.csv",
    "diagnostics": "fit/diagnostics.csv",
    "vif": "fit/vif.csv",
    "model": "model.json",
    "validation_summary": "validation/summary.csv",
    "residuals": "validation/residuals.parquet",
    # compare (the model family)
    "comparison": "comparison/summary.csv",
    "comparison_per_run": "comparison/per_run.csv",
    "comparison_residuals": "comparison/residuals.parquet",
    "best_model": "comparison/best_model.json",
    "comparison_cv": "comparison/cv.csv",
    # decide (the registry's declared outputs; its own files are side effects, see REGISTRY_DIR)
    "decision": "registry/decision.json",
    "registry_comparison": "registry/comparison.csv",
    # replay
    "replay": "deploy/replay.parquet",
    "replay_summary": "deploy/replay_summary.csv",
    # report_figures: what the report shows from evaluating the model, and the figures
    "training_fit": "report/training_fit.parquet",
    "training_fit_rmse": "report/training_fit.csv",
    "fuzzy_example": "report/fuzzy_example.json",
    "figures": "report/figures/{group}",
    # per-rule benchmark TSVs
    "benchmark": "benchmarks/{step}.tsv",
}

#: The model registry of a machine, ``results/<machine>/registry/`` (``docs/operations.md``):
#: ``models/<id>.json``, ``champion.json``, ``history.jsonl`` besides the declared outputs.
REGISTRY_DIR = "registry"

#: The tables of ``docs/design.md`` every full run produces per machine (``rule tables``).
PIPELINE_TABLES = (
    "audit",
    "runs_csv",
    "runs_parquet",
    "equilibrium",
    "correlation",
    "key_sensors",
    "key_sensors_json",
    "collinearity",
    "coefficients",
    "diagnostics",
    "vif",
    "model",
    "validation_summary",
    "residuals",
)
#: Outputs of rule compare.
COMPARISON_FILES = ("comparison", "comparison_per_run", "comparison_residuals", "best_model", "comparison_cv")
#: Declared outputs of rule decide.
DECISION_FILES = ("decision", "registry_comparison")
#: Outputs of rule replay.
REPLAY_FILES = ("replay", "replay_summary")
#: What rule report_figures writes before it draws: the report's tables from evaluating the model.
REPORT_MODEL_TABLES = ("training_fit", "training_fit_rmse", "fuzzy_example")
#: What the report's model tables (:mod:`rafi.report.tables`) read.
REPORT_MODEL_TABLE_INPUTS = ("model", "runs_csv", "runs_parquet", "diagnostics")

#: Figure groups of rule report_figures and the inputs each draws from.
FIGURE_GROUPS: dict[str, tuple[str, ...]] = {
    "pipeline": (
        "runs_csv",
        "runs_parquet",
        "equilibrium",
        "correlation",
        "key_sensors",
        "key_sensors_json",
        "collinearity",
        "model",
        "validation_summary",
        "residuals",
        "training_fit",
        "fuzzy_example",
    ),
    "comparison": ("comparison", "comparison_per_run", "comparison_residuals"),
    "replay": ("replay", "replay_summary"),
}

#: What the report needs: these tables must exist ...
REPORT_REQUIRED = (
    "audit",
    "runs_csv",
    "equilibrium",
    "correlation",
    "key_sensors",
    "key_sensors_json",
    "collinearity",
    "coefficients",
    "diagnostics",
    "model",
    "validation_summary",
    "residuals",
    "training_fit_rmse",
    "fuzzy_example",
)
#: ... these are read when present (a section is left out without its file).
REPORT_OPTIONAL = (
    "input_status",
    "decision",
    "registry_comparison",
    "comparison",
    "comparison_per_run",
    "comparison_cv",
    "best_model",
    "replay_summary",
    "runs_parquet",
)


def result_file(name: str, **fields: str) -> str:
    """Path of result ``name`` relative to ``results/<machine>/``, its ``{...}`` fields filled.

    A field not given stays a ``{field}`` wildcard (Snakemake's form), e.g.
    ``result_file("clean_parquet")`` is ``"clean/{stem}.parquet"``.
    """
    path = RESULT_FILES[name]
    for key, value in fields.items():
        path = path.replace("{" + key + "}", str(value))
    return path


# --------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class Setting:
    """One settings key: its default, its JSON schema (no ``default`` keyword), and what it means.

    ``shown`` is how ``docs/settings.md`` writes the default where the value itself reads badly
    (``None`` for a key the table leaves out); ``limit`` marks a ``deploy:`` key of
    :class:`rafi.deploy.limits.Limits`, ``replay`` one the replay rule depends on.
    """

    default: Any
    schema: dict
    doc: str
    shown: str | None = None
    limit: bool = False
    replay: bool = False


@dataclass(frozen=True)
class Section:
    """A mapping of settings (``clean:``, ``deploy:``, ...): every key known, none other allowed."""

    doc: str
    keys: dict
    shown: str | None = None
    schema_extra: dict = field(default_factory=dict)


# --------------------------------------------------------------------------- the input: mapping

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
    "time": {"kind": "timestamp", "start": "2000-01-01T00:00:00", "format": None, "period_s": None},
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
                "start": {"type": "string", "minLength": 1},
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
        schema={"type": "number", "minimum": 0},
        shown="0",
        doc=(
            "a raw file modified less than this many seconds ago is still being written: it is left out of "
            "this run (listed as waiting) and read by the next one"
        ),
    ),
    "nightly_settle_s": Setting(
        default=600,
        schema={"type": "number", "minimum": 0},
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
#: Per-machine settings: ``defaults:`` and ``machines.<name>:`` of ``config.yaml``.
MACHINE_SETTINGS: dict[str, Setting | Section] = {
    "input": Setting(
        default={},
        schema=INPUT_SCHEMA,
        shown="native format",
        doc=(
            "how the raw files are found and read: `docs/raw-format.md` (`format`, `pattern`, `sheet`, "
            "`delimiter`, `decimal`, `encoding`, `header_row`, `skip_rows`, `columns`, `time`, `speed`, "
            "`sample_period_s`, `displacement`, `temperature_unit`, `keep_extra`). A log without a time "
            "column: `time: {kind: none, period_s: ...}` (row k at `time.start + k * period_s`); without a "
            "speed column: `speed.constant_rpm` and/or `speed.constant_rpm_by_file` (glob on the file name "
            '-> r/min); raw-format.md, "Logs without a time or speed column"'
        ),
    ),
    "sample_period_s": Setting(
        default=5,
        schema={"type": "number", "exclusiveMinimum": 0},
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
        schema={"type": "number", "minimum": 0},
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
                schema={"type": "number", "minimum": 0},
                shown="60",
                doc="gaps up to this are interpolated; longer ones split the log into segments",
            ),
            "spike_threshold": Setting(
                default=8,
                schema={"type": "number", "exclusiveMinimum": 0},
                shown="8",
                doc="robust z-score (MAD of first differences) above which a single sample is a spike",
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
                schema={"type": "number", "minimum": 0},
                shown="100",
                doc="below this the spindle stands",
            ),
            "min_run_s": Setting(
                default=1800,
                schema={"type": "number", "minimum": 0},
                shown="1800",
                doc="shorter runs are excluded (reported, not used)",
            ),
            "min_constant_s": Setting(
                default=3600,
                schema={"type": "number", "minimum": 0},
                shown="3600",
                doc="a constant-speed stretch shorter than this is part of a varying run",
            ),
            "max_leading_rest_s": Setting(
                default=300,
                schema={"type": "number", "minimum": 0},
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
                default=False,
                schema={"type": "boolean"},
                shown="false",
                doc=(
                    "idle cool-downs (automatic validation_idle runs, and idle runs inside a training "
                    "window) are training runs for the family's models; RAFI as published ignores them"
                ),
            ),
            "allow_training_after_validation": Setting(
                default=False,
                schema={"type": "boolean"},
                shown="false",
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
                schema={"type": "number", "exclusiveMinimum": 0},
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
                schema={"type": "number", "exclusiveMinimum": 0},
                shown="900",
                doc="final plateau = median of the last 15 min",
            ),
            "smooth_window_s": Setting(
                default=300,
                schema={"type": "number", "exclusiveMinimum": 0},
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
    "qualification": Section(
        doc="gates a model must pass to be promoted (every validation run)",
        keys={
            "max_residual_um": Setting(
                default=12.0,
                schema={"type": "number", "exclusiveMinimum": 0},
                shown="12.0",
                doc="gate: max \\|residual\\| on every validation run",
            ),
            "min_improvement_pct": Setting(
                default=30.0,
                schema={"type": "number", "maximum": 100},
                shown="30.0",
                doc="gate: improvement over no compensation on every validation run",
            ),
            "never_worse_than_uncompensated": Setting(
                default=True,
                schema={"type": "boolean"},
                shown="true",
                doc="gate: on no run worse than no compensation",
            ),
        },
    ),
    "models": Section(
        doc="the model family compared with RAFI (docs/models.md)",
        keys={
            "enabled": Setting(
                default=["rafi", "rafi_linear", "ridge_global", "dynamic", "grey_box"],
                schema={
                    "type": "array",
                    "items": {"enum": ["rafi", "rafi_linear", "ridge_global", "dynamic", "grey_box"]},
                    "minItems": 1,
                    "uniqueItems": True,
                },
                shown="all five",
                doc=(
                    "the model family (`docs/models.md`): `rafi`, `rafi_linear`, `ridge_global`, `dynamic`, "
                    "`grey_box`"
                ),
            ),
            "cv": Setting(
                default="leave_one_run_out",
                schema={"enum": ["leave_one_run_out", "leave_one_speed_out"]},
                shown="`leave_one_run_out`",
                doc=(
                    "whole-run cross-validation on training runs: `leave_one_run_out` or "
                    "`leave_one_speed_out`; it always runs (`comparison/cv.csv`): its held-out scores choose"
                    " the model offered to the machine (`docs/models.md`; the former `models.cv_report` "
                    "switch is gone)"
                ),
            ),
            "cv_metric": Setting(
                default="rmse",
                schema={"enum": ["rmse", "max_abs"]},
                shown="`rmse`",
                doc="`rmse` or `max_abs`",
            ),
            "ridge_alphas": Setting(
                default=[float(f"{m}e{e}") for e in range(-8, 1) for m in (1, 2, 5)] + [10.0],
                schema={"type": "array", "items": {"type": "number", "exclusiveMinimum": 0}, "minItems": 1},
                shown="1e-8 ... 10, 1-2-5 per decade",
                doc="ridge penalties tried by CV",
            ),
            "dynamic_taus_s": Setting(
                default="auto",
                schema={
                    "oneOf": [
                        {"const": "auto"},
                        {
                            "type": "array",
                            "items": {"type": "number", "minimum": 0},
                            "minItems": 1,
                            "uniqueItems": True,
                        },
                    ]
                },
                shown="`auto`",
                doc=(
                    "first-order filter constants of `dynamic`; `auto`: 0 and a geometric grid (ratio 3) "
                    "from 4 sample periods up to about the median training-run length (`docs/models.md`, "
                    "Grids); or a list"
                ),
            ),
            "dynamic_max_taus": Setting(
                default=2,
                schema={"type": "integer", "minimum": 1},
                shown="2",
                doc="at most this many filters at once",
            ),
            "speed_gain": Setting(
                default="cv",
                schema={"enum": [True, False, "cv"]},
                shown="`cv`",
                doc="speed terms: `true`, `false` or chosen by CV",
            ),
            "speed_reference": Setting(
                default="auto",
                schema={"enum": ["auto", "run_start", "zero"]},
                shown="`auto`",
                doc="`auto`, `run_start` or `zero`",
            ),
            "grey_box_taus_s": Setting(
                default="auto",
                schema={
                    "oneOf": [
                        {"const": "auto"},
                        {
                            "type": "array",
                            "items": {"type": "number", "minimum": 0},
                            "minItems": 1,
                            "uniqueItems": True,
                        },
                    ]
                },
                shown="`auto`",
                doc=(
                    "rise filters of `grey_box` (0 = the rise itself); `auto`: 0 and 24 P .. L/24, ratio 5 "
                    "(0, 120, 600 s at 5 s and 4 h runs); or a list"
                ),
            ),
            "grey_box_speed_taus_s": Setting(
                default="auto",
                schema={
                    "oneOf": [
                        {"const": "auto"},
                        {
                            "type": "array",
                            "items": {"type": "number", "exclusiveMinimum": 0},
                            "minItems": 1,
                            "uniqueItems": True,
                        },
                    ]
                },
                shown="`auto`",
                doc=(
                    "heat-input filters; `auto`: 12 P .. L/6, ratio 3 (60, 180, 540, 1600 s at 5 s and 4 h);"
                    " or a list"
                ),
            ),
            "grey_box_filter_search": Setting(
                default="all",
                schema={"enum": ["all", "subsets"]},
                shown="`all`",
                doc="`all` filters at once with the ridge penalty by CV, or `subsets`",
            ),
            "grey_box_max_taus": Setting(
                default=1,
                schema={"type": "integer", "minimum": 1},
                shown="1",
                doc="(`subsets` only)",
            ),
            "grey_box_max_speed_taus": Setting(
                default=2,
                schema={"type": "integer", "minimum": 0},
                shown="2",
                doc="(`subsets` only)",
            ),
            "grey_box_centrifugal_lags_s": Setting(
                default="auto",
                schema={
                    "oneOf": [
                        {"const": "auto"},
                        {
                            "type": "array",
                            "items": {"type": "number", "minimum": 0},
                            "minItems": 1,
                            "uniqueItems": True,
                        },
                    ]
                },
                shown="`auto`",
                doc=(
                    "lag of the n² draw-in term, by CV; `auto`: 0, P, 2 P, 4 P (P = sample period); or a list"
                ),
            ),
            "grey_box_speed_powers": Setting(
                default=[0, 1, 5 / 3, 2],
                schema={
                    "type": "array",
                    "items": {"type": "number", "minimum": 0},
                    "minItems": 1,
                    "uniqueItems": True,
                },
                shown="0, 1, 5/3, 2",
                doc="(n/10000)^p; 0 = running indicator",
            ),
            "grey_box_cv_metric": Setting(
                default="max_abs",
                schema={"enum": ["rmse", "max_abs"]},
                shown="`max_abs`",
                doc="the gates are about the max residual",
            ),
            "filter_restart_gap_s": Setting(
                default=3600,
                schema={"type": "number", "minimum": 0},
                shown="3600",
                doc=(
                    "on whole logs, a gap longer than this (s) restarts the family's filters (settled on the"
                    " first sample after it); shorter gaps and cool-downs carry the filter state "
                    "(`docs/models.md`, Whole-log dynamics)"
                ),
            ),
        },
    ),
    "nightly": Section(
        doc="the nightly champion/challenger decision (docs/operations.md)",
        keys={
            "candidate": Setting(
                default="family",
                schema={"type": "string", "enum": ["fit", "family"]},
                shown="`family`",
                doc="tonight's candidate: `family` (the family's best model) or `fit` (RAFI as published)",
            ),
            "retrain_speed_range_rpm": Setting(
                default=None,
                schema={
                    "oneOf": [
                        {"type": "null"},
                        {
                            "type": "array",
                            "items": {"type": "number", "minimum": 0},
                            "minItems": 2,
                            "maxItems": 2,
                        },
                    ]
                },
                shown="none",
                doc="`[lo, hi]`: retrain only these speeds, keep the champion's others",
            ),
            "drift_margin_um": Setting(
                default=2.0,
                schema={"type": "number", "minimum": 0},
                shown="2.0",
                doc="the champion's residual on new validation logs may grow this much",
            ),
            "champion_margin_um": Setting(
                default="noise",
                schema={"oneOf": [{"type": "number", "minimum": 0}, {"const": "noise"}]},
                shown="`noise`",
                doc=(
                    "a candidate is promoted only if on no validation run both models are scored on its max "
                    "residual exceeds the champion's by more than this (um); `noise`: the run's noise floor "
                    "(docs/operations.md)"
                ),
            ),
        },
    ),
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
                schema={"type": "boolean"},
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
                        schema={"type": ["null", "string"]},
                        shown="none",
                        doc=(
                            "the sign-off block on the first page: the document number; left out, a blank "
                            "line to fill in by hand"
                        ),
                    ),
                    "prepared_by": Setting(
                        default=None,
                        schema={"type": ["null", "string"]},
                        shown="none",
                        doc="who prepared the report; left out, a blank line to sign",
                    ),
                    "approved_by": Setting(
                        default=None,
                        schema={"type": ["null", "string"]},
                        shown="none",
                        doc="who approved it; left out, a blank line to sign",
                    ),
                    "approved_date": Setting(
                        default=None,
                        schema={"type": ["null", "string"]},
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
                        schema={"type": ["null", "string"]},
                        shown="none",
                        doc="the machine's serial number (test record); missing ones are listed in a warning",
                    ),
                    "controller": Setting(
                        default=None,
                        schema={"type": ["null", "string"]},
                        shown="none",
                        doc="the controller (test record)",
                    ),
                    "probe": Setting(
                        default=None,
                        schema={"type": ["null", "string"]},
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
                schema={"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": 2},
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
                schema={"type": "number", "exclusiveMinimum": 0},
                shown="0.2",
                doc="nor changes faster than this (um/s)",
                limit=True,
                replay=True,
            ),
            "temp_valid_c": Setting(
                default=[-10.0, 70.0],
                schema={"type": "array", "items": {"type": "number"}, "minItems": 2, "maxItems": 2},
                shown="[-10, 70]",
                doc="a temperature outside this range (degC) is a sensor fault",
                limit=True,
                replay=True,
            ),
            "stuck_s": Setting(
                default=1800,
                schema={"type": "number", "exclusiveMinimum": 0},
                shown="1800",
                doc="a sensor whose reading has not changed for this long (s) ...",
                limit=True,
                replay=True,
            ),
            "stuck_change_k": Setting(
                default=0.5,
                schema={"type": "number", "exclusiveMinimum": 0},
                shown="0.5",
                doc="... while another sensor the model reads moved by this much (K) is stuck",
                limit=True,
                replay=True,
            ),
            "range_margin_k": Setting(
                default=2.0,
                schema={"type": "number", "minimum": 0},
                shown="2.0",
                doc="outside the trained range: a rise beyond its training range by more than this (K) ...",
                limit=True,
                replay=True,
            ),
            "speed_margin_rpm": Setting(
                default=500,
                schema={"type": "number", "minimum": 0},
                shown="500",
                doc="... or a speed above the trained speeds by more than this (r/min)",
                limit=True,
                replay=True,
            ),
            "hold_s": Setting(
                default=600,
                schema={"type": "number", "minimum": 0},
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
                schema={"type": "number", "exclusiveMinimum": 0},
                shown="0.02",
                doc="... at this rate (um/s)",
                limit=True,
                replay=True,
            ),
            "interval_s": Setting(
                default=5,
                schema={"type": "number", "exclusiveMinimum": 0},
                shown="5",
                doc="the live loop writes every this many seconds",
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
                    "`T1`..`T16`: a node id or `{node, scale, offset}`), `node_prefix`, `credentials_file`, "
                    '`timeout_s`, `reconnect_min_s`, `reconnect_max_s` (docs/deploy.md "Live: OPC UA"; '
                    "checked by `rafi.deploy.opcua_client.opcua_settings`). Never a user or password: those "
                    "come from the environment or a file outside the repository, and are refused here"
                ),
            ),
            "replay_roles": Setting(
                default=["validation_multi"],
                schema={
                    "type": "array",
                    "items": {
                        "enum": ["training", "validation_single", "validation_multi", "validation_idle"]
                    },
                    "uniqueItems": True,
                },
                shown="`[validation_multi]`",
                doc=(
                    "the report replays the runs of these roles through the compensator with the limits in "
                    "force"
                ),
                replay=True,
            ),
        },
    ),
}

#: ``deploy:`` keys of the limits and fault rules (:class:`rafi.deploy.limits.Limits`).
LIMIT_KEYS: tuple[str, ...] = tuple(k for k, s in MACHINE_SETTINGS["deploy"].keys.items() if s.limit)
#: ``deploy:`` keys the replay depends on: the limits and which runs it replays (not the
#: controller's connection settings).
REPLAY_KEYS: tuple[str, ...] = tuple(k for k, s in MACHINE_SETTINGS["deploy"].keys.items() if s.replay)
#: The promotion gates, in the order they are reported.
GATE_KEYS: tuple[str, ...] = tuple(MACHINE_SETTINGS["qualification"].keys)


def defaults(tree: dict) -> dict:
    """The default of every key of a settings tree (:data:`RUN_SETTINGS`, :data:`MACHINE_SETTINGS`).

    A fresh copy: the caller may change it.
    """
    return {
        key: defaults(node.keys) if isinstance(node, Section) else copy.deepcopy(node.default)
        for key, node in tree.items()
    }


def _node_schema(node: Setting | Section) -> dict:
    if isinstance(node, Setting):
        return copy.deepcopy(node.schema)
    schema = {"type": "object", "description": node.doc} if node.doc else {"type": "object"}
    schema.update(copy.deepcopy(node.schema_extra))
    schema["properties"] = {key: _node_schema(child) for key, child in node.keys.items()}
    schema["additionalProperties"] = False
    return schema


def config_schema() -> dict:
    """JSON schema (2020-12) of ``config.yaml``: the run settings at the top level, ``defaults:``
    and ``machines.<name>:`` each a partial machine settings mapping. No key is required and no
    ``default`` keyword is given (defaults are merged by :func:`rafi.settings.machine_settings`);
    every mapping is strict, so a typo in a key is an error, not a silent default."""
    machine = {
        "type": "object",
        "properties": {key: _node_schema(node) for key, node in MACHINE_SETTINGS.items()},
        "additionalProperties": False,
    }
    properties = {key: _node_schema(node) for key, node in RUN_SETTINGS.items()}
    for key, node in RUN_SETTINGS.items():
        properties[key]["description"] = node.doc
    properties["defaults"] = {"$ref": "#/$defs/machine_settings"}
    properties["machines"] = {
        "type": ["object", "null"],
        "description": "machine folder name -> partial settings deep-merged over `defaults`",
        "additionalProperties": {"anyOf": [{"$ref": "#/$defs/machine_settings"}, {"type": "null"}]},
    }
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "description": (
            "RAFI pipeline configuration (config.yaml). GENERATED from rafi/contract.py by "
            "`python -m rafi.contract`: edit the contract, not this file. Every default lives in "
            "the contract (docs/settings.md); `defaults` holds what this installation changes for "
            "every machine and `machines.<name>` what one machine changes, both partial and "
            "deep-merged in that order by rafi.settings.machine_settings."
        ),
        "type": "object",
        "$defs": {"machine_settings": machine},
        "properties": properties,
        "additionalProperties": False,
    }


def schema_yaml() -> str:
    """:func:`config_schema` as the text of ``workflow/schemas/config.schema.yaml`` (JSON is YAML:
    one key per line, keys in the contract's order, so a diff of the file reads like one of the
    contract)."""
    return (
        "# GENERATED by `python -m rafi.contract` from rafi/contract.py; do not edit.\n"
        + json.dumps(config_schema(), indent=2, ensure_ascii=False)
        + "\n"
    )


def _shown(node: Setting | Section) -> str | None:
    return node.shown


def _rows(tree: dict, prefix: str = "") -> list[tuple[str, str, str]]:
    rows = []
    for key, node in tree.items():
        path = f"{prefix}{key}"
        if node.shown is not None:
            rows.append((path, node.shown, node.doc))
        if isinstance(node, Section):
            rows.extend(_rows(node.keys, path + "."))
    return rows


def settings_tables() -> str:
    """The two tables of ``docs/settings.md`` (run settings, per-machine settings), as Markdown."""
    parts = []
    for title, tree in (
        ("Run settings (top level)", RUN_SETTINGS),
        ("Per-machine settings", MACHINE_SETTINGS),
    ):
        lines = [f"## {title}", "", "| key | default | meaning |", "|---|---|---|"]
        lines += [f"| `{key}` | {shown} | {doc} |" for key, shown, doc in _rows(tree)]
        parts.append("\n".join(lines))
    return "\n\n".join(parts) + "\n"


TABLES_BEGIN = "<!-- settings tables: generated by `python -m rafi.contract`; edit rafi/contract.py -->"
TABLES_END = "<!-- end of the generated settings tables -->"


def with_settings_tables(text: str) -> str:
    """``docs/settings.md``'s ``text`` with the generated tables between the two markers."""
    begin, end = text.index(TABLES_BEGIN), text.index(TABLES_END)
    return text[: begin + len(TABLES_BEGIN)] + "\n\n" + settings_tables() + "\n" + text[end:]


def write_generated(root: Path) -> list[Path]:
    """Rewrite the generated files under the project ``root``; return those that changed."""
    changed = []
    targets = {
        root / "workflow" / "schemas" / "config.schema.yaml": lambda old: schema_yaml(),
        root / "docs" / "settings.md": with_settings_tables,
    }
    for path, render in targets.items():
        old = path.read_text(encoding="utf-8")
        new = render(old)
        if new != old:
            path.write_text(new, encoding="utf-8")
            changed.append(path)
    return changed


if __name__ == "__main__":
    root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[1]
    for path in write_generated(root):
        print(f"rewrote {path}")
