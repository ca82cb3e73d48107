"""The report's figures: the files rule ``report_figures`` wrote, embedded in the HTML.

Each figure group is a folder ``results/<machine>/report/figures/<group>/`` holding one PNG
or SVG file per figure and ``index.csv`` (``key,file``: which figures the group drew; a
figure whose data is absent is not drawn and not listed). The report embeds the files (PNG
as a data URI, SVG inline), so the HTML and the PDF made from it need no other file. No
figure is drawn here: this module does not import matplotlib.
"""

from __future__ import annotations

import base64
import csv
import os
import re
from pathlib import Path

#: The list of figures in each group folder.
INDEX = "index.csv"

_SVG_SIZE = re.compile(r'<svg([^>]*?) width="[^"]*" height="[^"]*"')


def embed(data: bytes, fmt: str) -> dict:
    """A figure file as the template embeds it.

    Parameters
    ----------
    data : bytes
        The file's content.
    fmt : {"png", "svg"}

    Returns
    -------
    dict
        ``{"kind": "png", "src": "data:image/png;base64,..."}`` or ``{"kind": "svg", "svg":
        "<svg ...>"}`` (the XML prologue and the fixed size dropped, so it fills the width).
    """
    if fmt == "svg":
        text = data.decode("utf-8")
        text = text[text.index("<svg") :]
        return {"kind": "svg", "svg": _SVG_SIZE.sub(r"<svg\1", text, count=1)}
    if fmt == "png":
        return {"kind": "png", "src": "data:image/png;base64," + base64.b64encode(data).decode("ascii")}
    raise ValueError(f"figure format {fmt!r}; expected png or svg")


def read_index(folder: str | os.PathLike) -> dict:
    """``key -> file path`` of one group folder (its ``index.csv``)."""
    folder = Path(folder)
    with open(folder / INDEX, encoding="utf-8", newline="") as fh:
        return {row["key"]: folder / row["file"] for row in csv.DictReader(fh)}


class FigureFiles:
    """The figure files of the groups given, looked up by group and key.

    Parameters
    ----------
    folders : dict
        ``group -> folder`` of rule ``report_figures``. Every group the report asks for must
        be here; a figure its group did not draw (no data) is ``None``.
    """

    def __init__(self, folders: dict):
        self.files = {group: read_index(folder) for group, folder in folders.items()}
        self.used: list[str] = []

    def get(self, group: str, key: str) -> dict | None:
        """Figure ``key`` of ``group``, embedded (:func:`embed`), or ``None`` if not drawn."""
        if group not in self.files:
            raise ValueError(f"no figure folder of group {group!r} was given to the report")
        path = self.files[group].get(key)
        if path is None:
            return None
        self.used.append(f"{group}/{key}")
        return embed(path.read_bytes(), path.suffix[1:])
