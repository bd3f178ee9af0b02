"""Stack-based BVH traversal over 4-wide records: closest hit and any hit, ``prange``
over ray blocks.

Layout read here (made by ``collapse.to_quad_layout``; boxes float32, rounded outward)::

    nodes (n4, 32) float32   per record: child boxes as structure of arrays (0:24,
                             see ``intersect.slab``); 128 bytes, two cache lines
    links (n4, 32) int32     the same memory seen as int32: 24:28 = child (record index,
                             or first triangle slot of a leaf), 28:32 = triangle count
                             (0: internal child or unused lane)
    tris  (m, 9) float64     per slot (leaf order): v0, e1 = v1 - v0, e2 = v2 - v0, in
                             the scene's local frame (72 B, one contiguous run a leaf)
    ids   (m,) int32         slot -> input triangle index (for the tie-break)

Traversal (nearest child first, as in pbrt-v4 and Embree's BVH4): a visit tests the
four child boxes, sorts the hit ones by entry distance, intersects leaf children at once
(nearer first, which tightens t before farther boxes are judged), visits the nearest
internal child next and pushes the others, farthest first, with their entry distances;
a popped record whose entry distance exceeds the current closest hit is skipped.

Determinism: the closest hit is the minimum of (t, input index) over all triangles the
ray hits within [t_min, t_max] — a total order, so the result does not depend on the
visiting order, the block split or the thread count. Rays run in fixed-size blocks
(``config.RAY_BLOCK``); within a block the previous ray's triangle is tested first
("warm start"): for rays in scan order it is usually the answer, and a tight t_max from
the start prunes most of the tree. It changes only the work, never the result.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..config import CACHE, ERROR_MODEL, RAY_BLOCK
from .intersect import closer, moller_trumbore


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _sorted_hits(nodes, node, ox, oy, oz, ix, iy, iz, nx, ny, nz, t0, t1, sd, si):
    """Slab-test (Kay & Kajiya 1986) the four children of ``node``; write the hit ones
    into sd (distance) and si (lane) in ascending distance; return how many.

    Columns: min x/y/z at 0/4/8, max x/y/z at 12/16/20 (+ lane). ``nx`` is 0 when the
    ray's x direction is >= 0 (the near plane is the minimum) and 12 otherwise; the far
    plane is then at 12 - nx; likewise ``ny``, ``nz``. With the planes chosen once per
    ray the four lanes run without branches (selects only), which LLVM vectorises.
    A NaN from 0 * inf (a ray lying in a slab plane) fails the comparisons and is thereby
    ignored, which keeps the test conservative (Williams et al. 2005).
    """
    for lane in range(4):
        ax = (nodes[node, nx + lane] - ox) * ix
        bx = (nodes[node, 12 - nx + lane] - ox) * ix
        ay = (nodes[node, 4 + ny + lane] - oy) * iy
        by = (nodes[node, 16 - ny + lane] - oy) * iy
        az = (nodes[node, 8 + nz + lane] - oz) * iz
        bz = (nodes[node, 20 - nz + lane] - oz) * iz
        lo = t0
        lo = ax if ax > lo else lo
        lo = ay if ay > lo else lo
        lo = az if az > lo else lo
        hi = t1
        hi = bx if bx < hi else hi
        hi = by if by < hi else hi
        hi = bz if bz < hi else hi
        sd[lane] = lo if lo <= hi else np.inf
    k = 0
    for lane in range(4):
        dd = sd[lane]
        if dd != np.inf:
            # Insertion into the sorted prefix [0, k); entries at >= lane are unread.
            j = k
            while j > 0 and sd[j - 1] > dd:
                sd[j] = sd[j - 1]
                si[j] = si[j - 1]
                j -= 1
            sd[j] = dd
            si[j] = lane
            k += 1
    return k


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def trace_closest(nodes, links, tris, ids, ox, oy, oz, dx, dy, dz, t0, t1, prev,
                  st_node, st_dist, sd, si):
    """Closest hit of one ray o + t d, t in [t0, t1], through the BVH.

    ``prev`` (a slot, or -1) is tested first to tighten t1 (warm start). ``st_node``,
    ``st_dist`` (stack) and ``sd``, ``si`` (4 entries) are the caller's scratch buffers.
    Returns (t, input index, slot, u, v); slot -1 and t = t1 on a miss.
    """
    ix = 1.0 / dx
    iy = 1.0 / dy
    iz = 1.0 / dz
    nx = 0 if ix >= 0.0 else 12
    ny = 0 if iy >= 0.0 else 12
    nz = 0 if iz >= 0.0 else 12
    best_t = t1
    best_id = -1
    best_slot = -1
    best_u = 0.0
    best_v = 0.0
    if prev >= 0:
        t, u, v = moller_trumbore(tris, prev, ox, oy, oz, dx, dy, dz)
        if closer(t, ids, prev, t0, best_t, best_id):
            best_t = t
            best_id = ids[prev]
            best_slot = prev
            best_u = u
            best_v = v
    sp = 0
    cur = 0
    while cur >= 0:
        k = _sorted_hits(nodes, cur, ox, oy, oz, ix, iy, iz, nx, ny, nz, t0, best_t, sd, si)
        # Leaves first (nearest first), remembering internal children in order.
        n_int = 0
        for q in range(k):
            if sd[q] > best_t:
                break
            lane = si[q]
            cnt = links[cur, 28 + lane]
            if cnt > 0:
                first = links[cur, 24 + lane]
                for j in range(first, first + cnt):
                    t, u, v = moller_trumbore(tris, j, ox, oy, oz, dx, dy, dz)
                    if closer(t, ids, j, t0, best_t, best_id):
                        best_t = t
                        best_id = ids[j]
                        best_slot = j
                        best_u = u
                        best_v = v
            else:
                # Reuse the sorted buffers in place: internal children keep their order.
                sd[n_int] = sd[q]
                si[n_int] = links[cur, 24 + lane]
                n_int += 1
        cur = -1
        cur_d = 0.0
        # Push the farther internal children (farthest first), visit the nearest next.
        for q in range(n_int - 1, -1, -1):
            if sd[q] > best_t:
                continue
            if cur >= 0:
                st_node[sp] = cur
                st_dist[sp] = cur_d
                sp += 1
            cur = si[q]
            cur_d = sd[q]
        # Pop the next record still worth visiting.
        while cur < 0 and sp > 0:
            sp -= 1
            if st_dist[sp] <= best_t:
                cur = st_node[sp]
    return best_t, best_id, best_slot, best_u, best_v


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _closest_block(nodes, links, tris, ids, org, dirs, tmin, tmax, stack_size, order,
                   r0, r1, out_t, out_slot, out_u, out_v):
    """Rays order[r0:r1] of ``closest_hit`` (or rays r0..r1 when ``order`` is empty),
    sequentially, with the warm start.

    DECISION: the per-block work is its own (serial) function called from the prange
    loop, not inlined into it: Numba's parfor lowering compiled the same loop ~35 %
    slower (measured: 0.9 vs 1.45 Mrays/s on one thread, incoherent rays).
    """
    st_node = np.empty(stack_size, dtype=np.int64)
    st_dist = np.empty(stack_size)
    sd = np.empty(4)
    si = np.empty(4, dtype=np.int64)
    one_org = org.shape[0] == 1
    one_t = tmin.shape[0] == 1
    ordered = order.shape[0] > 0
    prev = -1
    for p in range(r0, r1):
        r = order[p] if ordered else p
        ro = 0 if one_org else r
        rt = 0 if one_t else r
        bt, bid, bslot, bu, bv = trace_closest(
            nodes, links, tris, ids, org[ro, 0], org[ro, 1], org[ro, 2],
            dirs[r, 0], dirs[r, 1], dirs[r, 2], tmin[rt], tmax[rt], prev,
            st_node, st_dist, sd, si)
        if bslot >= 0:
            out_t[r] = bt
            out_slot[r] = bslot
            out_u[r] = bu
            out_v[r] = bv
            prev = bslot
        else:
            out_t[r] = np.inf
            out_slot[r] = -1
            out_u[r] = 0.0
            out_v[r] = 0.0


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def closest_hit(nodes, links, tris, ids, org, dirs, tmin, tmax, stack_size, order,
                out_t, out_slot, out_u, out_v):
    """Closest hit for n rays.

    org : (n_o, 3) float64, n_o in {1, n}; dirs : (n, 3) float64 unit vectors;
    tmin, tmax : (n_t,) float64, n_t in {1, n}; order : (n,) int64 processing order
    (see ``order.py``) or empty for 0..n-1. Writes out_t (inf on miss), out_slot
    (-1 on miss), out_u, out_v (0 on miss), each at the ray's own index.
    """
    n = dirs.shape[0]
    n_blocks = (n + RAY_BLOCK - 1) // RAY_BLOCK
    for b in prange(n_blocks):
        _closest_block(nodes, links, tris, ids, org, dirs, tmin, tmax, stack_size, order,
                       b * RAY_BLOCK, min(n, (b + 1) * RAY_BLOCK),
                       out_t, out_slot, out_u, out_v)


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def trace_any(nodes, links, tris, ox, oy, oz, dx, dy, dz, t0, t1, prev, st_node, sd, si):
    """Any hit of one ray o + t d with t in [t0, t1]: the slot of a triangle hit, or -1.
    ``prev`` (a slot, or -1) is tested first. Early exit; children are visited nearest
    first, as in ``trace_closest``."""
    if prev >= 0:
        t, u, v = moller_trumbore(tris, prev, ox, oy, oz, dx, dy, dz)
        if t >= t0 and t <= t1:
            return prev
    ix = 1.0 / dx
    iy = 1.0 / dy
    iz = 1.0 / dz
    nx = 0 if ix >= 0.0 else 12
    ny = 0 if iy >= 0.0 else 12
    nz = 0 if iz >= 0.0 else 12
    sp = 0
    cur = 0
    while cur >= 0:
        k = _sorted_hits(nodes, cur, ox, oy, oz, ix, iy, iz, nx, ny, nz, t0, t1, sd, si)
        nxt = -1
        for q in range(k):
            lane = si[q]
            cnt = links[cur, 28 + lane]
            child = links[cur, 24 + lane]
            if cnt > 0:
                for j in range(child, child + cnt):
                    t, u, v = moller_trumbore(tris, j, ox, oy, oz, dx, dy, dz)
                    if t >= t0 and t <= t1:
                        return j
            elif nxt < 0:
                nxt = child
            else:
                st_node[sp] = child
                sp += 1
        cur = nxt
        if cur < 0 and sp > 0:
            sp -= 1
            cur = st_node[sp]
    return -1


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _any_block(nodes, links, tris, org, dirs, tmin, tmax, stack_size, order, r0, r1, out):
    """Rays order[r0:r1] of ``any_hit`` (or r0..r1 when ``order`` is empty)."""
    st_node = np.empty(stack_size, dtype=np.int64)
    sd = np.empty(4)
    si = np.empty(4, dtype=np.int64)
    one_org = org.shape[0] == 1
    one_t = tmin.shape[0] == 1
    ordered = order.shape[0] > 0
    prev = -1
    for p in range(r0, r1):
        r = order[p] if ordered else p
        ro = 0 if one_org else r
        rt = 0 if one_t else r
        slot = trace_any(nodes, links, tris, org[ro, 0], org[ro, 1], org[ro, 2],
                         dirs[r, 0], dirs[r, 1], dirs[r, 2], tmin[rt], tmax[rt], prev,
                         st_node, sd, si)
        out[r] = slot >= 0
        if slot >= 0:
            prev = slot


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def any_hit(nodes, links, tris, org, dirs, tmin, tmax, stack_size, order, out):
    """Any hit within [tmin, tmax] for n rays, in ``order`` (or 0..n-1 when it is
    empty); writes out (bool) at each ray's index."""
    n = dirs.shape[0]
    n_blocks = (n + RAY_BLOCK - 1) // RAY_BLOCK
    for b in prange(n_blocks):
        _any_block(nodes, links, tris, org, dirs, tmin, tmax, stack_size, order,
                   b * RAY_BLOCK, min(n, (b + 1) * RAY_BLOCK), out)
