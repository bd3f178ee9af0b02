"""The cheaper 8-wide visit (issue 33, ENGINE8): the new intrinsics of
``raytrace/_kernels/simd.py`` (``leaf8``, ``lowest_lane``, ``int32_at``,
``round_up32_fast``, ``round_down32_fast``, ``axis_setup_fast``) equal their scalar twins
bit for bit on random input; the rewritten ``traverse.trace_closest`` and ``trace_any``
return, bit for bit, what the walks they replaced returned (copies of the old walks live
here as the references) on random soups, with warm starts and [t_min, t_max] limits, and
every ray inside a closed mesh hits; the intrinsics compile to the instructions they exist for; a generic
(no-AVX) CPU gets the same answers."""

from __future__ import annotations

import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from numba import njit

from raytrace import MeshError, Scene
from raytrace._kernels import simd
from raytrace._kernels.intersect import GROUP, GROUP_MIN, closer, moller_trumbore, mt4
from raytrace._kernels.traverse import (CHILD, COUNT, RECORD, new_scratch, trace_any,
                                       trace_closest)
from raytrace.shapes import icosphere
from tests.raytrace.cpu import generic_and_host, jit_call, needs_avx2

_I32 = st.one_of(st.integers(-2 ** 31, 2 ** 31 - 1), st.sampled_from([0, 1, -1, 2 ** 31 - 1,
                                                                      -2 ** 31]))
_F64_ANY = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.sampled_from([0.0, -0.0, 5e-324, -5e-324, 1e-45, -1e-45, 1.4e-45, 3.4028234663852886e38,
                     3.4028235677973366e38, -3.4028235677973366e38, 3.5e38, -3.5e38, 1e300,
                     np.inf, -np.inf, np.nan, 1.0, -1.0, 0.1, -0.1]),
    # float32 values themselves and their float64 neighbours (rounding already exact,
    # or off by one float64 ulp either way).
    st.floats(width=32, allow_nan=False).flatmap(
        lambda f: st.sampled_from([f, np.nextafter(f, np.inf), np.nextafter(f, -np.inf)])),
)


# ---------------------------------------------------------------------------------------
# Intrinsics against their scalar twins
# ---------------------------------------------------------------------------------------
_leaf8 = jit_call(simd.leaf8, 2)
_int32_at = jit_call(simd.int32_at, 2)
_lowest = jit_call(simd.lowest_lane, 1)
_up = jit_call(simd.round_up32_fast, 1, error_model="numpy")
_down = jit_call(simd.round_down32_fast, 1, error_model="numpy")
_up_twin = jit_call(simd.round_up32, 1, error_model="numpy")
_down_twin = jit_call(simd.round_down32, 1, error_model="numpy")
_setup_fast = jit_call(simd.axis_setup_fast, 2, error_model="numpy")
_setup_twin = jit_call(simd.axis_setup, 2, error_model="numpy")


@settings(max_examples=300, deadline=None)
@given(a=arrays(np.int32, (3, 16), elements=_I32), i=st.integers(0, 40))
def test_leaf8_and_int32_at_equal_their_twins(a, i):
    """Any int32 values (negative, zero, INT_MIN/MAX) at any flat offset of a 2-D
    array: the same mask and the same values as the scalar twins."""
    assert _leaf8(a, i) == simd.leaf8_scalar(a, i)
    for k in range(8):
        assert _int32_at(a, i + k) == simd.int32_at_scalar(a, i + k) == a.ravel()[i + k]


def test_leaf8_empty_and_full_masks():
    """All counts 0: mask 0; all positive: 0xff; one positive lane: its bit; and the
    mask is independent of the bytes beside the eight read."""
    a = np.zeros((2, 64), dtype=np.int32)
    a[0, :56] = -7                      # around the counts: must not leak into the mask
    assert _leaf8(a, COUNT) == simd.leaf8_scalar(a, COUNT) == 0
    a[0, COUNT:COUNT + 8] = np.arange(1, 9)
    assert _leaf8(a, COUNT) == simd.leaf8_scalar(a, COUNT) == 0xFF
    for lane in range(8):
        a[0, COUNT:COUNT + 8] = 0
        a[0, COUNT + lane] = 3
        assert _leaf8(a, COUNT) == simd.leaf8_scalar(a, COUNT) == 1 << lane


