"""Section 8 of the report: the registry's decision - champion vs candidate, per validation run,
the checks against the champion in service (relative gate, speed coverage, vanished or changed
training files, input warnings), speed-range adaptation and drift (``registry/decision.json``,
``registry/comparison.csv``).

The functions return data read from those files; the sentences and tables are in
``templates/sections/registry.html.j2``. The gates per run are the stored verdicts of rule decide
(``verdict`` and ``champion_verdict`` of ``registry/decision.json``,
:func:`rafi.report.verdict.registry_gates`); where no file stores a model's verdict the section
says so and judges nothing.
"""

from __future__ import annotations

import pandas as pd

from rafi.family.confirmation import awaiting_confirmation
from rafi.report.ensemble_section import adapted_from, adapted_weight_rule
from rafi.report.format import isnum, short_id, truthy
from rafi.report.inputs import noise_floors
from rafi.report.requalification_section import confirmed_fitness
from rafi.report.verdict import artefact_of, registry_gates


def worst_with_noise(summ_rec: dict | None, noise: dict) -> dict:
    """The worst max |residual| of a decision's model summary and the noise floor of its run.

    Parameters
    ----------
    summ_rec : dict or None
        ``candidate_summary`` / ``champion_summary`` of ``registry/decision.json``:
        ``max_residual_um`` and ``runs`` (run id -> ``max_abs_after_um``, ...).
    noise : dict
        Run id -> noise floor (:func:`rafi.report.inputs.noise_floors`).

    Returns
    -------
    dict
        ``value`` (um, ``None`` when unknown) and ``noise``: the noise floor of the run with
        the largest ``max_abs_after_um`` (``None`` when that run has none).
    """
    rec = summ_rec or {}
    per_run = {
        str(k): float(v["max_abs_after_um"])
        for k, v in (rec.get("runs") or {}).items()
        if isinstance(v, dict) and isnum(v.get("max_abs_after_um"))
    }
    worst = max(per_run, key=per_run.get) if per_run else None
    return {"value": rec.get("max_residual_um"), "noise": noise.get(worst) if worst else None}


def model_column(
    model_id, summary: dict | None, run_gates: dict | None, info: dict, noise: dict
) -> dict | None:
    """One model's column of the champion-and-candidate table (``None`` without the model).

    Parameters
    ----------
    model_id : str or None
    summary : dict or None
        The model's summary in ``registry/decision.json``.
    run_gates : dict or None
        ``run_id -> (passed, failed criteria)`` (:func:`rafi.report.verdict.registry_gates`);
        ``None`` when no file stores the model's verdict.
    info : dict
        The model's ``kind``, ``created`` and training ``files`` (:func:`rafi.report.verdict.model_infos`).
    noise : dict
        Run id -> noise floor.

    Returns
    -------
    dict or None
        ``id``, ``kind``, ``created``, ``files``, ``worst`` (:func:`worst_with_noise`),
        ``min_improvement_pct``, ``n_runs`` and ``n_failed`` (runs with gates; failed) and
        ``gates_stored`` (false: no file stores its verdict, ``n_runs`` is 0).
    """
    if not model_id:
        return None
    return {
        "id": model_id,
        "kind": info.get("kind"),
        "created": info.get("created"),
        "files": list(info.get("files") or []),
        "worst": worst_with_noise(summary, noise),
        "min_improvement_pct": (summary or {}).get("min_improvement_pct"),
        "n_runs": len(run_gates or {}),
        "n_failed": sum(1 for ok, _ in (run_gates or {}).values() if not ok),
        "gates_stored": run_gates is not None,
    }


def ordered_comparison(comp: pd.DataFrame | None, runs: pd.DataFrame | None) -> pd.DataFrame | None:
    """``registry/comparison.csv`` in the order of ``runs.csv`` (runs it does not list last)."""
    if comp is None or not len(comp) or runs is None:
        return comp
    order = {str(r): k for k, r in enumerate(runs["run_id"].astype(str))}
    comp = comp.assign(_o=comp["run_id"].astype(str).map(order).fillna(len(order)))
    return comp.sort_values("_o", kind="stable").drop(columns="_o")


