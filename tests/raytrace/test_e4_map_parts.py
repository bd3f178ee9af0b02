"""Cube-map construction in parts, whole maps compiled without the near map's tests, and
stations given as (n, 3) arrays of one origin (issue 33).

* ``footprints_counted`` / ``entry_offsets`` / ``fill_entries`` (one task a part of
  the footprints) and the serial ``count_part`` / ``fill_part`` give the lists a plain
  Python walk over the footprints gives, in footprint-row order, for any number of
  parts;
* ``footprints`` with ``sel``/``rot`` None (a whole map) equals the general form with an
  arange and the identity turn, in int16 as in int32;
* ``ray_cone``'s cone does not depend on the thread count and holds every ray;
* an (n, 3) array whose rows are one origin is cast as that origin (``prepare_cast``
  returns one local row), with the (3,) origin's answers bit for bit, and arrays that
  differ anywhere (a single middle row, -0.0 against 0.0, NaN) take the general path.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from raytrace import RayError, Scene, config
from raytrace._kernels.cubemap import (count_part, entry_offsets, fill_entries,
                                       fill_part, footprints, footprints_counted)
from raytrace._kernels.nearmap import ray_cone
from raytrace._kernels.rays import rows_unlike_first
from raytrace.checks import prepare_cast
from raytrace.shapes import tunnel_tube

FIELDS = ("t", "triangle", "u", "v")


def _bits(a):
    a = np.ascontiguousarray(a)
    return a.view(np.int64) if a.dtype == np.float64 else a


def _assert_same(a, b):
    for name in FIELDS:
        np.testing.assert_array_equal(_bits(getattr(a, name)), _bits(getattr(b, name)),
                                      err_msg=name)


def _naive_lists(fp, sel, g, n_faces, hot):
    """(counts, start, slots) by a plain Python walk: every footprint row in order,
    every cell of its ranges on the first n_faces faces; hot cells keep no list."""
    n_cells = n_faces * g * g
    lists = [[] for _ in range(n_cells)]
    for k in range(fp.shape[0]):
        slot = k if sel is None else int(sel[k])
        for face in range(n_faces):
            r0, r1, c0, c1 = (int(x) for x in fp[k, face])
            if r0 < 0:
                continue
            for r in range(r0, r1 + 1):
                for c in range(c0, c1 + 1):
                    lists[face * g * g + r * g + c].append(slot)
    counts = np.array([len(x) for x in lists], dtype=np.int32)
    kept = [x if len(x) <= hot else [] for x in lists]
    start = np.concatenate([[0], np.cumsum([len(x) for x in kept])]).astype(np.int32)
    slots = np.array([s for x in kept for s in x], dtype=np.int32)
    return counts, start, slots


def _lists(fp, sel, g, n_faces, hot, n_parts):
    """The lists as ``Scene._map`` builds them: serially (one part) or in parts (the
    counts of part p over its rows, as ``footprints_counted`` counts them)."""
    m = fp.shape[0]
    parts = np.zeros((n_parts, n_faces * g * g), dtype=np.int32)
    for p in range(n_parts):
        count_part(fp, g, n_faces, p * m // n_parts, (p + 1) * m // n_parts, parts[p])
    counts, start, kept = entry_offsets(parts, hot)
    slots = np.empty(kept, dtype=np.int32)
    if n_parts == 1:
        fill_part(fp, sel, g, n_faces, 0, m, counts, hot, parts[0], slots)
    else:
        fill_entries(fp, sel, g, n_faces, parts, counts, hot, slots)
    assert kept == start[-1]
    return counts, start, slots


@st.composite
def _footprints(draw):
    """Random footprints: k rows, g cells a side, 1 or 6 faces, rows missing faces."""
    g = draw(st.integers(1, 6))
    n_faces = draw(st.sampled_from([1, 6]))
    k = draw(st.integers(0, 40))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    a = rng.integers(0, g, (k, 6, 2))
    b = rng.integers(0, g, (k, 6, 2))
    fp = np.empty((k, 6, 4), dtype=draw(st.sampled_from([np.int16, np.int32])))
    fp[..., 0] = np.minimum(a[..., 0], b[..., 0])
    fp[..., 1] = np.maximum(a[..., 0], b[..., 0])
    fp[..., 2] = np.minimum(a[..., 1], b[..., 1])
    fp[..., 3] = np.maximum(a[..., 1], b[..., 1])
    fp[rng.random((k, 6)) < 0.4, 0] = -1          # the triangle misses that face
    sel = None if draw(st.booleans()) else rng.permutation(10 * k + 1)[:k].astype(np.int32)
    return fp, sel, g, n_faces, draw(st.integers(0, 8))


@settings(max_examples=150, deadline=None)
@given(_footprints(), st.integers(1, 5))
def test_lists_in_parts_equal_a_naive_walk(case, n_parts):
    """Counts, offsets and lists, serial or in 2-5 parts, equal the naive walk's, bit
    for bit (the same order inside every cell)."""
    fp, sel, g, n_faces, hot = case
    want = _naive_lists(fp, sel, g, n_faces, hot)
    got = _lists(fp, sel, g, n_faces, hot, n_parts)
    for name, w, x in zip(("counts", "start", "slots"), want, got):
        np.testing.assert_array_equal(x, w, err_msg=name)


@pytest.fixture(scope="module")
def tube():
    v, f = tunnel_tube(20_000, length_m=60.0, roughness_m=0.003, seed=4)
    return Scene(v, f)


def _station_dirs(n, seed=0):
    d = np.random.default_rng(seed).standard_normal((n, 3))
    return np.concatenate([d, [[1.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 1.0, 1.0]]])


@pytest.mark.parametrize("origin", [[30.0, 0.1, 1.4], [1.0, -1.0, 0.3]])
def test_whole_map_footprints_match_the_general_form(tube, origin):
    """``footprints`` with sel and rot None equals the general call (an arange, the
    identity turn, scale 1) on every triangle, and int16 equals int32."""
    o = np.asarray(origin) - tube.origin_offset
    m = tube.n_triangles
    g = 97
    fast = np.empty((m, 6, 4), dtype=np.int16)
    footprints(tube._tris, None, o[0], o[1], o[2], None, 1.0, g, fast)
    general = np.empty((m, 6, 4), dtype=np.int32)
    footprints(tube._tris, np.arange(m, dtype=np.int32), o[0], o[1], o[2], np.eye(3),
               1.0, g, general)
    # Row0 everywhere; the other three where the face is reached (else left unwritten).
    np.testing.assert_array_equal(fast[:, :, 0], general[:, :, 0])
    on = general[:, :, 0] >= 0
    np.testing.assert_array_equal(fast[on].astype(np.int32), general[on])
    assert (fast[:, :, 0] >= 0).any(axis=1).all()      # every triangle on some face
    # The fused pass writes the same footprints, and each part's counts are the naive
    # counts of its rows.
    for n_parts in (1, 2, 3):
        fused = np.empty((m, 6, 4), dtype=np.int16)
        parts = np.zeros((n_parts, 6 * g * g), dtype=np.int32)
        footprints_counted(tube._tris, None, o[0], o[1], o[2], None, 1.0, g, fused, 6,
                           parts)
        np.testing.assert_array_equal(fused[:, :, 0], fast[:, :, 0])
        np.testing.assert_array_equal(fused[on], fast[on])
        for p in range(n_parts):
            rows = general[p * m // n_parts:(p + 1) * m // n_parts]
            want = _naive_lists(rows, None, g, 6, 0)[0]
            np.testing.assert_array_equal(parts[p], want)


@pytest.mark.parametrize("origin", [[30.0, 0.1, 1.4], [59.0, 0.4, 2.5]])
def test_map_in_parts_equals_serial_and_bvh(tube, origin, monkeypatch):
    """A whole map built in parts (every map parallel) and serially (none) holds the
    same arrays, and the cast through either equals the BVH's, at 1 and 2 threads."""
    d = _station_dirs(40_000)
    local = (np.asarray(origin, float) - tube.origin_offset)[None]
    ref = tube.cast(origin, d, method="bvh")
    views = []
    for min_tris, threads in ((10**9, 1), (1, 2), (1, 1)):
        monkeypatch.setattr(config, "CUBEMAP_PARALLEL_MIN_TRIS", min_tris)
        old = numba.get_num_threads()
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
        try:
            tube._view_cache = None
            views.append(tube._view(local))
            tube._view_cache = None
            _assert_same(tube.cast(origin, d, method="cubemap"), ref)
        finally:
            numba.set_num_threads(old)
    for v in views[1:]:
        for a, b in zip(views[0][:3], v[:3]):
            np.testing.assert_array_equal(a, b)
    # The lists equal the naive walk over the footprints (the serial reference).
    start, slots, counts, g = views[0][:4]
    fp = np.empty((tube.n_triangles, 6, 4), dtype=np.int32)
    footprints(tube._tris, None, *local[0], None, 1.0, g, fp)
    w_counts, w_start, w_slots = _naive_lists(fp, None, g, 6, config.CUBEMAP_HOT)
    np.testing.assert_array_equal(counts, w_counts)
    np.testing.assert_array_equal(start, w_start)
    np.testing.assert_array_equal(slots, w_slots)


