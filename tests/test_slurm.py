"""The pipeline through a real Slurm cluster (workflow/profiles/slurm) equals the local run.

Two copies of the project with the shipped machines: one runs `snakemake --cores 2` here, the
other `snakemake --workflow-profile workflow/profiles/slurm` (snakemake-executor-plugin-slurm:
sbatch, squeue). Checks:

* every job of the local run ran inside a Slurm job: the Slurm job logs (written by slurmd for
  each job id the plugin reported) show the same (rule, wildcards) jobs, and slurmctld knows each
  of those job ids as COMPLETED in the Slurm copy's folder;
* the result trees are the same files, byte for byte, except those that carry the run's own
  identity (model ids, creation times, the code version; `rafi diff` masks exactly these and
  must find nothing) and results/.raw_hashes.json (a stat cache: inodes and mtimes of this
  copy's raw files; its content hashes must agree).

Skipped when there is no idle Slurm node (`bash .ci/slurm-up.sh` brings up a single-node test
cluster; docs/cluster.md) or the plugin is not installed. Every Snakemake run is bounded
(`timeout -s KILL`) and Slurm jobs left behind are cancelled. Without a cluster, the profile's
groups are still checked against the workflow's rules.
"""

from __future__ import annotations

import importlib.util
import json
import re
import shutil
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest
import yaml
from conftest import require
from project_copy import ROOT, copy_project

from rafi.contract import RESULT_FILES, RUN_FILES
from rafi.ops.result_diff import diff_trees

PROFILE = Path("workflow") / "profiles" / "slurm"
#: The target built through Slurm: every machine's tables, comparison, decision, replay,
#: reports and the fleet page (measured here: 2.5 min through Slurm, 45 s locally).
TARGET = "all"
#: Upper bounds of the two runs (killed past them; they are no timing assertions).
SLURM_TIMEOUT_S = 600
LOCAL_TIMEOUT_S = 600
#: Rules that are not per machine, so not in the profile's group "machine" (why, per rule).
CROSS_MACHINE = {
    "all": "target rule, runs on the submit host",
    "tables": "target rule",
    "nightly": "target rule",
    "input_check": "reads every machine's input_status.json",
    "fleet_index": "reads every machine's state",
    "probes_report": "reads every probe's report of a machine with several probes (as fleet_index)",
}
#: Result files that carry the run's identity (model ids hash the creation time and code
#: version; the registry and the reports show them): compared by `rafi diff`, not byte for byte.
IDENTITY = ("model.json", "comparison/", "registry/")

_JOB = re.compile(r"^local(?:rule|checkpoint) (\w+):$")
_WILDCARDS = re.compile(r"^\s+wildcards: (.*)$")
_SUBMITTED = re.compile(r"has been submitted with SLURM jobid (\d+)")


def _rules_in_workflow() -> set[str]:
    names = set()
    for path in [ROOT / "Snakefile", *sorted((ROOT / "workflow" / "rules").glob("*.smk"))]:
        names |= set(re.findall(r"^(?:rule|checkpoint) (\w+):", path.read_text(), flags=re.M))
    return names


def test_profile_groups_every_per_machine_rule():
    """A per-machine rule outside the group breaks grouping (Snakemake refuses a group whose
    jobs depend on an outside job that depends on the group); a new rule must be classified."""
    profile = yaml.safe_load((ROOT / PROFILE / "config.yaml").read_text())
    groups = dict(item.split("=", 1) for item in profile["groups"])
    rules = _rules_in_workflow()
    assert set(groups.values()) == {"machine"}
    assert set(CROSS_MACHINE) <= rules, "a rule named in CROSS_MACHINE is gone"
    assert set(groups) == rules - set(CROSS_MACHINE), (
        "rules to add to the groups of workflow/profiles/slurm/config.yaml (or to CROSS_MACHINE): "
        f"{sorted(rules - set(CROSS_MACHINE) - set(groups))}; not rules: {sorted(set(groups) - rules)}"
    )
    resourced = {item.split(":", 1)[0] for item in profile["set-resources"]}
    assert resourced <= rules, f"set-resources for unknown rules: {sorted(resourced - rules)}"


def _skip_reason() -> str | None:
    """Why the Slurm run cannot happen here, or None."""
    if importlib.util.find_spec("snakemake_executor_plugin_slurm") is None:
        return "snakemake-executor-plugin-slurm is not installed"
    if shutil.which("sinfo") is None or shutil.which("sbatch") is None:
        return "no Slurm client (sinfo/sbatch); `bash .ci/slurm-up.sh` brings up a test cluster"
    try:
        states = subprocess.run(
            ["sinfo", "-h", "-N", "-o", "%t"], capture_output=True, text=True, timeout=15
        ).stdout.split()
    except subprocess.TimeoutExpired:
        return "sinfo did not answer within 15 s (slurmctld down?)"
    if "idle" not in states:
        return f"no idle Slurm node (sinfo node states: {states or 'none'}); run `bash .ci/slurm-up.sh`"
    return None


def _project(path: Path) -> Path:
    copy_project(path)
    shutil.copytree(ROOT / "raw", path / "raw")
    return path


