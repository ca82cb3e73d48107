"""The displacement jumping between two rows: a bumped or re-zeroed probe (``displacement_step``,
warning) or a probe whose sign flips part way (``probe_sign``, error).

A jump is a change *from one row to the next* (missing values skipped) of at least the threshold,
beyond the trend of the rows around it, after which the level stays (a single glitch sample does
not count). Thermal growth is slow: a warm-up of 1.5 um per row never jumps, however much its
5-row medians differ. Thresholds are documented in docs/raw-format.md ("Checks").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rafi.readers.checks_base import CheckWarning, Signals, Where, fmt

#: The displacement changing by this much (um) and this share of its 2nd-98th percentile range
#: from one row to the next, beyond its trend (thermal growth is slow): a bumped or re-zeroed probe
#: (warning); to minus its level before (within 10 %, or 1 um): a probe whose sign flips (error).
JUMP_UM = 5.0
JUMP_SHARE = 0.25
#: Rows each side of a jump whose median is the level before / after it, and whose row-to-row
#: changes give the trend the jump is measured against.
JUMP_ROWS = 5
#: Share of the row-to-row change the level must keep after the jump (else a glitch sample).
JUMP_KEPT = 0.5


@dataclass(frozen=True)
class Jump:
    """One row-to-row jump of a channel.

    Attributes
    ----------
    row_before, row_after : int
        Row indices (into the channel) of the last value before and the first after the jump.
    value_before, value_after : float
        The two values; ``change`` is their difference.
    level_before, level_after : float
        Medians of up to :data:`JUMP_ROWS` values before and after the jump.
    trend : float
        Median row-to-row change of those rows (the jump left out).
    """

    row_before: int
    row_after: int
    value_before: float
    value_after: float
    level_before: float
    level_after: float
    trend: float

    @property
    def change(self) -> float:
        """The row-to-row change measured (after minus before)."""
        return self.value_after - self.value_before


def row_jumps(values: np.ndarray, min_step: float) -> list[Jump]:
    """Where ``values`` change by ``min_step`` or more from one row to the next (missing values
    skipped), beyond the median row-to-row change of the :data:`JUMP_ROWS` rows each side, and the
    level (median of those rows, trend removed) keeps at least :data:`JUMP_KEPT` of that change.

    Parameters
    ----------
    values : numpy.ndarray
        One channel, NaN where missing.
    min_step : float
        Smallest jump, in the channel's unit.

    Returns
    -------
    list of Jump
        In row order.
    """
    rows = np.flatnonzero(np.isfinite(values))
    if rows.size < 2 * JUMP_ROWS:
        return []
    v = values[rows].astype(float)
    d = np.diff(v)
    per_row = d / np.diff(rows)  # a change across missing rows is spread over them
    out = []
    for j in np.flatnonzero(np.abs(d) >= min_step):
        before, after = slice(max(0, j - JUMP_ROWS + 1), j + 1), slice(j + 1, j + 1 + JUMP_ROWS)
        if v[before].size < 3 or v[after].size < 3:
            continue
        near = np.concatenate([per_row[before.start : j], per_row[j + 1 : after.stop - 1]])
        trend = float(np.median(near))
        gap = int(rows[j + 1] - rows[j])
        if abs(d[j] - trend * gap) < min_step:
            continue
        apart = float(np.median(rows[after]) - np.median(rows[before]))  # rows between the medians
        kept = float(np.median(v[after]) - np.median(v[before])) - trend * (apart - gap)
        if np.sign(kept) != np.sign(d[j]) or abs(kept) < JUMP_KEPT * abs(d[j]):
            continue
        out.append(
            Jump(
                int(rows[j]),
                int(rows[j + 1]),
                float(v[j]),
                float(v[j + 1]),
                float(np.median(v[before])),
                float(np.median(v[after])),
                trend,
            )
        )
    return out


def displacement_jumps(sig: Signals, where: Where, spread: float) -> list[CheckWarning]:
    """The displacement jumping from one row to the next (by :data:`JUMP_UM` and
    :data:`JUMP_SHARE` of ``spread``, its 2nd-98th percentile range): error if its level jumps to
    minus its level before (the probe's sign flips part way), else a warning for the first jump (a
    bumped or re-zeroed probe) naming the two lines and the change measured between them."""
    label = where.label("disp_um")
    jumps = row_jumps(sig.values["disp_um"], max(JUMP_UM, JUMP_SHARE * spread))
    for jump in jumps:
        b, a = jump.level_before, jump.level_after
        if abs(a + b) <= max(1.0, 0.1 * abs(b)):
            line = int(sig.lines[jump.row_after])
            raise where.check_error(
                "probe_sign",
                f"{label} jumps from {fmt(b)} to {fmt(a)} um at line {line}: the probe's sign flips "
                "there (thermal growth does not jump); write one sign for the whole log",
                line=line,
                column="disp_um",
            )
    if not jumps:
        return []
    jump = jumps[0]
    first, line = int(sig.lines[jump.row_before]), int(sig.lines[jump.row_after])
    more = f"; {len(jumps) - 1} more jump(s) later in the log" if len(jumps) > 1 else ""
    return [
        CheckWarning(
            "displacement_step",
            "disp_um",
            f"{label} changes by {fmt(jump.change)} um from line {first} to line {line} "
            f"({fmt(jump.value_before)} to {fmt(jump.value_after)} um, "
            f"{100 * abs(jump.change) / spread:.0f} % of its range, while the rows around it change by "
            f"{fmt(jump.trend)} um per row; thermal growth does not jump){more}: a bumped or "
            "re-zeroed probe, or a changed offset; the rows after it are not comparable with the "
            "rows before",
            line,
            line,
        )
    ]
