"""Sections 10 and 11 of the report: the choices the paper leaves open, and provenance."""

from __future__ import annotations

import datetime as _dt
import os
import platform
from importlib import metadata as _metadata

import pandas as pd

from rafi.family.selection import rule_of_candidates
from rafi.method.windows import describe_window
from rafi.report.format import isnum, truthy
from rafi.report.segmentation_section import SOURCE_TEXT


def section_choices(
    settings: dict,
    key_info: dict,
    eq_method,
    *,
    time_blocks: bool = False,
    forward: int = 0,
    interval: dict | None = None,
    comparison: dict | None = None,
    runs: pd.DataFrame | None = None,
) -> dict:
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
    time_blocks : bool
        The family's cross-validation used time-blocked folds (``comparison/cv.csv`` scheme
        ``time_blocks``: too few training runs for whole-run folds).
    forward : int
        Runs a forward-in-time fold held out when the family's selection also scored forward
        folds (``comparison/cv.csv`` scheme ``forward_<h>``); 0: it did not.
    interval : dict, optional
        How the offered model's prediction interval is computed
        (:func:`rafi.report.intervals.interval_context` of its artefact); ``None``: the results
        hold no interval and the list says nothing about one.
    comparison : dict, optional
        The comparison section's context (:func:`rafi.report.comparison_section.section_comparison`):
        the rule that chose the offered model, as applied (:func:`champion_rule`).
    runs : DataFrame, optional
        ``runs.csv``: where the roles came from (:func:`role_rules`).

    Returns
    -------
    dict
        The settings the sentences of ``templates/sections/choices.html.j2`` state:
        ``reference`` (``rule``, ``window_s``), ``rank`` (``scope``, ``threshold``,
        ``max_key_sensors``, ``min_coverage``), ``fallback_used`` and ``fallback_message``
        (``rank/key_sensors.json``), ``fuzzy_outside``, ``hac_maxlags`` and ``hac_span_s``,
        ``period_s``, ``clean`` (``spike_threshold``, ``open_circuit_values``,
        ``max_interpolate_gap_s``), ``runs`` (``min_constant_s``, ``idle_below_rpm``,
        ``max_leading_rest_s``), ``models`` (``enabled``, ``cv``, ``time_blocks``, ``forward``),
        ``paper``, ``interval``, ``champion`` (:func:`champion_rule`) and ``roles``
        (:func:`role_rules`).
    """
    ref, rank, fit = settings["reference"], settings["rank"], settings["fit"]
    clean, run_rules, models = settings["clean"], settings["runs"], settings["models"]
    period = float(settings["sample_period_s"])
    return {
        "reference": {"rule": ref["rule"], "window_s": ref["window_s"]},
        "rank": {k: rank[k] for k in ("scope", "threshold", "max_key_sensors", "min_coverage")},
        "fallback_used": truthy(key_info.get("fallback_used")),
        "fallback_message": key_info.get("message"),
        "fuzzy_outside": settings["fuzzy"]["outside"],
        "hac_maxlags": fit["hac_maxlags"],
        "hac_span_s": float(fit["hac_maxlags"]) * period,
        "period_s": period,
        "clean": {k: clean[k] for k in ("spike_threshold", "open_circuit_values", "max_interpolate_gap_s")},
        "runs": {
            k: run_rules[k]
            for k in ("min_constant_s", "min_run_s", "idle_below_rpm", "max_leading_rest_s", "idle_training")
        },
        "models": {
            "enabled": list(models["enabled"]),
            "cv": models["cv"],
            "time_blocks": bool(time_blocks),
            "forward": int(forward),
        },
        "paper": bool(settings["report"]["paper_rig"]),
        "interval": interval,
        "champion": champion_rule(comparison, settings),
        "roles": role_rules(runs, settings),
    }


def champion_rule(comparison: dict | None, settings: dict) -> dict:
    """How this run chose the model offered to the machine, as its comparison applied it.

    Parameters
    ----------
    comparison : dict or None
        The comparison section's context (:func:`rafi.report.comparison_section.section_comparison`:
        ``selection``, ``ensemble``, ``models``); ``None`` without ``comparison/summary.csv``.
    settings : dict
        The machine's settings (``models.offer``, ``models.enabled``).

    Returns
    -------
    dict
        ``how``: ``ensemble`` (the CV-weighted ensemble of this run's kinds, offered under
        ``models: offer: ensemble`` whatever its score), ``adapted`` (an ensemble prior adapted as
        a whole, offered by the re-qualification's rule), ``best`` (the lowest selection score),
        ``default`` (no CV fold: the default rule), ``none`` (no champion in ``summary.csv``) or
        ``setting`` (no comparison in the results: the rule of ``models.offer`` is stated);
        ``champion``; ``fitted`` (the models the comparison fitted and scored beside RAFI as
        published and the offered blend, in ``summary.csv`` order); ``plain_ridge`` (the plain
        ridge's name when it was scored as the reference only, not enabled; else ``None``);
        ``members`` (``model``, ``weight``, heaviest first) and ``score`` (the offered model's
        selection score, um); ``lowest`` (``model``, ``score``: the candidate with the lowest
        selection score when it is not the offered model; ``None`` otherwise); ``rule`` (the
        re-qualification's rule of the candidates, :func:`rafi.family.selection.rule_of_candidates`,
        ``""`` without a prior) and ``offer`` (``models.offer``).
    """
    out = {
        "how": "setting",
        "champion": None,
        "fitted": [],
        "plain_ridge": None,
        "members": [],
        "score": None,
        "lowest": None,
        "rule": "",
        "offer": str(settings["models"].get("offer", "best")),
    }
    if not comparison:
        return out
    rows = comparison.get("models") or []
    sel = comparison.get("selection") or {}
    ens = comparison.get("ensemble")
    champ = sel.get("champion")
    out["champion"] = champ
    out["rule"] = rule_of_candidates(r["model"] for r in rows)
    blend = champ if ens is not None and not ens.get("adapted") else None
    out["fitted"] = [r["model"] for r in rows if not r.get("is_rafi") and r["model"] != blend]
    ridge = next((r for r in rows if r.get("is_plain_ridge")), None)
    out["plain_ridge"] = ridge["model"] if ridge is not None and not ridge.get("candidate", True) else None
    if champ is None:
        out["how"] = "none"
        return out
    me = next((r for r in rows if r["model"] == champ), {})
    out["score"] = me.get("selection_score_um") if isnum(me.get("selection_score_um")) else None
    others = [
        r
        for r in rows
        if r["model"] != champ and r.get("candidate", True) and isnum(r.get("selection_score_um"))
    ]
    best = min(others, key=lambda r: float(r["selection_score_um"]), default=None)
    if best is not None and (out["score"] is None or float(best["selection_score_um"]) < float(out["score"])):
        out["lowest"] = {"model": best["model"], "score": float(best["selection_score_um"])}
    if ens is not None:
        out["how"] = "adapted" if ens.get("adapted") else "ensemble"
        out["members"] = [{"model": m["model"], "weight": m["weight"]} for m in ens.get("members") or []]
    elif sel.get("basis") == "default":
        out["how"] = "default"
    else:
        out["how"] = "best"
    return out


def window_text(spec: dict) -> str:
    """A window of ``runs.windows`` for people: :func:`rafi.method.windows.describe_window` and the
    logs it applies to where it names them (``training window start-end of the log (logs
    *_train*)``)."""
    glob = str(spec.get("log", "*") or "*")
    text = describe_window(spec)
    return text if glob == "*" else f"{text} (logs {glob})"


def role_rules(runs: pd.DataFrame | None, settings: dict) -> dict:
    """Where the roles of this run's runs came from, from ``runs.csv``.

    Parameters
    ----------
    runs : DataFrame or None
        ``runs.csv`` (``role_source``: ``window``, ``auto``, ``config``, ``leak_guard``; ``role``,
        ``kind``, ``run_id``).
    settings : dict
        The machine's settings (``runs.windows``, ``runs.idle_training``, ``training_speeds_rpm``,
        ``speed_tolerance_rpm``).

    Returns
    -------
    dict
        ``n_runs``; ``sources`` (one dict per source present, in the order window, auto, config,
        leak_guard, then any other: ``source``, ``text`` (:data:`rafi.report.segmentation_section.
        SOURCE_TEXT`), ``n``); ``windows`` (:func:`window_text` of each configured window);
        ``varying_training`` (the varying runs that train: a training window holds them) and
        ``training_speeds`` / ``tolerance_rpm`` (the speed rule's). Without ``runs.csv``
        ``n_runs`` is 0 and ``sources`` empty (the section then states the rules of the
        settings).
    """
    out = {
        "n_runs": 0,
        "sources": [],
        "windows": [window_text(w) for w in settings["runs"].get("windows") or []],
        "varying_training": [],
        "training_speeds": [float(v) for v in settings.get("training_speeds_rpm") or []],
        "tolerance_rpm": settings.get("speed_tolerance_rpm"),
    }
    if runs is None or not len(runs) or "role_source" not in runs:
        return out
    source = runs["role_source"].astype(str)
    counts = source.value_counts(sort=False).to_dict()
    order = ["window", "auto", "config", "leak_guard"]
    out["n_runs"] = len(runs)
    out["sources"] = [
        {"source": k, "text": SOURCE_TEXT.get(k, k), "n": int(counts[k])}
        for k in order + sorted(set(counts) - set(order))
        if k in counts
    ]
    if {"kind", "role"} <= set(runs.columns):
        trains = (runs["role"].astype(str) == "training") & (runs["kind"].astype(str) == "varying")
        out["varying_training"] = runs.loc[trains, "run_id"].astype(str).tolist()
    return out


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
