"""The sign-off block on the report's first page: document number, revision, prepared /
approved by and date.

The names and the document number come from the machine's settings
(``report.document.{number,prepared_by,approved_by,approved_date}``); a value left out is a
blank line to sign by hand. The **revision** is not a setting: it is derived from what the
report is about, so it changes when the model or the data change, and only then
(:func:`revision`, docs/report.md "Sign-off and the archival PDF").
"""

from __future__ import annotations

import datetime as dt
import hashlib
from collections.abc import Mapping

from rafi.artefact import canonical_json

#: Length (hex digits) of the revision shown: 10 digits = 40 bits, no collision in practice
#: among the revisions of one machine's reports.
REVISION_DIGITS = 10

#: Settings blocks left out of the revision: they change what the report shows, not a result.
PRESENTATION_KEYS = ("report",)

#: Fields of the sign-off block, in the order they are shown: (key, label).
FIELDS = (
    ("number", "Document no."),
    ("revision", "Revision"),
    ("prepared_by", "Prepared by"),
    ("approved_by", "Approved by"),
    ("approved_date", "Date"),
)


def _content_id(model: dict | None) -> str:
    """SHA-256 of a model artefact's content without ``model_id``, ``created`` and ``code_version``.

    RAFI's ``model_id`` hashes the code version (with the git commit); the revision must not
    change with a commit that changes no number, so the model is identified by its content.
    """
    if not model:
        return ""
    content = {k: v for k, v in model.items() if k not in ("model_id", "created", "code_version")}
    return hashlib.sha256(canonical_json(content).encode("ascii")).hexdigest()


def revision_inputs(*, deployed_id: str | None, rafi_model: dict | None, audit, settings: dict) -> dict:
    """Everything the revision is a hash of (shown in the provenance and the docs).

    Parameters
    ----------
    deployed_id : str or None
        Registry id of the model on the machine after this run (``champion_id_after`` of
        ``registry/decision.json``; its content hash, see :mod:`rafi.ops.registry`).
    rafi_model : dict or None
        ``model.json`` (RAFI as published), identified by :func:`_content_id`.
    audit : pandas.DataFrame or None
        ``audit.csv``: ``file`` and ``sha256`` of every raw file the run read.
    settings : dict
        The machine's settings; the blocks of :data:`PRESENTATION_KEYS` are left out.

    Returns
    -------
    dict
        ``{deployed_model, rafi_model, raw_files: {file: sha256}, settings}``.
    """
    raw = {}
    if audit is not None and {"file", "sha256"} <= set(audit.columns):
        raw = {str(f): str(h) for f, h in zip(audit["file"], audit["sha256"])}
    return {
        "deployed_model": deployed_id or "",
        "rafi_model": _content_id(rafi_model),
        "raw_files": dict(sorted(raw.items())),
        "settings": {k: v for k, v in settings.items() if k not in PRESENTATION_KEYS},
    }


def revision(inputs: dict) -> str:
    """The revision: the first :data:`REVISION_DIGITS` hex digits of the SHA-256 of the
    canonical JSON (:func:`rafi.artefact.canonical_json`) of :func:`revision_inputs`."""
    return hashlib.sha256(canonical_json(inputs).encode("ascii")).hexdigest()[:REVISION_DIGITS]


def _text(value) -> str:
    if value is None:
        return ""
    if isinstance(value, (dt.date, dt.datetime)):
        return value.isoformat()
    return str(value).strip()


def _block(doc: Mapping, rev: str, inputs: dict) -> dict:
    """The block's fields from ``report.document`` (``doc``) and the revision ``rev``."""
    values = {
        "number": _text(doc.get("number")),
        "revision": rev,
        "prepared_by": _text(doc.get("prepared_by")),
        "approved_by": _text(doc.get("approved_by")),
        "approved_date": _text(doc.get("approved_date")),
    }
    return {
        "fields": [{"key": k, "label": label, "value": values[k]} for k, label in FIELDS],
        "revision": rev,
        "number": values["number"],
        "inputs": inputs,
    }


def section_signoff(res: dict, settings: dict) -> dict:
    """The sign-off block of the first page.

    Parameters
    ----------
    res : dict
        Loaded inputs (:func:`rafi.report.inputs.load_results`): ``model``, ``audit`` and
        ``decision`` are read.
    settings : dict
        The machine's settings (``report.document`` and what :func:`revision_inputs` keeps).

    Returns
    -------
    dict
        ``fields`` (``[{key, label, value}]``, an empty value is a line to sign),
        ``revision``, ``number``, ``inputs`` (a summary of what the revision covers:
        ``deployed_model``, ``rafi_model``, ``raw_files`` and ``on_machine``: ``model`` where a
        model is on the machine after this run, ``none`` where the decision left none on it (a
        candidate waiting or rejected with no champion), ``no_decision`` without a registry
        decision).
    """
    doc = (settings.get("report") or {}).get("document") or {}
    dec = res.get("decision") if isinstance(res.get("decision"), dict) else {}
    on_machine = "model" if dec.get("champion_id_after") else ("none" if dec else "no_decision")
    inputs = revision_inputs(
        deployed_id=dec.get("champion_id_after"),
        rafi_model=res.get("model"),
        audit=res.get("audit"),
        settings=settings,
    )
    return _block(
        doc,
        revision(inputs),
        {
            "deployed_model": inputs["deployed_model"][:12],
            "rafi_model": inputs["rafi_model"][:12],
            "raw_files": len(inputs["raw_files"]),
            "on_machine": on_machine,
        },
    )


def probes_signoff(settings: dict, revisions: Mapping[str, str]) -> dict:
    """The sign-off block of the report of a machine with several probes (its cover).

    Parameters
    ----------
    settings : dict
        The machine's settings (``report.document``: the number and the names, as a unit's).
    revisions : Mapping
        ``probe -> revision`` of each probe's own report (:func:`section_signoff` of the unit),
        in the order the reports follow the cover.

    Returns
    -------
    dict
        As :func:`section_signoff`; the revision is the first :data:`REVISION_DIGITS` hex digits
        of the SHA-256 of the canonical JSON of ``{"probes": [[probe, revision], ...]}``: it
        changes when one probe's report changes (its model, its data, its settings) or the probes
        change, and only then. ``inputs``: ``probes`` (``[(probe, revision)]``).
    """
    doc = (settings.get("report") or {}).get("document") or {}
    parts = [[str(probe), str(rev)] for probe, rev in revisions.items()]
    return _block(doc, revision({"probes": parts}), {"probes": [tuple(p) for p in parts]})
