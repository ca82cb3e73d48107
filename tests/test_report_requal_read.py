"""The re-qualification as the engineer signs it (issue 47, audit of 2026-12-01): the builders of
sections 1, 3 and the registry on the decisions and artefacts of an ensemble prior adapted as a
whole (``prior_shared_ridge``), each figure checked against the block it is read from.

The blocks below are cut from the audit's re-qualification of tapping-center-a after a simulated
repair (its champion, an ensemble of four ridge members, adapted as a whole): the coefficient of
``ridge_global: dT11@0s`` went from -0.0530 to -0.5617 (10.6 times its prior value, the same sign),
``prior_shared_ridge`` was offered with a whole-run CV score of 23.36 um while ``prior_shared_gain``
scored 2.41 um, and the candidate went on the machine once its two fitness warnings were confirmed.
"""

from __future__ import annotations

import numpy as np
import pytest

from rafi.report.format import fmt_sig
from rafi.report.registry_section import adaptation_words, section_registry
from rafi.report.requalification_section import (
    comparison_sentence,
    confirmed_fitness,
    fitness_context,
    member_moves,
    ratio_words,
    rule_sentence,
)
from rafi.report.verdict import placement, verdict_all

PRIOR = "6fca63e8ad59" + "5" * 52
CANDIDATE = "9cb3d9298248" + "8" * 52
GAIN = 1.2510292841521282

#: Each member's coefficient_change, as the audit's best_model.json has them (a few per member).
CHANGES = {
    "grey_box": [
        {"name": "dT1@0s", "prior": 0.04681171952254563, "new": 0.052668066791074684},
        {"name": "dT2@0s", "prior": -0.062162396517208875, "new": -0.08475237464953743},
        {"name": "dT8@120s", "prior": 0.1, "new": 0.3147088244597},
    ],
    "dynamic": [
        {"name": "dT1@0s", "prior": 0.029091364939785903, "new": 0.028942223475150807},
        {"name": "dT2@0s", "prior": -0.01318640259722973, "new": -0.025103717934084772},
    ],
    "ridge_global": [
        {"name": "dT1@0s", "prior": 0.3044256360812415, "new": 0.442485457803333},
        {"name": "dT2@0s", "prior": -0.09149217373176809, "new": -0.0494481322890612},
        {"name": "dT11@0s", "prior": -0.05302628193778224, "new": -0.5617482702903772},
        {"name": "dT3@0s", "prior": 0.2, "new": -0.1},  # a sign flip
        {"name": "dT4@0s", "prior": 0.5, "new": 0.9},
        {"name": "n^2", "prior": 0.0, "new": 0.0},
    ],
    "temperature_ridge": [
        {"name": "dT1@0s", "prior": 0.27036180391806713, "new": 0.33111435174153214},
    ],
}
WEIGHTS = {"dynamic": 0.356, "grey_box": 0.439, "ridge_global": 0.093, "temperature_ridge": 0.111}


def _best(method: str = "shared_ridge") -> dict:
    """An ensemble adapted as a whole (comparison/best_model.json) with the members above."""
    member_method = "ridge" if method == "shared_ridge" else "gain"
    members = {
        name: {
            "kind": name,
            "model_id": f"{k}" * 64,
            "adaptation": {
                "method": member_method,
                "gain": GAIN,
                "alpha": 10.0 if member_method == "ridge" else None,
                "coefficient_change": change,
            },
        }
        for k, (name, change) in enumerate(CHANGES.items())
    }
    return {
        "kind": "ensemble",
        "model_id": CANDIDATE,
        "machine": "tapping-center-a",
        "weights": WEIGHTS,
        "members": members,
        "adaptation": {
            "method": method,
            "parent": PRIOR,
            "parent_machine": "tapping-center-a",
            "gain": GAIN,
            "alpha": 10.0 if method == "shared_ridge" else None,
            "members": {n: {"kind": n, "model_id": m["model_id"]} for n, m in members.items()},
        },
    }


def _ratios(change):
    prior = np.array([c["prior"] for c in change], float)
    new = np.array([c["new"] for c in change], float)
    keep = prior != 0
    return new[keep] / prior[keep], prior, new


