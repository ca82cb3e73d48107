"""The audit of a machine's raw files: one summary row per file, quarantined files, and the
check that stops an interactive run on a file that could not be used.

``audit.csv`` is the stack of the per-file summaries (``docs/design.md``). A file that cannot
be read or fails the plausibility checks is *quarantined*: the clean step writes empty
outputs and a summary row with ``status`` ``quarantined`` and the reason (the error message
naming file, line and column), or, with ``on_bad_input: fail``, the clean job fails with
that message (``workflow/scripts/clean.py``).
"""

from __future__ import annotations

from collections.abc import Iterable

import pandas as pd

from rafi.method.clean import AUDIT_COLUMNS, SENSOR_COLUMNS

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
)


def summarise_audit(
    file, sha256: str, rows_in: int, clean_frame: pd.DataFrame, audit_actions: pd.DataFrame
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
        The two results of :func:`clean_log`.

    Returns
    -------
    pandas.DataFrame
        One row with ``file``, ``sha256``, ``rows_in``, ``rows_out`` (rows of the
        clean grid), ``duplicates_dropped`` (rows), ``reordered`` (backwards steps
        repaired), ``spikes_replaced`` (values), ``values_interpolated`` (sensor /
        extra values filled after a dropout or open circuit; spikes and inserted
        gap rows not included), ``gaps_interpolated`` (gaps bridged, not rows),
        ``segments``, ``status`` (``ok``) and ``reason`` (empty).
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
    }
    return pd.DataFrame([row], columns=list(SUMMARY_COLUMNS))


def quarantined(file: str, sha256: str, reason: str) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]:
    """The clean step's outputs for a file that could not be read or checked.

    Returns an empty clean frame with the usual columns and types, an empty audit
    table, and a summary row with ``status`` ``quarantined`` and the ``reason`` (the
    error message naming file, line and column), so the other files carry on and the
    report lists this one.
    """
    clean = pd.DataFrame(
        {
            "time": pd.Series(dtype="datetime64[ns]"),
            "t_s": pd.Series(dtype="float64"),
            "speed_rpm": pd.Series(dtype="float64"),
            **{c: pd.Series(dtype="float64") for c in SENSOR_COLUMNS},
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