def _gate_fields(who: str, gate) -> dict:
    """``<who>_passed`` (``None``: no gates) and ``<who>_failed`` (criteria) of one run."""
    passed, failed = gate if gate is not None else (None, [])
    return {f"{who}_passed": passed, f"{who}_failed": list(failed)}


def per_run_rows(comp: pd.DataFrame | None, noise: dict, gates: dict) -> list[dict] | None:
    """One row per validation run of ``registry/comparison.csv``: its role, max |dz|, noise
    floor, both models' max |residual|, improvement and gates (``None`` without runs).

    Parameters
    ----------
    comp : DataFrame or None
        ``registry/comparison.csv`` (:func:`ordered_comparison`).
    noise : dict
        Run id -> noise floor.
    gates : dict
        :func:`rafi.report.verdict.registry_gates`.
    """
    if comp is None or not len(comp):
        return None
    rows = []
    for r in comp.to_dict("records"):
        rid = str(r["run_id"])
        rows.append(
            {
                "run_id": rid,
                "new": truthy(r.get("new_since_champion", False)),
                "role": str(r.get("role", "")).replace("validation_", ""),
                "max_abs_before_um": r.get("max_abs_before_um"),
                "noise_floor_um": noise.get(rid),
                "champion_max_abs_after_um": r.get("champion_max_abs_after_um"),
                "champion_improvement_pct": r.get("champion_improvement_pct"),
                **_gate_fields("champion", gates["champion"].get(rid) if gates["champion"] else None),
                "candidate_max_abs_after_um": r.get("candidate_max_abs_after_um"),
                "candidate_improvement_pct": r.get("candidate_improvement_pct"),
                **_gate_fields("candidate", gates["candidate"].get(rid) if gates["candidate"] else None),
            }
        )
    return rows


def adaptation_words(artefact: dict | None) -> str | None:
    """What the candidate is when it was adapted from a prior, in words, from its artefact's
    ``adaptation`` block; ``None`` for a model fitted from scratch (or no artefact).

    An ensemble adapted as a whole (``prior_shared_gain``, ``prior_shared_ridge``) is the prior's
    members and weights, moved (:func:`rafi.report.ensemble_section.adapted_weight_rule`), not an
    ensemble of this run's kinds; a model of one kind is the prior adapted by its method.
    """
    if not isinstance(artefact, dict):
        return None
    block = artefact.get("adaptation")
    if not isinstance(block, dict) or not block.get("parent"):
        return None
    where = f" of {block['parent_machine']}" if block.get("parent_machine") else ""
    prior = f"the prior {short_id(str(block['parent']))}{where}"
    if artefact.get("kind") == "ensemble":
        adapted = adapted_from(artefact)
        n = len(artefact.get("weights") or {})
        return (
            f"an adapted ensemble: the {n} members of {prior} as this run moved them "
            f"({adapted['candidate']}), with {adapted_weight_rule(adapted)}"
        )
    method = str(block.get("method") or "")
    return f"{prior} adapted on the training runs (prior_{method}; one {artefact.get('kind')} model)"


def adaptation(dec: dict, infos: dict, artefact: dict | None = None) -> dict:
    """What this run retrained (``adaptation`` and ``retrained_speeds`` of ``decision.json``).

    ``artefact``: the candidate's artefact (:func:`rafi.report.verdict.artefact_of`), for what it
    is when adapted from a prior (:func:`adaptation_words`).

    Returns
    -------
    dict
        ``mode`` (``speed_range`` / ``full``), ``range`` (``retrain_speed_range_rpm`` as
        stored: ``None`` or ``[lo, hi]``), ``lo_hi`` (its two ends, ``None`` for a missing one),
        ``kept_from`` (the model the other speeds come from), ``note``, ``retrained``
        (``speed_rpm``, ``train_runs``, ``files`` per retrained speed), ``equals_champion``
        (the candidate is the champion), ``candidate_kind`` and ``adapted``
        (:func:`adaptation_words`; None for a model fitted from scratch).
    """
    ad = dec.get("adaptation") or {}
    cand_id = dec.get("candidate_id")
    rng = ad.get("retrain_speed_range_rpm")
    return {
        "mode": ad.get("mode", "full"),
        "range": None if rng is None else list(rng),
        "lo_hi": (list(rng or []) + [None, None])[:2],
        "kept_from": ad.get("kept_from"),
        "note": ad.get("note") or "",
        "retrained": [
            {
                "speed_rpm": r.get("speed_rpm"),
                "train_runs": [str(x) for x in r.get("train_runs") or []],
                "files": [str(x) for x in r.get("files") or []],
            }
            for r in dec.get("retrained_speeds") or []
        ],
        "equals_champion": bool(cand_id and cand_id == dec.get("champion_id_before")),
        "candidate_kind": infos.get(cand_id or "", {}).get("kind") or (artefact or {}).get("kind"),
        "adapted": adaptation_words(artefact),
    }


