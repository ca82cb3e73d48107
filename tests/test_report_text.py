"""Text of the qualification report computed from this machine's results (issue 15 items 6-7).

Every sentence that states a property of the data (collinearity, sample period, sensor roles,
the paper comparison, equilibrium flags) is tested on generated inputs whose truth is known:
a collinearity matrix with |r| 0.45, 15 s data, a machine that is not the paper's rig, an
equilibrium time eight times its tau cross-check, a first-order fit driven to its bound by a
straight ramp. The cosmetic items (format glitches, one spelling of the micrometre, legends and
titles inside the figure, text colour on heat-map cells, the configuration appendix) are tested
the same way: each test fails on the report as it was before the fix.
"""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from html_tables import html_tables
from report_fixture import copy_fixture, empty_figure_dirs, write_upstream_tables

from rafi.method.audit import summarise_audit
from rafi.method.clean import clean_log
from rafi.method.equilibrium import first_order_fit
from rafi.report import plot_layout, plots
from rafi.report.choices import section_choices, setting_text, settings_changes
from rafi.report.context import build_context
from rafi.report.data_sections import (
    COLLINEAR_ABS_R,
    TAU_MAX_SPANS,
    equilibrium_description,
    section_data,
    section_equilibrium,
    section_ranking,
    tau_at_bound,
)
from rafi.report.format import fmt_speed_range, micro
from rafi.report.model_sections import section_validation
from rafi.report.render import _environment, render_html
from rafi.settings import MACHINE_DEFAULTS, machine_settings
from rafi.twin.synthetic_logs import CLEAN_KWARGS, OPEN_CIRCUIT, canonical_log

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT / "tests" / "data" / "report_fixture" / "tapping-center-a"
CONFIG = yaml.safe_load((ROOT / "config.yaml").read_text(encoding="utf-8"))

#: The paper's numbers (../shared/docs/paper-notes.md: Tables 1, 3 and 4, the multi-condition
#: and single-speed examples, the fuzzy worked example) as they would print, thousands
#: separators removed; and the paper's key sensors.
PAPER_NUMBERS = [
    *("10160", "9675", "6895", "6615", "5385", "5560"),
    *("0.639", "0.418", "0.277", "0.283", "0.780", "0.421"),
    *("10.03", "5.64", "5.36", "3.48", "9.23"),
    *("23.12", "14.59", "36.9", "16.48", "39.16", "24.22", "85.64"),
    *("0.334", "0.666"),
]
PAPER_PHRASES = ["T6, T8, T9", "paper Table", "paper Figure", "paper's Table", "paper's Figure"]


class _Figs:
    """A FigureFiles stand-in without figures (the sections' text is under test)."""

    used: list = []

    def get(self, group, key):
        return None


def _section(name: str, **ctx) -> str:
    """One section template rendered alone (the heading macro needs ``section_by_id``)."""
    ids = (
        "verdict",
        "data",
        "equilibrium",
        "ranking",
        "models",
        "fuzzy",
        "validation",
        "choices",
        "provenance",
    )
    base = {
        "section_by_id": {s: {"id": s, "number": k, "title": s} for k, s in enumerate(ids, start=1)},
        "fig_offset": 0,
        "deployed": None,
        "paper_rig": False,
        "coolant_sensors": [],
        "machine": "m",
    }
    return _environment().get_template(f"sections/{name}.html.j2").render(**{**base, **ctx})


def _choices_text(settings: dict, key_info: dict | None = None) -> str:
    """The visible text of the section choices of a machine with ``settings``."""
    html = _section("choices", choices=section_choices(settings, key_info or {}, None))
    text = re.sub(r"<[^>]+>", " ", html).replace("&gt;", ">").replace("&lt;", "<").replace("&#39;", "'")
    return re.sub(r"[ \t\r\n]+", " ", text).strip()  # no-break spaces kept


def _text(html: str) -> str:
    """Visible text: styles, embedded images and tags removed, digit groups joined
    (``10 160`` -> ``10160``), whitespace collapsed."""
    html = re.sub(r"<style>.*?</style>", "", html, flags=re.S)
    html = re.sub(r"<svg.*?</svg>", "", html, flags=re.S)
    html = re.sub(r'src="data:[^"]*"', "", html)
    text = re.sub(r"<wbr>", "", html)
    text = re.sub(r"<[^>]+>", " ", text).replace("&amp;", "&").replace("&#39;", "'")
    text = re.sub(r"(?<=\d)[\u00a0\u202f ](?=\d{3}(?!\d))", "", text)
    return " ".join(text.split())


