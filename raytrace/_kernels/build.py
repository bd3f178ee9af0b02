"""Binned SAH BVH construction (Wald 2007) in Numba, parallel over subtrees.

Reference: I. Wald, "On fast construction of SAH-based bounding volume hierarchies",
IEEE Symposium on Interactive Ray Tracing 2007 (binned SAH, bins over centroid bounds).
Parallelisation by independent subtrees after a serial top phase, as in Wald's paper
(section 4) and Embree's binned builders.

Steps:

1. ``triangle_setup``: per triangle a 36-byte primitive record (float32 box rounded
   outward, float32 centroid) and a zero-area flag, in parallel.
2. ``build_bvh``: a serial top phase splits the triangles until every open task holds at
   most ``stop`` triangles; those tasks are then built in parallel (``prange``), each
   into its own pre-allocated range of the node arrays. Each task carries its node box
   and centroid box (the union of the parent's bins on its side), so a level touches
   each primitive twice: once to bin it, once to partition it. Primitive records are
   partitioned physically (rows swapped with their triangle index), so every pass
   reads memory sequentially. Work O(n log n); no Python loop over triangles.
3. ``to_quad_layout``: collapses the binary tree into 4-wide records (the traversal
   layout, see ``traverse.py``) and collects the tree statistics.

Build arrays (explicit child pointers; node order is irrelevant, only the walk matters)::

    node_box  (2m - 1, 6) float32   min x, min y, min z, max x, max y, max z
    node_meta (2m - 1, 4) int32     left child, right child, first slot, count
                                    (count 0: internal; count > 0: leaf [first, first+count))

The boxes are conservative: primitive boxes are rounded outward to float32, and unions
(min/max) of float32 values are exact.

Sizing: the top phase and the subtrees together use at most 2m - 1 nodes: with P open
tasks of c_k triangles, the top tree has P - 1 internal nodes and P task roots, and a
subtree needs at most 2 c_k - 2 nodes besides its root: (P - 1) + P + sum(2 c_k - 2)
= 2m - 1.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..config import BUILD_FASTMATH, CACHE, ERROR_MODEL

#: Fields of a primitive record.
_LO, _HI, _CE = 0, 3, 6


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def triangle_setup(verts, faces, area_rel, prim, good):
    """Primitive records and zero-area flags.

    verts (n, 3) float64 local frame; faces (m, 3) int64. Writes prim (m, 9) float32:
    box min (0:3) rounded down, box max (3:6) rounded up, centroid (6:9); and good (m,)
    bool: |e1 x e2| > area_rel * (longest edge)^2.
    """
    for i in prange(faces.shape[0]):
        a = faces[i, 0]
        b = faces[i, 1]
        c = faces[i, 2]
        for k in range(3):
            p = verts[a, k]
            q = verts[b, k]
            r = verts[c, k]
            lo = min(p, min(q, r))
            hi = max(p, max(q, r))
            lo32 = np.float32(lo)
            if lo32 > lo:
                lo32 = np.nextafter(lo32, np.float32(-np.inf))
            hi32 = np.float32(hi)
            if hi32 < hi:
                hi32 = np.nextafter(hi32, np.float32(np.inf))
            prim[i, _LO + k] = lo32
            prim[i, _HI + k] = hi32
            prim[i, _CE + k] = (p + q + r) / 3.0
        e1x = verts[b, 0] - verts[a, 0]
        e1y = verts[b, 1] - verts[a, 1]
        e1z = verts[b, 2] - verts[a, 2]
        e2x = verts[c, 0] - verts[a, 0]
        e2y = verts[c, 1] - verts[a, 1]
        e2z = verts[c, 2] - verts[a, 2]
        cx = e1y * e2z - e1z * e2y
        cy = e1z * e2x - e1x * e2z
        cz = e1x * e2y - e1y * e2x
        l1 = e1x * e1x + e1y * e1y + e1z * e1z
        l2 = e2x * e2x + e2y * e2y + e2z * e2z
        l3 = (e2x - e1x) ** 2 + (e2y - e1y) ** 2 + (e2z - e1z) ** 2
        longest = max(l1, max(l2, l3))
        good[i] = np.sqrt(cx * cx + cy * cy + cz * cz) > area_rel * longest


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def slot_triangles(verts, faces, order, out):
    """Triangle records in leaf order: out[j] = v0, e1 = v1 - v0, e2 = v2 - v0 of face
    order[j] (float64, local frame), the layout the traversal reads."""
    for j in prange(order.shape[0]):
        i = order[j]
        a = faces[i, 0]
        b = faces[i, 1]
        c = faces[i, 2]
        for k in range(3):
            p = verts[a, k]
            out[j, k] = p
            out[j, 3 + k] = verts[b, k] - p
            out[j, 6 + k] = verts[c, k] - p


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
def _half_area(b):
    dx = b[3] - b[0]
    dy = b[4] - b[1]
    dz = b[5] - b[2]
    if dx < 0.0 or dy < 0.0 or dz < 0.0:
        return 0.0
    return dx * dy + dy * dz + dz * dx


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _bounds(prim, s, e, box, cbox):
    for c in range(3):
        box[c] = np.inf
        box[c + 3] = -np.inf
        cbox[c] = np.inf
        cbox[c + 3] = -np.inf
    for j in range(s, e):
        for c in range(3):
            box[c] = min(box[c], prim[j, _LO + c])
            box[c + 3] = max(box[c + 3], prim[j, _HI + c])
            cbox[c] = min(cbox[c], prim[j, _CE + c])
            cbox[c + 3] = max(cbox[c + 3], prim[j, _CE + c])


#: Nodes of at least this many triangles are binned in parallel chunks (top phase only).
_PAR_BIN_MIN = 65_536
_PAR_BIN_CHUNKS = 16


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, parallel=True)
def _bin_parallel(prim, s, e, cbox, scale, nb, b_cnt, b_box):
    """Bin rows [s, e) like the serial loop in ``_split``, in parallel chunks with local
    bins, then reduce. Counts, minima and maxima do not depend on the order, so the
    bins (and the tree) are identical to the serial result."""
    n_ch = _PAR_BIN_CHUNKS
    loc_cnt = np.zeros((n_ch, 3, nb), dtype=np.int64)
    loc_box = np.empty((n_ch, 3, nb, 12))
    step = (e - s + n_ch - 1) // n_ch
    for ch in prange(n_ch):
        for a in range(3):
            for k in range(nb):
                for c in range(3):
                    loc_box[ch, a, k, c] = np.inf
                    loc_box[ch, a, k, c + 3] = -np.inf
                    loc_box[ch, a, k, c + 6] = np.inf
                    loc_box[ch, a, k, c + 9] = -np.inf
        for j in range(s + ch * step, min(e, s + (ch + 1) * step)):
            for a in range(3):
                if scale[a] > 0.0:
                    k = int((prim[j, _CE + a] - cbox[a]) * scale[a])
                    k = min(nb - 1, max(0, k))
                    loc_cnt[ch, a, k] += 1
                    for c in range(3):
                        loc_box[ch, a, k, c] = min(loc_box[ch, a, k, c], prim[j, _LO + c])
                        loc_box[ch, a, k, c + 3] = max(loc_box[ch, a, k, c + 3],
                                                       prim[j, _HI + c])
                        loc_box[ch, a, k, c + 6] = min(loc_box[ch, a, k, c + 6],
                                                       prim[j, _CE + c])
                        loc_box[ch, a, k, c + 9] = max(loc_box[ch, a, k, c + 9],
                                                       prim[j, _CE + c])
    for ch in range(n_ch):
        for a in range(3):
            for k in range(nb):
                b_cnt[a, k] += loc_cnt[ch, a, k]
                for c in range(3):
                    b_box[a, k, c] = min(b_box[a, k, c], loc_box[ch, a, k, c])
                    b_box[a, k, c + 3] = max(b_box[a, k, c + 3], loc_box[ch, a, k, c + 3])
                    b_box[a, k, c + 6] = min(b_box[a, k, c + 6], loc_box[ch, a, k, c + 6])
                    b_box[a, k, c + 9] = max(b_box[a, k, c + 9], loc_box[ch, a, k, c + 9])


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _split(prim, idx, s, e, box, cbox, n_bins, all_axes, c_trav, c_isect, max_leaf,
           max_leaf_forced, par, b_cnt, b_box, acc, r_area, r_cnt, scale, out):
    """Decide leaf or split for [s, e) (Wald 2007 binned SAH); on a split, partition the
    rows in place and write the children's boxes into out (4, 6): left box, right box,
    left centroid box, right centroid box. Returns the split position, or -1 for a leaf.
    """
    count = e - s
    if count == 1:
        return -1
    # Small nodes get fewer bins: with ~n/2 nodes of a handful of triangles, clearing
    # and sweeping 3 x n_bins bins per node would dominate the build.
    nb = min(n_bins, max(2, count))
    any_extent = False
    longest = 0
    for a in range(3):
        if cbox[a + 3] - cbox[a] > cbox[longest + 3] - cbox[longest]:
            longest = a
    for a in range(3):
        scale[a] = 0.0
        ext = cbox[a + 3] - cbox[a]
        if ext > 0.0 and (all_axes or a == longest):
            # (1 - 1e-6) keeps the largest centroid inside the last bin.
            scale[a] = nb * (1.0 - 1e-6) / ext
            any_extent = True
    best_cost = np.inf
    best_axis = -1
    best_k = -1
    if any_extent:
        for a in range(3):
            for k in range(nb):
                b_cnt[a, k] = 0
                for c in range(3):
                    b_box[a, k, c] = np.inf
                    b_box[a, k, c + 3] = -np.inf
                    b_box[a, k, c + 6] = np.inf
                    b_box[a, k, c + 9] = -np.inf
        if par and e - s >= _PAR_BIN_MIN:
            _bin_parallel(prim, s, e, cbox, scale, nb, b_cnt, b_box)
        else:
            for j in range(s, e):
                for a in range(3):
                    if scale[a] > 0.0:
                        k = int((prim[j, _CE + a] - cbox[a]) * scale[a])
                        k = min(nb - 1, max(0, k))
                        b_cnt[a, k] += 1
                        for c in range(3):
                            b_box[a, k, c] = min(b_box[a, k, c], prim[j, _LO + c])
                            b_box[a, k, c + 3] = max(b_box[a, k, c + 3], prim[j, _HI + c])
                            b_box[a, k, c + 6] = min(b_box[a, k, c + 6], prim[j, _CE + c])
                            b_box[a, k, c + 9] = max(b_box[a, k, c + 9], prim[j, _CE + c])
        # Sweep from the right, then from the left; cost of a split after bin k:
        # C_trav + C_isect * (A_L N_L + A_R N_R) / A_parent  (half areas suffice).
        for a in range(3):
            if scale[a] == 0.0:
                continue
            for c in range(3):
                acc[c] = np.inf
                acc[c + 3] = -np.inf
            n_acc = 0
            for k in range(nb - 1, 0, -1):
                n_acc += b_cnt[a, k]
                for c in range(3):
                    acc[c] = min(acc[c], b_box[a, k, c])
                    acc[c + 3] = max(acc[c + 3], b_box[a, k, c + 3])
                r_cnt[k] = n_acc
                r_area[k] = _half_area(acc)
            for c in range(3):
                acc[c] = np.inf
                acc[c + 3] = -np.inf
            n_acc = 0
            for k in range(nb - 1):
                n_acc += b_cnt[a, k]
                for c in range(3):
                    acc[c] = min(acc[c], b_box[a, k, c])
                    acc[c + 3] = max(acc[c + 3], b_box[a, k, c + 3])
                n_r = r_cnt[k + 1]
                if n_acc == 0 or n_r == 0:
                    continue
                cost = _half_area(acc) * n_acc + r_area[k + 1] * n_r
                if cost < best_cost:
                    best_cost = cost
                    best_axis = a
                    best_k = k
        parent_area = _half_area(box)
        if parent_area > 0.0:
            best_cost = c_trav + c_isect * best_cost / parent_area
        else:
            best_cost = c_trav + c_isect * count

    if best_axis < 0:
        # Every centroid coincides: no positional split exists.
        if count <= max_leaf_forced:
            return -1
        mid = s + count // 2
        for c in range(6):
            out[0, c] = box[c]
            out[1, c] = box[c]
            out[2, c] = cbox[c]
            out[3, c] = cbox[c]
        return mid
    if count <= max_leaf and c_isect * count <= best_cost:
        return -1

    # Partition rows [s, e): bins <= best_k go left.
    a = best_axis
    lo_j = s
    hi_j = e - 1
    while lo_j <= hi_j:
        k = int((prim[lo_j, _CE + a] - cbox[a]) * scale[a])
        k = min(nb - 1, max(0, k))
        if k <= best_k:
            lo_j += 1
        else:
            for c in range(9):
                tmp = prim[lo_j, c]
                prim[lo_j, c] = prim[hi_j, c]
                prim[hi_j, c] = tmp
            ti = idx[lo_j]
            idx[lo_j] = idx[hi_j]
            idx[hi_j] = ti
            hi_j -= 1
    for q in range(4):
        for c in range(3):
            out[q, c] = np.inf
            out[q, c + 3] = -np.inf
    for k in range(nb):
        if b_cnt[a, k] == 0:
            continue
        side = 0 if k <= best_k else 1
        for c in range(3):
            out[side, c] = min(out[side, c], b_box[a, k, c])
            out[side, c + 3] = max(out[side, c + 3], b_box[a, k, c + 3])
            out[2 + side, c] = min(out[2 + side, c], b_box[a, k, c + 6])
            out[2 + side, c + 3] = max(out[2 + side, c + 3], b_box[a, k, c + 9])
    return lo_j


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _grow(prim, idx, s0, e0, root, next_free, box0, cbox0, n_bins, all_axes, c_trav,
          c_isect, max_leaf, max_leaf_forced, stop, node_box, node_meta, pend):
    """Build the tree over rows [s0, e0) with its root at node ``root`` and further
    nodes allocated from ``next_free`` on. Tasks of at most ``stop`` triangles are not
    expanded but appended to ``pend`` (rows: node, s, e) when stop > 0.
    Returns (next_free, number of pending tasks)."""
    cap = e0 - s0 + 1
    t_s = np.empty(cap, dtype=np.int64)
    t_e = np.empty(cap, dtype=np.int64)
    t_node = np.empty(cap, dtype=np.int64)
    t_box = np.empty((cap, 12))
    b_cnt = np.zeros((3, n_bins), dtype=np.int64)
    b_box = np.empty((3, n_bins, 12))
    acc = np.empty(6)
    r_area = np.empty(n_bins)
    r_cnt = np.empty(n_bins, dtype=np.int64)
    scale = np.zeros(3)
    out = np.empty((4, 6))
    box = np.empty(6)
    cbox = np.empty(6)
    n_pend = 0

    t_s[0] = s0
    t_e[0] = e0
    t_node[0] = root
    t_box[0, :6] = box0
    t_box[0, 6:] = cbox0
    sp = 1
    while sp > 0:
        sp -= 1
        s = t_s[sp]
        e = t_e[sp]
        node = t_node[sp]
        for c in range(6):
            box[c] = t_box[sp, c]
            cbox[c] = t_box[sp, 6 + c]
            node_box[node, c] = box[c]
        if stop > 0 and e - s <= stop:
            pend[n_pend, 0] = node
            pend[n_pend, 1] = s
            pend[n_pend, 2] = e
            n_pend += 1
            continue
        mid = _split(prim, idx, s, e, box, cbox, n_bins, all_axes, c_trav, c_isect, max_leaf,
                     max_leaf_forced, stop > 0, b_cnt, b_box, acc, r_area, r_cnt, scale,
                     out)
        if mid < 0:
            node_meta[node, 0] = -1
            node_meta[node, 1] = -1
            node_meta[node, 2] = s
            node_meta[node, 3] = e - s
            continue
        left = next_free
        right = next_free + 1
        next_free += 2
        node_meta[node, 0] = left
        node_meta[node, 1] = right
        node_meta[node, 2] = s
        node_meta[node, 3] = 0
        # Push right first so the left subtree is built (and allocated) first.
        t_s[sp] = mid
        t_e[sp] = e
        t_node[sp] = right
        t_box[sp, :6] = out[1]
        t_box[sp, 6:] = out[3]
        sp += 1
        t_s[sp] = s
        t_e[sp] = mid
        t_node[sp] = left
        t_box[sp, :6] = out[0]
        t_box[sp, 6:] = out[2]
        sp += 1
    return next_free, n_pend


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def _grow_pending(prim, idx, pend, n_pend, bases, n_bins, all_axes, c_trav, c_isect,
                  max_leaf, max_leaf_forced, node_box, node_meta):
    dummy = np.zeros((1, 3), dtype=np.int64)
    for q in prange(n_pend):
        node = pend[q, 0]
        s = pend[q, 1]
        e = pend[q, 2]
        box = np.empty(6)
        cbox = np.empty(6)
        _bounds(prim, s, e, box, cbox)
        _grow(prim, idx, s, e, node, bases[q], box, cbox, n_bins, all_axes, c_trav, c_isect,
              max_leaf, max_leaf_forced, 0, node_box, node_meta, dummy)


@njit(cache=CACHE, error_model=ERROR_MODEL)
def build_top(prim, idx, n_bins, all_axes, c_trav, c_isect, max_leaf, max_leaf_forced, stop):
    """Serial top phase over all rows. Returns node arrays (2m - 1 rows), the pending
    tasks (node, s, e) and, per pending task, the first free node of its range."""
    m = prim.shape[0]
    n_nodes = 2 * m - 1
    node_box = np.empty((n_nodes, 6), dtype=np.float32)
    node_meta = np.zeros((n_nodes, 4), dtype=np.int32)
    box = np.empty(6)
    cbox = np.empty(6)
    _bounds(prim, 0, m, box, cbox)
    pend = np.empty((m, 3), dtype=np.int64)
    next_free, n_pend = _grow(prim, idx, 0, m, 0, 1, box, cbox, n_bins, all_axes, c_trav,
                              c_isect, max_leaf, max_leaf_forced, stop, node_box, node_meta,
                              pend)
    bases = np.empty(n_pend, dtype=np.int64)
    for q in range(n_pend):
        bases[q] = next_free
        next_free += 2 * (pend[q, 2] - pend[q, 1]) - 2
    return node_box, node_meta, pend[:n_pend].copy(), bases


def build_bvh(prim, idx, n_bins, all_axes, c_trav, c_isect, max_leaf, max_leaf_forced, stop):
    """Binned SAH BVH over the primitive rows (permuted in place together with idx).

    ``all_axes``: bin along all three axes (Wald 2007) or only along the axis of largest
    centroid extent (3x less binning work, the usual fast-builder shortcut).

    Returns node_box (2m - 1, 6) float32 and node_meta (2m - 1, 4) int32 with the root
    at 0 (rows not reached from the root are unused).
    """
    node_box, node_meta, pend, bases = build_top(prim, idx, n_bins, all_axes, c_trav,
                                                 c_isect, max_leaf, max_leaf_forced, stop)
    if len(pend):
        _grow_pending(prim, idx, pend, len(pend), bases, n_bins, all_axes, c_trav, c_isect,
                      max_leaf, max_leaf_forced, node_box, node_meta)
    return node_box, node_meta


@njit(cache=CACHE, error_model=ERROR_MODEL)
def to_quad_layout(node_box, node_meta, c_trav, c_isect):
    """Collapse the binary tree into 4-wide records and collect the tree statistics.

    Wide-BVH collapse by surface area as in Embree's BVH4 and Wald, Benthin & Boulos
    2008 ("Getting rid of packets"): a record starts with the two children of a binary
    node and repeatedly opens its largest-area internal child until it has four.
    The root is record 0; the internal children of a record get consecutive record
    indices when it is filled (siblings sit side by side in memory).

    Returns
    -------
    box : (n4, 24) float32
        Child boxes, structure of arrays: min x[4], min y[4], min z[4], max x[4],
        max y[4], max z[4]. Unused lanes hold an empty box (min +inf, max -inf).
    link : (n4, 8) int64
        child[4] (record index for an internal child, first triangle slot for a leaf),
        count[4] (0: internal child or unused lane; > 0: leaf).
    stats : tuple
        binary nodes, leaves, binary max depth, triangles in leaves, SAH cost (Wald 2007:
        sum over internal nodes of C_trav A / A_root plus over leaves of
        C_isect N A / A_root), 4-wide max depth.
    """
    n = node_box.shape[0]
    root_area = _half_area(node_box[0])
    if root_area <= 0.0:
        root_area = 1.0
    # Binary statistics.
    stack = np.empty(n + 1, dtype=np.int64)
    depth = np.empty(n + 1, dtype=np.int64)
    n_nodes = 0
    n_leaves = 0
    in_leaves = 0
    max_depth = 0
    cost = 0.0
    stack[0] = 0
    depth[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        i = stack[sp]
        d = depth[sp]
        n_nodes += 1
        max_depth = max(max_depth, d)
        area = _half_area(node_box[i]) / root_area
        if node_meta[i, 3] > 0:
            n_leaves += 1
            in_leaves += node_meta[i, 3]
            cost += c_isect * node_meta[i, 3] * area
        else:
            cost += c_trav * area
            stack[sp] = node_meta[i, 1]
            depth[sp] = d + 1
            stack[sp + 1] = node_meta[i, 0]
            depth[sp + 1] = d + 1
            sp += 2

    n_rec_max = max(1, n // 2 + 1)
    box = np.empty((n_rec_max, 24), dtype=np.float32)
    link = np.zeros((n_rec_max, 8), dtype=np.int64)
    ch = np.empty(4, dtype=np.int64)
    # Work list: (binary node, record index). Pre-order: records are numbered when
    # their parent record is filled, children pushed in reverse.
    work = np.empty(n + 1, dtype=np.int64)
    wrec = np.empty(n + 1, dtype=np.int64)
    wdep = np.empty(n + 1, dtype=np.int64)
    n_rec = 1
    max_depth4 = 0
    work[0] = 0
    wrec[0] = 0
    wdep[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        i = work[sp]
        r = wrec[sp]
        d4 = wdep[sp]
        max_depth4 = max(max_depth4, d4)
        if node_meta[i, 3] > 0:  # the root itself is a leaf
            ch[0] = i
            k = 1
        else:
            ch[0] = node_meta[i, 0]
            ch[1] = node_meta[i, 1]
            k = 2
            while k < 4:
                best = -1
                best_a = -1.0
                for q in range(k):
                    if node_meta[ch[q], 3] == 0:
                        a = _half_area(node_box[ch[q]])
                        if a > best_a:
                            best_a = a
                            best = q
                if best < 0:
                    break
                opened = ch[best]
                ch[best] = node_meta[opened, 0]
                ch[k] = node_meta[opened, 1]
                k += 1
        for lane in range(4):
            if lane >= k:
                for c in range(3):
                    box[r, 4 * c + lane] = np.inf
                    box[r, 12 + 4 * c + lane] = -np.inf
                link[r, lane] = 0
                link[r, 4 + lane] = 0
                continue
            c_node = ch[lane]
            for c in range(3):
                box[r, 4 * c + lane] = node_box[c_node, c]
                box[r, 12 + 4 * c + lane] = node_box[c_node, 3 + c]
            if node_meta[c_node, 3] > 0:
                link[r, lane] = node_meta[c_node, 2]
                link[r, 4 + lane] = node_meta[c_node, 3]
            else:
                link[r, lane] = n_rec
                link[r, 4 + lane] = 0
                n_rec += 1
        # Push internal children in reverse lane order so that the first is next.
        for lane in range(k - 1, -1, -1):
            c_node = ch[lane]
            if node_meta[c_node, 3] == 0:
                work[sp] = c_node
                wrec[sp] = link[r, lane]
                wdep[sp] = d4 + 1
                sp += 1
    return box[:n_rec].copy(), link[:n_rec].copy(), (n_nodes, n_leaves, max_depth,
                                                      in_leaves, cost, max_depth4)