#: The numbers of the interval drift test the section states (``drift.interval`` of ``decision.json``).
_INTERVAL_EVIDENCE = (
    "n",
    "k",
    "level",
    "allowed_rate",
    "expected_k",
    "p_value",
    "false_alarm",
    "decorrelation_s",
)


def _pct(fraction) -> str:
    """A fraction as a percentage without trailing zeros: ``0.1`` -> ``10``, ``0.025`` -> ``2.5``."""
    return f"{100.0 * float(fraction):.6g}"


def interval_check(dr: dict | None) -> dict | None:
    """The interval drift test of ``decision.json`` (``drift.interval``, written by
    :func:`rafi.ops.drift.interval_drift`) as the section states it, or ``None`` where it has no
    evidence: an older registry (no such block), no interval (the champion's artefact has no
    ``interval`` block, its residuals no bounds), no new validation run or no champion.

    Returns
    -------
    dict or None
        ``k`` of ``n`` thinned new samples (one per ``decorrelation_s``) outside the interval,
        ``n_samples`` (usable before thinning, ``None`` when not stored), ``n_runs``,
        ``level_pct``, ``allowed_pct`` (``1 - level`` in %), ``observed_pct``, ``expected_k``,
        ``p_value``, ``false_alarm`` (``nightly.drift_false_alarm``) and ``detected`` (p-value
        below the false-alarm rate: the new data fall outside more often than the level allows).
    """
    iv = (dr or {}).get("interval")
    if not isinstance(iv, dict) or iv.get("status") not in ("ok", "recalibration_due"):
        return None
    if not all(isnum(iv.get(key)) for key in _INTERVAL_EVIDENCE) or int(iv["n"]) <= 0:
        return None
    n, k = int(iv["n"]), int(iv["k"])
    return {
        "n": n,
        "k": k,
        "n_samples": int(iv["n_samples"]) if isnum(iv.get("n_samples")) else None,
        "n_runs": len(iv.get("per_run") or {}),
        "decorrelation_s": float(iv["decorrelation_s"]),
        "level_pct": _pct(iv["level"]),
        "allowed_pct": _pct(iv["allowed_rate"]),
        "observed_pct": 100.0 * k / n,
        "expected_k": float(iv["expected_k"]),
        "p_value": float(iv["p_value"]),
        "false_alarm": f"{float(iv['false_alarm']):g}",
        "detected": truthy(iv.get("detected", False)),
    }


def drift(dec: dict, noise: dict) -> dict:
    """The drift checks of ``decision.json``: its status, the champion checked, its max residual
    at promotion and on the new validation logs (with the noise floor of the worst run), margin,
    limit, change, the new runs, whether a recalibration is due and ``interval`` (the interval
    drift test, :func:`interval_check`; ``None`` without its evidence)."""
    dr = dec.get("drift") or {}
    per_run = dr.get("per_run") or {}
    return {
        "status": str(dr.get("status", "\u2013")),
        "detected": truthy(dr.get("detected", False)),
        "recal": truthy(dec.get("recalibration_due", False)),
        "champion": dr.get("champion_id"),
        "promoted_at": dr.get("promoted_at"),
        "margin_um": dr.get("margin_um"),
        "reference_um": dr.get("reference_max_residual_um"),
        "now": worst_with_noise(
            {
                "max_residual_um": dr.get("new_max_residual_um"),
                "runs": {k: {"max_abs_after_um": v} for k, v in per_run.items()},
            },
            noise,
        ),
        "limit_um": dr.get("limit_um"),
        "degradation_um": dr.get("degradation_um"),
        "new_runs": [str(r) for r in dr.get("new_runs") or []],
        "interval": interval_check(dr),
    }


