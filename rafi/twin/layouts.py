"""Real-world log layouts written by the twin (``rafi simulate layout``): machines that are not
the paper's rig, each with the truth of what it is.

A layout is a machine with its own temperature sensors (4, 6, 22 or 40 of them, named as a
plant names them) and its own files. The logs are the twin's (:func:`rafi.twin.simulate.simulate_run`)
with the sensors chosen, renamed and, beyond the twin's sixteen, derived: an extra sensor is a
low-passed mix of two of the twin's sensors plus its own noise, as a sensor between two others
would read. What a layout is (its sensors, its speeds, its probe) is returned with the files, so
a test can check what the pipeline made of it.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from rafi.contract.sensors import DEFAULT_SENSORS
from rafi.readers.mapped_table import excel_column
from rafi.twin.schedules import constant_schedule, multi_condition_schedule, with_rest
from rafi.twin.simulate import simulate_run

#: Sample period of the layouts' logs (s): a plant logger's, coarser than the paper's 5 s.
LAYOUT_SAMPLE_S = 30.0
#: Training speeds (r/min) of every layout, and the speed of its single-speed validation run.
LAYOUT_TRAINING_RPM = (3000, 9000, 15000)
LAYOUT_VALIDATION_RPM = 6000
#: Hours of each constant-speed run.
LAYOUT_RUN_H = 2.0
#: Daily tests (sheets) of the ``sheets-18`` workbook, their sample period (s) and the workbook's name.
DAILY_SHEETS = 18
DAILY_SAMPLE_S = 60.0
DAILY_WORKBOOK = "daily tests.xlsx"
#: The file-name parts that tell a ``two-files`` run's temperatures from its displacement.
PAIR_PARTS = ("temps", "disp")


@dataclass(frozen=True)
class Layout:
    """What a layout is: its name, its sensors (the twin's sensor each one reads, or two and a
    mixing weight for a derived one), its file format and its probe."""

    name: str
    description: str
    sensors: tuple[str, ...]
    sources: tuple[tuple[str, str, float], ...]
    file_format: str  # native | csv | headerless-xlsx | sheets | two-files
    headers: tuple[str, ...] = ()
    displacement_header: str = "disp_um"
    displacement_unit: str = "um"
    displacement_sign: int = 1
    delimiter: str = ","
    probes: tuple[tuple[str, str, float, float], ...] = ()  # name, header, gain, lag (s)
    sample_s: float = LAYOUT_SAMPLE_S


def _derived(n_extra: int, seed: int) -> list[tuple[str, str, float]]:
    """``n_extra`` derived sensors: two twin sensors and a weight each (deterministic)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_extra):
        a, b = rng.choice(len(DEFAULT_SENSORS), size=2, replace=False)
        out.append((DEFAULT_SENSORS[a], DEFAULT_SENSORS[b], float(rng.uniform(0.2, 0.8))))
    return out


