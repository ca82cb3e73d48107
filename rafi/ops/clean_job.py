"""The clean step of one machine in one process: every raw file -> its three per-file outputs.

Rule ``clean`` (``workflow/scripts/clean.py``) calls :func:`clean_machine`: every raw file, in
log-id order, is read, checked and cleaned by :func:`clean_file`. Snakemake alone decides when
the job runs (a raw file added, removed, changed - its content hash is a param -, a setting or
the code changed); then it cleans every file of the machine again (about 0.3 s a file), which
is what a job per machine costs instead of a job per file (docs/decisions.md).

- with ``on_bad_input=quarantine`` ANY failure reading, checking or cleaning the file (a
  RawFormatError, but also an OSError, a pandas ValueError, a MemoryError, ...) quarantines the
  file with a one-line reason (the traceback goes to the log); so does a clean table that
  cannot be read back;
- with ``fail`` the exception propagates: the job fails with the message (file, line, column)
  on the first bad file, in log-id order.

A reason ends with ``[<check id>]`` when the error is a documented check
(``docs/raw-format.md``); ``[unreadable]`` for an OSError.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

import rafi.artefact
import rafi.method.audit
import rafi.method.clean
import rafi.readers.log_sources
import rafi.readers.logs
from rafi.errors import RafiUserError, RawFormatError
from rafi.readers.checks import check_file
from rafi.readers.input_spec import normalise_input_spec
from rafi.readers.recordings import recording_spec

#: The per-file outputs of the clean step: key -> suffix after the file's log id
#: (``clean_parquet``, ``clean_audit``, ``clean_summary`` of :data:`rafi.contract.RESULT_FILES`).
SUFFIXES = {"parquet": ".parquet", "audit": ".audit.csv", "summary": ".summary.csv"}


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


@dataclass(frozen=True)
class CleanSettings:
    """What the clean step of a machine uses (the rule's params)."""

    input_spec: Mapping
    sample_period_s: float
    clean: Mapping
    checks: Mapping


def _write(outputs: Mapping[str, Path], clean, actions, summary) -> None:
    rafi.artefact.write_parquet_atomic(clean, outputs["parquet"])
    rafi.artefact.write_csv_atomic(actions, outputs["audit"])
    rafi.artefact.write_csv_atomic(summary, outputs["summary"])


def _as_bad_input(exc: Exception, src: Path) -> Exception:
    """What a fail-mode run raises for ``exc`` on raw file ``src``: a user error as it is; any other
    failure (a pandas ValueError, an OSError, ...) as a :class:`RawFormatError` naming the file
    with the reason a quarantine would give, so the run ends with one clear line, not a
    traceback (``debug: true`` shows the chained traceback)."""
    if isinstance(exc, RafiUserError):
        return exc
    check = "unreadable" if isinstance(exc, OSError) else None
    why = f"could not be read or cleaned: {type(exc).__name__}: {rafi.method.audit.one_line(exc)}"
    return RawFormatError(src, why, check=check)


def _log_digest(file_sha: str, part: Mapping) -> str:
    """The SHA-256 a log goes by (:func:`rafi.readers.log_sources.log_stamp`): the file's for a
    whole file; else one of the file's, its sheet's name and its partner's content."""
    if not part.get("sheet") and not part.get("partner"):
        return file_sha
    partner_stamp = None
    if part.get("partner"):
        try:
            partner_stamp = "sha256:" + rafi.readers.logs.sha256_file(part["partner"])
        except RawFormatError:
            partner_stamp = "missing"
    stamp = rafi.readers.log_sources.log_stamp("sha256:" + file_sha, part.get("sheet"), partner_stamp)
    return stamp.removeprefix("sha256:")


def clean_file(
    src: Path,
    outputs: Mapping[str, Path],
    settings: CleanSettings,
    *,
    fail_mode: bool,
    log: logging.Logger,
    say: Callable[[str], None] = print,
    sha: str | None = None,
    part: Mapping | None = None,
    name: str | None = None,
) -> str:
    """Read, check and clean one raw log; write its outputs; return ``ok`` or ``quarantined``.

    ``say`` gets the progress lines (the rule's log); ``log`` the warnings. ``sha`` is the
    file's SHA-256 if already known. A log that is not a whole file has ``part`` (``sheet``,
    ``partner``: :mod:`rafi.readers.log_sources`) and its ``name`` (default: the file's);
    its ``sha256`` is then :func:`rafi.readers.log_sources.log_stamp`'s. A file ``rafi record``
    wrote has ``part`` ``{"recording": True}``: it is read as a native file with the machine's
    sensors (:func:`rafi.readers.recordings.recording_spec`), whatever ``input.format``.
    """
    part = dict(part or {})
    # a file rafi record wrote is a native log whatever the machine's own format
    spec = settings.input_spec
    if part.get("recording"):
        spec = recording_spec(normalise_input_spec(spec))
    cfg = settings.clean
    digest = ""
    name = name or src.name

    def quarantine(reason: str) -> str:
        say(f"  QUARANTINED: {reason}")
        sensors = spec.get("sensors") or rafi.method.audit.DEFAULT_SENSORS
        _write(outputs, *rafi.method.audit.quarantined(name, digest, reason, sensors))
        return "quarantined"

    try:
        digest = sha or rafi.readers.logs.sha256_file(src)
        digest = _log_digest(digest, part)
        where = f", sheet {part['sheet']!r}" if part.get("sheet") else ""
        where += f", partner {part['partner']}" if part.get("partner") else ""
        what = "native: a recording of rafi record" if part.get("recording") else spec.get("format", "native")
        say(f"read {src}{where} (format {what}, sha256 {digest[:12]})")
        frame = rafi.readers.logs.read_log(
            src, spec, sheet=part.get("sheet"), partner=part.get("partner"), name=name
        )
        rows_in = len(frame)
        say(f"  {rows_in} rows, {frame.shape[1]} columns")
        joined = frame.attrs.get("metadata", {}).get("join")
        if joined:
            say(
                f"  joined {joined['columns']} of {joined['partner']} by {joined['by']}: "
                f"{joined['unmatched_rows']} row(s) without a partner row"
            )
        report = check_file(frame, src, **settings.checks)
        for w in report.warnings:
            log.warning("%s: %s", name, w.detail)
            say(f"  warning: {w.detail}")
        say(f"  checks: {len(report.warnings)} warning(s), probe sign {report.probe_sign:+d}")
        clean, actions = rafi.method.clean.clean_log(
            frame,
            file=name,
            sample_period_s=settings.sample_period_s,
            max_interpolate_gap_s=cfg["max_interpolate_gap_s"],
            spike_threshold=cfg["spike_threshold"],
            open_circuit_values=cfg["open_circuit_values"],
        )
        actions = rafi.method.audit.with_warnings(
            actions, rafi.method.audit.warning_rows(name, report.warnings)
        )
        summary = rafi.method.audit.summarise_audit(
            name, digest, rows_in, clean, actions, probe_sign=report.probe_sign
        )
    except Exception as exc:  # noqa: BLE001 - any failure on one file quarantines that file
        if fail_mode:
            raise _as_bad_input(exc, src) from exc
        reason = rafi.method.audit.quarantine_reason(exc, name)
        # a documented check needs no traceback; anything else keeps it in the log
        log.warning("quarantined %s: %s", name, reason, exc_info=not isinstance(exc, RawFormatError))
        return quarantine(reason)
    counts = actions["action"].value_counts().to_dict() if len(actions) else {}
    say(f"  clean: {len(clean)} rows; actions: {counts or 'none'}")
    _write(outputs, clean, actions, summary)
    # the next rule must be able to read what we wrote (e.g. huge metadata breaks parquet)
    try:
        back = pd.read_parquet(outputs["parquet"])
        if len(back) != len(clean):
            raise ValueError(f"{len(back)} rows read back, {len(clean)} written")
    except Exception as exc:  # noqa: BLE001
        why = (
            f"its clean table {outputs['parquet']} cannot be read back "
            f"({type(exc).__name__}: {rafi.method.audit.one_line(exc)})"
        )
        if fail_mode:
            raise RawFormatError(src, why, check="clean_table_unreadable") from exc
        log.warning("quarantined %s: %s", name, why, exc_info=True)
        return quarantine(f"{name}: {why} [clean_table_unreadable]")
    return "ok"


def clean_machine(
    raw_paths: Mapping[str, str],
    folder: str | Path,
    settings: CleanSettings,
    *,
    fail_mode: bool,
    log: logging.Logger,
    parts: Mapping[str, Mapping] | None = None,
) -> dict[str, str]:
    """Clean every raw log of a machine (``raw_paths``: log id -> path) into ``folder``.

    ``parts`` (log id -> ``{sheet, partner}``) gives the logs that are not a whole file
    (:func:`rafi.readers.input_spec.discover_logs`): a sheet of a workbook, a file joined with
    its partner. Returns log id -> ``ok`` or ``quarantined``.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    parts = parts or {}
    done: dict[str, str] = {}
    for stem in sorted(raw_paths):
        outputs = output_paths(folder, stem)
        part = parts.get(stem) or {}
        src = Path(raw_paths[stem])
        name = stem if part.get("sheet") else src.name
        done[stem] = clean_file(src, outputs, settings, fail_mode=fail_mode, log=log, part=part, name=name)
        print(f"wrote {outputs['parquet']}", flush=True)
        print(f"{stem}: {done[stem]}", flush=True)
    return done