def section_registry(res: dict, infos: dict, registry_dir=None, confirmed=()) -> dict | None:
    """Section 8: the registry's decision, as data for ``sections/registry.html.j2``.

    Parameters
    ----------
    res : dict
        Loaded inputs: ``decision`` (``registry/decision.json``: the stored verdicts of both
        models, :func:`rafi.report.verdict.registry_gates`), ``registry_comparison``,
        ``runs_csv`` (the order of the runs), the noise floors and ``best_model`` (the
        candidate's artefact when it carries its id).
    infos : dict
        ``model_id -> {kind, created, files}`` (:func:`rafi.report.verdict.model_infos`).
    registry_dir : path, optional
        Where ``models/<id>.json`` are looked up (the candidate's artefact).
    confirmed : sequence of dict
        The machine's ``checks.confirmed`` (:func:`rafi.report.requalification_section.confirmed_fitness`).

    Returns
    -------
    dict or None
        ``None`` without ``decision.json``; else ``decision``, ``reasons``, ``time``,
        ``schema``, ``champion`` / ``candidate`` (:func:`model_column`), ``champion_stays``,
        ``candidate_on_machine``, ``runs`` (:func:`per_run_rows`), ``against``
        (:func:`against_champion`), ``adaptation``, ``new_files``, ``drift``, ``waiting``
        (what tonight's candidate waits for, :func:`rafi.family.confirmation.awaiting_confirmation`:
        the words of the end-of-run line; None) and ``confirmed`` (the fitness warnings a person
        confirmed, :func:`rafi.report.requalification_section.confirmed_fitness`, when the decision
        promoted the candidate on them; else None).
    """
    dec = res.get("decision")
    if not isinstance(dec, dict):
        return None
    comp = ordered_comparison(res.get("registry_comparison"), res.get("runs_csv"))
    noise = noise_floors(res)
    run_gates = registry_gates(res)
    cand_id, champ_id = dec.get("candidate_id"), dec.get("champion_id_before")
    after = dec.get("champion_id_after")
    conf = confirmed_fitness(dec, confirmed)
    return {
        "decision": str(dec.get("decision", "?")),
        "reasons": [str(r) for r in dec.get("reasons") or []],
        "time": dec.get("time") or None,
        "schema": dec.get("schema", ""),
        "champion": model_column(
            champ_id, dec.get("champion_summary"), run_gates["champion"], infos.get(champ_id or "", {}), noise
        ),
        "candidate": model_column(
            cand_id, dec.get("candidate_summary"), run_gates["candidate"], infos.get(cand_id or "", {}), noise
        ),
        "champion_stays": bool(after and after == champ_id),
        "candidate_on_machine": bool(after and after == cand_id and after != champ_id),
        "runs": per_run_rows(comp, noise, run_gates),
        "against": against_champion(dec, comp, noise),
        "adaptation": adaptation(dec, infos, artefact_of(res, cand_id, registry_dir)),
        "new_files": [str(f) for f in (dec.get("data") or {}).get("new_since_champion") or []],
        "drift": drift(dec, noise),
        "waiting": awaiting_confirmation(dec),
        "confirmed": conf if conf is not None and conf["promoted"] else None,
    }


