"""Binned SAH BVH construction (Wald 2007) in Numba, parallel over nodes as tasks.

Reference: I. Wald, "On fast construction of SAH-based bounding volume hierarchies",
IEEE Symposium on Interactive Ray Tracing 2007 (binned SAH, bins over centroid bounds).
Parallelisation by nodes as tasks on a shared queue, work first (the scheme of TBB's
task scheduler, which Embree's binned builders run on; Wald's section 4 splits the top
levels in parallel over primitives and the subtrees as tasks).

Steps:

1. ``vertex_bounds`` and ``triangle_setup``: the mesh's bounds, and per triangle a
   36-byte primitive record (float32 box rounded outward, float32 centroid, from the
   vertices minus the local origin) and a zero-area flag, in parallel.
2. ``build_bvh``: one parallel region for the whole tree. The root is the first task of
   a queue; a worker takes a task, splits the node (bins, SAH sweep, in-place Hoare
   partition of its rows), publishes the right child as a new task and goes on with
   the left child, until a node has at most ``stop`` rows: that subtree it builds
   alone, depth first, into a node range it reserves from a shared counter
   (``tasks.fetch_add``). Idle workers take published tasks as they appear, so two
   workers are busy from the second level on, and a worker descheduled on a loaded
   machine simply takes fewer tasks (DECISION: this replaced a breadth-first top phase
   that binned and partitioned each level over work items in two parallel regions a
   level, with a stable partition into a second row buffer: ~11 parallel regions, each
   waiting for every thread, 36 MB of extra buffers and an extra copy of every row;
   the build's CPU time fell from 0.48 to 0.34 s at 0.81M triangles with the same
   tree). Primitive records are partitioned physically (rows moved with their triangle
   index), so every pass reads memory sequentially. Bin boxes are eight float32 lanes
   grown by one packed operation (``bounds8.grow8``; a minimum or maximum of float32
   values is exact, so the tree is the one float64 bins would give). The tree, the row
   order and the leaves' slots do not depend on the thread count or timing: each node
   is split by the same serial code on its own rows. Work O(n log n); no Python loop
   over triangles.
3. ``collapse.to_wide_layout`` (its own module): collapses the binary tree into 8-wide
   records (the traversal layout, see ``traverse.py``) and collects the tree statistics;
   ``collapse.pack_records`` writes the traversal's padded float32 records.

Build arrays (explicit child pointers; node order is irrelevant, only the walk matters)::

    node_box  (2m - 1, 6) float32   min x, min y, min z, max x, max y, max z
    node_meta (2m - 1, 4) int32     left child, right child, first slot, count
                                    (count 0: internal; count > 0: leaf
                                    [first, first + count))

    bin boxes (3 bins, 8) float32   per axis and bin: min x, y, z, max x, y, z, 2 spare
                                    lanes (32 bytes, one AVX register; ``bounds8``)

    task queue (``build_top``)      tq (m, 3) int64: node, first row, end row;
                                    tq_box (m, 12) float64: box, centroid box;
                                    ready (m,) int64: slot published; ctl (4,) int64:
                                    HEAD (next slot to take), TAIL (next slot to fill),
                                    OPEN (tasks not finished), NEXT (next free node).
                                    Only the slots used are touched (a few per 4096
                                    triangles), so the rest cost no memory.

The boxes are conservative: primitive boxes are rounded outward to float32, and unions
(min/max) of float32 values are exact.

Sizing: the queue's splits and the subtrees together use at most 2m - 1 nodes: with P
subtrees of c_k triangles built alone, the nodes split from the queue are P - 1 and
their children (2 each) include the P subtree roots, and a subtree needs at most
2 c_k - 2 nodes besides its root: 1 + 2 (P - 1) + sum(2 c_k - 2) = 2m - 1.
"""

from __future__ import annotations

import numba
import numpy as np
from numba import njit, prange

from ..config import BUILD_FASTMATH, CACHE, ERROR_MODEL
from .bounds8 import BOX_LANES, grow8, next_down32, next_up32
from .tasks import atomic_load, fetch_add

