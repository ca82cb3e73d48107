"""Sections 10 and 11 of the report: the choices the paper leaves open, and provenance."""

from __future__ import annotations

import datetime as _dt
import os
import platform
from importlib import metadata as _metadata

from rafi.report.format import fmt_duration, fmt_num, truthy


def section_choices(settings: dict, key_info: dict, eq_method) -> list[dict]:
    """Section 10: how this run decided what the paper leaves open (from the machine's settings).

    Parameters
    ----------
    settings : dict
        The machine's settings, every key present (``rafi.settings``).
    key_info : dict
        ``rank/key_sensors.json`` (the fallback message).
    eq_method : str or None
        The equilibrium method recorded in ``equilibrium.csv`` (not repeated here: section
        Thermal equilibrium describes the method once).
    """
    ref, rank, fit = settings["reference"], settings["rank"], settings["fit"]
    clean, runs, models = settings["clean"], settings["runs"], settings["models"]
    rule = ref["rule"]
    period = float(settings["sample_period_s"])
    paper = bool(settings["report"]["paper_rig"])
    scope_text = (
        "the smallest |r| over the training speeds must pass"
        if rank["scope"] == "min_per_speed"
        else "all training runs pooled"
    )
    rule_text = {
        "run_start": "the median of the first {w} s of each run",
        "log_start": "the median of the first {w} s of the log/segment the run came from",
    }
    rows = [
        (
            "Regressors and target",
            "Temperature rises dT = T \u2212 T_ref (K) of the key sensors and displacement change "
            "dz = disp \u2212 disp_ref (\u00b5m); the reference state is "
            + rule_text.get(rule, "rule '{r}' over {w} s").format(w=ref["window_s"], r=rule)
            + f" (reference.rule = {rule}). Absolute temperatures would make the model depend on the "
            "season.",
        ),
        (
            "Thermal equilibrium",
            "Detected from dz with a band around the final plateau and cross-checked with a fitted "
            "first-order time constant; the method with this machine's parameters is described once, "
            "in section Thermal equilibrium.",
        ),
        (
            "Correlation scope",
            f"Pearson r of each sensor rise with dz, scope = {rank['scope']}"
            f" ({scope_text}); "
            f"threshold |r| > {rank['threshold']}, at most "
            f"{rank['max_key_sensors']} key sensors.",
        ),
        (
            "Fewer sensors than needed pass the threshold",
            "Fallback: the best-scoring sensors are taken up to max_key_sensors and marked "
            "'fallback' in rank/key_sensors.csv; the report shows the message."
            + (
                f" This run: {key_info.get('message')}"
                if truthy(key_info.get("fallback_used"))
                else " This run: not needed."
            ),
        ),
        (
            "Outside the trained speed range",
            f"fuzzy.outside = {settings['fuzzy']['outside']}: the nearest edge model is used with weight "
            "1 (no extrapolation in speed) and the sample is flagged outside_speed_range; samples "
            "whose key-sensor rises leave the fitted range are flagged outside_temp_range and counted "
            "in section Validation.",
        ),
        (
            "Standard errors",
            f"OLS coefficients with Newey-West (HAC) standard errors, {fit['hac_maxlags']} "
            f"lags ({fmt_duration(float(fit['hac_maxlags']) * period)} at this machine's "
            f"{fmt_num(period, 0, 's')} sample period), because successive samples of a thermal "
            "drift are strongly autocorrelated; the plain OLS errors are reported in "
            "fit/coefficients.csv but not used for inference.",
        ),
        (
            "Validation",
            "By whole run: a validation run is never used for training (no "
            "sample-wise cross-validation, which would leak through autocorrelation).",
        ),
        (
            "Fuzzy membership",
            "Triangular functions centred on the training speeds: the nearer training speed gets "
            "the larger weight"
            + (" (see Fuzzy blending for the paper's 0.334 / 0.666 wording)." if paper else "."),
        ),
        (
            "Cleaning the logs",
            f"Regular grid of {fmt_num(settings['sample_period_s'], 0, 's')}; duplicate rows "
            "dropped (first kept); rows at most 3 samples out of order re-sorted, a larger step back "
            "is an error; single-sample spikes (beyond both neighbours by more than "
            f"{clean['spike_threshold']} robust sigma of the first differences) replaced by "
            f"interpolation; open-circuit values {clean['open_circuit_values']} treated as "
            f"missing; gaps and dropouts up to {fmt_num(clean['max_interpolate_gap_s'], 0, 's')} "
            "interpolated linearly, a longer gap splits the log into segments (never bridged). Every "
            "action is listed per file in results/<machine>/clean/<file>.audit.csv.",
        ),
        (
            "Runs, roles and the rest before start",
            f"Runs are cut from the speed column: constant for at least "
            f"{fmt_num(runs['min_constant_s'], 0, 's')} at a training speed -> training, elsewhere "
            "-> single-speed validation; shorter steps -> one multi-condition run; speed below "
            f"{fmt_num(runs['idle_below_rpm'], 0, 'r/min')} -> idle cool-down (validated, never "
            "trained on). A rest at the start of a log shorter than "
            f"{fmt_num(runs['max_leading_rest_s'], 0, 's')} belongs to the run"
            + (
                ", so the reference state is the cold machine at rest, before the spindle turns "
                "(what a controller compensation is relative to)."
                if rule == "run_start"
                else f"; with reference.rule = {rule} the reference state is taken at the start of "
                "the log or segment a run was cut from, so a run cut later in a log does not start "
                "cold."
            )
            + " Roles can be overridden per file (runs.overrides).",
        ),
        (
            "Sensor dropouts",
            f"A sensor's correlation uses the samples it has; a sensor present in fewer than "
            f"{fmt_num(100 * float(rank['min_coverage']), 0, '%')} of a speed's samples is "
            "not ranked there. Samples with a missing key sensor are left out of the fit and "
            "get no prediction.",
        ),
        (
            "Model family and the champion",
            "Besides RAFI as published, the models in models.enabled "
            f"({', '.join(models['enabled'])}) "
            f"are fitted on the same training runs; their hyperparameters come from whole-run "
            f"cross-validation ({models['cv']}) on training runs only. The "
            "champion (the model offered to the machine) is the one with the lowest mean "
            "held-out max |residual| in that cross-validation; the validation runs are "
            "predicted once, after the choice, and a champion that fails a gate is a FAIL, "
            "not a reason to pick another model. RAFI as published is always reported as the "
            "paper's reference. A centrifugal (speed-squared) "
            "term is used only when training runs contain a speed step that identifies it.",
        ),
    ]
    return [{"topic": a, "text": b} for a, b in rows]


