"""Collapse of the binary BVH (``build.build_bvh``) into the wide records the traversal
reads (``traverse.py``, 8 lanes), with the tree statistics. Serial: ~0.016 s at 0.8M
triangles, under a twentieth of the build.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..config import CACHE, ERROR_MODEL
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
    root_area = half_area(node_box[0])
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
        area = half_area(node_box[i]) / root_area
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
    box = np.empty((n_rec_max, 6 * width), dtype=np.float32)
    # DECISION: np.empty, not np.zeros: every lane of every record written below is
    # set (unused lanes explicitly), and zeroing the n/2 rows bound cost a 42 MB
    # memset, 0.04 s of the 0.06 s collapse at 0.8M triangles.
    link = np.empty((n_rec_max, 2 * width), dtype=np.int64)
    ch = np.empty(width, dtype=np.int64)
    # Work list: (binary node, record index). Pre-order: records are numbered when
    # their parent record is filled, children pushed in reverse.
    work = np.empty(n + 1, dtype=np.int64)
    wrec = np.empty(n + 1, dtype=np.int64)
    wdep = np.empty(n + 1, dtype=np.int64)
    n_rec = 1
    max_depth_w = 0
    work[0] = 0
    wrec[0] = 0
    wdep[0] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        i = work[sp]
        r = wrec[sp]
        dw = wdep[sp]
        max_depth_w = max(max_depth_w, dw)
        if node_meta[i, 3] > 0:  # the root itself is a leaf
            ch[0] = i
            k = 1
        else:
            ch[0] = node_meta[i, 0]
            ch[1] = node_meta[i, 1]
            k = 2
            while k < width:
                best = -1
                best_a = -1.0
                for q in range(k):
                    if node_meta[ch[q], 3] == 0:
                        a = half_area(node_box[ch[q]])
                        if a > best_a:
                            best_a = a
                            best = q
                if best < 0:
                    break
                opened = ch[best]
                ch[best] = node_meta[opened, 0]
                ch[k] = node_meta[opened, 1]
                k += 1
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
                work[sp] = c_node
                wrec[sp] = link[r, lane]
                wdep[sp] = dw + 1
                sp += 1
    return box[:n_rec].copy(), link[:n_rec].copy(), (n_nodes, n_leaves, max_depth,
                                                      in_leaves, cost, max_depth_w)