def test_member_moves_state_each_members_coefficients_not_one_gain():
    """Item 3: shared_ridge moved each ridge member's coefficients at the fixed penalty after the
    shared gain: the new/prior ratios differ from the gain, member by member, and the section says
    so from each member's own coefficient_change."""
    moves = member_moves(_best())
    assert moves["method"] == "shared_ridge" and moves["gain"] == GAIN and moves["alpha"] == 10.0
    assert [m["name"] for m in moves["members"]] == sorted(WEIGHTS, key=lambda n: -WEIGHTS[n])
    every = []
    for m in moves["members"]:
        ratio, prior, new = _ratios(CHANGES[m["name"]])
        every += list(ratio)
        assert m["n"] == len(CHANGES[m["name"]])
        assert m["ratio_lo"] == pytest.approx(ratio.min()) and m["ratio_hi"] == pytest.approx(ratio.max())
        assert m["n_flipped"] == int(np.sum(ratio < 0))
        assert m["moved"] == "ridge" and m["weight"] == WEIGHTS[m["name"]]
        # the largest moves of this member: by |new - prior| / |prior|, at most MEMBER_MOVES_SHOWN
        rows = [r for r in moves["rows"] if r["member"] == m["name"]]
        rel = np.where(prior != 0, np.abs(new - prior) / np.where(prior != 0, np.abs(prior), 1), 0.0)
        order = np.argsort(-rel, kind="stable")[: len(rows)]
        assert [r["name"] for r in rows] == [CHANGES[m["name"]][i]["name"] for i in order]
    assert moves["n"] == sum(len(c) for c in CHANGES.values())
    assert moves["ratio_lo"] == pytest.approx(min(every)) and moves["ratio_hi"] == pytest.approx(max(every))
    top = next(r for r in moves["rows"] if r["member"] == "ridge_global")
    assert top["name"] == "dT11@0s" and top["ratio"] == pytest.approx(
        -0.5617482702903772 / -0.05302628193778224
    )


def test_member_moves_of_the_shared_gain_and_of_other_models():
    """prior_shared_gain: every member's coefficients times the gain (ratios all the gain, no
    table of moves); a model that is not an ensemble adapted as a whole has none."""
    best = _best("shared_gain")
    for m in best["members"].values():
        m["adaptation"]["coefficient_change"] = [
            {**c, "new": GAIN * c["prior"]} for c in m["adaptation"]["coefficient_change"]
        ]
    moves = member_moves(best)
    assert moves["method"] == "shared_gain" and moves["rows"] == []
    assert all(m["moved"] == "gain" for m in moves["members"])
    assert moves["ratio_lo"] == pytest.approx(GAIN) and moves["ratio_hi"] == pytest.approx(GAIN)
    assert member_moves({"kind": "dynamic", "adaptation": {"method": "gain"}}) is None
    assert member_moves(None) is None and member_moves({}) is None


@pytest.mark.parametrize(
    ("prior", "new", "said", "not_said"),
    [
        (-0.05302628193778224, -0.5617482702903772, "10.6 times its prior value", "sign"),
        (0.2, -0.1, "\u22120.500 times its prior value: its sign flipped", "\u2212150"),
        (0.0, 0.25, "from 0 to 0.2500", "times"),
    ],
)
def test_a_coefficients_move_is_said_as_new_over_prior(prior, new, said, not_said):
    """Item 3: a relative change (new - prior) / |prior| of -959 % reads as a shrink; the coefficient
    grew 10.6-fold with its sign. The section says new / prior, and a sign flip in words."""
    text = ratio_words(prior, new)
    assert said in text and not_said not in text


def test_the_largest_change_of_the_fitness_block_is_said_as_a_factor():
    block = {
        "parent": PRIOR,
        "fitness": {
            "largest_coefficient_change": {
                "name": "ridge_global: dT11@0s",
                "prior": -0.05302628193778224,
                "new": -0.5617482702903772,
                "relative": -9.593770669222064,
            },
            "warnings": [],
        },
    }
    f = fitness_context(block, "tapping-center-a")
    assert "10.6 times its prior value" in f["largest_words"]
    assert "ridge_global: dT11@0s" in f["largest_words"] and "959" not in f["largest_words"]


