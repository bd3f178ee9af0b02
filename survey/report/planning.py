"""Station plans on paper: CSV of stations, Markdown summary and the unrolled coverage
map (chainage x angle, like the seed's Figure 6). On any mesh (``RoutePlanner``) the
chainage is the distance along the route found in it and the map shows the mesh's own
(sub-)triangles unrolled around the route."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from survey.analysis.planning import Plan, Planner


def plan_csv(plan: Plan, planner: Planner) -> str:
    """One row per station: chainage (on any mesh: distance along the route), position,
    area share it serves alone, overlap with the next station, left offset from the
    axis or route (m)."""
    lines = ["plan,station,chainage_m,x,y,z,serves_share,overlap_next_share,offset_m"]
    off = plan.offsets_m if len(plan.offsets_m) else np.zeros(len(plan.chainages))
    for i, (s, p) in enumerate(zip(plan.chainages, plan.stations)):
        ov = f"{plan.overlap[i]:.4f}" if i < len(plan.overlap) else ""
        lines.append(f"{plan.name},{i + 1},{s:.3f},{p[0]:.4f},{p[1]:.4f},{p[2]:.4f},"
                     f"{plan.per_station[i]:.4f},{ov},{off[i]:.3f}")
    return "\n".join(lines) + "\n"


def _where(planner: Planner) -> str:
    """What the stations stand on and what the coverage is measured on (one sentence)."""
    from survey.analysis.planning import RoutePlanner

    c = planner.cells
    if isinstance(planner, RoutePlanner):
        r = planner.route
        return (f"Surface {c.total_area:.1f} m^2 (floor left out): the mesh's "
                f"{len(np.unique(planner.surface.triangle)):,} triangles as {len(c.area):,} area samples; "
                f"stations {planner.height_m:.2f} m above the floor along the route found "
                f"in the mesh ({r.length_m:.1f} m, smallest clearance "
                f"{r.min_clearance_m:.2f} m) or offset across it; chainage is the "
                "distance along the route.")
    return (f"Lining area {c.total_area:.1f} m^2 in {len(c.area):,} cells; stations "
            f"{planner.height_m:.2f} m above the floor on the axis.")


def plan_markdown(plans: Sequence[Plan], planner: Planner,
                  info: Mapping[str, Any] | None = None) -> str:
    """The plans as Markdown: thresholds, one row per plan, the optimisation's figures
    and each plan's largest gaps."""
    th = planner.th
    out = [(f"# Station plan: {planner.sensor.name}, resolution {planner.resolution} "
            f"({np.degrees(planner.step_rad):.4f} deg)"), "",
           (f"Thresholds: point spacing <= {1000 * th.spacing_m:.1f} mm, incidence <= "
            f"{np.degrees(th.incidence_rad):.0f} deg, range <= {th.range_m:.1f} m. "
            f"{_where(planner)} Point spacing "
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
            at = "x" in p.gaps[0]
            out += ["", f"## Largest gaps: {p.name}", "",
                    "| chainage from (m) | to (m) | angle from (deg) | to (deg) | area (m^2) |"
                    + (" centre x, y, z (m) |" if at else ""),
                    "|---:|---:|---:|---:|---:|" + ("---|" if at else "")]
            for g in p.gaps[:8]:
                out.append(f"| {g['chainage_from']:.2f} | {g['chainage_to']:.2f} | "
                           f"{g['angle_from_deg']:.0f} | {g['angle_to_deg']:.0f} | "
                           f"{g['area_m2']:.2f} |" + (f" {g['x']:.2f}, {g['y']:.2f}, "
                                                     f"{g['z']:.2f} |" if at else ""))
    return "\n".join(out) + "\n"


def plan_summary(plans: Sequence[Plan], planner: Planner,
                 info: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The plans as plain data (what ``tunnelsim plan`` writes as plan.json): sensor,
    resolution, what the stations follow ("centreline" or "route"), per plan its name,
    station count, coverage share, gap count, station chainages and offsets (m) and
    positions (x, y, z in m), the optimisation's figures (``Planner.optimize``'s info)
    or None, and on any mesh the route's length and clearance and the surface measured.
    NumPy numbers become Python ones; a NaN stays NaN (strict JSON writers make it
    null)."""
    def plain(v: Any) -> Any:
        return v.item() if isinstance(v, np.generic) else v

    from survey.analysis.planning import RoutePlanner

    out = {"sensor": planner.sensor.name, "resolution": planner.resolution,
           "along": "centreline",
           "plans": [{"name": p.name, "stations": len(p.chainages),
                      "coverage": float(p.coverage), "gaps": len(p.gaps),
                      "chainages_m": np.asarray(p.chainages, dtype=np.float64).tolist(),
                      "offsets_m": np.asarray(p.offsets_m, dtype=np.float64).tolist(),
                      "stations_xyz": np.asarray(p.stations, dtype=np.float64).tolist()}
                     for p in plans],
           "optimisation": None if info is None else {k: plain(v) for k, v in info.items()}}
    if isinstance(planner, RoutePlanner):
        r = planner.route
        out.update(along="route", route={"length_m": r.length_m,
                                         "min_clearance_m": r.min_clearance_m,
                                         "seconds": r.seconds},
                   surface={"triangles": int(len(np.unique(planner.surface.triangle))),
                            "samples": int(len(planner.cells.area)),
                            "area_m2": planner.cells.total_area})
    return out


def plot_coverage(plans: Sequence[Plan], planner: Planner,
                  path: str | os.PathLike[str]) -> str | os.PathLike[str]:
    """Unrolled coverage maps, one panel per plan: white = no cell (floor), red = gap,
    yellow = seen but below the thresholds, greens = served by 1, 2, 3+ stations;
    station chainages marked (open triangles: offset from the route). On any mesh the
    mesh's own (sub-)triangles, unrolled around the route (distance along it x angle
    from the crown seen from the instrument height). Atomic PNG."""
    from survey.report.plotting import pyplot, save_png

    plt = pyplot()
    from matplotlib.colors import ListedColormap

    from survey.analysis.planning import Cells, RoutePlanner

    c = planner.cells
    cmap = ListedColormap(["#d7301f", "#fdd049", "#a1d99b", "#41ab5d", "#006d2c"])
    fig, axes = plt.subplots(len(plans), 1, figsize=(11, 1.2 + 2.2 * len(plans)), dpi=110,
                             squeeze=False, layout="constrained")
    route = isinstance(planner, RoutePlanner)
    if route:
        polys, seam = _unrolled(planner)
    for ax, p in zip(axes[:, 0], plans):
        val = np.where(p.served > 0, 1 + np.minimum(p.served, 3),
                       np.where(p.seen > 0, 1, 0)).astype(float)
        if route:
            im = _draw_unrolled(ax, polys[~seam], val[~seam], cmap)
            ax.set_xlim(*planner.span_m)
            ax.set_ylim(-180, 180)
        else:
            assert isinstance(c, Cells)
            grid = np.full(c.shape, np.nan)
            grid[c.ring, c.col] = val
            ext = [c.s_edges[0], c.s_edges[-1], np.degrees(c.a_edges[0]),
                   np.degrees(c.a_edges[-1])]
            im = ax.imshow(grid.T, origin="lower", aspect="auto", extent=ext, cmap=cmap,
                           vmin=-0.5, vmax=4.5, interpolation="nearest")
        side = np.asarray(p.offsets_m) != 0 if len(p.offsets_m) else \
            np.zeros(len(p.chainages), dtype=bool)
        ax.plot(p.chainages[~side], np.zeros(int((~side).sum())), "v", color="k", ms=4)
        if side.any():
            ax.plot(p.chainages[side], np.zeros(int(side.sum())), "^", color="k", ms=4,
                    mfc="none", label="offset from the route")
            ax.legend(loc="upper right", fontsize=7)
        ax.set_title(f"{p.name}: {len(p.chainages)} stations, coverage "
                     f"{100 * p.coverage:.1f} %", fontsize=9)
        ax.set_ylabel("angle from crown (deg)")
        ax.set_yticks([-180, -90, 0, 90, 180])
    axes[-1, 0].set_xlabel("distance along the route (m)" if route else "chainage (m)")
    cb = fig.colorbar(im, ax=axes[:, 0].tolist(), ticks=[0, 1, 2, 3, 4], shrink=0.9)
    cb.ax.set_yticklabels(["gap", "below thr.", "1 station", "2", "3+"], fontsize=8)
    save_png(fig, os.fspath(path))
    return path


def _unrolled(planner: Any) -> tuple[np.ndarray, np.ndarray]:
    """The surface samples' corners unrolled around the route: (k, 3, 2) (distance in
    m, angle from the crown in degrees), and (k,) bool: straddling the +-180 deg seam
    (not drawn)."""
    c = planner.cells
    s, off, h = planner.frame.to_local(c.corners.reshape(-1, 3))
    ang = np.degrees(np.arctan2(off, h - planner.height_m)).reshape(-1, 3)
    seam = np.ptp(ang, axis=1) > 180.0
    return np.stack([s.reshape(-1, 3), ang], axis=2), seam


def _draw_unrolled(ax: Any, polys: np.ndarray, val: np.ndarray, cmap: Any) -> Any:
    """Sub-triangles as filled polygons coloured by ``val`` (0 gap .. 4 three or more
    stations); gaps drawn last so that no covered neighbour hides them."""
    from matplotlib.collections import PolyCollection

    order = np.argsort(-val, kind="stable")
    pc = PolyCollection(list(polys[order]), array=val[order], cmap=cmap, edgecolors="face",
                        linewidths=0.2, rasterized=True)
    pc.set_clim(-0.5, 4.5)
    ax.add_collection(pc)
    return pc


__all__ = ["plan_csv", "plan_markdown", "plan_summary", "plot_coverage"]
