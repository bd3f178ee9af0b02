"""Stack-based BVH traversal: closest hit and any hit, ``prange`` over ray blocks.

Layout read here (made by ``build.to_pair_layout``; boxes float32, rounded outward)::

    nodes (n_int, 16) float32  per internal node: left box (0:6), right box (6:12)
    links (n_int, 16) int32    the same memory seen as int32: 12, 13 = child (record index
                               or first triangle slot), 14, 15 = triangle count (0: internal)
    verts (n_v, 3) float64     vertices in the scene's local frame
    tri   (m, 3) int32         vertex indices per triangle slot (leaf order)
    ids   (m,) int32           slot -> input triangle index (for the tie-break)

Traversal (Aila & Laine 2009 record layout; nearest child first as in pbrt-v4): a visit
reads one 64-byte record and tests both child boxes; leaf children are intersected at
once (nearer first, which tightens t before the farther box is judged), of the internal
children the nearer is visited next and the farther pushed with its entry distance; a
popped record whose entry distance exceeds the current closest hit is skipped.

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
from .intersect import moller_trumbore, slab


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def trace_closest(nodes, links, verts, tri, ids, ox, oy, oz, dx, dy, dz, t0, t1, prev,
                  st_node, st_dist):
    """Closest hit of one ray o + t d, t in [t0, t1], through the BVH.

    ``prev`` (a slot, or -1) is tested first to tighten t1 (warm start). ``st_node`` and
    ``st_dist`` are the caller's stack buffers (depth + 2 entries). Returns (t, input
    index, slot, u, v); slot -1 and t = t1 on a miss.
    """
    ix = 1.0 / dx
    iy = 1.0 / dy
    iz = 1.0 / dz
    best_t = t1
    best_id = -1
    best_slot = -1
    best_u = 0.0
    best_v = 0.0
    if prev >= 0:
        t, u, v = moller_trumbore(verts, tri, prev, ox, oy, oz, dx, dy, dz)
        if t >= t0 and t <= best_t:
            best_t = t
            best_id = ids[prev]
            best_slot = prev
            best_u = u
            best_v = v
    sp = 0
    node = 0
    while node >= 0:
        dl = slab(nodes, node, 0, ox, oy, oz, ix, iy, iz, t0, best_t)
        dr = slab(nodes, node, 6, ox, oy, oz, ix, iy, iz, t0, best_t)
        if dr < dl:
            first_side = 1
            d_first = dr
            d_second = dl
        else:
            first_side = 0
            d_first = dl
            d_second = dr
        nxt = -1
        nxt_d = np.inf
        for step in range(2):
            side = first_side if step == 0 else 1 - first_side
            dist = d_first if step == 0 else d_second
            # Missed (inf, also while best_t is still inf) or now beyond the closest hit
            # found in the nearer child.
            if dist == np.inf or dist > best_t:
                continue
            child = links[node, 12 + side]
            cnt = links[node, 14 + side]
            if cnt > 0:
                for k in range(child, child + cnt):
                    t, u, v = moller_trumbore(verts, tri, k, ox, oy, oz, dx, dy, dz)
                    if t >= t0 and t <= best_t:
                        kid = ids[k]
                        if t < best_t or best_id < 0 or kid < best_id:
                            best_t = t
                            best_id = kid
                            best_slot = k
                            best_u = u
                            best_v = v
            elif nxt < 0:
                nxt = child
                nxt_d = dist
            else:
                st_node[sp] = child
                st_dist[sp] = dist
                sp += 1
        node = nxt
        if node >= 0 and nxt_d > best_t:
            node = -1
        # Pop the next record still worth visiting.
        while node < 0 and sp > 0:
            sp -= 1
            if st_dist[sp] <= best_t:
                node = st_node[sp]
    return best_t, best_id, best_slot, best_u, best_v


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def closest_hit(nodes, links, verts, tri, ids, org, dirs, tmin, tmax, stack_size,
                out_t, out_slot, out_u, out_v):
    """Closest hit for n rays.

    org : (n_o, 3) float64, n_o in {1, n}; dirs : (n, 3) float64 unit vectors;
    tmin, tmax : (n_t,) float64, n_t in {1, n}. Writes out_t (inf on miss), out_slot
    (-1 on miss), out_u, out_v (0 on miss).
    """
    n = dirs.shape[0]
    n_blocks = (n + RAY_BLOCK - 1) // RAY_BLOCK
    one_org = org.shape[0] == 1
    one_t = tmin.shape[0] == 1
    for b in prange(n_blocks):
        st_node = np.empty(stack_size, dtype=np.int64)
        st_dist = np.empty(stack_size)
        prev = -1
        for r in range(b * RAY_BLOCK, min(n, (b + 1) * RAY_BLOCK)):
            ro = 0 if one_org else r
            rt = 0 if one_t else r
            bt, bid, bslot, bu, bv = trace_closest(
                nodes, links, verts, tri, ids, org[ro, 0], org[ro, 1], org[ro, 2],
                dirs[r, 0], dirs[r, 1], dirs[r, 2], tmin[rt], tmax[rt], prev,
                st_node, st_dist)
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
def any_hit(nodes, links, verts, tri, org, dirs, tmin, tmax, stack_size, out):
    """Any hit within [tmin, tmax] for n rays; writes out (bool). Early exit."""
    n = dirs.shape[0]
    n_blocks = (n + RAY_BLOCK - 1) // RAY_BLOCK
    one_org = org.shape[0] == 1
    one_t = tmin.shape[0] == 1
    for b in prange(n_blocks):
        st_node = np.empty(stack_size, dtype=np.int64)
        prev = -1
        for r in range(b * RAY_BLOCK, min(n, (b + 1) * RAY_BLOCK)):
            ro = 0 if one_org else r
            rt = 0 if one_t else r
            ox = org[ro, 0]
            oy = org[ro, 1]
            oz = org[ro, 2]
            dx = dirs[r, 0]
            dy = dirs[r, 1]
            dz = dirs[r, 2]
            ix = 1.0 / dx
            iy = 1.0 / dy
            iz = 1.0 / dz
            t0 = tmin[rt]
            t1 = tmax[rt]
            found = False
            if prev >= 0:
                t, u, v = moller_trumbore(verts, tri, prev, ox, oy, oz, dx, dy, dz)
                found = t >= t0 and t <= t1
            sp = 0
            node = -1 if found else 0
            while node >= 0:
                dl = slab(nodes, node, 0, ox, oy, oz, ix, iy, iz, t0, t1)
                dr = slab(nodes, node, 6, ox, oy, oz, ix, iy, iz, t0, t1)
                first_side = 1 if dr < dl else 0
                nxt = -1
                for step in range(2):
                    side = first_side if step == 0 else 1 - first_side
                    dist = dl if side == 0 else dr
                    if dist == np.inf:
                        continue
                    child = links[node, 12 + side]
                    cnt = links[node, 14 + side]
                    if cnt > 0:
                        for k in range(child, child + cnt):
                            t, u, v = moller_trumbore(verts, tri, k, ox, oy, oz, dx, dy, dz)
                            if t >= t0 and t <= t1:
                                found = True
                                prev = k
                                break
                        if found:
                            break
                    elif nxt < 0:
                        nxt = child
                    else:
                        st_node[sp] = child
                        sp += 1
                if found:
                    break
                node = nxt
                if node < 0 and sp > 0:
                    sp -= 1
                    node = st_node[sp]
            out[r] = found
