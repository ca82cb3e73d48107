"""``rafi status`` and reports/index.html on fabricated projects whose truth is known.

Each machine below is written to be in exactly one state (plus ``quarantined`` where said);
the expected attention order, residuals, exit codes and links follow from the files alone.
"""

from __future__ import annotations

import argparse
import html
import json
import os
import re
from pathlib import Path

import pytest

from rafi.ops import fleet as F
from rafi.ops import fleet_cli
from rafi.ops.project import Paths
from rafi.report.fleet_page import fleet_page, write_fleet_page

T0 = 1_800_000_000  # audit.csv time; a decision is written after it unless the machine is stale
RAW_T = 1_700_000_000  # when the raw files were recorded (2023), before every decision's time
ID = {k: (c * 64) for k, c in {"X": "a", "Y": "b", "Z": "c", "C": "d", "R": "e", "Q": "f"}.items()}


def _json(path: Path, data) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data))


def _summary(worst_run: str, worst: float, other: float = 1.0) -> dict:
    return {
        "n_runs": 2,
        "max_residual_um": worst,
        "runs": {
            "v_other": {"max_abs_after_um": other, "max_abs_before_um": 20.0},
            worst_run: {"max_abs_after_um": worst, "max_abs_before_um": 20.0},
        },
    }


def _machine(
    root: Path,
    name: str,
    *,
    champion: str | None = None,
    kind: str = "rafi",
    decision: dict | None = None,
    audit: list[tuple[str, str, str]] = (("day1.csv", "ok", ""),),
    skipped: bool = False,
    stale: bool = False,
    history: list[dict] = (),
    report: bool = True,
) -> None:
    (root / "raw" / name).mkdir(parents=True)
    (root / "raw" / name / "day1.csv").write_text("time\n")
    os.utime(root / "raw" / name / "day1.csv", (RAW_T, RAW_T))  # recorded before any decision here
    if audit is None:  # never run: nothing under results/
        return
    res = root / "results" / name
    res.mkdir(parents=True)
    rows = "\n".join(f"{f},{s},{r}" for f, s, r in audit)
    (res / "audit.csv").write_text(f"file,status,reason\n{rows}\n")
    _json(
        res / "input_status.json",
        {"machine": name, "status": "skipped" if skipped else "usable", "rejected": []},
    )
    os.utime(res / "audit.csv", (T0, T0))
    for f, _, _ in audit:  # each raw file cleaned by that run, after it was recorded
        (res / "clean").mkdir(exist_ok=True)
        (res / "clean" / f"{Path(f).stem}.summary.csv").write_text("file,status\n")
        os.utime(res / "clean" / f"{Path(f).stem}.summary.csv", (T0, T0))
    reg = res / "registry"
    if champion:
        _json(
            reg / "champion.json",
            {"model_id": ID[champion], "since": "2026-01-02T03:04:05Z", "reason": "promoted"},
        )
        _json(reg / "models" / f"{ID[champion]}.json", {"model_id": ID[champion], "kind": kind})
    if decision is not None:
        _json(reg / "decision.json", decision)
        t = T0 - 10 if stale else T0 + 10
        os.utime(reg / "decision.json", (t, t))
    if history:
        reg.mkdir(parents=True, exist_ok=True)
        lines = "".join(json.dumps(h) + "\n" for h in history)
        (reg / "history.jsonl").write_text(lines + '{"torn": ')  # a line torn by a crash is skipped
    page = root / "reports" / name / ("skipped.html" if skipped else "qualification.html")
    if report:
        page.parent.mkdir(parents=True, exist_ok=True)
        page.write_text("<html></html>")


def _decision(kind: str, champion: str | None, candidate: str, **extra) -> dict:
    return {
        "decision": kind,
        "time": "2026-03-04T05:06:07Z",
        "candidate_id": ID[candidate],
        "champion_id_before": ID[champion] if champion else None,
        "champion_id_after": ID[candidate] if kind == "promoted" else (ID[champion] if champion else None),
        "reasons": [f"{kind} for the test"],
        "recalibration_due": False,
        "drift": {"status": "ok", "degradation_um": 0.1, "limit_um": 2.0},
        **extra,
    }


