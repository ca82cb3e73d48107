"""Section 8 of the report: the registry's decision - champion vs candidate, per validation run,
the checks against the champion in service (relative gate, speed coverage, vanished or changed
training files, input warnings), speed-range adaptation and drift (``registry/decision.json``,
``registry/comparison.csv``)."""

from __future__ import annotations

from markupsafe import Markup, escape

from rafi.report.format import cell, fmt_num, fmt_speed, isnum, micro, run_label, short_id, table, truthy
from rafi.report.inputs import noise_floors
from rafi.report.verdict import DECISION_TEXT, per_run_gates, registry_summary

GATE_SHORT = {
    "max_residual_um": "residual",
    "min_improvement_pct": "improvement",
    "never_worse_than_uncompensated": "worse than uncomp.",
}


def gate_cell(result) -> dict:
    if result is None:
        return cell("\u2013")
    ok, failed = result
    if ok:
        return cell("PASS", "pass")
    return cell("FAIL: " + ", ".join(GATE_SHORT.get(c, c) for c in failed), "fail")


def worst_with_noise(summ_rec: dict | None, noise: dict) -> str:
    """``max_residual_um`` of a decision's model summary, with the noise floor of the run it
    comes from (the run of ``runs`` with the largest ``max_abs_after_um``; none when unknown)."""
    rec = summ_rec or {}
    text = fmt_num(rec.get("max_residual_um"), 2, "\u00b5m")
    per_run = {
        str(k): float(v["max_abs_after_um"])
        for k, v in (rec.get("runs") or {}).items()
        if isinstance(v, dict) and isnum(v.get("max_abs_after_um"))
    }
    if per_run:
        worst = max(per_run, key=per_run.get)
        if worst in noise:
            text += " (noise floor of that run " + fmt_num(noise[worst], 2, "\u00b5m") + ")"
    return text


