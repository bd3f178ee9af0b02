"""Brute-force references (stumpy's ``tests/naive.py`` habit): slow, obvious, float64.

``naive_cast`` tests every ray against every triangle with the textbook Möller–Trumbore
formulas in world coordinates, vectorised over triangles, and keeps the smallest t
(ties: the smallest triangle index). Written independently of ``raytrace``'s kernels;
only the tolerance constant is shared, because it is part of the definition of a hit.
"""

from __future__ import annotations

import numpy as np

from raytrace.config import BARY


def naive_cast(vertices, faces, origins, directions, t_min=0.0, t_max=np.inf):
    """Returns t (n,), triangle (n,), u (n,), v (n,), and margin (n,): how far the winning
    hit's barycentric coordinates are from the edge of the accepted region (small means
    the ray grazes an edge, where rounding may decide either way)."""
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
            # Closest near-miss margin, for diagnosing grazing rays.
            m = np.where((det != 0) & (t >= t_min) & (t <= t_max), -m, np.inf)
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
    return out_t, out_tri, out_u, out_v, margin
