"""Controller targets (rafi.deploy.targets): the SINUMERIK setting data and the generic files.

The expected values are computed by hand from ../shared/docs/controllers.md: SD 43900 is in
mm on a metric machine (12.3 um -> 0.0123 mm), K = K_abs + tan(beta) * (P - P0), MD 32760
caps tan(beta) (default 0.01) and the travel per interpolation cycle (factor * MD 32000).
"""

from __future__ import annotations

import csv
import json
import os

import pytest

from rafi.deploy.targets import (
    CsvFileTarget,
    DrySink,
    JsonLinesTarget,
    SinumerikAxis,
    SinumerikTarget,
    Target,
    WrittenValue,
)
from rafi.errors import RafiUserError, TargetError

ABS = "/NC/_N_AX_SEA_ACX/$SA_TEMP_COMP_ABS_VALUE[u{}]"
SLOPE = "/NC/_N_AX_SEA_ACX/$SA_TEMP_COMP_SLOPE[u{}]"
REF = "/NC/_N_AX_SEA_ACX/$SA_TEMP_COMP_REF_POSITION[u{}]"


def z_axis(**kw):
    return SinumerikAxis(**{"name": "Z", "number": 3, "sign": 1, "limit_um": 200.0, **kw})


def written(sink, node):
    return [w.value for w in sink.writes if w.node == node]


# -- SD 43900: unit, rounding, sign, layout --------------------------------------------------


@pytest.mark.parametrize(
    ("incr", "value_um", "expected_mm"),
    [
        (10000, 12.3, 0.0123),  # controllers.md: 12.3 um is 0.0123 mm (0.1 um resolution)
        (1000, 12.3, 0.012),  # default MD 10200 = 1000: 1 um resolution, 12.3 -> 12 um
        (1000, 12.5, 0.013),  # half away from zero
        (1000, -12.5, -0.013),
        (1000, 12.49, 0.012),
        (100000, -7.25, -0.00725),
        (1000, 0.4, 0.0),
        (1000, -0.4, 0.0),  # no negative zero on the controller
    ],
)
def test_sd43900_unit_and_rounding(incr, value_um, expected_mm):
    sink = DrySink()
    with SinumerikTarget([z_axis()], sink, int_incr_per_mm=incr) as target:
        target.write(0.0, {"Z": value_um}, "ok")
    assert sink.writes == [WrittenValue(ABS.format(3), expected_mm, "Double")]
    assert type(sink.writes[0].value) is float
    assert str(sink.writes[0].value) != "-0.0"


def test_sign_turns_the_written_offset():
    sink = DrySink()
    with SinumerikTarget([z_axis(sign=-1)], sink, int_incr_per_mm=10000) as target:
        target.write(0.0, {"Z": 12.3}, "ok")
        target.write(1.0, {"Z": -4.0}, "ok")
    assert written(sink, ABS.format(3)) == [-0.0123, 0.004]


def test_per_axis_layout_uses_machine_axis_numbers_in_order():
    axes = [
        SinumerikAxis("X", 1, 1, 50.0),
        SinumerikAxis("Z", 3, -1, 200.0),
        SinumerikAxis("Y", 2, 1, 50.0),
    ]
    sink = DrySink()
    with SinumerikTarget(axes, sink, int_incr_per_mm=1000) as target:
        target.write(5.0, {"Y": 2.0, "Z": 30.0, "X": 1.0}, "ok")
        assert target.required_temp_comp_type() == {1: 1, 3: 1, 2: 1}
    assert [(w.node, w.value) for w in sink.writes] == [
        (ABS.format(1), 0.001),
        (ABS.format(3), -0.03),
        (ABS.format(2), 0.002),
    ]


def test_callable_sink_and_custom_node_template():
    calls = []
    target = SinumerikTarget(
        [z_axis()],
        lambda node, value, datatype: calls.append((node, value, datatype)),
        node_template="ns=2;s=/NC/_N_AX_SEA_ACX/$SA_{data}[u{axis}]",
    )
    with target:
        target.write(0.0, {"Z": 3.0}, "ok")
    assert calls == [("ns=2;s=/NC/_N_AX_SEA_ACX/$SA_TEMP_COMP_ABS_VALUE[u3]", 0.003, "Double")]