#: Fields of a primitive record (float32 each; a record is _ROW floats, 36 bytes).
_LO, _HI, _CE = 0, 3, 6
_ROW = 9
#: float32 lanes of a bin box (bounds8.BOX_LANES).
_BL = BOX_LANES


#: Vertices per work item of ``vertex_bounds`` (a fixed size: the result is a min/max,
#: the same for any split, but fixed items keep the work independent of the threads).
_BOUNDS_ITEM = 16384


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def vertex_bounds(verts):
    """Per-axis minimum and maximum of verts (n, 3) float64 (finite): (lo, hi) (3,)
    float64 each, in parallel work items (min/max are exact, so equal to NumPy's
    ``verts.min(0)``, ``verts.max(0)``)."""
    n = verts.shape[0]
    n_items = (n + _BOUNDS_ITEM - 1) // _BOUNDS_ITEM
    part = np.empty((n_items, 6))
    for w in prange(n_items):
        j0 = w * _BOUNDS_ITEM
        j1 = min(n, j0 + _BOUNDS_ITEM)
        lx = verts[j0, 0]
        ly = verts[j0, 1]
        lz = verts[j0, 2]
        hx = lx
        hy = ly
        hz = lz
        for j in range(j0 + 1, j1):
            x = verts[j, 0]
            y = verts[j, 1]
            z = verts[j, 2]
            lx = min(lx, x)
            ly = min(ly, y)
            lz = min(lz, z)
            hx = max(hx, x)
            hy = max(hy, y)
            hz = max(hz, z)
        part[w, 0] = lx
        part[w, 1] = ly
        part[w, 2] = lz
        part[w, 3] = hx
        part[w, 4] = hy
        part[w, 5] = hz
    lo = part[0, :3].copy()
    hi = part[0, 3:].copy()
    for w in range(1, n_items):
        for k in range(3):
            lo[k] = min(lo[k], part[w, k])
            hi[k] = max(hi[k], part[w, 3 + k])
    return lo, hi


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def triangle_setup(verts, origin, faces, area_rel, prim, good):
    """Primitive records and zero-area flags.

    verts (n, 3) float64; origin (3,) float64, the local frame's origin (each
    coordinate is taken as ``verts[i, k] - origin[k]``, the same float64 subtraction as
    NumPy's ``verts - origin``; DECISION: done here rather than on a local copy of the
    vertices: one pass and 24 B a vertex less, and the copy was a serial NumPy pass of
    ~20 ms at 0.4M vertices); faces (m, 3) int64. Writes prim (m, 9) float32: box min
    (0:3) rounded down, box max (3:6) rounded up, centroid (6:9); and good (m,) bool:
    |e1 x e2| > area_rel * (longest edge)^2.
    """
    for i in prange(faces.shape[0]):
        a = faces[i, 0]
        b = faces[i, 1]
        c = faces[i, 2]
        pa0 = verts[a, 0] - origin[0]
        pa1 = verts[a, 1] - origin[1]
        pa2 = verts[a, 2] - origin[2]
        pb0 = verts[b, 0] - origin[0]
        pb1 = verts[b, 1] - origin[1]
        pb2 = verts[b, 2] - origin[2]
        pc0 = verts[c, 0] - origin[0]
        pc1 = verts[c, 1] - origin[1]
        pc2 = verts[c, 2] - origin[2]
        _setup_axis(pa0, pb0, pc0, prim, i, 0)
        _setup_axis(pa1, pb1, pc1, prim, i, 1)
        _setup_axis(pa2, pb2, pc2, prim, i, 2)
        e1x = pb0 - pa0
        e1y = pb1 - pa1
        e1z = pb2 - pa2
        e2x = pc0 - pa0
        e2y = pc1 - pa1
        e2z = pc2 - pa2
        cx = e1y * e2z - e1z * e2y
        cy = e1z * e2x - e1x * e2z
        cz = e1x * e2y - e1y * e2x
        l1 = e1x * e1x + e1y * e1y + e1z * e1z
        l2 = e2x * e2x + e2y * e2y + e2z * e2z
        l3 = (e2x - e1x) ** 2 + (e2y - e1y) ** 2 + (e2z - e1z) ** 2
        longest = max(l1, max(l2, l3))
        good[i] = np.sqrt(cx * cx + cy * cy + cz * cz) > area_rel * longest


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _setup_axis(p, q, r, prim, i, k):
    """Axis k of primitive record i from its three vertex coordinates p, q, r."""
    lo = min(p, min(q, r))
    hi = max(p, max(q, r))
    # Rounded outward by selects, not branches: whether float32 rounding went up or
    # down is as good as random, and the mispredicted branches were most of this
    # kernel's time.
    lo32 = np.float32(lo)
    down = next_down32(lo32)
    lo32 = down if lo32 > lo else lo32
    hi32 = np.float32(hi)
    up = next_up32(hi32)
    hi32 = up if hi32 < hi else hi32
    prim[i, _LO + k] = lo32
    prim[i, _HI + k] = hi32
    prim[i, _CE + k] = (p + q + r) / 3.0


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def slot_triangles(verts, origin, faces, order, out):
    """Triangle records in leaf order: out[j] = v0, e1 = v1 - v0, e2 = v2 - v0 of face
    order[j] (float64, in the local frame of ``origin``, coordinates formed as in
    ``triangle_setup``), the layout the traversal reads."""
    for j in prange(order.shape[0]):
        i = order[j]
        a = faces[i, 0]
        b = faces[i, 1]
        c = faces[i, 2]
        for k in range(3):
            p = verts[a, k] - origin[k]
            out[j, k] = p
            out[j, 3 + k] = (verts[b, k] - origin[k]) - p
            out[j, 6 + k] = (verts[c, k] - origin[k]) - p


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
def half_area(b):
    dx = b[3] - b[0]
    dy = b[4] - b[1]
    dz = b[5] - b[2]
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
    """Box (6,) and centroid box (6,) of rows [s, e), float64 (of float32 values: exact).
    Running values in float32 locals, stored once (an array accumulator was reloaded
    after every store)."""
    inf32 = np.float32(np.inf)
    b0, b1, b2, b3, b4, b5 = inf32, inf32, inf32, -inf32, -inf32, -inf32
    q0, q1, q2, q3, q4, q5 = inf32, inf32, inf32, -inf32, -inf32, -inf32
    for j in range(s, e):
        b0 = min(b0, prim[j, _LO])
        b1 = min(b1, prim[j, _LO + 1])
        b2 = min(b2, prim[j, _LO + 2])
        b3 = max(b3, prim[j, _HI])
        b4 = max(b4, prim[j, _HI + 1])
        b5 = max(b5, prim[j, _HI + 2])
        q0 = min(q0, prim[j, _CE])
        q1 = min(q1, prim[j, _CE + 1])
        q2 = min(q2, prim[j, _CE + 2])
        q3 = max(q3, prim[j, _CE])
        q4 = max(q4, prim[j, _CE + 1])
        q5 = max(q5, prim[j, _CE + 2])
    box[0], box[1], box[2], box[3], box[4], box[5] = b0, b1, b2, b3, b4, b5
    cbox[0], cbox[1], cbox[2], cbox[3], cbox[4], cbox[5] = q0, q1, q2, q3, q4, q5


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
def _bin_of(x, lo, scale, nb):
    """Bin of centroid coordinate x (one formula for binning and partitioning, so a
    row always goes to the side its bin was counted on)."""
    k = int((x - lo) * scale)
    return min(nb - 1, max(0, k))


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
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
    a n_bins + k is bin k of axis a.

    DECISION: the node's bin origin and scales are read into locals once: indexed
    inside the loop, every ``grow8`` store (which
    may alias them as far as LLVM knows) forced a reload of cbox and scale for the
    next row. No ``reshape`` to flat views: each costs a library call (~50 ns), which
    is most of the binning of a 4-row node."""
    lo0 = cbox[0]
    lo1 = cbox[1]
    lo2 = cbox[2]
    s0 = scale[0]
    s1 = scale[1]
    s2 = scale[2]
    o1 = b_cnt.shape[1]
    o2 = 2 * o1
    for j in range(s, e):
        q = j * _ROW
        if s0 > 0.0:
            k = _bin_of(prim[j, _CE], lo0, s0, nb)
            b_cnt[0, k] += 1
            grow8(b_box, k * _BL, prim, q)
        if s1 > 0.0:
            k = _bin_of(prim[j, _CE + 1], lo1, s1, nb)
            b_cnt[1, k] += 1
            grow8(b_box, (k + o1) * _BL, prim, q)
        if s2 > 0.0:
            k = _bin_of(prim[j, _CE + 2], lo2, s2, nb)
            b_cnt[2, k] += 1
            grow8(b_box, (k + o2) * _BL, prim, q)


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
def _half_area6(lx, ly, lz, hx, hy, hz):
    """``half_area`` of the float32 box (lx, ly, lz)-(hx, hy, hz), computed in float64
    (the SAH costs of the bins; an empty box, min > max, has area 0)."""
    dx = np.float64(hx) - np.float64(lx)
    dy = np.float64(hy) - np.float64(ly)
    dz = np.float64(hz) - np.float64(lz)
    if dx < 0.0 or dy < 0.0 or dz < 0.0:
        return 0.0
    return dx * dy + dy * dz + dz * dx


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
def _best_split(b_cnt, b_box, nb, scale, r_area, r_cnt):
    """SAH sweep over the bins (Wald 2007): (cost sum, axis, last bin of the left side);
    axis -1 when no split separates the centroids. The cost of a split after bin k is
    A_L N_L + A_R N_R (half areas; scaled to C_trav + C_isect * cost / A_parent by the
    caller).

    DECISION: the running box is six float32 locals, not an 8-lane array row: the
    row's view and its store/reload per bin made the sweep of a 16-row node cost
    ~1.5 us, more than binning its rows (min/max of float32 values is exact either
    way, so the costs and the tree are unchanged). Empty bins are skipped: a node of
    n < 16 rows gets n bins, about a third of them empty for uniform centroids (1 / e)."""
    n_bins = b_cnt.shape[1]
    best_cost = np.inf
    best_axis = -1
    best_k = -1
    inf32 = np.float32(np.inf)
    for a in range(3):
        if scale[a] == 0.0:
            continue
        base = a * n_bins
        # Sweep from the right, then from the left.
        lx = inf32
        ly = inf32
        lz = inf32
        hx = -inf32
        hy = -inf32
        hz = -inf32
        n_acc = 0
        for k in range(nb - 1, 0, -1):
            r = base + k
            if b_cnt[a, k] == 0 and k < nb - 1:
                # An empty bin changes neither the count nor the box.
                r_cnt[k] = n_acc
                r_area[k] = r_area[k + 1]
                continue
            n_acc += b_cnt[a, k]
            lx = min(lx, b_box[r, 0])
            ly = min(ly, b_box[r, 1])
            lz = min(lz, b_box[r, 2])
            hx = max(hx, b_box[r, 3])
            hy = max(hy, b_box[r, 4])
            hz = max(hz, b_box[r, 5])
            r_cnt[k] = n_acc
            r_area[k] = _half_area6(lx, ly, lz, hx, hy, hz)
        lx = inf32
        ly = inf32
        lz = inf32
        hx = -inf32
        hy = -inf32
        hz = -inf32
        n_acc = 0
        for k in range(nb - 1):
            r = base + k
            if b_cnt[a, k] == 0:
                # Same sides as after bin k - 1: the same cost, which cannot be
                # strictly lower (or a side is empty there too).
                continue
            n_acc += b_cnt[a, k]
            lx = min(lx, b_box[r, 0])
            ly = min(ly, b_box[r, 1])
            lz = min(lz, b_box[r, 2])
            hx = max(hx, b_box[r, 3])
            hy = max(hy, b_box[r, 4])
            hz = max(hz, b_box[r, 5])
            n_r = r_cnt[k + 1]
            if n_acc == 0 or n_r == 0:
                continue
            cost = _half_area6(lx, ly, lz, hx, hy, hz) * n_acc + r_area[k + 1] * n_r
            if cost < best_cost:
                best_cost = cost
                best_axis = a
                best_k = k
    return best_cost, best_axis, best_k


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
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


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
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


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
def _grow6(b0, b1, b2, b3, b4, b5, x, y, z):
    """The box (b0, b1, b2)-(b3, b4, b5) grown by the point (x, y, z) (scalars only:
    no array, so no reference counting where it is inlined)."""
    return min(b0, x), min(b1, y), min(b2, z), max(b3, x), max(b4, y), max(b5, z)


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, inline="always")
def _split(prim, idx, s, e, box, cbox, n_bins, all_axes, c_trav, c_isect, max_leaf,
           max_leaf_forced, b_cnt, b_box, r_area, r_cnt, scale, out):
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
        best_cost, best_axis, best_k = _best_split(b_cnt, b_box, nb, scale, r_area, r_cnt)
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
    inf32 = np.float32(np.inf)
    # Centroid boxes of the two sides in float32 locals (exact: min/max).
    l0 = inf32
    l1 = inf32
    l2 = inf32
    l3 = -inf32
    l4 = -inf32
    l5 = -inf32
    r0 = inf32
    r1 = inf32
    r2 = inf32
    r3 = -inf32
    r4 = -inf32
    r5 = -inf32
    # Two-sided Hoare partition (Hoare 1962): scan from both ends and swap a right-side
    # row found from the left with a left-side row found from the right, so rows
    # already on their side (most of them, in a mesh's spatially ordered rows) are never
    # moved. DECISION: replaced a one-sided scan that swapped every right-side row with
    # the last unscanned one; the children's rows are the same sets (the tree is
    # unchanged), only their order inside a child differs.
    i = s
    j = e - 1
    while True:
        while i <= j and _bin_of(prim[i, _CE + a], lo, sc, nb) <= best_k:
            l0, l1, l2, l3, l4, l5 = _grow6(l0, l1, l2, l3, l4, l5, prim[i, _CE],
                                            prim[i, _CE + 1], prim[i, _CE + 2])
            i += 1
        if i > j:
            break
        # Row i belongs right.
        while j > i and _bin_of(prim[j, _CE + a], lo, sc, nb) > best_k:
            r0, r1, r2, r3, r4, r5 = _grow6(r0, r1, r2, r3, r4, r5, prim[j, _CE],
                                            prim[j, _CE + 1], prim[j, _CE + 2])
            j -= 1
        r0, r1, r2, r3, r4, r5 = _grow6(r0, r1, r2, r3, r4, r5, prim[i, _CE],
                                        prim[i, _CE + 1], prim[i, _CE + 2])
        if j == i:
            break
        # Row j belongs left: swap it with row i.
        l0, l1, l2, l3, l4, l5 = _grow6(l0, l1, l2, l3, l4, l5, prim[j, _CE],
                                        prim[j, _CE + 1], prim[j, _CE + 2])
        for c in range(_ROW):
            tmp = prim[i, c]
            prim[i, c] = prim[j, c]
            prim[j, c] = tmp
        ti = idx[i]
        idx[i] = idx[j]
        idx[j] = ti
        i += 1
        j -= 1
    out[2, 0] = l0
    out[2, 1] = l1
    out[2, 2] = l2
    out[2, 3] = l3
    out[2, 4] = l4
    out[2, 5] = l5
    out[3, 0] = r0
    out[3, 1] = r1
    out[3, 2] = r2
    out[3, 3] = r3
    out[3, 4] = r4
    out[3, 5] = r5
    return i


# DECISION: compiled without reference counting (``_nrt=False``; it allocates nothing;
# so is ``_task_loop``).
# With it, every node's inlined ``_split`` took a reference to each of its ten array
# arguments and dropped it again: twenty atomic operations a node, ~13 % of the
# subtree phase serially (perf), and the ones on ``prim``/``idx``, which both worker
# threads share, bounce a cache line between the cores.
@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, _nrt=False)
def _grow_loop(prim, idx, s0, e0, root, next_free, box0, cbox0, n_bins, all_axes, c_trav,
               c_isect, max_leaf, max_leaf_forced, node_box, node_meta, t_s, t_e, t_node,
               t_box, b_cnt, b_box, r_area, r_cnt, scale, out, box, cbox):
    """Build the tree over rows [s0, e0) with its root at node ``root`` and further
    nodes allocated from ``next_free`` on (depth first, serial, in place), in the
    caller's work arrays. Returns the next free node."""
    t_s[0] = s0
    t_e[0] = e0
    t_node[0] = root
    for c in range(6):
        t_box[0, c] = box0[c]
        t_box[0, 6 + c] = cbox0[c]
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
                     max_leaf, max_leaf_forced, b_cnt, b_box, r_area, r_cnt, scale,
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
        # Push right first so the left subtree is built (and allocated) first. Element
        # loops, not row slices: a slice is an array view, and each view's reference
        # count is an atomic operation on an array the other worker shares.
        t_s[sp] = mid
        t_e[sp] = e
        t_node[sp] = right
        for c in range(6):
            t_box[sp, c] = out[1, c]
            t_box[sp, 6 + c] = out[3, c]
        sp += 1
        t_s[sp] = s
        t_e[sp] = mid
        t_node[sp] = left
        for c in range(6):
            t_box[sp, c] = out[0, c]
            t_box[sp, 6 + c] = out[2, c]
        sp += 1
    return next_free


