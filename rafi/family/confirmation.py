"""What a candidate that passed every gate waits for: the confirmations of ``checks.confirmed``.

Two blocks of a decision (``decision.json`` ``blocked_by``) are lifted by a person's confirmation
alone, not by new data or a better model: an unconfirmed input warning on a file the night's data
uses (``input_warnings``, :func:`rafi.ops.provenance.input_warnings`; ``docs/raw-format.md``,
"Checks") and an unconfirmed fitness warning of the prior the candidate was adapted from
(``prior_fitness``, :func:`rafi.ops.provenance.prior_warnings`; ``docs/models.md``, "The prior's
fitness"). Both are confirmed in the machine's ``checks.confirmed``: ``{file: <file name or
glob>, check: <check id>}`` for an input warning, ``{file: <the prior's model id>, check: <check
id>}`` for a fitness warning.

A candidate held back by nothing else is neither a pass that went on the machine nor a failure:
it waits for a confirmation. :func:`awaiting_confirmation` says so in the words the end-of-run
line (``WAITING``), ``rafi status`` (state ``waiting``, headline ``WAITING FOR CONFIRMATION``), the
fleet page and the report's verdict share. Pure, on the dict of ``decision.json``.
"""

from __future__ import annotations

import json

__all__ = ["CONFIRMABLE", "awaiting_confirmation", "confirmation_entries"]

#: The blocks of ``decision.json`` ``blocked_by`` a confirmation in ``checks.confirmed`` lifts.
CONFIRMABLE = ("input_warnings", "prior_fitness")


def _blocking(decision: dict, block: str) -> list[dict]:
    """The blocking warnings of ``block`` (``decision[block]["blocking"]``), dicts only."""
    found = (decision.get(block) or {}).get("blocking") if isinstance(decision.get(block), dict) else None
    return [w for w in found or [] if isinstance(w, dict)]


def _prior(w: dict) -> str:
    return str(w.get("prior") or "")[:12]


def confirmation_entries(decision: dict | None) -> list[str]:
    """The ``checks.confirmed`` entries that lift the blocks of ``decision`` a confirmation can
    lift, in YAML flow style, each once: the input warnings' (the file name quoted: it is read as a
    glob), then the prior's fitness warnings' (the prior's id, its first 12 characters)."""
    decision = decision or {}
    entries = [
        f"{{file: {json.dumps(str(w.get('file') or ''))}, check: {w.get('check')}}}"
        for w in _blocking(decision, "input_warnings")
    ]
    priors = _blocking(decision, "prior_fitness")
    entries += [f"{{file: {_prior(w)}, check: {w.get('check')}}}" for w in priors]
    return list(dict.fromkeys(entries))


def awaiting_confirmation(decision: dict | None) -> str | None:
    """What a candidate that passed every gate waits for, in words, or None.

    A decision ``rejected`` with ``gates_passed`` whose every block is one of :data:`CONFIRMABLE`,
    each with its warnings listed, goes on the machine once a person confirms them. The words name
    each input warning (check and file) and each fitness check (check and prior), then the
    ``checks.confirmed`` entries to add (:func:`confirmation_entries`) and the machine whose
    settings take them. None for any other decision: a failed gate, or a block beside them that
    no confirmation lifts (the relative gate, the speed coverage).

    Parameters
    ----------
    decision : dict or None
        ``decision.json``.

    Returns
    -------
    str or None
        E.g. ``"waits for a confirmation of the input warning speed_range on v.csv: add
        checks.confirmed: [{file: "v.csv", check: speed_range}] in a2's settings"``.
    """
    decision = decision or {}
    blocked = list(decision.get("blocked_by") or [])
    if (
        decision.get("decision") != "rejected"
        or not decision.get("gates_passed")
        or not blocked
        or any(b not in CONFIRMABLE or not _blocking(decision, b) for b in blocked)
    ):
        return None
    inputs, priors = _blocking(decision, "input_warnings"), _blocking(decision, "prior_fitness")
    what = []
    if inputs:
        files = ", ".join(f"{w.get('check')} on {w.get('file')}" for w in inputs)
        what.append(f"the input warning{'s' if len(inputs) > 1 else ''} {files}")
    if priors:
        checks = ", ".join(f"{w.get('check')} of prior {_prior(w)} ({w.get('machine')})" for w in priors)
        what.append(f"the prior fitness check {checks}")
    machine = next((w.get("for_machine") for w in priors if w.get("for_machine")), None)
    machine = machine or decision.get("machine")
    where = f" in {machine}'s settings" if machine else ""
    return (
        f"waits for a confirmation of {' and '.join(what)}: add checks.confirmed: "
        f"[{', '.join(confirmation_entries(decision))}]{where}"
    )