@settings(max_examples=300, deadline=None)
@given(m=st.one_of(st.integers(0, 255), st.integers(-2 ** 63, 2 ** 63 - 1),
                   st.sampled_from([0, 0xFF, 1, 0x80, -2 ** 63, -1])))
def test_lowest_lane_equals_twin(m):
    """Any int64 (0 and 0xff included): the index of the lowest set bit, 64 for 0, as
    the twin and as Python's own bit arithmetic say."""
    got = _lowest(m)
    assert got == simd.lowest_lane_scalar(m)
    assert got == (64 if m == 0 else ((m & -m).bit_length() - 1))


def test_lowest_lane_every_byte():
    """Every 8-bit mask a visit can produce."""
    for m in range(256):
        assert _lowest(m) == simd.lowest_lane_scalar(m) == (64 if m == 0 else
                                                            (m & -m).bit_length() - 1)


def _f32_bits(x):
    return int(np.float32(x).view(np.int32))


@settings(max_examples=1500, deadline=None)
@given(x=_F64_ANY)
def test_fast_roundings_equal_the_nextafter_twins(x):
    """Any float64 (NaN, +-inf, +-0, subnormals, beyond the float32 range, float32
    values and their float64 neighbours): the same float32 bits as ``round_up32`` /
    ``round_down32`` (``np.nextafter``); and, checked by NumPy alone, the smallest
    float32 >= x / the largest <= x."""
    up, down = _up(x), _down(x)
    assert _f32_bits(up) == _f32_bits(_up_twin(x))
    assert _f32_bits(down) == _f32_bits(_down_twin(x))
    if np.isnan(x):
        assert np.isnan(up) and np.isnan(down)
        return
    assert float(up) >= x and float(down) <= x
    with np.errstate(over="ignore"):
        below = np.nextafter(np.float32(up), np.float32(-np.inf))
        above = np.nextafter(np.float32(down), np.float32(np.inf))
    assert not float(below) >= x or np.isinf(up) and np.isinf(below)
    assert not float(above) <= x or np.isinf(down) and np.isinf(above)


@settings(max_examples=600, deadline=None)
@given(o=_F64_ANY.filter(lambda v: not np.isnan(v)),
       d=st.one_of(st.floats(-1.0, 1.0, width=64),
                   st.sampled_from([0.0, -0.0, 1e-39, -1e-39, 2.9e-39, -3e-39, 1e-300,
                                    -1e-300, 1.0, -1.0])))
def test_axis_setup_fast_equals_axis_setup(o, d):
    """Per axis: the same plane offset and the same float32 bits of the near and far
    origins and of the inverse, tiny directions (inverse beyond float32) included."""
    a, b = _setup_fast(o, d), _setup_twin(o, d)
    assert a[0] == b[0]
    assert [_f32_bits(x) for x in a[1:]] == [_f32_bits(x) for x in b[1:]]


# ---------------------------------------------------------------------------------------
# The walk against the walk it replaced
# ---------------------------------------------------------------------------------------
@njit(error_model="numpy", inline="always")
def _old_visit_order(mask, sd):
    if mask & (mask - 1) == 0:
        if mask == 0:
            return 0, 0
        lane = 0
        while mask > 1:
            mask >>= 1
            lane += 1
        return 1, lane
    return simd.order8(mask, sd)


