"""Collapse of the binary BVH (``build.build_bvh``) into the wide records the traversal
reads (``traverse.py``, 8 lanes), with the tree statistics, in one serial walk (~0.013 s
at 0.8M triangles), and the packing of the records into the traversal's padded float32
layout (parallel).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..config import CACHE, ERROR_MODEL
from .bounds8 import next_down32, next_up32
from .build import half_area


@njit(cache=CACHE, error_model=ERROR_MODEL)
def to_wide_layout(node_box, node_meta, c_trav, c_isect, width):
    """Collapse the binary tree into ``width``-wide records and collect the tree
    statistics.

    Wide-BVH collapse by surface area as in Embree's BVH4/BVH8 and Wald, Benthin & Boulos
    2008 ("Getting rid of packets"): a record starts with the two children of a binary
    node and repeatedly opens its largest-area internal child until it has ``width``
    (Ylitie, Karras & Laine 2017 collapse to 8 the same way before their SAH-optimal
    pass, which is not done here). The root is record 0; the internal children of a
    record get consecutive record indices when it is filled (siblings sit side by side
    in memory).

    Returns
    -------
    box : (n_w, 6 width) float32
        Child boxes, structure of arrays: min x[width], min y[width], min z[width],
        max x[width], max y[width], max z[width]. Unused lanes hold an empty box
        (min +inf, max -inf).
    link : (n_w, 2 width) int64
        child[width] (record index for an internal child, first triangle slot for a
        leaf), count[width] (0: internal child or unused lane; > 0: leaf).
    stats : tuple
        binary nodes, leaves, binary max depth, triangles in leaves, SAH cost (Wald 2007:
        sum over internal nodes of C_trav A / A_root plus over leaves of
        C_isect N A / A_root), wide max depth.
    """
    n = node_box.shape[0]
    n_rec_max = max(1, n // 2 + 1)
    box = np.empty((n_rec_max, 6 * width), dtype=np.float32)
    # DECISION: np.empty, not np.zeros: every lane of every record written below is
    # set (unused lanes explicitly), and zeroing the n/2 rows bound cost a 42 MB
    # memset, 0.04 s of the 0.06 s collapse at 0.8M triangles.
    link = np.empty((n_rec_max, 2 * width), dtype=np.int64)
    work = np.empty((n + 1, 4), dtype=np.int64)
    ch = np.empty(width, dtype=np.int64)
    ch_dep = np.empty(width, dtype=np.int64)
    ch_area = np.empty(width)
    ints = np.zeros(5, dtype=np.int64)
    cost = _collapse_loop(node_box, node_meta, c_trav, c_isect, width, box, link, work,
                          ch, ch_dep, ch_area, ints)
    n_rec, n_nodes, n_leaves, max_depth, in_leaves = ints[0], ints[1], ints[2], ints[3], \
        ints[4]
    max_depth_w = work[0, 0]
    # Views, not copies: the rows past n_rec were never written, so their pages were
    # never touched and cost no memory; the caller packs and drops these at once.
    return box[:n_rec], link[:n_rec], (n_nodes, n_leaves, max_depth, in_leaves, cost,
                                       max_depth_w)


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _stat(count, area):
    """(leaves, triangles in leaves, is internal) of a node with ``count`` triangles
    (0: internal)."""
    if count > 0:
        return 1, count, 0
    return 0, 0, 1


# DECISION: one walk for the records and the statistics (a separate preorder walk over
# the binary tree for the statistics was about a third of the collapse), each binary
# node's half area computed once, when it is reached (it was recomputed for every
# candidate each time a record opened a child), and no reference counting
# (``_nrt=False``: every ``node_box[i]`` row view took and dropped a reference, an
# atomic operation each). The statistics are those of the preorder walk; only the
# order of the cost sum differs (the last bits of sah_cost).
@njit(cache=CACHE, error_model=ERROR_MODEL, _nrt=False)
def _collapse_loop(node_box, node_meta, c_trav, c_isect, width, box, link, work, ch,
                   ch_dep, ch_area, ints):
    """The walk of ``to_wide_layout`` over preallocated arrays. Writes records into
    box/link; ints = (records, binary nodes, leaves, binary max depth, triangles in
    leaves); work[0, 0] = wide max depth. Returns the SAH cost."""
    root_area = half_area(node_box[0])
    if root_area <= 0.0:
        root_area = 1.0
    n_nodes = 1
    n_leaves = 0
    in_leaves = 0
    max_depth = 0
    cnt = node_meta[0, 3]
    lv, tl, internal = _stat(cnt, 0.0)
    n_leaves += lv
    in_leaves += tl
    cost = (c_trav * internal + c_isect * cnt * lv) * (half_area(node_box[0]) / root_area)
    # Work list rows: (binary node, record index, wide depth, binary depth). Pre-order:
    # records are numbered when their parent record is filled, children pushed in
    # reverse.
    n_rec = 1
    max_depth_w = 0
    work[0, 0] = 0
    work[0, 1] = 0
    work[0, 2] = 0
    work[0, 3] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        i = work[sp, 0]
        r = work[sp, 1]
        dw = work[sp, 2]
        db = work[sp, 3]
        max_depth_w = max(max_depth_w, dw)
        if node_meta[i, 3] > 0:  # the root itself is a leaf
            ch[0] = i
            k = 1
        else:
            # Start with the two children of i, then open the largest internal child
            # until the record is full; each node reached is counted once.
            k = 0
            parent = i
            dep = db + 1
            slot = 0
            while True:
                for side in range(2):
                    c_node = node_meta[parent, side]
                    q = slot if side == 0 else k
                    ch[q] = c_node
                    ch_dep[q] = dep
                    area = half_area(node_box[c_node])
                    ch_area[q] = area
                    cnt = node_meta[c_node, 3]
                    lv, tl, internal = _stat(cnt, 0.0)
                    n_nodes += 1
                    n_leaves += lv
                    in_leaves += tl
                    max_depth = max(max_depth, dep)
                    cost += (c_trav * internal + c_isect * cnt * lv) * (area / root_area)
                    if side == 1 or k == 0:
                        k += 1
                if k >= width:
                    break
                best = -1
                best_a = -1.0
                for q in range(k):
                    if node_meta[ch[q], 3] == 0 and ch_area[q] > best_a:
                        best_a = ch_area[q]
                        best = q
                if best < 0:
                    break
                parent = ch[best]
                dep = ch_dep[best] + 1
                slot = best
        for lane in range(width):
            if lane >= k:
                for c in range(3):
                    box[r, width * c + lane] = np.inf
                    box[r, 3 * width + width * c + lane] = -np.inf
                link[r, lane] = 0
                link[r, width + lane] = 0
                continue
            c_node = ch[lane]
            for c in range(3):
                box[r, width * c + lane] = node_box[c_node, c]
                box[r, 3 * width + width * c + lane] = node_box[c_node, 3 + c]
            if node_meta[c_node, 3] > 0:
                link[r, lane] = node_meta[c_node, 2]
                link[r, width + lane] = node_meta[c_node, 3]
            else:
                link[r, lane] = n_rec
                link[r, width + lane] = 0
                n_rec += 1
        # Push internal children in reverse lane order so that the first is next.
        for lane in range(k - 1, -1, -1):
            c_node = ch[lane]
            if node_meta[c_node, 3] == 0:
                work[sp, 0] = c_node
                work[sp, 1] = link[r, lane]
                work[sp, 2] = dw + 1
                work[sp, 3] = ch_dep[lane]
                sp += 1
    ints[0] = n_rec
    ints[1] = n_nodes
    ints[2] = n_leaves
    ints[3] = max_depth
    ints[4] = in_leaves
    work[0, 0] = max_depth_w
    return cost


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def pack_records(box, link, pad, nodes, links):
    """The traversal's records from ``to_wide_layout``'s arrays, in parallel over
    records (``scene._pack_nodes`` documents the layout and why the boxes are padded).

    box (n_w, 48) float32 and link (n_w, 16) int64 (width 8); pad float64 (metres);
    writes nodes (n_w, 64) float32 columns 0:48: minima (columns 0:24) as
    float32(float64(min) - pad) one more float32 step down, maxima as
    float32(float64(max) + pad) one step up (NumPy's ``astype`` rounding, then
    ``nextafter``, as ``bounds8.next_down32``/``next_up32``: an empty lane's +inf/-inf
    become the largest finite values, still an empty box); and links (n_w, 64) int32, the same memory as nodes, columns 48:64 =
    link. The caller checks that every link fits in int32.
    """
    half = box.shape[1] // 2
    n_link = link.shape[1]
    for r in prange(box.shape[0]):
        for c in range(half):
            lo = np.float32(np.float64(box[r, c]) - pad)
            nodes[r, c] = next_down32(lo)
            hi = np.float32(np.float64(box[r, half + c]) + pad)
            nodes[r, half + c] = next_up32(hi)
        for c in range(n_link):
            links[r, 2 * half + c] = np.int32(link[r, c])
