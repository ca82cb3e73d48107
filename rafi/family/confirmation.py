"""What a candidate that passed every gate waits for: the confirmations of ``checks.confirmed``.

Two blocks of a decision (``decision.json`` ``blocked_by``) are lifted by a person's confirmation
alone, not by new data or a better model: an unconfirmed input warning on a file the night's data
uses (``input_warnings``, :func:`rafi.ops.provenance.input_warnings`; ``docs/raw-format.md``,
"Checks") and an unconfirmed fitness warning of the prior the candidate was adapted from
(``prior_fitness``, :func:`rafi.ops.provenance.prior_warnings`; ``docs/models.md``, "The prior's
fitness"). Both are confirmed in the machine's ``checks.confirmed``: ``{file: <file name or
glob>, check: <check id>}`` for an input warning, ``{file: <the prior's model id>, check: <check
id>}`` for a fitness warning. Every entry printed quotes its ``file`` (:func:`confirmation_entry`):
a file name is read as a glob, and a model id is hex, whose first 12 characters are sometimes all
digits, which YAML would read as a number (:func:`unquoted_ids` takes such a number back where it
can only be the id).

A candidate held back by nothing else is neither a pass that went on the machine nor a failure:
it waits for a confirmation. :func:`awaiting_confirmation` says so in the words the end-of-run
line (``WAITING``), ``rafi status`` (state ``waiting``, headline ``WAITING FOR CONFIRMATION``), the
fleet page and the report's verdict share. Pure, on the dict of ``decision.json``.
"""

from __future__ import annotations

import json
from collections.abc import Mapping

from rafi.errors import SettingsError

__all__ = [
    "CONFIRMABLE",
    "awaiting_confirmation",
    "confirmation_entries",
    "confirmation_entry",
    "taken_back_line",
    "unquoted_ids",
]

#: The blocks of ``decision.json`` ``blocked_by`` a confirmation in ``checks.confirmed`` lifts.
CONFIRMABLE = ("input_warnings", "prior_fitness")


def _blocking(decision: dict, block: str) -> list[dict]:
    """The blocking warnings of ``block`` (``decision[block]["blocking"]``), dicts only."""
    found = (decision.get(block) or {}).get("blocking") if isinstance(decision.get(block), dict) else None
    return [w for w in found or [] if isinstance(w, dict)]


def _prior(w: dict) -> str:
    return str(w.get("prior") or "")[:12]


def confirmation_entry(file, check) -> str:
    """One ``checks.confirmed`` entry in YAML flow style, ``file`` quoted (``json.dumps``) so that
    it reads back as the string printed: ``{file: "012345670123", check: prior_speeds}`` (an id of
    digits unquoted is a number in YAML, a file name a glob either way).

    >>> confirmation_entry("6fca63e8ad59", "prior_speeds")
    '{file: "6fca63e8ad59", check: prior_speeds}'
    """
    return f"{{file: {json.dumps(str(file or ''))}, check: {check}}}"


#: The lengths of a model id in ``checks.confirmed``: its first 12 characters, or all of it.
ID_LENGTHS = (12, 64)


def unquoted_ids(config: Mapping) -> list[str]:
    """Take back, in place, a prior's id written unquoted in ``checks.confirmed`` that YAML read
    as a number; refuse, in one line naming the fix, a number that cannot be told back.

    An id of 12 (or 64) decimal digits without a leading zero is read as that integer, whose
    digits are the id: it becomes the string again. With a leading zero and digits 0-7 only YAML
    reads it as an octal number (``012345670123`` is 1402433619): the zeros and the digits are
    lost, as for any other number, and the entry is refused. Read are ``defaults.checks.confirmed``
    and every ``machines.<name>.checks.confirmed``; the workflow and ``rafi nightly`` call this
    before the schema (``file``: a string) sees the config.

    Parameters
    ----------
    config : mapping
        ``config.yaml`` as loaded (changed in place).

    Returns
    -------
    list of str
        ``<key>: <number>`` for each id taken back (the caller may say so).

    Raises
    ------
    SettingsError
        A ``file`` that is a number and not an id of digits: the key, the number, and to quote it.
    """
    blocks = [("defaults", (config.get("defaults") or {}) if isinstance(config, Mapping) else {})]
    machines = config.get("machines") if isinstance(config, Mapping) else None
    blocks += [(f"machines.{name}", value) for name, value in (machines or {}).items()]
    taken = []
    for where, block in blocks:
        checks = block.get("checks") if isinstance(block, Mapping) else None
        entries = checks.get("confirmed") if isinstance(checks, Mapping) else None
        for k, entry in enumerate(entries if isinstance(entries, list) else []):
            value = entry.get("file") if isinstance(entry, dict) else None
            if not isinstance(value, int) or isinstance(value, bool):
                continue
            key = f"{where}.checks.confirmed[{k}].file: {value}"
            if value > 0 and len(str(value)) in ID_LENGTHS:
                entry["file"] = str(value)
                taken.append(key)
                continue
            raise SettingsError(
                f"config.yaml: {key} is a number: YAML reads an unquoted id or name of digits as one "
                f"(a leading 0 as octal), so it matches no file or prior; quote it: "
                f'{{file: "<the id as printed>", check: {entry.get("check")}}}'
            )
    return taken


def taken_back_line(taken: str) -> str:
    """What is said of an id :func:`unquoted_ids` took back (``taken``, one of its lines):
    ``machines.m.checks.confirmed[0].file: 123456789012 read as the prior's id '123456789012';
    quote it in config.yaml``."""
    return f"{taken} read as the prior's id '{taken.rsplit(' ', 1)[-1]}'; quote it in config.yaml"


def confirmation_entries(decision: dict | None) -> list[str]:
    """The ``checks.confirmed`` entries that lift the blocks of ``decision`` a confirmation can
    lift, in YAML flow style, each once: the input warnings' (the file name quoted: it is read as a
    glob), then the prior's fitness warnings' (the prior's id, its first 12 characters, quoted
    too: :func:`confirmation_entry`)."""
    decision = decision or {}
    entries = [
        confirmation_entry(w.get("file"), w.get("check")) for w in _blocking(decision, "input_warnings")
    ]
    priors = _blocking(decision, "prior_fitness")
    entries += [confirmation_entry(_prior(w), w.get("check")) for w in priors]
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
