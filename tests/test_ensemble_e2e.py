"""The CV-weighted ensemble through the real pipeline (issue 46): ``models: offer: ensemble`` on a
copy of the project with the shipped tapping-center-a trimmed to five logs, as the other
end-to-end tests run the Snakefile (tests/project_copy.py).

What a user meets is checked against outside oracles: the weights recomputed here from
``comparison/cv.csv`` (1 / s^2 of each member's mean whole-run held-out max |residual|); the model
id recomputed from the artefact's content; the registry's decision, champion and stored model; the
report's HTML and its PDF read back with poppler; ``rafi status`` in a subprocess.
"""

from __future__ import annotations

import html
import json
import re
import subprocess
from pathlib import Path

import pandas as pd
import pytest
from conftest import which_or_skip

from rafi.artefact import compute_model_id
from rafi.family.ensemble import ENSEMBLE, NOT_MEMBERS, WEIGHT_RULE
from rafi.family.plain_ridge import PLAIN_RIDGE
from rafi.settings import MACHINE_DEFAULTS
from tests.project_copy import copy_project, copy_settled, run_rafi, run_snakemake

ROOT = Path(__file__).resolve().parents[1]
MACHINE = "tapping-center-a"
KEEP = re.compile(r"train.*(03000|09000|15000)|valid_04500|multi_condition")


@pytest.fixture(scope="module")
def project(tmp_path_factory):
    """The pipeline's report of tapping-center-a with ``models: offer: ensemble``."""
    proj = copy_project(tmp_path_factory.mktemp("ensemble") / "proj")
    config = proj / "config.yaml"
    text = config.read_text(encoding="utf-8")
    block = f"  {MACHINE}:\n"
    assert text.count(block) == 1
    config.write_text(text.replace(block, block + "    models:\n      offer: ensemble\n"), encoding="utf-8")
    (proj / "raw" / MACHINE).mkdir(parents=True)
    for f in sorted((ROOT / "raw" / MACHINE).iterdir()):
        if KEEP.search(f.name):
            copy_settled(f, proj / "raw" / MACHINE / f.name)
    done = run_snakemake(proj, f"reports/{MACHINE}/qualification.pdf", cores=2, timeout=1500)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return proj


def _results(proj: Path) -> Path:
    return proj / "results" / MACHINE


def _text(markup: str) -> str:
    """The words of an HTML fragment, whitespace collapsed."""
    return " ".join(html.unescape(re.sub(r"<[^>]+>", " ", markup)).replace("\u00a0", " ").split())


def _oracle_weights(cv: pd.DataFrame, members) -> dict:
    whole = cv[~cv["scheme"].astype(str).str.startswith("forward")]
    s = {m: whole.loc[whole["model"] == m, "max_abs_after_um"].astype(float).mean() for m in members}
    inverse = {m: 1.0 / v**2 for m, v in s.items()}
    return {m: v / sum(inverse.values()) for m, v in inverse.items()}


@pytest.mark.slow
def test_the_ensemble_is_offered_with_the_weights_of_its_cv(project):
    res = _results(project)
    art = json.loads((res / "comparison" / "best_model.json").read_text())
    assert art["kind"] == ENSEMBLE and art["model_id"] == compute_model_id(art)
    members = {*MACHINE_DEFAULTS["models"]["enabled"], PLAIN_RIDGE} - set(NOT_MEMBERS)
    assert set(art["weights"]) == members and len(members) == 4
    oracle = _oracle_weights(pd.read_csv(res / "comparison" / "cv.csv"), art["weights"])
    assert art["weights"] == pytest.approx(oracle, rel=1e-9)
    summary = pd.read_csv(res / "comparison" / "summary.csv").set_index("model")
    assert bool(summary.loc[ENSEMBLE, "champion"]) and summary.loc[ENSEMBLE, "selection_rank"] == 1
    assert summary.loc[ENSEMBLE, "model_id"] == art["model_id"]  # the table names the file offered


