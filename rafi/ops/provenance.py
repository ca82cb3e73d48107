"""What tonight's candidate was trained on, against the champion in service (issue 13 item 4).

* :func:`trained_speeds` / :func:`champion_speeds` / :func:`speed_coverage`: a candidate is
  promoted only if its training data covers every speed the champion's did (within the
  machine's ``speed_tolerance_rpm``);
* :func:`training_data_changes`: training files of the champion that are gone from tonight's
  data or whose content changed (reported, not blocking: the other gates judge the result);
* :func:`input_warnings`: the plausibility warnings of ``input_status.json`` on files tonight's
  data uses; an unconfirmed one blocks promotion;
* :func:`prior_warnings`: the fitness warnings of a candidate adapted from a prior
  (:mod:`rafi.family.prior_fitness`); an unconfirmed one blocks promotion likewise, confirmed in
  the same ``checks.confirmed`` as ``{file: <the prior's model id>, check: <check id>}``;
* :func:`confirming_entries`: which entries of ``checks.confirmed`` confirm a warning (kept with
  it: what a promotion rested on).

Pure functions on dicts and frames; no I/O.
"""

from __future__ import annotations

import math

import pandas as pd

from rafi.family.confirmation import confirmation_entry
from rafi.family.prior_fitness import warning_remedy


def _speed_of_run(runs_table: pd.DataFrame) -> dict[str, float]:
    if not {"run_id", "speed_rpm"} <= set(runs_table.columns):
        return {}
    speeds = pd.to_numeric(runs_table["speed_rpm"], errors="coerce")
    return {str(r): float(s) for r, s in zip(runs_table["run_id"], speeds) if pd.notna(s)}


def _unique(speeds) -> list[float]:
    return sorted({float(s) for s in speeds if s is not None and math.isfinite(float(s))})


def trained_speeds(model_dict: dict | None, runs_table: pd.DataFrame) -> dict:
    """The speeds a model was trained on.

    From the artefact's per-speed models (``speeds``: kinds ``rafi``, ``rafi_linear``), else
    from its ``train_runs`` (global kinds: ``ridge_global``, ``grey_box``, ``dynamic``) looked
    up in ``runs_table`` (``speed_rpm`` per ``run_id``).

    Returns
    -------
    dict
        ``speeds_rpm`` (sorted, or None when the model says nothing about its training),
        ``train_runs``, ``source`` (``artefact speeds`` / ``training runs`` / ``unknown``) and
        ``unknown_runs`` (training runs not in ``runs_table``: their speed is unknown).
    """
    d = model_dict or {}
    per_speed = d.get("speeds") or []
    if per_speed:
        runs = sorted({str(r) for sp in per_speed for r in sp.get("train_runs", [])})
        return {
            "speeds_rpm": _unique(sp.get("speed_rpm") for sp in per_speed),
            "train_runs": runs,
            "source": "artefact speeds",
            "unknown_runs": [],
        }
    runs = [str(r) for r in d.get("train_runs") or []]
    if not runs:
        return {"speeds_rpm": None, "train_runs": [], "source": "unknown", "unknown_runs": []}
    speed = _speed_of_run(runs_table)
    return {
        "speeds_rpm": _unique(speed[r] for r in runs if r in speed),
        "train_runs": runs,
        "source": "training runs",
        "unknown_runs": [r for r in runs if r not in speed],
    }


def champion_speeds(champion_dict: dict | None, promotion: dict | None, runs_table: pd.DataFrame) -> dict:
    """The champion's training speeds: its artefact's per-speed models, else the speeds recorded
    in its promotion record (``training.speeds_rpm`` of history.jsonl), else its training runs
    in tonight's ``runs_table`` (a run whose file is gone has an unknown speed)."""
    if champion_dict is not None and champion_dict.get("speeds"):
        return trained_speeds(champion_dict, runs_table)
    recorded = ((promotion or {}).get("training") or {}).get("speeds_rpm")
    if recorded is not None:
        return {
            "speeds_rpm": _unique(recorded),
            "train_runs": list(((promotion or {}).get("training") or {}).get("train_runs") or []),
            "source": "promotion record",
            "unknown_runs": [],
        }
    return trained_speeds(champion_dict, runs_table)


