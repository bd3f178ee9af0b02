"""Routes found in a mesh: the free space inside it, its floor, and a path along the
middle of the passage at a sensor's height above that floor.

Method, in four steps:

1. **Free space.** The mesh's bounding box is cut into cubic voxels (``voxel_m``; by
   default the smallest that keeps the grid within ``max_voxels``). The triangles are
   split until no edge is longer than ``SUB_EDGE_VOX`` voxels and sampled on a
   barycentric lattice no coarser than ``SAMPLE_STEP_VOX`` voxels; the voxels holding a
   sample are the surface. A Euclidean distance transform (Maurer et al. 2003, scipy's
   ``distance_transform_edt``) gives every voxel centre its distance to the nearest
   surface voxel, a clearance estimate within ~1.4 voxels of the exact distance; voxels
   within sqrt(3) voxels of the surface (its 26-neighbourhood, which closes any gap
   between samples) are occupied. A free voxel is *inside* when the surface lies both
   below and above it in its column (a floor and a roof: an open bowl or a plane has
   none), and the free space is one 6-connected component of those: the largest, or
   the one holding ``start``.
2. **Floor.** Floor voxels are free voxels whose voxel below is not free. A floor voxel
   is drivable when the voxel at the sensor's height above it is free and its clearance
   reaches ``clearance_m`` plus ``CLEARANCE_MARGIN_VOX`` voxels. Its *width* is its
   walking distance along the floor to the floor's edge (a floor voxel beside a wall or
   a step): the ridge of that distance is the medial axis of the floor plan (Blum 1967).
3. **Path.** Floor voxels are joined to their 26-neighbours one voxel up or down at
   most (floors steeper than 45 degrees are not driven). The ends are the two drivable
   voxels farthest apart by walking distance, found by a double sweep (Dijkstra from the
   widest voxel to the farthest, then from there to the farthest again; exact on a
   tree, tight on passages: Magnien, Latapy & Habib 2009, "Fast computation of
   empirically tight bounds for the diameter of massive graphs"), each moved to the
   middle of its end of the passage; at a junction that is the longest branch. The
   route is the cheapest path between the ends, or through the waypoints in order, with
   edge cost ``length / width**p``: a maximum-clearance path as in the clearance-weighted
   planners of Wein, van den Berg & Halperin (2008, "Planning high-quality paths and
   corridors amidst obstacles", IJRR 27) and Geraerts & Overmars (2007, "Creating
   high-quality paths for motion planning", IJRR 26): it keeps to the medial ridge
   rather than cutting bends.
4. **Smoothing and height.** Each leg is smoothed with a Gaussian moving average
   (``smoothing_m``; its ends kept by point reflection), cut where the floor ends under
   an oblique open end, resampled every ``spacing_m``, set on the floor by rays cast
   down (``Scene.cast``) and lifted by ``height_m``. Every point's exact distance to the
   mesh (closest point on a triangle, Ericson 2005, "Real-Time Collision Detection"
   5.1.5) is measured; where one is below ``clearance_m`` the smoothing is halved, then
   dropped.

>>> from raytrace.shapes import tunnel_tube
>>> route = find_route(tunnel_tube(1500, length_m=10.0), voxel_m=0.1)
>>> round(route.length_m), round(route.min_clearance_m, 2), route.points.shape[1]
(10, 0.5, 3)
"""

from __future__ import annotations

import os
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage, sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from raytrace import Scene
from raytrace.fileio import atomic_writer

from ._checks import as_number, as_whole
from .errors import TrajectoryError
from .trajectory import Trajectory

__all__ = ["FreeSpace", "MAX_VOXELS", "MIN_VOXEL_M", "ROUTE_CSV_COLUMNS", "Route",
           "find_route", "free_space", "read_waypoints"]

#: Default voxel budget: ~0.1 m voxels on the SubT tiles and the 80 m cave (~20 MB of
#: grids). The voxel is the smallest that keeps the grid within it, not below
#: ``MIN_VOXEL_M`` (ASSUMED: finer buys nothing for a route that is smoothed over 0.5 m).
MAX_VOXELS = 2_000_000
MIN_VOXEL_M = 0.05
#: Triangles are split until no edge exceeds this many voxels, then sampled on a
#: barycentric lattice no coarser than ``SAMPLE_STEP_VOX``: every surface point lies
#: within half a voxel of a sample, so the 26-neighbourhood of the sampled voxels seals
#: the surface (no 6-connected path of free voxels crosses it).
SUB_EDGE_VOX = 2.0
SAMPLE_STEP_VOX = 0.5
#: Voxels of clearance asked beyond ``clearance_m`` in the voxel test: the clearance
#: estimate can exceed the exact distance by ~1.4 voxels (a sample's voxel centre vs the
#: surface). DECISION: 1.5, not the worst case; the exact check on the final points
#: catches the rest, and a wider margin shuts narrow passages.
CLEARANCE_MARGIN_VOX = 1.5
#: Height of a floor voxel's centre above the floor (voxels): the floor's voxel and the
#: one above are occupied, so the first free centre lies 1.5-2.5 voxels up.
FLOOR_OFFSET_VOX = 2.0
#: A second part of the drivable floor at least this share of it is reported (a
#: warning): the passage is cut by a pinch, not just a pocket behind a boulder or a
#: strip beyond a drain (ASSUMED: a drain beside a wall leaves ~15 %).
SPLIT_WARN_SHARE = 0.25
#: The walk that finds the ends steps up or down this much between neighbouring
#: floor voxels (the route itself one voxel): a drain or a kerb does not cut the floor
#: into strips whose dead ends would pass for the passage's ends (ASSUMED: 0.3 m).
SWEEP_STEP_M = 0.3
#: The voxel path is centred between the walls by rays (``_recentre``): from a
#: reference smoothed over ``RECENTRE_REF_M``, middles within ``RECENTRE_MAX_VOX`` voxels
#: of the path, median over ``RECENTRE_MEDIAN_M`` (ASSUMED: over twice a niche's length,
#: 1.5 m in the generator, so that a niche does not pull the route).
RECENTRE_REF_M = 2.0
RECENTRE_MAX_VOX = 1.0
RECENTRE_MEDIAN_M = 4.0
#: Columns of the route CSV (``Route.write_csv``).
ROUTE_CSV_COLUMNS = ("s_m", "x", "y", "z", "floor_z", "clearance_m")
_SQRT3 = float(np.sqrt(3.0))
_QUERY_CHUNK = 64          # route points per exact-distance batch (memory)
_SAMPLE_CHUNK = 200_000    # sub-triangles per sampling batch (memory)


