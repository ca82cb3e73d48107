"""Writers of the layouts of docs/raw-format.md beyond one header row, one sheet and one file.

Each writer takes a canonical frame (:func:`canonical_frame`: time, speed_rpm, T1..T16, disp_um)
and returns what a reader must find: the mapping to read it with and the frame(s) it holds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import openpyxl
import pandas as pd

from rafi import SENSORS
from rafi.readers.input_layouts import column_label

CANONICAL = ["time", "speed_rpm", *SENSORS, "disp_um"]


def canonical_frame(n: int = 40, *, seed: int = 0, start: str = "2026-03-02 06:00", period_s: int = 60):
    """A canonical log of ``n`` rows: values with 3 decimals (exact through text), one speed."""
    rng = np.random.default_rng(seed)
    frame = pd.DataFrame({"time": pd.date_range(start, periods=n, freq=f"{period_s}s")})
    frame["speed_rpm"] = float(rng.choice([1000, 3000, 6000]))
    for k, s in enumerate(SENSORS):
        frame[s] = np.round(20 + k + np.cumsum(rng.random(n)) * 0.1, 3)
    frame["disp_um"] = np.round(np.cumsum(rng.normal(size=n)), 3)
    return frame


def _cell(value):
    return value.to_pydatetime() if isinstance(value, pd.Timestamp) else float(value)


def write_headerless_xlsx(path: Path, frame: pd.DataFrame, *, extra: int = 10, seed: int = 0) -> dict:
    """A workbook without a header row: the canonical columns in a shuffled order among ``extra``
    columns of noise (so some sit past column Z). Returns ``input.columns`` (canonical -> letter)."""
    rng = np.random.default_rng(seed)
    order = list(rng.permutation(len(CANONICAL) + extra))
    wb = openpyxl.Workbook()
    ws = wb.active
    ws.title = "Daten"
    width = len(CANONICAL) + extra
    noise = np.round(rng.random((len(frame), extra)), 3)
    for i in range(len(frame)):
        row = [None] * width
        for k, canon in enumerate(CANONICAL):
            row[order[k]] = _cell(frame[canon].iloc[i])
        for k in range(extra):
            row[order[len(CANONICAL) + k]] = float(noise[i, k])
        ws.append(row)
    wb.save(path)
    return {canon: column_label(int(order[k])) for k, canon in enumerate(CANONICAL)}


def write_headerless_csv(path: Path, frame: pd.DataFrame, *, preamble: int = 2) -> dict:
    """A csv without a header row, ``preamble`` lines of text first, columns reversed.
    Returns ``input.columns`` (canonical -> 1-based position)."""
    cols = list(reversed(CANONICAL))
    lines = [f"logger export line {k}" for k in range(preamble)]
    for i in range(len(frame)):
        cells = []
        for c in cols:
            v = frame[c].iloc[i]
            cells.append(v.strftime("%Y-%m-%d %H:%M:%S") if c == "time" else repr(float(v)))
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return {c: k + 1 for k, c in enumerate(cols)}


def write_daily_workbook(path: Path, days: int = 18, *, extra_sheets=("Notes",), seed: int = 0) -> dict:
    """A workbook of ``days`` sheets ``Tag 01`` .. (one test day each, with a header row) and the
    ``extra_sheets`` (text, not logs). Returns sheet name -> the canonical frame it holds."""
    wb = openpyxl.Workbook()
    wb.remove(wb.active)
    truth = {}
    for d in range(days):
        name = f"Tag {d + 1:02d}"
        frame = canonical_frame(40 + d, seed=seed + d, start=f"2026-03-{d + 1:02d} 06:00")
        ws = wb.create_sheet(name)
        ws.append(CANONICAL)
        for row in frame.itertuples(index=False):
            ws.append([_cell(v) for v in row])
        truth[name] = frame
    for name in extra_sheets:
        wb.create_sheet(name).append(["written by", "the test"])
    wb.save(path)
    return truth


def write_split_pair(
    folder: Path,
    frame: pd.DataFrame,
    *,
    stem: str = "0312",
    shift_s: float = 0,
    drop: int = 0,
    extra: int = 0,
) -> tuple[Path, Path]:
    """``temps_<stem>.csv`` (time, speed, T1..T16) and ``disp_<stem>.csv`` (its own clock
    ``shift_s`` later, rows in reverse order, ``drop`` rows left out from the middle, ``extra``
    rows appended after the end; headers ``Zeit`` and ``Weg [um]``)."""
    temps = frame[["time", "speed_rpm", *SENSORS]].copy()
    temps["time"] = temps["time"].dt.strftime("%Y-%m-%d %H:%M:%S")
    main = folder / f"temps_{stem}.csv"
    temps.to_csv(main, index=False)
    disp = pd.DataFrame(
        {
            "Zeit": (frame["time"] + pd.Timedelta(seconds=shift_s)).dt.strftime("%Y-%m-%d %H:%M:%S"),
            "Weg [um]": [repr(float(v)) for v in frame["disp_um"]],
        }
    )
    if drop:
        mid = len(disp) // 2
        disp = disp.drop(index=range(mid, mid + drop))
    if extra:
        last = frame["time"].iloc[-1]
        more = pd.DataFrame(
            {
                "Zeit": [
                    (last + pd.Timedelta(minutes=k + 1)).strftime("%Y-%m-%d %H:%M:%S") for k in range(extra)
                ],
                "Weg [um]": ["0.0"] * extra,
            }
        )
        disp = pd.concat([disp, more])
    partner = folder / f"disp_{stem}.csv"
    disp.iloc[::-1].to_csv(partner, index=False)
    return main, partner


def write_sheet_pair(folder: Path, days: int = 4, *, rows: int = 60, seed: int = 0) -> dict:
    """``rig_X.xlsx`` (one sheet per test day, ``Sheet1`` ..: four temperatures under their
    header, no time and no speed column) and ``rig_Y.xlsx`` (the same sheets, one column
    ``Dia Disp``: the displacement alone, smooth, starting far from 0). Returns sheet name ->
    ``(temperatures, displacement)`` arrays as written."""
    rng = np.random.default_rng(seed)
    names = ["Room", "Bed", "Motor Rear", "Motor Front"]
    wx, wy = openpyxl.Workbook(), openpyxl.Workbook()
    wx.remove(wx.active)
    wy.remove(wy.active)
    truth = {}
    for d in range(days):
        sheet = f"Sheet{d + 1}"
        n = rows + d
        warm = 1.0 - np.exp(-np.arange(n) / 25.0)
        temps = np.round(
            20.0 + d * 0.3 + np.outer(warm, [0.5, 1.0, 6.0, 4.0]) + rng.normal(0, 0.01, (n, 4)), 2
        )
        disp = np.round(40.0 + 25.0 * warm + rng.normal(0, 0.05, n), 3)
        xs, ys = wx.create_sheet(sheet), wy.create_sheet(sheet)
        xs.append(names)
        ys.append(["Dia Disp"])
        for k in range(n):
            xs.append([float(v) for v in temps[k]])
            ys.append([float(disp[k])])
        truth[sheet] = (temps, disp)
    wx.save(folder / "rig_X.xlsx")
    wy.save(folder / "rig_Y.xlsx")
    return truth


def write_table(table: pd.DataFrame, path: Path, *, sheet: str = "Log", sep: str = ",") -> Path:
    """``table`` (its headers in row 1) as an xlsx workbook of one sheet named ``sheet`` when
    ``path`` ends in ``.xlsx``, else as a csv separated by ``sep``; returns ``path``."""
    if path.suffix == ".xlsx":
        wb = openpyxl.Workbook()
        ws = wb.active
        ws.title = sheet
        ws.append(list(table.columns))
        for row in table.itertuples(index=False):
            ws.append(list(row))
        wb.save(path)
    else:
        path.write_text(table.to_csv(sep=sep, index=False), encoding="utf-8")
    return path


#: The headers of a logger that writes the time of day and the date only in the file name.
CLOCK_HEADERS = {"time": "Uhrzeit", "speed_rpm": "Drehzahl", **{s: f"Temp {s}" for s in SENSORS}}
CLOCK_HEADERS["disp_um"] = "Z [um]"


def write_time_of_day_log(path: Path, frame: pd.DataFrame, *, time_format: str = "%H:%M:%S") -> Path:
    """``frame`` under :data:`CLOCK_HEADERS` with its time of day only (text ``time_format`` in a csv,
    time cells in a workbook): the date is the file name's to give. Returns ``path``."""
    table = frame.rename(columns=CLOCK_HEADERS)
    clock = frame["time"]
    if path.suffix == ".xlsx":
        table["Uhrzeit"] = [t.to_pydatetime().time() for t in clock]
    else:
        table["Uhrzeit"] = clock.dt.strftime(time_format)
    return write_table(table, path, sheet="Daten", sep=";")