def test_skip_unchanged_writes_only_changes():
    sink = DrySink()
    with SinumerikTarget([z_axis()], sink, skip_unchanged=True) as target:
        for t, v in enumerate([1.0, 1.2, 1.4, 2.0]):  # 1, 1, 1, 2 um at 1 um resolution
            target.write(float(t), {"Z": v}, "ok")
    assert written(sink, ABS.format(3)) == [0.001, 0.002]


# -- SD 43910 / 43920 ---------------------------------------------------------------------


def test_slope_mode_values():
    # P0 = 100 mm, the model's 20 um hold at 600 mm: tan(beta) = 0.020 mm / 500 mm = 4e-5
    axis = SinumerikAxis("X", 1, -1, 100.0, mode="slope", ref_position_mm=100.0, measured_at_mm=600.0)
    sink = DrySink()
    with SinumerikTarget([axis], sink) as target:
        assert sink.writes == [WrittenValue(REF.format(1), 100.0, "Double")]  # written on open
        target.write(0.0, {"X": 20.0}, "ok")
        target.write(1.0, {"X": -5.0}, "ok")
        assert target.required_temp_comp_type() == {1: 2}
    assert written(sink, SLOPE.format(1)) == pytest.approx([-4e-5, 1e-5], rel=1e-12)
    assert written(sink, ABS.format(1)) == []  # SD 43900 is not touched in slope mode
    # the controller's K at the measurement position is the sample's value
    k_um = 1000 * written(sink, SLOPE.format(1))[0] * (600.0 - 100.0)
    assert k_um == pytest.approx(-20.0, abs=1e-9)


def test_slope_ref_position_is_rounded_to_resolution():
    axis = SinumerikAxis("X", 1, 1, 100.0, mode="slope", ref_position_mm=-250.00049, measured_at_mm=0.5)
    sink = DrySink()
    with SinumerikTarget([axis], sink, int_incr_per_mm=1000):
        pass
    assert sink.writes == [WrittenValue(REF.format(1), -250.0, "Double")]


def test_slope_beyond_md32760_is_refused():
    # 60 um at 5 mm from P0: 0.012 > 0.01 (the controller would clip it silently)
    axis = SinumerikAxis("X", 1, 1, 100.0, mode="slope", ref_position_mm=10.0, measured_at_mm=15.0)
    sink = DrySink()
    with SinumerikTarget([axis], sink) as target:
        target.write(0.0, {"X": 50.0}, "ok")  # 0.010: at the limit, accepted
        with pytest.raises(TargetError, match="MD 32760") as err:
            target.write(1.0, {"X": 60.0}, "ok")
    assert err.value.value == pytest.approx(0.012) and err.value.limit == 0.01
    assert written(sink, SLOPE.format(1)) == [pytest.approx(0.01)]
    with SinumerikTarget([axis], DrySink(), comp_add_velo_factor=0.10) as target:
        target.write(0.0, {"X": 60.0}, "ok")  # MD 32760 set to its documented maximum


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"mode": "slope", "ref_position_mm": 0.0, "measured_at_mm": 100.0}, "axis zero"),
        ({"mode": "slope", "ref_position_mm": 50.0, "measured_at_mm": 50.0}, "no slope"),
        ({"mode": "slope", "ref_position_mm": 50.0}, "measured_at_mm"),
        ({"ref_position_mm": 50.0}, "slope' only"),
        ({"mode": "pitch"}, "mode"),
        ({"sign": 0}, "sign"),
        ({"number": 0}, "axis number"),
        ({"limit_um": 5000.0}, "limit_um"),
        ({"limit_um": float("nan")}, "limit_um"),
    ],
)
def test_axis_setup_errors(kw, match):
    with pytest.raises(TargetError, match=match):
        SinumerikTarget([z_axis(**kw)], DrySink())


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"comp_add_velo_factor": 0.2}, "MD 32760"),
        ({"comp_add_velo_factor": 0.0}, "MD 32760"),
        ({"int_incr_per_mm": 0}, "int_incr_per_mm"),
        ({"node_template": "/NC/$SA_TEMP"}, "node_template"),
        ({"ipo_cycle_s": 2.0}, "ipo_cycle_s"),
    ],
)
def test_target_setup_errors(kw, match):
    with pytest.raises(TargetError, match=match):
        SinumerikTarget([z_axis()], DrySink(), **kw)


