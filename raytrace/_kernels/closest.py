"""Closest point on the mesh: a point–triangle test and a branch-and-bound traversal of
the scene's 8-wide BVH, ``prange`` over point blocks.

Layout read here: the records of ``traverse.py`` (``nodes`` float32 child boxes as
structure of arrays, ``links`` int32 children and counts, ``tris`` (m, 9) float64 slots
v0, e1 = v1 - v0, e2 = v2 - v0 in the scene's local frame, ``ids`` slot -> input index).

Point–triangle (``offset_to_triangle``): Ericson 2005, *Real-Time Collision Detection*,
5.1.5 — the Voronoi regions of vertex A, vertex B, edge AB, vertex C, edge AC, edge BC
and the face, tested in that order. Written on the slot's own numbers (a, ab, ac) and
returning the *offset* p - q rather than q: ``p - b`` is spelt ``(p - a) - ab``, so a
point that is exactly a vertex gets the offset (0, 0, 0) exactly, and the distance is
measured from the point itself (no large-coordinate q subtracted back).

Traversal (Friedman, Bentley & Finkel 1977, ACM TOMS 3(3): nearest neighbour by branch
and bound, on the BVH as in pbrt-v4 and Embree's closest-point query): a visit computes
the squared distance from the point to each of the eight child boxes (float64 from the
float32 planes), orders the children nearer first, tests leaf children at once (which
tightens the bound before farther boxes are judged), visits the nearest internal child
next and pushes the others, farthest first. A box is skipped only when it is *strictly*
farther than the best squared distance so far (times ``BOUND_SLACK``), so a triangle at
exactly the best distance is still compared.

Exactness: the result is the minimum of (squared distance, input triangle index) over
all triangles — a total order, so it does not depend on the tree, the visiting order,
the block split or the thread count: bit for bit the answer of trying every triangle.
A float32 child box contains its float64 triangles with margin (``scene._pack_nodes``
rounds outward and pads by ``config.BOX_PAD_REL`` of the extent), so the computed
distance to a box never exceeds the computed distance to a triangle inside it.

Points run in fixed-size blocks (``config.RAY_BLOCK``); within a block the previous
point's triangle is tried first ("warm start"): for points in scan order it is usually
the answer or close to it, and a tight bound from the start prunes most of the tree. It
changes only the work, never the result.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..config import CACHE, ERROR_MODEL, RAY_BLOCK
from .simd import LANES
from .traverse import CHILD, COUNT

#: Multiplier of the best squared distance before a box is judged "farther". DECISION:
#: 1 + 2^-40, a safety margin far above float64 rounding of a squared distance (a few
#: ulps, ~1e-16 relative) and far below any measurable extra work: a box the exact
#: arithmetic would keep is never culled by rounding.
BOUND_SLACK = 1.0 + 2.0 ** -40

_MAXX = 3 * LANES          # first column of the maxima (min x, y, z then max x, y, z)


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def offset_to_triangle(tris, j, px, py, pz):
    """Offset p - q from the closest point q of triangle slot ``j`` (v0, e1, e2 in
    ``tris[j]``) to the point p (same frame). Ericson 2005, 5.1.5."""
    ax, ay, az = tris[j, 0], tris[j, 1], tris[j, 2]
    abx, aby, abz = tris[j, 3], tris[j, 4], tris[j, 5]
    acx, acy, acz = tris[j, 6], tris[j, 7], tris[j, 8]
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:                          # vertex region A
        return apx, apy, apz
    bpx, bpy, bpz = apx - abx, apy - aby, apz - abz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:                           # vertex region B
        return bpx, bpy, bpz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:            # edge region AB
        v = d1 / (d1 - d3)
        return apx - v * abx, apy - v * aby, apz - v * abz
    cpx, cpy, cpz = apx - acx, apy - acy, apz - acz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:                           # vertex region C
        return cpx, cpy, cpz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:            # edge region AC
        w = d2 / (d2 - d6)
        return apx - w * acx, apy - w * acy, apz - w * acz
    va = d3 * d6 - d5 * d4
    e43 = d4 - d3
    e56 = d5 - d6
    if va <= 0.0 and e43 >= 0.0 and e56 >= 0.0:          # edge region BC
        w = e43 / (e43 + e56)
        return (bpx - w * (acx - abx), bpy - w * (acy - aby), bpz - w * (acz - abz))
    den = 1.0 / (va + vb + vc)                           # face region (barycentric)
    v = vb * den
    w = vc * den
    return (apx - abx * v - acx * w, apy - aby * v - acy * w, apz - abz * v - acz * w)


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _axis_gap(lo, hi, p):
    """Distance from p to the interval [lo, hi] (float32 bounds), float64; 0 inside."""
    a = np.float64(lo) - p
    b = p - np.float64(hi)
    g = a if a > b else b
    return g if g > 0.0 else 0.0


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _try(tris, ids, j, px, py, pz, best, best_id):
    """Squared distance and offset of slot j, and whether (d2, id) beats (best, best_id)."""
    ex, ey, ez = offset_to_triangle(tris, j, px, py, pz)
    d2 = ex * ex + ey * ey + ez * ez
    tid = ids[j]
    return d2, ex, ey, ez, d2 < best or (d2 == best and tid < best_id)


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def nearest(nodes, links, tris, ids, px, py, pz, prev, st_node, st_dist, cn, cd, cl, dd):
    """Nearest triangle to the point p (local frame) through the BVH.

    ``prev`` (a slot, or -1) is tried first to set the bound. ``st_node``, ``st_dist``
    (stack) and ``cn``, ``cd``, ``cl``, ``dd`` (8 each: a visit's children, distances
    and lanes, sorted; the eight box distances) are the caller's scratch. Returns
    (squared distance, slot, ex, ey, ez) with (ex, ey, ez) = p - q.
    """
    # DECISION: without a previous answer, slot 0 sets the first bound: the bound is then
    # always finite, so unused lanes (box +inf..-inf, distance inf) fall to ``d > cull``
    # with no test of their own, and the lane loop below has no branch.
    if prev < 0:
        prev = 0
    best, bx, by, bz, _ = _try(tris, ids, prev, px, py, pz, np.inf, 0)
    best_id = ids[prev]
    best_slot = prev
    cull = best * BOUND_SLACK
    sp = 0
    cur = 0
    while cur >= 0:
        # Squared distances to the eight child boxes (a branch-free loop over the SoA
        # planes), then the kept ones sorted nearer first (insertion sort).
        for lane in range(LANES):
            gx = _axis_gap(nodes[cur, lane], nodes[cur, _MAXX + lane], px)
            gy = _axis_gap(nodes[cur, LANES + lane], nodes[cur, _MAXX + LANES + lane], py)
            gz = _axis_gap(nodes[cur, 2 * LANES + lane],
                           nodes[cur, _MAXX + 2 * LANES + lane], pz)
            dd[lane] = gx * gx + gy * gy + gz * gz
        k = 0
        for lane in range(LANES):
            d = dd[lane]
            if d > cull or d == np.inf:                  # (inf: an unused lane)
                continue
            q = k
            while q > 0 and cd[q - 1] > d:
                cd[q] = cd[q - 1]
                cl[q] = cl[q - 1]
                q -= 1
            cd[q] = d
            cl[q] = lane
            k += 1
        # Leaves first (nearest first), remembering internal children in order.
        n_int = 0
        for q in range(k):
            dq = cd[q]
            if dq > cull:
                continue
            lane = cl[q]
            cnt = links[cur, COUNT + lane]
            if cnt > 0:
                first = links[cur, CHILD + lane]
                for j in range(first, first + cnt):
                    d2, ex, ey, ez, win = _try(tris, ids, j, px, py, pz, best, best_id)
                    if win:
                        best, best_id, best_slot, bx, by, bz = d2, ids[j], j, ex, ey, ez
                        cull = best * BOUND_SLACK
            else:
                cn[n_int] = links[cur, CHILD + lane]
                cd[n_int] = dq                           # n_int <= q: no overwrite
                n_int += 1
        cur = -1
        cur_d = 0.0
        # Push the farther internal children (farthest first), visit the nearest next.
        for q in range(n_int - 1, -1, -1):
            if cd[q] > cull:
                continue
            if cur >= 0:
                st_node[sp] = cur
                st_dist[sp] = cur_d
                sp += 1
            cur = cn[q]
            cur_d = cd[q]
        # Pop the next record still worth visiting.
        while cur < 0 and sp > 0:
            sp -= 1
            if st_dist[sp] <= cull:
                cur = st_node[sp]
    return best, best_slot, bx, by, bz


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def side_of(tris, j, ex, ey, ez):
    """-1.0 where the offset (ex, ey, ez) = p - q points against slot j's normal
    e1 x e2 (dot < 0), else +1.0 (on the normal's side, or in the plane)."""
    e1x, e1y, e1z = tris[j, 3], tris[j, 4], tris[j, 5]
    e2x, e2y, e2z = tris[j, 6], tris[j, 7], tris[j, 8]
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    return -1.0 if ex * nx + ey * ny + ez * nz < 0.0 else 1.0


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _block(nodes, links, tris, ids, pts, stack_size, order, r0, r1,
           out_d, out_tri, out_e, out_side):
    """Points order[r0:r1] (or r0..r1 when ``order`` is empty), sequentially, with the
    warm start."""
    st_node = np.empty(stack_size, dtype=np.int64)
    st_dist = np.empty(stack_size)
    cn = np.empty(LANES, dtype=np.int64)
    cd = np.empty(LANES)
    cl = np.empty(LANES, dtype=np.int64)
    dd = np.empty(LANES)
    ordered = order.shape[0] > 0
    prev = -1
    for p in range(r0, r1):
        r = order[p] if ordered else p
        d2, slot, ex, ey, ez = nearest(nodes, links, tris, ids, pts[r, 0], pts[r, 1],
                                       pts[r, 2], prev, st_node, st_dist, cn, cd, cl, dd)
        out_d[r] = np.sqrt(d2)
        out_tri[r] = ids[slot]
        out_side[r] = side_of(tris, slot, ex, ey, ez)
        out_e[r, 0] = ex
        out_e[r, 1] = ey
        out_e[r, 2] = ez
        prev = slot


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def closest_points(nodes, links, tris, ids, pts, stack_size, order, out_d, out_tri,
                   out_e, out_side):
    """Nearest triangle of n points.

    pts : (n, 3) float64, local frame; order : (n,) int64 processing order or empty for
    0..n-1. Writes out_d (n,) distance, out_tri (n,) input triangle index, out_e (n, 3)
    offset p - q and out_side (n,) +-1 (``side_of``), each at the point's own index.
    """
    n = pts.shape[0]
    n_blocks = (n + RAY_BLOCK - 1) // RAY_BLOCK
    for b in prange(n_blocks):
        _block(nodes, links, tris, ids, pts, stack_size, order, b * RAY_BLOCK,
               min(n, (b + 1) * RAY_BLOCK), out_d, out_tri, out_e, out_side)