def with_prior_speeds(
    candidate_model: dict, candidate: dict, champion_id: str | None, champion_training
) -> dict:
    """A candidate adapted from the champion (``adaptation.parent``: :mod:`rafi.family.adapted`)
    keeps what the champion learnt at its training speeds, so those speeds count as covered
    besides tonight's runs; any other candidate's speeds are returned as they are."""
    parent = ((candidate_model or {}).get("adaptation") or {}).get("parent")
    if not parent or parent != champion_id or not champion_training:
        return candidate
    if champion_training.get("speeds_rpm") is None or candidate.get("speeds_rpm") is None:
        return candidate
    speeds = sorted(set(candidate["speeds_rpm"]) | set(champion_training["speeds_rpm"]))
    source = f"{candidate.get('source')} + prior {str(parent)[:12]}"
    return {**candidate, "speeds_rpm": speeds, "source": source}


def speed_coverage(champion: dict | None, candidate: dict, tolerance_rpm: float) -> dict:
    """Does the candidate's training cover every speed the champion's did?

    A champion speed is covered if a candidate training speed lies within ``tolerance_rpm``.
    ``status``: ``ok``, ``missing`` (speeds in ``missing_speeds_rpm``), ``unknown_runs``
    (champion training runs whose speed is known nowhere: not covered, by caution),
    ``no_champion``, or ``not_checked`` (the candidate says nothing about its training, or the
    champion nothing about its). ``blocking`` is true for ``missing`` and ``unknown_runs``.
    """
    tol = float(tolerance_rpm)
    out = {
        "status": "ok",
        "blocking": False,
        "tolerance_rpm": tol,
        "champion_speeds_rpm": None,
        "champion_source": None,
        "candidate_speeds_rpm": candidate.get("speeds_rpm"),
        "candidate_source": candidate.get("source"),
        "missing_speeds_rpm": [],
        "unknown_runs": [],
    }
    if champion is None:
        out["status"] = "no_champion"
        return out
    out["champion_speeds_rpm"] = champion.get("speeds_rpm")
    out["champion_source"] = champion.get("source")
    champ, cand = champion.get("speeds_rpm"), candidate.get("speeds_rpm")
    if champ is None or cand is None:
        out["status"] = "not_checked"
        return out
    out["missing_speeds_rpm"] = [s for s in champ if not any(abs(s - c) <= tol for c in cand)]
    out["unknown_runs"] = list(champion.get("unknown_runs") or [])
    if out["missing_speeds_rpm"]:
        out["status"] = "missing"
    elif out["unknown_runs"]:
        out["status"] = "unknown_runs"
    out["blocking"] = out["status"] in ("missing", "unknown_runs")
    return out


def coverage_reasons(cov: dict, champion_id: str | None) -> list[str]:
    """Reason lines of :func:`speed_coverage` (none when nothing blocks)."""
    who = f"champion {str(champion_id)[:12]}"
    tol = f"{cov['tolerance_rpm']:g}"
    out = []
    for s in cov["missing_speeds_rpm"]:
        out.append(
            f"coverage: the candidate's training data has no run at {s:g} r/min (within {tol} r/min), "
            f"a speed {who} was trained on; record or restore a training run at that speed"
        )
    if cov["status"] == "unknown_runs":
        runs = ", ".join(cov["unknown_runs"][:5]) + (" ..." if len(cov["unknown_runs"]) > 5 else "")
        out.append(
            f"coverage: the speed of {who}'s training run(s) {runs} is unknown (not in tonight's data, "
            "not recorded at its promotion), so the candidate's coverage cannot be confirmed; restore "
            "the file, or promote by hand (rafi nightly --promote <model id>)"
        )
    return out


def files_of(runs_table: pd.DataFrame) -> dict[str, str]:
    """``file -> sha256`` of the raw files tonight's runs come from."""
    if not {"file", "sha256"} <= set(runs_table.columns):
        return {}
    return dict(zip(runs_table["file"].astype(str), runs_table["sha256"].astype(str)))