def test_duplicate_axis_numbers_refused():
    with pytest.raises(TargetError, match="repeat"):
        SinumerikTarget([z_axis(), z_axis(name="W")], DrySink())


# -- refusals: limits, whole sample -------------------------------------------------------


def test_value_outside_the_limit_is_refused_and_nothing_of_the_sample_written():
    axes = [SinumerikAxis("X", 1, 1, 50.0), SinumerikAxis("Z", 3, 1, 200.0)]
    sink = DrySink()
    with SinumerikTarget(axes, sink) as target:
        target.write(0.0, {"X": 50.0, "Z": 200.0}, "ok")  # at the limit: accepted
        with pytest.raises(TargetError, match=r"axis Z: 200.5 um is outside .* \+-200 um") as err:
            target.write(1.0, {"X": 1.0, "Z": 200.5}, "ok")
        assert err.value.axis == "Z" and err.value.value == 200.5 and err.value.limit == 200.0
        assert isinstance(err.value, RafiUserError) and isinstance(err.value, ValueError)
        target.write(2.0, {"X": -50.0, "Z": 0.0}, "ok")
    assert written(sink, ABS.format(1)) == [0.05, -0.05]  # X=1.0 of the refused sample never sent
    assert written(sink, ABS.format(3)) == [0.2, 0.0]


@pytest.mark.parametrize(
    ("time_s", "values", "status", "match"),
    [
        (0.0, {"Z": float("nan")}, "ok", "finite"),
        (0.0, {"Z": float("inf")}, "ok", "finite"),
        (0.0, {"Z": "1.0"}, "ok", "finite"),
        (0.0, {"Z": True}, "ok", "finite"),
        (float("nan"), {"Z": 1.0}, "ok", "sample time"),
        (0.0, {}, "ok", r"missing \['Z'\]"),
        (0.0, {"Z": 1.0, "Q": 2.0}, "ok", r"unknown \['Q'\]"),
        (0.0, [1.0], "ok", "map each axis"),
        (0.0, {"Z": 1.0}, "a\nb", "one line"),
        (0.0, {"Z": 1.0}, None, "one line"),
    ],
)
def test_bad_samples_refused(tmp_path, time_s, values, status, match):
    targets = [
        SinumerikTarget([z_axis()], DrySink()),
        CsvFileTarget(tmp_path / "c.csv", ["Z"]),
        JsonLinesTarget(tmp_path / "c.jsonl", ["Z"]),
    ]
    for target in targets:
        with target, pytest.raises(TargetError, match=match):
            target.write(time_s, values, status)
        assert target.samples_written == 0
    assert targets[0].sink.writes == []
    assert (tmp_path / "c.csv").read_text() == "time_s,Z_um,status\n"
    assert (tmp_path / "c.jsonl").read_text() == ""


def test_write_outside_open_refused(tmp_path):
    target = CsvFileTarget(tmp_path / "c.csv", ["Z"])
    with pytest.raises(TargetError, match="not opened"):
        target.write(0.0, {"Z": 1.0}, "ok")
    with target:
        target.write(0.0, {"Z": 1.0}, "ok")
    with pytest.raises(TargetError, match="closed"):
        target.write(1.0, {"Z": 1.0}, "ok")
    with pytest.raises(TargetError, match="once"):
        target.open()
    target.close()  # a second close does nothing


# -- the step report (MD 32760 spread) ----------------------------------------------------


