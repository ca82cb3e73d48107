"""Defects injected into a canonical log, with the lines the audit must report (the ground truth).

:func:`inject_defects` (also imported by :mod:`rafi.twin.synthetic_logs`) places every defect
at random, away from the others, in this order of random draws: gaps too long to interpolate,
short gaps, dropouts, open-circuit values, spikes, swapped rows, duplicated rows. The written
frame is then put together and each defect's position in the regular log is turned into the
lines of the written file.

Everything is deterministic given ``seed``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from rafi import SENSORS
from rafi.method.clean import MAX_SPIKE_SAMPLES
from rafi.twin.defects import OPEN_CIRCUIT_VALUES

#: The open-circuit code injected (the logger's first one).
OPEN_CIRCUIT = OPEN_CIRCUIT_VALUES[0]


def _placer(rng: np.random.Generator, n_rows: int, margin: int) -> Callable[[int], int]:
    """A function that picks where the next defect of ``length`` rows goes, away from the others.

    Parameters
    ----------
    rng : numpy.random.Generator
        Draws the positions.
    n_rows : int
        Rows of the log.
    margin : int
        Clean rows kept between any two defects (and from either end of the log, plus 2).

    Returns
    -------
    callable
        ``place(length) -> position``: the first row of a free stretch of ``length`` rows,
        then marked as taken (with its margins). Raises RuntimeError when no free stretch
        is found in 10000 draws.
    """
    used = np.zeros(n_rows, bool)

    def place(length: int) -> int:
        for _ in range(10000):
            p = int(rng.integers(margin + 2, n_rows - length - margin - 2))
            lo, hi = p - margin, p + length + margin
            if not used[lo:hi].any():
                used[lo:hi] = True
                return p
        raise RuntimeError("could not place all defects; use a longer log or fewer defects")

    return place


@dataclass
class _Injection:
    """What :func:`inject_defects` has done so far to a log.

    Attributes
    ----------
    log : pandas.DataFrame
        The regular log (gives each defect's true time).
    values : pandas.DataFrame
        Its rows with the value defects (dropouts, open circuits, spikes) in.
    order_keys : numpy.ndarray
        Sort key of each row in the written file (a swapped row's key moves past its neighbour's).
    keep : numpy.ndarray
        False for the rows left out (gaps).
    extra_rows : list of (float, int, dict)
        Rows written twice: sort key, position in ``log``, changed values.
    defects : list of dict
        One record per defect (position in ``log``, not yet line numbers).
    place : callable
        Where the next defect goes (:func:`_placer`).
    """

    log: pd.DataFrame
    values: pd.DataFrame
    order_keys: np.ndarray
    keep: np.ndarray
    extra_rows: list[tuple[float, int, dict]]
    defects: list[dict]
    place: Callable[[int], int]

    def record(self, kind: str, column: str, pos: int, n_rows: int, **extra) -> None:
        """Note one defect at row ``pos`` of the log (``extra``: ``last_pos`` and, for spikes, ``size``)."""
        self.defects.append(
            {
                "kind": kind,
                "column": column,
                "position": pos,
                "n_rows": n_rows,
                "time": self.log["time"].iloc[pos],
                **extra,
            }
        )


def _cut_gaps(state: _Injection, rng: np.random.Generator, long_gaps: int, gaps: int, max_rows: int) -> None:
    """Leave out stretches of rows: ``long_gaps`` too long to interpolate, then ``gaps`` short enough.

    Parameters
    ----------
    state : _Injection
        Changed in place.
    rng : numpy.random.Generator
        Draws the lengths.
    long_gaps, gaps : int
        How many of each.
    max_rows : int
        The longest run of missing rows that may be interpolated.
    """
    for _ in range(long_gaps):
        length = max_rows + 1 + int(rng.integers(5, 40))
        p = state.place(length)
        state.keep[p : p + length] = False
        state.record("long_gap", "time", p, length, last_pos=p + length)
    for _ in range(gaps):
        length = int(rng.integers(1, max_rows + 1))
        p = state.place(length)
        state.keep[p : p + length] = False
        state.record("gap", "time", p, length, last_pos=p + length)


def _spoil_values(
    state: _Injection,
    rng: np.random.Generator,
    *,
    dropouts: int,
    open_circuit: int,
    spikes: int,
    bursts: int,
    max_rows: int,
    spike_size: dict[str, float],
) -> None:
    """Put empty values, open-circuit codes, spikes and short bursts into random channels.

    Parameters
    ----------
    state : _Injection
        Changed in place.
    rng : numpy.random.Generator
        Draws lengths, channels and spike signs.
    dropouts : int
        Runs of 1..``max_rows`` NaN in a temperature or the displacement.
    open_circuit : int
        Runs of 1..3 :data:`OPEN_CIRCUIT` values in a temperature.
    spikes : int
        Single samples moved by ``spike_size['temp']`` or ``spike_size['disp']``, sign at random.
    bursts : int
        Runs of 2..``MAX_SPIKE_SAMPLES`` consecutive samples moved by one spike size.
    max_rows : int
        The longest run of missing values that may be interpolated.
    spike_size : dict
        Spike height per kind, ``temp`` (K) and ``disp`` (um).
    """
    values = state.values
    sensor_cols = [*SENSORS, "disp_um"]
    for _ in range(dropouts):
        length = int(rng.integers(1, max_rows + 1))
        p = state.place(length)
        col = sensor_cols[int(rng.integers(len(sensor_cols)))]
        values.iloc[p : p + length, values.columns.get_loc(col)] = np.nan
        state.record("dropout", col, p, length, last_pos=p + length - 1)
    for _ in range(open_circuit):
        length = int(rng.integers(1, 4))
        p = state.place(length)
        col = SENSORS[int(rng.integers(16))]
        values.iloc[p : p + length, values.columns.get_loc(col)] = OPEN_CIRCUIT
        state.record("open_circuit", col, p, length, last_pos=p + length - 1)
    for length in [1] * spikes + [int(rng.integers(2, MAX_SPIKE_SAMPLES + 1)) for _ in range(bursts)]:
        p = state.place(length)
        col = sensor_cols[int(rng.integers(len(sensor_cols)))]
        size = spike_size["disp" if col == "disp_um" else "temp"] * (1 if rng.random() < 0.5 else -1)
        values.iloc[p : p + length, values.columns.get_loc(col)] += size
        state.record("spike", col, p, length, last_pos=p + length - 1, size=size)


def _misorder_rows(state: _Injection, swaps: int, duplicates: int, duplicates_differ: int) -> None:
    """Write ``swaps`` pairs of rows in the wrong order, and rows twice (same, or ``T1`` + 0.5 K).

    Parameters
    ----------
    state : _Injection
        Changed in place.
    swaps : int
        Row p written after row p + 1.
    duplicates, duplicates_differ : int
        Rows written again right after themselves: identical, or with ``T1`` 0.5 K higher.
    """
    for _ in range(swaps):
        p = state.place(2)
        state.order_keys[p] = p + 1.25  # row p written after row p + 1
        state.record("swap", "time", p, 1, last_pos=p)
    for kind, count in (("duplicate", duplicates), ("duplicate_differ", duplicates_differ)):
        for _ in range(count):
            p = state.place(1)
            changes = {"T1": float(state.values["T1"].iloc[p]) + 0.5} if kind == "duplicate_differ" else {}
            state.extra_rows.append((p + 0.5, p, changes))
            state.record(kind, "time", p, 1, last_pos=p)


def _written_frame(state: _Injection, first_line: int) -> tuple[pd.DataFrame, dict[tuple[int, bool], int]]:
    """The rows as the faulty logger wrote them, and the line each source row ended on.

    Parameters
    ----------
    state : _Injection
        The injected defects.
    first_line : int
        Line of the first written row.

    Returns
    -------
    frame : pandas.DataFrame
        Kept rows and duplicates in written order, index ``line`` from ``first_line``.
    line_of : dict
        (position in the log, is the duplicate) -> line in ``frame``.
    """
    values, keep, extra_rows = state.values, state.keep, state.extra_rows
    base = values[keep].copy()
    base_keys = state.order_keys[keep]
    base_pos = np.flatnonzero(keep)
    dup_frames = []
    for _key, p, changes in extra_rows:
        row = values.iloc[[p]].copy()
        for c, v in changes.items():
            row[c] = v
        dup_frames.append(row)
    frame = pd.concat([base, *dup_frames]) if dup_frames else base
    all_keys = np.concatenate([base_keys, [k for k, _, _ in extra_rows]])
    all_pos = np.concatenate([base_pos, [p for _, p, _ in extra_rows]]).astype(int)
    is_dup = np.concatenate([np.zeros(len(base_keys), bool), np.ones(len(extra_rows), bool)])
    order = np.argsort(all_keys, kind="stable")
    frame = frame.iloc[order].copy()
    frame.index = pd.Index(np.arange(first_line, first_line + len(frame)), name="line")
    line_of = {
        (int(p), bool(d)): first_line + r for r, (p, d) in enumerate(zip(all_pos[order], is_dup[order]))
    }
    return frame, line_of


def _defect_table(defects: list[dict], line_of: dict[tuple[int, bool], int]) -> pd.DataFrame:
    """The defect records with the lines the audit must report, sorted by line.

    Parameters
    ----------
    defects : list of dict
        Records of :meth:`_Injection.record` (``position`` and ``last_pos`` in the log).
    line_of : dict
        (position in the log, is the duplicate) -> line in the written file.

    Returns
    -------
    pandas.DataFrame
        Columns ``kind``, ``column``, ``line``, ``last_line``, ``n_rows``, ``time``,
        ``position``, ``size``. A gap spans the rows around it; a swap starts at the row
        written first (the later one in time).
    """
    out = []
    for record in defects:
        d = dict(record)
        p, kind = d.pop("position"), d["kind"]
        last_pos = d.pop("last_pos")
        if kind in ("gap", "long_gap"):
            line, last = line_of[(p - 1, False)], line_of[(last_pos, False)]
        elif kind in ("duplicate", "duplicate_differ"):
            line = last = line_of[(p, True)]
        elif kind == "swap":
            line, last = line_of[(p + 1, False)], line_of[(p, False)]
        else:
            line, last = line_of[(p, False)], line_of[(last_pos, False)]
        out.append({**d, "line": line, "last_line": last, "position": p})
    columns = ["kind", "column", "line", "last_line", "n_rows", "time", "position", "size"]
    return pd.DataFrame(out, columns=columns).sort_values("line", ignore_index=True)


def inject_defects(
    log: pd.DataFrame,
    *,
    duplicates: int = 0,
    duplicates_differ: int = 0,
    swaps: int = 0,
    spikes: int = 0,
    bursts: int = 0,
    dropouts: int = 0,
    open_circuit: int = 0,
    gaps: int = 0,
    long_gaps: int = 0,
    period_s: float = 5.0,
    max_gap_s: float = 60.0,
    spike_size: dict | None = None,
    seed: int = 0,
    margin: int = 6,
) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Inject defects into a canonical log at random, non-interacting places.

    Parameters
    ----------
    log : pandas.DataFrame
        Regular canonical frame (e.g. from :func:`rafi.twin.synthetic_logs.canonical_log`); not modified.
    duplicates : int
        Rows written twice, identical.
    duplicates_differ : int
        Rows written twice with the same time but a different ``T1`` (kept: first).
    swaps : int
        Adjacent rows written in the wrong order (one ``reordered`` event each).
    spikes : int
        Single-sample spikes (temperatures and ``disp_um``).
    bursts : int
        Spikes of 2..``rafi.method.clean.MAX_SPIKE_SAMPLES`` consecutive samples, all
        moved by the same amount (kind ``spike``, ``n_rows`` = their number).
    dropouts : int
        Runs of 1..``max_gap_s / period_s - 1`` empty values in one sensor
        (interpolable).
    open_circuit : int
        Runs of 1..3 open-circuit values (``OPEN_CIRCUIT``) in one temperature.
    gaps : int
        Missing rows, interpolable (at most ``max_gap_s / period_s - 1`` rows).
    long_gaps : int
        Missing stretches too long to interpolate (split the log).
    spike_size : dict, optional
        Spike height per kind: ``{"temp": 5.0, "disp": 15.0}``.
    seed : int
        Random seed.
    margin : int
        Clean samples kept between any two defects.

    Returns
    -------
    frame : pandas.DataFrame
        Canonical frame as a logger with these faults would have produced it,
        index = its own line numbers (first line as in ``log``).
    defects : pandas.DataFrame
        One row per defect: ``kind`` (duplicate, duplicate_differ, swap, spike,
        dropout, open_circuit, gap, long_gap), ``column``, ``line`` and
        ``last_line`` (lines in ``frame``; for gaps the rows around the gap),
        ``n_rows`` (rows / values concerned), ``time`` (true time of the first
        affected sample), ``position`` (row in ``log``).
    """
    rng = np.random.default_rng(seed)
    n = len(log)
    first_line = int(log.index[0])
    max_rows = int(max_gap_s // period_s) - 1  # longest interpolable run of missing rows
    state = _Injection(
        log=log,
        values=log.copy(deep=True),
        order_keys=np.arange(n, dtype=float),
        keep=np.ones(n, bool),
        extra_rows=[],
        defects=[],
        place=_placer(rng, n, margin),
    )
    _cut_gaps(state, rng, long_gaps, gaps, max_rows)
    _spoil_values(
        state,
        rng,
        dropouts=dropouts,
        open_circuit=open_circuit,
        spikes=spikes,
        bursts=bursts,
        max_rows=max_rows,
        spike_size={"temp": 5.0, "disp": 15.0, **(spike_size or {})},
    )
    _misorder_rows(state, swaps, duplicates, duplicates_differ)
    frame, line_of = _written_frame(state, first_line)
    frame.attrs = dict(log.attrs)
    return frame, _defect_table(state.defects, line_of)
