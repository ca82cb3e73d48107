"""Property tests: whatever bytes a raw file holds, the readers either return a frame that
satisfies the canonical contract or raise RawFormatError - never anything else - and the
native writer/reader pair round-trips values to the written decimals."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rafi import SENSORS
from rafi.errors import RawFormatError
from rafi.readers.checks import check_log
from rafi.readers.logs import read_log
from rafi.readers.native import DEFAULT_DECIMALS, contract_violations, format_raw_log, read_raw_log

SETTINGS = settings(
    max_examples=200, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)
WORK = Path(tempfile.mkdtemp(prefix="rafi-props-"))


def base_frame(n=12) -> pd.DataFrame:
    times = pd.date_range("2026-03-01T08:00:00", periods=n, freq="5s").astype("datetime64[ns]")
    f = pd.DataFrame({"time": times, "speed_rpm": 3000.0})
    for i, s in enumerate(SENSORS):
        f[s] = np.round(21 + 0.1 * i + np.linspace(0, 4, n), 2)
    f["disp_um"] = np.round(np.linspace(0, 20, n), 3)
    f["coolant_c"] = 19.5
    return f


NATIVE = format_raw_log(base_frame(), {"machine": "rig", "sample_period_s": 5}).encode()

# The same log in a foreign layout: ';' delimiter, decimal commas, non-ASCII headers.
MAPPED_SPEC = {
    "format": "csv",
    "delimiter": ";",
    "decimal": ",",
    "columns": {
        "time": "Zeit",
        "speed_rpm": "Drehzahl [1/min]",
        **{s: f"Temperatur {s[1:]} [°C]" for s in SENSORS},
    },
    "displacement": {"column": "Verlagerung Z1 [µm]", "unit": "um", "sign": -1},
    "time": {"kind": "timestamp"},
}


def _mapped_text() -> bytes:
    f = base_frame()
    header = [
        "Zeit",
        "Drehzahl [1/min]",
        *[f"Temperatur {s[1:]} [°C]" for s in SENSORS],
        "Verlagerung Z1 [µm]",
        "Kühlmittel [°C]",
    ]
    lines = [";".join(header)]
    for _, r in f.iterrows():
        cells = [
            r["time"].strftime("%Y-%m-%dT%H:%M:%S"),
            f"{r['speed_rpm']:.0f}",
            *[f"{r[s]:.2f}".replace(".", ",") for s in SENSORS],
            f"{-r['disp_um']:.3f}".replace(".", ","),
            "19,5",
        ]
        lines.append(";".join(cells))
    return ("\n".join(lines) + "\n").encode("utf-8")


MAPPED = _mapped_text()

INSERTS = [
    b",",
    b";",
    b'"',
    b"\x00",
    b"\n",
    b"\r",
    b"\r\n",
    b"",
    b" ",
    b"#",
    b"-",
    b".",
    b"e",
    b"nan",
    b"\xff",
    b"\xc3",
    "ü".encode(),
    "\u2028".encode(),
    "µ°".encode(),
]


@st.composite
def corruptions(draw, data: bytes) -> bytes:
    buf = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        lines = bytes(buf).split(b"\n")
        op = draw(
            st.sampled_from(
                [
                    "flip",
                    "truncate",
                    "insert",
                    "delete_line",
                    "swap_lines",
                    "dup_header",
                    "cell_text",
                    "unicode",
                ]
            )
        )
        if op == "flip" and buf:
            i = draw(st.integers(0, len(buf) - 1))
            buf[i] ^= draw(st.integers(1, 255))
        elif op == "truncate":
            buf = buf[: draw(st.integers(0, len(buf)))]
        elif op == "insert":
            i = draw(st.integers(0, len(buf)))
            buf[i:i] = draw(st.sampled_from(INSERTS))
        elif op == "unicode":
            i = draw(st.integers(0, len(buf)))
            buf[i:i] = draw(st.text(min_size=1, max_size=4)).encode("utf-8", "surrogatepass")
        elif op == "delete_line" and lines:
            del lines[draw(st.integers(0, len(lines) - 1))]
            buf = bytearray(b"\n".join(lines))
        elif op == "swap_lines" and len(lines) > 1:
            i = draw(st.integers(0, len(lines) - 1))
            j = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
            buf = bytearray(b"\n".join(lines))
        elif op == "dup_header" and lines:
            header = next((ln for ln in lines if ln and not ln.startswith(b"#")), b"")
            lines.insert(draw(st.integers(0, len(lines))), header)
            buf = bytearray(b"\n".join(lines))
        elif op == "cell_text" and lines:
            i = draw(st.integers(0, len(lines) - 1))
            sep = b";" if b";" in lines[i] else b","
            cells = lines[i].split(sep)
            j = draw(st.integers(0, len(cells) - 1))
            cells[j] = draw(
                st.sampled_from(
                    [
                        b"ERR",
                        b"n/a",
                        b"",
                        b"1e999",
                        b"--",
                        b"0x1F",
                        b"2026-13-45T99:00:00",
                        b"inf",
                        b"9" * 40,
                        b"3026-01-01T00:00:00",
                        b"'",
                        b'""',
                    ]
                )
            )
            lines[i] = sep.join(cells)
            buf = bytearray(b"\n".join(lines))
    return bytes(buf)


def _outcome(read, data: bytes, name: str):
    path = WORK / name
    path.write_bytes(data)
    try:
        frame = read(path)
    except RawFormatError as exc:
        assert str(exc).startswith(str(path)), str(exc)
        return None
    assert contract_violations(frame) == [], contract_violations(frame)
    assert path.read_bytes() == data  # never modified
    try:
        check_log(frame, path, min_run_s=0, open_circuit_values=[-999.0, 999.9, 850.0])
    except RawFormatError as exc:
        assert str(exc).startswith(str(path))
    return frame


def test_uncorrupted_examples_read():
    assert len(_outcome(read_raw_log, NATIVE, "ok.csv")) == 12
    f = _outcome(lambda p: read_log(p, MAPPED_SPEC), MAPPED, "ok_mapped.csv")
    assert len(f) == 12 and f["disp_um"].iloc[-1] == 20.0 and "kuhlmittel_c" in f.columns


@SETTINGS
@given(corruptions(NATIVE))
def test_native_reader_never_fails_otherwise(data):
    _outcome(read_raw_log, data, "native.csv")


@SETTINGS
@given(corruptions(MAPPED))
def test_mapped_csv_reader_never_fails_otherwise(data):
    _outcome(lambda p: read_log(p, MAPPED_SPEC), data, "mapped.csv")


@SETTINGS
@given(st.binary(max_size=300))
def test_arbitrary_bytes(data):
    _outcome(read_raw_log, data, "bytes.csv")
    _outcome(lambda p: read_log(p, MAPPED_SPEC), data, "bytes_mapped.csv")


# --------------------------------------------------------------------------- round trip

#: Values that stress the rounding and formatting: half-way points, tiny negatives
#: (written as "-0.000" before the writer normalises them), the range limits.
SPECIALS = [
    0.0,
    -0.0,
    0.0005,
    -0.0004,
    0.0015,
    2.675,
    1e-9,
    -1e-9,
    0.5,
    1.005,
    -40.0,
    200.0,
    199.995,
    29999.5,
    1e6,
    -123.4565,
]


@st.composite
def canonical_frames(draw):
    """Random canonical frames: bulk values from a seeded generator (fast), plus
    hypothesis-chosen special values at hypothesis-chosen cells (shrinkable)."""
    n = draw(st.integers(1, 25))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    start = draw(
        st.datetimes(
            min_value=pd.Timestamp("1990-01-01").to_pydatetime(),
            max_value=pd.Timestamp("2100-01-01").to_pydatetime(),
        )
    )
    whole_seconds = draw(st.booleans())
    steps = rng.integers(0, 10_000_000, n)  # microseconds
    if whole_seconds:
        steps = steps // 1_000_000 * 1_000_000
        start = start.replace(microsecond=0)
    times = pd.Timestamp(start) + pd.to_timedelta(np.cumsum(steps), unit="us")
    frame = pd.DataFrame({"time": pd.Series(times).astype("datetime64[ns]")})
    nan_p = draw(st.sampled_from([0.0, 0.1, 0.5, 1.0]))
    for name, (lo, hi) in [
        ("speed_rpm", (0, 30000)),
        *[(s, (-40, 200)) for s in SENSORS],
        ("disp_um", (-1000, 1000)),
    ]:
        vals = rng.uniform(lo, hi, n)
        vals[rng.random(n) < nan_p] = np.nan
        frame[name] = vals
    cols = ["speed_rpm", *SENSORS, "disp_um"]
    for _ in range(draw(st.integers(0, 5))):
        frame.iloc[draw(st.integers(0, n - 1)), 1 + draw(st.integers(0, len(cols) - 1))] = draw(
            st.sampled_from(SPECIALS)
        )
    return frame


@SETTINGS
@given(
    canonical_frames(),
    st.sampled_from([{}, {"machine": "m", "sample_period_s": 5}, {"notes": "a\nb", "run_id": "x"}]),
)
def test_format_then_read_reproduces_values(frame, meta):
    path = WORK / "roundtrip.csv"
    path.write_text(format_raw_log(frame, meta), encoding="utf-8")
    got = read_raw_log(path)
    assert contract_violations(got) == []
    assert len(got) == len(frame)
    assert (got["time"].to_numpy() == frame["time"].to_numpy()).all()
    for name, nd in DEFAULT_DECIMALS.items():
        a, b = frame[name].to_numpy(), got[name].to_numpy()
        assert (np.isnan(a) == np.isnan(b)).all(), name
        ok = ~np.isnan(a)
        assert np.all(np.abs(a[ok] - b[ok]) <= 0.5 * 10.0**-nd + 1e-9), name
    for key, value in meta.items():
        assert got.attrs["metadata"][key] == (float(value) if key == "sample_period_s" else value)