def training_data_changes(
    champion_data: dict | None,
    tonight: dict[str, str],
    rejected: list[dict] | None = None,
    usable: list[str] | None = None,
) -> dict:
    """Training files of the champion (``{file: sha256}``) missing from tonight's data or changed.

    Parameters
    ----------
    champion_data : dict
        What the champion trained on (its artefact's ``data``).
    tonight : dict
        ``file -> sha256`` of the files tonight's runs come from (:func:`files_of`).
    rejected, usable : list, optional
        ``rejected`` and ``usable`` of tonight's ``input_status.json``: say why a file is
        missing (quarantined tonight, or read but giving no run).

    Returns
    -------
    dict
        ``vanished``: ``[{file, sha256, why}]`` (a file whose content is still there under
        another name is not vanished: it is listed in ``renamed`` as ``{file, now}``);
        ``changed``: ``[{file, sha256_champion, sha256_now}]``.
    """
    vanished, changed, renamed = [], [], []
    by_hash = {h: f for f, h in tonight.items()}
    why_rejected = {str(r.get("file")): str(r.get("reason") or "") for r in rejected or []}
    usable_set = {str(f) for f in usable or []}
    for name, sha in sorted((champion_data or {}).items()):
        now = tonight.get(name)
        if now is not None:
            if now != sha:
                changed.append({"file": name, "sha256_champion": sha, "sha256_now": now})
            continue
        if sha in by_hash:
            renamed.append({"file": name, "now": by_hash[sha]})
            continue
        if name in why_rejected:
            why = f"quarantined tonight: {why_rejected[name]}"
        elif name in usable_set:
            why = "read tonight but gives no run"
        else:
            why = "no longer in the raw folder"
        vanished.append({"file": name, "sha256": sha, "why": why})
    return {"vanished": vanished, "changed": changed, "renamed": renamed}


#: At most this many names in the one reason line of the champion's training files that are no
#: longer in the raw folder (``...`` and the count beyond).
GONE_NAMES_SHOWN = 4


def data_change_reasons(changes: dict, champion_id: str | None) -> list[str]:
    """Reason lines for the champion's vanished or changed training files: one per file, except
    the files no longer in the raw folder, said in one line (a machine re-qualified on new logs
    has its old ones archived: every one of them is gone, for one reason)."""
    who = f"champion {str(champion_id)[:12]}"
    vanished = changes.get("vanished", [])
    gone = [v["file"] for v in vanished if v["why"] == "no longer in the raw folder"]
    out = [
        f"training file of {who} vanished: {v['file']} ({v['why']})"
        for v in vanished
        if v["file"] not in gone
    ]
    if len(gone) == 1:
        out.append(f"training file of {who} vanished: {gone[0]} (no longer in the raw folder)")
    elif gone:
        shown = ", ".join(gone[:GONE_NAMES_SHOWN]) + (
            f", ... ({len(gone) - GONE_NAMES_SHOWN} more)" if len(gone) > GONE_NAMES_SHOWN else ""
        )
        out.append(
            f"{len(gone)} training files of {who} vanished: {shown} (no longer in the raw folder: "
            "archived, e.g. for a re-qualification on new logs?)"
        )
    out += [
        f"training file of {who} changed: {c['file']} (sha256 {c['sha256_champion'][:12]} at training, "
        f"{c['sha256_now'][:12]} now)"
        for c in changes.get("changed", [])
    ]
    return out


def confirming_entries(name: str, check: str, confirmed=()) -> list[dict]:
    """The entries of ``checks.confirmed`` (``confirmed``) that confirm the warning ``check`` on
    ``name`` (a raw file's name, or a prior's model id): ``{file, check}`` each, in their order.

    The match of :func:`rafi.readers.checks_machine.is_confirmed` (the file name without folder
    against the entry's glob, case-sensitive; the check id exactly); a prior's id matches whole
    or by its first 12 characters, as :func:`prior_warnings` confirms it. Kept with each confirmed
    warning (``confirmed_by``) in ``decision.json`` and ``history.jsonl``: what a promotion rested
    on, after ``config.yaml`` changed.
    """
    from rafi.readers.checks_machine import is_confirmed

    names = [str(name)] if len(str(name)) <= 12 else [str(name), str(name)[:12]]
    found = []
    for c in confirmed or ():
        if not hasattr(c, "get"):
            continue
        if any(is_confirmed(n, check, [c]) for n in names):
            entry = {"file": str(c.get("file", "")), "check": str(c.get("check"))}
            if entry not in found:
                found.append(entry)
    return found


