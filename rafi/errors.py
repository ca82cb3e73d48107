"""The documented error types.

* :class:`RawFormatError` - a raw log that cannot be read as documented in
  ``docs/raw-format.md`` (or as its machine's ``input:`` mapping says). It is the
  only error a reader (``rafi.readers.native.read_raw_log``, ``rafi.readers.logs.read_log``) or the
  plausibility checks (``rafi.readers.checks.check_log``) raise for bad *data*.
* :class:`InputSpecError` - the ``input:`` mapping in ``config.yaml`` itself is
  wrong (unknown format, bad unit, ...). It is raised before any file is read and
  is a configuration mistake, not a bad file, so the workflow should stop rather
  than quarantine the file.
"""

from __future__ import annotations

from pathlib import Path


class RawFormatError(ValueError):
    """A log file that cannot be read as documented in ``docs/raw-format.md``.

    The message always names the file and, where known, the line (1-based, as an
    editor shows it) - or, for a spreadsheet, the sheet and row (1-based, as Excel
    shows it) - and the column, then what was found and what was expected.

    Parameters
    ----------
    path : str or Path
        File that failed.
    message : str
        What was found and what was expected.
    line : int, optional
        1-based line number in the file (row number for a spreadsheet).
    column : str, optional
        Column name (as written in the file's header) concerned.
    sheet : str, optional
        Worksheet name for spreadsheets; the location then reads ``sheet 'S', row N``.
    """

    def __init__(
        self,
        path,
        message: str,
        *,
        line: int | None = None,
        column: str | None = None,
        sheet: str | None = None,
    ):
        self.path = str(path)
        self.line = line
        self.column = column
        self.sheet = sheet
        self.reason = message
        where = self.path
        if sheet is not None:
            where += f", sheet {sheet!r}"
        if line is not None:
            where += f", {'row' if sheet is not None else 'line'} {line}"
        if column is not None:
            where += f", column {column!r}"
        super().__init__(f"{where}: {message}")

    @property
    def file_name(self) -> str:
        return Path(self.path).name


class InputSpecError(ValueError):
    """The per-machine ``input:`` mapping is invalid (a configuration error).

    The message names the offending key (e.g. ``input.displacement.unit``) and the
    accepted values.
    """


class RegistryError(RuntimeError):
    """The registry is inconsistent (hash mismatch, overwrite attempt, unknown model id)."""


class IncompatibleModels(ValueError):
    """Two models cannot be merged speed by speed (different sensors, terms or reference)."""


class LockHeld(RuntimeError):
    """Another process holds the nightly lock; ``holder`` is what it wrote in the file."""

    def __init__(self, path: Path, holder: str):
        self.path = path
        self.holder = holder.strip() or "unknown process"
        super().__init__(f"another nightly run holds {path}: {self.holder}")


class SettingsError(ValueError):
    """``config.yaml`` puts a setting where nothing reads it, or names an unknown one.

    The message names the key and where it belongs.
    """