@pytest.mark.slow
def test_the_registry_promotes_it_through_its_gates(project):
    res = _results(project)
    art = json.loads((res / "comparison" / "best_model.json").read_text())
    decision = json.loads((res / "registry" / "decision.json").read_text())
    assert decision["decision"] == "promoted", decision["reasons"]
    assert decision["candidate_id"] == decision["champion_id_after"] == art["model_id"]
    assert any("passed every absolute gate" in r for r in decision["reasons"]), decision["reasons"]
    summary = pd.read_csv(res / "comparison" / "summary.csv").set_index("model")
    worst = float(summary.loc[ENSEMBLE, "max_abs_after_um"])
    assert decision["candidate_summary"]["max_residual_um"] == pytest.approx(worst, rel=1e-12)
    assert worst <= MACHINE_DEFAULTS["qualification"]["max_residual_um"]
    assert json.loads((res / "registry" / "champion.json").read_text())["model_id"] == art["model_id"]
    stored = json.loads((res / "registry" / "models" / f"{art['model_id']}.json").read_text())
    assert stored["kind"] == ENSEMBLE and stored["weights"] == art["weights"]


@pytest.mark.slow
def test_rafi_status_names_the_ensemble_in_service(project):
    res = _results(project)
    art = json.loads((res / "comparison" / "best_model.json").read_text())
    heaviest = max(art["weights"], key=art["weights"].get)
    done = run_rafi(project, "status", "--machine", MACHINE, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    line = next(x for x in done.stdout.splitlines() if "model in service:" in x)
    assert f"{art['model_id'][:12]} ensemble of {len(art['weights'])} members" in line
    assert f"heaviest {heaviest} {art['weights'][heaviest]:.3f}" in line


@pytest.mark.slow
def test_the_report_states_the_ensemble_its_members_weights_and_rule(project):
    res = _results(project)
    art = json.loads((res / "comparison" / "best_model.json").read_text())
    page = (project / "reports" / MACHINE / "qualification.html").read_text(encoding="utf-8")
    verdict = _text(re.search(r'<p class="rafi-line"><b>How the model offered.*?</p>', page, re.S).group(0))
    assert "the CV-weighted ensemble of 4 kinds" in verdict and "models: offer: ensemble" in verdict
    block = _text(re.search(r'<div class="keep" id="ensemble">(.*?)</div>', page, re.S).group(1))
    assert WEIGHT_RULE in block and "judged one level up" in block.lower()
    assert "docs/decisions.md, 2026-11-29" in block and "slightly optimistic" in block
    summary = pd.read_csv(res / "comparison" / "summary.csv").set_index("model")
    ordered = sorted(art["weights"], key=lambda m: -art["weights"][m])
    for m in ordered:  # each member's row: its weight and its own whole-run CV score, heaviest first
        s = float(summary.loc[m, "cv_mean_max_abs_um"])
        assert re.search(rf"\b{m}\b.*?{art['weights'][m]:.3f} {s:.2f}", block), (m, block)
    positions = [block.index(f" {art['weights'][m]:.3f} ") for m in ordered]
    assert positions == sorted(positions)
    rule = _text(re.search(r"<b>Selection rule\.</b>(.*?)</p>", page, re.S).group(1))
    assert "the CV-weighted ensemble of the ridge kinds" in rule and "lowest mean" not in rule
    ridge = _text(re.search(r'<p id="plain-ridge">(.*?)</p>', page, re.S).group(1))
    assert "The offered model (ensemble)" in ridge
    assert f"a member of the ensemble offered (weight {art['weights'][PLAIN_RIDGE]:.3f})" in ridge
    assert "The model offered to the machine: ensemble" in _text(page)
    pdf = project / "reports" / MACHINE / "qualification.pdf"
    words = subprocess.run(
        [which_or_skip("pdftotext"), "-layout", str(pdf), "-"], capture_output=True, text=True, check=True
    ).stdout
    flat = " ".join(words.split())
    assert "The CV-weighted ensemble." in flat and "Its members and their weights" in flat
    assert f"{ordered[0]} heaviest {art['weights'][ordered[0]]:.3f}" in flat
