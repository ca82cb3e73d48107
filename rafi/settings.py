"""The one settings resolver: every default, and the effective settings of a machine.

Standard library only: Snakemake imports this while it plans every run (``rafi nightly``
included), before any job starts.

Layers, lowest first; a dict merges key by key, any other value (lists included) replaces:

1. :data:`MACHINE_DEFAULTS` and :data:`RUN_DEFAULTS` below, read off :mod:`rafi.contract` - the
   only place a default lives (the input mapping's own defaults too:
   :data:`rafi.contract.INPUT_DEFAULTS`);
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
import re
from collections.abc import Mapping

from rafi.contract import (
    GATE_KEYS,
    MACHINE_SETTINGS,
    PROBE_SEPARATOR,
    RUN_SETTINGS,
    config_schema,
    defaults,
    retired_setting,
)
from rafi.errors import InputSpecError, SettingsError
from rafi.readers.input_assumed import check_period
from rafi.readers.input_spec import normalise_input_spec, probe_spec

#: Largest backwards time step (sample periods) that cleaning repairs by sorting; more is a clock reset.
BACKWARDS_TOLERANCE_SAMPLES = 3.0

#: A daylight-saving change moves a local clock by this many seconds (one hour) ...
DAYLIGHT_SAVING_SHIFT_S = 3600.0
#: ... and a backwards jump within this many seconds of it is worded as one (a fall-back between
#: two samples of up to 5 min reads as a jump back of 55-60 min).
DAYLIGHT_SAVING_SLACK_S = 300.0


def backwards_cause(back_s: float) -> str:
    """The likely cause of a clock that goes back by ``back_s`` seconds, for its error: a
    daylight-saving change (about an hour: ``input.time.timezone``), else a clock reset."""
    if abs(back_s - DAYLIGHT_SAVING_SHIFT_S) <= DAYLIGHT_SAVING_SLACK_S:
        return (
            "a daylight-saving change? set input.time.timezone to the logger's time zone "
            "(e.g. Europe/Berlin), or check the zone set there; else a clock reset: split the file "
            "there or correct the clock"
        )
    return "a clock reset? split the file there or correct the clock"


#: Run settings: top level of ``config.yaml`` (``--config key=value`` on the command line); each
#: key's type, default and meaning is in :data:`rafi.contract.RUN_SETTINGS`.
RUN_DEFAULTS: dict = defaults(RUN_SETTINGS)

#: Every per-machine default (:data:`rafi.contract.MACHINE_SETTINGS`; ``docs/settings.md``).
MACHINE_DEFAULTS: dict = defaults(MACHINE_SETTINGS)

#: The promotion gates (re-exported for the method and ops, which read settings here).
__all__ = ["GATE_KEYS"]

#: Top-level keys of ``config.yaml``.
TOP_LEVEL_KEYS = frozenset(RUN_DEFAULTS) | {"defaults", "machines"}


def truthy(value) -> bool:
    """A flag as a setting or a table cell carries it: ``True``, ``1``, ``"yes"``, ``"true"``, ``"on"``.

    The one reading of booleans (``--config debug=true`` arrives as a string, a CSV column as
    ``"True"``): any other string, ``None`` and ``0`` are false.
    """
    if isinstance(value, str):
        return value.strip().lower() in ("1", "true", "yes", "on")
    return bool(value)


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


def validate_config(config: Mapping) -> None:
    """Check ``config`` (``config.yaml`` as loaded) against the contract's schema, with jsonschema.

    The workflow validates the same schema (``workflow/schemas/config.schema.yaml``, generated
    from :mod:`rafi.contract`) while it plans; the commands that read the config without
    Snakemake (``rafi settings``, ``nightly``, ``status``, ``deploy``) call this.

    Raises
    ------
    SettingsError
        Naming the first key the schema refuses (``machines.m.deploy.hold_s``) and why; a
        retired key (:data:`rafi.contract.RETIRED_SETTINGS`) with what replaced it.
    """
    import jsonschema

    check_layout(config)  # a misplaced section: say where it belongs, not only that it is unexpected
    retired = retired_setting(config)  # a removed key: say what replaced it
    if retired:
        raise SettingsError(retired)
    validator = jsonschema.Draft202012Validator(config_schema())
    # the most specific error (best_match descends into anyOf/oneOf: machines.<name> is one)
    first = jsonschema.exceptions.best_match(validator.iter_errors(dict(config)))
    if first is not None:
        from rafi.secret_mask import scrub

        where = ".".join(str(p) for p in first.absolute_path) or "top level"
        raise SettingsError(scrub(f"config.yaml: {where}: {first.message}", config))  # never a secret


def run_settings(config: Mapping) -> dict:
    """The run settings (top level of ``config.yaml`` over :data:`RUN_DEFAULTS`)."""
    check_layout(config)
    out = copy.deepcopy(RUN_DEFAULTS)
    out.update({k: copy.deepcopy(v) for k, v in config.items() if k in RUN_DEFAULTS})
    return out


def split_unit(name: str) -> tuple[str, str | None]:
    """``(machine, probe)`` of a qualification unit's name: ``fl-thermal@ch1`` -> ``("fl-thermal",
    "ch1")``; a machine with one probe is its own unit (``probe`` None)."""
    machine, sep, probe = str(name).partition(PROBE_SEPARATOR)
    return (machine, probe) if sep else (machine, None)


def unit_name(machine: str, probe: str | None) -> str:
    """The name of the unit of ``machine``'s probe ``probe`` (:func:`split_unit` reversed)."""
    return machine if probe is None else f"{machine}{PROBE_SEPARATOR}{probe}"


