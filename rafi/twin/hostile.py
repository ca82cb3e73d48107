"""Hostile logs: good native logs made wrong in ways that still look valid, with the ground truth.

Each :class:`HostileCase` says which file to write, what was done to it, which check must
catch it (a check id of ``docs/raw-format.md``, "Checks") and how: ``quarantined`` (certain:
the file is refused), ``rejected`` (refused at machine level, e.g. a byte-identical copy),
``warning`` (used, shown in the report, blocks promotion until confirmed), ``flagged`` (either
of the last three) or ``not_read`` (never opened: a link leaving ``raw/``, a file still being
written). :func:`hostile_corpus` derives every case from the shipped tapping-center-a logs;
:func:`rafi.twin.hostile_files.write_hostile_corpus` writes them beside a machine's files
(``rafi simulate hostile``).

The cases are the kinds of issue 13: wrong units (degF, K, mm, nm, rev/s, rad/s; on some
sensors, from half way, with many glitches, an inch factor), a reversed probe (training and
validation, or flipping half way), a re-zeroed probe, swapped channels, a displacement made from
a temperature, copied sensors, a stuck logger, a constant sensor, a speed stuck at rest, a channel
missing in most rows, absurd speeds, oversized lines and fields, duplicate content, metadata
contradicting the data or the folder, links out of ``raw/`` and a file still being written.
"""

from __future__ import annotations

import io
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from rafi import SENSORS as _SENSORS

SENSORS = list(_SENSORS)

#: Outcomes a case can expect.
OUTCOMES = ("quarantined", "rejected", "warning", "flagged", "not_read")

#: The logger's open-circuit codes (settings ``clean.open_circuit_values``), kept by unit changes.
OPEN_CIRCUIT = (-999.0, 999.9, 850.0)

#: Length of the oversized field: over the readers' field limit (4 KiB), under their line limit (64 KiB).
FIELD_CHARS = 20_000

#: Shipped tapping-center-a logs the cases start from.
SOURCES = ("train_03000rpm.csv", "train_06000rpm.csv", "train_09000rpm.csv", "valid_13500rpm.csv")


@dataclass(frozen=True)
class HostileCase:
    """One hostile log and what must happen to it.

    Attributes
    ----------
    name : str
        Case id.
    file : str
        File name under the machine folder.
    check : str
        Check id that must name the problem.
    outcome : str
        One of :data:`OUTCOMES`.
    what : str
        What was done to the good log, for people.
    """

    name: str
    file: str
    check: str
    outcome: str
    what: str


def split_native(text: str) -> tuple[dict[str, str], pd.DataFrame]:
    """Metadata lines and data of a native log (the columns as text-free floats, ``time`` as text)."""
    meta: dict[str, str] = {}
    lines = text.splitlines(keepends=True)
    k = 0
    while k < len(lines) and lines[k].startswith("#"):
        key, _, value = lines[k][1:].strip().partition(":")
        meta[key.strip()] = value.strip()
        k += 1
    frame = pd.read_csv(io.StringIO("".join(lines[k:])), dtype={"time": str})
    return meta, frame


def join_native(meta: dict[str, str], frame: pd.DataFrame, decimals: dict[str, int] | None = None) -> str:
    """Native log text of ``meta`` and ``frame`` (inverse of :func:`split_native`)."""
    decimals = {"speed_rpm": 0, **{s: 2 for s in SENSORS}, "disp_um": 3, **(decimals or {})}
    out = io.StringIO()
    for key, value in meta.items():
        out.write(f"# {key}: {value}\n")
    cols = list(frame.columns)
    out.write(",".join(cols) + "\n")
    rendered = []
    for name in cols:
        col = frame[name]
        if name == "time" or not pd.api.types.is_numeric_dtype(col):
            rendered.append(col.fillna("").astype(str).to_numpy(dtype=object))
        else:
            nd = decimals.get(name, 4)
            rendered.append(np.array(["" if np.isnan(v) else f"{v:.{nd}f}" for v in col.to_numpy(float)]))
    for row in zip(*rendered, strict=True):
        out.write(",".join(row) + "\n")
    return out.getvalue()