# ---------------------------------------------------------------------------------------
# Parallel build: nodes as tasks on a shared queue (work first, as TBB/Embree schedule)
# ---------------------------------------------------------------------------------------
#: Control counters of the task queue (one int64 each, ``tasks.fetch_add``).
_HEAD, _TAIL, _OPEN, _NEXT = 0, 1, 2, 3


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, _nrt=False)
def _task_loop(prim, idx, tq, tq_box, ctl, ready, n_bins, all_axes, c_trav, c_isect,
               max_leaf, max_leaf_forced, stop, node_box, node_meta, t_s, t_e, t_node,
               t_box, b_cnt, b_box, r_area, r_cnt, scale, out, box, cbox, box0, cbox0):
    """One worker of ``_grow_pending``: take tasks from the queue until none is open.

    A task is a node over rows [s, e) whose box and centroid box are known. A worker
    splits it in place (``_split``: binned SAH and an in-place partition), publishes
    the right child as a new task and goes on with the left one (work first), until
    the node has at most ``stop`` rows: that subtree it builds alone, depth first
    (``_grow_loop``), into a node range it reserves from the shared counter.

    Queue protocol (``tasks.fetch_add`` is sequentially consistent): a worker takes
    slot q = HEAD++, then waits until ``ready[q]`` is set or no task is open (OPEN = 0:
    none can be published any more, so it stops). A task is counted in OPEN before its
    slot is reserved (TAIL++) and published (``ready[slot]``), and leaves OPEN when the
    worker that took it is done with it and with everything it went on with, so OPEN
    cannot reach 0 while a task could still be published.
    """
    cap = tq.shape[0]
    while True:
        q = fetch_add(ctl, _HEAD, 1)
        if q >= cap:
            return
        while atomic_load(ready, q) == 0:
            if atomic_load(ctl, _OPEN) == 0:
                return
        node = tq[q, 0]
        s = tq[q, 1]
        e = tq[q, 2]
        for c in range(6):
            box0[c] = tq_box[q, c]
            cbox0[c] = tq_box[q, 6 + c]
        while True:
            count = e - s
            if count <= stop:
                base = fetch_add(ctl, _NEXT, max(0, 2 * count - 2))
                _grow_loop(prim, idx, s, e, node, base, box0, cbox0, n_bins, all_axes,
                           c_trav, c_isect, max_leaf, max_leaf_forced, node_box, node_meta,
                           t_s, t_e, t_node, t_box, b_cnt, b_box, r_area, r_cnt, scale, out,
                           box, cbox)
                break
            for c in range(6):
                box[c] = box0[c]
                cbox[c] = cbox0[c]
                node_box[node, c] = box0[c]
            mid = _split(prim, idx, s, e, box, cbox, n_bins, all_axes, c_trav, c_isect,
                         max_leaf, max_leaf_forced, b_cnt, b_box, r_area, r_cnt, scale, out)
            if mid < 0:
                node_meta[node, 0] = -1
                node_meta[node, 1] = -1
                node_meta[node, 2] = s
                node_meta[node, 3] = count
                break
            left = fetch_add(ctl, _NEXT, 2)
            node_meta[node, 0] = left
            node_meta[node, 1] = left + 1
            node_meta[node, 2] = s
            node_meta[node, 3] = 0
            # Publish the right child: its rows, box and centroid box first, then the
            # flag (the fetch_add orders the stores before it).
            fetch_add(ctl, _OPEN, 1)
            slot = fetch_add(ctl, _TAIL, 1)
            tq[slot, 0] = left + 1
            tq[slot, 1] = mid
            tq[slot, 2] = e
            for c in range(6):
                tq_box[slot, c] = out[1, c]
                tq_box[slot, 6 + c] = out[3, c]
            fetch_add(ready, slot, 1)
            # Go on with the left child.
            node = left
            e = mid
            for c in range(6):
                box0[c] = out[0, c]
                cbox0[c] = out[2, c]
        fetch_add(ctl, _OPEN, -1)


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH)
def _task_worker(prim, idx, tq, tq_box, ctl, ready, n_bins, all_axes, c_trav, c_isect,
                 max_leaf, max_leaf_forced, stop, node_box, node_meta):
    """A worker's own work arrays, then ``_task_loop``."""
    cap = min(prim.shape[0], stop) + 1
    t_s = np.empty(cap, dtype=np.int64)
    t_e = np.empty(cap, dtype=np.int64)
    t_node = np.empty(cap, dtype=np.int64)
    t_box = np.empty((cap, 12))
    b_cnt = np.zeros((3, n_bins), dtype=np.int64)
    b_box = np.empty((3 * n_bins, _BL), dtype=np.float32)
    r_area = np.empty(n_bins)
    r_cnt = np.empty(n_bins, dtype=np.int64)
    scale = np.zeros(3)
    out = np.empty((4, 6))
    box = np.empty(6)
    cbox = np.empty(6)
    box0 = np.empty(6)
    cbox0 = np.empty(6)
    _task_loop(prim, idx, tq, tq_box, ctl, ready, n_bins, all_axes, c_trav, c_isect,
               max_leaf, max_leaf_forced, stop, node_box, node_meta, t_s, t_e, t_node,
               t_box, b_cnt, b_box, r_area, r_cnt, scale, out, box, cbox, box0, cbox0)


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, parallel=True)
def _grow_pending(prim, idx, tq, tq_box, ctl, ready, n_bins, all_axes, c_trav, c_isect,
                  max_leaf, max_leaf_forced, stop, node_box, node_meta, workers):
    """Run ``workers`` task workers (``_task_loop``) on the queue ``build_top`` set up:
    one parallel region for the whole tree. Numba's OpenMP layer alone would give each
    thread a fixed half of a list known in advance; here the list grows as nodes are
    split, and a worker that is descheduled on a loaded machine simply takes fewer
    tasks."""
    for _ in prange(workers):
        _task_worker(prim, idx, tq, tq_box, ctl, ready, n_bins, all_axes, c_trav, c_isect,
                     max_leaf, max_leaf_forced, stop, node_box, node_meta)


