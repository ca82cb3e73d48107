"""A content-addressed memo of the model family's cross-validation scores (``comparison/cv.csv``).

The whole-run CV of :func:`rafi.family.compare.run_family` is a pure function of what it reads:
the logs holding a training run (every column of every row: a filter runs through the other runs
of such a log), the table rows of their runs, the settings the models are built from, and the
code. Its key (:func:`cv_memo_key`) is the SHA-256 of exactly those, with the digest of the code
the compare job runs (the rule's ``code`` param, :func:`rafi.ops.code_deps.code_version`) and the
versions of the numerical libraries; its value is the CV rows, stored as Parquet (floats to the
last bit) in ``results/<machine>/.cv_memo/<key>.parquet``, with the out-of-fold samples the
prediction intervals are calibrated on (:data:`rafi.family.intervals.OOF_COLUMNS`) beside them in
``<key>.oof.parquet`` (written first: an entry is its CV rows, read only with its OOF samples).

It decides nothing about what runs: Snakemake re-runs ``rule compare`` as before (its inputs,
params and code), and the job, when the memo holds the key, reads the CV rows instead of
computing them - e.g. on a night that only added a validation log. Same key, same rows: a
result can never be stale, only recomputed. Only the :data:`KEEP` newest entries are kept; the
folder may be deleted at any time.
"""

from __future__ import annotations

import hashlib
import json
import os
import platform
from pathlib import Path

import numpy as np
import pandas as pd

from rafi.family.crossval import training_runs
from rafi.family.whole_log import rows_of_logs

__all__ = [
    "MEMO_FORMAT",
    "KEEP",
    "training_content",
    "cv_memo_key",
    "read_cv",
    "write_cv",
    "read_oof",
    "write_oof",
]

#: Changes when the memo's layout or key changes (old entries are then never read).
MEMO_FORMAT = "rafi.cv_memo/5"
#: Entries kept per folder, the newest by modification time.
KEEP = 8


def _frame_digest(frame: pd.DataFrame, digest) -> None:
    """Feed ``frame`` into ``digest``: its shape, column names, dtypes and values in row order.
    Not the index: a log added before the training logs shifts their labels, not their values,
    and nothing the CV computes depends on the labels."""
    digest.update(f"{frame.shape}|{list(map(str, frame.columns))}".encode())
    for name in frame.columns:
        values = frame[name]
        array = np.asarray(values)
        digest.update(f"|{name}:{values.dtype}:".encode())
        if array.dtype.kind in "biufcmM":
            digest.update(np.ascontiguousarray(array).tobytes())
        else:  # text or mixed: each value's repr, NaN and None apart
            digest.update("\x1f".join(map(repr, array.tolist())).encode())


def training_content(runs_table: pd.DataFrame, runs_frame: pd.DataFrame) -> str:
    """SHA-256 of what the cross-validation reads: every row (all columns, in order) of the logs
    that hold a training run, and the table rows of the runs in those logs."""
    train, _ = training_runs(runs_table, runs_frame)
    logs = runs_frame.loc[rows_of_logs(runs_frame, train["run_id"])]
    runs = runs_table.loc[runs_table["run_id"].astype(str).isin(logs["run_id"].astype(str).unique())]
    digest = hashlib.sha256()
    _frame_digest(logs, digest)
    _frame_digest(runs, digest)
    return digest.hexdigest()


def cv_memo_key(runs_table: pd.DataFrame, runs_frame: pd.DataFrame, settings: dict, code_version: str) -> str:
    """The memo key of a CV: :data:`MEMO_FORMAT`, ``code_version`` (the digest of the code that
    computes it), the numerical libraries' versions, ``settings`` (everything the models are
    built from, as canonical JSON) and :func:`training_content`."""
    import scipy

    identity = {
        "format": MEMO_FORMAT,
        "code": str(code_version),
        "libraries": [platform.python_version(), np.__version__, pd.__version__, scipy.__version__],
        "settings": settings,
        "training": training_content(runs_table, runs_frame),
    }
    text = json.dumps(identity, sort_keys=True, default=repr, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def read_cv(folder: str | os.PathLike, key: str) -> pd.DataFrame | None:
    """The CV rows stored under ``key`` in ``folder``, or ``None`` (absent or unreadable)."""
    path = Path(folder) / f"{key}.parquet"
    try:
        return pd.read_parquet(path)
    except (OSError, ValueError):
        return None


def write_cv(folder: str | os.PathLike, key: str, cv: pd.DataFrame) -> Path:
    """Store ``cv`` under ``key`` in ``folder`` (atomically), keeping the :data:`KEEP` newest
    entries (an entry's OOF samples go with it)."""
    from rafi.artefact import write_parquet_atomic

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{key}.parquet"
    write_parquet_atomic(cv, path)
    entries = [p for p in folder.glob("*.parquet") if not p.name.endswith(OOF_SUFFIX)]
    entries.sort(key=lambda p: (p.stat().st_mtime, p.name), reverse=True)
    for old in entries[KEEP:]:
        old.unlink(missing_ok=True)
        (folder / f"{old.stem}{OOF_SUFFIX}").unlink(missing_ok=True)
    return path


#: File name ending of an entry's out-of-fold samples.
OOF_SUFFIX = ".oof.parquet"


def read_oof(folder: str | os.PathLike, key: str) -> pd.DataFrame | None:
    """The OOF samples stored under ``key`` in ``folder``, or ``None`` (absent or unreadable)."""
    try:
        return pd.read_parquet(Path(folder) / f"{key}{OOF_SUFFIX}")
    except (OSError, ValueError):
        return None


def write_oof(folder: str | os.PathLike, key: str, oof: pd.DataFrame) -> Path:
    """Store the OOF samples ``oof`` under ``key`` in ``folder`` (atomically; before :func:`write_cv`,
    which prunes them with their entry)."""
    from rafi.artefact import write_parquet_atomic

    path = Path(folder) / f"{key}{OOF_SUFFIX}"
    path.parent.mkdir(parents=True, exist_ok=True)
    write_parquet_atomic(oof.reset_index(drop=True), path)
    return path