@pytest.fixture
def fleet(tmp_path):
    root = tmp_path / "proj"
    _machine(
        root,
        "ok-m",
        champion="X",
        decision=_decision("promoted", None, "X", candidate_summary=_summary("v1", 2.5)),
    )
    _machine(
        root,
        "recal-m",
        champion="Y",
        kind="grey_box",
        decision=_decision(
            "kept",
            "Y",
            "Y",
            candidate_summary=_summary("v3", 6.25),
            recalibration_due=True,
            drift={"status": "degraded", "degradation_um": 3.1, "limit_um": 2.0, "new_runs": ["v3"]},
        ),
    )
    _machine(
        root,
        "rej-m",
        champion="Z",
        decision=_decision(
            "rejected", "Z", "C", champion_summary=_summary("v2", 4.0), candidate_summary=_summary("v2", 9.0)
        ),
    )
    _machine(
        root,
        "quar-m",
        champion="Q",
        decision=_decision("promoted", None, "Q", candidate_summary=_summary("v1", 1.5)),
        audit=[("good.csv", "ok", ""), ("bad.csv", "quarantined", "line 3: <b>not a number</b>")],
    )
    _machine(
        root,
        "skip-m",
        champion="X",
        decision=_decision("promoted", None, "X", candidate_summary=_summary("v1", 2.0)),
        audit=[("only.csv", "quarantined", "empty file")],
        skipped=True,
    )
    _machine(
        root,
        "fail-m",
        champion="X",
        history=[{"decision": "promoted", "time": "2026-02-01T00:00:00Z", "candidate_id": ID["X"]}],
    )
    _machine(
        root,
        "stale-m",
        champion="X",
        decision=_decision("promoted", None, "X", candidate_summary=_summary("v1", 3.0)),
        stale=True,
    )
    _machine(root, "new-m", audit=None, report=False)
    _machine(
        root,
        "rolled-m",
        champion="R",
        decision=_decision("rolled_back", "X", "X", candidate_summary=_summary("v1", 2.0))
        | {"champion_id_after": ID["R"]},
        report=False,
    )
    (root / "config.yaml").write_text("raw_dir: raw\nresults_dir: results\nreports_dir: reports\n")
    return root


def _rows(root: Path, machines=None) -> list[dict]:
    return F.fleet_overview(Paths.from_config(root, {}), root / "reports", machines)


EXPECTED_ORDER = ["fail-m", "new-m", "skip-m", "stale-m", "recal-m", "quar-m", "rej-m", "ok-m", "rolled-m"]
EXPECTED_STATE = {
    "fail-m": "failed",
    "new-m": "not_run",
    "skip-m": "skipped",
    "stale-m": "failed",
    "recal-m": "recalibration_due",
    "quar-m": "quarantined",
    "rej-m": "rejected",
    "ok-m": "ok",
    "rolled-m": "ok",
}


def test_states_and_attention_order(fleet):
    rows = _rows(fleet)
    assert [r["machine"] for r in rows] == EXPECTED_ORDER
    assert {r["machine"]: r["state"] for r in rows} == EXPECTED_STATE
    assert [r["rank"] for r in rows] == [0, 0, 0, 0, 1, 2, 2, 3, 3]
    assert F.exit_code(rows) == 1