def _rows(offered: str, scores: dict) -> list[dict]:
    group = {"prior": "prior", "dynamic": "from scratch", "grey_box": "from scratch"}
    return [
        {
            "model": name,
            "group": group.get(name, "adapted prior"),
            "cv_um": score,
            "offered": name == offered,
            "candidate": True,
        }
        for name, score in scores.items()
    ]


def test_the_rule_that_offered_the_moved_members_is_said_with_the_scores():
    """Item 6: prior_shared_ridge is offered whatever the scores (cv.csv: 23.36 um against
    prior_shared_gain's 2.41 um); the section says that rule, not that the CV chose."""
    scores = {"prior": 5.27, "prior_shared_gain": 2.41, "prior_shared_ridge": 23.36, "dynamic": 3.92}
    text = rule_sentence(_rows("prior_shared_ridge", scores), cv=True, forward=False)
    assert "whatever the scores" in text and "chose between" not in text
    assert "prior_shared_ridge" in text and "23.36 \u00b5m" in text
    assert "prior_shared_ridge 23.36 \u00b5m, the lowest prior_shared_gain 2.41 \u00b5m" in text
    # the shared gain's rule (no moved members among the candidates)
    del scores["prior_shared_ridge"]
    text = rule_sentence(_rows("prior_shared_gain", scores), cv=True, forward=False)
    assert "unless another candidate's score is lower than its by more than one standard error" in text
    # a prior of one kind: the CV chose
    plain = {"prior": 5.0, "prior_gain": 2.0, "dynamic": 3.0}
    text = rule_sentence(_rows("prior_gain", plain), cv=True, forward=False)
    assert text.startswith("Whole-run cross-validation on the new training runs chose between")
    assert rule_sentence(_rows("prior_gain", plain), cv=False, forward=False).startswith(
        "The new training runs give no whole-run cross-validation fold"
    )


def test_the_ensemble_prior_on_the_machine_and_its_heaviest_member_are_two_numbers():
    """Item 13: the candidate `prior` of an ensemble prior is its heaviest member alone (6.59 um);
    the ensemble prior as it is, on the machine before this run, scored 6.83 um (decision.json
    champion_summary).
    The sentence names both, each as what it is."""
    offered = {"model": "prior_shared_ridge", "worst_um": 2.95}
    prior_row = {"model": "prior", "kind": "grey_box", "worst_um": 6.59, "member": True}
    on_machine = {"id": PRIOR[:12], "worst_um": 6.829279203122159}
    text = comparison_sentence(offered, prior_row, None, on_machine)
    assert f"the ensemble prior as it is ({PRIOR[:12]}, on the machine before this run) 6.83 \u00b5m" in text
    assert "its heaviest member alone (grey_box, the candidate prior) unchanged 6.59 \u00b5m" in text
    alone = comparison_sentence(offered, prior_row, None, None)
    assert (
        "the ensemble prior's heaviest member alone (grey_box, the candidate prior) unchanged 6.59" in alone
    )


def _decision(state: str) -> dict:
    """decision.json of the audit's candidate: promoted on two confirmations, or waiting for them."""
    warnings = [
        {
            "check": check,
            "prior": PRIOR,
            "machine": "tapping-center-a",
            "for_machine": "tapping-center-a",
            "message": f"{check} message",
            "confirmed": state == "promoted",
        }
        for check in ("prior_speeds", "prior_misfit")
    ]
    champion_after = CANDIDATE if state == "promoted" else PRIOR
    return {
        "decision": "promoted" if state == "promoted" else "rejected",
        "machine": "tapping-center-a",
        "candidate_id": CANDIDATE,
        "champion_id_before": PRIOR,
        "champion_id_after": champion_after,
        "gates_passed": True,
        "blocked_by": [] if state == "promoted" else ["prior_fitness"],
        "prior_fitness": {
            "blocking": [] if state == "promoted" else warnings,
            "confirmed": warnings if state == "promoted" else [],
        },
        "recalibration_due": state != "promoted",
        "champion_summary": {"max_residual_um": 6.829279203122159, "runs": {}},
        "candidate_summary": {"max_residual_um": 2.951762864611542, "runs": {}},
        "drift": {"status": "degraded", "detected": True},
    }


