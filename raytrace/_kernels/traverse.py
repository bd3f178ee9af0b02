"""Stack-based BVH traversal over 8-wide records: closest hit and any hit, ``prange``
over ray blocks.

Layout read here (made by ``collapse.to_wide_layout`` with width 8 and packed by
``scene._pack_nodes``; boxes float32, rounded outward)::

    nodes (n8, 64) float32   per record: child boxes as structure of arrays, 0:48 =
                             min x[8], min y[8], min z[8], max x[8], max y[8], max z[8]
                             (read as <8 x float> by ``simd.slab8``); 256 bytes, four
                             cache lines
    links (n8, 64) int32     the same memory seen as int32: 48:56 = child (record index,
                             or first triangle slot of a leaf), 56:64 = triangle count
                             (0: internal child or unused lane)
    tris  (m, 9) float64     per slot (leaf order): v0, e1 = v1 - v0, e2 = v2 - v0, in
                             the scene's local frame (72 B, one contiguous run a leaf)
    ids   (m,) int32         slot -> input triangle index (for the tie-break)

Traversal (nearest child first, as in pbrt-v4 and Embree's BVH8): a visit tests the
eight child boxes at once (``simd.slab8``: packed float32 slab test) and splits the hit
lanes into leaves and internal children with one packed compare of the eight counts
(``simd.leaf8``); it intersects the leaf children (nearer first, ordered by
``simd.order8``, a bitonic network, when there are several: a hit tightens t before
farther boxes are judged), then goes to the nearest internal child and pushes the
others, farthest first, with their entry distances; a popped record whose entry
distance exceeds the current closest hit is skipped. One or two internal children
(most visits) take no sorting network and no stack of the visit's children.

Leaves of at least ``intersect.GROUP_MIN`` triangles are tested four slots at a time
(``intersect.mt4``, one ``<4 x double>`` Möller–Trumbore whose lanes are bit for bit
the scalar test): the answers do not change, only the work.

Exactness of the float32 box test: the ray origin enters the test rounded to float32 in
the direction that can only widen the slab interval (``simd.axis_setup``), and the exit
distance is scaled by 1 + 2 gamma(3) (Ize 2013), so a box the exact float64 ray touches
is never culled; an entry distance may exceed the exact one by ``simd.ENTRY_SLACK``
(relative), so it is compared with the float64 t only after that allowance. Triangle
tests are the float64 ``intersect.moller_trumbore``, unchanged.

Determinism: the closest hit is the minimum of (t, input index) over all triangles the
ray hits within [t_min, t_max] — a total order, so the result does not depend on the
visiting order, the block split or the thread count. Rays run in fixed-size blocks
(``config.RAY_BLOCK``). ``trace_closest`` and ``trace_any`` can test a previous ray's
triangle first ("warm start": ``any_hit`` and the cube-map kernels do; ``closest_hit``
no longer does, see ``_closest_block``). It changes only the work, never the result.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..config import CACHE, ERROR_MODEL, RAY_BLOCK
from .intersect import GROUP, GROUP_MIN, closer, moller_trumbore, mt4
from .simd import (ENTRY_SLACK, LANES, PLANES, axis_setup_fast, int32_at, leaf8, lowest_lane,
                   order8, round_down32_fast, round_up32_fast, slab8)
from .tasks import fetch_add

#: float32 columns of one record: 48 planes, 8 child links, 8 counts.
RECORD = PLANES + 2 * LANES
#: First int32 column of the child links and of the counts.
CHILD = PLANES
COUNT = PLANES + LANES


@njit(cache=CACHE, error_model=ERROR_MODEL)
def new_scratch(stack_size):
    """Per-worker buffers of ``trace_closest`` / ``trace_any``: the stack (records and
    entry distances), the eight entry distances of a visit (float32) and the ordered
    internal children of a visit (records, distances)."""
    return (np.empty(stack_size, dtype=np.int64), np.empty(stack_size),
            np.empty(LANES, dtype=np.float32), np.empty(LANES, dtype=np.int64),
            np.empty(LANES))


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _visit_order(mask, sd):
    """(count, order) of ``simd.order8``, with a shortcut for at most one hit lane.

    DECISION: most visits hit a single child box (box hits per visit ~1.04 on the
    1M-triangle benchmark tunnel, coherent and random rays alike), where the bitonic
    network has nothing to sort; the shortcut took 300 -> 220 ns a coherent ray and
    990 -> 850 ns a random ray (one thread, CPU time, counting kernel; issue 33).
    """
    if mask & (mask - 1) == 0:
        if mask == 0:
            return 0, 0
        lane = 0
        while mask > 1:
            mask >>= 1
            lane += 1
        return 1, lane
    return order8(mask, sd)


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def take_hit(t, u, v, ids, k):
    """The state of a closest-hit search once the hit (t, u, v) on slot k has passed
    ``closer``: (t, input index, slot, u, v, hi32, cull), hi32 the float32 bound of the
    box test (``round_up32_fast``) and cull the entry-distance bound (t times
    ``ENTRY_SLACK``) that follow the new t. The one place a closest-hit loop (this
    walk's leaves, the cube-map lists) takes a hit; a caller that culls no boxes drops
    the last two, and the compiler with them.

    DECISION: called only where ``closer`` passed, so the bounds are rounded once a
    closer hit, as when the update was written out in each loop: ``closest_hit`` and
    the whole cube map's ``_view_block`` compile to the same machine code as that form
    (normalised ``inspect_asm``). Setting the bounds once a leaf instead (the update
    then without them) changed the code and measured 1-3 % slower in the median (bfo,
    one thread, seven alternations, drive 194 -> 198, station 158 -> 163 ns a ray)."""
    return t, ids[k], k, u, v, round_up32_fast(t), t * ENTRY_SLACK


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def trace_closest(nodes, links, tris, ids, ox, oy, oz, dx, dy, dz, t0, t1, prev,
                  st_node, st_dist, sd, cn, cd):
    """Closest hit of one ray o + t d, t in [t0, t1], through the BVH.

    ``prev`` (a slot, or -1) is tested first to tighten t1 (warm start). ``st_node``,
    ``st_dist`` (stack), ``sd`` (8 float32), ``cn``, ``cd`` (8) are the caller's scratch
    buffers (``new_scratch``; ``cn`` and ``cd`` are no longer written, kept so that the
    callers stay as they are). Returns (t, input index, slot, u, v); slot -1 and t = t1
    on a miss.

    Float32 roundings of the ray (``simd.axis_setup_fast``, ``round_up32_fast``) are
    bit for bit those of ``simd.axis_setup`` / ``round_up32``, without library calls.
    """
    nx, onx, ofx, ix = axis_setup_fast(ox, dx)
    ny, ony, ofy, iy = axis_setup_fast(oy, dy)
    nz, onz, ofz, iz = axis_setup_fast(oz, dz)
    lo32 = round_down32_fast(t0)
    best_t = t1
    best_id = -1
    best_slot = -1
    best_u = 0.0
    best_v = 0.0
    if prev >= 0:
        t, u, v = moller_trumbore(tris, prev, ox, oy, oz, dx, dy, dz)
        if closer(t, ids, prev, t0, best_t, best_id):
            best_t, best_id, best_slot, best_u, best_v, _, _ = take_hit(t, u, v, ids, prev)
    hi32 = round_up32_fast(best_t)
    cull = best_t * ENTRY_SLACK
    sp = 0
    cur = 0
    while cur >= 0:
        base = cur * RECORD
        mask = slab8(nodes, base, nx, ny, nz, onx, ony, onz, ofx, ofy, ofz,
                     ix, iy, iz, lo32, hi32, sd)
        # DECISION: split the hit lanes into leaves and internal children with two mask
        # operations (``leaf8``: the eight counts compared at once), not a branch per
        # lane: a visit then costs its control flow only where there is work. Most
        # visits hit no leaf and one or two internal children (bfo, drive rays, per ray:
        # 9.0 visits, 4.0 one internal child, 1.3 two, 2.1 none, 1.2 with leaves; issue 33).
        leaf = mask & leaf8(links, base + COUNT)
        inner = mask ^ leaf
        if leaf != 0:
            # Leaves nearest first: each hit tightens t before farther boxes are judged.
            if leaf & (leaf - 1) == 0:
                k = 1
                order = lowest_lane(leaf)
            else:
                k, order = order8(leaf, sd)
            for q in range(k):
                lane = (order >> (4 * q)) & 15
                # DECISION: skip, not stop: order8's keys drop the distance's low 3
                # bits, so a later lane may be nearer by a few ulps.
                if np.float64(sd[lane]) > cull:
                    continue
                cnt = int32_at(links, base + COUNT + lane)
                first = int32_at(links, base + CHILD + lane)
                if cnt >= GROUP_MIN:
                    # Four slots a <4 x double> test (mt4: each lane bit for bit the
                    # scalar test); only lanes with a non-NaN t can pass ``closer``.
                    for g in range(first, first + cnt, GROUP):
                        hits, gt, gu, gv = mt4(tris, g, min(GROUP, first + cnt - g),
                                               ox, oy, oz, dx, dy, dz)
                        for m in range(GROUP):
                            if (hits >> m) & 1 and closer(gt[m], ids, g + m, t0,
                                                          best_t, best_id):
                                (best_t, best_id, best_slot, best_u, best_v, hi32,
                                 cull) = take_hit(gt[m], gu[m], gv[m], ids, g + m)
                else:
                    for j in range(first, first + cnt):
                        t, u, v = moller_trumbore(tris, j, ox, oy, oz, dx, dy, dz)
                        if closer(t, ids, j, t0, best_t, best_id):
                            (best_t, best_id, best_slot, best_u, best_v, hi32,
                             cull) = take_hit(t, u, v, ids, j)
        rest = inner & (inner - 1)
        if rest == 0:
            # At most one internal child: go there. Without a leaf in this visit t did
            # not change since the slab test, whose exit bound (hi32) already culled
            # the boxes beyond it, so no entry distance needs comparing.
            if inner == 0:
                cur = -1
            else:
                # DECISION: a loop, not ``lowest_lane`` (tzcnt): the loop's exit is a
                # predicted branch, so the lane, and the load of the next record, are
                # known before the slab test's mask is; tzcnt makes them wait for it on
                # every visit (bfo, one thread, kernel CPU ns a ray, loop / tzcnt: drive
                # 175 / 205, station 152 / 179, random 275 / 282; issue 33).
                lane = 0
                m = inner
                while m > 1:
                    m >>= 1
                    lane += 1
                if leaf != 0 and np.float64(sd[lane]) > cull:
                    cur = -1
                else:
                    cur = int32_at(links, base + CHILD + lane)
        elif rest & (rest - 1) == 0:
            # Two: one comparison orders them; push the farther, visit the nearer
            # (lanes found by predicted loops, as above).
            a = 0
            m = inner
            while m & 1 == 0:
                m >>= 1
                a += 1
            b = a + 1
            m >>= 1
            while m & 1 == 0:
                m >>= 1
                b += 1
            da = np.float64(sd[a])
            db = np.float64(sd[b])
            if db < da:
                a, b = b, a
                da, db = db, da
            ca = int32_at(links, base + CHILD + a)
            cb = int32_at(links, base + CHILD + b)
            if db <= cull:
                st_node[sp] = cb
                st_dist[sp] = db
                sp += 1
            cur = ca if da <= cull else -1
        else:
            # Three or more: order them (bitonic network), push the farther ones
            # (farthest first), visit the nearest.
            k, order = order8(inner, sd)
            nxt = -1
            nxt_d = 0.0
            for q in range(k - 1, -1, -1):
                lane = (order >> (4 * q)) & 15
                dq = np.float64(sd[lane])
                if dq > cull:
                    continue
                if nxt >= 0:
                    st_node[sp] = nxt
                    st_dist[sp] = nxt_d
                    sp += 1
                nxt = int32_at(links, base + CHILD + lane)
                nxt_d = dq
            cur = nxt
        # Pop the next record still worth visiting.
        while cur < 0 and sp > 0:
            sp -= 1
            if st_dist[sp] <= cull:
                cur = st_node[sp]
    return best_t, best_id, best_slot, best_u, best_v


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _closest_block(nodes, links, tris, ids, org, dirs, tmin, tmax, stack_size, order,
                   unit, r0, r1, out_t, out_slot, out_tri, out_u, out_v):
    """Rays order[r0:r1] of ``closest_hit`` (or rays r0..r1 when ``order`` is empty),
    sequentially.

    DECISION: the per-block work is its own (serial) function called from the prange
    loop, not inlined into it: Numba's parfor lowering compiled the same loop ~35 %
    slower (measured: 0.9 vs 1.45 Mrays/s on one thread, incoherent rays).

    DECISION: no warm start here (the previous ray's triangle tested first, as the
    cube-map kernels still do): with the nearest-first 8-wide walk the first leaf
    reached is usually the answer anyway, and the extra triangle test cost more than the
    tighter t saved. Measured on bfo (one process, CPU ns a ray at 2 threads, three
    passes each, with / without): drive 258-261 / 238-240, station from one origin
    183-187 / 166-169, random 383-411 / 373-383; even an oracle that tests the true
    answer first gave only 230 on the drive (issue 33).

    ``unit`` False: ``dirs`` are the caller's directions, normalised here per ray with
    the arithmetic of ``rays.unit_directions`` (sqrt(x x + y y + z z), one division per
    component), so the ray cast is bit for bit the one of the normalised array.
    """
    st_node, st_dist, sd, cn, cd = new_scratch(stack_size)
    one_org = org.shape[0] == 1
    one_t = tmin.shape[0] == 1
    ordered = order.shape[0] > 0
    for p in range(r0, r1):
        r = order[p] if ordered else p
        ro = 0 if one_org else r
        rt = 0 if one_t else r
        dx = dirs[r, 0]
        dy = dirs[r, 1]
        dz = dirs[r, 2]
        if not unit:
            length = np.sqrt(dx * dx + dy * dy + dz * dz)
            dx = dx / length
            dy = dy / length
            dz = dz / length
        bt, bid, bslot, bu, bv = trace_closest(
            nodes, links, tris, ids, org[ro, 0], org[ro, 1], org[ro, 2],
            dx, dy, dz, tmin[rt], tmax[rt], -1, st_node, st_dist, sd, cn, cd)
        if bslot >= 0:
            out_t[r] = bt
            out_slot[r] = bslot
            out_tri[r] = bid
            out_u[r] = bu
            out_v[r] = bv
        else:
            out_t[r] = np.inf
            out_slot[r] = -1
            out_tri[r] = -1
            out_u[r] = 0.0
            out_v[r] = 0.0


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def closest_hit(nodes, links, tris, ids, org, dirs, tmin, tmax, stack_size, order,
                out_t, out_slot, out_tri, out_u, out_v, unit, workers, counter):
    """Closest hit for n rays.

    org : (n_o, 3) float64, n_o in {1, n}; dirs : (n, 3) float64 unit vectors, or (with
    ``unit`` False) non-zero finite vectors that each ray normalises itself, as
    ``rays.unit_directions`` would (no (n, 3) array of unit vectors is written);
    tmin, tmax : (n_t,) float64, n_t in {1, n}; order : (n,) int64 processing order
    (see ``order.py``) or empty for 0..n-1. Writes out_t (inf on miss), out_slot
    (-1 on miss), out_tri (the input triangle ``ids[slot]``, -1 on miss), out_u, out_v
    (0 on miss), each at the ray's own index. ``workers``: the thread count
    (``numba.get_num_threads()``); ``counter``: a (1,) int64 zero (``tasks.fetch_add``);
    call with ``numba.parallel_chunksize(1)``.

    DECISION: the workers take blocks of ``RAY_BLOCK`` rays one at a time from the shared
    counter (dynamic scheduling), not a ``prange`` over the blocks: Numba's OpenMP layer
    gives each thread a fixed half of a ``prange`` (``tasks.py``), so on this shared
    2-core VM a thread descheduled by another process held up its whole half
    (bench_raycast's drive row fell from 7.4 to 2.9-3.7 Mrays/s at load average 2-3,
    Open3D's only from 5.6 to 4.4-4.8; issue 33). The BVH build balances its tasks the
    same way. Not measured in isolation: on a quiet machine both schedules should
    cast alike. Which worker casts a block never changes what it writes.

    DECISION: the input index is written here,
    not mapped from the slots by a separate parallel pass: on this loaded 2-core VM
    every parallel region costs milliseconds of waiting for the worker thread.
    """
    n = dirs.shape[0]
    n_blocks = (n + RAY_BLOCK - 1) // RAY_BLOCK
    for _ in prange(min(workers, n_blocks)):
        while True:
            b = fetch_add(counter, 0, 1)
            if b >= n_blocks:
                break
            _closest_block(nodes, links, tris, ids, org, dirs, tmin, tmax, stack_size,
                           order, unit, b * RAY_BLOCK, min(n, (b + 1) * RAY_BLOCK),
                           out_t, out_slot, out_tri, out_u, out_v)


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def trace_any(nodes, links, tris, ox, oy, oz, dx, dy, dz, t0, t1, prev, st_node, sd):
    """Any hit of one ray o + t d with t in [t0, t1]: the slot of a triangle hit, or -1.
    ``prev`` (a slot, or -1) is tested first. Early exit; children are visited nearest
    first, as in ``trace_closest``.

    The visit splits leaves from internal children as ``trace_closest`` does
    (``simd.leaf8``) and tests the same triangles in the same order as before that
    split, so it returns the same slot (bfo, one thread, kernel CPU ns a ray, t_max 5 m,
    before / after: drive 137 / 116, station 56 / 54, random 306 / 263; issue 33).
    """
    if prev >= 0:
        t, u, v = moller_trumbore(tris, prev, ox, oy, oz, dx, dy, dz)
        if t >= t0 and t <= t1:
            return prev
    nx, onx, ofx, ix = axis_setup_fast(ox, dx)
    ny, ony, ofy, iy = axis_setup_fast(oy, dy)
    nz, onz, ofz, iz = axis_setup_fast(oz, dz)
    lo32 = round_down32_fast(t0)
    hi32 = round_up32_fast(t1)
    sp = 0
    cur = 0
    while cur >= 0:
        base = cur * RECORD
        mask = slab8(nodes, base, nx, ny, nz, onx, ony, onz, ofx, ofy, ofz,
                     ix, iy, iz, lo32, hi32, sd)
        leaf = mask & leaf8(links, base + COUNT)
        inner = mask ^ leaf
        if leaf != 0:
            k, order = _visit_order(leaf, sd)
            for q in range(k):
                lane = (order >> (4 * q)) & 15
                cnt = int32_at(links, base + COUNT + lane)
                child = int32_at(links, base + CHILD + lane)
                # DECISION: one triangle at a time here, not ``mt4``: the walk stops at
                # the first hit, and groups made occluded() slower (bfo, one thread, CPU
                # ns a ray, t_max 5 m: drive 147 -> 163, station 57 -> 71, random 361
                # -> 359).
                for j in range(child, child + cnt):
                    t, u, v = moller_trumbore(tris, j, ox, oy, oz, dx, dy, dz)
                    if t >= t0 and t <= t1:
                        return j
        rest = inner & (inner - 1)
        if rest == 0:
            if inner == 0:
                cur = -1
            else:
                lane = 0
                m = inner
                while m > 1:
                    m >>= 1
                    lane += 1
                cur = int32_at(links, base + CHILD + lane)
        else:
            # Nearest next, the others pushed nearest first (so popped farthest
            # first), as the walk did before the split.
            k, order = order8(inner, sd)
            cur = int32_at(links, base + CHILD + (order & 15))
            for q in range(1, k):
                st_node[sp] = int32_at(links, base + CHILD + ((order >> (4 * q)) & 15))
                sp += 1
        if cur < 0 and sp > 0:
            sp -= 1
            cur = st_node[sp]
    return -1

@njit(cache=CACHE, error_model=ERROR_MODEL)
def _any_block(nodes, links, tris, org, dirs, tmin, tmax, stack_size, order, r0, r1, out):
    """Rays order[r0:r1] of ``any_hit`` (or r0..r1 when ``order`` is empty)."""
    st_node, st_dist, sd, cn, cd = new_scratch(stack_size)
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
                         st_node, sd)
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
