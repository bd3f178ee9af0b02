"""Station plans on paper: CSV of stations, Markdown summary and the unrolled coverage
map (chainage x angle, like the seed's Figure 6)."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from survey.analysis.planning import Plan, Planner


def plan_csv(plan: Plan, planner: Planner) -> str:
    """One row per station: chainage, position, area share it serves alone, overlap with
    the next station."""
    lines = ["plan,station,chainage_m,x,y,z,serves_share,overlap_next_share"]
    for i, (s, p) in enumerate(zip(plan.chainages, plan.stations)):
        ov = f"{plan.overlap[i]:.4f}" if i < len(plan.overlap) else ""
        lines.append(f"{plan.name},{i + 1},{s:.3f},{p[0]:.4f},{p[1]:.4f},{p[2]:.4f},"
                     f"{plan.per_station[i]:.4f},{ov}")
    return "\n".join(lines) + "\n"


def plan_markdown(plans: Sequence[Plan], planner: Planner,
                  info: Mapping[str, Any] | None = None) -> str:
    th = planner.th
    out = [(f"# Station plan: {planner.sensor.name}, resolution {planner.resolution} "
            f"({np.degrees(planner.step_rad):.4f} deg)"), "",
           (f"Thresholds: point spacing <= {1000 * th.spacing_m:.1f} mm, incidence <= "
            f"{np.degrees(th.incidence_rad):.0f} deg, range <= {th.range_m:.1f} m. Lining "
            f"area {planner.cells.total_area:.1f} m^2 in {len(planner.cells.area):,} cells; "
            f"stations {planner.height_m:.2f} m above the floor on the axis. Point spacing "
            "is the preset's angular step times range over cos(incidence)."), "",
           "| plan | stations | coverage | largest gap (m^2) | gaps | min overlap with next |",
           "|---|---:|---:|---:|---:|---:|"]
    for p in plans:
        big = p.gaps[0]["area_m2"] if p.gaps else 0.0
        ov = f"{100 * p.overlap.min():.1f} %" if len(p.overlap) else "-"
        out.append(f"| {p.name} | {len(p.chainages)} | {100 * p.coverage:.2f} % | "
                   f"{big:.2f} | {len(p.gaps)} | {ov} |")
    if info:
        out += ["", "## Optimisation", "",
                (f"- candidates: {info['candidates']}, target {100 * info['target']:.1f} % "
                 f"(reachable with all candidates: {100 * info['reachable']:.2f} %)"),
                (f"- greedy: {info['greedy']} stations; MILP: {info.get('milp')} stations "
                 f"({info.get('milp_status')})"),
                f"- lower bound {info.get('lower_bound')}, optimality gap "
                f"{100 * info['gap']:.1f} %" if np.isfinite(info.get("gap", np.nan))
                else "- optimality gap: unknown (no bound)"]
        if info.get("note"):
            out.append(f"- note: {info['note']}")
    for p in plans:
        if p.gaps:
            out += ["", f"## Largest gaps: {p.name}", "",
                    "| chainage from (m) | to (m) | angle from (deg) | to (deg) | area (m^2) |",
                    "|---:|---:|---:|---:|---:|"]
            for g in p.gaps[:8]:
                out.append(f"| {g['chainage_from']:.2f} | {g['chainage_to']:.2f} | "
                           f"{g['angle_from_deg']:.0f} | {g['angle_to_deg']:.0f} | "
                           f"{g['area_m2']:.2f} |")
    return "\n".join(out) + "\n"


def plan_summary(plans: Sequence[Plan], planner: Planner,
                 info: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The plans as plain data (what ``tunnelsim plan`` writes as plan.json): sensor,
    resolution, per plan its name, station count, coverage share, gap count and station
    chainages (m), and the optimisation's figures (``Planner.optimize``'s info) or None.
    NumPy numbers become Python ones; a NaN stays NaN (strict JSON writers make it
    null)."""
    def plain(v: Any) -> Any:
        return v.item() if isinstance(v, np.generic) else v

    return {"sensor": planner.sensor.name, "resolution": planner.resolution,
            "plans": [{"name": p.name, "stations": len(p.chainages),
                       "coverage": float(p.coverage), "gaps": len(p.gaps),
                       "chainages_m": np.asarray(p.chainages, dtype=np.float64).tolist()}
                      for p in plans],
            "optimisation": None if info is None else {k: plain(v) for k, v in info.items()}}


def plot_coverage(plans: Sequence[Plan], planner: Planner,
                  path: str | os.PathLike[str]) -> str | os.PathLike[str]:
    """Unrolled coverage maps, one panel per plan: white = no cell (floor), red = gap,
    yellow = seen but below the thresholds, greens = served by 1, 2, 3+ stations;
    station chainages marked. Atomic PNG."""
    from survey.report.plotting import pyplot, save_png

    plt = pyplot()
    from matplotlib.colors import ListedColormap

    c = planner.cells
    cmap = ListedColormap(["#d7301f", "#fdd049", "#a1d99b", "#41ab5d", "#006d2c"])
    fig, axes = plt.subplots(len(plans), 1, figsize=(11, 1.2 + 2.2 * len(plans)), dpi=110,
                             squeeze=False, layout="constrained")
    ext = [c.s_edges[0], c.s_edges[-1], np.degrees(c.a_edges[0]),
           np.degrees(c.a_edges[-1])]
    for ax, p in zip(axes[:, 0], plans):
        grid = np.full(c.shape, np.nan)
        val = np.where(p.served > 0, 1 + np.minimum(p.served, 3),
                       np.where(p.seen > 0, 1, 0)).astype(float)
        grid[c.ring, c.col] = val
        im = ax.imshow(grid.T, origin="lower", aspect="auto", extent=ext, cmap=cmap,
                       vmin=-0.5, vmax=4.5, interpolation="nearest")
        ax.plot(p.chainages, np.zeros_like(p.chainages), "v", color="k", ms=4)
        ax.set_title(f"{p.name}: {len(p.chainages)} stations, coverage "
                     f"{100 * p.coverage:.1f} %", fontsize=9)
        ax.set_ylabel("angle from crown (deg)")
        ax.set_yticks([-180, -90, 0, 90, 180])
    axes[-1, 0].set_xlabel("chainage (m)")
    cb = fig.colorbar(im, ax=axes[:, 0].tolist(), ticks=[0, 1, 2, 3, 4], shrink=0.9)
    cb.ax.set_yticklabels(["gap", "below thr.", "1 station", "2", "3+"], fontsize=8)
    save_png(fig, os.fspath(path))
    return path


__all__ = ["plan_csv", "plan_markdown", "plan_summary", "plot_coverage"]
