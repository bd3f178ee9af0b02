"""Reconstruction of spaces that are not tubes (caves, mines, caverns, side galleries):
screened Poisson surface reconstruction with normals oriented by the scanners.

The tunnel-aware mesher (``survey.clouds.reconstruct``) keeps one radius per (chainage,
angle) cell about an axis, so it cannot hold an overhang, a side gallery or a cavern,
and it needs an axis. This route needs neither; it needs to know, for each point, where
the scanner that measured it stood (``survey.clouds.scanners`` reads that from station
poses, a trajectory and point times, or a list of positions).

Method (Kazhdan & Hoppe 2013, "Screened Poisson surface reconstruction", ACM TOG 32(3),
through Open3D's ``create_from_point_cloud_poisson``):

1. Voxel grid (``ScannerVoxelGrid``, streamed): the centroid of each voxel's points and
   the mean position of the scanners that measured them. The mean of scanner positions
   that all see the surface from the same side lies on that side too (a convex
   combination of vectors with a positive dot product with the normal keeps it), so it
   orients the voxel's normal as any one of them would.
2. Normals: principal component of the ``NORMAL_NEIGHBOURS`` nearest points (Open3D
   ``estimate_normals``), flipped to point towards the scanner (the side the beam came
   from is empty space: Hoppe et al. 1992 orient by propagation; a scanner position
   makes it exact and local, with no propagation to go wrong across thin walls).
3. Screened Poisson on an octree whose finest cell is ``cell_m`` (the depth follows from
   the cloud's extent: ``poisson_depth``); the faces point into the empty space, as the
   tunnel mesher's do.
4. Trimming calibrated in metres, not by a density quantile: every vertex farther than
   ``trim_m`` from every input point is removed (Poisson closes every open end with a
   "bulbous" cap, metres from any data), and with it the faces that use it. Default
   ``trim_m`` = ``TRIM_CELLS`` x ``cell_m``, at least ``TRIM_MIN_M``: holes up to about
   twice that wide stay filled (occlusions behind a rib or a block, the shadow under a
   station); wider openings (portals, unscanned galleries) stay open, with a band of
   at most ``trim_m`` of the cap left at their rim.
5. Support: the number of input points within ``support_radius_m`` (default
   ``SUPPORT_CELLS`` x ``cell_m``) of each vertex; 0 marks the vertices Poisson
   interpolated across a hole (``support`` PLY vertex property, as the tunnel mesher's).

DECISION: distance trimming rather than CloudCompare's density quantile. A quantile
removes a fixed share of the surface whatever the data: too much on a complete scan,
too little where the caps are large (a short, wide cavern). The distance to the nearest
sample has a unit and a meaning (the widest gap filled) and is checked in the tests.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from raytrace.checks import as_points
from survey.errors import ReconstructionError

__all__ = ["MIN_SOLID_POINTS", "NORMAL_NEIGHBOURS", "POISSON_SCALE", "SUPPORT_CELLS",
           "TRIM_CELLS", "TRIM_MIN_M", "ScannerVoxelGrid", "SolidMesh", "nearest_scanner",
           "orient_normals", "poisson_depth", "reconstruct_solid"]

#: Fewest points ``reconstruct_solid`` takes (a plane fit per point needs neighbours,
#: and Poisson needs a surface's worth of them).
MIN_SOLID_POINTS = 100
#: Neighbours of the PCA normal (Open3D's KNN search; the point included). ASSUMED:
#: 16 spans about 2 voxels each way on a voxel-gridded scan, enough to average noise
#: without rounding edges of 0.5 m facets.
NORMAL_NEIGHBOURS = 16
#: Ratio of the Poisson cube to the points' bounding box (Kazhdan's default, Open3D's).
POISSON_SCALE = 1.1
#: Default trim distance in cells of the finest octree level (see the module doc).
TRIM_CELLS = 5.0
#: Smallest default trim distance (m): occlusion shadows up to about 0.6 m wide stay
#: filled (the back of a rib, the underside of a pipe). Measured on the DARPA SubT
#: tile tunnel_bend_left (stations every 10 m, 12 % of its surface seen by none):
#: truth -> mesh 95 % 32.3 mm with 0.1 m, 27.9 mm with 0.3 m
#: (benchmarks/validate_nontubular.py).
TRIM_MIN_M = 0.3
#: Default support radius in cells of the finest octree level.
SUPPORT_CELLS = 2.0
#: Deepest octree ``poisson_depth`` gives (Open3D's PoissonRecon is built for <= 16).
MAX_DEPTH = 16

Floats = NDArray[np.float64]


# ---------------------------------------------------------------------- voxel grid
class ScannerVoxelGrid:
    """Streaming voxel grid of points and the scanners that measured them.

    ``ScannerVoxelGrid(voxel_size_m, min_bound)``, then ``add(points, scanners)`` per
    chunk, then ``result()``. The grid is the one ``survey.clouds.VoxelGrid`` uses
    (anchored at ``min_bound`` - ``voxel_size_m`` / 2, Open3D's semantics); sums are
    kept relative to the anchor in float64.

    Parameters
    ----------
    voxel_size_m : float > 0
    min_bound : (3,) float
        The cloud's minimum x, y, z (m).
    """

    #: Bits per axis in the packed key (1 cm voxels: 21 km per axis).
    BITS = 21

    def __init__(self, voxel_size_m: float, min_bound: ArrayLike) -> None:
        size = float(voxel_size_m)
        if not (np.isfinite(size) and size > 0):
            raise ReconstructionError(f"Expected a positive voxel size (m), got "
                                      f"{voxel_size_m!r}.")
        lo = np.asarray(min_bound, dtype=np.float64)
        if lo.shape != (3,) or not np.isfinite(lo).all():
            raise ReconstructionError(f"Expected a finite min_bound of shape (3,), got "
                                      f"{lo.shape}.")
        self.voxel_size_m = size
        self.anchor = lo - size / 2
        self._parts: list[tuple[NDArray[np.int64], Floats, NDArray[np.int64]]] = []
        self._pending = 0
        self.n_points = 0

    def add(self, points: ArrayLike, scanners: ArrayLike) -> None:
        """Accumulate points (n, 3) and the position (n, 3) (or one (3,)) of the scanner
        that measured each."""
        p, _ = as_points(points, "points", ReconstructionError)
        s = np.broadcast_to(np.asarray(scanners, dtype=np.float64), p.shape)
        if len(p) == 0:
            return
        local = p - self.anchor
        idx = np.floor(local / self.voxel_size_m).astype(np.int64)
        if (idx < 0).any() or (idx >= 1 << self.BITS).any():
            raise ReconstructionError("Expected points within the bounds given to the "
                                      "voxel grid, got one outside; pass the cloud's "
                                      "minimum bound.")
        key = (idx[:, 0] << (2 * self.BITS)) | (idx[:, 1] << self.BITS) | idx[:, 2]
        u, inv = np.unique(key, return_inverse=True)
        sums = np.stack([np.bincount(inv, weights=c, minlength=len(u))
                         for c in (*local.T, *(s - self.anchor).T)], 1).astype(
                             np.float64, copy=False)
        self._parts.append((u.astype(np.int64), sums,
                            np.bincount(inv, minlength=len(u)).astype(np.int64)))
        self._pending += len(u)
        self.n_points += len(p)
        if self._pending > 1 << 22:
            self._merge()

    def _merge(self) -> None:
        if len(self._parts) < 2:
            return
        keys = np.concatenate([k for k, _, _ in self._parts])
        u, inv = np.unique(keys, return_inverse=True)
        sums = np.concatenate([s for _, s, _ in self._parts])
        counts = np.concatenate([c for _, _, c in self._parts])
        self._parts = [(u, np.stack([np.bincount(inv, weights=sums[:, k], minlength=len(u))
                                     for k in range(6)], 1),
                        np.bincount(inv, weights=counts, minlength=len(u)).astype(np.int64))]
        self._pending = 0

    def result(self) -> tuple[Floats, Floats, NDArray[np.int64]]:
        """(centroids (m, 3) float64, mean scanner positions (m, 3) float64, counts (m,)
        int64), ordered by voxel key; world coordinates."""
        self._merge()
        if not self._parts:
            return np.empty((0, 3)), np.empty((0, 3)), np.empty(0, dtype=np.int64)
        _, sums, counts = self._parts[0]
        mean = sums / counts[:, None]
        return mean[:, :3] + self.anchor, mean[:, 3:] + self.anchor, counts.copy()


def nearest_scanner(points: ArrayLike, positions: ArrayLike) -> Floats:
    """For each point (n, 3), the nearest of the scanner positions (k, 3): the fallback
    when the cloud does not say which scanner measured a point. Right wherever the
    nearest station saw the point (a passage between stations); it can be wrong behind a
    corner, where a farther station measured the point: give per-point scanners there.

    Returns (n, 3) float64.
    """
    p, _ = as_points(points, "points", ReconstructionError)
    s, _ = as_points(positions, "positions", ReconstructionError, min_points=1)
    _, i = cKDTree(s).query(p, workers=-1)
    return s[i]


def orient_normals(points: ArrayLike, normals: ArrayLike, scanners: ArrayLike) -> Floats:
    """Normals (n, 3) flipped where needed so that each points towards its scanner (n, 3):
    dot(normal, scanner - point) >= 0. Returns a new (n, 3) float64 array."""
    p = np.asarray(points, dtype=np.float64)
    n = np.array(normals, dtype=np.float64)
    s = np.broadcast_to(np.asarray(scanners, dtype=np.float64), p.shape)
    flip = np.einsum("ij,ij->i", n, s - p) < 0
    n[flip] *= -1.0
    return n


def poisson_depth(extent_m: float, cell_m: float) -> tuple[int, float]:
    """(depth, scale) of the Poisson octree whose finest cell is exactly ``cell_m`` for
    a cloud whose largest bounding-box side is ``extent_m``: depth = ceil(log2(
    POISSON_SCALE x extent / cell)) (at least 1), and the cube enlarged from
    ``POISSON_SCALE`` x extent to cell x 2**depth (scale = that / extent).

    DECISION: the cube is fitted to the cell, not the cell to the cube: with a fixed
    scale the cell jumps by 2x between depths, and a cloud a little longer than a power
    of two would get cells half the size asked for (8x the octree nodes and time on a
    surface) or twice it (rounded edges). The octree is adaptive: the empty margin
    costs almost nothing."""
    if not (np.isfinite(extent_m) and extent_m > 0 and np.isfinite(cell_m) and cell_m > 0):
        raise ReconstructionError(f"Expected a positive extent and cell size (m), got "
                                  f"{extent_m!r} and {cell_m!r}.")
    d = max(1, int(np.ceil(np.log2(POISSON_SCALE * extent_m / cell_m) - 1e-9)))
    if d > MAX_DEPTH:
        raise ReconstructionError(f"Expected an octree of depth <= {MAX_DEPTH}, got "
                                  f"{d} for a {extent_m:.0f} m cloud at {cell_m:g} m cells; "
                                  "use larger cells or split the cloud.")
    return d, float(cell_m * 2.0 ** d / extent_m)


# ---------------------------------------------------------------------- the mesh
@dataclass
class SolidMesh:
    """A reconstructed surface (``reconstruct_solid``).

    Attributes
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
        Wound so that the normals (b - a) x (c - a) point into the empty space (towards
        the scanners).
    support : (n,) int64
        Input points within ``support_radius_m`` of each vertex; 0: interpolated
        across a hole.
    gap_m : (n,) float64
        Distance from each vertex to the nearest input point (m).
    cell_m, trim_m, support_radius_m : float
        The finest octree cell, the trim distance and the support radius used (m).
    depth : int
        The octree depth.
    quality : dict
        ``points``, ``triangles``, ``trimmed_vertices`` (removed as farther than
        ``trim_m``), ``unsupported_share`` (vertices with support 0), and the distances
        from a sample of the input points to the mesh: ``mean_m``, ``median_m``,
        ``p95_m``, ``max_m``.
    """

    vertices: Floats
    faces: NDArray[np.int64]
    support: NDArray[np.int64]
    gap_m: Floats
    cell_m: float
    trim_m: float
    support_radius_m: float
    depth: int
    quality: dict[str, Any] = field(default_factory=dict)

    def write(self, path: Any) -> Any:
        """Binary PLY with a ``support`` vertex property; atomic."""
        from survey.world.mesh import write_ply

        return write_ply(path, self.vertices, self.faces,
                         vertex_fields={"support": self.support.astype(np.float64)})

    @property
    def unsupported_share(self) -> float:
        """Share of the vertices with support 0 (interpolated across holes)."""
        return float(np.mean(self.support == 0)) if len(self.support) else 0.0


def _open3d() -> Any:
    from raytrace.config import threading_info

    # DECISION: Numba picks its threading layer first. Open3D ships an older TBB; once it
    # is loaded, Numba finds it, refuses it and warns (a NumbaWarning on every run).
    threading_info()
    try:
        import open3d as o3d
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ReconstructionError("Expected the optional package open3d for the solid "
                                  "(Poisson) reconstruction, got none; install it with: "
                                  "pip install 'open3d>=0.18'.") from exc
    return o3d


#: Input points sampled for the quality figures (point-to-mesh distances).
QUALITY_SAMPLE = 200_000


def reconstruct_solid(points: ArrayLike, *, scanners: ArrayLike | None = None,
                      stations: ArrayLike | None = None, cell_m: float = 0.02,
                      trim_m: float | None = None, support_radius_m: float | None = None,
                      normal_neighbours: int = NORMAL_NEIGHBOURS,
                      threads: int = -1) -> SolidMesh:
    """Mesh any enclosed space from its points (see the module doc).

    Parameters
    ----------
    points : (n, 3) array_like of float
        The cloud (m); voxel-gridded to about ``cell_m`` for the usual cost
        (``ScannerVoxelGrid``).
    scanners : (n, 3) or (3,) array_like of float, optional, keyword-only
        The position of the scanner that measured each point (a station's position; on
        a moving platform the sensor's position at the point's time), or one position
        for all.
    stations : (k, 3) array_like of float, optional
        Scanner positions without the link to the points: each point takes the nearest
        (``nearest_scanner``). One of ``scanners`` and ``stations`` is required.
    cell_m : float > 0
        Finest octree cell (m); the depth follows from the extent (``poisson_depth``).
    trim_m : float > 0, optional
        Vertices farther than this from every point are removed; default
        max(``TRIM_CELLS`` x ``cell_m``, ``TRIM_MIN_M``).
    support_radius_m : float > 0, optional
        Radius of the support count; default ``SUPPORT_CELLS`` x ``cell_m``.
    normal_neighbours : int >= 3
        Neighbours of the PCA normal.
    threads : int
        Poisson threads (-1: all cores).

    Returns
    -------
    SolidMesh

    Raises
    ------
    ReconstructionError
        Fewer than ``MIN_SOLID_POINTS`` finite points, no scanner positions (or of the
        wrong shape), bad sizes, Open3D missing, or a mesh trimmed to nothing.
    """
    p, _ = as_points(points, "points", ReconstructionError)
    if len(p) < MIN_SOLID_POINTS:
        raise ReconstructionError(f"Expected at least {MIN_SOLID_POINTS} points for a solid "
                                  f"reconstruction, got {len(p)}.")
    if (scanners is None) == (stations is None):
        raise ReconstructionError("Expected the scanner positions as either `scanners` "
                                  "(one per point) or `stations` (the nearest is used), "
                                  f"got {'both' if scanners is not None else 'neither'}; "
                                  "they orient the normals.")
    if scanners is not None:
        s = np.asarray(scanners, dtype=np.float64)
        if s.shape not in ((3,), p.shape) or not np.isfinite(s).all():
            raise ReconstructionError(f"Expected finite `scanners` of shape (3,) or "
                                      f"{p.shape}, got {s.shape}.")
        s = np.broadcast_to(s, p.shape)
    else:
        s = nearest_scanner(p, np.asarray(stations, dtype=np.float64))
    for name, size in (("cell_m", cell_m), ("trim_m", trim_m),
                       ("support_radius_m", support_radius_m)):
        if size is not None and not (np.isfinite(size) and size > 0):
            raise ReconstructionError(f"Expected a positive `{name}` (m), got {size!r}.")
    if int(normal_neighbours) < 3:
        raise ReconstructionError(f"Expected normal_neighbours >= 3, got "
                                  f"{normal_neighbours}.")
    trim = float(trim_m) if trim_m is not None else max(TRIM_CELLS * cell_m, TRIM_MIN_M)
    radius = float(support_radius_m) if support_radius_m is not None else \
        SUPPORT_CELLS * cell_m
    o3d = _open3d()
    # Poisson works in float32 inside Open3D's octree: centre the cloud (UTM-sized
    # coordinates would lose millimetres).
    origin = np.round(p.mean(axis=0))
    q = p - origin
    extent = float(np.max(q.max(axis=0) - q.min(axis=0)))
    depth, scale = poisson_depth(max(extent, cell_m), cell_m)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(q))
    pc.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=int(normal_neighbours)))
    normals = orient_normals(q, np.asarray(pc.normals), s - origin)
    pc.normals = o3d.utility.Vector3dVector(normals)
    # PoissonRecon reports numerical trivia ("bad average roots") as warnings; errors
    # still show.
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(
            pc, depth=depth, scale=scale, linear_fit=False, n_threads=int(threads))
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.triangles, dtype=np.int64)
    del mesh, pc
    tree = cKDTree(q)
    gap, _ = tree.query(v, workers=-1)
    keep = gap <= trim
    f = f[keep[f].all(axis=1)]
    used = np.unique(f)
    remap = np.full(len(v), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    v, gap, f = v[used], gap[used], remap[f]
    if len(f) == 0:
        raise ReconstructionError(f"Expected a surface within trim_m = {trim:g} m of the "
                                  f"points, got none; check the scanner positions or "
                                  "raise trim_m.")
    support = np.asarray(tree.query_ball_point(v, radius, return_length=True, workers=-1),
                         dtype=np.int64)
    # Open3D's Poisson winds its faces so that (b - a) x (c - a) follows the input
    # normals: towards the scanners (checked in the tests).
    quality = _quality(q, v, f)
    quality.update(points=int(len(p)), triangles=int(len(f)),
                   trimmed_vertices=int((~keep).sum()),
                   unsupported_share=float(np.mean(support == 0)))
    return SolidMesh(v + origin, f, support, gap, float(cell_m), trim, radius, depth,
                     quality)


def _quality(q: Floats, v: Floats, f: NDArray[np.int64]) -> dict[str, Any]:
    """Distances (m) from a seeded sample of the points to the mesh: the exact nearest
    triangle (the engine's closest-point query, ``raytrace.Scene.closest``)."""
    from survey.clouds.decimate import point_mesh_distances

    if len(q) > QUALITY_SAMPLE:
        q = q[np.random.default_rng(0).choice(len(q), QUALITY_SAMPLE, replace=False)]
    d = point_mesh_distances(q, v, f)
    return {"mean_m": float(d.mean()), "median_m": float(np.median(d)),
            "p95_m": float(np.percentile(d, 95)), "max_m": float(d.max())}
