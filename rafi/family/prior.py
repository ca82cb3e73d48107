"""The prior of a re-qualification (``models: prior``, ``docs/models.md``): which fitted artefact
the adaptation family (:mod:`rafi.family.adapted`) starts from, and whether it may.

* :func:`prior_chain` resolves the setting against the registry
  (:class:`rafi.ops.registry.Registry`): the champion of the machine (or of a sibling) and then
  each model's ``adaptation.parent``, in order.
* :func:`choose_prior` applies the honesty rule: the first artefact of the chain that has seen
  none of the current runs (:func:`seen_data`: its ``data`` and its ``adaptation.prior_data``,
  against every current run's ``sha256``, training or validation).
* :func:`check_compatible` refuses a prior whose sensors have no data here or that was qualified
  for another probe (:class:`rafi.errors.PriorIncompatible`, one line). Only physics is compared:
  the probe's sign and the reference rule are properties of the logs (the readers apply
  ``input.displacement.sign``, every reference rule measures from the cold machine at rest), and
  the adapted model takes this machine's (:class:`rafi.family.adapted.AdaptedPrior`).
* :func:`prior_origin` / :func:`check_origin`: where the prior comes from (this machine, a
  sibling declared in ``models.prior_siblings``, or elsewhere); a prior from elsewhere is
  refused (:class:`rafi.errors.PriorForeign`, one line naming its id, its machine and the key);
* :func:`prior_qualification` is the prior's own qualification (its promotion in its registry:
  date, worst validation residual, training speeds), for the fitness figures and the report;
  the date is a fact of that registry, not of the data, so the fitness block leaves it out (the
  adapted model's id depends on content only) and the report and ``rafi status`` read it from
  the registry (:func:`prior_promoted`).
* :func:`prior_base`: what the adaptation re-fits. A prior that is a CV-weighted ensemble
  (:mod:`rafi.family.ensemble`, the champion of a machine qualified under ``models: offer:
  ensemble``) is adapted through its heaviest member (the largest weight): the adaptation family
  re-fits one model's coefficients and time constants, and a gain or a ridge on a blend of six
  kinds would be six adaptations in one. The prior stays the ensemble everywhere else (its
  id is the adapted model's ``adaptation.parent``, its registry record is its qualification, its
  ``data`` is what it learnt from); :func:`ensemble_member` says which member, for the fitness
  block and the report.
* :func:`prior_param` is what ``rule compare`` gets while Snakemake plans: the chain from its
  first model disjoint from the machine's raw files (ids only), so that promoting a champion
  trained on these logs changes nothing the workflow sees.

Standard library only at import (``workflow/rules/common.smk`` imports it while planning).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from rafi.errors import PriorForeign, PriorIncompatible, PriorUnavailable, RegistryError

__all__ = [
    "PRIOR_MODES",
    "RIDGE_KINDS",
    "ORIGINS",
    "prior_source",
    "prior_chain",
    "prior_origin",
    "check_origin",
    "prior_qualification",
    "prior_promoted",
    "prior_record",
    "seen_data",
    "choose_prior",
    "ENSEMBLE_KIND",
    "prior_base",
    "ensemble_member",
    "prior_sensors",
    "prior_probe",
    "check_compatible",
    "prior_param",
    "available_sensors",
    "resolved_prior",
    "parent_of",
    "registry_meta",
]

#: The string values of ``models: prior`` (a mapping ``{machine: <name>}`` is the fourth form).
PRIOR_MODES = ("auto", "none", "champion")
#: The kinds whose prediction is ``features @ coefficients`` (``prior_ridge`` is offered for these).
RIDGE_KINDS = ("ridge_global", "dynamic", "grey_box", "temperature_ridge")
#: Where a prior may come from (:func:`prior_origin`), in the words of the fitness block.
ORIGINS = ("this machine", "declared sibling")
#: The kind of a CV-weighted ensemble's artefact (:data:`rafi.family.ensemble.ENSEMBLE`; spelt out
#: here, this module imports the standard library only).
ENSEMBLE_KIND = "ensemble"
#: A guard against a corrupt registry whose parents form a very long chain.
MAX_CHAIN = 100


def prior_source(setting, machine: str) -> tuple[str, str]:
    """``(mode, source machine)`` of a ``models: prior`` value: mode ``auto``, ``none``,
    ``champion`` (the machine's own registry) or ``sibling`` (``{machine: <name>}``)."""
    if isinstance(setting, dict):
        name = setting.get("machine")
        if set(setting) != {"machine"} or not isinstance(name, str) or not name:
            raise PriorUnavailable(
                f"models.prior: {setting!r} is not a prior; use auto, none, champion or {{machine: <name>}}"
            )
        return "sibling", name
    if setting not in PRIOR_MODES:
        raise PriorUnavailable(
            f"models.prior: {setting!r} is not a prior; use auto, none, champion or {{machine: <name>}}"
        )
    return str(setting), machine


def _registry(results_dir: str | os.PathLike, machine: str):
    from rafi.ops.registry import Registry, registry_dir

    return Registry(registry_dir(results_dir, machine), machine)


def source_unit(results_dir: str | os.PathLike, setting, machine: str) -> tuple[str, str]:
    """``(mode, source)`` of :func:`prior_source`, a sibling's name mapped to its unit of the same
    probe: for a unit ``a@Z`` of a machine with several probes, ``{machine: b}`` is ``b@Z`` when
    ``results_dir`` holds that unit's registry (``b`` qualified per probe), else ``b``."""
    from rafi.ops.registry import registry_dir
    from rafi.settings import split_unit, unit_name

    mode, source = prior_source(setting, machine)
    probe = split_unit(machine)[1]
    if mode == "sibling" and probe is not None and split_unit(source)[1] is None:
        unit = unit_name(source, probe)
        if Path(registry_dir(results_dir, unit)).is_dir():
            return mode, unit
    return mode, source


def prior_chain(results_dir: str | os.PathLike, machine: str, setting) -> list[dict]:
    """The candidate priors of ``machine`` under ``models: prior`` = ``setting``, in order.

    Parameters
    ----------
    results_dir : str or path
        The folder holding ``<machine>/registry`` (``results_dir`` of the run settings).
    machine : str
        The machine being qualified.
    setting : str or dict
        ``auto`` (the champion chain when the registry has a champion, else none), ``none``,
        ``champion`` (required) or ``{machine: <name>}`` (a sibling's champion chain, required;
        of the same probe, :func:`source_unit`).

    Returns
    -------
    list of dict
        The champion's artefact, then its ``adaptation.parent``'s, and so on; the walk stops at
        a parent missing from the registry or already seen (a cycle).

    Raises
    ------
    PriorUnavailable
        ``champion`` or a sibling without a champion (the message names the registry path).
    """
    mode, source = source_unit(results_dir, setting, machine)
    if mode == "none":
        return []
    reg = _registry(results_dir, source)
    try:
        champion_id = reg.champion_id()
    except (OSError, ValueError):
        champion_id = None
    if champion_id is None or not reg.has_model(champion_id):
        if mode == "auto":
            return []
        what = "models.prior: champion" if mode == "champion" else f"models.prior: {{machine: {source}}}"
        raise PriorUnavailable(
            f"{what}: {reg.root} has no champion; qualify {source} first, or set models.prior to auto or none"
        )
    chain, seen, model_id = [], set(), champion_id
    while model_id and model_id not in seen and len(chain) < MAX_CHAIN and reg.has_model(model_id):
        seen.add(model_id)
        try:
            artefact = reg.load_model_dict(model_id)
        except (RegistryError, OSError, ValueError):
            break  # a modified file ends the chain: never start from an unverified model
        chain.append(artefact)
        model_id = (artefact.get("adaptation") or {}).get("parent")
    return chain


def seen_data(artefact: dict) -> set[str]:
    """The sha256 of every file an artefact learnt from: its ``data`` and, for an adapted model,
    its prior's (``adaptation.prior_data``, itself the prior's whole lineage)."""
    data = dict(artefact.get("data") or {})
    prior = (artefact.get("adaptation") or {}).get("prior_data") or {}
    return {str(h) for h in list(data.values()) + list(prior.values()) if h}


def _current_hashes(runs_table) -> set[str]:
    if runs_table is None or "sha256" not in getattr(runs_table, "columns", ()):
        return set()
    return {str(h) for h in runs_table["sha256"].tolist() if isinstance(h, str) and h}


def _first_disjoint(chain: list[dict], current: set[str]) -> int | None:
    for k, artefact in enumerate(chain):
        if not seen_data(artefact) & current:
            return k
    return None


def choose_prior(chain: list[dict], runs_table) -> tuple[dict | None, str]:
    """The first artefact of ``chain`` that has seen none of the current runs, and why.

    Parameters
    ----------
    chain : list of dict
        :func:`prior_chain`.
    runs_table : pandas.DataFrame
        ``runs.csv`` (``file``, ``sha256``): every run, training and validation.

    Returns
    -------
    (dict or None, str)
        The prior (``None``: none) and one line for the log and the report.
    """
    if not chain:
        return None, "no prior: the registry offers none (models.prior)"
    k = _first_disjoint(chain, _current_hashes(runs_table))
    if k is None:
        who = "the champion" if len(chain) == 1 else f"the champion and its {len(chain) - 1} parent(s)"
        return None, f"no prior: {who} learnt from some of these logs"
    prior = chain[k]
    skipped = f"; {k} newer model(s) of the chain learnt from these logs" if k else ""
    member = ensemble_member(prior) if prior.get("kind") == ENSEMBLE_KIND else None
    through = (
        f"; adapted through its heaviest member {member['name']} ({member['kind']}, weight "
        f"{member['weight']:.3f} of {member['n_members']})"
        if member
        else ""
    )
    return prior, (
        f"prior {str(prior.get('model_id', ''))[:12]} ({prior.get('kind')} of {prior.get('machine')}, "
        f"trained on {len(seen_data(prior))} other log(s)){through}{skipped}"
    )


def _heaviest(weights: dict) -> str | None:
    """The name with the largest weight, the first of equals
    (:meth:`rafi.family.ensemble.WeightedEnsemble.heaviest_member`)."""
    return max(weights, key=lambda n: float(weights[n])) if weights else None


def prior_base(prior: dict) -> dict:
    """The artefact a re-qualification re-fits: ``prior`` itself, or for a CV-weighted ensemble
    (``kind: ensemble``) its heaviest member's own artefact (module docstring)."""
    if prior.get("kind") != ENSEMBLE_KIND:
        return prior
    name = _heaviest(prior.get("weights") or {})
    members = prior.get("members") or {}
    if name is None or not isinstance(members.get(name), dict):
        raise PriorIncompatible(
            f"prior {str(prior.get('model_id', '?'))[:12]}: an ensemble without its members' artefacts "
            "(weights and members); set models.prior: none"
        )
    return members[name]


def ensemble_member(prior: dict) -> dict | None:
    """For a CV-weighted ensemble prior, the member the adaptation re-fits (:func:`prior_base`):
    ``name``, ``kind``, ``model_id``, ``weight`` and ``n_members``; ``None`` for any other prior."""
    if prior.get("kind") != ENSEMBLE_KIND:
        return None
    weights = prior.get("weights") or {}
    name = _heaviest(weights)
    base = prior_base(prior)
    return {
        "name": name,
        "kind": base.get("kind"),
        "model_id": str(base.get("model_id") or ""),
        "weight": float(weights[name]),
        "n_members": len(weights),
    }


def prior_sensors(prior: dict) -> list[str]:
    """The temperature sensors a prior reads (its ``key_sensors``; an ensemble's: those of the
    member the adaptation re-fits, :func:`prior_base`)."""
    return [str(s) for s in prior_base(prior).get("key_sensors") or []]


def prior_probe(prior: dict) -> str | None:
    """The probe a prior was qualified for: the part after ``@`` of its ``machine`` (a unit of a
    machine with several probes, ``spindle-7@Z``), else ``None`` (a machine with one probe)."""
    from rafi.settings import split_unit

    return split_unit(str(prior.get("machine") or ""))[1]


def _machine_part(name: str) -> str:
    from rafi.settings import split_unit

    return split_unit(name)[0]


def prior_origin(prior_machine: str | None, machine: str, siblings: Iterable[str] = ()) -> str | None:
    """Where a prior of ``prior_machine`` comes from, for ``machine``: ``"this machine"`` (the
    same unit), ``"declared sibling"`` (the unit, or its machine, is in ``siblings``:
    ``models.prior_siblings``) or ``None`` (elsewhere: refused by :func:`check_origin`).

    A probe unit ``m@X`` is its own machine: a prior of ``m@Y`` for it is a sibling only when
    declared (``m@Y``, or ``m`` for every probe of ``m``).
    """
    if not prior_machine:
        return None
    if str(prior_machine) == str(machine):
        return ORIGINS[0]
    declared = {str(s) for s in siblings or ()}
    if str(prior_machine) in declared or _machine_part(str(prior_machine)) in declared:
        return ORIGINS[1]
    return None


def check_origin(prior: dict, machine: str, siblings: Iterable[str] = (), source: str | None = None) -> str:
    """The origin of ``prior`` (:func:`prior_origin`; its machine: the artefact's ``machine``,
    else ``source``, the registry it was read from); raise :class:`rafi.errors.PriorForeign`
    (one line: the prior's id, its machine, the key to set) for a prior from elsewhere."""
    prior_machine = str(prior.get("machine") or source or "")
    origin = prior_origin(prior_machine, machine, siblings)
    if origin is None:
        pid = str(prior.get("model_id", "?"))[:12]
        name = _machine_part(prior_machine) or "<machine>"
        raise PriorForeign(
            f"prior {pid} is a model of {prior_machine or 'an unnamed machine'}, neither {machine} nor a "
            f"declared sibling of it; if the two are of one design set models.prior_siblings: [{name}] "
            f"in {machine}'s settings, else models.prior: none"
        )
    return origin


def prior_qualification(registry_root: str | os.PathLike, prior: dict) -> dict:
    """The prior's own qualification, from its registry (``registry_root``): ``model_id``,
    ``machine``, ``kind``, ``promoted`` (time of the decision that made it champion, or
    ``None``), ``max_residual_um`` and ``n_runs`` (its worst validation residual at that
    decision) and ``speeds_rpm`` (the speeds it was trained at: its per-speed models, else its
    promotion's ``training.speeds_rpm``, else ``None``)."""
    from rafi.artefact import read_jsonl
    from rafi.ops.registry import promotion_record

    model_id = str(prior.get("model_id") or "")
    history = []
    try:
        history = read_jsonl(Path(registry_root) / "history.jsonl")
    except (OSError, ValueError):
        pass
    record = promotion_record(history, model_id) or {}
    summary = record.get("candidate_summary") if record.get("candidate_id") == model_id else None
    speeds = [float(s["speed_rpm"]) for s in prior.get("speeds") or [] if "speed_rpm" in s]
    if not speeds:
        speeds = list(((record.get("training") or {}).get("speeds_rpm")) or [])
    return {
        "model_id": model_id,
        "machine": prior.get("machine"),
        "kind": prior.get("kind"),
        "promoted": record.get("time"),
        "max_residual_um": (summary or {}).get("max_residual_um"),
        "n_runs": (summary or {}).get("n_runs"),
        "speeds_rpm": sorted({float(s) for s in speeds}) or None,
    }


def prior_promoted(results_dir: str | os.PathLike, machine: str | None, model_id: str | None) -> str | None:
    """When the prior ``model_id`` of ``machine`` was made champion: the time of its promotion
    record in ``<results_dir>/<machine>/registry/history.jsonl``, or ``None`` (no such registry or
    record).

    A fact of that registry, not of the data: it differs between two installations that made the
    same model champion, so it is read where it is shown (the report, ``rafi status``) and kept out
    of the adapted model's artefact, whose ``model_id`` depends on content only.
    """
    from rafi.artefact import read_jsonl
    from rafi.ops.registry import promotion_record, registry_dir

    if not machine or not model_id:
        return None
    try:
        history = read_jsonl(registry_dir(results_dir, str(machine)) / "history.jsonl")
    except (OSError, ValueError):
        return None
    return (promotion_record(history, str(model_id)) or {}).get("time")


def check_compatible(prior: dict, *, sensors_available: Iterable[str], unit: str | None = None) -> None:
    """Raise :class:`rafi.errors.PriorIncompatible` unless ``prior`` can be applied here.

    Only physics is compared: the sensors the prior reads must have data here (the names map:
    ``input.columns`` maps any header to a sensor name), and a prior qualified for one probe of a
    machine with several (``<machine>@<probe>``) serves the same probe only. The displacement
    sign and the reference rule are not compared: they describe how the logs were written (the
    readers multiply by ``input.displacement.sign``, so every model is fitted in the physical
    convention; ``log_start`` in a continuous log and ``run_start`` on cold-start files both
    measure from the cold machine at rest), and the adapted model takes this machine's reference
    (:class:`rafi.family.adapted.AdaptedPrior`, ``reference``).

    Parameters
    ----------
    prior : dict
        The prior's artefact.
    sensors_available : iterable of str
        The sensors with data in the current runs (``T1`` ...).
    unit : str, optional
        The unit being qualified (``machine`` or ``machine@probe``); None: the probe is not checked.
    """
    from rafi.settings import split_unit

    pid = str(prior.get("model_id", "?"))[:12]
    missing = [s for s in prior_sensors(prior) if s not in set(map(str, sensors_available))]
    if missing:
        raise PriorIncompatible(
            f"prior {pid}: sensor(s) {', '.join(missing)} it reads have no data here; a replaced or "
            "renamed sensor? (map it in input.columns, or set models.prior: none)"
        )
    probe_prior = prior_probe(prior)
    probe_now = split_unit(unit)[1] if unit else None
    if probe_prior is not None and probe_now is not None and probe_prior != probe_now:
        raise PriorIncompatible(
            f"prior {pid}: qualified for probe {probe_prior} ({prior.get('machine')}), this is probe "
            f"{probe_now} ({unit}); another axis is other physics (name the same probe, or set "
            "models.prior: none)"
        )


def prior_param(
    results_dir: str | os.PathLike,
    machine: str,
    setting,
    raw_hashes: Iterable[str],
    siblings: Iterable[str] = (),
) -> dict:
    """The param ``prior`` of ``rule compare``, resolved while Snakemake plans.

    ``chain`` holds the ids of :func:`prior_chain` from its first model that has seen none of
    ``raw_hashes`` (the sha256 of the machine's raw files); ``machine`` and ``siblings``
    (``models.prior_siblings``: :func:`check_origin`). Nothing else: a champion trained on
    these logs must leave the param as it was without one (no re-run after a promotion). The
    job loads the artefacts from ``registry`` and chooses again on ``runs.csv``
    (:func:`resolved_prior`).
    """
    mode, source = source_unit(results_dir, setting, machine)
    chain = prior_chain(results_dir, machine, setting)
    k = _first_disjoint(chain, {str(h) for h in raw_hashes})
    eligible = chain[k:] if k is not None else []
    reg = _registry(results_dir, source)
    return {
        "mode": mode,
        "source": source,
        "registry": str(reg.root) if eligible else None,
        "chain": [str(a["model_id"]) for a in eligible],
        "machine": machine,
        "siblings": sorted({str(s) for s in siblings or ()}),
    }


def available_sensors(runs_frame) -> list[str]:
    """The sensors (:func:`rafi.contract.sensors.run_sensors`) whose rise column ``d<s>`` has a finite value
    in ``runs_frame``."""
    from rafi.contract.sensors import run_sensors

    return [s for s in run_sensors(runs_frame) if bool(runs_frame[f"d{s}"].notna().any())]


def resolved_prior(
    param: dict | None, runs_table, runs_frame, *, unit: str | None = None, log=print
) -> dict | None:
    """The prior ``rule compare`` adapts (:func:`prior_param` = ``param``), or ``None``.

    Loads the chain's artefacts from the registry (verified), chooses the first that learnt
    from none of the runs of ``runs_table`` (:func:`choose_prior`), refuses one from elsewhere
    than this machine or a declared sibling (:func:`check_origin`, which raises) and checks it
    against ``runs_frame``'s sensors and the probe of ``unit`` (the unit qualified:
    :func:`check_compatible`, which raises). The reason goes to ``log``.
    """
    from rafi.ops.registry import Registry

    param = param or {}
    ids = list(param.get("chain") or [])
    if not ids:
        if param.get("mode", "none") == "none":
            log("no prior: models.prior is none")
        else:
            log(
                f"no prior: the registry of {param.get('source')} has no champion, or every model of its "
                "chain learnt from these logs"
            )
        return None
    reg = Registry(Path(param["registry"]), str(param.get("source") or ""))
    prior, reason = choose_prior([reg.load_model_dict(i) for i in ids], runs_table)
    log(reason)
    if prior is not None:
        if param.get("machine"):  # a param of before the origin check names no machine
            origin = check_origin(prior, param["machine"], param.get("siblings") or (), param.get("source"))
            log(f"prior {str(prior.get('model_id', ''))[:12]} comes from {origin}")
        check_compatible(
            prior,
            sensors_available=available_sensors(runs_frame),
            unit=unit,
        )
    return prior


def prior_record(param: dict | None, prior: dict | None) -> dict | None:
    """What the fitness block of an adaptation of ``prior`` needs from the compare param
    (:func:`prior_param` = ``param``): ``origin`` (:func:`prior_origin`; ``None`` for a param
    without the machine) and ``qualification`` (:func:`prior_qualification` from its registry).
    ``None`` without a prior."""
    if prior is None:
        return None
    param = param or {}
    origin = None
    if param.get("machine"):
        machine_of_prior = str(prior.get("machine") or param.get("source") or "")
        origin = prior_origin(machine_of_prior, param["machine"], param.get("siblings") or ())
    registry = param.get("registry")
    qualification = prior_qualification(registry, prior) if registry else None
    return {"origin": origin, "qualification": qualification}


def parent_of(artefact: dict) -> str | None:
    """The model id an adapted artefact was re-qualified from (``adaptation.parent``), else None."""
    block = artefact.get("adaptation")
    parent = block.get("parent") if isinstance(block, dict) else None
    return str(parent) if parent else None


def registry_meta(artefact: dict, displacement_sign: int | None) -> dict:
    """What the registry's ``models/<id>.meta.json`` adds: ``parent`` (an adapted model only) and a
    ``config`` snapshot holding the displacement sign the model's logs were read with
    (``input.displacement.sign``, added when the artefact's own ``config`` lacks it; provenance
    only: a later prior does not compare it, :func:`check_compatible`)."""
    out = {}
    parent = parent_of(artefact)
    if parent:
        out["parent"] = parent
    config = dict(artefact.get("config") or {})
    current = ((config.get("input") or {}).get("displacement") or {}).get("sign")
    if current is None and displacement_sign is not None:
        source = dict(config.get("input") or {})
        source["displacement"] = {**(source.get("displacement") or {}), "sign": int(displacement_sign)}
        out["config"] = {**config, "input": source}
    return out
