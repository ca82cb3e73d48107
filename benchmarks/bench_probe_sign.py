"""The probe-sign check on a real log cut into files: how often it warns between files of one
channel.

Usage (from the repository root; see benchmarks/README.md)::

    python benchmarks/bench_probe_sign.py [--workbook ../shared/data/fl-thermal/data.xlsx]

**Why.** ``checks.probe_sign: auto`` warns a file whose displacement moves against the sign of
most of the machine's other files, and an unconfirmed warning holds promotion at night. A user
who logs one file per run, per shift or per day gets files whose sign evidence must agree on a
probe that never changed. FL_THERMAL (one continuous 46 h test, five probes) is cut into its six
heating runs (each with the rest after it), into halves, quarters and eighths; every piece is
one file of a machine per channel, its sign computed by :func:`rafi.readers.checks_channels.probe_sign`
and the machine's warnings by :func:`rafi.readers.checks_machine.probe_sign_findings` (the
check's own code). The probe never changes, so a warning between files is a false alarm; a
warning from the convention (a single file with a clear sign, negative) is the check asking
whether the probe counts the documented way, and is counted apart.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd

from rafi import SENSORS
from rafi.readers.checks_base import Signals
from rafi.readers.checks_channels import probe_sign
from rafi.readers.checks_machine import probe_sign_findings

WORKBOOK = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "fl-thermal" / "data.xlsx"
#: The starts of the six heating runs (s), each piece running to the next (README of the log).
RUN_STARTS_S = (0.0, 29265.0, 58065.0, 86865.0, 115665.0, 144465.0)
CHANNELS = 5


def pieces(t: np.ndarray) -> dict[str, list[np.ndarray]]:
    """Masks of the log's pieces per cutting scheme."""
    edges = [*RUN_STARTS_S, np.inf]
    cuts = {"runs": [(t >= edges[i]) & (t < edges[i + 1]) for i in range(len(RUN_STARTS_S))]}
    for parts in (2, 4, 8):
        size = len(t) // parts
        masks = []
        for k in range(parts):
            mask = np.zeros(len(t), bool)
            mask[k * size : (k + 1) * size] = True
            masks.append(mask)
        cuts[f"1/{parts}"] = masks
    return cuts


def warnings_per_scheme(frame: pd.DataFrame) -> pd.DataFrame:
    """One row per scheme and channel: the pieces' signs and the warnings, between files and from
    the convention."""
    t = frame.iloc[:, 0].to_numpy(float)
    speed = frame.iloc[:, 1].to_numpy(float)
    disp = frame.iloc[:, 2 : 2 + CHANNELS].to_numpy(float)
    temps = frame.iloc[:, 2 + CHANNELS : 2 + CHANNELS + len(SENSORS)].to_numpy(float)
    period = float(np.median(np.diff(t)))
    rows = []
    for scheme, masks in pieces(t).items():
        for c in range(CHANNELS):
            signs = {}
            for i, m in enumerate(masks):
                values = {"speed_rpm": speed[m], "disp_um": disp[m, c]}
                values.update({s: temps[m, j] for j, s in enumerate(SENSORS)})
                sig = Signals(t[m] - t[m][0], values, np.arange(int(m.sum())), period)
                signs[f"piece{i}"] = probe_sign(sig)
            _, warnings = probe_sign_findings(signs, "auto")
            convention = sum("convention" in w["message"] for w in warnings)
            rows.append(
                {
                    "scheme": scheme,
                    "channel": f"ch{c + 1}",
                    "signs": " ".join(f"{s:+d}" for s in signs.values()),
                    "between_files": len(warnings) - convention,
                    "convention": convention,
                }
            )
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workbook", type=Path, default=WORKBOOK)
    args = parser.parse_args(argv)
    table = warnings_per_scheme(pd.read_excel(args.workbook))
    print(table.to_string(index=False))
    print(
        f"\nwarnings between files: {int(table.between_files.sum())}; "
        f"from the convention: {int(table.convention.sum())}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
