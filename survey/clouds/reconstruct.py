"""Tunnel-aware mesh reconstruction from a cleaned point cloud.

1. Axis: a centreline from the cloud (``estimate_axis``): slice the cloud along its
   principal direction, take each slice's robust centre (mid-range of the 2nd and 98th
   percentiles across and up), fit an ``Alignment`` to the centres (least-squares
   spline, ``Alignment.fit``), then repeat once with slices perpendicular to that
   alignment. A cloud that is not elongated, or whose slices do not surround their
   centre, is not a tunnel: "could not find a tunnel axis".
2. Unroll: every point to (chainage s, angle phi, radius rho) about the profile centre
   (offset 0, height h_c) of the alignment's cross-section; phi from the crown,
   positive to the left (as ``Profile.t_at_angle``).
   Chainages beyond the alignment's ends are measured along the end tangents.
   Where the lining ends (a portal) is found from the data (``lining_extent``: per
   ring, the share of angular sectors whose radius agrees with the neighbouring
   rings' lining drops where the crown and walls stop); terrain beyond it, and
   points farther out than the lining near a portal end (the face around the
   opening), do not enter the cells. The axis estimate refuses slices whose extent
   is not the tube's, so terrain does not pull it either.
3. Cells of ``cell_m`` along the axis x ``cell_rad`` around it: the radius of a cell is
   the median of its points' radii (robust to noise and to a minority of attachments);
   its support is the number of points. Cells with fewer than ``min_points`` are filled
   by periodic linear interpolation around the ring, then linearly along the axis, and
   get support 0 (extrapolated).
4. Triangulate the grid of cell centres (two triangles per quad, faces pointing into
   the tunnel, open at both portals) and map back with ``Alignment.to_world``.

The result carries per-vertex ``support`` (a PLY vertex property: the seed study's
Figure 2 colouring).

Memory: with ``counts`` (voxel centroids and their point counts, as ``tunnelsim mesh``
streams them through ``VoxelGrid``) a cell's radius is the count-weighted median, so
the mesher runs on the occupied voxels (about lining area / voxel^2), not on the
points; the unrolling goes ``UNROLL_CHUNK`` points at a time, and the rest costs about
90 bytes a point (measured peak of ``tunnelsim mesh`` on a 300 m tube: ~140-165 bytes a
voxel of 2 cm, 4.7 GB for 10^8 points in 29 M voxels).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from survey.clouds.axis import (
    cell_runs,
    extend_chainage,
    fill_gaps,
    lining_extent,
    unroll,
    unroll_extended,
)
from survey.errors import ReconstructionError
from survey.world.alignment import Alignment


@dataclass
class ReconstructedTunnel:
    """vertices (n, 3), faces (m, 3), support (n,) int (0 = extrapolated),
    alignment, centre_height_m, the grid (chainages (r,), angles (k,)) and ``quality``
    (radial point-to-surface distances: mean, median, 95 %, max; extrapolated share;
    triangles)."""

    vertices: np.ndarray
    faces: np.ndarray
    support: np.ndarray
    alignment: Alignment
    centre_height_m: float
    chainages: np.ndarray
    angles: np.ndarray
    quality: dict | None = None

    def write(self, path):
        """Binary PLY with a ``support`` vertex property; atomic."""
        from survey.world.mesh import write_ply

        return write_ply(path, self.vertices, self.faces,
                         vertex_fields={"support": self.support.astype(np.float64)})

    @property
    def extrapolated_share(self) -> float:
        return float(np.mean(self.support == 0))


def to_world_extended(alignment: Alignment, chainage: ArrayLike, offset: ArrayLike,
                      height: ArrayLike) -> NDArray[np.float64]:
    """``Alignment.to_world`` with chainages beyond the ends on the end tangent, at the
    end's elevation (the straight extension of ``extend_chainage``)."""
    s = np.asarray(chainage, dtype=np.float64)
    c0, c1 = alignment.chainage_range
    sc = np.clip(s, c0, c1)
    w = alignment.to_world(sc, offset, height)
    beyond = s - sc
    if np.any(beyond != 0):
        th = alignment.heading(sc)
        w[..., 0] += beyond * np.cos(th)
        w[..., 1] += beyond * np.sin(th)
    return w


#: How far beyond an estimated axis's ends points still count when no rings are given
#: (m), along the end tangent: the estimate ends a slice or two (2 m each) inside the
#: data, more at a portal where the slices holding the face were refused (4.8 m on
#: the portal of tests/survey/clouds/test_portal.py); the lining's extent
#: (``lining_extent``) then decides where the mesh stops. ASSUMED: the tangent departs
#: from a curve of radius 200 m by L^2 / 2R = 0.25 m over 10 m, which the rings (a
#: median radius about their own centre) still follow.
AXIS_END_REACH_M = 10.0


