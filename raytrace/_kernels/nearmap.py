"""Near maps: the cube map of ``cubemap.py`` over only the triangles nearest to a shared
origin, for single-origin batches too small to repay a map of the whole mesh (a camera
frame: 307k rays against 0.8M triangles, a new origin every frame).

Two serial passes before the map is built:

* ``ray_cone``: the cone of the batch's directions (axis = the normalised sum of a
  sample of the unit directions, half-angle = the largest angle of any direction to it).
* ``gather_near``: best-first walk of the BVH from the origin (Hjaltason & Samet 1999,
  "Distance browsing in spatial databases": a priority queue of boxes keyed by their
  distance to the query point), skipping every box that lies outside the cone, until
  ``k_max`` triangles are collected. ``radius`` is the key of the first box left in the
  queue: every triangle not collected lies in a box at least that far from the origin,
  or outside the cone.

The map over the collected triangles answers a ray exactly when its closest local hit
lies nearer than ``radius`` (a farther triangle's hit point lies in its padded box, at
least ``radius`` away: the assumption the BVH's own box culling rests on), or when the
ray's whole interval [t_min, t_max] lies nearer; every other ray walks the BVH
(``cubemap._view_block``). The answer is therefore the BVH's, bit for bit.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..config import CACHE, ERROR_MODEL
from .traverse import CHILD, COUNT

#: Angle added to the cone's half-angle and to each box's angular radius before a box is
#: judged outside the cone (radians). DECISION: 1e-6, far above the ~1e-8 rad error of
#: ``acos`` near 1 and the float64 rounding of the dot products; the float32 boxes are
#: already padded outward (``scene._pack_nodes``), so a triangle's hit points lie inside.
_CONE_PAD_RAD = 1e-6
#: Relative enlargement of a box's bounding-sphere radius (float64 rounding of the
#: half-diagonal and of the centre).
_SPHERE_PAD_REL = 1e-9
#: The returned radius is lowered by this much (relative): the float64 distance to a box
#: may round up by a few ulps, and a hit's t along the normalised direction may differ
#: from the hit point's distance by as much.
_RADIUS_SLACK_REL = 1e-9
#: Rows summed for ``ray_cone``'s axis (a stride through the batch).
_CONE_SAMPLE = 4096


@njit(cache=CACHE, error_model=ERROR_MODEL)
def ray_cone(dirs):
    """Axis (ax, ay, az) and cosine of the half-angle of a cone holding every row of
    ``dirs`` (n, 3) float64 unit vectors; cosine -1 (all directions) when the rows sum to
    (almost) zero.

    The axis is the normalised sum of every ``_cone_stride(n)``-th row (every row below
    2 _CONE_SAMPLE rows); the cosine is the exact minimum over all rows. Serial, so the
    cone does not depend on the thread count.

    DECISION: a sampled axis (any axis gives a cone that holds every ray, as the cosine
    is exact; a camera's sample sum points where the full sum does) reads the rays once
    instead of twice. DECISION: serial: a parallel version (chunks, the minimum per
    chunk) took 7 ms of wall clock a 640x480 frame at load average 4 on this 2-core VM,
    waiting for its second thread, against 1.5 ms for the old serial two passes.
    """
    n = dirs.shape[0]
    step = _cone_stride(n)
    sx = 0.0
    sy = 0.0
    sz = 0.0
    k = 0
    for i in range(0, n, step):
        sx += dirs[i, 0]
        sy += dirs[i, 1]
        sz += dirs[i, 2]
        k += 1
    norm = np.sqrt(sx * sx + sy * sy + sz * sz)
    if not norm > 1e-9 * k:
        return 1.0, 0.0, 0.0, -1.0
    ax = sx / norm
    ay = sy / norm
    az = sz / norm
    # Four running minima (exact in any order: the same result), so that each step
    # does not wait for the previous one's.
    c0 = 1.0
    c1 = 1.0
    c2 = 1.0
    c3 = 1.0
    n4 = n - n % 4
    for i in range(0, n4, 4):
        c0 = min(c0, dirs[i, 0] * ax + dirs[i, 1] * ay + dirs[i, 2] * az)
        c1 = min(c1, dirs[i + 1, 0] * ax + dirs[i + 1, 1] * ay + dirs[i + 1, 2] * az)
        c2 = min(c2, dirs[i + 2, 0] * ax + dirs[i + 2, 1] * ay + dirs[i + 2, 2] * az)
        c3 = min(c3, dirs[i + 3, 0] * ax + dirs[i + 3, 1] * ay + dirs[i + 3, 2] * az)
    for i in range(n4, n):
        c0 = min(c0, dirs[i, 0] * ax + dirs[i, 1] * ay + dirs[i, 2] * az)
    return ax, ay, az, min(min(c0, c1), min(c2, c3))


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _cone_stride(n):
    """Row stride of ``ray_cone``'s axis sample: about _CONE_SAMPLE rows (all rows below
    twice that)."""
    return max(1, n // _CONE_SAMPLE)


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _push(keys, items, size, key, item):
    """Binary min-heap insert (Williams 1964); returns the new size."""
    i = size
    while i > 0:
        parent = (i - 1) >> 1
        if keys[parent] <= key:
            break
        keys[i] = keys[parent]
        items[i] = items[parent]
        i = parent
    keys[i] = key
    items[i] = item
    return size + 1


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _pop(keys, items, size):
    """Remove the heap's minimum (the caller reads keys[0], items[0] first); returns the
    new size."""
    size -= 1
    key = keys[size]
    item = items[size]
    i = 0
    while True:
        c = 2 * i + 1
        if c >= size:
            break
        if c + 1 < size and keys[c + 1] < keys[c]:
            c += 1
        if key <= keys[c]:
            break
        keys[i] = keys[c]
        items[i] = items[c]
        i = c
    if size > 0:
        keys[i] = key
        items[i] = item
    return size


@njit(cache=CACHE, error_model=ERROR_MODEL)
def gather_near(nodes, links, ox, oy, oz, ax, ay, az, cos_cone, k_max, out):
    """The triangles nearest to the origin (ox, oy, oz) within the cone (axis a, cosine
    ``cos_cone`` of its half-angle), at least ``k_max`` of them unless fewer exist.

    nodes, links : the 8-wide records (``traverse.py``); out : (m,) int32, receives the
    slots. Returns (count, radius): ``out[:count]`` holds every triangle of every leaf box
    nearer than ``radius`` that reaches into the cone (whole leaves); radius is +inf when
    every such leaf was collected. A triangle left out has no hit point nearer than
    ``radius`` along any direction of the cone.
    """
    n_rec = nodes.shape[0]
    cap = 8 * n_rec + 8
    keys = np.empty(cap)
    items = np.empty(cap, dtype=np.int64)
    half_cone = np.arccos(max(-1.0, min(1.0, cos_cone))) + _CONE_PAD_RAD
    size = _push(keys, items, 0, 0.0, 0)  # the root record (its lanes: the root's children)
    count = 0
    while size > 0:
        key = keys[0]
        item = items[0]
        if count >= k_max:
            return count, key * (1.0 - _RADIUS_SLACK_REL)
        size = _pop(keys, items, size)
        if item < 0:  # a leaf lane: -1 - (record * 8 + lane)
            code = -1 - item
            rec = code >> 3
            lane = code & 7
            first = links[rec, CHILD + lane]
            for j in range(first, first + links[rec, COUNT + lane]):
                out[count] = j
                count += 1
            continue
        for lane in range(8):
            lx = np.float64(nodes[item, lane])
            ly = np.float64(nodes[item, 8 + lane])
            lz = np.float64(nodes[item, 16 + lane])
            hx = np.float64(nodes[item, 24 + lane])
            hy = np.float64(nodes[item, 32 + lane])
            hz = np.float64(nodes[item, 40 + lane])
            if not (lx <= hx and ly <= hy and lz <= hz):
                continue  # an unused lane (empty box)
            # Cone test on the box's bounding sphere (centre c, radius rb): outside when
            # the angle between c - o and the axis exceeds the cone's half-angle plus the
            # sphere's angular radius.
            cx = 0.5 * (lx + hx) - ox
            cy = 0.5 * (ly + hy) - oy
            cz = 0.5 * (lz + hz) - oz
            rb = 0.5 * np.sqrt((hx - lx) ** 2 + (hy - ly) ** 2 + (hz - lz) ** 2)
            rb = rb * (1.0 + _SPHERE_PAD_REL) + 1e-300
            dist_c = np.sqrt(cx * cx + cy * cy + cz * cz)
            if dist_c > rb and half_cone < np.pi:
                cos_c = (cx * ax + cy * ay + cz * az) / dist_c
                angle = np.arccos(max(-1.0, min(1.0, cos_c)))
                if angle > half_cone + np.arcsin(rb / dist_c) + _CONE_PAD_RAD:
                    continue
            # Distance from the origin to the box (0 inside it).
            gx = max(lx - ox, max(0.0, ox - hx))
            gy = max(ly - oy, max(0.0, oy - hy))
            gz = max(lz - oz, max(0.0, oz - hz))
            d = np.sqrt(gx * gx + gy * gy + gz * gz)
            cnt = links[item, COUNT + lane]
            if cnt > 0:
                size = _push(keys, items, size, d, -1 - (item * 8 + lane))
            else:
                size = _push(keys, items, size, d, np.int64(links[item, CHILD + lane]))
    return count, np.inf


__all__ = ["ray_cone", "gather_near"]
