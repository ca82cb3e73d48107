"""The files ``rafi record`` writes, recognised while the run is planned (standard library only).

A recording is a native-format log (docs/raw-format.md) in ``raw/<machine>/``, whatever the
machine's own ``input:`` says: ``rafi record`` reads OPC UA nodes (or a DAQ's native file) and
writes ``time, speed_rpm, <the machine's sensors>, disp_um`` in degC and um, so a machine whose own
logger writes a workbook with German headers still gets recordings the pipeline can read.
Discovery (:func:`rafi.readers.input_spec.discover_logs`) therefore finds them beside the
machine's own logs, and the clean step reads them with :func:`recording_spec`, not with the
machine's mapping (docs/record.md, "How the pipeline reads a recording").

A file is a recording when both hold (:func:`is_recording`):

* **its name** is one ``rafi record`` gives: ``<run>_<YYYYMMDDTHHMMSSZ>.csv``, possibly with
  ``_2``, ``_3`` ... before ``.csv`` (:data:`RECORDING_NAME`);
* **its header** (the leading ``#`` lines) holds ``# recorded_by: rafi record ...``
  (:data:`RECORDED_BY`; a ``notes`` line cannot forge it: every line of the notes starts with
  ``# notes:``).

The name finds the candidates without opening every file of the folder; the header keeps a
machine's own CSV log that happens to have such a name from being read as native. A machine
with several probes (``input.probes``) has no recordings: ``rafi record`` refuses it.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from rafi.readers.discovery import not_a_file, not_a_file_warning, split_outside

__all__ = [
    "HEAD_MAX_BYTES",
    "RECORDED_BY",
    "RECORDING_GLOB",
    "RECORDING_NAME",
    "find_recordings",
    "has_recording_header",
    "is_recording",
    "is_recording_name",
    "recording_spec",
]

#: The value of the ``recorded_by`` metadata line, before the version: ``rafi record 0.1.0``.
RECORDED_BY = "rafi record"
#: A recording's file name: the run (``--name`` or the plan's ``run``), the UTC time of its
#: first sample, the ``_N`` that keeps an existing file, ``.csv``.
RECORDING_NAME = re.compile(
    r"^(?P<run>[A-Za-z0-9][A-Za-z0-9._-]{0,79})_(?P<start>[0-9]{8}T[0-9]{6}Z)(?:_[0-9]{1,3})*\.csv$"
)
#: The glob that finds the candidates in a machine folder (the name rule decides).
RECORDING_GLOB = "*.csv"
#: How much of a file's start is read for its header: the notes (at most 4000 characters),
#: the plan's name, the endpoint and the other metadata fit well within it.
HEAD_MAX_BYTES = 64 * 1024
_RECORDED_BY_LINE = re.compile(r"^#\s*recorded_by:\s*" + re.escape(RECORDED_BY) + r"(\s|$)")


def is_recording_name(name: str) -> bool:
    """True if ``name`` (a file name, no folder) is one ``rafi record`` gives its files:
    ``rec_20260302T080000Z.csv``, ``train_03000rpm_20260302T080000Z_2.csv``."""
    return RECORDING_NAME.match(name) is not None


def has_recording_header(path: str | os.PathLike) -> bool:
    """True if the leading ``#`` lines of ``path`` hold ``# recorded_by: rafi record``.

    Only the first :data:`HEAD_MAX_BYTES` bytes are read; blank lines are skipped and the first
    other line that does not start with ``#`` ends the header. A file that cannot be read (or
    is not a regular file) is not a recording: discovery and the reader say what is wrong with it.
    """
    try:
        with open(path, "rb") as fh:
            head = fh.read(HEAD_MAX_BYTES)
    except OSError:
        return False
    text = head.decode("utf-8", errors="replace").removeprefix("\ufeff")
    for line in text.splitlines():
        stripped = line.strip()
        if not stripped:
            continue
        if not stripped.startswith("#"):
            return False
        if _RECORDED_BY_LINE.match(stripped):
            return True
    return False


def is_recording(path: str | os.PathLike) -> bool:
    """True if ``path`` is a file ``rafi record`` wrote: its name (:func:`is_recording_name`) and
    its header (:func:`has_recording_header`) say so."""
    path = Path(path)
    return is_recording_name(path.name) and not_a_file(path) is None and has_recording_header(path)


def find_recordings(
    folder: str | os.PathLike, spec: dict, raw_dir: str | os.PathLike
) -> tuple[list[Path], list[str]]:
    """The recordings in one machine folder, sorted, and a warning line per candidate refused.

    Parameters
    ----------
    folder : path
        ``raw/<machine>/``.
    spec : dict
        The machine's normalised ``input:`` mapping: a machine with several probes
        (``input.probes``) has no recordings (``rafi record`` refuses it).
    raw_dir : path
        The raw folder: a link out of it is refused (``link_outside_raw``), as discovery does.

    Returns
    -------
    recordings : list of Path
        Regular files with a recording's name and header (:func:`is_recording`); hidden names
        (a recording still being written, ``.<name>.csv.part``) never.
    refused : list of str
        A ``link_outside_raw`` or ``not_a_file`` line per candidate name that cannot be read
        (the same line :func:`rafi.readers.input_spec.scan_logs` gives for a name of the pattern).
    """
    if spec.get("probes"):
        return [], []
    names = sorted(
        p
        for p in Path(folder).glob(RECORDING_GLOB)
        if not p.name.startswith(".") and is_recording_name(p.name)
    )
    inside, refused = split_outside(names, raw_dir)
    found = []
    for path in inside:
        what = not_a_file(path)  # never open a FIFO
        if what is not None:
            refused.append(not_a_file_warning(path, what))
        elif has_recording_header(path):
            found.append(path)
    return found, refused


def recording_spec(spec: dict) -> dict:
    """The ``input:`` mapping a recording of a machine is read with: the native format, the
    machine's sensors (``spec["sensors"]``) and its ``sample_period_s`` (used only where the file's
    own metadata gives none); everything else of the machine's mapping (format, pattern, columns,
    sheet, join, time, displacement unit and sign, temperature unit) describes the machine's own
    logs, not what ``rafi record`` writes.

    Parameters
    ----------
    spec : dict
        The machine's normalised ``input:`` mapping
        (:func:`rafi.readers.input_spec.normalise_input_spec`: ``sensors`` resolved).

    Returns
    -------
    dict
        A native mapping for :func:`rafi.readers.logs.read_log`.
    """
    out = {"format": "native", "sensors": list(spec["sensors"])}
    if spec.get("sample_period_s") is not None:
        out["sample_period_s"] = spec["sample_period_s"]
    return out
