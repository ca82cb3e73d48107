"""Logger defects of the twin: where they go in a log and the table that reports them.

Missing rows, logger restart gaps, duplicated rows, swapped rows, single-sample spikes and
sensor dropouts (empty fields or an open-circuit value) are placed at the seed-controlled
rates of :class:`rafi.twin.machines.DefectRates` (:func:`plan_defects`) and then written into
the log with one row per defect in the table (:func:`apply_defects`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from rafi import SENSORS
from rafi.twin.machines import DefectRates

#: Columns of :attr:`rafi.twin.simulate.TwinRun.defects`.
DEFECT_COLUMNS = ("kind", "row", "n_rows", "column", "time", "value", "detail")
#: Values a broken sensor shows (besides empty fields).
OPEN_CIRCUIT_VALUES = (-999.0, 850.0)


def defect_record(
    kind: str, src: int, n_rows: int, detail: str, column: str = "", value: float = np.nan
) -> dict:
    """One row-level defect at source sample ``src`` (turned into a table row by :func:`apply_defects`)."""
    return dict(kind=kind, src=src, n_rows=n_rows, column=column, value=value, detail=detail)


def plan_defects(rates: DefectRates, n: int, dt: float, rng: np.random.Generator, records: list[dict]):
    """Place the defects of a log of ``n`` samples.

    Parameters
    ----------
    rates : DefectRates
        Defect rates.
    n : int
        Samples of the run.
    dt : float
        Sample period, s.
    rng : numpy.random.Generator
        The defects' own random stream.
    records : list of dict
        Row-level defects placed before (:func:`defect_record`); extended in place.

    Returns
    -------
    order : numpy.ndarray
        Source sample of each written row (rows missing, duplicated or swapped).
    records : list of dict
        Row-level defects.
    cells : list of dict
        Cell defects (spikes, dropouts) by written row.
    """
    keep = _kept_rows(rates, n, dt, rng, records)
    order, kinds = _written_rows(rates, np.flatnonzero(keep), rng, records)
    _swap_rows(rates, n, order, kinds, rng, records)
    cells = _spikes(rates, n, kinds, rng)
    if rates.dropout_prob > 0 and rng.random() < rates.dropout_prob:
        lo, hi = rates.dropout_s
        length = max(int(round(rng.uniform(lo, hi) / dt)), 1)
        p = int(rng.integers(int(0.05 * len(order)), int(0.95 * len(order)) - length))
        col = SENSORS[int(rng.integers(0, 16))]
        style = ["", *OPEN_CIRCUIT_VALUES][int(rng.integers(0, 3))]
        cells.append(dict(kind="dropout", pos=p, n_rows=length, column=col, style=style))
    return order, records, cells


#: The first and last rows of a log are never a defect.
_PROTECT = 3


def _kept_rows(rates: DefectRates, n: int, dt: float, rng: np.random.Generator, records: list) -> np.ndarray:
    """Which of the ``n`` source samples are written: a logger restart's gap and single missing
    rows left out (recorded in ``records``)."""
    keep = np.ones(n, dtype=bool)
    if rates.restart_gap_prob > 0 and rng.random() < rates.restart_gap_prob:
        lo, hi = rates.restart_gap_s
        length = max(int(round(rng.uniform(lo, hi) / dt)), 1)
        p = int(rng.integers(int(0.1 * n), int(0.9 * n) - length))
        keep[p : p + length] = False
        records.append(
            defect_record("restart_gap", p, length, f"logger restart: {length * dt:.0f} s without rows")
        )
    if rates.missing_row > 0:
        cand = rng.random(n) < rates.missing_row
        cand[:_PROTECT] = cand[-_PROTECT:] = False
        for p in np.flatnonzero(cand & keep):
            if not keep[p - 1] or not keep[p + 1]:
                continue
            keep[p] = False
            records.append(defect_record("missing_row", int(p), 1, "sample not written"))
    return keep


def _written_rows(rates: DefectRates, src: np.ndarray, rng: np.random.Generator, records: list) -> tuple:
    """``(order, kinds)``: the source sample of each written row, some written twice, and what
    each row is (``""`` plain, ``"dup0"``/``"dup"`` the first and second of a duplicate)."""
    dup = rng.random(len(src)) < rates.duplicate_row if rates.duplicate_row > 0 else np.zeros(len(src), bool)
    dup[:_PROTECT] = dup[-_PROTECT:] = False
    order_l: list[int] = []
    kind_l: list[str] = []
    for i, s in enumerate(src):
        order_l.append(int(s))
        kind_l.append("")
        if dup[i]:
            order_l.append(int(s))
            kind_l.append("dup")
            kind_l[-2] = "dup0"
            records.append(defect_record("duplicate_row", int(s), 1, "row written twice"))
    return np.asarray(order_l), np.asarray(kind_l, dtype=object)


def _swap_rows(
    rates: DefectRates, n: int, order: np.ndarray, kinds: np.ndarray, rng: np.random.Generator, records: list
) -> None:
    """Swap two adjacent, consecutive, plain rows, about ``swap_per_1000_rows`` times per 1000
    samples (``order`` and ``kinds`` changed in place)."""
    n_swap = rng.poisson(rates.swap_per_1000_rows * n / 1000.0) if rates.swap_per_1000_rows > 0 else 0
    for _ in range(n_swap):
        for _try in range(20):
            p = int(rng.integers(_PROTECT, len(order) - _PROTECT - 1))
            if (kinds[p - 1 : p + 3] == "").all() and order[p + 1] == order[p] + 1:
                order[p], order[p + 1] = order[p + 1], order[p]
                kinds[p] = kinds[p + 1] = "swap"
                records.append(
                    defect_record(
                        "swapped_rows", int(order[p]), 2, "two adjacent rows written in swapped order"
                    )
                )
                break


def _spikes(rates: DefectRates, n: int, kinds: np.ndarray, rng: np.random.Generator) -> list[dict]:
    """Single-sample spikes on plain rows (a sensor, or now and then the displacement), about
    ``spike_per_1000_rows`` per 1000 samples (``kinds`` marked in place)."""
    cells: list[dict] = []
    n_spike = rng.poisson(rates.spike_per_1000_rows * n / 1000.0) if rates.spike_per_1000_rows > 0 else 0
    for _ in range(n_spike):
        for _try in range(20):
            p = int(rng.integers(_PROTECT, len(kinds) - _PROTECT))
            if kinds[p] == "":
                break
        kinds[p] = "spike"
        if rng.random() < 0.2:
            col = "disp_um"
            delta = float(rng.choice([-1, 1]) * rng.uniform(8.0, 30.0))
        else:
            col = SENSORS[int(rng.integers(0, 16))]
            delta = float(rng.choice([-1, 1]) * rng.uniform(3.0, 15.0))
        cells.append(dict(kind="spike", pos=p, n_rows=1, column=col, delta=delta))
    return cells


def apply_defects(records, cells, log: pd.DataFrame, order: np.ndarray, times) -> pd.DataFrame:
    """Write the cell defects into ``log`` (in place) and return the defect table.

    ``records`` and ``cells`` are from :func:`plan_defects`, ``order`` the source sample of
    each row of ``log`` and ``times`` the true time of each source sample. Returns one row
    per defect (:data:`DEFECT_COLUMNS`), sorted by row position in ``log``.
    """
    rows = []
    first_pos = {}
    for pos, s in enumerate(order):
        first_pos.setdefault(int(s), pos)
    for rec in records:
        s = rec["src"]
        if rec["kind"] in ("missing_row", "restart_gap"):
            after = np.searchsorted(np.sort(order), s + rec["n_rows"])
            nxt = np.sort(order)[min(after, len(order) - 1)]
            pos = first_pos[int(nxt)]
        elif rec["kind"] == "duplicate_row":
            pos = first_pos[s] + 1
        elif rec["kind"] == "swapped_rows":
            pos = first_pos[s]
        else:
            pos = first_pos.get(s, 0)
        rows.append(
            dict(
                kind=rec["kind"],
                row=int(pos),
                n_rows=int(rec["n_rows"]),
                column=rec["column"],
                time=times[s],
                value=rec["value"],
                detail=rec["detail"],
            )
        )
    for c in cells:
        p, col = c["pos"], c["column"]
        j = log.columns.get_loc(col)
        if c["kind"] == "spike":
            old = float(log.iat[p, j])
            log.iat[p, j] = round(old + c["delta"], 3 if col == "disp_um" else 2)
            rows.append(
                dict(
                    kind="spike",
                    row=p,
                    n_rows=1,
                    column=col,
                    time=log["time"].iat[p],
                    value=float(log.iat[p, j]),
                    detail=f"single-sample spike {c['delta']:+.2f}",
                )
            )
        else:
            length = min(c["n_rows"], len(log) - p)
            style = c["style"]
            log.iloc[p : p + length, j] = np.nan if style == "" else float(style)
            what = "empty fields" if style == "" else f"open-circuit value {style}"
            rows.append(
                dict(
                    kind="dropout",
                    row=p,
                    n_rows=length,
                    column=col,
                    time=log["time"].iat[p],
                    value=np.nan if style == "" else float(style),
                    detail=f"sensor dropout, {what}",
                )
            )
    table = pd.DataFrame(rows, columns=list(DEFECT_COLUMNS))
    if len(table):
        table = table.sort_values(["row", "kind"], kind="stable").reset_index(drop=True)
    table["row"] = table["row"].astype("int64")
    table["n_rows"] = table["n_rows"].astype("int64")
    return table
