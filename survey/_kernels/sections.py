"""Numba kernels of the section analysis: the closest segment of a 2-D polyline to many
points, through a uniform grid of segment lists.

Grid (built by ``build_grid``): the design's bounding box plus a margin, square cells
of ``cell`` m; ``start`` (nx * ny + 1,) int64 CSR offsets into ``items`` (int64
segment ids), a segment listed in every cell its bounding box overlaps. Query: the
cells in Chebyshev rings r = 0, 1, ... around the point's cell; after ring r every
segment not yet seen lies at least r * cell away (the point is inside its own cell),
so the search stops once the best distance is below that (exact). Points outside the
grid test every segment (rare: the grid has a margin).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from raytrace.config import CACHE, ERROR_MODEL


@njit(cache=CACHE, error_model=ERROR_MODEL)
def build_grid(a, b, x0, y0, cell, nx, ny):
    """CSR (start (nx*ny + 1,), items) of the segments a[i]-b[i] ((m, 2) each) per
    cell of the grid with corner (x0, y0)."""
    m = a.shape[0]
    lo = np.empty((m, 2), np.int64)
    hi = np.empty((m, 2), np.int64)
    count = np.zeros(nx * ny + 1, np.int64)
    for i in range(m):
        for k in range(2):
            o = x0 if k == 0 else y0
            n = nx if k == 0 else ny
            u = int(np.floor((min(a[i, k], b[i, k]) - o) / cell))
            v = int(np.floor((max(a[i, k], b[i, k]) - o) / cell))
            lo[i, k] = min(max(u, 0), n - 1)
            hi[i, k] = min(max(v, 0), n - 1)
        for cy in range(lo[i, 1], hi[i, 1] + 1):
            for cx in range(lo[i, 0], hi[i, 0] + 1):
                count[cy * nx + cx + 1] += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    items = np.empty(start[-1], np.int64)
    for i in range(m):
        for cy in range(lo[i, 1], hi[i, 1] + 1):
            for cx in range(lo[i, 0], hi[i, 0] + 1):
                c = cy * nx + cx
                items[fill[c]] = i
                fill[c] += 1
    return start, items


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _seg_test(px, py, a, d, length, s, best):
    """Distance of p to segment s (start a[s], unit direction d[s], length[s]) and the
    foot's distance along it; best = (distance, segment, along) updated in place when
    closer (ties keep the lower segment id)."""
    w = (px - a[s, 0]) * d[s, 0] + (py - a[s, 1]) * d[s, 1]
    if w < 0.0:
        w = 0.0
    elif w > length[s]:
        w = length[s]
    fx = a[s, 0] + w * d[s, 0] - px
    fy = a[s, 1] + w * d[s, 1] - py
    dist = np.sqrt(fx * fx + fy * fy)
    if dist < best[0] or (dist == best[0] and s < best[1]):
        best[0] = dist
        best[1] = s
        best[2] = w


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def closest_segments(p, a, d, length, start, items, x0, y0, cell, nx, ny, seg, along,
                     dist):
    """For each point p[i] ((n, 2)): its closest segment seg[i], the foot's distance
    along it along[i] and the distance dist[i] (outputs preallocated, (n,))."""
    m = a.shape[0]
    for i in prange(p.shape[0]):
        px, py = p[i, 0], p[i, 1]
        best = np.empty(3)
        best[0] = np.inf
        best[1] = m
        best[2] = 0.0
        cx = int(np.floor((px - x0) / cell))
        cy = int(np.floor((py - y0) / cell))
        if cx < 0 or cy < 0 or cx >= nx or cy >= ny:
            for s in range(m):
                _seg_test(px, py, a, d, length, s, best)
        else:
            r = 0
            while True:
                for gy in range(cy - r, cy + r + 1):
                    if gy < 0 or gy >= ny:
                        continue
                    edge = gy == cy - r or gy == cy + r
                    step = 1 if edge else 2 * r
                    gx = cx - r
                    while gx <= cx + r:
                        if 0 <= gx < nx:
                            c = gy * nx + gx
                            for k in range(start[c], start[c + 1]):
                                _seg_test(px, py, a, d, length, items[k], best)
                        if step == 0:
                            break
                        gx += step
                if best[0] <= r * cell:
                    break
                if cx - r <= 0 and cy - r <= 0 and cx + r >= nx - 1 and cy + r >= ny - 1:
                    break
                r += 1
        seg[i] = int(best[1])
        along[i] = best[2]
        dist[i] = best[0]
