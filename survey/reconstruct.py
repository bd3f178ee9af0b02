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
3. Cells of ``cell_m`` along the axis x ``cell_rad`` around it: the radius of a cell is
   the median of its points' radii (robust to noise and to a minority of attachments);
   its support is the number of points. Cells with fewer than ``min_points`` are filled
   by periodic linear interpolation around the ring, then linearly along the axis, and
   get support 0 (extrapolated).
4. Triangulate the grid of cell centres (two triangles per quad, faces pointing into
   the tunnel, open at both portals) and map back with ``Alignment.to_world``.

The result carries per-vertex ``support`` (a PLY vertex property: the seed study's
Figure 2 colouring).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from raytrace.errors import TunnelsimError

from .alignment import Alignment, AlignmentError


#: Points used to estimate the axis (a seeded random subset of larger clouds).
AXIS_SAMPLE = 200_000


class ReconstructionError(TunnelsimError, ValueError):
    """A cloud cannot be reconstructed as a tunnel."""


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
        from .tunnel_io import write_ply

        return write_ply(path, self.vertices, self.faces,
                         vertex_fields={"support": self.support.astype(np.float64)})

    @property
    def extrapolated_share(self) -> float:
        return float(np.mean(self.support == 0))


def _centres(q):
    """Robust mid-range centre of 2-D points (k, 2)."""
    a = np.percentile(q, [2, 98], axis=0)
    return (a[0] + a[1]) / 2, a[1] - a[0]