def test_the_confirmations_a_promotion_rested_on_are_read_from_the_decision():
    """Item 1: decision.json prior_fitness.confirmed lists the checks a person confirmed; the
    entry that lifted each is the checks.confirmed entry that matches it (a glob too), else the
    prior's short id and the check."""
    dec = _decision("promoted")
    setting = [{"file": "6fca*", "check": "prior_misfit"}, {"file": "x.csv", "check": "prior_speeds"}]
    conf = confirmed_fitness(dec, setting)
    assert conf["promoted"] is True and conf["checks"] == ["prior_speeds", "prior_misfit"]
    assert conf["entries"] == [
        f"{{file: {PRIOR[:12]}, check: prior_speeds}}",
        "{file: 6fca*, check: prior_misfit}",
    ]
    assert conf["words"] == (
        f"the prior fitness checks prior_speeds, prior_misfit of prior {PRIOR[:12]} (tapping-center-a), "
        f"confirmed in checks.confirmed: [{{file: {PRIOR[:12]}, check: prior_speeds}}, "
        "{file: 6fca*, check: prior_misfit}]"
    )
    assert confirmed_fitness(_decision("waiting"), setting) is None
    assert confirmed_fitness({}, setting) is None and confirmed_fitness(None) is None


def test_the_fitness_warnings_of_a_promoted_candidate_are_said_confirmed():
    """Item 1: section 3 lists each warning as confirmed (the entry that lifted it), not as one
    to confirm, when the decision on this model lists it confirmed."""
    block = {
        "parent": PRIOR,
        "fitness": {
            "warnings": [
                {"check": "prior_speeds", "message": "m1"},
                {"check": "prior_misfit", "message": "m2"},
            ]
        },
    }
    dec = _decision("promoted")
    f = fitness_context(block, "tapping-center-a", decision=dec, model_id=CANDIDATE)
    assert [w["confirmed_by"] for w in f["warnings"]] == [
        f"{{file: {PRIOR[:12]}, check: prior_speeds}}",
        f"{{file: {PRIOR[:12]}, check: prior_misfit}}",
    ]
    assert f["all_confirmed"] is True and f["promoted_on_confirmation"] is True
    waiting = fitness_context(block, "tapping-center-a", decision=_decision("waiting"), model_id=CANDIDATE)
    assert [w["confirmed_by"] for w in waiting["warnings"]] == [None, None]
    assert waiting["all_confirmed"] is False and waiting["promoted_on_confirmation"] is False
    # a decision on another model says nothing of this one's warnings
    other = fitness_context(block, "tapping-center-a", decision=dec, model_id="ff" * 32)
    assert [w["confirmed_by"] for w in other["warnings"]] == [None, None]


def test_a_waiting_candidate_beside_a_champion_reads_waiting():
    """Item 7: the champion stays, tonight's candidate passed every gate and waits for a
    confirmation: the verdict says WAITING (not PASS), and sections 2 and 4 say what it waits for."""
    dec = _decision("waiting")
    dec["champion_verdict"] = [
        {"criterion": "max_residual_um", "limit": 12.0, "measured": 6.83, "passed": True, "run_id": "v1"}
    ]
    out = verdict_all({"decision": dec}, {})
    assert out["status"] == "WAITING" and out["css"] == "unknown"
    assert out["judged"]["waiting"].startswith(
        "waits for a confirmation of the prior fitness check prior_speeds"
    )
    assert [r["status"] for r in out["rows"]] == ["PASS"]  # the champion's own checks, as stored
    placed = placement(dec, CANDIDATE, PRIOR)
    assert placed["on_machine"] is False and placed["waiting"] == out["judged"]["waiting"]
    assert placement(dec, PRIOR, PRIOR)["waiting"] is None  # the champion waits for nothing
    assert placement(_decision("promoted"), CANDIDATE, CANDIDATE)["waiting"] is None


