"""The ray-triangle test: a small pure function, inlined into the traversal kernels.

No ``fastmath`` here (see ``config.BUILD_FASTMATH``): the results must be the IEEE
float64 results of the formulas as written.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..config import BARY, CACHE, ERROR_MODEL


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def moller_trumbore(tris, k, ox, oy, oz, dx, dy, dz):
    """Möller & Trumbore 1997 ray-triangle test, both faces, float64.

    ``tris[k]`` holds v0 (0:3), e1 = v1 - v0 (3:6), e2 = v2 - v0 (6:9), local frame.
    The ray is o + t d. Returns (t, u, v) with the hit at (1 - u - v) v0 + u v1 + v v2, or
    t = inf when the ray misses the triangle's (slightly enlarged) interior.

    Edges and vertices: the barycentric test uses the slack ``config.BARY`` on all three
    constraints, so a ray through a shared edge or vertex hits every triangle sharing it
    (the caller breaks the tie: smaller t, then smaller input index). A ray parallel to
    the triangle's plane (det == 0 exactly) misses it.
    """
    v0x = tris[k, 0]
    v0y = tris[k, 1]
    v0z = tris[k, 2]
    e1x = tris[k, 3]
    e1y = tris[k, 4]
    e1z = tris[k, 5]
    e2x = tris[k, 6]
    e2y = tris[k, 7]
    e2z = tris[k, 8]
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
def closer(t, ids, k, t0, best_t, best_id):
    """Whether a hit at t on slot k beats the best so far (input index best_id, -1 for
    none): t must lie in [t0, best_t]; a smaller t wins, an equal t goes to the smaller
    input index (``ids[k]``). The one place the tie rule lives: it makes the closest hit
    a total order, independent of traversal order and thread count."""
    return t >= t0 and t <= best_t and (t < best_t or best_id < 0 or ids[k] < best_id)