def input_warnings(status: dict | None, tonight: dict[str, str], confirmed=()) -> dict:
    """Split the ``warnings`` of ``input_status.json`` by what they mean for promotion.

    A warning applies to tonight's data if its file (by name or sha256) is one of ``tonight``
    (``file -> sha256``), or if it names no file (a machine-level warning). A missing
    ``warnings`` key means no warnings. ``confirmed`` (``checks.confirmed``) names, under each
    confirmed warning, the entries that confirm it (``confirmed_by``, :func:`confirming_entries`;
    the warning's own ``confirmed`` flag, set by rule ``input_status`` from the same setting,
    decides).

    Returns
    -------
    dict
        ``blocking`` (unconfirmed, on data tonight uses), ``confirmed`` (confirmed in config
        ``checks.confirmed``), ``not_used`` (unconfirmed, on a file tonight's data does not use);
        each a list of ``{file, sha256, check, column, message, confirmed}``, a confirmed one with
        ``confirmed_by`` besides.
    """
    out: dict[str, list] = {"blocking": [], "confirmed": [], "not_used": []}
    shas = set(tonight.values())
    for w in (status or {}).get("warnings") or []:
        if not isinstance(w, dict):
            continue
        rec = {k: w.get(k) for k in ("file", "sha256", "check", "column", "message")}
        rec["confirmed"] = bool(w.get("confirmed"))
        f, sha = rec["file"], rec["sha256"]
        used = not f or str(f) in tonight or (bool(sha) and sha in shas)
        if rec["confirmed"]:
            rec["confirmed_by"] = confirming_entries(str(f or ""), str(rec["check"]), confirmed)
            out["confirmed"].append(rec)
        elif used:
            out["blocking"].append(rec)
        else:
            out["not_used"].append(rec)
    return out


def warning_reason(w: dict) -> str:
    """The reason line of a blocking warning."""
    file = w.get("file") or "(machine)"
    return (
        f"input warning not confirmed: {file} {w.get('check')}: {w.get('message')}; "
        "confirm it in config checks.confirmed or fix the file"
    )


def prior_warnings(candidate_model: dict | None, confirmed=()) -> dict:
    """The fitness warnings of a candidate adapted from a prior (``adaptation.fitness.warnings``,
    :func:`rafi.family.prior_fitness.fitness_warnings`), split by ``checks.confirmed``
    (``confirmed``): an entry ``{file: <the prior's model id, its first 12 characters or a
    glob>, check: prior_adaptation | prior_speeds | prior_dynamics | prior_misfit}`` confirms it.

    Returns
    -------
    dict
        ``blocking`` and ``confirmed``, each a list of ``{prior, machine, for_machine, check,
        message, confirmed}`` (``prior``: the prior's model id, ``machine`` its machine,
        ``for_machine`` the candidate's), a confirmed one with ``confirmed_by`` besides (the
        entries that confirm it, :func:`confirming_entries`); both empty for a candidate that is
        not an adapted prior, or one without a fitness block.
    """
    from rafi.readers.checks_machine import is_confirmed

    out: dict[str, list] = {"blocking": [], "confirmed": []}
    adaptation = (candidate_model or {}).get("adaptation")
    fitness = adaptation.get("fitness") if isinstance(adaptation, dict) else None
    if not isinstance(fitness, dict):
        return out
    prior = str(adaptation.get("parent") or (fitness.get("prior") or {}).get("model_id") or "")
    machine = adaptation.get("parent_machine") or (fitness.get("prior") or {}).get("machine")
    for w in fitness.get("warnings") or []:
        check = str(w.get("check"))
        ok = bool(prior) and (
            is_confirmed(prior, check, confirmed) or is_confirmed(prior[:12], check, confirmed)
        )
        rec = {
            "prior": prior,
            "machine": machine,
            "for_machine": (candidate_model or {}).get("machine"),
            "check": check,
            "message": w.get("message"),
            "confirmed": ok,
        }
        if ok:
            rec["confirmed_by"] = confirming_entries(prior, check, confirmed)
        out["confirmed" if ok else "blocking"].append(rec)
    return out


def prior_warning_reason(w: dict) -> str:
    """The reason line of a blocking fitness warning (:func:`prior_warnings`): the warning, how to
    confirm it, and what else to do (:func:`rafi.family.prior_fitness.warning_remedy`)."""
    pid = str(w.get("prior") or "")[:12]
    return (
        f"prior fitness not confirmed: prior {pid} of {w.get('machine')}: {w.get('message')}; "
        f"confirm it in config checks.confirmed ({confirmation_entry(pid, w.get('check'))}) or "
        + warning_remedy(str(w.get("check")), w.get("for_machine"))
    )