def _layouts() -> dict[str, Layout]:
    twin = [(s, s, 1.0) for s in DEFAULT_SENSORS]
    four = ("front_bearing", "rear_bearing", "motor", "housing")
    six = tuple(f"Temp{i}" for i in range(1, 7))
    six_sources = tuple((s, s, 1.0) for s in ("T6", "T8", "T9", "T1", "T11", "T13"))
    return {
        "sensors-4": Layout(
            "sensors-4",
            "a spindle with 4 named sensors, native CSV",
            four,
            (("T9", "T9", 1.0), ("T8", "T8", 1.0), ("T6", "T6", 1.0), ("T13", "T13", 1.0)),
            "native",
        ),
        "sensors-6-diameter": Layout(
            "sensors-6-diameter",
            "a turning centre with 6 temperatures and a diameter probe in mm, semicolon CSV",
            six,
            (
                ("T6", "T6", 1.0),
                ("T8", "T8", 1.0),
                ("T9", "T9", 1.0),
                ("T1", "T1", 1.0),
                ("T11", "T11", 1.0),
                ("T13", "T13", 1.0),
            ),  # fmt: skip
            "csv",
            headers=tuple(f"Temperatur {i} [°C]" for i in range(1, 7)),
            displacement_header="Durchmesser [mm]",
            displacement_unit="mm",
            displacement_sign=1,
            delimiter=";",
        ),
        "sensors-22": Layout(
            "sensors-22",
            "a test rig with 22 temperatures, native CSV",
            tuple(f"T{i}" for i in range(1, 23)),
            tuple(twin + _derived(6, 22)),
            "native",
        ),
        "probes-xyz": Layout(
            "probes-xyz",
            "a machining centre tested after ISO 230-3: 8 temperatures, probes in X, Y and Z, CSV",
            tuple(f"T{i}" for i in range(1, 9)),
            tuple((s, s, 1.0) for s in ("T6", "T8", "T9", "T13", "T1", "T4", "T11", "T16")),
            "csv",
            headers=tuple(f"T{i} [C]" for i in range(1, 9)),
            probes=(("X", "dX [um]", 0.25, 900.0), ("Y", "dY [um]", -0.4, 300.0), ("Z", "dZ [um]", 1.0, 0.0)),
        ),
        "sensors-40": Layout(
            "sensors-40",
            "a rig with 40 thermocouple channels, CSV with its own headers",
            tuple(f"ch{i:02d}" for i in range(1, 41)),
            tuple(twin + _derived(24, 40)),
            "csv",
            headers=tuple(f"TC{i:02d}" for i in range(1, 41)),
            displacement_header="Z displacement (um)",
        ),
        "headerless-xlsx": Layout(
            "headerless-xlsx",
            "a test rig writing workbooks without a header row: time, speed, 6 temperatures, displacement",
            six,
            six_sources,
            "headerless-xlsx",
        ),
        "sheets-18": Layout(
            "sheets-18",
            f"a turning centre: one workbook, a sheet per daily test ({DAILY_SHEETS} days), an info sheet",
            six,
            six_sources,
            "sheets",
            headers=tuple(f"Temperatur {i} [°C]" for i in range(1, 7)),
            displacement_header="Verlagerung Z [µm]",
            sample_s=DAILY_SAMPLE_S,
        ),
        "two-files": Layout(
            "two-files",
            "temperatures and displacement logged by two programs: temps_<run>.csv and disp_<run>.csv",
            six,
            six_sources,
            "two-files",
            headers=tuple(f"Temp {i} [C]" for i in range(1, 7)),
            displacement_header="Weg [um]",
        ),
    }


#: Every layout by name.
LAYOUTS: dict[str, Layout] = _layouts()


def _lowpass(x: np.ndarray, dt: float, tau_s: float) -> np.ndarray:
    alpha = 1.0 - np.exp(-dt / tau_s)
    y = np.empty_like(x)
    y[0] = x[0]
    for k in range(1, len(x)):
        y[k] = y[k - 1] + alpha * (x[k] - y[k - 1])
    return y


def layout_frame(layout: Layout, log: pd.DataFrame, seed: int) -> pd.DataFrame:
    """The twin's canonical log ``log`` as ``layout``'s machine logs it: ``time``, ``speed_rpm``,
    the layout's sensors (a derived one: the low-passed mix of its two sources plus 0.02 K
    noise, rounded to 0.01 K) and ``disp_um``."""
    rng = np.random.default_rng(seed)
    out = pd.DataFrame({"time": log["time"].to_numpy(), "speed_rpm": log["speed_rpm"].to_numpy()})
    for name, (a, b, w) in zip(layout.sensors, layout.sources):
        if a == b:
            out[name] = log[a].to_numpy(dtype=float)
            continue
        mix = w * log[a].to_numpy(dtype=float) + (1 - w) * log[b].to_numpy(dtype=float)
        value = _lowpass(mix, layout.sample_s, 600.0) + rng.normal(0.0, 0.02, len(mix))
        out[name] = np.round(value, 2)
    out["disp_um"] = log["disp_um"].to_numpy(dtype=float)
    disp = out["disp_um"].to_numpy()
    for name, _header, gain, lag_s in layout.probes:
        moved = gain * (_lowpass(disp - disp[0], layout.sample_s, lag_s) if lag_s > 0 else disp - disp[0])
        out[f"probe_{name}"] = np.round(moved + rng.normal(0.0, 0.05, len(disp)), 3)
    return out


def layout_runs() -> list[tuple[str, list, str]]:
    """``(file stem, schedule, role)`` of every log of a layout: a cold-start run per training
    speed, one at the validation speed, and the multi-condition run."""
    hours = LAYOUT_RUN_H * 3600.0
    runs = [
        (f"train_{rpm:05d}rpm", with_rest(constant_schedule(rpm, hours)), "training")
        for rpm in LAYOUT_TRAINING_RPM
    ]
    valid = with_rest(constant_schedule(LAYOUT_VALIDATION_RPM, hours))
    runs.append((f"valid_{LAYOUT_VALIDATION_RPM:05d}rpm", valid, "validation"))
    runs.append(("multi_condition", with_rest(multi_condition_schedule()), "validation"))
    return runs