def _weighted_median_runs(cell: NDArray[np.int64], r: NDArray[np.float64],
                          w: NDArray[np.int64]
                          ) -> tuple[NDArray[np.int64], NDArray[np.float64],
                                     NDArray[np.int64]]:
    """(cell ids (k,), weighted median radius (k,), summed weight (k,)) per cell; with
    unit weights the plain median (the mean of the two middle values of an even run)."""
    order = np.lexsort((r, cell))
    cs, rs, ws = cell[order], r[order], w[order]
    starts = np.flatnonzero(np.concatenate([[True], cs[1:] != cs[:-1]]))
    lengths = np.diff(np.append(starts, len(cs)))
    cum = np.cumsum(ws)
    before = np.concatenate([[0], cum[:-1]])[starts]       # weight before each run
    total = np.append(before[1:], cum[-1]) - before
    # The first element whose cumulative weight within its run reaches half the run's
    # weight; where it is exactly half (an even split), the mean with the next one.
    twice = 2 * (cum - np.repeat(before, lengths))
    tot = np.repeat(total, lengths)
    at = starts + np.add.reduceat((twice < tot).astype(np.int64), starts)
    ends = starts + lengths
    even = (twice[at] == total) & (at + 1 < ends)
    med = np.where(even, 0.5 * (rs[at] + rs[np.minimum(at + 1, len(rs) - 1)]), rs[at])
    return cs[starts], med, total


def _weighted_quantiles(x: NDArray[np.float64], w: NDArray[np.int64], q: list[float]
                        ) -> list[float]:
    """Quantiles q (fractions) of x (n,) with integer weights w (n,) (the value whose
    cumulative weight first reaches q x the total)."""
    order = np.argsort(x)
    cum = np.cumsum(w[order])
    return [float(x[order][min(np.searchsorted(cum, qq * cum[-1]), len(x) - 1)])
            for qq in q]