def _paper_hits(text: str, own: set | None = None) -> list[str]:
    """The paper's numbers and phrases in ``text``, except those in ``own`` (the machine's own
    numbers, :func:`_own_numbers`: a residual of 5.64 um measured on this machine is data)."""
    hits = [n for n in PAPER_NUMBERS if re.search(rf"(?<![\d.]){re.escape(n)}(?![\d])", text)]
    return [h for h in hits + [p for p in PAPER_PHRASES if p in text] if h not in (own or set())]


def _own_numbers(results: Path) -> set:
    """Every number of the machine's result tables (CSV and JSON, the ``paper_*`` columns
    left out) as the report could print it (0 to 4 decimals), and its key sensors."""
    values = []
    for path in results.rglob("*.csv"):
        frame = pd.read_csv(path)
        for col in frame.columns:
            if not str(col).startswith("paper") and pd.api.types.is_numeric_dtype(frame[col]):
                values += frame[col].dropna().tolist()
    for path in results.rglob("*.json"):
        values += [
            float(v) for v in re.findall(r"(?<![\w.])-?\d+\.\d+(?![\w])", path.read_text(encoding="utf-8"))
        ]
    out = {f"{abs(v):.{d}f}" for v in values for d in range(5)}
    info = json.loads((results / "rank" / "key_sensors.json").read_text(encoding="utf-8"))
    out.add(", ".join(sorted(info["sensors"], key=lambda s: int(s[1:]))))
    return out


# --------------------------------------------------------------------------- whole report


def _fixture_html(tmp_path: Path, *, paper_rig: bool, machine: str = "tapping-center-a") -> tuple[dict, str]:
    """The report fixture's context and HTML (tables of rule report_tables, no figures)."""
    results = copy_fixture(tmp_path, machine)
    paths = write_upstream_tables(results)
    dirs = empty_figure_dirs(results)
    settings = machine_settings(CONFIG, "tapping-center-a")
    if not paper_rig:  # another machine: nothing of the paper's rig in its configuration
        settings["report"] = machine_settings({}, machine)["report"]
    ctx = build_context(paths, dirs, machine=machine, settings=settings)
    return ctx, render_html(ctx)


@pytest.fixture(scope="module")
def both(tmp_path_factory):
    """The fixture rendered as the paper's rig and as another machine."""
    out = {}
    for flag in (True, False):
        out[flag] = _fixture_html(tmp_path_factory.mktemp(f"paper{int(flag)}"), paper_rig=flag)
    return out


def test_no_paper_number_anywhere_unless_the_machine_is_the_papers_rig(both):
    on_rig = _paper_hits(_text(both[True][1]))
    # the scan finds the paper's tables and comparisons where they belong (a control)
    for n in ("10160", "0.639", "10.03", "23.12", "14.59", "0.334", "T6, T8, T9", "paper Table"):
        assert n in on_rig, n
    assert _paper_hits(_text(both[False][1]), _own_numbers(FIXTURE)) == []


def test_coolant_wording_only_with_coolant_sensors(both):
    assert "coolant" not in _text(both[False][1]).lower()
    eq = {**both[True][0]["equilibrium"], "figure": {"kind": "png", "src": "data:,"}}
    html = _section("equilibrium", equilibrium=eq, coolant_sensors=["T13"], paper_rig=True)
    assert "coolant sensor T13 dashed" in _text(html) and "paper Figure 9" in html
    html = _section("equilibrium", equilibrium=eq, coolant_sensors=[])
    assert "coolant" not in html and "Figure 1." in html and "paper Figure" not in html


def test_one_spelling_of_the_micrometre(both):
    for _, html in both.values():
        text = _text(html)
        assert not re.search(r"\d\s*um\b", text), re.search(r".{40}\d\s*um\b.{20}", text)
        assert "\u00b5m" in text
    assert micro("max residual 2.45 um (limit 12)") == "max residual 2.45 \u00b5m (limit 12)"
    assert micro("sum of drums") == "sum of drums"


def test_no_number_glued_to_the_next_sentence(both):
    for _, html in both.values():
        assert not re.search(r"%\.\d", _text(html))  # was "36.9 %.1624 of 3276 samples"


def test_equilibrium_method_described_once(both):
    for _, html in both.values():
        text = _text(html)
        assert text.count("rolling median") == 1, text.count("rolling median")


