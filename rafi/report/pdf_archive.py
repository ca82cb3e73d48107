"""The archival PDF: PDF/A-3b with the files the report is about attached.

WeasyPrint writes the PDF/A-3b itself (``pdf_variant="pdf/a-3b"``): an sRGB output intent,
the XMP metadata declaring ``pdfaid:part 3`` / ``pdfaid:conformance B``, embedded (subset)
fonts and an ``/AF`` entry per attached file. What the report adds is which files go in
(:func:`attachment_specs`) and their descriptions. The figures are PNG without alpha
(:func:`rafi.report.plot_layout.render`), so no soft mask enters the PDF from them.

Attached (when the run wrote them):

- the model on the machine after this run: its registry artefact
  (``registry/models/<champion_id_after>.json``);
- RAFI as published: ``model.json`` (the paper's reference of sections 3-7);
- ``audit.csv``: every raw file read, with its SHA-256 and what cleaning did;
- ``validation/summary.csv`` and ``comparison/summary.csv``: the validation and model
  comparison summary tables.

The HTML report stays self-contained and carries no attachment (docs/report.md).
"""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path

#: The PDF variant written (WeasyPrint's name).
PDF_VARIANT = "pdf/a-3b"

#: ``input name -> (name in the PDF, AFRelationship, description)`` of the fixed attachments.
#: AFRelationship (ISO 32000-2, 14.13): ``Data`` = data the document's tables and figures
#: present; ``Source`` = the original the document is about (the model artefacts).
FIXED = {
    "model": (
        "model.json",
        "Source",
        "RAFI as published (the paper's reference, report sections on the method): the model "
        "artefact model.json, model id {model_id}",
    ),
    "audit": (
        "audit.csv",
        "Data",
        "Audit of the raw files read: file name, SHA-256, rows in and out, what cleaning did, status",
    ),
    "validation_summary": (
        "validation_summary.csv",
        "Data",
        "Validation summary of RAFI as published (validation/summary.csv): per validation run max "
        "|dz| before, max |residual| after, improvement, RMSE, noise floor",
    ),
    "comparison": (
        "comparison_summary.csv",
        "Data",
        "Model comparison summary (comparison/summary.csv): every model of the family on the same "
        "validation runs, its gates, its cross-validation score and which one was chosen",
    ),
}


def _json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def deployed_model_path(decision_path) -> Path | None:
    """Registry artefact of the model on the machine after this run, or None.

    ``champion_id_after`` of ``registry/decision.json`` names it; the file is
    ``registry/models/<id>.json`` beside the decision (immutable, named by its content hash).
    """
    if not decision_path:
        return None
    decision_path = Path(decision_path)
    mid = _json(decision_path).get("champion_id_after") if decision_path.is_file() else None
    if not isinstance(mid, str) or not mid or "/" in mid or "\\" in mid:
        return None
    path = decision_path.parent / "models" / f"{mid}.json"
    return path if path.is_file() else None


def attachment_specs(paths: dict) -> list[dict]:
    """The files to attach, from the report's input paths.

    Parameters
    ----------
    paths : dict
        Input name -> path (:func:`rafi.report.inputs.result_paths` names: ``decision``,
        ``model``, ``audit``, ``validation_summary``, ``comparison``); missing files are skipped.

    Returns
    -------
    list of dict
        ``{path, name, relationship, description}`` in the order attached: the model on the
        machine first.
    """
    specs = []
    deployed = deployed_model_path(paths.get("decision"))
    if deployed is not None:
        d = _json(deployed)
        mid = d.get("model_id") or deployed.stem
        specs.append(
            {
                "path": deployed,
                "name": f"model_on_the_machine_{d.get('kind', 'model')}_{mid[:12]}.json",
                "relationship": "Source",
                "description": f"The model on the machine after this run (the model the verdict judges): "
                f"registry artefact, kind {d.get('kind', '?')}, model id {mid}",
            }
        )
    for key, (name, rel, desc) in FIXED.items():
        p = paths.get(key)
        if not p or not Path(p).is_file():
            continue
        if key == "model":
            desc = desc.format(model_id=_json(Path(p)).get("model_id", "?"))
        specs.append({"path": Path(p), "name": name, "relationship": rel, "description": desc})
    return specs


def write_options(specs: list[dict]) -> dict:
    """Keyword arguments of WeasyPrint's ``write_pdf`` for a PDF/A-3b with ``specs`` attached.

    The attachment's dates are the file's modification time (UTC), so the same files give
    the same attachment dictionaries.
    """
    import weasyprint

    atts = []
    # the PDF's EmbeddedFiles name tree must be sorted by name (ISO 32000-1, 7.9.6); WeasyPrint
    # writes the attachments in the order given
    for s in sorted(specs, key=lambda s: s["name"]):
        path = Path(s["path"])
        mtime = dt.datetime.fromtimestamp(path.stat().st_mtime, dt.UTC).replace(tzinfo=None)
        atts.append(
            weasyprint.Attachment(
                string=path.read_bytes(),
                name=s["name"],
                description=s["description"],
                created=mtime,
                modified=mtime,
                relationship=s["relationship"],
            )
        )
    return {"pdf_variant": PDF_VARIANT, "attachments": atts}