@njit(error_model="numpy")
def _old_trace_closest(nodes, links, tris, ids, ox, oy, oz, dx, dy, dz, t0, t1, prev,
                       st_node, st_dist, sd, cn, cd):
    """``traverse.trace_closest`` as it was at commit b77ee8c (before issue 33's
    ENGINE8 visit), copied verbatim apart from names: the reference."""
    nx, onx, ofx, ix = simd.axis_setup(ox, dx)
    ny, ony, ofy, iy = simd.axis_setup(oy, dy)
    nz, onz, ofz, iz = simd.axis_setup(oz, dz)
    lo32 = simd.round_down32(t0)
    best_t = t1
    best_id = -1
    best_slot = -1
    best_u = 0.0
    best_v = 0.0
    if prev >= 0:
        t, u, v = moller_trumbore(tris, prev, ox, oy, oz, dx, dy, dz)
        if closer(t, ids, prev, t0, best_t, best_id):
            best_t = t
            best_id = ids[prev]
            best_slot = prev
            best_u = u
            best_v = v
    hi32 = simd.round_up32(best_t)
    cull = best_t * simd.ENTRY_SLACK
    sp = 0
    cur = 0
    while cur >= 0:
        mask = simd.slab8(nodes, cur * RECORD, nx, ny, nz, onx, ony, onz, ofx, ofy, ofz,
                          ix, iy, iz, lo32, hi32, sd)
        k, order = _old_visit_order(mask, sd)
        n_int = 0
        for q in range(k):
            lane = (order >> (4 * q)) & 15
            dq = np.float64(sd[lane])
            if dq > cull:
                continue
            cnt = links[cur, COUNT + lane]
            if cnt >= GROUP_MIN:
                first = links[cur, CHILD + lane]
                for g in range(first, first + cnt, GROUP):
                    hits, gt, gu, gv = mt4(tris, g, min(GROUP, first + cnt - g),
                                           ox, oy, oz, dx, dy, dz)
                    for m in range(GROUP):
                        if (hits >> m) & 1 and closer(gt[m], ids, g + m, t0, best_t,
                                                      best_id):
                            best_t = gt[m]
                            best_id = ids[g + m]
                            best_slot = g + m
                            best_u = gu[m]
                            best_v = gv[m]
                            hi32 = simd.round_up32(best_t)
                            cull = best_t * simd.ENTRY_SLACK
            elif cnt > 0:
                first = links[cur, CHILD + lane]
                for j in range(first, first + cnt):
                    t, u, v = moller_trumbore(tris, j, ox, oy, oz, dx, dy, dz)
                    if closer(t, ids, j, t0, best_t, best_id):
                        best_t = t
                        best_id = ids[j]
                        best_slot = j
                        best_u = u
                        best_v = v
                        hi32 = simd.round_up32(best_t)
                        cull = best_t * simd.ENTRY_SLACK
            else:
                cn[n_int] = links[cur, CHILD + lane]
                cd[n_int] = dq
                n_int += 1
        cur = -1
        cur_d = 0.0
        for q in range(n_int - 1, -1, -1):
            if cd[q] > cull:
                continue
            if cur >= 0:
                st_node[sp] = cur
                st_dist[sp] = cur_d
                sp += 1
            cur = cn[q]
            cur_d = cd[q]
        while cur < 0 and sp > 0:
            sp -= 1
            if st_dist[sp] <= cull:
                cur = st_node[sp]
    return best_t, best_id, best_slot, best_u, best_v


@njit(error_model="numpy")
def _walk_both(nodes, links, tris, ids, org, dirs, t0, t1, prev, stack_size, out):
    """Both walks for every ray; out[r] = new (t, id, slot, u, v), old (t, id, slot,
    u, v), floats as their bit patterns."""
    st_node, st_dist, sd, cn, cd = new_scratch(stack_size)
    for r in range(dirs.shape[0]):
        a = trace_closest(nodes, links, tris, ids, org[r, 0], org[r, 1], org[r, 2],
                          dirs[r, 0], dirs[r, 1], dirs[r, 2], t0[r], t1[r], prev[r],
                          st_node, st_dist, sd, cn, cd)
        b = _old_trace_closest(nodes, links, tris, ids, org[r, 0], org[r, 1], org[r, 2],
                               dirs[r, 0], dirs[r, 1], dirs[r, 2], t0[r], t1[r], prev[r],
                               st_node, st_dist, sd, cn, cd)
        for k, res in enumerate((a, b)):
            out[r, 5 * k] = np.array([res[0]]).view(np.int64)[0]
            out[r, 5 * k + 1] = res[1]
            out[r, 5 * k + 2] = res[2]
            out[r, 5 * k + 3] = np.array([res[3]]).view(np.int64)[0]
            out[r, 5 * k + 4] = np.array([res[4]]).view(np.int64)[0]


