"""MLS study on paper: CSV and Markdown tables, the floor-ring figure (seed Figure 7)
and density-versus-speed curves."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from sensors.route import Route
    from survey.analysis.study import Study, StudyRow

__all__ = ["plot_study", "study_csv", "study_markdown"]

_COLS = [("speed_mps", "speed (m/s)", "{:.2f}"), ("rate_hz", "rate (Hz)", "{:.0f}"),
         ("mount", "mount", "{}"), ("density_lining", "lining (pts/m^2)", "{:,.0f}"),
         ("density_floor", "floor (pts/m^2)", "{:,.0f}"),
         ("empty_lining_share", "empty lining", "{:.1%}"),
         ("line_spacing_m", "line spacing (m)", "{:.3f}"),
         ("line_spacing_analytic_m", "v/f (m)", "{:.3f}"),
         ("distortion_max_m", "distortion max (m)", "{:.3f}"),
         ("distortion_rms_m", "distortion RMS (m)", "{:.3f}")]


def study_csv(rows: Sequence[StudyRow]) -> str:
    """CSV of the study rows (every field, SI units)."""
    keys = list(rows[0].to_dict()) if rows else []
    lines = [",".join(keys)]
    for r in rows:
        d = r.to_dict()
        lines.append(",".join(str(d[k]) if isinstance(d[k], str) else f"{d[k]:.6g}"
                              for k in keys))
    return "\n".join(lines) + "\n"


def study_markdown(rows: Sequence[StudyRow], sensor_name: str,
                   strip: tuple[float, float], lead_m: float, *,
                   route: Route | None = None) -> str:
    """Markdown table of the study rows; ``strip`` (start, end) chainages and
    ``lead_m`` in m; with ``route`` (a study on any mesh) the chainage is the distance
    along it and the cells are the mesh's own triangles."""
    where = "chainage"
    if route is not None:
        where = (f"distance along the route found in the mesh ({route.length_m:.1f} m, "
                 f"smallest clearance {route.min_clearance_m:.2f} m; cells: the mesh's "
                 "own triangles, cut into samples)")
    out = [f"# MLS study: {sensor_name}", "",
           f"Evaluation strip: {where} {strip[0]:.1f}-{strip[1]:.1f} m; points counted "
           f"while the sensor is within {lead_m:.1f} m of it (one pass). Densities at "
           "0 m/s are per sweep. Distortion: each sweep placed with the pose at its start, "
           "against the truth; analytic maximum v/f (straight, level motion).", "",
           "| " + " | ".join(c[1] for c in _COLS) + " |",
           "|" + "---:|" * len(_COLS)]
    for r in rows:
        d = r.to_dict()
        out.append("| " + " | ".join(f.format(d[k]) for k, _, f in _COLS) + " |")
    return "\n".join(out) + "\n"


def plot_study(study: Study, rows: Sequence[StudyRow], path: str | Path, *,
               rings_mount: str | None = None, rings_rate: float | None = None
               ) -> str | Path:
    """Two panels: the floor footprint (chainage x lateral offset) of three sweeps at
    each speed, colour by speed (seed Figure 7), and lining/floor density against speed
    per rate, with the 1/v law through the slowest moving point. Atomic PNG."""
    from survey.report.plotting import pyplot, save_png

    plt = pyplot()
    kept = study.kept
    keys = [k for k in kept if (rings_mount is None or k[2] == rings_mount)
            and (rings_rate is None or k[1] == rings_rate)]
    if keys:
        m0, f0 = keys[0][2], keys[0][1]
        keys = sorted(k for k in keys if k[2] == m0 and k[1] == f0)
    n = max(len(keys), 1)
    fig = plt.figure(figsize=(13, 1.2 + 1.6 * n), dpi=110)
    gs = fig.add_gridspec(n, 2, width_ratios=[1.3, 1])
    a2 = fig.add_subplot(gs[:, 1])
    cmap = plt.get_cmap("plasma")
    first = None
    for i, k in enumerate(keys):
        ax = fig.add_subplot(gs[i, 0], sharex=first, sharey=first)
        first = first or ax
        p = kept[k]
        ax.scatter(p[:, 0], p[:, 1], s=0.3, color=cmap(0.85 * i / max(n - 1, 1)),
                   rasterized=True)
        ax.set_ylabel("offset (m)", fontsize=8)
        ax.text(0.01, 0.92, f"{k[0]:g} m/s", transform=ax.transAxes, fontsize=9,
                va="top", bbox=dict(fc="white", alpha=0.8, lw=0))
        ax.set_aspect("equal", adjustable="box")
        if i == 0:
            ax.set_title(f"{study.sensor.name}, {m0} mount, {f0:g} Hz: floor footprint of "
                         "3 sweeps (every 6th channel)", fontsize=9)
        if i == n - 1:
            from survey.analysis.surface import RouteFrame

            ax.set_xlabel("distance along the route (m)"
                          if isinstance(study.frame, RouteFrame) else "chainage (m)")
        else:
            ax.tick_params(labelbottom=False)
    for mount in sorted({r.mount for r in rows}):
        for f in sorted({r.rate_hz for r in rows}):
            sel = sorted([r for r in rows if r.mount == mount and r.rate_hz == f
                          and r.speed_mps > 0], key=lambda r: r.speed_mps)
            if not sel:
                continue
            v = np.array([r.speed_mps for r in sel])
            mk = "o" if f == min(r.rate_hz for r in rows) else "x"
            a2.plot(v, [r.density_lining for r in sel], mk + "-", ms=8, mfc="none",
                    label=f"lining, {f:g} Hz, {mount}")
            a2.plot(v, [r.density_floor for r in sel], mk + "--", ms=8, mfc="none",
                    label=f"floor, {f:g} Hz, {mount}")
    moving = [r for r in rows if r.speed_mps > 0]
    if moving:
        r0 = min(moving, key=lambda r: r.speed_mps)
        vv = np.linspace(min(r.speed_mps for r in moving), max(r.speed_mps for r in moving))
        for d in (r0.density_lining, r0.density_floor):
            a2.plot(vv, d * r0.speed_mps / vv, ":", color="grey",
                    label="1/v" if d == r0.density_lining else None)
    a2.set_xlabel("speed (m/s)")
    a2.set_ylabel("points per m^2 (one pass)")
    a2.set_yscale("log")
    a2.grid(alpha=0.3, which="both")
    a2.set_title("density per pass (equal at every rate: constant pulse rate)",
                 fontsize=9)
    a2.legend(fontsize=7)
    fig.tight_layout()
    save_png(fig, path)
    return path