def test_the_registry_says_waiting_and_the_adapted_ensemble():
    """Items 7 and 8: a waiting decision reads WAITING with the entry to add, and the candidate's
    recalibration needs no new training run; the candidate is an adapted ensemble (the prior's
    members and weights, moved), not an ensemble of this run's kinds."""
    dec = _decision("waiting")
    g = section_registry({"decision": dec, "best_model": _best()}, {CANDIDATE: {"kind": "ensemble"}})
    assert g["waiting"].startswith("waits for a confirmation of the prior fitness check prior_speeds")
    assert f'add checks.confirmed: [{{file: "{PRIOR[:12]}", check: prior_speeds}}' in g["waiting"]
    words = g["adaptation"]["adapted"]
    assert words.startswith(
        f"an adapted ensemble: the 4 members of the prior {PRIOR[:12]} of tapping-center-a"
    )
    assert "the prior's weights, kept as they are" in words and "fixed penalty 10" in words
    assert "CV-weighted ensemble blends" not in words
    promoted = section_registry({"decision": _decision("promoted"), "best_model": _best()}, {})
    assert promoted["waiting"] is None
    assert promoted["confirmed"]["checks"] == ["prior_speeds", "prior_misfit"]
    assert adaptation_words(None) is None and adaptation_words({"kind": "dynamic"}) is None


def test_ratios_print_three_significant_digits():
    assert fmt_sig(-0.5617482702903772 / -0.05302628193778224, 3) == "10.6"


def test_status_says_the_largest_move_in_the_reports_words():
    """tapping-center-a-rep: ``rafi status`` said "largest coefficient change -460 %
    (ridge_global: dT11@0s)" where the report says "-0.05303 -> -0.2968: 5.60 times its prior
    value" (the mixed fleet read page by page, 2026-12-01): a relative change reads as a shrink
    of a coefficient that grew 5.6-fold with its sign (docs/report.md)."""
    from rafi.ops.fleet_cli import describe_prior

    largest = {"name": "ridge_global: dT11@0s", "prior": -0.053026281942656864, "new": -0.2967688093311099}
    block = {"parent": PRIOR, "fitness": {"largest_coefficient_change": largest | {"relative": -4.5966}}}
    report = fitness_context(block, "tapping-center-a-rep")["largest_words"]
    assert report == "ridge_global: dT11@0s, \u22120.05303 \u2192 \u22120.2968: 5.60 times its prior value"
    prior = {"id": PRIOR, "machine": "tapping-center-a", "method": "shared_ridge", "gain": 1.02}
    lines = describe_prior(prior | {"largest_coefficient_change": largest | {"relative": -4.5966}})
    (adaptation,) = [line for line in lines if line.startswith("  adaptation:")]
    assert adaptation.endswith(f"the coefficient that moved most relative to its prior value: {report}")
    assert "%" not in adaptation and "460" not in adaptation


def test_the_prior_rise_table_reads_none_for_ranges_too_narrow_to_show_and_in_sensor_order():
    """tapping-center-a-rep p6: the prior's alone column read "T11 −0.7 … −0.7; 1.1 … 1.1" (two
    slivers of 0.05 and 0.005 K, below the table's 0.1 K) and the rows ran T1, T10, T11 … T2."""
    rises = {  # sensor: (tested here, the prior's training), K; the prior's alone follows from them
        "T2": ([-1.625, 2.325], [-0.155, 2.86]),
        "T11": ([-0.69, 1.105], [-0.74, 1.11]),
        "T10": ([-3.53, 4.335], [-0.13, 4.535]),
        "T1": ([-1.8, 2.485], [-0.12, 2.87]),
        "T8": ([-12.255, 13.36], [-0.14, 12.755]),
    }
    from rafi.family.prior_fitness import _outside

    temperature = [
        {"sensor": s, "tested": here, "prior": there, "prior_only": _outside(there, here)}
        for s, (here, there) in sorted(rises.items())  # as the fitness block stores them: as text
    ]
    block = {"parent": PRIOR, "fitness": {"temperature": temperature, "warnings": []}}
    rows = {r["sensor"]: r for r in fitness_context(block, "m")["temperature"]}
    assert list(rows) == ["T1", "T2", "T8", "T10", "T11"]
    assert rows["T11"]["prior_only"] == "none" and rows["T8"]["prior_only"] == "none"
    assert rows["T1"]["prior_only"] == "2.5 \u2026 2.9" and rows["T10"]["prior_only"] == "4.3 \u2026 4.5"
    assert rows["T11"]["prior"] == "\u22120.7 \u2026 1.1"