def _variant(meta, frame, change: Callable[[dict, pd.DataFrame], None], decimals=None) -> str:
    meta, frame = dict(meta), frame.copy()
    change(meta, frame)
    return join_native(meta, frame, decimals)


def hostile_corpus(sources: dict[str, str], *, long_bytes: int = 200_000) -> list[tuple[HostileCase, str]]:
    """Every text case of the corpus, built from good native logs.

    Parameters
    ----------
    sources : dict
        File name -> text of the shipped logs named in :data:`SOURCES`.
    long_bytes : int
        Length of the oversized line (the issue's corpus used 50 MB).

    Returns
    -------
    list of (HostileCase, str)
        The case and the file's text. Cases that are not text (a link, a file still being
        written) are made by :func:`rafi.twin.hostile_files.write_hostile_corpus`.
    """
    parsed = {name: split_native(text) for name, text in sources.items()}
    m3, f3 = parsed["train_03000rpm.csv"]
    m6, f6 = parsed["train_06000rpm.csv"]
    m9, f9 = parsed["train_09000rpm.csv"]
    mv, fv = parsed["valid_13500rpm.csv"]
    rng = np.random.default_rng(13)
    glitch = int(rng.integers(len(f6) // 4, 3 * len(f6) // 4))

    def temps(f, convert):
        # the logger's open-circuit codes stay as they are: only real readings change unit
        values = f[SENSORS]
        f[SENSORS] = values.where(values.isin(OPEN_CIRCUIT), convert(values))

    def degf(_, f):
        temps(f, lambda v: v * 9 / 5 + 32)

    def kelvin(_, f):
        temps(f, lambda v: v + 273.15)

    def mm_glitch(_, f):
        f["disp_um"] = f["disp_um"] / 1000.0
        f.loc[glitch, "disp_um"] = 35.0  # one glitch sample makes max - min look like micrometres

    def nm(_, f):
        f["disp_um"] = f["disp_um"] * 1000.0

    def reversed_probe(_, f):
        f["disp_um"] = -f["disp_um"]

    def swapped(_, f):
        f["T1"], f["disp_um"] = f["disp_um"].to_numpy(), f["T1"].to_numpy()

    def stuck(_, f):
        f[SENSORS] = f[SENSORS].iloc[0].to_numpy()

    def rev_s(_, f):
        f["speed_rpm"] = f["speed_rpm"] / 60.0

    def fast(_, f):
        f.loc[f["speed_rpm"] > 100, "speed_rpm"] = 50_000.0

    def sparse(_, f):
        keep = f.index.isin([0, len(f) // 2, len(f) - 1])
        f.loc[~keep, "disp_um"] = np.nan

    def long_line(m, _):
        m["notes"] = "x" * long_bytes

    def long_field(_, f):
        f["remark"] = ""
        f.loc[len(f) // 3, "remark"] = "y" * FIELD_CHARS

    def other_machine(m, _):
        m["machine"] = "machining-center-b"

    def wrong_period(m, _):
        m["sample_period_s"] = "1"

    def clock_1970(_, f):
        times = pd.to_datetime(f["time"])
        f["time"] = (times - (times.min() - pd.Timestamp("1970-01-01"))).dt.strftime("%Y-%m-%dT%H:%M:%S")

    def constant_sensor(_, f):
        f["T5"] = f["T5"].iloc[0]

    half6 = np.arange(len(f6)) >= len(f6) // 2
    halfv = np.arange(len(fv)) >= len(fv) // 2

    def degf_some(_, f):  # T1..T8 only: the coolest sensor is still in deg C
        values = f[SENSORS[:8]]
        f[SENSORS[:8]] = values.where(values.isin(OPEN_CIRCUIT), values * 9 / 5 + 32)

    def degf_part_way(_, f):
        values = f[SENSORS]
        converted = values.where(values.isin(OPEN_CIRCUIT), values * 9 / 5 + 32)
        f[SENSORS] = values.where(np.repeat(~halfv[:, None], len(SENSORS), axis=1), converted)

    def mm_part_way(_, f):
        f["disp_um"] = np.where(half6, f["disp_um"] / 1000.0, f["disp_um"])

    def mm_many_glitches(_, f):
        f["disp_um"] = f["disp_um"] / 1000.0
        rows = np.random.default_rng(31).choice(len(f), int(0.03 * len(f)), replace=False)
        f.loc[f.index[rows], "disp_um"] = 35.0  # 3 % glitch samples: more than p2-p98 ignores

    def inch(_, f):
        f["disp_um"] = f["disp_um"] * 25.4

    def rad_s(_, f):
        f["speed_rpm"] = f["speed_rpm"] * 2 * np.pi / 60.0

    def at_rest(_, f):
        f["speed_rpm"] = 0.0

    def copied(_, f):
        for s in SENSORS[1:]:
            f[s] = f["T1"].to_numpy()

    def affine(_, f):
        t3 = f["T3"].where(~f["T3"].isin(OPEN_CIRCUIT))
        f["disp_um"] = (2.0 * (t3 - t3.iloc[:20].median())).interpolate().bfill().ffill()

    def flip_part_way(_, f):
        f["disp_um"] = np.where(halfv, -f["disp_um"], f["disp_um"])

    def re_zeroed(_, f):
        k = len(f) // 2
        f["disp_um"] = np.where(half6, f["disp_um"] - f["disp_um"].iloc[k], f["disp_um"])

    def rev_s_part_way(_, f):
        f["speed_rpm"] = np.where(half6, f["speed_rpm"] / 60.0, f["speed_rpm"])

    more_cases = [
        (
            "probe_flips_part_way",
            mv,
            fv,
            flip_part_way,
            None,
            "probe_sign",
            "quarantined",
            "the probe's sign flips half way through a validation run",
        ),
        (
            "probe_re_zeroed",
            m6,
            f6,
            re_zeroed,
            None,
            "displacement_step",
            "warning",
            "the probe re-zeroed half way (the displacement jumps to 0)",
        ),
        (
            "rev_s_part_way",
            m6,
            f6,
            rev_s_part_way,
            {"speed_rpm": 2},
            "speed_unit",
            "quarantined",
            "speed in r/min, then in rev/s from half way",
        ),
        (
            "degF_some_sensors",
            m6,
            f6,
            degf_some,
            None,
            "temperature_unit",
            "quarantined",
            "T1..T8 in degF, T9..T16 in degC",
        ),
        (
            "degF_part_way",
            mv,
            fv,
            degf_part_way,
            None,
            "temperature_unit",
            "quarantined",
            "a validation run whose temperatures switch to degF half way",
        ),
        (
            "mm_part_way",
            m6,
            f6,
            mm_part_way,
            {"disp_um": 6},
            "displacement_unit",
            "quarantined",
            "displacement in um, then in mm from half way",
        ),
        (
            "mm_many_glitches",
            m6,
            f6,
            mm_many_glitches,
            {"disp_um": 6},
            "displacement_unit",
            "quarantined",
            "displacement in mm with 3 % glitch samples",
        ),
        (
            "inch_scale",
            mv,
            fv,
            inch,
            None,
            "displacement_unit",
            "warning",
            "displacement x 25.4 (an inch conversion applied to um) on a validation run",
        ),
        (
            "rad_s",
            m3,
            f3,
            rad_s,
            {"speed_rpm": 2},
            "speed_unit",
            "quarantined",
            "speed in rad/s on a training run",
        ),
        (
            "rad_s_validation",
            mv,
            fv,
            rad_s,
            {"speed_rpm": 2},
            "speed_range",
            "warning",
            "speed in rad/s on a validation run (far below the training speeds)",
        ),
        (
            "speed_at_rest",
            m9,
            f9,
            at_rest,
            None,
            "constant_channel",
            "warning",
            "speed 0 throughout while the machine heats (a stuck speed channel)",
        ),
        (
            "copied_sensors",
            m6,
            f6,
            copied,
            None,
            "copied_channel",
            "quarantined",
            "all 16 temperature columns hold T1",
        ),
        (
            "disp_from_temperature",
            m9,
            f9,
            affine,
            None,
            "swapped_channels",
            "flagged",
            "the displacement column is 2 x the rise of T3",
        ),
        (
            "reversed_probe_validation",
            mv,
            fv,
            reversed_probe,
            None,
            "probe_sign",
            "warning",
            "the displacement probe's sign reversed on a validation run",
        ),
    ]
    text_cases = [
        ("degF", m6, f6, degf, None, "temperature_unit", "quarantined", "temperatures in degF"),
        ("kelvin", m6, f6, kelvin, None, "temperature_unit", "quarantined", "temperatures in K"),
        (
            "mm_glitch",
            m6,
            f6,
            mm_glitch,
            {"disp_um": 6},
            "displacement_unit",
            "quarantined",
            "displacement in mm with one glitch sample",
        ),
        ("nm", m6, f6, nm, {"disp_um": 0}, "displacement_unit", "quarantined", "displacement in nm"),
        (
            "reversed_probe",
            m9,
            f9,
            reversed_probe,
            None,
            "probe_sign",
            "warning",
            "the displacement probe's sign reversed",
        ),
        (
            "swapped_T1_disp",
            m6,
            f6,
            swapped,
            None,
            "swapped_channels",
            "flagged",
            "T1 and the displacement column swapped",
        ),
        ("stuck_logger", m6, f6, stuck, None, "stuck_logger", "quarantined", "all 16 temperatures constant"),
        (
            "rev_s",
            m3,
            f3,
            rev_s,
            {"speed_rpm": 1},
            "speed_unit",
            "quarantined",
            "speed in rev/s on a training run",
        ),
        ("fast_validation", mv, fv, fast, None, "speed_range", "warning", "a validation run at 50,000 r/min"),
        (
            "sparse_disp",
            m6,
            f6,
            sparse,
            None,
            "sparse_channel",
            "quarantined",
            "displacement present in 3 rows",
        ),
        (
            "long_line",
            m6,
            f6,
            long_line,
            None,
            "line_too_long",
            "quarantined",
            f"a notes line of {long_bytes} bytes",
        ),
        (
            "long_field",
            m6,
            f6,
            long_field,
            None,
            "field_too_long",
            "quarantined",
            f"a field of {FIELD_CHARS} characters",
        ),
        (
            "other_machine",
            m9,
            f9,
            other_machine,
            None,
            "metadata_machine",
            "warning",
            "metadata names another machine than the folder",
        ),
        (
            "clock_1970",
            mv,
            fv,
            clock_1970,
            None,
            "clock_unset",
            "warning",
            "a logger clock that was never set (timestamps from 1970-01-01)",
        ),
        (
            "wrong_period",
            m9,
            f9,
            wrong_period,
            None,
            "metadata_period",
            "quarantined",
            "metadata says 1 s samples on 5 s data",
        ),
        (
            "constant_sensor",
            m9,
            f9,
            constant_sensor,
            None,
            "constant_channel",
            "warning",
            "temperature T5 constant (a dead sensor)",
        ),
    ]
    out = []
    for name, meta, frame, change, decimals, check, outcome, what in [*text_cases, *more_cases]:
        case = HostileCase(name, f"hostile_{name}.csv", check, outcome, what)
        out.append((case, _variant(meta, frame, change, decimals)))
    dup = HostileCase(
        "duplicate",
        "train_03000rpm_copy.csv",
        "duplicate_content",
        "rejected",
        "a byte-identical copy of a training file",
    )
    out.append((dup, sources["train_03000rpm.csv"]))
    return out
