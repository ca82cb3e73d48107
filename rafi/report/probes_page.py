"""The qualification report of a machine with several probes: the verdict of every probe on its
first page, then a section per probe, then every probe's own report (the PDF holds their pages).

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


def render_probes_html(ctx: dict) -> str:
    """The page as HTML (``templates/probes.html.j2``, in the environment and with the stylesheet
    of a unit's report: :func:`rafi.report.render._environment`)."""
    from rafi.report.render import _environment

    return _environment().get_template("probes.html.j2").render(**ctx)


def render_probes_pdf(html: str, probe_reports: list[str | Path]) -> bytes:
    """The PDF: this page, then every page of each probe's own report (its HTML, rendered again
    by WeasyPrint: the figures are embedded, so the HTML stands alone)."""
    from weasyprint import HTML

    cover = HTML(string=html).render()
    pages = list(cover.pages)
    for path in probe_reports:
        text = Path(path).read_text(encoding="utf-8")
        pages += HTML(string=text, base_url=str(Path(path).parent)).render().pages
    return cover.copy(pages).write_pdf()
