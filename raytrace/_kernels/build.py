"""Binned SAH BVH construction (Wald 2007) in Numba, parallel over subtrees.

Reference: I. Wald, "On fast construction of SAH-based bounding volume hierarchies",
IEEE Symposium on Interactive Ray Tracing 2007 (binned SAH, bins over centroid bounds).
Parallelisation by independent subtrees after a serial top phase, as in Wald's paper
(section 4) and Embree's binned builders.

Steps:

1. ``triangle_setup``: per triangle a 36-byte primitive record (float32 box rounded
   outward, float32 centroid) and a zero-area flag, in parallel.
2. ``build_bvh``: a top phase, serial over nodes, splits the triangles until every open
   task holds at most ``stop`` triangles; those tasks are then built in parallel
   (``prange``), each into its own pre-allocated range of the node arrays. Each task
   carries its node box (the union of the parent's bins on its side) and centroid box
   (gathered while partitioning), so a level touches each primitive twice: once to bin
   it, once to partition it. Primitive records are partitioned physically (rows moved
   with their triangle index), so every pass reads memory sequentially. Top-phase nodes
   are binned and partitioned in parallel chunks: a stable partition from one row
   buffer into a second (ping-pong; a task's rows are copied back once, when it starts
   its subtree). Below, partitions are in place (Hoare-style swaps). The tree does not
   depend on the thread count (fixed chunks; counts, min and max are order-free).
   Work O(n log n); no Python loop over triangles.
3. ``collapse.to_wide_layout`` (its own module): collapses the binary tree into 8-wide
   records (the traversal layout, see ``traverse.py``) and collects the tree statistics.

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
def half_area(b):
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


#: Top-phase nodes of at least this many triangles are binned and partitioned in
#: parallel chunks. DECISION: 4096 (= config.BUILD_TASK_MIN, so every top-phase node on
#: the benchmark tunnel): at 65,536 the nodes of 12k-65k triangles left a serial bin and
#: partition over all rows on each of the last top levels (810k triangles, 2 threads:
#: top phase 0.22 -> 0.14 s with the parallel partition, ping-pong buffers and this).
_PAR_BIN_MIN = 4096
#: Chunks of a parallel bin/partition: a fixed count, so results never depend on the
#: thread count.
_PAR_BIN_CHUNKS = 16


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
def _bin_of(x, lo, scale, nb):
    """Bin of centroid coordinate x (one formula for binning and partitioning, so a
    row always goes to the side its bin was counted on)."""
    k = int((x - lo) * scale)
    return min(nb - 1, max(0, k))


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, parallel=True)
def _bin_parallel(prim, s, e, cbox, scale, nb, b_cnt, b_box, loc_cnt):
    """Bin rows [s, e) like the serial loop in ``_split``, in parallel chunks with local
    bins, then reduce. Counts, minima and maxima do not depend on the order, so the
    bins (and the tree) are identical to the serial result. The per-chunk counts stay
    in loc_cnt (_PAR_BIN_CHUNKS, 3, >= nb) for ``_partition_parallel``."""
    n_ch = _PAR_BIN_CHUNKS
    loc_box = np.empty((n_ch, 3, nb, 6))
    step = (e - s + n_ch - 1) // n_ch
    for ch in prange(n_ch):
        for a in range(3):
            for k in range(nb):
                loc_cnt[ch, a, k] = 0
                for c in range(3):
                    loc_box[ch, a, k, c] = np.inf
                    loc_box[ch, a, k, c + 3] = -np.inf
        for j in range(s + ch * step, min(e, s + (ch + 1) * step)):
            for a in range(3):
                if scale[a] > 0.0:
                    k = _bin_of(prim[j, _CE + a], cbox[a], scale[a], nb)
                    loc_cnt[ch, a, k] += 1
                    for c in range(3):
                        loc_box[ch, a, k, c] = min(loc_box[ch, a, k, c], prim[j, _LO + c])
                        loc_box[ch, a, k, c + 3] = max(loc_box[ch, a, k, c + 3],
                                                       prim[j, _HI + c])
    for ch in range(n_ch):
        for a in range(3):
            for k in range(nb):
                b_cnt[a, k] += loc_cnt[ch, a, k]
                for c in range(3):
                    b_box[a, k, c] = min(b_box[a, k, c], loc_box[ch, a, k, c])
                    b_box[a, k, c + 3] = max(b_box[a, k, c + 3], loc_box[ch, a, k, c + 3])


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _scatter_chunk(prim, idx, j0, j1, a, lo, scale, nb, best_k, li, ri, tmp_prim, tmp_idx,
                   cb, ch):
    """Rows [j0, j1) to tmp rows li.. (left) and ri.. (right), in order; the centroid
    boxes of both sides into cb[ch] (2, 6)."""
    for q in range(2):
        for c in range(3):
            cb[ch, q, c] = np.inf
            cb[ch, q, c + 3] = -np.inf
    for j in range(j0, j1):
        if _bin_of(prim[j, _CE + a], lo, scale, nb) <= best_k:
            q = 0
            dst = li
            li += 1
        else:
            q = 1
            dst = ri
            ri += 1
        for c in range(9):
            tmp_prim[dst, c] = prim[j, c]
        tmp_idx[dst] = idx[j]
        for c in range(3):
            cb[ch, q, c] = min(cb[ch, q, c], prim[j, _CE + c])
            cb[ch, q, c + 3] = max(cb[ch, q, c + 3], prim[j, _CE + c])


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, parallel=True)
def _scatter_parallel(prim, idx, s, e, step, a, lo, scale, nb, best_k, l_ofs, r_ofs,
                      tmp_prim, tmp_idx, loc_cb):
    """``_scatter_chunk`` over the chunks of rows [s, e), in parallel."""
    for g in prange(l_ofs.shape[0]):
        _scatter_chunk(prim, idx, s + g * step, min(e, s + (g + 1) * step), a, lo, scale,
                       nb, best_k, l_ofs[g], r_ofs[g], tmp_prim, tmp_idx, loc_cb, g)


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _partition_parallel(prim, idx, s, e, a, lo, scale, nb, best_k, loc_cnt, dst_prim,
                        dst_idx, out):
    """Stable partition of rows [s, e) (bins <= best_k of axis a go left) of prim/idx
    into the same rows of dst_prim/dst_idx, in the chunks of ``_bin_parallel``, whose
    per-chunk counts give each chunk its output offsets. Writes the children's centroid
    boxes into out[2] (left) and out[3] (right); returns the split position.

    The row order is that of a stable partition, whatever the thread count.
    """
    n_ch = _PAR_BIN_CHUNKS
    step = (e - s + n_ch - 1) // n_ch
    n_l = np.zeros(n_ch, dtype=np.int64)
    n_left = 0
    for ch in range(n_ch):
        for k in range(best_k + 1):
            n_l[ch] += loc_cnt[ch, a, k]
        n_left += n_l[ch]
    l_ofs = np.empty(n_ch, dtype=np.int64)
    r_ofs = np.empty(n_ch, dtype=np.int64)
    l_at = s
    r_at = s + n_left
    for ch in range(n_ch):
        l_ofs[ch] = l_at
        r_ofs[ch] = r_at
        size = max(0, min(e, s + (ch + 1) * step) - (s + ch * step))
        l_at += n_l[ch]
        r_at += size - n_l[ch]
    loc_cb = np.empty((n_ch, 2, 6))
    # DECISION: the parallel loop is a kernel of its own, its chunk body a serial
    # function: written inline, the prange body's running offsets and min/max updates
    # were not kept per chunk (Numba's parfor lowering treats in-place updates of outer
    # variables as reductions), and the centroid boxes came out wrong. test_build.py
    # checks the kernel against a NumPy partition.
    _scatter_parallel(prim, idx, s, e, step, a, lo, scale, nb, best_k, l_ofs, r_ofs,
                      dst_prim, dst_idx, loc_cb)
    for ch in range(n_ch):
        for side in range(2):
            for c in range(3):
                out[2 + side, c] = min(out[2 + side, c], loc_cb[ch, side, c])
                out[2 + side, c + 3] = max(out[2 + side, c + 3], loc_cb[ch, side, c + 3])
    return s + n_left


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _split(prim, idx, s, e, box, cbox, n_bins, all_axes, c_trav, c_isect, max_leaf,
           max_leaf_forced, par, b_cnt, b_box, acc, r_area, r_cnt, scale, out, loc_cnt,
           alt_prim, alt_idx):
    """Decide leaf or split for [s, e) (Wald 2007 binned SAH); on a split, partition the
    rows and write the children's boxes into out (4, 6): left box, right box, left
    centroid box, right centroid box.

    Returns (split position or -1 for a leaf, moved): with ``moved`` the partitioned
    rows are in alt_prim/alt_idx (parallel partition of a big top-phase node), else in
    place in prim/idx.
    """
    count = e - s
    if count == 1:
        return -1, False
    # Small nodes get fewer bins: with ~n/2 nodes of a handful of triangles, clearing
    # and sweeping 3 x n_bins bins per node would dominate the build.
    nb = min(n_bins, max(2, count))
    big = par and count >= _PAR_BIN_MIN
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
        if big:
            _bin_parallel(prim, s, e, cbox, scale, nb, b_cnt, b_box, loc_cnt)
        else:
            for j in range(s, e):
                for a in range(3):
                    if scale[a] > 0.0:
                        k = _bin_of(prim[j, _CE + a], cbox[a], scale[a], nb)
                        b_cnt[a, k] += 1
                        for c in range(3):
                            b_box[a, k, c] = min(b_box[a, k, c], prim[j, _LO + c])
                            b_box[a, k, c + 3] = max(b_box[a, k, c + 3], prim[j, _HI + c])
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
                r_area[k] = half_area(acc)
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
                cost = half_area(acc) * n_acc + r_area[k + 1] * n_r
                if cost < best_cost:
                    best_cost = cost
                    best_axis = a
                    best_k = k
        parent_area = half_area(box)
        if parent_area > 0.0:
            best_cost = c_trav + c_isect * best_cost / parent_area
        else:
            best_cost = c_trav + c_isect * count

    if best_axis < 0:
        # Every centroid coincides: no positional split exists.
        if count <= max_leaf_forced:
            return -1, False
        mid = s + count // 2
        for c in range(6):
            out[0, c] = box[c]
            out[1, c] = box[c]
            out[2, c] = cbox[c]
            out[3, c] = cbox[c]
        return mid, False
    if count <= max_leaf and c_isect * count <= best_cost:
        return -1, False

    # Node boxes of the children: the union of their side's bins.
    a = best_axis
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
    # Partition rows [s, e): bins <= best_k go left. DECISION: the children's centroid
    # boxes are gathered here, from the rows the pass reads anyway, not kept per bin
    # (bins of 6 instead of 12 floats: the subtree phase 0.46 -> 0.35 s on 810k
    # triangles, 2 threads; min/max are exact, so the tree is bit-identical).
    if big:
        mid = _partition_parallel(prim, idx, s, e, a, cbox[a], scale[a], nb, best_k,
                                  loc_cnt, alt_prim, alt_idx, out)
        return mid, True
    lo_j = s
    hi_j = e - 1
    while lo_j <= hi_j:
        side = 2 if _bin_of(prim[lo_j, _CE + a], cbox[a], scale[a], nb) <= best_k else 3
        for c in range(3):
            out[side, c] = min(out[side, c], prim[lo_j, _CE + c])
            out[side, c + 3] = max(out[side, c + 3], prim[lo_j, _CE + c])
        if side == 2:
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
    return lo_j, False


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _grow(prim, idx, s0, e0, root, next_free, box0, cbox0, n_bins, all_axes, c_trav,
          c_isect, max_leaf, max_leaf_forced, stop, node_box, node_meta, pend, pend_box,
          alt_prim, alt_idx):
    """Build the tree over rows [s0, e0) with its root at node ``root`` and further
    nodes allocated from ``next_free`` on. Tasks of at most ``stop`` triangles are not
    expanded but appended to ``pend`` (rows: node, s, e, rows in alt_prim/alt_idx?) and
    ``pend_box`` (box, centroid box) when stop > 0. Big nodes (stop > 0) are
    partitioned from one buffer into the other (prim/idx, alt_prim/alt_idx), so each
    task remembers which buffer holds its rows.
    Returns (next_free, number of pending tasks)."""
    cap = e0 - s0 + 1
    t_s = np.empty(cap, dtype=np.int64)
    t_e = np.empty(cap, dtype=np.int64)
    t_node = np.empty(cap, dtype=np.int64)
    t_alt = np.zeros(cap, dtype=np.bool_)
    t_box = np.empty((cap, 12))
    b_cnt = np.zeros((3, n_bins), dtype=np.int64)
    b_box = np.empty((3, n_bins, 6))
    loc_cnt = np.zeros((_PAR_BIN_CHUNKS if stop > 0 else 1, 3, n_bins), dtype=np.int64)
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
        in_alt = t_alt[sp]
        for c in range(6):
            box[c] = t_box[sp, c]
            cbox[c] = t_box[sp, 6 + c]
            node_box[node, c] = box[c]
        if stop > 0 and e - s <= stop:
            pend[n_pend, 0] = node
            pend[n_pend, 1] = s
            pend[n_pend, 2] = e
            pend[n_pend, 3] = in_alt
            pend_box[n_pend, :6] = box
            pend_box[n_pend, 6:] = cbox
            n_pend += 1
            continue
        if in_alt:
            mid, moved = _split(alt_prim, alt_idx, s, e, box, cbox, n_bins, all_axes, c_trav,
                                c_isect, max_leaf, max_leaf_forced, stop > 0, b_cnt, b_box,
                                acc, r_area, r_cnt, scale, out, loc_cnt, prim, idx)
        else:
            mid, moved = _split(prim, idx, s, e, box, cbox, n_bins, all_axes, c_trav,
                                c_isect, max_leaf, max_leaf_forced, stop > 0, b_cnt, b_box,
                                acc, r_area, r_cnt, scale, out, loc_cnt, alt_prim, alt_idx)
        if moved:
            in_alt = not in_alt
        if mid < 0:
            if in_alt:  # a leaf of the top phase (only with a tiny ``stop``)
                for j in range(s, e):
                    for c in range(9):
                        prim[j, c] = alt_prim[j, c]
                    idx[j] = alt_idx[j]
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
        t_alt[sp] = in_alt
        t_box[sp, :6] = out[1]
        t_box[sp, 6:] = out[3]
        sp += 1
        t_s[sp] = s
        t_e[sp] = mid
        t_node[sp] = left
        t_alt[sp] = in_alt
        t_box[sp, :6] = out[0]
        t_box[sp, 6:] = out[2]
        sp += 1
    return next_free, n_pend


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def _grow_pending(prim, idx, pend, pend_box, n_pend, bases, n_bins, all_axes, c_trav,
                  c_isect, max_leaf, max_leaf_forced, node_box, node_meta, alt_prim, alt_idx):
    """Build the pending tasks of ``build_top`` in parallel, each into its own node
    range; rows a task left in alt_prim/alt_idx are first copied back into prim/idx."""
    no_pend = np.zeros((1, 4), dtype=np.int64)
    no_box = np.empty((1, 12))
    for q in prange(n_pend):
        node = pend[q, 0]
        s = pend[q, 1]
        e = pend[q, 2]
        if pend[q, 3]:
            for j in range(s, e):
                for c in range(9):
                    prim[j, c] = alt_prim[j, c]
                idx[j] = alt_idx[j]
        box = pend_box[q, :6].copy()
        cbox = pend_box[q, 6:].copy()
        _grow(prim, idx, s, e, node, bases[q], box, cbox, n_bins, all_axes, c_trav, c_isect,
              max_leaf, max_leaf_forced, 0, node_box, node_meta, no_pend, no_box, alt_prim,
              alt_idx)


@njit(cache=CACHE, error_model=ERROR_MODEL)
def build_top(prim, idx, n_bins, all_axes, c_trav, c_isect, max_leaf, max_leaf_forced, stop):
    """Top phase over all rows (serial over nodes, parallel within big ones). Returns
    node arrays (2m - 1 rows); the pending tasks (node, s, e, rows in the second
    buffer?), their boxes and centroid boxes (n_pend, 12) and, per pending task, the
    first free node of its range; the second row buffer (alt_prim, alt_idx)."""
    m = prim.shape[0]
    n_nodes = 2 * m - 1
    node_box = np.empty((n_nodes, 6), dtype=np.float32)
    node_meta = np.zeros((n_nodes, 4), dtype=np.int32)
    box = np.empty(6)
    cbox = np.empty(6)
    _bounds(prim, 0, m, box, cbox)
    pend = np.empty((m, 4), dtype=np.int64)
    pend_box = np.empty((m, 12))
    alt_prim = np.empty_like(prim)
    alt_idx = np.empty_like(idx)
    next_free, n_pend = _grow(prim, idx, 0, m, 0, 1, box, cbox, n_bins, all_axes, c_trav,
                              c_isect, max_leaf, max_leaf_forced, stop, node_box, node_meta,
                              pend, pend_box, alt_prim, alt_idx)
    bases = np.empty(n_pend, dtype=np.int64)
    for q in range(n_pend):
        bases[q] = next_free
        next_free += 2 * (pend[q, 2] - pend[q, 1]) - 2
    return (node_box, node_meta, pend[:n_pend].copy(), pend_box[:n_pend].copy(), bases,
            alt_prim, alt_idx)


def build_bvh(prim, idx, n_bins, all_axes, c_trav, c_isect, max_leaf, max_leaf_forced, stop):
    """Binned SAH BVH over the primitive rows (permuted in place together with idx).

    ``all_axes``: bin along all three axes (Wald 2007) or only along the axis of largest
    centroid extent (3x less binning work, the usual fast-builder shortcut).

    Returns node_box (2m - 1, 6) float32 and node_meta (2m - 1, 4) int32 with the root
    at 0 (rows not reached from the root are unused).
    """
    node_box, node_meta, pend, pend_box, bases, alt_prim, alt_idx = build_top(
        prim, idx, n_bins, all_axes, c_trav, c_isect, max_leaf, max_leaf_forced, stop)
    if len(pend):
        _grow_pending(prim, idx, pend, pend_box, len(pend), bases, n_bins, all_axes, c_trav,
                      c_isect, max_leaf, max_leaf_forced, node_box, node_meta, alt_prim,
                      alt_idx)
    return node_box, node_meta
