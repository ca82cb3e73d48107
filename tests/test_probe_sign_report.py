"""Where the report says a probe's sign comes from (issue 46's audit of FL_THERMAL): set in the
settings, stated by ``checks.probe_sign``, or the default; and what the data say of it, read from
``audit.csv``'s ``probe_sign`` (the clean job's per-file sign, docs/raw-format.md "Checks"), never
estimated again here. A sign the data contradict, or a default the data do not confirm, is flagged.
"""

from __future__ import annotations

import re

import pandas as pd
import pytest

from rafi.report.probe import probe_sign_record, sign_key
from rafi.settings import machine_settings

PROBES = {"format": "csv", "probes": {"ch1": {"column": "ch1(um)"}, "ch3": {"column": "ch3(um)", "sign": -1}}}


def _audit(**signs) -> pd.DataFrame:
    return pd.DataFrame({"file": list(signs), "status": "ok", "probe_sign": list(signs.values())})


def _settings(checks=None, unit="m@ch1", **inp) -> dict:
    machine = {"input": {**PROBES, **inp}}
    if checks:
        machine["checks"] = checks
    return machine_settings({"machines": {"m": machine}}, unit)


def test_sign_key_names_the_key_of_config_yaml_that_sets_the_sign():
    config = {"machines": {"m": {"input": PROBES}}}
    assert sign_key(config, "m@ch1") is None  # rafi init leaves it a CHECK line: the default
    assert sign_key(config, "m@ch3") == "machines.m.input.probes.ch3.sign"
    one = {"machines": {"m": {"input": {"format": "csv", "displacement": {"column": "Z", "sign": -1}}}}}
    assert sign_key(one, "m") == "machines.m.input.displacement.sign"
    shared = {"defaults": {"input": {"displacement": {"sign": 1}}}, "machines": {"m": {"input": PROBES}}}
    assert sign_key(shared, "m@ch1") == "defaults.input.displacement.sign"
    assert sign_key({}, "m") is None


def test_fl_thermal_ch1_the_default_the_data_agree_with():
    rec = probe_sign_record(_settings(), None, _audit(**{"data.xlsx": 1}))
    assert (rec["sign"], rec["source"], rec["data"], rec["flagged"]) == (1, "default", "agree", False)
    assert "input.probes.ch1.sign not set" in rec["text"]
    assert "data.xlsx rises while the spindle heats" in rec["text"]


def test_fl_thermal_ch3_a_default_no_file_confirms_is_flagged_unconfirmed():
    rec = probe_sign_record(_settings(), None, _audit(**{"data.xlsx": 0}))
    assert (rec["source"], rec["data"], rec["flagged"]) == ("default", "no evidence", True)
    assert rec["short"] == "default, unconfirmed"
    assert "no clear direction" in rec["text"] and "Unconfirmed" in rec["text"]
    assert "input.probes.ch1.sign" in rec["text"]


def test_a_sign_the_data_contradict_is_flagged_whatever_its_source():
    audit = _audit(**{"a.csv": 1, "b.csv": -1})
    for settings, key in ((_settings(), None), (_settings(unit="m@ch3"), "machines.m.input.probes.ch3.sign")):
        rec = probe_sign_record(settings, key, audit)
        assert rec["data"] == "contradict" and rec["flagged"], rec
        assert "b.csv falls while the spindle heats" in rec["text"] and "a.csv" not in rec["text"]
    # a person confirmed the file's sign (checks.confirmed): said, no longer flagged
    confirmed = _settings(checks={"confirmed": [{"file": "b.csv", "check": "probe_sign"}]})
    rec = probe_sign_record(confirmed, None, audit)
    assert rec["data"] == "contradict" and not rec["flagged"] and "checks.confirmed" in rec["text"]


@pytest.mark.parametrize(
    ("checks", "unit", "key", "source", "signs"),
    [
        (None, "m@ch3", "machines.m.input.probes.ch3.sign", "set", {"x.csv": 0}),
        ({"probe_sign": "negative"}, "m@ch1", None, "stated", {"x.csv": -1, "y.csv": 0}),
    ],
)
def test_a_sign_set_or_stated_is_not_flagged_without_contrary_data(checks, unit, key, source, signs):
    rec = probe_sign_record(_settings(checks=checks, unit=unit), key, _audit(**signs))
    assert rec["source"] == source and not rec["flagged"]
    assert (key or "checks.probe_sign: negative") in rec["text"]


def test_without_audit_the_data_say_nothing_and_a_default_is_unconfirmed():
    rec = probe_sign_record(_settings(), None, None)
    assert rec["data"] == "unknown" and rec["flagged"]


def test_section_15_says_where_the_sign_comes_from():
    from test_report_text import _section

    rec = probe_sign_record(_settings(), None, _audit(**{"data.xlsx": 0}))
    ctx = {
        "versions": [],
        "generated": "now",
        "model_id": "",
        "champion_id": "",
        "code_version": "",
        "config_changes": [],
        "probe_sign": rec,
    }
    html = _section("provenance", **ctx)
    text = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html))
    assert "Probe sign +1" in text and "Unconfirmed" in text
    assert 'class="note"' in html


