"""Binned SAH BVH construction (Wald 2007) in Numba, parallel over subtrees.

Reference: I. Wald, "On fast construction of SAH-based bounding volume hierarchies",
IEEE Symposium on Interactive Ray Tracing 2007 (binned SAH, bins over centroid bounds).
Parallelisation by independent subtrees after a breadth-first top phase, as in Wald's
paper (section 4) and Embree's binned builders.

Steps:

1. ``triangle_setup``: per triangle a 36-byte primitive record (float32 box rounded
   outward, float32 centroid) and a zero-area flag, in parallel.
2. ``build_bvh``: a top phase splits the triangles until every open task holds at most
   ``stop`` triangles; those tasks are then built in parallel, largest first, each into
   its own pre-allocated range of the node arrays: the worker threads take the next
   task from a shared atomic counter (``tasks.fetch_add``; Numba's OpenMP layer alone
   would give each thread a fixed half of the list). The top phase works
   level by level (breadth first): one parallel pass bins the rows of *every* open node
   of the level (work items of a fixed number of rows), a serial step chooses each
   node's split from its bins, and a second parallel pass partitions all of them (a
   stable partition from one row buffer into a second; the buffers alternate by level,
   and a subtree task copies its rows back once, when it starts). Two parallel regions
   a level instead of two a node: on a loaded machine each region waits for every
   worker thread to be scheduled. Each task carries its node box (the union of the
   parent's bins on its side) and centroid box (gathered while partitioning), so a
   level touches each primitive twice: once to bin it, once to partition it. Primitive
   records are partitioned physically (rows moved with their triangle index), so every
   pass reads memory sequentially; below the top phase partitions are in place
   (Hoare-style swaps). Bin boxes are eight float32 lanes grown by one packed operation
   (``bounds8.grow8``; a minimum or maximum of float32 values is exact, so the tree is
   the one float64 bins would give). The tree does not depend on the thread count
   (fixed work items, each writing its own rows; counts, min and max are order-free).
   Work O(n log n); no Python loop over triangles.
3. ``collapse.to_wide_layout`` (its own module): collapses the binary tree into 8-wide
   records (the traversal layout, see ``traverse.py``) and collects the tree statistics.

Build arrays (explicit child pointers; node order is irrelevant, only the walk matters)::

    node_box  (2m - 1, 6) float32   min x, min y, min z, max x, max y, max z
    node_meta (2m - 1, 4) int32     left child, right child, first slot, count
                                    (count 0: internal; count > 0: leaf [first, first+count))

    bin boxes (3 bins, 8) float32   per axis and bin: min x, y, z, max x, y, z, 2 spare
                                    lanes (32 bytes, one AVX register; ``bounds8``)

The boxes are conservative: primitive boxes are rounded outward to float32, and unions
(min/max) of float32 values are exact.

Sizing: the top phase and the subtrees together use at most 2m - 1 nodes: with P open
tasks of c_k triangles, the top tree has P - 1 internal nodes and P task roots, and a
subtree needs at most 2 c_k - 2 nodes besides its root: (P - 1) + P + sum(2 c_k - 2)
= 2m - 1.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

from ..config import BUILD_FASTMATH, CACHE, ERROR_MODEL
from .bounds8 import BOX_LANES, grow8
from .tasks import fetch_add

#: Fields of a primitive record (float32 each; a record is _ROW floats, 36 bytes).
_LO, _HI, _CE = 0, 3, 6
_ROW = 9
#: float32 lanes of a bin box (bounds8.BOX_LANES).
_BL = BOX_LANES


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


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
def _half_area8(b):
    """``half_area`` of a float32 bin box, in float64 (the arithmetic of ``half_area``
    on the same values stored as float64, so costs and the tree are unchanged)."""
    dx = np.float64(b[3]) - np.float64(b[0])
    dy = np.float64(b[4]) - np.float64(b[1])
    dz = np.float64(b[5]) - np.float64(b[2])
    if dx < 0.0 or dy < 0.0 or dz < 0.0:
        return 0.0
    return dx * dy + dy * dz + dz * dx


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
def _empty8(b, r):
    """Reset the 8-lane box in row r of the float32 array b (n, 8) to empty."""
    for c in range(3):
        b[r, c] = np.inf
    for c in range(3, _BL):
        b[r, c] = -np.inf


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


#: Nodes of more than this many triangles (and more than the caller's ``stop``) are
#: split in the breadth-first top phase, binned and partitioned in parallel work items.
_PAR_BIN_MIN = 4096
#: Rows of one work item of the top phase. A fixed size, so results never depend on the
#: thread count. DECISION: 8192 rows (295 kB of records, L2-sized): ~100 items at the
#: root of the 0.8M-triangle benchmark tunnel, several per node at the last top level,
#: enough for the shared counter to balance the threads (not tuned further).
_PAR_ITEM_ROWS = 8192


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
def _bin_of(x, lo, scale, nb):
    """Bin of centroid coordinate x (one formula for binning and partitioning, so a
    row always goes to the side its bin was counted on)."""
    k = int((x - lo) * scale)
    return min(nb - 1, max(0, k))


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _set_scales(cbox, nb, all_axes, scale):
    """Bin scale per axis (0: the axis is not binned); True when any axis is."""
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
    return any_extent


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
def _clear_bins(b_cnt, b_box, nb):
    n_bins = b_cnt.shape[1]
    for a in range(3):
        for k in range(nb):
            b_cnt[a, k] = 0
            _empty8(b_box, a * n_bins + k)


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
def _bin_rows(prim, s, e, cbox, scale, nb, b_cnt, b_box):
    """Bin rows [s, e) of prim into b_cnt (3, n_bins) and b_box (3 n_bins, 8): row
    a n_bins + k is bin k of axis a."""
    n_bins = b_cnt.shape[1]
    for j in range(s, e):
        for a in range(3):
            if scale[a] > 0.0:
                k = _bin_of(prim[j, _CE + a], cbox[a], scale[a], nb)
                b_cnt[a, k] += 1
                grow8(b_box, (a * n_bins + k) * _BL, prim, j * _ROW)


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _best_split(b_cnt, b_box, nb, scale, acc, r_area, r_cnt):
    """SAH sweep over the bins (Wald 2007): (cost sum, axis, last bin of the left side);
    axis -1 when no split separates the centroids. The cost of a split after bin k is
    A_L N_L + A_R N_R (half areas; scaled to C_trav + C_isect * cost / A_parent by the
    caller)."""
    n_bins = b_cnt.shape[1]
    best_cost = np.inf
    best_axis = -1
    best_k = -1
    for a in range(3):
        if scale[a] == 0.0:
            continue
        # Sweep from the right, then from the left.
        _empty8(acc, 0)
        n_acc = 0
        for k in range(nb - 1, 0, -1):
            n_acc += b_cnt[a, k]
            grow8(acc, 0, b_box, (a * n_bins + k) * _BL)
            r_cnt[k] = n_acc
            r_area[k] = _half_area8(acc[0])
        _empty8(acc, 0)
        n_acc = 0
        for k in range(nb - 1):
            n_acc += b_cnt[a, k]
            grow8(acc, 0, b_box, (a * n_bins + k) * _BL)
            n_r = r_cnt[k + 1]
            if n_acc == 0 or n_r == 0:
                continue
            cost = _half_area8(acc[0]) * n_acc + r_area[k + 1] * n_r
            if cost < best_cost:
                best_cost = cost
                best_axis = a
                best_k = k
    return best_cost, best_axis, best_k


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _side_boxes(b_cnt, b_box, nb, a, best_k, out):
    """Node boxes of the children (out[0] left, out[1] right): the union of their side's
    bins; out[2], out[3] (centroid boxes) reset to empty for the partition to fill."""
    n_bins = b_cnt.shape[1]
    for q in range(4):
        for c in range(3):
            out[q, c] = np.inf
            out[q, c + 3] = -np.inf
    for k in range(nb):
        if b_cnt[a, k] == 0:
            continue
        side = 0 if k <= best_k else 1
        r = a * n_bins + k
        for c in range(3):
            out[side, c] = min(out[side, c], np.float64(b_box[r, c]))
            out[side, c + 3] = max(out[side, c + 3], np.float64(b_box[r, 3 + c]))


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _decide(count, box, cbox, best_cost, best_axis, c_trav, c_isect, max_leaf,
            max_leaf_forced, out):
    """Leaf or split after the sweep: 0 leaf, 1 split at the SAH plane, 2 split by index
    (every centroid coincides: no positional split exists; out gets the parent's boxes
    for both children)."""
    if best_axis < 0:
        if count <= max_leaf_forced:
            return 0
        for c in range(6):
            out[0, c] = box[c]
            out[1, c] = box[c]
            out[2, c] = cbox[c]
            out[3, c] = cbox[c]
        return 2
    parent_area = half_area(box)
    if parent_area > 0.0:
        cost = c_trav + c_isect * best_cost / parent_area
    else:
        cost = c_trav + c_isect * count
    if count <= max_leaf and c_isect * count <= cost:
        return 0
    return 1


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _split(prim, idx, s, e, box, cbox, n_bins, all_axes, c_trav, c_isect, max_leaf,
           max_leaf_forced, b_cnt, b_box, acc, r_area, r_cnt, scale, out):
    """Decide leaf or split for rows [s, e) (Wald 2007 binned SAH); on a split, partition
    the rows in place and write the children's boxes into out (4, 6): left box, right
    box, left centroid box, right centroid box. Returns the split position, -1 for a
    leaf."""
    count = e - s
    if count == 1:
        return -1
    # Small nodes get fewer bins: with ~n/2 nodes of a handful of triangles, clearing
    # and sweeping 3 x n_bins bins per node would dominate the build.
    nb = min(n_bins, max(2, count))
    best_cost = np.inf
    best_axis = -1
    best_k = -1
    if _set_scales(cbox, nb, all_axes, scale):
        _clear_bins(b_cnt, b_box, nb)
        _bin_rows(prim, s, e, cbox, scale, nb, b_cnt, b_box)
        best_cost, best_axis, best_k = _best_split(b_cnt, b_box, nb, scale, acc, r_area,
                                                   r_cnt)
    kind = _decide(count, box, cbox, best_cost, best_axis, c_trav, c_isect, max_leaf,
                   max_leaf_forced, out)
    if kind == 0:
        return -1
    if kind == 2:
        return s + count // 2
    a = best_axis
    _side_boxes(b_cnt, b_box, nb, a, best_k, out)
    # Partition rows [s, e): bins <= best_k go left. DECISION: the children's centroid
    # boxes are gathered here, from the rows the pass reads anyway, not kept per bin
    # (bins of 6 instead of 12 floats: the subtree phase 0.46 -> 0.35 s on 810k
    # triangles, 2 threads; min/max are exact, so the tree is bit-identical).
    lo = cbox[a]
    sc = scale[a]
    lo_j = s
    hi_j = e - 1
    while lo_j <= hi_j:
        side = 2 if _bin_of(prim[lo_j, _CE + a], lo, sc, nb) <= best_k else 3
        for c in range(3):
            out[side, c] = min(out[side, c], prim[lo_j, _CE + c])
            out[side, c + 3] = max(out[side, c + 3], prim[lo_j, _CE + c])
        if side == 2:
            lo_j += 1
        else:
            for c in range(_ROW):
                tmp = prim[lo_j, c]
                prim[lo_j, c] = prim[hi_j, c]
                prim[hi_j, c] = tmp
            ti = idx[lo_j]
            idx[lo_j] = idx[hi_j]
            idx[hi_j] = ti
            hi_j -= 1
    return lo_j


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _grow(prim, idx, s0, e0, root, next_free, box0, cbox0, n_bins, all_axes, c_trav,
          c_isect, max_leaf, max_leaf_forced, node_box, node_meta):
    """Build the tree over rows [s0, e0) with its root at node ``root`` and further
    nodes allocated from ``next_free`` on (depth first, serial, in place). Returns the
    next free node."""
    cap = e0 - s0 + 1
    t_s = np.empty(cap, dtype=np.int64)
    t_e = np.empty(cap, dtype=np.int64)
    t_node = np.empty(cap, dtype=np.int64)
    t_box = np.empty((cap, 12))
    b_cnt = np.zeros((3, n_bins), dtype=np.int64)
    b_box = np.empty((3 * n_bins, _BL), dtype=np.float32)
    acc = np.empty((1, _BL), dtype=np.float32)
    r_area = np.empty(n_bins)
    r_cnt = np.empty(n_bins, dtype=np.int64)
    scale = np.zeros(3)
    out = np.empty((4, 6))
    box = np.empty(6)
    cbox = np.empty(6)

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
        mid = _split(prim, idx, s, e, box, cbox, n_bins, all_axes, c_trav, c_isect,
                     max_leaf, max_leaf_forced, b_cnt, b_box, acc, r_area, r_cnt, scale,
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
    return next_free


# ---------------------------------------------------------------------------------------
# Top phase: breadth first, each level binned and partitioned in parallel work items
# ---------------------------------------------------------------------------------------
@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _bin_item(prim, w, j0, j1, cbox, scale, nb, it_cnt, it_box):
    """Bins of work item w (rows [j0, j1) of one node) into it_cnt[w], it_box[w]."""
    _clear_bins(it_cnt[w], it_box[w], nb)
    _bin_rows(prim, j0, j1, cbox, scale, nb, it_cnt[w], it_box[w])


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, parallel=True)
def _bin_level(prim, items, n_items, lvl_box, lvl_scale, nb, it_cnt, it_box, workers,
               counter):
    """Bin every work item of a level in parallel: items[w] = (level node, first row,
    end row); the node's centroid box is lvl_box[q, 6:12], its scales lvl_scale[q].
    Workers take items from the shared counter (``tasks.fetch_add``; counter: (1,)
    int64 zero, allocated by the caller: a counter allocated inside a parallel kernel
    reads back as its initial value after the loop)."""
    for _ in prange(workers):
        while True:
            w = fetch_add(counter, 0, 1)
            if w >= n_items:
                break
            q = items[w, 0]
            _bin_item(prim, w, items[w, 1], items[w, 2], lvl_box[q, 6:], lvl_scale[q], nb,
                      it_cnt, it_box)


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _scatter_item(prim, idx, j0, j1, kind, a, lo, scale, nb, best_k, mid, li, ri,
                  dst_prim, dst_idx, cb, w):
    """Rows [j0, j1) to dst rows li.. (left) and ri.. (right), in order; the centroid
    boxes of both sides into cb[w] (2, 6). kind 1: bins <= best_k of axis a go left;
    kind 2: rows before ``mid`` go left."""
    for q in range(2):
        for c in range(3):
            cb[w, q, c] = np.inf
            cb[w, q, c + 3] = -np.inf
    for j in range(j0, j1):
        if kind == 1:
            go_left = _bin_of(prim[j, _CE + a], lo, scale, nb) <= best_k
        else:
            go_left = j < mid
        if go_left:
            q = 0
            dst = li
            li += 1
        else:
            q = 1
            dst = ri
            ri += 1
        for c in range(_ROW):
            dst_prim[dst, c] = prim[j, c]
        dst_idx[dst] = idx[j]
        for c in range(3):
            cb[w, q, c] = min(cb[w, q, c], prim[j, _CE + c])
            cb[w, q, c + 3] = max(cb[w, q, c + 3], prim[j, _CE + c])


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, parallel=True)
def _scatter_level(prim, idx, items, n_items, lvl_split, lvl_box, lvl_scale, nb, l_ofs,
                   r_ofs, dst_prim, dst_idx, cb, workers, counter):
    """Stable partition of every split node of a level from prim/idx into the same rows
    of dst_prim/dst_idx, one work item per iteration, each at its precomputed offsets.

    DECISION: the loop body is a serial function of its own: written inline, the prange
    body's running offsets and min/max updates were not kept per item (Numba's parfor
    lowering treats in-place updates of outer variables as reductions)."""
    for _ in prange(workers):
        while True:
            w = fetch_add(counter, 0, 1)
            if w >= n_items:
                break
            q = items[w, 0]
            kind = lvl_split[q, 0]
            if kind == 0:
                continue
            a = lvl_split[q, 1]
            lo = lvl_box[q, 6 + a] if kind == 1 else 0.0
            sc = lvl_scale[q, a] if kind == 1 else 0.0
            _scatter_item(prim, idx, items[w, 1], items[w, 2], kind, a, lo, sc, nb,
                          lvl_split[q, 2], lvl_split[q, 3], l_ofs[w], r_ofs[w], dst_prim,
                          dst_idx, cb, w)


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _top_level(src_prim, src_idx, dst_prim, dst_idx, lvl_node, lvl_s, lvl_e, lvl_box,
               n_lvl, n_bins, all_axes, c_trav, c_isect, max_leaf, max_leaf_forced, stop,
               node_box, node_meta, next_free, nxt_node, nxt_s, nxt_e, nxt_box, pend,
               pend_box, n_pend, src_is_alt, workers):
    """One level of the top phase: bin, decide and partition the n_lvl open nodes
    (rows in src), writing their children's rows into dst. Children of more than
    ``stop`` rows become the next level (nxt_*), the others pending tasks; a node that
    is not split becomes a pending task as it is (rows still in src).

    Returns (next free node, nodes in the next level, pending tasks)."""
    nb = n_bins  # every top-phase node has more rows than bins
    n_items = 0
    for q in range(n_lvl):
        n_items += (lvl_e[q] - lvl_s[q] + _PAR_ITEM_ROWS - 1) // _PAR_ITEM_ROWS
    items = np.empty((n_items, 3), dtype=np.int64)
    w = 0
    for q in range(n_lvl):
        for j0 in range(lvl_s[q], lvl_e[q], _PAR_ITEM_ROWS):
            items[w, 0] = q
            items[w, 1] = j0
            items[w, 2] = min(lvl_e[q], j0 + _PAR_ITEM_ROWS)
            w += 1
    lvl_scale = np.zeros((n_lvl, 3))
    for q in range(n_lvl):
        _set_scales(lvl_box[q, 6:], nb, all_axes, lvl_scale[q])
    it_cnt = np.zeros((n_items, 3, n_bins), dtype=np.int64)
    it_box = np.empty((n_items, 3 * n_bins, _BL), dtype=np.float32)
    _bin_level(src_prim, items, n_items, lvl_box, lvl_scale, nb, it_cnt, it_box, workers,
               np.zeros(1, dtype=np.int64))

    # Per node: reduce its items' bins, sweep, decide; the items' output offsets.
    b_cnt = np.zeros((3, n_bins), dtype=np.int64)
    b_box = np.empty((3 * n_bins, _BL), dtype=np.float32)
    acc = np.empty((1, _BL), dtype=np.float32)
    r_area = np.empty(n_bins)
    r_cnt = np.empty(n_bins, dtype=np.int64)
    out = np.empty((4, 6))
    lvl_split = np.zeros((n_lvl, 4), dtype=np.int64)  # kind, axis, best_k, mid
    lvl_out = np.empty((n_lvl, 4, 6))
    l_ofs = np.empty(n_items, dtype=np.int64)
    r_ofs = np.empty(n_items, dtype=np.int64)
    w0 = 0
    for q in range(n_lvl):
        s = lvl_s[q]
        e = lvl_e[q]
        w1 = w0
        while w1 < n_items and items[w1, 0] == q:
            w1 += 1
        best_cost = np.inf
        best_axis = -1
        best_k = -1
        if lvl_scale[q, 0] > 0.0 or lvl_scale[q, 1] > 0.0 or lvl_scale[q, 2] > 0.0:
            _clear_bins(b_cnt, b_box, nb)
            for v in range(w0, w1):
                for a in range(3):
                    for k in range(nb):
                        b_cnt[a, k] += it_cnt[v, a, k]
                        grow8(b_box, (a * n_bins + k) * _BL, it_box,
                              ((v * 3 + a) * n_bins + k) * _BL)
            best_cost, best_axis, best_k = _best_split(b_cnt, b_box, nb, lvl_scale[q],
                                                       acc, r_area, r_cnt)
        kind = _decide(e - s, lvl_box[q, :6], lvl_box[q, 6:], best_cost, best_axis,
                       c_trav, c_isect, max_leaf, max_leaf_forced, out)
        lvl_split[q, 0] = kind
        if kind == 1:
            _side_boxes(b_cnt, b_box, nb, best_axis, best_k, out)
            lvl_split[q, 1] = best_axis
            lvl_split[q, 2] = best_k
            n_left = 0
            for v in range(w0, w1):
                for k in range(best_k + 1):
                    n_left += it_cnt[v, best_axis, k]
        else:
            n_left = (e - s) // 2
        lvl_split[q, 3] = s + n_left
        lvl_out[q] = out
        l_at = s
        r_at = s + n_left
        for v in range(w0, w1):
            if kind == 1:
                n_l = 0
                for k in range(best_k + 1):
                    n_l += it_cnt[v, best_axis, k]
            else:
                n_l = max(0, min(items[v, 2], s + n_left) - items[v, 1])
            l_ofs[v] = l_at
            r_ofs[v] = r_at
            l_at += n_l
            r_at += items[v, 2] - items[v, 1] - n_l
        w0 = w1

    cb = np.empty((n_items, 2, 6))
    _scatter_level(src_prim, src_idx, items, n_items, lvl_split, lvl_box, lvl_scale, nb,
                   l_ofs, r_ofs, dst_prim, dst_idx, cb, workers,
                   np.zeros(1, dtype=np.int64))

    # Children: the next level or pending tasks.
    n_nxt = 0
    w0 = 0
    for q in range(n_lvl):
        s = lvl_s[q]
        e = lvl_e[q]
        node = lvl_node[q]
        w1 = w0
        while w1 < n_items and items[w1, 0] == q:
            w1 += 1
        if lvl_split[q, 0] == 0:
            # Not split (only with a tiny ``stop``): the subtree phase makes the leaf.
            pend[n_pend, 0] = node
            pend[n_pend, 1] = s
            pend[n_pend, 2] = e
            pend[n_pend, 3] = src_is_alt
            pend_box[n_pend] = lvl_box[q]
            n_pend += 1
            w0 = w1
            continue
        out = lvl_out[q]
        if lvl_split[q, 0] == 1:
            for v in range(w0, w1):
                for side in range(2):
                    for c in range(3):
                        out[2 + side, c] = min(out[2 + side, c], cb[v, side, c])
                        out[2 + side, c + 3] = max(out[2 + side, c + 3],
                                                   cb[v, side, c + 3])
        w0 = w1
        mid = lvl_split[q, 3]
        left = next_free
        next_free += 2
        node_meta[node, 0] = left
        node_meta[node, 1] = left + 1
        node_meta[node, 2] = s
        node_meta[node, 3] = 0
        for side in range(2):
            child = left + side
            cs = s if side == 0 else mid
            ce = mid if side == 0 else e
            for c in range(6):
                node_box[child, c] = out[side, c]
            if ce - cs > stop:
                nxt_node[n_nxt] = child
                nxt_s[n_nxt] = cs
                nxt_e[n_nxt] = ce
                nxt_box[n_nxt, :6] = out[side]
                nxt_box[n_nxt, 6:] = out[2 + side]
                n_nxt += 1
            else:
                pend[n_pend, 0] = child
                pend[n_pend, 1] = cs
                pend[n_pend, 2] = ce
                pend[n_pend, 3] = not src_is_alt
                pend_box[n_pend, :6] = out[side]
                pend_box[n_pend, 6:] = out[2 + side]
                n_pend += 1
    return next_free, n_nxt, n_pend


@njit(cache=CACHE, error_model=ERROR_MODEL)
def build_top(prim, idx, n_bins, all_axes, c_trav, c_isect, max_leaf, max_leaf_forced, stop,
              workers):
    """Top phase over all rows, breadth first (two parallel passes a level). Nodes of
    more than max(stop, _PAR_BIN_MIN) rows are split here. Returns node arrays
    (2m - 1 rows); the pending tasks (node, s, e, rows in the second buffer?), largest
    first, their boxes and centroid boxes (n_pend, 12) and, per pending task, the first
    free node of its range; the second row buffer (alt_prim, alt_idx)."""
    m = prim.shape[0]
    n_nodes = 2 * m - 1
    stop = max(stop, _PAR_BIN_MIN)
    node_box = np.empty((n_nodes, 6), dtype=np.float32)
    # DECISION: np.empty: every node reached from the root gets its row written, the
    # others are never read; np.zeros cost a 26 MB memset (~0.02 s at 0.8M triangles).
    node_meta = np.empty((n_nodes, 4), dtype=np.int32)
    box = np.empty(6)
    cbox = np.empty(6)
    _bounds(prim, 0, m, box, cbox)
    for c in range(6):
        node_box[0, c] = box[c]
    cap = m // (stop + 1) + 1
    # A level's nodes hold disjoint rows, more than ``stop`` each; pending tasks hold
    # disjoint, non-empty rows (np.empty: only the rows used are touched).
    pend = np.empty((m, 4), dtype=np.int64)
    pend_box = np.empty((m, 12))
    n_pend = 0
    alt_prim = np.empty_like(prim)
    alt_idx = np.empty_like(idx)
    lvl_node = np.empty(cap, dtype=np.int64)
    lvl_s = np.empty(cap, dtype=np.int64)
    lvl_e = np.empty(cap, dtype=np.int64)
    lvl_box = np.empty((cap, 12))
    nxt_node = np.empty(cap, dtype=np.int64)
    nxt_s = np.empty(cap, dtype=np.int64)
    nxt_e = np.empty(cap, dtype=np.int64)
    nxt_box = np.empty((cap, 12))
    next_free = 1
    if m > stop:
        lvl_node[0] = 0
        lvl_s[0] = 0
        lvl_e[0] = m
        lvl_box[0, :6] = box
        lvl_box[0, 6:] = cbox
        n_lvl = 1
    else:
        pend[0, 0] = 0
        pend[0, 1] = 0
        pend[0, 2] = m
        pend[0, 3] = 0
        pend_box[0, :6] = box
        pend_box[0, 6:] = cbox
        n_pend = 1
        n_lvl = 0
    in_alt = False
    while n_lvl > 0:
        if in_alt:
            next_free, n_nxt, n_pend = _top_level(
                alt_prim, alt_idx, prim, idx, lvl_node, lvl_s, lvl_e, lvl_box, n_lvl,
                n_bins, all_axes, c_trav, c_isect, max_leaf, max_leaf_forced, stop,
                node_box, node_meta, next_free, nxt_node, nxt_s, nxt_e, nxt_box, pend,
                pend_box, n_pend, True, workers)
        else:
            next_free, n_nxt, n_pend = _top_level(
                prim, idx, alt_prim, alt_idx, lvl_node, lvl_s, lvl_e, lvl_box, n_lvl,
                n_bins, all_axes, c_trav, c_isect, max_leaf, max_leaf_forced, stop,
                node_box, node_meta, next_free, nxt_node, nxt_s, nxt_e, nxt_box, pend,
                pend_box, n_pend, False, workers)
        in_alt = not in_alt
        lvl_node, nxt_node = nxt_node, lvl_node
        lvl_s, nxt_s = nxt_s, lvl_s
        lvl_e, nxt_e = nxt_e, lvl_e
        lvl_box, nxt_box = nxt_box, lvl_box
        n_lvl = n_nxt
    # Largest tasks first (longest-processing-time order): the last task a thread
    # takes is a small one, so the threads finish together.
    sizes = pend[:n_pend, 2] - pend[:n_pend, 1]
    order = np.argsort(-sizes, kind="mergesort")
    pend_s = pend[order]
    pend_box_s = pend_box[order]
    bases = np.empty(n_pend, dtype=np.int64)
    for q in range(n_pend):
        bases[q] = next_free
        next_free += 2 * (pend_s[q, 2] - pend_s[q, 1]) - 2
    return node_box, node_meta, pend_s, pend_box_s, bases, alt_prim, alt_idx


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _grow_task(prim, idx, pend, pend_box, q, bases, n_bins, all_axes, c_trav, c_isect,
               max_leaf, max_leaf_forced, node_box, node_meta, alt_prim, alt_idx):
    """Pending task q of ``build_top``: its rows copied back from alt_prim/alt_idx when
    they are there, then its subtree built in place."""
    s = pend[q, 1]
    e = pend[q, 2]
    if pend[q, 3]:
        for j in range(s, e):
            for c in range(_ROW):
                prim[j, c] = alt_prim[j, c]
            idx[j] = alt_idx[j]
    box = pend_box[q, :6].copy()
    cbox = pend_box[q, 6:].copy()
    _grow(prim, idx, s, e, pend[q, 0], bases[q], box, cbox, n_bins, all_axes, c_trav,
          c_isect, max_leaf, max_leaf_forced, node_box, node_meta)


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def _grow_pending(prim, idx, pend, pend_box, n_pend, bases, n_bins, all_axes, c_trav,
                  c_isect, max_leaf, max_leaf_forced, node_box, node_meta, alt_prim, alt_idx,
                  workers, counter):
    """Build the pending tasks of ``build_top`` in parallel, each into its own node
    range; rows a task left in alt_prim/alt_idx are first copied back into prim/idx.
    Workers take the tasks in order (largest first) from a shared counter
    (``tasks.fetch_add``): Numba's OpenMP layer would otherwise give each thread a
    fixed half of the list."""
    for _ in prange(workers):
        while True:
            q = fetch_add(counter, 0, 1)
            if q >= n_pend:
                break
            _grow_task(prim, idx, pend, pend_box, q, bases, n_bins, all_axes, c_trav,
                       c_isect, max_leaf, max_leaf_forced, node_box, node_meta, alt_prim,
                       alt_idx)


def build_bvh(prim, idx, n_bins, all_axes, c_trav, c_isect, max_leaf, max_leaf_forced, stop):
    """Binned SAH BVH over the primitive rows (permuted in place together with idx).

    ``prim`` (m, 9) float32 C-contiguous (``triangle_setup``); ``idx`` (m,) int64.
    ``all_axes``: bin along all three axes (Wald 2007) or only along the axis of largest
    centroid extent (3x less binning work, the usual fast-builder shortcut). ``stop``:
    nodes of more than max(stop, 4096) rows are split in the parallel top phase.

    Returns node_box (2m - 1, 6) float32 and node_meta (2m - 1, 4) int32 with the root
    at 0 (rows not reached from the root are unused).
    """
    # The worker count only sets how many threads take work items and tasks from the
    # shared counters; the tree never depends on it.
    workers = numba.get_num_threads()
    node_box, node_meta, pend, pend_box, bases, alt_prim, alt_idx = build_top(
        prim, idx, n_bins, all_axes, c_trav, c_isect, max_leaf, max_leaf_forced, stop,
        workers)
    if len(pend):
        _grow_pending(prim, idx, pend, pend_box, len(pend), bases, n_bins, all_axes, c_trav,
                      c_isect, max_leaf, max_leaf_forced, node_box, node_meta, alt_prim,
                      alt_idx, workers, np.zeros(1, dtype=np.int64))
    return node_box, node_meta
