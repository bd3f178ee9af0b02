"""Exact nearest triangle of many points: a bounding-volume hierarchy over the triangles
and a depth-first, nearest-child-first branch-and-bound query.

Build: binary tree, each node split at the median centroid along the widest axis of
its centroids' box (found by selection, not sorting: O(m log m) in all), leaves of at
most ``LEAF_SIZE`` triangles, each node's children's boxes stored in it (one visit
reads both, as tinybvh's BVH_GPU layout does). The object median keeps the tree
balanced; a linear BVH (one Morton sort, ranges halved: Lauterbach et al. 2009) builds
faster but was measured 6x slower to query on a tunnel mesh (its boxes straddle the
curve's jumps).

Query: the classic branch and bound of nearest-neighbour search (Friedman, Bentley &
Finkel 1977, ACM TOMS 3(3)): visit the nearer child box first and skip any box farther
than the best squared distance so far. Boxes are skipped only when strictly farther,
so a triangle at exactly the best distance is still compared and ties keep the lower
triangle index (the rule of ``closest.nearest_triangles``): the answer is the same
whatever the tree and the thread count.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from raytrace.config import CACHE, ERROR_MODEL
from survey._kernels.closest import closest_on_triangle

#: Most triangles in a leaf.
LEAF_SIZE = 4
#: Depth of the traversal stack (a median-split tree of 2**40 triangles is 40 deep).
STACK = 96


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _select(idx, key, first, end, kth):
    """Reorder idx[first:end] so that idx[kth] holds the element of rank kth by
    key[idx] (ties by index), smaller ones before it and larger after (Hoare's
    FIND, CACM 4(7) 1961, with a median-of-three pivot; deterministic)."""
    lo, hi = first, end - 1
    while hi > lo:
        mid = (lo + hi) // 2
        a, b, c = idx[lo], idx[mid], idx[hi]
        ka, kb, kc = key[a], key[b], key[c]
        if (ka < kb) == (kb < kc):
            piv = b
        elif (kb < ka) == (ka < kc):
            piv = a
        else:
            piv = c
        kp = key[piv]
        i, j = lo, hi
        while i <= j:
            while key[idx[i]] < kp or (key[idx[i]] == kp and idx[i] < piv):
                i += 1
            while key[idx[j]] > kp or (key[idx[j]] == kp and idx[j] > piv):
                j -= 1
            if i <= j:
                idx[i], idx[j] = idx[j], idx[i]
                i += 1
                j -= 1
        if kth <= j:
            hi = j
        elif kth >= i:
            lo = i
        else:
            return


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _topology(m):
    """The tree's shape, which depends on m alone (each node halves its count):
    child (k, 2), first (k,), count (k,) in breadth-first order, and level_start
    (levels + 1,): the nodes of level L are level_start[L]:level_start[L + 1]."""
    # A split node holds more than LEAF_SIZE (>= 3) triangles, so each half gets at
    # least 2: leaves <= m / 2 and nodes = 2 leaves - 1 <= m.
    k_max = m + 2
    child = np.empty((k_max, 2), dtype=np.int64)
    first_of = np.empty(k_max, dtype=np.int64)
    count_of = np.empty(k_max, dtype=np.int64)
    level_start = np.zeros(STACK, dtype=np.int64)
    first_of[0], count_of[0] = 0, m
    n_nodes, n_levels = 1, 0
    begin, end = 0, 1                        # the level being split
    while begin < end:
        for i in range(begin, end):
            first, count = first_of[i], count_of[i]
            if count <= LEAF_SIZE:
                child[i, 0] = -1 - first
                child[i, 1] = count
                continue
            half = count // 2
            for c in range(2):
                first_of[n_nodes] = first + (half if c else 0)
                count_of[n_nodes] = (count - half) if c else half
                child[i, c] = n_nodes
                n_nodes += 1
        n_levels += 1
        level_start[n_levels] = end
        begin, end = end, n_nodes
    return (child[:n_nodes].copy(), first_of[:n_nodes].copy(), count_of[:n_nodes].copy(),
            level_start[:n_levels + 1].copy())


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def build_tree(tris):
    """Tree over the triangles tris (m, 3, 3).

    Returns (child (k, 2) int64, box (k, 2, 2, 3) float64, order (m,) int64):
    child[i] = (left, right) node indices, or (-1 - first, count) for a leaf holding
    order[first:first + count]; box[i, c] = (min, max) of child c of node i (a tree of
    one leaf: box[0, 0] is its box). Node 0 is the root. The nodes of one level own
    disjoint ranges of ``order`` and are split in parallel; the result does not depend
    on the thread count.
    """
    m = tris.shape[0]
    child, first_of, count_of, level_start = _topology(m)
    n_nodes = child.shape[0]
    order = np.arange(m)
    centre = np.empty((m, 3))
    for t in prange(m):
        for d in range(3):
            centre[t, d] = (tris[t, 0, d] + tris[t, 1, d] + tris[t, 2, d]) / 3.0
    key = np.empty(m)
    for lv in range(level_start.shape[0] - 1):
        for i in prange(level_start[lv], level_start[lv + 1]):
            if child[i, 0] < 0:
                continue
            first, count = first_of[i], count_of[i]
            c0, c1, c2 = np.inf, np.inf, np.inf
            e0, e1, e2 = -np.inf, -np.inf, -np.inf
            for k in range(first, first + count):
                t = order[k]
                c0, e0 = min(c0, centre[t, 0]), max(e0, centre[t, 0])
                c1, e1 = min(c1, centre[t, 1]), max(e1, centre[t, 1])
                c2, e2 = min(c2, centre[t, 2]), max(e2, centre[t, 2])
            axis = 0
            if e1 - c1 > e0 - c0:
                axis = 1
            if e2 - c2 > max(e0 - c0, e1 - c1):
                axis = 2
            for k in range(first, first + count):
                key[order[k]] = centre[order[k], axis]
            _select(order, key, first, first + count, first + count // 2)
    own = np.empty((n_nodes, 2, 3))
    for lv in range(level_start.shape[0] - 2, -1, -1):      # children before parents
        for i in prange(level_start[lv], level_start[lv + 1]):
            for d in range(3):
                own[i, 0, d] = np.inf
                own[i, 1, d] = -np.inf
            if child[i, 0] < 0:
                for k in range(first_of[i], first_of[i] + count_of[i]):
                    t = order[k]
                    for v in range(3):
                        for d in range(3):
                            own[i, 0, d] = min(own[i, 0, d], tris[t, v, d])
                            own[i, 1, d] = max(own[i, 1, d], tris[t, v, d])
            else:
                a, b = child[i, 0], child[i, 1]
                for d in range(3):
                    own[i, 0, d] = min(own[a, 0, d], own[b, 0, d])
                    own[i, 1, d] = max(own[a, 1, d], own[b, 1, d])
    box = np.zeros((n_nodes, 2, 2, 3))
    for i in prange(n_nodes):
        if child[i, 0] >= 0:
            box[i, 0] = own[child[i, 0]]
            box[i, 1] = own[child[i, 1]]
    if child[0, 0] < 0:
        box[0, 0] = own[0]
    return child, box, order


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _box_d2(px, py, pz, b):
    """Squared distance from p to the box b (2, 3) (0 inside)."""
    dx = max(b[0, 0] - px, 0.0, px - b[1, 0])
    dy = max(b[0, 1] - py, 0.0, py - b[1, 1])
    dz = max(b[0, 2] - pz, 0.0, pz - b[1, 2])
    return dx * dx + dy * dy + dz * dz


@njit(parallel=True, cache=CACHE, error_model=ERROR_MODEL)
def nearest_in_tree(points, tris, child, box, order, out_tri, out_q):
    """For each point (n, 3): the nearest triangle of tris (m, 3, 3) (out_tri (n,),
    ties to the lower index) and its closest point (out_q (n, 3)), through the tree of
    ``build_tree``."""
    for i in prange(points.shape[0]):
        q = np.empty(3)
        stack = np.empty(STACK, dtype=np.int64)
        stack_d = np.empty(STACK)
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        best = np.inf
        bt = -1
        stack[0] = 0
        stack_d[0] = 0.0
        top = 1
        while top > 0:
            top -= 1
            if stack_d[top] > best:                     # a nearer triangle was found since
                continue
            node = stack[top]
            a = child[node, 0]
            if a < 0:                                   # leaf
                first = -1 - a
                for k in range(first, first + child[node, 1]):
                    j = order[k]
                    closest_on_triangle(px, py, pz, tris[j, 0], tris[j, 1], tris[j, 2], q)
                    d = (q[0] - px) ** 2 + (q[1] - py) ** 2 + (q[2] - pz) ** 2
                    if d < best or (d == best and j < bt):
                        best = d
                        bt = j
                        out_q[i, 0], out_q[i, 1], out_q[i, 2] = q[0], q[1], q[2]
                continue
            d0 = _box_d2(px, py, pz, box[node, 0])
            d1 = _box_d2(px, py, pz, box[node, 1])
            b = child[node, 1]
            # Push the farther child first so that the nearer one is visited first.
            if d0 <= d1:
                if d1 <= best:
                    stack[top], stack_d[top] = b, d1
                    top += 1
                if d0 <= best:
                    stack[top], stack_d[top] = a, d0
                    top += 1
            else:
                if d0 <= best:
                    stack[top], stack_d[top] = a, d0
                    top += 1
                if d1 <= best:
                    stack[top], stack_d[top] = b, d1
                    top += 1
        out_tri[i] = bt