def test_the_machine_page_says_where_each_probes_sign_comes_from(tmp_path):
    """FL_THERMAL's page said "sign +1" for all five probes; ch3's sign is the default and its
    file shows no clear direction: flagged, ch1's the default its file agrees with."""
    import json

    from rafi.report.probes_page import probe_row, probes_context, render_probes_html

    rows = []
    for probe, sign in (("ch1", 1), ("ch3", 0)):
        d = tmp_path / probe
        d.mkdir()
        pd.DataFrame(
            {
                "model": ["ensemble"],
                "kind": ["ensemble"],
                "champion": [True],
                "passed": [True],
                "max_abs_after_um": [4.0],
                "max_abs_before_um": [20.0],
            }
        ).to_csv(d / "summary.csv", index=False)
        pd.DataFrame(
            {
                "model": ["ensemble"],
                "run_id": ["data#9"],
                "max_abs_before_um": [20.0],
                "max_abs_after_um": [4.0],
            }
        ).to_csv(d / "per_run.csv", index=False)
        (d / "decision.json").write_text(json.dumps({"decision": "promoted"}))
        _audit(**{"data.xlsx": sign}).to_csv(d / "audit.csv", index=False)
        paths = {
            k: str(d / f"{k}.{'json' if k == 'decision' else 'csv'}")
            for k in ("summary", "per_run", "decision", "audit")
        }
        fl = {"format": "csv", "probes": {"ch1": "ch1(um)", "ch3": "ch3(um)"}}  # as rafi init wrote them
        settings = machine_settings({"machines": {"m": {"input": fl}}}, f"m@{probe}")
        rows.append(probe_row(probe, settings, paths, f"../m@{probe}/qualification.html"))
    assert [r["sign_record"]["flagged"] for r in rows] == [False, True]
    html = render_probes_html(probes_context("m", rows))
    text = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html))
    assert "default, the data agree" in text and "default, unconfirmed" in text
    assert "data.xlsx rises while the spindle heats" in text and "Unconfirmed" in text


def test_the_verdict_box_says_a_flagged_sign_in_one_line_naming_the_key_that_settles_it():
    """FL_THERMAL ch3's page 1 was a plain PASS; its sign, a default no file confirms, was said only
    in the provenance on the last page (the mixed fleet read page by page, 2026-12-01)."""
    from collections import defaultdict

    from test_report_text import _section

    unconfirmed = probe_sign_record(_settings(), None, _audit(**{"data.xlsx": 0}))
    line = unconfirmed["verdict_line"]
    assert line.startswith("Probe sign +1 unconfirmed") and "\n" not in line
    assert "set input.probes.ch1.sign" in line and "no clear direction" in line
    contradicted = probe_sign_record(
        _settings(unit="m@ch3"), "machines.m.input.probes.ch3.sign", _audit(b=-1)
    )
    assert contradicted["verdict_line"].startswith("Probe sign \u22121 contradicted by the data")
    assert "machines.m.input.probes.ch3.sign" in contradicted["verdict_line"]
    # a sign the data agree with, or one set in the settings: nothing on page 1
    assert probe_sign_record(_settings(), None, _audit(**{"data.xlsx": 1}))["verdict_line"] is None
    set_sign = probe_sign_record(_settings(unit="m@ch3"), "machines.m.input.probes.ch3.sign", _audit(x=0))
    assert set_sign["verdict_line"] is None

    def box(rec):
        verdict = defaultdict(lambda: None, css="pass", status="PASS", stored=True, rows=[], probe_sign=rec)
        html = _section("verdict", verdict=verdict)
        text = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", html))
        return html, text

    html, text = box(line)
    inside = html[html.index('<div class="verdict') : html.index("</div>")]
    assert "Probe sign +1 unconfirmed" in re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", inside))
    assert 'href="#provenance"' in inside
    assert "Probe sign" not in box(None)[1]


def test_the_files_sign_is_said_to_be_measured_after_the_configured_sign():
    """machining-center-b read "Probe sign −1: set in the settings ...; the data agree: ... rises
    while the spindle heats (audit.csv probe_sign +1)", a contradiction at first sight: the clean
    job measures the sign of the displacement the reader already multiplied by −1."""
    reversed_probe = _settings(unit="m@ch3")  # input.probes.ch3.sign: -1
    rec = probe_sign_record(reversed_probe, "machines.m.input.probes.ch3.sign", _audit(**{"log.xlsx": 1}))
    assert rec["sign"] == -1 and rec["data"] == "agree"
    assert (
        "log.xlsx rises while the spindle heats (audit.csv probe_sign +1, measured after the configured "
        in rec["text"]
    )
    assert "sign \u22121 is applied)" in rec["text"]
    against = probe_sign_record(
        reversed_probe, "machines.m.input.probes.ch3.sign", _audit(**{"log.xlsx": -1})
    )
    assert "probe_sign \u22121, measured after the configured sign \u22121 is applied" in against["text"]
    # a sign of +1 changes nothing: nothing to say
    plain = probe_sign_record(_settings(), None, _audit(**{"log.xlsx": 1}))
    assert "(audit.csv probe_sign +1)" in plain["text"] and "applied" not in plain["text"]