class FreeSpace:
    """The free space inside a mesh on a voxel grid (built by ``free_space``).

    Attributes
    ----------
    scene : raytrace.Scene
    voxel_m : float
        Edge of a voxel (m).
    origin : (3,) float64
        World position of the corner of voxel (0, 0, 0) (m).
    free : (nx, ny, nz) bool
        The voxels of the free space (one 6-connected component).
    clearance_m : (nx, ny, nz) float32
        Distance of each voxel centre to the nearest surface voxel (m): the exact
        distance to the mesh within ~1.4 voxels.
    """

    def __init__(self, scene: Scene, voxel_m: float, origin: NDArray[np.float64],
                 free: NDArray[np.bool_], clearance_m: NDArray[np.float32],
                 surface: _Surface) -> None:
        self.scene, self.voxel_m, self.origin = scene, voxel_m, origin
        self.free, self.clearance_m, self._surface = free, clearance_m, surface

    def centres(self, ijk: ArrayLike) -> NDArray[np.float64]:
        """World positions (n, 3) of voxel centres given by indices (n, 3)."""
        return self.origin + (np.asarray(ijk, dtype=np.float64) + 0.5) * self.voxel_m

    def index(self, points: ArrayLike) -> NDArray[np.int64]:
        """Voxel indices (n, 3) int64 of world points (n, 3); may lie outside the grid."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return np.floor((p - self.origin) / self.voxel_m).astype(np.int64)

    def distance(self, points: ArrayLike) -> NDArray[np.float64]:
        """Exact distance (n,) float64 of world points (n, 3) to the mesh (m)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return self._surface.distance(p - self.scene.origin_offset)

    def __repr__(self) -> str:
        return (f"FreeSpace({int(self.free.sum()):,} free voxels of {self.free.size:,}, "
                f"voxel {self.voxel_m:.3g} m)")


class _Surface:
    """The mesh as small sub-triangles (local frame) with a k-d tree of their centroids:
    exact point-to-mesh distances looking only at nearby sub-triangles."""

    def __init__(self, tri: NDArray[np.float64]) -> None:
        self.tri = tri
        c = tri.mean(axis=1)
        self.reach = float(np.linalg.norm(tri - c[:, None], axis=2).max())
        self.tree = cKDTree(c)

    def distance(self, p: NDArray[np.float64]) -> NDArray[np.float64]:
        out = np.full(len(p), np.inf)
        if not len(p):
            return out
        # The nearest centroid is a surface point: an upper bound on the distance, so
        # only sub-triangles whose centroid lies within it plus their reach can be nearer.
        ub, _ = self.tree.query(p)
        for a in range(0, len(p), _QUERY_CHUNK):
            q = p[a:a + _QUERY_CHUNK]
            near = self.tree.query_ball_point(q, ub[a:a + _QUERY_CHUNK] + self.reach)
            counts = np.fromiter((len(x) for x in near), dtype=np.int64, count=len(q))
            pi = np.repeat(np.arange(len(q)), counts)
            ti = np.concatenate([np.asarray(x, dtype=np.int64) for x in near])
            d = np.linalg.norm(q[pi] - _closest_on_triangles(q[pi], self.tri[ti]), axis=1)
            np.minimum.at(out, a + pi, d)
        return out


