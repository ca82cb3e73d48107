"""Model artefacts and the files around them: canonical JSON, model id, code version,
atomic writes (temporary file, fsync, rename; fsync of the folder).

Every file the project writes goes through this module, so an interrupted run never
leaves a half-written file that looks complete.
"""

from __future__ import annotations

import contextlib
import datetime as dt
import hashlib
import json
import math
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rafi import __version__
from rafi.readers.input_spec import log_id

if TYPE_CHECKING:
    import pandas as pd


def jsonable(value):
    """Convert numpy scalars/arrays, tuples, timestamps and NaN to plain JSON values (NaN -> None)."""
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return [jsonable(v) for v in value.tolist()]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return v if math.isfinite(v) else None
    if hasattr(value, "isoformat"):  # pandas.Timestamp, datetime
        return value.isoformat()
    return value


def canonical_json(content: dict) -> str:
    """Canonical JSON used for ``model_id``: sorted keys, no whitespace, ASCII, no NaN."""
    return json.dumps(
        jsonable(content), sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False
    )


def code_version() -> str:
    """``"rafi <version>"`` plus the git commit of the source tree (:func:`git_commit`), if any."""
    commit = git_commit()
    if commit and re.fullmatch(r"[0-9a-f]{40}", commit):
        return f"rafi {__version__} (git {commit[:12]})"
    return f"rafi {__version__}"


def now_iso() -> str:
    """Current UTC time, ISO-8601 with seconds and ``Z``."""
    return dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


#: Fields of an artefact that are provenance, not the model: left out of its id.
PROVENANCE_FIELDS = ("model_id", "created")


def _names_to_hashes(value, names: dict[str, str]):
    """``value`` with every string in ``names`` (a training file's name or log id) replaced by the
    file's SHA-256, and a run ``<log id>#<k>`` by ``<sha256>#<k>``; in dict keys too, unless two
    keys would become one."""
    if isinstance(value, str):
        if value in names:
            return names[value]
        log, sep, k = value.rpartition("#")
        return f"{names[log]}#{k}" if sep and k.isdigit() and log in names else value
    if isinstance(value, dict):
        values = {str(k): _names_to_hashes(v, names) for k, v in value.items()}
        renamed = {_names_to_hashes(k, names): v for k, v in values.items()}
        return renamed if len(renamed) == len(values) else values
    if isinstance(value, (list, tuple)):
        return [_names_to_hashes(v, names) for v in value]
    return value


def identity_content(model_dict: dict) -> dict:
    """What a model id hashes: the artefact's content, without provenance.

    ``model_id`` and ``created`` are left out (and the ``created`` of each of an ensemble's
    ``members``, :mod:`rafi.family.ensemble`, which keep their own ``model_id``), and the
    training files' names are replaced by their content: ``data`` (``file -> sha256``) becomes
    the sorted list of the hashes, and every string naming a training file - its name, its log id
    (the run of a one-run file, e.g. in ``train_runs``) or a run ``<log id>#<k>`` - becomes the
    file's SHA-256 (``#<k>`` kept). So a training file renamed, or a byte-identical copy trained
    on in its place, gives the same id.
    """
    content = {k: v for k, v in model_dict.items() if k not in PROVENANCE_FIELDS}
    members = content.get("members")
    if isinstance(members, dict):  # an ensemble's members: when each was written is not the model
        content["members"] = {
            n: {k: v for k, v in a.items() if k != "created"} if isinstance(a, dict) else a
            for n, a in members.items()
        }
    data = content.get("data")
    if not isinstance(data, dict) or not data:
        return content
    names: dict[str, str] = {}
    for file, sha in data.items():
        names[str(file)] = str(sha)
        names[log_id(Path(str(file)).stem)] = str(sha)
    content = {k: _names_to_hashes(v, names) for k, v in content.items() if k != "data"}
    content["data"] = sorted(str(sha) for sha in data.values())
    return content


def compute_model_id(model_dict: dict) -> str:
    """The model id: SHA-256 of the canonical JSON of :func:`identity_content`.

    It depends on the model (kind, terms, coefficients, settings, code version) and on the
    content of its training files, not on when it was made (``created``) nor on what its files
    are called: the same data gives the same model id.
    """
    return hashlib.sha256(canonical_json(identity_content(model_dict)).encode("ascii")).hexdigest()


def named_model_id(model_dict: dict) -> str:
    """The id of an artefact written before ids were content only: SHA-256 of the canonical JSON
    without ``model_id``/``created``, the training files' names included. Registries hold such
    artefacts under their id; :func:`model_id_verifies` still accepts them."""
    content = {k: v for k, v in model_dict.items() if k not in PROVENANCE_FIELDS}
    return hashlib.sha256(canonical_json(content).encode("ascii")).hexdigest()


