"""Section 8 of the report: the registry's decision - champion vs candidate, per validation run,
speed-range adaptation and drift (``registry/decision.json``, ``registry/comparison.csv``)."""

from __future__ import annotations

from markupsafe import Markup, escape

from rafi.report.format import cell, fmt_num, fmt_speed, run_label, short_id, table, truthy
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
        "reasons": [str(r) for r in dec.get("reasons") or []],
        "time": str(dec.get("time") or "\u2013"),
        "schema": dec.get("schema", ""),
    }
    cand_id, champ_id = dec.get("candidate_id"), dec.get("champion_id_before")
    after = dec.get("champion_id_after")
    comp = res.get("registry_comparison")
    cand_s, champ_s = registry_summary(comp, "candidate"), registry_summary(comp, "champion")
    cs, ks = dec.get("candidate_summary") or {}, dec.get("champion_summary") or {}

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
            fmt_num((summ_rec or {}).get("max_residual_um"), 2, "\u00b5m"),
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
        noise = noise_floors(res)
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
        "now": fmt_num(dr.get("new_max_residual_um"), 2, "\u00b5m"),
        "limit": fmt_num(dr.get("limit_um"), 2, "\u00b5m"),
        "degradation": fmt_num(dr.get("degradation_um"), 2, "\u00b5m", signed=True),
        "new_runs": Markup(", ".join(str(run_label(r)) for r in dr.get("new_runs") or [])),
        "per_run": table(
            ["new validation run", "champion max |residual|"],
            [[cell(run_label(k)), fmt_num(v, 2, "\u00b5m")] for k, v in per_run.items()],
            cls="num narrow",
        )
        if per_run
        else None,
    }
    return out