def relative_rows(comp: pd.DataFrame | None, noise: dict | None = None) -> list[dict] | None:
    """The relative gate per validation run (``registry/comparison.csv``): both models' max
    |residual|, the difference, noise floor (the run's, ``noise``:
    :func:`rafi.report.inputs.noise_floors`; without it the table's), margin (as the decision
    applied it) and ``state`` (``worse``, ``not_worse``, ``not_compared``: a model has no finite
    prediction); ``None`` without the columns."""
    if comp is None or not len(comp) or "candidate_worse" not in comp:
        return None
    rows = []
    for r in comp.to_dict("records"):
        scored = truthy(r.get("both_scored", False))
        worse = truthy(r.get("candidate_worse", False))
        margin = r.get("margin_um")
        rows.append(
            {
                "run_id": str(r["run_id"]),
                "champion_max_abs_after_um": r.get("champion_max_abs_after_um"),
                "candidate_max_abs_after_um": r.get("candidate_max_abs_after_um"),
                "candidate_minus_champion_um": r.get("candidate_minus_champion_um"),
                "noise_floor_um": r.get("noise_floor_um") if noise is None else noise.get(str(r["run_id"])),
                "margin_um": margin if scored or isnum(margin) else None,
                "state": "worse" if worse else "not_worse" if scored else "not_compared",
            }
        )
    return rows


def changed_files(data: dict) -> list[dict] | None:
    """The champion's training files gone (``vanished``), changed or renamed since its training
    (``data`` of ``decision.json``): ``file``, ``state``, ``why``, ``sha256_champion``,
    ``sha256_now``, ``now`` (a renamed file's new name); ``None`` without any."""
    rows = [
        {"file": str(v.get("file")), "state": "vanished", "why": str(v.get("why") or "")}
        for v in data.get("vanished") or []
    ]
    rows += [
        {
            "file": str(c.get("file")),
            "state": "changed",
            "sha256_champion": c.get("sha256_champion"),
            "sha256_now": c.get("sha256_now"),
        }
        for c in data.get("changed") or []
    ]
    rows += [
        {"file": str(r.get("file")), "state": "renamed", "now": r.get("now")}
        for r in data.get("renamed") or []
    ]
    return rows or None


def warning_rows(warns: dict) -> list[dict] | None:
    """The input warnings of ``decision.json`` (``input_warnings``): ``file`` (``None``: the
    machine), ``check``, ``column``, ``message`` and ``group`` (``blocking``, ``confirmed``,
    ``not_used``: not confirmed, on a file not used tonight); ``None`` without any."""
    rows = [
        {
            "file": w.get("file") or None,
            "check": str(w.get("check")),
            "column": w.get("column") or None,
            "message": str(w.get("message") or ""),
            "group": group,
        }
        for group in ("blocking", "confirmed", "not_used")
        for w in warns.get(group) or []
    ]
    return rows or None


def against_champion(dec: dict, comp, noise: dict | None = None) -> dict | None:
    """The checks of tonight's candidate against the champion in service (issue 13 item 4).

    Parameters
    ----------
    dec : dict
        ``registry/decision.json``.
    comp : DataFrame or None
        ``registry/comparison.csv``.
    noise : dict, optional
        Run id -> noise floor (:func:`rafi.report.inputs.noise_floors`).

    Returns
    -------
    dict or None
        ``None`` for a decision.json written before these checks existed; else ``blocked``
        (what blocked promotion), ``has_champion``, ``rejected``, ``relative_gate`` (as stored)
        with ``n_worse`` and ``relative`` (:func:`relative_rows`, with a champion),
        ``coverage`` (as stored), ``files`` (:func:`changed_files`) and ``warnings``
        (:func:`warning_rows`).
    """
    if not any(k in dec for k in ("relative_gate", "coverage", "input_warnings")):
        return None
    rel = dict(dec.get("relative_gate") or {})
    has_champion = bool(dec.get("champion_id_before"))
    return {
        "blocked": [str(b) for b in dec.get("blocked_by") or []],
        "has_champion": has_champion,
        "rejected": dec.get("decision") == "rejected",
        "relative_gate": {
            "applied": bool(rel.get("applied")),
            "passed": rel.get("passed", True),
            "n_runs_both_scored": rel.get("n_runs_both_scored", 0),
            "n_worse": len(rel.get("worse_runs") or []),
            "margin": rel.get("champion_margin_um", "noise"),
        },
        "relative": relative_rows(comp, noise) if has_champion else None,
        "coverage": dict(dec.get("coverage") or {}),
        "files": changed_files(dec.get("data") or {}),
        "warnings": warning_rows(dec.get("input_warnings") or {}),
    }
