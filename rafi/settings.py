"""The one settings resolver: every default, and the effective settings of a machine.

Standard library only: Snakemake imports this while it plans every run (``rafi nightly``
included), before any job starts.

Layers, lowest first; a dict merges key by key, any other value (lists included) replaces:

1. :data:`MACHINE_DEFAULTS` and :data:`RUN_DEFAULTS` below - the only place a default lives
   (the input mapping's own defaults live with the mapping, in
   :data:`rafi.readers.input_spec.INPUT_DEFAULTS`);
2. ``defaults:`` of ``config.yaml`` - what this installation changes for every machine;
3. ``machines: <name>:`` - what one machine changes.

Run settings (``raw_dir``, ``results_dir``, ``reports_dir``, ``on_bad_input`` and the options
``rafi nightly`` passes) are top-level keys of ``config.yaml``; per-machine sections
(``qualification:``, ``models:``, ...) are not, and :func:`check_layout` says where such a key
belongs instead of letting it be read by one job and ignored by another.
``docs/settings.md`` explains every key; ``rafi settings --machine NAME`` prints what a machine
gets.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Mapping

from rafi.errors import SettingsError
from rafi.readers.input_assumed import check_period
from rafi.readers.input_spec import normalise_input_spec

#: Largest backwards time step (sample periods) that cleaning repairs by sorting; more is a clock reset.
BACKWARDS_TOLERANCE_SAMPLES = 3.0

#: Run settings: top level of ``config.yaml`` (``--config key=value`` on the command line).
RUN_DEFAULTS: dict = {
    "raw_dir": "raw",
    "results_dir": "results",
    "reports_dir": "reports",
    # fail: the run stops at the first unreadable file; quarantine: the file is listed as
    # quarantined and the rest carries on (rafi nightly). The clean outputs are the same.
    "on_bad_input": "fail",
    "nightly_machines": None,  # rafi nightly --machine: only these machines
    "nightly_report": True,  # rafi nightly --no-report: false
    # a raw file modified less than this many seconds ago is still being written: it waits
    "settle_s": 0,
    "nightly_settle_s": 600,  # the settle_s of `rafi nightly`
    "debug": False,  # a user error prints its traceback too (rafi --debug, --config debug=true)
}

#: Every per-machine default (``docs/settings.md`` explains each key).
MACHINE_DEFAULTS: dict = {
    "input": {},  # rafi.readers.input_spec.INPUT_DEFAULTS (the native format)
    "sample_period_s": 5,
    "training_speeds_rpm": [3000, 6000, 9000, 12000, 15000, 18000],
    "speed_tolerance_rpm": 50,
    "checks": {
        # expected sign of dz while the machine warms up: positive (the spindle grows towards
        # the table, docs/raw-format.md), negative, or auto (the machine's other files)
        "probe_sign": "auto",
        # warnings a person has looked at: [{file: <name or glob>, check: <check id>}]
        "confirmed": [],
    },
    "clean": {
        "max_interpolate_gap_s": 60,
        "spike_threshold": 8,
        "open_circuit_values": [-999.0, 999.9, 850.0],
    },
    "runs": {
        "idle_below_rpm": 100,
        "min_run_s": 1800,
        "min_constant_s": 3600,
        "max_leading_rest_s": 300,
        "overrides": {},
        "windows": [],
        "idle_training": False,
        "allow_training_after_validation": False,
    },
    "reference": {"rule": "run_start", "window_s": 60},
    "equilibrium": {"band_fraction": 0.05, "plateau_window_s": 900, "smooth_window_s": 300},
    "rank": {"threshold": 0.97, "max_key_sensors": 3, "scope": "min_per_speed", "min_coverage": 0.9},
    "fit": {
        "terms": ["1", "x1", "x2", "x3", "x1*x2", "x1*x3", "x2*x3", "x1^2", "x2^2", "x3^2", "x1*x2*x3"],
        "hac_maxlags": 60,
    },
    "fuzzy": {"outside": "edge"},
    "qualification": {
        "max_residual_um": 12.0,
        "min_improvement_pct": 30.0,
        "never_worse_than_uncompensated": True,
    },
    "models": {
        "enabled": ["rafi", "rafi_linear", "ridge_global", "dynamic", "grey_box"],
        "cv": "leave_one_run_out",
        "cv_metric": "rmse",
        "ridge_alphas": [float(f"{m}e{e}") for e in range(-8, 1) for m in (1, 2, 5)] + [10.0],
        "dynamic_taus_s": "auto",
        "dynamic_max_taus": 2,
        "speed_gain": "cv",
        "speed_reference": "auto",
        "grey_box_taus_s": "auto",
        "grey_box_speed_taus_s": "auto",
        "grey_box_filter_search": "all",
        "grey_box_max_taus": 1,
        "grey_box_max_speed_taus": 2,
        "grey_box_centrifugal_lags_s": "auto",
        "grey_box_speed_powers": [0, 1, 5 / 3, 2],
        "grey_box_cv_metric": "max_abs",
        "filter_restart_gap_s": 3600,
    },
    "nightly": {
        "candidate": "family",
        "retrain_speed_range_rpm": None,
        "drift_margin_um": 2.0,
        # a candidate may be worse than the champion on a validation run by at most this (um);
        # "noise": the run's noise floor (rafi.method.noise)
        "champion_margin_um": "noise",
    },
    "report": {
        "figure_format": "png",
        # sensors the report names by role; none unless the machine's settings say so
        "coolant_sensors": [],
        "ambient_sensor": None,  # the sensor in the room air: the test record's ambient
        # the machine is the paper's rig (Chang et al. 2023): the paper's numbers are shown
        # beside this machine's; on any other machine they are left out
        "paper_rig": False,
        # the sign-off block on the first page: a value left out is a blank line to sign
        "document": {"number": None, "prepared_by": None, "approved_by": None, "approved_date": None},
        # test conditions for the test record, shown when given (a warning names what is missing)
        "instruments": {
            "machine_serial": None,
            "controller": None,
            "probe": None,  # displacement probe: make, model, resolution
            "sensor_positions": {},  # sensor -> where it sits, e.g. T8: rear spindle bearing
            "calibration": {},  # instrument -> calibration date (ISO 8601)
        },
    },
    # the model on the machine: limits and fault rules (rafi.deploy.limits), the live loop
    # (rafi deploy), the report's replay (docs/deploy.md)
    "deploy": {
        "clamp_um": [-50.0, 50.0],  # the command never leaves this range (um)
        "rate_um_per_s": 0.2,  # nor changes faster than this
        "temp_valid_c": [-10.0, 70.0],  # a temperature outside this range is a sensor fault
        # a sensor whose reading has not changed for stuck_s while another sensor the model
        # reads moved by stuck_change_k is stuck
        "stuck_s": 1800,
        "stuck_change_k": 0.5,
        # outside the trained range: a rise beyond its training range by more than
        # range_margin_k, a speed above the trained speeds by more than speed_margin_rpm
        "range_margin_k": 2.0,
        "speed_margin_rpm": 500,
        # on a fault or outside the trained range: hold the last good value for hold_s, then
        # ramp to safe_um at ramp_um_per_s
        "hold_s": 600,
        "safe_um": 0.0,
        "ramp_um_per_s": 0.02,
        "interval_s": 5,  # the live loop writes every interval_s
        "target": None,  # the controller (docs/deploy-targets.md); none: replay only
        "opcua": None,  # the OPC UA connection of the live loop (docs/deploy.md)
        "replay_roles": ["validation_multi"],  # the runs the report replays
    },
}

#: The promotion gates, in the order they are reported.
GATE_KEYS = tuple(MACHINE_DEFAULTS["qualification"])

#: Top-level keys of ``config.yaml``.
TOP_LEVEL_KEYS = frozenset(RUN_DEFAULTS) | {"defaults", "machines"}


def deep_merge(base: Mapping, override: Mapping | None) -> dict:
    """``base`` updated recursively with ``override`` (neither is modified).

    Dicts merge key by key; any other value in ``override`` (lists included) replaces the one
    in ``base``.
    """
    merged = copy.deepcopy(dict(base))
    for key, value in (override or {}).items():
        if isinstance(value, Mapping) and isinstance(merged.get(key), Mapping):
            merged[key] = deep_merge(merged[key], value)
        else:
            merged[key] = copy.deepcopy(value)
    return merged


def check_layout(config: Mapping) -> None:
    """Raise :class:`SettingsError` for a top-level key that is not a run setting.

    A per-machine section at the top level (``qualification:``, ``models:``, ...) would be
    read by nothing; the message says where it belongs.
    """
    misplaced = sorted(k for k in config if k not in TOP_LEVEL_KEYS)
    if not misplaced:
        return
    hints = []
    for key in misplaced:
        if key in MACHINE_DEFAULTS:
            hints.append(
                f"{key!r} is a per-machine setting: put it under 'defaults:' (every machine) or "
                f"'machines: <name>:' (one machine)"
            )
        else:
            hints.append(f"{key!r} is not a setting (top-level keys: {', '.join(sorted(TOP_LEVEL_KEYS))})")
    raise SettingsError("config.yaml: " + "; ".join(hints))


def run_settings(config: Mapping) -> dict:
    """The run settings (top level of ``config.yaml`` over :data:`RUN_DEFAULTS`)."""
    check_layout(config)
    out = copy.deepcopy(RUN_DEFAULTS)
    out.update({k: copy.deepcopy(v) for k, v in config.items() if k in RUN_DEFAULTS})
    return out


def machine_settings(config: Mapping, machine: str) -> dict:
    """Effective settings of one machine: every key present, nothing to default later.

    Parameters
    ----------
    config : Mapping
        ``config.yaml`` as loaded (validated against ``workflow/schemas/config.schema.yaml``).
    machine : str
        Folder name under ``raw_dir``.

    Returns
    -------
    dict
        A fresh copy of :data:`MACHINE_DEFAULTS` < ``defaults:`` < ``machines.<machine>``, with
        ``input`` normalised by :func:`rafi.readers.input_spec.normalise_input_spec` (its
        defaults filled in).
    """
    check_layout(config)
    merged = deep_merge(MACHINE_DEFAULTS, config.get("defaults"))
    merged = deep_merge(merged, (config.get("machines") or {}).get(machine))
    merged["input"] = normalise_input_spec(merged["input"])
    check_period(merged["input"], merged["sample_period_s"])
    return merged


def model_provenance(settings: Mapping) -> dict:
    """The settings recorded in ``model.json`` (``config``): everything upstream of the model."""
    keys = (
        "input",
        "sample_period_s",
        "training_speeds_rpm",
        "speed_tolerance_rpm",
        "clean",
        "runs",
        "reference",
        "rank",
        "fit",
        "fuzzy",
    )
    return {key: copy.deepcopy(settings[key]) for key in keys}


def candidate_model_path(machine: str, results_dir: str | os.PathLike, source: str) -> str:
    """Path of tonight's candidate model of ``machine``.

    ``source`` is ``nightly.candidate``: ``fit`` -> ``<results>/<machine>/model.json`` (RAFI as
    published, rule ``fit``); ``family`` -> ``<results>/<machine>/comparison/best_model.json``
    (the best model of the family, rule ``compare``). Decided from the settings when the job
    graph is built, not from which files exist, so the graph is the same before and after a run.
    """
    if source == "fit":
        return f"{results_dir}/{machine}/model.json"
    if source == "family":
        return f"{results_dir}/{machine}/comparison/best_model.json"
    raise SettingsError(f"nightly.candidate is {source!r}; expected 'fit' or 'family'")


# --------------------------------------------------------------------------- rafi settings


def add_arguments(parser) -> None:
    """``rafi settings``: print the effective settings of a machine."""
    parser.add_argument("--config", default="config.yaml", help="config file (default: config.yaml)")
    parser.add_argument("--machine", help="a machine folder under raw_dir (default: the run settings)")


def run(args) -> int:
    import sys

    import yaml

    try:
        with open(args.config, encoding="utf-8") as fh:
            config = yaml.safe_load(fh) or {}
        shown = machine_settings(config, args.machine) if args.machine else run_settings(config)
    except (OSError, yaml.YAMLError, SettingsError) as exc:
        print(f"rafi settings: {exc}", file=sys.stderr)
        return 2
    yaml.safe_dump(shown, sys.stdout, sort_keys=False, allow_unicode=True)
    return 0