def test_config_appendix_lists_only_what_differs_from_the_defaults(both):
    html = both[False][1]
    assert '<pre class="config">' not in html and "docs/settings.md" in html
    assert "ridge_alphas" not in html and "max_residual_um: 12.0" not in html
    rows = settings_changes(machine_settings(CONFIG, "machining-center-b"))
    keys = [r["key"] for r in rows]
    assert "sample_period_s" in keys and "reference.rule" in keys
    assert "input.columns" in keys and not any(k.startswith("input.columns.") for k in keys)  # one row
    assert not any(k.startswith(("models.", "qualification.", "deploy.")) for k in keys)
    row = rows[keys.index("sample_period_s")]
    assert (row["value"], row["default"]) == ("15", "5")
    # a changed long list is one short row, not 28 lines
    s = machine_settings({"machines": {"m": {"models": {"ridge_alphas": list(np.logspace(-8, 1, 28))}}}}, "m")
    (row,) = [r for r in settings_changes(s) if r["key"] == "models.ridge_alphas"]
    assert row["value"].startswith("[28 values: ") and "\n" not in row["value"]
    assert settings_changes(machine_settings({}, "m")) == []
    assert setting_text(None) == "none" and setting_text([1, 2]) == "[1, 2]"


# --------------------------------------------------------------------------- sections


def _ranking_res(r_offdiag: float) -> tuple[dict, dict]:
    names = ["T1", "T2", "T3"]
    coll = pd.DataFrame(np.eye(3), index=names, columns=names)
    coll.loc["T1", "T2"] = coll.loc["T2", "T1"] = r_offdiag
    coll.loc["T1", "T3"] = coll.loc["T3", "T1"] = r_offdiag / 2
    coll.loc["T2", "T3"] = coll.loc["T3", "T2"] = -r_offdiag / 3
    res = {"correlation": None, "key_sensors": None, "collinearity": coll.reset_index(names="sensor")}
    return res, {"sensors": names, "threshold": 0.97, "scope": "min_per_speed"}


@pytest.mark.parametrize("r, collinear", [(0.45, False), (-0.45, False), (0.98, True), (-0.93, True)])
def test_collinearity_wording_follows_the_measured_r(r, collinear):
    res, info = _ranking_res(r)
    ranking = section_ranking(res, info, _Figs())
    assert ranking["collinear"] is collinear and ranking["pair"] == "T1\u2013T2"
    text = _text(_section("ranking", ranking=ranking))
    assert f"{abs(r):.4f} (T1\u2013T2)" in text
    assert ("nearly collinear too" in text) is collinear
    assert f"{COLLINEAR_ABS_R:g}" in text  # the threshold is stated
    assert "paper" not in text


def test_sample_period_is_the_machines():
    for period in (15, 5, 1):
        settings = machine_settings({"machines": {"m": {"sample_period_s": period}}}, "m")
        text = _choices_text(settings)
        assert f"at this machine's {period}\u00a0s sample period" in text
        assert f"Regular grid of {period}\u00a0s" in text
        if period != 5:
            assert not re.search(r"(?<![\d.])5[\u00a0 ]s sample", text)
    data = section_data({"runs_csv": None, "audit": None}, 15)
    assert data["totals_text"] is None


@pytest.mark.parametrize("rule, cold", [("run_start", True), ("log_start", False)])
def test_the_reference_state_sentence_follows_the_reference_rule(rule, cold):
    settings = machine_settings({"machines": {"m": {"reference": {"rule": rule, "window_s": 60}}}}, "m")
    text = _choices_text(settings)
    text = text[text.index("Runs, roles and the rest before start") : text.index("Sensor dropouts")]
    assert ("the reference state is the machine at rest, before the spindle turns" in text) is cold
    assert ("does not start cold" in text) is not cold


@pytest.mark.parametrize(
    "idle_training, said",
    [
        (None, "a training run when a training run of its log follows it before any validation data"),
        (True, "a training run when it lies before the log's first validation data"),
        (False, "validated, never trained on"),
    ],
)
def test_the_cool_down_sentence_follows_idle_training(idle_training, said):
    runs = {} if idle_training is None else {"runs": {"idle_training": idle_training}}
    settings = machine_settings({"machines": {"m": runs}}, "m")
    text = _choices_text(settings)
    text = text[text.index("Runs, roles and the rest before start") : text.index("Sensor dropouts")]
    assert said in text
    shown = "schedule" if idle_training is None else str(idle_training).lower()
    assert f"(runs.idle_training = {shown})" in text


