"""The template context of the qualification report: every section, formatted.

The report only presents: each number it shows is read from a table that a rule wrote
upstream (``docs/design.md``; what comes from evaluating the model from rule
``report_tables``) and each figure is a file of rule ``report_figures``. It evaluates no
model and draws nothing.

With ``registry/decision.json`` the verdict judges the model on the machine after this run
(the registry's champion); RAFI as published is always reported beside it as the paper's
reference. Both verdicts are read where rules decide and compare stored them
(:mod:`rafi.report.verdict`); the report judges no gate.
"""

from __future__ import annotations

import time
from pathlib import Path

from rafi.report.choices import generated_at, section_choices, settings_changes, versions
from rafi.report.comparison_section import section_comparison
from rafi.report.data_sections import section_data, section_equilibrium, section_ranking
from rafi.report.deployed_section import section_deployed
from rafi.report.embed import FigureFiles
from rafi.report.inputs import load_results, noise_floors
from rafi.report.intervals import interval_context
from rafi.report.model_sections import section_fuzzy, section_models, section_validation
from rafi.report.probe import probe_sign_record
from rafi.report.registry_section import section_registry
from rafi.report.replay_section import replay_gaps, section_replay, section_title
from rafi.report.requalification_section import section_requalification
from rafi.report.segmentation_section import section_segmentation
from rafi.report.signoff import section_signoff
from rafi.report.test_record import section_test_record
from rafi.report.verdict import model_infos, residual_statement, verdict_all

SECTION_TITLES = {
    "verdict": "Verdict",
    "deployed": "The model offered to the machine",
    "requalification": "Re-qualification from a prior",
    "replay": "The model on the machine: replay",
    "data": "Data",
    "test_record": "Test record and conditions",
    "segmentation": "Segmentation",
    "equilibrium": "Thermal equilibrium",
    "ranking": "Key-sensor ranking",
    "models": "Models",
    "fuzzy": "Fuzzy blending",
    "validation": "Validation",
    "registry": "Model registry: champion vs candidate",
    "comparison": "Model comparison",
    "choices": "Choices the paper leaves open",
    "provenance": "Software, configuration and provenance",
}


def build_context(
    paths: dict,
    figure_dirs: dict,
    *,
    machine: str,
    settings: dict,
    config: dict | None = None,
    now=None,
    sign_key: str | None = None,
) -> dict:
    """Load the results and build the template context.

    Parameters
    ----------
    paths : dict
        Input name -> path (:func:`rafi.report.inputs.result_paths`); the optional inputs
        may be absent.
    figure_dirs : dict
        ``group -> folder`` of rule ``report_figures`` (:func:`rafi.report.inputs.figure_dirs`).
    machine : str
    settings : dict
        The machine's settings, every key present (``rafi.settings``): ``qualification`` and
        the choice parameters are read from here.
    config : dict, optional
        The run's configuration: its run settings (``raw_dir``, ...) that differ from
        ``rafi.settings.RUN_DEFAULTS`` join the machine's settings that differ from the defaults
        in the provenance section's table (:func:`rafi.report.choices.settings_changes`).
    now : datetime, optional
        The time the report says it was made.
    sign_key : str, optional
        The key of config.yaml that sets the probe's sign (:func:`rafi.report.probe.sign_key`);
        ``None``: nothing sets it, the sign is the default (section provenance says where the
        sign comes from and what the data say: :func:`rafi.report.probe.probe_sign_record`).

    Returns
    -------
    dict
        The template's variables; ``figures_used`` lists the figures embedded.
    """
    t0 = time.perf_counter()
    res = load_results(paths)
    model = res["model"] or {}
    key_info = res["key_sensors_json"] or {}
    gates = settings["qualification"]
    figs = FigureFiles(figure_dirs)

    ctx: dict = {"machine": machine, "generated": generated_at(now), "sections": []}
    dec_path = paths.get("decision")
    registry_dir = Path(dec_path).parent if dec_path else None
    infos = model_infos(res, registry_dir)
    ctx["verdict"] = verdict_all(res, infos, registry_dir)
    ctx["verdict"]["residual"] = residual_statement(res, settings)
    ctx["gates"] = gates
    paper = bool(settings["report"]["paper_rig"])  # paper numbers only on the paper's rig
    ctx["paper_rig"] = paper
    ctx["coolant_sensors"] = list(settings["report"]["coolant_sensors"])
    ctx["data"] = section_data(
        res, settings["sample_period_s"], max_gap_s=settings["clean"]["max_interpolate_gap_s"]
    )
    ctx["test_record"] = section_test_record(res, settings)
    ctx["segmentation"] = section_segmentation(res, settings, figs)
    ctx["equilibrium"] = section_equilibrium(res, figs, settings, paper=paper)
    ctx["ranking"] = section_ranking(res, key_info, figs, paper=paper)
    ctx["models"] = section_models(res, figs, paper=paper)
    ctx["fuzzy"] = section_fuzzy(res, figs, paper=paper)
    ctx["validation"] = section_validation(res, figs, paper=paper)
    ctx["registry"] = section_registry(res, infos, registry_dir, settings["checks"]["confirmed"])
    dec = res["decision"] if isinstance(res.get("decision"), dict) else {}
    ctx["comparison"] = section_comparison(res, dec.get("champion_id_after"), settings, figs)
    ctx["requalification"] = section_requalification(
        res,
        registry_dir.parent.parent if registry_dir is not None else None,
        settings["checks"]["confirmed"],
    )
    ctx["replay"] = section_replay(res, settings, figs, dec.get("champion_id_after"))
    ctx["deployed"] = section_deployed(res, figs, dec.get("champion_id_after"))
    _replay_findings(ctx, res, dec, gates)
    # figure numbers in document order: the offered model, its replay, then sections 3 on
    ctx["fig_deployed0"] = 0
    ctx["fig_replay0"] = len(ctx["deployed"]["figures"]) if ctx["deployed"] else 0
    ctx["fig_offset"] = ctx["fig_replay0"] + (len(ctx["replay"]["runs"]) if ctx["replay"] else 0)
    ctx["figures_used"] = list(figs.used)
    ctx["probe_sign"] = probe_sign_record(settings, sign_key, res.get("audit"))
    _verdict_findings(ctx)
    # the folds the family's CV used (time blocks when the training data hold no whole-run fold)
    # and whether forward-in-time folds scored the models too
    sel = ctx["verdict"]["selection"] or {}
    interval = (ctx["deployed"] or {}).get("interval") or interval_context(model)
    ctx["choices"] = section_choices(
        settings,
        key_info,
        ctx["equilibrium"]["method"],
        time_blocks=bool(sel.get("time_blocks")),
        forward=int(sel.get("horizon") or 0),
        interval=interval,
        comparison=ctx["comparison"],  # the rule that chose, as applied (not the settings' text)
        runs=res.get("runs_csv"),  # where the roles came from
    )
    ctx["versions"] = versions()
    ctx["signoff"] = section_signoff(res, settings)  # first page: number, revision, names
    # the configuration appendix: only what differs from the defaults (docs/settings.md)
    ctx["config_changes"] = settings_changes(settings, config)
    ctx["model_id"] = model.get("model_id", "")
    ctx["champion_id"] = dec.get("champion_id_after") or ""
    ctx["code_version"] = model.get("code_version", "")

    ctx["sections"] = numbered_sections(ctx)
    ctx["section_by_id"] = {s["id"]: s for s in ctx["sections"]}
    ctx["build_seconds"] = time.perf_counter() - t0
    return ctx