def test_ipo_cycles_of_a_step():
    # MD 32760 0.01, MD 32000 30000 mm/min = 500 mm/s, 4 ms: at most 0.02 mm per cycle
    sink = DrySink()
    axis = z_axis(max_velocity_mm_min=30000.0)
    with SinumerikTarget([axis], sink, ipo_cycle_s=0.004) as target:
        target.write(0.0, {"Z": 10.0}, "ok")
        assert target.last_report["Z"]["step"] is None
        target.write(1.0, {"Z": 30.0}, "ok")  # 0.020 mm: one cycle
        assert target.last_report["Z"]["ipo_cycles"] == 1
        target.write(2.0, {"Z": 81.0}, "ok")  # 0.051 mm: three cycles
        assert target.last_report["Z"]["step"] == pytest.approx(0.051)
        assert target.last_report["Z"]["ipo_cycles"] == 3
        target.write(3.0, {"Z": 81.0}, "ok")
        assert target.last_report["Z"]["ipo_cycles"] == 0


# -- the generic file targets -------------------------------------------------------------

SAMPLES = [
    (0.0, {"X": 1.5, "Z": -12.3}, "ok"),
    (1.25, {"X": 0.1 + 0.2, "Z": 1e-300}, "hold: sensor T6 stuck"),
    (2.5, {"X": -0.0, "Z": 123456.789}, 'clamped, "rate" limit'),
]


def test_csv_file_contents_parse_back(tmp_path):
    path = tmp_path / "out" / "comp.csv"
    with CsvFileTarget(path, ["X", "Z"]) as target:
        for sample in SAMPLES:
            target.write(*sample)
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0] == ["time_s", "X_um", "Z_um", "status"]
    parsed = [(float(t), {"X": float(x), "Z": float(z)}, s) for t, x, z, s in rows[1:]]
    assert parsed == SAMPLES  # exact: the shortest round-trip repr
    assert path.read_bytes().endswith(b"\n") and path.read_bytes().count(b"\n") == 4


def test_jsonl_file_contents_parse_back(tmp_path):
    path = tmp_path / "comp.jsonl"
    with JsonLinesTarget(path, ["X", "Z"]) as target:
        for sample in SAMPLES:
            target.write(*sample)
    lines = path.read_text(encoding="utf-8").splitlines()
    records = [json.loads(line) for line in lines]
    assert [list(r) for r in records] == [["time_s", "values_um", "status"]] * 3
    assert [(r["time_s"], r["values_um"], r["status"]) for r in records] == SAMPLES
    assert [list(r["values_um"]) for r in records] == [["X", "Z"]] * 3


def test_append_keeps_lines_and_checks_header(tmp_path):
    path = tmp_path / "comp.csv"
    with CsvFileTarget(path, ["Z"]) as target:
        target.write(0.0, {"Z": 1.0}, "ok")
    with CsvFileTarget(path, ["Z"]) as target:
        target.write(1.0, {"Z": 2.0}, "ok")
    assert path.read_text() == "time_s,Z_um,status\n0.0,1.0,ok\n1.0,2.0,ok\n"
    with pytest.raises(TargetError, match="another header"):
        CsvFileTarget(path, ["X", "Z"]).open()
    assert path.read_text().count("\n") == 3


@pytest.mark.parametrize("cls", [CsvFileTarget, JsonLinesTarget])
def test_torn_last_line_dropped_on_reopen(tmp_path, cls):
    path = tmp_path / "comp.out"
    with cls(path, ["Z"]) as target:
        target.write(0.0, {"Z": 1.0}, "ok")
    good = path.read_bytes()
    with open(path, "ab") as fh:  # a power loss in the middle of a line
        fh.write(b"1.0,2.")
    target = cls(path, ["Z"])
    with target:
        target.write(2.0, {"Z": 3.0}, "ok")
    assert target.torn_bytes_dropped == 6
    new_line = {
        CsvFileTarget: b"2.0,3.0,ok\n",
        JsonLinesTarget: b'{"time_s":2.0,"values_um":{"Z":3.0},"status":"ok"}\n',
    }[cls]
    assert path.read_bytes() == good + new_line


@pytest.mark.parametrize("cls", [CsvFileTarget, JsonLinesTarget])
def test_each_line_is_on_disk_before_close(tmp_path, cls):
    # a crash after a write leaves that write's complete line (one os.write per line)
    path = tmp_path / "comp.out"
    target = cls(path, ["Z"]).open()
    target.write(0.0, {"Z": 1.0}, "ok")
    seen = path.read_text()
    assert seen.endswith("\n") and ("1.0" in seen.splitlines()[-1])
    target.close()


