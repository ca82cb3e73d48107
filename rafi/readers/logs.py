"""Reading one raw log of a machine, whatever its format, and hashing it."""

from __future__ import annotations

import hashlib
import os

import pandas as pd

from rafi.readers.native import read_raw_log
from rafi.readers.parsing import open_regular, unreadable_error


def sha256_file(path: str | os.PathLike) -> str:
    """Return the hex SHA-256 of a file's bytes (read in blocks of 1 MiB).

    Raises
    ------
    RawFormatError
        Check ``unreadable``: the file cannot be opened or read (permissions, an I/O error,
        not a regular file: a directory, a FIFO - never waited on - or a socket); check
        ``file_too_large``: more than ``rafi.readers.parsing.FILE_MAX_BYTES`` bytes. The message
        says so and what to check.
    """
    digest = hashlib.sha256()
    with open_regular(path) as fh:
        try:
            for block in iter(lambda: fh.read(1 << 20), b""):
                digest.update(block)
        except OSError as exc:
            raise unreadable_error(path, exc) from None
    return digest.hexdigest()


def read_log(
    path: str | os.PathLike,
    input_spec: dict | None = None,
    *,
    sheet: str | None = None,
    partner: str | os.PathLike | None = None,
    name: str | None = None,
) -> pd.DataFrame:
    """Read one raw log as its machine's ``input:`` mapping says; return the canonical frame.

    Parameters
    ----------
    path : str or os.PathLike
        The raw file.
    input_spec : dict, optional
        The machine's ``input:`` mapping from ``config.yaml`` (``docs/raw-format.md``,
        "Bringing your own layout"). ``None`` or ``{"format": "native"}`` reads the
        native format with :func:`read_raw_log`; ``csv`` and ``xlsx`` go through
        :func:`rafi.readers.mapped.read_mapped`.
    sheet, partner, name : optional
        A log that is not a whole file (:mod:`rafi.readers.log_sources`): its sheet (when
        ``input.sheet`` is a pattern), its partner file (``input.join``) and its name.

    Returns
    -------
    pandas.DataFrame
        The canonical frame (same contract as :func:`read_raw_log`). A
        ``sample_period_s`` in the spec fills ``attrs['metadata']['sample_period_s']``
        (for native files only when the file's own metadata does not give one).

    Raises
    ------
    RawFormatError
        The file does not follow the format / mapping, breaks a limit (``line_too_long``,
        ``field_too_long``), holds formulas without values (``formula_without_value``) or
        cannot be read (``unreadable``).
    rafi.errors.InputSpecError
        The mapping itself is invalid.
    """
    from rafi.readers import mapped as formats

    spec = formats.normalise_input_spec(input_spec)
    if spec["format"] == "native":
        frame = read_raw_log(path, spec["sensors"], spec["missing_values"])
        if spec.get("sample_period_s") is not None:
            frame.attrs["metadata"].setdefault("sample_period_s", float(spec["sample_period_s"]))
        return frame
    return formats.read_mapped(path, spec, sheet=sheet, partner=partner, name=name)