#: Rows per work item of ``root_bounds`` (fixed, so the work does not depend on the
#: thread count; the result, a min/max, does not either way).
_ROOT_ITEM = 16384


@njit(cache=CACHE, error_model=ERROR_MODEL, fastmath=BUILD_FASTMATH, parallel=True)
def root_bounds(prim):
    """Box and centroid box (6,) float64 each of all rows, in parallel work items
    (``_bounds`` on each; min/max are exact, so the result is ``_bounds`` of all)."""
    m = prim.shape[0]
    n_items = max(1, (m + _ROOT_ITEM - 1) // _ROOT_ITEM)
    part = np.empty((n_items, 12))
    for w in prange(n_items):
        _bounds(prim, w * _ROOT_ITEM, min(m, (w + 1) * _ROOT_ITEM), part[w, :6],
                part[w, 6:])
    box = part[0, :6].copy()
    cbox = part[0, 6:].copy()
    for w in range(1, n_items):
        for c in range(3):
            box[c] = min(box[c], part[w, c])
            box[3 + c] = max(box[3 + c], part[w, 3 + c])
            cbox[c] = min(cbox[c], part[w, 6 + c])
            cbox[3 + c] = max(cbox[3 + c], part[w, 9 + c])
    return box, cbox


@njit(cache=CACHE, error_model=ERROR_MODEL)
def build_top(prim, box, cbox):
    """Node arrays (2m - 1 rows) and the task queue holding the root (node 0, all rows,
    its box and centroid box from ``root_bounds``): (node_box, node_meta, tq, tq_box,
    ctl, ready).

    The queue has a slot for every task a build can publish (at most one per split
    node: m - 1) plus the root; np.empty/np.zeros leave the pages of unused slots
    untouched."""
    m = prim.shape[0]
    n_nodes = 2 * m - 1
    node_box = np.empty((n_nodes, 6), dtype=np.float32)
    # DECISION: np.empty: every node reached from the root gets its row written, the
    # others are never read; np.zeros cost a 26 MB memset (~0.02 s at 0.8M triangles).
    node_meta = np.empty((n_nodes, 4), dtype=np.int32)
    tq = np.empty((m, 3), dtype=np.int64)
    tq_box = np.empty((m, 12))
    ready = np.zeros(m, dtype=np.int64)
    ctl = np.zeros(4, dtype=np.int64)
    tq[0, 0] = 0
    tq[0, 1] = 0
    tq[0, 2] = m
    for c in range(6):
        tq_box[0, c] = box[c]
        tq_box[0, 6 + c] = cbox[c]
    ready[0] = 1
    ctl[_TAIL] = 1
    ctl[_OPEN] = 1
    ctl[_NEXT] = 1
    return node_box, node_meta, tq, tq_box, ctl, ready


def build_bvh(prim, idx, n_bins, all_axes, c_trav, c_isect, max_leaf, max_leaf_forced, stop,
              workers=None):
    """Binned SAH BVH over the primitive rows (permuted in place together with idx).

    ``prim`` (m, 9) float32 C-contiguous (``triangle_setup``); ``idx`` (m,) int32 or
    int64 (the scene passes int32).
    ``all_axes``: bin along all three axes (Wald 2007) or only along the axis of largest
    centroid extent (3x less binning work, the usual fast-builder shortcut). ``stop``:
    a node of at most ``stop`` rows is built by one worker alone; larger nodes are
    split one at a time by whichever worker takes them from the shared queue.
    ``workers``: worker threads (default: Numba's thread count).

    Returns node_box (2m - 1, 6) float32 and node_meta (2m - 1, 4) int32 with the root
    at 0 (rows not reached from the root are unused). The tree, the row order and the
    leaves' slots do not depend on the workers or their timing (every node is split by
    the same serial code, in place, on its own rows); only the numbering of the binary
    nodes does, and nothing downstream reads it (``collapse`` walks from the root).
    """
    if workers is None:
        workers = numba.get_num_threads()
    box, cbox = root_bounds(prim)
    node_box, node_meta, tq, tq_box, ctl, ready = build_top(prim, box, cbox)
    _grow_pending(prim, idx, tq, tq_box, ctl, ready, n_bins, all_axes, c_trav, c_isect,
                  max_leaf, max_leaf_forced, max(1, stop), node_box, node_meta, workers)
    return node_box, node_meta
