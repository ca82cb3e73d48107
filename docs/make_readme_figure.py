"""Draw the README's picture from a pipeline run (``snakemake --cores 2`` first).

    python docs/make_readme_figure.py [results/tapping-center-a] [docs/img/readme-multi-condition.png]

Top: spindle speed of the multi-condition validation run. Bottom: the displacement the
probe measured (uncompensated), and what is left after compensation by RAFI as published
and by the champion of the model family.
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402


def main(results: Path, out: Path) -> None:
    summary = pd.read_csv(results / "comparison" / "summary.csv")
    champion = summary.loc[summary["champion"].astype(bool), "model"]
    champion = str(champion.iloc[0]) if len(champion) else "rafi"
    runs = pd.read_csv(results / "runs.csv")
    multi = runs.loc[runs["role"] == "validation_multi", "run_id"].iloc[0]
    res = pd.read_parquet(results / "comparison" / "residuals.parquet")
    res = res[res["run_id"] == multi]
    rafi = res[res["model"] == "rafi"].sort_values("t_s")
    best = res[res["model"] == champion].sort_values("t_s")
    hours = rafi["t_s"] / 3600.0

    fig, (ax_n, ax_z) = plt.subplots(
        2, 1, figsize=(8, 4.2), sharex=True, gridspec_kw={"height_ratios": [1, 2.6]}, constrained_layout=True
    )
    ax_n.plot(hours, rafi["speed_rpm"], color="#2e7d32", lw=1.2)
    ax_n.set_ylabel("speed (r/min)")
    ax_n.set_title(f"{results.name}: multi-condition validation run ({multi})", fontsize=10)
    peak = rafi["measured_um"].abs().max()
    for label, frame, colour, lw in (
        (f"uncompensated (max {peak:.1f} µm)", rafi.assign(r=rafi["measured_um"]), "#9aa0a6", 1.0),
        (
            f"after RAFI as published (max {rafi['residual_um'].abs().max():.1f} µm)",
            rafi.assign(r=rafi["residual_um"]),
            "#c0392b",
            0.9,
        ),
        (
            f"after {champion} (max {best['residual_um'].abs().max():.1f} µm)",
            best.assign(r=best["residual_um"]),
            "#1f77b4",
            0.9,
        ),
    ):
        ax_z.plot(frame["t_s"] / 3600.0, frame["r"], color=colour, lw=lw, label=label)
    ax_z.axhline(0, color="black", lw=0.5)
    ax_z.set_xlabel("time since run start (h)")
    ax_z.set_ylabel("axial displacement (µm)")
    ax_z.legend(loc="upper left", fontsize=8, frameon=False)
    for ax in (ax_n, ax_z):
        ax.grid(alpha=0.3)
        ax.spines[["top", "right"]].set_visible(False)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110, metadata={"Software": None})
    print(f"wrote {out}")


if __name__ == "__main__":
    args = sys.argv[1:]
    main(
        Path(args[0] if args else "results/tapping-center-a"),
        Path(args[1] if len(args) > 1 else "docs/img/readme-multi-condition.png"),
    )