def test_cleaning_says_rows_read_and_rows_on_the_grid():
    audit = pd.DataFrame(
        {
            "file": ["a.csv", "b.csv"],
            "sha256": ["0" * 64] * 2,
            "rows_in": [16000, 16026],
            "rows_out": [16050, 16062],
            "duplicates_dropped": [10, 17],
            "reordered": [0, 0],
            "spikes_replaced": [20, 20],
            "values_interpolated": [0, 0],
            "gaps_interpolated": [40, 33],
            "segments": [1, 1],
            "status": ["ok", "ok"],
            "reason": ["", ""],
        }
    )
    d = section_data({"runs_csv": None, "audit": audit}, 15)
    text = d["totals_text"].replace("\u00a0", " ")
    assert "kept" not in text
    assert text.startswith("Cleaning read 32 026 rows and wrote 32 112 rows on the regular 15 s grid")
    assert "27 duplicate row(s) dropped" in text and "73 gap(s) bridged" in text
    assert "40 spike value(s) replaced" in text  # values: a burst of three samples counts three
    (audit_t,) = html_tables(_section("data", data=d), "audit num")
    assert audit_t["headers"][1:3] == ["rows read", "rows on the grid"]
    assert [r[-1]["cls"] for r in audit_t["rows"]] == ["pass", "pass"]


def test_the_data_section_names_the_values_cleaning_left_missing():
    """A file whose cleaning left sensor values missing (an open circuit, a long dropout): the
    Data section counts them and names each span (file, run, sensor, lines, what was done), as the
    clean step recorded them; the cleaning-audit table shows the count per file."""
    log, _ = canonical_log(400, extras=False)
    broken = log.copy()
    i = broken.index
    broken.loc[i[100:156], "T8"] = OPEN_CIRCUIT
    broken.loc[i[200:286], "T11"] = np.nan
    rows = []
    for name, frame in (("valid_a.csv", broken), ("valid_b.csv", log)):
        out, actions = clean_log(frame, **{**CLEAN_KWARGS, "file": name})
        rows.append(summarise_audit(name, "0" * 64, len(frame), out, actions))
    audit = pd.read_csv(io.StringIO(pd.concat(rows).to_csv(index=False)))  # as audit.csv reads back
    runs = pd.DataFrame(
        {"run_id": ["valid_a", "valid_b"], "file": ["valid_a.csv", "valid_b.csv"], "role": ["validation"] * 2}
    )
    d = section_data({"runs_csv": runs, "audit": audit}, 5, max_gap_s=60)
    assert (
        d["totals_text"]
        .replace("\u00a0", " ")
        .endswith("0 sensor value(s) interpolated, 142 sensor value(s) left missing.")
    )
    assert [m["file"] for m in d["missing"]] == ["valid_a.csv"]
    html = _section("data", data=d)
    text = _text(html)
    assert f"valid_a.csv (run valid_a): T8 lines {i[100]}-{i[155]}: 56 open-circuit value(s) removed" in text
    assert f"T11 lines {i[200]}-{i[285]}: 86 value(s) absent from the file and left missing" in text
    assert "more than 60 s apart" in text and "gets no compensation" in text
    (audit_t,) = html_tables(html, "audit num")
    col = audit_t["headers"].index("values missing")
    assert [r[col]["text"] for r in audit_t["rows"]] == ["142", "0"]


def test_speed_range_never_prints_the_same_speed_twice():
    assert fmt_speed_range(0.0, 0.4) == "0\u00a0r/min"
    assert fmt_speed_range(598, 4803.2) == "598\u20134\u00a0803\u00a0r/min"
    summary = pd.DataFrame(
        {
            "run_id": ["idle#1"],
            "role": ["validation_other"],
            "speed_rpm": [0.0],
            "duration_s": [3600.0],
            "n_samples": [240],
            "max_abs_before_um": [4.0],
            "max_abs_after_um": [1.0],
            "improvement_pct": [75.0],
            "rmse_before_um": [2.0],
            "rmse_after_um": [0.5],
            "n_outside_temp_range": [0],
            "n_outside_speed_range": [0],
        }
    )
    resid = pd.DataFrame({"run_id": ["idle#1"] * 3, "t_s": [0, 15, 30], "speed_rpm": [0.0, 0.3, 0.1]})
    v = section_validation({"validation_summary": summary, "residuals": resid}, _Figs())
    assert v["multi"][0]["speed"] == "0\u00a0r/min"  # without runs.csv: its samples' range, printed once
    assert "speed 0\u00a0r/min with 0 speed change(s)" in _section("validation", validation=v)


# --------------------------------------------------------------------------- equilibrium flags


def _eq_res(rows: list[dict], spans: dict) -> dict:
    eq = pd.DataFrame(rows)
    runs = pd.DataFrame({"run_id": list(spans), "start_s": [0.0] * len(spans), "end_s": list(spans.values())})
    return {"equilibrium": eq, "runs_csv": runs}


