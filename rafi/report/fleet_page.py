"""The fleet overview page ``reports/index.html``: every machine's state on one page.

The rows are :func:`rafi.ops.fleet.fleet_overview`'s (machines that need attention first),
computed by the caller (the report imports nothing of ``rafi.ops``); the page is one
self-contained HTML file (template ``templates/fleet_index.html.j2``, inline CSS,
no script) whose links point at each machine's ``qualification.html`` or ``skipped.html``,
relative to where the page is written. Written by rule ``fleet_index``
(``workflow/rules/fleet.smk``), after a night for some machines by ``rafi nightly``, and by
``rafi status --html PATH``.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Protocol

from rafi.artefact import now_iso, write_text_atomic

TEMPLATE = "fleet_index.html.j2"

#: Serialises writers of the page (nights for different machines may end at the same time);
#: under ``results_dir``, named like the nightly's files but never like a machine's lock.
PAGE_LOCK = ".nightly.page-lock"


class ProjectPaths(Protocol):
    """The folders of a project the page names (``rafi.ops.project.Paths`` is one)."""

    directory: Path
    raw_dir: Path
    results_dir: Path


def _environment():
    """The jinja2 environment of the page's template (autoescaped, strict)."""
    import jinja2

    return jinja2.Environment(
        loader=jinja2.PackageLoader("rafi.report", "templates"),
        autoescape=jinja2.select_autoescape(["html", "j2"], default_for_string=True),
        undefined=jinja2.StrictUndefined,
        trim_blocks=True,
        lstrip_blocks=True,
    )


def machine_groups(rows: list[dict]) -> list[dict]:
    """The rows of :func:`rafi.ops.fleet.fleet_overview` by machine: a machine with several probes
    (units ``<machine>@<probe>``, :func:`rafi.settings.split_unit`) is one machine with its
    probes' rows under it.

    Parameters
    ----------
    rows : list of dict
        One per qualification unit (``machine``, ``state``, ``rank``; a probe's
        ``machine_report``: its machine's page), in the order to show.

    Returns
    -------
    list of dict
        One per machine, in the order of its first row: ``machine`` (the folder), ``units`` (its
        rows in order, each ``{"probe", "row"}``: the probe's name, None for the machine
        itself), ``probes`` (its probe names; ``[]`` for a machine with one probe, whose row is
        the machine's), ``state`` / ``rank`` (the most urgent of its rows: a machine needs
        attention when one of its probes does), ``report`` (a machine with several probes:
        its own page, or None where it is not built) and ``above_gate`` (``{"probe", "text"}`` of
        each probe whose model in service with the controller's limits leaves more than the
        largest-residual gate: its row's ``replay_above_gate``).
    """
    from rafi.settings import split_unit

    groups: dict = {}
    for r in rows:
        folder, probe = split_unit(r["machine"])
        first = {"machine": folder, "units": [], "probes": [], "report": None, "above_gate": []}
        g = groups.setdefault(folder, {**first, "state": r["state"], "rank": r["rank"]})
        g["units"].append({"probe": probe, "row": r})
        if probe is not None:
            g["probes"].append(probe)
            g["report"] = g["report"] or r.get("machine_report")
        if r.get("replay_above_gate"):
            g["above_gate"].append({"probe": probe, "text": r["replay_above_gate"]})
        if r["rank"] < g["rank"]:
            g["state"], g["rank"] = r["state"], r["rank"]
    return list(groups.values())


def fleet_page(
    rows: list[dict],
    *,
    created: str,
    results_dir: str = "results",
    raw_dir: str = "raw",
    link_prefix: str = "",
) -> str:
    """HTML of the fleet overview.

    Parameters
    ----------
    rows : list of dict
        :func:`rafi.ops.fleet.fleet_overview` (in the order to show; ``state`` and its
        attention ``rank`` are read), one per qualification unit: the page lists them by machine
        (:func:`machine_groups`), counts machines and links a machine's own page.
    created : str
        When the page is written (shown).
    results_dir, raw_dir : str
        Shown to the reader.
    link_prefix : str
        Put before each row's ``report`` (a path relative to ``reports_dir``) so the link works
        from where the page is: ``""`` for ``reports/index.html``.

    Returns
    -------
    str
        A complete HTML document (every value escaped).
    """
    shown = []
    for r in rows:
        r = dict(r)
        for key in ("report", "machine_report"):
            if r.get(key):
                r[key] = f"{link_prefix}{r[key]}"
        shown.append(r)
    groups = machine_groups(shown)
    by_state = Counter(g["state"] for g in groups)
    rank = {g["state"]: g["rank"] for g in groups}
    counts = {
        "machines": len(groups),
        "attention": sum(1 for g in groups if g["state"] != "ok"),
        "by_state": sorted(by_state.items(), key=lambda kv: (rank[kv[0]], kv[0])),
    }
    return (
        _environment()
        .get_template(TEMPLATE)
        .render(
            rows=shown,
            groups=groups,
            counts=counts,
            rank=rank,
            created=created,
            results_dir=results_dir,
            raw_dir=raw_dir,
        )
    )


def _link_prefix(reports_dir: Path, out: Path) -> str:
    """What to put before a path relative to ``reports_dir`` to reach it from the page ``out``."""
    rel = os.path.relpath(reports_dir.resolve(), out.resolve().parent)
    return "" if rel == "." else rel.replace(os.sep, "/") + "/"


def write_fleet_page(
    paths: ProjectPaths,
    reports_dir: str | os.PathLike,
    out: str | os.PathLike | None = None,
    *,
    rows: list[dict] | Callable[[], list[dict]],
) -> Path:
    """Write the overview of every machine to ``out`` (default ``<reports_dir>/index.html``).

    The write runs under an exclusive ``flock`` on ``results/.nightly.page-lock`` (waits for
    another writer); rows given as a function are read under it too, so the last page written
    read every machine's files after the writer before it had finished.

    Parameters
    ----------
    paths : ProjectPaths
        The project (``rafi.ops.project.Paths``).
    reports_dir : path
        The project's ``reports_dir``.
    out : path, optional
        Where to write the page.
    rows : list of dict, or a function returning them
        The machines' rows, :func:`rafi.ops.fleet.fleet_overview` (a function is called under
        the lock, e.g. ``lambda: fleet_overview(paths, reports_dir)``).

    Returns
    -------
    Path
        The page written (atomic replace).
    """
    reports_dir = Path(reports_dir)
    out = Path(out) if out is not None else reports_dir / "index.html"
    lock_path = paths.results_dir / PAGE_LOCK
    lock_path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        html = fleet_page(
            rows() if callable(rows) else rows,
            created=now_iso(),
            results_dir=_shown(paths.results_dir, paths.directory),
            raw_dir=_shown(paths.raw_dir, paths.directory),
            link_prefix=_link_prefix(reports_dir, out),
        )
        out.parent.mkdir(parents=True, exist_ok=True)
        write_text_atomic(out, html)
    finally:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)
    return out


def _shown(path: Path, directory: Path) -> str:
    """``path`` relative to the project folder where it is inside it (as the page shows it)."""
    with contextlib.suppress(ValueError):
        return str(Path(path).relative_to(directory))
    return str(path)
