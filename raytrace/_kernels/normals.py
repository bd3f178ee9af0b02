"""Geometric unit normals of hit triangles, from the slot records (e1 x e2)."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..config import CACHE, ERROR_MODEL


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def hit_normals(tris, slot, out):
    """out[i] = normalised e1 x e2 of slot[i]'s record, NaN where slot[i] < 0.

    tris (m, 9) float64 slot records (v0, e1, e2); slot (n,) int64; out (n, 3) float64.
    """
    for i in prange(slot.shape[0]):
        s = slot[i]
        if s < 0:
            out[i, 0] = np.nan
            out[i, 1] = np.nan
            out[i, 2] = np.nan
            continue
        ax, ay, az = tris[s, 3], tris[s, 4], tris[s, 5]
        bx, by, bz = tris[s, 6], tris[s, 7], tris[s, 8]
        cx = ay * bz - az * by
        cy = az * bx - ax * bz
        cz = ax * by - ay * bx
        inv = 1.0 / np.sqrt(cx * cx + cy * cy + cz * cz)
        out[i, 0] = cx * inv
        out[i, 1] = cy * inv
        out[i, 2] = cz * inv
