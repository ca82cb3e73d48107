"""Files of the hostile-log corpus: the shipped sources in, the corpus written beside a machine's logs.

:func:`shipped_sources` reads (or has the twin simulate again) the logs the cases start from;
:func:`write_hostile_corpus` writes every case of :func:`rafi.twin.hostile.hostile_corpus`, a link
leaving ``raw/`` and a file still being written, and returns the ground truth
(``rafi simulate hostile``).
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from rafi.twin.hostile import SOURCES, HostileCase, hostile_corpus


def shipped_sources(shipped_dir: str | os.PathLike | None = None) -> dict[str, str]:
    """Text of the shipped logs of :data:`SOURCES`: read from ``shipped_dir`` when it holds them
    all, else simulated again by the twin (byte for byte the shipped files, a few seconds).

    Parameters
    ----------
    shipped_dir : path, optional
        Folder of the shipped tapping-center-a logs (``raw/tapping-center-a``).

    Returns
    -------
    dict
        File name -> text.
    """
    folder = Path(shipped_dir) if shipped_dir is not None else None
    if folder is not None and all((folder / name).is_file() for name in SOURCES):
        return {name: (folder / name).read_text(encoding="utf-8") for name in SOURCES}
    from rafi.twin.recipes import shipped_specs
    from rafi.twin.writers import render_run

    specs = {spec.file: spec for spec in shipped_specs("tapping-center-a")}
    return {name: render_run(specs[name])[0] for name in SOURCES}


def write_hostile_corpus(
    shipped_dir: str | os.PathLike | None,
    machine_dir: str | os.PathLike,
    outside_dir: str | os.PathLike,
    *,
    long_bytes: int = 200_000,
    settling: bool = True,
) -> list[HostileCase]:
    """Write the hostile corpus into ``machine_dir``; return its cases (the ground truth).

    Parameters
    ----------
    shipped_dir : path or None
        Folder holding the shipped tapping-center-a logs (:data:`SOURCES`); None or a folder
        without them: the twin simulates them again (:func:`shipped_sources`).
    machine_dir : path
        Machine folder under ``raw/`` to write into (created).
    outside_dir : path
        A folder outside ``raw/`` for the target of the link case.
    long_bytes : int
        Length of the oversized line.
    settling : bool
        Also write a file that is still being written (its modification time is now).

    Returns
    -------
    list of HostileCase
    """
    machine_dir, outside_dir = Path(machine_dir), Path(outside_dir)
    machine_dir.mkdir(parents=True, exist_ok=True)
    outside_dir.mkdir(parents=True, exist_ok=True)
    sources = shipped_sources(shipped_dir)
    cases = []
    old = time.time() - 86_400  # a day old: settled
    for case, text in hostile_corpus(sources, long_bytes=long_bytes):
        path = machine_dir / case.file
        path.write_text(text, encoding="utf-8")
        os.utime(path, (old, old))
        cases.append(case)
    target = outside_dir / "elsewhere.csv"
    target.write_text(sources["train_06000rpm.csv"], encoding="utf-8")
    link = machine_dir / "hostile_link_outside.csv"
    link.symlink_to(target.resolve())
    cases.append(
        HostileCase("link_outside", link.name, "link_outside_raw", "not_read", "a symlink leaving raw/")
    )
    if settling:
        text = sources["train_06000rpm.csv"]
        half = text[: len(text) // 2].rsplit("\n", 1)[0] + "\n"
        (machine_dir / "hostile_settling.csv").write_text(half, encoding="utf-8")
        cases.append(
            HostileCase(
                "settling",
                "hostile_settling.csv",
                "settling",
                "not_read",
                "a file still being written (half its rows, modified now)",
            )
        )
    return cases
