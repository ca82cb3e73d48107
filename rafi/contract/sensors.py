"""The temperature sensors of a machine, as its tables carry them.

A machine has its own sensors, 1 to 64 of them, named as its ``input:`` mapping names them
(``input.sensors``, resolved once by :func:`rafi.readers.input_spec.check_sensors`; the paper's
rig, ``T1`` .. ``T16``, where the mapping names none). The tables then say which they are:

- a canonical or clean log frame has the columns ``time, speed_rpm, <sensors>, disp_um`` first,
  in that order, then any extra columns (:func:`frame_sensors`);
- ``runs.parquet`` has every sensor ``s`` beside its rise ``d<s>`` (:func:`run_sensors`).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from rafi.contract.input import DEFAULT_SENSORS

__all__ = [
    "DEFAULT_SENSORS",
    "canonical_columns",
    "common_sensors",
    "frame_sensors",
    "rise_columns",
    "run_sensors",
    "runs_frame_columns",
]


def canonical_columns(sensors: Sequence[str] = DEFAULT_SENSORS) -> tuple[str, ...]:
    """The first columns of a canonical log frame of a machine with ``sensors``, in order."""
    return ("time", "speed_rpm", *sensors, "disp_um")


def frame_sensors(columns: Iterable[str] | object) -> tuple[str, ...]:
    """The sensors of a canonical or clean log frame: its columns between ``speed_rpm`` and
    ``disp_um``.

    Parameters
    ----------
    columns : iterable of str, or a DataFrame
        The frame's columns in order (a frame is taken by its ``columns``).

    Returns
    -------
    tuple of str
        The sensor names in column order.

    Raises
    ------
    ValueError
        If ``speed_rpm`` or ``disp_um`` is missing or they are out of order (not a canonical frame).
    """
    names = [str(c) for c in getattr(columns, "columns", columns)]
    try:
        first, last = names.index("speed_rpm"), names.index("disp_um")
    except ValueError:
        raise ValueError(f"not a canonical log frame (no speed_rpm or disp_um column): {names[:6]}") from None
    if last <= first:
        raise ValueError(f"not a canonical log frame: disp_um before speed_rpm in {names[:6]}")
    return tuple(names[first + 1 : last])


def run_sensors(columns: Iterable[str] | object) -> tuple[str, ...]:
    """The sensors of a runs table (or any frame holding rises): every column ``s`` beside which
    there is its rise ``d<s>``, in column order; in a frame of rises only (no sensor column
    beside any of them), every rise column ``d<s>`` but ``dz_um`` and ``disp_um``."""
    names = [str(c) for c in getattr(columns, "columns", columns)]
    present = set(names)
    paired = tuple(s for s in names if f"d{s}" in present)
    if paired:
        return paired
    return tuple(c[1:] for c in names if c.startswith("d") and len(c) > 1 and c not in ("dz_um", "disp_um"))


def rise_columns(sensors: Iterable[str]) -> list[str]:
    """The rise column of every sensor: ``d<s>``."""
    return [f"d{s}" for s in sensors]


def runs_frame_columns(sensors=DEFAULT_SENSORS) -> tuple[str, ...]:
    """Columns of ``runs.parquet`` of a machine with ``sensors``, in order."""
    return (
        "run_id",
        "t_s",
        "time",
        "speed_rpm",
        *sensors,
        "disp_um",
        *(f"d{s}" for s in sensors),
        "dz_um",
        "log",
        "log_t_s",
        "segment",
    )


def common_sensors(clean_frames: dict) -> tuple[str, ...]:
    """The sensors every clean frame of a machine has (:func:`frame_sensors`; the
    paper rig's without a frame); ValueError naming the logs if two frames differ."""
    found = {key: frame_sensors(frame) for key, frame in sorted(clean_frames.items())}
    distinct = sorted(set(found.values()))
    if len(distinct) > 1:
        first = {sensors: key for key, sensors in reversed(found.items())}
        shown = "; ".join(f"{first[s]}: {', '.join(s)}" for s in distinct[:2])
        raise ValueError(f"the clean logs of one machine have different sensors ({shown})")
    return distinct[0] if distinct else DEFAULT_SENSORS
