"""``rafi diff OLD NEW``: are two result trees the same, number for number?

Compares two runs of the pipeline (``results/`` and ``reports/`` of each, or any two folders):
every CSV and Parquet table cell by cell, every JSON document key by key, and the text of every
HTML report token by token. What must differ between two honest runs is left out and listed:
timings (``benchmarks/`` folders), creation times, the code version and the model ids that
cover it, the registry's history. Used to show that a change of code layout changed no result
(``docs/decisions.md``), and by anyone upgrading who wants the same check.
"""

from __future__ import annotations

import argparse
import html
import json
import math
import re
import sys
from pathlib import Path

from rafi.contract import RESULT_FILES, RUN_FILES

#: JSON keys whose values differ between two runs of the same code on the same data.
VOLATILE_KEYS = frozenset(
    {
        "created",
        "model_id",
        "code_version",
        "git_commit",
        "decided_at",
        "time",
        "registered",
        "champion_id_before",
        "champion_id_after",
        "candidate_id",
        "promoted_at",
        "at",
    }
)

#: Folders and files never compared: timings, logs and the registry's append-only history.
SKIPPED = (
    "benchmarks/",
    "history.jsonl",
    ".nightly",
    "registry/models/",
    "champion.json",
    ".clean_cache/",  # the clean step's former cache (results of before issue 23)
    RESULT_FILES["cv_memo"] + "/",
    RUN_FILES["template_cache"] + "/",
)

_HEX_ID = re.compile(r"\b[0-9a-f]{12,64}\b")
_ISO_TIME = re.compile(r"\d{4}-\d{2}-\d{2}[T ]\d{2}:\d{2}(:\d{2})?(\.\d+)?(Z|[+-]\d{2}:?\d{2})?")
_TAG = re.compile(r"<[^>]+>")
_DATA_URI = re.compile(r"data:[a-z/+]+;base64,[A-Za-z0-9+/=]+")
_SVG = re.compile(r"<svg.*?</svg>", re.S)


def _skipped(rel: str) -> bool:
    return any(part in rel for part in SKIPPED)


def _close(a, b, rtol: float) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        try:
            fa, fb = float(a), float(b)
        except (TypeError, ValueError):
            return a == b
        if math.isnan(fa) and math.isnan(fb):
            return True
        return fa == fb or abs(fa - fb) <= rtol * max(abs(fa), abs(fb))
    return a == b


