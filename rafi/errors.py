"""The one documented error type for bad input."""

from __future__ import annotations

from pathlib import Path


class RawFormatError(ValueError):
    """A log file that cannot be read as documented in ``docs/raw-format.md``.

    The message always names the file and, where known, the line (1-based, as an
    editor shows it) and the column, then what was expected.

    Parameters
    ----------
    path : str or Path
        File that failed.
    message : str
        What was found and what was expected.
    line : int, optional
        1-based line number in the file.
    column : str, optional
        Column name (or spreadsheet column) concerned.
    """

    def __init__(self, path, message: str, *, line: int | None = None, column: str | None = None):
        self.path = str(path)
        self.line = line
        self.column = column
        self.reason = message
        where = self.path
        if line is not None:
            where += f", line {line}"
        if column is not None:
            where += f", column {column!r}"
        super().__init__(f"{where}: {message}")

    @property
    def file_name(self) -> str:
        return Path(self.path).name