def _eq_row(run_id, speed, t_eq, tau, t_eq_tau):
    return {
        "run_id": run_id,
        "speed_rpm": speed,
        "t_eq_s": t_eq,
        "t_eq_low_s": 0.9 * t_eq,
        "t_eq_high_s": 1.1 * t_eq,
        "tau_s": tau,
        "t_eq_tau_s": t_eq_tau,
        "plateau_um": 10.0,
        "paper_t_eq_s": np.nan,
        "method": "band",
    }


def test_equilibrium_flags_disagreement_and_a_fit_at_its_bound():
    settings = machine_settings({}, "m")
    rows = [
        _eq_row("a", 3000.0, 11970.0, 537.8, 1611.0),  # factor 7.4: flagged
        _eq_row("b", 6000.0, 6000.0, 1500.0, 4494.0),  # factor 1.34: not flagged
        _eq_row("c", 9000.0, 9000.0, 2154680.0, 6455000.0),  # tau at 50 x span (43 093.6 s)
    ]
    eq = section_equilibrium(_eq_res(rows, {"a": 14400.0, "b": 14400.0, "c": 43093.6}), _Figs(), settings)
    assert len(eq["flags"]) == 2
    bound, apart = eq["flags"]
    assert "9\u00a0000\u00a0r/min" in bound and "upper bound" in bound
    assert "3\u00a0000\u00a0r/min" in apart and "factor 7.43" in apart and "6\u00a0000" not in apart
    html = _section("equilibrium", equilibrium=eq)
    (table,) = html_tables(html, "num")
    cells = [[c["text"] for c in r] for r in table["rows"]]
    assert cells[0][1].endswith("\u2020") and table["rows"][0][1]["cls"] == "fail"
    assert not cells[1][1].endswith("\u2020") and table["rows"][1][1]["cls"] == ""
    assert "2\u00a0154\u00a0680" not in " ".join(cells[2]) and cells[2][4] == "at upper bound"
    assert [c["cls"] for c in table["rows"][2][3:5]] == ["fail", "fail"]
    text = _text(html)
    assert "Flagged" in text and "factor of 2" in text
    assert "paper" not in text.replace("the paper's reference", "").replace("the paper's method", "")


def test_equilibrium_says_why_a_run_has_no_t_eq_and_flags_a_tau_time_beyond_the_run():
    """FL_THERMAL ch3 and ch1 (issue 46's audit): equilibrium.csv says why a run has no t_eq, and a
    t_eq from the fitted tau longer than the run is an extrapolation of the fit, not a time seen."""
    never = "band: ...; times from the spindle start; never settled inside the band before the end of the run"

    def row(run_id, speed, t_eq, low, high, tau, method="band: ...; times from the spindle start"):
        r = _eq_row(run_id, speed, t_eq, tau, tau * np.log(20.0))
        return {**r, "t_eq_low_s": low, "t_eq_high_s": high, "method": method}

    rows = [
        row("data#2", 1250.0, np.nan, 14385.0, np.nan, 7058.9, never),  # tau t_eq 21 147 s
        row("data#4", 2500.0, np.nan, np.nan, np.nan, 3552.2, never),  # tau t_eq 10 642 s: inside
        row("data#8", 5000.0, 10500.0, 9600.0, np.nan, 5198.2),  # tau t_eq 15 572 s
    ]
    spans = {"data#2": 14385.0, "data#4": 14385.0, "data#8": 14385.0}
    eq = section_equilibrium(_eq_res(rows, spans), _Figs(), machine_settings({}, "m"))
    t = eq["table"]
    assert [r["no_t_eq"] for r in t] == [
        "never settled inside the band before the end of the run",
        "never settled inside the band before the end of the run",
        None,
    ]
    assert [r["beyond"] for r in t] == [True, False, True]
    assert [r["tau_flagged"] for r in t] == [True, False, True]
    gaps, beyond = eq["flags"]
    assert "1\u00a0250\u00a0r/min and 2\u00a0500\u00a0r/min" in gaps
    assert "never settled inside the band" in gaps
    assert "21\u00a0147\u00a0s" in beyond and "15\u00a0572\u00a0s" in beyond and "10\u00a0642" not in beyond
    assert "14\u00a0385\u00a0s" in beyond and "extrapolat" in beyond
    html = _section("equilibrium", equilibrium=eq)
    (table,) = html_tables(html, "num")
    cells = [[c["text"] for c in r] for r in table["rows"]]
    assert cells[0][1] == "not settled" and cells[0][2] == "14\u00a0385\u00a0s \u2013 not settled"
    assert cells[1][2] == "not settled" and cells[2][2] == "9\u00a0600\u00a0s \u2013 not settled"
    assert [r[3]["cls"] for r in table["rows"]] == ["fail", "", "fail"]
    assert [r[1]["cls"] for r in table["rows"]] == ["fail", "fail", ""]
    assert "\u2013\u2013" not in html


