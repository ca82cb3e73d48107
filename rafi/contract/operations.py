"""Per-machine settings of the model family and its promotion: ``qualification``, ``models``, ``nightly``."""

from __future__ import annotations

from rafi.contract.keys import FLAG, NON_NEGATIVE, POSITIVE, Section, Setting, auto_or_numbers

#: Every kind of the model family (`docs/models.md`); `models: enabled` names some of them.
MODEL_KINDS = ("rafi", "rafi_linear", "ridge_global", "dynamic", "grey_box", "temperature_ridge")

OPERATIONS_SETTINGS: dict = {
    "qualification": Section(
        doc="gates a model must pass to be promoted (every validation run)",
        keys={
            "max_residual_um": Setting(
                default=12.0,
                schema=POSITIVE,
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
                schema=FLAG,
                shown="`true`",
                doc="gate: on no run worse than no compensation",
            ),
            "min_coverage": Setting(
                default=None,
                schema={"oneOf": [{"type": "null"}, {"type": "number", "minimum": 0, "maximum": 1}]},
                shown="none (off)",
                doc=(
                    "gate: the fraction of every validation run's samples inside the model's prediction"
                    " interval (`coverage`, 0..1; e.g. 0.8 for the 90 % interval); a model without an"
                    " interval fails it (`docs/models.md`, Prediction intervals)"
                ),
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
                    "items": {"enum": list(MODEL_KINDS)},
                    "minItems": 1,
                    "uniqueItems": True,
                },
                shown="all five",
                doc=(
                    "the model family (`docs/models.md`): `rafi`, `rafi_linear`, `ridge_global`, `dynamic`, "
                    "`grey_box`; `temperature_ridge` (no speed input) offered on request, and scored in every"
                    " comparison as the plain-ridge floor either way"
                ),
            ),
            "prior": Setting(
                default="auto",
                schema={
                    "oneOf": [
                        {"enum": ["auto", "none", "champion"]},
                        {
                            "type": "object",
                            "properties": {"machine": {"type": "string", "minLength": 1}},
                            "required": ["machine"],
                            "additionalProperties": False,
                        },
                    ]
                },
                shown="`auto`",
                doc=(
                    "the prior a re-qualification starts from (`docs/models.md`, Re-qualification from a "
                    "prior): `auto` (the registry's champion chain when the machine has a champion, else "
                    "none), `none`, `champion` (required: an error without one) or `{machine: <name>}` (a "
                    "sibling's champion chain); a model that learnt from any current run is skipped"
                ),
            ),
            "prior_siblings": Setting(
                default=[],
                schema={"type": "array", "items": {"type": "string", "minLength": 1}, "uniqueItems": True},
                shown="none",
                doc=(
                    "the machines declared siblings of this one (same design, sensors and probe map): a "
                    "prior that is a model of another machine (`models.prior: {machine: <name>}`) must be"
                    " of one of these, or the re-qualification stops (`PriorForeign`, one line; "
                    "`docs/models.md`, Re-qualification from a prior). A name is a machine (every probe"
                    " of it) or a probe unit `<machine>@<probe>`"
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
            "offer": Setting(
                default="ensemble",
                schema={"enum": ["best", "ensemble"]},
                shown="`ensemble`",
                doc=(
                    "what is offered to the machine: `best` (the kind with the lowest selection score"
                    " on the training runs) or `ensemble` (the enabled kinds but RAFI's two, and the "
                    "plain ridge, blended with weights from the whole-run CV, `docs/models.md`, The "
                    "CV-weighted ensemble); without a prior only"
                ),
            ),
            "cv_forward_runs": Setting(
                default=2,
                schema={"type": "integer", "minimum": 0},
                shown="2",
                doc=(
                    "forward-in-time folds beside the whole-run CV: in a log with at least 3 + this many"
                    " training runs, train on the runs before a point in time and hold out the next this"
                    " many; the selection score is then the mean of the whole-run and the forward scores"
                    " (`docs/models.md`, Forward folds); 0 = whole-run CV only"
                ),
            ),
            "interval_level": Setting(
                default=0.9,
                schema={"type": "number", "exclusiveMinimum": 0, "exclusiveMaximum": 1},
                shown="0.9",
                doc=(
                    "nominal coverage of every model's prediction interval, calibrated on the whole-run CV"
                    " residuals (`docs/models.md`, Prediction intervals)"
                ),
            ),
            "interval_transient_s": Setting(
                default=1800,
                schema=NON_NEGATIVE,
                shown="1800",
                doc=(
                    "a sample less than this (s) after a reference, a filter restart or a speed change is"
                    " in the interval's `transient` cell (wider); about the spindle's thermal time constant"
                ),
            ),
            "interval_min_runs": Setting(
                default=3,
                schema={"type": "integer", "minimum": 1},
                shown="3",
                doc=(
                    "an interval cell calibrated on fewer held-out runs (time blocks) than this uses the"
                    " pooled half-width instead"
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
            "since_change": Setting(
                default=True,
                schema={"type": "boolean"},
                shown="`true`",
                doc=(
                    "when the training runs no model explains are separated from the others by one "
                    "change in the order the runs were recorded, set aside the runs before it and train "
                    "on the runs since (`docs/models.md`, Training runs since a change)"
                ),
            ),
            "component_envelope": Setting(
                default=True,
                schema={"type": "boolean"},
                shown="`true`",
                doc=(
                    "the ridge kinds also hold each principal component of their standardised features "
                    "where it would add more than one training span of the displacement beyond its "
                    "training range (`docs/models.md`, The training envelope)"
                ),
            ),
            "prior_ridge_alphas": Setting(
                default=[float(f"{m}e{e}") for e in range(-4, 5) for m in (1, 2, 5)] + [1e5],
                schema={"type": "array", "items": {"type": "number", "exclusiveMinimum": 0}, "minItems": 1},
                shown="1e-4 ... 1e5, 1-2-5 per decade",
                doc=(
                    "penalties of `prior_ridge` tried by CV (`docs/models.md`, Re-qualification from a "
                    "prior): the ridge shrinks the move from the prior's coefficients, so the grid reaches "
                    "far enough to keep the prior (without a CV fold the largest is taken)"
                ),
            ),
            "dynamic_taus_s": Setting(
                default="auto",
                schema=auto_or_numbers(),
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
            "dynamic_heat_input": Setting(
                default=True,
                schema={"type": "boolean"},
                shown="`true`",
                doc=(
                    "`dynamic` also gets the heat-input history: the filtered speed powers of `grey_box` "
                    "(`grey_box_speed_taus_s`, `grey_box_speed_powers`), every filter at once, and then "
                    "no speed gain under `speed_gain: cv` (`docs/decisions.md`, 2026-11-26)"
                ),
            ),
            "temperature_ridge_taus_s": Setting(
                default=[0, 900, 3600],
                schema={
                    "type": "array",
                    "items": {"type": "number", "minimum": 0},
                    "minItems": 1,
                    "uniqueItems": True,
                },
                shown="0, 900, 3600",
                doc=(
                    "first-order filter constants of `temperature_ridge`, every one at once (0 = the rise "
                    "itself): the plain ridge of `benchmarks/bench_realdata.py`"
                ),
            ),
            "speed_gain": Setting(
                default="cv",
                schema={"enum": [True, False, "cv"]},
                shown="`cv`",
                doc=(
                    "the speed gain `L_tau(dT_i) * n` of `ridge_global` and `dynamic`: `true`, `false` or "
                    "chosen by CV (`cv`; for `dynamic` with its heat-input history `cv` means none)"
                ),
            ),
            "speed_reference": Setting(
                default="auto",
                schema={"enum": ["auto", "run_start", "zero"]},
                shown="`auto`",
                doc="`auto`, `run_start` or `zero`",
            ),
            "grey_box_taus_s": Setting(
                default="auto",
                schema=auto_or_numbers(),
                shown="`auto`",
                doc=(
                    "rise filters of `grey_box` (0 = the rise itself); `auto`: 0 and 24 P .. L/24, ratio 5 "
                    "(0, 120, 600 s at 5 s and 4 h runs); or a list"
                ),
            ),
            "grey_box_speed_taus_s": Setting(
                default="auto",
                schema=auto_or_numbers(positive=True),
                shown="`auto`",
                doc=(
                    "heat-input filters; `auto`: 12 P .. L/6, ratio 3 (60, 180, 540, 1600 s at 5 s and 4 h);"
                    " or a list"
                ),
            ),
            "grey_box_centrifugal_lags_s": Setting(
                default="auto",
                schema=auto_or_numbers(),
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
            "cv_time_blocks": Setting(
                default=4,
                schema={"type": "integer", "minimum": 2},
                shown="4",
                doc=(
                    "training data without a whole-run fold (one long training run): its training time is"
                    " cut into this many blocks, each held out in turn (fewer when the blocks would be"
                    " shorter than the gap; `docs/models.md`, Time-blocked folds)"
                ),
            ),
            "cv_time_block_gap_s": Setting(
                default=10800,
                schema=NON_NEGATIVE,
                shown="10800",
                doc=(
                    "guard gap (s) between time blocks: the gaps beside a held-out block never train its"
                    " fold, and no filter time constant above a third of it is a candidate then"
                ),
            ),
            "filter_restart_gap_s": Setting(
                default=3600,
                schema=NON_NEGATIVE,
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
                schema=NON_NEGATIVE,
                shown="2.0",
                doc="the champion's residual on new validation logs may grow this much",
            ),
            "drift_false_alarm": Setting(
                default=0.01,
                schema={"type": "number", "exclusiveMinimum": 0, "exclusiveMaximum": 1},
                shown="0.01",
                doc=(
                    "false-alarm rate of the interval drift test: recalibration is due when the new "
                    "validation samples (thinned to one per `decorrelation_s`) fall outside the champion's "
                    "interval so often that a machine as calibrated would do so with a probability below "
                    "this (one-sided binomial test; docs/operations.md)"
                ),
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
}