class Boom(Exception):
    pass


def test_context_manager_closes_on_exception(tmp_path):
    sink = DrySink()
    csv_target = CsvFileTarget(tmp_path / "c.csv", ["Z"])
    sin_target = SinumerikTarget([z_axis()], sink)
    with pytest.raises(Boom):
        with csv_target, sin_target:
            csv_target.write(0.0, {"Z": 1.0}, "ok")
            sin_target.write(0.0, {"Z": 1.0}, "ok")
            raise Boom
    assert csv_target.closed and not csv_target.is_open and csv_target._fd is None
    assert sin_target.closed and sink.opened == 1 and sink.closed == 1
    assert (tmp_path / "c.csv").read_text() == "time_s,Z_um,status\n0.0,1.0,ok\n"


def test_context_manager_closes_on_refused_value(tmp_path):
    target = JsonLinesTarget(tmp_path / "c.jsonl", ["Z"])
    fds_before = len(os.listdir("/proc/self/fd"))
    with pytest.raises(TargetError):
        with target:
            target.write(0.0, {"Z": 1.0}, "ok")
            target.write(1.0, {"Z": float("nan")}, "ok")
    assert target.closed and len(os.listdir("/proc/self/fd")) == fds_before
    assert len((tmp_path / "c.jsonl").read_text().splitlines()) == 1


def test_every_target_is_a_target(tmp_path):
    for target in (
        CsvFileTarget(tmp_path / "a", ["Z"]),
        JsonLinesTarget(tmp_path / "b", ["Z"]),
        SinumerikTarget([z_axis()], DrySink()),
    ):
        assert isinstance(target, Target)


# -- read-back: where the controller is before the first write --------------------------------


def test_sinumerik_read_back_inverts_the_written_value_in_both_modes():
    slope_axis = SinumerikAxis("X", 1, -1, 100.0, mode="slope", ref_position_mm=100.0, measured_at_mm=600.0)
    sink = DrySink(start={ABS.format(3): 0.0068, SLOPE.format(1): -4e-5})  # the last session's values
    target = SinumerikTarget([z_axis(sign=-1), slope_axis], sink, int_incr_per_mm=100000)
    assert target.read_current_um() == pytest.approx({"Z": -6.8, "X": 20.0}, abs=1e-9)
    assert target.output_nodes() == [ABS.format(3), SLOPE.format(1), REF.format(1)]
    with target:
        target.write(0.0, {"Z": 1.25, "X": -5.0}, "ok")
        assert target.last_report["Z"]["step"] == pytest.approx(-0.0068 - 0.00125)  # from the value read
    assert target.read_current_um() == pytest.approx({"Z": 1.25, "X": -5.0}, abs=1e-9)  # the last written
    for value_um in (12.34, -7.25, 0.0):
        node, setting = target.setting_value("Z", value_um)
        assert target.value_um("Z", setting) == pytest.approx(value_um, abs=1e-9)
    assert SinumerikTarget([z_axis()], lambda *a: None).read_current_um() == {"Z": None}  # cannot read
    assert SinumerikTarget([z_axis()], DrySink()).read_current_um() == {"Z": None}  # nothing there


@pytest.mark.parametrize("cls", [CsvFileTarget, JsonLinesTarget])
def test_a_file_target_reads_back_its_last_line(tmp_path, cls):
    path = tmp_path / "out" / f"commands.{cls.name}"
    assert cls(path, ["Z", "Y"]).read_current_um() == {"Z": None, "Y": None}  # no file: not known
    with cls(path, ["Z", "Y"]) as target:
        assert target.read_current_um() == {"Z": None, "Y": None}  # a header only
        target.write(1.0, {"Z": 1.5, "Y": -2.0}, "ok")
        target.write(2.0, {"Z": -6.8, "Y": 0.25}, 'hold: T8 missing, "quoted"')
    with open(path, "a") as fh:
        fh.write('2,99,99,"torn')  # half a line (a power loss): not a value
    assert cls(path, ["Z", "Y"]).read_current_um() == {"Z": -6.8, "Y": 0.25}