def test_the_reason_equilibrium_table_writes_is_the_one_the_report_shows():
    from rafi.method.equilibrium import equilibrium_table

    t = np.arange(0.0, 4 * 3600.0, 15.0)
    dz = 10 * (1 - np.exp(-t / 1200.0))
    dz[t >= t[-1] - 300] += 5.0  # the last 5 min leave the band: it never settles
    frame = pd.DataFrame({"run_id": "r", "t_s": t, "dz_um": dz, "speed_rpm": 3000.0})
    runs = pd.DataFrame({"run_id": ["r"], "role": ["training"], "speed_rpm": [3000.0]})
    eq = equilibrium_table(runs, frame)
    assert np.isnan(eq["t_eq_s"].iloc[0])
    res = _eq_res(eq.to_dict("records"), {"r": float(t[-1])})
    (row,) = section_equilibrium(res, _Figs(), machine_settings({}, "m"))["table"]
    assert row["no_t_eq"] == "never settled inside the band before the end of the run"
    assert row["t_eq"] == "not settled"


def test_the_equilibrium_method_states_t_eq_from_tau_as_an_equation():
    """The cross-check's formula: t_eq = tau ln(1/band), as the table computes it."""
    eqs = {"smooth_window_s": 300, "band_fraction": 0.05, "plateau_window_s": 1800}
    text = equilibrium_description(eqs)
    assert "t_eq = \u03c4 ln(1/0.05)" in text
    assert "from \u03c4 = \u03c4" not in text  # was "t_eq from \u03c4 = \u03c4 ln(1/0.05)"


def test_a_ramp_drives_the_real_fit_to_the_bound_the_report_checks():
    t = np.arange(0.0, 4 * 3600.0, 15.0)
    _, _, tau = first_order_fit(t, 1e-3 * t)  # a straight ramp: no time constant
    assert tau_at_bound(tau, t[-1]) == "upper"
    assert tau == pytest.approx(TAU_MAX_SPANS * t[-1], rel=1e-3)
    _, _, tau = first_order_fit(t, 10 * (1 - np.exp(-t / 1200.0)))
    assert tau == pytest.approx(1200.0, rel=1e-3) and tau_at_bound(tau, t[-1]) is None


# --------------------------------------------------------------------------- figures


def test_heatmap_text_colour_follows_the_cell(kept_figures):
    names = [f"T{i}" for i in range(1, 9)]
    vals = np.linspace(0.2, 1.0, 8)
    plots.fig_correlation_heatmap(
        pd.DataFrame([vals], index=["3000"], columns=names), threshold=0.97, chosen=[]
    )
    (fig,) = kept_figures
    ax = fig.axes[0]
    im = ax.get_images()[0]
    assert len(ax.texts) == len(vals)
    for text in ax.texts:
        x = int(round(text.get_position()[0]))
        # WCAG 2 contrast ratio of black and of white text on the cell: the larger one wins
        lin = [
            c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in im.cmap(im.norm(vals[x]))[:3]
        ]
        lum = 0.2126 * lin[0] + 0.7152 * lin[1] + 0.0722 * lin[2]
        best = "black" if (lum + 0.05) / 0.05 > 1.05 / (lum + 0.05) else "white"
        assert text.get_color() == best, (vals[x], text.get_color())
    # the old rule (white below the threshold) put white on light cells
    assert [t.get_color() for t in ax.texts][5] == "black"
    assert (
        plot_layout.text_colour((1.0, 1.0, 0.6)) == "black"
        and plot_layout.text_colour((0.1, 0.0, 0.3)) == "white"
    )


def _boxes(fig):
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    return r, fig.bbox


def test_legends_are_outside_the_axes(kept_figures):
    t = np.arange(0.0, 3600.0, 15.0)
    f = pd.DataFrame(
        {
            "t_s": t,
            "speed_rpm": np.where(t < 1800, 3000.0, 6000.0),
            "measured_um": np.sqrt(t),
            "predicted_um": np.sqrt(t) + 0.1,
            "residual_um": -0.1 * np.ones_like(t),
            "T1": 20 + t / 600,
            "T2": 20 + t / 500,
            "T3": 20 + t / 700,
            "T13": 20 + t / 6000,
        }
    )
    plots.fig_multi_condition(f, temp_sensors=["T1", "T2", "T3", "T13"], n_key=3)
    fits = {
        s: pd.DataFrame({"t_s": t, "measured_um": np.sqrt(t), "fitted_um": np.sqrt(t)}) for s in (3000, 6000)
    }
    plots.fig_fit_residuals(fits)
    for fig in kept_figures:
        renderer, _ = _boxes(fig)
        assert all(ax.get_legend() is None for ax in fig.axes)
        assert fig.legends
        for leg in fig.legends:
            lb = leg.get_window_extent(renderer)
            for ax in fig.axes:
                assert not lb.overlaps(ax.get_window_extent(renderer))
    labels = [t.get_text() for t in kept_figures[0].legends[0].get_texts()]
    assert "T13 (coolant)" in labels and "T1" in labels