def test_what_each_row_says(fleet):
    rows = {r["machine"]: r for r in _rows(fleet)}
    # model in service: champion.json + the kind of its stored model
    assert rows["recal-m"]["champion"] == {
        "id": ID["Y"],
        "kind": "grey_box",
        "candidate": None,  # not adapted from a prior: no prior_* row names it
        "members": None,  # not an ensemble (tests/test_ensemble_report.py: one that is)
        "parent": None,  # not re-qualified from a prior (tests/test_requalify_e2e.py: one that is)
        "parent_machine": None,
        "prior": None,  # tests/test_prior_fitness.py: a model in service that has one
        "trail": None,  # no history line put it in service (tests/test_promotion_trail.py: lines that did)
        "since": "2026-01-02T03:04:05Z",
        "reason": "promoted",
    }
    assert rows["new-m"]["champion"] is None and rows["new-m"]["last_decision"] is None
    # worst residual of the model in service: the summary that scores it
    assert rows["ok-m"]["worst_residual"] == {
        "max_residual_um": 2.5,
        "run": "v1",
        "n_runs": 2,
        "source": "candidate_summary",
    }
    assert rows["recal-m"]["worst_residual"]["max_residual_um"] == 6.25
    rej = rows["rej-m"]["worst_residual"]  # the champion (4.0), not the rejected candidate (9.0)
    assert (rej["max_residual_um"], rej["run"], rej["source"]) == (4.0, "v2", "champion_summary")
    assert rows["rolled-m"]["worst_residual"] is None  # not scored since the rollback
    assert rows["fail-m"]["worst_residual"] is None
    # last decision: decision.json, else the last whole line of history.jsonl
    assert rows["rej-m"]["last_decision"]["decision"] == "rejected"
    assert rows["fail-m"]["last_decision"] == {
        "decision": "promoted",
        "time": "2026-02-01T00:00:00Z",
        "candidate_id": ID["X"],
        "reasons": [],
        "source": "history.jsonl",
    }
    # drift and recalibration
    assert rows["recal-m"]["recalibration_due"] and rows["recal-m"]["drift"]["degradation_um"] == 3.1
    assert "3.10 um" in rows["recal-m"]["attention"][0]["text"]
    assert not rows["ok-m"]["recalibration_due"]
    # quarantine, skipped
    assert rows["quar-m"]["quarantined"] == ["bad.csv (line 3: <b>not a number</b>)"]
    assert rows["skip-m"]["skipped"] and rows["skip-m"]["quarantined"] == ["only.csv (empty file)"]
    # pages, relative to reports_dir
    assert rows["ok-m"]["report"] == "ok-m/qualification.html"
    assert rows["skip-m"]["report"] == "skip-m/skipped.html"
    assert rows["rolled-m"]["report"] is None
    # per-machine exit codes (rafi nightly's)
    codes = {m: r["exit_code"] for m, r in rows.items()}
    assert codes == {
        "fail-m": 1,
        "new-m": 1,
        "skip-m": 4,
        "stale-m": 1,
        "recal-m": 3,
        "quar-m": 4,
        "rej-m": 2,
        "ok-m": 0,
        "rolled-m": 0,
    }


@pytest.mark.parametrize(
    "machines, code",
    [
        (["ok-m", "rolled-m"], 0),
        (["ok-m", "quar-m"], 4),
        (["quar-m", "rej-m"], 2),
        (["rej-m", "recal-m", "skip-m"], 3),
        (["skip-m", "recal-m", "new-m"], 1),
    ],
)
def test_exit_code_is_the_most_severe(fleet, machines, code):
    assert F.exit_code(_rows(fleet, machines)) == code


def test_page_lists_every_machine_most_urgent_first_with_links(fleet):
    paths = Paths.from_config(fleet, {})
    out = write_fleet_page(paths, fleet / "reports", rows=lambda: F.fleet_overview(paths, fleet / "reports"))
    assert out == fleet / "reports" / "index.html"
    page = out.read_text()
    positions = [page.index(f"<strong>{m}</strong>") for m in EXPECTED_ORDER]
    assert positions == sorted(positions)
    links = re.findall(r'href="([^"]+)"', page)
    with_page = [m for m in EXPECTED_ORDER if m not in ("new-m", "rolled-m")]  # no page built
    assert sorted(links) == sorted(
        f"{m}/{'skipped' if m == 'skip-m' else 'qualification'}.html" for m in with_page
    )
    assert "&lt;b&gt;not a number&lt;/b&gt;" in page and "<b>not a number" not in page  # escaped
    assert "<script" not in page and "http" not in page.split("<body>")[1]  # self-contained
    assert "4.00" in page and "6.25" in page


def test_page_elsewhere_links_back_into_reports(fleet, tmp_path):
    paths = Paths.from_config(fleet, {})
    rows = F.fleet_overview(paths, fleet / "reports")
    out = write_fleet_page(paths, fleet / "reports", tmp_path / "www" / "fleet.html", rows=rows)
    assert 'href="../proj/reports/ok-m/qualification.html"' in out.read_text()


