"""What a model in service rests on: the confirmations of its warnings, kept in the registry
(issue 47: a foreign prior never reaches the machine without a confirmation).

Two ways put a model in service, and each keeps in its ``history.jsonl`` line what it rested on:

* a night's decision (rule ``decide``) promotes a candidate only when none of its input warnings
  and none of its prior's fitness warnings is unconfirmed; its line keeps both blocks
  (``input_warnings``, ``prior_fitness``: each confirmed warning with ``confirmed_by``, the
  ``checks.confirmed`` entries that confirm it, :func:`rafi.ops.provenance.confirming_entries`);
* ``rafi nightly --promote <id>`` (a rollback, or a manual promotion). A model a decision once
  promoted is a rollback: its confirmations were given then. Any other model is judged as the
  night would: the fitness warnings of its artefact and the input warnings of the decision that
  judged it, against the machine's ``checks.confirmed`` now (:func:`warnings_now`). An
  unconfirmed one refuses the promotion in one line naming each warning and the entries to add
  (:func:`refusal_text`, exit status 64 as the other refusals of ``--promote``), unless
  ``--confirm-warnings`` is given: the promotion then goes ahead over them, and the line records
  which warnings were overridden and by whom (``by_hand.overridden``). The line's ``by_hand``
  block (:func:`by_hand_block`) keeps the warnings, the confirmations and the override; the
  rewritten ``decision.json`` gets the same block.

``rafi status`` reads the trail back (:func:`promotion_trail`) and says, under the model in
service, whether its warnings were confirmed and by which entries, or that it was promoted by hand
over unconfirmed warnings (:func:`trail_lines`). A ``history.jsonl`` written before these blocks
has neither: the trail then says what the lines do record (``blocked_by``), and no more.

Pure functions on dicts, except :func:`promote_by_hand` (the registry's files).
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path

__all__ = [
    "CONFIRM_OPTION",
    "judged_record",
    "promoted_by_decision",
    "warnings_now",
    "unconfirmed",
    "refusal_text",
    "by_hand_block",
    "promote_by_hand",
    "promotion_trail",
    "trail_lines",
]

#: The option of ``rafi nightly --promote`` that promotes over unconfirmed warnings.
CONFIRM_OPTION = "--confirm-warnings"

#: Decisions of rule ``decide`` that judged a candidate.
_JUDGED = ("promoted", "rejected", "kept")


def _dicts(items) -> list[dict]:
    return [w for w in items or [] if isinstance(w, dict)]


def judged_record(decision: dict | None, history: list[dict], model_id: str) -> dict | None:
    """The last decision that judged ``model_id`` as its candidate: ``decision.json`` when it is
    that decision, else the last such line of ``history.jsonl``; None if there is none."""
    if (decision or {}).get("candidate_id") == model_id and (decision or {}).get("decision") in _JUDGED:
        return decision
    for rec in reversed(history or []):
        if rec.get("candidate_id") == model_id and rec.get("decision") in _JUDGED:
            return rec
    return None


def promoted_by_decision(history: list[dict], model_id: str) -> dict | None:
    """The last line of ``history.jsonl`` whose decision promoted ``model_id`` (None: no night's
    decision ever put it in service)."""
    for rec in reversed(history or []):
        if rec.get("decision") == "promoted" and rec.get("champion_id_after") == model_id:
            return rec
    return None


def warnings_now(model: dict, judged: dict | None, confirmed=()) -> dict:
    """The warnings of ``model`` against ``checks.confirmed`` as it is now (``confirmed``).

    Parameters
    ----------
    model : dict
        The model's artefact (its ``adaptation.fitness.warnings``:
        :func:`rafi.ops.provenance.prior_warnings`).
    judged : dict or None
        The decision that judged it (:func:`judged_record`): its ``input_warnings`` (the input
        warnings on the data it was judged on), each blocking one looked up again in
        ``confirmed``.
    confirmed : list of dict
        The machine's ``checks.confirmed``.

    Returns
    -------
    dict
        ``prior_fitness`` (``blocking``, ``confirmed``) and ``input_warnings`` (``blocking``,
        ``confirmed``, ``not_used``), each confirmed warning with ``confirmed_by``;
        ``input_unknown``: the decision was held back by input warnings it does not list (a
        ``history.jsonl`` line from before they were kept), so they count as unconfirmed.
    """
    from rafi.ops.provenance import confirming_entries, prior_warnings

    prior = prior_warnings(model, confirmed)
    block = (judged or {}).get("input_warnings")
    inputs: dict[str, list] = {"blocking": [], "confirmed": [], "not_used": []}
    unknown = False
    if isinstance(block, dict):
        inputs["confirmed"] = _dicts(block.get("confirmed"))
        inputs["not_used"] = _dicts(block.get("not_used"))
        for w in _dicts(block.get("blocking")):
            by = confirming_entries(str(w.get("file") or ""), str(w.get("check")), confirmed)
            if by:
                inputs["confirmed"].append({**w, "confirmed": True, "confirmed_by": by})
            else:
                inputs["blocking"].append(w)
    elif "input_warnings" in ((judged or {}).get("blocked_by") or []):
        unknown = True
    return {"prior_fitness": prior, "input_warnings": inputs, "input_unknown": unknown}


def unconfirmed(found: dict) -> bool:
    """``found`` (:func:`warnings_now`) holds a warning no entry of ``checks.confirmed`` confirms."""
    return bool(
        found["prior_fitness"]["blocking"] or found["input_warnings"]["blocking"] or found["input_unknown"]
    )


def _entries(found: dict) -> list[str]:
    from rafi.family.confirmation import confirmation_entries

    return confirmation_entries(found)


def _what(found: dict) -> str:
    """The unconfirmed warnings of ``found`` in words: ``fitness warnings prior_speeds,
    prior_misfit of its prior 6fca63e8ad59 (tapping-center-a)``, ``input warning speed_range on
    v.csv``."""
    what = []
    priors = found["prior_fitness"]["blocking"]
    if priors:
        checks = ", ".join(str(w.get("check")) for w in priors)
        p = priors[0]
        what.append(
            f"fitness warning{'s' if len(priors) > 1 else ''} {checks} of its prior "
            f"{str(p.get('prior') or '')[:12]} ({p.get('machine') or '?'})"
        )
    inputs = found["input_warnings"]["blocking"]
    if inputs:
        files = ", ".join(f"{w.get('check')} on {w.get('file') or '(machine)'}" for w in inputs)
        what.append(f"input warning{'s' if len(inputs) > 1 else ''} {files}")
    if found["input_unknown"]:
        what.append("input warnings of the decision that judged it (its history line does not list them)")
    return " and ".join(what)


def refusal_text(machine: str, model_id: str, found: dict) -> str:
    """The one line that refuses to promote ``model_id`` by hand over unconfirmed warnings
    (``found``, :func:`warnings_now`): the warnings, the ``checks.confirmed`` entries to add and
    where, and the option that promotes over them."""
    entries = _entries(found)
    todo = [f"add checks.confirmed: [{', '.join(entries)}] in {machine}'s settings"] if entries else []
    if found["input_unknown"]:
        todo.append("let the next night list and judge its input warnings")
    return (
        f"{machine}: {model_id[:12]} not promoted: the {_what(found)} not confirmed; "
        f"{' and '.join(todo)}, then promote it again (or let the night promote it), or promote it "
        f"over them with {CONFIRM_OPTION} (recorded in history.jsonl)"
    )


def by_hand_block(found: dict | None, *, promotion: dict | None = None, operator: str | None = None) -> dict:
    """The ``by_hand`` block of a promotion by hand (its ``history.jsonl`` line and the rewritten
    ``decision.json``).

    Parameters
    ----------
    found : dict or None
        :func:`warnings_now` at the promotion; None for a rollback to a model a decision promoted.
    promotion : dict, optional
        That decision's line (:func:`promoted_by_decision`): its time and the blocks it kept.
    operator : str, optional
        Who promoted over unconfirmed warnings (``--confirm-warnings``): the login name.

    Returns
    -------
    dict
        ``promoted_at`` (the time of the decision that promoted the model, or None),
        ``prior_fitness`` and ``input_warnings`` (the promotion's blocks, or the warnings now;
        None where not recorded), ``overridden`` (None, or ``option``, ``operator``, ``warnings``:
        the unconfirmed ones in words, and ``entries``: the ``checks.confirmed`` entries that
        would have confirmed them).
    """
    if promotion is not None:
        return {
            "promoted_at": promotion.get("time"),
            "prior_fitness": promotion.get("prior_fitness"),
            "input_warnings": promotion.get("input_warnings"),
            "overridden": None,
        }
    found = found or {
        "prior_fitness": {"blocking": [], "confirmed": []},
        "input_warnings": {"blocking": [], "confirmed": [], "not_used": []},
        "input_unknown": False,
    }
    overridden = None
    if unconfirmed(found):
        overridden = {
            "option": CONFIRM_OPTION,
            "operator": operator,
            "warnings": _what(found),
            "entries": _entries(found),
        }
    return {
        "promoted_at": None,
        "prior_fitness": found["prior_fitness"],
        "input_warnings": found["input_warnings"],
        "overridden": overridden,
    }


def _operator() -> str | None:
    import getpass

    with contextlib.suppress(Exception):
        return getpass.getuser()
    return None


def promote_by_hand(
    registry_root: str | os.PathLike,
    machine: str,
    model_id: str,
    *,
    confirmed=(),
    confirm_warnings: bool = False,
    reason: str = "operator rollback",
) -> dict:
    """``rafi nightly --promote``: point the champion at a registered model, or refuse.

    The model (id or a unique prefix) is resolved and verified (:class:`rafi.ops.registry.Registry`).
    A model a decision once promoted goes back in service (a rollback; its line keeps that
    promotion's blocks). Any other is judged against ``confirmed`` (``checks.confirmed``:
    :func:`warnings_now`); an unconfirmed warning raises :class:`rafi.errors.RegistryError`
    (:func:`refusal_text`) unless ``confirm_warnings``. Then, as
    :func:`rafi.ops.registry.promote`: a ``rolled_back`` line in ``history.jsonl`` (with the
    ``by_hand`` block, :func:`by_hand_block`; the drift reference, files and training speeds of
    the model's promotion, else of the decision that judged it), ``champion.json`` replaced,
    ``decision.json`` rewritten (the manual change and the same block), by the registry's one
    writer of a manual promotion (:func:`rafi.ops.registry.record_manual_promotion`).

    Returns
    -------
    dict
        The ``history.jsonl`` line.
    """
    from rafi.errors import RegistryError
    from rafi.ops.registry import Registry, promotion_record, record_manual_promotion

    reg = Registry(Path(registry_root), machine)
    model_id = reg.resolve(model_id)
    model = reg.load_model_dict(model_id)
    history = reg.history()
    decision = {}
    if reg.decision_path.exists():
        with contextlib.suppress(ValueError):
            decision = json.loads(reg.decision_path.read_text(encoding="utf-8"))
    promotion = promoted_by_decision(history, model_id)
    found = None
    if promotion is None:
        found = warnings_now(model, judged_record(decision, history, model_id), confirmed)
        if unconfirmed(found) and not confirm_warnings:
            raise RegistryError(refusal_text(machine, model_id, found))
    block = by_hand_block(
        found, promotion=promotion, operator=_operator() if found and unconfirmed(found) else None
    )
    # the drift reference, the files seen and the training speeds of the model's own promotion;
    # for a model no decision promoted, of the decision that judged it (what it would have kept)
    prom = promotion_record(history, model_id) or judged_record(None, history, model_id) or {}
    said = f"{reason}: champion set to {model_id[:12]} by an operator"
    if block["overridden"]:
        said += f" over unconfirmed warnings ({CONFIRM_OPTION}): {block['overridden']['warnings']}"
    return record_manual_promotion(
        reg,
        model_id,
        reason=reason,
        reference=prom,
        said=said,
        by_hand=block,
        decision=decision,
        decision_path=reg.decision_path,
    )


# --------------------------------------------------------------------------- reading the trail


def _confirmed_items(block: dict | None, kind: str) -> list[dict]:
    return [
        {"kind": kind, "check": w.get("check"), "file": w.get("file"), "by": _dicts(w.get("confirmed_by"))}
        for w in _dicts((block or {}).get("confirmed"))
    ]


def promotion_trail(history: list[dict], model_id: str | None, decision: dict | None = None) -> dict | None:
    """What the model in service rests on, from ``history.jsonl`` (and ``decision.json``).

    Parameters
    ----------
    history : list of dict
        ``history.jsonl``.
    model_id : str or None
        The model in service.
    decision : dict, optional
        ``decision.json``: a later decision that judged the model in service again (``kept``)
        and found its warnings confirmed since (``since``).

    Returns
    -------
    dict or None
        None without a line that put ``model_id`` in service. Else ``how``:

        * ``decision``: a night's decision promoted it (``time``); ``prior`` / ``inputs``: the
          confirmed warnings with the entries that confirm them (``by``), or None for a line
          written before they were kept (``recorded`` False);
        * ``by_hand``: promoted by hand with every warning confirmed (``prior`` / ``inputs``);
        * ``rollback``: promoted by hand back to a model a decision promoted (``promoted_at``,
          its blocks as under ``decision``);
        * ``overridden``: promoted by hand over unconfirmed warnings (``--confirm-warnings``):
          ``warnings``, ``entries`` (to add), ``operator``;
        * ``unconfirmed``: promoted by hand before the check existed while the decision that
          judged it held it back for its warnings (``held_at``, ``held_by``: the blocks);
        * ``by_hand_unknown``: promoted by hand before the check existed, nothing recorded.

        ``time``: when it was put in service; ``since``: ``{time, prior, inputs}`` of a later
        decision that found every warning of the model confirmed, or None.
    """
    from rafi.ops.registry import promotion_record

    if not model_id:
        return None
    rec = promotion_record(history or [], model_id)
    if rec is None:
        return None
    out: dict = {"how": None, "time": rec.get("time"), "since": None}
    if rec.get("decision") == "promoted":
        recorded = "prior_fitness" in rec
        out |= {
            "how": "decision",
            "recorded": recorded,
            "prior": _confirmed_items(rec.get("prior_fitness"), "prior") if recorded else None,
            "inputs": _confirmed_items(rec.get("input_warnings"), "input") if recorded else None,
        }
        return out
    block = rec.get("by_hand")
    if isinstance(block, dict):
        prior = _confirmed_items(block.get("prior_fitness"), "prior")
        inputs = _confirmed_items(block.get("input_warnings"), "input")
        if block.get("overridden"):
            over = block["overridden"]
            out |= {"how": "overridden", **{k: over.get(k) for k in ("warnings", "entries", "operator")}}
        elif block.get("promoted_at"):
            recorded = block.get("prior_fitness") is not None
            out |= {"how": "rollback", "promoted_at": block["promoted_at"], "recorded": recorded}
        else:
            out |= {"how": "by_hand", "recorded": True}
        out |= {"prior": prior, "inputs": inputs}
    else:  # a line of an earlier --promote: what the lines before it say
        before = history[: next(i for i, h in enumerate(history) if h is rec)]
        earlier = promoted_by_decision(before, model_id)
        judged = judged_record(None, before, model_id)
        held = [b for b in (judged or {}).get("blocked_by") or [] if b in ("prior_fitness", "input_warnings")]
        if earlier is not None:
            recorded = "prior_fitness" in earlier
            out |= {
                "how": "rollback",
                "promoted_at": earlier.get("time"),
                "recorded": recorded,
                "prior": _confirmed_items(earlier.get("prior_fitness"), "prior") if recorded else None,
                "inputs": _confirmed_items(earlier.get("input_warnings"), "input") if recorded else None,
            }
        elif held:
            out |= {"how": "unconfirmed", "held_at": judged.get("time"), "held_by": held}
        else:
            out |= {"how": "by_hand_unknown"}
    if out["how"] in ("overridden", "unconfirmed") and decision:
        later = decision.get("decision") in _JUDGED and decision.get("candidate_id") == model_id
        pf, iw = decision.get("prior_fitness") or {}, decision.get("input_warnings") or {}
        if later and not _dicts(pf.get("blocking")) and not _dicts(iw.get("blocking")):
            out["since"] = {
                "time": decision.get("time"),
                "prior": _confirmed_items(pf, "prior"),
                "inputs": _confirmed_items(iw, "input"),
            }
    return out


def _entry(entry: dict) -> str:
    file = str(entry.get("file", ""))
    # quoted as every printed entry is (rafi.family.confirmation.confirmation_entry): an id of
    # digits would be a number in YAML
    return f"{{file: {json.dumps(file)}, check: {entry.get('check')}}}"


def _by_words(items: list[dict] | None) -> str:
    """``{file: .., check: ..}, ...``: every entry that confirmed ``items``, each once."""
    entries = [_entry(e) for i in items or [] for e in i["by"]]
    return ", ".join(dict.fromkeys(entries))


def trail_lines(trail: dict | None, warnings: list[str], machine: str | None = None) -> dict[str, str]:
    """The words of ``rafi status`` for what the model in service rests on.

    Parameters
    ----------
    trail : dict or None
        :func:`promotion_trail`.
    warnings : list of str
        The fitness checks of the model's artefact (``adaptation.fitness.warnings``).
    machine : str, optional
        Whose settings take the entries to add.

    Returns
    -------
    dict
        ``prior``: what follows the checks on the ``prior warnings:`` line (empty without
        fitness warnings); ``inputs``: the ``input warnings:`` line (empty unless the model went
        in service over unconfirmed input warnings, or with confirmed ones).
    """
    t = trail or {"how": None}
    how = t.get("how")
    where = f" in {machine}'s settings" if machine else ""
    since = t.get("since")
    later = ""
    if since:
        by = _by_words((since["prior"] or []) + (since["inputs"] or []))
        later = f"; confirmed since in checks.confirmed ({by}) at the decision of {since['time']}"
    out = {"prior": "", "inputs": ""}
    if how == "overridden":
        who = f" by {t['operator']}" if t.get("operator") else ""
        text = (
            f"NOT CONFIRMED: promoted by hand at {t['time']} with {CONFIRM_OPTION}{who} over "
            f"{t.get('warnings')}"
        )
        if not since and t.get("entries"):
            text += f"; to confirm add checks.confirmed: [{', '.join(t['entries'])}]{where}"
        text += later
        if warnings:
            out["prior"] = text
        else:
            out["inputs"] = text
        if t.get("inputs"):
            out["inputs"] = out["inputs"] or f"confirmed in checks.confirmed ({_by_words(t['inputs'])})"
        return out
    if how == "unconfirmed":
        held = " and ".join(
            {"prior_fitness": "its prior's fitness warnings", "input_warnings": "its input warnings"}[b]
            for b in t["held_by"]
        )
        text = (
            f"NOT CONFIRMED: promoted by hand (rafi nightly --promote) at {t['time']} while the "
            f"decision of {t.get('held_at')} held it back for {held}; no confirmation is recorded{later}"
        )
        if warnings:
            out["prior"] = text
        if "input_warnings" in t["held_by"]:
            out["inputs"] = text
        return out
    if how == "by_hand_unknown":
        out["prior"] = (
            f"promoted by hand (rafi nightly --promote) at {t['time']}; whether they were confirmed "
            "is not recorded"
            if warnings
            else ""
        )
        return out
    if how in ("decision", "by_hand", "rollback"):
        at = {
            "decision": f"at the decision of {t['time']} that promoted it",
            "by_hand": f"when promoted by hand at {t['time']}",
            "rollback": (
                f"at the decision of {t.get('promoted_at')} that promoted it (rolled back to at {t['time']})"
            ),
        }[how]
        if not t.get("recorded"):
            if warnings:
                out["prior"] = f"confirmed {at} (the checks.confirmed entries were not recorded)"
            return out
        if warnings:
            by = _by_words(t.get("prior"))
            out["prior"] = f"confirmed in checks.confirmed ({by}) {at}" if by else f"confirmed {at}"
        if t.get("inputs"):
            names = ", ".join(f"{i['check']} on {i['file'] or '(machine)'}" for i in t["inputs"])
            out["inputs"] = f"{names}: confirmed in checks.confirmed ({_by_words(t['inputs'])}) {at}"
        return out
    out["prior"] = "whether they were confirmed is not recorded" if warnings else ""
    return out