def test_panel_titles_fit_their_panel_and_the_page(kept_figures):
    t = np.arange(0.0, 3600.0, 15.0)
    frame = pd.DataFrame({"t_s": t, "measured_um": np.sqrt(t), "residual_um": np.zeros_like(t)})
    labels = [
        f"thermal_log_2026-10-14#{k}: {v} \u2192 1.8 \u00b5m" for k, v in ((10, 14.7), (12, 11.2), (17, 3.8))
    ]
    plots.fig_validation_single(dict.fromkeys(labels, frame))
    plots.fig_validation_single(
        {f"{lab}: 12 500 r/min": frame for lab in ("valid_04500rpm", "valid_08000rpm")}
    )
    for fig in kept_figures:
        renderer, page = _boxes(fig)
        titles = [
            ax.title.get_window_extent(renderer) for ax in fig.axes if ax.get_visible() and ax.get_title()
        ]
        assert titles
        for k, a in enumerate(titles):
            assert page.x0 - 0.5 <= a.x0 and a.x1 <= page.x1 + 0.5 and a.y1 <= page.y1 + 0.5
            for b in titles[k + 1 :]:
                assert not a.overlaps(b)
        for ax in fig.axes:
            if ax.get_visible():
                a = ax.title.get_window_extent(renderer)
                assert not a.overlaps(ax.get_window_extent(renderer))
                assert not any(a.overlaps(leg.get_window_extent(renderer)) for leg in fig.legends)


def test_the_defaults_the_appendix_compares_with_are_the_settings_module():
    # machine_settings of an empty config is the defaults: nothing differs
    assert settings_changes(machine_settings({}, "m")) == []
    changed = machine_settings({"machines": {"m": {"qualification": {"max_residual_um": 9.0}}}}, "m")
    assert settings_changes(changed) == [
        {"key": "qualification.max_residual_um", "value": "9.0", "default": "12.0"}
    ]
    assert MACHINE_DEFAULTS["qualification"]["max_residual_um"] == 12.0


def _png_grey(data: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(data)).convert("L"))


def test_training_figure_labels_stay_inside_the_figure_and_apart():
    """Read from the PNG itself: nothing drawn on the outermost pixels, and a blank pixel column
    between the two columns of panels (the right dz label of one, the temperature label of the
    next)."""
    t = np.arange(0.0, 4 * 3600.0, 15.0)
    rise = {1250: (-0.4, 7.4), 2500: (2.4, 13.6), 3750: (3.5, 14.6), 5000: (-1.2, 16.0)}
    runs = {
        s: pd.DataFrame(
            {
                "t_s": t,
                "T8": 20 + 4 * (1 - np.exp(-t / 1500)),
                "T9": 20 + 3 * (1 - np.exp(-t / 1500)),
                "dz_um": lo + (hi - lo) * (1 - np.exp(-t / 1200)),
            }
        )
        for s, (lo, hi) in rise.items()
    }
    grey = _png_grey(plots.fig_training_runs(runs, temp_sensors=["T8", "T9"], eq_times={}, n_key=2))
    assert (grey[:, :2] > 250).all() and (grey[:, -2:] > 250).all()
    assert (grey[:2, :] > 250).all() and (grey[-2:, :] > 250).all()
    h, w = grey.shape
    middle = grey[int(0.12 * h) :, int(0.4 * w) : int(0.6 * w)]  # below the legend
    assert (middle > 250).all(axis=0).any()


# --------------------------------------------------------------------------- held at the envelope's edge