def model_id_verifies(model_dict: dict, model_id: str | None = None) -> bool:
    """True if ``model_id`` (default: the artefact's own ``model_id``) is the id of the artefact's
    content: :func:`compute_model_id`, or :func:`named_model_id` for an artefact written before
    ids were content only. False for an edited artefact."""
    model_id = model_dict.get("model_id") if model_id is None else model_id
    if not isinstance(model_id, str) or not model_id:
        return False
    return model_id in (compute_model_id(model_dict), named_model_id(model_dict))


def json_text(obj) -> str:
    return json.dumps(jsonable(obj), indent=2, sort_keys=True, allow_nan=False) + "\n"


def fsync_dir(path: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def write_once(path: Path, text: str) -> bool:
    """Create ``path`` with ``text`` unless it exists; never overwrites.

    The content goes to a temporary file (fsynced) that is then hard-linked onto
    ``path``: ``link`` fails if ``path`` exists, so two writers cannot clobber each
    other and a reader never sees a half-written file. Returns True if created.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o444)
        try:
            os.link(tmp, path)
        except FileExistsError:
            return False
        fsync_dir(path.parent)
        return True
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)


def append_jsonl(path: Path, record: dict) -> None:
    """Append one JSON object as one line; flush and fsync before returning.

    The line is written with a single ``write`` on an ``O_APPEND`` descriptor, so
    concurrent appenders do not interleave and existing lines are never rewritten.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    line = json.dumps(jsonable(record), sort_keys=True, separators=(",", ":"), allow_nan=False) + "\n"
    if "\n" in line[:-1]:  # pragma: no cover - json.dumps never emits raw newlines
        raise ValueError("history record would span lines")
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        data = line.encode("utf-8")
        # A torn previous line (crash mid-write) must not swallow this record.
        if os.fstat(fd).st_size > 0:
            with open(path, "rb") as rf:
                rf.seek(-1, os.SEEK_END)
                if rf.read(1) != b"\n":
                    data = b"\n" + data
        os.write(fd, data)
        os.fsync(fd)
    finally:
        os.close(fd)


def read_jsonl(path: Path) -> list[dict]:
    """Records of a JSONL file; a torn (unparsable) line is skipped, not fatal."""
    if not path.exists():
        return []
    records = []
    for line in path.read_text(encoding="utf-8").splitlines():
        if not line.strip():
            continue
        try:
            obj = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(obj, dict):
            records.append(obj)
    return records


def git_commit(checkout: str | os.PathLike | None = None) -> str | None:
    """Commit checked out in ``checkout`` (default: the tree this package lives in), read from
    ``.git`` directly (no subprocess); ``None`` outside a git checkout.

    Only ``checkout`` itself is looked at, not its parents: a copy of the package installed
    inside some other repository (a virtual environment in a checkout) has no commit.
    """
    git = Path(checkout or Path(__file__).resolve().parents[1]) / ".git"
    try:
        head = (git / "HEAD").read_text().strip()
        if not head.startswith("ref:"):
            return head or None
        ref = head.split(None, 1)[1]
        if (git / ref).exists():
            return (git / ref).read_text().strip() or None
        packed = git / "packed-refs"
        if packed.exists():
            for line in packed.read_text().splitlines():
                parts = line.split()
                if len(parts) == 2 and parts[1] == ref:
                    return parts[0]
    except OSError:
        pass
    return None


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success fsync it, rename it onto ``path``
    and fsync the folder, so that after a crash ``path`` is either the old or the new file.

    On any exception the temporary file is removed and ``path`` is untouched.
    The file gets the usual permissions (``0o666`` less the umask), not
    ``mkstemp``'s private ``0o600``.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".part", dir=target.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_umask())
        fd = os.open(tmp_path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp_path, target)
        fsync_dir(target.parent)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def write_text_atomic(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8, ``\\n`` line ends) to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8", newline="\n")


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_csv_atomic(frame: pd.DataFrame, path: str | os.PathLike, **kwargs) -> None:
    """Write a table as CSV atomically (no index unless asked)."""
    kwargs.setdefault("index", False)
    kwargs.setdefault("lineterminator", "\n")
    with atomic_path(path) as tmp:
        frame.to_csv(tmp, **kwargs)


def write_parquet_atomic(frame: pd.DataFrame, path: str | os.PathLike) -> None:
    """Write a frame as Parquet atomically (index kept)."""
    with atomic_path(path) as tmp:
        frame.to_parquet(tmp, engine="pyarrow")
