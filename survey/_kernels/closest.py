"""Closest point on a triangle (Ericson 2005, *Real-Time Collision Detection*, 5.1.5:
Voronoi regions of the vertices, edges and face, tested in that order), and the exact
nearest triangle among candidate lists."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from raytrace.config import CACHE, ERROR_MODEL


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def closest_on_triangle(px, py, pz, a, b, c, out):
    """Closest point of triangle (a, b, c) (each (3,)) to p, written into out (3,)."""
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    acx, acy, acz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    apx, apy, apz = px - a[0], py - a[1], pz - a[2]
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:                       # vertex region A
        out[0], out[1], out[2] = a[0], a[1], a[2]
        return
    bpx, bpy, bpz = px - b[0], py - b[1], pz - b[2]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:                        # vertex region B
        out[0], out[1], out[2] = b[0], b[1], b[2]
        return
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:         # edge region AB
        v = d1 / (d1 - d3)
        out[0], out[1], out[2] = a[0] + v * abx, a[1] + v * aby, a[2] + v * abz
        return
    cpx, cpy, cpz = px - c[0], py - c[1], pz - c[2]
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:                        # vertex region C
        out[0], out[1], out[2] = c[0], c[1], c[2]
        return
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:         # edge region AC
        w = d2 / (d2 - d6)
        out[0], out[1], out[2] = a[0] + w * acx, a[1] + w * acy, a[2] + w * acz
        return
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:   # edge region BC
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        out[0] = b[0] + w * (c[0] - b[0])
        out[1] = b[1] + w * (c[1] - b[1])
        out[2] = b[2] + w * (c[2] - b[2])
        return
    den = 1.0 / (va + vb + vc)                        # face region (barycentric)
    v = vb * den
    w = vc * den
    out[0] = a[0] + abx * v + acx * w
    out[1] = a[1] + aby * v + acy * w
    out[2] = a[2] + abz * v + acz * w


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def nearest_triangles(points, tris, cand_start, cand, out_tri, out_q):
    """points (n, 3); tris (m, 3, 3); candidates of point i are
    cand[cand_start[i]:cand_start[i + 1]]. Writes the nearest candidate (out_tri (n,))
    and its closest point (out_q (n, 3)); ties keep the lower triangle index."""
    for i in prange(points.shape[0]):
        q = np.empty(3)
        best = np.inf
        bt = -1
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        for k in range(cand_start[i], cand_start[i + 1]):
            j = cand[k]
            closest_on_triangle(px, py, pz, tris[j, 0], tris[j, 1], tris[j, 2], q)
            d = (q[0] - px) ** 2 + (q[1] - py) ** 2 + (q[2] - pz) ** 2
            if d < best or (d == best and j < bt):
                best = d
                bt = j
                out_q[i, 0], out_q[i, 1], out_q[i, 2] = q[0], q[1], q[2]
        out_tri[i] = bt