def probes_by_machine(units) -> dict[str, list[str]]:
    """Machine -> its probes in order, of the units (:func:`split_unit`) that are probes."""
    out: dict[str, list[str]] = {}
    for unit in units:
        machine, probe = split_unit(unit)
        if probe is not None:
            out.setdefault(machine, []).append(probe)
    return out


def one_of_pattern(names) -> str:
    """A regular expression that matches exactly one of ``names`` (escaped), or nothing when
    there are none: a rule's ``wildcard_constraints`` that keeps it to those names (a machine
    with several probes for ``probes_report``), so Snakemake never calls its input function
    for another folder."""
    names = sorted(names, key=len, reverse=True)  # a name that is a prefix of another comes last
    return "|".join(re.escape(n) for n in names) if names else "(?!)"


def machine_units(config: Mapping, machine: str) -> list[str]:
    """What the pipeline qualifies of ``machine``: one unit per probe of its ``input.probes``
    (``<machine>@<probe>``, in the mapping's order), else the machine itself."""
    probes = machine_settings(config, machine)["input"]["probes"]
    return [unit_name(machine, probe) for probe in probes] or [machine]


def machine_settings(config: Mapping, machine: str) -> dict:
    """Effective settings of one machine, or of one probe of it: every key present, nothing to
    default later.

    Parameters
    ----------
    config : Mapping
        ``config.yaml`` as loaded (validated against ``workflow/schemas/config.schema.yaml``).
    machine : str
        Folder name under ``raw_dir``; or ``<folder>@<probe>``, a probe of its ``input.probes``
        (:func:`split_unit`), whose column, unit and sign then are ``input.displacement`` and
        over which ``machines.<folder>@<probe>`` is merged (what one probe changes: its deploy
        target, its gates; not its input).

    Returns
    -------
    dict
        A fresh copy of :data:`MACHINE_DEFAULTS` < ``defaults:`` < ``machines.<machine>``, with
        ``input`` normalised by :func:`rafi.readers.input_spec.normalise_input_spec` (its
        defaults filled in).

    Raises
    ------
    SettingsError
        The name asks for a probe the machine does not have.
    """
    check_layout(config)
    folder, probe = split_unit(machine)
    machines = config.get("machines") or {}
    merged = deep_merge(MACHINE_DEFAULTS, config.get("defaults"))
    merged = deep_merge(merged, machines.get(folder))
    if probe is not None:  # what this probe changes (machines.<machine>@<probe>), its input aside
        own = dict(machines.get(machine) or {})
        if "input" in own:
            raise SettingsError(
                f"machines.{machine}.input: a probe reads its machine's files; give its column, unit "
                f"and sign in machines.{folder}.input.probes.{probe}"
            )
        merged = deep_merge(merged, own)
    merged["input"] = normalise_input_spec(merged["input"])
    if probe is not None:
        try:
            merged["input"] = probe_spec(merged["input"], probe)
        except InputSpecError as exc:
            raise SettingsError(f"machines.{folder}.{exc}") from None
    check_period(merged["input"], merged["sample_period_s"])
    return merged


