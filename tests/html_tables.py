"""The tables of rendered report HTML, cell by cell (for tests that check what a table shows)."""

from __future__ import annotations

import html as _html
import re


def _visible(fragment: str) -> str:
    """A cell's visible text: tags dropped, entities resolved, white space (not the no-break
    space) collapsed."""
    return re.sub(r"[ \t\r\n]+", " ", _html.unescape(re.sub(r"<[^>]+>", "", fragment))).strip()


def html_tables(page: str, cls: str | None = None) -> list[dict]:
    """The ``<table>`` elements of ``page`` (of class ``cls`` only, if given).

    Parameters
    ----------
    page : str
        Rendered HTML.
    cls : str, optional
        The table's exact ``class`` attribute.

    Returns
    -------
    list of dict
        Per table: ``cls``, ``headers`` (visible text), ``widths`` (the ``<col>`` widths, %),
        ``rows`` (per row a list of cells: ``text`` (visible), ``html`` (inner HTML), ``cls``
        (class attribute or ``""``)) and ``records`` (per row ``header -> visible text``).
    """
    out = []
    for m in re.finditer(r'<table class="([^"]*)">(.*?)</table>', page, flags=re.S):
        if cls is not None and m.group(1) != cls:
            continue
        body = m.group(2)
        widths = [float(w) for w in re.findall(r'<col style="width: ([0-9.]+)%">', body)]
        head = re.search(r"<thead>(.*?)</thead>", body, flags=re.S)
        headers = [
            _visible(h) for h in re.findall(r"<th[^>]*>(.*?)</th>", head.group(1) if head else "", re.S)
        ]
        rows = []
        tbody = re.search(r"<tbody>(.*?)</tbody>", body, flags=re.S)
        for tr in re.findall(r"<tr>(.*?)</tr>", tbody.group(1) if tbody else "", flags=re.S):
            cells = []
            for attrs, inner in re.findall(r"<td([^>]*)>(.*?)</td>", tr, flags=re.S):
                c = re.search(r'class="([^"]*)"', attrs)
                cells.append({"text": _visible(inner), "html": inner.strip(), "cls": c.group(1) if c else ""})
            rows.append(cells)
        records = [dict(zip(headers, [c["text"] for c in r])) for r in rows]
        out.append(
            {"cls": m.group(1), "headers": headers, "widths": widths, "rows": rows, "records": records}
        )
    return out