def _dot(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    return np.einsum("ij,ij->i", a, b)


def _closest_on_triangles(p: NDArray[np.float64], tri: NDArray[np.float64]
                          ) -> NDArray[np.float64]:
    """Closest point (n, 3) on triangle tri[i] (n, 3, 3) to p[i] (n, 3): Ericson 2005,
    5.1.5, the Voronoi regions of the vertices, edges and face, vectorised (the regions
    are applied from the face up, so that the vertex regions take precedence)."""
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    ab, ac = b - a, c - a
    d1, d2 = _dot(ab, p - a), _dot(ac, p - a)
    d3, d4 = _dot(ab, p - b), _dot(ac, p - b)
    d5, d6 = _dot(ab, p - c), _dot(ac, p - c)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        den = va + vb + vc
        out = a + ab * (vb / den)[:, None] + ac * (vc / den)[:, None]
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        m = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        out[m] = (b + (c - b) * w[:, None])[m]
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        out[m] = (a + ac * (d2 / (d2 - d6))[:, None])[m]
        m = (d6 >= 0) & (d5 <= d6)
        out[m] = c[m]
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        out[m] = (a + ab * (d1 / (d1 - d3))[:, None])[m]
    m = (d3 >= 0) & (d4 <= d3)
    out[m] = b[m]
    m = (d1 <= 0) & (d2 <= 0)
    out[m] = a[m]
    return out


def _split_triangles(tri: NDArray[np.float64], max_edge: float) -> NDArray[np.float64]:
    """Triangles (m, 3, 3) halved at the midpoint of their longest edge until no edge
    is longer than ``max_edge``: slivers become short pieces, not huge lattices."""
    done = []
    while len(tri):
        e = np.linalg.norm(tri[:, [1, 2, 0]] - tri, axis=2)   # edge k: vertex k -> k+1
        long = e.max(axis=1) > max_edge
        done.append(tri[~long])
        t = tri[long]
        order = (e[long].argmax(axis=1)[:, None] + np.arange(3)) % 3
        t = np.take_along_axis(t, order[:, :, None], axis=1)     # longest edge first
        mid = 0.5 * (t[:, 0] + t[:, 1])
        tri = np.concatenate([np.stack([t[:, 0], mid, t[:, 2]], 1),
                              np.stack([mid, t[:, 1], t[:, 2]], 1)])
    return np.concatenate(done)


def _lattice_samples(tri: NDArray[np.float64], step: float) -> NDArray[np.float64]:
    """Points (k, 3) on a barycentric lattice of each triangle (m, 3, 3), n subdivisions
    per edge with n = ceil(longest edge / step): no point of a triangle lies farther
    than ``step`` from a sample."""
    e = np.linalg.norm(tri[:, [1, 2, 0]] - tri, axis=2).max(axis=1)
    n = np.maximum(1, np.ceil(e / step - 1e-9)).astype(np.int64)
    out = []
    for k in np.unique(n):
        ab = np.array([(i, j) for i in range(k + 1) for j in range(k + 1 - i)]) / k
        wts = np.column_stack([1.0 - ab.sum(axis=1), ab])         # (q, 3) barycentric
        out.append(np.einsum("qj,mjd->mqd", wts, tri[n == k]).reshape(-1, 3))
    return np.concatenate(out)


def _as_scene(mesh: Any) -> Scene:
    if isinstance(mesh, Scene):
        return mesh
    if isinstance(mesh, tuple | list) and len(mesh) == 2:
        return Scene(mesh[0], mesh[1])
    raise TrajectoryError(f"Expected a raytrace.Scene or (vertices, faces), got "
                          f"{type(mesh).__name__}.")


def free_space(mesh: Scene | tuple[ArrayLike, ArrayLike], *, voxel_m: float | None = None,
               max_voxels: int = MAX_VOXELS, start: ArrayLike | None = None) -> FreeSpace:
    """The free space inside a mesh, on a voxel grid (step 1 of the module's method).

    Parameters
    ----------
    mesh : raytrace.Scene, or (vertices (n, 3) float, faces (m, 3) int)
        Any triangle mesh, z up, in metres; need not be watertight.
    voxel_m : float, optional
        Voxel edge (m); by default the smallest (not below ``MIN_VOXEL_M``) that keeps
        the grid within ``max_voxels``.
    max_voxels : int
        Bound on the grid's size (memory ~10 bytes a voxel, time ~linear).
    start : (3,) array_like of float, optional
        A point in the free space to keep (its component); by default the largest.

    Returns
    -------
    FreeSpace

    Raises
    ------
    TrajectoryError
        A grid over ``max_voxels``, a mesh that encloses no free space (no floor below
        and roof above: a plane, an open bowl), or ``start`` outside the free space.
    """
    scene = _as_scene(mesh)
    max_voxels = as_whole(max_voxels, "max_voxels", TrajectoryError, lo=1000)
    f = np.asarray(scene.faces)
    v = np.asarray(scene.vertices, dtype=np.float64) - scene.origin_offset
    tri = v[f]
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    tri = tri[area2 > 0]
    lo, hi = v.min(axis=0), v.max(axis=0)
    ext = hi - lo
    if voxel_m is None:
        s = max(float(np.prod(ext + 1e-9) / max_voxels) ** (1 / 3), MIN_VOXEL_M)
        while np.prod(np.ceil(ext / s) + 1) > max_voxels:
            s *= 1.02
    else:
        s = as_number(voxel_m, "voxel_m", TrajectoryError, unit="m", lo=0, lo_open=True)
    shape = (np.ceil(ext / s - 1e-9) + 1).astype(np.int64)
    if np.prod(shape) > max_voxels:
        raise TrajectoryError(f"Expected at most max_voxels={max_voxels:,} voxels, got "
                              f"{int(np.prod(shape)):,} of {s:g} m over a box of "
                              f"{' x '.join(f'{x:.4g}' for x in ext)} m; pass a larger "
                              "voxel_m or max_voxels.")
    origin = lo + 0.5 * ext - 0.5 * shape * s            # the box in the middle
    sub = _split_triangles(tri, SUB_EDGE_VOX * s)
    marked = np.zeros(tuple(shape), dtype=np.bool_)
    for a in range(0, len(sub), _SAMPLE_CHUNK):
        pts = _lattice_samples(sub[a:a + _SAMPLE_CHUNK], SAMPLE_STEP_VOX * s)
        ijk = np.clip(np.floor((pts - origin) / s).astype(np.int64), 0, shape - 1)
        marked[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = True
    dvox = ndimage.distance_transform_edt(~marked).astype(np.float32)
    # Inside: below the highest and above the lowest surface voxel of the column.
    iz = np.arange(shape[2])
    has: NDArray[np.bool_] = np.any(marked, axis=2)
    low = np.argmax(marked, axis=2)
    high = shape[2] - 1 - np.argmax(marked[:, :, ::-1], axis=2)
    inside = (has[..., None] & (iz > low[..., None]) & (iz < high[..., None])
              & (dvox > _SQRT3 + 1e-6))
    labels, n = ndimage.label(inside)
    if n == 0:
        raise TrajectoryError("Expected a mesh that encloses free space (a floor below and "
                              "a roof above, as a tunnel or cave has), got none at voxel "
                              f"{s:.3g} m; is it a single surface, an open bowl or a "
                              "terrain?")
    if start is None:
        keep = int(np.argmax(np.bincount(labels.ravel())[1:])) + 1
    else:
        p = np.asarray(start, dtype=np.float64).reshape(3) - scene.origin_offset
        keep = _label_near(labels, np.floor((p - origin) / s).astype(np.int64))
        if keep == 0:
            raise TrajectoryError(f"Expected `start` inside the mesh's free space, got "
                                  f"{_xyz(p + scene.origin_offset)}, which is outside it or "
                                  "within two voxels of the surface.")
    return FreeSpace(scene, s, origin + scene.origin_offset, labels == keep,
                     dvox * np.float32(s), _Surface(sub))


def _label_near(labels: NDArray[np.int32], ijk: NDArray[np.int64], reach: int = 2) -> int:
    """The label at voxel ``ijk``, or the nearest non-zero one within ``reach`` voxels
    (a point on the floor lies in an occupied voxel); 0 if none."""
    lo = np.maximum(ijk - reach, 0)
    hi = np.minimum(ijk + reach + 1, labels.shape)
    if (hi <= lo).any():
        return 0
    box = labels[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
    nz = np.argwhere(box > 0)
    if not len(nz):
        return 0
    best = nz[np.argmin(np.linalg.norm(nz + lo - ijk, axis=1))]
    return int(box[tuple(best)])


@dataclass(frozen=True, repr=False)
class Route:
    """A route found in a mesh (``find_route``).

    Attributes
    ----------
    points : (n, 3) float64
        Sensor positions (world, m), evenly spaced, ``height_m`` above the floor.
    floor : (n, 3) float64
        The floor under each point (where the ray cast down hit it).
    clearance_m : (n,) float64
        Exact distance of each point to the mesh (m).
    distance_m : (n,) float64
        Distance along the route (m), from 0.
    waypoints : (k, 3) float64
        The ends, or the waypoints, as the route reached them (sensor positions).
    voxel_m, seconds : float
        The voxel used, and the time taken to find the route (s).
    """

    points: NDArray[np.float64]
    floor: NDArray[np.float64]
    clearance_m: NDArray[np.float64]
    distance_m: NDArray[np.float64]
    waypoints: NDArray[np.float64]
    voxel_m: float
    seconds: float

    @property
    def length_m(self) -> float:
        return float(self.distance_m[-1])

    @property
    def min_clearance_m(self) -> float:
        return float(self.clearance_m.min())

    def trajectory(self, speed_mps: float, *, accel_mps2: float | None = None,
                   rate_hz: float = 100.0, follow_grade: bool = False,
                   start_time: float = 0.0) -> Trajectory:
        """The route driven at ``speed_mps`` (``Trajectory.along_polyline``)."""
        return Trajectory.along_polyline(self.points, speed_mps, rate_hz=rate_hz,
                                         start_time=start_time, follow_grade=follow_grade,
                                         accel_mps2=accel_mps2)

    def write_csv(self, path: str | os.PathLike[str]) -> Path:
        """The route as CSV (``ROUTE_CSV_COLUMNS``), atomically; returns the path.
        ``read_waypoints`` reads it back."""
        path = Path(path)
        data = np.column_stack([self.distance_m, self.points, self.floor[:, 2],
                                self.clearance_m])
        with atomic_writer(path, "w") as fh:
            fh.write(",".join(ROUTE_CSV_COLUMNS) + "\n")
            np.savetxt(fh, data, delimiter=",", fmt="%.6f")
        return path

    def __repr__(self) -> str:
        return (f"Route({self.length_m:.1f} m, {len(self.points)} points, smallest "
                f"clearance {self.min_clearance_m:.2f} m, voxel {self.voxel_m:.2f} m)")


def _xyz(p: ArrayLike) -> str:
    """(x, y, z) for a message; a NaN z (a waypoint without one) left out."""
    c = np.asarray(p, dtype=np.float64).reshape(-1)
    return "(" + ", ".join(f"{float(x):.6g}" for x in c[np.isfinite(c)]) + ")"


def find_route(mesh: Scene | tuple[ArrayLike, ArrayLike], *,
               waypoints: ArrayLike | None = None, start: ArrayLike | None = None,
               height_m: float = 0.5, clearance_m: float = 0.2,
               voxel_m: float | None = None, max_voxels: int = MAX_VOXELS,
               spacing_m: float = 0.25, smoothing_m: float = 0.5,
               clearance_power: float = 2.0, space: FreeSpace | None = None) -> Route:
    """A route along the middle of the passage of a mesh, ``height_m`` above its floor.

    Parameters
    ----------
    mesh : raytrace.Scene, or (vertices (n, 3) float, faces (m, 3) int)
        Any triangle mesh of a passage (tunnel, cave, mine), z up, metres.
    waypoints : (k, 2) or (k, 3) array_like of float, optional
        Points to visit in order (k >= 2); the route starts at the first and ends at the
        last. x, y pick the floor under them; z (NaN: none) picks the floor below z when
        passages lie above one another (without z: the lowest). By default the route
        joins the two ends of the passage that lie farthest apart.
    start : (3,) array_like of float, optional
        A point in the free space to use (``free_space``); by default the largest.
    height_m : float
        Sensor height above the floor (m), > ``clearance_m``.
    clearance_m : float
        Smallest distance kept from the mesh at every point (m).
    voxel_m, max_voxels
        The grid (``free_space``).
    spacing_m : float
        Distance between the route's points (m).
    smoothing_m : float
        Standard deviation of the Gaussian moving average along the route (m); halved
        where the smoothed route would come closer than ``clearance_m``.
    clearance_power : float
        p in the edge cost length / width**p (0: the shortest path).
    space : FreeSpace, optional
        A free space already built for this mesh (``voxel_m``, ``max_voxels`` and
        ``start`` are then ignored).

    Returns
    -------
    Route

    Raises
    ------
    TrajectoryError
        No enclosed free space, ``start`` or a waypoint outside it, waypoints not
        connected, or a passage too narrow (or low) for ``clearance_m`` at ``height_m``.
    """
    t0 = time.perf_counter()
    height_m = as_number(height_m, "height_m", TrajectoryError, unit="m", lo=0, lo_open=True)
    clearance_m = as_number(clearance_m, "clearance_m", TrajectoryError, unit="m", lo=0)
    spacing_m = as_number(spacing_m, "spacing_m", TrajectoryError, unit="m", lo=0,
                          lo_open=True)
    smoothing_m = as_number(smoothing_m, "smoothing_m", TrajectoryError, unit="m", lo=0)
    power = as_number(clearance_power, "clearance_power", TrajectoryError, unit="1", lo=0)
    if height_m <= clearance_m:
        raise TrajectoryError(f"Expected height_m above clearance_m, got height_m="
                              f"{height_m:g} m and clearance_m={clearance_m:g} m.")
    wp = None if waypoints is None else _waypoint_array(waypoints)
    if space is None:
        space = free_space(mesh, voxel_m=voxel_m, max_voxels=max_voxels, start=start)
    s = space.voxel_m
    fl = _Floor(space, height_m, clearance_m)
    g_len, width = fl.g_len, fl.width[fl.nodes]
    n_parts, part = csgraph.connected_components(g_len, directed=False)
    if wp is None:
        sizes = np.bincount(part)
        big = int(np.argmax(sizes))
        if n_parts > 1 and np.sort(sizes)[-2] >= SPLIT_WARN_SHARE * len(part):
            share = 100 * sizes[big] / len(part)
            warnings.warn(f"The drivable floor is cut where the passage is narrower than "
                          f"2 x {clearance_m:g} m (or lower than {height_m + clearance_m:g} "
                          f"m); the route runs in the largest part, {share:.0f} % of it; "
                          "pass waypoints to choose another.", UserWarning, stacklevel=2)
        src = int(np.argmax(np.where(part == big, width, -np.inf)))
        a = _far_end(fl.g_sweep, src, width, part == big)
        stops = [a, _far_end(fl.g_sweep, a, width, part == big)]
    else:
        stops = [fl.snap(p, i + 1) for i, p in enumerate(wp)]
        keep = [0] + [i for i in range(1, len(stops)) if stops[i] != stops[i - 1]]
        if len(keep) < 2:
            raise TrajectoryError(f"Expected waypoints apart from one another, got "
                                  f"{len(wp)} on the same voxel of {s:.3g} m.")
        for i in range(1, len(stops)):
            if part[stops[i]] != part[stops[i - 1]]:
                raise TrajectoryError(
                    f"Expected waypoint {i + 1} {_xyz(wp[i])} to be reachable from "
                    f"waypoint {i} {_xyz(wp[i - 1])}, got no path between them that keeps "
                    f"{clearance_m:g} m from the mesh at {height_m:g} m above the floor; "
                    "the passage between them is closed, too narrow or too low.")
        stops, wp = [stops[i] for i in keep], wp[keep]
    legs = _legs(fl.cost_graph(power), stops)
    ends = fl.centres(stops)
    if wp is not None:      # a waypoint over drivable floor is passed through exactly
        over = np.linalg.norm(ends[:, :2] - wp[:, :2], axis=1) <= s
        ends[over, :2] = wp[over, :2]
    ok = False
    for sigma in (smoothing_m, smoothing_m / 2, smoothing_m / 4, 0.0):
        if 0 < sigma < s:
            continue
        parts, at = [], [0]
        for k, leg in enumerate(legs):
            c = fl.centres(leg)
            c[0, :2], c[-1, :2] = ends[k, :2], ends[k + 1, :2]
            q = _resample(c, s)
            if sigma > 0:
                q = _recentre(space.scene, _smooth(q, sigma / s), height_m, s, sigma / s,
                              fixed=(wp is not None or k > 0,
                                     wp is not None or k < len(legs) - 1))
            # Voxels straddle an oblique open end: cut the route where the floor ends.
            on = np.flatnonzero(_floor_under(space.scene, q, height_m, s)[1])
            if len(on):
                q = q[on[0] if k == 0 else 0:on[-1] + 1 if k == len(legs) - 1 else None]
            q = _resample(q, spacing_m)
            parts.append(q if k == 0 else q[1:])
            at.append(at[-1] + len(q) - 1)
        floor, hit = _floor_under(space.scene, np.vstack(parts), height_m, s)
        if hit.sum() < 2:
            raise TrajectoryError(f"Expected a floor under the route, got none under "
                                  f"{int((~hit).sum())} of its {len(hit)} points.")
        pts = floor + [0.0, 0.0, height_m]
        clr = space.distance(pts)
        ok = bool(clr.min() >= clearance_m)
        if ok:
            break
    if not ok:
        i = int(np.argmin(clr))
        raise TrajectoryError(f"Expected a passage at least 2 x {clearance_m:g} m wide at "
                              f"{height_m:g} m above its floor, got {clr[i]:.3g} m of "
                              f"clearance at {_xyz(pts[i])}; lower clearance_m or "
                              "voxel_m.")
    dist = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return Route(pts, floor, clr, dist, pts[at], s, time.perf_counter() - t0)


class _Floor:
    """The floor voxels of a free space (step 2): all of them (``floor``, flat indices),
    their distance to the nearest foot of a wall (``width``, m), and the drivable ones
    (``nodes``, indices into ``floor``), where a sensor ``height_m`` above them keeps
    ``clearance_m``, with their graphs (``g_len``: the route's; ``g_sweep``: the ends')."""

    def __init__(self, space: FreeSpace, height_m: float, clearance_m: float) -> None:
        self.space, self.height_m, self.clearance_m = space, height_m, clearance_m
        s, shape = space.voxel_m, space.free.shape
        nz = shape[2]
        fi = np.flatnonzero(space.free.ravel())
        # A run of free voxels up a column starts where the voxel below is not free.
        first = np.ones(len(fi), dtype=np.bool_)
        first[1:] = (fi[1:] != fi[:-1] + 1) | (fi[1:] % nz == 0)
        rs = np.flatnonzero(first)
        self.floor, self.run = fi[rs], np.diff(np.append(rs, len(fi)))
        self.ijk = np.column_stack(np.unravel_index(self.floor, shape))
        d = space.clearance_m.ravel()
        k = max(0, int(np.floor(height_m / s - FLOOR_OFFSET_VOX + 0.5)))
        sensor = np.where(self.run > k, d[self.floor + np.minimum(k, self.run - 1)], 0.0)
        # DECISION: the margin is not asked beyond the floor's own distance from the
        # sensor voxel (k + FLOOR_OFFSET_VOX voxels, less half a voxel): a voxel no
        # nearer than that to anything has only the floor near it, height_m away. Else
        # voxels of 0.2 m and more would leave no floor drivable at a 0.5 m height.
        need = max(clearance_m, min(clearance_m + CLEARANCE_MARGIN_VOX * s,
                                    (k + FLOOR_OFFSET_VOX - 0.5) * s))
        good = sensor >= need
        if not good.any():
            raise TrajectoryError(
                f"Expected a passage at least 2 x {clearance_m:g} m wide (plus "
                f"{CLEARANCE_MARGIN_VOX:g} voxels of {s:.3g} m) and higher than "
                f"{height_m + clearance_m:g} m, got at most {float(sensor.max()):.3g} m "
                f"of clearance at {height_m:g} m above the floor; lower clearance_m or "
                "height_m, or use a smaller voxel_m.")
        # The middle of the passage on the floor: the ridge of the distance to the
        # floor's edge at the walls, the floor plan's medial axis. DECISION: not the 3-D
        # clearance, whose ridge is flat across any passage wider than high (a ball
        # touching floor and roof fits anywhere there); and a straight-line distance, not
        # a walk along the floor, which a drain in the floor would cut.
        wall = self.space.centres(self.ijk[self._at_wall()])
        self.width = (cKDTree(wall).query(self.space.centres(self.ijk))[0] + 0.5 * s
                      if len(wall) else np.ones(len(self.floor)))
        self.nodes = np.flatnonzero(good)
        m = len(self.floor)
        self.g_len, self.g_sweep = (
            sparse.csr_matrix((ln, (i, j)), shape=(m, m))[self.nodes][:, self.nodes]
            for i, j, ln in (self._edges(self.nodes, up) for up in (
                1, max(1, round(SWEEP_STEP_M / s)))))
        self._tree: cKDTree | None = None

    def _lookup(self, ijk: NDArray[np.int64]) -> NDArray[np.int64]:
        """The floor index of each voxel ijk (n, 3), -1 where it is not a floor voxel."""
        shape = np.array(self.space.free.shape)
        out = np.full(len(ijk), -1, dtype=np.int64)
        inb = np.flatnonzero(((ijk >= 0) & (ijk < shape)).all(axis=1))
        flat = np.ravel_multi_index(tuple(ijk[inb].T), tuple(shape))
        pos = np.minimum(np.searchsorted(self.floor, flat), len(self.floor) - 1)
        hit = self.floor[pos] == flat
        out[inb[hit]] = pos[hit]
        return out

    def _edges(self, sub: NDArray[np.int64], up: int = 1) -> tuple[NDArray[np.int64], ...]:
        """Edges (i, j, length m) among floor voxels ``sub``, each once: to the 8 columns
        around, at most ``up`` voxels up or down (1: 26-neighbours, step 3)."""
        rows, cols, lens = [], [], []
        for off in ((dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1)
                    for dz in range(-up, up + 1)
                    if (dx, dy) != (0, 0) and (dx, dy, dz) > (0, 0, 0)):
            j = self._lookup(self.ijk[sub] + off)
            hit = np.flatnonzero(j >= 0)
            rows.append(sub[hit])
            cols.append(j[hit])
            lens.append(np.full(len(hit), self.space.voxel_m * float(np.linalg.norm(off))))
        return np.concatenate(rows), np.concatenate(cols), np.concatenate(lens)

    def _at_wall(self) -> NDArray[np.int64]:
        """Floor voxels at the foot of a wall: a side where no floor voxel lies within a
        voxel up or down and the voxel one up is occupied. A drain (a step down), the
        grid's border and the open space beyond a portal are not walls."""
        sp = self.space
        shape = np.array(sp.free.shape)
        occupied = sp.clearance_m <= (_SQRT3 + 1e-3) * sp.voxel_m
        wall = np.zeros(len(self.floor), dtype=np.bool_)
        for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)):
            side = self.ijk + (dx, dy, 0)
            none = np.all([self._lookup(side + (0, 0, dz)) < 0 for dz in (-1, 0, 1)], axis=0)
            up = side + (0, 0, 1)
            inb = ((up >= 0) & (up < shape)).all(axis=1)
            q = np.minimum(np.maximum(up, 0), shape - 1)
            wall |= none & inb & occupied[q[:, 0], q[:, 1], q[:, 2]]
        return np.flatnonzero(wall)

    def centres(self, nodes: ArrayLike) -> NDArray[np.float64]:
        """World centres (n, 3) of drivable nodes (indices into ``nodes``)."""
        return self.space.centres(self.ijk[self.nodes[np.asarray(nodes, dtype=np.int64)]])

    def cost_graph(self, power: float) -> sparse.csr_matrix:
        """The drivable graph with edge costs length x (widest / width)**p."""
        g = self.g_len.tocoo()
        w = self.width[self.nodes]
        r = 0.5 * (w[g.row] + w[g.col])
        return sparse.csr_matrix((g.data * (w.max() / r) ** power, (g.row, g.col)),
                                 shape=g.shape)

    def snap(self, p: NDArray[np.float64], number: int) -> int:
        """The drivable floor voxel for waypoint ``number`` at p (x, y, z or NaN): the
        floor in its column (the highest below z, else the lowest), then the nearest
        drivable voxel within ``clearance_m`` + 3 voxels of it."""
        sp, s = self.space, self.space.voxel_m
        nx, ny, nz = sp.free.shape
        ix, iy, _ = sp.index(np.nan_to_num(p))[0]
        lo = hi = 0
        if 0 <= ix < nx and 0 <= iy < ny:
            col = self.floor // nz
            lo, hi = (int(np.searchsorted(col, ix * ny + iy, side=x))
                      for x in ("left", "right"))
        pick = lo if hi > lo else -1
        if hi > lo and np.isfinite(p[2]):
            iz = self.ijk[lo:hi, 2]
            zf = sp.origin[2] + (iz + 0.5 - FLOOR_OFFSET_VOX) * s
            ztop = sp.origin[2] + (iz + self.run[lo:hi] - 0.5 + FLOOR_OFFSET_VOX) * s
            fit = np.flatnonzero((zf <= p[2] + 2 * s) & (p[2] <= ztop))
            pick = lo + int(fit[-1]) if len(fit) else -1
        if pick < 0:
            raise TrajectoryError(f"Expected waypoint {number} {_xyz(p)} inside the "
                                  "passage's free space (over its floor, under its roof), "
                                  "got a point outside it.")
        c = sp.centres(self.ijk[pick:pick + 1])
        if self._tree is None:
            self._tree = cKDTree(self.centres(np.arange(len(self.nodes))))
        d, node = self._tree.query(c[0])
        if d > self.clearance_m + 3 * s:
            raise TrajectoryError(
                f"Expected waypoint {number} {_xyz(p)} where the passage keeps "
                f"{self.clearance_m:g} m from the mesh at {self.height_m:g} m above the "
                f"floor, got the nearest such floor {d:.3g} m away; move the waypoint "
                "into the passage.")
        return int(node)


def _far_end(g: sparse.csr_matrix, src: int, width: NDArray[np.float64],
             keep: NDArray[np.bool_]) -> int:
    """The end of the passage farthest (walking) from ``src`` among the drivable voxels
    ``keep``, in its middle: the largest walking distance + 2 x width. A step sideways
    off the ridge loses two units for at most one gained, so the farthest voxel, at a
    wall, gives way to the middle of its end; a ledge or alcove that runs back from the
    end is no longer the farthest for its few metres."""
    dist = csgraph.dijkstra(g, directed=False, indices=src)
    return int(np.argmax(np.where(np.isfinite(dist) & keep, dist + 2.0 * width, -np.inf)))


def _legs(g: sparse.csr_matrix, stops: list[int]) -> list[NDArray[np.int64]]:
    """The cheapest paths between consecutive ``stops``, as node indices (each leg from
    one stop to the next, both included)."""
    _, pred = csgraph.dijkstra(g, directed=False, indices=stops[:-1],
                               return_predecessors=True)
    out = []
    for i in range(1, len(stops)):
        leg = [stops[i]]
        while leg[-1] != stops[i - 1]:
            leg.append(int(pred[i - 1, leg[-1]]))
        out.append(np.array(leg[::-1], dtype=np.int64))
    return out


def _recentre(scene: Scene, q: NDArray[np.float64], height_m: float, s: float,
              sigma: float, fixed: tuple[bool, bool]) -> NDArray[np.float64]:
    """The path q (n, 3) (floor voxels' height, a point every ``s``) moved sideways to
    the middle between the walls at the sensor's height: the voxel path is only centred
    to about a voxel. The middle is found by rays cast left and right from a reference,
    the path smoothed over ``RECENTRE_REF_M``, where the walls are nearly parallel to
    it; a middle over ``RECENTRE_MAX_VOX`` voxels off the path (a side passage, a
    corner) is replaced by its neighbours', and a median over ``RECENTRE_MEDIAN_M``
    removes the pull of a niche. The offsets are smoothed (``sigma`` samples) and, at a
    ``fixed`` (start, end) waypoint, blended back into the path over ``RECENTRE_REF_M``."""
    if len(q) < 3:
        return q
    r = _smooth(q, RECENTRE_REF_M / s)
    t = np.gradient(r[:, :2], axis=0)
    n = np.column_stack([-t[:, 1], t[:, 0], np.zeros(len(q))])
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-12)[:, None]
    org = r + [0.0, 0.0, height_m - FLOOR_OFFSET_VOX * s]
    with np.errstate(invalid="ignore"):                          # inf - inf: no walls
        mid = 0.5 * (scene.cast(org, n).t - scene.cast(org, -n).t)
    dev = np.einsum("ij,ij->i", q - r, n)                        # the path, off r
    ok = np.flatnonzero(np.abs(mid - dev) <= RECENTRE_MAX_VOX * s)
    if not len(ok):
        return q
    i = np.arange(len(q))
    mid = ndimage.median_filter(np.interp(i, ok, mid[ok]), int(RECENTRE_MEDIAN_M / s) | 1,
                                mode="nearest")
    mid = ndimage.gaussian_filter1d(mid, max(sigma, 1e-9), mode="nearest")
    ramp = np.minimum(1.0, i * s / RECENTRE_REF_M)
    w = (ramp if fixed[0] else 1.0) * (ramp[::-1] if fixed[1] else 1.0)
    return q + ((w * mid + (1 - w) * dev) - dev)[:, None] * n