def _write_native(frame: pd.DataFrame, path: Path, layout: Layout, stem: str) -> None:
    from rafi.artefact import write_text_atomic
    from rafi.readers.native import format_raw_log

    meta = {"machine": layout.name, "run_id": stem, "sample_period_s": f"{LAYOUT_SAMPLE_S:g}"}
    write_text_atomic(path, format_raw_log(frame, meta, decimals={s: 2 for s in layout.sensors}))


def _write_csv(frame: pd.DataFrame, path: Path, layout: Layout) -> None:
    from rafi.artefact import write_text_atomic

    disp = frame["disp_um"].to_numpy(dtype=float) * layout.displacement_sign
    if layout.displacement_unit == "mm":
        disp = disp / 1000.0
    table = pd.DataFrame({"Zeit": pd.to_datetime(frame["time"]).dt.strftime("%Y-%m-%d %H:%M:%S")})
    table["Drehzahl [1/min]"] = frame["speed_rpm"].round(0).astype(int)
    for header, name in zip(layout.headers, layout.sensors):
        table[header] = frame[name].round(2)
    if layout.probes:
        for name, header, _gain, _lag in layout.probes:
            table[header] = frame[f"probe_{name}"]
    else:
        table[layout.displacement_header] = np.round(disp, 6 if layout.displacement_unit == "mm" else 3)
    write_text_atomic(path, table.to_csv(index=False, sep=layout.delimiter, lineterminator="\n"))


def _disp_cells(frame: pd.DataFrame, layout: Layout) -> np.ndarray:
    """The displacement as the layout's probe writes it (its unit and sign)."""
    disp = frame["disp_um"].to_numpy(dtype=float) * layout.displacement_sign
    return np.round(disp / 1000.0, 6) if layout.displacement_unit == "mm" else np.round(disp, 3)


def _sheet_rows(frame: pd.DataFrame, layout: Layout) -> list[list]:
    """Rows of a workbook sheet: a datetime cell, the speed, the sensors, the displacement."""
    times = pd.to_datetime(frame["time"]).dt.to_pydatetime()
    speed = frame["speed_rpm"].round(0).astype(int).tolist()
    temps = frame[list(layout.sensors)].round(2).to_numpy().tolist()
    disp = _disp_cells(frame, layout).tolist()
    return [[t, n, *row, d] for t, n, row, d in zip(times, speed, temps, disp)]


def _write_workbook(path: Path, sheets: dict[str, list[list]]) -> None:
    """A workbook of ``sheets`` (name -> rows), written next to ``path`` and moved into place."""
    import openpyxl

    wb = openpyxl.Workbook(write_only=True)
    for name, rows in sheets.items():
        ws = wb.create_sheet(name)
        for row in rows:
            ws.append(row)
    tmp = path.with_name(path.name + ".tmp")
    wb.save(tmp)
    os.replace(tmp, path)


def _write_pair(frame: pd.DataFrame, folder: Path, layout: Layout, stem: str) -> list[Path]:
    """``temps_<stem>.csv`` (time, speed, the sensors) and ``disp_<stem>.csv`` (time, displacement)."""
    from rafi.artefact import write_text_atomic

    times = pd.to_datetime(frame["time"]).dt.strftime("%Y-%m-%d %H:%M:%S")
    temps = pd.DataFrame({"Zeit": times, "Drehzahl [1/min]": frame["speed_rpm"].round(0).astype(int)})
    for header, name in zip(layout.headers, layout.sensors):
        temps[header] = frame[name].round(2)
    disp = pd.DataFrame({"Zeit": times, layout.displacement_header: _disp_cells(frame, layout)})
    paths = [folder / f"{part}_{stem}.csv" for part in PAIR_PARTS]
    for table, path in zip((temps, disp), paths):
        write_text_atomic(path, table.to_csv(index=False, lineterminator="\n"))
    return paths


def _layout_log(layout: Layout, schedule: list, day: int, seed: int) -> pd.DataFrame:
    start = pd.Timestamp("2026-05-04T08:00:00") + pd.Timedelta(days=day)
    run = simulate_run(schedule, seed=seed, start=start, defects=False, sample_period_s=layout.sample_s)
    return layout_frame(layout, run.log, seed)