def _compare(scene, o, d, t0, t1, prev):
    """Runs both walks on the scene's own arrays (origins shifted into its local
    frame, unit directions) and returns the (n, 10) table; asserts equality."""
    local = np.ascontiguousarray(np.broadcast_to(o, d.shape) - scene.origin_offset)
    unit = np.ascontiguousarray(d / np.linalg.norm(d, axis=1)[:, None])
    out = np.zeros((len(d), 10), dtype=np.int64)
    _walk_both(scene._nodes, scene._nodes.view(np.int32), scene._tris, scene._ids, local,
               unit, t0, t1, prev, scene._stack_size, out)
    np.testing.assert_array_equal(out[:, :5], out[:, 5:])
    return out


def _soup_and_rays(seed, m, leaf, bounded):
    """A random soup of m triangles (leaves of at most ``leaf``) and 4000 random rays
    through it: 5 % of direction components zero (axis-parallel rays), t_min 0 or
    random, t_max finite on a ``bounded`` share of the rays, else inf, and a random
    warm-start slot on 30 % (else -1). Returns (scene, o, d, t0, t1, prev)."""
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-5.0, 5.0, (m, 1, 3))
    v = (centres + rng.normal(0.0, 0.4, (m, 3, 3))).reshape(-1, 3)
    scene = Scene(v, np.arange(3 * m).reshape(m, 3), max_leaf_size=leaf)
    n = 4000
    o = rng.uniform(-6.0, 6.0, (n, 3))
    d = rng.standard_normal((n, 3))
    d[rng.random((n, 3)) < 0.05] = 0.0
    d[np.linalg.norm(d, axis=1) == 0.0] = [0.0, 0.0, 1.0]
    t0 = np.where(rng.random(n) < 0.3, rng.uniform(0.0, 2.0, n), 0.0)
    t1 = np.where(rng.random(n) < bounded, t0 + rng.uniform(0.0, 6.0, n), np.inf)
    prev = np.where(rng.random(n) < 0.3, rng.integers(0, len(scene._ids), n), -1)
    return scene, o, d, t0, t1, prev


@pytest.mark.parametrize("seed, m, leaf", [(0, 400, 8), (1, 3000, 4), (2, 3000, 2),
                                           (3, 3000, 1), (4, 1500, 16)])
def test_walk_equals_the_old_walk_on_random_soups(seed, m, leaf):
    """Random triangle soups (leaves of 1 to 16 triangles, so visits hit 0, 1, 2 and 3+
    internal children and leaves of every group size), random rays with warm starts
    (a random slot, or -1) and random [t_min, t_max] (0 / finite / inf): t, input
    index, slot, u and v bit for bit as the old walk; and over a tenth of the rays hit."""
    scene, o, d, t0, t1, prev = _soup_and_rays(seed, m, leaf, bounded=0.3)
    out = _compare(scene, o, d, t0, t1, prev)
    n = len(d)
    hit = out[:, 2] >= 0
    assert n // 10 < hit.sum() < n


@pytest.mark.parametrize("leaf", [1, 3, 8])
def test_walk_inside_a_closed_mesh_hits_every_ray_as_the_old_walk(leaf):
    """From inside a closed, shifted icosphere every ray hits (0 misses), bit for bit as
    the old walk, rays aimed at vertices included."""
    v, f = icosphere(3, radius=3.0)
    v = v + [0.25, -0.5, 0.125]
    scene = Scene(v, f, max_leaf_size=leaf)
    rng = np.random.default_rng(leaf)
    o = np.array([0.5, -0.25, 0.0])
    d = np.vstack([rng.standard_normal((4000, 3)), v[:40] - o])
    n = len(d)
    out = _compare(scene, o, d, np.zeros(n), np.full(n, np.inf), np.full(n, -1))
    assert (out[:, 2] >= 0).all()


@pytest.mark.filterwarnings("ignore:Dropped .* zero-area:UserWarning")
@settings(max_examples=60, deadline=None)
@given(v=arrays(np.float64, (3 * 12, 3), elements=st.floats(-4.0, 4.0, width=64)),
       o=arrays(np.float64, (8, 3), elements=st.floats(-5.0, 5.0, width=64)),
       d=arrays(np.float64, (8, 3), elements=st.one_of(st.floats(-1.0, 1.0, width=64),
                                                       st.sampled_from([0.0, -0.0]))))