def test_cone_is_the_same_at_any_thread_count_and_holds_every_ray():
    """The cone of 100k rays (a camera-like bundle plus a few stray rays) at 1 and 2
    threads, bit for bit; its cosine is the exact minimum over all rays."""
    rng = np.random.default_rng(3)
    d = rng.normal([1.0, 0.2, -0.1], 0.2, (100_000, 3))
    d[::9973] = rng.standard_normal((len(d[::9973]), 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    old = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = ray_cone(d)
        numba.set_num_threads(min(2, numba.config.NUMBA_NUM_THREADS))
        two = ray_cone(d)
    finally:
        numba.set_num_threads(old)
    assert _bits(np.array(one)).tolist() == _bits(np.array(two)).tolist()
    a = np.array(one[:3])
    assert abs(np.linalg.norm(a) - 1.0) < 1e-12
    cos = d[:, 0] * a[0] + d[:, 1] * a[1] + d[:, 2] * a[2]   # the kernel's arithmetic
    assert one[3] == cos.min()


@settings(max_examples=100, deadline=None)
@given(arrays(np.float64, st.tuples(st.integers(1, 30), st.just(3)),
              elements=st.sampled_from([0.0, -0.0, 1.5, np.nan, np.inf, -2.0])))
def test_rows_unlike_first_counts_bitwise_differences(o):
    """Rows whose bits differ from row 0's, as a NumPy comparison of the bytes counts
    them (-0.0 differs from 0.0; a NaN row equals the same NaN)."""
    bits = o.view(np.int64)
    assert rows_unlike_first(bits) == int((bits != bits[0]).any(axis=1).sum())


def test_station_array_is_cast_as_its_single_origin(tube):
    """n equal rows: one local row, unit directions, and the (3,) origin's answers (t,
    triangle, u, v, directions, points), bit for bit, also by the BVH."""
    d = _station_dirs(30_000, seed=1) * 3.0
    origin = np.array([30.0, 0.1, 1.4])
    rows = np.tile(origin, (len(d), 1))
    _, local, dirs, unit, _, _ = prepare_cast(rows, d, 0.0, np.inf, tube.origin_offset)
    assert local.shape == (1, 3) and unit
    np.testing.assert_array_equal(_bits(local[0]), _bits(origin - tube.origin_offset))
    single = tube.cast(origin, d)
    for method in ("auto", "cubemap", "near", "bvh"):
        h = tube.cast(rows, d, method=method)
        _assert_same(h, single)
        np.testing.assert_array_equal(_bits(h.directions), _bits(single.directions))
        np.testing.assert_array_equal(_bits(h.points), _bits(single.points))


@pytest.mark.parametrize("change", ["middle", "negzero"])
def test_almost_shared_origins_take_the_general_path(tube, change):
    """One differing row that the three-row pre-check does not see, or -0.0 against
    0.0: the general path (n local rows), with the BVH's answers."""
    d = _station_dirs(20_000, seed=2)
    rows = np.tile([30.0, 0.0, 1.4], (len(d), 1))
    if change == "middle":
        rows[len(d) // 3] = [30.0, 0.0, 1.5]
    else:
        rows[len(d) // 3, 1] = -0.0
    _, local, *_ = prepare_cast(rows, d, 0.0, np.inf, tube.origin_offset)
    assert local.shape == rows.shape
    _assert_same(tube.cast(rows, d), tube.cast(rows, d, method="bvh"))


def test_bad_origin_in_a_shared_array_names_its_row(tube):
    """A NaN in a middle row of otherwise equal origins is refused with the row named."""
    d = _station_dirs(1000)
    rows = np.tile([30.0, 0.0, 1.4], (len(d), 1))
    rows[517, 2] = np.nan
    with pytest.raises(RayError, match=r"Expected finite `origins`, got NaN/inf at row\(s\) 517"):
        tube.cast(rows, d)
    rows = np.tile([np.inf, 0.0, 1.4], (len(d), 1))
    with pytest.raises(RayError, match=r"Expected finite `origins`.* row\(s\) 0, 1, 2"):
        tube.cast(rows, d)