def section_registry(res: dict, gates: dict, infos: dict):
    dec = res.get("decision")
    if not isinstance(dec, dict):
        return None
    decision = str(dec.get("decision", "?"))
    cls, word, meaning = DECISION_TEXT.get(decision, ("neutral", decision.upper(), ""))
    out = {
        "decision": decision,
        "cls": cls,
        "word": word,
        "meaning": meaning,
        "reasons": [micro(r) for r in dec.get("reasons") or []],
        "time": str(dec.get("time") or "\u2013"),
        "schema": dec.get("schema", ""),
    }
    cand_id, champ_id = dec.get("candidate_id"), dec.get("champion_id_before")
    after = dec.get("champion_id_after")
    comp = res.get("registry_comparison")
    cand_s, champ_s = registry_summary(comp, "candidate"), registry_summary(comp, "champion")
    cs, ks = dec.get("candidate_summary") or {}, dec.get("champion_summary") or {}
    noise = noise_floors(res)

    def info_col(mid, summ_rec, summ, present):
        if not mid:
            return ["none (no champion yet)" if not present else "\u2013"] + ["\u2013"] * 6
        i = infos.get(mid, {})
        files = i.get("files")
        gate = per_run_gates(summ, gates) if summ is not None else {}
        n_fail = sum(1 for ok, _ in gate.values() if not ok)
        files_text = Markup(", ".join(str(escape(f)) for f in files)) if files else "\u2013"
        return [
            Markup(f"<code>{escape(short_id(mid))}</code>"),
            i.get("kind") or "\u2013",
            i.get("created") or "\u2013",
            cell(Markup(f"{len(files)} file(s): <small>{files_text}</small>")) if files else "\u2013",
            worst_with_noise(summ_rec, noise),
            fmt_num((summ_rec or {}).get("min_improvement_pct"), 1, "%"),
            (
                cell("no validation runs", "")
                if not gate
                else cell("PASS on every run", "pass")
                if n_fail == 0
                else cell(f"FAIL on {n_fail} of {len(gate)} run(s)", "fail")
            ),
        ]

    labels = [
        "model id",
        "kind",
        "created",
        "training data",
        "worst max residual (all validation runs)",
        "min improvement (all validation runs)",
        "gates",
    ]
    champ_col = info_col(champ_id, ks, champ_s, False)
    cand_col = info_col(cand_id, cs, cand_s, True)
    rows = [[cell(label, "rowhead"), a, b] for label, a, b in zip(labels, champ_col, cand_col)]
    head_champ = "champion before this run" + (" (stays)" if after and after == champ_id else "")
    head_cand = "candidate" + (
        " (now on the machine)" if after and after == cand_id and after != champ_id else ""
    )
    out["side"] = table(["", head_champ, head_cand], rows, cls="side", widths=[22, 39, 39])

    # per validation run
    out["runs"] = None
    if comp is not None and len(comp) and res.get("runs_csv") is not None:
        order = {str(r): k for k, r in enumerate(res["runs_csv"]["run_id"].astype(str))}
        comp = comp.assign(_o=comp["run_id"].astype(str).map(order).fillna(len(order)))
        comp = comp.sort_values("_o", kind="stable").drop(columns="_o")
    if comp is not None and len(comp):
        g_c = per_run_gates(cand_s, gates) if cand_s is not None else {}
        g_k = per_run_gates(champ_s, gates) if champ_s is not None else {}
        rows = []
        for r in comp.to_dict("records"):
            rid = str(r["run_id"])
            new = truthy(r.get("new_since_champion", False))
            rows.append(
                [
                    cell(Markup(f"{run_label(rid)}" + (' <span class="tag">new</span>' if new else ""))),
                    str(r.get("role", "")).replace("validation_", ""),
                    fmt_num(r.get("max_abs_before_um"), 2),
                    fmt_num(noise.get(rid), 2),
                    fmt_num(r.get("champion_max_abs_after_um"), 2),
                    fmt_num(r.get("champion_improvement_pct"), 1),
                    gate_cell(g_k.get(rid)) if g_k else "\u2013",
                    fmt_num(r.get("candidate_max_abs_after_um"), 2),
                    fmt_num(r.get("candidate_improvement_pct"), 1),
                    gate_cell(g_c.get(rid)) if g_c else "\u2013",
                ]
            )
        out["runs"] = table(
            [
                "validation run",
                "role",
                "max |dz| uncomp. (\u00b5m)",
                "noise floor (\u00b5m)",
                "champion max |res.| (\u00b5m)",
                "champion impr. (%)",
                "champion gates",
                "candidate max |res.| (\u00b5m)",
                "candidate impr. (%)",
                "candidate gates",
            ],
            rows,
            cls="num runs-cmp",
            widths=[17, 7, 8, 7, 10, 8, 10, 10, 8, 15],
        )

    out["against"] = against_champion(dec, comp)

    # speed-range adaptation
    ad = dec.get("adaptation") or {}
    rng = ad.get("retrain_speed_range_rpm")
    rs = dec.get("retrained_speeds") or []
    mode = ad.get("mode", "full")
    if mode == "speed_range":
        lo, hi = (list(rng or []) + [None, None])[:2]
        text = (
            f"Speed-range adaptation: only the speeds in [{fmt_num(lo, 0)}, "
            f"{fmt_speed(hi)}] were retrained from this run's data; every other speed keeps "
            f"the champion's regression (from model {short_id(ad.get('kept_from'))})."
        )
    elif rng is not None:
        text = (
            f"Speed-range adaptation was requested (retrain_speed_range_rpm = {rng}) but the "
            "full new fit is the candidate."
        )
    else:
        ckind = infos.get(cand_id or "", {}).get("kind")
        text = "Full refit: retrain_speed_range_rpm is not set, so the candidate is the complete new fit"
        if rs:
            text += " (every speed retrained on the runs below)."
        elif cand_id and cand_id == champ_id:
            text += "; it equals the champion (no new training data), nothing was retrained."
        elif ckind and ckind not in ("rafi", "rafi_linear"):
            text += (
                f"; {ckind} is one global model fitted on every training run (no per-speed "
                "regressions to list)."
            )
        else:
            text += "."
    out["adapt_text"] = text
    out["adapt_note"] = ad.get("note") or ""
    out["retrained"] = None
    if rs:
        out["retrained"] = table(
            ["speed", "training runs", "files"],
            [
                [
                    fmt_speed(r.get("speed_rpm")),
                    cell(Markup(", ".join(str(run_label(x)) for x in r.get("train_runs") or [])) or "\u2013"),
                    cell(
                        Markup(
                            "<small>" + ", ".join(str(escape(x)) for x in r.get("files") or []) + "</small>"
                        )
                    ),
                ]
                for r in rs
            ],
            cls="num",
            widths=[16, 34, 50],
        )
    new_files = (dec.get("data") or {}).get("new_since_champion") or []
    out["new_files"] = ", ".join(str(f) for f in new_files)

    # drift
    dr = dec.get("drift") or {}
    status = str(dr.get("status", "\u2013"))
    recal = truthy(dec.get("recalibration_due", False))
    status_text = {
        "ok": "no drift: the champion's residual on the new validation logs is within the margin",
        "degraded": "DRIFT DETECTED: the champion's residual on the new validation logs grew "
        "beyond the margin",
        "no_new_runs": "no validation log is new since the champion's promotion: nothing to check",
        "no_reference": "the champion's residual at promotion is unknown: drift cannot be judged",
        "no_champion": "no champion yet: nothing to check",
    }.get(status, status)
    if status == "degraded" and not recal:
        status_text += "; resolved by tonight's promotion (no recalibration due)"
    per_run = dr.get("per_run") or {}
    out["drift"] = {
        "status": status,
        "text": status_text,
        "detected": truthy(dr.get("detected", False)),
        "recal": recal,
        "champion": short_id(dr.get("champion_id")),
        "promoted_at": dr.get("promoted_at") or "\u2013",
        "margin": fmt_num(dr.get("margin_um"), 2, "\u00b5m"),
        "reference": fmt_num(dr.get("reference_max_residual_um"), 2, "\u00b5m"),
        "now": worst_with_noise(
            {
                "max_residual_um": dr.get("new_max_residual_um"),
                "runs": {k: {"max_abs_after_um": v} for k, v in per_run.items()},
            },
            noise,
        ),
        "limit": fmt_num(dr.get("limit_um"), 2, "\u00b5m"),
        "degradation": fmt_num(dr.get("degradation_um"), 2, "\u00b5m", signed=True),
        "new_runs": Markup(", ".join(str(run_label(r)) for r in dr.get("new_runs") or [])),
        "per_run": table(
            ["new validation run", "champion max |residual|", "noise floor of the run"],
            [
                [cell(run_label(k)), fmt_num(v, 2, "\u00b5m"), fmt_num(noise.get(str(k)), 2, "\u00b5m")]
                for k, v in per_run.items()
            ],
            cls="num narrow",
        )
        if per_run
        else None,
    }
    return out


