"""Figure 9 style plots of twin logs (``rafi simulate plot``); matplotlib is imported on use."""

from __future__ import annotations

import io
import os
from collections.abc import Sequence
from pathlib import Path

from rafi.artefact import write_bytes_atomic
from rafi.twin.calibration import quick_clean


def plot_runs(
    paths: Sequence[str | os.PathLike],
    out_dir: str | os.PathLike = "docs/img",
    sensors: Sequence[str] = ("T6", "T8", "T9", "T16", "T5", "T11", "T13"),
) -> list[Path]:
    """Figure 9 style plots: temperatures (top) and displacement (bottom) against time.

    One image ``twin-<stem>.png`` per log and ``twin-overview.png`` (all displacements).
    Logs get :func:`quick_clean` (open-circuit values and spikes masked) before plotting.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from rafi.readers.native import read_raw_log

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    runs = []
    for path in paths:
        raw = read_raw_log(path)
        f = quick_clean(raw, float(raw.attrs["metadata"].get("sample_period_s", 5.0)))
        runs.append((Path(path).stem, f))
        hours = f["t_s"] / 3600.0
        fig, (ax1, ax2) = plt.subplots(
            2, 1, figsize=(9, 6.5), sharex=True, gridspec_kw={"height_ratios": [3, 2]}
        )
        for s in sensors:
            style = "-" if s in ("T6", "T8", "T9", "T16") else "--"
            ax1.plot(hours, f[s], style, lw=0.8, label=s)
        ax1.set_ylabel("temperature (°C)")
        ax1.legend(ncol=4, fontsize=8, loc="lower right")
        ax1.grid(alpha=0.3)
        dz = f["disp_um"] - f["disp_um"][f["t_s"] <= 60].median()
        ax2.plot(hours, dz, lw=0.7, color="k")
        ax2.set_ylabel("axial displacement dz (µm)")
        ax2.set_xlabel("time since start (h)")
        ax2.grid(alpha=0.3)
        sp = f["speed_rpm"].median()
        fig.suptitle(
            f"{raw.attrs['metadata'].get('machine', '')} {Path(path).name} (median speed {sp:.0f} r/min)"
        )
        fig.tight_layout()
        target = out / f"twin-{Path(path).stem}.png"
        _save(fig, target)
        written.append(target)
    fig, ax = plt.subplots(figsize=(9, 4.5))
    for stem, f in runs:
        dz = f["disp_um"] - f["disp_um"][f["t_s"] <= 60].median()
        ax.plot(f["t_s"] / 3600.0, dz, lw=0.7, label=stem)
    ax.set_xlabel("time since start (h)")
    ax.set_ylabel("dz (µm)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title("displacement rise per run")
    fig.tight_layout()
    target = out / "twin-overview.png"
    _save(fig, target)
    written.append(target)
    return written


def _save(fig, target: Path) -> None:
    """Write ``fig`` as PNG to ``target`` atomically and close it."""
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    write_bytes_atomic(target, buf.getvalue())
