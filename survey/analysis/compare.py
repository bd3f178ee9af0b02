"""Cloud-to-cloud and cloud-to-mesh distances with CloudCompare's semantics, statistics
per scan (the seed's Table 1), a histogram and the distance as a LAS scalar field.

- ``cloud_to_cloud``: for every compared point the exact nearest reference point
  (scipy ``cKDTree``, no approximation). ``max_dist`` clamps: a point with no reference
  point within ``max_dist`` gets exactly ``max_dist`` (CloudCompare's "max. distance":
  farther points are not searched and receive the limit). ``split=True`` also returns
  the signed components of (compared - nearest reference) along X, Y and Z (NaN where
  clamped). ``model="plane"``: the distance to the least-squares plane through the
  ``k`` nearest reference points (CloudCompare's local model "least square plane"),
  which removes the reference's sampling from the distance.
- ``cloud_to_mesh``: signed distance to the exact closest point of the mesh (Ericson
  2005, 5.1.5, on candidate triangles from a centroid k-d tree with a radius bound that
  keeps the search exact). Sign as CloudCompare: positive on the side the closest
  triangle's right-hand normal (b - a) x (c - a) points to.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from survey.errors import CompareError

#: Points per block in the distance loops (bounds the candidate lists' memory).
BLOCK = 200_000


def _points(a, name):
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise CompareError(f"Expected `{name}` to have shape (n, 3), got {a.shape}.")
    if not np.isfinite(a).all():
        raise CompareError(f"Expected finite coordinates in `{name}`, got NaN or inf; "
                           "drop those points first.")
    return a


@dataclass
class Distances:
    """Result of a comparison.

    distance : (n,) float64, m (unsigned for C2C, signed for C2M)
    dx, dy, dz : (n,) float64 or None, split components (C2C with ``split``)
    nearest : (n,) int64, index of the nearest reference point or triangle (-1 where
        clamped)
    """

    distance: np.ndarray
    nearest: np.ndarray
    dx: np.ndarray | None = None
    dy: np.ndarray | None = None
    dz: np.ndarray | None = None


class ReferenceCloud:
    """A reference cloud prepared once (k-d tree) for comparing many clouds or chunks."""

    def __init__(self, reference):
        self.points = _points(reference, "reference")
        if len(self.points) == 0:
            raise CompareError("Expected a reference cloud with points, got none.")
        # Local origin: the tree works on small numbers (UTM-sized inputs keep mm).
        self.origin = self.points.mean(axis=0)
        self.tree = cKDTree(self.points - self.origin)

    def distances(self, compared, *, max_dist=None, split=False, model=None,
                  k: int = 6) -> Distances:
        p = _points(compared, "compared") - self.origin
        if max_dist is not None and not max_dist > 0:
            raise CompareError(f"Expected a positive max distance, got {max_dist}.")
        if model not in (None, "plane"):
            raise CompareError(f"Expected model None or 'plane', got {model!r}.")
        ub = np.inf if max_dist is None else float(max_dist)
        d, idx = self.tree.query(p, k=1, distance_upper_bound=ub, workers=-1)
        far = ~np.isfinite(d)
        idx = np.where(far, -1, idx).astype(np.int64)
        if model == "plane":
            kk = min(int(k), len(self.points))
            if kk < 3:
                raise CompareError(f"Expected k >= 3 reference points for a plane, got {kk}.")
            _, nb = self.tree.query(p, k=kk, workers=-1)
            q = self.tree.data[nb]                               # (n, k, 3)
            c = q.mean(axis=1)
            cov = np.einsum("nki,nkj->nij", q - c[:, None], q - c[:, None])
            normal = np.linalg.eigh(cov)[1][:, :, 0]             # smallest eigenvalue
            d = np.where(far, d, np.abs(np.einsum("ni,ni->n", p - c, normal)))
        d = np.where(far, ub, d)
        out = Distances(d, idx)
        if split:
            diff = np.full_like(p, np.nan)
            diff[~far] = p[~far] - self.tree.data[idx[~far]]
            out.dx, out.dy, out.dz = diff[:, 0], diff[:, 1], diff[:, 2]
        return out


def cloud_to_cloud(compared, reference, *, max_dist=None, split=False, model=None,
                   k: int = 6) -> Distances:
    """Distances (n,) from each compared point (n, 3) to the reference cloud (m, 3);
    see the module doc for ``max_dist``, ``split`` and ``model``."""
    return ReferenceCloud(reference).distances(compared, max_dist=max_dist, split=split,
                                               model=model, k=k)


class ReferenceMesh:
    """A reference triangle mesh prepared once for signed point-to-mesh distances."""

    def __init__(self, vertices, faces):
        v = _points(vertices, "vertices")
        f = np.asarray(faces)
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0 or \
                not np.issubdtype(f.dtype, np.integer) or f.min() < 0 or f.max() >= len(v):
            raise CompareError(f"Expected `faces` (m, 3) of vertex indices below {len(v)}, "
                               f"got shape {f.shape}.")
        self.origin = v.mean(axis=0)
        self.tris = np.ascontiguousarray((v - self.origin)[f])          # (m, 3, 3)
        n = np.cross(self.tris[:, 1] - self.tris[:, 0], self.tris[:, 2] - self.tris[:, 0])
        ln = np.linalg.norm(n, axis=1)
        self.normals = n / np.where(ln > 0, ln, 1.0)[:, None]
        cen = self.tris.mean(axis=1)
        rad = np.linalg.norm(self.tris - cen[:, None], axis=2).max(axis=1)
        # Triangles grouped by size (powers of two of the centroid-to-vertex radius),
        # one centroid tree each, so one big triangle (an end-cap fan) does not widen
        # every small triangle's search radius.
        grp = np.floor(np.log2(np.maximum(rad, 1e-9))).astype(int)
        self.groups = []
        for g in np.unique(grp):
            ids = np.flatnonzero(grp == g)
            self.groups.append((ids, cKDTree(cen[ids]), float(rad[ids].max())))

    def distances(self, points, *, max_dist=None) -> Distances:
        from survey._kernels.closest import nearest_triangles

        p = _points(points, "points") - self.origin
        if max_dist is not None and not max_dist > 0:
            raise CompareError(f"Expected a positive max distance, got {max_dist}.")
        dist = np.empty(len(p))
        tri = np.empty(len(p), dtype=np.int64)
        for b in range(0, len(p), BLOCK):
            q = p[b:b + BLOCK]
            # Upper bound: the nearest centroid lies on its triangle.
            ub = np.min([t.query(q, k=1, workers=-1)[0] for _, t, _ in self.groups], axis=0)
            # Exact: a triangle closer than ub has its centroid within ub + its radius.
            lists = []
            for ids, t, r in self.groups:
                got = t.query_ball_point(q, ub + r + 1e-12, workers=-1)
                lists.append([ids[np.asarray(g, dtype=np.int64)] for g in got])
            cand = [np.concatenate(x) for x in zip(*lists)]
            start = np.zeros(len(q) + 1, dtype=np.int64)
            start[1:] = np.cumsum([len(c) for c in cand])
            flat = np.concatenate(cand).astype(np.int64)
            out_t = np.empty(len(q), dtype=np.int64)
            out_q = np.empty((len(q), 3))
            nearest_triangles(q, self.tris, start, flat, out_t, out_q)
            diff = q - out_q
            dd = np.linalg.norm(diff, axis=1)
            sign = np.where(np.einsum("ni,ni->n", diff, self.normals[out_t]) < 0, -1.0, 1.0)
            dist[b:b + BLOCK] = sign * dd
            tri[b:b + BLOCK] = out_t
        if max_dist is not None:
            far = np.abs(dist) > max_dist
            dist[far] = np.sign(dist[far]) * max_dist
            tri[far] = -1
        return Distances(dist, tri)


def cloud_to_mesh(points, vertices, faces, *, max_dist=None) -> Distances:
    """Signed distances (n,) from points (n, 3) to a triangle mesh (vertices (v, 3),
    faces (m, 3)); ``max_dist`` clamps |d| keeping the sign."""
    return ReferenceMesh(vertices, faces).distances(points, max_dist=max_dist)


# ------------------------------------------------------------------ statistics, outputs
STAT_FIELDS = ("n", "mean", "median", "std", "p95", "rms", "max_abs")


def distance_stats(d) -> dict:
    """n, mean, median, std (ddof 0), p95 of |d|, RMS and max |d| of distances (m)."""
    d = np.asarray(d, dtype=np.float64)
    if d.size == 0:
        return {k: (0 if k == "n" else float("nan")) for k in STAT_FIELDS}
    a = np.abs(d)
    return {"n": int(d.size), "mean": float(d.mean()), "median": float(np.median(d)),
            "std": float(d.std()), "p95": float(np.percentile(a, 95)),
            "rms": float(np.sqrt(np.mean(d * d))), "max_abs": float(a.max())}