def test_walk_equals_the_old_walk_on_any_small_soup(v, o, d):
    """Hypothesis soups (degenerate and coincident triangles, zero direction
    components, one-triangle leaves): the same answers to the bit."""
    f = np.arange(36).reshape(12, 3)
    try:
        scene = Scene(v, f, max_leaf_size=1)
    except MeshError:                 # every triangle degenerate: nothing to walk
        return
    ok = np.linalg.norm(d, axis=1) > 1e-6
    if not ok.any():
        return
    n = int(ok.sum())
    _compare(scene, o[ok], d[ok], np.zeros(n), np.full(n, np.inf), np.full(n, -1))


@njit(error_model="numpy")
def _old_trace_any(nodes, links, tris, ox, oy, oz, dx, dy, dz, t0, t1, prev, st_node, sd):
    """``traverse.trace_any`` as it was at commit b77ee8c: the reference."""
    if prev >= 0:
        t, u, v = moller_trumbore(tris, prev, ox, oy, oz, dx, dy, dz)
        if t >= t0 and t <= t1:
            return prev
    nx, onx, ofx, ix = simd.axis_setup(ox, dx)
    ny, ony, ofy, iy = simd.axis_setup(oy, dy)
    nz, onz, ofz, iz = simd.axis_setup(oz, dz)
    lo32 = simd.round_down32(t0)
    hi32 = simd.round_up32(t1)
    sp = 0
    cur = 0
    while cur >= 0:
        mask = simd.slab8(nodes, cur * RECORD, nx, ny, nz, onx, ony, onz, ofx, ofy, ofz,
                          ix, iy, iz, lo32, hi32, sd)
        k, order = _old_visit_order(mask, sd)
        nxt = -1
        for q in range(k):
            lane = (order >> (4 * q)) & 15
            cnt = links[cur, COUNT + lane]
            child = links[cur, CHILD + lane]
            if cnt > 0:
                for j in range(child, child + cnt):
                    t, u, v = moller_trumbore(tris, j, ox, oy, oz, dx, dy, dz)
                    if t >= t0 and t <= t1:
                        return j
            elif nxt < 0:
                nxt = child
            else:
                st_node[sp] = child
                sp += 1
        cur = nxt
        if cur < 0 and sp > 0:
            sp -= 1
            cur = st_node[sp]
    return -1


@njit(error_model="numpy")
def _any_both(nodes, links, tris, org, dirs, t0, t1, prev, stack_size, out):
    """Both any-hit walks for every ray: out[r] = (new slot, old slot)."""
    st_node, st_dist, sd, cn, cd = new_scratch(stack_size)
    for r in range(dirs.shape[0]):
        out[r, 0] = trace_any(nodes, links, tris, org[r, 0], org[r, 1], org[r, 2],
                              dirs[r, 0], dirs[r, 1], dirs[r, 2], t0[r], t1[r], prev[r],
                              st_node, sd)
        out[r, 1] = _old_trace_any(nodes, links, tris, org[r, 0], org[r, 1], org[r, 2],
                                   dirs[r, 0], dirs[r, 1], dirs[r, 2], t0[r], t1[r],
                                   prev[r], st_node, sd)


@pytest.mark.parametrize("seed, m, leaf", [(5, 400, 8), (6, 3000, 3), (7, 3000, 1)])
def test_any_hit_walk_returns_the_old_walks_slot(seed, m, leaf):
    """``trace_any`` on random soups with warm starts and [t_min, t_max] limits returns
    the very slot the old walk returned (not only hit / no hit: the slot feeds the next
    ray's warm start), and its hit / no hit is ``trace_closest``'s."""
    scene, o, d, t0, t1, prev = _soup_and_rays(seed, m, leaf, bounded=0.5)
    n = len(d)
    local = np.ascontiguousarray(o - scene.origin_offset)
    unit = np.ascontiguousarray(d / np.linalg.norm(d, axis=1)[:, None])
    out = np.zeros((n, 2), dtype=np.int64)
    _any_both(scene._nodes, scene._nodes.view(np.int32), scene._tris, local, unit, t0, t1,
              prev, scene._stack_size, out)
    np.testing.assert_array_equal(out[:, 0], out[:, 1])
    closest = _compare(scene, o, d, t0, t1, np.full(n, -1))
    np.testing.assert_array_equal(out[:, 0] >= 0, closest[:, 2] >= 0)
    assert n // 10 < (out[:, 0] >= 0).sum() < n


