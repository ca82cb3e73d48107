"""Property test: whatever columns a log holds, ``rafi init`` proposes a block or says in one
line why it cannot - it never stops with a traceback (a log with its date and time of day in two
columns once made it divide by a zero period)."""

from __future__ import annotations

import contextlib
import datetime as dt
import io
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from rafi.cli import main

SETTINGS = settings(
    max_examples=60, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)
WORK = Path(tempfile.mkdtemp(prefix="rafi-init-props-"))
ROWS = 120
T0 = dt.datetime(2023, 7, 1, 23, 0)


def local_time_with_offset(t: dt.datetime) -> str:
    """``t`` (UTC) as local ISO text with its offset: ``+02:00`` for the first two hours after
    :data:`T0`, then ``+01:00`` (a change of the offset within one file, as daylight saving time ends)."""
    hours = 2 if t < T0 + dt.timedelta(hours=2) else 1
    return f"{t + dt.timedelta(hours=hours):%Y-%m-%dT%H:%M:%S}+{hours:02d}:00"


def column(kind: str, seed: int) -> tuple[str, list[str]]:
    """A header and the cells of one column of ``kind``."""
    rng = np.random.default_rng(seed)
    k = np.arange(ROWS)
    stamps = [T0 + dt.timedelta(seconds=30 * int(i)) for i in k]
    cells = {
        "stamp": ("Zeitstempel", [f"{t:%d.%m.%Y %H:%M:%S}" for t in stamps]),
        "stamp_utc": ("Timestamp", [f"{t:%Y-%m-%dT%H:%M:%S}Z" for t in stamps]),
        "stamp_offset": ("Zeit", [local_time_with_offset(t) for t in stamps]),
        "date": ("Date", [f"{t:%Y-%m-%d}" for t in stamps]),
        "frozen": ("Zeit", [f"{T0:%Y-%m-%d %H:%M:%S}"] * ROWS),
        "clock": ("Time", [f"{t:%H:%M:%S}" for t in stamps]),
        "elapsed": ("t [s]", [str(30 * int(i)) for i in k]),
        "hours": ("Time (h)", [f"{i / 120:.5f}" for i in k]),
        "speed": ("n [1/min]", ["0" if i < 10 else "6000" for i in k]),
        "temp": ("T1 [°C]", [f"{22 + 8 * (1 - np.exp(-i / 40)) + rng.normal(0, 0.02):.2f}" for i in k]),
        "temp_f": ("T2 (F)", [f"{72 + 14 * (1 - np.exp(-i / 40)):.2f}" for i in k]),
        "disp": ("Z [um]", [f"{10 * (1 - np.exp(-i / 50)):.3f}" for i in k]),
        "text": ("Note", ["ok" if i % 7 else "" for i in k]),
        "noise": ("x", [f"{v:.3f}" for v in rng.normal(0, 1, ROWS)]),
        "empty": ("blank", [""] * ROWS),
        "constant": ("c", ["5"] * ROWS),
    }
    return cells[kind]


KINDS = [
    "stamp",
    "stamp_utc",
    "stamp_offset",
    "date",
    "clock",
    "elapsed",
    "hours",
    "speed",
    "temp",
    "temp_f",
    "disp",
    "text",
    "noise",
    "empty",
    "constant",
]


@SETTINGS
@example(kinds=["frozen", "speed", "temp", "disp"], seed=1, delimiter=",")  # a clock that stands still
@example(kinds=["date", "clock", "speed", "temp", "disp"], seed=2, delimiter=";")
@example(kinds=["stamp_utc", "speed", "temp", "disp"], seed=3, delimiter=",")  # aware times: a TypeError
@example(kinds=["stamp_offset", "speed", "temp", "disp"], seed=4, delimiter=";")
@given(
    kinds=st.lists(st.sampled_from(KINDS), min_size=1, max_size=6),
    seed=st.integers(0, 1000),
    delimiter=st.sampled_from([",", ";"]),
)
def test_rafi_init_proposes_or_says_why_never_a_traceback(kinds, seed, delimiter):
    folder = WORK / f"m{seed}-{'-'.join(kinds)}-{ord(delimiter)}"
    folder.mkdir(parents=True, exist_ok=True)
    cols = [column(kind, seed + j) for j, kind in enumerate(kinds)]
    headers = [f"{h} {j}" if [c[0] for c in cols].count(h) > 1 else h for j, (h, _) in enumerate(cols)]
    rows = zip(*(cells for _, cells in cols))
    text = delimiter.join(headers) + "\n" + "\n".join(delimiter.join(r) for r in rows) + "\n"
    (folder / "log.csv").write_text(text, encoding="utf-8")
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        status = main(["init", "--machine", "m", str(folder), "--config", str(WORK / "none.yaml")])
    assert status in (0, 2, 64, 65, 66), err.getvalue()
    assert "Traceback" not in err.getvalue()
