"""Reports of a comparison: CSV and Markdown tables, histogram."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from survey.analysis.compare import STAT_FIELDS

__all__ = ["plot_histogram", "stats_csv", "stats_markdown"]


def stats_csv(rows: Mapping[str, Mapping[str, float]]) -> str:
    """rows {scan name: distance_stats} -> CSV text (metres)."""
    lines = ["scan," + ",".join(f if f == "n" else f + "_m" for f in STAT_FIELDS)]
    for name, s in rows.items():
        lines.append(",".join([name] + [str(s["n"])] +
                              [f"{s[f]:.6f}" for f in STAT_FIELDS[1:]]))
    return "\n".join(lines) + "\n"


def stats_markdown(rows: Mapping[str, Mapping[str, float]], *,
                   title: str = "Distances") -> str:
    """rows {scan name: distance_stats} -> Markdown table in millimetres."""
    out = [f"| {title} | points | mean (mm) | median (mm) | std (mm) | 95 % abs (mm) | "
           "RMS (mm) |", "|---|---:|---:|---:|---:|---:|---:|"]
    for name, s in rows.items():
        out.append(f"| {name} | {s['n']:,} | " + " | ".join(
            f"{1000 * s[f]:.2f}" for f in ("mean", "median", "std", "p95", "rms")) + " |")
    return "\n".join(out) + "\n"


def plot_histogram(named: Mapping[str, ArrayLike], path: str | Path, *,
                   xlabel: str = "distance (mm)", bins: int = 80) -> str | Path:
    """Histogram PNG of {name: distances (m)} (overlaid, in mm); atomic."""
    from survey.report.plotting import pyplot, save_png

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4), dpi=110)
    allv = np.concatenate([np.asarray(v, dtype=float) for v in named.values()]) * 1000
    lo, hi = (np.percentile(allv, [0.5, 99.5]) if allv.size else (0, 1))
    # Equal distances (a copy shifted by a constant): a range narrower than the float
    # noise of the values has no bins; widen it to 1 mm around them.
    if not hi - lo > 1e-6 * max(1.0, abs(lo)):
        lo, hi = lo - 0.5, hi + 0.5
    for name, dd in named.items():
        d = np.asarray(dd, dtype=float)
        ax.hist(d * 1000, bins=bins, range=(lo, hi), histtype="step", lw=1.4,
                label=f"{name} (mean {1000 * np.mean(d):.1f} mm)" if len(d) else name)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("points")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_png(fig, path)
    return path
