"""The build's fused and parallel kernels (issue 33, faster build) against plain NumPy
references of the passes they replace: the vertex bounds, the primitive records and
triangle records formed from the vertices minus the local origin, the outward float32
steps (``np.nextafter``), the packed node records, and a whole ``Scene`` whose arrays
must equal those the NumPy formulas give."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from raytrace import Scene, config
from raytrace._kernels import bounds8, build, collapse
from raytrace._kernels.simd import LANES
from raytrace._kernels.traverse import CHILD, RECORD
from raytrace.scene import _pack_nodes
from tests.raytrace.test_build import _soup, _walk


def _mesh(m, seed, offset=(0.0, 0.0, 0.0)):
    """m random triangles over shared vertices, far from the origin when asked."""
    rng = np.random.default_rng(seed)
    v = rng.standard_normal((m + 2, 3)) * rng.choice([0.01, 1.0, 30.0], size=(m + 2, 1))
    v += np.asarray(offset)
    f = np.stack([np.arange(m), np.arange(m) + 1, np.arange(m) + 2], axis=1)
    f = rng.permuted(f, axis=1)
    return v, f


# --------------------------------------------------------------------------- steps
@njit
def _steps(x, down, up):
    for i in range(x.size):
        down[i] = bounds8.next_down32(x[i])
        up[i] = bounds8.next_up32(x[i])


_F32 = st.floats(width=32, allow_nan=True, allow_infinity=True, allow_subnormal=True)


@settings(max_examples=300, deadline=None)
@given(xs=st.lists(_F32, min_size=1, max_size=20))
def test_float32_steps_equal_nextafter(xs):
    """Bit for bit against NumPy, zeros of both signs, subnormals, infinities and NaN
    included (NaN stays NaN)."""
    x = np.array(xs + [0.0, -0.0, np.inf, -np.inf, 1e-45, -1e-45], dtype=np.float32)
    down = np.empty_like(x)
    up = np.empty_like(x)
    _steps(x, down, up)
    with np.errstate(all="ignore"):
        want_d = np.nextafter(x, np.float32(-np.inf))
        want_u = np.nextafter(x, np.float32(np.inf))
    for got, want in ((down, want_d), (up, want_u)):
        nan = np.isnan(want)
        np.testing.assert_array_equal(np.isnan(got), nan)
        np.testing.assert_array_equal(got[~nan].view(np.uint32), want[~nan].view(np.uint32))


# --------------------------------------------------------------------------- setup
@pytest.mark.parametrize("n", [1, 5, build._BOUNDS_ITEM + 3, 3 * build._BOUNDS_ITEM])
def test_vertex_bounds_equal_numpy(n):
    rng = np.random.default_rng(n)
    v = rng.standard_normal((n, 3)) * 1e3 + 5e5
    lo, hi = build.vertex_bounds(v)
    np.testing.assert_array_equal(lo, v.min(axis=0))
    np.testing.assert_array_equal(hi, v.max(axis=0))


def _setup_reference(local, f, area_rel):
    """The primitive records written plainly from the local vertices (float64)."""
    tri = local[f]                                   # (m, 3 vertices, 3)
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    lo32, hi32 = lo.astype(np.float32), hi.astype(np.float32)
    with np.errstate(all="ignore"):
        lo32 = np.where(lo32 > lo, np.nextafter(lo32, np.float32(-np.inf)), lo32)
        hi32 = np.where(hi32 < hi, np.nextafter(hi32, np.float32(np.inf)), hi32)
    ce = ((tri[:, 0] + tri[:, 1] + tri[:, 2]) / 3.0).astype(np.float32)
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    cross = np.linalg.norm(np.cross(e1, e2), axis=1)
    longest = np.max([(e1 * e1).sum(1), (e2 * e2).sum(1), ((e2 - e1) ** 2).sum(1)], axis=0)
    return np.concatenate([lo32, hi32, ce], axis=1), cross, area_rel * longest


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (451_000.3, 5_352_000.7, 611.1)])
def test_triangle_setup_subtracts_the_origin_like_numpy(offset):
    """Records from (vertices, origin) equal the records of NumPy's ``vertices - origin``
    (the local copy the kernel no longer makes), bit for bit; the zero-area flags agree
    wherever the reference is not within rounding of the threshold."""
    v, f = _mesh(2000, 1, offset)
    origin = np.round(0.5 * (v.min(0) + v.max(0)))
    local = v - origin
    prim = np.empty((len(f), 9), dtype=np.float32)
    good = np.empty(len(f), dtype=np.bool_)
    build.triangle_setup(v, origin, f, config.AREA_REL, prim, good)
    want, cross, limit = _setup_reference(local, f, config.AREA_REL)
    np.testing.assert_array_equal(prim.view(np.uint32), want.view(np.uint32))
    clear = np.abs(cross - limit) > 1e-9 * np.maximum(cross, limit)
    np.testing.assert_array_equal(good[clear], (cross > limit)[clear])
    # Some triangles of each kind, so the flag comparison tests something.
    f = f.copy()
    f[:7, 1] = f[:7, 0]
    build.triangle_setup(v, origin, f, config.AREA_REL, prim, good)
    assert not good[:7].any() and good[7:].sum() > 1000


def test_slot_triangles_subtract_the_origin_like_numpy():
    v, f = _mesh(1500, 2, (300_000.0, -20.0, 4_000_000.0))
    origin = np.round(0.5 * (v.min(0) + v.max(0)))
    local = v - origin
    order = np.random.default_rng(3).permutation(len(f))
    out = np.empty((len(f), 9))
    build.slot_triangles(v, origin, f, order, out)
    tri = local[f[order]]
    want = np.concatenate([tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]], axis=1)
    np.testing.assert_array_equal(out.view(np.uint64), want.view(np.uint64))


# --------------------------------------------------------------------------- packing
def _pack_reference(wide_box, wide_link, extent):
    """The NumPy formula ``_pack_nodes`` used before the kernel (kept here as the
    specification): pad, round to float32, one more step outward; links as int32."""
    pad = config.BOX_PAD_REL * float(max(np.max(extent), 1e-12))
    half = 3 * LANES
    nodes = np.empty((wide_box.shape[0], RECORD), dtype=np.float32)
    with np.errstate(all="ignore"):
        lo = (wide_box[:, :half].astype(np.float64) - pad).astype(np.float32)
        hi = (wide_box[:, half:2 * half].astype(np.float64) + pad).astype(np.float32)
        nodes[:, :half] = np.nextafter(lo, np.float32(-np.inf))
        nodes[:, half:2 * half] = np.nextafter(hi, np.float32(np.inf))
    nodes.view(np.int32)[:, CHILD:RECORD] = wide_link.astype(np.int32)
    return nodes


def test_packed_records_equal_the_numpy_formula():
    """Random boxes (empty lanes +inf/-inf, values at the float32 limits) and links."""
    rng = np.random.default_rng(4)
    n = 3000
    box = (rng.standard_normal((n, 6 * LANES)) * 100).astype(np.float32)
    box[rng.random(box.shape) < 0.05] = np.float32(3.4028235e38)
    empty = rng.random((n, LANES)) < 0.2
    for c in range(3):
        box[:, c * LANES:(c + 1) * LANES][empty] = np.inf
        box[:, (3 + c) * LANES:(4 + c) * LANES][empty] = -np.inf
    link = rng.integers(0, 2 ** 31 - 1, size=(n, 2 * LANES))
    extent = np.array([120.0, 7.5, 9.0])
    got = _pack_nodes(box, link, extent)
    want = _pack_reference(box, link, extent)
    np.testing.assert_array_equal(got.view(np.uint32), want.view(np.uint32))


def test_scene_arrays_equal_the_numpy_passes():
    """A whole Scene far from the origin: its node records are the NumPy pack of the
    collapsed tree, its triangle records the NumPy ``local`` formula (so the fused
    kernels change no bit of what the traversal reads)."""
    v, f = _mesh(6000, 5, (451_000.0, 5_352_000.0, 600.0))
    s = Scene(v, f)
    local = v - s.origin_offset
    np.testing.assert_array_equal(s.origin_offset,
                                  np.round(0.5 * (v.min(0) + v.max(0))))
    tri = local[f[s._ids]]
    want = np.concatenate([tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]], axis=1)
    np.testing.assert_array_equal(s._tris.view(np.uint64), want.view(np.uint64))
    # The node records: the tree rebuilt with the same kernels, packed by NumPy.
    prim = np.empty((len(f), 9), dtype=np.float32)
    good = np.empty(len(f), dtype=np.bool_)
    build.triangle_setup(v, s.origin_offset, f, config.AREA_REL, prim, good)
    keep = np.flatnonzero(good)
    prim = prim[keep]
    b = s._build
    node_box, node_meta = build.build_bvh(
        prim, keep, b["sah_bins"], bool(config.SAH_ALL_AXES), b["c_trav"], b["c_isect"],
        b["max_leaf_size"], int(config.MAX_LEAF_SIZE_FORCED),
        max(config.BUILD_TASK_MIN, len(keep) // config.BUILD_TASKS))
    wb, wl, _ = collapse.to_wide_layout(node_box, node_meta, b["c_trav"], b["c_isect"],
                                        LANES)
    want_nodes = _pack_reference(wb, wl, v.max(0) - v.min(0))
    np.testing.assert_array_equal(s._nodes.view(np.uint32), want_nodes.view(np.uint32))
    np.testing.assert_array_equal(s._ids, keep)


# --------------------------------------------------------------------------- collapse
def _collapse_reference(node_box, node_meta, c_trav, c_isect, width):
    """The wide collapse written plainly (Python): records by a preorder work list, each
    opening its largest-area internal child (first of equal areas) until ``width``
    children, a record numbered when its parent's lanes are filled; statistics from a
    separate preorder walk of the binary tree."""
    def area(i):
        d = node_box[i, 3:].astype(np.float64) - node_box[i, :3].astype(np.float64)
        return 0.0 if (d < 0).any() else d[0] * d[1] + d[1] * d[2] + d[2] * d[0]

    root_area = area(0) if area(0) > 0 else 1.0
    n_nodes = n_leaves = in_leaves = max_depth = 0
    cost = 0.0
    stack = [(0, 0)]
    while stack:
        i, d = stack.pop()
        n_nodes += 1
        max_depth = max(max_depth, d)
        if node_meta[i, 3] > 0:
            n_leaves += 1
            in_leaves += node_meta[i, 3]
            cost += c_isect * node_meta[i, 3] * area(i) / root_area
        else:
            cost += c_trav * area(i) / root_area
            stack += [(node_meta[i, 1], d + 1), (node_meta[i, 0], d + 1)]
    records, work, depth_w = {}, [(0, 0, 0)], 0
    n_rec = 1
    while work:
        i, r, dw = work.pop()
        depth_w = max(depth_w, dw)
        ch = [i] if node_meta[i, 3] > 0 else [node_meta[i, 0], node_meta[i, 1]]
        while len(ch) < width and node_meta[i, 3] == 0:
            inner = [q for q in range(len(ch)) if node_meta[ch[q], 3] == 0]
            if not inner:
                break
            best = max(inner, key=lambda q: (area(ch[q]), -q))
            opened = ch[best]
            ch[best] = node_meta[opened, 0]
            ch.append(node_meta[opened, 1])
        lanes = []
        for c in ch:
            if node_meta[c, 3] > 0:
                lanes.append((c, node_meta[c, 2], node_meta[c, 3]))
            else:
                lanes.append((c, n_rec, 0))
                n_rec += 1
        records[r] = lanes
        for c, rec, cnt in reversed(lanes):
            if cnt == 0:
                work.append((c, rec, dw + 1))
    stats = (n_nodes, n_leaves, max_depth, in_leaves, cost, depth_w)
    return [records[r] for r in range(n_rec)], stats


@pytest.mark.parametrize("m", [1, 2, 9, 700, 5000])
def test_wide_collapse_equals_a_plain_reference(m):
    """Records (children, links, boxes, empty lanes) and statistics of the one-walk
    collapse against the plain two-walk reference, on trees from the real build."""
    prim = _soup(m, m)
    node_box, node_meta = build.build_bvh(prim, np.arange(m), config.SAH_BINS, True,
                                          config.SAH_C_TRAV, config.SAH_C_ISECT,
                                          config.MAX_LEAF_SIZE,
                                          config.MAX_LEAF_SIZE_FORCED, 64)
    box, link, stats = collapse.to_wide_layout(node_box, node_meta, config.SAH_C_TRAV,
                                               config.SAH_C_ISECT, LANES)
    records, want = _collapse_reference(node_box, node_meta, config.SAH_C_TRAV,
                                        config.SAH_C_ISECT, LANES)
    assert len(records) == box.shape[0] == link.shape[0]
    for r, lanes in enumerate(records):
        for lane in range(LANES):
            lo = box[r, [lane, LANES + lane, 2 * LANES + lane]]
            hi = box[r, [3 * LANES + lane, 4 * LANES + lane, 5 * LANES + lane]]
            if lane < len(lanes):
                c, child, cnt = lanes[lane]
                assert (link[r, lane], link[r, LANES + lane]) == (child, cnt)
                np.testing.assert_array_equal(np.concatenate([lo, hi]), node_box[c])
            else:
                assert (link[r, lane], link[r, LANES + lane]) == (0, 0)
                assert (lo == np.inf).all() and (hi == -np.inf).all()
    assert stats[:4] == want[:4] and stats[5] == want[5]
    # The kernel's statistics take the half areas of the float32 node boxes in float32
    # (``build.half_area``), the reference in float64: a few units in the 9th digit.
    assert stats[4] == pytest.approx(want[4], rel=1e-6)


# --------------------------------------------------------------------------- property
@settings(max_examples=25, deadline=None)
@given(m=st.integers(2, 3000), seed=st.integers(0, 2 ** 16), stop=st.integers(1, 400),
       workers=st.integers(1, 3))
def test_any_task_size_and_worker_count_build_the_serial_tree(m, seed, stop, workers):
    """Whatever the task size (``stop``) and the worker count, the build is the one
    worker, one task build: the same rows in the same order, the same nodes (boxes,
    first slots, counts) in the same walk; and every node's box is the brute-force
    bound of its rows."""
    prim = _soup(m, seed)
    ref = prim.copy()
    ref_idx = np.arange(m, dtype=np.int32)
    args = (config.SAH_BINS, True, config.SAH_C_TRAV, config.SAH_C_ISECT,
            config.MAX_LEAF_SIZE, config.MAX_LEAF_SIZE_FORCED)
    ref_box, ref_meta = build.build_bvh(ref, ref_idx, *args, m, workers=1)
    p = prim.copy()
    idx = np.arange(m, dtype=np.int32)
    box, meta = build.build_bvh(p, idx, *args, stop, workers=workers)
    np.testing.assert_array_equal(idx, ref_idx)
    np.testing.assert_array_equal(p, ref)
    np.testing.assert_array_equal(p, prim[idx])
    walk, walk_ref = _walk(box, meta), _walk(ref_box, ref_meta)
    assert len(walk) == len(walk_ref)
    np.testing.assert_array_equal(box[walk], ref_box[walk_ref])
    np.testing.assert_array_equal(meta[walk, 2:], ref_meta[walk_ref, 2:])
    for i in walk:
        s = meta[i, 2]
        j = i
        while meta[j, 3] == 0:
            j = meta[j, 1]
        rows = p[s:meta[j, 2] + meta[j, 3]]
        np.testing.assert_array_equal(
            box[i], np.concatenate([rows[:, 0:3].min(0), rows[:, 3:6].max(0)]))