def _speeds(speeds) -> str:
    if speeds is None:
        return "unknown"
    return ", ".join(fmt_speed(s) for s in speeds) or "none"


def _relative_table(comp):
    if comp is None or not len(comp) or "candidate_worse" not in comp:
        return None
    rows = []
    for r in comp.to_dict("records"):
        scored = truthy(r.get("both_scored", False))
        worse = truthy(r.get("candidate_worse", False))
        margin = r.get("margin_um")
        rows.append(
            [
                cell(run_label(str(r["run_id"]))),
                fmt_num(r.get("champion_max_abs_after_um"), 2),
                fmt_num(r.get("candidate_max_abs_after_um"), 2),
                fmt_num(r.get("candidate_minus_champion_um"), 2, signed=True),
                fmt_num(r.get("noise_floor_um"), 2),
                fmt_num(margin, 2) if scored or isnum(margin) else "\u2013",
                cell("WORSE", "fail")
                if worse
                else cell("not worse", "pass")
                if scored
                else cell("not compared (a model has no finite prediction)", ""),
            ]
        )
    return table(
        [
            "validation run",
            "champion max |res.| (\u00b5m)",
            "candidate max |res.| (\u00b5m)",
            "candidate \u2212 champion (\u00b5m)",
            "noise floor (\u00b5m)",
            "margin (\u00b5m)",
            "relative gate",
        ],
        rows,
        cls="num",
        widths=[20, 13, 13, 13, 11, 10, 20],
    )


