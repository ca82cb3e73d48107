"""The qualification report of a machine with several probes: the verdict of every probe on its
first page, then a section per probe, then every probe's own report (the HTML links them, the PDF
holds their pages, numbered as one document).

A machine of ``input.probes`` is qualified one probe at a time (``<machine>@<probe>``: its own
model, chosen by the same training-run cross-validation, its registry and its report). This page
puts them together for the engineer who signs: nothing here is computed anew, every number is
read from the tables of the probes' own runs.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path

import pandas as pd

from rafi.report.choices import generated_at
from rafi.report.format import fmt_num
from rafi.report.inputs import load_results
from rafi.report.probe import probe_sign_record
from rafi.report.replay_section import above_gate_words, replay_gaps_of
from rafi.report.signoff import probes_signoff, section_signoff


def _json(path) -> dict:
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


def probe_row(
    probe: str, settings: Mapping, paths: Mapping[str, str], report_href: str, sign_key: str | None = None
) -> dict:
    """What the first page says of one probe, from its unit's tables.

    Parameters
    ----------
    probe : str
        The probe's name (a key of ``input.probes``).
    settings : Mapping
        The unit's effective settings (``rafi.settings.machine_settings`` of ``<machine>@<probe>``).
    paths : Mapping
        ``summary`` (comparison/summary.csv), ``per_run`` (comparison/per_run.csv),
        ``decision`` (registry/decision.json), ``audit`` (audit.csv: the files' probe sign;
        optional), ``replay`` (deploy/replay_summary.csv: the offered model with the
        controller's limits; optional) and ``validation`` (validation/summary.csv: the runs'
        noise floors beside per_run's; optional) and ``model`` (model.json: RAFI as published,
        which the revision of the unit's report hashes; optional) of the unit.
    report_href : str
        The probe's own report, relative to this page.
    sign_key : str, optional
        The key of config.yaml that sets the probe's sign (:func:`rafi.report.probe.sign_key`);
        ``None``: the default.

    Returns
    -------
    dict
        ``probe``, ``channel``, ``description``, ``unit``/``sign`` (as configured), ``sign_record``
        (where the sign comes from and whether the data agree,
        :func:`rafi.report.probe.probe_sign_record`), ``verdict``
        (``PASS`` / ``FAIL``: the offered model's gates on the validation runs), ``model`` (its
        kind), ``worst_um`` / ``before_um`` (its worst validation residual and the worst
        uncompensated displacement), ``decision`` (the registry's), ``runs`` (one dict per
        validation run of the offered model), ``replay_above_gate`` (where the offered model with
        the controller's limits leaves more than the largest-residual gate, in the words of the
        probe's own verdict: :func:`rafi.report.replay_section.above_gate_words`; None where it
        does not: the replay says, it does not gate), ``revision`` (the revision of the probe's
        own report: :func:`unit_revision`) and ``href``.
    """
    disp = settings["input"]["displacement"]
    described = (settings["input"].get("probes") or {}).get(probe, {}).get("description")
    summary = pd.read_csv(paths["summary"])
    offered = summary[summary["champion"].astype(bool)]
    row = offered.iloc[0] if len(offered) else None
    per_run = pd.read_csv(paths["per_run"])
    runs = []
    if row is not None:
        mine = per_run[per_run["model"].astype(str) == str(row["model"])]
        for _, r in mine.iterrows():
            runs.append(
                {
                    "run": str(r["run_id"]),
                    "before": fmt_num(r.get("max_abs_before_um"), 2),
                    "after": fmt_num(r.get("max_abs_after_um"), 2),
                }
            )
    decision = _json(paths["decision"])
    audit_path = paths.get("audit")
    audit = pd.read_csv(audit_path) if audit_path and Path(audit_path).is_file() else None
    passed = bool(row["passed"]) if row is not None else False
    gate = (settings.get("qualification") or {}).get("max_residual_um")
    gaps = replay_gaps_of(paths.get("replay"), paths["per_run"], paths.get("validation"), gate)
    return {
        "probe": probe,
        "channel": disp["column"],
        "description": described or "",
        "unit": disp["unit"],
        "sign": disp["sign"],
        "sign_record": probe_sign_record(dict(settings), sign_key, audit),
        "verdict": "PASS" if passed else "FAIL",
        "model": str(row["kind"]) if row is not None else "none",
        "worst_um": fmt_num(row["max_abs_after_um"], 2) if row is not None else "",
        "before_um": fmt_num(row["max_abs_before_um"], 2) if row is not None else "",
        "decision": str(decision.get("decision", "")),
        "runs": runs,
        "replay_above_gate": above_gate_words(gaps),
        "revision": unit_revision(paths, settings),
        "href": report_href,
    }


def unit_revision(paths: Mapping[str, str], settings: Mapping) -> str:
    """The revision of a probe's own report, as that report computes it
    (:func:`rafi.report.signoff.section_signoff` of the unit's ``decision``, ``model`` and ``audit``
    and its settings)."""
    keys = ("decision", "model", "audit")
    res = load_results({key: paths.get(key) for key in keys})
    return section_signoff(res, dict(settings))["revision"]


def probes_context(machine: str, rows: list[dict], settings: Mapping | None = None, now=None) -> dict:
    """The template's context: the machine, its probes' rows, the machine's verdict (PASS only
    when every probe passes), ``above_gate``: the probes whose offered model with the
    controller's limits leaves more than the largest-residual gate (said, not judged), the
    sign-off block (:func:`rafi.report.signoff.probes_signoff` of the machine's settings
    ``settings`` and the rows' revisions) and ``generated``
    (:func:`rafi.report.choices.generated_at` of ``now``)."""
    revisions = {r["probe"]: r["revision"] for r in rows}
    return {
        "machine": machine,
        "generated": generated_at(now),
        "signoff": probes_signoff(dict(settings or {}), revisions),
        "probes": rows,
        "verdict": "PASS" if rows and all(r["verdict"] == "PASS" for r in rows) else "FAIL",
        "n_pass": sum(r["verdict"] == "PASS" for r in rows),
        "above_gate": [r["probe"] for r in rows if r.get("replay_above_gate")],
    }


def render_probes_html(ctx: dict, medium: str = "html") -> str:
    """The page as HTML (``templates/probes.html.j2``, in the environment and with the stylesheet
    of a unit's report: :func:`rafi.report.render._environment`).

    ``medium``: ``html``, the page written beside the probes' reports, which links them; ``pdf``,
    the first pages of the PDF, which the probes' reports follow (then every row of ``ctx``
    carries ``pages``, the first and the last page of its report in the PDF:
    :func:`render_probes_pdf`)."""
    from rafi.report.render import _environment

    return _environment().get_template("probes.html.j2").render(**ctx, medium=medium)


#: Renderings of the parts at most, after the first that counts their pages: the page numbers of
#: the next renderings do not move a page break (they are in the page margins), only the width of
#: a number in a report's contents could, by a line.
MAX_RENUMBERINGS = 3


def numbering_css(first_page: int, total: int, part: str | None = None, part_pages: int = 0) -> str:
    """The page numbers of one part of the PDF (``templates/styles/numbering.css.j2``): its pages
    numbered from ``first_page`` of ``total``; a probe's report (``part``: its unit) also its own
    page of ``part_pages``."""
    from rafi.report.render import _environment

    template = _environment().get_template("styles/numbering.css.j2")
    return template.render(first_page=first_page, total=total, part=part, part_pages=part_pages)


def render_probes_pdf(ctx: dict, probe_reports: Mapping[str, str | Path]) -> bytes:
    """The PDF: this page (:func:`render_probes_html` for the PDF: it says at which pages each
    probe's report follows), then every page of each probe's own report (its HTML, rendered again
    by WeasyPrint: the figures are embedded, so the HTML stands alone), numbered as one document.

    Every page's footer says its place in the whole PDF, "Page k of N", the number to cite; a
    probe's report also says its own page beside it (``<unit>: page j of n``, the number of its
    own PDF), and its contents lead to the pages of the whole PDF (:func:`numbering_css`). The
    parts are rendered once to count their pages, then again numbered (until the counts hold:
    :data:`MAX_RENUMBERINGS`).

    Parameters
    ----------
    ctx : dict
        This page's context (:func:`probes_context`).
    probe_reports : Mapping
        ``unit -> path`` of each probe's report (``reports/<machine>@<probe>/qualification.html``),
        in the order of ``ctx["probes"]``.
    """
    import gc

    from weasyprint import CSS, HTML

    if len(probe_reports) != len(ctx["probes"]):
        raise ValueError(f"{len(probe_reports)} probe report(s) for {len(ctx['probes'])} probe(s)")
    reports = []
    for unit, path in probe_reports.items():
        text = Path(path).read_text(encoding="utf-8")
        reports.append((unit, HTML(string=text, base_url=str(Path(path).parent))))

    def cover(counts: list[int]):
        """The cover for the PDF, each row with the pages of its report (from ``counts``)."""
        first = 1 + counts[0]
        rows = []
        for row, n in zip(ctx["probes"], counts[1:]):
            rows.append({**row, "pages": (first, first + n - 1)})
            first += n
        return HTML(string=render_probes_html({**ctx, "probes": rows}, medium="pdf"))

    # WeasyPrint allocates millions of small objects: the garbage collector paused, as render_pdf
    enabled = gc.isenabled()
    gc.disable()
    try:
        counts = [len(doc.render().pages) for _, doc in reports]
        counts = [len(cover([1, *counts]).render().pages), *counts]
        for _ in range(MAX_RENUMBERINGS):
            parts = [(None, cover(counts)), *reports]
            firsts = [1 + sum(counts[:i]) for i in range(len(parts))]
            docs = [
                doc.render(stylesheets=[CSS(string=numbering_css(first, sum(counts), unit, n))])
                for (unit, doc), first, n in zip(parts, firsts, counts)
            ]
            numbered = [len(doc.pages) for doc in docs]
            if numbered == counts:
                break
            counts = numbered
        else:
            raise RuntimeError(f"the page counts of the parts do not settle: {counts}")
        pages = [page for doc in docs for page in doc.pages]
        return docs[0].copy(pages).write_pdf()
    finally:
        if enabled:
            gc.enable()
