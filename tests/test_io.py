"""Native reader, writers and atomic helpers (rafi.readers.native, rafi.readers.logs, rafi.artefact)."""

from __future__ import annotations

import hashlib

import numpy as np
import pandas as pd
import pytest

from rafi import REQUIRED_COLUMNS, SENSORS
from rafi.artefact import (
    atomic_path,
    write_bytes_atomic,
    write_csv_atomic,
    write_parquet_atomic,
    write_text_atomic,
)
from rafi.errors import RawFormatError
from rafi.readers.logs import read_log, sha256_file
from rafi.readers.native import contract_violations, format_raw_log, read_raw_log, write_raw_log
from rafi.readers.parsing import split_lines


def make_frame(n=20, start="2026-03-01T08:00:00", period_s=5, seed=0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    times = pd.date_range(start, periods=n, freq=f"{period_s}s").astype("datetime64[ns]")
    frame = pd.DataFrame({"time": times})
    frame["speed_rpm"] = 3000.0
    for i, s in enumerate(SENSORS):
        frame[s] = np.round(21 + 0.1 * i + np.linspace(0, 4, n) + rng.normal(0, 0.01, n), 2)
    frame["disp_um"] = np.round(np.linspace(0, 20, n), 3)
    return frame


def write(tmp_path, text, name="log.csv"):
    path = tmp_path / name
    path.write_bytes(text.encode("utf-8") if isinstance(text, str) else text)
    return path


def test_round_trip_with_metadata_and_extra_columns(tmp_path):
    frame = make_frame()
    frame["coolant_c"] = 19.5
    frame["note"] = ["a"] * len(frame)
    frame.loc[3, "T4"] = np.nan
    meta = {"machine": "m", "run_id": "r1", "sample_period_s": 5, "notes": "x\ny"}
    path = tmp_path / "log.csv"
    write_raw_log(frame, path, metadata=meta, decimals={"coolant_c": 1})
    got = read_raw_log(path)
    assert contract_violations(got) == []
    assert got.index[0] == 7 and got.index.name == "line"  # 6 metadata lines, header line 6
    assert got.attrs["metadata"] == {"machine": "m", "run_id": "r1", "sample_period_s": 5.0, "notes": "x\ny"}
    assert got.attrs["sha256"] == sha256_file(path)
    assert np.isnan(got["T4"].iloc[3])
    assert list(got.columns) == [*REQUIRED_COLUMNS, "coolant_c", "note"]
    assert got["coolant_c"].dtype == "float64" and got["note"].iloc[0] == "a"
    np.testing.assert_allclose(got["T1"].to_numpy(), frame["T1"].to_numpy())
    assert (got["time"].to_numpy() == frame["time"].to_numpy()).all()


def test_line_numbers_follow_the_editor(tmp_path):
    text = format_raw_log(make_frame(5), {"sample_period_s": 5})
    lines = text.splitlines()
    lines.insert(3, "")  # blank line kept in numbering
    lines[5] = lines[5] + ",,"  # will fail: extra fields
    path = write(tmp_path, "\r\n".join(lines) + "\r\n")
    with pytest.raises(RawFormatError, match=r"line 6: found 21 fields"):
        read_raw_log(path)
    # a form feed or U+2028 inside a value is not a line break for an editor
    assert split_lines("a\x0cb\u2028c\r\nd\re\n") == ["a\x0cb\u2028c", "d", "e"]


def test_bom_crlf_and_quotes_are_accepted(tmp_path):
    text = format_raw_log(make_frame(5))
    lines = text.splitlines()
    lines[2] = ",".join(f'"{v}"' for v in lines[2].split(","))
    path = write(tmp_path, b"\xef\xbb\xbf" + "\r\n".join(lines).encode() + b"\r\n")
    got = read_raw_log(path)
    assert len(got) == 5 and got.index.tolist() == [2, 3, 4, 5, 6]


def test_timezone_offsets_are_converted_to_utc(tmp_path):
    text = format_raw_log(make_frame(3)).replace("T08:00:00", "T09:00:00+01:00")
    got = read_raw_log(write(tmp_path, text))
    assert got["time"].iloc[0] == pd.Timestamp("2026-03-01T08:00:00")
    assert str(got["time"].dtype) == "datetime64[ns]"


@pytest.mark.parametrize(
    "value, fragment",
    [
        ("nan", "'nan' is not a number"),
        ("inf", "'inf' is not a number"),
        ("1,5", "decimal comma"),
    ],
)
def test_non_finite_and_bad_numbers(tmp_path, value, fragment):
    text = format_raw_log(make_frame(4))
    lines = text.splitlines()
    cells = lines[2].split(",")
    cells[5] = f'"{value}"'
    lines[2] = ",".join(cells)
    with pytest.raises(RawFormatError, match=fragment) as info:
        read_raw_log(write(tmp_path, "\n".join(lines)))
    assert info.value.line == 3 and info.value.column == "T4"


def test_metadata_errors_name_the_line(tmp_path):
    body = format_raw_log(make_frame(3))
    for value in ("five", "-5", "inf", "nan"):
        path = write(tmp_path, f"# machine: m\n# sample_period_s: {value}\n" + body)
        with pytest.raises(RawFormatError, match="line 2: metadata 'sample_period_s'"):
            read_raw_log(path)


def test_missing_file_is_a_raw_format_error(tmp_path):
    with pytest.raises(RawFormatError, match="cannot read the file"):
        read_raw_log(tmp_path / "nope.csv")


def test_read_log_dispatches_native_and_fills_sample_period(tmp_path):
    path = write(tmp_path, format_raw_log(make_frame(3)))
    got = read_log(path, {"format": "native", "pattern": "*.csv", "sample_period_s": 5})
    assert got.attrs["metadata"]["sample_period_s"] == 5.0
    path = write(tmp_path, format_raw_log(make_frame(3), {"sample_period_s": 2}), "b.csv")
    assert read_log(path, {"sample_period_s": 5}).attrs["metadata"]["sample_period_s"] == 2.0
    assert read_log(path).attrs["metadata"]["sample_period_s"] == 2.0


def test_contract_violations_detects_problems():
    frame = make_frame(3)
    frame.index = pd.Index([1, 2, 3], name="line")
    frame.attrs.update(metadata={}, source="x", sha256="0")
    assert contract_violations(frame) == []
    bad = frame.copy()
    bad.index = pd.Index([2, 2, 3], name="line")
    assert contract_violations(bad)
    bad = frame.copy()
    bad["T1"] = bad["T1"].astype("float32")
    assert contract_violations(bad)
    assert contract_violations(frame[["speed_rpm", "time"]])


# --------------------------------------------------------------------------- writers


def test_atomic_path_leaves_target_untouched_on_error(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("boom")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_writers(tmp_path):
    write_text_atomic(tmp_path / "a" / "t.txt", "x\ny")
    assert (tmp_path / "a" / "t.txt").read_bytes() == b"x\ny"
    write_bytes_atomic(tmp_path / "b.bin", b"\x00\x01")
    assert (tmp_path / "b.bin").read_bytes() == b"\x00\x01"
    frame = pd.DataFrame({"a_um": [1.0, 2.0], "b": ["x", "y"]})
    write_csv_atomic(frame, tmp_path / "c.csv")
    assert (tmp_path / "c.csv").read_text() == "a_um,b\n1.0,x\n2.0,y\n"
    write_parquet_atomic(frame, tmp_path / "d.parquet")
    pd.testing.assert_frame_equal(pd.read_parquet(tmp_path / "d.parquet"), frame)
    assert sha256_file(tmp_path / "b.bin") == hashlib.sha256(b"\x00\x01").hexdigest()


def test_format_raw_log_is_deterministic_and_has_no_negative_zero():
    frame = make_frame(3)
    frame["disp_um"] = [-0.0001, 0.0, 1.0]
    text = format_raw_log(frame)
    assert text == format_raw_log(frame)
    assert ",-0.000" not in text and text.splitlines()[1].endswith(",0.000")


def test_atomic_writes_get_normal_permissions(tmp_path):
    import os

    from rafi.artefact import write_text_atomic

    target = tmp_path / "out.txt"
    write_text_atomic(target, "x")
    mask = os.umask(0)
    os.umask(mask)
    assert (target.stat().st_mode & 0o777) == (0o666 & ~mask)
    assert not list(tmp_path.glob(".*.part"))