def _jobs(text: str) -> Counter:
    """(rule, wildcards) of every job a Snakemake log shows being executed here."""
    jobs: Counter = Counter()
    block: list[str] | None = None  # [rule, wildcards] of the job whose lines are being read
    for line in [*text.splitlines(), ""]:
        if block is not None and not line.startswith((" ", "\t")):
            jobs[tuple(block)] += 1
            block = None
        if match := _JOB.match(line):
            block = [match.group(1), ""]
        elif block is not None and (found := _WILDCARDS.match(line)):
            block[1] = found.group(1)
    return jobs


def _scontrol(job_id: str) -> dict[str, str]:
    out = subprocess.run(
        ["scontrol", "-o", "show", "job", job_id], capture_output=True, text=True, timeout=15
    ).stdout
    return dict(field.split("=", 1) for field in out.split() if "=" in field)


def _cancel_leftovers(workdir: Path, job_ids: list[str]) -> None:
    """scancel every job of this test still known to Slurm as pending or running."""
    listing = subprocess.run(
        ["squeue", "-h", "-o", "%i %Z"], capture_output=True, text=True, timeout=15
    ).stdout
    mine = {line.split()[0] for line in listing.splitlines() if line.split()[1:] == [str(workdir)]}
    mine |= set(job_ids)
    if mine:
        subprocess.run(["scancel", *sorted(mine)], capture_output=True, timeout=15)


#: Not results: timings, and the memos whose entry names depend on where the code ran (the compiled
#: templates are keyed by the template's path, which differs between the two projects' frozen copies).
NOT_RESULTS = ("benchmarks/", f"{RESULT_FILES['cv_memo']}/", f"{RUN_FILES['template_cache']}/")


def _files(root: Path) -> dict[str, Path]:
    return {
        str(p.relative_to(root)): p
        for top in ("results", "reports")
        for p in (root / top).rglob("*")
        if p.is_file() and not any(part in str(p.relative_to(root)) for part in NOT_RESULTS)
    }


def _raw_hashes(project: Path) -> dict[str, str]:
    """results/.raw_hashes.json as {raw path relative to the project: sha256}."""
    files = json.loads((project / "results" / ".raw_hashes.json").read_text())["files"]
    return {str(Path(path).relative_to(project)): entry[-1] for path, entry in files.items()}


@pytest.mark.slow
def test_slurm_run_equals_local_run(tmp_path):
    require(_skip_reason())
    local, cluster = _project(tmp_path / "local"), _project(tmp_path / "slurm")
    slurm_log = tmp_path / "slurm-run.log"
    submitted: list[str] = []
    # the Slurm run waits on the cluster most of the time: the local run goes meanwhile
    with open(slurm_log, "w") as out:
        slurm_run = subprocess.Popen(
            ["timeout", "-s", "KILL", str(SLURM_TIMEOUT_S), sys.executable, "-m", "snakemake",
             "--workflow-profile", str(PROFILE), "--slurm-keep-successful-logs", TARGET],
            cwd=cluster, stdout=out, stderr=subprocess.STDOUT,
        )  # fmt: skip
    try:
        local_run = subprocess.run(
            ["timeout", "-s", "KILL", str(LOCAL_TIMEOUT_S), sys.executable, "-m", "snakemake",
             "--workflow-profile", "none", "--cores", "2", TARGET],
            cwd=local, capture_output=True, text=True,
        )  # fmt: skip
        slurm_rc = slurm_run.wait()
    finally:
        if slurm_run.poll() is None:
            slurm_run.kill()
            slurm_run.wait()
        submitted = _SUBMITTED.findall(slurm_log.read_text())
        _cancel_leftovers(cluster, submitted)
    text = slurm_log.read_text()
    assert local_run.returncode == 0, local_run.stderr[-3000:]
    assert slurm_rc == 0, f"exit {slurm_rc} (137: killed after {SLURM_TIMEOUT_S} s)\n{text[-3000:]}"

    # every job ran inside Slurm: slurmctld knows each job id as done in this folder ...
    assert submitted, text[-3000:]
    for job_id in submitted:
        info = _scontrol(job_id)
        assert info.get("JobState") == "COMPLETED", (job_id, info)
        assert Path(info.get("WorkDir", "")) == cluster, (job_id, info)
    # ... and the job logs slurmd wrote show the local run's jobs, each once
    slurm_logs = sorted((cluster / ".snakemake" / "slurm_logs").rglob("*.log"))
    assert {p.stem for p in slurm_logs} == set(submitted)
    in_slurm = sum((_jobs(p.read_text()) for p in slurm_logs), Counter())
    here = _jobs(local_run.stderr + local_run.stdout)
    del here["all", ""]
    assert in_slurm == here
    assert not _jobs(text) - Counter({("all", ""): 1}), "a job ran on the submit host"

    # the same results: byte for byte, but for the run's identity (masked by rafi diff)
    a, b = _files(local), _files(cluster)
    assert sorted(a) == sorted(b)
    differ = sorted(rel for rel in a if a[rel].read_bytes() != b[rel].read_bytes())
    identity = [r for r in differ if r.startswith("reports/") or any(k in r for k in IDENTITY)]
    assert [r for r in differ if r not in identity] == ["results/.raw_hashes.json"]
    assert _raw_hashes(local) == _raw_hashes(cluster)
    found = {top: diff_trees(local / top, cluster / top) for top in ("results", "reports")}
    found["results"].pop(".raw_hashes.json", None)
    assert found == {"results": {}, "reports": {}}
