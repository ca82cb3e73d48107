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
    """Native log text of ``meta`` and ``frame`` after ``change`` (on copies: the inputs stay as they are)."""
    meta, frame = dict(meta), frame.copy()
    change(meta, frame)
    return join_native(meta, frame, decimals)


# --------------------------------------------------------------------------- the changes
# Each change takes a log's metadata and data (copies) and makes them wrong in place.


def _second_half(frame: pd.DataFrame) -> np.ndarray:
    """True for the rows from half way through ``frame`` on."""
    return np.arange(len(frame)) >= len(frame) // 2


def _convert_temperatures(frame: pd.DataFrame, sensors: list[str], convert) -> pd.DataFrame:
    """``sensors`` of ``frame`` through ``convert``, the logger's open-circuit codes left as they are."""
    values = frame[sensors]
    return values.where(values.isin(OPEN_CIRCUIT), convert(values))


def _to_degf(_meta: dict, frame: pd.DataFrame) -> None:
    """Every temperature in degF."""
    frame[SENSORS] = _convert_temperatures(frame, SENSORS, lambda v: v * 9 / 5 + 32)


def _to_kelvin(_meta: dict, frame: pd.DataFrame) -> None:
    """Every temperature in K."""
    frame[SENSORS] = _convert_temperatures(frame, SENSORS, lambda v: v + 273.15)


def _degf_t1_to_t8(_meta: dict, frame: pd.DataFrame) -> None:
    """T1..T8 in degF; the coolest sensors stay in deg C."""
    frame[SENSORS[:8]] = _convert_temperatures(frame, SENSORS[:8], lambda v: v * 9 / 5 + 32)


def _degf_from_half_way(_meta: dict, frame: pd.DataFrame) -> None:
    """Every temperature in degF from half way on."""
    values = frame[SENSORS]
    converted = _convert_temperatures(frame, SENSORS, lambda v: v * 9 / 5 + 32)
    first_half = ~_second_half(frame)
    frame[SENSORS] = values.where(np.repeat(first_half[:, None], len(SENSORS), axis=1), converted)