def _held_fixture_html(tmp_path: Path, *, held: bool) -> tuple[str, pd.DataFrame, pd.DataFrame]:
    """The fixture's report; ``held``: with the envelope flags of issue 46 added as the pipeline
    writes them (``n_outside_envelope`` in validation/summary.csv, ``outside_envelope`` in
    comparison/residuals.parquet: set for model dynamic above 10 000 r/min, one such sample
    without a measurement). Returns the HTML and the two edited tables."""
    results = copy_fixture(tmp_path)
    summary = pd.read_csv(results / "validation" / "summary.csv")
    resid = pd.read_parquet(results / "comparison" / "residuals.parquet")
    if held:
        summary["n_outside_envelope"] = np.where(
            np.arange(len(summary)) % 2 == 1, summary["n_samples"] // 3, 0
        )
        summary.to_csv(results / "validation" / "summary.csv", index=False)
        resid["outside_envelope"] = (resid["model"] == "dynamic") & (resid["speed_rpm"] > 10000)
        first = resid.index[resid["outside_envelope"]][0]
        resid.loc[first, "measured_um"] = np.nan  # not measured: not counted
        resid.to_parquet(results / "comparison" / "residuals.parquet")
    paths = write_upstream_tables(results)
    ctx = build_context(
        paths,
        empty_figure_dirs(results),
        machine="tapping-center-a",
        settings=machine_settings(CONFIG, "tapping-center-a"),
    )
    return render_html(ctx), summary, resid


def test_the_report_says_per_run_the_samples_held_at_the_envelope_edge_only_when_some_were(tmp_path):
    from rafi.report.envelope_text import MEANING

    html, summary, resid = _held_fixture_html(tmp_path / "held", held=True)
    text = _text(html)
    # validation: the runs with held samples, from validation/summary.csv, and what it means
    held = summary[summary["n_outside_envelope"] > 0]
    assert len(held) and len(held) < len(summary)
    said = "; ".join(
        f"{r.n_outside_envelope} of {r.n_samples} samples of run {r.run_id}" for r in held.itertuples()
    )
    assert f"Held at the training envelope's edge: {said}. {MEANING}" in text
    (table,) = [t for t in html_tables(html) if "held at the training envelope's edge" in t["headers"]]
    got = {r["run"]: int(r["held at the training envelope's edge"]) for r in table["records"]}
    assert got == dict(zip(summary["run_id"], summary["n_outside_envelope"]))
    # comparison: per model and run, counted over the measured samples of residuals.parquet
    ok = resid["outside_envelope"] & resid["measured_um"].notna() & resid["predicted_um"].notna()
    mine = resid[resid["model"] == "dynamic"]
    runs = [
        f"{int(ok[g.index].sum())} of {int((g['measured_um'].notna() & g['predicted_um'].notna()).sum())} "
        f"samples of run {rid}"
        for rid, g in mine.groupby("run_id", sort=False)
        if ok[g.index].any()
    ]
    assert len(runs) >= 2
    assert f"on the validation runs: dynamic on {', '.join(runs)}. {MEANING}" in text
    # the fixture as it is (a model without an envelope, tables written before the columns): nothing
    plain = _text(_held_fixture_html(tmp_path / "plain", held=False)[0])
    assert "envelope's edge" not in plain and "training envelope" not in plain


def test_the_replay_says_the_samples_held_at_the_envelope_edge_only_when_some_were():
    from rafi.report.envelope_text import MEANING
    from rafi.report.replay_section import section_replay

    settings = machine_settings(CONFIG, "tapping-center-a")
    summary = pd.DataFrame(
        {
            "model_id": ["abc"] * 3,
            "kind": ["dynamic"] * 3,
            "reference_rule": ["run_start"] * 3,
            "run_id": ["cool", "hot", "warm"],
            "log": ["a.csv", "b.csv", "c.csv"],
            "n_samples": [100, 240, 90],
            **{f"n_{s}": [0, 0, 0] for s in ("off", "referencing", "hold", "ramp")},
            "n_ok": [100, 240, 90],
            "n_clamped": [0, 0, 0],
            "n_rate_limited": [0, 0, 0],
            "n_fault": [0, 0, 0],
            "n_outside_range": [0, 0, 0],
            "n_outside_envelope": [0, 173, 4],
            "faults": ["", "", ""],
            "max_abs_command_minus_model_um": [0.0] * 3,
            "max_abs_measured_um": [9.0] * 3,
            "max_abs_residual_model_um": [1.0] * 3,
            "max_abs_residual_um": [1.0] * 3,
        }
    )
    ids = ("replay",)
    base = {"section_by_id": {s: {"id": s, "number": 1, "title": s} for s in ids}, "fig_replay0": 0}

    def text(s):
        rp = section_replay({"replay_summary": s}, settings, _Figs(), None)
        return _text(_section("replay", replay=rp, **base))

    said = (
        "held at its training envelope's edge on 173 of 240 samples of run hot; 4 of 90 samples of run warm."
    )
    assert said in text(summary) and MEANING in text(summary)
    for quiet in (summary.assign(n_outside_envelope=0), summary.drop(columns="n_outside_envelope")):
        assert "envelope" not in text(quiet)