#: A list setting with more items than this is shown as its length and its two ends.
MAX_LIST_ITEMS = 8


def _flat(d, ref=None, prefix: str = "") -> dict:
    """``{"a.b.c": leaf}``: a dict is walked where ``ref`` (the defaults) has a non-empty dict
    (without ``ref``: where the dict is not empty); anything else (lists, a mapping whose
    default is ``{}`` such as ``input.columns``) is one leaf."""
    out = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        sub = ref.get(k) if isinstance(ref, dict) else None
        walk = isinstance(sub, dict) and bool(sub) if ref is not None else bool(v)
        if isinstance(v, dict) and walk:
            out.update(_flat(v, sub, key + "."))
        else:
            out[key] = v
    return out


def setting_text(value) -> str:
    """A setting's value for the appendix: YAML flow style on one line; ``none`` for null; a
    list longer than :data:`MAX_LIST_ITEMS` as ``[n values: first \u2026 last]``."""
    import yaml

    if isinstance(value, (list, tuple)):
        value = [v.item() if hasattr(v, "item") else v for v in value]
    if isinstance(value, list) and len(value) > MAX_LIST_ITEMS:
        ends = [setting_text(value[0]), setting_text(value[-1])]
        return f"[{len(value)} values: {ends[0]} \u2026 {ends[1]}]"
    if value is None:
        return "none"
    if isinstance(value, str):
        return value
    if isinstance(value, dict) and value:  # a mapping without defaults: "key: value; ..."
        return "; ".join(f"{k}: {setting_text(v)}" for k, v in value.items())
    if hasattr(value, "item") and not isinstance(value, (list, dict)):  # a numpy scalar
        value = value.item()
    text = yaml.safe_dump(value, default_flow_style=True, width=10**9, allow_unicode=True).strip()
    return text[: -len("...")].strip() if text.endswith("...") else text


def settings_changes(settings: dict, run: dict | None = None) -> list[dict]:
    """The settings of this machine that differ from the built-in defaults.

    Parameters
    ----------
    settings : dict
        The machine's effective settings (:func:`rafi.settings.machine_settings`).
    run : dict, optional
        Run settings shown beside them (``raw_dir``, ...): compared with
        :data:`rafi.settings.RUN_DEFAULTS`; keys that are not run settings are ignored.

    Returns
    -------
    list of dict
        ``key`` (dotted path), ``value`` and ``default`` (text; an en dash where the key has no
        default), in the order of the settings. ``input`` is compared with the defaults of
        the input mapping (:func:`rafi.readers.input_spec.normalise_input_spec` of ``{}``).
    """
    from rafi.readers.input_spec import normalise_input_spec
    from rafi.settings import MACHINE_DEFAULTS, RUN_DEFAULTS

    defaults = {**MACHINE_DEFAULTS, "input": normalise_input_spec(MACHINE_DEFAULTS["input"])}
    rows = []
    for section, ref in (((run or {}), RUN_DEFAULTS), (settings, defaults)):
        flat_ref = _flat(ref)
        for key, value in _flat({k: v for k, v in section.items() if k in ref}, ref).items():
            missing = key not in flat_ref
            if not missing and flat_ref[key] == value:
                continue
            if missing and value in ({}, [], None):
                continue
            rows.append(
                {
                    "key": key,
                    "value": setting_text(value),
                    "default": "\u2013" if missing else setting_text(flat_ref[key]),
                }
            )
    return rows


def versions() -> list[dict]:
    """Versions of Python and of the packages the pipeline and the report use."""
    out = [{"name": "python", "version": platform.python_version()}]
    for pkg in (
        "rafi",
        "numpy",
        "pandas",
        "scipy",
        "statsmodels",
        "snakemake",
        "matplotlib",
        "jinja2",
        "weasyprint",
        "pyarrow",
    ):
        try:
            v = _metadata.version(pkg)
        except _metadata.PackageNotFoundError:
            v = "not installed"
        out.append({"name": pkg, "version": v})
    return out


def generated_at(now=None) -> str:
    """``now`` (default: ``SOURCE_DATE_EPOCH`` if set, else the clock) as ``YYYY-MM-DD HH:MM UTC``."""
    if now is None:
        epoch = os.environ.get("SOURCE_DATE_EPOCH")
        now = _dt.datetime.fromtimestamp(int(epoch), _dt.UTC) if epoch else _dt.datetime.now(_dt.UTC)
    return now.strftime("%Y-%m-%d %H:%M UTC")
