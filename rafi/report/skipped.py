"""The page of a skipped machine: ``reports/<machine>/skipped.html`` (standard library only).

A machine none of whose raw files is usable (every one quarantined, ``on_bad_input:
quarantine``) gets no qualification report; this short page takes its place, so people who open
the machine's report folder see that it was skipped, which files were rejected and why.
"""

from __future__ import annotations

import html

from rafi.readers.quarantine import is_skipped

_STYLE = """
body { font-family: "DejaVu Sans", Arial, sans-serif; margin: 2em auto; max-width: 60em; color: #222; }
h1 { font-size: 1.5em; margin-bottom: 0.2em; }
.verdict { border-left: 6px solid #b26b00; background: #fff4e0; padding: 0.6em 1em; margin: 1em 0; }
table { border-collapse: collapse; width: 100%; margin: 0.5em 0 1em 0; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.5em; text-align: left; vertical-align: top; }
th { background: #f2f2f2; }
code { font-size: 0.95em; }
.small { color: #555; font-size: 0.9em; }
"""


def _how_many(n: int) -> str:
    return "The only raw file was" if n == 1 else f"All {n} raw files were"


def skipped_page(status: dict, *, created: str, audit_path: str = "", status_path: str = "") -> str:
    """HTML of the page of a skipped machine.

    Parameters
    ----------
    status : dict
        The machine's input status (:func:`rafi.readers.quarantine.machine_input_status`) with
        ``status`` ``skipped``.
    created : str
        When the page is written (ISO-8601 text), shown on the page.
    audit_path, status_path : str
        Where ``audit.csv`` and ``input_status.json`` of the machine are (shown to the reader).

    Returns
    -------
    str
        A complete HTML document (every value from ``status`` escaped).

    Raises
    ------
    ValueError
        If ``status`` is not that of a skipped machine.
    """
    if not is_skipped(status):
        raise ValueError(
            f"machine {status.get('machine')!r} is not skipped (status {status.get('status')!r})"
        )
    esc = html.escape
    machine = esc(str(status["machine"]))
    rejected = status.get("rejected") or []
    rows = "\n".join(
        f"<tr><td><code>{esc(str(f['file']))}</code></td><td><code>{esc(str(f.get('sha256') or '')[:12])}"
        f"</code></td><td>{esc(str(f['reason']))}</td></tr>"
        for f in rejected
    )
    where = " and ".join(f"<code>{esc(p)}</code>" for p in (audit_path, status_path) if p)
    return f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{machine}: skipped, no usable raw file</title>
<style>{_STYLE}</style>
</head>
<body>
<h1>{machine}: skipped</h1>
<p class="small">RAFI qualification, {esc(created)}</p>
<div class="verdict"><strong>No usable raw file.</strong> {_how_many(len(rejected))} of this
machine quarantined, so nothing was cleaned into runs, fitted, validated or judged: there is
no qualification report for this data, no candidate model and no registry decision. The model
in service on the machine (if any) stays as it was; any other report in this folder is from an
earlier run with usable data. The other machines of the run were processed as usual.</div>
<h2>Rejected files</h2>
<table>
<thead><tr><th>file</th><th>sha256</th><th>reason</th></tr></thead>
<tbody>
{rows}
</tbody>
</table>
<h2>What to do</h2>
<p>Fix or replace the files named above (the reason gives file, line and column where known) or
remove them, and add usable logs. The next run picks up the change; this page is removed once
the machine has a usable file again.{f" The same list is in {where}." if where else ""}</p>
</body>
</html>
"""
