"""``input.time.timezone``: a logger's local clock across a daylight-saving change. With the key a
fall-back repeats no time and a spring-forward leaves no false gap; without it the backwards jump
is worded as a daylight-saving change naming the key and the raw file; ``rafi init`` proposes the
key with a CHECK."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from rafi import SENSORS
from rafi.errors import InputSpecError, RawFormatError
from rafi.method.clean import clean_log
from rafi.ops.init_config import config_block, parse_block
from rafi.ops.init_survey import survey
from rafi.readers.checks import check_file
from rafi.readers.infer_files import read_unknown_logs
from rafi.readers.input_spec import normalise_input_spec
from rafi.readers.logs import read_log
from rafi.twin.synthetic_logs import schedule_log

ZONE = "Europe/Berlin"

#: UTC spans of a 60 s log across each change of 2026 in Berlin (29 March, 25 October).
SPANS = {
    "spring_forward": ("2026-03-28T20:00:00", "2026-03-29T04:00:00"),
    "fall_back": ("2026-10-24T20:00:00", "2026-10-25T04:00:00"),
}


def local_log(
    path: Path, change: str, zone: str = ZONE, header: str = "time", span: tuple | None = None
) -> pd.DatetimeIndex:
    """A log at 60 s whose times are the local clock of ``zone`` (naive text), over ``span`` (UTC;
    default ``SPANS[change]``); its UTC times."""
    utc = pd.date_range(*(span or SPANS[change]), freq="60s", tz="UTC")
    frame, _ = schedule_log([(0, 600), (3000, len(utc) * 60 - 600)], period_s=60.0, seed=1)
    frame = frame.iloc[: len(utc)].copy()
    frame["time"] = utc.tz_convert(zone).tz_localize(None).strftime("%Y-%m-%d %H:%M:%S")
    out = frame[["time", "speed_rpm", *SENSORS, "disp_um"]].round(3).rename(columns={"time": header})
    out.to_csv(path, index=False)
    return utc.tz_localize(None)


def spec(**time) -> dict:
    return {"format": "csv", "time": {"kind": "timestamp", **time}}


@pytest.mark.parametrize("change", sorted(SPANS))
def test_local_times_across_a_change_read_as_utc(tmp_path, change):
    path = tmp_path / f"{change}.csv"
    utc = local_log(path, change)
    frame = read_log(path, spec(timezone=ZONE))
    assert (frame["time"].to_numpy() == utc.to_numpy()).all()
    steps = np.diff(frame["time"].to_numpy()).astype("timedelta64[s]").astype(int)
    assert (steps == 60).all()  # no time repeated, no gap
    cleaned, audit = clean(frame, path)
    assert cleaned["segment"].nunique() == 1 and len(cleaned) == len(frame)
    assert not set(audit["action"]) & {"gap_split", "duplicate_dropped", "reordered"}


def clean(frame: pd.DataFrame, path: Path):
    """The pipeline's cleaning of a 60 s log read from ``path``."""
    return clean_log(
        frame,
        file=path.name,
        sample_period_s=60.0,
        max_interpolate_gap_s=120.0,
        spike_threshold=8.0,
        open_circuit_values=[],
    )


def test_without_the_key_the_fall_back_names_the_raw_file_and_the_key(tmp_path):
    folder = tmp_path / "raw" / "m"
    folder.mkdir(parents=True)
    path = folder / "log.csv"
    local_log(path, "fall_back")
    frame = read_log(path, spec())
    line = 2 + int(
        (pd.Timestamp("2026-10-25T01:00:00") - pd.Timestamp(SPANS["fall_back"][0])).total_seconds() // 60
    )
    with pytest.raises(RawFormatError) as info:
        clean(frame, path)
    message = str(info.value)
    assert message.startswith(f"{path}, line {line}, column 'time': timestamps go backwards by 3540 s")
    assert "a daylight-saving change? set input.time.timezone" in message
    with pytest.raises(RawFormatError, match="daylight-saving change.*input.time.timezone") as info:
        check_file(frame, path, sample_period_s=60.0)
    assert info.value.check == "clock_reset" and info.value.line == line


def test_a_clock_reset_is_not_called_daylight_saving(tmp_path):
    path = tmp_path / "log.csv"
    local_log(path, "spring_forward")
    frame = read_log(path, spec())
    frame.loc[frame.index >= 200, "time"] -= pd.Timedelta(hours=5)
    with pytest.raises(RawFormatError) as info:
        clean(frame, path)
    assert "a clock reset? split the file" in str(info.value) and "daylight" not in str(info.value)


def test_an_offset_with_a_timezone_is_refused(tmp_path):
    path = tmp_path / "log.csv"
    path.write_text(
        "time,speed_rpm,"
        + ",".join(SENSORS)
        + ",disp_um\n"
        + "\n".join(f"2026-03-02T06:0{k}:00+01:00,0," + ",".join(["20"] * 16) + ",0" for k in range(5)),
        encoding="utf-8",
    )
    with pytest.raises(RawFormatError, match="line 2, column 'time': .* carries a UTC offset"):
        read_log(path, spec(timezone=ZONE))


@pytest.mark.parametrize(
    "time, fragment",
    [
        ({"timezone": "Europe/Berln"}, "'Europe/Berln' is not a time zone name; expected an IANA name"),
        ({"timezone": 1}, "1 is not a time zone name"),
        ({"kind": "elapsed_s", "timezone": ZONE}, "applies to time.kind timestamp only"),
    ],
)
def test_a_bad_timezone_is_a_one_line_config_error(time, fragment):
    with pytest.raises(InputSpecError, match=f"^input.time.timezone: {fragment}") as info:
        normalise_input_spec(spec(**time))
    assert "\n" not in str(info.value)


def test_init_proposes_the_timezone_commented_with_a_check(tmp_path):
    path = tmp_path / "log.csv"
    local_log(path, "fall_back", header="Zeitstempel")  # a csv of its own layout, not the native one
    s = survey("m", read_unknown_logs(path))
    assert s.clock_back is not None and s.clock_back[2] == 3540
    assert any(c.startswith("input.time.timezone:") and "daylight-saving" in c for c in s.checks)
    assert s.period_s == 60.0 and s.regular_share == 1.0
    block = config_block(s)
    assert '# timezone: "Europe/Berlin"' in block
    assert "CHECK: the clock of log.csv goes back by 3540 s" in block
    entry = parse_block(block, "m")
    assert "timezone" not in entry["input"]["time"]  # the user gives it


def test_init_proposes_the_zone_whose_clocks_go_back_on_that_day(tmp_path):
    """A US logger's fall-back (1 November 2026) proposes America/New_York, not Europe/Berlin,
    whose clocks went back a week before; the zone proposed reads the log right."""
    path = tmp_path / "log.csv"
    us_fall_back = ("2026-10-31T20:00:00", "2026-11-01T12:00:00")
    utc = local_log(path, "us", zone="America/New_York", header="Zeitstempel", span=us_fall_back)
    s = survey("m", read_unknown_logs(path))
    assert s.clock_back_zone == "America/New_York"
    block = config_block(s)
    assert '# timezone: "America/New_York"' in block
    assert "America/New_York's clocks go back that day" in block
    entry = parse_block(block, "m")
    entry["input"]["time"]["timezone"] = "America/New_York"
    frame = read_log(path, normalise_input_spec(entry["input"]))
    assert frame["time"].tolist() == list(utc)
