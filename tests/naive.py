"""Brute-force references (stumpy's ``tests/naive.py`` habit): slow, obvious, float64.

``naive_cast`` tests every ray against every triangle with the textbook Möller–Trumbore
formulas in world coordinates, vectorised over triangles, and keeps the smallest t
(ties: the smallest triangle index). Written independently of ``raytrace``'s kernels;
only the tolerance constant is shared, because it is part of the definition of a hit.
"""

from __future__ import annotations

import numpy as np

from raytrace.config import BARY

#: Relative distance of t from [t_min, t_max] within which a missed triangle still
#: counts as grazed (``margin``).
T_GRAZE = 1e-9
#: Distance (relative to the size of the coordinates) from a triangle's edges within
#: which the point where a ray meets its plane counts as on the edge (``margin`` 0): a
#: sliver 1e-12 m wide has a large barycentric margin one coordinate ulp outside it.
EDGE_GRAZE = 1e-12


def edge_distance(a, b, c, x):
    """(k,) distance from x[i] to the nearest edge of triangle (a[i], b[i], c[i])."""
    best = np.full(len(x), np.inf)
    for p, q in ((a, b), (b, c), (c, a)):
        e = q - p
        den = np.einsum("ij,ij->i", e, e)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.clip(np.einsum("ij,ij->i", x - p, e) / den, 0.0, 1.0)
        s = np.where(den > 0, s, 0.0)
        best = np.minimum(best, np.linalg.norm(x - (p + s[:, None] * e), axis=1))
    return best


def naive_cast(vertices, faces, origins, directions, t_min=0.0, t_max=np.inf):
    """Returns t (n,), triangle (n,), u (n,), v (n,), and margin (n,): how far the winning
    hit's barycentric coordinates are from the edge of the accepted region (small means
    the ray grazes an edge, where rounding may decide either way); 0 where the point
    lies within ``EDGE_GRAZE`` of the coordinates' size of an edge."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    d = np.asarray(directions, dtype=np.float64)
    d = d / np.linalg.norm(d, axis=1)[:, None]
    o = np.broadcast_to(np.asarray(origins, dtype=np.float64), d.shape)
    p0 = v[f[:, 0]]
    e1 = v[f[:, 1]] - p0
    e2 = v[f[:, 2]] - p0
    n = d.shape[0]
    out_t = np.full(n, np.inf)
    out_tri = np.full(n, -1, dtype=np.int64)
    out_u = np.zeros(n)
    out_v = np.zeros(n)
    margin = np.full(n, np.inf)
    near_edge = EDGE_GRAZE * max(1.0, float(np.abs(v).max(initial=0.0)),
                                 float(np.abs(o).max(initial=0.0)))
    for i in range(n):
        p = np.cross(d[i], e2)
        det = np.einsum("ij,ij->i", e1, p)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            inv = 1.0 / det
            s = o[i] - p0
            u = np.einsum("ij,ij->i", s, p) * inv
            q = np.cross(s, e1)
            vv = (q @ d[i]) * inv
            t = np.einsum("ij,ij->i", e2, q) * inv
            ok = (det != 0) & (u >= -BARY) & (u <= 1 + BARY) & (vv >= -BARY) & \
                 (u + vv <= 1 + BARY) & (t >= t_min) & (t <= t_max)
            m = np.minimum(np.minimum(u, vv), 1 - u - vv)
        if not ok.any():
            # Closest near-miss margin, for diagnosing grazing rays. A triangle met just
            # outside [t_min, t_max] counts (rounding decides t there as on an edge):
            # a ray from a triangle's vertex hits it at t = +-1e-122 either way.
            near = (t >= t_min - T_GRAZE * (1 + abs(t_min))) & \
                (t <= t_max + T_GRAZE * (1 + abs(t_max)))
            m = np.where((det != 0) & near, -m, np.inf)
            seen = np.flatnonzero(np.isfinite(m))
            if seen.size:
                x = o[i] + t[seen, None] * d[i]
                on_edge = edge_distance(p0[seen], p0[seen] + e1[seen], p0[seen] + e2[seen],
                                         x) <= near_edge
                m[seen[on_edge]] = 0.0
            margin[i] = np.nanmin(np.abs(m)) if np.isfinite(m).any() else np.inf
            continue
        cand = np.flatnonzero(ok)
        tt = t[cand]
        best = cand[tt == tt.min()].min()
        out_t[i] = t[best]
        out_tri[i] = best
        out_u[i] = u[best]
        out_v[i] = vv[best]
        margin[i] = abs(min(u[best], vv[best], 1 - u[best] - vv[best]))
        x = (o[i] + t[best] * d[i])[None]
        if edge_distance(p0[best][None], (p0[best] + e1[best])[None],
                          (p0[best] + e2[best])[None], x)[0] <= near_edge:
            margin[i] = 0.0
    return out_t, out_tri, out_u, out_v, margin


def naive_nearest(points, reference):
    """Exact nearest reference point of each point by all pairs: (distance (n,), index (n,))."""
    p = np.asarray(points, dtype=np.float64)
    r = np.asarray(reference, dtype=np.float64)
    d = np.empty(len(p))
    idx = np.empty(len(p), dtype=np.int64)
    for i in range(len(p)):
        dd = np.sqrt(((r - p[i]) ** 2).sum(axis=1))
        idx[i] = int(np.argmin(dd))
        d[i] = dd[idx[i]]
    return d, idx


def _segment_closest(p, a, b):
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
    return a + t[:, None] * ab


def naive_point_mesh(points, vertices, faces):
    """Unsigned distance of each point to a mesh, every triangle tried: the foot of the
    perpendicular when it falls inside the triangle (barycentric coordinates by solving
    the 2x2 normal equations), else the nearest of the three edges. (distance (n,),
    triangle (n,))."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    e1, e2 = b - a, c - a
    g11 = np.einsum("ij,ij->i", e1, e1)
    g12 = np.einsum("ij,ij->i", e1, e2)
    g22 = np.einsum("ij,ij->i", e2, e2)
    det = g11 * g22 - g12 * g12
    out = np.empty(len(points))
    tri = np.empty(len(points), dtype=np.int64)
    for i, p in enumerate(np.asarray(points, dtype=np.float64)):
        w = p - a
        r1 = np.einsum("ij,ij->i", w, e1)
        r2 = np.einsum("ij,ij->i", w, e2)
        u = (g22 * r1 - g12 * r2) / det
        vv = (g11 * r2 - g12 * r1) / det
        inside = (u >= 0) & (vv >= 0) & (u + vv <= 1)
        foot = a + u[:, None] * e1 + vv[:, None] * e2
        P = np.broadcast_to(p, a.shape)
        best = np.where(inside[:, None], foot, _segment_closest(P, a, b))
        for q in (_segment_closest(P, b, c), _segment_closest(P, c, a)):
            better = (~inside) & (np.linalg.norm(q - p, axis=1) <
                                  np.linalg.norm(best - p, axis=1))
            best = np.where(better[:, None], q, best)
        d = np.linalg.norm(best - p, axis=1)
        tri[i] = int(np.argmin(d))
        out[i] = d[tri[i]]
    return out, tri