# ---------------------------------------------------------------------------------------
# Emitted code
# ---------------------------------------------------------------------------------------
@needs_avx2
def test_leaf8_compiles_to_one_packed_compare():
    """The eight counts are compared by one packed 32-bit compare of a 256-bit (or
    wider) register, not eight scalar ones."""
    _leaf8(np.ones((1, 64), dtype=np.int32), COUNT)
    asm = _leaf8.inspect_asm(_leaf8.signatures[0])
    assert re.search(r"\bvpcmp\w*d\b[^\n]*%[yz]mm", asm), "no packed vpcmp*d"


@needs_avx2
def test_lowest_lane_is_one_instruction():
    """Count trailing zeros: ``tzcnt`` (or ``bsf``), no loop."""
    _lowest(8)
    asm = _lowest.inspect_asm(_lowest.signatures[0])
    assert re.search(r"\b(tzcnt|bsf)\w*\b", asm), "no tzcnt/bsf"


def test_the_walk_makes_no_library_call_to_round():
    """The walk rounds to float32 without library calls (``np.nextafter`` compiles to a
    call of ``numba_nextafterf``; the old walk's roundings do, as a check of the
    check)."""
    scene = Scene(*icosphere(1))

    @njit(error_model="numpy")
    def new_only(nodes, links, tris, ids, st_node, st_dist, sd, cn, cd):
        return trace_closest(nodes, links, tris, ids, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0,
                             np.inf, -1, st_node, st_dist, sd, cn, cd)

    @njit(error_model="numpy")
    def old_only(nodes, links, tris, ids, st_node, st_dist, sd, cn, cd):
        return _old_trace_closest(nodes, links, tris, ids, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0,
                                  0.0, np.inf, -1, st_node, st_dist, sd, cn, cd)

    args = (scene._nodes, scene._nodes.view(np.int32), scene._tris, scene._ids,
            *new_scratch(scene._stack_size))
    assert new_only(*args) == old_only(*args)
    assert "numba_nextafter" not in new_only.inspect_asm(new_only.signatures[0])
    assert "numba_nextafter" in old_only.inspect_asm(old_only.signatures[0])


_GENERIC_SCRIPT = r"""
import json, sys
import numpy as np
from raytrace import Scene
from raytrace._kernels import simd
from numba import njit

@njit(error_model="numpy")
def roundings(x, out):
    for i in range(x.shape[0]):
        out[i, 0] = simd.round_up32_fast(x[i])
        out[i, 1] = simd.round_down32_fast(x[i])

def case(seed, m=2000, n=3000):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-5.0, 5.0, (m, 1, 3))
    v = (centres + rng.normal(0.0, 0.4, (m, 3, 3))).reshape(-1, 3)
    scene = Scene(v, np.arange(3 * m).reshape(m, 3), max_leaf_size=3)
    o = rng.uniform(-6.0, 6.0, (n, 3))
    d = rng.standard_normal((n, 3))
    h = scene.cast(o, d, method="bvh")
    occ = scene.occluded(o, d, t_max=2.0)
    x = np.concatenate([rng.standard_normal(500) * 10.0 ** rng.integers(-40, 40, 500),
                        [0.0, -0.0, np.inf, -np.inf, 1e-45, -1e-45, 3.5e38, -3.5e38]])
    r = np.empty((x.size, 2), dtype=np.float32)
    roundings(x, r)
    return dict(t=h.t.view(np.int64).tolist(), tri=h.triangle.tolist(),
                u=h.u.view(np.int64).tolist(), v=h.v.view(np.int64).tolist(),
                occ=occ.tolist(), r=r.view(np.int32).ravel().tolist())

if __name__ == "__main__":
    print(json.dumps(case(int(sys.argv[1]))))
"""


def test_generic_cpu_gives_the_same_walk(tmp_path):
    """``NUMBA_CPU_NAME=generic`` (no AVX: LLVM splits the vectors; the empty ``asm``
    of ``leaf8`` on a generic target) in a subprocess with its own Numba cache agrees
    bit for bit with this process: casts, occlusion, fast roundings."""
    generic, host = generic_and_host(tmp_path, "generic_e8_walk", _GENERIC_SCRIPT)
    hits = sum(t >= 0 for t in host["tri"])
    assert 0 < hits < len(host["tri"])
    assert generic == host
