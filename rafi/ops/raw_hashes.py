"""Content hashes of raw files, cached so that planning does not re-read an unchanged file.

Snakemake decides what is out of date by modification times. A raw file whose content changed
while its size and mtime were kept (``cp -p``, ``rsync -t``, ``touch -r``, ``os.utime``) would
not be re-read. So the clean rule carries the file's SHA-256 as a param
(``workflow/rules/common.smk``, ``raw_stamp``): a different hash fires Snakemake's ``params``
rerun trigger for that file's clean job only.

Hashing every raw file at every planning would read the whole of ``raw/`` each time, so the
hashes are cached in ``results/.raw_hashes.json``, keyed on the file's path and
``(size, mtime_ns, ctime_ns, inode)``. The inode change time (ctime) cannot be set by a user
(``utime`` sets only atime and mtime, and sets ctime to now), and every write to a file
changes it, so a content edit with the mtime put back still misses the cache and the file is
hashed again. A missing, unreadable or corrupt cache is ignored (everything is hashed again);
the cache is replaced atomically (temporary file, fsync, rename) and only when it changed.

Standard library only: ``workflow/rules/common.smk`` imports this module while Snakemake plans.
(``rafi.artefact`` imports NumPy, so the atomic replace is written out here.)
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path

from rafi.contract import RUN_FILES

#: The cache file, under ``results_dir``.
CACHE_NAME = RUN_FILES["raw_hashes"]

#: Format of the cache file (a different value is ignored: everything is hashed again).
CACHE_VERSION = 1

_CHUNK = 1 << 20


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 (hex) of the bytes of ``path``, read in 1 MiB chunks.

    Raises
    ------
    OSError
        If the file cannot be read.
    """
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def stat_key(st: os.stat_result) -> list[int]:
    """``[size, mtime_ns, ctime_ns, inode]``: what must be equal for a cached hash to be reused."""
    return [st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino]


def unreadable_stamp(exc: OSError) -> str:
    """The stamp of a file that cannot be read: ``unreadable:<errno name>`` (its clean job runs
    and reports the error; the stamp changes once the file can be read)."""
    name = errno.errorcode.get(exc.errno or 0, "error")
    return f"unreadable:{name}"


class RawHashCache:
    """SHA-256 of raw files, reused while a file's ``stat_key`` is unchanged.

    Parameters
    ----------
    cache_path : str or os.PathLike
        The JSON cache (``results/.raw_hashes.json``); need not exist.

    Attributes
    ----------
    hashed : int
        Files read (hashed) since the cache was loaded.
    reused : int
        Files whose cached hash was reused.
    """

    def __init__(self, cache_path: str | os.PathLike):
        self.path = Path(cache_path)
        self.entries: dict[str, list] = self._load()
        self.dirty = False
        self.hashed = 0
        self.reused = 0

    def _load(self) -> dict[str, list]:
        with contextlib.suppress(OSError, ValueError, TypeError, AttributeError):
            data = json.loads(self.path.read_text(encoding="utf-8"))
            if data.get("version") == CACHE_VERSION and isinstance(data.get("files"), dict):
                return {
                    str(k): v
                    for k, v in data["files"].items()
                    if isinstance(v, list) and len(v) == 5 and isinstance(v[4], str)
                }
        return {}

    def sha256(self, path: str | os.PathLike) -> str:
        """SHA-256 of ``path``: the cached one if the file's ``stat_key`` is unchanged, else
        read anew (and cached unless the file changed while it was read).

        Raises
        ------
        OSError
            If the file cannot be stat'ed or read.
        """
        key = os.path.abspath(path)
        before = stat_key(os.stat(key))
        entry = self.entries.get(key)
        if entry is not None and entry[:4] == before:
            self.reused += 1
            return entry[4]
        digest = file_sha256(key)
        self.hashed += 1
        if stat_key(os.stat(key)) == before:  # not being written while it was read
            self.entries[key] = [*before, digest]
            self.dirty = True
        return digest

    def stamp(self, path: str | os.PathLike) -> str:
        """``sha256:<hex>`` of ``path``, or :func:`unreadable_stamp` if it cannot be read."""
        try:
            return f"sha256:{self.sha256(path)}"
        except OSError as exc:
            return unreadable_stamp(exc)

    def save(self) -> bool:
        """Write the cache if it changed (entries of files that are gone are dropped).

        Returns False, writing nothing, if it cannot be written (read-only or full disk):
        the cache only saves time.
        """
        if not self.dirty:
            return True
        files = {k: v for k, v in sorted(self.entries.items()) if os.path.exists(k)}
        text = json.dumps({"version": CACHE_VERSION, "files": files}, separators=(",", ":")) + "\n"
        tmp = None
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".part", dir=self.path.parent)
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(text)
                fh.flush()
                os.fsync(fh.fileno())
            os.chmod(tmp, 0o644)
            os.replace(tmp, self.path)
        except OSError:
            if tmp is not None:
                with contextlib.suppress(OSError):
                    os.unlink(tmp)
            return False
        self.dirty = False
        return True


def raw_stamps(
    paths: Iterable[str | os.PathLike], cache_path: str | os.PathLike, *, write: bool = True
) -> dict[str, str]:
    """The stamp (:meth:`RawHashCache.stamp`) of every path, the cache saved once at the end.

    Parameters
    ----------
    paths : iterable of path
        Raw files.
    cache_path : path
        The cache (``results/.raw_hashes.json``).
    write : bool
        Save the cache (False for a dry run, which writes nothing).

    Returns
    -------
    dict
        ``{str(path): "sha256:<hex>" | "unreadable:<errno name>"}``.
    """
    cache = RawHashCache(cache_path)
    stamps = {str(p): cache.stamp(p) for p in paths}
    if write:
        cache.save()
    return stamps
