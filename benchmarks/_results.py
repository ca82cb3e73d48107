"""Where the benchmarks put their results, and the one function that writes them.

Every benchmark ends with ``write_results(stem, report, text)``: ``<out_dir>/<stem>.json`` (the
report) and ``<stem>.md`` (the table), each written atomically through rafi's
``write_text_atomic`` (a temporary file beside the target, fsynced, then renamed onto it), so a
killed or failing run leaves the previous file or the new one, never half of one, and no
temporary file.

The JSON options are keyword arguments because the benchmarks' files differ in them (indent,
``ensure_ascii``, a final newline, the fallback for values JSON cannot encode); each benchmark
passes the ones its files have always had, so its output stays byte for byte what it was.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from rafi.artefact import write_text_atomic  # noqa: E402

OUT_DIR = ROOT / "benchmarks" / "results"


def results_json(
    report: Any,
    *,
    indent: int = 2,
    ensure_ascii: bool = True,
    default: Callable[[Any], Any] = str,
    final_newline: bool = False,
) -> str:
    """The text of a results JSON file.

    Parameters
    ----------
    report
        Anything ``json.dumps`` encodes; other values go through ``default``.
    indent, ensure_ascii, default
        Passed to ``json.dumps`` (keys keep their insertion order).
    final_newline
        End the text with ``\\n``.

    Returns
    -------
    str
        The JSON text.
    """
    text = json.dumps(report, indent=indent, ensure_ascii=ensure_ascii, default=default)
    return text + "\n" if final_newline else text


def write_results(
    stem: str,
    report: Any,
    text: str | None = None,
    *,
    out_dir: Path = OUT_DIR,
    indent: int = 2,
    ensure_ascii: bool = True,
    default: Callable[[Any], Any] = str,
    final_newline: bool = False,
) -> tuple[Path, ...]:
    """Write ``<out_dir>/<stem>.json`` and, when ``text`` is given, ``<stem>.md``, each atomically.

    Parameters
    ----------
    stem
        File name without suffix.
    report
        The JSON content (see ``results_json`` for ``indent``, ``ensure_ascii``, ``default`` and
        ``final_newline``).
    text
        The markdown content, written as is; ``None`` writes no ``.md``.
    out_dir
        The folder, created if missing (default ``benchmarks/results``).

    Returns
    -------
    tuple of Path
        The files written: the ``.json``, then the ``.md`` if any.
    """
    out_dir = Path(out_dir)
    json_path = out_dir / f"{stem}.json"
    write_text_atomic(
        json_path,
        results_json(
            report, indent=indent, ensure_ascii=ensure_ascii, default=default, final_newline=final_newline
        ),
    )
    if text is None:
        return (json_path,)
    md_path = out_dir / f"{stem}.md"
    write_text_atomic(md_path, text)
    return (json_path, md_path)