def reconstruct_tunnel(points: ArrayLike, *, alignment: Alignment | None = None,
                       centre_height_m: float | None = None, cell_m: float = 0.1,
                       cell_rad: float = np.deg2rad(2.0), min_points: int = 3,
                       margin_m: float = 0.0,
                       rows_at: ArrayLike | None = None,
                       end_reach_m: float | None = None,
                       counts: ArrayLike | None = None,
                       portals: bool | None = None) -> ReconstructedTunnel:
    """Mesh a tunnel lining from points (see module doc).

    Parameters
    ----------
    points : (n, 3) float64
        The cloud (or voxel centroids, with ``counts``).
    alignment, centre_height_m : Alignment and float, optional
        Known centreline and height of the profile centre above it (e.g. from the
        tunnel's JSON); else estimated from the cloud.
    cell_m, cell_rad : float
        Cell size along the axis (m) and around it (rad).
    min_points : int
        Cells with fewer points are interpolated (support 0).
    margin_m : float
        Chainage trimmed at both ends of the point coverage (m).
    rows_at : (r,) array_like of float, optional
        Increasing chainages of the mesh rings (e.g. the chainages of measured
        profiles); each point goes to the nearest ring within half the local spacing.
        Default: rings every ``cell_m``.
    end_reach_m : float, optional
        How far beyond the alignment's ends points still count (m), measured along the
        end tangent; the rings may then lie beyond the ends (the alignment extended
        straight). Default: with ``rows_at``, as far as the end rings' halves reach (an
        estimated axis ends ~2 m inside the data, and a profile whose plane is not
        quite normal to it has a part beyond its end: without them the first ring lost
        a wall at Ringo's portal and was filled by a chord 0.5 m inside); else
        ``AXIS_END_REACH_M`` for an estimated axis with ``portals``, 0 otherwise.
    counts : (n,) int64, optional
        Multiplicity of each point (the points per voxel of a voxel grid,
        ``VoxelGrid.result``): a cell's radius is the weighted median, its support
        (and the ``min_points`` test) the summed counts, so that a voxelised cloud
        meshes as the cloud it came from.
    portals : bool, optional
        Find where the lining ends (``survey.clouds.axis.lining_extent``, rings of
        ``cell_m`` or the ``rows_at`` spacing) and mesh only that extent: terrain
        beyond a portal, and points farther out than the lining within
        ``PORTAL_BAND_M`` of a portal end (the face around the opening), are left out;
        rings (``rows_at``) beyond it are dropped. False: every point's chainage range,
        as before issue 18. Default: True for a cloud, False with ``rows_at``.

    Returns
    -------
    ReconstructedTunnel
        The mesh, its per-vertex support, the alignment and grid it was built on and
        its ``quality``.
    """
    # DECISION: with ``rows_at`` (measured profiles) each ring is lining by the caller's
    # word; on Ringo the detection cut the last 2 m, where the portal changes the
    # profile, and the leave-one-out C2C of profile 235 went from 38 to 103 mm.
    if portals is None:
        portals = rows_at is None
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or not np.isfinite(p).all():
        raise ReconstructionError(f"Expected finite points of shape (n, 3), got {p.shape}.")
    if len(p) == 0:
        raise ReconstructionError("Expected a non-empty cloud, got 0 points.")
    if not (cell_m > 0 and 0 < cell_rad < np.pi / 4):
        raise ReconstructionError(f"Expected cell sizes > 0 m and in (0, pi/4) rad, got "
                                  f"{cell_m}, {cell_rad}.")
    w = None
    if counts is not None:
        w = np.asarray(counts)
        if w.shape != (len(p),) or not np.issubdtype(w.dtype, np.integer) or (w < 1).any():
            raise ReconstructionError(f"Expected `counts` as ({len(p)},) integers >= 1, "
                                      f"got shape {w.shape} of {w.dtype}.")
        w = w.astype(np.int64)
    estimated = alignment is None
    alignment, hc, s, phi, rho = unroll_extended(p, alignment, centre_height_m)
    c0, c1 = alignment.chainage_range
    if end_reach_m is None:
        if rows_at is None:
            end_reach_m = AXIS_END_REACH_M if (estimated and portals) else 0.0
        else:               # as far as the end rings' own halves reach
            r = np.asarray(rows_at, dtype=np.float64).reshape(-1)
            if len(r) > 1:
                end_reach_m = max(0.0, c0 - (r[0] - 0.5 * (r[1] - r[0])),
                                  (r[-1] + 0.5 * (r[-1] - r[-2])) - c1)
            else:
                end_reach_m = 0.0
    use = (s >= c0 - end_reach_m) & (s <= c1 + end_reach_m)
    if end_reach_m == 0.0:
        use &= (s > c0 + 1e-9) & (s < c1 - 1e-9)
    if use.sum() == 0:
        raise ReconstructionError("Expected points along the alignment, got none within "
                                  "its chainage range.")
    extent = None
    if portals:
        ring = cell_m
        if rows_at is not None:
            ra = np.asarray(rows_at, dtype=np.float64).reshape(-1)
            ring = float(np.median(np.diff(ra))) if len(ra) > 1 else cell_m
        if not ring > 0:    # decreasing rows: refused below
            ring = cell_m
        extent = lining_extent(s[use], phi[use], rho[use], ring_m=ring)
        # A portal where any point lies beyond the end (a known alignment may end at
        # the portal, and the points beyond are not in `use`).
        extent = replace(extent, portal_start=bool((s < extent.start_m - ring).any()),
                         portal_end=bool((s > extent.end_m + ring).any()))
        use &= ~extent.terrain(s, phi, rho)
    n_a = max(8, int(np.round(2 * np.pi / cell_rad)))
    da = 2 * np.pi / n_a
    if rows_at is None:
        s_lo, s_hi = s[use].min() + margin_m, s[use].max() - margin_m
        n_s = max(2, int(np.ceil((s_hi - s_lo) / cell_m)))
        ds = (s_hi - s_lo) / n_s
        sc = s_lo + (np.arange(n_s) + 0.5) * ds
        use &= (s >= s_lo) & (s <= s_hi)
        i = np.clip(((s[use] - s_lo) / ds).astype(np.int64), 0, n_s - 1)
    else:
        sc = np.asarray(rows_at, dtype=np.float64)
        if sc.ndim != 1 or len(sc) < 2 or (np.diff(sc) <= 0).any():
            raise ReconstructionError("Expected `rows_at` as at least 2 increasing "
                                      "chainages.")
        if extent is not None:          # rings whose half-spacing misses the lining go
            half = np.diff(sc).min() / 2
            sc = sc[(sc + half > extent.start_m) & (sc - half < extent.end_m)]
            if len(sc) < 2:
                raise ReconstructionError(f"Expected at least 2 rings on the lining, got "
                                          f"{len(sc)} (lining {extent.start_m:.2f} to "
                                          f"{extent.end_m:.2f} m); the portals found in the data "
                                          "leave too little lining: crop the cloud to the "
                                          "tunnel (preprocess --crop), or in Python pass "
                                          "portals=False.")
        n_s = len(sc)
        edges = np.concatenate([[sc[0] - (sc[1] - sc[0]) / 2], (sc[1:] + sc[:-1]) / 2,
                                [sc[-1] + (sc[-1] - sc[-2]) / 2]])
        use &= (s >= edges[0]) & (s < edges[-1])
        i = np.searchsorted(edges, s[use], side="right") - 1
    cell = i * n_a + np.mod(np.floor((phi[use] + np.pi) / da).astype(np.int64), n_a)
    del i
    r = rho[use]
    del s, phi, rho
    wu = None if w is None else w[use]
    if wu is None:
        # Median radius per cell (the middle element(s) of each sorted run).
        ids, rs, starts, cnt = cell_runs(cell, r)
        med = 0.5 * (rs[starts + (cnt - 1) // 2] + rs[starts + cnt // 2])
    else:
        ids, med, cnt = _weighted_median_runs(cell, r, wu)
    radius = np.full(n_s * n_a, np.nan)
    support = np.zeros(n_s * n_a, dtype=np.int64)
    radius[ids] = med
    support[ids] = cnt
    radius[support < min_points] = np.nan
    support[support < min_points] = 0
    grid = fill_gaps(radius.reshape(n_s, n_a), sc)
    if not np.isfinite(grid).all():
        raise ReconstructionError("Expected points around the whole lining, got too few to "
                                  "fill the unrolled grid; use larger cells.")
    ac = -np.pi + (np.arange(n_a) + 0.5) * da
    o = grid * np.sin(ac)[None, :]
    z = hc + grid * np.cos(ac)[None, :]
    verts = to_world_extended(alignment, np.broadcast_to(sc[:, None], grid.shape), o,
                              z).reshape(-1, 3)
    # Faces: grid quads. The angle runs bottom -> right wall -> crown -> left wall,
    # clockwise in the (offset, height) plane, so (a, b, c) winds the normals inwards.
    a_ = (np.arange(n_s - 1)[:, None] * n_a + np.arange(n_a)[None, :]).ravel()
    b_ = (np.arange(n_s - 1)[:, None] * n_a + (np.arange(n_a)[None, :] + 1) % n_a).ravel()
    c_, d_ = a_ + n_a, b_ + n_a
    faces = np.concatenate([np.stack([a_, b_, c_], 1), np.stack([b_, d_, c_], 1)])
    # Quality: each point's radial distance to its cell's surface (the point-to-mesh
    # distance for a smooth lining, up to the cell's tilt); voxels weighted by counts.
    resid = np.abs(r - grid.reshape(-1)[cell])
    if wu is None:
        n_pts, mean = int(use.sum()), float(resid.mean())
        med_r, p95 = float(np.median(resid)), float(np.percentile(resid, 95))
    else:
        n_pts, mean = int(wu.sum()), float(np.average(resid, weights=wu))
        med_r, p95 = _weighted_quantiles(resid, wu, [0.5, 0.95])
    quality = {"points": n_pts, "mean_m": mean, "median_m": med_r, "p95_m": p95,
               "max_m": float(resid.max()),
               "extrapolated_share": float(np.mean(support == 0)),
               "triangles": int(len(faces))}
    if extent is not None:
        quality["lining_start_m"] = float(extent.start_m)
        quality["lining_end_m"] = float(extent.end_m)
    return ReconstructedTunnel(verts, faces.astype(np.int64), support, alignment, hc, sc, ac,
                               quality)


def poisson_tunnel(points: ArrayLike, *, alignment: Alignment | None = None,
                   centre_height_m: float | None = None, depth: int = 10,
                   density_quantile: float = 0.02, normal_radius_m: float = 0.1
                   ) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """The CloudCompare-style alternative: screened Poisson reconstruction through
    Open3D (Kazhdan & Hoppe 2013), with normals oriented towards the tunnel axis,
    vertices of the lowest ``density_quantile`` of Poisson densities removed, and the
    "bulbous closures" Poisson puts at the portals cut off: every vertex beyond the
    chainage range of the points goes. Returns (vertices (n, 3), faces (m, 3)).
    Needs the optional Open3D (``pip install open3d``)."""
    from raytrace.config import threading_info

    threading_info()        # before Open3D's TBB is loaded (see survey.clouds.solid)
    try:
        import open3d as o3d
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ReconstructionError("Expected the optional package open3d for Poisson "
                                  "reconstruction; install it with: pip install open3d "
                                  "(or use the default tunnel-aware method).") from exc
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 100 or not np.isfinite(p).all():
        raise ReconstructionError(f"Expected at least 100 finite points (n, 3), got "
                                  f"{p.shape}.")
    alignment, hc, s, off, h, _, _ = unroll(p, alignment, centre_height_m)
    origin = np.round(p.mean(axis=0))
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p - origin))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=normal_radius_m,
                                                              max_nn=30))
    n = np.asarray(pc.normals)
    axis = alignment.to_world(s, 0 * off, 0 * h + hc) - origin
    flip = np.einsum("ij,ij->i", n, axis - (p - origin)) < 0
    n[flip] *= -1.0                                   # towards the axis (the scanner side)
    pc.normals = o3d.utility.Vector3dVector(n)
    mesh, o3d_dens = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pc,
                                                                                depth=depth)
    v = np.asarray(mesh.vertices) + origin
    f = np.asarray(mesh.triangles).astype(np.int64)
    dens = np.asarray(o3d_dens, dtype=np.float64)
    sv, _, _ = alignment.to_local(v)
    keep = (dens >= np.quantile(dens, density_quantile)) & (sv >= s.min()) & (sv <= s.max())
    f = f[keep[f].all(axis=1)]
    used = np.unique(f)
    remap = np.full(len(v), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return v[used], remap[f]




#: Growth of the cells per step of ``reconstruct_within_budget``: at least 2 % (cell
#: counts round, so a smaller step might not change the mesh).
BUDGET_MIN_GROWTH = 1.02
#: Largest cell growth ``reconstruct_within_budget`` tries before giving up.
BUDGET_MAX_GROWTH = 1e3


def reconstruct_within_budget(points: ArrayLike, max_triangles: int, *,
                              alignment: Alignment | None = None,
                              centre_height_m: float | None = None, cell_m: float = 0.1,
                              cell_rad: float = np.deg2rad(2.0),
                              min_points: int = 3, counts: ArrayLike | None = None,
                              portals: bool | None = None) -> ReconstructedTunnel:
    """``reconstruct_tunnel`` with at most ``max_triangles`` faces.

    The same reconstruction on proportionally larger cells (both directions scaled
    alike, by the square root of the excess, at least ``BUDGET_MIN_GROWTH`` a step, the
    angle capped below pi/4), until the mesh fits: the grid stays regular and the
    support per cell meaningful. The axis is estimated once, on the first pass.

    Parameters
    ----------
    points : (n, 3) float64
    max_triangles : int
        The budget, > 0.
    alignment, centre_height_m, cell_m, cell_rad, min_points, counts, portals
        As ``reconstruct_tunnel``; ``cell_m``/``cell_rad`` are the finest cells tried.

    Raises
    ------
    ReconstructionError
        When even cells ``BUDGET_MAX_GROWTH`` times larger exceed the budget.
    """
    if not (isinstance(max_triangles, (int, np.integer)) and max_triangles > 0):
        raise ReconstructionError(f"Expected a positive integer triangle budget, got "
                                  f"{max_triangles!r}.")
    rec = reconstruct_tunnel(points, alignment=alignment, centre_height_m=centre_height_m,
                             cell_m=cell_m, cell_rad=cell_rad, min_points=min_points,
                             counts=counts, portals=portals)
    # Later passes get the first pass's axis: they keep its reach beyond the ends.
    reach = AXIS_END_REACH_M if (alignment is None and portals is not False) else None
    grow = 1.0
    while len(rec.faces) > max_triangles:
        grow *= max(BUDGET_MIN_GROWTH, np.sqrt(len(rec.faces) / max_triangles))
        if grow > BUDGET_MAX_GROWTH:
            raise ReconstructionError(f"Expected a reachable triangle budget, got "
                                      f"{max_triangles}; ask for more triangles.")
        rec = reconstruct_tunnel(points, alignment=rec.alignment,
                                 centre_height_m=rec.centre_height_m, cell_m=cell_m * grow,
                                 cell_rad=min(cell_rad * grow, np.pi / 4 - 1e-9),
                                 min_points=min_points, counts=counts, portals=portals,
                                 end_reach_m=reach)
    return rec


__all__ = ["AXIS_END_REACH_M", "BUDGET_MAX_GROWTH", "BUDGET_MIN_GROWTH", "ReconstructedTunnel",
           "poisson_tunnel",
           "reconstruct_tunnel", "reconstruct_within_budget"]
