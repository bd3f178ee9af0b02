"""Binned SAH BVH construction (Wald 2007), as one Numba kernel.

Reference: I. Wald, "On fast construction of SAH-based bounding volume hierarchies",
IEEE Symposium on Interactive Ray Tracing 2007. Node layout after pbrt-v4
``aggregates.cpp`` (``flattenBVH``): depth-first pre-order, the left child directly after
its parent, the right child's index stored in the parent.

The builder works top-down with an explicit task stack (no recursion, no Python loop over
triangles). Each task carries its node box and centroid box, which the parent's binning
already produced (union of the bins on each side), so every level touches each triangle
twice: once to bin it, once to partition it. Total work O(n log n).

Output arrays (the reference layout; traversal reads them directly)::

    node_box  (n_nodes, 6) float64   min x, min y, min z, max x, max y, max z
    node_meta (n_nodes, 2) int64     internal: (index of right child, 0)
                                     leaf:     (first triangle slot, triangle count > 0)
    order     (m,) int64             triangle slot -> input triangle index

The left child of internal node i is i + 1. ``Scene`` converts the boxes to float32
(rounded outward), giving the 32-byte node of tinybvh: 24 bytes of box + 8 bytes of meta
(the meta is stored as int32 there).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..config import BUILD_FASTMATH, CACHE, ERROR_MODEL


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _half_area(bx0, by0, bz0, bx1, by1, bz1):
    dx = bx1 - bx0
    dy = by1 - by0
    dz = bz1 - bz0
    if dx < 0.0 or dy < 0.0 or dz < 0.0:
        return 0.0
    return dx * dy + dy * dz + dz * dx


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def build_sah(tri_lo, tri_hi, cent, n_bins, c_trav, c_isect, max_leaf, max_leaf_forced):
    """Build a binned-SAH BVH over m triangle boxes.

    Parameters
    ----------
    tri_lo, tri_hi : (m, 3) float64
        Per-triangle bounding boxes.
    cent : (m, 3) float64
        Per-triangle centroids (the binning key).
    n_bins : int
        Bins per axis (Wald 2007 uses 16-32).
    c_trav, c_isect : float
        SAH costs of a traversal step and of a triangle test.
    max_leaf : int
        Largest leaf SAH may choose.
    max_leaf_forced : int
        Largest leaf made of triangles with identical centroids (unsplittable).

    Returns
    -------
    node_box : (n_nodes, 6) float64
    node_meta : (n_nodes, 2) int64
    order : (m,) int64
    max_depth : int
    """
    m = tri_lo.shape[0]
    order = np.arange(m)
    max_nodes = 2 * m - 1
    node_box = np.empty((max_nodes, 6))
    node_meta = np.zeros((max_nodes, 2), dtype=np.int64)

    # Task stack: range [s, e), parent whose right-child field to patch (-1 for a left
    # child, which lands at parent + 1 by construction), depth, node box, centroid box.
    # Only right children wait on the stack, at most one per level: depth <= m.
    cap = m + 1
    t_s = np.empty(cap, dtype=np.int64)
    t_e = np.empty(cap, dtype=np.int64)
    t_par = np.empty(cap, dtype=np.int64)
    t_dep = np.empty(cap, dtype=np.int64)
    t_box = np.empty((cap, 6))
    t_cbox = np.empty((cap, 6))

    # Root boxes.
    rb = np.empty(6)
    cb = np.empty(6)
    for a in range(3):
        rb[a] = np.inf
        rb[a + 3] = -np.inf
        cb[a] = np.inf
        cb[a + 3] = -np.inf
    for i in range(m):
        for a in range(3):
            rb[a] = min(rb[a], tri_lo[i, a])
            rb[a + 3] = max(rb[a + 3], tri_hi[i, a])
            cb[a] = min(cb[a], cent[i, a])
            cb[a + 3] = max(cb[a + 3], cent[i, a])
    t_s[0] = 0
    t_e[0] = m
    t_par[0] = -1
    t_dep[0] = 0
    t_box[0, :] = rb
    t_cbox[0, :] = cb
    sp = 1

    # Per-bin accumulators: count, triangle box, centroid box; per axis.
    b_cnt = np.zeros((3, n_bins), dtype=np.int64)
    b_box = np.empty((3, n_bins, 6))
    b_cbox = np.empty((3, n_bins, 6))
    # Sweep results: right-side area, count and boxes for a split after bin k.
    r_area = np.empty(n_bins)
    r_cnt = np.empty(n_bins, dtype=np.int64)
    acc = np.empty(6)
    cacc = np.empty(6)
    bin_of = np.empty(3, dtype=np.int64)
    scale = np.zeros(3)
    box = np.empty(6)
    cbox = np.empty(6)
    lbox = np.empty(6)
    rbox = np.empty(6)
    lcb = np.empty(6)
    rcb = np.empty(6)

    n_nodes = 0
    max_depth = 0
    while sp > 0:
        sp -= 1
        s = t_s[sp]
        e = t_e[sp]
        par = t_par[sp]
        dep = t_dep[sp]
        for c in range(6):
            box[c] = t_box[sp, c]
            cbox[c] = t_cbox[sp, c]

        node = n_nodes
        n_nodes += 1
        if par >= 0:
            node_meta[par, 0] = node
        node_box[node, :] = box
        if dep > max_depth:
            max_depth = dep
        count = e - s

        if count == 1:
            node_meta[node, 0] = s
            node_meta[node, 1] = 1
            continue

        # --- Wald 2007: bin centroids along each axis ---------------------------------
        # Small nodes get fewer bins: with ~n/2 nodes of a handful of triangles, clearing
        # and sweeping 3 x n_bins bins per node would dominate the build.
        nb = min(n_bins, max(2, count))
        any_extent = False
        for a in range(3):
            scale[a] = 0.0
            ext = cbox[a + 3] - cbox[a]
            if ext > 0.0:
                # (1 - 1e-9) keeps the maximum centroid inside the last bin.
                scale[a] = nb * (1.0 - 1e-9) / ext
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
                        b_cbox[a, k, c] = np.inf
                        b_cbox[a, k, c + 3] = -np.inf
            for j in range(s, e):
                i = order[j]
                for a in range(3):
                    if scale[a] > 0.0:
                        k = int((cent[i, a] - cbox[a]) * scale[a])
                        if k >= nb:
                            k = nb - 1
                        elif k < 0:
                            k = 0
                        bin_of[a] = k
                for a in range(3):
                    if scale[a] > 0.0:
                        k = bin_of[a]
                        b_cnt[a, k] += 1
                        for c in range(3):
                            lo = tri_lo[i, c]
                            hi = tri_hi[i, c]
                            if lo < b_box[a, k, c]:
                                b_box[a, k, c] = lo
                            if hi > b_box[a, k, c + 3]:
                                b_box[a, k, c + 3] = hi
                            ce = cent[i, c]
                            if ce < b_cbox[a, k, c]:
                                b_cbox[a, k, c] = ce
                            if ce > b_cbox[a, k, c + 3]:
                                b_cbox[a, k, c + 3] = ce
            # Sweep from the right, then from the left; cost of a split after bin k:
            # C_trav + C_isect * (A_L N_L + A_R N_R) / A_parent  (half areas suffice).
            parent_area = _half_area(box[0], box[1], box[2], box[3], box[4], box[5])
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
                    r_area[k] = _half_area(acc[0], acc[1], acc[2], acc[3], acc[4], acc[5])
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
                    l_area = _half_area(acc[0], acc[1], acc[2], acc[3], acc[4], acc[5])
                    cost = c_isect * (l_area * n_acc + r_area[k + 1] * n_r)
                    if cost < best_cost:
                        best_cost = cost
                        best_axis = a
                        best_k = k
            if parent_area > 0.0:
                best_cost = c_trav + best_cost / parent_area
            else:
                best_cost = c_trav + c_isect * count

        leaf_cost = c_isect * count
        if best_axis < 0:
            # Every centroid coincides: no positional split exists.
            if count <= max_leaf_forced:
                node_meta[node, 0] = s
                node_meta[node, 1] = count
                continue
            mid = s + count // 2
            for c in range(6):
                lbox[c] = box[c]
                rbox[c] = box[c]
                lcb[c] = cbox[c]
                rcb[c] = cbox[c]
        elif count <= max_leaf and leaf_cost <= best_cost:
            node_meta[node, 0] = s
            node_meta[node, 1] = count
            continue
        else:
            # Partition [s, e) in place: bins <= best_k go left.
            a = best_axis
            lo_j = s
            hi_j = e - 1
            while lo_j <= hi_j:
                i = order[lo_j]
                k = int((cent[i, a] - cbox[a]) * scale[a])
                if k >= nb:
                    k = nb - 1
                elif k < 0:
                    k = 0
                if k <= best_k:
                    lo_j += 1
                else:
                    order[lo_j] = order[hi_j]
                    order[hi_j] = i
                    hi_j -= 1
            mid = lo_j
            for c in range(3):
                lbox[c] = np.inf
                lbox[c + 3] = -np.inf
                rbox[c] = np.inf
                rbox[c + 3] = -np.inf
                lcb[c] = np.inf
                lcb[c + 3] = -np.inf
                rcb[c] = np.inf
                rcb[c + 3] = -np.inf
            for k in range(nb):
                if b_cnt[a, k] == 0:
                    continue
                if k <= best_k:
                    for c in range(3):
                        lbox[c] = min(lbox[c], b_box[a, k, c])
                        lbox[c + 3] = max(lbox[c + 3], b_box[a, k, c + 3])
                        lcb[c] = min(lcb[c], b_cbox[a, k, c])
                        lcb[c + 3] = max(lcb[c + 3], b_cbox[a, k, c + 3])
                else:
                    for c in range(3):
                        rbox[c] = min(rbox[c], b_box[a, k, c])
                        rbox[c + 3] = max(rbox[c + 3], b_box[a, k, c + 3])
                        rcb[c] = min(rcb[c], b_cbox[a, k, c])
                        rcb[c + 3] = max(rcb[c + 3], b_cbox[a, k, c + 3])

        # Push right first so the left child is popped next and lands at node + 1.
        t_s[sp] = mid
        t_e[sp] = e
        t_par[sp] = node
        t_dep[sp] = dep + 1
        t_box[sp, :] = rbox
        t_cbox[sp, :] = rcb
        sp += 1
        t_s[sp] = s
        t_e[sp] = mid
        t_par[sp] = -1
        t_dep[sp] = dep + 1
        t_box[sp, :] = lbox
        t_cbox[sp, :] = lcb
        sp += 1
        node_meta[node, 1] = 0

    return node_box[:n_nodes].copy(), node_meta[:n_nodes].copy(), order, max_depth


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def triangle_setup(verts, faces, area_rel, lo, hi, cent, good):
    """Per triangle: box, centroid, and whether it has non-zero area
    (|e1 x e2| > area_rel * longest edge^2). Vertices are in the local frame.
    """
    for i in prange(faces.shape[0]):
        a = faces[i, 0]
        b = faces[i, 1]
        c = faces[i, 2]
        for k in range(3):
            p = verts[a, k]
            q = verts[b, k]
            r = verts[c, k]
            lo[i, k] = min(p, min(q, r))
            hi[i, k] = max(p, max(q, r))
            cent[i, k] = (p + q + r) / 3.0
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


@njit(cache=CACHE, error_model=ERROR_MODEL)
def to_pair_layout(node_box, node_meta):
    """Convert the reference tree into the traversal layout: one record per internal
    node holding both children's boxes (Aila & Laine 2009, "Understanding the efficiency
    of ray traversal on GPUs"; tinybvh ``BVH_GPU``), so a visit reads one 64-byte record.

    Returns ``nodes`` (n_internal, 16) float32, laid out per record as::

        0:6    left child box  (min x, min y, min z, max x, max y, max z)
        6:12   right child box
        12, 13 left, right child: internal -> record index; leaf -> first triangle slot
        14, 15 left, right triangle count: 0 for an internal child, > 0 for a leaf

    Fields 12-15 are int32 stored in the float32 array's bits (read through an int32
    view of the same memory). Records are in depth-first order, the root first. A tree
    that is a single leaf gets one record whose right child is an empty box.
    """
    n = node_box.shape[0]
    rec = np.full(n, -1, dtype=np.int64)
    n_int = 0
    for i in range(n):
        if node_meta[i, 1] == 0:
            rec[i] = n_int
            n_int += 1
    if n_int == 0:
        n_int = 1
    box = np.empty((n_int, 12), dtype=np.float64)
    link = np.zeros((n_int, 4), dtype=np.int64)
    if n == 1 or node_meta[0, 1] > 0:
        for c in range(6):
            box[0, c] = node_box[0, c]
        for c in range(3):
            box[0, 6 + c] = np.inf
            box[0, 9 + c] = -np.inf
        link[0, 0] = node_meta[0, 0]
        link[0, 2] = node_meta[0, 1]
        link[0, 1] = 0
        link[0, 3] = 1  # an empty leaf behind an empty box: never entered
        return box, link
    for i in range(n):
        if node_meta[i, 1] != 0:
            continue
        r = rec[i]
        children = (i + 1, node_meta[i, 0])
        for side in range(2):
            ch = children[side]
            for c in range(6):
                box[r, 6 * side + c] = node_box[ch, c]
            if node_meta[ch, 1] > 0:
                link[r, side] = node_meta[ch, 0]
                link[r, 2 + side] = node_meta[ch, 1]
            else:
                link[r, side] = rec[ch]
                link[r, 2 + side] = 0
    return box, link


@njit(cache=CACHE, error_model=ERROR_MODEL)
def sah_cost(node_box, node_meta, c_trav, c_isect):
    """Expected SAH cost of a finished tree, normalised by the root's area.

    cost = sum_internal C_trav * A(n) / A(root) + sum_leaf C_isect * N(n) * A(n) / A(root)
    """
    root = _half_area(node_box[0, 0], node_box[0, 1], node_box[0, 2],
                      node_box[0, 3], node_box[0, 4], node_box[0, 5])
    if root <= 0.0:
        root = 1.0
    total = 0.0
    for i in range(node_box.shape[0]):
        a = _half_area(node_box[i, 0], node_box[i, 1], node_box[i, 2],
                       node_box[i, 3], node_box[i, 4], node_box[i, 5]) / root
        if node_meta[i, 1] > 0:
            total += c_isect * node_meta[i, 1] * a
        else:
            total += c_trav * a
    return total