def daily_runs() -> list[tuple[str, list, str]]:
    """``(sheet name, schedule, role)`` of the ``sheets-18`` workbook: the runs of
    :func:`layout_runs` again and again, one a day, ``Tag 01`` .. ``Tag 18``."""
    runs = layout_runs()
    return [(f"Tag {d + 1:02d}", runs[d % len(runs)][1], runs[d % len(runs)][2]) for d in range(DAILY_SHEETS)]


def write_layout(
    name: str, out_dir: str | os.PathLike, *, seed: int = 1, machine: str | None = None
) -> list[Path]:
    """Write the logs of layout ``name`` into ``out_dir/<machine>/`` (``machine`` defaults to
    the layout's name); returns the files in order. Runs of the twin's tapping-center-a, cold
    starts on consecutive days, without logger defects. ``sheets-18`` is one workbook (a sheet a
    day, each run of :func:`daily_runs` with its own seed, and an ``Info`` sheet of text);
    ``two-files`` writes two files per run (:data:`PAIR_PARTS`)."""
    layout = LAYOUTS[name]
    folder = Path(out_dir) / (machine or layout.name)
    folder.mkdir(parents=True, exist_ok=True)
    if layout.file_format == "sheets":
        header = ["Zeit", "Drehzahl [1/min]", *layout.headers, layout.displacement_header]
        sheets = {"Info": [["Prüfstand", layout.description], ["Sensoren", ", ".join(layout.headers)]]}
        for day, (sheet, schedule, _role) in enumerate(daily_runs()):
            frame = _layout_log(layout, schedule, day, seed * 100 + day)
            sheets[sheet] = [header, *_sheet_rows(frame, layout)]
        path = folder / DAILY_WORKBOOK
        _write_workbook(path, sheets)
        return [path]
    written = []
    for k, (stem, schedule, _role) in enumerate(layout_runs()):
        frame = _layout_log(layout, schedule, k, seed * 100 + k)
        path = folder / f"{stem}.csv"
        if layout.file_format == "native":
            _write_native(frame, path, layout, stem)
        elif layout.file_format == "headerless-xlsx":
            path = path.with_suffix(".xlsx")
            _write_workbook(path, {"Daten": _sheet_rows(frame, layout)})
        elif layout.file_format == "two-files":
            written += _write_pair(frame, folder, layout, stem)
            continue
        else:
            _write_csv(frame, path, layout)
        written.append(path)
    return written


def _mapped_input(layout: Layout) -> dict:
    """The ``input:`` block of a layout written with a header row."""
    fmt = "xlsx" if layout.file_format == "sheets" else "csv"
    block = {
        "format": fmt,
        **({"delimiter": layout.delimiter} if fmt == "csv" else {}),
        "columns": {
            "time": "Zeit",
            "speed_rpm": "Drehzahl [1/min]",
            **dict(zip(layout.sensors, layout.headers)),
        },
        "displacement": {
            "column": layout.displacement_header,
            "unit": layout.displacement_unit,
            "sign": layout.displacement_sign,
        },
    }
    if layout.file_format == "sheets":
        block["pattern"] = "*.xlsx"
        block["sheet"] = "Tag *"
    if layout.file_format == "two-files":
        block["pattern"] = f"{PAIR_PARTS[0]}_*.csv"
        block["join"] = {"replace": list(PAIR_PARTS), "by": "time"}
    return block


def layout_config(name: str) -> dict:
    """The ``machines.<machine>:`` block that reads layout ``name`` (what ``rafi init`` should
    propose, and the worked example of the docs adds): its input mapping, training speeds and
    every run's role follows from its speed (a run at a training speed trains)."""
    layout = LAYOUTS[name]
    block: dict = {"sample_period_s": layout.sample_s, "training_speeds_rpm": list(LAYOUT_TRAINING_RPM)}
    if layout.file_format == "native":
        block["input"] = {"sensors": list(layout.sensors)}
        return block
    if layout.file_format == "headerless-xlsx":
        letters = [excel_column(k) for k in range(len(layout.sensors) + 3)]
        names = ["time", "speed_rpm", *layout.sensors, "disp_um"]
        block["input"] = {"format": "xlsx", "header_row": None, "columns": dict(zip(names, letters))}
        return block
    block["input"] = _mapped_input(layout)
    if layout.probes:
        block["input"]["displacement"] = {"unit": "um"}
        block["input"]["probes"] = {name: {"column": header} for name, header, _g, _l in layout.probes}
    return block


def layout_names() -> Sequence[str]:
    """The layouts ``rafi simulate layout`` writes."""
    return tuple(LAYOUTS)