def _to_mm_one_glitch(_meta: dict, frame: pd.DataFrame) -> None:
    """Displacement in mm, with one glitch sample that makes max - min look like micrometres."""
    glitch = int(np.random.default_rng(13).integers(len(frame) // 4, 3 * len(frame) // 4))
    frame["disp_um"] = frame["disp_um"] / 1000.0
    frame.loc[glitch, "disp_um"] = 35.0


def _to_mm_many_glitches(_meta: dict, frame: pd.DataFrame) -> None:
    """Displacement in mm with 3 % glitch samples: more than a p2-p98 range ignores."""
    frame["disp_um"] = frame["disp_um"] / 1000.0
    rows = np.random.default_rng(31).choice(len(frame), int(0.03 * len(frame)), replace=False)
    frame.loc[frame.index[rows], "disp_um"] = 35.0


def _mm_from_half_way(_meta: dict, frame: pd.DataFrame) -> None:
    """Displacement in mm from half way on."""
    frame["disp_um"] = np.where(_second_half(frame), frame["disp_um"] / 1000.0, frame["disp_um"])


def _to_nm(_meta: dict, frame: pd.DataFrame) -> None:
    """Displacement in nm."""
    frame["disp_um"] = frame["disp_um"] * 1000.0


def _inch_scale(_meta: dict, frame: pd.DataFrame) -> None:
    """Displacement times 25.4 (an inch conversion applied to um)."""
    frame["disp_um"] = frame["disp_um"] * 25.4


def _reverse_probe(_meta: dict, frame: pd.DataFrame) -> None:
    """The displacement's sign reversed."""
    frame["disp_um"] = -frame["disp_um"]


def _flip_from_half_way(_meta: dict, frame: pd.DataFrame) -> None:
    """The displacement's sign reversed from half way on."""
    frame["disp_um"] = np.where(_second_half(frame), -frame["disp_um"], frame["disp_um"])


def _re_zero_half_way(_meta: dict, frame: pd.DataFrame) -> None:
    """The probe re-zeroed half way: the displacement jumps to 0 there and goes on from it."""
    middle = len(frame) // 2
    frame["disp_um"] = np.where(
        _second_half(frame), frame["disp_um"] - frame["disp_um"].iloc[middle], frame["disp_um"]
    )


def _swap_t1_and_disp(_meta: dict, frame: pd.DataFrame) -> None:
    """T1 and the displacement column swapped."""
    frame["T1"], frame["disp_um"] = frame["disp_um"].to_numpy(), frame["T1"].to_numpy()


def _disp_from_t3(_meta: dict, frame: pd.DataFrame) -> None:
    """The displacement replaced by 2 x the rise of T3 (open-circuit codes interpolated over)."""
    t3 = frame["T3"].where(~frame["T3"].isin(OPEN_CIRCUIT))
    frame["disp_um"] = (2.0 * (t3 - t3.iloc[:20].median())).interpolate().bfill().ffill()


def _copy_t1(_meta: dict, frame: pd.DataFrame) -> None:
    """Every temperature column holds T1."""
    for sensor in SENSORS[1:]:
        frame[sensor] = frame["T1"].to_numpy()


def _freeze_temperatures(_meta: dict, frame: pd.DataFrame) -> None:
    """Every temperature stuck at its first value."""
    frame[SENSORS] = frame[SENSORS].iloc[0].to_numpy()


def _constant_t5(_meta: dict, frame: pd.DataFrame) -> None:
    """T5 stuck at its first value (a dead sensor)."""
    frame["T5"] = frame["T5"].iloc[0]


def _to_rev_s(_meta: dict, frame: pd.DataFrame) -> None:
    """Speed in rev/s."""
    frame["speed_rpm"] = frame["speed_rpm"] / 60.0


def _rev_s_from_half_way(_meta: dict, frame: pd.DataFrame) -> None:
    """Speed in rev/s from half way on."""
    frame["speed_rpm"] = np.where(_second_half(frame), frame["speed_rpm"] / 60.0, frame["speed_rpm"])


def _to_rad_s(_meta: dict, frame: pd.DataFrame) -> None:
    """Speed in rad/s."""
    frame["speed_rpm"] = frame["speed_rpm"] * 2 * np.pi / 60.0


def _spin_at_50000(_meta: dict, frame: pd.DataFrame) -> None:
    """Every moving sample at 50,000 r/min."""
    frame.loc[frame["speed_rpm"] > 100, "speed_rpm"] = 50_000.0


def _speed_at_rest(_meta: dict, frame: pd.DataFrame) -> None:
    """Speed 0 throughout (a stuck speed channel)."""
    frame["speed_rpm"] = 0.0


def _sparse_disp(_meta: dict, frame: pd.DataFrame) -> None:
    """The displacement kept in the first, middle and last rows only."""
    keep = frame.index.isin([0, len(frame) // 2, len(frame) - 1])
    frame.loc[~keep, "disp_um"] = np.nan


def _long_field(_meta: dict, frame: pd.DataFrame) -> None:
    """An extra ``remark`` column with one field of :data:`FIELD_CHARS` characters."""
    frame["remark"] = ""
    frame.loc[len(frame) // 3, "remark"] = "y" * FIELD_CHARS


def _other_machine(meta: dict, _frame: pd.DataFrame) -> None:
    """Metadata naming another machine than the folder."""
    meta["machine"] = "machining-center-b"


def _wrong_period(meta: dict, _frame: pd.DataFrame) -> None:
    """Metadata saying 1 s samples."""
    meta["sample_period_s"] = "1"


def _clock_1970(_meta: dict, frame: pd.DataFrame) -> None:
    """Timestamps from 1970-01-01 (a logger clock that was never set)."""
    times = pd.to_datetime(frame["time"])
    frame["time"] = (times - (times.min() - pd.Timestamp("1970-01-01"))).dt.strftime("%Y-%m-%dT%H:%M:%S")


def _long_notes(n_chars: int) -> Callable[[dict, pd.DataFrame], None]:
    """A change that writes a notes metadata line of ``n_chars`` characters."""

    def change(meta: dict, _frame: pd.DataFrame) -> None:
        meta["notes"] = "x" * n_chars

    return change


# --------------------------------------------------------------------------- the cases


@dataclass(frozen=True)
class _Recipe:
    """How one text case is made: which good log, what change, and the :class:`HostileCase` fields."""

    name: str
    source: str
    change: Callable[[dict, pd.DataFrame], None]
    check: str
    outcome: str
    what: str
    decimals: dict[str, int] | None = None


_TRAIN_3000, _TRAIN_6000, _TRAIN_9000, _VALID_13500 = SOURCES


def _recipes(long_bytes: int) -> list[_Recipe]:
    """Every text case in corpus order (the first corpus, then the cases added after it).

    Parameters
    ----------
    long_bytes : int
        Length of the oversized notes line.

    Returns
    -------
    list of _Recipe
        One per case; ``decimals`` overrides the written decimals where a changed unit
        needs more (or fewer) of them.
    """
    return [
        _Recipe("degF", _TRAIN_6000, _to_degf, "temperature_unit", "quarantined", "temperatures in degF"),
        _Recipe("kelvin", _TRAIN_6000, _to_kelvin, "temperature_unit", "quarantined", "temperatures in K"),
        _Recipe("mm_glitch", _TRAIN_6000, _to_mm_one_glitch, "displacement_unit", "quarantined",
                "displacement in mm with one glitch sample", {"disp_um": 6}),
        _Recipe("nm", _TRAIN_6000, _to_nm, "displacement_unit", "quarantined", "displacement in nm",
                {"disp_um": 0}),
        _Recipe("reversed_probe", _TRAIN_9000, _reverse_probe, "probe_sign", "warning",
                "the displacement probe's sign reversed"),
        _Recipe("swapped_T1_disp", _TRAIN_6000, _swap_t1_and_disp, "swapped_channels", "flagged",
                "T1 and the displacement column swapped"),
        _Recipe("stuck_logger", _TRAIN_6000, _freeze_temperatures, "stuck_logger", "quarantined",
                "all 16 temperatures constant"),
        _Recipe("rev_s", _TRAIN_3000, _to_rev_s, "speed_unit", "quarantined",
                "speed in rev/s on a training run", {"speed_rpm": 1}),
        _Recipe("fast_validation", _VALID_13500, _spin_at_50000, "speed_range", "warning",
                "a validation run at 50,000 r/min"),
        _Recipe("sparse_disp", _TRAIN_6000, _sparse_disp, "sparse_channel", "quarantined",
                "displacement present in 3 rows"),
        _Recipe("long_line", _TRAIN_6000, _long_notes(long_bytes), "line_too_long", "quarantined",
                f"a notes line of {long_bytes} bytes"),
        _Recipe("long_field", _TRAIN_6000, _long_field, "field_too_long", "quarantined",
                f"a field of {FIELD_CHARS} characters"),
        _Recipe("other_machine", _TRAIN_9000, _other_machine, "metadata_machine", "warning",
                "metadata names another machine than the folder"),
        _Recipe("clock_1970", _VALID_13500, _clock_1970, "clock_unset", "warning",
                "a logger clock that was never set (timestamps from 1970-01-01)"),
        _Recipe("wrong_period", _TRAIN_9000, _wrong_period, "metadata_period", "quarantined",
                "metadata says 1 s samples on 5 s data"),
        _Recipe("constant_sensor", _TRAIN_9000, _constant_t5, "constant_channel", "warning",
                "temperature T5 constant (a dead sensor)"),
        # added after the first corpus
        _Recipe("probe_flips_part_way", _VALID_13500, _flip_from_half_way, "probe_sign", "quarantined",
                "the probe's sign flips half way through a validation run"),
        _Recipe("probe_re_zeroed", _TRAIN_6000, _re_zero_half_way, "displacement_step", "warning",
                "the probe re-zeroed half way (the displacement jumps to 0)"),
        _Recipe("rev_s_part_way", _TRAIN_6000, _rev_s_from_half_way, "speed_unit", "quarantined",
                "speed in r/min, then in rev/s from half way", {"speed_rpm": 2}),
        _Recipe("degF_some_sensors", _TRAIN_6000, _degf_t1_to_t8, "temperature_unit", "quarantined",
                "T1..T8 in degF, T9..T16 in degC"),
        _Recipe("degF_part_way", _VALID_13500, _degf_from_half_way, "temperature_unit", "quarantined",
                "a validation run whose temperatures switch to degF half way"),
        _Recipe("mm_part_way", _TRAIN_6000, _mm_from_half_way, "displacement_unit", "quarantined",
                "displacement in um, then in mm from half way", {"disp_um": 6}),
        _Recipe("mm_many_glitches", _TRAIN_6000, _to_mm_many_glitches, "displacement_unit", "quarantined",
                "displacement in mm with 3 % glitch samples", {"disp_um": 6}),
        _Recipe("inch_scale", _VALID_13500, _inch_scale, "displacement_unit", "warning",
                "displacement x 25.4 (an inch conversion applied to um) on a validation run"),
        _Recipe("rad_s", _TRAIN_3000, _to_rad_s, "speed_unit", "quarantined",
                "speed in rad/s on a training run", {"speed_rpm": 2}),
        _Recipe("rad_s_validation", _VALID_13500, _to_rad_s, "speed_range", "warning",
                "speed in rad/s on a validation run (far below the training speeds)", {"speed_rpm": 2}),
        _Recipe("speed_at_rest", _TRAIN_9000, _speed_at_rest, "constant_channel", "warning",
                "speed 0 throughout while the machine heats (a stuck speed channel)"),
        _Recipe("copied_sensors", _TRAIN_6000, _copy_t1, "copied_channel", "quarantined",
                "all 16 temperature columns hold T1"),
        _Recipe("disp_from_temperature", _TRAIN_9000, _disp_from_t3, "swapped_channels", "flagged",
                "the displacement column is 2 x the rise of T3"),
        _Recipe("reversed_probe_validation", _VALID_13500, _reverse_probe, "probe_sign", "warning",
                "the displacement probe's sign reversed on a validation run"),
    ]  # fmt: skip


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
    out = []
    for recipe in _recipes(long_bytes):
        file = f"hostile_{recipe.name}.csv"
        case = HostileCase(recipe.name, file, recipe.check, recipe.outcome, recipe.what)
        meta, frame = parsed[recipe.source]
        out.append((case, _variant(meta, frame, recipe.change, recipe.decimals)))
    dup = HostileCase(
        "duplicate",
        "train_03000rpm_copy.csv",
        "duplicate_content",
        "rejected",
        "a byte-identical copy of a training file",
    )
    out.append((dup, sources["train_03000rpm.csv"]))
    return out