def diff_json(a, b, path: str = "", rtol: float = 0.0) -> list[str]:
    """Differences between two JSON values, volatile keys left out."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            if key in VOLATILE_KEYS:
                continue
            if key not in a or key not in b:
                out.append(f"{path}/{key}: only in {'new' if key in b else 'old'}")
                continue
            out += diff_json(a[key], b[key], f"{path}/{key}", rtol)
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: {len(a)} items vs {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in diff_json(x, y, f"{path}[{i}]", rtol)]
    if isinstance(a, str) and isinstance(b, str):
        a, b = _HEX_ID.sub("<id>", a), _HEX_ID.sub("<id>", b)
    return [] if _close(a, b, rtol) else [f"{path}: {a!r} vs {b!r}"]


def diff_frames(a, b, rtol: float = 0.0) -> list[str]:
    """Differences between two tables (column names, shape, then cell by cell)."""
    import numpy as np
    import pandas as pd

    if list(a.columns) != list(b.columns):
        return [f"columns {list(a.columns)} vs {list(b.columns)}"]
    if a.shape != b.shape:
        return [f"shape {a.shape} vs {b.shape}"]
    out = []
    for col in a.columns:
        x, y = a[col], b[col]
        if pd.api.types.is_numeric_dtype(x) and pd.api.types.is_numeric_dtype(y):
            xv, yv = x.to_numpy(dtype=float), y.to_numpy(dtype=float)
            same = (xv == yv) | (np.isnan(xv) & np.isnan(yv))
            if rtol:
                same |= np.abs(xv - yv) <= rtol * np.maximum(np.abs(xv), np.abs(yv))
        else:
            xs = x.astype(str).str.replace(_HEX_ID, "<id>", regex=True)
            ys = y.astype(str).str.replace(_HEX_ID, "<id>", regex=True)
            # pandas >= 3 keeps a missing value missing through astype(str): missing on both sides is the same
            same = ((xs == ys).fillna(False) | (xs.isna() & ys.isna())).to_numpy(dtype=bool)
        if not same.all():
            i = int(np.argmin(same))
            out.append(
                f"column {col}: {int((~same).sum())} cell(s) differ, "
                f"first at row {i}: {x.iloc[i]!r} vs {y.iloc[i]!r}"
            )
    return out


def report_tokens(text: str) -> list[str]:
    """The words and numbers an HTML report shows (figures, ids and times masked)."""
    text = _SVG.sub(" <figure> ", _DATA_URI.sub("<figure>", text))
    text = re.sub(r"<(script|style)\b.*?</\1>", " ", text, flags=re.S)
    text = html.unescape(_TAG.sub(" ", text))
    text = _HEX_ID.sub("<id>", _ISO_TIME.sub("<time>", text))
    text = re.sub(r"rafi \d+\.\d+\.\d+( \(git <id>\))?", "<code-version>", text)
    return text.split()


def diff_file(old: Path, new: Path, rtol: float = 0.0) -> list[str]:
    """Differences between two result files of the same name."""
    suffix = old.suffix.lower()
    if suffix == ".csv":
        import pandas as pd

        return diff_frames(pd.read_csv(old), pd.read_csv(new), rtol)
    if suffix == ".parquet":
        import pandas as pd

        return diff_frames(pd.read_parquet(old), pd.read_parquet(new), rtol)
    if suffix == ".json":
        return diff_json(json.loads(old.read_text()), json.loads(new.read_text()), "", rtol)
    if suffix == ".html":
        a, b = report_tokens(old.read_text(encoding="utf-8")), report_tokens(new.read_text(encoding="utf-8"))
        if a == b:
            return []
        import difflib

        changes = [
            f"{tag}: {' '.join(a[i1:i2])[:200]!r} -> {' '.join(b[j1:j2])[:200]!r}"
            for tag, i1, i2, j1, j2 in difflib.SequenceMatcher(None, a, b, autojunk=False).get_opcodes()
            if tag != "equal"
        ]
        return changes
    return []  # binary (PDF, PNG): the HTML they are rendered from is compared


def diff_trees(old: Path, new: Path, rtol: float = 0.0) -> dict[str, list[str]]:
    """Per relative path, the differences between two result trees (missing files included)."""

    def files(root: Path) -> dict[str, Path]:
        return {
            str(p.relative_to(root)): p
            for p in root.rglob("*")
            if p.is_file() and not _skipped(str(p.relative_to(root)))
        }

    a, b = files(old), files(new)
    out: dict[str, list[str]] = {}
    for rel in sorted(set(a) | set(b)):
        if Path(rel).suffix.lower() not in (".csv", ".parquet", ".json", ".html"):
            continue
        if rel not in b or rel not in a:
            out[rel] = [f"only in {'old' if rel in a else 'new'}"]
            continue
        found = diff_file(a[rel], b[rel], rtol)
        if found:
            out[rel] = found
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("old", type=Path, help="one result tree (e.g. a copy of results/ and reports/)")
    parser.add_argument("new", type=Path, help="the other")
    parser.add_argument(
        "--rtol", type=float, default=0.0, help="relative tolerance for numbers (default: exact)"
    )


def run(args) -> int:
    found = diff_trees(args.old, args.new, args.rtol)
    for rel, diffs in found.items():
        print(rel)
        for d in diffs[:20]:
            print(f"  {d}")
    print(f"{len(found)} file(s) differ" if found else "no difference (timings, times, ids aside)")
    return 1 if found else 0


if __name__ == "__main__":  # pragma: no cover
    parser = argparse.ArgumentParser(description=__doc__)
    add_arguments(parser)
    sys.exit(run(parser.parse_args()))
