"""Figures of a reconstruction."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from survey.clouds.reconstruct import ReconstructedTunnel

__all__ = ["plot_support"]


def plot_support(rec: ReconstructedTunnel, path: str | Path, *,
                 title: str | None = None) -> str | Path:
    """Unrolled support map of a reconstruction (chainage x angle from the crown):
    colour = points per cell (log), grey = cells filled by interpolation (support 0),
    as the seed's support-coloured mesh (Figure 2). Atomic PNG."""
    from matplotlib.colors import LogNorm

    from survey.report.plotting import pyplot, save_png

    plt = pyplot()
    n_s, n_a = len(rec.chainages), len(rec.angles)
    sup = rec.support[:n_s * n_a].reshape(n_s, n_a).astype(float)
    fig, ax = plt.subplots(figsize=(11, 3.6), dpi=110, layout="constrained")
    ext = [rec.chainages[0], rec.chainages[-1], -180, 180]
    ax.imshow(np.where(sup == 0, 1.0, np.nan).T, origin="lower", aspect="auto",
              extent=ext, cmap="Greys", vmin=0, vmax=2, interpolation="nearest")
    im = ax.imshow(np.where(sup > 0, sup, np.nan).T, origin="lower", aspect="auto",
                   extent=ext, cmap="viridis", norm=LogNorm(vmin=1, vmax=max(sup.max(), 2)),
                   interpolation="nearest")
    q = rec.quality or {}
    ax.set_title(title or f"reconstructed lining: {q.get('triangles', len(rec.faces)):,} "
                 f"triangles, {100 * rec.extrapolated_share:.1f} % interpolated (grey), "
                 f"point-to-surface median {1000 * q.get('median_m', np.nan):.1f} mm",
                 fontsize=9)
    ax.set_xlabel("chainage (m)")
    ax.set_ylabel("angle from crown (deg)")
    ax.set_yticks([-180, -90, 0, 90, 180])
    fig.colorbar(im, ax=ax, label="points per cell")
    save_png(fig, path)
    return path
