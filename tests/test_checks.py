"""Plausibility checks (rafi.readers.checks.check_log): thresholds and what they leave alone."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from rafi import SENSORS
from rafi.errors import RawFormatError
from rafi.readers.checks import check_log

OC = [-999.0, 999.9, 850.0]


def frame(n=200, period_s=5.0, seed=1) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    times = pd.date_range("2026-03-01T08:00:00", periods=n, freq=f"{period_s}s")
    f = pd.DataFrame({"time": times.astype("datetime64[ns]")})
    f["speed_rpm"] = 6000.0
    for i, s in enumerate(SENSORS):
        f[s] = 21 + 0.1 * i + np.linspace(0, 5, n) + rng.normal(0, 0.02, n)
    f["disp_um"] = np.round(np.linspace(0, 30, n) + rng.normal(0, 0.1, n), 3)
    f.index = pd.Index(np.arange(n) + 3, name="line")  # two metadata lines + header
    f.attrs.update(metadata={"sample_period_s": period_s}, source="raw/m/log.csv", sha256="0")
    return f


def check(f, **kw):
    kw.setdefault("open_circuit_values", OC)
    return check_log(f, "raw/m/log.csv", **kw)


def test_valid_log_passes_and_is_returned_unchanged():
    f = frame()
    assert check(f, min_run_s=900) is f


def test_adjacent_swap_and_duplicates_are_left_for_cleaning():
    f = frame()
    t = f["time"].to_numpy().copy()
    t[[10, 11]] = t[[11, 10]]
    t[50] = t[49]
    f["time"] = t
    check(f)


@pytest.mark.parametrize("back_samples, fails", [(3, False), (3.2, True), (4, True)])
def test_backwards_threshold_is_three_samples(back_samples, fails):
    f = frame()
    t = f["time"].to_numpy().copy()
    t[100:] = t[100:] - np.timedelta64(int((back_samples + 1) * 5000), "ms")  # step = -back
    f["time"] = t
    if fails:
        with pytest.raises(RawFormatError, match="clock reset") as info:
            check(f)
        assert info.value.line == 103 and info.value.column == "time"
    else:
        check(f)


def test_sample_period_is_inferred_when_not_given():
    f = frame(period_s=1.0)
    f.attrs["metadata"] = {}
    t = f["time"].to_numpy().copy()
    t[100:] = t[100:] - np.timedelta64(10, "s")
    f["time"] = t
    with pytest.raises(RawFormatError, match="more than 3 samples of 1 s"):
        check(f)
    check(f, sample_period_s=5.0)  # a 9 s step back is under 3 x 5 s


def test_too_short():
    with pytest.raises(RawFormatError, match="995 s, shorter than the minimum run of 1800 s"):
        check(frame(), min_run_s=1800)
    check(frame(), min_run_s=0)


def test_open_circuit_values_are_allowed_and_count_as_missing():
    f = frame()
    f.loc[f.index[5], "T3"] = 850.0
    f.loc[f.index[6], "T4"] = -999.0
    check(f)
    with pytest.raises(RawFormatError, match=r"temperature 850 deg C is outside.*\(none configured"):
        check(f, open_circuit_values=[])
    f["T7"] = 999.9
    with pytest.raises(RawFormatError, match="T7 has no value.*open-circuit") as info:
        check(f)
    assert info.value.column == "T7"


@pytest.mark.parametrize("value, ok", [(-40.0, True), (200.0, True), (-40.5, False), (200.1, False)])
def test_temperature_range_edges(value, ok):
    f = frame()
    f.loc[f.index[9], "T16"] = value
    if ok:
        check(f)
    else:
        with pytest.raises(RawFormatError, match="outside -40..200") as info:
            check(f)
        assert info.value.line == 12 and info.value.column == "T16"


@pytest.mark.parametrize("speed, ok", [(0.0, True), (100_000.0, True), (-1.0, False), (100_001.0, False)])
def test_speed_limits(speed, ok):
    f = frame()
    f.loc[f.index[4], "speed_rpm"] = speed
    if ok:
        check(f)
    else:
        with pytest.raises(RawFormatError, match="r/min is") as info:
            check(f)
        assert info.value.line == 7 and info.value.column == "speed_rpm"


def test_stuck_probe_by_std_and_by_identical_fraction():
    f = frame()
    f["disp_um"] = 5.0 + np.arange(len(f)) * 1e-7  # std far below 1e-3 um
    with pytest.raises(RawFormatError, match="is constant"):
        check(f)
    f = frame()
    f.loc[f.index[:195], "disp_um"] = 3.0  # 97.5 % identical
    with pytest.raises(RawFormatError, match="98 % of the values equal 3"):
        check(f)
    f = frame()
    f.loc[f.index[:180], "disp_um"] = 3.0  # 90 %: a long standstill is fine ...
    for s in SENSORS:  # ... when the machine is at rest
        f.loc[f.index[:180], s] = 21.0
    check(f)


def test_few_values_are_not_judged_stuck():
    f = frame(n=8)
    f["disp_um"] = 1.0
    check(f)


def test_millimetres_are_spotted_only_when_temperatures_rise():
    f = frame()
    f["disp_um"] = f["disp_um"] / 1000
    with pytest.raises(RawFormatError, match="values look like millimetres; set displacement.unit: mm"):
        check(f)
    for s in SENSORS:  # no heating: small movement is fine
        f[s] = 21.0 + np.random.default_rng(0).normal(0, 0.05, len(f))
    check(f)


def test_all_nan_column():
    f = frame()
    f["speed_rpm"] = np.nan
    with pytest.raises(RawFormatError, match="speed_rpm has no value in any of the 200 rows") as e:
        check(f)
    assert e.value.line is None and e.value.column == "speed_rpm"


def test_mapped_frames_name_the_header_and_sheet():
    f = frame()
    f.attrs["metadata"] = {
        "sample_period_s": 5.0,
        "sheet": "Messdaten",
        "columns": {"T4": "Temperatur 4 [°C]", "disp_um": "Verlagerung Z1 [µm]"},
    }
    f.loc[f.index[2], "T4"] = 500.0
    with pytest.raises(RawFormatError) as info:
        check_log(f, "b.xlsx", open_circuit_values=OC)
    msg = str(info.value)
    assert msg.startswith(
        "b.xlsx, sheet 'Messdaten', row 5, column 'T4': T4 (header 'Temperatur 4 [°C]'): temperature 500"
    )


def test_default_path_is_the_source():
    f = frame()
    f["T2"] = np.nan
    with pytest.raises(RawFormatError, match=r"^raw/m/log.csv, column 'T2'"):
        check_log(f)


def test_probe_stuck_mid_run_is_rejected_with_its_lines(tmp_path):
    import numpy as np
    import pandas as pd

    from rafi.errors import RawFormatError
    from rafi.readers.checks import check_log

    n = 720
    t = pd.date_range("2026-03-01T08:00:00", periods=n, freq="5s")
    rng = np.random.default_rng(3)
    frame = pd.DataFrame(
        {
            "time": t,
            "speed_rpm": 3000.0,
            **{f"T{i}": 21 + np.linspace(0, 4 + 0.1 * i, n) for i in range(1, 17)},  # distinct sensors
            "disp_um": np.round(np.linspace(0, 12, n) + rng.normal(0, 0.2, n), 3),
        },
        index=pd.Index(np.arange(n) + 3, name="line"),
    )
    check_log(frame, "ok.csv", sample_period_s=5)  # a live probe passes
    frame.loc[frame.index[500] :, "disp_um"] = frame["disp_um"].iloc[500]
    with pytest.raises(RawFormatError, match=r"stuck at .* for 220 rows") as err:
        check_log(frame, "stuck.csv", sample_period_s=5)
    assert err.value.line == 503 and err.value.column == "disp_um"