def _resample(p: NDArray[np.float64], step: float) -> NDArray[np.float64]:
    """The polyline p (n, 3) at even arc-length steps of about ``step`` (ends kept)."""
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    p = np.vstack([p[:1], p[1:][seg > 0]])
    s = np.concatenate([[0.0], np.cumsum(seg[seg > 0])])
    if s[-1] == 0:
        return np.vstack([p[:1], p[:1]])
    t = np.linspace(0.0, s[-1], max(2, int(np.ceil(s[-1] / step - 1e-9)) + 1))
    return np.column_stack([np.interp(t, s, p[:, k]) for k in range(3)])


def _smooth(p: NDArray[np.float64], sigma: float) -> NDArray[np.float64]:
    """Gaussian moving average of an evenly spaced polyline (sigma in samples), padded by
    point reflection through each end so that the ends and straight runs stay put."""
    if sigma <= 0 or len(p) < 3:
        return p
    pad = min(len(p) - 1, int(4 * sigma) + 1)
    ext = np.vstack([2 * p[0] - p[pad:0:-1], p, 2 * p[-1] - p[-2:-pad - 2:-1]])
    out = ndimage.gaussian_filter1d(ext, sigma, axis=0, mode="nearest")[pad:pad + len(p)]
    out[0], out[-1] = p[0], p[-1]
    return out