def estimate_axis(points, *, slice_m: float = 2.0, knot_spacing_m: float = 15.0,
                  min_points: int = 50):
    """(Alignment, centre height h_c): a centreline at the profile's mid-height and the
    height of the profile centre above it (0 here: the axis runs through the centre)."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) < 3 * min_points:
        raise ReconstructionError(f"Expected a cloud of at least {3 * min_points} points "
                                  f"(n, 3), got shape {p.shape}.")
    if len(p) > AXIS_SAMPLE:   # the axis needs shape, not every point
        p = p[np.random.default_rng(0).choice(len(p), AXIS_SAMPLE, replace=False)]
    origin = np.round(p.mean(axis=0))
    q = p - origin
    # Principal direction in plan (tunnels are near-horizontal).
    cov = np.cov(q[:, :2].T)
    w, v = np.linalg.eigh(cov)
    if w[1] < 9.0 * max(w[0], 1e-12):
        raise ReconstructionError("Expected an elongated tunnel-shaped cloud, got one "
                                  "whose plan extent is not elongated (could not find a "
                                  "tunnel axis).")
    d = v[:, 1]
    along = q[:, :2] @ d
    n_sl = max(2, int(np.ceil(np.ptp(along) / slice_m)))
    edges = np.linspace(along.min(), along.max(), n_sl + 1)
    idx = np.clip(np.searchsorted(edges, along, side="right") - 1, 0, n_sl - 1)
    nrm = np.array([-d[1], d[0]])
    cen = []
    for k in range(n_sl):
        m = idx == k
        if m.sum() < min_points:
            continue
        lat = q[m, :2] @ nrm
        c, span = _centres(np.stack([lat, q[m, 2]], 1))
        # The slice must surround its centre: points on both sides and above/below.
        rel = np.stack([lat - c[0], q[m, 2] - c[1]], 1)
        ang = np.arctan2(rel[:, 1], rel[:, 0])
        cover = np.unique(np.floor((ang + np.pi) / (np.pi / 6)).astype(int)).size
        if cover < 9:
            continue
        a = 0.5 * (edges[k] + edges[k + 1])
        cen.append(np.array([*(a * d + c[0] * nrm), c[1]]))
    if len(cen) < 5:
        raise ReconstructionError("Expected cross-sections that surround an axis, got too "
                                  "few (could not find a tunnel axis); is this a tunnel?")
    cen = np.array(cen) + origin
    try:
        al = Alignment.fit(cen, knot_spacing_m=max(knot_spacing_m, 3 * slice_m))
    except AlignmentError as exc:
        raise ReconstructionError(f"Expected a smooth centreline through the cross-"
                                  f"sections, got a fit failure ({exc}); could not find a "
                                  "tunnel axis.") from exc
    # Second pass: centres of slices perpendicular to the first alignment.
    s, off, h = al.to_local(p)
    c0, c1 = al.chainage_range
    inner = (s > c0 + 1e-6) & (s < c1 - 1e-6)
    sb = np.floor((s - c0) / slice_m).astype(int)
    pts = []
    for k in np.unique(sb[inner]):
        m = inner & (sb == k)
        if m.sum() < min_points:
            continue
        c, _ = _centres(np.stack([off[m], h[m]], 1))
        sc = float(np.median(s[m]))
        pts.append(al.to_world(sc, c[0], c[1]))
    if len(pts) < 5:
        raise ReconstructionError("Expected cross-sections along the first axis estimate, "
                                  "got too few (could not find a tunnel axis).")
    al2 = Alignment.fit(np.array(pts), knot_spacing_m=max(knot_spacing_m, 3 * slice_m))
    return al2, 0.0


def unroll(points, alignment=None, centre_height_m=None):
    """(alignment, h_c, s, offset, height, phi, rho) of points about the profile centre:
    the alignment estimated when not given (its axis runs through the centre, h_c = 0),
    phi from the crown positive to the left, rho the distance from the centre."""
    if alignment is None:
        alignment, _ = estimate_axis(points)
    hc = 0.0 if centre_height_m is None else float(centre_height_m)
    s, off, h = alignment.to_local(points)
    return alignment, hc, s, off, h, np.arctan2(off, h - hc), np.hypot(off, h - hc)


def cell_runs(cell, values):
    """Values grouped by cell: (cell ids (k,), values sorted within each cell (n,),
    start of each cell's run (k,), run lengths (k,))."""
    order = np.lexsort((values, cell))
    cs, vs = cell[order], values[order]
    starts = np.flatnonzero(np.concatenate([[True], cs[1:] != cs[:-1]]))
    return cs[starts], vs, starts, np.diff(np.append(starts, len(cs)))


def fill_gaps(grid, axis_coords):
    """NaN cells of a (rings, around) grid filled in place: periodic linear
    interpolation around each ring, then linear along the axis at ``axis_coords``."""
    n_a = grid.shape[1]
    ang = np.arange(n_a)
    for row in grid:
        ok = np.isfinite(row)
        if ok.any() and not ok.all():
            row[~ok] = np.interp(ang[~ok], ang[ok], row[ok], period=n_a)
    for col in grid.T:
        ok = np.isfinite(col)
        if ok.any() and not ok.all():
            col[~ok] = np.interp(axis_coords[~ok], axis_coords[ok], col[ok])
    return grid


def reconstruct_tunnel(points, *, alignment: Alignment | None = None,
                       centre_height_m: float | None = None, cell_m: float = 0.1,
                       cell_rad: float = np.deg2rad(2.0), min_points: int = 3,
                       margin_m: float = 0.0, rows_at=None) -> ReconstructedTunnel:
    """Mesh a tunnel lining from points (see module doc).

    alignment, centre_height_m : optional known centreline and height of the profile
        centre above it (e.g. from the tunnel's JSON); else estimated from the cloud.
    cell_m, cell_rad : cell size along the axis (m) and around it (rad).
    min_points : cells with fewer points are interpolated (support 0).
    margin_m : chainage trimmed at both ends of the point coverage.
    rows_at : optional increasing chainages of the mesh rings (e.g. the chainages of
        measured profiles); each point goes to the nearest ring within half the local
        spacing. Default: rings every ``cell_m``.
    """
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3 or not np.isfinite(p).all():
        raise ReconstructionError(f"Expected finite points of shape (n, 3), got {p.shape}.")
    if len(p) == 0:
        raise ReconstructionError("Expected a non-empty cloud, got 0 points.")
    if not (cell_m > 0 and 0 < cell_rad < np.pi / 4):
        raise ReconstructionError(f"Expected cell sizes > 0 m and in (0, pi/4) rad, got "
                                  f"{cell_m}, {cell_rad}.")
    alignment, hc, s, off, h, phi, rho = unroll(p, alignment, centre_height_m)
    c0, c1 = alignment.chainage_range
    use = (s > c0 + 1e-9) & (s < c1 - 1e-9)
    if use.sum() == 0:
        raise ReconstructionError("Expected points along the alignment, got none within "
                                  "its chainage range.")
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
        n_s = len(sc)
        edges = np.concatenate([[sc[0] - (sc[1] - sc[0]) / 2], (sc[1:] + sc[:-1]) / 2,
                                [sc[-1] + (sc[-1] - sc[-2]) / 2]])
        use &= (s >= edges[0]) & (s < edges[-1])
        i = np.searchsorted(edges, s[use], side="right") - 1
    j = np.mod(np.floor((phi[use] + np.pi) / da).astype(np.int64), n_a)
    cell = i * n_a + j
    r = rho[use]
    # Median radius per cell (the middle element(s) of each sorted run).
    ids, rs, starts, counts = cell_runs(cell, r)
    med = 0.5 * (rs[starts + (counts - 1) // 2] + rs[starts + counts // 2])
    radius = np.full(n_s * n_a, np.nan)
    support = np.zeros(n_s * n_a, dtype=np.int64)
    radius[ids] = med
    support[ids] = counts
    radius[support < min_points] = np.nan
    support[support < min_points] = 0
    grid = fill_gaps(radius.reshape(n_s, n_a), sc)
    if not np.isfinite(grid).all():
        raise ReconstructionError("Expected points around the whole lining, got too few to "
                                  "fill the unrolled grid; use larger cells.")
    ac = -np.pi + (np.arange(n_a) + 0.5) * da
    o = grid * np.sin(ac)[None, :]
    z = hc + grid * np.cos(ac)[None, :]
    verts = alignment.to_world(np.broadcast_to(sc[:, None], grid.shape), o, z).reshape(-1, 3)
    # Faces: grid quads. The angle runs bottom -> right wall -> crown -> left wall,
    # clockwise in the (offset, height) plane, so (a, b, c) winds the normals inwards.
    a_ = (np.arange(n_s - 1)[:, None] * n_a + np.arange(n_a)[None, :]).ravel()
    b_ = (np.arange(n_s - 1)[:, None] * n_a + (np.arange(n_a)[None, :] + 1) % n_a).ravel()
    c_, d_ = a_ + n_a, b_ + n_a
    faces = np.concatenate([np.stack([a_, b_, c_], 1), np.stack([b_, d_, c_], 1)])
    # Quality: each point's radial distance to its cell's surface (the point-to-mesh
    # distance for a smooth lining, up to the cell's tilt).
    resid = np.abs(r - grid.reshape(-1)[cell])
    quality = {"points": int(use.sum()), "mean_m": float(resid.mean()),
               "median_m": float(np.median(resid)),
               "p95_m": float(np.percentile(resid, 95)), "max_m": float(resid.max()),
               "extrapolated_share": float(np.mean(support == 0)),
               "triangles": int(len(faces))}
    return ReconstructedTunnel(verts, faces.astype(np.int64), support, alignment, hc, sc, ac,
                               quality)


def poisson_tunnel(points, *, alignment: Alignment | None = None,
                   centre_height_m: float | None = None, depth: int = 10,
                   density_quantile: float = 0.02, normal_radius_m: float = 0.1):
    """The CloudCompare-style alternative: screened Poisson reconstruction through
    Open3D (Kazhdan & Hoppe 2013), with normals oriented towards the tunnel axis,
    vertices of the lowest ``density_quantile`` of Poisson densities removed, and the
    "bulbous closures" Poisson puts at the portals cut off: every vertex beyond the
    chainage range of the points goes. Returns (vertices (n, 3), faces (m, 3)).
    Needs the optional Open3D (``pip install open3d``)."""
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
    mesh, dens = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pc, depth=depth)
    v = np.asarray(mesh.vertices) + origin
    f = np.asarray(mesh.triangles).astype(np.int64)
    dens = np.asarray(dens)
    sv, _, _ = alignment.to_local(v)
    keep = (dens >= np.quantile(dens, density_quantile)) & (sv >= s.min()) & (sv <= s.max())
    f = f[keep[f].all(axis=1)]
    used = np.unique(f)
    remap = np.full(len(v), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return v[used], remap[f]


def plot_support(rec: ReconstructedTunnel, path, *, title=None):
    """Unrolled support map of a reconstruction (chainage x angle from the crown):
    colour = points per cell (log), grey = cells filled by interpolation (support 0),
    as the seed's support-coloured mesh (Figure 2). Atomic PNG."""
    from .plotting import pyplot, save_png

    plt = pyplot()
    from matplotlib.colors import LogNorm


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