def test_a_skipped_machine_alone(tmp_path):
    root = tmp_path / "p"
    _machine(
        root,
        "only",
        audit=[("a.csv", "quarantined", "no header"), ("b.csv", "quarantined", "empty")],
        skipped=True,
    )
    rows = _rows(root)
    assert [r["state"] for r in rows] == ["skipped"] and F.exit_code(rows) == 4
    page = fleet_page(rows, created="now")
    assert 'href="only/skipped.html"' in page and "a.csv (no header)" in page and "skipped: 1" in page


def test_empty_fleet(tmp_path):
    rows = _rows(tmp_path)
    assert rows == [] and F.exit_code(rows) == 0
    assert "No machine" in fleet_page(rows, created="now")


def _cli(root: Path, *argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    fleet_cli.add_arguments(parser)
    return parser.parse_args(["--directory", str(root), *argv])


def test_cli_json_text_and_html(fleet, capsys, tmp_path):
    assert fleet_cli.run(_cli(fleet, "--json")) == 1
    doc = json.loads(capsys.readouterr().out)
    assert doc["exit_code"] == 1 and [m["machine"] for m in doc["machines"]] == EXPECTED_ORDER
    assert fleet_cli.run(_cli(fleet, "--machine", "ok-m", "--machine", "rolled-m")) == 0
    text = capsys.readouterr().out
    assert text.startswith("ok-m: OK") and "2.50 um (v1)" in text and "rolled-m: OK" in text
    html = tmp_path / "out" / "index.html"
    assert fleet_cli.run(_cli(fleet, "--machine", "recal-m", "--html", str(html))) == 3
    assert "RECALIBRATION_DUE" in capsys.readouterr().out and "recal-m" in html.read_text()
    assert fleet_cli.run(_cli(fleet, "--machine", "nope")) == 64
    assert "no machine 'nope'" in capsys.readouterr().err


def test_rows_given_as_a_function_are_read_under_the_lock(fleet):
    paths = Paths.from_config(fleet, {})
    lock = paths.results_dir / ".nightly.page-lock"
    seen = []

    def rows():
        import fcntl

        fd = os.open(lock, os.O_RDWR)
        try:  # another process's writer would wait: the page lock is held while the rows are read
            with pytest.raises(BlockingIOError):
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        finally:
            os.close(fd)
        seen.append(True)
        return F.fleet_overview(paths, fleet / "reports")

    out = write_fleet_page(paths, fleet / "reports", rows=rows)
    assert seen == [True] and "ok-m" in out.read_text()


@pytest.mark.parametrize(
    "drift, has_champion, expected",
    [
        ({"status": "no_champion"}, True, "not checked yet (the model was promoted by the last decision)"),
        ({"status": "no_champion"}, False, "-"),
        (None, True, "-"),
        ({"status": "no_new_runs"}, True, "no new validation runs since the last check"),
        (
            {"status": "degraded", "degradation_um": 3.0, "limit_um": 9.0},
            True,
            "degraded, +3.00 um (limit 9.00 um)",
        ),
    ],
)
def test_the_drift_line_under_a_model_in_service(drift, has_champion, expected):
    # a decision that promoted the first champion had none to check: "no_champion" under
    # "model in service: <id>" read as a contradiction
    assert fleet_cli.describe_drift(drift, has_champion=has_champion) == expected


def _cells(page: str, machine: str) -> dict:
    """The visible text of ``machine``'s row of the fleet page, header -> cell."""
    head = re.search(r"<thead>(.*?)</thead>", page, flags=re.S).group(1)
    headers = [re.sub(r"<[^>]+>", "", h) for h in re.findall(r"<th>(.*?)</th>", head, flags=re.S)]
    row = re.search(rf"<tr>\s*<td><strong>{re.escape(machine)}</strong>(.*?)</tr>", page, flags=re.S)
    cells = [f"<strong>{machine}</strong>", *re.findall(r"<td[^>]*>(.*?)</td>", row.group(1), flags=re.S)]
    text = [" ".join(html.unescape(re.sub(r"<[^>]+>", " ", c)).split()) for c in cells]
    return dict(zip(headers, text, strict=True))


def test_the_page_says_in_words_why_drift_was_not_checked(fleet):
    """A model promoted (or rolled back to) by the last decision was not what that decision
    checked: the page says so in a sentence, as rafi status does, never the status key, and shows
    none of the replaced model's figures."""
    root = fleet
    old = _decision("kept", "Z", "Z")["drift"] | {
        "status": "degraded",
        "degradation_um": 4.53,
        "detected": True,
    }
    old["interval"] = {"status": "recalibration_due", "detected": True, "n": 40, "k": 20, "level": 0.9}
    _machine(
        root, "swap-m", champion="C",
        decision=_decision("promoted", "Z", "C", candidate_summary=_summary("v1", 1.25), drift=old),
    )  # fmt: skip
    # the model in service is re-qualified from a prior of another machine
    model = root / "results" / "swap-m" / "registry" / "models" / f"{ID['C']}.json"
    _json(
        model,
        {
            "model_id": ID["C"],
            "kind": "grey_box",
            "adaptation": {"parent": ID["Q"], "parent_machine": "quar-m", "method": "gain"},
        },
    )
    paths = Paths.from_config(root, {})
    page = write_fleet_page(
        paths, root / "reports", rows=lambda: F.fleet_overview(paths, root / "reports")
    ).read_text()
    for key in ("not_checked", "no_champion", "no_new_runs"):
        assert key not in page
    swap = _cells(page, "swap-m")
    assert swap["drift"] == f"not checked yet (the last check was of {ID['Z'][:12]}, the model replaced)"
    assert swap["interval drift"] == "-" and "4.53" not in page and swap["state"] == "ok"
    assert swap["model in service"].endswith(f"adapted from {ID['Q'][:12]} of quar-m")
    # named as the report's sections 1 and 3 name it, beside its kind
    assert swap["model in service"].startswith(f"{ID['C'][:12]} grey_box (prior_gain)")
    assert _cells(page, "ok-m")["drift"] == "not checked yet (the model was promoted by the last decision)"
    # a rollback keeps the drift block of the decision before it: not the model in service's
    assert (
        _cells(page, "rolled-m")["drift"]
        == "not checked yet (the model was rolled back to after the last check)"
    )
    # a model checked by the last decision: its own figures, the same words as rafi status
    assert _cells(page, "recal-m")["drift"] == "degraded, +3.10 um (limit 2.00 um) recalibration due"
    assert _cells(page, "rej-m")["drift"] == "ok, +0.10 um (limit 2.00 um)"
    rows = {r["machine"]: r for r in F.fleet_overview(paths, root / "reports")}
    for name in ("swap-m", "recal-m", "ok-m"):
        text = fleet_cli.format_rows([rows[name] | {"report_path": None}])
        assert f"drift:            {rows[name]['drift']['text']}; recalibration due" in text


def test_a_machine_waiting_for_a_confirmation_reads_so_in_its_headline_and_last_decision():
    row = {
        "machine": "a2",
        "champion": None,
        "last_decision": {"decision": "rejected", "time": "2026-11-30T20:41:39Z"},
        "waiting": True,
        "state": "waiting",
        "rank": F.RANK["waiting"],
        "attention": [{"text": "waits for a confirmation of the prior fitness check prior_speeds ..."}],
        "worst_residual": None,
        "recalibration_due": False,
        "drift": None,
        "quarantined": [],
        "report_path": None,
    }
    text = fleet_cli.format_rows([row])
    assert text.startswith("a2: WAITING FOR CONFIRMATION\n  ! waits for a confirmation")
    assert (
        "  last decision:    rejected at 2026-11-30T20:41:39Z (not promoted until the confirmation above)"
        in text
    )
    assert "REJECTED" not in text
    plain = fleet_cli.format_rows([row | {"waiting": False, "state": "rejected"}])
    assert plain.startswith("a2: REJECTED\n") and "(not promoted until" not in plain


def test_a_candidate_waiting_for_a_confirmation_is_its_own_state_not_rejected(fleet):
    """A last candidate that passed every gate and waits only for a confirmation (an input warning,
    its prior's fitness) is state waiting on rafi status and the page, never rejected: ranked with
    the rejected (a person has something to do, the model in service stays) and exit 2 as rafi
    nightly exits that night; its attention line names the checks.confirmed entry to add."""
    warning = {"file": "val.csv", "sha256": "ab" * 32, "check": "probe_sign", "message": "x"}
    _machine(
        fleet,
        "wait-m",
        champion="Z",
        decision=_decision(
            "rejected",
            "Z",
            "C",
            machine="wait-m",
            gates_passed=True,
            blocked_by=["input_warnings"],
            input_warnings={"blocking": [warning], "confirmed": [], "not_used": []},
            champion_summary=_summary("v2", 4.0),
        ),
    )
    rows = {r["machine"]: r for r in _rows(fleet)}
    wait = rows["wait-m"]
    assert (wait["state"], wait["rank"], wait["exit_code"], wait["waiting"]) == ("waiting", 2, 2, True)
    assert [a["state"] for a in wait["attention"]] == ["waiting"]
    assert wait["attention"][0]["text"].endswith(
        'add checks.confirmed: [{file: "val.csv", check: probe_sign}] in wait-m\'s settings; '
        "the champion stays until then"
    )
    assert rows["rej-m"]["state"] == "rejected" and not rows["rej-m"]["waiting"]
    order = [r["machine"] for r in _rows(fleet)]
    assert order.index("recal-m") < order.index("wait-m") < order.index("ok-m")  # rank 2, by name
    assert F.exit_code(_rows(fleet, ["wait-m", "quar-m", "ok-m"])) == 2
    assert F.exit_code(_rows(fleet, ["wait-m", "recal-m"])) == 3
    text = fleet_cli.format_rows([wait | {"report_path": None}])
    assert text.startswith("wait-m: WAITING FOR CONFIRMATION\n  ! the last candidate")
    page = fleet_page(list(rows.values()), created="now")
    cells = _cells(page, "wait-m")
    assert cells["state"].startswith("waiting the last candidate") and "rejected" not in cells["state"]
    assert "waiting: 1" in page and "rejected: 1" in page  # rej-m stays rejected
    # drift beside it: recalibration due leads, the waiting candidate is still said below it
    _machine(
        fleet,
        "wait-recal-m",
        champion="Z",
        decision=_decision(
            "rejected",
            "Z",
            "C",
            gates_passed=True,
            blocked_by=["input_warnings"],
            input_warnings={"blocking": [warning]},
            recalibration_due=True,
            drift={"status": "degraded", "degradation_um": 3.1, "limit_um": 2.0},
        ),
    )
    (both,) = _rows(fleet, ["wait-recal-m"])
    assert both["state"] == "recalibration_due" and both["waiting"] and both["exit_code"] == 3
    assert [a["state"] for a in both["attention"]] == ["recalibration_due", "waiting"]
    text = fleet_cli.format_rows([both | {"report_path": None}])
    assert text.startswith("wait-recal-m: RECALIBRATION_DUE\n")
    assert "last decision:    rejected at 2026-03-04T05:06:07Z (not promoted until the confirmation" in text


def test_status_counts_the_raw_files_that_arrived_after_the_last_decision(fleet, capsys):
    """rafi status says per machine how many raw files the last decision has not judged: modified
    after its time, or not cleaned in their present content (no clean/<log>.summary.csv, or one
    older than the file: a copy that kept an old mtime, a file rafi nightly left out as still being
    written); none, no line. The same rows feed --json and the page."""
    raw = fleet / "raw" / "ok-m"
    decided = 1_772_600_767  # 2026-03-04T05:06:07Z, the time of ok-m's decision
    (raw / "day2.csv").write_text("time\n")
    os.utime(raw / "day2.csv", (decided + 60, decided + 60))  # arrived after it
    (raw / "day0.csv").write_text("time\n")
    os.utime(raw / "day0.csv", (RAW_T, RAW_T))  # copied keeping its mtime: its run never read it
    stale = fleet / "results" / "rej-m" / "clean" / "day1.summary.csv"
    os.utime(stale, (RAW_T - 1, RAW_T - 1))  # cleaned before its file was last written
    (raw / "notes.txt").write_text("not a raw log: input.pattern *.csv\n")
    os.utime(raw / "notes.txt", (decided + 60, decided + 60))
    paths = Paths.from_config(fleet, {})
    rows = {r["machine"]: r for r in F.fleet_overview(paths, fleet / "reports", config={})}
    assert rows["ok-m"]["unjudged"] == {
        "count": 2,
        "files": ["day0.csv", "day2.csv"],
        "since": "2026-03-04T05:06:07Z",
    }
    assert rows["rej-m"]["unjudged"]["files"] == ["day1.csv"]
    os.utime(stale, (T0, T0))
    rows = {r["machine"]: r for r in F.fleet_overview(paths, fleet / "reports", config={})}
    assert rows["rej-m"]["unjudged"] is None  # day1.csv: cleaned by its run, recorded before it
    assert rows["new-m"]["unjudged"] is None  # no decision yet: its state says so
    assert F.fleet_overview(paths, fleet / "reports")[0]["unjudged"] is None  # without the config
    page = fleet_page(list(rows.values()), created="now")
    assert _cells(page, "ok-m")["last decision"].endswith("2 raw file(s) not judged yet (arrived after it)")
    assert "not judged yet" not in _cells(page, "rej-m")["last decision"]
    many = {"count": 7, "files": [f"d{i}.csv" for i in range(7)], "since": "t"}
    assert fleet_cli.unjudged_text(many) == (
        "7 raw file(s) arrived after the last decision (t): d0.csv, d1.csv, d2.csv, d3.csv, d4.csv, "
        "... (2 more); the next night judges them"
    )
    assert fleet_cli.run(_cli(fleet, "--machine", "ok-m", "--machine", "rej-m")) == 2
    text = capsys.readouterr().out
    assert (
        "  not judged yet:   2 raw file(s) arrived after the last decision (2026-03-04T05:06:07Z): "
        "day0.csv, day2.csv; the next night judges them\n"
    ) in text
    assert text.count("not judged yet") == 1
    assert fleet_cli.run(_cli(fleet, "--machine", "ok-m", "--json")) == 0
    (row,) = json.loads(capsys.readouterr().out)["machines"]
    assert row["unjudged"]["count"] == 2


def test_a_machine_with_several_probes_is_one_machine_with_its_probes_under_it(tmp_path):
    """FL_THERMAL (issue 46's audit): one machine, five probe units ``fl-thermal@ch1``..; the page
    counted "5 machine(s)" and never linked the machine's own page."""
    root = tmp_path / "p"
    for probe, kind in (("ch1", "promoted"), ("ch2", "rejected")):
        decision = _decision(
            kind, "X", "X" if kind == "promoted" else "C", candidate_summary=_summary("v1", 2.0)
        )
        _machine(root, f"fl@{probe}", champion="X", decision=decision | {"champion_id_after": ID["X"]})
    _machine(
        root,
        "solo",
        champion="X",
        decision=_decision("promoted", None, "X", candidate_summary=_summary("v1", 1.0)),
    )
    (root / "reports" / "fl" / "qualification.html").parent.mkdir(parents=True)
    (root / "reports" / "fl" / "qualification.html").write_text("<html></html>")
    rows = _rows(root, ["fl@ch1", "fl@ch2", "solo"])
    by = {r["machine"]: r for r in rows}
    assert (by["fl@ch1"]["folder"], by["fl@ch1"]["probe"], by["solo"]["probe"]) == ("fl", "ch1", None)
    assert by["fl@ch2"]["machine_report"] == "fl/qualification.html" and by["solo"]["machine_report"] is None
    paths = Paths.from_config(root, {})
    page = write_fleet_page(paths, root / "reports", tmp_path / "www" / "index.html", rows=rows).read_text()
    text = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html.unescape(page)))
    assert "1 of 2 machine(s) need attention" in text and "2 machine(s)" in text and "3 machine" not in text
    assert "rejected: 1" in text and "ok: 1" in text  # a machine is as urgent as its most urgent probe
    assert 'href="../p/reports/fl/qualification.html"' in page
    assert 'href="../p/reports/fl@ch1/qualification.html"' in page
    # the probes under their machine: fl, then its probes, then the other machine
    order = [page.index(s) for s in ("<strong>fl</strong>", "@ch2", "@ch1", "<strong>solo</strong>")]
    assert order == sorted(order)