def _floor_under(scene: Scene, q: NDArray[np.float64], height_m: float, s: float
                 ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The floor (n, 3) under each route point q (n, 3) (z: a floor voxel's centre), by
    a ray cast down from half the sensor height above it, and whether it was found
    (n,) bool; a miss (a hole in the floor) takes the floor height interpolated from the
    points that found it."""
    lift = 0.5 * height_m
    org = q + [0.0, 0.0, lift]
    t = scene.cast(org, [0.0, 0.0, -1.0], t_max=lift + (FLOOR_OFFSET_VOX + 4) * s).t
    hit = np.isfinite(t)
    i = np.flatnonzero(hit)
    z = np.interp(np.arange(len(q)), i, org[i, 2] - t[i]) if len(i) else q[:, 2]
    return np.column_stack([q[:, :2], z]), hit


def _waypoint_array(waypoints: ArrayLike) -> NDArray[np.float64]:
    """Waypoints as (k, 3) float64, z NaN where not given; k >= 2."""
    try:
        w = np.asarray(waypoints, dtype=np.float64)
    except (TypeError, ValueError):
        w = np.empty((0, 0))
    if w.ndim != 2 or w.shape[1] not in (2, 3) or len(w) < 2 or \
            not np.isfinite(w[:, :2]).all():
        raise TrajectoryError(f"Expected at least 2 waypoints of finite x, y[, z] (shape "
                              f"(k, 2) or (k, 3)), got shape {np.shape(waypoints)}.")
    return w if w.shape[1] == 3 else np.column_stack([w, np.full(len(w), np.nan)])


def read_waypoints(path: str | os.PathLike[str]) -> NDArray[np.float64]:
    """Waypoints (k, 3) float64 from a CSV file of ``x,y`` or ``x,y,z`` rows ('#'
    comments; z NaN where not given), with an optional header naming x, y[, z] (a route
    CSV's other ``ROUTE_CSV_COLUMNS`` are read past). ``TrajectoryError`` for a missing
    file, an unknown header name, rows that are not 2 or 3 numbers, or fewer than 2."""
    path = Path(path)
    if not path.is_file():
        raise TrajectoryError(f"Expected a waypoints file, got '{path}' which does not "
                              "exist.")
    rows = [ln.split("#")[0].strip() for ln in path.read_text().splitlines()]
    rows = [r for r in rows if r]
    names = ["x", "y", "z"]
    try:
        np.array(rows[0].split(",") if rows else [], dtype=np.float64)
    except ValueError:                                           # a header
        names = [x.strip().lower() for x in rows.pop(0).split(",")]
        if not {"x", "y"} <= set(names) <= set(ROUTE_CSV_COLUMNS):
            raise TrajectoryError(f"Expected a waypoints header naming x, y[, z], got "
                                  f"'{','.join(names)}' in '{path}'.") from None
    try:
        w = np.array([r.split(",") for r in rows], dtype=np.float64).reshape(len(rows), -1)
    except ValueError:
        w = np.empty((len(rows), 0))
    if rows and w.shape[1] not in ((2, 3) if len(names) == 3 else (len(names),)):
        raise TrajectoryError(f"Expected rows of 2 or 3 numbers x,y[,z] (as many as the "
                              f"header names) in '{path}', got unreadable rows or rows of "
                              "different lengths.")
    cols = [names.index(c) for c in ("x", "y", "z") if c in names[:w.shape[1]]]
    try:
        return _waypoint_array(w[:, cols])
    except TrajectoryError as exc:
        raise TrajectoryError(f"{exc} (in '{path}')") from None