def read_config(config_path: str | os.PathLike, *, say: bool = True) -> dict:
    """``config.yaml`` as every command reads it: ``{}`` for an empty file, and a prior's id in
    ``checks.confirmed`` written unquoted taken back where it can only be that id, said on stderr
    (:func:`rafi.family.confirmation.unquoted_ids`, as the workflow does; ``say=False`` for a
    command's second reading of the same file), so that ``rafi settings`` and the pipeline read
    the same settings.

    Raises
    ------
    SettingsError
        The file cannot be read or parsed (one line naming it), or an unquoted number in
        ``checks.confirmed`` cannot be an id.
    """
    import sys

    import yaml

    from rafi.family.confirmation import taken_back_line, unquoted_ids

    try:
        with open(config_path, encoding="utf-8") as fh:
            config = yaml.safe_load(fh) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise SettingsError(f"{config_path}: cannot read the config ({exc})") from None
    for taken in unquoted_ids(config):
        if say:
            print(f"rafi: {taken_back_line(taken)}", file=sys.stderr)
    return config


def read_machine_config(config_path: str | os.PathLike, machine: str) -> tuple[dict, dict]:
    """``(config, the machine's settings)`` of a command that works on one named machine.

    Raises
    ------
    SettingsError
        The file cannot be read or parsed, or ``machine`` is not under ``machines:`` (a typo would
        otherwise start a new machine folder): one line naming the file and the machines it has.
    """
    from rafi.errors import short_path

    config = read_config(config_path)
    known = sorted((config.get("machines") or {}) if isinstance(config, dict) else {})
    if split_unit(machine)[0] not in known:
        raise SettingsError(
            f"--machine {machine!r} is not under machines: in {short_path(config_path)} (known: "
            f"{', '.join(known) or 'none'}); add it there first, so that its settings are the ones used"
        )
    return config, machine_settings(config, machine)


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


#: ``rafi settings --help`` (the module docstring above is for developers).
CLI_DESCRIPTION = """Print the effective settings of a machine: every key of config.yaml with the value this
machine gets, every default filled in.

Layers, lowest first (a mapping merges key by key, any other value, lists included, replaces):
the built-in defaults (docs/settings.md lists each with its meaning); `defaults:` of config.yaml,
what this installation changes for every machine; `machines: <name>:`, what one machine changes.
A key in the wrong place (a per-machine section at the top level) is refused with where it belongs.
"""


def add_arguments(parser) -> None:
    """``rafi settings``: print the effective settings of a machine."""
    from rafi.cli import add_config_option

    add_config_option(parser)
    parser.add_argument("--machine", help="a machine folder under raw_dir (default: the run settings)")


def run(args) -> int:
    import sys

    import yaml

    from rafi.errors import EX_USAGE
    from rafi.secret_mask import MASK, masked, secret_paths

    try:
        config = read_config(args.config)
        validate_config(config)
        shown = machine_settings(config, args.machine) if args.machine else run_settings(config)
    except (OSError, yaml.YAMLError, SettingsError) as exc:
        print(f"rafi settings: {exc}", file=sys.stderr)
        return 2
    yaml.safe_dump(masked(shown), sys.stdout, sort_keys=False, allow_unicode=True)
    secrets = secret_paths(config)
    if secrets:  # shown as MASK; rafi deploy / rafi record refuse the config
        print(
            f"rafi settings: {args.config}: {secrets[0]}"
            f"{f' (and {len(secrets) - 1} more)' if len(secrets) > 1 else ''} holds a credential "
            f"(shown as {MASK}): credentials never go to config.yaml, and rafi deploy and rafi record "
            "refuse this config; move it to the environment or a credentials file "
            "(docs/deploy.md#credentials)",
            file=sys.stderr,
        )
        return EX_USAGE
    return 0
