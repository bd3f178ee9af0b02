"""Per-origin cube map of candidate triangles: exact closest hit for many rays sharing
one origin (a TLS station), without walking the BVH for most rays.

Idea: around the origin, the sphere of directions is split into the six faces of a cube
(gnomonic projection: direction d on face +x maps to (d_y / d_x, d_z / d_x) in [-1, 1]^2).
A gnomonic projection maps straight lines to straight lines, so the part of a triangle
inside a face's frustum projects to a convex polygon whose vertices are the projections
of the clipped triangle's vertices: its bounding box is a conservative footprint. Each
face carries a G x G grid; each cell lists every triangle whose footprint box overlaps
it. A ray then tests only the triangles of its own cell — the exact closest hit, because
any triangle the ray hits contains a point t d in the ray's frustum cell, whose
projection is the ray's own (u, v).

Cells listing more than ``HOT`` triangles (looking down a long tunnel, many far
triangles crowd into a small solid angle) are marked, and their rays walk the BVH
instead. Both paths use the same float64 Möller–Trumbore on the same local-frame data
and the same (t, input index) order, so the result is bit-identical to the BVH's.

Layout (one view, for one origin)::

    start (6 G G + 1,) int32   CSR offsets: cell c lists slots[start[c]:start[c+1]]
    counts (6 G G,) int32      triangles per cell (hot cells: more than HOT, no list)
    slots (n_entries,) int32   triangle slots (into the leaf-ordered triangle arrays)

Cell index c = face * G * G + row * G + col; face = 2 * axis + (0 if d[axis] > 0 else 1);
row from the first, col from the second of the other two axes in cyclic order.

The cube map is a view-dependent acceleration in the spirit of light-buffer / "hemicube"
occlusion culling (Haines & Greenberg 1986, "The light buffer: a shadow-testing
accelerator"; Cohen & Greenberg 1985, hemicube), here made exact by conservative
footprints.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..config import CACHE, CUBEMAP_PAD, ERROR_MODEL
from .intersect import closer, moller_trumbore
from .traverse import trace_closest

#: Chunk of triangles per parallel task in the footprint pass.
_CHUNK = 4096


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _clip(px, py, pz, n, qx, qy, qz, a, b, lateral):
    """Sutherland & Hodgman 1974 polygon clipping of p (n vertices, face frame: x =
    depth, y and z lateral) by the half-space a * x + b * (y if lateral == 1 else z) >= 0,
    a plane through the origin. Output into q; returns its vertex count (0: empty)."""
    m = 0
    for i in range(n):
        j = (i + 1) % n
        if lateral == 1:
            fi = a * px[i] + b * py[i]
            fj = a * px[j] + b * py[j]
        else:
            fi = a * px[i] + b * pz[i]
            fj = a * px[j] + b * pz[j]
        if fi >= 0.0:
            qx[m] = px[i]
            qy[m] = py[i]
            qz[m] = pz[i]
            m += 1
        if (fi >= 0.0) != (fj >= 0.0):
            s = fi / (fi - fj)
            qx[m] = px[i] + s * (px[j] - px[i])
            qy[m] = py[i] + s * (py[j] - py[i])
            qz[m] = pz[i] + s * (pz[j] - pz[i])
            m += 1
    return m


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def footprints(tris, ox, oy, oz, g, out):
    """Cell ranges of every triangle on every cube face.

    tris : (m, 9) float64 per slot v0, e1, e2 (local frame); (ox, oy, oz) the origin;
    g : cells per face side. Writes out (m, 6, 4) int32: row0, row1, col0, col1
    (inclusive), or row0 = -1 when the triangle does not reach that face.
    """
    m = tris.shape[0]
    n_chunks = (m + _CHUNK - 1) // _CHUNK
    for ch in prange(n_chunks):
        bx = np.empty(8)
        by = np.empty(8)
        bz = np.empty(8)
        cx = np.empty(8)
        cy = np.empty(8)
        cz = np.empty(8)
        p = np.empty((3, 3))
        for k in range(ch * _CHUNK, min(m, (ch + 1) * _CHUNK)):
            for c in range(3):
                o = ox if c == 0 else (oy if c == 1 else oz)
                v0 = tris[k, c] - o
                p[0, c] = v0
                p[1, c] = v0 + tris[k, 3 + c]
                p[2, c] = v0 + tris[k, 6 + c]
            for face in range(6):
                axis = face // 2
                sgn = 1.0 if face % 2 == 0 else -1.0
                a1 = (axis + 1) % 3
                a2 = (axis + 2) % 3
                for i in range(3):
                    bx[i] = sgn * p[i, axis]
                    by[i] = p[i, a1]
                    bz[i] = p[i, a2]
                # Frustum |y| <= x (1 + pad), |z| <= x (1 + pad): four planes through
                # the origin; enlarged by CUBEMAP_PAD so that rounding never excludes a
                # triangle a ray on the face border hits.
                sc = 1.0 + CUBEMAP_PAD
                n = _clip(bx, by, bz, 3, cx, cy, cz, sc, -1.0, 1)
                n = _clip(cx, cy, cz, n, bx, by, bz, sc, 1.0, 1)
                n = _clip(bx, by, bz, n, cx, cy, cz, sc, -1.0, 2)
                n = _clip(cx, cy, cz, n, bx, by, bz, sc, 1.0, 2)
                if n == 0:
                    out[k, face, 0] = -1
                    continue
                umin = np.inf
                umax = -np.inf
                wmin = np.inf
                wmax = -np.inf
                full = False
                for i in range(n):
                    x = bx[i]
                    if x <= 1e-300:
                        full = True  # the triangle touches the origin: all directions
                        break
                    u = by[i] / x
                    w = bz[i] / x
                    umin = min(umin, u)
                    umax = max(umax, u)
                    wmin = min(wmin, w)
                    wmax = max(wmax, w)
                if full:
                    out[k, face, 0] = 0
                    out[k, face, 1] = g - 1
                    out[k, face, 2] = 0
                    out[k, face, 3] = g - 1
                    continue
                half = 0.5 * g
                r0 = int(np.floor((umin - CUBEMAP_PAD + 1.0) * half))
                r1 = int(np.floor((umax + CUBEMAP_PAD + 1.0) * half))
                c0 = int(np.floor((wmin - CUBEMAP_PAD + 1.0) * half))
                c1 = int(np.floor((wmax + CUBEMAP_PAD + 1.0) * half))
                out[k, face, 0] = max(0, min(g - 1, r0))
                out[k, face, 1] = max(0, min(g - 1, r1))
                out[k, face, 2] = max(0, min(g - 1, c0))
                out[k, face, 3] = max(0, min(g - 1, c1))


@njit(cache=CACHE, error_model=ERROR_MODEL)
def count_entries(fp, g):
    """Per-cell triangle counts (6 g g,) int32. A cell counts at most one entry per
    triangle, so int32 holds any mesh below 2^31 triangles."""
    counts = np.zeros(6 * g * g, dtype=np.int32)
    for k in range(fp.shape[0]):
        for face in range(6):
            r0 = fp[k, face, 0]
            if r0 < 0:
                continue
            base = face * g * g
            for r in range(r0, fp[k, face, 1] + 1):
                for c in range(fp[k, face, 2], fp[k, face, 3] + 1):
                    counts[base + r * g + c] += 1
    return counts


@njit(cache=CACHE, error_model=ERROR_MODEL)
def fill_entries(fp, g, counts, hot):
    """CSR arrays from footprints; hot cells (count > hot) keep no list (their rays use
    the BVH), so memory is spent on the cells that are used."""
    n_cells = 6 * g * g
    # int32 offsets: the caller keeps at most config.CUBEMAP_MAX_ENTRIES (< 2^31) entries.
    start = np.zeros(n_cells + 1, dtype=np.int32)
    for c in range(n_cells):
        keep = counts[c] if counts[c] <= hot else 0
        start[c + 1] = start[c] + keep
    slots = np.empty(start[n_cells], dtype=np.int32)
    fill = start[:-1].copy()
    for k in range(fp.shape[0]):
        for face in range(6):
            r0 = fp[k, face, 0]
            if r0 < 0:
                continue
            base = face * g * g
            for r in range(r0, fp[k, face, 1] + 1):
                for c in range(fp[k, face, 2], fp[k, face, 3] + 1):
                    cell = base + r * g + c
                    if counts[cell] <= hot:
                        slots[fill[cell]] = k
                        fill[cell] += 1
    return start, slots


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def closest_hit_view(start, slots, counts, g, hot, nodes, links, tris, ids, org, dirs,
                     tmin, tmax, stack_size, block, out_t, out_slot, out_u, out_v):
    """Closest hit for n rays from the single origin org (1, 3) (local frame) using the
    cube map, falling back to the BVH for rays in hot cells. Same outputs as
    ``traverse.closest_hit``."""
    n = dirs.shape[0]
    n_blocks = (n + block - 1) // block
    one_t = tmin.shape[0] == 1
    ox = org[0, 0]
    oy = org[0, 1]
    oz = org[0, 2]
    half = 0.5 * g
    for b in prange(n_blocks):
        st_node = np.empty(stack_size, dtype=np.int64)
        st_dist = np.empty(stack_size)
        sd = np.empty(4)
        si = np.empty(4, dtype=np.int64)
        for r in range(b * block, min(n, (b + 1) * block)):
            rt = 0 if one_t else r
            dx = dirs[r, 0]
            dy = dirs[r, 1]
            dz = dirs[r, 2]
            ax = abs(dx)
            ay = abs(dy)
            az = abs(dz)
            # Dominant axis (ties: lowest axis) and the face's lateral coordinates.
            if ax >= ay and ax >= az:
                face = 0 if dx > 0 else 1
                u = dy / ax
                w = dz / ax
            elif ay >= az:
                face = 2 if dy > 0 else 3
                u = dz / ay
                w = dx / ay
            else:
                face = 4 if dz > 0 else 5
                u = dx / az
                w = dy / az
            row = min(g - 1, max(0, int(np.floor((u + 1.0) * half))))
            col = min(g - 1, max(0, int(np.floor((w + 1.0) * half))))
            cell = face * g * g + row * g + col
            t0 = tmin[rt]
            t1 = tmax[rt]
            if counts[cell] > hot:
                bt, bid, bslot, bu, bv = trace_closest(nodes, links, tris, ids, ox, oy, oz,
                                                       dx, dy, dz, t0, t1, -1,
                                                       st_node, st_dist, sd, si)
            else:
                bt = t1
                bid = -1
                bslot = -1
                bu = 0.0
                bv = 0.0
                for e in range(start[cell], start[cell + 1]):
                    k = slots[e]
                    t, uu, vv = moller_trumbore(tris, k, ox, oy, oz, dx, dy, dz)
                    if closer(t, ids, k, t0, bt, bid):
                        bt = t
                        bid = ids[k]
                        bslot = k
                        bu = uu
                        bv = vv
            if bslot >= 0:
                out_t[r] = bt
                out_slot[r] = bslot
                out_u[r] = bu
                out_v[r] = bv
            else:
                out_t[r] = np.inf
                out_slot[r] = -1
                out_u[r] = 0.0
                out_v[r] = 0.0
