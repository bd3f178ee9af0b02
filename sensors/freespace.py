"""The free space inside a mesh and its floor, on a voxel grid: steps 1 and 2 of the
route finder (``sensors.route`` does steps 3 and 4, the path and its smoothing).

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
2. **Floor** (``FloorGraph``). Floor voxels are free voxels whose voxel below is not
   free. A floor voxel is drivable when the voxel at the sensor's height above it is
   free and its clearance reaches ``clearance_m`` plus ``CLEARANCE_MARGIN_VOX`` voxels.
   Its *width* is its distance to the foot of the nearest wall: the ridge of that
   distance is the medial axis of the floor plan (Blum 1967). Floor voxels are joined
   to their 26-neighbours one voxel up or down at most (floors steeper than 45 degrees
   are not driven).

Exact point-to-mesh distances (``FreeSpace.distance``) are the engine's closest-point
query, ``raytrace.Scene.closest`` (Ericson 2005, "Real-Time Collision Detection", 5.1.5,
by branch and bound over the scene's BVH).

>>> from raytrace.shapes import tunnel_tube
>>> space = free_space(tunnel_tube(1500, length_m=10.0), voxel_m=0.1)
>>> space.voxel_m, bool(space.free.any())
(0.1, True)
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage, sparse
from scipy.spatial import cKDTree

from raytrace import Scene

from ._checks import as_number, as_whole
from .errors import RouteError

__all__ = ["CLEARANCE_MARGIN_VOX", "FLOOR_OFFSET_VOX", "FloorGraph", "FreeSpace",
           "MAX_VOXELS", "MIN_VOXEL_M", "SAMPLE_STEP_VOX", "SUB_EDGE_VOX", "SWEEP_STEP_M",
           "free_space", "point_text"]

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
#: The walk that finds the ends steps up or down this much between neighbouring
#: floor voxels (the route itself one voxel): a drain or a kerb does not cut the floor
#: into strips whose dead ends would pass for the passage's ends (ASSUMED: 0.3 m).
SWEEP_STEP_M = 0.3
_SQRT3 = float(np.sqrt(3.0))
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
                 free: NDArray[np.bool_], clearance_m: NDArray[np.float32]) -> None:
        self.scene, self.voxel_m, self.origin = scene, voxel_m, origin
        self.free, self.clearance_m = free, clearance_m

    def centres(self, ijk: ArrayLike) -> NDArray[np.float64]:
        """World positions (n, 3) of voxel centres given by indices (n, 3)."""
        return self.origin + (np.asarray(ijk, dtype=np.float64) + 0.5) * self.voxel_m

    def index(self, points: ArrayLike) -> NDArray[np.int64]:
        """Voxel indices (n, 3) int64 of world points (n, 3); may lie outside the grid."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return np.floor((p - self.origin) / self.voxel_m).astype(np.int64)

    def distance(self, points: ArrayLike) -> NDArray[np.float64]:
        """Exact distance (n,) float64 of world points (n, 3) to the mesh (m)
        (``raytrace.Scene.closest``)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return np.asarray(self.scene.closest(p).distance)

    def __repr__(self) -> str:
        return (f"FreeSpace({int(self.free.sum()):,} free voxels of {self.free.size:,}, "
                f"voxel {self.voxel_m:.3g} m)")


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
    raise RouteError(f"Expected a raytrace.Scene or (vertices, faces), got "
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
    RouteError
        A grid over ``max_voxels``, a mesh that encloses no free space (no floor below
        and roof above: a plane, an open bowl), or ``start`` outside the free space.
    """
    scene = _as_scene(mesh)
    max_voxels = as_whole(max_voxels, "max_voxels", RouteError, lo=1000)
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
        s = as_number(voxel_m, "voxel_m", RouteError, unit="m", lo=0, lo_open=True)
    shape = (np.ceil(ext / s - 1e-9) + 1).astype(np.int64)
    if np.prod(shape) > max_voxels:
        raise RouteError(f"Expected a grid of at most {max_voxels:,} voxels, got "
                         f"{int(np.prod(shape)):,} of {s:g} m over a box of "
                         f"{' x '.join(f'{x:.4g}' for x in ext)} m; pass a larger "
                         "--voxel.")
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
        raise RouteError("Expected a mesh that encloses free space (a floor below and "
                              "a roof above, as a tunnel or cave has), got none at voxel "
                              f"{s:.3g} m; is it a single surface, an open bowl or a "
                              "terrain?")
    if start is None:
        keep = int(np.argmax(np.bincount(labels.ravel())[1:])) + 1
    else:
        p = np.asarray(start, dtype=np.float64).reshape(3) - scene.origin_offset
        keep = _label_near(labels, np.floor((p - origin) / s).astype(np.int64))
        if keep == 0:
            raise RouteError(f"Expected `start` inside the mesh's free space, got "
                                  f"{point_text(p + scene.origin_offset)}, which is outside it or "
                                  "within two voxels of the surface.")
    return FreeSpace(scene, s, origin + scene.origin_offset, labels == keep,
                     dvox * np.float32(s))


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


class FloorGraph:
    """The floor voxels of a free space (step 2): all of them (``floor``, flat indices),
    their distance to the nearest foot of a wall (``width``, m), and the drivable ones
    (``nodes``, indices into ``floor``), where a sensor ``height_m`` above them keeps
    ``clearance_m``, with their graphs (``g_len``: the route's, joining voxels at most
    one voxel up or down, or ``step_m`` (a platform's step, rounded up to voxels);
    ``g_sweep``: the ends')."""

    def __init__(self, space: FreeSpace, height_m: float, clearance_m: float,
                 step_m: float | None = None) -> None:
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
            raise RouteError(
                f"Expected a passage at least 2 x {clearance_m:g} m wide (plus "
                f"{CLEARANCE_MARGIN_VOX:g} voxels of {s:.3g} m) and higher than "
                f"{height_m + clearance_m:g} m, got at most {float(sensor.max()):.3g} m "
                f"of clearance at {height_m:g} m above the floor; pass a smaller "
                "--clearance or --height, or a smaller --voxel.")
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
        up_len = 1 if step_m is None else max(1, int(np.ceil(step_m / s - 1e-9)))
        self.g_len, self.g_sweep = (
            sparse.csr_matrix((ln, (i, j)), shape=(m, m))[self.nodes][:, self.nodes]
            for i, j, ln in (self._edges(self.nodes, up) for up in (
                up_len, max(up_len, round(SWEEP_STEP_M / s)))))
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
            raise RouteError(f"Expected waypoint {number} {point_text(p)} inside the "
                                  "passage's free space (over its floor, under its roof), "
                                  "got a point outside it.")
        c = sp.centres(self.ijk[pick:pick + 1])
        if self._tree is None:
            self._tree = cKDTree(self.centres(np.arange(len(self.nodes))))
        d, node = self._tree.query(c[0])
        if d > self.clearance_m + 3 * s:
            raise RouteError(
                f"Expected waypoint {number} {point_text(p)} where the passage keeps "
                f"{self.clearance_m:g} m from the mesh at {self.height_m:g} m above the "
                f"floor, got the nearest such floor {d:.3g} m away; move the waypoint "
                "into the passage.")
        return int(node)


def point_text(p: ArrayLike) -> str:
    """(x, y, z) for a message; a NaN z (a waypoint without one) left out."""
    c = np.asarray(p, dtype=np.float64).reshape(-1)
    return "(" + ", ".join(f"{float(x):.6g}" for x in c[np.isfinite(c)]) + ")"
