"""Of a machine's byte-identical raw files, which one stays (standard library only).

The checkpoint ``input_status`` rejects all but one of the raw files that share their content
(:func:`rafi.readers.checks_machine.duplicate_rejections`: the same data must not be trained or
validated on twice). Which one stays must not depend on how a newcomer is named: a copy
``train_03000rpm (copy).csv`` sorts before ``train_03000rpm.csv``, and keeping the first by
name quarantined the original and trained on the copy. :func:`copies_to_keep` ranks the files
of one content:

1. a regular file before a symbolic link (removing the link loses nothing);
2. the file the champion was trained on (its name and content in the ``data`` of the
   champion's artefact, :func:`champion_training_files`): the model in service stays the
   model of tonight's data;
3. the oldest file (modification time): the newcomer is the copy;
4. the name, when all else is equal (a ``cp -p`` copy keeps the mtime).

:func:`duplicate_keepers` is the ``keep`` param of rule ``input_status``, computed while
Snakemake plans (hence the standard library only). It names only contents held by more than
one file, so a machine without duplicates always gets ``{}`` and a promotion does not make the
next run re-run the checkpoint.
"""

from __future__ import annotations

import json
import os
from collections import Counter
from collections.abc import Iterable, Mapping
from pathlib import Path

#: Prefix of a readable file's raw stamp (``rafi.ops.raw_hashes``).
STAMP_PREFIX = "sha256:"


def champion_training_files(registry: str | os.PathLike) -> dict[str, str]:
    """``file -> sha256`` the champion of a registry folder was trained on.

    The ``data`` of ``models/<id>.json``, ``<id>`` from ``champion.json``. ``{}`` without a
    champion, or if either file is missing or unreadable (the files are not verified here:
    rule ``decide`` does that before it uses them).
    """
    root = Path(registry)
    try:
        pointer = json.loads((root / "champion.json").read_text(encoding="utf-8"))
        model_id = str(pointer["model_id"])
        if not model_id or "/" in model_id or model_id.startswith("."):
            return {}
        model = json.loads((root / "models" / f"{model_id}.json").read_text(encoding="utf-8"))
    except (OSError, ValueError, KeyError, TypeError):
        return {}
    data = model.get("data") if isinstance(model, dict) else None
    if not isinstance(data, dict):
        return {}
    return {str(file): str(sha) for file, sha in data.items()}


def copies_to_keep(
    contents: Mapping[str, str],
    *,
    trained_on: Mapping[str, str],
    mtimes: Mapping[str, int],
    links: Iterable[str] = (),
) -> dict[str, str]:
    """For every content held by more than one file, the file that stays.

    Parameters
    ----------
    contents : mapping
        ``file name -> sha256`` of the machine's raw files (files without a hash left out).
    trained_on : mapping
        ``file name -> sha256`` the champion was trained on (:func:`champion_training_files`).
    mtimes : mapping
        ``file name -> modification time`` (ns); a file without one counts as the newest.
    links : iterable of str
        The files that are symbolic links.

    Returns
    -------
    dict
        ``sha256 -> file name``, the best of each group by the ranking of the module docstring.
    """
    linked = set(links)
    groups: dict[str, list[str]] = {}
    for file, sha in contents.items():
        groups.setdefault(sha, []).append(file)

    def rank(file: str) -> tuple:
        known = trained_on.get(file) == contents[file]
        return (file in linked, not known, mtimes.get(file, float("inf")), file)

    return {sha: min(files, key=rank) for sha, files in sorted(groups.items()) if len(files) > 1}


def duplicate_keepers(
    raw_paths: Mapping[str, str | os.PathLike],
    stamps: Mapping[str, str],
    registry: str | os.PathLike,
    names: Mapping[str, str] | None = None,
) -> dict[str, str]:
    """The ``keep`` param of rule ``input_status``: :func:`copies_to_keep` of one machine.

    Parameters
    ----------
    raw_paths : mapping
        ``log id -> raw path`` of the machine's files.
    stamps : mapping
        ``log id -> raw stamp`` (``sha256:<hex>``, or ``unreadable:...``: left out).
    registry : path
        The machine's registry folder (its champion's training files).
    names : mapping, optional
        ``log id -> the log's name`` (its ``file`` in the audit; default: the raw file's name;
        a sheet of a workbook goes by its log id, ``rafi.readers.log_sources.log_name``).
    """
    names = {stem: (names or {}).get(stem) or Path(path).name for stem, path in raw_paths.items()}
    contents = {
        names[stem]: stamp[len(STAMP_PREFIX) :]
        for stem, stamp in stamps.items()
        if stem in raw_paths and str(stamp).startswith(STAMP_PREFIX)
    }
    held = Counter(contents.values())
    duplicated = {file: sha for file, sha in contents.items() if held[sha] > 1}
    if not duplicated:
        return {}
    paths = {names[stem]: Path(p) for stem, p in raw_paths.items()}
    mtimes, links = {}, []
    for file in duplicated:
        try:
            mtimes[file] = paths[file].lstat().st_mtime_ns
        except OSError:
            continue  # gone since discovery: counts as the newest
        if paths[file].is_symlink():
            links.append(file)
    return copies_to_keep(
        duplicated, trained_on=champion_training_files(registry), mtimes=mtimes, links=links
    )
