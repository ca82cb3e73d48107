"""The audit of a machine's raw files: one summary row per file, quarantined files, and the
check that stops an interactive run on a file that could not be used.

``audit.csv`` is the stack of the per-file summaries (``docs/design.md``). A file that cannot
be read or fails the plausibility checks is *quarantined*: the clean step writes empty
outputs and a summary row with ``status`` ``quarantined`` and the reason (the error message
naming file, line and column), or, with ``on_bad_input: fail``, the clean job fails with
that message (``workflow/scripts/clean.py``). The plausibility checks' warnings are audit rows
with action ``warning`` (:func:`warning_rows`); the summary counts them (``warnings``) and
records the file's ``probe_sign`` (docs/raw-format.md, "Checks").
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import pandas as pd

from rafi.contract.sensors import DEFAULT_SENSORS
from rafi.errors import RawFormatError
from rafi.method.clean import AUDIT_COLUMNS

#: Columns of the per-file summary (``audit.csv``), in order.
SUMMARY_COLUMNS = (
    "file",
    "sha256",
    "rows_in",
    "rows_out",
    "duplicates_dropped",
    "reordered",
    "spikes_replaced",
    "values_interpolated",
    "gaps_interpolated",
    "segments",
    "status",
    "reason",
    "warnings",
    "probe_sign",
    "open_circuit_removed",
    "values_left_missing",
    "missing_spans",
)

#: ``action`` of an audit row that records a warning of the plausibility checks.
WARNING_ACTION = "warning"


def summarise_audit(
    file,
    sha256: str,
    rows_in: int,
    clean_frame: pd.DataFrame,
    audit_actions: pd.DataFrame,
    *,
    probe_sign: int = 0,
) -> pd.DataFrame:
    """One-row summary of the cleaning of one file (a row of ``audit.csv``).

    Parameters
    ----------
    file : str
        File name as it should appear in ``audit.csv``.
    sha256 : str
        Hex SHA-256 of the raw file.
    rows_in : int
        Data rows read from the raw file.
    clean_frame, audit_actions : pandas.DataFrame
        The two results of :func:`clean_log` (``audit_actions`` with the :func:`warning_rows`
        of the checks appended).
    probe_sign : int
        The file's probe sign from the checks (+1, -1, 0 = no evidence).

    Returns
    -------
    pandas.DataFrame
        One row with ``file``, ``sha256``, ``rows_in``, ``rows_out`` (rows of the
        clean grid), ``duplicates_dropped`` (rows), ``reordered`` (backwards steps
        repaired), ``spikes_replaced`` (values), ``values_interpolated`` (sensor /
        extra values filled after a dropout or open circuit; spikes and inserted
        gap rows not included), ``gaps_interpolated`` (gaps bridged, not rows),
        ``segments``, ``status`` (``ok``), ``reason`` (empty), ``warnings`` (rows with action
        ``warning``), ``probe_sign``, ``open_circuit_removed`` (values equal to an open-circuit
        marker, removed: then bridged or left missing like a dropout), ``values_left_missing``
        (values left NaN: a gap longer than ``max_interpolate_gap_s`` or at a segment's end) and
        ``missing_spans`` (:func:`missing_spans`).
    """
    a = audit_actions

    def rows_of(action: str) -> int:
        if len(a) == 0:
            return 0
        return int(a.loc[a["action"] == action, "n_rows"].sum())

    def events_of(action: str) -> int:
        return int((a["action"] == action).sum()) if len(a) else 0

    segments = (
        int(pd.Series(clean_frame["segment"]).nunique())
        if "segment" in clean_frame and len(clean_frame)
        else (1 if len(clean_frame) else 0)
    )
    row = {
        "file": str(file),
        "sha256": str(sha256),
        "rows_in": int(rows_in),
        "rows_out": int(len(clean_frame)),
        "duplicates_dropped": rows_of("duplicate_dropped"),
        "reordered": rows_of("reordered"),
        "spikes_replaced": rows_of("spike_replaced"),
        "values_interpolated": rows_of("dropout_interpolated"),
        "gaps_interpolated": events_of("gap_interpolated"),
        "segments": segments,
        "status": "ok",
        "reason": "",
        "warnings": events_of(WARNING_ACTION),
        "probe_sign": int(probe_sign),
        "open_circuit_removed": rows_of("open_circuit_removed"),
        "values_left_missing": rows_of("dropout_left_nan"),
        "missing_spans": missing_spans(a),
    }
    return pd.DataFrame([row], columns=list(SUMMARY_COLUMNS))


def missing_spans(audit_actions: pd.DataFrame) -> str:
    """The values a file's cleaning left missing, one span per ``dropout_left_nan`` row, in
    source-line order, joined by ``"; "``: ``"T8 lines 1145-1200: 56 open-circuit value(s)
    removed and left missing"`` or ``"T11 lines 404-489: 86 value(s) absent from the file and left
    missing"`` (``""`` without any).

    A span's open-circuit values are the ``open_circuit_removed`` rows of its column inside its
    lines; a span holding both kinds says how many of its values were open-circuit markers. A
    sample that needs such a value is not fitted or scored and gets no compensation.
    """
    a = audit_actions
    if len(a) == 0:
        return ""
    left = a[a["action"] == "dropout_left_nan"]
    opened = a[a["action"] == "open_circuit_removed"]
    spans = []
    for r in left.itertuples(index=False):
        first, last, n = int(r.first_line), int(r.last_line), int(r.n_rows)
        inside = (
            (opened["column"] == r.column) & (opened["first_line"] >= first) & (opened["last_line"] <= last)
        )
        n_open = int(opened.loc[inside, "n_rows"].sum())
        if n_open >= n:
            what = f"{n} open-circuit value(s) removed and left missing"
        elif n_open:
            what = f"{n} value(s) left missing, {n_open} of them open-circuit values removed"
        else:
            what = f"{n} value(s) absent from the file and left missing"
        spans.append((first, str(r.column), f"{r.column} lines {first}-{last}: {what}"))
    return "; ".join(text for *_, text in sorted(spans))


def warning_rows(file: str, warnings) -> pd.DataFrame:
    """Audit rows (``clean/<stem>.audit.csv``) of the checks' warnings: action ``warning``,
    ``column``, ``first_line`` / ``last_line`` (empty when the finding has no span), ``n_rows`` 0
    and ``detail`` ``"<check id>: <message>"``.

    Parameters
    ----------
    file : str
        File name as in the other audit rows.
    warnings : iterable of rafi.readers.checks_base.CheckWarning
        What :func:`rafi.readers.checks.check_file` returned.
    """
    rows = [
        {
            "file": str(file),
            "action": WARNING_ACTION,
            "column": w.column,
            "first_line": w.first_line,
            "last_line": w.last_line,
            "n_rows": 0,
            "detail": w.detail,
        }
        for w in warnings
    ]
    frame = pd.DataFrame(rows, columns=list(AUDIT_COLUMNS))
    for col in ("first_line", "last_line", "n_rows"):
        frame[col] = frame[col].astype("Int64")
    return frame


def with_warnings(audit_actions: pd.DataFrame, warnings: pd.DataFrame) -> pd.DataFrame:
    """The cleaning's audit rows followed by the :func:`warning_rows` (line columns nullable)."""
    if len(warnings) == 0:
        return audit_actions
    if len(audit_actions) == 0:
        return warnings.reset_index(drop=True)
    actions = audit_actions.copy()
    for col in ("first_line", "last_line", "n_rows"):
        actions[col] = actions[col].astype("Int64")
    return pd.concat([actions, warnings], ignore_index=True)


#: Longest text of an unexpected exception quoted in a quarantine reason.
REASON_CHARS = 300


def one_line(exc: BaseException, limit: int | None = REASON_CHARS) -> str:
    """An exception's text on one line, at most ``limit`` characters (``None``: all of it)."""
    text = " ".join(str(exc).split())
    if limit is not None and len(text) > limit:
        text = text[:limit] + " ..."
    return text


def quarantine_reason(exc: BaseException, file: str) -> str:
    """The one-line reason a file is quarantined for ``exc``, ending with ``[<check id>]``.

    A :class:`rafi.errors.RawFormatError` is its own (already bounded) message plus its check id;
    any other exception names the file and the exception type, quoted to :data:`REASON_CHARS`
    characters, with ``[unreadable]`` for an ``OSError``.
    """
    if isinstance(exc, RawFormatError):
        return one_line(exc, None) + (f" [{exc.check}]" if exc.check else "")
    tag = " [unreadable]" if isinstance(exc, OSError) else ""
    return f"{file}: could not be read or cleaned: {type(exc).__name__}: {one_line(exc)}{tag}"


def quarantined(
    file: str, sha256: str, reason: str, sensors: Sequence[str] = DEFAULT_SENSORS
) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """The clean step's outputs for a file that could not be read or checked.

    Returns an empty clean frame with the usual columns (the machine's ``sensors``) and types, an empty audit
    table, and a summary row with ``status`` ``quarantined`` and the ``reason`` (the
    error message naming file, line and column), so the other files carry on and the
    report lists this one.
    """
    clean = pd.DataFrame(
        {
            "time": pd.Series(dtype="datetime64[ns]"),
            "t_s": pd.Series(dtype="float64"),
            "speed_rpm": pd.Series(dtype="float64"),
            **{c: pd.Series(dtype="float64") for c in (*sensors, "disp_um")},
            "segment": pd.Series(dtype="int64"),
        }
    )
    actions = pd.DataFrame(columns=list(AUDIT_COLUMNS))
    summary = pd.DataFrame(
        [
            {
                "file": file,
                "sha256": sha256,
                "rows_in": pd.NA,
                "rows_out": 0,
                "duplicates_dropped": 0,
                "reordered": 0,
                "spikes_replaced": 0,
                "values_interpolated": 0,
                "gaps_interpolated": 0,
                "segments": 0,
                "status": "quarantined",
                "reason": reason,
                "warnings": 0,
                "probe_sign": 0,
                "open_circuit_removed": 0,
                "values_left_missing": 0,
                "missing_spans": "",
            }
        ],
        columns=list(SUMMARY_COLUMNS),
    )
    return clean, actions, summary


def stack_summaries(summaries: Iterable[pd.DataFrame]) -> pd.DataFrame:
    """``audit.csv``: the per-file summary rows of a machine, in the order given."""
    frames = list(summaries)
    if not frames:
        return pd.DataFrame(columns=list(SUMMARY_COLUMNS))
    return pd.concat(frames, ignore_index=True)