def against_champion(dec: dict, comp) -> dict | None:
    """The checks of tonight's candidate against the champion in service (issue 13 item 4):
    relative gate per run, coverage of the champion's speeds, the champion's training files
    gone or changed, and the input warnings (blocking, confirmed). None for a decision.json
    written before these checks existed."""
    keys = ("relative_gate", "coverage", "input_warnings")
    if not any(k in dec for k in keys):
        return None
    rel = dec.get("relative_gate") or {}
    cov = dec.get("coverage") or {}
    warns = dec.get("input_warnings") or {}
    data = dec.get("data") or {}
    blocked = [str(b) for b in dec.get("blocked_by") or []]
    margin = rel.get("champion_margin_um", "noise")
    margin_text = (
        "the run's noise floor (the expected max |noise| of its dz)"
        if isinstance(margin, str)
        else fmt_num(margin, 2, "\u00b5m")
    )
    has_champion = bool(dec.get("champion_id_before"))
    if not has_champion:
        rel_text = "No champion yet: only the absolute gates apply."
    elif not rel.get("applied"):
        rel_text = "No validation run both the candidate and the champion can be scored on: not applied."
    elif rel.get("passed", True):
        rel_text = (
            f"Not worse than the champion on any of the {rel.get('n_runs_both_scored', 0)} validation "
            f"run(s) both are scored on (margin: {margin_text})."
        )
    else:
        rel_text = (
            f"WORSE than the champion on {len(rel.get('worse_runs') or [])} of "
            f"{rel.get('n_runs_both_scored', 0)} validation run(s) by more than the margin ({margin_text}): "
            "not promoted."
        )
    status = cov.get("status")
    missing = cov.get("missing_speeds_rpm") or []
    cov_text = {
        "ok": "The candidate's training covers every speed the champion was trained on.",
        "missing": f"The candidate's training has no run at {_speeds(missing)}, a speed the champion "
        "was trained on: not promoted.",
        "unknown_runs": "The speed of the champion's training run(s) "
        + ", ".join(str(r) for r in cov.get("unknown_runs") or [])
        + " is unknown (gone from the data, not recorded at its promotion): not promoted.",
        "no_champion": "No champion yet: nothing to cover.",
        "not_checked": "Not checked: a model does not record what it was trained on.",
    }.get(status, "\u2013")
    cov_rows = None
    if status not in (None, "no_champion"):
        cov_rows = table(
            ["", "speeds (tolerance " + fmt_num(cov.get("tolerance_rpm"), 0, "r/min") + ")", "from"],
            [
                [
                    cell("champion", "rowhead"),
                    _speeds(cov.get("champion_speeds_rpm")),
                    cov.get("champion_source") or "\u2013",
                ],
                [
                    cell("candidate", "rowhead"),
                    _speeds(cov.get("candidate_speeds_rpm")),
                    cov.get("candidate_source") or "\u2013",
                ],
                [
                    cell("missing", "rowhead"),
                    cell(_speeds(missing), "fail") if missing else cell("none", "pass"),
                    "",
                ],
            ],
            cls="kv narrow",
        )
    files = [
        [cell(str(v.get("file"))), cell("vanished", "fail"), str(v.get("why") or "")]
        for v in data.get("vanished") or []
    ]
    files += [
        [
            cell(str(c.get("file"))),
            cell("changed", "fail"),
            f"sha256 {short_id(c.get('sha256_champion'))} at training, {short_id(c.get('sha256_now'))} now",
        ]
        for c in data.get("changed") or []
    ]
    files += [
        [cell(str(r.get("file"))), "renamed", f"same content as {r.get('now')}"]
        for r in data.get("renamed") or []
    ]

    def warn_rows(entries, state, cls):
        return [
            [
                cell(str(w.get("file") or "(machine)")),
                cell(Markup(f"<code>{escape(str(w.get('check')))}</code>")),
                str(w.get("column") or "\u2013"),
                cell(state, cls),
                str(w.get("message") or ""),
            ]
            for w in entries
        ]

    wrows = (
        warn_rows(
            warns.get("blocking") or [],
            "NOT CONFIRMED: blocks promotion"
            if dec.get("decision") == "rejected"
            else "not confirmed (would block a promotion)",
            "fail",
        )
        + warn_rows(warns.get("confirmed") or [], "confirmed", "pass")
        + warn_rows(warns.get("not_used") or [], "not confirmed; file not used tonight", "")
    )
    return {
        "blocked": ", ".join(b.replace("_", " ") for b in blocked),
        "relative_text": rel_text,
        "relative_fail": bool(has_champion and not rel.get("passed", True)),
        "relative": _relative_table(comp) if has_champion else None,
        "coverage_text": cov_text,
        "coverage_fail": bool(cov.get("blocking")),
        "coverage": cov_rows,
        "files": table(
            ["training file of the champion", "now", "detail"], files, cls="narrow", widths=[30, 12, 58]
        )
        if files
        else None,
        "n_blocking_warnings": len(warns.get("blocking") or []),
        "warnings": table(["file", "check", "column", "state", "message"], wrows, widths=[18, 14, 8, 16, 44])
        if wrows
        else None,
    }
