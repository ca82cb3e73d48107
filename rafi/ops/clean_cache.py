"""Content-addressed cache of the clean step's per-file outputs (standard library only).

The workflow cleans all raw files of a machine in ONE job (rule ``clean``: one Python start-up
per machine instead of one per file). Its output is the folder ``results/<machine>/clean/``,
which Snakemake deletes before the job runs, so the per-file outputs of a file that did not
change cannot be "kept": they are restored from this cache instead, keyed by everything that
determines them:

- the raw file's name (it is written into the audit rows) and the SHA-256 of its content;
- the settings the clean step uses (``input``, ``sample_period_s``, ``clean``, the checks'
  settings), as canonical JSON;
- the code: the SHA-256 of the rafi modules the step runs, the rule's script and its glue
  (``code_fingerprint``), and the versions of pandas, NumPy and PyArrow (Parquet bytes).

Only files that were cleaned (status ``ok``) are stored; a quarantined file is read again on
every run of the job, so a fail-mode run fails on it with its message exactly as before. An
entry is a folder ``results/<machine>/.clean_cache/<key>/`` holding the three outputs as hard
links to the files the job wrote (a copy where links are impossible) and ``log.txt``, the
lines the file's cleaning wrote to the log; a restore links them back, so a restored file keeps
its bytes and its modification time. Writes are atomic (a temporary folder renamed into
place). After a successful job the entries no current raw file uses are removed (``prune``).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Iterable, Mapping
from pathlib import Path

#: Folder of the cache under ``results/<machine>/``.
CACHE_DIR = ".clean_cache"

#: The per-file outputs of the clean step: key -> suffix after the file's log id.
SUFFIXES = {"parquet": ".parquet", "audit": ".audit.csv", "summary": ".summary.csv"}

_LOG = "log.txt"


def output_paths(folder: str | os.PathLike, stem: str) -> dict[str, Path]:
    """The per-file outputs of log id ``stem`` in the clean folder: ``parquet``, ``audit``, ``summary``."""
    return {kind: Path(folder) / f"{stem}{suffix}" for kind, suffix in SUFFIXES.items()}


def stems_in(folder: str | os.PathLike) -> list[str]:
    """Log ids with a summary in the clean folder, sorted (the order of the raw files' ids)."""
    suffix = SUFFIXES["summary"]
    return sorted(p.name[: -len(suffix)] for p in Path(folder).iterdir() if p.name.endswith(suffix))


def files_in(folder: str | os.PathLike, kind: str) -> list[str]:
    """Paths of one kind of per-file output (a key of ``SUFFIXES``) in the clean folder,
    in log-id order."""
    return [str(output_paths(folder, stem)[kind]) for stem in stems_in(folder)]


def _sha256_bytes(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def code_fingerprint(paths: Iterable[str | os.PathLike]) -> str:
    """SHA-256 over the names and contents of the code files (order-independent) and the
    versions of the libraries that write the outputs."""
    digest = hashlib.sha256()
    for path in sorted(str(p) for p in paths):
        digest.update(Path(path).name.encode("utf-8") + b"\0")
        digest.update(_sha256_bytes(Path(path).read_bytes()).encode("ascii") + b"\n")
    versions = {}
    for name in ("pandas", "numpy", "pyarrow"):
        with contextlib.suppress(Exception):
            from importlib.metadata import version

            versions[name] = version(name)
    digest.update(json.dumps(versions, sort_keys=True).encode("utf-8"))
    return digest.hexdigest()


def cache_key(file_name: str, sha256: str, settings: Mapping, code: str) -> str:
    """The key of one file's outputs (hex SHA-256 of the canonical JSON of what determines them)."""
    content = {"file": file_name, "sha256": sha256, "settings": settings, "code": code}
    text = json.dumps(content, sort_keys=True, separators=(",", ":"), default=str)
    return _sha256_bytes(text.encode("utf-8"))


def _link_or_copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(FileNotFoundError):
        dst.unlink()
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


class CleanCache:
    """The cache of one machine's clean outputs, rooted at ``results/<machine>/.clean_cache``."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        self.used: set[str] = set()

    def _entry(self, key: str) -> Path:
        return self.root / key

    def restore(self, key: str, outputs: Mapping[str, Path]) -> list[str] | None:
        """Put the cached outputs of ``key`` at ``outputs``; return the log lines stored with
        them, or None (and restore nothing) if there is no complete entry."""
        entry = self._entry(key)
        sources = {kind: entry / Path(path).name for kind, path in outputs.items()}
        if not all(p.is_file() for p in sources.values()) or not (entry / _LOG).is_file():
            return None
        for kind, src in sources.items():
            _link_or_copy(src, Path(outputs[kind]))
        self.used.add(key)
        return (entry / _LOG).read_text(encoding="utf-8").splitlines()

    def store(self, key: str, outputs: Mapping[str, Path], log_lines: Iterable[str]) -> None:
        """Keep the outputs just written under ``key`` (no-op if the entry exists)."""
        self.used.add(key)
        entry = self._entry(key)
        if entry.is_dir():
            return
        self.root.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{key[:12]}.", dir=self.root))
        try:
            for path in outputs.values():
                _link_or_copy(Path(path), tmp / Path(path).name)
            (tmp / _LOG).write_text("".join(f"{line}\n" for line in log_lines), encoding="utf-8")
            os.replace(tmp, entry)
        except OSError:
            shutil.rmtree(tmp, ignore_errors=True)
            if not entry.is_dir():
                raise

    def prune(self) -> int:
        """Remove the entries (and leftover temporary folders) not used since this object was
        made; return how many were removed."""
        if not self.root.is_dir():
            return 0
        removed = 0
        for entry in self.root.iterdir():
            if entry.name not in self.used:
                if entry.is_dir():
                    shutil.rmtree(entry, ignore_errors=True)
                else:
                    entry.unlink(missing_ok=True)
                removed += 1
        return removed