def test_without_a_machine_list_the_config_lists_each_machines_probes(tmp_path):
    """What a night for some machines writes the page with: raw/fl is one folder, qualified as
    ``fl@ch1`` and ``fl@ch2``; without the config its probes' results were never found."""
    import shutil

    root = tmp_path / "p"
    for probe in ("ch1", "ch2"):
        _machine(root, f"fl@{probe}", champion="X", decision=_decision("promoted", None, "X"))
        shutil.rmtree(root / "raw" / f"fl@{probe}")
    (root / "raw" / "fl").mkdir()
    (root / "raw" / "fl" / "data.csv").write_text("time\n")
    config = {"machines": {"fl": {"input": {"format": "csv", "probes": {"ch1": "a", "ch2": "b"}}}}}
    paths = Paths.from_config(root, {})
    assert [r["state"] for r in F.fleet_overview(paths, root / "reports")] == ["not_run"]
    rows = F.fleet_overview(paths, root / "reports", config=config)
    assert [(r["machine"], r["state"]) for r in rows] == [("fl@ch1", "ok"), ("fl@ch2", "ok")]


def test_status_prints_the_pages_table_a_machine_then_its_probes(tmp_path, capsys):
    """The page's footer said "rafi status prints the same table" while status listed FL_THERMAL's
    units flat, with no machine line, and left out the interval drift line where the page shows
    "-" (the mixed fleet read page by page, 2026-12-01)."""
    import shutil

    root = tmp_path / "p"
    for probe, kind in (("ch1", "promoted"), ("ch2", "rejected")):
        decision = _decision(
            kind, "X", "X" if kind == "promoted" else "C", candidate_summary=_summary("v1", 2.0)
        )
        _machine(root, f"fl@{probe}", champion="X", decision=decision | {"champion_id_after": ID["X"]})
        shutil.rmtree(root / "raw" / f"fl@{probe}")  # one raw folder, two probe units
    (root / "raw" / "fl").mkdir()
    (root / "raw" / "fl" / "data.csv").write_text("time\n")
    _machine(root, "solo", champion="X", decision=_decision("promoted", None, "X"))
    (root / "reports" / "fl" / "qualification.html").parent.mkdir(parents=True)
    (root / "reports" / "fl" / "qualification.html").write_text("<html></html>")
    probes = {"ch1": {"column": "a"}, "ch2": {"column": "b"}}
    config = {"machines": {"fl": {"input": {"format": "csv", "probes": probes}}}}
    (root / "config.yaml").write_text(json.dumps(config))  # YAML reads JSON
    assert fleet_cli.run(_cli(root)) == 2
    text = capsys.readouterr().out
    heads = [line for line in text.splitlines() if not line.startswith(" ")]
    # as the page: the machine (as urgent as its most urgent probe), its probes under it, then the others
    assert heads[0].startswith("fl: REJECTED (2 probes, each qualified on its own")
    assert heads[1:] == ["fl@ch2: REJECTED", "fl@ch1: OK", "solo: OK"]
    machine = text[: text.index("fl@ch2:")]
    assert f"report:           {root / 'reports' / 'fl' / 'qualification.html'}" in machine
    # every unit's block has the page's columns, an interval drift line too ("-" as the page)
    blocks = text.split("\nfl@")[1:]
    assert all("  interval drift:   " in b for b in blocks)
    assert "  interval drift:   -\n" in text
    page = (
        (root / "reports" / "index.html").read_text() if (root / "reports" / "index.html").exists() else None
    )
    assert page is None  # status writes the page only with --html


def test_the_page_fits_a_phone_and_its_footer_says_what_status_prints(fleet):
    page = fleet_page(_rows(fleet), created="now")
    assert '<meta name="viewport" content="width=device-width, initial-scale=1">' in page
    wrapper = re.search(r'<div class="table-wrap">\s*<table>', page)
    assert wrapper and ".table-wrap { overflow-x: auto;" in page
    text = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", page))
    assert "rafi status prints the same rows as text" in text and "prints the same table" not in text
