"""A mesh's own triangles as area samples, seen from a route through it: the frame
(``RouteFrame``: distance along the route, offset, height) and the samples
(``Surface``, ``mesh_surface``) that station planning and MLS studies measure coverage
on where a mesh has no tunnel axis (a cave, a mine, a mesh made elsewhere)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike, NDArray

from survey.errors import PlanningError

if TYPE_CHECKING:
    from raytrace import Scene

__all__ = ["FLOOR_NORMAL_Z", "ROUTE_FRAME_STEP_M", "RouteFrame", "Surface", "mesh_surface",
           "sub_index"]

Floats = NDArray[np.float64]
Ints = NDArray[np.int64]

#: A sample whose normal's z exceeds this (facing up) below the route is floor.
FLOOR_NORMAL_Z = 0.8

# ---------------------------------------------------------------------- any mesh (route)
#: Spacing (m) of the dense copy of a route that ``RouteFrame`` projects points onto;
#: a foot point is then within this of the exact one before the tangent correction.
ROUTE_FRAME_STEP_M = 0.05


class RouteFrame:
    """A route (n, 3) as a curvilinear frame, duck-typing ``Alignment``'s ``to_world``
    and ``to_local``: distance along the route (m, from 0), offset to its left (m,
    horizontal, across the route's heading) and height above it (m).

    ``to_local`` takes the nearest point of the route resampled every
    ``ROUTE_FRAME_STEP_M`` and moves it twice along the local heading; points beyond the
    ends get the end distance (as ``Alignment.to_local`` does).
    """

    def __init__(self, points: ArrayLike) -> None:
        from scipy.spatial import cKDTree

        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or len(p) < 2:
            raise PlanningError(f"Expected a route of shape (n, 3) with n >= 2, got shape "
                                f"{p.shape}.")
        d = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
        self.length_m = float(d[-1])
        if not self.length_m > 0:
            raise PlanningError("Expected a route of positive length, got 0 m.")
        s = np.unique(np.append(np.arange(0.0, self.length_m, ROUTE_FRAME_STEP_M),
                                self.length_m))
        self._s = s
        self._q = np.stack([np.interp(s, d, p[:, k]) for k in range(3)], axis=1)
        t = np.gradient(self._q[:, :2], s, axis=0)
        t /= np.maximum(np.linalg.norm(t, axis=1), 1e-12)[:, None]
        self._t = t                                             # heading (x, y), unit
        self._tree = cKDTree(self._q)

    def __repr__(self) -> str:
        return f"RouteFrame({self.length_m:.1f} m)"

    @property
    def chainage_range(self) -> tuple[float, float]:
        """(0, length) in m."""
        return 0.0, self.length_m

    def _at(self, s: Floats) -> tuple[Floats, Floats]:
        """Route point (..., 3) and heading (..., 2) at distances ``s``."""
        q = np.stack([np.interp(s, self._s, self._q[:, k]) for k in range(3)], axis=-1)
        t = np.stack([np.interp(s, self._s, self._t[:, k]) for k in range(2)], axis=-1)
        return q, t / np.maximum(np.linalg.norm(t, axis=-1), 1e-12)[..., None]

    def to_world(self, chainage: ArrayLike, offset: ArrayLike, height: ArrayLike
                 ) -> Floats:
        """World points (..., 3) from distance, left offset and height (m, broadcast)."""
        s, off, h = np.broadcast_arrays(np.asarray(chainage, dtype=np.float64),
                                        np.asarray(offset, dtype=np.float64),
                                        np.asarray(height, dtype=np.float64))
        q, t = self._at(s)
        return np.stack([q[..., 0] - off * t[..., 1], q[..., 1] + off * t[..., 0],
                         q[..., 2] + h], axis=-1)

    def to_local(self, points: ArrayLike) -> tuple[Floats, Floats, Floats]:
        """(distance, offset, height), each (n,) in m, of world points (n, 3)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        _, i = self._tree.query(p)
        s = self._s[i]
        # Two steps along the heading (Newton on (p - q(s)) . t(s) = 0 with the
        # curvature term dropped): the residual falls as the square of the first.
        for _ in range(2):
            q, t = self._at(s)
            s = np.clip(s + np.einsum("ni,ni->n", p[:, :2] - q[:, :2], t), 0.0,
                        self.length_m)
        q, t = self._at(s)
        dp = p - q
        return s, t[:, 0] * dp[:, 1] - t[:, 1] * dp[:, 0], dp[:, 2]


@dataclass(repr=False)
class Surface:
    """A mesh's own triangles as area samples: each triangle cut into n x n equal
    sub-triangles (n from its longest edge and ``sample_m``), one sample at each
    sub-triangle's centroid, standing for its area.

    Attributes
    ----------
    points, normals : (k, 3) float64, sample (m) and its triangle's unit normal, turned
        towards the route (the side the scanner looks from)
    area : (k,) float64, m^2
    corners : (k, 3, 3) float64, the sub-triangle (m)
    triangle : (k,) int64, face index in the mesh
    sub : (k,) int64, sub-triangle index in it (``sub_index``)
    split : (n_faces,) int64, n per face
    chainage, angle : (k,) float64, distance along the route (m) and angle around it
        from the crown (radians, positive left), seen from ``height_m`` above the route
    is_floor : (k,) bool, below the route and facing up (kept only by ``keep_floor``)
    """

    points: Floats
    normals: Floats
    area: Floats
    corners: Floats
    triangle: Ints
    sub: Ints
    split: Ints
    chainage: Floats
    angle: Floats
    is_floor: NDArray[np.bool_]

    def __repr__(self) -> str:
        return (f"Surface({len(self.area):,} samples of {len(np.unique(self.triangle)):,} "
                f"triangles, {self.total_area:.1f} m^2)")

    @property
    def total_area(self) -> float:
        """Sum of the sample areas (m^2)."""
        return float(self.area.sum())


def _sub_lattice(n: int) -> NDArray[np.int64]:
    """The n x n sub-triangles of a triangle as (n * n, 3, 2) lattice indices (i, j):
    corner a + (i b' + j c') / n; upright ones first, row by row, then inverted."""
    up = [((i, j), (i + 1, j), (i, j + 1)) for i in range(n) for j in range(n - i)]
    dn = [((i + 1, j), (i + 1, j + 1), (i, j + 1)) for i in range(n - 1)
          for j in range(n - 1 - i)]
    return np.array(up + dn, dtype=np.int64).reshape(-1, 3, 2)


def sub_index(u: ArrayLike, v: ArrayLike, n: ArrayLike) -> Ints:
    """Index (k,) of the sub-triangle (``_sub_lattice`` order) holding barycentric
    (u, v) (weights of the second and third corner) of a triangle cut n x n."""
    u, v, n = np.broadcast_arrays(np.asarray(u, dtype=np.float64),
                                  np.asarray(v, dtype=np.float64), np.asarray(n))
    x = np.clip(u, 0, 1) * n
    y = np.clip(v, 0, 1) * n
    i = np.clip(np.floor(x), 0, n - 1).astype(np.int64)
    j = np.clip(np.floor(y), 0, n - 1 - i).astype(np.int64)
    upright = (x - i) + (y - j) < 1
    upright |= i + j > n - 2                       # the last row has no inverted ones
    n_up = n * (n + 1) // 2
    # Row i of the upright ones starts after sum_{r<i} (n - r); of the inverted after
    # sum_{r<i} (n - 1 - r).
    up_idx = i * n - i * (i - 1) // 2 + j
    dn_idx = n_up + i * (n - 1) - i * (i - 1) // 2 + j
    return np.where(upright, up_idx, dn_idx).astype(np.int64)


def mesh_surface(scene: Scene, frame: RouteFrame, *, sample_m: float = 0.25,
                 height_m: float = 0.0, keep_floor: bool = False,
                 chainage_range_m: tuple[float, float] | None = None) -> Surface:
    """Area samples of ``scene``'s triangles (``Surface``), no sub-triangle edge longer
    than ``sample_m`` (m); floor samples dropped unless ``keep_floor``; only samples
    whose distance along ``frame`` lies in ``chainage_range_m`` (default: all).
    ``height_m`` (m) lifts the point above ``frame`` that normals are turned towards and
    angles seen from: with a frame on the floor, give it a positive height (the floor
    is what lies below it)."""
    if not (np.isfinite(sample_m) and sample_m > 0):
        raise PlanningError(f"Expected a positive sample size, got {sample_m} m.")
    v = np.asarray(scene.vertices, dtype=np.float64)
    f = np.asarray(scene.faces, dtype=np.int64)
    tri = v[f]
    e = np.linalg.norm(tri[:, [1, 2, 0]] - tri, axis=2).max(axis=1)
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    a2 = np.linalg.norm(nrm, axis=1)
    split = np.maximum(1, np.ceil(e / sample_m - 1e-9)).astype(np.int64)
    out: list[tuple[Floats, Ints, Ints]] = []
    for n in np.unique(split[a2 > 0]):
        faces = np.flatnonzero((split == n) & (a2 > 0))
        lat = _sub_lattice(int(n)) / n                          # (m, 3, 2)
        t = tri[faces]
        c = (t[:, None, None, 0] + lat[None, :, :, :1] * (t[:, None, None, 1] - t[:, None, None, 0])
             + lat[None, :, :, 1:] * (t[:, None, None, 2] - t[:, None, None, 0]))
        out.append((c.reshape(-1, 3, 3), np.repeat(faces, len(lat)),
                    np.tile(np.arange(len(lat)), len(faces))))
    corners = np.concatenate([o[0] for o in out]) if out else np.zeros((0, 3, 3))
    face = np.concatenate([o[1] for o in out]) if out else np.zeros(0, dtype=np.int64)
    sub = np.concatenate([o[2] for o in out]) if out else np.zeros(0, dtype=np.int64)
    pts = corners.mean(axis=1)
    area = 0.5 * a2[face] / split[face] ** 2
    s, off, h = frame.to_local(pts)
    h = h - height_m
    n = nrm[face] / a2[face, None]
    # DECISION: a mesh from elsewhere has no reliable winding: the normal is turned
    # towards the route point it is unrolled around, as the grid path turns it towards
    # the axis.
    centre = frame.to_world(s, 0.0, height_m)
    n = np.where((np.einsum("ni,ni->n", n, centre - pts) < 0)[:, None], -n, n)
    ang = np.arctan2(off, h)
    floor = (np.abs(ang) > np.pi / 2) & (n[:, 2] > FLOOR_NORMAL_Z)
    keep = np.ones(len(pts), dtype=bool) if keep_floor else ~floor
    if chainage_range_m is not None:
        keep &= (s >= chainage_range_m[0]) & (s < chainage_range_m[1])
    return Surface(pts[keep], n[keep], area[keep], corners[keep], face[keep], sub[keep],
                   split, s[keep], ang[keep], floor[keep])
