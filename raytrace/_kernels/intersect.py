"""Ray-triangle and ray-box tests: small pure functions, inlined into the traversal.

No ``fastmath`` here (see ``config.BUILD_FASTMATH``): the results must be the IEEE
float64 results of the formulas as written.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..config import BARY, CACHE, ERROR_MODEL


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def moller_trumbore(verts, tri, k, ox, oy, oz, dx, dy, dz):
    """Möller & Trumbore 1997 ray-triangle test, both faces, float64.

    Triangle k has vertices ``verts[tri[k]]`` = (v0, v1, v2); e1 = v1 - v0, e2 = v2 - v0
    are formed here, in the local frame, exactly as everywhere else. The ray is o + t d. Returns (t, u, v) with the hit at (1 - u - v) v0 + u v1 + v v2, or
    t = inf when the ray misses the triangle's (slightly enlarged) interior.

    Edges and vertices: the barycentric test uses the slack ``config.BARY`` on all three
    constraints, so a ray through a shared edge or vertex hits every triangle sharing it
    (the caller breaks the tie: smaller t, then smaller input index). A ray parallel to
    the triangle's plane (det == 0 exactly) misses it.
    """
    ia = tri[k, 0]
    ib = tri[k, 1]
    ic = tri[k, 2]
    v0x = verts[ia, 0]
    v0y = verts[ia, 1]
    v0z = verts[ia, 2]
    e1x = verts[ib, 0] - v0x
    e1y = verts[ib, 1] - v0y
    e1z = verts[ib, 2] - v0z
    e2x = verts[ic, 0] - v0x
    e2y = verts[ic, 1] - v0y
    e2z = verts[ic, 2] - v0z
    # p = d x e2, det = e1 . p
    px = dy * e2z - dz * e2y
    py = dz * e2x - dx * e2z
    pz = dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    if det == 0.0:
        return (np.nan, 0.0, 0.0)
    inv = 1.0 / det
    sx = ox - v0x
    sy = oy - v0y
    sz = oz - v0z
    u = (sx * px + sy * py + sz * pz) * inv
    if u < -BARY or u > 1.0 + BARY:
        return (np.nan, 0.0, 0.0)
    # q = s x e1
    qx = sy * e1z - sz * e1y
    qy = sz * e1x - sx * e1z
    qz = sx * e1y - sy * e1x
    v = (dx * qx + dy * qy + dz * qz) * inv
    if v < -BARY or u + v > 1.0 + BARY:
        return (np.nan, 0.0, 0.0)
    t = (e2x * qx + e2y * qy + e2z * qz) * inv
    return (t, u, v)


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def slab(box, n, j, ox, oy, oz, ix, iy, iz, t0, t1):
    """Kay & Kajiya 1986 slab test of ray o + t d (inverse direction i) against a box.

    ``box[n, j:j+6]`` is (min x, min y, min z, max x, max y, max z). Returns the entry distance
    clipped to [t0, t1], or inf if the ray misses the box within that interval.
    A NaN from 0 * inf (ray lying in a slab plane) fails both comparisons and is thereby
    ignored, which keeps the test conservative (Williams et al. 2005).
    """
    if ix >= 0.0:
        ax = (box[n, j] - ox) * ix
        bx = (box[n, j + 3] - ox) * ix
    else:
        ax = (box[n, j + 3] - ox) * ix
        bx = (box[n, j] - ox) * ix
    if iy >= 0.0:
        ay = (box[n, j + 1] - oy) * iy
        by = (box[n, j + 4] - oy) * iy
    else:
        ay = (box[n, j + 4] - oy) * iy
        by = (box[n, j + 1] - oy) * iy
    if iz >= 0.0:
        az = (box[n, j + 2] - oz) * iz
        bz = (box[n, j + 5] - oz) * iz
    else:
        az = (box[n, j + 5] - oz) * iz
        bz = (box[n, j + 2] - oz) * iz
    lo = t0
    hi = t1
    if ax > lo:
        lo = ax
    if ay > lo:
        lo = ay
    if az > lo:
        lo = az
    if bx < hi:
        hi = bx
    if by < hi:
        hi = by
    if bz < hi:
        hi = bz
    if lo <= hi:
        return lo
    return float("inf")
