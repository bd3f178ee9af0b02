"""Per-origin cube map of candidate triangles: exact closest hit for many rays sharing
one origin (a TLS station), without walking the BVH for most rays.

Idea: around the origin, the sphere of directions is split into the six faces of a cube
(gnomonic projection: direction d on face +x maps to (d_y / d_x, d_z / d_x) in [-1, 1]^2).
A gnomonic projection maps straight lines to straight lines, so the part of a triangle
inside a face's frustum projects to a convex polygon whose vertices are the projections
of the clipped triangle's vertices: its bounding box is a conservative footprint. Each
face carries a G x G grid; each cell lists every triangle whose footprint box overlaps
it. A ray then tests only the triangles of its own cell — the exact closest hit, because
any triangle the ray hits contains a point t d in the ray's frustum cell, whose
projection is the ray's own (u, v).

Building a view is one parallel pass over the triangles that writes their footprints
(a triangle whose three vertices lie well inside one face's frustum, most of them, is
projected without clipping) and counts them per cell (``footprints_counted``), a
serial prefix sum (``entry_offsets``) and a parallel pass that writes the lists
(``fill_entries``). Both parallel passes split the footprint rows into contiguous
parts, one task a part: the lists come out in footprint-row order whatever the number
of parts. Small maps (config.CUBEMAP_PARALLEL_MIN_TRIS) run ``footprints`` (parallel)
and the serial ``count_part``, ``fill_part``.

Cells listing more than ``HOT`` triangles (looking down a long tunnel, many far
triangles crowd into a small solid angle) are marked, and their rays walk the BVH
instead. Both paths use the same float64 Möller–Trumbore on the same local-frame data
and the same (t, input index) order, so the result is bit-identical to the BVH's. A
cell's list is tested four entries at a time (``mt4_gather``: one ``<4 x double>``
Möller–Trumbore over four gathered rows, each lane the scalar test bit for bit), as the
BVH's leaves are (``intersect.mt4``).

Layout (one view, for one origin)::

    start (6 G G + 1,) int32   CSR offsets: cell c lists slots[start[c]:start[c+1]]
    counts (6 G G,) int32      triangles per cell (hot cells: more than HOT, no list)
    slots (n_entries,) int32   triangle slots (into the leaf-ordered triangle arrays)

Cell index c = face * G * G + row * G + col; face = 2 * axis + (0 if d[axis] > 0 else 1);
row from the first, col from the second of the other two axes in cyclic order.

A near map (``nearmap.py``) is the same structure over the triangles nearest to the
origin only: its directions are first turned by ``rot`` (the rays' cone axis onto +x)
when the cone is narrow, in which case only face 0 is kept (``n_faces`` = 1) and its
grid spans [-scale, scale]^2 instead of [-1, 1]^2; ``radius`` (finite) says how far its
lists are complete. A whole map passes ``sel``, ``rot``, ``scale`` and ``radius`` as
None (all triangles, not turned, scale 1, radius inf): Numba compiles those tests away,
and the whole map runs the code it ran before near maps existed.

The cube map is a view-dependent acceleration in the spirit of light-buffer / "hemicube"
occlusion culling (Haines & Greenberg 1986, "The light buffer: a shadow-testing
accelerator"; Cohen & Greenberg 1985, hemicube), here made exact by conservative
footprints.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from ..config import CACHE, CUBEMAP_PAD, ERROR_MODEL
from .intersect import GROUP, closer, moller_trumbore, mt4_gather
from .traverse import new_scratch, take_hit, trace_closest

#: Chunk of triangles per parallel task in the footprint pass.
_CHUNK = 4096
#: A vertex counts as well inside a face's frustum (footprint fast path) when its two
#: lateral tan-angles are at most 1 - _FAST_MARGIN. DECISION: 1e-4, 100 times
#: CUBEMAP_PAD: a vertex that close to a face border takes the clipping path, whose
#: enlarged frustums list the triangle on the neighbouring face too.
_FAST_MARGIN = 1e-4
#: A triangle whose plane passes within _TOUCH_REL times its longest edge L of the
#: origin, with the origin inside its box grown by as much, is listed in every cell of
#: every face. DECISION: the intersection test accepts hits up to ~BARY * L outside a
#: triangle, which a footprint at distance r widens by BARY * L / r in tan units; that
#: stays below CUBEMAP_PAD only for r > BARY * L / CUBEMAP_PAD = 1e-3 L. Nearer
#: triangles (an origin on an edge, in the plane, hit at t = 0 for every direction;
#: found by the brute-force property test) go everywhere. 1e-2 keeps a factor 10; only a
#: station within 1 mm of a 0.1 m triangle pays for it.
_TOUCH_REL = 1e-2


#: A cell's list is tested in groups of ``intersect.GROUP`` (``mt4_gather``) from this
#: many entries left; a last single entry is tested on its own (``moller_trumbore``).
LIST_GROUP_MIN = 2


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _clip(px, py, pz, n, qx, qy, qz, a, b, lateral):
    """Sutherland & Hodgman 1974 polygon clipping of p (n vertices, face frame: x =
    depth, y and z lateral) by the half-space a * x + b * (y if lateral == 1 else z) >= 0,
    a plane through the origin. Output into q; returns its vertex count (0: empty)."""
    m = 0
    for i in range(n):
        j = (i + 1) % n
        if lateral == 1:
            fi = a * px[i] + b * py[i]
            fj = a * px[j] + b * py[j]
        else:
            fi = a * px[i] + b * pz[i]
            fj = a * px[j] + b * pz[j]
        if fi >= 0.0:
            qx[m] = px[i]
            qy[m] = py[i]
            qz[m] = pz[i]
            m += 1
        if (fi >= 0.0) != (fj >= 0.0):
            s = fi / (fi - fj)
            qx[m] = px[i] + s * (px[j] - px[i])
            qy[m] = py[i] + s * (py[j] - py[i])
            qz[m] = pz[i] + s * (pz[j] - pz[i])
            m += 1
    return m


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _inside_face(p, i):
    """The cube face whose frustum holds vertex p[i] (relative to the origin) with the
    margin ``_FAST_MARGIN`` on all four sides, or -1 (near a face border, or at the
    origin)."""
    x = p[i, 0]
    y = p[i, 1]
    z = p[i, 2]
    ax = abs(x)
    ay = abs(y)
    az = abs(z)
    lim = 1.0 - _FAST_MARGIN
    if ay <= lim * ax and az <= lim * ax and ax > 0.0:
        return 0 if x > 0.0 else 1
    if ax <= lim * ay and az <= lim * ay and ay > 0.0:
        return 2 if y > 0.0 else 3
    if ax <= lim * az and ay <= lim * az and az > 0.0:
        return 4 if z > 0.0 else 5
    return -1


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _touches_origin(p):
    """Whether the triangle p (3, 3) (vertices relative to the origin) lies within
    _TOUCH_REL times its longest edge of the origin, judged by its plane and its box
    (conservative: a few more triangles than the distance itself would select)."""
    e1x = p[1, 0] - p[0, 0]
    e1y = p[1, 1] - p[0, 1]
    e1z = p[1, 2] - p[0, 2]
    e2x = p[2, 0] - p[0, 0]
    e2y = p[2, 1] - p[0, 1]
    e2z = p[2, 2] - p[0, 2]
    e3 = (e2x - e1x) ** 2 + (e2y - e1y) ** 2 + (e2z - e1z) ** 2
    edge = np.sqrt(max(e1x * e1x + e1y * e1y + e1z * e1z,
                       max(e2x * e2x + e2y * e2y + e2z * e2z, e3)))
    tol = _TOUCH_REL * edge
    for c in range(3):
        if min(p[0, c], min(p[1, c], p[2, c])) > tol:
            return False
        if max(p[0, c], max(p[1, c], p[2, c])) < -tol:
            return False
    nx = e1y * e2z - e1z * e2y
    ny = e1z * e2x - e1x * e2z
    nz = e1x * e2y - e1y * e2x
    nn = np.sqrt(nx * nx + ny * ny + nz * nz)
    return abs(nx * p[0, 0] + ny * p[0, 1] + nz * p[0, 2]) <= tol * nn


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _write_cells(out, k, face, umin, umax, wmin, wmax, g, scale):
    """Cell range of the tan-angle box [umin, umax] x [wmin, wmax] on ``face``, padded
    by CUBEMAP_PAD and clamped to the face; the grid spans [-scale, scale]^2 of the
    face (1: all of it)."""
    half = 0.5 * g
    r0 = int(np.floor(((umin - CUBEMAP_PAD) / scale + 1.0) * half))
    r1 = int(np.floor(((umax + CUBEMAP_PAD) / scale + 1.0) * half))
    c0 = int(np.floor(((wmin - CUBEMAP_PAD) / scale + 1.0) * half))
    c1 = int(np.floor(((wmax + CUBEMAP_PAD) / scale + 1.0) * half))
    out[k, face, 0] = max(0, min(g - 1, r0))
    out[k, face, 1] = max(0, min(g - 1, r1))
    out[k, face, 2] = max(0, min(g - 1, c0))
    out[k, face, 3] = max(0, min(g - 1, c1))


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def footprints(tris, sel, ox, oy, oz, rot, scale, g, out):
    """Cell ranges of the triangles ``sel`` on every cube face.

    tris : (m, 9) float64 per slot v0, e1, e2 (local frame); sel : (k,) int32 slots
    (the nearest ones for a near map), or None for every slot (a full view, k = m);
    (ox, oy, oz) the origin; rot : (3, 3) float64 applied to the vertices (relative to
    the origin; a near map turns its cone's axis onto +x, ``nearmap.py``), or None;
    scale: the grid spans [-scale, scale]^2 of each face; g : cells per face side.
    Writes out (k, 6, 4) int16 (or any wider signed integer), row i for slot sel[i]:
    row0, row1, col0, col1 (inclusive), or row0 = -1 when the triangle does not reach
    that face.

    DECISION: int16 footprints (g <= config.CUBEMAP_MAX_G = 2048 < 2^15): half the
    bytes of int32, written once and read twice (a whole bfo map's 78 MB became 39 MB,
    its first-touch page faults with it).

    DECISION: ``sel`` and ``rot`` are None, not an arange and an identity with a flag,
    for the whole map: Numba compiles a None argument's branch away, and the full
    map's passes run as they did before near maps existed (measured: the flags cost
    0.3-0.6 ns a station ray here, 2-3 in ``fill_entries``).
    """
    m = out.shape[0]
    n_chunks = (m + _CHUNK - 1) // _CHUNK
    for ch in prange(n_chunks):
        _footprint_rows(tris, sel, ox, oy, oz, rot, scale, g, out, ch * _CHUNK,
                        min(m, (ch + 1) * _CHUNK))


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _footprint_rows(tris, sel, ox, oy, oz, rot, scale, g, out, k0, k1):
    """Rows k0..k1 of ``footprints``, sequentially."""
    bx = np.empty(8)
    by = np.empty(8)
    bz = np.empty(8)
    cx = np.empty(8)
    cy = np.empty(8)
    cz = np.empty(8)
    p = np.empty((3, 3))
    q = np.empty(3)
    for k in range(k0, k1):
        slot = k
        if sel is not None:
            slot = sel[k]
        for c in range(3):
            o = ox if c == 0 else (oy if c == 1 else oz)
            v0 = tris[slot, c] - o
            p[0, c] = v0
            p[1, c] = v0 + tris[slot, 3 + c]
            p[2, c] = v0 + tris[slot, 6 + c]
        if rot is not None:
            for i in range(3):
                x = p[i, 0]
                y = p[i, 1]
                z = p[i, 2]
                for c in range(3):
                    q[c] = rot[c, 0] * x + rot[c, 1] * y + rot[c, 2] * z
                for c in range(3):
                    p[i, c] = q[c]
        # A triangle on or next to the origin (a hit at t ~ 0 for any direction,
        # within the intersection test's BARY slack) goes into every cell.
        if _touches_origin(p):
            for face in range(6):
                out[k, face, 0] = 0
                out[k, face, 1] = g - 1
                out[k, face, 2] = 0
                out[k, face, 3] = g - 1
            continue
        # Fast path (most triangles of a mesh around a station): all three vertices
        # well inside one face's frustum. The clipping below would then keep the
        # triangle's vertices unchanged on that face and clip it away on the other
        # five, so the footprint written here is the same, bit for bit.
        f0 = _inside_face(p, 0)
        if f0 >= 0 and _inside_face(p, 1) == f0 and _inside_face(p, 2) == f0:
            axis = f0 // 2
            sgn = 1.0 if f0 % 2 == 0 else -1.0
            a1 = (axis + 1) % 3
            a2 = (axis + 2) % 3
            umin = np.inf
            umax = -np.inf
            wmin = np.inf
            wmax = -np.inf
            for i in range(3):
                x = sgn * p[i, axis]
                u = p[i, a1] / x
                w = p[i, a2] / x
                umin = min(umin, u)
                umax = max(umax, u)
                wmin = min(wmin, w)
                wmax = max(wmax, w)
            for face in range(6):
                out[k, face, 0] = -1
            _write_cells(out, k, f0, umin, umax, wmin, wmax, g, scale)
            continue
        for face in range(6):
            axis = face // 2
            sgn = 1.0 if face % 2 == 0 else -1.0
            a1 = (axis + 1) % 3
            a2 = (axis + 2) % 3
            for i in range(3):
                bx[i] = sgn * p[i, axis]
                by[i] = p[i, a1]
                bz[i] = p[i, a2]
            # Frustum |y| <= x (1 + pad), |z| <= x (1 + pad): four planes through
            # the origin; enlarged by CUBEMAP_PAD so that rounding never excludes a
            # triangle a ray on the face border hits.
            sc = 1.0 + CUBEMAP_PAD
            n = _clip(bx, by, bz, 3, cx, cy, cz, sc, -1.0, 1)
            n = _clip(cx, cy, cz, n, bx, by, bz, sc, 1.0, 1)
            n = _clip(bx, by, bz, n, cx, cy, cz, sc, -1.0, 2)
            n = _clip(cx, cy, cz, n, bx, by, bz, sc, 1.0, 2)
            if n == 0:
                out[k, face, 0] = -1
                continue
            umin = np.inf
            umax = -np.inf
            wmin = np.inf
            wmax = -np.inf
            full = False
            for i in range(n):
                x = bx[i]
                if x <= 1e-300:
                    full = True  # the triangle touches the origin: all directions
                    break
                u = by[i] / x
                w = bz[i] / x
                umin = min(umin, u)
                umax = max(umax, u)
                wmin = min(wmin, w)
                wmax = max(wmax, w)
            if full:
                out[k, face, 0] = 0
                out[k, face, 1] = g - 1
                out[k, face, 2] = 0
                out[k, face, 3] = g - 1
                continue
            _write_cells(out, k, face, umin, umax, wmin, wmax, g, scale)


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _part_range(m, n_parts, p):
    """Footprint rows [k0, k1) of part p of n_parts (contiguous, in order)."""
    return (p * m) // n_parts, ((p + 1) * m) // n_parts


@njit(cache=CACHE, error_model=ERROR_MODEL, inline="always")
def _entries(fp, sel, g, n_faces, k0, k1, counts, hot, pos, slots, fill):
    """The footprint rows k0..k1: with ``fill`` False, count each triangle once in every
    cell it reaches (pos[cell] += 1); with ``fill`` True, write its slot (sel[k], or k
    when ``sel`` is None) at pos[cell] in every cell holding at most ``hot``
    (counts[cell]) and advance pos[cell]."""
    for k in range(k0, k1):
        slot = k
        if sel is not None:
            slot = sel[k]
        for face in range(n_faces):
            r0 = fp[k, face, 0]
            if r0 < 0:
                continue
            base = face * g * g
            for r in range(r0, fp[k, face, 1] + 1):
                for c in range(fp[k, face, 2], fp[k, face, 3] + 1):
                    cell = base + r * g + c
                    if not fill:
                        pos[cell] += 1
                    elif counts[cell] <= hot:
                        slots[pos[cell]] = slot
                        pos[cell] += 1


# DECISION: the serial bodies below are separate functions with the face count as a
# literal where it is 6 (the whole map): a face loop of unknown length inside the prange
# body measured 1.45x slower for the count (15.1 vs 10.4 ms a 0.81M-triangle station
# map, one thread), the cause of most of the whole map's slowdown after near maps came.
@njit(cache=CACHE, error_model=ERROR_MODEL)
def _count6(fp, g, k0, k1, pos):
    _entries(fp, None, g, 6, k0, k1, pos, 0, pos, pos, False)


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _count_n(fp, g, n_faces, k0, k1, pos):
    _entries(fp, None, g, n_faces, k0, k1, pos, 0, pos, pos, False)


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _fill6(fp, sel, g, k0, k1, counts, hot, pos, slots):
    _entries(fp, sel, g, 6, k0, k1, counts, hot, pos, slots, True)


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _fill_n(fp, sel, g, n_faces, k0, k1, counts, hot, pos, slots):
    _entries(fp, sel, g, n_faces, k0, k1, counts, hot, pos, slots, True)


@njit(cache=CACHE, error_model=ERROR_MODEL)
def count_part(fp, g, n_faces, k0, k1, pos):
    """Add the footprint rows k0..k1 of the first ``n_faces`` faces (6, or 1 for a near
    map turned onto +x) to the per-cell counts pos (n_faces g g,) int32 (serial)."""
    if n_faces == 6:
        _count6(fp, g, k0, k1, pos)
    else:
        _count_n(fp, g, n_faces, k0, k1, pos)


@njit(cache=CACHE, error_model=ERROR_MODEL)
def fill_part(fp, sel, g, n_faces, k0, k1, counts, hot, pos, slots):
    """Write the slots of the footprint rows k0..k1 (sel[k], or k when ``sel`` is None)
    into the lists of the cells holding at most ``hot`` triangles (``counts``), at the
    positions pos (n_faces g g,) int32, advanced as they are written (serial)."""
    if n_faces == 6:
        _fill6(fp, sel, g, k0, k1, counts, hot, pos, slots)
    else:
        _fill_n(fp, sel, g, n_faces, k0, k1, counts, hot, pos, slots)


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def footprints_counted(tris, sel, ox, oy, oz, rot, scale, g, out, n_faces, parts):
    """``footprints`` and the per-cell counts in one pass: the rows split into
    parts.shape[0] contiguous parts, one task each, every chunk of _CHUNK rows counted
    into its part's row of ``parts`` (zeros on entry) right after its footprints are
    written, while they are in cache (measured: 9.1-9.7 CPU ns a ray of a 4M-ray
    station on bfo against 11.7-11.9 for the two passes). Same ``out`` as
    ``footprints``; part p's counts as ``count_part`` over its rows.

    DECISION: a row of counts per part, then a prefix sum over (cell, part)
    (``entry_offsets``): each part then writes its own stretch of every cell's list
    (``fill_entries``), so the lists come out in footprint-row order, as the serial
    pass wrote them, bit for bit and whatever the number of parts (the answer never
    depends on the thread count). The earlier attempt, row bands of cells, read the
    footprints three times (2x slower on one thread); this one costs n_parts rows of
    counts.
    """
    m = out.shape[0]
    n_parts = parts.shape[0]
    for p in prange(n_parts):
        k0, k1 = _part_range(m, n_parts, p)
        for a in range(k0, k1, _CHUNK):
            b = min(k1, a + _CHUNK)
            _footprint_rows(tris, sel, ox, oy, oz, rot, scale, g, out, a, b)
            count_part(out, g, n_faces, a, b, parts[p])


@njit(cache=CACHE, error_model=ERROR_MODEL)
def entry_offsets(parts, hot):
    """From the per-part counts of ``footprints_counted`` (or ``count_part``): counts (n_cells,) int32 (their
    sum) and the CSR offsets start (n_cells + 1,) int32 of the lists kept (cells with at
    most ``hot`` triangles; hot cells keep no list: their rays use the BVH, so memory
    is spent on the cells that are used). ``parts`` is overwritten with each part's
    write positions (part p writes cell c's list from start[c] + the entries of the
    parts before p). Also returns kept (int): the number of entries, start[-1]
    unless it overflowed int32 (the caller refuses maps above
    config.CUBEMAP_MAX_ENTRIES < 2^31 before using start). Serial: one pass over the
    cells."""
    n_parts, n_cells = parts.shape
    counts = np.empty(n_cells, dtype=np.int32)
    start = np.empty(n_cells + 1, dtype=np.int32)
    start[0] = 0
    kept = 0
    if n_parts == 1:  # the serial build's (a camera's near map): a plain prefix sum
        row = parts[0]
        for c in range(n_cells):
            total = row[c]
            counts[c] = total
            row[c] = start[c]
            keep = total if total <= hot else 0
            start[c + 1] = start[c] + keep
            kept += keep
        return counts, start, kept
    for c in range(n_cells):
        total = 0
        at = start[c]
        for p in range(n_parts):
            k = parts[p, c]
            parts[p, c] = at
            at += k
            total += k
        counts[c] = total
        keep = total if total <= hot else 0
        start[c + 1] = start[c] + keep
        kept += keep
    return counts, start, kept


@njit(cache=CACHE, error_model=ERROR_MODEL, parallel=True)
def fill_entries(fp, sel, g, n_faces, parts, counts, hot, slots):
    """The cells' lists (slots (start[-1],) int32) from footprints (row i: slot sel[i],
    or slot i when ``sel`` is None), the write positions ``parts`` of
    ``entry_offsets`` (advanced as they are written) and the ``counts``, one task a
    part. Each cell's list holds its triangles in footprint-row order, whatever the
    number of parts.

    Lists are not sorted by distance: with a stop at the first entry beyond the closest
    hit, a station ray on the bfo preset still tested 2.8 of its cell's 3.1 triangles
    (3 % faster casting, more than paid for by the sort).
    """
    m = fp.shape[0]
    n_parts = parts.shape[0]
    for p in prange(n_parts):
        k0, k1 = _part_range(m, n_parts, p)
        fill_part(fp, sel, g, n_faces, k0, k1, counts, hot, parts[p], slots)


@njit(cache=CACHE, error_model=ERROR_MODEL)
def _view_block(start, slots, counts, g, n_faces, rot, scale, hot, radius, nodes,
                links, tris, ids, org, dirs, tmin, tmax, stack_size, r0, r1, out_t,
                out_slot, out_tri, out_u, out_v):
    """Rays r0..r1 of ``closest_hit_view``, sequentially: a serial function called from
    the prange loop, as ``traverse._closest_block`` is (measured here: as fast as the
    loop inlined into the prange body, within this VM's noise).

    DECISION: the lists in groups of four (``mt4_gather``) from two entries left, a last
    single entry on its own. Measured on bfo (one thread, CPU time, the lists' tests
    alone): a camera frame's near map (4.9 entries a ray) 82-96 -> 45-50 ns a ray. The
    (t, input index) minimum does not depend on the order in which a list's entries
    are tried."""
    st_node, st_dist, sd, cn, cd = new_scratch(stack_size)
    # Warm start of the BVH walks (``traverse.trace_closest``): a near map's only (a
    # whole map, radius None, keeps -1, as before near maps existed).
    prev = -1
    one_t = tmin.shape[0] == 1
    ox = org[0, 0]
    oy = org[0, 1]
    oz = org[0, 2]
    half = 0.5 * g
    for r in range(r0, r1):
        rt = 0 if one_t else r
        dx = dirs[r, 0]
        dy = dirs[r, 1]
        dz = dirs[r, 2]
        # The map's frame (turned for a near map): used to find the cell only.
        if rot is not None:
            mx = rot[0, 0] * dx + rot[0, 1] * dy + rot[0, 2] * dz
            my = rot[1, 0] * dx + rot[1, 1] * dy + rot[1, 2] * dz
            mz = rot[2, 0] * dx + rot[2, 1] * dy + rot[2, 2] * dz
        else:
            mx = dx
            my = dy
            mz = dz
        ax = abs(mx)
        ay = abs(my)
        az = abs(mz)
        # Dominant axis (ties: lowest axis) and the face's lateral coordinates.
        if ax >= ay and ax >= az:
            face = 0 if mx > 0 else 1
            u = my / ax
            w = mz / ax
        elif ay >= az:
            face = 2 if my > 0 else 3
            u = mz / ay
            w = mx / ay
        else:
            face = 4 if mz > 0 else 5
            u = mx / az
            w = my / az
        # A grid over all of each face (scale None: 1) skips the two divisions (u / 1.0
        # is u, the same cells).
        if scale is not None:
            u = u / scale
            w = w / scale
        row = min(g - 1, max(0, int(np.floor((u + 1.0) * half))))
        col = min(g - 1, max(0, int(np.floor((w + 1.0) * half))))
        cell = face * g * g + row * g + col
        t0 = tmin[rt]
        t1 = tmax[rt]
        # A face the map does not hold (rounding at a turned near map's cone edge) or a
        # hot cell: the BVH answers.
        # DECISION: scale, radius and rot are None (compiled away) for a whole map:
        # as runtime tests (scale != 1, face >= n_faces, bt > radius, the warm start)
        # they cost a whole map 7 % of a station ray (66-71 against 61-64 ns, one
        # thread); an unturned map holds all six faces.
        other_face = False
        if rot is not None:
            other_face = face >= n_faces
        if other_face or counts[cell] > hot:
            bt, bid, bslot, bu, bv = trace_closest(nodes, links, tris, ids, ox, oy, oz,
                                                   dx, dy, dz, t0, t1, prev,
                                                   st_node, st_dist, sd, cn, cd)
            if radius is not None:
                if bslot >= 0:
                    prev = bslot
        else:
            bt = t1
            bid = -1
            bslot = -1
            bu = 0.0
            bv = 0.0
            e1 = start[cell + 1]
            for e in range(start[cell], e1, GROUP):
                left = e1 - e
                if left >= LIST_GROUP_MIN:
                    # Four entries a <4 x double> test, each lane the scalar test bit
                    # for bit; ``closer`` keeps the (t, input index) minimum, which does
                    # not depend on the order the entries are tried in.
                    hits, gt, gu, gv = mt4_gather(tris, slots, e, min(GROUP, left),
                                                  ox, oy, oz, dx, dy, dz)
                    for q in range(GROUP):
                        if (hits >> q) & 1:
                            k = slots[e + q]
                            if closer(gt[q], ids, k, t0, bt, bid):
                                bt, bid, bslot, bu, bv, _, _ = take_hit(gt[q], gu[q],
                                                                        gv[q], ids, k)
                else:
                    k = slots[e]
                    t, uu, vv = moller_trumbore(tris, k, ox, oy, oz, dx, dy, dz)
                    if closer(t, ids, k, t0, bt, bid):
                        bt, bid, bslot, bu, bv, _, _ = take_hit(t, uu, vv, ids, k)
            # A near map (finite radius) lists only the triangles nearer than radius:
            # its answer stands when it is nearer than that, or when the whole interval
            # is; otherwise the BVH decides, warm-started with the local hit (nearmap.py).
            # DECISION: that walk starts its interval at max(t0, radius): the ray hits
            # nothing in [t0, radius) (a listed triangle would have answered, an
            # unlisted one it can hit was not collected, so it has no hit point nearer
            # than radius), so the answer, ties at radius included (closed interval), is
            # the same, and the walk culls the boxes it leaves before radius. Measured
            # with the grouped lists (bfo frame, one thread): the 3.3 % of rays beyond
            # the radius 710-940 -> 540-610 ns a ray.
            if radius is not None:
                if bt > radius:
                    bt, bid, bslot, bu, bv = trace_closest(
                        nodes, links, tris, ids, ox, oy, oz, dx, dy, dz,
                        max(t0, radius), t1, bslot if bslot >= 0 else prev,
                        st_node, st_dist, sd, cn, cd)
                    if bslot >= 0:
                        prev = bslot
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
def closest_hit_view(start, slots, counts, g, n_faces, rot, scale, hot, radius,
                     nodes, links, tris, ids, org, dirs, tmin, tmax, stack_size, block,
                     out_t, out_slot, out_tri, out_u, out_v):
    """Closest hit for n rays from the single origin org (1, 3) (local frame) using the
    cube map, falling back to the BVH for rays in hot cells, and, for a near map
    (``radius`` finite: the map lists only the triangles nearer than that), for rays
    whose answer may lie farther. Same outputs as ``traverse.closest_hit``.

    The map (``start``, ``slots``, ``counts`` of ``fill_entries``, g cells a side,
    ``n_faces`` faces) is turned by ``rot`` (3, 3) float64, or not (None); its grid
    spans [-scale, scale]^2 of a face (None: [-1, 1]^2); ``radius`` (float, or None for
    +inf) says how far its lists are complete. dirs : (n, 3) float64 unit vectors.
    None arguments are compiled away (a whole map runs no test it does not need).
    """
    n = dirs.shape[0]
    n_blocks = (n + block - 1) // block
    for b in prange(n_blocks):
        _view_block(start, slots, counts, g, n_faces, rot, scale, hot, radius,
                    nodes, links, tris, ids, org, dirs, tmin, tmax, stack_size,
                    b * block, min(n, (b + 1) * block), out_t, out_slot, out_tri,
                    out_u, out_v)