def _verdict_findings(ctx: dict) -> None:
    """What the verdict box adds from the sections: quarantined files, unconfirmed warnings,
    late training data, the selection, a recalibration due, the fitness warnings a promotion
    rested on and a flagged probe sign (set in ``ctx["verdict"]``)."""
    verdict = ctx["verdict"]
    verdict["quarantined"] = len(ctx["data"]["quarantined"])
    verdict["unconfirmed_warnings"] = sum(not w["confirmed"] for w in ctx["data"]["warnings"])
    seg = ctx["segmentation"] or {}
    verdict["allow_late"] = bool(seg.get("allow_late"))
    verdict["late"] = list(seg.get("late") or [])
    verdict["selection"] = (ctx["comparison"] or {}).get("selection")
    verdict["recalibration_due"] = bool(ctx["registry"] and ctx["registry"]["drift"]["recal"])
    # the fitness warnings a person confirmed, when the promotion rested on them
    verdict["confirmed"] = (ctx["registry"] or {}).get("confirmed")
    # a probe sign the data contradict or nothing confirms: on page 1 too, not only in section 15
    verdict["probe_sign"] = ctx["probe_sign"]["verdict_line"]


def _replay_findings(ctx: dict, res: dict, dec: dict, gates: dict) -> None:
    """Where the replay with the controller's limits leaves materially more than the model alone
    (:func:`rafi.report.replay_section.replay_gaps`): ``verdict.replay`` (``None`` where it does
    not), ``verdict.replay_in_box`` (the replayed model is the box's: the model on the machine,
    or tonight's candidate where none is), ``verdict.replay_offered`` (it is the model offered,
    whose gates the selection sentence states) and ``deployed.replay_gap`` (for section 2)."""
    verdict = ctx["verdict"]
    gaps = replay_gaps(res.get("replay_summary"), noise_floors(res), gates.get("max_residual_um"))
    box = dec.get("champion_id_after") or (dec.get("candidate_id") if verdict.get("of_candidate") else None)
    offered = (ctx["deployed"] or {}).get("model_id")
    replayed = gaps["model_id"] if gaps else None
    verdict["replay"] = gaps
    verdict["replay_in_box"] = bool(replayed) and replayed == box
    verdict["replay_offered"] = bool(replayed) and replayed == offered
    if ctx["deployed"] is not None:
        ctx["deployed"]["replay_gap"] = gaps if verdict["replay_offered"] else None


def numbered_sections(ctx: dict) -> list[dict]:
    """The sections the report has (``{"id", "number", "title"}``, in :data:`SECTION_TITLES`
    order): the optional ones only when their context is not None."""
    optional = ("fuzzy", "segmentation", "registry", "comparison", "replay", "deployed", "requalification")
    sections = []
    for sid, title in SECTION_TITLES.items():
        if sid in optional and ctx[sid] is None:
            continue
        if sid == "replay":
            title = section_title(ctx["replay"], title)
        if sid == "deployed":
            title = f"{title}: {ctx['deployed']['kind']}"
        sections.append({"id": sid, "number": len(sections) + 1, "title": title})
    return sections
